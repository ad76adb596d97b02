"""``RIG_DIR`` in; per-instant 3D poses (JSON Lines), one ``.trc`` per track and a recap out."""
from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from mvm.core.config import Config
from mvm.core.keypoints import COCO_KEYPOINTS
from mvm.io.files import atomic_write_json, atomic_write_text
from mvm.io.trc import to_opensim, write_trc
from mvm.rig.instants import InstantPersons, reconstruct_instants
from mvm.rig.options import RigOptions
from mvm.rig.recap import recap
from mvm.rig.rigdir import RigData, read_rig
from mvm.rig.tracking import link_tracks, smooth_tracks, track_series

log = logging.getLogger(__name__)

POSES3D_LINES_FORMAT = "mvm.rig.poses3d/1"


@dataclass
class RigResult:
    """``persons`` of every instant with ``track: (Q,)`` ids; ``X: (Q, 17, 3)`` the (smoothed)
    joints written out; ``recap`` (see :func:`mvm.rig.recap.recap`); paths written; timings."""

    rig: RigData
    persons: InstantPersons
    track: np.ndarray
    X: np.ndarray
    recap: dict
    outputs: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)


def _number(v, digits=6):
    return round(float(v), digits) if math.isfinite(v) else None


def poses3d_lines(frames: np.ndarray, persons: InstantPersons, X: np.ndarray, track: np.ndarray,
                  camera_names) -> str:
    """One JSON object per instant: ``{"format", "frame", "persons": [{"id" (track), "keypoints3d"
    [[x, y, z, score] | [null, null, null, 0]], "members" {camera: pose index in that camera's
    frame}, "views_per_joint", "reprojection_error_px"}]}``."""
    lines = []
    bounds = np.searchsorted(persons.instant, np.arange(len(frames) + 1))
    views = (persons.inliers & np.isfinite(X).all(-1)[:, None, :]).sum(1)
    for t, frame in enumerate(frames):
        out = []
        for q in range(bounds[t], bounds[t + 1]):
            kp = [[_number(c) for c in X[q, j]] + [round(float(persons.scores[q, j]), 4)]
                  if np.isfinite(X[q, j]).all() else [None, None, None, 0.0] for j in range(len(COCO_KEYPOINTS))]
            out.append({"id": int(track[q]), "keypoints3d": kp,
                        "members": {camera_names[v]: int(m) for v, m in enumerate(persons.members[q]) if m >= 0},
                        "views_per_joint": views[q].tolist(),
                        "reprojection_error_px": _number(persons.reprojection_error_px[q], 4)})
        lines.append(json.dumps({"format": POSES3D_LINES_FORMAT, "frame": int(frame), "persons": out},
                                allow_nan=False))
    return "\n".join(lines) + ("\n" if lines else "")


def _local_members(persons: InstantPersons, rig: RigData) -> InstantPersons:
    """Members as the pose's index within its camera and frame (as in the input files)."""
    det = rig.detections
    key = det.instant * (det.view.max() + 1 if len(det) else 1) + det.view
    order = np.argsort(key, kind="stable")
    rank = np.empty(len(key), dtype=int)
    starts = np.searchsorted(key[order], key[order])
    rank[order] = np.arange(len(key)) - starts
    members = np.where(persons.members >= 0, rank[np.maximum(persons.members, 0)], -1)
    return InstantPersons(persons.X, persons.instant, persons.scores, members, persons.inliers,
                          persons.valid, persons.errors, persons.reprojection_error_px)


def write_tracks(directory: Path, frames: np.ndarray, X: np.ndarray, instant: np.ndarray,
                 track: np.ndarray, options: RigOptions) -> list[Path]:
    """One ``track_<id>.trc`` per track of at least ``min_track_length`` instants (Y up, metres)."""
    paths = []
    for k in np.unique(track):
        if (track == k).sum() < options.min_track_length:
            continue
        times, series = track_series(X, instant, track, k)
        path = directory / f"track_{int(k)}.trc"
        write_trc(path, to_opensim(series, options.up, options.metres_per_unit), COCO_KEYPOINTS,
                  options.frame_rate, frames=frames[times])
        paths.append(path)
    return paths


def reconstruct_rig(rig_dir: str | Path, config: Config | None = None, options: RigOptions | None = None,
                    calib: str | Path | None = None, frames: str | None = None, output: str | Path | None = None,
                    prior=None, progress: Callable[[int, int], None] | None = None) -> RigResult:
    """Reconstruct, track and write a rig: ``<output>/poses3d.jsonl``, ``<output>/tracks/*.trc``,
    ``<output>/recap.json`` (``output`` defaults to ``RIG_DIR/mvm``)."""
    config = config or Config()
    options = options or RigOptions()
    timings = {}
    t0 = time.perf_counter()
    rig = read_rig(rig_dir, calib, frames)
    timings["read_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    persons = reconstruct_instants(rig.calibration.cameras, rig.detections, config, prior,
                                   options.batch_size, progress)
    timings["reconstruct_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    unit = 1.0 / options.metres_per_unit
    track = link_tracks(persons.X, persons.instant, options.max_link_distance_m * unit, options.max_gap)
    X = smooth_tracks(persons.X, persons.instant, track, options.smoothing, rate=options.frame_rate,
                      cutoff_hz=options.cutoff_hz, order=options.filter_order, window=options.savgol_window)
    timings["tracking_s"] = time.perf_counter() - t0
    names = rig.calibration.cameras.names
    summary = recap(persons, names, len(rig.frames), len(rig.detections))
    summary["tracks"] = int(len(np.unique(track)))
    summary["instants_per_s"] = round(len(rig.frames) / max(timings["reconstruct_s"], 1e-9), 2)
    out_dir = Path(output) if output else Path(rig_dir) / "mvm"
    outputs = {"poses3d": out_dir / "poses3d.jsonl", "recap": out_dir / "recap.json"}
    atomic_write_text(outputs["poses3d"], poses3d_lines(rig.frames, _local_members(persons, rig), X, track, names))
    outputs["tracks"] = write_tracks(out_dir / "tracks", rig.frames, X, persons.instant, track, options)
    timings["write_s"] = time.perf_counter() - t0 - timings["tracking_s"]
    atomic_write_json(outputs["recap"], {**summary, "timings_s": {k: round(v, 4) for k, v in timings.items()},
                                         "config": asdict(config), "options": asdict(options),
                                         "calibration": rig.calibration.metadata.get("source"),
                                         "pose_format": rig.pose_format}, indent=1)
    return RigResult(rig, persons, track, X, summary, outputs, timings)
