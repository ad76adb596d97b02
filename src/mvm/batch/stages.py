"""One stage of one clip, as a worker runs it: the stage of :data:`mvm.stages.SCENE_STAGES`
(the same objects ``mvm run`` runs), the files it commits, their checksum and the clip's
statistics.

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
from dataclasses import dataclass
from pathlib import Path

from threadpoolctl import threadpool_limits

from mvm.batch.clips import Clip
from mvm.errors import InputError
from mvm.io.coco import read_coco_keypoints
from mvm.io.layout import DEFAULT_OUTPUT, SceneLayout
from mvm.io.scene_dir import load_poses3d_document, parse_poses3d
from mvm.stages import SCENE_STAGES, Job, SceneOptions, scene_stage
from mvm.stages import run_stage as run_scene_stage

#: The stages in pipeline order.
STAGES = tuple(stage.name for stage in SCENE_STAGES)
#: Stages that use an accelerator when one is available (the network's detection).
GPU_STAGES = ("detect",)
#: Exceptions worth another attempt: the machine, not the clip, is at fault.
TRANSIENT = (OSError, MemoryError, TimeoutError, ConnectionError)
#: The settings of every clip's stages (the ``[batch]`` table and the stages' own tables).
BatchOptions = SceneOptions


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


def job_of(clip: Clip, options: SceneOptions | None = None) -> Job:
    """The clip as the stages take it (``options`` None: the defaults, built when called: they
    import the video stages). Each clip's SfM runs on one thread: the clips run in parallel (the
    thread count is not among the settings its record keeps)."""
    options = options or SceneOptions()
    options = options.replace(sfm=dataclasses.replace(options.sfm, threads=1))
    return Job(Path(clip.scene), options, None if clip.video is None else Path(clip.video),
               None if clip.detections is None else Path(clip.detections))


def output_files(clip: Clip, stage: str, options: SceneOptions | None = None) -> list[Path]:
    """The files ``stage`` commits for ``clip``, sorted (an empty list when absent)."""
    return scene_stage(stage).files(job_of(clip, options))


def stage_reason(clip: Clip, stage: str, options: SceneOptions) -> str | None:
    """Why ``stage`` of ``clip`` must run (None: its outputs are there and their record says
    they were made from the inputs and settings it would use now)."""
    return scene_stage(stage).why(job_of(clip, options))


def not_applicable(clip: Clip, stage: str) -> str | None:
    """Why ``stage`` has nothing to do for ``clip`` (None when it applies)."""
    return scene_stage(stage).applies(job_of(clip))


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


def clip_stats(scene: str | Path, output: str = DEFAULT_OUTPUT) -> dict:
    """The clip's row of the data set statistics, from ``poses2d.json`` and ``poses3d.json``:
    frames, 2D poses, matched and unmatched 2D poses, 3D poses (persons), G_k (2D joints per
    triangulated joint), reconstructed joints, E_R.

    Both files are read by the guarded readers: a corrupt one raises :class:`InputError`
    naming it (the clip's failure, never the batch's)."""
    scene = Path(scene)
    stats: dict = {}
    layout = SceneLayout(scene, output)
    poses2d = layout.poses2d
    if poses2d.exists():
        coco = read_coco_keypoints(poses2d, root=scene)
        stats["frames"] = len(coco.file_names)
        stats["poses2d"] = len(coco.ann_ids)
    poses3d = layout.poses3d
    if poses3d.exists():
        document = load_poses3d_document(poses3d, root=scene)
        parse_poses3d(document, poses3d)
        metrics = document.get("metrics", {})
        stats.update(matched=metrics.get("matched_poses"), unmatched=metrics.get("unmatched_poses"),
                     persons=metrics.get("persons"), G_k=metrics.get("G_k"),
                     joints=metrics.get("reconstructed_joints"), E_R_px=metrics.get("E_R_px"))
    return stats


def one_line(error: BaseException) -> str:
    if isinstance(error, InputError):
        return str(error)
    text = str(error).strip().splitlines()
    return f"{type(error).__name__}: {text[0][:300]}" if text else type(error).__name__


def run_stage(clip: Clip, stage: str, options: SceneOptions, force: bool = False) -> StageResult:
    """Run ``stage`` on ``clip`` with single-threaded BLAS (``force``: made again whatever its
    record says); never raises for a bad clip."""
    declared = scene_stage(stage)
    result = StageResult(clip.id, stage, ok=False, pid=os.getpid(), host=socket.gethostname())
    t = time.perf_counter()
    try:
        job = job_of(clip, options)
        with threadpool_limits(limits=1):
            if stage == "detect" and options.checkpoint is not None and "torch" in sys.modules:
                sys.modules["torch"].set_num_threads(1)
            run_scene_stage(declared, job, force)
            files = declared.files(job)
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
