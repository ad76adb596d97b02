"""Bundle adjustment of a rig's cameras and the points they see (no I/O): every camera but the
reference (rotation vector, translation) and every point (the people's joints, or a calibration
board's corners: an object of ``J`` points seen at once), reprojection errors in
pixels, ``scipy.optimize.least_squares`` with an explicit Jacobian sparsity, ``x_scale='jac'``
and a soft-L1 loss (as aniposelib's ``bundle_adjust``)."""
from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import coo_matrix
from scipy.spatial.transform import Rotation

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


def bundle_adjust(x: np.ndarray, present: np.ndarray, camera: np.ndarray, person: np.ndarray, focal: np.ndarray,
                  R: np.ndarray, t: np.ndarray, X: np.ndarray, refine_focal: bool = False
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool]:
    """Sparse bundle adjustment (module docstring, step 3). Camera 0 stays fixed.

    Args:
        x: ``(N, J, 2)`` normalized points (a person's ``J = 17`` joints, a board's corners) of
            ``N`` views of objects; present: ``(N, J)``; camera, person: ``(N,)`` (person: the
            object, -1: none); focal: ``(V,)`` px, the focal lengths ``x`` was normalized with;
            R, t: ``(V, 3, 3)``, ``(V, 3)`` initial cameras; X: ``(Q, J, 3)`` the objects' points.
        refine_focal: adjust every camera's focal length too (its principal point and aspect
            ratio stay).
    Returns:
        ``(R, t, X, focal (V,) px, converged)``.
    """
    V, J = len(R), x.shape[1]
    use = present & (person >= 0)[:, None] & np.isfinite(X[np.maximum(person, 0)]).all(-1)
    pose, joint = np.nonzero(use)
    cam, point = camera[pose], person[pose] * J + joint
    points_used, point_index = np.unique(point, return_inverse=True)
    obs = x[pose, joint]
    P = len(points_used)
    X0 = X.reshape(-1, 3)[points_used]
    rvec0 = Rotation.from_matrix(R[1:]).as_rotvec()
    params0 = np.concatenate([np.column_stack([rvec0, t[1:]]).ravel(), X0.ravel()] + ([np.ones(V)] if refine_focal
                                                                                        else []))
    f = focal[cam]
    end = 6 * (V - 1) + 3 * P

    def residuals(params):
        cams = params[:6 * (V - 1)].reshape(V - 1, 6)
        Rs = np.concatenate([R[:1], _rotation_matrices(cams[:, :3])])
        ts = np.concatenate([t[:1], cams[:, 3:]])
        pts = params[6 * (V - 1):end].reshape(P, 3)
        pc = np.einsum("nij,nj->ni", Rs[cam], pts[point_index]) + ts[cam]
        z = np.where(np.abs(pc[:, 2]) > 1e-9, pc[:, 2], 1e-9)
        scale = params[end:][cam, None] if refine_focal else 1.0
        return ((scale * pc[:, :2] / z[:, None] - obs) * f[:, None]).ravel()

    sparsity = jacobian_sparsity(cam, point_index, V, P, refine_focal)
    result = least_squares(residuals, params0, jac_sparsity=sparsity, x_scale="jac", loss="soft_l1",
                           f_scale=LOSS_SCALE_PX, method="trf", max_nfev=200)
    cams = result.x[:6 * (V - 1)].reshape(V - 1, 6)
    R = np.concatenate([R[:1], _rotation_matrices(cams[:, :3])])
    t = np.concatenate([t[:1], cams[:, 3:]])
    Xout = np.full((len(X) * J, 3), np.nan)
    Xout[points_used] = result.x[6 * (V - 1):end].reshape(P, 3)
    focal_out = focal * result.x[end:] if refine_focal else focal.copy()
    return R, t, Xout.reshape(X.shape), focal_out, bool(result.status > 0)


def reprojection_px(x: np.ndarray, present: np.ndarray, camera: np.ndarray, person: np.ndarray, focal: np.ndarray,
                    R: np.ndarray, t: np.ndarray, X: np.ndarray, refined: np.ndarray | None = None) -> np.ndarray:
    """``(N, J)`` reprojection error (px) of every point of an object (NaN otherwise); the
    arguments of :func:`bundle_adjust` (``refined``: its focal lengths, when it adjusted them)."""
    Xp = X[np.maximum(person, 0)]                                                 # (N, J, 3)
    pc = np.einsum("nij,nkj->nki", R[camera], Xp) + t[camera][:, None]
    scale = (refined / focal)[camera][:, None, None] if refined is not None else 1.0
    err = np.linalg.norm(scale * pc[..., :2] / pc[..., 2:] - x, axis=-1) * focal[camera][:, None]
    return np.where(present & (person >= 0)[:, None] & np.isfinite(err), err, np.nan)
