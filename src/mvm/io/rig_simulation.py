"""Writing a simulated rig (:mod:`mvm.sim.rig_scene`) as a rig folder, its truth beside it::

    OUT/
      Calib.toml            the cameras (with ``intrinsics_only``: no rotation / translation)
      pose/<camera>.json    one COCO keypoints file per camera, file_name "<camera>/<frame>.jpg"
      videos/<camera>.mp4   or, when rendered, each camera's video instead (no pose/: what a
                            user brings, for ``mvm rig detect``)
    OUT.groundtruth.json    format ``mvm.rig.groundtruth/1``: cameras, true offsets, true
                            extrinsics, the scene's instants and 3D poses (metres)
    OUT.groundtruth.toml    the true, full calibration

The folder is written whole (a temporary folder renamed into place), the truth files atomically.
"""
from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from mvm.io.calib_toml import calib_toml_text, write_calib_toml
from mvm.io.coco import coco_keypoints_document
from mvm.io.files import atomic_write_json, atomic_write_text, check_file_target
from mvm.io.layout import CALIB_TOML, POSE_DIR, VIDEOS, RigLayout
from mvm.io.outputs import atomic_replace_dir

TRUTH_FORMAT = "mvm.rig.groundtruth/1"


def intrinsics_only_text(text: str) -> str:
    """A Calib.toml text without its ``rotation`` and ``translation`` lines."""
    return "".join(line for line in text.splitlines(keepends=True)
                   if not line.startswith(("rotation = ", "translation = ")))


def truth_document(sim) -> dict:
    """The ground truth of ``sim`` (a :class:`mvm.sim.rig_scene.RigSimulation`) as a JSON-ready dict."""
    cams = sim.calibration.cameras
    return {"format": TRUTH_FORMAT, "cameras": list(cams.names), "frame_rate": sim.frame_rate,
            "frames": sim.frames,
            "offsets": {n: int(o) for n, o in zip(cams.names, sim.offsets)},
            "sync_offsets": {n: int(o) for n, o in zip(cams.names, sim.sync_offsets)},
            "extrinsics": {n: {"rotation": cv2.Rodrigues(cams.R[v])[0].ravel().round(9).tolist(),
                               "translation": cams.t[v].round(9).tolist(),
                               "center": cams.centers[v].round(9).tolist()} for v, n in enumerate(cams.names)},
            "instants": sim.instants.tolist(),
            "poses3d": np.round(sim.poses3d, 5).tolist()}


def write_rig_simulation(out: str | Path, sim, intrinsics_only: bool = False,
                         render: Callable[[Path], object] | None = None) -> dict[str, Path]:
    """Write ``sim`` (a :class:`mvm.sim.rig_scene.RigSimulation`) into the rig folder ``out`` and
    its truth beside it. ``render(folder)`` writes the cameras' videos into ``folder``
    (``OUT/videos``, :func:`mvm.sim.rig_render.render_rig_videos`); the simulated detections
    (``pose/``) are then left out. Returns the paths written (``rig``, ``calibration``,
    ``truth``, ``true_calibration``, and ``videos`` when rendered)."""
    out = Path(out)
    cams = sim.calibration.cameras

    def build(folder: Path) -> None:
        text = calib_toml_text(sim.calibration)
        atomic_write_text(folder / CALIB_TOML, intrinsics_only_text(text) if intrinsics_only else text)
        if render is not None:
            render(folder / VIDEOS)
            return
        for v, name in enumerate(cams.names):
            rows = sim.camera == v
            frames, ann_image = np.unique(sim.frame[rows], return_inverse=True)
            document = coco_keypoints_document([f"{name}/{f:06d}.jpg" for f in frames],
                                               [cams.size[v]] * len(frames), ann_image, sim.keypoints[rows],
                                               sim.score[rows])
            atomic_write_json(folder / POSE_DIR / f"{name}.json", document)

    layout = RigLayout(out)
    truth, true_calibration = layout.truth, layout.true_calibration
    for path in (truth, true_calibration):           # a device, FIFO or link there: refused before any write
        check_file_target(path)
    atomic_replace_dir(build, out)
    atomic_write_json(truth, truth_document(sim))
    write_calib_toml(true_calibration, sim.calibration)
    paths = {"rig": out, "calibration": layout.calib_toml, "truth": truth, "true_calibration": true_calibration}
    return {**paths, "videos": layout.videos} if render is not None else paths
