"""Eq. 2 computed the plain way, beside the fused implementation of :mod:`mvm.core.affinity`.

The reference builds the fundamental matrix of every pair of views from the two projection
matrices, ``F = [e']_x P' P^+`` (Hartley & Zisserman, Eq. 9.1), and sums point-to-epipolar-line
distances joint by joint, pose pair by pose pair, in Python loops:

    D(x_u, x_v) = 1 / (2 C) Σ_c d(x_u^c, L_uv(x_v^c)) + d(x_v^c, L_vu(x_u^c))

with the conventions of :func:`mvm.core.affinity.epipolar_distance`: ``C`` counts the joints
both poses have (confidence >= the threshold), a distance in view ``u`` is measured in units of
``distance_scale · f_u`` pixels (``f_u`` the mean focal length), ``D = inf`` for two poses of one
view (or of two instants), NaN for fewer than ``min_common_keypoints`` shared joints or views
with one centre (no epipolar geometry). The fused version (Plücker rays, batched over pose
pairs, float32 by default) must give the same numbers on random, non-degenerate inputs, and
both the number computed by hand for a simple rig.
"""
import numpy as np
import pytest

from mvm.core.affinity import block_epipolar_distance, epipolar_distance
from mvm.core.geometry import skew
from mvm.core.scene import Cameras


def fundamental(P_u: np.ndarray, P_v: np.ndarray) -> np.ndarray:
    """``F`` with ``l_u = F x_v`` the epipolar line in view ``u`` of a pixel ``x_v`` of view ``v``:
    ``F = [e_u]_x P_u P_v^+``, ``e_u = P_u C_v`` the epipole (``C_v`` the null vector of ``P_v``)."""
    C_v = np.linalg.svd(P_v)[2][-1]
    return skew(P_u @ C_v) @ P_u @ np.linalg.pinv(P_v)


def point_line_distance(x: np.ndarray, line: np.ndarray) -> float:
    """Euclidean distance of the pixel ``x: (2,)`` to the line ``a u + b v + c = 0``."""
    return abs(line @ [x[0], x[1], 1.0]) / np.hypot(line[0], line[1])


def reference_distance(cameras: Cameras, keypoints: np.ndarray, view: np.ndarray, threshold: float,
                       distance_scale: float, min_common: int = 1, instant=None) -> np.ndarray:
    """Eq. 2 for every pair of poses, one pair and one joint at a time. ``(N, N)``."""
    N = len(keypoints)
    P = cameras.P
    unit = distance_scale * cameras.focal
    visible = keypoints[:, :, 2] >= max(threshold, 1e-9)
    D = np.full((N, N), np.inf)
    for a in range(N):
        for b in range(N):
            u, v = view[a], view[b]
            if u == v or (instant is not None and instant[a] != instant[b]):
                continue
            if np.allclose(cameras.centers[u], cameras.centers[v]):
                D[a, b] = np.nan
                continue
            F = fundamental(P[u], P[v])                 # pixels of v -> lines in u; F.T the other way
            common = np.flatnonzero(visible[a] & visible[b])
            if len(common) < max(min_common, 1):
                D[a, b] = np.nan
                continue
            total = 0.0
            for c in common:
                xa, xb = keypoints[a, c, :2], keypoints[b, c, :2]
                total += point_line_distance(xa, F @ [xb[0], xb[1], 1.0]) / unit[u]
                total += point_line_distance(xb, F.T @ [xa[0], xa[1], 1.0]) / unit[v]
            D[a, b] = total / (2 * len(common))
    return D


def _rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q * np.linalg.det(q)


def random_rig(rng, V: int) -> Cameras:
    """``V`` cameras with random intrinsics (fx != fy, skew, principal point), orientations and
    centres 3–6 m from the origin, looking roughly at it."""
    K, R, t = [], [], []
    for _ in range(V):
        centre = rng.normal(size=3)
        centre *= rng.uniform(3, 6) / np.linalg.norm(centre)
        forward = -centre / np.linalg.norm(centre) + rng.normal(0, 0.1, 3)
        forward /= np.linalg.norm(forward)
        side = np.cross(forward, rng.normal(size=3))
        side /= np.linalg.norm(side)
        rot = np.stack([side, np.cross(forward, side), forward])     # rows: camera x, y, z in the world
        R.append(rot)
        t.append(-rot @ centre)
        f = rng.uniform(600, 2000)
        K.append([[f * rng.uniform(0.9, 1.1), rng.uniform(-2, 2), rng.uniform(300, 900)],
                  [0, f, rng.uniform(200, 600)], [0, 0, 1]])
    R = np.array(R)
    assert np.allclose(np.linalg.det(R), 1.0)
    return Cameras(np.array(K), R, np.array(t), np.broadcast_to([1280.0, 720.0], (V, 2)),
                   tuple(f"cam{i}" for i in range(V)))


def random_poses(rng, cameras: Cameras, per_view: int, persons: int = 3):
    """Poses of ``persons`` random people seen in every view, with pixel noise, random
    confidences and missing joints; ``per_view`` poses a view (repeats and strangers).
    Returns ``keypoints: (N, 17, 3)`` and ``view: (N,)``."""
    people = rng.normal(0, 0.5, (persons, 17, 3))
    keypoints, view = [], []
    for v in range(len(cameras)):
        for k in range(per_view):
            X = people[k % persons] + rng.normal(0, 0.02, (17, 3))
            x = (cameras.P[v] @ np.concatenate([X, np.ones((17, 1))], 1).T).T
            xy = x[:, :2] / x[:, 2:] + rng.normal(0, 3.0, (17, 2))
            conf = rng.uniform(0.05, 1.0, 17)
            conf[rng.uniform(size=17) < 0.2] = 0.0                    # missing
            keypoints.append(np.concatenate([xy, conf[:, None]], 1))
            view.append(v)
    return np.array(keypoints), np.array(view)


@pytest.mark.parametrize("seed", range(6))
def test_fused_equals_reference_on_random_rigs(seed):
    rng = np.random.default_rng(seed)
    cameras = random_rig(rng, int(rng.integers(2, 6)))
    keypoints, view = random_poses(rng, cameras, per_view=int(rng.integers(1, 4)))
    threshold, scale, min_common = 0.3, float(rng.uniform(0.005, 0.02)), int(rng.integers(1, 6))
    expected = reference_distance(cameras, keypoints, view, threshold, scale, min_common)
    assert np.isfinite(expected).any() and (expected[np.isfinite(expected)] > 0).all()   # not degenerate
    exact = epipolar_distance(cameras, keypoints, view, threshold, scale, min_common, dtype=np.float64)
    np.testing.assert_allclose(exact, expected, rtol=1e-9, atol=0)
    assert np.array_equal(np.isnan(exact), np.isnan(expected)) and np.array_equal(np.isinf(exact), np.isinf(expected))
    fast = epipolar_distance(cameras, keypoints, view, threshold, scale, min_common)                # float32
    np.testing.assert_allclose(fast, expected, rtol=2e-4, atol=1e-4)
    # Small blocks of working memory: the same numbers.
    blocked = epipolar_distance(cameras, keypoints, view, threshold, scale, min_common, dtype=np.float64,
                                block_bytes=17 * 8 * 3)
    np.testing.assert_allclose(blocked, expected, rtol=1e-9, atol=0)


def test_block_version_and_instants_equal_reference():
    rng = np.random.default_rng(11)
    cameras = random_rig(rng, 4)
    keypoints, view = random_poses(rng, cameras, per_view=3)
    instant = rng.integers(0, 2, len(view))
    expected = reference_distance(cameras, keypoints, view, 0.2, 0.01, 2, instant=instant)
    got = epipolar_distance(cameras, keypoints, view, 0.2, 0.01, 2, dtype=np.float64, instant=instant)
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=0)
    # block_epipolar_distance: the poses of each instant as one block, padded with -1.
    members = [np.flatnonzero(instant == i) for i in range(2)]
    n = max(len(m) for m in members)
    blocks = np.array([np.concatenate([m, -np.ones(n - len(m), int)]) for m in members])
    D = block_epipolar_distance(cameras, keypoints, view, blocks, 0.2, 0.01, 2, dtype=np.float64)
    for b, m in enumerate(members):
        np.testing.assert_allclose(D[b, :len(m), :len(m)], expected[np.ix_(m, m)], rtol=1e-9, atol=0)
        assert np.isinf(D[b, len(m):]).all() and np.isinf(D[b, :, len(m):]).all()


def test_hand_computed_distance_of_a_horizontal_stereo_pair():
    # Two cameras with the same K and orientation, the second 0.5 m to the right: the epipolar
    # lines are the image rows, so each joint's distance (either way) is |y_a - y_b| pixels.
    f = 1000.0
    K = np.array([[f, 0, 640], [0, f, 360], [0, 0, 1]])
    cameras = Cameras(np.stack([K, K]), np.stack([np.eye(3)] * 2), np.array([[0.0, 0, 0], [-0.5, 0, 0]]),
                      np.array([[1280.0, 720], [1280.0, 720]]), ("left", "right"))
    a = np.zeros((17, 3))
    b = np.zeros((17, 3))
    a[:, 0], a[:, 1] = np.arange(17) * 10.0, 100.0 + np.arange(17)
    b[:, 0], b[:, 1] = 500.0 - np.arange(17), 100.0 + 2 * np.arange(17)      # rows off by j px for joint j
    a[:, 2] = b[:, 2] = 1.0
    a[[0, 1], 2] = 0.0                            # joints 0 and 1 missing in a
    b[16, 2] = 0.05                               # joint 16 below the threshold in b
    keypoints = np.stack([a, b])
    # common joints 2..15: mean |Δy| = mean(2..15) = 8.5 px; in units of 0.01 · f = 10 px: 0.85
    D = epipolar_distance(cameras, keypoints, np.array([0, 1]), keypoint_threshold=0.1, distance_scale=0.01,
                          dtype=np.float64)
    assert D[0, 1] == pytest.approx(0.85, rel=1e-12) and D[1, 0] == pytest.approx(0.85, rel=1e-12)
    assert np.isinf(D[0, 0]) and np.isinf(D[1, 1])
    reference = reference_distance(cameras, keypoints, np.array([0, 1]), 0.1, 0.01)
    assert reference[0, 1] == pytest.approx(0.85, rel=1e-9)
    # No baseline (one centre): undefined; fewer common joints than asked: undefined.
    same = Cameras(cameras.K, cameras.R, np.zeros((2, 3)), cameras.size, cameras.names)
    assert np.isnan(epipolar_distance(same, keypoints, np.array([0, 1]), 0.1, 0.01)[0, 1])
    assert np.isnan(epipolar_distance(cameras, keypoints, np.array([0, 1]), 0.1, 0.01, min_common_keypoints=15)[0, 1])
