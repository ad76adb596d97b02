"""Throughput of the RTMO / RTMPose adapter's own pre- and post-processing on CPU, the model
excluded (frames per second).

The ONNX session is replaced by a stub that returns outputs of the real models' shapes
(RTMO: 100 candidate instances per frame; YOLOX: person boxes; RTMPose: SimCC at 192×256)
for a crowd of ``--people`` per frame; everything else is the adapter's code: letterbox
resize and padding, NMS, mapping to frame pixels, top-down crops and normalization, SimCC
decoding, COCO-17, and (a separate line) the colour appearance descriptor of every pose.

    python benchmarks/detector_throughput.py [--width 1920] [--height 1080] [--people 20] [--batch 8]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from mvm.video.appearance import colour_descriptor
from mvm.video.rtm import Rtmo, RtmOptions, RtmPose

J = 17


class StubModel:
    """Stands in for an ONNX session: ``size`` (w, h) and ``__call__(batch)`` -> outputs."""

    def __init__(self, size, make):
        self.size, self.make = size, make

    def __call__(self, batch):
        return self.make(len(batch))


def crowd(rng, people: int, width: int, height: int):
    """``boxes (P, 4)``, ``keypoints (P, 17, 2)`` of a crowd in frame pixels."""
    x = rng.uniform(50, width - 150, people)
    y = rng.uniform(50, height - 350, people)
    boxes = np.stack([x, y, x + 100, y + 300], 1)
    kp = np.stack([x[:, None] + rng.uniform(0, 100, (people, J)), y[:, None] + rng.uniform(0, 300, (people, J))], -1)
    return boxes, kp


def rtmo_stub(rng, people, width, height, candidates=100):
    ratio = 640 / max(width, height)
    boxes, kp = crowd(rng, people, width, height)
    dets = np.zeros((candidates, 5), np.float32)
    keypoints = np.zeros((candidates, J, 3), np.float32)
    dets[:people, :4] = boxes * ratio
    dets[:people, 4] = rng.uniform(0.75, 1.0, people)
    dets[people:, :4] = (boxes[rng.integers(0, people, candidates - people)]
                         + rng.normal(0, 5, (candidates - people, 4))) * ratio
    dets[people:, 4] = rng.uniform(0.0, 0.9, candidates - people)
    keypoints[:people, :, :2] = kp * ratio
    keypoints[:, :, 2] = rng.uniform(0, 1, (candidates, J))
    return StubModel((640, 640), lambda b: [np.repeat(dets[None], b, 0), np.repeat(keypoints[None], b, 0)])


def rtmpose_stubs(rng, people, width, height):
    ratio = 640 / max(width, height)
    boxes, _ = crowd(rng, people, width, height)
    dets = np.concatenate([boxes * ratio, rng.uniform(0.5, 1.0, (people, 1))], 1).astype(np.float32)
    sx = rng.uniform(0, 1, (1, J, 384)).astype(np.float32)
    sy = rng.uniform(0, 1, (1, J, 512)).astype(np.float32)
    person = StubModel((640, 640), lambda b: [np.repeat(dets[None], b, 0)])
    pose = StubModel((192, 256), lambda n: [np.repeat(sx, n, 0), np.repeat(sy, n, 0)])
    return person, pose


def frames_per_second(run, frames, batch: int, repeat: int) -> float:
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        for b in range(0, len(frames), batch):
            run(frames[b:b + batch])
        best = min(best, time.perf_counter() - t)
    return len(frames) / best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--width", type=int, default=1920)
    parser.add_argument("--height", type=int, default=1080)
    parser.add_argument("--people", type=int, default=20)
    parser.add_argument("--frames", type=int, default=32)
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--repeat", type=int, default=3, help="best of this many runs")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 255, (args.height, args.width, 3), dtype=np.uint8) for _ in range(args.frames)]

    rtmo = Rtmo.__new__(Rtmo)
    rtmo.model, rtmo.options = rtmo_stub(rng, args.people, args.width, args.height), RtmOptions()
    rtmpose = RtmPose.__new__(RtmPose)
    rtmpose.person, rtmpose.pose = rtmpose_stubs(rng, args.people, args.width, args.height)
    rtmpose.mean, rtmpose.std, rtmpose.options = (123.675, 116.28, 103.53), (58.395, 57.12, 57.375), RtmOptions()
    kept = rtmo(frames[:1])[0][0]

    def appearance(batch):
        for frame in batch:
            colour_descriptor(frame, kept)

    print(f"{args.width}×{args.height} frames, {args.people} people per frame, model excluded, "
          f"best of {args.repeat}:")
    for name, run in (("rtmo pre+post", rtmo), ("rtmpose pre+post", rtmpose), ("colour appearance", appearance)):
        for batch in sorted({1, args.batch}):
            fps = frames_per_second(run, frames, batch, args.repeat)
            print(f"  {name:<20} batch {batch:>2}: {fps:7.1f} frames/s")


if __name__ == "__main__":
    main()
