"""The 3DPW data set (von Marcard et al., ECCV 2018) as the paper evaluates on it (Table 3).

The published layout: ``ROOT/sequenceFiles/{train,validation,test}/<clip>.pkl`` (Python 2
pickles) and ``ROOT/imageFiles/<clip>/image_%05d.jpg``. A clip's pickle is a dict whose
per-actor fields are lists with one entry per tracked person:

- ``sequence``: the clip name; ``img_frame_ids``: ``(N,)`` image index of each of the N frames;
- ``jointPositions``: ``[(N, 72)]`` the 24 SMPL joints in world coordinates [m];
- ``poses2d``: ``[(N, 3, 18)]`` x, y, confidence of the 18 OpenPose/COCO-18 joints (0: not visible);
- ``cam_poses``: ``(N, 4, 4)`` world-to-camera transform of each frame;
- ``campose_valid``: ``[(N,)]`` whether the camera pose of each frame is aligned for that person;
- ``cam_intrinsics``: ``(3, 3)``.

The evaluation uses the 14 joints common to COCO and SMPL (``COMMON14_NAMES``: the 12 limb
joints, the neck, the head) in the camera frame.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mvm.errors import InputError
from mvm.io.paths import name_problem
from mvm.io.safe_pickle import load_pickle

#: SMPL joint of each of the 14 common joints (``COMMON14_NAMES`` order): shoulders 16/17,
#: elbows 18/19, wrists 20/21, hips 1/2, knees 4/5, ankles 7/8, neck 12, head 15.
SMPL_TO_COMMON14 = (16, 17, 18, 19, 20, 21, 1, 2, 4, 5, 7, 8, 12, 15)
#: OpenPose COCO-18 joint (0 nose, 1 neck, 2-4 right arm, 5-7 left arm, 8-10 right leg,
#: 11-13 left leg) of each of the 14 common joints; the nose stands for the head.
COCO18_TO_COMMON14 = (5, 2, 6, 3, 7, 4, 11, 8, 12, 9, 13, 10, 1, 0)
SPLITS = ("train", "validation", "test")


@dataclass(frozen=True)
class ThreeDPWPoses:
    """Every (frame, person) of some 3DPW clips with an aligned camera pose; ``N`` rows.

    Attributes:
        clip: ``(N,)`` clip name; track: ``(N,)`` person index within the clip;
        frame: ``(N,)`` image index (``image_%05d.jpg``); images: the ``N`` image paths;
        joints3d: ``(N, 14, 3)`` ground truth in the camera frame [m];
        joints2d: ``(N, 14, 3)`` x, y [px] and confidence (0: not visible);
        intrinsics: ``(N, 3, 3)``.
    """

    clip: np.ndarray
    track: np.ndarray
    frame: np.ndarray
    images: tuple[Path, ...]
    joints3d: np.ndarray
    joints2d: np.ndarray
    intrinsics: np.ndarray

    def __len__(self) -> int:
        return len(self.clip)

    @property
    def visible(self) -> np.ndarray:
        """``(N, 14)`` whether each joint is visible in the image."""
        return self.joints2d[..., 2] > 0


#: The largest image index a clip may name (``image_%05d.jpg``; a clip is minutes at 30 fps).
MAX_FRAME_ID = 10 ** 9


def _field(doc: dict, name: str, path: Path):
    if name not in doc:
        raise InputError(path, name, "missing (not a 3DPW sequence file)")
    return doc[name]


def _numbers(value, path: Path, name: str, dtype=float) -> np.ndarray:
    """``value`` as a finite float (or integer) array; text, objects and non-finite numbers
    raise InputError naming the field."""
    try:
        a = np.asarray(value)
        if a.dtype.kind not in "biuf":
            raise TypeError(f"{a.dtype}")
        a = a.astype(float)
    except (TypeError, ValueError, OverflowError):
        raise InputError(path, name, "expected numbers") from None
    if not np.isfinite(a).all():
        raise InputError(path, name, "not finite (NaN or infinite values)")
    if dtype is int:
        if (a != np.round(a)).any() or (a < 0).any() or (a > MAX_FRAME_ID).any():
            raise InputError(path, name, f"expected image indices (integers from 0 to {MAX_FRAME_ID})")
        return a.astype(np.int64)
    return a


def _array(value, shape_tail: tuple, path: Path, name: str) -> np.ndarray:
    a = _numbers(value, path, name)
    if a.ndim != len(shape_tail) + 1 or a.shape[1:] != shape_tail:
        raise InputError(path, name, f"expected shape (N, {', '.join(map(str, shape_tail))}), got {a.shape}")
    return a


def _persons(doc: dict, name: str, path: Path) -> list:
    value = _field(doc, name, path)
    if not isinstance(value, (list, tuple, np.ndarray)):
        raise InputError(path, name, f"expected one entry per person, got {type(value).__name__}")
    return list(value)


def read_sequence(path: str | Path, images_dir: str | Path | None = None) -> ThreeDPWPoses:
    """Read one clip's ``.pkl``; images are looked for in ``images_dir`` (default:
    ``ROOT/imageFiles/<clip>`` of the published layout). The pickle is read by
    :func:`mvm.io.safe_pickle.load_pickle` (numpy arrays and plain containers only, no code)."""
    path = Path(path)
    doc = load_pickle(path, encoding="latin1")
    if not isinstance(doc, dict):
        raise InputError(path, None, f"expected a dict, got {type(doc).__name__}")
    name = _field(doc, "sequence", path)
    if not isinstance(name, str) or name_problem(name) or "/" in name or "\\" in name:
        raise InputError(path, "sequence", f"expected a clip name (one folder name), got {str(name)[:40]!r}")
    frames = _numbers(_field(doc, "img_frame_ids", path), path, "img_frame_ids", dtype=int).reshape(-1)
    cam = _array(_field(doc, "cam_poses", path), (4, 4), path, "cam_poses")
    K = _numbers(_field(doc, "cam_intrinsics", path), path, "cam_intrinsics")
    if K.shape != (3, 3):
        raise InputError(path, "cam_intrinsics", f"expected shape (3, 3), got {K.shape}")
    joints, poses2d, valid = (_persons(doc, k, path) for k in ("jointPositions", "poses2d", "campose_valid"))
    if not (len(joints) == len(poses2d) == len(valid)):
        raise InputError(path, "jointPositions", "jointPositions, poses2d and campose_valid differ in persons")
    n = len(frames)
    if len(cam) != n:
        raise InputError(path, "cam_poses", f"expected {n} poses (one per img_frame_ids), got {len(cam)}")
    if images_dir is None:
        images_dir = path.parent.parent.parent / "imageFiles" / name
    rows = []
    for p in range(len(joints)):
        X = _array(joints[p], (72,), path, f"jointPositions[{p}]").reshape(-1, 24, 3)
        x2 = _array(poses2d[p], (3, 18), path, f"poses2d[{p}]").transpose(0, 2, 1)
        ok = _numbers(valid[p], path, f"campose_valid[{p}]").astype(bool).reshape(-1)
        if not (len(X) == len(x2) == len(ok) == n):
            raise InputError(path, f"jointPositions[{p}]", f"expected {n} frames in every per-person field")
        Xc = np.einsum("nij,nkj->nki", cam[:, :3, :3], X[:, SMPL_TO_COMMON14]) + cam[:, None, :3, 3]
        rows.append((np.nonzero(ok)[0], p, Xc[ok], x2[ok][:, COCO18_TO_COMMON14]))
    keep = [r[0] for r in rows]
    count = sum(len(k) for k in keep)
    frame = np.concatenate(keep + [np.zeros(0, int)])
    return ThreeDPWPoses(
        clip=np.full(count, name, dtype=object),
        track=np.concatenate([np.full(len(r[0]), r[1]) for r in rows] + [np.zeros(0, int)]),
        frame=frames[frame],
        images=tuple(Path(images_dir) / f"image_{i:05d}.jpg" for i in frames[frame]),
        joints3d=np.concatenate([r[2] for r in rows] + [np.zeros((0, 14, 3))]),
        joints2d=np.concatenate([r[3] for r in rows] + [np.zeros((0, 14, 3))]),
        intrinsics=np.broadcast_to(K, (count, 3, 3)).copy(),
    )


def read_3dpw(root: str | Path, split: str = "test") -> ThreeDPWPoses:
    """Every clip of ``split`` under the data set's ``root`` (``sequenceFiles/``, ``imageFiles/``)."""
    if split not in SPLITS:
        raise InputError(None, "split", f"expected one of {', '.join(SPLITS)}, got {split!r}")
    folder = Path(root) / "sequenceFiles" / split
    files = sorted(folder.glob("*.pkl"))
    if not files:
        raise InputError(folder, None, "no .pkl sequence files (expected the published 3DPW layout)")
    parts = [read_sequence(f) for f in files]
    return ThreeDPWPoses(
        clip=np.concatenate([p.clip for p in parts]), track=np.concatenate([p.track for p in parts]),
        frame=np.concatenate([p.frame for p in parts]), images=sum((p.images for p in parts), ()),
        joints3d=np.concatenate([p.joints3d for p in parts]), joints2d=np.concatenate([p.joints2d for p in parts]),
        intrinsics=np.concatenate([p.intrinsics for p in parts]))
