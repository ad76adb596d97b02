"""The rig's outputs: complete people with flags in poses3d.jsonl, .trc files that carry only
observed and interpolated markers and say so, --no-complete, and the output set as one unit."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner
from test_rig_dir import _write_rig

from mvm.cli.rig import rig
from mvm.core.camera import project_views
from mvm.core.config import Config
from mvm.errors import InputError
from mvm.io.openpose import BODY25_TO_COCO17
from mvm.io.outputs import make_temporary_dir
from mvm.io.trc import read_trc, to_opensim
from mvm.rig.options import RigOptions
from mvm.rig.reconstruct_rig import reconstruct_rig


def _lines(folder):
    return [json.loads(line) for line in (folder / "poses3d.jsonl").read_text().splitlines()]


@pytest.fixture(scope="module")
def rig_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("rig")
    cameras, truth = _write_rig(root, T=12)
    # hide the left wrist of every camera's detections at instants 7..9: no view sees it
    for path in (root / "pose").glob("*/*_keypoints.json"):
        frame = int(path.stem.split("_")[-2])
        if 7 <= frame <= 9:
            data = json.loads(path.read_text())
            for person in data["people"]:
                person["pose_keypoints_2d"][3 * 7:3 * 7 + 3] = [0, 0, 0]   # BODY25 LWrist
            path.write_text(json.dumps(data))
    return root, truth


def test_complete_people_are_flagged(rig_dir, tmp_path):
    root, truth = rig_dir
    result = reconstruct_rig(root, Config(refine=False), output=tmp_path / "out")
    lines = _lines(tmp_path / "out")
    persons = [p for line in lines for p in line["persons"]]
    assert all(None not in sum(p["keypoints3d"], []) for p in persons)     # all 17 joints everywhere
    wrist = [p["flags"][9] for line in lines[7:10] for p in line["persons"]]
    assert wrist and set(wrist) == {"interpolated"}
    assert {f for p in persons for f in p["flags"]} <= {"observed", "interpolated", "inferred"}
    for line in lines[7:10]:
        for p in line["persons"]:
            views = p["views_per_joint"]
            assert views[9] == 0                                           # not seen by any camera
            x = np.array(p["keypoints3d"][9][:3])
            assert np.linalg.norm(truth[line["frame"], :, 9] - x, axis=-1).min() < 0.05
    recap = json.loads((tmp_path / "out" / "recap.json").read_text())
    assert recap["joint_flags"]["interpolated"] > 0 and recap["joint_flags"]["missing"] == 0
    assert recap["tracks"] == 2 and result.flags.shape == (len(result.persons), 17)
    assert recap["persons_filled_whole"] == 0                              # no instant missed a person
    for path in sorted((tmp_path / "out" / "tracks").glob("*.trc")):
        trc = read_trc(path)
        assert "interpolated" in trc.comment and "30 frames" in trc.comment
        assert np.isfinite(trc.points).all()                               # every marker at every frame
        expected = to_opensim(truth, "+z")                                   # (T, G, 17, 3)
        err = np.linalg.norm(trc.points[:, None] - expected, axis=-1).mean(axis=(0, 2))
        assert err.min() < 0.05


def test_no_complete_keeps_nulls(rig_dir, tmp_path):
    root, _ = rig_dir
    out = tmp_path / "plain"
    result = CliRunner().invoke(rig, ["reconstruct", str(root), "--no-refine", "--no-complete", "-o", str(out)])
    assert result.exit_code == 0, result.output
    lines = _lines(out)
    wrist = [p["keypoints3d"][9] for line in lines[7:10] for p in line["persons"]]
    assert wrist and all(w == [None, None, None, 0.0] for w in wrist)
    assert {p["flags"][9] for line in lines[7:10] for p in line["persons"]} == {"missing"}
    trc = read_trc(next((out / "tracks").glob("*.trc")))
    assert np.isnan(trc.points[7:10, 9]).all() and "left empty" in trc.comment


def test_an_instant_no_camera_saw_a_person_at_is_filled_and_said_so(tmp_path):
    """No camera has a pose of one of the two people at instant 5 of 12: its track resumes after
    it and has a person there, every joint interpolated near the truth, no member, no view; the
    recap counts it and the command says so. Without completion the instant holds the other
    person only."""
    root = tmp_path / "rig"
    root.mkdir()
    cameras, truth = _write_rig(root, T=12)
    for path in (root / "pose").glob("*/*_000000000005_keypoints.json"):
        data = json.loads(path.read_text())
        view = next(v for v, n in enumerate(cameras.names) if path.parent.name == f"{n.replace('_', '')}_json")
        uv = project_views(cameras.subset([view]), truth[5, 0])[0][0]             # (17, 2)
        distance = [np.linalg.norm(np.reshape(p["pose_keypoints_2d"], (25, 3))[BODY25_TO_COCO17, :2] - uv,
                                   axis=-1).mean() for p in data["people"]]
        data["people"].pop(int(np.argmin(distance)))                              # person 0, from every camera
        path.write_text(json.dumps(data))
    result = CliRunner().invoke(rig, ["reconstruct", str(root), "--no-refine", "-o", str(tmp_path / "a")])
    assert result.exit_code == 0, result.output
    assert "24 persons (1 filled where a track missed them)" in " ".join(result.output.split())
    filled = [p for p in _lines(tmp_path / "a")[5]["persons"] if not p["members"]]
    assert len(_lines(tmp_path / "a")[5]["persons"]) == 2 and len(filled) == 1
    assert filled[0]["views_per_joint"] == [0] * 17 and filled[0]["reprojection_error_px"] is None
    assert set(filled[0]["flags"]) == {"interpolated"}
    x = np.array([k[:3] for k in filled[0]["keypoints3d"]])
    assert np.linalg.norm(truth[5, 0] - x, axis=-1).mean() < 0.03
    assert json.loads((tmp_path / "a" / "recap.json").read_text())["persons_filled_whole"] == 1
    # the filled instant does not count towards a track's length: seen at 11 instants, not 12
    result = CliRunner().invoke(rig, ["reconstruct", str(root), "--no-refine", "--rig-set", "min_track_length=12",
                                      "-o", str(tmp_path / "c")])
    assert result.exit_code == 0, result.output
    assert len(list((tmp_path / "c" / "tracks").glob("*.trc"))) == 1
    result = CliRunner().invoke(rig, ["reconstruct", str(root), "--no-refine", "--no-complete", "-o",
                                      str(tmp_path / "b")])
    assert result.exit_code == 0, result.output
    assert [p["members"] != {} for p in _lines(tmp_path / "b")[5]["persons"]] == [True]


def test_inferred_joints_stay_out_of_trc_unless_asked(tmp_path):
    root = tmp_path / "rig"
    root.mkdir()
    _write_rig(root, T=6)
    for path in (root / "pose").glob("*/*_keypoints.json"):                # no camera sees a right ankle
        data = json.loads(path.read_text())
        for person in data["people"]:
            person["pose_keypoints_2d"][3 * 11:3 * 11 + 3] = [0, 0, 0]     # BODY25 RAnkle
        path.write_text(json.dumps(data))
    reconstruct_rig(root, Config(refine=False), output=tmp_path / "a")
    line = _lines(tmp_path / "a")[0]
    assert {p["flags"][16] for p in line["persons"]} == {"inferred"}
    trc = read_trc(next((tmp_path / "a" / "tracks").glob("*.trc")))
    assert np.isnan(trc.points[:, 16]).all() and np.isfinite(trc.points[:, 15]).all()
    reconstruct_rig(root, Config(refine=False), RigOptions(trc_inferred=True), output=tmp_path / "b")
    trc = read_trc(next((tmp_path / "b" / "tracks").glob("*.trc")))
    assert np.isfinite(trc.points[:, 16]).all() and "inferred" in trc.comment


def test_output_set_is_one_unit(rig_dir, tmp_path, monkeypatch):
    root, _ = rig_dir
    out = tmp_path / "set"
    reconstruct_rig(root, Config(refine=False), output=out)
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    # a run that fails while writing its .trc files leaves the previous set untouched
    import mvm.rig.reconstruct_rig as driver

    def broken(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(driver, "write_tracks", broken)
    with pytest.raises(InputError, match="no space left"):
        reconstruct_rig(root, Config(refine=False), output=out)
    monkeypatch.undo()
    after = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert after == before
    assert [p.name for p in tmp_path.iterdir()] == ["set"]                 # no temporary folder left
    # a killed run's folders are removed by the next run; a shorter run leaves no .trc of the
    # longer one
    killed = make_temporary_dir(out)                                      # as atomic_replace_dir makes them
    (killed / "poses3d.jsonl").write_text("partial")
    (tmp_path / ".set.old.12345").mkdir()                                 # a user's folder of that pattern stays
    (tmp_path / ".set.old.12345" / "notes.txt").write_text("mine")
    (out / "tracks" / "track_7.trc").write_text("stale")
    reconstruct_rig(root, Config(refine=False), frames="0:6", output=out)
    assert sorted(p.name for p in tmp_path.iterdir()) == [".set.old.12345", "set"]
    assert (tmp_path / ".set.old.12345" / "notes.txt").read_text() == "mine"
    assert not (out / "tracks" / "track_7.trc").exists()
    assert len(_lines(out)) == 6 and json.loads((out / "recap.json").read_text())["instants"] == 6


def test_output_that_cannot_be_written_is_one_line(rig_dir, tmp_path):
    root, _ = rig_dir
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="not a folder"):
        reconstruct_rig(root, Config(refine=False), output=tmp_path / "file")
    if os.geteuid() != 0:
        locked = tmp_path / "locked"
        locked.mkdir()
        locked.chmod(0o500)
        try:
            with pytest.raises(InputError, match="cannot write"):
                reconstruct_rig(root, Config(refine=False), output=locked / "out")
        finally:
            locked.chmod(0o700)


def test_cutoff_follows_frame_rate_and_stays_below_nyquist():
    assert RigOptions().cutoff == 6.0 and RigOptions(frame_rate=10).cutoff == 2.0
    with pytest.raises(ValueError, match="cutoff_hz: must be below half the frame rate"):
        RigOptions(frame_rate=10, cutoff_hz=6)
    with pytest.raises(ValueError, match="cutoff_hz"):
        RigOptions(cutoff_hz=float("inf"))
    RigOptions(frame_rate=10, cutoff_hz=6, smoothing="none")               # no filter, no constraint
    run = subprocess.run([sys.executable, "-c", "from mvm.cli.main import run; run()", "rig", "reconstruct", "nowhere",
                          "--frame-rate", "10", "--rig-set", "cutoff_hz=6"], capture_output=True, text=True)
    assert run.returncode == 2 and "cutoff_hz" in run.stderr and "Traceback" not in run.stderr
    assert len(run.stderr.strip().splitlines()) == 1


def test_two_workers_write_the_same_files_as_one(tmp_path, monkeypatch):
    """Reading, reconstruction, refinement and formatting shared out over two processes give
    byte-identical outputs, and each of the four phases did run in two parts."""
    import mvm.parallel
    import mvm.rig.reconstruct_rig as driver

    _write_rig(tmp_path / "rig", T=200)
    parts, real = [], mvm.parallel.fork_map

    def recording(fn, chunks, workers=None):
        parts.append(len(chunks))
        return real(fn, chunks, workers)

    for module in (mvm.parallel, driver):              # fork_map_ranges' and the refinement's
        monkeypatch.setattr(module, "fork_map", recording)
    outputs = {}
    for workers in (1, 2):
        parts.clear()
        reconstruct_rig(tmp_path / "rig", Config(), RigOptions(workers=workers), output=tmp_path / f"out{workers}")
        outputs[workers] = parts.copy()
        assert parts == [workers] * 4
    for name in ["poses3d.jsonl"] + [f"tracks/{p.name}" for p in (tmp_path / "out1" / "tracks").iterdir()]:
        assert (tmp_path / "out1" / name).read_bytes() == (tmp_path / "out2" / name).read_bytes(), name


def _tree(path):
    return {p.relative_to(path).as_posix(): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


def _refused(*args):
    """Exit status and output lines of ``mvm rig reconstruct ARGS``."""
    result = CliRunner().invoke(rig, ["reconstruct", *map(str, args), "--no-refine", "--workers", "1"])
    assert "Traceback" not in result.output
    return result.exit_code, result.output.strip().splitlines()


def test_an_output_that_would_replace_the_rigs_inputs_is_refused(rig_dir, tmp_path):
    import shutil

    root = shutil.copytree(rig_dir[0], tmp_path / "rig")
    (root / "notes.txt").write_text("my notes")
    before = _tree(root)
    for output, problem in ((root, "contains the input"), (root / "pose", "is an input of this run"),
                            (root / "pose" / "cam1_json", "is an input of this run"),
                            (root / "pose" / "new", "lies inside the input folder")):
        code, lines = _refused(root, "-o", output)
        assert code == 2 and len(lines) == 1 and lines[0].startswith(f"mvm: error: {output}: "), lines
        assert problem in lines[0]
        assert _tree(root) == before                                       # Calib.toml, pose/, notes.txt kept
    user = tmp_path / "thesis"
    (user / "data").mkdir(parents=True)
    (user / "thesis.tex").write_text("chapter 1")
    (user / "data" / "x.csv").write_text("1,2")
    code, lines = _refused(root, "-o", user)
    assert code == 2 and len(lines) == 1 and "mvm did not make" in lines[0]
    assert _tree(user) == {"thesis.tex": b"chapter 1", "data/x.csv": b"1,2"}
    # the default output and a folder of the rig's own are fine, and stay fine on a rerun
    (root / ".mvm.backup").mkdir()
    (root / ".mvm.backup" / "old.jsonl").write_text("a user's copy")
    for _ in range(2):
        assert _refused(root)[0] == 0 and _refused(root, "-o", root / "results")[0] == 0
    assert (root / ".mvm.backup" / "old.jsonl").read_text() == "a user's copy"
    assert {k: v for k, v in _tree(root).items() if not k.startswith(("mvm/", "results/"))} == {
        **before, ".mvm.backup/old.jsonl": b"a user's copy"}


@pytest.mark.parametrize("sets, association, runs_3d", [([], "paper", False),
                                                         (["--set", "association=3d"], "3d", True),
                                                         (["--set", "association=paper"], "paper", False)])
def test_the_association_set_is_the_one_run_and_recorded_once(rig_dir, tmp_path, monkeypatch, sets, association,
                                                               runs_3d):
    """``--set association=3d`` on a rig runs the association consistent in 3D (by default a rig
    keeps the paper's grouping), and recap.json records the setting in effect, once."""
    import mvm.core.pipeline

    root, _ = rig_dir
    calls, real = [], mvm.core.pipeline.associate_poses

    def counting(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(mvm.core.pipeline, "associate_poses", counting)
    out = tmp_path / "out"
    result = CliRunner().invoke(rig, ["reconstruct", str(root), "--no-refine", "--workers", "1", "-o", str(out), *sets])
    assert result.exit_code == 0, result.output
    assert bool(calls) == runs_3d
    recap = (out / "recap.json").read_text()
    assert recap.count('"association"') == 1 and recap.count('"complete"') == 1
    document = json.loads(recap)
    assert document["config"]["association"] == association and document["config"]["complete"] is True
    assert "association" not in document["options"]


def test_defaults_left_to_the_driver_are_the_drivers():
    assert Config().association == "auto" and Config().complete is None
    assert (Config().for_driver("rig").association, Config().for_driver("rig").complete) == ("paper", True)
    assert (Config().for_driver("scene").association, Config().for_driver("scene").complete) == ("3d", False)
    explicit = Config(association="3d", complete=False)
    assert explicit.for_driver("rig") is explicit
