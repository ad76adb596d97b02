"""Fuzz the inputs of ``mvm frames``, ``mvm rig detect`` and a rig's ``sync.toml`` and print,
per surface, the cases tried and their outcomes.

- ``frames``: a small AVI whose RIFF headers are rewritten (frame counts, frame rate, size: any
  32-bit value), truncated or flipped at random bytes, extracted with random options into a
  scene that may hold a file where the scene goes, a record that is a folder or nested 1,020
  levels deep.
- ``rig-detect``: a rig of two such videos, one with a hostile camera name (long, a dot, a
  record's suffix, non-ASCII) and a folder state like the above, detected by a stand-in
  detector (one pose at each frame's centre: the video and file handling is under test).
- ``sync``: a 3-camera simulated rig whose ``sync.toml`` holds random offsets (huge, negative,
  floats, strings, tables, missing cameras) or is no regular file (a link to nothing, a FIFO,
  a folder, 2 MB), read with and without ``--frames``.

A case ends in a result or one ``InputError`` line (``mvm: error: ...``, exit 2); anything
else is a crash. A result must also be believable: the frames are those that decode, the
memory any case takes stays under ``--max-mb`` (tracemalloc's peak), and a synchronized rig
keeps every camera. Exit status 1 if any case fails.

    python benchmarks/fuzz_inputs.py                   # 300 cases per surface
    python benchmarks/fuzz_inputs.py --cases 50 --seed 3 --surface sync
"""
from __future__ import annotations

import argparse
import logging
import os
import resource
import shutil
import struct
import sys
import tempfile
import time
import traceback
import tracemalloc
from collections import Counter
from pathlib import Path

import cv2
import numpy as np

TESTS = Path(__file__).resolve().parents[1] / "tests"
sys.path[:0] = [str(TESTS)]

from mvm.errors import InputError  # noqa: E402

from helpers import write_avi  # noqa: E402

FRAMES = 6
NESTED = '{"a": ' * 1020 + "1" + "}" * 1020


def small_video(path: Path, codec: str = "MJPG") -> Path:
    """``FRAMES`` frames (64×48) of a textured background and a moving dot, as an AVI."""
    rng = np.random.default_rng(0)
    background = rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)
    images = []
    for i in range(FRAMES):
        image = background.copy()
        cv2.circle(image, (8 + 8 * i, 24), 5, (255, 255, 255), -1)
        images.append(image)
    return write_avi(path, images, 10.0, codec=codec)


#: The 32-bit fields of an AVI's headers a forged file may set: (chunk, offset in its data).
FIELDS = {"avih.dwMicroSecPerFrame": ("avih", 0), "avih.dwTotalFrames": ("avih", 16),
          "avih.dwWidth": ("avih", 32), "avih.dwHeight": ("avih", 36), "strh.dwScale": ("strh", 20),
          "strh.dwRate": ("strh", 24), "strh.dwLength": ("strh", 32)}
VALUES = (0, 1, 2, 5, 255, 2 ** 16, 2 ** 31 - 1, 2 ** 31, 2 ** 32 - 1, 10 ** 9)


def mutate_video(data: bytes, rng: np.random.Generator) -> tuple[bytes, str]:
    """A mutation of the AVI ``data`` -> (bytes, what was done)."""
    data = bytearray(data)
    how = rng.choice(["fields", "fields", "truncate", "flip"])
    if how == "fields":
        done = []
        for name in rng.choice(list(FIELDS), size=rng.integers(1, 4), replace=False):
            chunk, offset = FIELDS[name]
            at = data.find(chunk.encode()) + 8 + offset
            value = int(rng.choice(VALUES)) if rng.random() < 0.7 else int(rng.integers(0, 2 ** 32))
            struct.pack_into("<I", data, at, value)
            done.append(f"{name}={value}")
        return bytes(data), ", ".join(done)
    if how == "truncate":
        cut = int(rng.integers(0, len(data)))
        return bytes(data[:cut]), f"truncated at {cut}"
    at = rng.integers(0, len(data), size=rng.integers(1, 20))
    for i in at:
        data[i] = int(rng.integers(0, 256))
    return bytes(data), f"{len(at)} bytes changed"


def scene_state(scene: Path, output: str, record: str, rng: np.random.Generator) -> str:
    """Leave ``scene`` (a folder to write into) in a hostile state; ``output``: the name of the
    output inside it whose ``record`` a state may replace (the output then written too)."""
    state = rng.choice(["fresh", "fresh", "file", "record folder", "nested record"])
    if state == "file":
        scene.parent.mkdir(parents=True, exist_ok=True)
        scene.write_text("not a folder\n")
    elif state in ("record folder", "nested record"):
        scene.mkdir(parents=True, exist_ok=True)
        try:
            if state == "record folder":
                (scene / record).mkdir()
            else:
                (scene / output).write_text("{}")
                (scene / record).write_text('{"format": "mvm.inputs/1", "stage": "x", "inputs": {}, "settings": '
                                            + NESTED + "}")
        except OSError:                                        # a name too long for a record: none
            return "fresh"
    return str(state)


class Tally:
    def __init__(self):
        self.counts: dict[str, Counter] = {}
        self.failures: dict[str, str] = {}
        self.lines: dict[str, Counter] = {}
        self.seen: Counter = Counter()

    def add(self, surface: str, outcome: str, case: str = "", problem: str = "") -> None:
        self.counts.setdefault(surface, Counter())[outcome] += 1
        if outcome == "failure":
            self.failures.setdefault(f"{surface}: {problem}", case)
            self.seen[f"{surface}: {problem}"] += 1


def _where(error: Exception) -> str:
    """The last function of mvm (``module:function``) that ``error`` went through: a defect's
    identity, whatever the paths and values in its message."""
    frames = [f for f in traceback.extract_tb(error.__traceback__) if "/mvm/" in f.filename.replace("\\", "/")]
    if not frames:
        return "?"
    last = frames[-1]
    return f"{Path(last.filename).stem}:{last.name}"


def run(surface: str, case: str, tally: Tally, max_bytes: float, fn) -> None:
    """Run ``fn()`` (returns a problem text or None) and tally its outcome."""
    tracemalloc.start()
    try:
        problem = fn()
        peak = tracemalloc.get_traced_memory()[1]
    except InputError as e:
        tally.add(surface, "one line", case) if "\n" not in str(e) else tally.add(surface, "failure", case,
                                                                                  "InputError of several lines")
        tally.lines.setdefault(surface, Counter())[f"{e.field}: {e.problem}"[:110]] += 1
        return
    except Exception as e:                                              # noqa: BLE001 (a crash is what we seek)
        tally.add(surface, "failure", case, f"{type(e).__name__} in {_where(e)}")
        return
    finally:
        tracemalloc.stop()
    if problem is None and peak > max_bytes:
        problem = f"{peak / 2 ** 20:.0f} MiB allocated"
    tally.add(surface, "failure" if problem else "result", case, problem or "")


def fuzz_frames(root: Path, n: int, rng: np.random.Generator, tally: Tally, max_bytes: float) -> None:
    from mvm.video.frames import FrameOptions, extract_frames

    good = small_video(root / "good.avi").read_bytes()
    for i in range(n):
        data, how = mutate_video(good, rng)
        video = root / f"v{i}.avi"
        video.write_bytes(data)
        scene = root / f"scene{i}"
        state = scene_state(scene, "frames.json", "frames.inputs.json", rng)
        options = FrameOptions(rate=[None, 1.0, 30.0][rng.integers(3)], max_frames=[None, 1, 3][rng.integers(3)],
                               select=str(rng.choice(["auto", "motion", "all"])), blur_ratio=float(rng.random()))

        def case(video=video, scene=scene, options=options):
            index = extract_frames(video, scene, options, force=bool(rng.random() < 0.3))
            if len(index.numbers) and index.numbers.max() >= FRAMES:
                return f"frame {index.numbers.max()} of a {FRAMES}-frame video"
            return None

        run("frames", f"{how}; {state}; {options}", tally, max_bytes, case)


CAMERA_NAMES = ("cam_02", "c" * 245, "c" * 200, "cam.02", "cam 02", "caméra_02", "cam_02.inputs", ".cam_02",
                "-cam", "cam_02.json")


def fuzz_rig_detect(root: Path, n: int, rng: np.random.Generator, tally: Tally, max_bytes: float) -> None:
    import mvm.video.rig_videos as rig_videos
    from mvm.video.detect import DetectOptions
    from mvm.video.detectors import FrameDetector

    def centre_pose(frames):
        out = []
        for frame in frames:
            kp = np.zeros((1, 17, 3))
            kp[0, :, :2] = frame.shape[1] / 2, frame.shape[0] / 2
            kp[0, :, 2] = 0.9
            out.append((kp, np.array([0.9]), None))
        return out

    rig_videos.check_models = lambda options, checkpoint: None
    rig_videos.make_detector = lambda options, checkpoint: FrameDetector(centre_pose, {"detector": "rtmo",
                                                                                        "models": [], "device": "cpu"})
    good = small_video(root / "good.avi", "FFV1").read_bytes()
    for i in range(n):
        rig = root / f"rig{i}"
        (rig / "videos").mkdir(parents=True)
        (rig / "videos" / "cam_01.avi").write_bytes(good)
        data, how = mutate_video(good, rng) if rng.random() < 0.8 else (good, "intact")
        camera = str(rng.choice(CAMERA_NAMES))
        (rig / "videos" / f"{camera}.avi").write_bytes(data)
        state = scene_state(rig / "pose", f"{camera}.json", f"{camera}.inputs.json", rng)
        force = bool(rng.random() < 0.5)

        def case(rig=rig, force=force):
            done = rig_videos.detect_rig_videos(rig, None, DetectOptions(detector="rtmo"), force=force)
            for cam in done:
                if cam.video is not None and cam.video.frames > FRAMES:
                    return f"camera {cam.camera[:20]}: {cam.video.frames} frames of a {FRAMES}-frame video"
            return None

        run("rig-detect", f"{camera[:30]}: {how}; {state}; force={force}", tally, max_bytes, case)


HOSTILE_OFFSETS = (str(2 ** 63 - 1), str(-(2 ** 63)), "1" + "0" * 30, "1000000", "-1000000000", "1000000000",
                   "1.5", "nan", "inf", '"3"', "true", "[1, 2]", "{a = 1}", "1e400", "0x7fffffffffffffff", "-13",
                   "11")


def sync_text(rng: np.random.Generator) -> tuple[str, str]:
    """A ``sync.toml``: the three cameras with offsets of a few frames, then up to three changes
    (a hostile value, a camera left out or unknown, the table's header lost) -> (text, what)."""
    offsets = {f"cam_0{c}": str(int(rng.integers(-4, 5))) for c in (1, 2, 3)}
    header, changes = "[offsets]", []
    for _ in range(rng.integers(0, 4)):
        change = rng.choice(["value", "value", "value", "drop", "unknown", "header"])
        camera = f"cam_0{rng.integers(1, 4)}"
        if change == "value":
            offsets[camera] = str(rng.choice(HOSTILE_OFFSETS))
        elif change == "drop":
            offsets.pop(camera, None)
        elif change == "unknown":
            offsets[str(rng.choice(["cam_04", '"cam 01"', '"cam_02 "']))] = "0"
        else:
            header = ""
        changes.append(change)
    text = "\n".join([header, *(f"{k} = {v}" for k, v in offsets.items())]) + "\n"
    return text, "; ".join(f"{k} = {v}" for k, v in offsets.items()) + (" (no header)" if not header else "")


def fuzz_sync(root: Path, n: int, rng: np.random.Generator, tally: Tally, max_bytes: float) -> None:
    from mvm.io.rig_simulation import write_rig_simulation
    from mvm.rig.rigdir import read_rig
    from mvm.sim.rig_scene import RigSimConfig, simulate_rig

    base = root / "base"
    write_rig_simulation(base, simulate_rig(RigSimConfig(cameras=3, people=1, frames=12, seed=3)))
    for i in range(n):
        rig = root / f"rig{i}"
        shutil.copytree(base, rig)
        path = rig / "sync.toml"
        kind = rng.choice(["text"] * 6 + ["dangling link", "fifo", "folder", "2 MB", "binary"])
        if kind == "text":
            text, how = sync_text(rng)
            path.write_text(text)
        else:
            how = str(kind)
            if kind == "dangling link":
                path.symlink_to(rig / "gone.toml")
            elif kind == "fifo":
                os.mkfifo(path)
            elif kind == "folder":
                path.mkdir()
            elif kind == "2 MB":
                path.write_text("[offsets]\ncam_01 = 0\ncam_02 = 0\ncam_03 = 0\n" + "#" * 2_000_000)
            else:
                path.write_bytes(bytes(rng.integers(0, 256, 64, dtype=np.uint8)))
        frames = [None, "0:6", "5:", ":3"][rng.integers(4)]

        def case(rig=rig, frames=frames):
            data = read_rig(rig, frames=frames)
            seen = set(np.unique(data.detections.view).tolist())
            if data.offsets is None:
                return "a sync.toml present but the rig read unsynchronized"
            if frames is None and seen != set(range(len(data.calibration.cameras.names))):
                return "a camera dropped out"
            return None

        run("sync", f"{how}; --frames {frames}", tally, max_bytes, case)


SURFACES = {"frames": fuzz_frames, "rig-detect": fuzz_rig_detect, "sync": fuzz_sync}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=300, help="cases per surface (default 300)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--surface", action="append", choices=sorted(SURFACES), help="only these surfaces")
    parser.add_argument("--show", type=int, default=0, help="print this many of each surface's commonest lines")
    parser.add_argument("--max-mb", type=float, default=100.0, help="most memory a case may take (MiB, default 100)")
    parser.add_argument("--heap-gb", type=float, default=4.0,
                        help="the process's heap limit (GiB, default 4): a case that believes a header fails there")
    args = parser.parse_args()
    heap = int(args.heap_gb * 2 ** 30)
    resource.setrlimit(resource.RLIMIT_DATA, (heap, heap))
    logging.disable(logging.WARNING)
    rng = np.random.default_rng(args.seed)
    tally = Tally()
    seconds = {}
    with tempfile.TemporaryDirectory() as tmp:
        for surface in args.surface or list(SURFACES):
            start = time.perf_counter()
            folder = Path(tmp) / surface
            folder.mkdir()
            SURFACES[surface](folder, args.cases, rng, tally, args.max_mb * 2 ** 20)
            seconds[surface] = time.perf_counter() - start
    print(f"{'surface':<12}{'cases':>7}{'result':>8}{'one line':>10}{'failures':>10}{'seconds':>9}")
    for surface, counts in tally.counts.items():
        print(f"{surface:<12}{sum(counts.values()):>7}{counts['result']:>8}{counts['one line']:>10}"
              f"{counts['failure']:>10}{seconds[surface]:>9.1f}")
    for surface, lines in tally.lines.items() if args.show else ():
        print(f"{surface}: the commonest of its {len(lines)} distinct lines")
        for line, count in lines.most_common(args.show):
            print(f"  {count:>4}  {line}")
    if tally.failures:
        print(f"{len(tally.failures)} distinct failures:")
        for problem, case in tally.failures.items():
            print(f"  {problem} ({tally.seen[problem]} cases)\n      e.g. {case[:200]}")
        return 1
    print("no failure")
    return 0


if __name__ == "__main__":
    sys.exit(main())
