"""One stage of one clip, as a worker runs it: the call of the stage's library function, the
files it commits, their checksum and the clip's statistics.

Everything here runs in a worker process (a pool child or a Ray task) and returns a picklable
:class:`StageResult`; it never touches the manifest. An error becomes a failed result (the
error's one line), so a bad clip never stops the others.
"""
from __future__ import annotations

import dataclasses
import hashlib
import os
import socket
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from threadpoolctl import threadpool_limits

from mvm.batch.clips import Clip
from mvm.core.config import Config, check_settings, setting
from mvm.errors import InputError
from mvm.io.coco import read_coco_keypoints
from mvm.io.scene_dir import load_poses3d_document, parse_poses3d

if TYPE_CHECKING:
    from mvm.video.detect import DetectOptions
    from mvm.video.frames import FrameOptions
    from mvm.video.sfm import SfmOptions

#: The stages in pipeline order.
STAGES = ("frames", "sfm", "detect", "reconstruct", "export")
#: Stages that use an accelerator when one is available (the network's detection).
GPU_STAGES = ("detect",)
SUPERVISION_DIR = "supervision"
#: Exceptions worth another attempt: the machine, not the clip, is at fault.
TRANSIENT = (OSError, MemoryError, TimeoutError, ConnectionError)


def _default(path: str):
    """A factory of the default of the settings dataclass ``module:class``, imported when
    called (the video stages' modules import OpenCV)."""
    def make():
        import importlib

        module, name = path.split(":")
        return getattr(importlib.import_module(module), name)()
    return make


@dataclass(frozen=True)
class BatchOptions:
    """Settings of every clip's stages: each stage's own settings (the tables ``[reconstruct]``,
    ``[frames]``, ``[sfm]`` and ``[detect]`` of a settings file, as the single commands read
    them) and the batch's own (``[batch]``)."""

    #: The reconstruction's settings (the ``[reconstruct]`` table). [-]
    config: Config = field(default_factory=Config)
    #: The frame sampling of ``frames`` (the ``[frames]`` table). [-]
    frames: FrameOptions = field(default_factory=_default("mvm.video.frames:FrameOptions"))
    #: The structure from motion of ``sfm`` (the ``[sfm]`` table); each clip's SfM runs on one
    #: thread, as the clips run in parallel. [-]
    sfm: SfmOptions = field(default_factory=_default("mvm.video.sfm:SfmOptions"))
    #: The 2D detection of ``detect`` (the ``[detect]`` table): ``detector`` "rtmo" or "rtmpose"
    #: detects every clip's frames; None: ``checkpoint``, else each clip's imported detections. [-]
    detect: DetectOptions = field(default_factory=_default("mvm.video.detect:DetectOptions"))
    #: Folder of each scene directory receiving ``poses3d.json`` and the supervision. [name]
    output: str = "mvm"
    #: The pose network's checkpoint for ``detect``; None: a detector, or imported detections. [path]
    checkpoint: str | None = None
    #: ``export``: persons with fewer labelled joints in a frame get no annotation. [joints]
    min_keypoints: int = setting(3, ge=1, le=17)

    def __post_init__(self):
        check_settings(self)

    def replace(self, **changes) -> BatchOptions:
        return dataclasses.replace(self, **changes)


@dataclass
class StageResult:
    """What a worker reports for one (clip, stage): ``ok``; ``error`` (one line) and whether
    it is ``transient``; ``seconds``; ``checksum`` (sha256 of the committed files) and
    ``files`` (their count); ``stats`` of the clip (after ``reconstruct`` and ``export``)."""

    clip: str
    stage: str
    ok: bool
    seconds: float = 0.0
    error: str | None = None
    transient: bool = False
    checksum: str | None = None
    files: int = 0
    stats: dict | None = None
    pid: int = 0
    host: str = ""


def output_files(scene: str | Path, stage: str, output: str = "mvm") -> list[Path]:
    """The files ``stage`` commits in ``scene``, sorted (an empty list when absent)."""
    scene = Path(scene)
    if stage == "frames":
        index = scene / "frames.json"
        if not index.is_file():
            return []
        from mvm.video.frames import read_frame_index

        try:
            names = list(read_frame_index(scene).names)
        except InputError:
            return [index]
        return [index] + [scene / "frames" / n for n in sorted(names)]
    if stage == "sfm":
        files = sorted(p for p in (scene / "sparse").rglob("*") if p.is_file()) if (scene / "sparse").is_dir() else []
        report = scene / "sfm" / "report.json"
        return ([report] if report.is_file() else []) + files
    path = {"detect": scene / "poses2d.json", "reconstruct": scene / output / "poses3d.json",
            "export": scene / output / SUPERVISION_DIR / "annotations.json"}[stage]
    return [path] if path.is_file() else []


def record_of(scene: str | Path, stage: str, output: str = "mvm") -> Path:
    """The output whose record (:mod:`mvm.io.provenance`) says what ``stage`` made it from."""
    scene = Path(scene)
    return {"frames": scene / "frames.json", "sfm": scene / "sfm" / "report.json", "detect": scene / "poses2d.json",
            "reconstruct": scene / output / "poses3d.json",
            "export": scene / output / SUPERVISION_DIR}[stage]


#: The stages' names in the reasons of a rerun.
STAGE_NAMES = {"frames": "the frame extraction", "sfm": "the camera estimation", "detect": "the detection",
               "reconstruct": "the reconstruction", "export": "the export"}


def stage_inputs(clip: Clip, stage: str, output: str = "mvm") -> dict:
    """The inputs of ``stage`` of ``clip`` that can be named without its settings (for
    ``mvm status``; :func:`stage_reason` adds the rest)."""
    from mvm.io.scene_dir import reconstruction_inputs

    scene = Path(clip.scene)
    if stage == "frames":
        return {Path(clip.video).name: Path(clip.video)} if clip.video else {}
    if stage == "sfm":
        return {"frames.json": scene / "frames.json", "frames": scene / "frames"}
    if stage == "detect":
        inputs = {"frames.json": scene / "frames.json", "frames": scene / "frames"}
        return {**inputs, "detections": Path(clip.detections)} if clip.detections else inputs
    if stage == "export":
        from mvm.net.supervision import export_inputs

        return export_inputs([scene], output)
    return reconstruction_inputs(scene)


def _export_settings(options: BatchOptions) -> dict:
    return {"min_keypoints": options.min_keypoints}


def stage_reason(clip: Clip, stage: str, options: BatchOptions) -> str | None:
    """Why ``stage`` of ``clip`` must run (None: its outputs are there and their record says
    they were made from the inputs and settings it would use now). A camera model or 2D poses
    without a record were made elsewhere: the clip's input, kept."""
    from dataclasses import replace

    from mvm.io.provenance import read_record, why_redo
    from mvm.io.scene_dir import reconstruction_inputs

    scene = Path(clip.scene)
    output = options.output
    if stage == "frames":
        from mvm.video.frames import frames_reason

        return frames_reason(clip.video, scene, options.frames)
    if stage == "sfm":
        from mvm.video.sfm import sfm_inputs, sfm_settings

        report = scene / "sfm" / "report.json"
        if (scene / "sparse").is_dir() and not report.is_file():
            return None                                     # cameras made elsewhere
        return why_redo(report, sfm_inputs(scene), sfm_settings(replace(options.sfm, threads=1)),
                        STAGE_NAMES[stage], exists=report.is_file() and (scene / "sparse").is_dir())
    if stage == "detect":
        from mvm.io.pose_format import pose_format
        from mvm.video.detect import detect_inputs, detect_settings, registered_names

        out = scene / "poses2d.json"
        if out.is_file() and read_record(out) is None:
            return None                                     # 2D poses made elsewhere
        kind = options.detect.detector or ("mvm" if options.checkpoint is not None else "import")
        source = clip.detections if kind == "import" else None
        if kind == "import" and source is None:
            return "no output yet" if not out.is_file() else None
        fmt = pose_format(source)[0] if source is not None else None
        inputs = detect_inputs(scene, registered_names(scene), source, options.checkpoint if kind == "mvm" else None)
        return why_redo(out, inputs, detect_settings(kind, fmt, options.detect), STAGE_NAMES[stage])
    if stage == "reconstruct":
        return why_redo(scene / output / "poses3d.json", reconstruction_inputs(scene),
                        {"config": dataclasses.asdict(options.config.for_driver("scene")), "metric_scale": False},
                        STAGE_NAMES[stage])
    return why_redo(record_of(scene, stage, output), stage_inputs(clip, stage, output), _export_settings(options),
                    STAGE_NAMES[stage], exists=(scene / output / SUPERVISION_DIR / "annotations.json").is_file())


def not_applicable(clip: Clip, stage: str) -> str | None:
    """Why ``stage`` has nothing to do for ``clip`` (None when it applies)."""
    if stage == "frames" and clip.video is None:
        return "no video: a scene directory"
    return None


def checksum(scene: str | Path, files: list[Path]) -> str:
    """sha256 over the files' paths (relative to ``scene``) and contents."""
    h = hashlib.sha256()
    scene = Path(scene)
    for path in files:
        h.update(path.relative_to(scene).as_posix().encode() + b"\0")
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
        h.update(b"\0")
    return h.hexdigest()


def clip_stats(scene: str | Path, output: str = "mvm") -> dict:
    """The clip's row of the data set statistics, from ``poses2d.json`` and ``poses3d.json``:
    frames, 2D poses, matched and unmatched 2D poses, 3D poses (persons), G_k (2D joints per
    triangulated joint), reconstructed joints, E_R.

    Both files are read by the guarded readers: a corrupt one raises :class:`InputError`
    naming it (the clip's failure, never the batch's)."""
    scene = Path(scene)
    stats: dict = {}
    poses2d = scene / "poses2d.json"
    if poses2d.exists():
        coco = read_coco_keypoints(poses2d, root=scene)
        stats["frames"] = len(coco.file_names)
        stats["poses2d"] = len(coco.ann_ids)
    poses3d = scene / output / "poses3d.json"
    if poses3d.exists():
        document = load_poses3d_document(poses3d, root=scene)
        parse_poses3d(document, poses3d)
        metrics = document.get("metrics", {})
        stats.update(matched=metrics.get("matched_poses"), unmatched=metrics.get("unmatched_poses"),
                     persons=metrics.get("persons"), G_k=metrics.get("G_k"),
                     joints=metrics.get("reconstructed_joints"), E_R_px=metrics.get("E_R_px"))
    return stats


def _frames(clip: Clip, options: BatchOptions) -> None:
    from mvm.video.frames import extract_frames

    extract_frames(clip.video, clip.scene, options.frames)


def _sfm(clip: Clip, options: BatchOptions) -> None:
    from dataclasses import replace

    from mvm.video.sfm import run_sfm

    run_sfm(clip.scene, replace(options.sfm, threads=1))


def _detect(clip: Clip, options: BatchOptions) -> None:
    from mvm.video.detect import detect_scene

    if options.detect.detector is not None:
        detect_scene(clip.scene, options=options.detect)
        return
    if options.checkpoint is None and clip.detections is None:
        raise InputError(clip.scene, "detect", "no 2D poses: give --checkpoint, or put detections.json or "
                                               "detections/ in the scene directory")
    if options.checkpoint is not None and "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(1)
    source = None if options.checkpoint is not None else clip.detections
    detect_scene(clip.scene, source, options.checkpoint, None, options.detect)


def _reconstruct(clip: Clip, options: BatchOptions) -> None:
    from mvm.scenes import reconstruct_dir

    reconstruct_dir(clip.scene, options.config, options.output)


def _export(clip: Clip, options: BatchOptions) -> None:
    from mvm.io.provenance import fingerprints, forget, write_record
    from mvm.io.scene_dir import output_dir, read_poses3d, read_scene
    from mvm.net.supervision import export_supervision

    scene = Path(clip.scene)
    poses3d = scene / options.output / "poses3d.json"
    if not poses3d.is_file():
        raise InputError(poses3d, None, "not found: the clip is not reconstructed")
    inputs = stage_inputs(clip, "export", options.output)
    hashed = fingerprints(inputs)
    frames = scene / "frames"
    item = (read_scene(scene), read_poses3d(poses3d, root=scene), frames if frames.is_dir() else None)
    folder = output_dir(scene, options.output) / SUPERVISION_DIR
    forget(folder)
    export_supervision([item], folder, link="none", min_keypoints=options.min_keypoints)
    write_record(folder, STAGE_NAMES["export"], inputs, _export_settings(options), hashed)


_RUN = {"frames": _frames, "sfm": _sfm, "detect": _detect, "reconstruct": _reconstruct, "export": _export}


def one_line(error: BaseException) -> str:
    if isinstance(error, InputError):
        return str(error)
    text = str(error).strip().splitlines()
    return f"{type(error).__name__}: {text[0][:300]}" if text else type(error).__name__


def run_stage(clip: Clip, stage: str, options: BatchOptions) -> StageResult:
    """Run ``stage`` on ``clip`` with single-threaded BLAS; never raises for a bad clip."""
    if stage not in _RUN:
        raise ValueError(f"unknown stage {stage!r}: expected one of {', '.join(STAGES)}")
    result = StageResult(clip.id, stage, ok=False, pid=os.getpid(), host=socket.gethostname())
    t = time.perf_counter()
    try:
        with threadpool_limits(limits=1):
            _RUN[stage](clip, options)
            files = output_files(clip.scene, stage, options.output)
            if not files:
                raise InputError(clip.scene, stage, "the stage wrote no output")
            result.checksum = checksum(clip.scene, files)
            result.files = len(files)
            if stage in ("reconstruct", "export"):
                result.stats = clip_stats(clip.scene, options.output)
        result.ok = True
    except Exception as e:  # noqa: BLE001 - every failure is recorded with its clip, the others go on
        result.error = one_line(e)
        result.transient = isinstance(e, TRANSIENT) and not isinstance(e, InputError)
    result.seconds = time.perf_counter() - t
    return result
