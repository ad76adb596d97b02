"""``mvm rig calibrate --checkerboard / --charuco --intrinsics-only``: each camera's intrinsics
alone from photos or videos of a board (Pose2Sim's and anipose's layouts) drawn through cameras
the tests choose, the Calib.toml of intrinsics only it writes, the lab's photos of the real
footage against the lab's calibration, and the bad input (one line, exit 2, nothing written)."""
import re

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from board_scenes import (
    CHARUCO,
    CHECKERBOARD,
    SIZE,
    frontal_board_poses,
    lens_grid,
    render,
    ring_cameras,
    write_board_video,
)
from mvm.cli.rig import rig
from mvm.errors import InputError
from mvm.io.calib_toml import read_calib_toml
from mvm.rig.boards import Board
from mvm.rig.rigdir import read_calibration

from helpers import SHARED_DATA

REAL = SHARED_DATA / "real_footage" / "calibration"


def _calibrate(root, board, out, *extra):
    args = ["calibrate", root, "--" + board.kind, "--intrinsics-only", "--board-size", f"{board.cols}x{board.rows}",
            "--square-size", board.square_m, "-o", out, *extra]
    if board.kind == "charuco":
        args += ["--marker-size", board.marker_m]
    return CliRunner().invoke(rig, [str(a) for a in args])


def _one_line_exit_2(result, *words):
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1, result.output
    for word in words:
        assert word in lines[0], lines[0]


def write_photos(folder, board, camera, n, seed=0, blank=(), suffix=".png"):
    """``n`` photos of ``board`` held in front of ``camera`` in ``folder`` (``blank``: photos
    drawn without the board)."""
    texture, A = board.texture(24)
    grid = lens_grid(camera)
    R, t = frontal_board_poses(n, board, camera, seed=seed)
    folder.mkdir(parents=True, exist_ok=True)
    for k in range(n):
        image = render(board, texture, A, camera, grid, R[k], t[k])
        if k in blank:
            image[:] = 110
        cv2.imwrite(str(folder / f"photo_{k + 1:02d}{suffix}"), image)


def _assert_lens(found, v, camera, focal=0.005, centre_px=4.0):
    K = found.cameras.K[v]
    assert abs(K[0, 0] / camera.K[0, 0] - 1) < focal and abs(K[1, 1] / camera.K[1, 1] - 1) < focal
    assert np.abs(K[:2, 2] - camera.K[:2, 2]).max() < centre_px
    assert abs(found.distortions[v][0] - camera.distortion[0]) < 0.03


@pytest.fixture(scope="module")
def photo_rig(tmp_path_factory):
    """Pose2Sim's layout: calibration/intrinsics/int_camNN_img/ with 12 photos each, the board
    missing from two of cam02's; scene pictures without a board in extrinsics/."""
    root = tmp_path_factory.mktemp("photos") / "rig"
    cams = ring_cameras(2, seed=3)
    (root / "calibration" / "extrinsics").mkdir(parents=True)
    for v, cam in enumerate(cams):
        write_photos(root / "calibration" / "intrinsics" / f"int_cam0{v + 1}_img", CHECKERBOARD, cam, 12, seed=v,
                     blank=(4, 9) if v == 1 else ())
        cv2.imwrite(str(root / "calibration" / "extrinsics" / f"cam0{v + 1}_ext.png"),
                    np.full((SIZE[1], SIZE[0], 3), 90, np.uint8))
    return root, cams


def test_intrinsics_from_photos(photo_rig, tmp_path):
    """Pose2Sim's image folders: each focal length within 0.5 % of the true one, the cameras
    named without Pose2Sim's wrapping, the photos with the board counted, no rotation written,
    and the file read as intrinsics the way --from-people --intrinsics reads it."""
    root, cams = photo_rig
    out = tmp_path / "lenses.toml"
    result = _calibrate(root, CHECKERBOARD, out)
    assert result.exit_code == 0, result.output
    rows = {line.split("\t")[0]: line.split("\t") for line in result.output.splitlines() if "\t" in line}
    assert rows["cam01"][1:3] == ["int_cam01_img", "12 of 12 images"]
    assert rows["cam02"][1:3] == ["int_cam02_img", "10 of 12 images"]
    assert f"wrote {out}" in result.output
    found = read_calibration(out, extrinsics=False)
    assert found.cameras.names == ("cam01", "cam02")
    assert np.isnan(found.cameras.R).all() and np.isnan(found.cameras.t).all()
    assert found.cameras.size.tolist() == [list(SIZE)] * 2
    for v, cam in enumerate(cams):
        _assert_lens(found, v, cam)
    assert found.metadata["board_found"] == [12, 10] and found.metadata["board_searched"] == [12, 12]
    assert max(found.metadata["intrinsics_rms_px"]) < 0.3
    assert "rotation" not in out.read_text()
    with pytest.raises(InputError, match=r"\[cam01\]\.rotation: missing"):
        read_calib_toml(out)                                      # not a full calibration


def test_intrinsics_from_videos_pose2sim_and_anipose(tmp_path):
    """A ChArUco board filmed: Pose2Sim's int_<cam>_vid/ folders holding one video each, then
    anipose's calibration/calib-<cam>.mp4; one camera is enough."""
    cams = ring_cameras(2, seed=5)
    pose2sim, anipose = tmp_path / "pose2sim", tmp_path / "anipose"
    for v, cam in enumerate(cams):
        R, t = frontal_board_poses(14, CHARUCO, cam, seed=10 + v)
        write_board_video(pose2sim / "calibration" / "intrinsics" / f"int_cam{v + 1}_vid" / f"take{v + 1}.mp4",
                          CHARUCO, cam, R, t)
        if v == 0:
            write_board_video(anipose / "calibration" / "calib-camA.mp4", CHARUCO, cam, R, t)
    out = tmp_path / "pose2sim.toml"
    result = _calibrate(pose2sim, CHARUCO, out)
    assert result.exit_code == 0, result.output
    assert "take1.mp4" in result.output and "14 of 14 frames" in result.output
    found = read_calib_toml(out, extrinsics=False)
    assert found.cameras.names == ("cam1", "cam2")
    for v, cam in enumerate(cams):
        _assert_lens(found, v, cam)
    out = tmp_path / "anipose.toml"
    result = _calibrate(anipose, CHARUCO, out, "--fisheye")
    assert result.exit_code == 0, result.output
    found = read_calib_toml(out, extrinsics=False)
    assert found.cameras.names == ("calib-camA",) and found.fisheye.all()        # one camera: its whole name
    assert abs(found.cameras.K[0, 0, 0] / cams[0].K[0, 0] - 1) < 0.01


def test_real_photos_against_the_lab(tmp_path):
    """The real footage's photos (Pose2Sim's layout, 7 per camera, portrait 1088x1920): every
    focal length within 1.5 % of the lab's marker-based calibration, the board found in at least
    5 photos of each camera, and the recap says in how many."""
    if not (REAL / "intrinsics" / "int_cam01_img").is_dir():
        pytest.skip(f"real footage absent: {REAL}")
    rig_dir = tmp_path / "rig"
    rig_dir.mkdir()
    (rig_dir / "calibration").symlink_to(REAL)
    out = tmp_path / "lenses.toml"
    result = _calibrate(rig_dir, Board("checkerboard", 4, 7, 0.06), out)
    assert result.exit_code == 0, result.output
    lab = read_calib_toml(REAL / "Calib_converted_by_pose2sim.toml")
    found = read_calib_toml(out, extrinsics=False)
    assert found.cameras.names == lab.cameras.names
    assert found.cameras.size.tolist() == lab.cameras.size.tolist() == [[1088.0, 1920.0]] * 4
    focal = found.cameras.K[:, [0, 1], [0, 1]] / lab.cameras.K[:, [0, 1], [0, 1]] - 1
    assert np.abs(focal).max() < 0.015, focal
    for v, name in enumerate(found.cameras.names):
        n = found.metadata["board_found"][v]
        assert n >= 5 and found.metadata["board_searched"][v] == 7
        assert re.search(rf"^{name}\tint_{name}_img\t{n} of 7 images\t", result.output, re.M), result.output
    assert max(found.metadata["intrinsics_rms_px"]) < 0.5


def test_photos_without_the_board_one_line(photo_rig, tmp_path):
    """A camera whose photos never show the board: its name and its folder."""
    _, cams = photo_rig
    root = tmp_path / "rig"
    write_photos(root / "calibration" / "intrinsics" / "int_cam01_img", CHECKERBOARD, cams[0], 6)
    write_photos(root / "calibration" / "intrinsics" / "int_cam02_img", CHECKERBOARD, cams[1], 6, blank=range(6))
    out = tmp_path / "c.toml"
    _one_line_exit_2(_calibrate(root, CHECKERBOARD, out), str(root / "calibration" / "intrinsics" / "int_cam02_img"),
                     "camera cam02", "no checkerboard", "in the 6 images searched")
    _one_line_exit_2(_calibrate(root, Board("checkerboard", 8, 5, 0.07), out), "camera cam01", "no checkerboard of "
                     "8x5", "--board-size counts inner corners")
    write_photos(root / "calibration" / "intrinsics" / "int_cam02_img", CHECKERBOARD, cams[1], 6, blank=range(2, 6))
    _one_line_exit_2(_calibrate(root, CHECKERBOARD, out), "camera cam02", "seen in 2 frame(s), at least 5",
                     "(6 images searched)")
    assert not out.exists()


def test_bad_photo_folders_one_line(photo_rig, tmp_path):
    """Photos of two sizes for one camera, a camera's folder with no image, an image OpenCV
    cannot decode, images beside a video: one line naming the file or folder."""
    _, cams = photo_rig
    root = tmp_path / "rig"
    folder = root / "calibration" / "intrinsics"
    write_photos(folder / "int_cam01_img", CHECKERBOARD, cams[0], 6)
    write_photos(folder / "int_cam02_img", CHECKERBOARD, cams[1], 6, suffix=".jpg")
    out = tmp_path / "c.toml"
    small = folder / "int_cam02_img" / "photo_04.jpg"
    cv2.imwrite(str(small), cv2.resize(cv2.imread(str(small)), (320, 240)))
    _one_line_exit_2(_calibrate(root, CHECKERBOARD, out), str(small), "320x240 pixels",
                     "photo_01.jpg has 640x480", "one camera, one image size")
    small.unlink()
    (folder / "int_cam03_img").mkdir()
    (folder / "int_cam03_img" / ".gitkeep").write_text("")
    _one_line_exit_2(_calibrate(root, CHECKERBOARD, out), str(folder / "int_cam03_img"), "no image", "or video")
    (folder / "int_cam03_img" / "a.png").write_bytes(b"not a png")
    _one_line_exit_2(_calibrate(root, CHECKERBOARD, out), str(folder / "int_cam03_img" / "a.png"),
                     "not an image OpenCV can decode")
    (folder / "int_cam03_img" / "b.mp4").write_bytes(b"")
    _one_line_exit_2(_calibrate(root, CHECKERBOARD, out), str(folder / "int_cam03_img"), "images and a video")
    (folder / "int_cam03_img" / "a.png").unlink()
    (folder / "int_cam03_img" / "c.mp4").write_bytes(b"")
    _one_line_exit_2(_calibrate(root, CHECKERBOARD, out), str(folder / "int_cam03_img"), "2 videos",
                     "one per camera")
    assert not out.exists()


def test_intrinsics_only_options_and_layout_one_line(photo_rig, tmp_path):
    """Options of the other modes, no calibration folder, -o inside the inputs: refused before any
    photo is read."""
    root, _ = photo_rig
    out = tmp_path / "c.toml"
    for extra, option in ((["--world", "camera"], "--world"), (["--world-frame", "3"], "--world-frame"),
                          (["--intrinsics", out], "--intrinsics")):
        _one_line_exit_2(_calibrate(root, CHECKERBOARD, out, *extra), option, "does not apply to --intrinsics-only")
    _one_line_exit_2(CliRunner().invoke(rig, ["calibrate", str(root), "--from-people", "--intrinsics-only", "-o",
                                              str(out)]), "--intrinsics-only", "not --from-people")
    _one_line_exit_2(_calibrate(tmp_path / "empty", CHECKERBOARD, out), "calibration", "no calibration videos or "
                     "photos", "int_<camera>_img")
    full = CliRunner().invoke(rig, ["calibrate", str(root), "--checkerboard", "--board-size", "7x6", "--square-size",
                                    "0.07", "-o", str(out)])             # extrinsics/: scene pictures, no board
    _one_line_exit_2(full, "cam01_ext.png", "camera cam01", "in the 1 image searched", "the intrinsics alone: "
                     "--intrinsics-only")
    inside = root / "calibration" / "Calib.toml"
    _one_line_exit_2(_calibrate(root, CHECKERBOARD, inside), str(inside), "inside the input")
    assert not out.exists() and not inside.exists()


def test_an_output_inside_a_linked_photo_folder_is_refused(photo_rig, tmp_path):
    """A camera's photo folder linked from elsewhere is an input too: ``-o`` naming a file in it
    (a photo) is refused in one line, the photo untouched (it was checked against
    ``calibration/`` only, whose link leads out)."""
    import shutil

    src, _ = photo_rig
    photos = tmp_path / "elsewhere" / "photos"
    shutil.copytree(src / "calibration" / "intrinsics" / "int_cam01_img", photos)
    root = tmp_path / "rig"
    (root / "calibration" / "intrinsics").mkdir(parents=True)
    (root / "calibration" / "intrinsics" / "int_cam01_img").symlink_to(photos)
    shutil.copytree(src / "calibration" / "intrinsics" / "int_cam02_img",
                    root / "calibration" / "intrinsics" / "int_cam02_img")
    victim = sorted(photos.iterdir())[0]
    before = victim.read_bytes()
    _one_line_exit_2(_calibrate(root, CHECKERBOARD, victim), str(victim))
    assert victim.read_bytes() == before
