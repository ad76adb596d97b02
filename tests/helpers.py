"""Factories shared by the tests: cameras, standing poses, and where the data lie.

Importable from any test module (``from helpers import random_cameras``): ``tests/`` is on
pytest's ``pythonpath``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from mvm.sim.people import STANDING  # noqa: F401  (re-exported for the tests)

#: The test folder, the repository, and the shared real data beside the repository.
TESTS = Path(__file__).resolve().parent
REPO = TESTS.parent
SHARED_DATA = REPO.parent / "shared" / "data"
#: The corpus of malformed inputs and other test data.
DATA = TESTS / "data"

def standing_poses(n: int = 30, seed: int = 0, jitter: float = 0.04) -> np.ndarray:
    """``(n, 17, 3)`` varied standing poses in the bank frame."""
    rng = np.random.default_rng(seed)
    poses = STANDING[None] + rng.normal(0, jitter, (n, 17, 3))
    poses[..., 2] -= poses[..., 2].min(axis=1, keepdims=True)
    return poses


def random_cameras(rng: np.random.Generator, V: int, radius: float = 5.0, arc_deg: float = 90.0,
                   width: int = 1280, height: int = 720, focal: float = 1000.0):
    """``V`` cameras on an arc around the origin looking at (0, 0, 1)."""
    from mvm.core.scene import Cameras
    from mvm.sim.simulate import look_at

    angles = np.radians(np.linspace(-arc_deg / 2, arc_deg / 2, V)) + rng.uniform(0, 2 * np.pi)
    centers = np.stack([radius * np.cos(angles), radius * np.sin(angles),
                        1.5 + rng.normal(0, 0.1, V)], axis=1)
    R = look_at(centers, np.broadcast_to([0.0, 0.0, 1.0], (V, 3)))
    t = -np.einsum("vij,vj->vi", R, centers)
    K = np.array([[focal, 0, width / 2], [0, focal, height / 2], [0, 0, 1.0]])
    return Cameras(np.broadcast_to(K, (V, 3, 3)).copy(), R, t,
                   np.broadcast_to([float(width), float(height)], (V, 2)).copy(),
                   tuple(f"f{i:04d}.jpg" for i in range(V)))


def cmu_walk(z_up: bool = True):
    """Real walking motion: CMU motion capture subject 02, trial 01, at 30 Hz, ``(T, 17, 3)``
    metres (z up, centred sideways; or the file's y up). Skips the calling test where the data
    are absent."""
    import pytest

    folder = SHARED_DATA / "cmu_mocap" / "02"
    if not (folder / "02_01.amc").is_file():
        pytest.skip(f"CMU motion capture absent: {folder}")
    from mvm.core.kinematics import asf_to_coco17, forward_kinematics
    from mvm.io.asf_amc import read_asf, read_motion

    skeleton = read_asf(folder / "02.asf")
    positions, rotations = forward_kinematics(skeleton, *read_motion(folder / "02_01.amc", skeleton))
    walk = asf_to_coco17(positions[::4], rotations[::4], skeleton)             # 120 Hz -> 30 Hz
    if not z_up:
        return walk
    return np.stack([walk[..., 0] - walk[..., 0].mean(), -walk[..., 2], walk[..., 1]], -1)


def tiny_network(folder: Path, input_size: int = 64, steps: int = 2):
    """A tiny pose network (resnet18, width 8) trained for ``steps`` steps on 4 synthetic
    ``input_size`` px images under ``folder`` -> ``(checkpoint .pt, the training images)``."""
    from click.testing import CliRunner

    from mvm.cli.net import train_cmd
    from mvm.sim import people_images as images

    data = images.synthetic_dataset(folder / "data", 4, (input_size, input_size), seed=5)
    config = folder / "tiny.toml"
    config.write_text(f'[model]\nbackbone = "resnet18"\nstride = 16\nwidth = 8\n[data]\ninput_size = {input_size}\n'
                      f'[[data.train]]\nannotations = "{data}"\n[optim]\nsteps = {steps}\nbatch_size = 2\n'
                      f'[output]\nout_dir = "{folder / "run"}"\ndevice = "cpu"\n')
    result = CliRunner().invoke(train_cmd, [str(config)])
    assert result.exit_code == 0, result.output
    return folder / "run" / f"checkpoint-{steps:07d}.pt", sorted((folder / "data" / "images").iterdir())


def run_at_once(args: list[str], runs: int = 3) -> list[int]:
    """Start ``mvm ARGS`` ``runs`` times at once and wait for them: each must end either done
    (exit 0) or refused in one line because another run holds the output's lock (exit 2).
    Returns the exit statuses."""
    import subprocess
    import sys

    command = [sys.executable, "-c", "from mvm.cli.main import run; run()", *map(str, args)]
    processes = [subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                 for _ in range(runs)]
    for p in processes:
        p.wait(300)
        errors = p.stderr.read().strip().splitlines()
        assert p.returncode == 0 or (p.returncode == 2 and len(errors) == 1
                                     and "another mvm run is writing" in errors[0]), errors
    return [p.returncode for p in processes]


def coco_results(truth, rng, noise_px: float = 0.5, scale: float = 1.0, skip: int = 0) -> list[dict]:
    """The projected true joints (+ noise) of every frame, COCO results by file name
    (``scale``: in pixels of frames that size; ``skip``: leave out the first persons)."""
    results = []
    cams = truth.cameras
    for v, name in enumerate(cams.names):
        X = np.concatenate([truth.poses3d, np.ones(truth.poses3d.shape[:2] + (1,))], axis=2) @ cams.P[v].T
        uv = (X[..., :2] / X[..., 2:] + rng.normal(0, noise_px, X[..., :2].shape)) * scale
        for g in range(skip, len(uv)):
            kp = np.concatenate([uv[g], np.full((17, 1), 0.9)], axis=1)
            results.append({"image_id": name, "category_id": 1, "keypoints": kp.reshape(-1).round(3).tolist(),
                            "score": 0.9})
    return results



def marker_rtmo(path: Path, people: int) -> Path:
    """An ONNX model with RTMO's signature (``input (B, 3, 640, 640)`` raw BGR -> ``dets (B, G,
    5)``, ``keypoints (B, G, 17, 3)``) that finds people by reading the pixels: the joint
    markers of :mod:`mvm.sim.rig_render` (blue 255, green and red coding the joint and the
    person). Each keypoint is the centroid of the pixels of exactly its marker's colour, present
    where at least 3 such pixels are seen (a marker hidden by another person is missed); a person
    seen with at least 3 joints scores 0.9, their box spanning those joints. Nothing but the
    image goes in, so occlusion, the lens and the frame offsets all come through the pixels.
    Built with ``onnx.helper`` (no torch): the pixels of blue 255 are gathered first, so a batch
    costs a few passes over the frames."""
    import onnx
    from onnx import TensorProto
    from onnx import helper as h

    from mvm.sim.rig_render import MARKER_BASE, MARKER_BLUE, MARKER_JOINT_STEP, MARKER_PERSON_STEP

    S, J, codes = 640, 17, people * 17
    nodes, inits = [], []

    def const(name, value, dtype=np.float32):
        inits.append(onnx.numpy_helper.from_array(np.asarray(value, dtype=dtype), name))
        return name

    def op(kind, inputs, output, **attrs):
        nodes.append(h.make_node(kind, inputs, [output], **attrs))
        return output

    channel = [op("Reshape", [op("Gather", ["input", const(f"c{c}", c, np.int64)], f"plane{c}", axis=1),
                              const(f"n{c}", [-1], np.int64)], f"ch{c}") for c in range(3)]
    hit = op("Greater", [channel[0], const("blue", MARKER_BLUE - 0.5)], "hit")
    sel = op("Squeeze", [op("NonZero", [hit], "nz"), const("ax0", [0], np.int64)], "sel")     # (P,) pixels
    green = op("Gather", [channel[1], sel], "green", axis=0)
    red = op("Gather", [channel[2], sel], "red", axis=0)

    def code(value, step, name):
        k = op("Round", [op("Div", [op("Sub", [value, const(f"{name}b", MARKER_BASE)], f"{name}s"),
                                    const(f"{name}d", step)], f"{name}q")], f"{name}k")
        exact = op("Sub", [value, op("Add", [op("Mul", [k, const(f"{name}m", step)], f"{name}km"),
                                             const(f"{name}a", MARKER_BASE)], f"{name}want")], f"{name}off")
        return k, op("Less", [op("Abs", [exact], f"{name}abs"), const(f"{name}t", 0.5)], f"{name}ok")

    j, j_ok = code(green, MARKER_JOINT_STEP, "j")
    g, g_ok = code(red, MARKER_PERSON_STEP, "g")
    valid = j_ok
    for k, (value, low, high) in enumerate([(j, 0, J), (g, 0, people)]):
        valid = op("And", [valid, op("GreaterOrEqual", [value, const(f"lo{k}", low)], f"ge{k}")], f"v{k}a")
        valid = op("And", [valid, op("Less", [value, const(f"hi{k}", high)], f"lt{k}")], f"v{k}b")
    valid = op("And", [valid, g_ok], "valid")
    w = op("Cast", [valid], "w", to=TensorProto.FLOAT)
    frame = op("Div", [sel, const("hw", S * S, np.int64)], "frame")
    rest = op("Mod", [sel, const("hw2", S * S, np.int64)], "rest")
    ys = op("Cast", [op("Div", [rest, const("wd", S, np.int64)], "yi")], "ys", to=TensorProto.FLOAT)
    xs = op("Cast", [op("Mod", [rest, const("wm", S, np.int64)], "xi")], "xs", to=TensorProto.FLOAT)
    slot = op("Add", [op("Mul", [g, const("j17", J)], "g17"), j], "slot")
    slot = op("Add", [op("Mul", [op("Cast", [frame], "ff", to=TensorProto.FLOAT), const("cd", codes)], "fc"), slot],
              "slot2")
    index = op("Cast", [op("Mul", [slot, w], "slotw")], "index", to=TensorProto.INT64)
    batch = op("Slice", [op("Shape", ["input"], "shape"), const("s0", [0], np.int64), const("s1", [1], np.int64)],
               "batch")
    size = op("Mul", [batch, const("codes", [codes], np.int64)], "size")
    zero = op("ConstantOfShape", [size], "zero", value=h.make_tensor("z", TensorProto.FLOAT, [1], [0.0]))
    sums = [op("ScatterElements", [zero, index, u], f"sum{k}", axis=0, reduction="add")
            for k, u in enumerate([w, op("Mul", [w, xs], "wx"), op("Mul", [w, ys], "wy")])]
    shape = op("Concat", [batch, const("gj", [people, J], np.int64)], "bgj", axis=0)
    count, sx, sy = (op("Reshape", [s, shape], f"r{k}") for k, s in enumerate(sums))
    n = op("Max", [count, const("one", 1.0)], "n")
    kx, ky = op("Div", [sx, n], "kx"), op("Div", [sy, n], "ky")
    seen = op("Cast", [op("GreaterOrEqual", [count, const("three", 3.0)], "seen3")], "seen", to=TensorProto.FLOAT)
    conf = op("Mul", [seen, const("c95", 0.95)], "conf")
    unsq = const("last", [-1], np.int64)
    op("Concat", [op("Unsqueeze", [t, unsq], f"u{t}") for t in (kx, ky, conf)], "keypoints", axis=-1)
    on = op("Cast", [seen], "on", to=TensorProto.BOOL)
    bounds = []
    for t in (kx, ky):
        bounds.append(op("ReduceMin", [op("Where", [on, t, const(f"big{t}", 1e6)], f"lo{t}")], f"min{t}", axes=[-1],
                         keepdims=1))
    for t in (kx, ky):
        bounds.append(op("ReduceMax", [op("Where", [on, t, const(f"neg{t}", -1e6)], f"hi{t}")], f"max{t}", axes=[-1],
                         keepdims=1))
    joints = op("ReduceSum", [seen, unsq], "joints", keepdims=1)
    enough = op("GreaterOrEqual", [joints, const("three2", 3.0)], "enough")
    person = op("Cast", [enough], "person", to=TensorProto.FLOAT)
    box = op("Mul", [op("Concat", bounds, "box0", axis=-1), person], "box")
    op("Concat", [box, op("Mul", [person, const("s90", 0.9)], "score")], "dets", axis=-1)
    graph = h.make_graph(nodes, "marker_rtmo", [h.make_tensor_value_info("input", TensorProto.FLOAT, ["B", 3, S, S])],
                         [h.make_tensor_value_info("dets", TensorProto.FLOAT, ["B", people, 5]),
                          h.make_tensor_value_info("keypoints", TensorProto.FLOAT, ["B", people, J, 3])], inits)
    model = h.make_model(graph, opset_imports=[h.make_opsetid("", 17)], ir_version=8)
    onnx.checker.check_model(model)
    onnx.save(model, path)
    return path


def write_avi(path: Path, images, fps: float = 10.0, announce: int | None = None, codec: str = "MJPG") -> Path:
    """Write ``images`` ((H, W, 3) BGR, one size) as an AVI (``codec``: MJPG, FFV1: lossless);
    with ``announce``, its RIFF header then claims that many frames (the main header's
    ``dwTotalFrames`` and the video stream header's ``dwLength``), as a forged or damaged file
    would."""
    import struct

    import cv2

    images = list(images)
    h, w = images[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*codec), fps, (w, h))
    for image in images:
        writer.write(image)
    writer.release()
    if announce is not None:
        data = bytearray(path.read_bytes())
        main, stream = data.find(b"avih"), data.find(b"strh")       # each chunk: fourcc, size, fields
        assert main > 0 and stream > 0 and data[stream + 8:stream + 12] == b"vids", "not an AVI OpenCV wrote"
        struct.pack_into("<I", data, main + 8 + 16, announce)         # MainAVIHeader.dwTotalFrames
        struct.pack_into("<I", data, stream + 8 + 32, announce)       # AVIStreamHeader.dwLength
        path.write_bytes(bytes(data))
    return path


def dead_pid() -> int:
    """The process number of a process that has ended (and been waited for): what a killed
    writer's temporary file names (``.NAME.mvm-tmp-PID-XXXX.tmp``)."""
    import subprocess
    import sys

    return int(subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                              text=True, check=True).stdout)
