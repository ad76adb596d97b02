"""Reading a rig directory: a calibration and one source of 2D poses per camera.

The layout of a rig directory (calibration, ``sync.toml``, ``pose/``, ``videos/``, the output
set) is declared in :mod:`mvm.io.layout`.

Cameras are matched to folders by *name*, never by sort order: an exact name, then the name
without case and known suffixes (``_json``, ``_keypoints``, ``_img``, ``.json``), then the same
camera number (``cam_01`` and ``cam1_json``) when that number is unique on both sides.
"""
from __future__ import annotations

import logging
import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from mvm.core.camera import undistort_views
from mvm.core.scene import Poses2D
from mvm.errors import InputError
from mvm.io.calib_toml import RigCalibration, read_calib_toml
from mvm.io.coco import read_coco_keypoints
from mvm.io.layout import CALIBRATION_DIR, DEFAULT_OUTPUT, NOT_CALIBRATIONS, POSES2D, SPARSE, VIDEOS, RigLayout
from mvm.io.openpifpaf import read_openpifpaf_frame
from mvm.io.openpose import frame_number, read_openpose_frames
from mvm.io.pose_format import pose_format
from mvm.io.provenance import RECORD_SUFFIX
from mvm.parallel import fork_map_ranges
from mvm.rig.instants import rig_poses

log = logging.getLogger(__name__)

_SUFFIXES = ("_json", "-json", "_keypoints", "_img", "_images", "_pose", "_poses", ".json")
_IGNORED_DIRS = {CALIBRATION_DIR, SPARSE, DEFAULT_OUTPUT, VIDEOS, "video", "images"}


@dataclass
class RigData:
    """A rig's cameras and 2D poses.

    Attributes:
        calibration: the cameras (only those with poses, in calibration order).
        frames: ``(T,)`` frame numbers of the instants, increasing.
        detections: the 2D poses, undistorted; ``view`` is the camera, ``instant`` indexes ``frames``.
        sources: camera name -> the folder or file its poses came from.
        pose_format: "openpose", "openpifpaf" or "coco".
        offsets: camera name -> frames added to its frame numbers (from ``sync.toml``), or None
            when the frame numbers were used as they are.
        videos: camera name -> the ``info.video`` of its COCO pose file (``frame_rate``,
            ``frames``, ...: :mod:`mvm.video.rig_videos`), for the cameras whose file has one.
    """

    calibration: RigCalibration
    frames: np.ndarray
    detections: Poses2D
    sources: dict
    pose_format: str
    offsets: dict | None = None
    videos: dict = field(default_factory=dict)


def _normalize(name: str) -> str:
    name = name.lower()
    changed = True
    while changed:
        changed = False
        for suffix in _SUFFIXES:
            if name.endswith(suffix) and len(name) > len(suffix):
                name = name[: -len(suffix)]
                changed = True
    return re.sub(r"[^a-z0-9]", "", name)


def _number(name: str) -> int | None:
    digits = re.findall(r"\d+", _normalize(name))
    return int(digits[-1]) if digits else None


def match_cameras(camera_names, entry_names) -> dict[int, int]:
    """Match cameras to pose folders by name. Returns ``{camera index: entry index}``.

    Exact names first, then normalized names, then unique camera numbers. Ambiguity (two entries
    fitting one camera at the same rule) raises ``ValueError``.
    """
    cameras, entries = list(camera_names), list(entry_names)
    matched: dict[int, int] = {}
    for key in (lambda s: s, _normalize, _number):
        cam_keys = {c: key(cameras[c]) for c in range(len(cameras)) if c not in matched}
        used = set(matched.values())
        entry_keys = {e: key(entries[e]) for e in range(len(entries)) if e not in used}
        for c, k in cam_keys.items():
            if k is None:
                continue
            hits = [e for e, ke in entry_keys.items() if ke == k]
            same = [c2 for c2, k2 in cam_keys.items() if k2 == k]
            if len(hits) == 1 and len(same) == 1:
                matched[c] = hits[0]
            elif len(hits) > 1 and key is not _number:
                raise ValueError(f"camera {cameras[c]!r} matches several pose sources: "
                                 f"{sorted(entries[e] for e in hits)}")
    return matched


def find_calibration(rig_dir: Path) -> Path:
    """The calibration of ``rig_dir``: one ``*.toml`` at its top or in ``calibration/``, or a
    COLMAP model in ``sparse/``. Several candidates raise :class:`InputError` (use ``--calib``)."""
    layout = RigLayout(rig_dir)
    candidates = sorted(p for p in [*rig_dir.glob("*.toml"), *layout.calibration_dir.glob("*.toml")]
                        if p.name.lower() not in NOT_CALIBRATIONS)
    if layout.sparse.is_dir():
        candidates.append(layout.sparse)
    if len(candidates) == 1:
        return candidates[0]
    if not candidates:
        raise InputError(rig_dir, None, "no calibration: expected Calib.toml, calibration/*.toml or sparse/ "
                                        "(or pass --calib)")
    raise InputError(rig_dir, None, "several calibrations: " + ", ".join(str(c.relative_to(rig_dir))
                                                                      for c in candidates) + " (pass --calib)")


def read_calibration(path: Path, extrinsics: bool = True) -> RigCalibration:
    """A calibration file or COLMAP model (its lenses converted to OpenCV's model when read) ->
    the calibration. ``extrinsics=False``: a Calib.toml may lack rotations and translations (NaN)."""
    if path.is_dir():
        from mvm.io.colmap import read_colmap

        c = read_colmap(path).cameras
        names = tuple(Path(n).stem if "/" not in n else Path(n).parent.name for n in c.names)
        return RigCalibration(replace(c, names=names), {"source": str(path)})
    if path.suffix.lower() == ".json":
        from mvm.io.panoptic_calib import read_panoptic_calibration

        return read_panoptic_calibration(path)
    return read_calib_toml(path, extrinsics)


def _pose_root(rig_dir: Path) -> Path:
    pose_dir = RigLayout(rig_dir).pose_dir
    return pose_dir if pose_dir.is_dir() else rig_dir


def pose_sources(rig_dir: Path) -> dict[str, Path]:
    """Candidate pose sources: sub-folders holding ``*.json`` files and ``*.json`` COCO files
    (not the records of mvm's pose files, ``*.inputs.json``)."""
    root = _pose_root(rig_dir)
    sources = {}
    for p in sorted(root.iterdir()):
        if p.name.startswith(".") or p.name.lower() in _IGNORED_DIRS:
            continue
        if p.is_dir() and any(p.glob("*.json")):
            sources[p.name] = p
        elif (p.is_file() and p.suffix.lower() == ".json" and not p.name.startswith(CALIBRATION_DIR)
              and not p.name.endswith(RECORD_SUFFIX)):
            sources[p.name] = p
    return sources


def _source_format(path: Path, root: Path) -> tuple[str, list[tuple[int, Path]]]:
    """The format of one camera's pose source (:func:`mvm.io.pose_format.pose_format`: a COCO
    keypoints file, or a folder of OpenPose or OpenPifPaf files) and its per-frame files."""
    fmt, files = pose_format(path, root)
    if fmt == "coco-results":
        raise InputError(path, None, "a COCO results list: a camera's poses are a COCO keypoints file "
                                     "(images, annotations) or a folder of per-frame files")
    return fmt, files


def _read_coco_source(path: Path, root: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict | None]:
    """The 2D poses of one camera's COCO keypoints file, by frame number: ``(frames (N,),
    keypoints (N, 17, 3), scores (N,), its info.video or None)``."""
    coco = read_coco_keypoints(path, root=root)
    frame_of_image = np.array([frame_number(Path(n), path, f"images[{i}].file_name")
                               for i, n in enumerate(coco.file_names)], dtype=np.int64)
    frames = frame_of_image[coco.ann_image]
    order = np.argsort(frames, kind="stable")
    video = (coco.info or {}).get("video")
    return frames[order], coco.keypoints[order], coco.score[order], video if isinstance(video, dict) else None


def _read_frame_files(files: list[Path], fmt: str, root: Path) -> list[tuple[np.ndarray, np.ndarray | None]]:
    """``(keypoints (K, 17, 3), scores (K,) or None for OpenPose)`` of each OpenPose or OpenPifPaf
    file of ``files``, read the guarded way inside the rig directory ``root``."""
    if fmt != "openpose":
        return [read_openpifpaf_frame(file, root=root) for file in files]
    return [(kp, None) for kp in read_openpose_frames(files, root=root)]


def _read_sources(paths: list[Path], files: list[list[tuple[int, Path]]], fmt: str, root: Path,
                  start: int | None, stop: int | None, workers: int | None = None,
                  shifts: list[int] | None = None, videos: list | None = None, spans: list | None = None
                  ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The 2D poses of each camera's source of ``paths`` (its per-frame ``files``,
    :func:`_source_format`) with a frame number in ``[start, stop)`` (None: open):
    ``[(frames (N,), keypoints (N, 17, 3), scores (N,))]``. ``shifts``: per camera, frames
    added to its frame numbers first (the range applies to the shifted numbers, which are
    returned). Per-frame files outside the range are not read; the files of all cameras are
    read on ``workers`` processes (:func:`mvm.parallel.fork_map`). ``videos``: a list that gets
    each COCO file's ``info.video`` (or None); ``spans``: a list that gets each camera's first
    and last shifted frame number before the range is applied (None: no pose)."""
    low, high = -np.inf if start is None else start, np.inf if stop is None else stop
    shifts = shifts or [0] * len(paths)
    if fmt == "coco":
        out = []
        for path, shift in zip(paths, shifts):
            f, kp, score, video = _read_coco_source(path, root)
            if videos is not None:
                videos.append(video)
            f = f + shift
            if spans is not None:
                spans.append((int(f.min()), int(f.max())) if len(f) else None)
            keep = (f >= low) & (f < high)
            out.append((f[keep], kp[keep], score[keep]))
        return out
    if spans is not None:
        spans += [(min(f for f, _ in listing) + shift, max(f for f, _ in listing) + shift) if listing else None
                  for listing, shift in zip(files, shifts)]
    listings = [[(f + shift, file) for f, file in listing if low <= f + shift < high]
                for listing, shift in zip(files, shifts)]
    flat = [file for files in listings for _, file in files]
    parts = fork_map_ranges(lambda r: _read_frame_files(flat[r.start:r.stop], fmt, root), len(flat), 100, workers)
    per_file = iter([read for part in parts for read in part])
    out = []
    for files in listings:
        kps, scores = zip(*[next(per_file) for _ in files]) if files else ((), ())
        frames = np.repeat(np.array([f for f, _ in files], dtype=np.int64), [len(kp) for kp in kps])
        keypoints = np.concatenate(kps) if kps else np.zeros((0, 17, 3))
        if fmt == "openpose":                     # a pose's score: the mean confidence of its present joints
            present = keypoints[..., 2] > 0
            score = np.where(present, keypoints[..., 2], 0).sum(1) / np.maximum(present.sum(1), 1)
        else:
            score = np.concatenate(scores) if scores else np.zeros(0)
        out.append((frames, keypoints, score))
    return out


def parse_frames(spec: str | None) -> tuple[int | None, int | None]:
    """``"a:b"`` (b excluded; either may be empty) or ``"a"`` -> ``(start, stop)``. A range that
    holds no frame (``30:10``) is refused."""
    if not spec:
        return None, None
    try:
        if ":" not in spec:
            return int(spec), int(spec) + 1
        a, b = spec.split(":", 1)
        start, stop = (int(a) if a.strip() else None), (int(b) if b.strip() else None)
    except ValueError:
        raise InputError("--frames", spec, "expected START:STOP frame numbers, e.g. 0:1000") from None
    if start is not None and stop is not None and stop <= start:
        raise InputError("--frames", spec, "selects no frame: STOP (excluded) must be above START")
    return start, stop


def sync_shifts(offsets: dict[str, int], names: list[str], path: Path) -> list[int]:
    """The offsets of the cameras ``names`` (:mod:`mvm.io.sync_toml`); a camera missing from
    them raises :class:`InputError` naming it and ``path``."""
    missing = [n for n in names if n not in offsets]
    if missing:
        raise InputError(path, "[offsets]", f"no offset for camera {', '.join(missing)} "
                                            "(run mvm rig synchronize again)")
    return [offsets[n] for n in names]


def check_overlap(spans: list[tuple[int, int] | None], names: list[str], path: Path) -> None:
    """Every camera's shifted frames (``spans``: first and last frame number, None: no pose)
    must share instants with the first camera's: a camera whose offset moves it past the other
    videos raises :class:`InputError` naming it."""
    if not spans or spans[0] is None:
        return
    low, high = spans[0]
    for name, span in zip(names[1:], spans[1:]):
        if span is not None and (span[1] < low or span[0] > high):
            raise InputError(path, f"[offsets].{name}", f"the offset moves camera {name} beyond the videos' "
                                                        f"length (its frames {span[0]}..{span[1]}, the reference's "
                                                        f"{low}..{high})")


def read_rig(rig_dir: str | Path, calib: str | Path | None = None, frames: str | None = None,
             workers: int | None = None, extrinsics: bool = True, sync: bool = True) -> RigData:
    """Read ``rig_dir``: its calibration, the 2D poses of its cameras (undistorted), the frames
    (``"START:STOP"`` frame numbers, :func:`parse_frames`). The pose files are read on
    ``workers`` processes (default: :func:`mvm.parallel.available_workers`).

    With ``sync`` and a ``RIG_DIR/sync.toml``, each camera's frame numbers are shifted by its
    offset (the reference camera's numbering; ``frames`` selects in it). ``extrinsics=False``
    accepts a Calib.toml without rotations and translations (NaN)."""
    from mvm.io.sync_toml import read_sync_toml

    rig_dir = Path(rig_dir)
    if not rig_dir.is_dir():
        raise InputError(rig_dir, None, "not a directory")
    calib_path = Path(calib) if calib else find_calibration(rig_dir)
    calibration = read_calibration(calib_path, extrinsics)
    sync_path = RigLayout(rig_dir).sync
    present = sync_path.exists() or sync_path.is_symlink()       # a link to nothing, a FIFO: refused
    offsets = read_sync_toml(sync_path) if sync and present else None
    sources = pose_sources(rig_dir)
    names = calibration.cameras.names
    try:
        matched = match_cameras(names, list(sources))
    except ValueError as e:
        raise InputError(_pose_root(rig_dir), None, str(e)) from None
    scene = ("" if not (rig_dir / POSES2D).is_file() else
             " (a scene directory of one moving camera? use `mvm reconstruct`)")
    if not matched:
        shown = ", ".join(names[:10]) + (" …" if len(names) > 10 else "")
        raise InputError(_pose_root(rig_dir), None, f"no pose folder matches a camera of {calib_path} "
                                                    f"(cameras: {shown}; found: {', '.join(sources) or 'nothing'})"
                                                    f"{scene}")
    if len(matched) < 2:
        raise InputError(rig_dir, None, f"not a rig: {len(matched)} of the {len(names)} cameras of {calib_path.name} "
                                        f"has a pose folder, a rig needs 2{scene}")
    for c in range(len(names)):
        if c not in matched:
            log.warning("camera %s: no pose folder; it is not used", names[c])
    for e, name in enumerate(sources):
        if e not in matched.values():
            log.warning("%s: matches no camera of the calibration; ignored", sources[name])
    start, stop = parse_frames(frames)
    used = sorted(matched)                                                # calibration order
    entries = list(sources)
    paths = [sources[entries[matched[c]]] for c in used]
    formats, files = zip(*(_source_format(path, rig_dir) for path in paths))
    if len(set(formats)) > 1:
        raise InputError(_pose_root(rig_dir), None, f"mixed pose formats: {sorted(set(formats))}")
    fmt = formats[0]
    used_names = [names[c] for c in used]
    shifts = sync_shifts(offsets, used_names, sync_path) if offsets is not None else None
    videos: list = []
    spans: list = []
    read = _read_sources(paths, list(files), fmt, rig_dir, start, stop, workers, shifts, videos, spans)
    if offsets is not None:
        check_overlap(spans, used_names, sync_path)
    kps = [kp for _, kp, _ in read]
    scores = [score for _, _, score in read]
    frame_of = [f for f, _, _ in read]
    cam_of = [np.full(len(f), new_index) for new_index, (f, _, _) in enumerate(read)]
    keypoints = np.concatenate(kps) if kps else np.zeros((0, 17, 3))
    frame_of = np.concatenate(frame_of) if kps else np.zeros(0, int)
    cam_of = np.concatenate(cam_of) if kps else np.zeros(0, int)
    score = np.concatenate(scores) if kps else np.zeros(0)
    all_frames, instant = np.unique(frame_of, return_inverse=True)
    if not len(all_frames):
        raise InputError(*(("--frames", frames, "selects no frame with 2D poses") if frames else
                           (_pose_root(rig_dir), None, "no 2D pose in the pose folders")))
    calibration = subset_calibration(calibration, np.array(used))
    keypoints = undistort(calibration, keypoints, cam_of)
    detections = rig_poses(keypoints, instant, cam_of, score)
    log.info("%s: %d cameras, %d instants, %d 2D poses (%s)", rig_dir, len(used), len(all_frames),
             len(detections), fmt)
    return RigData(calibration, all_frames, detections,
                   {names[c]: sources[entries[matched[c]]] for c in used}, fmt,
                   None if shifts is None else dict(zip(used_names, shifts)),
                   {n: v for n, v in zip(used_names, videos) if v is not None})


#: Cameras whose videos' frame rates differ by less than this share agree (29.97 and 30 do not). [1]
FRAME_RATE_TOLERANCE = 1e-3
#: The slowest and fastest video frame rates read back from a pose file. [Hz]
MIN_FRAME_RATE_HZ, MAX_FRAME_RATE_HZ = 1e-3, 1e4


def recorded_frame_rate(rig: RigData) -> float | None:
    """The frame rate of the rig's videos recorded in its pose files (``info.video.frame_rate``,
    written by ``mvm rig detect``), or None when none records one. Cameras that disagree raise
    :class:`InputError` naming each camera's rate."""
    rates = {n: v.get("frame_rate") for n, v in rig.videos.items()}
    for n, r in rates.items():
        if r is not None and (isinstance(r, bool) or not isinstance(r, (int, float))
                              or not MIN_FRAME_RATE_HZ <= r <= MAX_FRAME_RATE_HZ):
            raise InputError(rig.sources.get(n), "info.video.frame_rate", f"camera {n}: expected a rate in Hz "
                             f"from {MIN_FRAME_RATE_HZ:g} to {MAX_FRAME_RATE_HZ:g}, or null, got {r!r}")
    rates = {n: float(r) for n, r in rates.items() if r is not None}
    if not rates:
        return None
    low, high = min(rates.values()), max(rates.values())
    if high > low * (1 + FRAME_RATE_TOLERANCE):
        where = next(iter(rig.sources.values())).parent
        raise InputError(where, "info.video.frame_rate", "the cameras' videos have different frame rates ("
                         + ", ".join(f"{n} {r:g} Hz" for n, r in rates.items())
                         + "): resample them to one rate and detect again, or give --frame-rate")
    return float(np.mean(list(rates.values())))


def subset_calibration(calibration: RigCalibration, index: np.ndarray) -> RigCalibration:
    return RigCalibration(calibration.cameras.subset(index), calibration.metadata)


def undistort(calibration: RigCalibration, keypoints: np.ndarray, camera: np.ndarray) -> np.ndarray:
    """Undo each camera's lens on ``keypoints: (N, 17, 3)`` seen by ``camera: (N,)`` (missing
    joints stay 0; :func:`mvm.core.camera.undistort_views`)."""
    out = np.array(keypoints, dtype=float)
    xy = undistort_views(calibration.cameras, out[..., :2], camera)
    out[..., :2] = np.where(out[..., 2:] > 0, xy, 0.0)
    return out
