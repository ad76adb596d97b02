"""Bundle adjustment of a rig's cameras and the points they see (no I/O), as aniposelib's
``CameraGroup.bundle_adjust``: it takes :class:`~mvm.core.scene.Cameras` and pixels seen through
their lens (undone once, at the entry, by :func:`mvm.core.camera.undistort_views`) and returns the
adjusted ``Cameras`` (the same lens; ``R``, ``t`` and the refined focal lengths adjusted). It moves
every camera but the reference (rotation vector, translation), every point (the people's joints,
or a calibration board's corners: an object of ``J`` points seen at once) and optionally every
camera's focal length (a factor of ``K``'s), on reprojection errors in pixels (the normalized
coordinates of each ``K`` times its mean focal length; points project through
:func:`mvm.core.geometry.project`), ``scipy.optimize.least_squares`` with an
explicit Jacobian sparsity, ``x_scale='jac'`` and a soft-L1 loss (as aniposelib's
``bundle_adjust``). Each observation may carry a weight (a detector's confidence). The cameras'
uncertainty comes from the Jacobian at the solution: the reduced camera system (the points
eliminated by their Schur complement), inverted with the scale held (it is free: every
translation may grow), scaled by the residuals' variance."""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import coo_matrix, csc_matrix, hstack
from scipy.spatial.transform import Rotation

from mvm.core.camera import normalized_points, projection_matrix, undistort_views
from mvm.core.geometry import project
from mvm.core.scene import Cameras

#: Scale of the soft-L1 loss on the reprojection errors. [px]
LOSS_SCALE_PX = 3.0

def _rotation_matrices(rvec: np.ndarray) -> np.ndarray:
    return Rotation.from_rotvec(rvec).as_matrix()


def jacobian_sparsity(cam: np.ndarray, point: np.ndarray, n_cameras: int, n_points: int,
                      focal: bool = False) -> coo_matrix:
    """Which parameters each residual depends on: the ``(2n, 6 (V - 1) + 3 P [+ V])`` 0/1 pattern
    of ``n`` observations of ``point: (n,)`` in ``cam: (n,)`` (x and y rows; camera 0 is fixed;
    ``focal``: one focal length per camera last)."""
    n = len(cam)
    rows, cols = [], []
    moving = np.flatnonzero(cam > 0)
    width = 6 * (n_cameras - 1) + 3 * n_points
    for r in (0, 1):
        rows.append(np.repeat(2 * moving + r, 6))
        cols.append((6 * (cam[moving] - 1))[:, None].repeat(6, 1).ravel() + np.tile(np.arange(6), len(moving)))
        rows.append(np.repeat(2 * np.arange(n) + r, 3))
        cols.append(6 * (n_cameras - 1) + (3 * point)[:, None].repeat(3, 1).ravel() + np.tile(np.arange(3), n))
        if focal:
            rows.append(2 * np.arange(n) + r)
            cols.append(width + cam)
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    return coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)),
                      shape=(2 * n, width + (n_cameras if focal else 0)))


@dataclass
class Adjusted:
    """A bundle adjustment's result: the adjusted ``cameras`` (:class:`~mvm.core.scene.Cameras`:
    the lens, principal point, aspect ratio, size and names of those given; ``R``, ``t`` and,
    when refined, the focal lengths adjusted), the points ``X (Q, J, 3)`` (NaN: not adjusted),
    ``focal_scale (V,)`` each focal length over the one given (1 unless refined), ``converged``
    (the solver met its tolerance), ``centre_sd (V,)`` each camera centre's standard deviation
    (the root of its covariance's trace; in the units of ``t``, 0 for the fixed reference camera)."""

    cameras: Cameras
    X: np.ndarray
    focal_scale: np.ndarray
    converged: bool
    centre_sd: np.ndarray


def _normalized(cameras: Cameras, pixels: np.ndarray, camera: np.ndarray) -> np.ndarray:
    """Pixels ``(N, J, 2)`` seen by ``camera: (N,)`` through the cameras' lens -> ``(N, J, 2)``
    normalized coordinates of their pinhole ``K`` (:func:`mvm.core.camera.undistort_views`)."""
    return normalized_points(undistort_views(cameras, pixels, camera), cameras.K[camera])


def bundle_adjust(cameras: Cameras, pixels: np.ndarray, present: np.ndarray, camera: np.ndarray, obj: np.ndarray,
                  X: np.ndarray, refine_focal: bool = False, weight: np.ndarray | None = None) -> Adjusted:
    """Sparse bundle adjustment (module docstring) of ``V`` cameras and the objects they see.
    Camera 0 stays fixed.

    Args:
        cameras: the ``V`` initial cameras (their lens is undone from ``pixels``; it stays).
        pixels: ``(N, J, 2)`` the points (a person's ``J = 17`` joints, a board's corners) of
            ``N`` views of objects, in pixels through the cameras' lens; present: ``(N, J)``;
            camera, obj: ``(N,)`` the camera and the object (-1: none) of each view;
            X: ``(Q, J, 3)`` the objects' initial points.
        refine_focal: adjust every camera's focal length too (its principal point and aspect
            ratio stay).
        weight: ``(N, J)`` each observation's weight (default 1; 0 drops it).
    Returns:
        :class:`Adjusted`.
    """
    x = _normalized(cameras, pixels, camera)
    R, t, focal = cameras.R, cameras.t, cameras.focal
    V, J = len(cameras), x.shape[1]
    weight = np.ones(present.shape) if weight is None else weight
    use = present & (obj >= 0)[:, None] & np.isfinite(X[np.maximum(obj, 0)]).all(-1) & (weight > 0)
    pose, joint = np.nonzero(use)
    cam, point = camera[pose], obj[pose] * J + joint
    points_used, point_index = np.unique(point, return_inverse=True)
    obs = x[pose, joint]
    P = len(points_used)
    X0 = X.reshape(-1, 3)[points_used]
    rvec0 = Rotation.from_matrix(R[1:]).as_rotvec()
    params0 = np.concatenate([np.column_stack([rvec0, t[1:]]).ravel(), X0.ravel()] + ([np.ones(V)] if refine_focal
                                                                                        else []))
    f = focal[cam] * np.sqrt(weight[pose, joint])
    end = 6 * (V - 1) + 3 * P

    def residuals(params):
        cams = params[:6 * (V - 1)].reshape(V - 1, 6)
        Rs = np.concatenate([R[:1], _rotation_matrices(cams[:, :3])])
        ts = np.concatenate([t[:1], cams[:, 3:]])
        pts = params[6 * (V - 1):end].reshape(P, 3)
        xy, _ = project(pts[point_index, None], projection_matrix(np.eye(3), Rs, ts)[cam], min_depth=1e-9)
        scale = params[end:][cam, None] if refine_focal else 1.0
        return ((scale * xy[:, 0] - obs) * f[:, None]).ravel()

    sparsity = jacobian_sparsity(cam, point_index, V, P, refine_focal)
    result = least_squares(residuals, params0, jac_sparsity=sparsity, x_scale="jac", loss="soft_l1",
                           f_scale=LOSS_SCALE_PX, method="trf", max_nfev=200)
    Xout = np.full((len(X) * J, 3), np.nan)
    Xout[points_used] = result.x[6 * (V - 1):end].reshape(P, 3)
    sd = centre_sd(result.jac, 2 * result.cost / max(result.fun.size - result.x.size, 1), result.x[:6 * (V - 1)], P,
                   refine_focal)
    scale = result.x[end:] if refine_focal else np.ones(V)
    return Adjusted(_adjusted_cameras(cameras, result.x[:6 * (V - 1)], scale), Xout.reshape(X.shape), scale,
                    bool(result.status > 0), np.concatenate([[0.0], sd]))


def _adjusted_cameras(cameras: Cameras, params: np.ndarray, focal_scale: np.ndarray) -> Cameras:
    """``cameras`` with every camera but the first moved to ``params: (6 (V - 1),)`` (rotation
    vector, translation) and its focal lengths (and skew) scaled by ``focal_scale: (V,)``."""
    cams = params.reshape(-1, 6)
    K = cameras.K.copy()
    K[:, :2, :2] *= focal_scale[:, None, None]
    return replace(cameras, K=K, R=np.concatenate([cameras.R[:1], _rotation_matrices(cams[:, :3])]),
                   t=np.concatenate([cameras.t[:1], cams[:, 3:]]))


def centre_sd(jac, variance: float, cams: np.ndarray, n_points: int, focal: bool = False) -> np.ndarray:
    """The standard deviation of every adjusted camera's centre ``-R^T t`` (module docstring).

    Args:
        jac: ``(2n, 6 (V - 1) + 3 P [+ V])`` sparse Jacobian at the solution (its columns:
            :func:`jacobian_sparsity`'s); variance: of one residual; cams: ``(6 (V - 1),)`` the
            cameras' parameters (rotation vector, translation); n_points: ``P``.
    Returns:
        ``(V - 1,)`` the root of each centre covariance's trace.
    """
    n_cams = len(cams) // 6
    width = 6 * n_cams
    J = csc_matrix(jac)
    A = J[:, :width]
    B = J[:, width:width + 3 * n_points]
    extra = J[:, width + 3 * n_points:]
    if focal:
        A = hstack([A, extra]).tocsc()
    H_cc = (A.T @ A).toarray()
    H_cp = (A.T @ B).toarray()                                                    # (c, 3P)
    BB = (B.T @ B).tocsr()
    index = 3 * np.arange(n_points)[:, None, None]
    rows = np.broadcast_to(index + np.arange(3)[:, None], (n_points, 3, 3))
    cols = np.broadcast_to(index + np.arange(3)[None, :], (n_points, 3, 3))
    inv = np.linalg.pinv(np.asarray(BB[rows.ravel(), cols.ravel()]).reshape(n_points, 3, 3))
    C = H_cp.reshape(len(H_cc), n_points, 3)
    schur = H_cc - np.einsum("cpk,pkm,dpm->cd", C, inv, C)
    scale = np.zeros(len(schur))                                                  # the free scale: every t grows
    scale[:width] = np.column_stack([np.zeros((n_cams, 3)), cams.reshape(n_cams, 6)[:, 3:]]).ravel()
    basis = np.linalg.svd(np.eye(len(schur)) - np.outer(scale, scale) / max(scale @ scale, 1e-300))[0][:, :-1]
    reduced = basis.T @ schur @ basis
    cov = variance * (basis @ np.linalg.pinv(reduced, hermitian=True) @ basis.T)[:width, :width]
    sd = np.zeros(n_cams)
    for v in range(n_cams):
        rvec, tv = cams[6 * v:6 * v + 3], cams[6 * v + 3:6 * v + 6]
        G = _centre_jacobian(rvec, tv)                                            # (3, 6)
        sd[v] = np.sqrt(max(np.trace(G @ cov[6 * v:6 * v + 6, 6 * v:6 * v + 6] @ G.T), 0.0))
    return sd


def _centre_jacobian(rvec: np.ndarray, t: np.ndarray, step: float = 1e-6) -> np.ndarray:
    """``(3, 6)`` derivative of ``-R(rvec)^T t`` by ``(rvec, t)`` (central differences)."""
    def centre(p):
        return -_rotation_matrices(p[:3]).T @ p[3:]

    p0 = np.concatenate([rvec, t])
    G = np.zeros((3, 6))
    for k in range(6):
        d = np.zeros(6)
        d[k] = step
        G[:, k] = (centre(p0 + d) - centre(p0 - d)) / (2 * step)
    return G


def reprojection_px(cameras: Cameras, pixels: np.ndarray, present: np.ndarray, camera: np.ndarray, obj: np.ndarray,
                    X: np.ndarray) -> np.ndarray:
    """``(N, J)`` reprojection error (px) of every present point of an object (NaN otherwise):
    the arguments of :func:`bundle_adjust`, ``cameras`` (an :class:`Adjusted`'s) and ``X: (Q, J, 3)``;
    the distance in the normalized coordinates of each camera's ``K``, times its mean focal length."""
    x = _normalized(cameras, pixels, camera)
    xy, _ = project(X[np.maximum(obj, 0)], projection_matrix(np.eye(3), cameras.R, cameras.t)[camera])   # (N, J, 2)
    err = np.linalg.norm(xy - x, axis=-1) * cameras.focal[camera][:, None]
    return np.where(present & (obj >= 0)[:, None] & np.isfinite(err), err, np.nan)
