"""The one projection and the one lens against reference versions: OpenCV's ``projectPoints``
and plain Python loops that spell out the pinhole camera and OpenCV's lens models point by point."""
import dataclasses
import math

import cv2
import numpy as np
import pytest

from mvm.core.camera import distort_views, has_lens, project_camera, undistort_views
from mvm.core.geometry import project as project_with_matrices

from helpers import random_cameras

#: A radial-tangential lens ``k1 k2 p1 p2 k3``, a plain ``k1 k2 p1 p2`` one and a fisheye one.
LENSES = ((np.array([-0.22, 0.2, 1e-4, 1e-3, 0.02]), False), (np.array([0.1, -0.05, 0.001, 0.002]), False),
          (np.array([0.05, -0.01, 0.002, 0.0]), True))


def _pixel_by_hand(X, K, R, t, lens=None, fisheye=False):
    """One world point ``X`` through one camera, number by number: ``x_cam = R X + t``, the
    normalized point, OpenCV's lens (radial-tangential or fisheye), then ``K``."""
    xc = [sum(R[i][j] * X[j] for j in range(3)) + t[i] for i in range(3)]
    x, y = xc[0] / xc[2], xc[1] / xc[2]
    d = list(lens) + [0.0] * 5 if lens is not None else [0.0] * 5
    if fisheye:
        r = math.hypot(x, y)
        theta = math.atan(r)
        theta_d = theta * (1 + d[0] * theta**2 + d[1] * theta**4 + d[2] * theta**6 + d[3] * theta**8)
        scale = theta_d / r if r > 0 else 1.0
        x, y = x * scale, y * scale
    else:
        k1, k2, p1, p2, k3 = d[:5]
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
        x, y = (x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
                y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y)
    return K[0][0] * x + K[0][1] * y + K[0][2], K[1][1] * y + K[1][2], xc[2]


def test_the_projection_is_the_pinhole_camera_point_by_point():
    """``geometry.project``'s broadcast contract (each camera's block of points) against a loop
    over persons, views and joints; ``min_depth`` keeps a point on the camera's plane finite."""
    rng = np.random.default_rng(11)
    cams = random_cameras(rng, 4)
    X = rng.uniform(-1, 1, (3, 17, 3)) + [0, 0, 1]
    X[2, 4] = np.nan
    uv, depth = project_with_matrices(X[:, None], cams.P)                              # (3, 4, 17, 2)
    assert uv.shape == (3, 4, 17, 2) and depth.shape == (3, 4, 17)
    for q in range(3):
        for v in range(4):
            for j in range(17):
                u, w, z = _pixel_by_hand(X[q, j], cams.K[v], cams.R[v], cams.t[v])
                np.testing.assert_allclose(uv[q, v, j], [u, w], rtol=1e-12, equal_nan=True)
                np.testing.assert_allclose(depth[q, v, j], z, rtol=1e-12, equal_nan=True)
    P0 = np.hstack([np.eye(3), np.zeros((3, 1))])
    on_plane = np.array([1.0, 2.0, 0.0])                                              # depth 0
    assert not np.isfinite(project_with_matrices(on_plane, P0)[0]).any()
    pixel, z = project_with_matrices(on_plane, P0, min_depth=1e-9)
    np.testing.assert_allclose(pixel, [1e9, 2e9])
    assert z == 0


@pytest.mark.parametrize("lens,fisheye", LENSES)
def test_projection_with_a_lens_is_opencv_and_the_loop(lens, fisheye):
    rng = np.random.default_rng(5)
    cams = random_cameras(rng, 3)
    X = rng.uniform(-1, 1, (2, 17, 3)) + [0, 0, 1]
    for v in range(3):
        pixels, depth = project_camera(X, cams.K[v], cams.R[v], cams.t[v], lens, fisheye)
        rvec = cv2.Rodrigues(cams.R[v])[0]
        opencv = cv2.fisheye.projectPoints if fisheye else cv2.projectPoints
        expected = opencv(X.reshape(-1, 1, 3), rvec, cams.t[v], cams.K[v], lens)[0].reshape(2, 17, 2)
        np.testing.assert_allclose(pixels, expected, atol=1e-6)
        by_hand = np.array([[_pixel_by_hand(p, cams.K[v], cams.R[v], cams.t[v], lens, fisheye) for p in person]
                            for person in X])
        np.testing.assert_allclose(pixels, by_hand[..., :2], atol=1e-6)
        np.testing.assert_allclose(depth, by_hand[..., 2], rtol=1e-12)


def test_each_view_has_its_own_lens_and_undistortion_inverts_it():
    """``distort_views`` applies each detection's camera's lens (the loop's, camera by camera) and
    ``undistort_views`` undoes it; a camera without a lens leaves its pixels as they are."""
    rng = np.random.default_rng(8)
    cams = random_cameras(rng, 4)
    cams = dataclasses.replace(cams, distortion=tuple(lens for lens, _ in LENSES) + (np.zeros(0),),
                               fisheye=[f for _, f in LENSES] + [False])
    X = rng.uniform(-1, 1, (12, 17, 3)) + [0, 0, 1]
    view = rng.integers(0, 4, 12)
    pinhole = np.stack([project_camera(X[n], cams.K[v], cams.R[v], cams.t[v])[0] for n, v in enumerate(view)])
    distorted = distort_views(cams, pinhole, view)
    for n, v in enumerate(view):
        by_hand = [_pixel_by_hand(p, cams.K[v], cams.R[v], cams.t[v], cams.distortion[v], cams.fisheye[v])[:2]
                   for p in X[n]]
        np.testing.assert_allclose(distorted[n], by_hand, atol=1e-6)
    assert np.abs(distorted - pinhole)[view < 3].max() > 1.0 and (distorted == pinhole)[view == 3].all()
    np.testing.assert_allclose(undistort_views(cams, distorted, view), pinhole, atol=1e-3)


def test_a_fisheye_lens_without_coefficients_is_the_equidistant_lens():
    assert has_lens(np.zeros(4), fisheye=True) and not has_lens(np.zeros(4)) and not has_lens(np.zeros(0), True)
    K, R, t = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]), np.eye(3), np.zeros(3)
    X = np.array([[0.8, -0.5, 1.0]])                                                  # 43° off the axis
    pixels, _ = project_camera(X, K, R, t, np.zeros(4), True)
    np.testing.assert_allclose(pixels[0], _pixel_by_hand(X[0], K, R, t, np.zeros(4), True)[:2], atol=1e-6)
    assert np.abs(pixels - project_camera(X, K, R, t)[0]).max() > 50
