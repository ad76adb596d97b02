"""Rebuild the pose bank and the GMM pose prior shipped in ``src/mvm/data`` from real motion capture.

Sources (see ``../shared/data/README.md``): the CMU motion-capture subjects 01-03 (ASF/AMC)
and the CMU Panoptic ``160906_band1`` bodies. Writes

* ``pose_bank.npz``: diverse poses in the bank frame (``mvm.core.posebank``), float32;
* ``pose_prior.npz``: the 8-component Gaussian mixture over canonical poses (``mvm.core.prior``).

Usage: ``python scripts/build_pose_data.py [--data PATH] [--out PATH]`` (needs scikit-learn).
"""
from __future__ import annotations

import argparse
import collections
import io
import json
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
try:
    import mvm  # noqa: F401
except ImportError:
    sys.path.insert(0, str(REPO / "src"))

from mvm.core.keypoints import COCO_KEYPOINTS, MEAN_BONE_LENGTHS_M, bone_lengths  # noqa: E402
from mvm.core.kinematics import asf_to_coco17, forward_kinematics  # noqa: E402
from mvm.core.posebank import LABELS, Z_UP_FROM_Y_DOWN, Z_UP_FROM_Y_UP, classify_poses, select_distinct, to_bank_frame  # noqa: E402
from mvm.core.prior import COMPONENTS, REG_COVAR, canonicalize, fit_pose_prior  # noqa: E402
from mvm.io.asf_amc import read_asf, read_motion  # noqa: E402
from mvm.io.files import atomic_write_bytes  # noqa: E402
from mvm.io.panoptic_bodies import read_panoptic_coco19, read_panoptic_ids  # noqa: E402

#: Poses whose bone lengths fall outside these multiples of the adult means are
#: reconstruction failures (a few Panoptic bodies) and are left out. [1]
BONE_RATIO_RANGE = (0.5, 1.6)


def read_cmu(root: Path, frame_step: int) -> tuple[np.ndarray, list[str], int]:
    """Every ``frame_step``-th frame of every motion, z up. -> ``(poses: (N, 17, 3), sources, frames read)``."""
    poses, sources, total = [], [], 0
    for asf in sorted(root.glob("*/*.asf")):
        skeleton = read_asf(asf)
        for amc in sorted(asf.parent.glob("*.amc")):
            positions, rotations = forward_kinematics(skeleton, *read_motion(amc, skeleton))
            keep = np.arange(0, len(positions), frame_step)
            poses.append(asf_to_coco17(positions[keep], rotations[keep], skeleton) @ Z_UP_FROM_Y_UP.T)
            sources += [f"{amc.stem}:{i + 1}" for i in keep]
            total += len(positions)
    if not poses:
        raise SystemExit(f"no ASF/AMC files under {root}")
    return np.concatenate(poses), sources, total


def read_panoptic(root: Path) -> tuple[np.ndarray, list[str]]:
    """All bodies of all ``body3DScene_*.json`` under ``root``, z up. -> ``(poses: (N, 17, 3), sources)``."""
    poses, sources = [], []
    for path in sorted(root.glob("*/hdPose3d_stage1_coco19/body3DScene_*.json")):
        frame = int(path.stem.rsplit("_", 1)[1])                 # body3DScene_00000168 -> 168
        poses.append(read_panoptic_coco19(path) @ Z_UP_FROM_Y_DOWN.T)
        sources += [f"panoptic:{frame:06d}:{body}" for body in read_panoptic_ids(path)]
    if not poses:
        raise SystemExit(f"no Panoptic body3DScene files under {root}")
    return np.concatenate(poses), sources


def plausible(poses: np.ndarray) -> np.ndarray:
    """``poses: (N, 17, 3)`` -> ``(N,)`` bool: every present bone within ``BONE_RATIO_RANGE`` of the mean."""
    ratio = bone_lengths(poses) / MEAN_BONE_LENGTHS_M
    low, high = BONE_RATIO_RANGE
    return np.all(np.isnan(ratio) | ((ratio >= low) & (ratio <= high)), axis=1)


def save_npz(path: Path, **arrays) -> int:
    """Write a compressed ``.npz`` atomically; returns its size in bytes."""
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    atomic_write_bytes(path, buffer.getvalue())
    path.chmod(0o644)
    return path.stat().st_size


def main(data: Path, out: Path, frame_step: int = 4, min_distance: float = 0.06,
         components: int = COMPONENTS, reg_covar: float = REG_COVAR, seed: int = 0) -> None:
    start = time.perf_counter()
    cmu, cmu_sources, cmu_frames = read_cmu(data / "cmu_mocap", frame_step)
    cmu_bank = to_bank_frame(cmu)
    print(f"CMU mocap: {cmu_frames} frames read, {len(cmu)} kept (every {frame_step}th)")

    panoptic, panoptic_sources = read_panoptic(data / "panoptic")
    panoptic_bank = to_bank_frame(panoptic)
    usable = plausible(panoptic) & ~np.isnan(panoptic_bank).all(axis=(1, 2))
    print(f"Panoptic: {len(panoptic)} bodies, {usable.sum()} usable "
          f"({(~usable).sum()} left out: no hip or ankle, or implausible bone lengths), "
          f"{(~np.isnan(panoptic[usable]).any(axis=(1, 2))).sum()} of them with all 17 joints")

    # --- the pose bank ---------------------------------------------------------------------
    chosen = select_distinct(cmu_bank, min_distance)
    poses = np.concatenate([cmu_bank[chosen], panoptic_bank[usable]]).astype(np.float32)
    sources = np.array([cmu_sources[i] for i in chosen] + [s for s, u in zip(panoptic_sources, usable) if u])
    labels = classify_poses(poses.astype(float))
    size = save_npz(out / "pose_bank.npz", poses=poses, labels=labels, sources=sources,
                    keypoints=np.array(COCO_KEYPOINTS), min_distance_m=np.float64(min_distance),
                    frame_step=np.int64(frame_step))
    counts = collections.Counter(labels.tolist())
    print(f"pose bank: {len(poses)} poses ({len(chosen)} CMU at least {min_distance} m apart, "
          f"{usable.sum()} Panoptic): " + ", ".join(f"{label} {counts.get(label, 0)}" for label in LABELS)
          + f"; {size / 1024:.0f} KiB")

    # --- the pose prior ----------------------------------------------------------------------
    panoptic_complete = panoptic[usable & ~np.isnan(panoptic).any(axis=(1, 2))]
    train = canonicalize(np.concatenate([cmu, panoptic_complete]))
    train = train[~np.isnan(train).any(axis=(1, 2))]
    prior, info = fit_pose_prior(train, components=components, reg_covar=reg_covar, random_state=seed)
    nll = prior.nll(train)
    size = save_npz(out / "pose_prior.npz", **prior.to_arrays(), keypoints=np.array(COCO_KEYPOINTS),
                    info=np.array(json.dumps(info)))
    print(f"pose prior: {components} components fitted on {info['poses']} canonical poses "
          f"({len(panoptic_complete)} Panoptic), reg_covar {reg_covar}, EM {info['iterations']} iterations "
          f"({'converged' if info['converged'] else 'NOT converged'}); mean log-likelihood "
          f"{info['mean_log_likelihood']:.2f} per pose; nll median {np.median(nll):.1f}, "
          f"99th percentile {np.percentile(nll, 99):.1f}; weights {np.round(prior.weights, 3).tolist()}; "
          f"{size / 1024:.0f} KiB")
    print(f"wrote {out / 'pose_bank.npz'} and {out / 'pose_prior.npz'} in {time.perf_counter() - start:.0f} s")


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data",
                        help="folder with cmu_mocap/ and panoptic/ (default: ../shared/data beside the repository)")
    parser.add_argument("--out", type=Path, default=REPO / "src" / "mvm" / "data",
                        help="output folder (default: src/mvm/data)")
    parser.add_argument("--frame-step", type=int, default=4, help="use every N-th mocap frame (120 fps)")
    parser.add_argument("--min-distance", type=float, default=0.06,
                        help="bank poses differ by at least this mean joint distance [m]")
    parser.add_argument("--components", type=int, default=COMPONENTS, help="mixture components")
    parser.add_argument("--reg-covar", type=float, default=REG_COVAR,
                        help="variance added to every covariance's diagonal [torso lengths²]")
    parser.add_argument("--seed", type=int, default=0, help="random state of the mixture fit")
    return parser.parse_args(argv)


if __name__ == "__main__":
    args = parse_args()
    main(args.data, args.out, args.frame_step, args.min_distance, args.components, args.reg_covar, args.seed)
