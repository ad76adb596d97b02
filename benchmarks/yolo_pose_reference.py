"""The YOLO-pose detector against Ultralytics' own detections of the same model, on the real
4-camera capture of ``/work/shared/data/real_footage`` (``README.md`` there): ``mvm rig detect``
on its videos (4 × 100 frames), timed, then every reference pose matched to a detected one of its
frame (OKS ≥ 0.5 with the COCO sigmas, the reference's box area as scale; one to one, by the
Hungarian method): the share of reference poses found, and the distances of their keypoints
(those both report present) to the reference's, median and 90th percentile, in pixels.

    python benchmarks/yolo_pose_reference.py [--rig DIR] [--batch-size 4]

ONNX Runtime runs with its default threads (one per physical core).

The rig folder gets ``videos/`` (links to the capture's videos) and ``pose/`` (the pose files,
which the rest of the rig chain reads). The model's weights are Ultralytics' (AGPL-3.0): they stay
in the shared data, never in the repository.
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real_footage"
CAMERAS = ("cam01", "cam02", "cam03", "cam04")
MATCH_OKS = 0.5


def by_frame(path: Path) -> dict[int, np.ndarray]:
    """A COCO keypoints file's poses by frame number (``file_name``'s last number): ``(K, 17, 3)``."""
    data = json.loads(Path(path).read_text())
    frame = {im["id"]: int(Path(im["file_name"]).stem.split("/")[-1]) for im in data["images"]}
    poses: dict[int, list] = {f: [] for f in frame.values()}
    for a in data["annotations"]:
        poses[frame[a["image_id"]]].append(np.asarray(a["keypoints"], float).reshape(17, 3))
    return {f: np.array(p).reshape(-1, 17, 3) for f, p in poses.items()}


def oks(found: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Object keypoint similarity ``(N, M)`` of ``found (N, 17, 3)`` to ``reference (M, 17, 3)``
    over the reference's present keypoints, its box area (of those keypoints) as the scale."""
    from mvm.core.keypoints import COCO_SIGMAS

    present = reference[:, :, 2] > 0                                            # (M, 17)
    lo = np.where(present[..., None], reference[:, :, :2], np.inf).min(1)
    hi = np.where(present[..., None], reference[:, :, :2], -np.inf).max(1)
    area = np.prod(np.maximum(hi - lo, 1.0), axis=1)                            # (M,)
    d2 = ((found[:, None, :, :2] - reference[None, :, :, :2]) ** 2).sum(-1)      # (N, M, 17)
    e = d2 / (2 * area[None, :, None] * (2 * COCO_SIGMAS) ** 2)
    return (np.exp(-e) * present[None]).sum(-1) / np.maximum(present.sum(-1), 1)[None]


def compare(found: dict[int, np.ndarray], reference: dict[int, np.ndarray]) -> dict:
    """Reference poses found (one-to-one OKS matches ≥ 0.5) and the keypoint distances (px) of
    the matched pairs over the joints both report present."""
    from scipy.optimize import linear_sum_assignment

    matched, total, distances = 0, 0, []
    for frame, ref in reference.items():
        total += len(ref)
        mine = found.get(frame, np.zeros((0, 17, 3)))
        if not len(ref) or not len(mine):
            continue
        similarity = oks(mine, ref)
        rows, cols = linear_sum_assignment(-similarity)
        for i, j in zip(rows, cols):
            if similarity[i, j] >= MATCH_OKS:
                matched += 1
                both = (mine[i, :, 2] > 0) & (ref[j, :, 2] > 0)
                distances.append(np.linalg.norm(mine[i, both, :2] - ref[j, both, :2], axis=1))
    d = np.concatenate(distances) if distances else np.zeros(0)
    return {"reference_poses": total, "found": matched, "found_share": matched / max(total, 1),
            "keypoints": len(d), "median_px": float(np.median(d)) if len(d) else None,
            "p90_px": float(np.percentile(d, 90)) if len(d) else None}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rig", default=None,
                        help="rig folder to fill (videos/ linked, pose/ written; default: a temporary one)")
    parser.add_argument("--batch-size", type=int, default=4)
    args = parser.parse_args()

    from mvm.video.detect import DetectOptions
    from mvm.video.rig_videos import detect_rig_videos

    rig = Path(args.rig) if args.rig else Path(tempfile.mkdtemp(prefix="mvm-yolo-"))
    (rig / "videos").mkdir(parents=True, exist_ok=True)
    for camera in CAMERAS:
        link = rig / "videos" / f"{camera}.mp4"
        if not link.exists():
            link.symlink_to(DATA / "videos" / f"{camera}.mp4")
    options = DetectOptions(detector="yolo-pose", model=str(DATA / "models" / "yolo11n-pose.onnx"),
                            batch_size=args.batch_size)
    start = time.perf_counter()
    cameras = detect_rig_videos(rig, options=options, force=True)
    seconds = time.perf_counter() - start
    frames = sum(c.video.frames for c in cameras)
    found = {c: by_frame(rig / "pose" / f"{c}.json") for c in CAMERAS}
    reference = {c: by_frame(DATA / "pose_ultralytics" / f"{c}.json") for c in CAMERAS}
    rows = {c: compare(found[c], reference[c]) for c in CAMERAS}
    everything = compare({(c, f): p for c in CAMERAS for f, p in found[c].items()},
                         {(c, f): p for c in CAMERAS for f, p in reference[c].items()})
    print(f"{frames} frames in {seconds:.1f} s ({1000 * seconds / frames:.0f} ms per frame), "
          f"{os.cpu_count()} CPUs, batch {args.batch_size}")
    for name, row in [*rows.items(), ("all", everything)]:
        print(f"{name}: found {row['found']} / {row['reference_poses']} ({100 * row['found_share']:.1f} %), "
              f"keypoints {row['keypoints']}: median {row['median_px']:.2f} px, 90th percentile {row['p90_px']:.2f} px")
    print(f"pose files: {rig / 'pose'}")


if __name__ == "__main__":
    main()
