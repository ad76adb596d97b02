"""A rig from raw poses: synchronize (sync.toml), calibrate from the people, reconstruct — on a
simulated rig with the detector's errors (true offsets, true cameras), and the bad input of each
step (one line naming the camera or file, exit 2, nothing written)."""
import dataclasses
import json

import numpy as np
import pytest
from click.testing import CliRunner

from mvm.cli.rig import rig
from mvm.cli.sim import simulate_cmd
from mvm.io.calib_toml import read_calib_toml
from mvm.io.rig_simulation import write_rig_simulation
from mvm.io.sync_toml import read_sync_toml, write_sync_toml
from mvm.metrics.poses import similarity_transform
from mvm.rig import calibrate
from mvm.rig.calibrate import calibrate_from_people
from mvm.rig.rigdir import read_rig
from mvm.sim.rig_scene import RigSimConfig, simulate_rig

OFFSETS = (0, 4, -3, 2)


@pytest.fixture(scope="module")
def unsynced(tmp_path_factory):
    """4 cameras, 3 people, 70 frames, offsets of several frames each way, intrinsics only."""
    root = tmp_path_factory.mktemp("rig") / "unsynced"
    sim = simulate_rig(RigSimConfig(cameras=4, people=3, frames=70, offsets=OFFSETS, seed=3))
    write_rig_simulation(root, sim, intrinsics_only=True)
    return root, sim


def _invoke(command, args):
    result = CliRunner().invoke(command, [str(a) for a in args])
    return result


@pytest.mark.slow
def test_synchronize_calibrate_reconstruct_chain(unsynced, tmp_path):
    root, sim = unsynced
    result = _invoke(rig, ["synchronize", root, "--max-offset", 8])
    assert result.exit_code == 0, result.output
    offsets = read_sync_toml(root / "sync.toml")
    assert offsets == dict(zip(sim.calibration.cameras.names, sim.sync_offsets.tolist()))

    out = tmp_path / "people.toml"
    result = _invoke(rig, ["calibrate", root, "--from-people", "-o", out])
    assert result.exit_code == 0, result.output
    found = read_calib_toml(out)
    assert len(found.metadata["residual_px"]) == 4 and max(found.metadata["residual_px"]) < 5.0
    true = sim.calibration.cameras
    s, R, t = similarity_transform(found.cameras.centers, true.centers)
    error = np.linalg.norm(s * found.cameras.centers @ R.T + t - true.centers, axis=1)
    assert error.mean() < 0.05                                               # camera centres within 5 cm
    assert abs(s - 1) < 0.1                                                  # metres from the bones
    assert np.abs(found.cameras.centers[:, 2] - true.centers[:, 2]).max() < 0.15   # up from the bodies, floor

    result = _invoke(rig, ["reconstruct", root, "--calib", out, "--no-refine"])
    assert result.exit_code == 0, result.output
    assert "synchronized by sync.toml" in result.output
    recap = json.loads((root / "mvm" / "recap.json").read_text())
    assert recap["sync_offsets"] == offsets and recap["persons"] > 0
    lines = (root / "mvm" / "poses3d.jsonl").read_text().splitlines()
    assert json.loads(lines[0])["frame"] == min(0, *sim.sync_offsets.tolist())   # the reference camera's numbering


def test_calibrate_small_simulated_rig_math():
    sim = simulate_rig(RigSimConfig(cameras=3, people=2, frames=40, seed=5))
    from mvm.rig.rigdir import undistort

    kp = undistort(sim.calibration, sim.keypoints, sim.camera)
    true = sim.calibration.cameras
    found = calibrate_from_people(kp, sim.camera, sim.frame, true)
    assert found.cameras.names == true.names and np.array_equal(found.cameras.size, true.size)
    assert np.array_equal(found.cameras.K, true.K) and np.array_equal(found.cameras.fisheye, true.fisheye)
    est = found.cameras.centers
    s, R, t = similarity_transform(est, true.centers)
    assert np.linalg.norm(s * est @ R.T + t - true.centers, axis=1).mean() < 0.05
    assert (found.residual_px < 5).all() and [c for _, c in found.tree] and sorted(c for _, c in found.tree) == [1, 2]


def _one_line_exit_2(result, *words):
    assert result.exit_code == 2, result.output
    line = result.output.strip().splitlines()[-1]
    assert line.startswith("mvm: error:") and all(w in line for w in words), line


def test_one_camera_refused(tmp_path):
    root = tmp_path / "one"
    write_rig_simulation(root, simulate_rig(RigSimConfig(cameras=1, people=2, frames=20)), intrinsics_only=True)
    _one_line_exit_2(_invoke(rig, ["synchronize", root]), "Calib.toml", "a rig needs 2")
    _one_line_exit_2(_invoke(rig, ["calibrate", root, "--from-people", "-o", tmp_path / "c.toml"]), "a rig needs 2")
    assert not (root / "sync.toml").exists() and not (tmp_path / "c.toml").exists()


@pytest.mark.slow
def test_camera_without_common_people_refused(unsynced, tmp_path):
    root, _ = unsynced
    moved = tmp_path / "moved"
    moved.mkdir()
    (moved / "Calib.toml").write_text((root / "Calib.toml").read_text())
    (moved / "pose").mkdir()
    for f in (root / "pose").glob("*.json"):
        doc = json.loads(f.read_text())
        if f.stem == "cam_03":                               # its frames share no instant with the others'
            for image in doc["images"]:
                image["file_name"] = image["file_name"].replace("/0", "/9")
        (moved / "pose" / f.name).write_text(json.dumps(doc))
    _one_line_exit_2(_invoke(rig, ["synchronize", moved, "--max-offset", 8]), "cam_03")
    _one_line_exit_2(_invoke(rig, ["calibrate", moved, "--from-people", "-o", tmp_path / "c.toml"]),
                     "cam_03", "shares no people")
    assert not (moved / "sync.toml").exists() and not (tmp_path / "c.toml").exists()


def test_offsets_beyond_the_videos_refused(unsynced, tmp_path):
    root, _ = unsynced
    _one_line_exit_2(_invoke(rig, ["synchronize", root, "--max-offset", 500]), "--max-offset", "videos' length")
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "Calib.toml").write_text((root.parent / "unsynced.groundtruth.toml").read_text())
    (bad / "pose").mkdir()
    for f in (root / "pose").glob("*.json"):
        (bad / "pose" / f.name).write_text(f.read_text())
    write_sync_toml(bad / "sync.toml", {"cam_01": 0, "cam_02": 500, "cam_03": 0, "cam_04": 0})
    _one_line_exit_2(_invoke(rig, ["reconstruct", bad]), "sync.toml", "cam_02", "beyond the videos' length")
    assert not (bad / "mvm").exists()


@pytest.mark.slow
def test_calibration_that_does_not_converge_refused(unsynced, tmp_path, monkeypatch):
    root, _ = unsynced
    monkeypatch.setattr(calibrate, "MAX_RESIDUAL_PX", 0.01)
    out = tmp_path / "c.toml"
    _one_line_exit_2(_invoke(rig, ["calibrate", root, "--from-people", "-o", out]), "does not converge", "camera cam_")
    assert not out.exists()


def test_rig_help_reads_as_the_path():
    text = CliRunner().invoke(rig, ["--help"]).output
    commands = text[text.index("Commands:"):]
    assert commands.index("synchronize") < commands.index("calibrate") < commands.index("reconstruct")


def test_simulate_rig_command(tmp_path):
    result = _invoke(simulate_cmd, [tmp_path / "r", "--rig", "--cameras", 3, "--people", 2, "--frames", 20,
                                    "--offsets", "0,2,-1", "--intrinsics-only"])
    assert result.exit_code == 0, result.output
    truth = json.loads((tmp_path / "r.groundtruth.json").read_text())
    assert truth["sync_offsets"] == {"cam_01": 0, "cam_02": 2, "cam_03": -1}
    assert read_rig(tmp_path / "r", extrinsics=False).calibration.cameras.names == ("cam_01", "cam_02", "cam_03")
    _one_line_exit_2(_invoke(simulate_cmd, [tmp_path / "s", "--rig", "--cameras", 3, "--offsets", "0,2"]),
                     "--offsets", "3 numbers")
    _one_line_exit_2(_invoke(simulate_cmd, [tmp_path / "s", "--rig", "--cameras", 3, "--offsets", "0,x,1"]),
                     "--offsets", "whole numbers")
    _one_line_exit_2(_invoke(simulate_cmd, [tmp_path / "s", "--rig", "--cameras", 3, "--frames", 20,
                                            "--offsets", "0,10" + "0" * 30 + ",1"]), "offsets")
    assert not (tmp_path / "s").exists()


def test_read_rig_applies_sync_toml_in_the_reference_numbering(tmp_path):
    sim = simulate_rig(RigSimConfig(cameras=3, people=2, frames=20, offsets=(0, 2, -3), seed=2))
    write_rig_simulation(tmp_path / "r", sim)
    write_sync_toml(tmp_path / "r" / "sync.toml", dict(zip(sim.calibration.cameras.names, sim.sync_offsets.tolist())))
    data = read_rig(tmp_path / "r", frames="0:10")
    assert data.offsets == {"cam_01": 0, "cam_02": 2, "cam_03": -3}
    assert data.frames.tolist() == list(range(10))
    det = data.detections
    for c, offset in enumerate(sim.sync_offsets):      # camera c's frame f is the reference frame f + offset
        mine = (sim.camera == c) & (sim.frame + offset >= 0) & (sim.frame + offset < 10)
        assert (det.view == c).sum() == mine.sum()
    assert read_rig(tmp_path / "r", sync=False).offsets is None


def test_focal_lengths_refined_from_people():
    """Focal lengths given 5 % off, alternately up and down: the bundle adjustment brings them
    within 1.5 % and the camera centres within 5 cm (16 cm without refining them)."""
    sim = simulate_rig(RigSimConfig(cameras=3, people=2, frames=40, seed=5))
    from mvm.rig.rigdir import undistort

    kp = undistort(sim.calibration, sim.keypoints, sim.camera)
    true = sim.calibration.cameras
    off = np.array([1.05, 0.95, 1.05])
    K = true.K.copy()
    K[:, :2, :2] *= off[:, None, None]
    found = calibrate_from_people(kp, sim.camera, sim.frame, dataclasses.replace(true, K=K), refine_focal=True)
    assert np.abs(off * found.focal_scale - 1).max() < 0.015
    assert np.abs(found.cameras.K[:, 0, 0] / true.K[:, 0, 0] - 1).max() < 0.015
    est = found.cameras.centers
    s, R, t = similarity_transform(est, true.centers)
    assert np.linalg.norm(s * est @ R.T + t - true.centers, axis=1).mean() < 0.05
    assert (found.residual_px < 5).all()


def test_output_on_an_input_refused_before_work(unsynced, tmp_path, monkeypatch):
    """-o on the rig's Calib.toml (the intrinsics read), the --intrinsics file, a pose folder, or a
    link to the Calib.toml: one line naming -o, before any calibration, the inputs unchanged."""
    root, _ = unsynced
    monkeypatch.setattr("mvm.rig.prepare.read_rig", lambda *a, **k: pytest.fail("worked before refusing"))
    calib = next(root.glob("*.toml"))
    before = calib.read_bytes()
    link = tmp_path / "link.toml"
    link.symlink_to(calib)
    pose = next(p for p in (root / "pose").iterdir())
    for out, extra, problem in ((calib, [], "is an input"), (link, [], "is an input"), (calib, ["--intrinsics", calib],
                                "is an input"), (pose / "c.toml", [], "inside the input folder"),
                                (root / "pose", [], "is a directory")):
        _one_line_exit_2(_invoke(rig, ["calibrate", root, "--from-people", "-o", out, *extra]), str(out), problem)
    assert calib.read_bytes() == before and link.is_symlink()


def _static_bystander_rig(seed: int = 2):
    """4 cameras without lens distortion; cameras 0-2 see a walking person and a person standing
    still, camera 3 the one standing still only: ``(sim, keypoints, camera, frame)``, 1 px noise."""

    sim = simulate_rig(RigSimConfig(cameras=4, people=2, frames=40, distortion=0.0, speed=0.8, seed=seed))
    rng = np.random.default_rng(seed)
    walking = sim.poses3d[:, 0]                                                  # (S, 17, 3)
    still = np.broadcast_to(sim.poses3d[0, 1], walking.shape)
    P = sim.calibration.cameras.P
    rows = []
    for v in range(4):
        for who, X in (("walking", walking), ("still", still)):
            if who == "walking" and v == 3:
                continue
            h = np.einsum("ij,skj->ski", P[v], np.concatenate([X, np.ones(X.shape[:-1] + (1,))], -1))
            xy = h[..., :2] / h[..., 2:] + rng.normal(0, 1.0, h[..., :2].shape)
            rows.append((np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], -1), np.full(len(X), v),
                         np.arange(len(X)), np.full(len(X), 0 if who == "walking" else 1)))
    kp, camera, frame, person = (np.concatenate(r) for r in zip(*rows))
    sim = dataclasses.replace(sim, keypoints=kp, camera=camera, frame=frame, person=person, score=np.ones(len(kp)),
                              offsets=np.zeros(4, int))
    return sim


def test_camera_sharing_only_a_person_standing_still_refused(tmp_path):
    sim = _static_bystander_rig()
    with pytest.raises(calibrate.CalibrationError) as e:
        calibrate_from_people(sim.keypoints, sim.camera, sim.frame, sim.calibration.cameras)
    assert e.value.camera == 3 and "standing still" in e.value.problem
    root = tmp_path / "still"
    write_rig_simulation(root, sim, intrinsics_only=True)
    out = tmp_path / "c.toml"
    _one_line_exit_2(_invoke(rig, ["calibrate", root, "--from-people", "-o", out]), "cam_04", "standing still")
    assert not out.exists()


def test_people_standing_still_counted_once():
    """A pairing that repeats an earlier instant's is not distinct: the person standing still counts
    once, the walking one whenever they moved 2 % of their height from every pose kept."""
    from mvm.rig.people_pairs import distinct_pairings

    sim = _static_bystander_rig()
    a, b = (sim.camera == 0), (sim.camera == 1)
    ka, kb = sim.keypoints[a][:, :, :2], sim.keypoints[b][:, :, :2]               # same order: who, then instant
    who, instant = sim.person[a], sim.frame[a]
    keep = distinct_pairings(ka, kb, np.full(len(ka), 300.0), np.ones(ka.shape[:2], bool), instant)
    assert keep[who == 1].sum() == 1                                              # the first instant only
    assert keep[who == 0].sum() >= 10                                            # one every few frames
