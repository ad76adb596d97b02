"""The whole path of a rig from its videos, on the command line, against the simulator's truth:
simulated rig with rendered videos (unsynchronized, intrinsics only) -> ``mvm rig detect`` ->
``mvm rig synchronize`` -> ``mvm rig calibrate --from-people`` -> ``mvm rig reconstruct``.

No detector's weights can be fetched in the tests, so the detector is an ONNX model with RTMO's
signature built here (:func:`helpers.marker_rtmo`) that reads the joint markers the renderer
draws on the people: it sees only the pixels, so what a camera cannot see (a person behind
another, the edge of the image) it misses, through the lens distortion and the frame offsets of
each video."""
from __future__ import annotations

import functools
import json
import re

import numpy as np
import pytest
from click.testing import CliRunner

from mvm.cli.rig import rig
from mvm.io.calib_toml import read_calib_toml
from mvm.io.rig_simulation import write_rig_simulation
from mvm.io.sync_toml import read_sync_toml
from mvm.metrics.poses import similarity_transform
from mvm.sim.rig_render import render_rig_videos
from mvm.sim.rig_scene import RigSimConfig, simulate_rig

from helpers import marker_rtmo

pytest.importorskip("onnxruntime", reason="onnxruntime is the optional 'detect' extra")
pytest.importorskip("onnx", reason="the test detector is built with the onnx package")

OFFSETS = (0, 3, -2)
RATE = 25.0


def _run(*args):
    result = CliRunner().invoke(rig, [str(a) for a in args])
    assert result.exit_code == 0, result.output
    return result


def _joint_errors(lines: list[dict], sim, s: float, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Distance of every observed reconstructed joint, moved into the true world by the
    similarity ``(s, R, t)``, to the same joint of the nearest true person at its instant (m)."""
    errors = []
    for line in lines:
        truth = sim.poses3d[line["frame"] + sim.offsets[0] - sim.instants[0]]                    # (G, 17, 3)
        for person in line["persons"]:
            X = np.array([[np.nan if c is None else c for c in k[:3]] for k in person["keypoints3d"]])
            observed = np.array([f == "observed" for f in person["flags"]]) & np.isfinite(X).all(-1)
            if observed.sum() < 3:
                continue
            X = s * X[observed] @ R.T + t
            distance = np.linalg.norm(truth[:, observed] - X[None], axis=-1)                       # (G, J)
            errors.append(distance[np.argmin(distance.mean(1))])
    return np.concatenate(errors)


@pytest.mark.slow
def test_from_videos_to_tracks(tmp_path):
    """3 cameras, 2 people, 40 frames at 25 Hz; about 13 s of CPU."""
    sim = simulate_rig(RigSimConfig(cameras=3, people=2, frames=40, offsets=OFFSETS, seed=3, frame_rate=RATE,
                                    image_width=640, image_height=360, focal_px=400.0))
    root = tmp_path / "rig"
    write_rig_simulation(root, sim, intrinsics_only=True,
                         render=functools.partial(render_rig_videos, sim=sim, suffix=".mkv"))
    assert sorted(p.name for p in root.iterdir() if not p.name.startswith(".")) == ["Calib.toml", "videos"]
    model = marker_rtmo(tmp_path / "markers.onnx", people=2)

    _run("detect", root, "--detector", "rtmo", "--model", model)
    names = sim.calibration.cameras.names
    assert sorted(p.name for p in (root / "pose").glob("*.json") if not p.name.endswith(".inputs.json")) == \
        [f"{n}.json" for n in names]

    _run("synchronize", root, "--max-offset", 4)
    assert read_sync_toml(root / "sync.toml") == dict(zip(names, sim.sync_offsets.tolist()))

    calib = tmp_path / "people.toml"
    _run("calibrate", root, "--from-people", "-o", calib)
    found, true = read_calib_toml(calib).cameras, sim.calibration.cameras
    s, R, t = similarity_transform(found.centers, true.centers)
    centre_error = np.linalg.norm(s * found.centers @ R.T + t - true.centers, axis=1)
    assert centre_error.mean() < 0.05 and abs(s - 1) < 0.1                        # 5 cm; metres from the bones

    result = _run("reconstruct", root, "--calib", calib, "--no-refine")
    assert "frame rate: 25 Hz (the videos'" in result.output and "synchronized by sync.toml" in result.output
    recap = json.loads((root / "mvm" / "recap.json").read_text())
    assert recap["frame_rate"] == {"hz": RATE, "source": "videos"} and recap["tracks"] >= 2
    lines = [json.loads(line) for line in (root / "mvm" / "poses3d.jsonl").read_text().splitlines()]
    errors = _joint_errors(lines, sim, s, R, t)
    assert len(errors) > 17 * len(lines) and np.median(errors) < 0.02 and np.mean(errors) < 0.03

    # the end of the path: the rig's page, which compares it with the truth beside the folder, and
    # each camera's video with its poses drawn (`mvm report RIG_DIR`, `mvm overlay RIG_DIR`)
    from mvm.cli.main import main

    result = CliRunner().invoke(main, ["report", str(root), "--calib", str(calib)])
    assert result.exit_code == 0, result.output
    page = (root / "mvm" / "report.html").read_text()
    data = json.loads(re.search(r'<script type="application/json" id="mvm-data">(.*?)</script>', page, re.S).group(1))
    assert data["figures"]["truth"]["mpjpe_m"]["observed"] < 0.02
    result = CliRunner().invoke(main, ["overlay", str(root), "--calib", str(calib)])
    assert result.exit_code == 0, result.output
    assert sorted(p.stem for p in (root / "mvm" / "overlay").glob("*.mp4")) == list(names)
