"""Calibrations of other systems: known cameras written by hand in each published layout
(tests/calibration_writers.py), converted, and compared with the cameras they were written from;
the real Qualisys sample against Pose2Sim's own conversion; bad files refused in one line."""
from __future__ import annotations

import os
import pickle

import numpy as np
import pytest

from calibration_writers import (
    known_cameras,
    write_anipose,
    write_biocv,
    write_caliscope,
    write_easymocap,
    write_opencap,
    write_qca,
    write_xcp,
)
from mvm.errors import InputError
from mvm.io.calib_toml import calib_toml_text, parse_calib
from mvm.io.calibrations import FORMATS, detect_format, read_foreign_calibration
from mvm.io.calibrations.common import quaternion_matrix
from mvm.io.checks import parse_toml

from helpers import SHARED_DATA


def _assert_same(calibration, cams, dist=None, names=None):
    """``calibration`` holds ``cams`` in order: projection matrices, centres, sizes, lenses."""
    got = calibration.cameras
    assert got.names == tuple(names or [c.name for c in cams])
    for v, c in enumerate(cams):
        np.testing.assert_allclose(got.P[v] / got.P[v][2, 3], c.P / c.P[2, 3], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(got.centers[v], c.center, atol=1e-9)
        np.testing.assert_allclose(got.K[v], c.K, rtol=1e-12)
        np.testing.assert_allclose(got.size[v], c.size)
        np.testing.assert_allclose(calibration.distortions[v], c.dist if dist is None else dist(c), rtol=1e-12)
    assert calibration.metadata["units"] == "m"


def _round_trip(calibration):
    """Written as Calib.toml and read back: the same cameras."""
    back = parse_calib(parse_toml(calib_toml_text(calibration), "x.toml"), "x.toml")
    np.testing.assert_allclose(back.cameras.P, calibration.cameras.P, rtol=1e-12, atol=1e-9)


def test_qualisys_sensor_units_window_and_axes(tmp_path):
    cams = known_cameras()
    path = write_qca(tmp_path / "Calib.qca.txt", cams)
    assert detect_format(path) == "qualisys"
    calibration = read_foreign_calibration(path)
    _assert_same(calibration, cams)
    _round_trip(calibration)


def test_qualisys_binning_divides_the_sensor_pixels(tmp_path):
    cams = known_cameras()
    path = write_qca(tmp_path / "c.qca.txt", cams, binning=2)
    _assert_same(read_foreign_calibration(path, "qualisys", binning=2), cams)
    unbinned = read_foreign_calibration(path, "qualisys")                   # the sensor's pixels
    binned = read_foreign_calibration(path, binning=2)
    np.testing.assert_allclose(unbinned.cameras.K[:, :2] / 2, binned.cameras.K[:, :2])
    np.testing.assert_allclose(unbinned.cameras.centers, [c.center for c in cams], atol=1e-9)


def test_qualisys_leaves_marker_cameras_out(tmp_path):
    marker = ('<camera serial="m1" model="Miqus M3" viewrotation="0"><fov_video left="0" top="0" right="1" bottom="1"/>'
              "</camera>")
    cams = known_cameras(2)
    calibration = read_foreign_calibration(write_qca(tmp_path / "c.qca.txt", cams, extra=marker))
    assert calibration.cameras.names == ("cam01", "cam02")


def test_vicon_quaternions_and_millimetres(tmp_path):
    cams = known_cameras()
    path = write_xcp(tmp_path / "calib.xcp", cams)
    assert detect_format(path) == "vicon"
    calibration = read_foreign_calibration(path)
    _assert_same(calibration, cams, dist=lambda c: np.array([c.dist[0], c.dist[1], 0.0, 0.0, c.dist[4]]))
    _round_trip(calibration)


def test_quaternion_matrix_matches_scipy():
    from scipy.spatial.transform import Rotation

    q = np.random.default_rng(1).normal(size=(20, 4))
    for quat in q:
        np.testing.assert_allclose(quaternion_matrix(quat), Rotation.from_quat(quat).as_matrix(), atol=1e-12)


def test_easymocap_either_file_or_the_folder(tmp_path):
    cams = known_cameras()
    intri = write_easymocap(tmp_path / "easymocap", cams)
    for given in (intri, intri.parent / "extri.yml", intri.parent):
        assert detect_format(given) == "easymocap"
        _assert_same(read_foreign_calibration(given), cams)


def test_easymocap_without_image_size_takes_twice_the_principal_point(tmp_path):
    cams = known_cameras(2)
    intri = write_easymocap(tmp_path, cams)
    intri.write_text("".join(line + "\n" for line in intri.read_text().splitlines() if line[:2] not in ("H_", "W_")))
    calibration = read_foreign_calibration(intri)
    np.testing.assert_allclose(calibration.cameras.size, [2 * c.K[:2, 2] for c in cams])
    assert calibration.metadata["size_guessed"] == ["cam01", "cam02"]


def test_opencap_pickles_turned_to_z_up(tmp_path):
    cams = known_cameras()
    first = write_opencap(tmp_path / "Videos", cams)
    for given in (first, tmp_path / "Videos"):
        assert detect_format(given) == "opencap"
        _assert_same(read_foreign_calibration(given), cams, names=["Cam0", "Cam1", "Cam2"])
    one = read_foreign_calibration(tmp_path / "Videos" / "Cam1", "opencap")       # a camera's folder alone
    assert list(one.cameras.names) == ["Cam1"]
    np.testing.assert_allclose(one.cameras.K[0], cams[1].K)


def test_anipose_and_freemocap_in_millimetres_or_metres(tmp_path):
    cams = known_cameras()
    mm = write_anipose(tmp_path / "calibration.toml", cams, unit=1000.0)
    assert detect_format(mm) == "anipose"
    _assert_same(read_foreign_calibration(mm), cams)
    _assert_same(read_foreign_calibration(mm, "freemocap"), cams)
    assert read_foreign_calibration(mm).metadata["source_units"].startswith("mm")
    m = write_anipose(tmp_path / "m.toml", cams, unit=1.0)
    _assert_same(read_foreign_calibration(m, "anipose"), cams)


def test_caliscope_ports_ignored_and_uncalibrated_cameras(tmp_path):
    cams = known_cameras()
    path = write_caliscope(tmp_path / "config.toml", cams)
    assert detect_format(path) == "caliscope"
    calibration = read_foreign_calibration(path)
    _assert_same(calibration, cams, names=["cam_0", "cam_1", "cam_2"])
    assert calibration.metadata["uncalibrated_cameras"] == ["cam_8"]


def test_biocv_files_of_a_folder(tmp_path):
    cams = known_cameras()
    first = write_biocv(tmp_path / "calib", cams)
    for given in (first, first.parent):
        assert detect_format(given) == "biocv"
        _assert_same(read_foreign_calibration(given), cams)


def test_every_format_has_a_test_here():
    tested = {"qualisys", "vicon", "easymocap", "opencap", "anipose", "freemocap", "caliscope", "biocv"}
    assert set(FORMATS) == tested


# -- the real sample ------------------------------------------------------------------------------

REAL = SHARED_DATA / "real_footage" / "calibration"


def test_real_qualisys_agrees_with_pose2sim():
    """Pose2Sim's converter on the lab's .qca: centres within 1 mm, focal lengths within 0.01 %
    (its distortions are divided by 64, ours are not: docs/rigs.md)."""
    if not (REAL / "Calib.qca.txt").is_file():
        pytest.skip(f"real footage calibration absent: {REAL}")
    ours = read_foreign_calibration(REAL / "Calib.qca.txt")
    theirs = parse_calib(parse_toml((REAL / "Calib_converted_by_pose2sim.toml").read_text(), "p2s"), "p2s")
    assert ours.cameras.names == theirs.cameras.names == ("cam01", "cam02", "cam03", "cam04")
    assert np.abs(ours.cameras.centers - theirs.cameras.centers).max() < 1e-3
    focal = np.concatenate([ours.cameras.K[:, 0, 0] / theirs.cameras.K[:, 0, 0],
                            ours.cameras.K[:, 1, 1] / theirs.cameras.K[:, 1, 1]])
    assert np.abs(focal - 1).max() < 1e-4
    np.testing.assert_allclose(ours.cameras.K, theirs.cameras.K, rtol=1e-9)
    np.testing.assert_allclose(ours.cameras.R, theirs.cameras.R, atol=1e-9)
    np.testing.assert_allclose(ours.cameras.size, theirs.cameras.size)
    np.testing.assert_allclose(np.array(ours.distortions)[:, :4] / 64, np.array(theirs.distortions), rtol=1e-9)


# -- bad files ------------------------------------------------------------------------------------

def _refused(call, *words):
    with pytest.raises(InputError) as e:
        call()
    line = str(e.value)
    assert "\n" not in line
    for word in words:
        assert word in line, line
    return line


def test_wrong_format_truncated_and_hostile_files(tmp_path):
    cams = known_cameras(2)
    xcp = write_xcp(tmp_path / "c.xcp", cams)
    _refused(lambda: read_foreign_calibration(xcp, "qualisys"), "not a Qualisys calibration")
    qca = write_qca(tmp_path / "c.qca.txt", cams)
    qca.write_text(qca.read_text()[: len(qca.read_text()) // 2])
    _refused(lambda: read_foreign_calibration(qca), "not a Qualisys calibration", "XML")
    bomb = tmp_path / "b.qca.txt"
    bomb.write_text('<?xml version="1.0"?><!DOCTYPE l [<!ENTITY a "aaaa">]><calibration>&a;</calibration>')
    _refused(lambda: read_foreign_calibration(bomb), "document type")
    text = tmp_path / "notes.txt"
    text.write_text("hello\n")
    _refused(lambda: read_foreign_calibration(text), "not recognised", "--format")
    _refused(lambda: read_foreign_calibration(xcp, "vicon", binning=2), "--binning", "Qualisys")
    calib = write_biocv(tmp_path / "bio", cams)
    calib.write_text("1920\n1080\n1 0 2\n")
    _refused(lambda: read_foreign_calibration(calib), "not a bioCV calibration")
    anipose = write_caliscope(tmp_path / "cs.toml", cams)
    _refused(lambda: read_foreign_calibration(anipose, "anipose"), "caliscope")


def test_turned_qualisys_camera_is_refused(tmp_path):
    qca = write_qca(tmp_path / "c.qca.txt", known_cameras(2))
    qca.write_text(qca.read_text().replace('viewrotation="0"', 'viewrotation="90"', 1))
    _refused(lambda: read_foreign_calibration(qca), "viewrotation", "cam01")


def test_a_rotation_that_is_not_one_is_refused(tmp_path):
    cams = known_cameras(2)
    cams[1].R = cams[1].R * 1.5
    _refused(lambda: read_foreign_calibration(write_biocv(tmp_path, cams)), "not a rotation")


class _RunsCode:
    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return os.system, (f"touch {self.marker}",)


def test_a_pickle_that_would_run_code_is_refused(tmp_path):
    """Never unpickled here: the bytes name os.system, the restricted unpickler refuses them."""
    marker = tmp_path / "ran"
    folder = tmp_path / "Videos" / "Cam0"
    folder.mkdir(parents=True)
    bad = folder / "cameraIntrinsicsExtrinsics.pickle"
    bad.write_bytes(pickle.dumps({"intrinsicMat": _RunsCode(marker)}))
    _refused(lambda: read_foreign_calibration(bad), "refusing to load", "system")
    assert not marker.exists()


def test_per_camera_sets_read_only_their_own_files(tmp_path):
    """Another session's pickles further down an OpenCap folder are not taken for this set's
    cameras (a broken one there was read), and a camera file of an OpenCap or bioCV set that is a
    link leading out of the set's folder is refused in one line."""
    from calibration_writers import write_biocv, write_opencap

    cams = known_cameras(2)
    first = write_opencap(tmp_path / "Videos", cams)
    (tmp_path / "Videos" / "old" / "Cam1").mkdir(parents=True)
    (tmp_path / "Videos" / "old" / "Cam1" / first.name).write_bytes(b"not a pickle at all")
    assert len(read_foreign_calibration(tmp_path / "Videos", "opencap").cameras) == 2
    second = tmp_path / "Videos" / "Cam1" / first.name
    outside = tmp_path / "elsewhere.pickle"
    outside.write_bytes(second.read_bytes())
    second.unlink()
    second.symlink_to(outside)
    with pytest.raises(InputError, match="outside"):
        read_foreign_calibration(tmp_path / "Videos", "opencap")
    write_biocv(tmp_path / "bio", cams)
    files = sorted((tmp_path / "bio").glob("*.calib"))
    away = tmp_path / "away.calib"
    away.write_text(files[1].read_text())
    files[1].unlink()
    files[1].symlink_to(away)
    with pytest.raises(InputError, match="outside"):
        read_foreign_calibration(files[0], "biocv")
