"""``mvm run``: one video through the scene stages (:data:`mvm.stages.RUN_STAGES`): frames ->
cameras -> 2D poses + appearance -> reconstruction in metres. Every stage writes its outputs
atomically into the scene directory with a record of its inputs and settings
(:mod:`mvm.io.provenance`), and is kept on a rerun when they are unchanged; a stage whose inputs
or settings changed is redone, and so is every stage whose inputs it changes. ``force`` names
stages to redo whatever the records say (or ``"all"``). Everything checkable in a second is
checked before the first frame is decoded (:func:`check_run`).
"""
from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from mvm.core.config import Config
from mvm.errors import InputError
from mvm.io.layout import DEFAULT_OUTPUT
from mvm.stages import RUN_STAGES, Job, SceneOptions, run_stages
from mvm.stages.scene_reconstruct import Reconstruction
from mvm.video.detect import DetectOptions, FramePoses
from mvm.video.frames import FrameIndex, FrameOptions
from mvm.video.sfm import SfmOptions, SfmReport

log = logging.getLogger(__name__)

#: The names of the stages ``mvm run`` runs.
STAGES = tuple(stage.name for stage in RUN_STAGES)


@dataclass
class RunReport:
    """What :func:`run_video` did: each stage's result and seconds; ``why``: per stage, why it
    was made by this run (None: kept, up to date)."""

    frames: FrameIndex | None = None
    sfm: SfmReport | None = None
    detections: FramePoses | None = None
    reconstruction: Reconstruction | None = None
    seconds: dict = field(default_factory=dict)
    why: dict = field(default_factory=dict)


def check_run(video: str | Path, scene: str | Path, detections=None, checkpoint=None, detections_format=None,
              cameras=None, frame_options: FrameOptions = FrameOptions(),
              detect_options: DetectOptions = DetectOptions(), output: str = DEFAULT_OUTPUT) -> None:
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
              config: Config | None = None, metric_scale: bool = True, output: str = DEFAULT_OUTPUT,
              force: bool | str | tuple[str, ...] = (),
              progress: Callable[[str, int, int], None] | None = None) -> RunReport:
    """The scene stages on one video (:data:`mvm.stages.RUN_STAGES`, as ``mvm batch`` runs them).

    Args:
        video: the video file; scene: the scene directory to fill.
        detections / checkpoint: imported 2D poses, or the mvm network's checkpoint; with
            neither, ``detect_options.detector`` (``rtmo``, ``rtmpose``, ``yolo-pose``) detects them.
        cameras: an existing COLMAP model directory or a RealEstate10K / MannequinChallenge
            camera file to use instead of SfM.
        metric_scale: scale the world (``sparse/`` and the 3D poses) to metres from the people's
            bone lengths before ``poses3d.json`` is written; otherwise the scale is only recorded.
        force: stages to redo (names from :data:`STAGES`), ``True`` / ``"all"`` for every stage;
            a forced stage also forces the stages after it. Without it a stage is redone when
            its inputs or settings changed (the report's ``why`` says which).
        progress: ``progress(stage, done, total)``.
    """
    scene = Path(scene)
    check_run(video, scene, detections, checkpoint, detections_format, cameras, frame_options, detect_options,
              output)
    options = SceneOptions(config=config or Config(), frames=frame_options, sfm=sfm_options, detect=detect_options,
                           output=output, checkpoint=None if checkpoint is None else str(checkpoint),
                           metric_scale=metric_scale)
    job = Job(scene, options, Path(video), None if detections is None else Path(detections), detections_format,
              None if cameras is None else Path(cameras), progress)
    done = run_stages(job, RUN_STAGES, force)
    report = RunReport(done["frames"].result, done["sfm"].result, done["detect"].result,
                       done["reconstruct"].result)
    report.seconds = {name: d.seconds for name, d in done.items()}
    report.why = {name: d.why for name, d in done.items()}
    return report
