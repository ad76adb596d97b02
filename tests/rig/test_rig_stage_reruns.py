"""``mvm rig synchronize`` and ``mvm rig calibrate`` as stages (:mod:`mvm.stages.rig_synchronize`,
:mod:`mvm.stages.rig_calibrate`): made once with a record, kept on a second run (not rewritten),
made again with the reason when an input or a setting changes, forced with ``--force``; their
records, lying where the rig's pose files lie, are never read as a camera."""
from __future__ import annotations

import shutil

from click.testing import CliRunner

from board_scenes import CHARUCO, write_board_rig
from calibration_writers import known_cameras, write_qca
from mvm.cli.rig import rig
from mvm.io.calib_toml import read_calib_toml
from mvm.io.provenance import read_record, record_path
from mvm.io.rig_simulation import write_rig_simulation
from mvm.io.sync_toml import read_sync_toml
from mvm.rig.reconstruct_rig import rig_fingerprint_inputs
from mvm.rig.rigdir import pose_sources
from mvm.sim.rig_scene import RigSimConfig, simulate_rig
from mvm.stages import RIG_STAGES, RigJob, run_stage
from mvm.stages.rig_calibrate import STAGE as CALIBRATE
from mvm.stages.rig_calibrate import Calibration
from mvm.stages.rig_synchronize import STAGE as SYNCHRONIZE

OFFSETS = (0, 3, -2)


def _unsynced(root, flat: bool = False):
    """3 cameras, 2 people, 50 frames, known offsets and cameras; ``flat``: the pose files
    in the rig folder itself (no ``pose/``), where the records of sync.toml and of a calibration
    written there lie too."""
    sim = simulate_rig(RigSimConfig(cameras=3, people=2, frames=50, offsets=OFFSETS, seed=4))
    write_rig_simulation(root, sim)
    if flat:
        for pose in sorted((root / "pose").iterdir()):
            pose.rename(root / pose.name)
        (root / "pose").rmdir()
    return sim


def _mtime(path):
    return path.stat().st_mtime_ns


def test_the_rig_stages_in_the_order_of_the_path():
    assert [s.name for s in RIG_STAGES] == ["detect", "synchronize", "calibrate", "reconstruct"]


def test_synchronize_made_kept_redone_forced(tmp_path):
    root = tmp_path / "rig"
    sim = _unsynced(root)
    job = RigJob(root, max_offset=6)
    done = run_stage(SYNCHRONIZE, job)
    sync = root / "sync.toml"
    assert done.why == "no output yet"
    assert read_sync_toml(sync) == dict(zip(sim.calibration.cameras.names, sim.sync_offsets.tolist()))
    record = read_record(sync)
    assert record["stage"] == "the synchronization" and record["settings"]["max_offset"] == 6
    assert list(record["inputs"]) == ["Calib.toml", "pose/cam_01.json", "pose/cam_02.json", "pose/cam_03.json",
                                      "pose"]
    made = _mtime(sync)

    kept = run_stage(SYNCHRONIZE, job)
    assert kept.why is None and kept.result == read_sync_toml(sync) and _mtime(sync) == made

    assert run_stage(SYNCHRONIZE, RigJob(root, max_offset=5)).why == \
        "setting max_offset changed since the synchronization (6 -> 5)"
    run_stage(SYNCHRONIZE, job)
    pose = root / "pose" / "cam_02.json"
    pose.write_text(pose.read_text().replace('"score"', '"score" ', 1))    # same poses, other bytes
    assert run_stage(SYNCHRONIZE, job).why == "pose/cam_02.json changed since the synchronization"
    assert run_stage(SYNCHRONIZE, job, force=True).why == "forced"
    assert SYNCHRONIZE.why(job) is None

    before = _mtime(sync)
    result = CliRunner().invoke(rig, ["synchronize", str(root), "--max-offset", "6"])
    assert result.exit_code == 0, result.output
    assert "kept" in result.output and "cam_02 +3" in result.output and _mtime(sync) == before
    result = CliRunner().invoke(rig, ["synchronize", str(root), "--max-offset", "6", "--force"])
    assert result.exit_code == 0 and f"wrote {sync}" in result.output and _mtime(sync) > before


def test_calibrate_by_conversion_made_kept_redone_forced(tmp_path):
    cams = known_cameras(3)
    source = write_qca(tmp_path / "lab.qca.txt", cams)
    root = tmp_path / "rig"
    (root / "videos").mkdir(parents=True)
    for name in ("cam01", "cam02"):
        (root / "videos" / f"{name}.mp4").write_bytes(b"")
    out = tmp_path / "Calib.toml"
    job = RigJob(root, calibration=Calibration("convert", out, source=source))
    assert run_stage(CALIBRATE, job).why == "no output yet"
    assert read_calib_toml(out).cameras.names == ("cam01", "cam02")
    assert read_record(out)["inputs"]["cameras"].startswith("value:")
    made = _mtime(out)
    assert run_stage(CALIBRATE, job).why is None and _mtime(out) == made

    binned = RigJob(root, calibration=Calibration("convert", out, source=source, binning=2.0))
    assert run_stage(CALIBRATE, binned).why == "setting binning changed since the calibration (1.0 -> 2.0)"
    (root / "videos" / "cam03.mp4").write_bytes(b"")                         # a camera more: matched again
    assert run_stage(CALIBRATE, binned).why == "cameras changed since the calibration"
    assert read_calib_toml(out).cameras.names == ("cam01", "cam02", "cam03")
    assert run_stage(CALIBRATE, binned, force=True).why == "forced"

    args = ["calibrate", str(root), "--convert", str(source), "-o", str(out), "--binning", "2"]
    result = CliRunner().invoke(rig, args)
    assert result.exit_code == 0 and f"kept {out}" in result.output, result.output
    result = CliRunner().invoke(rig, [*args, "--force"])
    assert result.exit_code == 0 and f"wrote {out}" in result.output, result.output


def test_calibrate_with_a_board_made_kept_redone(tmp_path):
    """A ChArUco calibration of rendered board videos: kept while its videos and board are the
    same, made again when the board's size is another, or a camera's video changed."""
    from dataclasses import replace

    root = tmp_path / "rig"
    write_board_rig(root, CHARUCO, intrinsic_frames=6, extrinsic_frames=6)
    out = tmp_path / "Calib.toml"
    job = RigJob(root, calibration=Calibration("charuco", out, board=CHARUCO))
    assert run_stage(CALIBRATE, job).why == "no output yet"
    record = read_record(out)
    assert "calibration/extrinsics/cam_01.mp4" in record["inputs"] and record["settings"]["board"]["cols"] == 6
    made = _mtime(out)
    assert run_stage(CALIBRATE, job).why is None and _mtime(out) == made

    bigger = RigJob(root, calibration=Calibration("charuco", out, board=replace(CHARUCO, square_m=0.2, marker_m=0.15)))
    assert CALIBRATE.why(bigger) == "setting board.marker_m changed since the calibration (0.075 -> 0.15)"
    video = root / "calibration" / "extrinsics" / "cam_02.mp4"
    video.write_bytes(video.read_bytes() + b"\0")
    assert CALIBRATE.why(job) == "calibration/extrinsics/cam_02.mp4 changed since the calibration"


def test_a_calibration_is_not_asked_for_without_its_request(tmp_path):
    assert CALIBRATE.applies(RigJob(tmp_path)) is not None


def test_records_in_the_rig_folder_are_never_a_camera(tmp_path):
    """Pose files in the rig folder itself: sync.toml's record and a calibration's record lie
    beside them; the cameras, the reconstruction's inputs and its output are those without them."""
    root = tmp_path / "rig"
    _unsynced(root, flat=True)
    cameras = pose_sources(root)
    assert run_stage(SYNCHRONIZE, RigJob(root, max_offset=6)).why is not None
    people = root / "people.toml"
    assert run_stage(CALIBRATE, RigJob(root, calibration=Calibration("people", people, intrinsics=root / "Calib.toml"))
                     ).why is not None
    assert record_path(root / "sync.toml").is_file() and record_path(people).is_file()
    assert pose_sources(root) == cameras
    assert not [name for name in rig_fingerprint_inputs(root, people) if name.endswith(".inputs.json")]

    bare = tmp_path / "bare"
    shutil.copytree(root, bare)
    for record in (record_path(bare / "sync.toml"), record_path(bare / "people.toml")):
        record.unlink()
    for folder in (root, bare):
        result = CliRunner().invoke(rig, ["reconstruct", str(folder), "--calib", str(folder / "people.toml"),
                                          "--no-refine", "--workers", "1"])
        assert result.exit_code == 0, result.output
    assert (root / "mvm" / "poses3d.jsonl").read_bytes() == (bare / "mvm" / "poses3d.jsonl").read_bytes()
    assert read_calib_toml(people).cameras.names == tuple(p.removesuffix(".json") for p in cameras)
