"""The batched DLT triangulation and Umeyama alignment against plain reference versions.

Each fast, vectorized implementation is compared with a version written here as the textbook
states it (a loop over points, one SVD each) and with OpenCV's ``cv2.triangulatePoints``, on
random non-zero inputs with noise, plus cases whose answer is known by construction.
"""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from mvm.core.geometry import project, similarity_transform, triangulate_dlt

from helpers import random_cameras


def dlt_loop(points: np.ndarray, P: np.ndarray, weights: np.ndarray | None = None,
             unit_rows: bool = True) -> np.ndarray:
    """The DLT one point at a time: ``points: (N, M, 2)``, ``P: (M, 3, 4)`` -> ``(N, 3)``.

    For each point, the rows ``x p₃ − p₁`` and ``y p₃ − p₂`` of every view (each scaled to unit
    norm when ``unit_rows``, as mvm does; OpenCV does not), times the view's weight, stacked
    into ``A``; the point is the right singular vector of the smallest singular value."""
    out = []
    for uv in points:
        rows = []
        for m, (x, y) in enumerate(uv):
            w = 1.0 if weights is None else weights[m]
            for row in (x * P[m, 2] - P[m, 0], y * P[m, 2] - P[m, 1]):
                rows.append(w * (row / np.linalg.norm(row) if unit_rows else row))
        X = np.linalg.svd(np.array(rows))[2][-1]
        out.append(X[:3] / X[3])
    return np.array(out)


def _scene(seed: int, views: int, points: int, noise_px: float):
    rng = np.random.default_rng(seed)
    cams = random_cameras(rng, views, arc_deg=120)
    X = rng.uniform([-1, -1, 0], [1, 1, 2], (points, 3))
    uv = project(X[None], cams.P)[0].swapaxes(0, 1)                             # (N, M, 2)
    return rng, cams, X, uv + rng.normal(0, noise_px, uv.shape)


@pytest.mark.parametrize("seed", range(3))
def test_dlt_equals_opencv_and_the_plain_loop_on_exact_points(seed):
    _, cams, X, uv = _scene(seed, 2, 50, noise_px=0.0)
    homogeneous = cv2.triangulatePoints(cams.P[0], cams.P[1], uv[:, 0].T.copy(), uv[:, 1].T.copy())   # (4, N)
    opencv = (homogeneous[:3] / homogeneous[3]).T
    ours = triangulate_dlt(uv, cams.P)
    np.testing.assert_allclose(opencv, X, atol=1e-6)
    np.testing.assert_allclose(ours, X, atol=1e-6)
    np.testing.assert_allclose(ours, dlt_loop(uv, cams.P), atol=1e-9)


@pytest.mark.parametrize("seed", range(3))
def test_dlt_with_noise_equals_the_plain_loop(seed):
    """Noisy pixels, two views: the loop without row scaling is OpenCV's DLT to rounding; with
    mvm's unit rows it is :func:`triangulate_dlt` to rounding. Several weighted views: the same."""
    rng, cams, X, uv = _scene(seed, 2, 40, noise_px=2.0)
    homogeneous = cv2.triangulatePoints(cams.P[0], cams.P[1], uv[:, 0].T.copy(), uv[:, 1].T.copy())
    opencv = (homogeneous[:3] / homogeneous[3]).T
    np.testing.assert_allclose(dlt_loop(uv, cams.P, unit_rows=False), opencv, atol=1e-8)
    ours = triangulate_dlt(uv, cams.P)
    np.testing.assert_allclose(ours, dlt_loop(uv, cams.P), atol=1e-8)
    assert np.abs(ours - X).max() > 1e-4                                       # the noise moved the points
    assert np.linalg.norm(ours - X, axis=1).max() < 0.05                        # ... a little

    rng, cams, X, uv = _scene(seed + 10, 6, 40, noise_px=2.0)
    weights = rng.uniform(0.1, 1.0, 6)
    weights[2] = 0.0                                                             # a dropped view
    ours = triangulate_dlt(uv, cams.P, np.broadcast_to(weights, uv.shape[:2]))
    np.testing.assert_allclose(ours, dlt_loop(uv, cams.P, weights), atol=1e-8)
    unweighted = triangulate_dlt(uv, cams.P)
    assert np.abs(ours - unweighted).max() > 1e-5                              # the weights mattered


def _rotation(rng) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def umeyama_loop(source: np.ndarray, target: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Umeyama (1991), eqs. 34–42, for one point set ``(N, 3)`` as the paper writes it."""
    mu_x, mu_y = source.mean(0), target.mean(0)
    var_x = ((source - mu_x) ** 2).sum() / len(source)
    cov = sum(np.outer(y - mu_y, x - mu_x) for x, y in zip(source, target, strict=True)) / len(source)
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(cov) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    c = np.trace(np.diag(D) @ S) / var_x
    return c, R, mu_y - c * R @ mu_x


def test_umeyama_equals_the_plain_version_on_noisy_point_sets():
    rng = np.random.default_rng(4)
    source = rng.normal(size=(6, 15, 3))
    R = np.stack([_rotation(rng) for _ in range(6)])
    s, t = rng.uniform(0.3, 3.0, 6), rng.normal(size=(6, 3))
    target = s[:, None, None] * np.einsum("nij,nkj->nki", R, source) + t[:, None] + rng.normal(0, 0.05, source.shape)
    found = similarity_transform(source, target)
    for n in range(6):
        reference = umeyama_loop(source[n], target[n])
        assert found[0][n] == pytest.approx(reference[0], rel=1e-10)
        np.testing.assert_allclose(found[1][n], reference[1], atol=1e-10)
        np.testing.assert_allclose(found[2][n], reference[2], atol=1e-10)
        assert abs(found[0][n] - s[n]) > 1e-6 and abs(found[0][n] - s[n]) < 0.1 * s[n]   # noise, not exactness


def test_umeyama_of_a_mirrored_set_is_a_rotation():
    """A target that is the source mirrored: the best orthogonal matrix is a reflection, which
    both versions refuse for the best rotation (``det R = +1``), and agree on."""
    rng = np.random.default_rng(5)
    source = rng.normal(size=(20, 3)) * [3.0, 2.0, 0.5]
    target = source * [1.0, 1.0, -1.0]
    s, R, t = similarity_transform(source, target)
    reference = umeyama_loop(source, target)
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(R, reference[1], atol=1e-10)
    assert s == pytest.approx(reference[0], rel=1e-10)
    np.testing.assert_allclose(t, reference[2], atol=1e-10)


def test_umeyama_with_a_mask_equals_the_plain_version_on_the_kept_points():
    rng = np.random.default_rng(6)
    source, R = rng.normal(size=(30, 3)), _rotation(rng)
    target = 1.7 * source @ R.T + [0.3, -2.0, 1.0] + rng.normal(0, 0.02, (30, 3))
    keep = rng.random(30) < 0.6
    target[~keep] += rng.normal(0, 5.0, ((~keep).sum(), 3))                     # outliers left out
    found = similarity_transform(source, target, keep)
    reference = umeyama_loop(source[keep], target[keep])
    for a, b in zip(found, reference, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-10)
