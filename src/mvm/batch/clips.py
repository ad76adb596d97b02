"""The clips of a data set root: videos and scene directories, grouped into sequences.

Layout (one level of sequences, as the paper's data set: a sequence is one source video, a clip
a stretch of it)::

    ROOT/
      clip.mp4                    a clip of its own sequence ("clip"); its scene directory is ROOT/clip/
      scene/                      a scene directory (sparse/, poses2d.json, frames/…): a clip of its own sequence
      sequence/                   any other directory is a sequence; its videos and scene
        clip_a.mp4                directories are its clips ("sequence/clip_a", …)
        clip_b/

A video and the directory of the same stem beside it are one clip (the directory is where the
video's stages write). Names starting with ``.`` (``ROOT/.mvm`` holds the manifest) are ignored.
Imported 2D poses of a clip, used by the ``detect`` stage when no network checkpoint is given:
``SCENE/detections.json`` or ``SCENE/detections/`` (COCO results, OpenPifPaf or OpenPose), or
``<clip>.detections.json`` / ``<clip>.detections/`` beside the video.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from mvm.errors import InputError
from mvm.io.layout import DETECTIONS, SCENE_INPUTS
from mvm.io.paths import VIDEO_SUFFIXES


@dataclass(frozen=True)
class Clip:
    """One clip: ``id`` its scene directory relative to the root (posix), ``sequence`` the
    sequence it belongs to, ``scene`` its scene directory (absolute), ``video`` its video file
    or None, ``detections`` imported 2D poses or None."""

    id: str
    sequence: str
    scene: str
    video: str | None = None
    detections: str | None = None


def is_scene_dir(path: Path) -> bool:
    return path.is_dir() and any((path / marker).exists() for marker in SCENE_INPUTS)


def _is_video(path: Path) -> bool:
    return path.is_file() and path.suffix.lower() in VIDEO_SUFFIXES


def _detections(scene: Path, video: Path | None) -> str | None:
    candidates = [scene / f"{DETECTIONS}.json", scene / DETECTIONS]
    if video is not None:
        beside = f"{video.stem}.{DETECTIONS}"
        candidates += [video.with_name(f"{beside}.json"), video.with_name(beside)]
    for candidate in candidates:
        if candidate.exists():
            return str(candidate)
    return None


def _clips_in(folder: Path, root: Path, sequence: str | None) -> tuple[list[Clip], list[Path]]:
    """Clips directly in ``folder`` and the directories that are neither clips nor hidden."""
    entries = sorted(p for p in folder.iterdir() if not p.name.startswith("."))
    videos = {p.stem: p for p in entries if _is_video(p)}
    clips, others = [], []
    seen = set()
    for entry in entries:
        if entry.is_dir() and not entry.name.endswith(".detections"):
            if entry.name in videos or is_scene_dir(entry):
                seen.add(entry.name)
                video = videos.get(entry.name)
                clips.append(_clip(entry, video, root, sequence))
            else:
                others.append(entry)
    for stem, video in videos.items():
        if stem not in seen:
            clips.append(_clip(folder / stem, video, root, sequence))
    return clips, others


def _clip(scene: Path, video: Path | None, root: Path, sequence: str | None) -> Clip:
    cid = scene.relative_to(root).as_posix()
    return Clip(cid, sequence if sequence is not None else cid, str(scene.resolve()),
                None if video is None else str(video.resolve()), _detections(scene, video))


def discover_clips(root: str | Path) -> list[Clip]:
    """Every clip under ``root`` (see the module's layout), sorted by id.

    Raises :class:`InputError` when ``root`` is not a directory or holds no clip.
    """
    root = Path(root)
    if not root.is_dir():
        raise InputError(root, None, "not a directory (expected videos or scene directories)")
    root = root.resolve()
    clips, sequences = _clips_in(root, root, None)
    for folder in sequences:
        inner, _ = _clips_in(folder, root, folder.name)
        clips += inner
    if not clips:
        raise InputError(root, None, "no clips: expected video files (" + ", ".join(VIDEO_SUFFIXES[:4])
                         + ", …) or scene directories, directly or one level down")
    return sorted(clips, key=lambda c: c.id)
