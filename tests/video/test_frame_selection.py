"""Frames kept by the camera's motion: a video whose image motion is known (a texture panned
slowly, stopped, then panned fast) -> the kept frames follow the rule; every frame on request;
the rule and its settings in frames.json, the settings in `mvm config` and in the rerun record."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from mvm.sim.mannequin_video import noise_texture
from mvm.video.camera_motion import FeatureTracks, select_by_motion
from mvm.video.frames import FrameOptions, extract_frames, read_frame_index

W, H, FPS = 320, 180, 30.0
DIAGONAL = float(np.hypot(W, H))
#: Pixels per frame: slow (60 frames), stopped (90 frames, 3 s), fast (40 frames).
STEPS = np.array([1.0] * 60 + [0.0] * 90 + [8.0] * 40)
SLOW, STOP = range(61), range(61, 151)
THRESHOLD_PX = 10.5
#: In the stop, where the gap rule would keep a frame (1 s after frame 55, the last slow one kept).
BLURRED = 85


def _write(path, shifts, blurred=(), fps=FPS):
    rng = np.random.default_rng(0)
    grain = rng.normal(0, 25, (1024, 1024, 1))                        # fine detail: blur shows
    texture = np.clip(noise_texture(rng, 1024) + grain, 0, 255).astype(np.uint8)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (W, H))
    for k, x in enumerate(shifts):
        image = cv2.warpAffine(texture, np.float32([[1, 0, -x], [0, 1, -200]]), (W, H), flags=cv2.INTER_LINEAR)
        writer.write(cv2.GaussianBlur(image, (0, 0), 5) if k in blurred else image)
    writer.release()
    return path


@pytest.fixture(scope="module")
def pan(tmp_path_factory):
    """The pan of :data:`STEPS`; frame :data:`BLURRED` is blurred. -> (path, x position of every
    frame (px))."""
    shifts = np.concatenate([[0.0], np.cumsum(STEPS)])
    return _write(tmp_path_factory.mktemp("pan") / "pan.mp4", shifts, blurred={BLURRED}), shifts


def test_kept_frames_follow_the_motion_the_gap_and_the_blur(pan, tmp_path):
    video, x = pan
    options = FrameOptions(min_motion=THRESHOLD_PX / DIAGONAL, max_gap_s=1.0, min_frames=2)
    index = extract_frames(video, tmp_path / "scene", options)
    kept = index.numbers.tolist()
    assert kept[0] == 0 and index.reasons[0] == "first"
    assert BLURRED not in kept and BLURRED in index.skipped                     # blurred: never kept
    for (a, b), reason in zip(zip(kept[:-1], kept[1:]), index.reasons[1:]):
        moved = abs(x[b] - x[a])
        if reason == "motion":                     # the first frame that moved enough since the last kept one
            assert moved >= THRESHOLD_PX - 0.5 and abs(x[b - 1] - x[a]) < THRESHOLD_PX + 0.5, (a, b)
        else:                                      # a still camera: one per max_gap_s (the next sharp one)
            assert reason == "max gap" and moved < THRESHOLD_PX + 0.5, (a, b, reason)
            assert b - a == 30 or (a < BLURRED < b and b - a == 31), (a, b)
    in_stop = [k for k in kept if k in STOP]
    assert len(in_stop) == 3                       # 3 s stopped: one a second, none in between
    slow = [k for k in kept if k in SLOW]
    assert np.diff(slow).tolist() == [11] * (len(slow) - 1) and len(slow) == 6
    fast = [k for k in kept if k > 151]
    assert set(np.diff(fast).tolist()) == {2}      # 16 px a kept frame: every other frame
    assert np.isnan(index.motion[0]) and np.allclose(index.motion[1:] * DIAGONAL,
                                                     np.abs(np.diff(x[kept])), atol=0.3)
    # frames.json holds the rule, its settings and why each frame was kept; it reads back
    document = json.loads((tmp_path / "scene" / "frames.json").read_text())
    assert document["selection"] == {"rule": "motion", "candidates": 191, "blurred": 1, "kept": len(kept),
                                     "min_motion": options.min_motion, "max_gap_s": 1.0, "min_frames": 2,
                                     "motion_width": 320}
    assert [f["kept_for"] for f in document["frames"]] == list(index.reasons)
    back = read_frame_index(tmp_path / "scene")
    assert back.selection == document["selection"] and back.reasons == index.reasons
    assert sorted(p.name for p in (tmp_path / "scene" / "frames").iterdir()) == list(index.names)
    # a frame written in the second pass is the frame measured in the first
    assert np.allclose(back.sharpness, [_sharpness(tmp_path / "scene" / "frames" / n) for n in back.names], rtol=0.02)


def _sharpness(path):
    return cv2.Laplacian(cv2.imread(str(path), cv2.IMREAD_GRAYSCALE), cv2.CV_64F).var()


def test_every_frame_and_a_rate_keep_all(pan, tmp_path):
    video, _ = pan
    every = extract_frames(video, tmp_path / "a", FrameOptions(select="all"))
    assert every.numbers.tolist() == [k for k in range(191) if k != BLURRED]
    assert every.selection == {"rule": "all", "candidates": 191, "blurred": 1, "kept": 190} and every.reasons == ()
    at_rate = extract_frames(video, tmp_path / "b", FrameOptions(rate=10.0))      # "auto" with a rate: all
    assert at_rate.numbers.tolist() == [k for k in range(0, 191, 3) if k != BLURRED]
    assert FrameOptions().rule == "motion" and FrameOptions(max_frames=9).rule == "all"
    assert FrameOptions(rate=10.0, select="motion").rule == "motion"


def test_a_still_camera_keeps_min_frames_spread_over_the_video(tmp_path):
    video = _write(tmp_path / "still.mp4", np.zeros(90))                           # 3 s, nothing moves
    index = extract_frames(video, tmp_path / "scene", FrameOptions(min_frames=12, max_gap_s=1.0))
    assert len(index.numbers) == 12
    assert index.reasons.count("max gap") == 2 and index.reasons.count("min frames") == 9
    assert np.diff(np.concatenate([index.numbers, [90]])).max() <= 12    # no long stretch left out
    assert np.nanmax(index.motion) < 0.002


def test_select_by_motion_on_known_tracks():
    """Tracks built by hand: 5 points moving 1 % of the diagonal a frame, all of them lost at
    frame 6 (a cut), then still."""
    tracks = FeatureTracks(diagonal=100.0)
    base = np.array([[10, 10], [20, 30], [40, 50], [60, 20], [80, 70]], dtype=np.float32)
    for f in range(12):
        ids = np.arange(5, dtype=np.int32) + (100 if f >= 6 else 0)
        tracks.ids.append(ids)
        tracks.points.append(base + [min(f, 6), 0])
    times = np.arange(12) / 10.0
    chosen = select_by_motion(tracks, np.ones(12, bool), times, 0.03, 0.45, 1)
    assert chosen.kept.tolist() == [0, 3, 6, 11] and chosen.reasons == ("first", "motion", "tracks lost", "max gap")
    assert np.allclose(chosen.motion[1], 0.03)
    usable = np.ones(12, bool)
    usable[3] = False
    assert select_by_motion(tracks, usable, times, 0.03, 10, 1).kept.tolist() == [0, 4, 6]


def test_settings_round_trip_through_config_and_the_rerun_record(tmp_path):
    from mvm.cli.video import frames_cmd
    from mvm.settings.reference import reference_toml
    from mvm.settings.tables import load_settings

    printed = reference_toml(("frames",))                                # what `mvm config` prints
    for key, value in (("select", '"auto"'), ("min_motion", "0.03"), ("max_gap_s", "1.0"), ("min_frames", "24")):
        assert f"\n{key} = {value}\n" in printed, key
    (tmp_path / "printed.toml").write_text(printed)
    assert load_settings(FrameOptions, "frames", str(tmp_path / "printed.toml"), {}, {}) == FrameOptions()
    video = _write(tmp_path / "short.mp4", np.concatenate([[0.0], np.cumsum(STEPS[40:100])]))     # slow, stopped
    settings = tmp_path / "mvm.toml"
    settings.write_text('[frames]\nselect = "motion"\nmin_motion = 0.05\nmax_gap_s = 2.5\nmin_frames = 3\n')
    scene = tmp_path / "scene"
    result = CliRunner().invoke(frames_cmd, [str(video), "-o", str(scene), "--config", str(settings)])
    assert result.exit_code == 0, result.output
    selection = read_frame_index(scene).selection
    assert (selection["min_motion"], selection["max_gap_s"], selection["min_frames"]) == (0.05, 2.5, 3)
    record = json.loads((scene / "frames.inputs.json").read_text())
    assert record["settings"]["min_motion"] == 0.05 and record["settings"]["select"] == "motion"
    # the same settings: kept; another one: made again, saying which
    again = CliRunner().invoke(frames_cmd, [str(video), "-o", str(scene), "--config", str(settings)])
    assert "frames: kept (up to date)" in again.output
    changed = CliRunner().invoke(frames_cmd, [str(video), "-o", str(scene), "--config", str(settings),
                                              "--min-motion", "0.08"])
    assert "setting min_motion changed since the frame extraction (0.05 -> 0.08)" in " ".join(changed.output.split())
    every = CliRunner().invoke(frames_cmd, [str(video), "-o", str(scene), "--config", str(settings),
                                            "--every-frame"])
    assert "frames: made: setting" in every.output
    assert json.loads((scene / "frames.inputs.json").read_text())["settings"]["select"] == "all"
    assert len(read_frame_index(scene).names) == 61
    # the motion rule's settings do not shape every frame: changing one keeps them
    same = CliRunner().invoke(frames_cmd, [str(video), "-o", str(scene), "--every-frame", "--max-gap", "9"])
    assert "frames: kept (up to date)" in same.output
    bad = CliRunner().invoke(frames_cmd, [str(video), "-o", str(scene), "--min-motion", "0"])
    assert bad.exit_code == 2 and "--min-motion" in bad.output


@pytest.mark.slow                                   # rendering the tour: about 15 s on a loaded machine
def test_a_selected_video_reconstructs_and_its_supervision_covers_every_kept_frame(tmp_path):
    """A rendered tour with its true cameras and true 2D poses: the frames kept by motion are the
    scene's views, the people are reconstructed from them, and the exported supervision has an
    image, with every person, for each kept frame."""
    from mvm.core.camera import project_camera
    from mvm.io.colmap import write_colmap
    from mvm.io.scene_dir import read_poses3d, read_scene
    from mvm.net.supervision import export_supervision
    from mvm.sim.mannequin_video import RenderConfig, render_video
    from mvm.stages.run import run_video
    from mvm.video.sfm import SfmOptions

    from helpers import coco_results

    truth = render_video(tmp_path / "tour.mp4", RenderConfig(frames=30, width=192, height=108, focal_px=170.0,
                                                             arc_deg=90, seed=2))
    write_colmap(tmp_path / "model", truth.cameras)
    (tmp_path / "detections.json").write_text(json.dumps(coco_results(truth, np.random.default_rng(0))))
    scene = tmp_path / "scene"
    report = run_video(tmp_path / "tour.mp4", scene, detections=tmp_path / "detections.json",
                       cameras=tmp_path / "model", frame_options=FrameOptions(min_motion=0.08, min_frames=4),
                       sfm_options=SfmOptions(camera_model="SIMPLE_PINHOLE"), metric_scale=False)
    kept = list(report.frames.names)
    assert report.frames.selection["rule"] == "motion" and 4 <= len(kept) < 15
    views = read_scene(scene)
    persons = read_poses3d(scene / "mvm" / "poses3d.json", views.poses)
    seen = sorted({views.cameras.names[v] for v in views.poses.view})
    assert seen == kept                                                   # 2D poses of the kept frames only
    assert len(persons) == len(truth.poses3d)
    error = np.nanmin(np.linalg.norm(persons.keypoints3d[:, None] - truth.poses3d[None], axis=-1).mean(-1), 0)
    assert error.max() < 0.05                                             # metres, in the true cameras' world
    export_supervision([(views, read_poses3d(scene / "mvm" / "poses3d.json"), scene / "frames")],
                       tmp_path / "supervision", link="copy")                         # as `mvm batch` exports
    data = json.loads((tmp_path / "supervision" / "annotations.json").read_text())
    images = {i["id"]: i["file_name"] for i in data["images"]}
    assert sorted(name.rsplit("/", 1)[-1] for name in images.values()) == kept
    per_image = np.bincount([a["image_id"] for a in data["annotations"] if a["num_keypoints"]],
                            minlength=max(images) + 1)
    for i, name in images.items():                    # every person with 3 joints or more in the frame
        v = truth.cameras.names.index(name.rsplit("/", 1)[-1])
        uv, _ = project_camera(truth.poses3d, truth.cameras.K[v], truth.cameras.R[v], truth.cameras.t[v])
        inside = ((uv >= 0) & (uv < [192, 108])).all(-1).sum(-1) >= 3
        assert per_image[i] == inside.sum() > 0, name


def test_batch_and_run_take_the_selection_options(tmp_path):
    from mvm.cli.batch import read_batch_options
    from mvm.cli.video import _frame_options

    assert read_batch_options(None, ()).frames.rule == "motion"
    assert read_batch_options(None, (), every_frame=True).frames.select == "all"
    settings = tmp_path / "mvm.toml"
    settings.write_text('[frames]\nmin_motion = 0.07\nmin_frames = 5\n')
    assert read_batch_options(str(settings), ()).frames.min_motion == 0.07
    options = _frame_options(str(settings), None, None, None, None, None, None, 2.0)
    assert (options.min_motion, options.min_frames, options.max_gap_s, options.rule) == (0.07, 5, 2.0, "motion")
