"""Bundle adjustment on :class:`~mvm.core.scene.Cameras`: a simulated rig whose true cameras,
lens and points the tests construct, seen in pixels through its lens."""
from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from mvm.core.camera import distort_views, project_views
from mvm.core.scene import Cameras
from mvm.rig.bundle_adjustment import bundle_adjust, reprojection_px

#: OpenCV's k1, k2, p1, p2, k3 of a wide lens: 20-60 px at the corners of a 1280 x 720 image.
LENS = np.array([-0.25, 0.08, 0.001, -0.0005, 0.0])


def _rig(lens: np.ndarray, n_objects: int = 30, n_points: int = 6, seed: int = 0):
    """Three cameras around objects 4 m away (camera 0 at the origin), every object's points
    seen by every camera: ``(cameras, pixels (N, J, 2), camera (N,), obj (N,), X (Q, J, 3))``."""
    rng = np.random.default_rng(seed)
    K = np.array([[900.0, 0, 640], [0, 905, 360], [0, 0, 1]])
    centres = np.array([[0.0, 0, 0], [2.0, 0.2, 0.5], [-1.5, -0.3, 1.0]])
    target = np.array([0.0, 0.0, 4.0])
    R = []
    for c in centres:
        z = (target - c) / np.linalg.norm(target - c)
        x = np.cross([0.0, 1.0, 0.0], z)
        x /= np.linalg.norm(x)
        R.append(np.stack([x, np.cross(z, x), z]))
    R = np.array(R)
    R[0] = np.eye(3)
    t = -np.einsum("vij,vj->vi", R, centres)
    V = len(centres)
    true = Cameras(np.repeat(K[None], V, 0), R, t, np.tile([1280.0, 720.0], (V, 1)), ("a", "b", "c"),
                   (lens,) * V)
    X = target + rng.uniform(-0.8, 0.8, (n_objects, n_points, 3))
    pinhole, _ = project_views(true, X)                                           # (V, Q, J, 2)
    camera = np.repeat(np.arange(V), n_objects)
    obj = np.tile(np.arange(n_objects), V)
    pixels = distort_views(true, pinhole.reshape(V * n_objects, n_points, 2), camera)
    return true, pixels, camera, obj, X


def _perturbed(true: Cameras, X: np.ndarray, seed: int = 1) -> tuple[Cameras, np.ndarray]:
    """The true cameras but the first turned by ~1° and moved by ~5 cm, the points by ~3 cm."""
    rng = np.random.default_rng(seed)
    turn = Rotation.from_rotvec(rng.normal(0, np.radians(1.0), (len(true), 3))).as_matrix()
    turn[0] = np.eye(3)
    shift = rng.normal(0, 0.05, (len(true), 3))
    shift[0] = 0
    return replace(true, R=turn @ true.R, t=true.t + shift), X + rng.normal(0, 0.03, X.shape)


def _centre_error(found: Cameras, true: Cameras) -> float:
    """The largest camera-centre error (m) once the free scale is fitted (camera 0 at the origin)."""
    scale = np.sum(found.centers * true.centers) / np.sum(found.centers ** 2)
    return float(np.abs(scale * found.centers - true.centers).max())


def test_bundle_adjust_recovers_a_rig_with_a_lens_from_its_pixels():
    true, pixels, camera, obj, X = _rig(LENS)
    start, X0 = _perturbed(true, X)
    present = np.ones(pixels.shape[:2], bool)
    adjusted = bundle_adjust(start, pixels, present, camera, obj, X0)
    found = adjusted.cameras
    assert adjusted.converged
    angle = np.degrees(Rotation.from_matrix(found.R @ true.R.transpose(0, 2, 1)).magnitude())
    assert angle.max() < 1e-4
    assert _centre_error(found, true) < 1e-5
    for v in range(len(true)):                                                    # the lens and intrinsics stay
        np.testing.assert_array_equal(found.distortion[v], LENS)
    np.testing.assert_array_equal(found.K, true.K)
    assert found.names == true.names
    np.testing.assert_array_equal(adjusted.focal_scale, 1.0)
    assert np.nanmax(reprojection_px(found, pixels, present, camera, obj, adjusted.X)) < 1e-3
    assert adjusted.centre_sd[0] == 0.0
    # the lens matters: the same pixels read as a pinhole camera's misplace the cameras
    pinhole = bundle_adjust(replace(start, distortion=()), pixels, present, camera, obj, X0)
    assert _centre_error(pinhole.cameras, true) > 0.005                         # 11 mm; with the lens 1e-11


def test_bundle_adjust_refines_the_focal_lengths_and_keeps_the_principal_point():
    true, pixels, camera, obj, X = _rig(np.zeros(0), n_objects=60)
    start, X0 = _perturbed(true, X)
    off = np.array([1.0, 1.03, 0.97])
    K = true.K.copy()
    K[:, :2, :2] *= off[:, None, None]
    adjusted = bundle_adjust(replace(start, K=K), pixels, np.ones(pixels.shape[:2], bool), camera, obj, X0,
                             refine_focal=True)
    found = adjusted.cameras.K
    np.testing.assert_allclose(found[:, 0, 0] / true.K[:, 0, 0], 1, atol=2e-3)
    np.testing.assert_allclose(found[:, 1, 1] / found[:, 0, 0], true.K[:, 1, 1] / true.K[:, 0, 0])
    np.testing.assert_array_equal(found[:, :2, 2], true.K[:, :2, 2])
    np.testing.assert_allclose(adjusted.focal_scale, found[:, 0, 0] / K[:, 0, 0])


def test_weights_drop_observations_and_unseen_objects_stay_nan():
    true, pixels, camera, obj, X = _rig(np.zeros(0), n_objects=10)
    wrong = (camera == 2) & (obj < 5)
    pixels[wrong] += 40.0                                                         # views 40 px off...
    weight = np.ones(pixels.shape[:2])
    weight[wrong] = 0.0                                                           # ...and dropped
    obj = np.where(obj == 9, -1, obj)                                             # object 9: no one's
    adjusted = bundle_adjust(true, pixels, np.ones(pixels.shape[:2], bool), camera, obj, X, weight=weight)
    np.testing.assert_allclose(adjusted.X[:9], X[:9], atol=1e-6)
    assert np.isnan(adjusted.X[9]).all()
