"""The camera and its lens: projection against hand-built ground truth and OpenCV, the lens and its inverse."""
import subprocess
import sys

import cv2
import numpy as np
import pytest

from mvm.core.camera import (
    UNDISTORT_CRITERIA,
    distort,
    has_lens,
    project_camera,
    project_views,
    projection_matrix,
    undistort,
)

from helpers import random_cameras

K = np.array([[1634.0, 0, 942], [0, 1629, 558], [0, 0, 1]])


def test_project_by_hand():
    # Camera 2 m behind the origin along z, looking along +z, rotated 90° about z.
    R = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
    t = np.array([0.0, 0.0, 2.0])
    K1 = np.array([[100.0, 0, 50], [0, 200, 40], [0, 0, 1]])
    pixels, depth = project_camera(np.array([[0.4, 0.2, 2.0], [0.0, 0.0, -3.0]]), K1, R, t)
    # x_cam = R X + t = (-0.2, 0.4, 4): u = 100 * -0.05 + 50, v = 200 * 0.1 + 40.
    np.testing.assert_allclose(pixels[0], [45.0, 60.0])
    np.testing.assert_allclose(depth, [4.0, -1.0])                 # the second point is behind
    np.testing.assert_allclose(projection_matrix(K1, R, t), K1 @ np.hstack([R, t[:, None]]))


@pytest.mark.parametrize("dist", [[-0.22, 0.2, 1e-4, 1e-3, 0.02], [0.1, -0.05, 0.001, 0.002]])
def test_project_with_a_lens_is_opencv(dist):
    rng = np.random.default_rng(4)
    rvec, t = rng.normal(0, 0.3, 3), np.array([0.1, -0.2, 4.0])
    X = rng.uniform(-1, 1, (5, 17, 3))
    pixels, depth = project_camera(X, K, cv2.Rodrigues(rvec)[0], t, np.array(dist))
    expected, _ = cv2.projectPoints(X.reshape(-1, 1, 3), rvec, t, K, np.array(dist))
    np.testing.assert_allclose(pixels, expected.reshape(5, 17, 2), atol=1e-6)
    assert depth.shape == (5, 17) and (depth > 0).all()


def test_project_views_is_every_camera_and_nan_stays_nan():
    rng = np.random.default_rng(2)
    cams = random_cameras(rng, 4)
    X = rng.uniform(-1, 1, (3, 17, 3))
    X[1, 5] = np.nan
    pixels, depth = project_views(cams, X)
    assert pixels.shape == (4, 3, 17, 2) and depth.shape == (4, 3, 17)
    for v in range(4):
        one, z = project_camera(X, cams.K[v], cams.R[v], cams.t[v])
        np.testing.assert_allclose(pixels[v], one, rtol=1e-12, equal_nan=True)
        np.testing.assert_allclose(depth[v], z, rtol=1e-12, equal_nan=True)
    assert np.isnan(pixels[:, 1, 5]).all() and np.isfinite(pixels[:, 1, 4]).all()


@pytest.mark.parametrize("fisheye,dist", [(False, [-0.22, 0.2, 1e-4, 1e-3, 0.02]), (True, [0.05, -0.01, 0.002, 0.0])])
def test_undistort_inverts_distort(fisheye, dist):
    xy = np.random.default_rng(0).uniform([100, 100], [1800, 1000], (50, 2))
    distorted = distort(xy, K, np.array(dist), fisheye)
    assert np.abs(distorted - xy).max() > 1.0                     # the lens matters
    np.testing.assert_allclose(undistort(distorted, K, np.array(dist), fisheye), xy, atol=1e-3)


def test_no_lens_and_missing_points():
    xy = np.array([[[10.0, 20.0], [np.nan, np.nan], [500.0, 400.0]]])
    for lens in (None, np.zeros(0), np.zeros(5)):
        assert not has_lens(lens)
        out = distort(xy, K, lens)
        np.testing.assert_array_equal(out, xy)
        assert out is not xy
    dist = np.array([-0.2, 0.1, 0.0, 0.0])
    assert has_lens(dist)
    for f in (distort, undistort):
        out = f(xy, K, dist)
        assert out.shape == xy.shape
        assert np.isnan(out[0, 1]).all() and np.isfinite(out[0, [0, 2]]).all()


def test_the_undistortion_criteria_are_opencvs_and_a_pinhole_scene_does_not_import_it():
    """:data:`UNDISTORT_CRITERIA` spells OpenCV's flags as numbers (OpenCV is imported only for
    a lens): they are its ``COUNT | EPS``; reconstructing a pinhole scene leaves it unimported."""
    assert UNDISTORT_CRITERIA[0] == cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS
    code = """
import sys
from mvm.core.reconstruct import reconstruct
from mvm.sim.simulate import SimConfig, simulate
scene, _ = simulate(SimConfig(people=2, frames=8, seed=0))
assert len(reconstruct(scene).persons) == 2
assert "cv2" not in sys.modules
"""
    run = subprocess.run([sys.executable, "-c", code], check=False, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
