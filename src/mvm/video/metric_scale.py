"""Metric scale of a video's reconstruction from the people themselves (the paper's s*).

SfM is up to scale. With ``l_b`` the median length of bone ``b`` over the reconstructed
persons (model units) and ``l̄_b`` the average adult length (metres), ``s*``
(:func:`mvm.core.keypoints.optimal_scale`) is in metres per model unit. The median over persons
keeps one badly reconstructed person from moving it.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mvm.core.keypoints import MEAN_BONE_LENGTHS_M, bone_lengths, optimal_scale
from mvm.errors import InputError
from mvm.io.checks import load_json_object, number
from mvm.io.files import atomic_write_json
from mvm.io.layout import SPARSE, SceneLayout
from mvm.io.outputs import atomic_replace_dir

log = logging.getLogger(__name__)


def people_scale(poses3d: np.ndarray, min_persons: int = 1) -> tuple[float, int]:
    """Metres per model unit from the persons' bones.

    ``poses3d: (P, 17, 3)`` model units (NaN: missing) -> ``(s*, bones used)``; ``s*`` is NaN
    when no bone is measured by at least ``min_persons`` persons.

    >>> from mvm.sim.people import STANDING
    >>> round(people_scale(STANDING[None] / 2.0)[0], 1)
    2.0
    """
    poses3d = np.asarray(poses3d, dtype=float)
    if poses3d.ndim != 3 or poses3d.shape[1:] != (17, 3):
        raise ValueError(f"poses3d: expected shape (P, 17, 3), got {poses3d.shape}")
    lengths = bone_lengths(poses3d)                                # (P, 12)
    measured = np.isfinite(lengths).sum(0) >= max(min_persons, 1)
    if not measured.any():
        return float("nan"), 0
    median = np.nanmedian(lengths[:, measured], axis=0)
    return float(optimal_scale(median, MEAN_BONE_LENGTHS_M[measured])), int(measured.sum())


@dataclass
class ScaleRecord:
    """The scale of a scene's world. ``metres_per_unit``: metres per unit of the coordinates
    now in ``sparse/`` and ``poses3d.json``; ``sfm_metres_per_unit``: metres per unit of the
    cameras as SfM (or the import) produced them; ``bones``: bone types measured."""

    source: str
    metres_per_unit: float | None
    sfm_metres_per_unit: float | None
    applied_to_model: bool
    bones: int = 0

    def to_json(self) -> dict:
        def r(v):
            return None if v is None or not np.isfinite(v) else round(float(v), 6)
        return {"source": self.source, "metres_per_unit": r(self.metres_per_unit),
                "sfm_metres_per_unit": r(self.sfm_metres_per_unit),
                "applied_to_model": self.applied_to_model, "bones": self.bones}


def _read_scale(scene: Path) -> float:
    """Metres per unit of ``sparse/`` relative to SfM's units so far (1 when never scaled, and,
    with a warning, when ``sfm/scale.json`` cannot be read as a positive number)."""
    path = SceneLayout(scene).scale_file
    if not path.is_file():
        return 1.0
    try:
        data = load_json_object(path, root=scene)
        value = number(data.get("sfm_units_per_model_unit"), path, "sfm_units_per_model_unit")
        if value <= 0:
            raise InputError(path, "sfm_units_per_model_unit", f"expected a positive number, got {value:g}")
        return value
    except InputError as e:
        log.warning("%s; assuming the model is in SfM units", e)
        return 1.0


def scale_model(scene: str | Path, s: float) -> None:
    """Multiply the world of ``scene/sparse`` by ``s`` (camera centres and points)."""
    import pycolmap

    from mvm.io.colmap import find_model_dir

    scene = Path(scene)
    rec = pycolmap.Reconstruction(str(find_model_dir(scene / SPARSE)))
    rec.transform(pycolmap.Sim3d(float(s), pycolmap.Rotation3d(np.eye(3)), np.zeros(3)))
    atomic_replace_dir(lambda tmp: rec.write_binary(str(tmp)), scene / SPARSE, replace_unmarked=True)


def apply_metric_scale(scene: str | Path, persons, metric_scale: bool) -> ScaleRecord:
    """Measure s* of the reconstructed ``persons`` of ``scene`` (:func:`people_scale`) and, with
    ``metric_scale``, put the world in metres: ``scene/sparse`` (and ``sfm/scale.json``, the
    scale relative to SfM's units) rewritten and ``persons.keypoints3d`` multiplied by s*, in
    place; otherwise s* is only measured. Returns the record ``poses3d.json`` keeps under
    ``"scale"``."""
    scene = Path(scene)
    s, bones = people_scale(persons.keypoints3d) if len(persons) else (float("nan"), 0)
    before = _read_scale(scene)
    if not np.isfinite(s) or s <= 0:
        log.warning("%s: no measurable bones; the world keeps the SfM's units", scene)
        return ScaleRecord("none", None, None, False)
    if not metric_scale:
        return ScaleRecord("people", s, before * s, False, bones)
    scale_model(scene, s)
    persons.keypoints3d = persons.keypoints3d * s
    atomic_write_json(SceneLayout(scene).scale_file, {"source": "people", "sfm_units_per_model_unit": before * s})
    return ScaleRecord("people", 1.0, before * s, True, bones)
