"""Calibrating a rig with a board: the math on projected corners, then ``mvm rig calibrate
--checkerboard / --charuco`` on rendered videos of a rig whose intrinsics, lenses and poses are
known, and the bad input (one line naming the camera or file, exit 2, nothing written)."""
import os
import shutil
import struct
import zlib

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from board_scenes import (
    CHARUCO,
    CHECKERBOARD,
    FIRST_CORNER,
    SIZE,
    floor_board_poses,
    frontal_board_poses,
    lens_grid,
    render,
    ring_cameras,
    seen_corners,
    true_cameras,
    write_board_rig,
    write_board_video,
    write_still_board,
    write_true_calibration,
)
from mvm.cli.rig import rig
from mvm.errors import InputError
from mvm.io.calib_toml import RigCalibration, read_calib_toml
from mvm.rig.board_calibration import calibrate_extrinsics, calibrate_intrinsics, image_coverage, usable_views
from mvm.rig.board_videos import intrinsic_videos
from mvm.rig.boards import Board, spread_views, view_features
from mvm.rig.calibrate import CalibrationError


def _rotation_deg(A, B) -> float:
    return float(np.degrees(np.linalg.norm(cv2.Rodrigues(A @ B.T)[0])))


def _noisy(corners, rng, sigma=0.1):
    return corners + rng.normal(0, sigma, corners.shape)


def test_intrinsics_and_extrinsics_from_projected_corners():
    """The math alone: corners projected through known lenses, 0.1 px of noise."""
    rng = np.random.default_rng(1)
    cams = ring_cameras(3, seed=1)
    K, truth_px = [], []
    for v, cam in enumerate(cams):
        R, t = frontal_board_poses(20, CHECKERBOARD, cam, seed=v)
        lens = calibrate_intrinsics(_noisy(seen_corners(CHECKERBOARD, cam, R, t), rng), CHECKERBOARD.object_points,
                                    SIZE)
        assert lens.rms_px < 0.2
        assert abs(lens.K[0, 0] / cam.K[0, 0] - 1) < 0.005 and abs(lens.K[1, 1] / cam.K[1, 1] - 1) < 0.005
        assert np.abs(lens.K[:2, 2] - cam.K[:2, 2]).max() < 3.0
        assert np.abs(lens.distortion[:2] - cam.distortion[:2]).max() < 0.03
        K.append(lens.K)
        truth_px.append(lens)
    R, t = floor_board_poses(20, CHECKERBOARD)
    corners = np.array([_noisy(seen_corners(CHECKERBOARD, cam, R, t), rng) for cam in cams])   # through the lens
    given = true_cameras(cams)
    found = calibrate_extrinsics(corners, given, CHECKERBOARD.object_points)
    assert found.world_view == 0 and found.rms_px.max() < 0.2 and found.converged
    assert found.cameras.names == given.names and np.array_equal(found.cameras.K, given.K)
    assert all(np.array_equal(a, b) for a, b in zip(found.cameras.distortion, given.distortion))
    for v, cam in enumerate(cams):
        assert np.linalg.norm(found.cameras.centers[v] - (cam.centre - FIRST_CORNER)) < 0.01   # 1 cm, 3 m away
        assert _rotation_deg(found.cameras.R[v], cam.R) < 0.2
    in_camera = calibrate_extrinsics(corners, given, CHECKERBOARD.object_points, "camera")
    assert in_camera.world_view == -1
    in_camera = in_camera.cameras
    assert np.allclose(in_camera.R[0], np.eye(3)) and np.allclose(in_camera.t[0], 0)
    relative = cams[1].R @ cams[0].R.T
    assert _rotation_deg(in_camera.R[1], relative) < 0.2
    assert np.linalg.norm(in_camera.t[1] - (cams[1].t - relative @ cams[0].t)) < 0.01


def test_spread_views_keeps_different_views():
    """Farthest-point sampling keeps one of each cluster of similar views."""
    clusters = np.repeat(np.eye(4), 10, axis=0) + np.random.default_rng(0).normal(0, 0.01, (40, 4))
    chosen = spread_views(clusters, 4)
    assert sorted(set(chosen // 10)) == [0, 1, 2, 3]
    assert view_features(np.array([[0.0, 0], [640, 0], [640, 480], [0, 480]]), SIZE)[:2] == pytest.approx([0.5, 0.5])
    corners = np.array([[[10.0, 10], [630, 470], [np.nan, np.nan]], [[12, 14], [320, 240], [330, 250]]])
    assert image_coverage(corners, SIZE) == 3 / 48                                 # 3 of the 8x6 cells


def _calibrate(root, board, out, *extra):
    args = ["calibrate", root, "--" + board.kind, "--board-size", f"{board.cols}x{board.rows}",
            "--square-size", board.square_m, "-o", out, *extra]
    if board.kind == "charuco":
        args += ["--marker-size", board.marker_m]
    return CliRunner().invoke(rig, [str(a) for a in args])


def _assert_matches(found: RigCalibration, truth, focal=0.005, centre_m=0.02, rotation_deg=0.5, lens=True):
    assert list(found.cameras.names) == truth.names
    for v, cam in enumerate(truth.cameras):
        K = found.cameras.K[v]
        if lens:
            assert abs(K[0, 0] / cam.K[0, 0] - 1) < focal and abs(K[1, 1] / cam.K[1, 1] - 1) < focal
            assert np.abs(K[:2, 2] - cam.K[:2, 2]).max() < 4.0
            assert abs(found.distortions[v][0] - cam.distortion[0]) < 0.03
        assert np.linalg.norm(found.cameras.centers[v] - (cam.centre - FIRST_CORNER)) < centre_m
        assert _rotation_deg(found.cameras.R[v], cam.R) < rotation_deg


@pytest.fixture(scope="module")
def checkerboard_rig(tmp_path_factory):
    root = tmp_path_factory.mktemp("board") / "rig"
    return root, write_board_rig(root, CHECKERBOARD)


@pytest.mark.slow
def test_checkerboard_videos(checkerboard_rig, tmp_path):
    """Intrinsics from calibration/intrinsics/, poses from calibration/extrinsics/ (rendered mp4)."""
    root, truth = checkerboard_rig
    out = tmp_path / "board.toml"
    result = _calibrate(root, CHECKERBOARD, out)
    assert result.exit_code == 0, result.output
    assert "cam_03" in result.output and f"wrote {out}" in result.output
    found = read_calib_toml(out)
    _assert_matches(found, truth, focal=0.003, centre_m=0.01, rotation_deg=0.2)
    assert max(found.metadata["residual_px"]) < 0.4 and max(found.metadata["intrinsics_rms_px"]) < 0.4
    assert "frame 0" in found.metadata["world"]

    out = tmp_path / "frame5.toml"                              # the world on the board of frame 5, tilted
    result = _calibrate(root, CHECKERBOARD, out, "--world-frame", 5, "--intrinsics", tmp_path / "board.toml")
    assert result.exit_code == 0, result.output
    found = read_calib_toml(out)
    assert "frame 5" in found.metadata["world"]
    R, t = floor_board_poses(24, CHECKERBOARD)
    flip = np.diag([1.0, -1.0, -1.0])                            # the board's z out of its face, up
    for v, cam in enumerate(truth.cameras):
        assert np.linalg.norm(found.cameras.centers[v] - flip @ R[5].T @ (cam.centre - t[5])) < 0.015
        assert _rotation_deg(found.cameras.R[v], cam.R @ R[5] @ flip) < 0.3


@pytest.mark.slow
def test_charuco_videos(tmp_path):
    """A ChArUco board, both steps from rendered videos."""
    truth = write_board_rig(tmp_path / "rig", CHARUCO, intrinsic_frames=16, extrinsic_frames=16)
    out = tmp_path / "charuco.toml"
    result = _calibrate(tmp_path / "rig", CHARUCO, out)
    assert result.exit_code == 0, result.output
    found = read_calib_toml(out)
    _assert_matches(found, truth, focal=0.003, centre_m=0.015, rotation_deg=0.4)
    assert max(found.metadata["residual_px"]) < 0.5


@pytest.mark.slow
def test_fisheye_lenses(tmp_path):
    """Wide-angle cameras with OpenCV's fisheye lens, calibrated with --fisheye."""
    truth = write_board_rig(tmp_path / "rig", CHECKERBOARD, intrinsic_frames=16, extrinsic_frames=16, fisheye=True)
    out = tmp_path / "fisheye.toml"
    result = _calibrate(tmp_path / "rig", CHECKERBOARD, out, "--fisheye")
    assert result.exit_code == 0, result.output
    found = read_calib_toml(out)
    assert found.fisheye.all() and all(len(d) == 4 for d in found.distortions)
    _assert_matches(found, truth, focal=0.005, centre_m=0.01, rotation_deg=0.2, lens=False)
    for v, cam in enumerate(truth.cameras):                  # the lens maps pixels as the true one does
        K = found.cameras.K[v]
        assert abs(K[0, 0] / cam.K[0, 0] - 1) < 0.005 and np.abs(K[:2, 2] - cam.K[:2, 2]).max() < 2.0
        rays = np.array([[0.3, 0.2, 1.0], [-0.5, 0.4, 1.0], [0.6, -0.45, 1.0]]).reshape(1, -1, 3)
        zero = np.zeros(3)
        true_px = cv2.fisheye.projectPoints(rays, zero, zero, cam.K, cam.distortion)[0]
        found_px = cv2.fisheye.projectPoints(rays, zero, zero, K, found.distortions[v])[0]
        assert np.abs(found_px - true_px).max() < 2.0


@pytest.mark.slow
def test_given_intrinsics_and_flat_layout(tmp_path):
    """Videos right in calibration/ (anipose's layout), intrinsics from --intrinsics."""
    truth = write_board_rig(tmp_path / "rig", CHARUCO, extrinsic_frames=10, layout="flat")
    cams = truth.cameras
    lens = write_true_calibration(tmp_path / "intrinsics.toml", cams, truth.names)
    out = tmp_path / "given.toml"
    result = _calibrate(tmp_path / "rig", CHARUCO, out, "--intrinsics", lens, "--world", "camera")
    assert result.exit_code == 0, result.output
    assert "(given)" in result.output
    found = read_calib_toml(out)
    assert np.allclose(found.cameras.K, [c.K for c in cams])
    assert np.allclose(found.cameras.R[0], np.eye(3)) and np.allclose(found.cameras.t[0], 0)
    for v in (1, 2):
        relative = cams[v].R @ cams[0].R.T
        assert _rotation_deg(found.cameras.R[v], relative) < 0.3
        assert np.linalg.norm(found.cameras.t[v] - (cams[v].t - relative @ cams[0].t)) < 0.02
    result = _calibrate(tmp_path / "rig", CHARUCO, tmp_path / "own.toml")        # lenses from the floor views:
    assert result.exit_code == 0, result.output                                   # said to be uncertain
    assert "warning: camera cam_01: the board covered" in result.output


def _one_line_exit_2(result, *words):
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1, result.output
    for word in words:
        assert word in lines[0], lines[0]


def _small_rig(tmp_path, **kwargs):
    root = tmp_path / "rig"
    write_board_rig(root, CHARUCO, intrinsic_frames=6, extrinsic_frames=6, **kwargs)
    return root


def test_bad_board_input_one_line(tmp_path):
    root = _small_rig(tmp_path)
    out = tmp_path / "c.toml"
    _one_line_exit_2(CliRunner().invoke(rig, ["calibrate", str(root), "-o", str(out)]), "choose one of")
    _one_line_exit_2(CliRunner().invoke(rig, ["calibrate", str(root), "--charuco", "--from-people", "-o", str(out)]),
                     "--from-people and --charuco")
    _one_line_exit_2(CliRunner().invoke(rig, ["calibrate", str(root), "--from-people", "--board-size", "7x6",
                                              "-o", str(out)]), "--board-size", "not --from-people")
    _one_line_exit_2(_calibrate(root, CHARUCO, out, "--refine-focal"), "--refine-focal", "--from-people only")
    _one_line_exit_2(_calibrate(root, CHARUCO, out, "--fisheye", "--intrinsics", out), "--fisheye", "--intrinsics")
    _one_line_exit_2(CliRunner().invoke(rig, ["calibrate", str(root), "--from-people", "--fisheye", "-o", str(out)]),
                     "--fisheye", "not --from-people")
    _one_line_exit_2(_calibrate(root, Board("checkerboard", 7, 6, 0.07), out, "--marker-size", 0.05),
                     "--marker-size", "--charuco only")
    _one_line_exit_2(CliRunner().invoke(rig, ["calibrate", str(root), "--charuco", "--board-size", "6x5",
                                              "--square-size", "0.1", "-o", str(out)]), "--marker-size", "required")
    _one_line_exit_2(CliRunner().invoke(rig, ["calibrate", str(root), "--checkerboard", "--board-size", "7by6",
                                              "--square-size", "0.1", "-o", str(out)]), "--board-size", "COLSxROWS")
    _one_line_exit_2(_calibrate(root, Board("checkerboard", 7, 5, 0.07), out), "--board-size", "7x5", "180°")
    _one_line_exit_2(CliRunner().invoke(rig, ["calibrate", str(root), "--charuco", "--board-size", "6x5",
                                              "--square-size", "0.1", "--marker-size", "0.2", "-o", str(out)]),
                     "--marker-size", "between 0 and the square size")
    assert not out.exists()


def test_board_not_found_one_line(tmp_path):
    """A camera whose extrinsics video never shows the board; a board of another dictionary."""
    root = _small_rig(tmp_path, blank={1: range(6)})
    out = tmp_path / "c.toml"
    _one_line_exit_2(_calibrate(root, CHARUCO, out), "cam_02.mp4", "camera cam_02", "no ChArUco board")
    _one_line_exit_2(_calibrate(root, CHARUCO, out, "--dictionary", "DICT_5X5_50"), "camera cam_01", "DICT_5X5_50")
    assert not out.exists()


def test_camera_without_a_shared_view_one_line(tmp_path):
    """cam_03 sees the board only when no other camera does."""
    root = _small_rig(tmp_path, blank={0: (3, 4, 5), 1: (3, 4, 5), 2: (0, 1, 2)})
    out = tmp_path / "c.toml"
    _one_line_exit_2(_calibrate(root, CHARUCO, out), "camera cam_03",
                     "never sees the board at the same instant as the other cameras")
    assert not out.exists()


def test_world_frame_without_the_board_one_line(tmp_path):
    root = _small_rig(tmp_path, blank={0: (2,), 1: (2,)})
    out = tmp_path / "c.toml"
    _one_line_exit_2(_calibrate(root, CHARUCO, out, "--world-frame", 2), "--world-frame: 2", "by cam_03",
                     "at least two cameras")
    _one_line_exit_2(_calibrate(root, CHARUCO, out, "--world-frame", 2, "--world", "camera"), "--world-frame",
                     "--world board")
    assert not out.exists()


def test_undecodable_video_and_one_camera_one_line(tmp_path):
    root = _small_rig(tmp_path)
    out = tmp_path / "c.toml"
    (root / "calibration" / "extrinsics" / "cam_02.mp4").write_bytes(b"not a video" * 100)
    _one_line_exit_2(_calibrate(root, CHARUCO, out), "cam_02.mp4", "OpenCV cannot")
    shutil.rmtree(root / "calibration" / "extrinsics")
    _one_line_exit_2(_calibrate(root, CHARUCO, out), "calibration", "no calibration videos")
    cam = ring_cameras(1)[0]
    R, t = floor_board_poses(2, CHARUCO)
    write_board_video(root / "calibration" / "extrinsics" / "cam_01.mp4", CHARUCO, cam, R, t)
    _one_line_exit_2(_calibrate(root, CHARUCO, out), "one camera (cam_01)", "at least two")
    assert not out.exists()


def test_views_along_one_line_are_not_used():
    corners = np.full((3, len(CHARUCO.object_points), 2), np.nan)
    corners[0, :8] = 1.0                                   # two rows of corners: a plane
    corners[1, :5] = 1.0                                   # one row: a line
    corners[2, :4] = 1.0                                   # too few
    assert usable_views(corners, CHARUCO.object_points).tolist() == [True, False, False]


def test_still_board_in_images(tmp_path):
    """Pose2Sim's extrinsics: one image of a board lying on the floor per camera (a file, or a
    folder of images), the intrinsics given. A still board tells the cameras less than a moving
    one (2.2 cm here, against 1 mm)."""
    cams = ring_cameras(3)
    folder = tmp_path / "rig" / "calibration" / "extrinsics"
    write_still_board([folder / "cam_01.png", folder / "cam_02" / "0001.png", folder / "cam_03.jpg"], CHECKERBOARD,
                      cams)
    lens = write_true_calibration(tmp_path / "intrinsics.toml", cams, ["cam_01", "cam_02", "cam_03"])
    out = tmp_path / "still.toml"
    result = _calibrate(tmp_path / "rig", CHECKERBOARD, out, "--intrinsics", lens)
    assert result.exit_code == 0, result.output
    found = read_calib_toml(out)
    for v, cam in enumerate(cams):                          # one view of a small board 3 m away: 2.2 cm, 0.45°
        assert np.linalg.norm(found.cameras.centers[v] - (cam.centre - FIRST_CORNER)) < 0.04
        assert _rotation_deg(found.cameras.R[v], cam.R) < 0.8


def test_unsynchronized_views_refused():
    """One camera's extrinsics shifted by 3 frames: its views do not agree with the others'."""
    cams = ring_cameras(3, seed=1)
    R, t = floor_board_poses(20, CHECKERBOARD)
    corners = np.array([seen_corners(CHECKERBOARD, cam, R, t) for cam in cams])
    corners[2] = np.roll(corners[2], 3, axis=0)
    with pytest.raises(CalibrationError, match="recorded together") as caught:
        calibrate_extrinsics(corners, true_cameras(cams), CHECKERBOARD.object_points)
    assert caught.value.camera == 2


def test_checkerboard_found_in_large_frames():
    """A 1920-pixel-wide frame is searched reduced, its corners refined at full size."""
    cam = ring_cameras(1)[0]
    R, t = frontal_board_poses(3, CHECKERBOARD, cam, seed=0)
    texture, A = CHECKERBOARD.texture(48)
    grid = lens_grid(cam)
    truth = seen_corners(CHECKERBOARD, cam, R, t)
    detect = CHECKERBOARD.detector()
    for k in range(3):
        gray = cv2.cvtColor(render(CHECKERBOARD, texture, A, cam, grid, R[k], t[k]), cv2.COLOR_BGR2GRAY)
        large = cv2.resize(gray, (SIZE[0] * 3, SIZE[1] * 3), interpolation=cv2.INTER_CUBIC)
        ids, pixels = detect(large)
        assert np.abs((pixels + 0.5) / 3 - 0.5 - truth[k][ids]).max() < 0.4


def test_intrinsics_videos_matched_by_name(tmp_path):
    """Pose2Sim's folder names (int_cam01_img, ext_cam01_img) go together; a stray video is named."""
    names = ["ext_cam01_img", "ext_cam02_img"]
    sources = {"int_cam02_img": tmp_path / "b", "int_cam01_img": tmp_path / "a"}
    assert intrinsic_videos(names, sources) == {"ext_cam01_img": tmp_path / "a", "ext_cam02_img": tmp_path / "b"}
    assert intrinsic_videos(names, {"cam_02": tmp_path / "c"}) == {"ext_cam02_img": tmp_path / "c"}
    with pytest.raises(InputError, match="no extrinsics video of the same camera"):
        intrinsic_videos(names, {"cam_07": tmp_path / "d"})


def test_output_on_an_input_refused_before_work(tmp_path, monkeypatch):
    """-o on a calibration video, inside calibration/, on the --intrinsics file or a link to it:
    one line naming -o before any video is read, the inputs unchanged."""
    root = _small_rig(tmp_path)
    monkeypatch.setattr("mvm.rig.board_videos.rig_videos", lambda *a: pytest.fail("worked before refusing"))
    given = write_true_calibration(tmp_path / "given.toml", ring_cameras(3), [f"cam_{v + 1:02d}" for v in range(3)])
    link = tmp_path / "link.toml"
    link.symlink_to(given)
    video = root / "calibration" / "extrinsics" / "cam_01.mp4"
    before = video.read_bytes(), given.read_bytes()
    for out, extra, problem in ((video, [], "inside the input"),
                                (root / "calibration" / "Calib.toml", [], "inside the input"),
                                (given, ["--intrinsics", given], "is an input"),
                                (link, ["--intrinsics", given], "is an input")):
        _one_line_exit_2(_calibrate(root, CHARUCO, out, *extra), str(out), problem)
    assert (video.read_bytes(), given.read_bytes()) == before and not (root / "calibration" / "Calib.toml").exists()


def test_board_sizes_opencv_cannot_find_refused(tmp_path):
    """Checkerboards with a count below 3 (OpenCV's findChessboardCorners rejects them) or above
    100 along a side (a typing error): one line naming --board-size before any video is read,
    nothing written."""
    root = _small_rig(tmp_path)
    out = tmp_path / "c.toml"
    for size in ("2x3", "3x2", "0x0", "1x1"):
        _one_line_exit_2(CliRunner().invoke(rig, ["calibrate", str(root), "--checkerboard", "--board-size", size,
                                                  "--square-size", "0.07", "-o", str(out)]),
                         "--board-size", "at least 3x3")
    with pytest.raises(ValueError, match="at least 3x3"):
        Board("checkerboard", 3, 2, 0.07)
    for size in ("101x6", "7x100000000000000000000"):
        _one_line_exit_2(CliRunner().invoke(rig, ["calibrate", str(root), "--checkerboard", "--board-size", size,
                                                  "--square-size", "0.07", "-o", str(out)]),
                         "--board-size", "at most 100 along a side")
    assert not out.exists()


def test_board_too_big_for_its_dictionary_one_line(tmp_path):
    """A ChArUco board with more markers than its dictionary holds: one line naming --dictionary,
    the dictionary's count and the board's need, before any video is read."""
    root = _small_rig(tmp_path)
    out = tmp_path / "c.toml"
    _one_line_exit_2(CliRunner().invoke(rig, ["calibrate", str(root), "--charuco", "--board-size", "100x3",
                                              "--square-size", "0.1", "--marker-size", "0.075", "-o", str(out)]),
                     "error: --dictionary: DICT_4X4_50 holds 50 markers", "100x3 squares needs 150")
    assert not out.exists()


def _png_header_only(path, width, height):
    """A PNG whose header claims ``width`` x ``height`` gray pixels (no real image data)."""
    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(bytes(1000))) + chunk(b"IEND", b""))


def test_huge_or_undecodable_calibration_image_one_line(tmp_path):
    """An image folder holding an image whose header claims 60000x60000 pixels (OpenCV refuses
    to decode it: it was a traceback) or a file that is not an image: one line naming it."""
    root = _small_rig(tmp_path)
    out = tmp_path / "c.toml"
    images = root / "calibration" / "extrinsics" / "cam_04"
    images.mkdir()
    for content in ("huge", b"not a png"):
        if content == "huge":
            _png_header_only(images / "a.png", 60000, 60000)
        else:
            (images / "a.png").write_bytes(content)
        _one_line_exit_2(_calibrate(root, CHARUCO, out), str(images / "a.png"), "not an image OpenCV can decode")
    assert not out.exists()


def test_fifo_named_like_a_calibration_video_or_image_one_line(tmp_path):
    """A FIFO named like a camera's video (it was left out unsaid: the rig calibrated without
    that camera) or like an image of an image folder (leaving it out shifts the frame numbers
    after it): one line naming it, exit 2, nothing written, no hang."""
    root = _small_rig(tmp_path)
    out = tmp_path / "c.toml"
    fifo = root / "calibration" / "extrinsics" / "cam_04.mp4"
    os.mkfifo(fifo)
    _one_line_exit_2(_calibrate(root, CHARUCO, out), str(fifo), "not a file")
    fifo.unlink()
    images = root / "calibration" / "extrinsics" / "cam_04"
    images.mkdir()
    cv2.imwrite(str(images / "a.png"), np.zeros((8, 8), np.uint8))
    os.mkfifo(images / "b.png")
    _one_line_exit_2(_calibrate(root, CHARUCO, out), str(images / "b.png"), "not a file")
    assert not out.exists()
