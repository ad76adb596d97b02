"""Timing of the video pipeline on a rendered 100-frame 960×540 clip (frames, SfM, detection,
reconstruction), plus SfM accuracy against the rendering's truth.

    python benchmarks/video_timing.py [--frames 100] [--width 960] [--height 540] [--out DIR]
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from mvm.metrics.poses import similarity_transform
from mvm.sim.mannequin_video import RenderConfig, default_people, render_video
from mvm.stages import Job, run_stage, scene_stage
from mvm.video.detect import detect_scene
from mvm.video.frames import FrameOptions, extract_frames
from mvm.video.sfm import SfmOptions, run_sfm


def network_seconds_per_frame(frame_path: Path, n: int = 3) -> float | None:
    """Seconds per frame of an (untrained) ResNet-50 pose network at input 641, or None without torch."""
    try:
        import cv2
        import torch  # noqa: F401

        from mvm.net.evaluate import run_model
        from mvm.net.model import build_model
    except ImportError:
        return None
    model = build_model("resnet50", 16, 64).eval()
    image = cv2.cvtColor(cv2.imread(str(frame_path)), cv2.COLOR_BGR2RGB)
    run_model(model, image, 641)
    t = time.perf_counter()
    for _ in range(n):
        run_model(model, image, 641)
    return (time.perf_counter() - t) / n


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--width", type=int, default=960)
    parser.add_argument("--height", type=int, default=540)
    parser.add_argument("--people", type=int, default=5)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    root = args.out or Path(tempfile.mkdtemp(prefix="mvm-video-"))
    focal = 0.85 * args.width
    config = RenderConfig(frames=args.frames, width=args.width, height=args.height, focal_px=focal, seed=1)
    rng = np.random.default_rng(1)
    t = time.perf_counter()
    truth = render_video(root / "clip.mp4", config, poses3d=default_people(rng, args.people, 0.8))
    render_s = time.perf_counter() - t

    seconds = {}
    scene = root / "scene"
    t = time.perf_counter()
    extract_frames(root / "clip.mp4", scene, FrameOptions(blur_ratio=0), force=True)
    seconds["frames"] = time.perf_counter() - t
    t = time.perf_counter()
    report = run_sfm(scene, SfmOptions(camera_model="SIMPLE_PINHOLE"), force=True)
    seconds["sfm"] = time.perf_counter() - t

    results = []
    for v, name in enumerate(truth.cameras.names):
        X = np.concatenate([truth.poses3d, np.ones(truth.poses3d.shape[:2] + (1,))], axis=2) @ truth.cameras.P[v].T
        uv = X[..., :2] / X[..., 2:] + rng.normal(0, 1.0, X[..., :2].shape)
        for g in range(len(uv)):
            kp = np.concatenate([uv[g], np.full((17, 1), 0.9)], axis=1)
            results.append({"image_id": name, "category_id": 1, "keypoints": kp.reshape(-1).tolist(), "score": 0.9})
    (root / "detections.json").write_text(json.dumps(results))
    t = time.perf_counter()
    detect_scene(scene, root / "detections.json", force=True)
    seconds["detect_import_and_colour"] = time.perf_counter() - t
    per_frame = network_seconds_per_frame(scene / "frames" / truth.cameras.names[0])
    if per_frame is not None:
        seconds["detect_network_resnet50_641_estimate"] = per_frame * args.frames
    t = time.perf_counter()
    rec = run_stage(scene_stage("reconstruct"), Job(scene), force=True).result
    seconds["reconstruct"] = time.perf_counter() - t

    from mvm.io.colmap import read_colmap

    model = read_colmap(scene / "sparse")
    index = [truth.cameras.names.index(n) for n in model.cameras.names]
    s, R, tr = similarity_transform(model.cameras.centers, truth.cameras.centers[index])
    err = np.linalg.norm(s * model.cameras.centers @ R.T + tr - truth.cameras.centers[index], axis=1)
    path_length = np.linalg.norm(np.diff(truth.cameras.centers, axis=0), axis=1).sum()
    summary = {
        "clip": f"{args.frames} frames {args.width}x{args.height}, {args.people} people",
        "render_s": round(render_s, 1),
        "seconds": {k: round(v, 1) for k, v in seconds.items()},
        "sfm_breakdown_s": report.seconds,
        "registered": f"{len(report.registered)}/{args.frames}",
        "reprojection_error_px": round(report.reprojection_error_px, 3),
        "focal_error_pct": round(100 * (report.focal_px / focal - 1), 2),
        "max_centre_error_pct_of_path": round(100 * err.max() / path_length, 3),
        "persons": rec.persons,
        "scale": rec.scale.to_json(),
        "alignment_scale_after_metric": round(float(s), 4),
        "scene": str(scene),
    }
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
