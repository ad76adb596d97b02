"""The paper's C_var (Table 5) of 2D detectors on reconstructed scenes: how consistent each
detector's 2D poses are across frames (lower: more consistent).

Given scene directories (each detected with one detector and reconstructed), prints C_var at
τ = 0.5 and 0.9 for each (:func:`mvm.eval.cvar.evaluate_cvar`, as ``mvm evaluate cvar``),
with the detector that ``poses2d.json`` records:

    mvm detect clip_rtmo --detector rtmo && mvm reconstruct clip_rtmo
    mvm detect clip_rtmpose --detector rtmpose && mvm reconstruct clip_rtmpose
    python benchmarks/detector_cvar.py clip_rtmo clip_rtmpose

Without scenes, a demonstration: one simulated tour seen by detectors of growing keypoint
noise (the simulator's error model), each reconstructed, so that C_var can be read against
a known cause.
"""
from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from mvm.eval.cvar import evaluate_cvar


def detector_of(scene: Path) -> str:
    """What produced ``scene/poses2d.json`` (its ``info.source``)."""
    try:
        info = json.loads((scene / "poses2d.json").read_text()).get("info") or {}
    except (OSError, ValueError, AttributeError):
        info = {}
    return str(info.get("source", "(not recorded)")) if isinstance(info, dict) else "(not recorded)"


def simulated_scenes(root: Path, noises: list[float], frames: int, people: int, seed: int) -> list[Path]:
    """One tour and crowd, detected with each keypoint noise (fraction of the person's size), reconstructed."""
    from mvm.core.config import Config
    from mvm.io.ground_truth import write_simulation
    from mvm.scenes import reconstruct_dir
    from mvm.sim.simulate import SimConfig, simulate

    scenes = []
    for noise in noises:
        config = SimConfig(seed=seed, frames=frames, people=people).replace(noise=noise)
        scene, truth = simulate(config)
        path = root / f"noise_{noise:g}"
        write_simulation(path, scene, truth, config)
        reconstruct_dir(path, Config(), "mvm")
        scenes.append(path)
    return scenes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="*", type=Path, help="reconstructed scene directories")
    parser.add_argument("--output-name", default="mvm", help="folder of poses3d.json in each scene")
    parser.add_argument("--noise", type=float, nargs="+", default=[0.004, 0.008, 0.016],
                        help="demonstration: keypoint noise of each simulated detector")
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--people", type=int, default=6)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        scenes = args.scenes or simulated_scenes(Path(tmp), args.noise, args.frames, args.people, args.seed)
        print(f"{'scene':<24} {'detector':<40} {'C_var@0.5':>10} {'C_var@0.9':>10}")
        for scene in scenes:
            values = evaluate_cvar([scene], (0.5, 0.9), args.output_name)["scenes"][scene.name]
            cells = " ".join(f"{'–' if v is None else f'{v:.5f}':>10}" for v in values.values())
            print(f"{scene.name:<24} {detector_of(scene)[:40]:<40} {cells}")
        print("C_var in squared world units (m² for a metric scene; the simulation is in metres)")


if __name__ == "__main__":
    main()
