"""Synthetic images of people: shaded capsules with a depth buffer over textured backgrounds.

Used by the learning test and the CPU demonstration. The people are random standing poses
(arms and legs at random angles) placed on a floor in front of a pinhole camera; every body
part is a capsule (a sphere for the head) lit by a flash at the camera (Lambertian, falling
off with the squared distance, over some ambient light), and a per-pixel depth buffer resolves
occlusions, so that images carry the cues a network can learn depth from: occlusion,
foreshortening and brightness along the limbs. Left limbs are tinted differently from right limbs, and the
head shows a face in front and darker hair behind, so the way a person faces (and so which
joints are nearer) can be seen.

``synthetic_dataset`` writes images and a COCO file with the supervision fields of
:mod:`mvm.net.supervision` (relative depths), exactly as ``mvm export`` does for real scenes.
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from mvm.core.camera import project_camera, project_persons
from mvm.core.keypoints import INDEX, NUM_JOINTS
from mvm.io.coco import annotation_record, empty_dataset
from mvm.io.files import atomic_write_json

LOG = logging.getLogger(__name__)

#: Joint positions of the standing template (person frame: x to the person's left, y up,
#: z forward), metres, for a person 1.7 m tall.
_TEMPLATE = {
    "nose": (0.0, 1.60, 0.10), "left_eye": (0.035, 1.65, 0.08), "right_eye": (-0.035, 1.65, 0.08),
    "left_ear": (0.075, 1.62, 0.0), "right_ear": (-0.075, 1.62, 0.0),
    "left_shoulder": (0.19, 1.42, 0.0), "right_shoulder": (-0.19, 1.42, 0.0),
    "left_hip": (0.10, 0.95, 0.0), "right_hip": (-0.10, 0.95, 0.0),
}
#: (parent, child, length m) of the limbs, posed by random angles.
_LIMBS = (("left_shoulder", "left_elbow", 0.29), ("left_elbow", "left_wrist", 0.25),
          ("right_shoulder", "right_elbow", 0.29), ("right_elbow", "right_wrist", 0.25),
          ("left_hip", "left_knee", 0.42), ("left_knee", "left_ankle", 0.41),
          ("right_hip", "right_knee", 0.42), ("right_knee", "right_ankle", 0.41))

#: Capsules (joint a, joint b, radius m, part) drawn for a person; a == b is a sphere.
#: Parts: 0 head, 1 torso, 2 left arm, 3 right arm, 4 left leg, 5 right leg.
_I = INDEX
CAPSULES = (
    (_I["left_shoulder"], _I["right_hip"], 0.11, 1), (_I["right_shoulder"], _I["left_hip"], 0.11, 1),
    (_I["left_shoulder"], _I["right_shoulder"], 0.06, 1), (_I["left_hip"], _I["right_hip"], 0.08, 1),
    (_I["left_shoulder"], _I["left_elbow"], 0.05, 2), (_I["left_elbow"], _I["left_wrist"], 0.04, 2),
    (_I["right_shoulder"], _I["right_elbow"], 0.05, 3), (_I["right_elbow"], _I["right_wrist"], 0.04, 3),
    (_I["left_hip"], _I["left_knee"], 0.075, 4), (_I["left_knee"], _I["left_ankle"], 0.055, 4),
    (_I["right_hip"], _I["right_knee"], 0.075, 5), (_I["right_knee"], _I["right_ankle"], 0.055, 5),
)
HEAD_RADIUS = 0.11
#: Hair colour relative to the face, and the cosine between the surface normal of the head
#: and the facing direction (nose − head centre) below which the head shows hair.
HAIR_SHADE = 0.3
#: Lighting: the share of ambient light, and the distance at which the flash at the camera
#: lights a surface facing it fully (brightness ∝ (FLASH_DISTANCE / z)², at most 1.6). [1], [m]
AMBIENT = 0.3
FLASH_DISTANCE = 2.2
HAIR_BELOW = -0.2


def random_poses(rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` random standing poses in the person frame (y up, feet near y = 0): ``(n, 17, 3)`` metres."""
    out = np.zeros((n, NUM_JOINTS, 3))
    for name, xyz in _TEMPLATE.items():
        out[:, INDEX[name]] = xyz
    # limb directions: angles away from straight down; arms move much more than legs
    for k, (parent, child, length) in enumerate(_LIMBS):
        arm = k < 4
        side = 1.0 if parent.startswith("left") else -1.0
        upper = k % 2 == 0
        if arm:
            swing = rng.uniform(-1.2, 2.2 if upper else 2.6, n)          # forward (+) / back (-)
            spread = rng.uniform(0.0, 1.6 if upper else 1.2, n) * side  # outward
        else:
            swing = rng.uniform(-0.4, 0.9, n) if upper else rng.uniform(-1.0, 0.1, n)
            spread = rng.uniform(-0.1, 0.35, n) * side
        d = np.stack([np.sin(spread) * np.cos(swing), -np.cos(spread) * np.cos(swing), np.sin(swing)], -1)
        out[:, INDEX[child]] = out[:, INDEX[parent]] + length * d
    # lift so that the lowest ankle touches the floor, scale and turn about the vertical
    out[:, :, 1] -= np.minimum(out[:, INDEX["left_ankle"], 1], out[:, INDEX["right_ankle"], 1])[:, None] - 0.05
    out *= rng.uniform(0.85, 1.1, (n, 1, 1))
    yaw = rng.uniform(-np.pi, np.pi, n)
    c, s = np.cos(yaw), np.sin(yaw)
    Ry = np.zeros((n, 3, 3))
    Ry[:, 0, 0], Ry[:, 0, 2], Ry[:, 1, 1], Ry[:, 2, 0], Ry[:, 2, 2] = c, s, 1.0, -s, c
    return np.einsum("nij,nkj->nki", Ry, out)


def random_scene(rng: np.random.Generator, n_persons: int, size: tuple[int, int], fov_deg: float = 60.0,
                 distance: tuple[float, float] = (2.5, 6.0),
                 camera_height: tuple[float, float] = (1.3, 1.7)) -> tuple[np.ndarray, np.ndarray]:
    """People on a floor at ``distance`` metres in front of a level camera ``camera_height`` metres high.

    Returns the joints in camera coordinates ``(P, 17, 3)`` (x right, y down, z forward) and
    the intrinsics ``K (3, 3)`` of a ``size = (width, height)`` image.
    """
    w, h = size
    f = 0.5 * w / np.tan(np.radians(fov_deg) / 2)
    K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])
    people = random_poses(rng, n_persons)
    z = rng.uniform(*distance, n_persons)
    half = np.tan(np.radians(fov_deg) / 2) * z * 0.8
    x = rng.uniform(-half, half)
    cam_h = rng.uniform(*camera_height)
    cam = np.empty_like(people)
    cam[..., 0] = people[..., 0] + x[:, None]
    cam[..., 1] = cam_h - people[..., 1]
    cam[..., 2] = people[..., 2] + z[:, None]
    return cam, K


def background(rng: np.random.Generator, size: tuple[int, int]) -> np.ndarray:
    """A random texture: smooth colour noise, stripes and blobs. -> ``(H, W, 3)`` float in [0, 1]."""
    import cv2

    w, h = size
    g = int(rng.integers(2, 8))
    img = cv2.resize(rng.uniform(0.1, 0.9, (g, g, 3)), (w, h), interpolation=cv2.INTER_CUBIC)
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    theta, freq = rng.uniform(0, np.pi), rng.uniform(0.05, 0.4)
    stripes = 0.5 + 0.5 * np.sin(freq * (np.cos(theta) * xx + np.sin(theta) * yy) + rng.uniform(0, 6.3))
    img = img + rng.uniform(0.0, 0.25) * (stripes[..., None] - 0.5) * rng.uniform(0.3, 1.0, 3)
    for _ in range(int(rng.integers(0, 5))):
        cx, cy, r = rng.uniform(0, w), rng.uniform(0, h), rng.uniform(0.03, 0.2) * w
        mask = ((xx - cx) ** 2 + (yy - cy) ** 2) < r ** 2
        img[mask] = 0.6 * img[mask] + 0.4 * rng.uniform(0, 1, 3)
    img += rng.normal(0, 0.03, img.shape)
    return np.clip(img, 0, 1)


def render(people: np.ndarray, K: np.ndarray, size: tuple[int, int], rng: np.random.Generator,
           colors: np.ndarray | None = None) -> np.ndarray:
    """Render people as shaded capsules with a depth buffer.

    Args:
        people: ``(P, 17, 3)`` joints in camera coordinates (metres, z forward).
        K: ``(3, 3)`` intrinsics; size: ``(width, height)``.
        colors: ``(P, 6, 3)`` RGB in [0, 1] per body part (random when None).
    Returns:
        ``(H, W, 3)`` uint8 RGB image.
    """
    w, h = size
    P = len(people)
    img = background(rng, size)
    if P == 0:
        return (img * 255).round().astype(np.uint8)
    if colors is None:
        colors = rng.uniform(0.15, 0.95, (P, 6, 3))
        colors[:, 0] = rng.uniform(0.5, 0.9, (P, 1)) * np.array([1.0, 0.8, 0.65])  # skin-like heads
        colors[:, 2] = colors[:, 3] * 0.55 + 0.45 * np.array([0.9, 0.9, 0.2])        # left side tinted
        colors[:, 4] = colors[:, 5] * 0.55 + 0.45 * np.array([0.9, 0.9, 0.2])
    a = np.array([c[0] for c in CAPSULES])
    b = np.array([c[1] for c in CAPSULES])
    radius = np.array([c[2] for c in CAPSULES])
    part = np.array([c[3] for c in CAPSULES])
    head = 0.5 * (people[:, INDEX["left_ear"]] + people[:, INDEX["right_ear"]])      # (P, 3)
    A = np.concatenate([people[:, a], head[:, None]], 1).reshape(-1, 3)             # (P*(n+1), 3)
    B = np.concatenate([people[:, b], head[:, None]], 1).reshape(-1, 3)
    R = np.tile(np.append(radius, HEAD_RADIUS), P)
    col = np.concatenate([colors[:, part], colors[:, 0:1]], 1).reshape(-1, 3)
    n_seg = len(CAPSULES) + 1
    is_head = np.tile(np.arange(n_seg) == n_seg - 1, P)
    facing = people[:, INDEX["nose"]] - head                                           # (P, 3)
    facing = np.repeat(facing / np.maximum(np.linalg.norm(facing, axis=-1, keepdims=True), 1e-9), n_seg, 0)
    hair = np.repeat(colors[:, 0] * HAIR_SHADE, n_seg, 0)
    front = (A[:, 2] > 0.1) & (B[:, 2] > 0.1)
    A, B, R, col = A[front], B[front], R[front], col[front]
    is_head, facing, hair = is_head[front], facing[front], hair[front]
    f = 0.5 * (K[0, 0] + K[1, 1])
    ua, ub = (project_camera(points, K, np.eye(3), np.zeros(3))[0] for points in (A, B))      # camera frame -> px
    ra, rb = f * R / A[:, 2], f * R / B[:, 2]                                         # (S,) px
    yy, xx = np.mgrid[0:h, 0:w]
    q = np.stack([xx.reshape(-1), yy.reshape(-1)], -1).astype(float)                 # (HW, 2)
    ab = ub - ua
    L2 = np.maximum((ab ** 2).sum(-1), 1e-9)
    t = np.clip(((q[None] - ua[:, None]) * ab[:, None]).sum(-1) / L2[:, None], 0, 1)  # (S, HW)
    dist = np.linalg.norm(q[None] - (ua[:, None] + t[..., None] * ab[:, None]), axis=-1)
    r = ra[:, None] + t * (rb - ra)[:, None]
    inside = dist < r
    cosn = np.sqrt(np.clip(1 - (dist / np.maximum(r, 1e-9)) ** 2, 0, 1))               # facing the camera
    z = A[:, 2, None] + t * (B[:, 2] - A[:, 2])[:, None] - R[:, None] * cosn
    z = np.where(inside, z, np.inf)
    best = np.argmin(z, axis=0)                                                       # (HW,)
    hit = np.isfinite(z[best, np.arange(len(q))])
    zb = z[best, np.arange(len(q))]
    falloff = np.minimum((FLASH_DISTANCE / np.where(hit, zb, FLASH_DISTANCE)) ** 2, 1.6)
    shade = AMBIENT + (1 - AMBIENT) * cosn[best, np.arange(len(q))] * falloff
    # the head: hair where the sphere's surface normal turns away from the face
    pix = np.arange(len(q))
    on_head = hit & is_head[best]
    normal = np.concatenate([(q - ua[best]) / np.maximum(r[best, pix], 1e-9)[:, None],
                             -cosn[best, pix][:, None]], -1)                     # (HW, 3) camera frame
    is_hair = on_head & ((normal * facing[best]).sum(-1) < HAIR_BELOW)
    base = np.where(is_hair[:, None], hair[best], col[best])
    person = (base * shade[:, None]).reshape(h, w, 3)
    img = np.where(hit.reshape(h, w, 1), np.clip(person, 0, 1), img)
    return (img * 255).round().astype(np.uint8)


def synthetic_dataset(out_dir: str | Path, n_images: int, size: tuple[int, int] = (128, 128),
                      persons: tuple[int, int] = (1, 3), seed: int = 0, min_keypoints: int = 5,
                      distance: tuple[float, float] = (2.5, 6.0),
                      camera_height: tuple[float, float] = (1.3, 1.7)) -> Path:
    """Render ``n_images`` images with 3D supervision into ``out_dir``; returns the COCO file.

    Writes ``out_dir/images/NNNNNN.png`` and ``out_dir/annotations.json`` (the format of
    :func:`mvm.net.supervision.export_supervision`: keypoints, ``keypoint_depths``, ``has_3d``).
    """
    import cv2

    out_dir = Path(out_dir)
    (out_dir / "images").mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    data = empty_dataset("mvm synthetic renders of capsule people")
    ann_id = 0
    for i in range(n_images):
        n = int(rng.integers(persons[0], persons[1] + 1))
        people, K = random_scene(rng, n, size, distance=distance, camera_height=camera_height)
        image = render(people, K, size, rng)
        name = f"images/{i:06d}.png"
        cv2.imwrite(str(out_dir / name), image[:, :, ::-1])
        data["images"].append({"id": i + 1, "file_name": name, "width": size[0], "height": size[1]})
        kp, dep = project_persons(people, K, np.eye(3), np.zeros(3), size)
        for p in np.nonzero((kp[:, :, 2] > 0).sum(1) >= min_keypoints)[0]:
            ann_id += 1
            data["annotations"].append(annotation_record(ann_id, i + 1, kp[p], dep[p], person_id=int(p)))
    path = out_dir / "annotations.json"
    atomic_write_json(path, data)
    LOG.info("rendered %d images with %d people into %s", n_images, ann_id, out_dir)
    return path


#: The scenes of the CPU demonstration (``configs/train_cpu_tiny.toml``, the learning test and
#: ``benchmarks/train_synthetic.py``): one or two people 1.7–2.8 m from a camera at hip to
#: chest height, so that at 96 px a person is 45–85 px tall (6–10 cells at stride 8).
DEMO_SCENES = {"persons": (1, 2), "distance": (1.7, 2.8), "camera_height": (0.85, 1.15)}


def demo_datasets(root: str | Path, train_images: int, val_images: int, size: int = 96,
                  seed: int = 0) -> tuple[Path, Path]:
    """Render the training and held-out sets of the CPU demonstration into ``root/train`` and
    ``root/val`` (independent random streams); returns their COCO files."""
    root = Path(root)
    train = synthetic_dataset(root / "train", train_images, (size, size), seed=seed, **DEMO_SCENES)
    val = synthetic_dataset(root / "val", val_images, (size, size), seed=seed + 1_000_003, **DEMO_SCENES)
    return train, val
