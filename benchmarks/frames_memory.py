"""Peak memory of ``mvm frames`` against the video's length, on synthetic 1080p clips.

Each clip (a textured scene panned past the camera, MJPG in AVI) is decoded by
:func:`mvm.video.frames.extract_frames` in a fresh process, every frame kept; the process's
peak resident set size is printed. Decoding is streamed, so the peak should not grow with
the length (target: < 500 MB at 2,000 frames).

    python benchmarks/frames_memory.py [--lengths 100 500 2000] [--width 1920] [--height 1080]
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

CHILD = """
import json, resource, sys, time
from mvm.video.frames import FrameOptions, extract_frames
t = time.perf_counter()
index = extract_frames(sys.argv[1], sys.argv[2], FrameOptions(blur_ratio=0.0))
print(json.dumps({"frames": len(index.names), "seconds": time.perf_counter() - t,
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def write_clip(path: Path, frames: int, width: int, height: int, fps: float = 30.0) -> Path:
    """A ``frames``-long clip panning over a smooth random texture (MJPG: fast to write)."""
    rng = np.random.default_rng(0)
    small = rng.integers(0, 255, (height // 8, (width + frames) // 8 + 1, 3), dtype=np.uint8)
    texture = cv2.resize(small, (small.shape[1] * 8, small.shape[0] * 8), interpolation=cv2.INTER_CUBIC)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (width, height))
    for k in range(frames):
        writer.write(np.ascontiguousarray(texture[:height, k:k + width]))
    writer.release()
    return path


def measure(video: Path, scene: Path) -> dict:
    """Run ``extract_frames`` in a fresh interpreter -> frames, seconds, peak RSS (MB)."""
    out = subprocess.run([sys.executable, "-c", CHILD, str(video), str(scene)], check=True,
                         capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lengths", type=int, nargs="+", default=[100, 500, 2000])
    parser.add_argument("--width", type=int, default=1920)
    parser.add_argument("--height", type=int, default=1080)
    args = parser.parse_args()
    print(f"{'frames':>7} {'decoded':>8} {'seconds':>8} {'peak RSS (MB)':>14}")
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.lengths:
            t = time.perf_counter()
            video = write_clip(Path(tmp) / f"clip_{n}.avi", n, args.width, args.height)
            written = time.perf_counter() - t
            result = measure(video, Path(tmp) / f"scene_{n}")
            print(f"{n:>7} {result['frames']:>8} {result['seconds']:>8.1f} {result['peak_rss_mb']:>14.0f}"
                  f"   (clip written in {written:.0f} s)", flush=True)
            video.unlink()
            for f in list((Path(tmp) / f"scene_{n}" / "frames").iterdir()):
                f.unlink()


if __name__ == "__main__":
    main()
