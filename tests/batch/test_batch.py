"""``mvm batch`` / ``mvm status`` on simulated clips with ground truth (local engine), the
manifest's claims and recovery, and resume. Helpers here are shared by the other batch tests."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from mvm.batch import Manifest, batch_status, discover_clips, run_batch
from mvm.batch.stages import StageResult
from mvm.io.ground_truth import read_ground_truth, write_simulation
from mvm.io.scene_dir import read_poses3d
from mvm.metrics.poses import match_persons, pose_errors
from mvm.sim.simulate import SimConfig, simulate

#: What makes a clip broken, and the text its recorded error must hold.
BROKEN = {
    "seq00/clip01": ("poses2d.json", "not valid JSON"),        # a corrupt detection file
    "seq01/clip04": ("frames", "no frames"),                   # no cameras, and no frames for SfM
    "seq02/clip07": ("poses2d.json", "annotations"),           # no people at all
    "lost": ("lost.mp4", "cannot open"),                        # a video that is not one
}


def make_root(root: Path, n: int = 9, people=(2, 3), frames=(12, 16), broken: bool = True) -> dict:
    """``n`` simulated clips in sequences of three (``seqSS/clipNN``), some broken on purpose
    (:data:`BROKEN`, when ``broken``) and a broken video. Returns {clip id: SimConfig} of the good clips."""
    good = {}
    for i in range(n):
        cid = f"seq{i // 3:02d}/clip{i:02d}"
        sim = SimConfig(people=people[0] + i % (people[1] - people[0] + 1),
                        frames=frames[0] + i % (frames[1] - frames[0] + 1), seed=100 + i)
        scene, truth = simulate(sim)
        write_simulation(root / cid, scene, truth, sim)
        good[cid] = sim
    if broken:
        for cid in [c for c in BROKEN if c in good]:
            del good[cid]
        if "seq00/clip01" in BROKEN and (root / "seq00/clip01").is_dir():
            (root / "seq00/clip01/poses2d.json").write_text('{"images": [')
        if (root / "seq01/clip04").is_dir():
            shutil.rmtree(root / "seq01/clip04/sparse")
        if (root / "seq02/clip07").is_dir():
            path = root / "seq02/clip07/poses2d.json"
            data = json.loads(path.read_text())
            data["annotations"] = []
            path.write_text(json.dumps(data))
        (root / "lost.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42 this is not a video")
    return good


def truth_error_mm(root: Path, cid: str) -> tuple[int, int, float]:
    """(persons found within 0.5 m, true persons, MPJPE mm) of a clip's result against its truth.
    A scene directory's cameras are its owner's: the batch records their scale from the people's
    bones but never rewrites them, so the result is in the simulation's metres."""
    truth = read_ground_truth(root / f"{cid}.groundtruth.json")
    path = root / cid / "mvm" / "poses3d.json"
    scale = json.loads(path.read_text())["scale"]
    assert not scale["applied_to_model"] and abs(scale["sfm_metres_per_unit"] - 1) < 0.15, (cid, scale)
    persons = read_poses3d(path)
    pairs = match_persons(persons.keypoints3d, truth.poses3d, 0.5)
    return len(pairs), len(truth.poses3d), 1000 * pose_errors(persons.keypoints3d, truth.poses3d, pairs)["mpjpe"]


def states(root: Path) -> dict:
    manifest = Manifest(root, create=False)
    try:
        return {(r["clip"], r["stage"]): r for r in manifest.stages()}
    finally:
        manifest.close()


def commits(root: Path) -> dict:
    manifest = Manifest(root, create=False)
    try:
        counts: dict = {}
        for h in manifest.history("commit"):
            counts[h["clip"], h["stage"]] = counts.get((h["clip"], h["stage"]), 0) + 1
        return counts
    finally:
        manifest.close()


def parse_outputs(root: Path, cids) -> None:
    """Every output file of the clips parses completely."""
    for cid in cids:
        json.loads((root / cid / "mvm" / "poses3d.json").read_text())
        json.loads((root / cid / "mvm" / "supervision" / "annotations.json").read_text())


# ------------------------------------------------------------------------------- discovery


def test_discovery_groups_clips_into_sequences(tmp_path):
    scene, truth = simulate(SimConfig(people=2, frames=10, seed=1))
    write_simulation(tmp_path / "single", scene, truth)               # a top-level scene directory
    write_simulation(tmp_path / "street" / "a", scene, truth)         # a sequence of two clips
    (tmp_path / "street" / "b.mp4").write_bytes(b"x")
    (tmp_path / "street" / "b").mkdir()                               # the video's scene directory
    (tmp_path / "street" / "b.detections.json").write_text("[]")
    (tmp_path / "alone.mov").write_bytes(b"x")
    (tmp_path / ".mvm").mkdir()
    (tmp_path / "empty").mkdir()                                      # a sequence without clips
    clips = {c.id: c for c in discover_clips(tmp_path)}
    assert sorted(clips) == ["alone", "single", "street/a", "street/b"]
    assert clips["street/a"].sequence == clips["street/b"].sequence == "street"
    assert clips["single"].sequence == "single" and clips["single"].video is None
    assert clips["street/b"].video.endswith("b.mp4") and clips["street/b"].detections.endswith("b.detections.json")
    assert clips["alone"].scene == str((tmp_path / "alone").resolve())


def test_discovery_of_nothing_is_one_line_error(tmp_path):
    result = CliRunner().invoke(__import__("mvm.cli", fromlist=["main"]).main, ["batch", str(tmp_path)])
    assert result.exit_code == 2
    assert result.output.strip().splitlines()[-1].startswith(f"mvm: error: {tmp_path.resolve()}: no clips")
    assert "Traceback" not in result.output


# ------------------------------------------------------------------------------ whole runs


@pytest.fixture(scope="module")
def finished_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("batch") / "root"
    good = make_root(root, n=9)
    summary = run_batch(root, workers=2)
    return root, good, summary


def test_good_clips_done_and_match_ground_truth(finished_root):
    root, good, summary = finished_root
    assert summary.clips == len(good) + 4
    assert summary.done == len(good)
    rows = states(root)
    for cid in good:
        assert rows[cid, "reconstruct"]["state"] == "done" and rows[cid, "export"]["state"] == "done"
        for stage in ("frames", "sfm", "detect"):                     # a simulated scene starts at reconstruct
            assert rows[cid, stage]["state"] == "skipped", (cid, stage)
        found, true, mpjpe = truth_error_mm(root, cid)
        assert found == true, cid
        assert mpjpe < 40.0, (cid, mpjpe)
        assert len(rows[cid, "reconstruct"]["checksum"]) == 64


def test_broken_clips_recorded_with_their_error(finished_root):
    root, good, summary = finished_root
    rows = states(root)
    failed = {clip: (stage, error) for clip, stage, error in summary.failed}
    assert set(failed) == set(BROKEN)
    for cid, (name, words) in BROKEN.items():
        stage, error = failed[cid]
        assert name in error and words in error, (cid, error)
        assert rows[cid, stage]["state"] == "failed" and rows[cid, stage]["error"] == error
        assert "Traceback" not in error and "\n" not in error
    assert failed["lost"][0] == "frames"
    assert rows["seq00/clip01", "export"]["state"] == "pending"      # never started after the failure


def test_statistics_and_training_set(finished_root):
    root, good, summary = finished_root
    status = batch_status(root)
    stats = status.statistics
    assert stats["clips"] == len(good)
    assert stats["sequences"] == 3
    assert stats["frames"] == sum(sim.frames for sim in good.values())
    docs = {cid: json.loads((root / cid / "mvm" / "poses3d.json").read_text()) for cid in good}
    assert stats["poses3d"] == sum(len(d["persons"]) for d in docs.values()) == sum(s.people for s in good.values())
    assert stats["matched_poses2d"] == sum(d["metrics"]["matched_poses"] for d in docs.values())
    poses2d = sum(len(json.loads((root / cid / "poses2d.json").read_text())["annotations"]) for cid in good)
    assert stats["matched_poses2d"] + stats["unmatched_poses2d"] == poses2d
    joints = sum(d["metrics"]["reconstructed_joints"] for d in docs.values())
    used = sum(d["metrics"]["G_k"] * d["metrics"]["reconstructed_joints"] for d in docs.values())
    assert stats["joints2d_per_triangulation"] == pytest.approx(used / joints, abs=0.06)
    assert stats["clips_per_sequence"] == pytest.approx(len(good) / 3, abs=0.01)
    assert status.clips == {"total": len(good) + 4, "done": len(good), "failed": 4, "running": 0, "pending": 0}
    merged = json.loads((root / ".mvm" / "training" / "annotations.json").read_text())
    parts = [json.loads((root / cid / "mvm" / "supervision" / "annotations.json").read_text()) for cid in good]
    assert len(merged["images"]) == sum(len(p["images"]) for p in parts) == stats["frames"]
    assert len(merged["annotations"]) == sum(len(p["annotations"]) for p in parts) > 0
    assert len({a["id"] for a in merged["annotations"]}) == len(merged["annotations"])


def test_status_command_table_and_json(finished_root):
    from mvm.cli.main import main

    root, good, _ = finished_root
    result = CliRunner().invoke(main, ["status", str(root), "--json"])
    assert result.exit_code == 0, result.output
    doc = json.loads(result.output)
    assert doc["statistics"]["clips"] == len(good) and doc["clips"]["failed"] == 4
    assert {f["clip"] for f in doc["failed"]} == set(BROKEN)
    table = CliRunner().invoke(main, ["status", str(root), "--verify"])
    assert table.exit_code == 0, table.output
    assert "generated 3D poses" in table.output and "avg. 2D joints per triangulation" in table.output


def test_rerun_does_only_what_is_not_done(finished_root, tmp_path):
    root, good, _ = finished_root
    copy = tmp_path / "root"
    shutil.copytree(root, copy, symlinks=True)
    before = commits(copy)
    scene, truth = simulate(SimConfig(people=2, frames=12, seed=999))
    write_simulation(copy / "seq03" / "new", scene, truth)            # a clip added since
    # Scene directories are recorded by absolute path: a copy has its own, so re-register.
    summary = run_batch(copy, workers=1)
    after = commits(copy)
    assert {k: v for k, v in after.items() if k[0] != "seq03/new"} == before
    assert after[("seq03/new", "reconstruct")] == after[("seq03/new", "export")] == 1
    assert summary.committed == 2
    assert all(v == 1 for v in after.values())
    assert {c for c, _, _ in summary.failed} == set(BROKEN)            # failures are tried again on a rerun


def test_an_output_that_cannot_be_written_fails_once_in_one_line(tmp_path):
    """A file where the output folder goes is the clip's fault, not the machine's: refused in
    one line naming it, and not retried (transient faults are: test_killed_worker_is_retried)."""
    scene, truth = simulate(SimConfig(people=2, frames=12, seed=3))
    write_simulation(tmp_path / "a", scene, truth)
    write_simulation(tmp_path / "b", scene, truth)
    (tmp_path / "b" / "mvm").write_text("a file where the output folder goes")
    summary = run_batch(tmp_path, stages=("reconstruct",), workers=1, retries=2)
    assert summary.done == 1 and [c for c, _, _ in summary.failed] == ["b"]
    assert summary.failed[0][2].endswith("b/mvm: cannot write: exists and is not a folder")
    manifest = Manifest(tmp_path, create=False)
    events = [h["event"] for h in manifest.history() if h["clip"] == "b"]
    row = {(r["clip"], r["stage"]): r for r in manifest.stages()}["b", "reconstruct"]
    manifest.close()
    assert events == ["claim", "fail"]
    assert row["attempts"] == 1 and row["state"] == "failed"


# -------------------------------------------------------------------------------- manifest


def test_claims_are_exclusive_and_dead_claims_recovered(tmp_path):
    from mvm.batch import Clip

    clip = Clip("a", "a", str(tmp_path / "a"))
    one, two = Manifest(tmp_path), Manifest(tmp_path)
    one.register([clip], ["reconstruct"])
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    run_a = one.begin_run("local", 1, ["reconstruct"])
    one.db.execute("UPDATE runs SET pid = ? WHERE id = ?", (dead.pid, run_a))   # a driver that died
    run_b = two.begin_run("local", 1, ["reconstruct"])
    assert one.claim(run_a, "a", "reconstruct")
    assert not two.claim(run_b, "a", "reconstruct")                  # held by run a
    assert two.recover_stale(run_b) == [("a", "reconstruct")]         # run a's process is gone
    assert two.claim(run_b, "a", "reconstruct")
    late = StageResult("a", "reconstruct", ok=True, checksum="0" * 64, files=1)
    assert not one.commit(run_a, late)                                # run a lost its claim: not recorded
    assert two.commit(run_b, late)
    assert [h["event"] for h in two.history()] == ["claim", "recover", "claim", "late", "commit"]
    live = Manifest(tmp_path)
    run_c = live.begin_run("local", 1, ["reconstruct"])               # this process: alive
    live.register([Clip("b", "b", str(tmp_path / "b"))], ["reconstruct"])
    assert live.claim(run_c, "b", "reconstruct")
    assert two.recover_stale(run_b) == []                             # a live run keeps its claims
    for m in (one, two, live):
        m.close()


def test_video_clip_runs_frames_and_detect(tmp_path):
    """A rendered video with imported detections (the true joints projected into each frame):
    ``frames`` and ``detect`` run on it, and the 2D poses are the projections."""
    pytest.importorskip("cv2", reason="the video stages need OpenCV (the 'video' extra)")
    from mvm.sim.mannequin_video import RenderConfig, render_video

    truth = render_video(tmp_path / "street" / "walk.mp4", RenderConfig(frames=8, width=320, height=180))
    cams = truth.cameras
    results = []
    for v in range(len(cams)):
        uvw = np.einsum("ij,gkj->gki", cams.P[v], np.concatenate([truth.poses3d, np.ones((3, 17, 1))], -1))
        uv = uvw[..., :2] / uvw[..., 2:]
        for g in range(len(uv)):
            kp = np.concatenate([uv[g], np.ones((17, 1))], -1)
            results.append({"image_id": v + 1, "category_id": 1, "keypoints": kp.round(2).ravel().tolist(),
                            "score": 0.9})
    (tmp_path / "street" / "walk.detections.json").write_text(json.dumps(results))
    summary = run_batch(tmp_path, stages=("frames", "detect"), workers=1)
    assert summary.done == 1 and not summary.failed, summary.failed
    rows = states(tmp_path)
    index = json.loads((tmp_path / "street" / "walk" / "frames.json").read_text())
    assert rows["street/walk", "frames"]["state"] == "done"
    assert rows["street/walk", "frames"]["files"] == 1 + len(index["frames"])
    poses = json.loads((tmp_path / "street" / "walk" / "poses2d.json").read_text())
    kept = [int(f["frame"]) for f in index["frames"]]
    assert len(poses["images"]) == len(kept) >= 6
    got = np.array([a["keypoints"] for a in poses["annotations"]]).reshape(len(kept), 3, 17, 3)
    want = np.array([r["keypoints"] for r in results]).reshape(len(cams), 3, 17, 3)[kept]
    assert np.allclose(got[..., :2], want[..., :2], atol=0.01)
    assert all(len(a["appearance"]) > 0 for a in poses["annotations"])      # colour descriptors of the frames
    assert run_batch(tmp_path, stages=("frames", "detect"), workers=1).committed == 0
