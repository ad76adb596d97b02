"""What a rerun of ``mvm run`` costs when nothing changed: every stage's inputs hashed and
compared with the records of its outputs (:mod:`mvm.io.provenance`), nothing recomputed.

A rendered clip, its true cameras imported as a COLMAP model and its projected poses imported
as detections (no SfM, no detector model); prints the first run's seconds, the rerun's, and the
seconds to hash the inputs alone.

    python benchmarks/rerun_cost.py [--frames 100] [--width 960] [--height 540]
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from mvm.io.colmap import write_colmap
from mvm.io.provenance import clear_hash_cache, fingerprint
from mvm.sim.mannequin_video import RenderConfig, render_video
from mvm.stages.run import run_video
from mvm.video.frames import FrameOptions


def coco_results(truth) -> list[dict]:
    """The projected true joints of every frame as COCO results keyed by file name."""
    results = []
    for v, name in enumerate(truth.cameras.names):
        X = np.concatenate([truth.poses3d, np.ones(truth.poses3d.shape[:2] + (1,))], axis=2) @ truth.cameras.P[v].T
        for uv in X[..., :2] / X[..., 2:]:
            kp = np.concatenate([uv, np.full((17, 1), 0.9)], axis=1)
            results.append({"image_id": name, "category_id": 1, "keypoints": kp.reshape(-1).round(3).tolist(),
                            "score": 0.9})
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--width", type=int, default=960)
    parser.add_argument("--height", type=int, default=540)
    args = parser.parse_args()
    root = Path(tempfile.mkdtemp(prefix="mvm-rerun-"))
    truth = render_video(root / "clip.mp4", RenderConfig(frames=args.frames, width=args.width, height=args.height,
                                                         focal_px=0.85 * args.width, seed=1))
    write_colmap(root / "model", truth.cameras)
    (root / "detections.json").write_text(json.dumps(coco_results(truth)))
    scene = root / "scene"

    def run():
        clear_hash_cache()                                   # as a new `mvm run` process
        t = time.perf_counter()
        report = run_video(root / "clip.mp4", scene, detections=root / "detections.json", cameras=root / "model",
                           frame_options=FrameOptions(blur_ratio=0), metric_scale=False)
        return time.perf_counter() - t, report

    first, _ = run()
    again, report = run()
    assert report.why == {"frames": None, "sfm": None, "detect": None, "reconstruct": None}, report.why
    clear_hash_cache()
    t = time.perf_counter()
    for path in (root / "clip.mp4", root / "model", root / "detections.json", scene / "frames", scene / "frames.json",
                 scene / "poses2d.json", scene / "sparse"):
        fingerprint(path)
    hashing = time.perf_counter() - t
    size = sum(p.stat().st_size for p in [root / "clip.mp4", *(scene / "frames").iterdir()]) / 1e6
    print(f"{args.frames} frames {args.width}×{args.height} ({size:.0f} MB of video and frames): first run "
          f"{first:.2f} s, rerun with nothing changed {again:.2f} s, hashing the inputs once {hashing:.2f} s")


if __name__ == "__main__":
    main()
