"""From a video file to 3D poses: frames -> cameras -> 2D poses + appearance -> reconstruction
-> metric scale. Every stage writes its outputs atomically into the scene directory with a
record of its inputs and settings (:mod:`mvm.io.provenance`), and is kept on a rerun when they
are unchanged; a stage whose inputs or settings changed is redone, and so is every stage whose
inputs it changes. ``force`` names stages to redo whatever the records say (or ``"all"``).
Everything checkable in a second is checked before the first frame is decoded
(:func:`check_run`).
"""
from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from mvm.core.config import Config
from mvm.errors import InputError
from mvm.io.checks import load_json_object, number
from mvm.io.files import atomic_write_json
from mvm.io.outputs import atomic_replace_dir
from mvm.io.provenance import fingerprint, fingerprints, forget, why_redo, write_record
from mvm.io.scene_dir import RECONSTRUCT_STAGE, reconstruction_inputs
from mvm.video.detect import DetectOptions, FramePoses, detect_scene
from mvm.video.frames import FrameIndex, FrameOptions, extract_frames
from mvm.video.metric_scale import people_scale
from mvm.video.sfm import (
    SCALE_FILE,
    SFM_DIR,
    SfmOptions,
    SfmReport,
    import_colmap,
    import_trajectory,
    run_sfm,
)

log = logging.getLogger(__name__)

STAGES = ("frames", "sfm", "detect", "reconstruct")


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


@dataclass
class ReconstructReport:
    persons: int
    metrics: dict
    scale: ScaleRecord
    path: Path
    skipped: bool = False
    #: Why the reconstruction was made by this call (None: kept, up to date).
    why: str | None = None


def _read_scale(scene: Path) -> float:
    """Metres per unit of ``sparse/`` relative to SfM's units so far (1 when never scaled)."""
    path = scene / SFM_DIR / SCALE_FILE
    if not path.is_file():
        return 1.0
    try:
        data = load_json_object(path, root=scene)
        return number(data.get("sfm_units_per_model_unit"), path, "sfm_units_per_model_unit")
    except InputError as e:
        log.warning("%s; assuming the model is in SfM units", e)
        return 1.0


def scale_model(scene: str | Path, s: float) -> None:
    """Multiply the world of ``scene/sparse`` by ``s`` (camera centres and points)."""
    import pycolmap

    from mvm.io.colmap import find_model_dir

    scene = Path(scene)
    rec = pycolmap.Reconstruction(str(find_model_dir(scene / "sparse")))
    rec.transform(pycolmap.Sim3d(float(s), pycolmap.Rotation3d(np.eye(3)), np.zeros(3)))
    atomic_replace_dir(lambda tmp: rec.write_binary(str(tmp)), scene / "sparse", replace_unmarked=True)


def reconstruct_scene(scene: str | Path, config: Config | None = None, output: str = "mvm",
                      metric_scale: bool = True, force: bool = False) -> ReconstructReport:
    """Reconstruct ``scene`` (``mvm.scenes.reconstruct_dir``) and give it a metric scale
    from the people's bone lengths, recorded under ``"scale"`` in ``poses3d.json``.

    With ``metric_scale`` the model in ``sparse/`` and the 3D poses are multiplied by s*, so
    that the world is in metres; otherwise s* is only recorded. Kept when the record of
    ``poses3d.json`` says it was made from this ``poses2d.json`` and ``sparse/`` (as scaled)
    with these settings, unless ``force``; the report's ``why`` says why it was made again.
    """
    from mvm.io.scene_dir import load_poses3d_document, poses3d_document, write_poses3d
    from mvm.scenes import reconstruct_dir

    scene = Path(scene)
    out = scene / output / "poses3d.json"
    config = (config or Config()).for_driver("scene")
    inputs = reconstruction_inputs(scene)
    settings = {"config": asdict(config), "metric_scale": metric_scale}
    hashed = fingerprints(inputs)
    why = "forced" if force else why_redo(out, inputs, settings, RECONSTRUCT_STAGE, hashed=hashed)
    if why is None:
        log.info("%s is up to date (made from this poses2d.json and sparse/ with these settings)", out)
        doc = load_poses3d_document(out, root=scene)
        record = (ScaleRecord(**doc["scale"]) if isinstance(doc.get("scale"), dict)
                  else ScaleRecord("none", None, None, False))
        return ReconstructReport(len(doc.get("persons", [])), doc.get("metrics", {}), record, out, skipped=True)
    log.info("%s: reconstructing: %s", scene, why)
    result = reconstruct_dir(scene, config, output)
    s, bones = people_scale(result.persons.keypoints3d) if len(result.persons) else (float("nan"), 0)
    before = _read_scale(scene)
    if not np.isfinite(s) or s <= 0:
        log.warning("%s: no measurable bones; the world keeps the SfM's units", scene)
        record = ScaleRecord("none", None, None, False)
    elif metric_scale:
        scale_model(scene, s)
        result.persons.keypoints3d = result.persons.keypoints3d * s
        record = ScaleRecord("people", 1.0, before * s, True, bones)
        atomic_write_json(scene / SFM_DIR / SCALE_FILE, {"source": "people", "sfm_units_per_model_unit": before * s})
        hashed["sparse"] = fingerprint(scene / "sparse")                # the model as scaled
    else:
        record = ScaleRecord("people", s, before * s, False, bones)
    document = poses3d_document(result.persons, result.scene.poses, result.metrics,
                                {"timings_s": {k: round(v, 4) for k, v in result.timings.items()},
                                 "config": asdict(config), "scale": record.to_json()})
    forget(out)
    write_poses3d(out, document)
    write_record(out, RECONSTRUCT_STAGE, inputs, settings, hashed)
    return ReconstructReport(len(result.persons), result.metrics, record, out, why=why)


@dataclass
class RunReport:
    """What :func:`run_video` did: each stage's result and seconds; ``why``: per stage, why it
    was made by this run (None: kept, up to date)."""

    frames: FrameIndex | None = None
    sfm: SfmReport | None = None
    detections: FramePoses | None = None
    reconstruction: ReconstructReport | None = None
    seconds: dict = field(default_factory=dict)
    why: dict = field(default_factory=dict)


def _forced(force, stage: str) -> bool:
    if force is True or force == "all":
        return True
    return bool(force) and stage in force


def check_run(video: str | Path, scene: str | Path, detections=None, checkpoint=None, detections_format=None,
              cameras=None, frame_options: FrameOptions = FrameOptions(),
              detect_options: DetectOptions = DetectOptions(), output: str = "mvm") -> None:
    """Everything :func:`run_video` can check in a second, checked before any work, each problem
    one :class:`InputError` line: the video and the cameras exist; the detector's model files
    (every one, named with its option) or the imported detections, read and matched against
    the size the frames will have; the scene directory and its output folder can be written.
    Then the published models the cache lacks are downloaded, before the first heavy step."""
    from dataclasses import replace

    from mvm.io.files import make_dir
    from mvm.io.scene_dir import output_dir
    from mvm.video.detect import detector_kind
    from mvm.video.detectors import check_models, fetch_missing_models
    from mvm.video.frames import frame_size
    from mvm.video.importers import check_detections_fit, imported_keypoints

    video, scene = Path(video), Path(scene)
    if not video.is_file():
        raise InputError(video, None, "video file not found")
    if cameras is not None and not Path(cameras).exists():
        raise InputError(cameras, "--cameras", "not found")
    kind = detector_kind(detect_options, detections, checkpoint)
    if kind == "import":
        if not Path(detections).exists():
            raise InputError(detections, "--import", "not found")
        size = frame_size(video, frame_options)
        if size is not None:
            check_detections_fit(imported_keypoints(detections, detections_format), size, detections)
    else:
        check_models(replace(detect_options, detector=kind), checkpoint)
    make_dir(scene)
    probe = scene / ".mvm-write-check"
    try:
        probe.touch()
        probe.unlink()
    except OSError as e:
        from mvm.io.files import output_error

        raise output_error(scene, e) from None
    output_dir(scene, output)
    if kind in ("rtmo", "rtmpose", "yolo-pose"):
        fetch_missing_models(replace(detect_options, detector=kind))


def run_video(video: str | Path, scene: str | Path, *, detections: str | Path | None = None,
              checkpoint: str | Path | None = None, detections_format: str | None = None,
              cameras: str | Path | None = None, frame_options: FrameOptions = FrameOptions(),
              sfm_options: SfmOptions = SfmOptions(), detect_options: DetectOptions = DetectOptions(),
              config: Config | None = None, metric_scale: bool = True, output: str = "mvm",
              force: bool | str | tuple[str, ...] = (),
              progress: Callable[[str, int, int], None] | None = None) -> RunReport:
    """The whole pipeline on one video.

    Args:
        video: the video file; scene: the scene directory to fill.
        detections / checkpoint: imported 2D poses, or the mvm network's checkpoint; with
            neither, ``detect_options.detector`` (``rtmo``, ``rtmpose``, ``yolo-pose``) detects them.
        cameras: an existing COLMAP model directory or a RealEstate10K / MannequinChallenge
            camera file to use instead of SfM.
        force: stages to redo (names from :data:`STAGES`), ``True`` / ``"all"`` for every stage;
            a forced stage also forces the stages after it. Without it a stage is redone when
            its inputs or settings changed (the report's ``why`` says which).
        progress: ``progress(stage, done, total)``.
    """
    scene = Path(scene)
    check_run(video, scene, detections, checkpoint, detections_format, cameras, frame_options, detect_options,
              output)
    report = RunReport()
    redo = False

    def step(name):
        nonlocal redo
        redo = redo or _forced(force, name)
        return redo

    def tick(stage):
        return (lambda done, total: progress(stage, done, total)) if progress else None

    t = time.perf_counter()
    report.frames = extract_frames(video, scene, frame_options, force=step("frames"), progress=tick("frames"))
    report.seconds["frames"] = time.perf_counter() - t

    t = time.perf_counter()
    again = step("sfm")
    if cameras is None:
        report.sfm = run_sfm(scene, sfm_options, force=again, progress=progress)
    elif Path(cameras).is_dir():
        report.sfm = import_colmap(cameras, scene, force=again)
    else:
        report.sfm = import_trajectory(cameras, scene, force=again)
    report.seconds["sfm"] = time.perf_counter() - t

    t = time.perf_counter()
    report.detections = detect_scene(scene, detections, checkpoint, detections_format, detect_options,
                                     force=step("detect"), progress=tick("detect"))
    report.seconds["detect"] = time.perf_counter() - t

    t = time.perf_counter()
    report.reconstruction = reconstruct_scene(scene, config, output, metric_scale, force=step("reconstruct"))
    report.seconds["reconstruct"] = time.perf_counter() - t
    report.why = {"frames": report.frames.why, "sfm": report.sfm.why, "detect": report.detections.why,
                  "reconstruct": report.reconstruction.why}
    for stage, why in report.why.items():
        log.info("%s: %s", stage, "kept: up to date" if why is None else f"redone: {why}")
    return report
