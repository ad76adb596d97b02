"""The data model: cameras of every frame, the 2D poses of every frame, and a scene.

A *scene* is one static multi-person scene seen from ``V`` views (frames of a moving
camera, or the cameras of a rig at one instant). Arrays use these axes:

- ``V`` views (frames), ``N`` 2D poses (annotations), ``J = 17`` COCO keypoints,
- ``P`` reconstructed persons.

Keypoint coordinates are *undistorted* pixel coordinates of each view's pinhole camera
``K``; readers undo lens distortion once, so that every piece of geometry is linear.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mvm.core.camera import projection_matrix
from mvm.core.keypoints import NUM_JOINTS


@dataclass(frozen=True)
class Cameras:
    """Cameras of ``V`` views, world -> camera ``x_cam = R @ X + t``: intrinsics, extrinsics and
    the lens (OpenCV's model; projection and undistortion in :mod:`mvm.core.camera`).

    Attributes:
        K: ``(V, 3, 3)`` intrinsics (pixels).
        R: ``(V, 3, 3)`` rotations, world -> camera.
        t: ``(V, 3)`` translations (world units).
        size: ``(V, 2)`` image width and height in pixels.
        names: ``V`` image names (COLMAP ``NAME``, COCO ``file_name``).
        distortion: ``V`` arrays of OpenCV lens coefficients (:mod:`mvm.core.camera`; empty: no
            lens); default none. A scene's keypoints are pixels of the pinhole ``K`` whatever
            the lens: readers undo it once.
        fisheye: ``(V,)`` bool, OpenCV's fisheye lens model; default all False.
    """

    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    size: np.ndarray
    names: tuple[str, ...]
    distortion: tuple[np.ndarray, ...] = ()
    fisheye: np.ndarray | None = None

    def __post_init__(self):
        V = len(self.names)
        for name, shape in (("K", (V, 3, 3)), ("R", (V, 3, 3)), ("t", (V, 3)), ("size", (V, 2))):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.shape != shape:
                raise ValueError(f"Cameras.{name}: expected shape {shape}, got {value.shape}")
            object.__setattr__(self, name, value)
        lens = tuple(np.asarray(d, dtype=float).reshape(-1) for d in self.distortion) or (np.zeros(0),) * V
        fisheye = np.zeros(V, bool) if self.fisheye is None else np.asarray(self.fisheye, dtype=bool).reshape(-1)
        if len(lens) != V or len(fisheye) != V:
            raise ValueError(f"Cameras: expected {V} lenses, got {len(lens)} distortions, {len(fisheye)} fisheye flags")
        object.__setattr__(self, "distortion", lens)
        object.__setattr__(self, "fisheye", fisheye)

    def __len__(self) -> int:
        return len(self.names)

    @property
    def P(self) -> np.ndarray:
        """Projection matrices ``K [R | t]``: ``(V, 3, 4)``."""
        return projection_matrix(self.K, self.R, self.t)

    @property
    def centers(self) -> np.ndarray:
        """Camera centres in the world ``C = -R^T t``: ``(V, 3)``."""
        return -np.einsum("vji,vj->vi", self.R, self.t)

    @property
    def focal(self) -> np.ndarray:
        """Mean focal length in pixels: ``(V,)``."""
        return 0.5 * (self.K[:, 0, 0] + self.K[:, 1, 1])

    def subset(self, index: np.ndarray) -> Cameras:
        index = np.asarray(index)
        return Cameras(self.K[index], self.R[index], self.t[index], self.size[index],
                       tuple(self.names[i] for i in index), tuple(self.distortion[i] for i in index),
                       self.fisheye[index])


@dataclass(frozen=True)
class Poses2D:
    """``N`` 2D poses (COCO annotations) over the views of a scene.

    Attributes:
        keypoints: ``(N, 17, 3)`` x, y (undistorted pixels) and confidence v in [0, 1];
            a missing joint has v = 0.
        view: ``(N,)`` index of the view (into ``Cameras``) each pose was detected in.
        ids: ``(N,)`` annotation ids as in ``poses2d.json``.
        score: ``(N,)`` pose confidence w in [0, 1].
        appearance: ``(N, D)`` appearance descriptors, or ``None`` when absent.
        instant: ``(N,)`` time instant of each pose, or ``None`` for one static scene. With a
            synchronized rig every instant is a scene of its own whose views are the cameras:
            poses of different instants are never matched together.
    """

    keypoints: np.ndarray
    view: np.ndarray
    ids: np.ndarray
    score: np.ndarray
    appearance: np.ndarray | None = None
    instant: np.ndarray | None = None

    def __post_init__(self):
        kp = np.asarray(self.keypoints, dtype=float).reshape(-1, NUM_JOINTS, 3)
        N = len(kp)
        object.__setattr__(self, "keypoints", kp)
        for name, dtype in (("view", np.int64), ("ids", np.int64), ("score", float)):
            value = np.asarray(getattr(self, name), dtype=dtype).reshape(-1)
            if len(value) != N:
                raise ValueError(f"Poses2D.{name}: expected {N} entries, got {len(value)}")
            object.__setattr__(self, name, value)
        if self.appearance is not None:
            app = np.asarray(self.appearance, dtype=float)
            if app.ndim != 2 or len(app) != N:
                raise ValueError(f"Poses2D.appearance: expected shape ({N}, D), got {app.shape}")
            object.__setattr__(self, "appearance", app)
        if self.instant is not None:
            instant = np.asarray(self.instant, dtype=np.int64).reshape(-1)
            if len(instant) != N:
                raise ValueError(f"Poses2D.instant: expected {N} entries, got {len(instant)}")
            object.__setattr__(self, "instant", instant)

    def __len__(self) -> int:
        return len(self.keypoints)

    def subset(self, index: np.ndarray) -> Poses2D:
        index = np.asarray(index)
        app = None if self.appearance is None else self.appearance[index]
        instant = None if self.instant is None else self.instant[index]
        return Poses2D(self.keypoints[index], self.view[index], self.ids[index],
                       self.score[index], app, instant)

    def blocks(self) -> list[np.ndarray]:
        """Pose indices of each independent block: one block of every pose for a scene, one
        per instant (in increasing order) for a rig. Matching never crosses blocks."""
        if self.instant is None:
            return [np.arange(len(self))]
        order = np.argsort(self.instant, kind="stable")
        bounds = np.flatnonzero(np.diff(self.instant[order])) + 1
        return np.split(order, bounds) if len(order) else []


@dataclass(frozen=True)
class Scene:
    """A static scene: cameras of its views and the 2D poses detected in them.

    Attributes:
        name: a label (the scene directory's name).
        cameras: the ``V`` views.
        poses: the ``N`` 2D poses, ``poses.view`` indexing ``cameras``.
        points3d: ``(M, 3)`` sparse SfM points (may be empty).
    """

    name: str
    cameras: Cameras
    poses: Poses2D
    points3d: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))


@dataclass
class Persons3D:
    """``P`` reconstructed persons.

    Attributes:
        keypoints3d: ``(P, 17, 3)`` world coordinates; NaN where a joint was not reconstructed.
        scores: ``(P, 17)`` per-joint confidence (mean confidence of the inlier 2D keypoints).
        members: ``P`` integer arrays: indices into ``Poses2D`` of each person's 2D poses.
        views_per_joint: ``(P, 17)`` inlier 2D keypoints used per joint.
        outliers_per_joint: ``(P, 17)`` 2D keypoints RANSAC rejected per joint.
        reprojection_error_px: ``(P,)`` mean reprojection error over the inlier keypoints.
        flags: ``(P, 17)`` how each joint was obtained (:mod:`mvm.core.completion`: observed,
            interpolated, inferred, missing); None: observed wherever ``keypoints3d`` is finite.
    """

    keypoints3d: np.ndarray
    scores: np.ndarray
    members: list[np.ndarray]
    views_per_joint: np.ndarray
    outliers_per_joint: np.ndarray
    reprojection_error_px: np.ndarray
    flags: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.keypoints3d)
