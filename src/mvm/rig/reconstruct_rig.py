"""``RIG_DIR`` in; per-instant 3D poses (JSON Lines), one ``.trc`` per track and a recap out."""
from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from mvm.core.completion import (
    FLAG_NAMES,
    INFERRED,
    MISSING,
    OBSERVED,
    complete_tracks,
    infer_missing,
    interpolate_series,
)
from mvm.core.config import DEFAULT_FRAME_RATE_HZ, Config
from mvm.core.keypoints import COCO_KEYPOINTS
from mvm.core.prior import load_prior, shipped_prior
from mvm.errors import InputError
from mvm.io.files import atomic_write_bytes, atomic_write_json
from mvm.io.layout import RECAP, RIG_POSES3D, TRACK_FILE, TRACKS_DIR
from mvm.io.provenance import fingerprints, write_record
from mvm.io.rig_poses3d import RigPoses3D, rig_poses3d_lines
from mvm.io.trc import to_opensim, write_trc
from mvm.parallel import available_workers, fork_map, fork_map_ranges
from mvm.rig.filters import min_cutoff
from mvm.rig.instants import InstantPersons, reconstruct_instants
from mvm.rig.occlusions import LIMB_JOINTS, fill_occlusions, ray_sigma, rays
from mvm.rig.options import RigOptions
from mvm.rig.output_set import check_rig_output, named_inputs, replace_output_set, rig_inputs
from mvm.rig.recap import recap
from mvm.rig.refusals import agreed_on_refused, refused_limb_joints, refused_parents
from mvm.rig.rigdir import RigData, read_rig, recorded_frame_rate
from mvm.rig.skeleton import capture_noise_factor, observations, refine_tracks, refit, track_bone_lengths
from mvm.rig.tracking import butterworth_order, smooth_tracks, track_persons, track_series, with_missed_instants

log = logging.getLogger(__name__)

#: The stage's name in the reasons of a rerun (:mod:`mvm.io.provenance`).
RIG_STAGE = "the rig reconstruction"


def rig_fingerprint_inputs(rig_dir: str | Path, calib: str | Path | None = None) -> dict[str, Path]:
    """What a rig's output set is made from (:mod:`mvm.io.provenance`): the calibration and
    every pose source, named relative to ``rig_dir`` where they lie in it."""
    return named_inputs(Path(rig_dir), rig_inputs(rig_dir, calib))


def rig_settings(config: Config, options: RigOptions, calib, frames: str | None) -> dict:
    """The settings that shape a rig's output set (the process count does not)."""
    settings = {"config": asdict(config), "options": asdict(options), "calib": str(calib) if calib else None,
                "frames": frames}
    settings["options"].pop("workers", None)
    return settings


@dataclass
class RigResult:
    """``persons`` of every instant with ``track: (Q,)`` ids; ``X: (Q, 17, 3)`` the (smoothed,
    completed) joints written out with ``flags: (Q, 17)`` (:mod:`mvm.core.completion`); ``recap``
    (see :func:`mvm.rig.recap.recap`); paths written; timings."""

    rig: RigData
    persons: InstantPersons
    track: np.ndarray
    X: np.ndarray
    flags: np.ndarray
    recap: dict
    outputs: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)


def poses3d_lines(frames: np.ndarray, persons: InstantPersons, X: np.ndarray, track: np.ndarray,
                  camera_names, flags: np.ndarray | None = None, workers: int | None = None) -> bytes:
    """``poses3d.jsonl`` of the persons of every instant (:func:`mvm.io.rig_poses3d.rig_poses3d_lines`):
    ``X: (Q, 17, 3)`` their joints, ``track: (Q,)``, ``flags: (Q, 17)`` (:mod:`mvm.core.completion`;
    None: observed where ``X`` is finite), ``views_per_joint`` the inlier 2D keypoints of their
    observed joints. Long captures are formatted in runs of instants on ``workers`` processes
    (:func:`mvm.parallel.fork_map_ranges`)."""
    X = np.asarray(X, dtype=float)
    flags = np.where(np.isfinite(X).all(-1), OBSERVED, MISSING) if flags is None else np.asarray(flags)
    views = (persons.inliers & (flags == OBSERVED)[:, None, :]).sum(1)
    poses = RigPoses3D(np.asarray(frames), persons.instant, np.asarray(track), X, persons.scores, flags,
                       persons.members, list(camera_names), views, persons.reprojection_error_px)
    return b"".join(fork_map_ranges(lambda instants: rig_poses3d_lines(poses, instants), len(frames), 100, workers))


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


def gap_policy(options: RigOptions, complete: bool) -> str:
    """The sentence written in each ``.trc`` header about the markers it carries (``complete``:
    the rig's :attr:`Config.complete`)."""
    if not complete:
        return "gaps: markers not reconstructed at a frame are left empty"
    kinds = "observed, interpolated and inferred (pose prior)" if options.trc_inferred else \
        "observed and interpolated"
    return (f"gaps: {kinds} markers; interpolation is cubic (Hermite) along the track over gaps of at most "
            f"{options.max_interpolation_gap} frames; other missing markers are left empty")


def write_tracks(directory: Path, frames: np.ndarray, X: np.ndarray, instant: np.ndarray,
                 track: np.ndarray, options: RigOptions, flags: np.ndarray | None = None,
                 complete: bool = True) -> list[Path]:
    """One ``track_<id>.trc`` per track seen at ``min_track_length`` instants or more (Y up,
    metres; the instants it was filled at, with no joint observed, do not count).

    ``flags: (Q, 17)``: inferred joints are left out unless ``options.trc_inferred``; with
    ``complete`` (the rig's :attr:`Config.complete`), instants where the track was unseen are
    interpolated like missing joints (gaps up to ``options.max_interpolation_gap``). The policy
    is written in the header."""
    paths = []
    if flags is not None and not options.trc_inferred:
        X = np.where((np.asarray(flags) == INFERRED)[..., None], np.nan, X)
    comment = gap_policy(options, complete)
    seen = np.ones(len(track), bool) if flags is None else (np.asarray(flags) == OBSERVED).any(1)
    for k in np.unique(track):
        if ((track == k) & seen).sum() < options.min_track_length:
            continue
        times, series = track_series(X, instant, track, k)
        if complete:
            series = interpolate_series(series, options.max_interpolation_gap)[0]
        path = directory / TRACK_FILE.format(track=int(k))
        write_trc(path, to_opensim(series, options.up, options.metres_per_unit), COCO_KEYPOINTS,
                  options.rate, frames=frames[times], comment=comment)
        paths.append(path)
    return paths


def rig_config(config: Config | None = None) -> Config:
    """The settings the rig driver runs with: ``config`` (default :class:`Config`) with the rig's
    defaults of the settings left to the driver (:meth:`Config.for_driver`). Resolved once, at the
    driver's entry (:func:`reconstruct_rig`, :func:`rig_reason`); the steps below take them so."""
    return (config or Config()).for_driver("rig")


def completion_prior(config: Config, prior=None):
    """The pose prior for refinement and completion: ``prior``, else the shipped one when either
    needs it (:func:`mvm.core.prior.load_prior`'s rule, extended to completion, which rigs run
    by default). ``config``: the rig's settings (:func:`rig_config`)."""
    assert config.resolved, "completion_prior takes the rig's settings (rig_config)"
    if prior is not None or not config.complete:
        return load_prior(config, prior)
    return shipped_prior()


def instants_config(config: Config) -> Config:
    """The settings :func:`reconstruct_instants` runs with in the rig driver: the rig's settings
    (:func:`rig_config`) without per-instant refinement (persons are refined once their track is
    known)."""
    assert config.resolved, "instants_config takes the rig's settings (rig_config)"
    return config.replace(refine=False)


def track_groups(track: np.ndarray, parts: int) -> list[np.ndarray]:
    """The persons of ``track: (Q,)`` ids shared out among at most ``parts`` groups of whole
    tracks, nearly equal in persons (largest track first to the smallest group): ``[(K_g,)]``
    sorted indices, non-empty."""
    ids, inverse, counts = np.unique(track, return_inverse=True, return_counts=True)
    group_of, load = np.zeros(len(ids), dtype=int), np.zeros(max(1, min(parts, len(ids))))
    for k in np.argsort(-counts, kind="stable"):
        group_of[k] = np.argmin(load)
        load[group_of[k]] += counts[k]
    member = group_of[inverse.ravel()]
    return [np.flatnonzero(member == g) for g in range(len(load)) if load[g] > 0]


def refine_by_tracks(persons: InstantPersons, track: np.ndarray, detections, cameras, config: Config, prior,
                     bone_weight: float, workers: int | None = None, noise: float = 1.0) -> InstantPersons:
    """:func:`mvm.rig.skeleton.refine_tracks` of ``persons`` with whole tracks shared out among
    ``workers`` processes (:func:`track_groups`, :func:`mvm.parallel.fork_map`): a track's
    bone lengths are its own, and the capture's ``noise`` (:func:`mvm.rig.skeleton.capture_noise_factor`)
    is measured before, so the result is the same as in one process."""
    groups = track_groups(track, available_workers(workers) if len(persons) >= 200 else 1)
    parts = fork_map(lambda index: refine_tracks(persons.take(index), track[index], detections, cameras, config,
                                                 prior, bone_weight, noise=noise), groups, workers)
    merged = InstantPersons.concatenate(parts, persons.members.shape[1])
    return merged.take(np.argsort(np.concatenate(groups), kind="stable"))


def refine_parents_again(triangulated: InstantPersons, refined: InstantPersons, refused: np.ndarray,
                         track: np.ndarray, detections, cameras, config: Config, prior, bone_weight: float,
                         noise: float) -> InstantPersons:
    """``refined`` (:func:`refine_by_tracks` of ``triangulated``) with the parents of its
    ``refused: (Q, 17)`` joints (:func:`mvm.rig.refusals.refused_parents`) refined again
    without those joints, against their track's bone lengths as before: a wrist that the views
    got wrong pulls its elbow towards it through the forearm's bone term, and an elbow its
    shoulder through the upper arm's. Only the persons with such a parent are refined again;
    their other joints are kept.

    On the simulated rig of ``benchmarks/rig_occlusion.py``, where most views agree on a wrist
    that is not there, the elbows and shoulders around it were 12-13 mm off, and are 6.3-6.5 mm
    off with this, as where the wrist is only missing; around a whole arm they agree on, the
    shoulders 20-32 mm, and 6-8 mm."""
    parents = refused_parents(refused)                                           # (Q, 17)
    rows = np.flatnonzero(parents.any(1))
    if not len(rows):
        return refined
    lengths = track_bone_lengths(triangulated.X, track)[rows]                     # as the first refinement's
    without = triangulated.take(rows)
    without = dataclasses.replace(without, X=np.where(refused[rows, :, None], np.nan, without.X))
    again = refine_tracks(without, track[rows], detections, cameras, config, prior, bone_weight, noise=noise,
                          lengths=lengths)
    X = refined.X.copy()
    X[rows] = np.where(parents[rows, :, None], again.X, X[rows])
    return refit(refined, X, detections, cameras)


def track_and_complete(persons: InstantPersons, options: RigOptions, prior=None, config: Config | None = None,
                       detections=None, cameras=None):
    """Tracks, the rigid-skeleton refinement, smoothing and completion of reconstructed instants
    (no I/O).

    With ``config.refine`` (and ``detections``, ``cameras``), every person is refined once its
    track is known: reprojection, the pose prior and the track's robust bone lengths
    (:func:`mvm.rig.skeleton.refine_tracks`), and the parents of the limb joints refused as
    outliers once more without them (:func:`refine_parents_again`); ``persons`` should then come from
    :func:`reconstruct_instants` with :func:`instants_config` (unrefined). Smoothing runs over
    each track's observed joints, then completion fills what is missing (time, then ``prior``)
    unless the rig's ``config.complete`` is off (``config``: the rig's settings,
    :func:`rig_config`; none: its defaults). With completion, a track has a row at each instant
    it missed whole between its first and last (:func:`mvm.rig.tracking.with_missed_instants`;
    no member, no keypoint), kept where the completion fills ``min_person_joints`` of its joints
    or more: the ``.trc`` and ``poses3d.jsonl`` carry the same instants.
    Returns ``(tracking, persons, X: (Q, 17, 3), flags: (Q, 17))``."""
    assert config is None or config.resolved, "track_and_complete takes the rig's settings (rig_config)"
    settings = config or rig_config()
    complete = settings.complete
    unit = 1.0 / options.metres_per_unit
    tracking = track_persons(persons.X, persons.instant, options.max_link_distance_m * unit, options.max_gap,
                             options.min_link_joints)
    refine = config is not None and config.refine and detections is not None and len(persons)
    triangulated, noise = persons, capture_noise_factor(persons, detections, config) if refine else 1.0
    if refine:
        persons = refine_by_tracks(persons, tracking.track, detections, cameras, config, prior, options.bone_weight,
                                   options.workers, noise)
    fill = complete and detections is not None and cameras is not None and options.occlusion_max_gap > 0
    refused = np.zeros(persons.X.shape[:2], bool)
    if fill and len(persons):
        refused = refused_limb_joints(persons.X, persons.inliers, persons.valid, persons.instant, tracking.track,
                                      unit)
        if refine:
            persons = refine_parents_again(triangulated, persons, refused, tracking.track, detections, cameras,
                                           config, prior, options.bone_weight, noise)
    if complete:
        persons, track, added = with_missed_instants(persons, tracking.track)
        tracking, before = dataclasses.replace(tracking, track=track), refused
        refused = np.zeros((len(added), before.shape[1]), bool)
        refused[~added] = before                                               # none at the added rows
    X = smooth_tracks(np.where(refused[..., None], np.nan, persons.X), persons.instant, tracking.track,
                      options.smoothing, rate=options.rate, cutoff_hz=options.cutoff, order=options.filter_order,
                      window=options.savgol_window)
    if not complete:
        return tracking, persons, X, np.where(np.isfinite(X).all(-1), OBSERVED, MISSING).astype(np.int8)
    filled = np.zeros(X.shape[:2], np.int8)
    if fill and len(persons):
        X, filled, confidence = fill_track_occlusions(persons, X, tracking.track, detections, cameras, prior,
                                                      options, settings, refused)
        persons = dataclasses.replace(persons, scores=np.where(filled > 0, confidence, persons.scores))
    X, flags = complete_tracks(X, persons.instant, tracking.track, options.max_interpolation_gap, prior)
    flags = np.where(filled > 0, filled, flags).astype(np.int8)
    kept = ~added | (np.isfinite(X).all(-1).sum(1) >= settings.min_person_joints)      # a missed instant, filled
    return dataclasses.replace(tracking, track=tracking.track[kept]), persons.take(kept), X[kept], flags[kept]


def fill_track_occlusions(persons: InstantPersons, X: np.ndarray, track: np.ndarray, detections, cameras, prior,
                          options: RigOptions, config: Config, refused: np.ndarray | None = None):
    """The limb joints of ``X: (Q, 17, 3)`` (smoothed tracks) filled through their occlusions
    (:func:`mvm.rig.occlusions.fill_occlusions`) from the rays of the 2D keypoints of each
    person's members, less those that agreed on a refused joint
    (:func:`mvm.rig.refusals.agreed_on_refused`), and the prior's guess; the rays' deviation
    measured on the capture's observed joints (:func:`mvm.rig.occlusions.ray_sigma`). Returns
    ``(X, flags: (Q, 17), confidence: (Q, 17))`` (flags 0 where not filled)."""
    xy, conf, _, used = observations(persons, detections, cameras, config.keypoint_threshold)
    unit = 1.0 / options.metres_per_unit
    origin, direction = rays(xy, conf, cameras)
    seen = X if refused is None else np.where(refused[..., None], np.nan, X)
    sigma = ray_sigma(seen, origin, direction, used, unit)
    keep = ~np.isfinite(X[:, LIMB_JOINTS]).all((1, 2))[:, None, None]               # rays only where needed
    if refused is not None:
        keep = keep & ~agreed_on_refused(refused, persons.inliers, persons.valid)
    origin, direction = (np.where(keep[..., None], a, np.nan) for a in (origin, direction))
    guess = infer_missing(X, prior)[0] if prior is not None else None
    return fill_occlusions(X, persons.instant, track, origin, direction, guess, options.occlusion_inferred_gap,
                           options.occlusion_max_gap, unit, refused, options.max_interpolation_gap, sigma)


def check_smoothing(options: RigOptions) -> None:
    """Refuse, with an :class:`InputError` naming the setting, a Butterworth cut-off so small a
    fraction of the frame rate's Nyquist frequency that the filter cannot be computed
    (:func:`mvm.rig.filters.min_cutoff`): a frame rate of 1e12 Hz, a cut-off of 1e-9 Hz."""
    if options.smoothing != "butterworth":
        return
    nyquist = options.rate / 2
    order = butterworth_order(options.filter_order)
    lowest = min_cutoff(order) * nyquist
    if not options.cutoff >= lowest:
        field = "cutoff_hz" if options.cutoff_hz is not None else "frame_rate"
        raise InputError(None, field, f"a cut-off of {options.cutoff:.3g} Hz at a frame rate of "
                                      f"{options.rate:.3g} Hz is below the {lowest:.3g} Hz the Butterworth "
                                      f"filter of filter_order {options.filter_order} can be computed at "
                                      f"({min_cutoff(order):.2g} of the Nyquist frequency): raise cutoff_hz, lower "
                                      "frame_rate or filter_order, or use smoothing = savgol")


def check_group_size(config: Config, rig: RigData) -> None:
    """Refuse, with an :class:`InputError` naming ``min_group_size``, settings the rig's cameras
    cannot meet: a person is reconstructed from a group of at least ``min_group_size`` 2D poses,
    one per camera, so a rig with fewer cameras with poses would reconstruct nobody."""
    cameras = len(rig.calibration.cameras.names)
    if cameras < config.min_group_size:
        raise InputError(None, "min_group_size", f"{config.min_group_size} cameras must see a person to reconstruct "
                                                 f"it, and this rig has {cameras} with 2D poses: nobody would be "
                                                 f"reconstructed (give --set min_group_size={cameras})")


def with_frame_rate(options: RigOptions, rig: RigData) -> tuple[RigOptions, str]:
    """``options`` with the rig's frame rate, and where it comes from: ``"setting"`` (given; a
    warning when the videos recorded another), ``"videos"`` (the rate ``mvm rig detect``
    recorded in the pose files: :func:`mvm.rig.rigdir.recorded_frame_rate`) or ``"default"``
    (:data:`mvm.core.config.DEFAULT_FRAME_RATE_HZ`)."""
    if options.frame_rate is not None:
        try:
            recorded = recorded_frame_rate(rig)
        except InputError as e:
            log.warning("%s (using the %g Hz given)", e, options.frame_rate)
            recorded = None
        if recorded is not None and abs(recorded - options.frame_rate) > 1e-3 * recorded:
            log.warning("frame rate %g Hz given; the videos were recorded at %g Hz", options.frame_rate, recorded)
        return options, "setting"
    recorded = recorded_frame_rate(rig)
    if recorded is None:
        return options.replace(frame_rate=DEFAULT_FRAME_RATE_HZ), "default"
    try:
        resolved = options.replace(frame_rate=recorded)
    except ValueError as e:
        raise InputError(None, "frame_rate", f"the videos' {recorded:g} Hz: {e}") from None
    check_smoothing(resolved)
    return resolved, "videos"


def rig_reason(rig_dir: str | Path, config: Config | None = None, options: RigOptions | None = None,
               calib: str | Path | None = None, frames: str | None = None,
               output: str | Path | None = None) -> str | None:
    """Why :func:`reconstruct_rig` with these arguments would make the output set again (None:
    the set's record says it was made from these inputs with these settings)."""
    from mvm.io.provenance import why_redo

    config = rig_config(config)
    options = options or RigOptions()
    check_smoothing(options)
    out_dir = check_rig_output(rig_dir, calib, output)
    return why_redo(out_dir / RIG_POSES3D, rig_fingerprint_inputs(rig_dir, calib),
                    rig_settings(config, options, calib, frames), RIG_STAGE,
                    exists=(out_dir / RIG_POSES3D).is_file() and (out_dir / RECAP).is_file())


def kept_set(rig_dir: str | Path, calib: str | Path | None = None,
             output: str | Path | None = None) -> tuple[dict, dict]:
    """The recap and the paths of an output set kept as it is (:func:`rig_reason` said it is up
    to date): ``(recap, {"poses3d", "tracks", "recap"})``."""
    from mvm.io.checks import load_json_object

    out_dir = check_rig_output(rig_dir, calib, output)
    recap_path = out_dir / RECAP
    return load_json_object(recap_path), {"poses3d": out_dir / RIG_POSES3D, "recap": recap_path,
                                          "tracks": sorted((out_dir / TRACKS_DIR).glob("*.trc"))}


def reconstruct_rig(rig_dir: str | Path, config: Config | None = None, options: RigOptions | None = None,
                    calib: str | Path | None = None, frames: str | None = None, output: str | Path | None = None,
                    prior=None, progress: Callable[[int, int], None] | None = None) -> RigResult:
    """Reconstruct, track, complete and write a rig: ``<output>/poses3d.jsonl``,
    ``<output>/tracks/*.trc``, ``<output>/recap.json`` (``output`` defaults to ``RIG_DIR/mvm``).

    The three are one set, with the record of its inputs and settings (``poses3d.inputs.json``,
    :mod:`mvm.io.provenance`): written into a temporary folder beside ``output`` and swapped in
    whole, so a failed or killed run leaves the previous set as it was (or no set), never a mix.
    A run that would produce nothing (a frame range without poses, a folder that is not a rig)
    is refused before anything is written.
    """
    config = rig_config(config)
    options = options or RigOptions()
    check_smoothing(options)
    timings = {}
    out_dir = check_rig_output(rig_dir, calib, output)
    inputs = rig_fingerprint_inputs(rig_dir, calib)
    hashed = fingerprints(inputs)                                    # before reading: never newer than the set
    t0 = time.perf_counter()
    rig = read_rig(rig_dir, calib, frames, options.workers)
    check_group_size(config, rig)
    given, (options, rate_source) = options, with_frame_rate(options, rig)
    timings["read_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    prior = completion_prior(config, prior)
    cameras = rig.calibration.cameras
    persons = reconstruct_instants(cameras, rig.detections, instants_config(config), prior,
                                   options.batch_size, progress, options.workers)
    timings["reconstruct_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    tracking, persons, X, flags = track_and_complete(persons, options, prior, config, rig.detections, cameras)
    track = tracking.track
    timings["tracking_refinement_s"] = time.perf_counter() - t0
    names = rig.calibration.cameras.names
    summary = recap(persons, names, len(rig.frames), len(rig.detections))
    summary["tracks"] = tracking.tracks
    summary["tracks_resumed"] = tracking.resumed
    summary["persons_not_linked_few_joints"] = tracking.unlinked
    summary["persons_filled_whole"] = int((persons.members < 0).all(1).sum())     # instants a track missed
    summary["sync_offsets"] = rig.offsets
    summary["frame_rate"] = {"hz": options.rate, "source": rate_source}
    counts = np.bincount(np.asarray(flags, dtype=int).ravel(), minlength=len(FLAG_NAMES))
    summary["joint_flags"] = {n: round(float(c / max(counts.sum(), 1)), 4) for n, c in zip(FLAG_NAMES, counts)}
    summary["instants_per_s"] = round(len(rig.frames) / max(timings["reconstruct_s"]
                                                            + timings["tracking_refinement_s"], 1e-9), 2)
    t0 = time.perf_counter()
    lines = poses3d_lines(rig.frames, _local_members(persons, rig), X, track, names, flags, options.workers)
    outputs = {}

    def build(folder: Path) -> None:
        atomic_write_bytes(folder / RIG_POSES3D, lines)
        outputs["tracks"] = [out_dir / TRACKS_DIR / p.name
                             for p in write_tracks(folder / TRACKS_DIR, rig.frames, X, persons.instant, track,
                                                   options, flags, config.complete)]
        timings["write_s"] = time.perf_counter() - t0
        atomic_write_json(folder / RECAP, {**summary, "timings_s": {k: round(v, 4) for k, v in timings.items()},
                                                 "config": asdict(config), "options": asdict(options),
                                                 "calibration": rig.calibration.metadata.get("source"),
                                                 "pose_format": rig.pose_format}, pretty=True)
        write_record(folder / RIG_POSES3D, RIG_STAGE, inputs, rig_settings(config, given, calib, frames), hashed)

    replace_output_set(build, out_dir, config.lock_timeout_s)
    outputs.update({"poses3d": out_dir / RIG_POSES3D, "recap": out_dir / RECAP})
    return RigResult(rig, persons, track, X, flags, summary, outputs, timings)
