"""End to end: a rendered video of a textured room with people -> `mvm run` -> 3D poses,
checked against the rendering's ground truth after a similarity alignment (SfM is up to one)."""
from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from mvm.io.colmap import read_colmap
from mvm.metrics.poses import similarity_transform
from mvm.sim.mannequin_video import RenderConfig, render_video

from helpers import coco_results

FRAMES = 40

pytestmark = pytest.mark.slow                          # SfM of the rendered clip: about 30 s


@pytest.fixture(scope="module")
def run_result(tmp_path_factory):
    from mvm.cli.video import run_cmd

    root = tmp_path_factory.mktemp("video")
    config = RenderConfig(frames=FRAMES, width=480, height=270, focal_px=400.0, seed=3)
    truth = render_video(root / "tour.mp4", config)
    detections = root / "detections.json"
    detections.write_text(json.dumps(coco_results(truth, np.random.default_rng(0))))
    scene = root / "scene"
    result = CliRunner().invoke(run_cmd, [str(root / "tour.mp4"), "-o", str(scene), "--import", str(detections),
                                          "--camera-model", "SIMPLE_PINHOLE", "--blur-ratio", "0",
                                          "--max-features", "2048", "--every-frame"])
    assert result.exit_code == 0, result.output
    return truth, scene, result


def test_all_frames_registered_and_focal(run_result):
    """Every frame is kept (``--every-frame``: SfM's accuracy on all 40 views is what the next
    test bounds; the selection by motion has its own tests) and registered."""
    truth, scene, _ = run_result
    report = json.loads((scene / "sfm" / "report.json").read_text())
    kept = [f["file_name"] for f in json.loads((scene / "frames.json").read_text())["frames"]]
    assert report["unregistered"] == []
    assert sorted(report["registered"]) == kept and len(kept) == FRAMES
    assert abs(report["focal_px"] / 400.0 - 1) < 0.02


def test_camera_centres_and_poses_match_truth(run_result, capsys):
    truth, scene, _ = run_result
    model = read_colmap(scene / "sparse")
    index = [truth.cameras.names.index(n) for n in model.cameras.names]
    true_centres = truth.cameras.centers[index]
    s, R, t = similarity_transform(model.cameras.centers, true_centres)
    aligned = s * model.cameras.centers @ R.T + t
    path_length = np.linalg.norm(np.diff(truth.cameras.centers, axis=0), axis=1).sum()
    assert np.linalg.norm(aligned - true_centres, axis=1).max() < 0.02 * path_length

    document = json.loads((scene / "mvm" / "poses3d.json").read_text())
    assert len(document["persons"]) == len(truth.poses3d)
    estimates = np.array([[[np.nan if v is None else v for v in kp[:3]] for kp in p["keypoints3d"]]
                          for p in document["persons"]])
    estimates = s * estimates @ R.T + t
    errors = []
    for g in range(len(truth.poses3d)):
        per_person = np.nanmean(np.linalg.norm(estimates - truth.poses3d[g], axis=-1), axis=1)
        errors.append(np.linalg.norm(estimates[np.nanargmin(per_person)] - truth.poses3d[g], axis=-1))
    errors = np.array(errors)
    # metres; the alignment comes from the cameras only, so a 0.5° rotation error of the
    # SfM world already shifts the people (4 m away) by 3 cm
    assert np.nanmean(errors) < 0.05
    assert np.nanmax(errors) < 0.12

    with capsys.disabled():
        print(f"\ncentre error max {np.linalg.norm(aligned - true_centres, axis=1).max() / path_length:.2%} of path; "
              f"joint error mean {np.nanmean(errors) * 100:.1f} cm, max {np.nanmax(errors) * 100:.1f} cm; "
              f"alignment scale after metric scaling {s:.3f}")
    # the people-based metric scale puts the model in metres (the figures' bones are adult-sized)
    assert document["scale"]["source"] == "people"
    assert document["scale"]["applied_to_model"] is True
    assert abs(s - 1) < 0.12


def test_rerun_skips_done_stages(run_result, tmp_path):
    from mvm.stages.run import run_video
    from mvm.video.frames import FrameOptions
    from mvm.video.sfm import SfmOptions

    truth, scene, _ = run_result
    before = (scene / "mvm" / "poses3d.json").stat().st_mtime_ns
    report = run_video(scene.parent / "tour.mp4", scene, detections=scene.parent / "detections.json",
                       frame_options=FrameOptions(blur_ratio=0, select="all"),
                       sfm_options=SfmOptions(camera_model="SIMPLE_PINHOLE", max_features=2048))
    assert report.seconds["sfm"] < 2 and report.seconds["frames"] < 2
    assert report.why == {"frames": None, "sfm": None, "detect": None, "reconstruct": None}
    assert report.reconstruction.persons == len(truth.poses3d)          # read back from the kept file
    assert (scene / "mvm" / "poses3d.json").stat().st_mtime_ns == before
