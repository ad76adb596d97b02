"""Overlays: every frame's 2D poses in their person's colour, reprojected 3D poses over them."""
from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

cv2 = pytest.importorskip("cv2")

from test_report import make_scene  # noqa: E402

from mvm.io.scene_dir import read_poses3d, read_scene  # noqa: E402
from mvm.report import write_overlays  # noqa: E402
from mvm.report.analysis import UNMATCHED_RGB, person_colors, pose_labels  # noqa: E402
from mvm.report.overlay import NEUTRAL_BGR, draw_overlay  # noqa: E402

from helpers import run_at_once  # noqa: E402


def _bgr(rgb):
    return np.array([rgb[2], rgb[1], rgb[0]], dtype=int)


def _pose(offset_x: float) -> np.ndarray:
    """A stick figure ``(17, 3)`` (x, y, v) with its left shin vertical at x = offset_x."""
    kp = np.zeros((17, 3))
    kp[:, 0] = offset_x + np.linspace(-20, 20, 17)
    kp[:, 1] = np.linspace(20, 180, 17)
    kp[:, 2] = 1.0
    kp[13] = [offset_x, 120, 1]   # left knee
    kp[15] = [offset_x, 170, 1]   # left ankle
    return kp


def test_draw_overlay_colours_poses_by_person():
    image = np.full((200, 300, 3), NEUTRAL_BGR, dtype=np.uint8)
    colors = person_colors(2)
    keypoints = np.stack([_pose(60), _pose(150), _pose(240)])
    keypoints[2, 5:, 2] = 0                                         # only the face of the grey pose
    keypoints[2, 15] = [240, 170, 1]
    keypoints[2, 13] = [240, 120, 1]
    out = draw_overlay(image, keypoints, np.array([1, -1, 0]), colors)
    assert out.shape == image.shape and (image == NEUTRAL_BGR).all()   # the input is untouched
    shin = lambda x: out[140:150, x].astype(int)  # noqa: E731 - pixels on the left shin
    assert (np.abs(shin(60) - _bgr(colors[1])).sum(-1) < 30).any()
    assert (np.abs(shin(150) - _bgr(UNMATCHED_RGB)).sum(-1) < 30).any()
    assert (np.abs(shin(240) - _bgr(colors[0])).sum(-1) < 30).any()
    assert (np.abs(out[140:150, 100].astype(int) - NEUTRAL_BGR).sum(-1) == 0).all()
    # reprojected 3D poses: thin lines in a lighter tint of the person's colour
    reprojected = np.stack([_pose(100)[:, :2], _pose(200)[:, :2]])
    thin = draw_overlay(image, keypoints[:0], np.zeros(0, int), colors, reprojected,
                        np.ones((2, 17), bool))
    lighter = np.round(0.45 * colors[1] + 0.55 * 255)
    assert (np.abs(thin[140:150, 198:203].astype(int) - _bgr(lighter)).sum(-1) < 60).any()  # anti-aliased
    with pytest.raises(ValueError, match="labels"):
        draw_overlay(image, keypoints, np.array([0]), colors)


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    path = tmp_path_factory.mktemp("overlay") / "scene"
    make_scene(path, people=3, frames=12, seed=7)
    return path


def test_overlay_folder_draws_matched_poses_in_their_colour(scene_dir, tmp_path):
    summary = write_overlays(scene_dir, tmp_path / "ov", step=3, image_format=".png")
    scene = read_scene(scene_dir)
    persons = read_poses3d(scene_dir / "mvm" / "poses3d.json", scene.poses)
    files = sorted((tmp_path / "ov").glob("*.png"))
    assert summary.frames == 4 and len(files) == 4 and not summary.on_frames
    assert [f.stem for f in files] == [scene.cameras.names[v].rsplit(".", 1)[0] for v in (0, 3, 6, 9)]
    labels = pose_labels(len(scene.poses), persons.members)
    colors = person_colors(len(persons))
    image = cv2.imread(str(files[1]))
    assert image.shape == (720, 1280, 3)
    hits = 0
    for n in np.flatnonzero((scene.poses.view == 3) & (labels >= 0)):
        for x, y, v in scene.poses.keypoints[n]:
            if v > 0:
                patch = image[int(y) - 2:int(y) + 3, int(x) - 2:int(x) + 3].reshape(-1, 3).astype(int)
                hits += (np.abs(patch - _bgr(colors[labels[n]])).sum(-1) < 40).any()
    assert hits > 0.7 * ((scene.poses.view == 3)[:, None] & (scene.poses.keypoints[:, :, 2] > 0)
                         & (labels >= 0)[:, None]).sum()


def test_overlay_video(scene_dir, tmp_path):
    path = tmp_path / "video.mp4"
    summary = write_overlays(scene_dir, path, step=2, max_width=320, fps=5)
    assert summary.frames == 6 and path.is_file()
    assert not list(tmp_path.glob(".video*"))                     # no temporary left behind
    video = cv2.VideoCapture(str(path))
    count = 0
    while True:
        ok, frame = video.read()
        if not ok:
            break
        count += 1
        assert frame.shape == (180, 320, 3)
    assert count == 6


def test_overlay_uses_the_frames_when_present(scene_dir, tmp_path):
    import shutil

    copy = tmp_path / "withframes"
    shutil.copytree(scene_dir, copy)
    scene = read_scene(copy)
    (copy / "frames").mkdir()
    fill = (200, 80, 20)
    for name in scene.cameras.names[:2]:
        cv2.imwrite(str(copy / "frames" / name), np.full((720, 1280, 3), fill, np.uint8))
    summary = write_overlays(copy, tmp_path / "ov", step=1, image_format=".png")
    assert summary.on_frames
    first = cv2.imread(str(tmp_path / "ov" / "frame_00000.png"))
    assert np.abs(first[5, 5].astype(int) - fill).sum() < 10                       # the frame
    last = cv2.imread(str(tmp_path / "ov" / "frame_00011.png"))                    # no image: neutral
    assert (last[5, 5] == NEUTRAL_BGR).all()


def test_overlay_command(scene_dir, tmp_path):
    from mvm.cli.report import overlay_cmd

    result = CliRunner().invoke(overlay_cmd, [str(scene_dir), "-o", str(tmp_path / "o"), "--every", "6"])
    assert result.exit_code == 0, result.output
    assert "2 frames drawn on a neutral background" in result.output
    assert len(list((tmp_path / "o").glob("*.jpg"))) == 2
    bad = CliRunner().invoke(overlay_cmd, [str(tmp_path / "nothing")])
    assert bad.exit_code == 2 and "mvm: error:" in bad.output


def test_an_empty_or_undecodable_frame_is_drawn_on_neutral_with_a_warning(scene_dir, tmp_path, caplog):
    import logging
    import shutil

    copy = tmp_path / "badframes"
    shutil.copytree(scene_dir, copy)
    names = read_scene(copy).cameras.names
    (copy / "frames").mkdir()
    (copy / "frames" / names[0]).write_bytes(b"")
    (copy / "frames" / names[1]).write_bytes(b"\xff\xd8\xff\xe0 not a jpeg")
    with caplog.at_level(logging.WARNING):
        summary = write_overlays(copy, tmp_path / "ov", step=1, image_format=".png")
    assert summary.frames == len(names)
    assert names[0] in caplog.text and names[1] in caplog.text
    first = cv2.imread(str(tmp_path / "ov" / "frame_00000.png"))
    assert (first[5, 5] == NEUTRAL_BGR).all()


def test_overlay_never_replaces_the_frames_nor_a_users_folder(scene_dir, tmp_path):
    import shutil

    from mvm.cli.report import overlay_cmd

    scene = shutil.copytree(scene_dir, tmp_path / "scene")
    (scene / "frames").mkdir()
    for name in read_scene(scene).cameras.names:
        cv2.imwrite(str(scene / "frames" / name), np.full((72, 128, 3), 90, np.uint8))
    photos = tmp_path / "photos"
    photos.mkdir()
    for i in range(5):
        cv2.imwrite(str(photos / f"IMG_{i:04d}.jpg"), np.full((8, 8, 3), i, np.uint8))
    frames_before = sorted(p.name for p in (scene / "frames").iterdir())
    photos_before = {p.name: p.read_bytes() for p in photos.iterdir()}
    for out, problem in ((scene / "frames", "is an input of this run"), (scene, "contains the input"),
                         (scene / "mvm", "contains the input"), (scene / "frames" / "ov", "lies inside the input"),
                         (photos, "mvm did not make")):
        result = CliRunner().invoke(overlay_cmd, [str(scene), "-o", str(out), "--every", "10"])
        lines = result.output.strip().splitlines()
        assert result.exit_code == 2 and len(lines) == 1 and lines[0].startswith(f"mvm: error: {out}: "), lines
        assert problem in lines[0]
    assert sorted(p.name for p in (scene / "frames").iterdir()) == frames_before      # 12 frames, not 2
    assert {p.name: p.read_bytes() for p in photos.iterdir()} == photos_before
    # a user's folder beside the overlay folder is not a leftover
    (scene / "mvm" / ".overlay.old").mkdir()
    (scene / "mvm" / ".overlay.old" / "keep.jpg").write_bytes(b"mine")
    for _ in range(2):
        result = CliRunner().invoke(overlay_cmd, [str(scene), "--every", "6"])
        assert result.exit_code == 0, result.output
    assert (scene / "mvm" / ".overlay.old" / "keep.jpg").read_bytes() == b"mine"
    assert len(list((scene / "mvm" / "overlay").glob("*.jpg"))) == 2


def test_concurrent_overlays_leave_one_complete_folder(scene_dir, tmp_path):

    out = tmp_path / "ov"
    assert 0 in run_at_once(["overlay", scene_dir, "-o", out, "--max-width", "64"])
    assert len(list(out.glob("*.jpg"))) == 12
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ov"]             # the folder, its record inside
    assert (out / "overlay.inputs.json").is_file()
