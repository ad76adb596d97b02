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
