"""``mvm status``: what is done, failed and pending in a root's manifest, and the data set's
statistics in the manner of the paper's table (sequences, clips, frames, 2D and 3D poses)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from mvm.batch.clips import Clip, discover_clips
from mvm.batch.manifest import STATES, Manifest
from mvm.batch.runner import TRAINING_SET
from mvm.batch.stages import STAGES, checksum, job_of, output_files
from mvm.errors import InputError
from mvm.io.layout import DEFAULT_OUTPUT


def dataset_statistics(rows: list[tuple[str, dict]]) -> dict:
    """The paper's data set table from the clips' statistics.

    Args:
        rows: ``(sequence, stats)`` per reconstructed clip, ``stats`` as
            :func:`mvm.batch.stages.clip_stats` gives it.
    Returns:
        sequences, clips, frames, unmatched / matched 2D poses, generated 3D poses, average
        clips per sequence, frames per clip and 2D joints per triangulation (G_k averaged over
        all reconstructed joints).
    """
    def total(key):
        return int(sum(s.get(key) or 0 for _, s in rows))

    sequences = len({seq for seq, _ in rows})
    clips = len(rows)
    frames = total("frames")
    joints = total("joints")
    used = sum((s.get("G_k") or 0) * (s.get("joints") or 0) for _, s in rows
               if s.get("G_k") is not None and math.isfinite(s["G_k"]))
    return {"sequences": sequences, "clips": clips, "frames": frames,
            "unmatched_poses2d": total("unmatched"), "matched_poses2d": total("matched"),
            "poses3d": total("persons"),
            "clips_per_sequence": round(clips / sequences, 2) if sequences else None,
            "frames_per_clip": round(frames / clips, 1) if clips else None,
            "joints2d_per_triangulation": round(used / joints, 1) if joints else None}


@dataclass
class Status:
    """The state of a root: ``stages[stage][state]`` counts; ``clips`` counts of clips done,
    failed, running and pending (clips found on disk but not yet in the manifest are pending);
    ``failed``: (clip, stage, error); ``statistics``: :func:`dataset_statistics`;
    ``mismatched``: clips whose committed files no longer match their checksum (with ``verify``);
    ``stale``: (clip, stage, why) of the done stages whose inputs changed since they were made
    (:func:`mvm.io.provenance.stale_reason`; ``mvm batch`` redoes them); ``views``: (clip, stage,
    why) of the pages and overlays the clips have (:data:`mvm.stages.VIEW_STAGES`, made by
    ``mvm report`` and ``mvm overlay``), ``why`` None where up to date."""

    root: Path
    stages: dict
    clips: dict
    failed: list[tuple[str, str, str]]
    statistics: dict
    seconds: dict
    runs: int
    training_set: str | None = None
    mismatched: list[tuple[str, str]] = field(default_factory=list)
    stale: list[tuple[str, str, str]] = field(default_factory=list)
    views: list[tuple[str, str, str | None]] = field(default_factory=list)

    def to_json(self) -> dict:
        return {"root": str(self.root), "clips": self.clips, "stages": self.stages,
                "failed": [{"clip": c, "stage": s, "error": e} for c, s, e in self.failed],
                "statistics": self.statistics, "stage_seconds": self.seconds, "runs": self.runs,
                "training_set": self.training_set,
                "checksum_mismatches": [{"clip": c, "stage": s} for c, s in self.mismatched],
                "stale": [{"clip": c, "stage": s, "why": w} for c, s, w in self.stale],
                "views": [{"clip": c, "stage": s, "why": w} for c, s, w in self.views]}


def clip_state(states: list[str]) -> str:
    """A clip's state from its stages' states."""
    if "failed" in states:
        return "failed"
    if all(s in ("done", "skipped") for s in states):
        return "done"
    if "running" in states:
        return "running"
    return "pending"


def _matches(clip: Clip, row: dict, output: str) -> bool:
    """Whether the committed files of a stage row still hash to its checksum (unreadable or
    missing files do not)."""
    from mvm.stages import SceneOptions

    try:
        files = output_files(clip, row["stage"], SceneOptions(output=output))
        return bool(files) and checksum(clip.scene, files) == row["checksum"]
    except OSError:
        return False


def _stale(clip: Clip, stage: str, output: str) -> str | None:
    """Why the outputs of a done ``stage`` of ``clip`` are out of date (None: they are, as far
    as their record tells, or they have none): the stage's declaration (:mod:`mvm.stages`)
    names its record and its inputs."""
    from mvm.io.provenance import stale_reason
    from mvm.stages import SceneOptions, scene_stage

    declared = scene_stage(stage)
    try:
        job = job_of(clip, SceneOptions(output=output))
        if declared.applies(job) is not None:
            return None
        return stale_reason(declared.record(job), declared.inputs(job))
    except InputError as e:
        return str(e)


def _views(clip: Clip, output: str) -> list[tuple[str, str, str | None]]:
    """(clip, stage, why) of the page and the overlays ``clip`` has in its output folder (the
    declarations of :data:`mvm.stages.VIEW_STAGES`), why None where up to date."""
    from mvm.stages import VIEW_STAGES
    from mvm.stages.view import ViewJob

    job, rows = ViewJob(Path(clip.scene), output), []
    for stage in VIEW_STAGES:
        try:
            if stage.applies(job) is None and stage.record(job).exists():
                rows.append((clip.id, stage.name, stage.why(job)))
        except InputError as e:
            rows.append((clip.id, stage.name, str(e)))
    return rows


def batch_status(root: str | Path, verify: bool = False, output: str = DEFAULT_OUTPUT) -> Status:
    """The state of ``root``'s manifest (:class:`Status`). Every done stage's inputs are hashed
    and compared with its outputs' record (``stale``: what ``mvm batch`` would redo). With
    ``verify``, the files of every committed stage are hashed again and compared with the
    recorded checksum (found under the root where it is now, even when the root was moved).
    The pages and overlays of the clips (``mvm report``, ``mvm overlay``) are checked the same
    way (``views``). Reads only: nothing is written. A manifest that is not one, or a corrupt cell, raises an
    InputError naming the file."""
    root = Path(root)
    manifest = Manifest(root, create=False)
    try:
        clips = {c["id"]: c for c in manifest.clips()}
        rows = manifest.stages()
        runs = len(manifest.runs())
    finally:
        manifest.close()
    try:
        on_disk = discover_clips(root)
    except Exception:  # noqa: BLE001 - the manifest alone still answers
        on_disk = []
    stages = {s: {state: 0 for state in STATES} for s in STAGES if any(r["stage"] == s for r in rows)}
    per_clip: dict[str, list[str]] = {cid: [] for cid in clips}
    failed, seconds, stats_rows, mismatched, stale = [], {}, [], [], []
    found = {c.id: c for c in on_disk}
    for r in rows:
        stages[r["stage"]][r["state"]] += 1
        per_clip.setdefault(r["clip"], []).append(r["state"])
        if r["state"] == "failed":
            failed.append((r["clip"], r["stage"], r["error"] or ""))
        if r["state"] == "done" and r["seconds"] is not None:
            seconds[r["stage"]] = seconds.get(r["stage"], 0.0) + r["seconds"]
        if r["clip"] not in clips:
            raise InputError(manifest.path, f"stages[{r['clip']!r}, {r['stage']!r}].clip", "not in the clips table")
        if r["stage"] == "reconstruct" and r["state"] in ("done", "skipped") and r["stats"]:
            stats_rows.append((clips[r["clip"]]["sequence"], r["stats"]))
        known = clips[r["clip"]]
        clip = Clip(r["clip"], known["sequence"], known["scene"], known["video"])
        if verify and r["state"] == "done" and r["checksum"] and not _matches(clip, r, output):
            mismatched.append((r["clip"], r["stage"]))
        if r["state"] in ("done", "skipped") and known["scene"]:
            clip = found.get(r["clip"]) or clip
            why = _stale(clip, r["stage"], output)
            if why is not None:
                stale.append((r["clip"], r["stage"], why))
    counts = {"total": 0, "done": 0, "failed": 0, "running": 0, "pending": 0}
    for states in per_clip.values():
        counts[clip_state(states)] += 1
    counts["pending"] += sum(1 for c in on_disk if c.id not in per_clip)
    counts["total"] = sum(v for k, v in counts.items() if k != "total")
    training = root / TRAINING_SET
    views = [row for clip in sorted(on_disk, key=lambda c: c.id) for row in _views(clip, output)]
    return Status(root, stages, counts, failed, dataset_statistics(stats_rows),
                  {k: round(v, 3) for k, v in seconds.items()}, runs,
                  str(training) if training.is_file() else None, mismatched,
                  sorted(stale, key=lambda row: (row[0], STAGES.index(row[1]))), views)
