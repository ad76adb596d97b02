"""One immutable configuration object for every threshold of the reconstruction.

Every field has a unit and a sentence in the README (section "Configuration"). A config is
read from a TOML file (flat keys, or under a ``[reconstruct]`` table) and overridden from the
command line with ``--set key=value``.
"""
from __future__ import annotations

import dataclasses
import math
import operator
import re
from dataclasses import dataclass, fields
from pathlib import Path

from mvm.errors import InputError


@dataclass(frozen=True)
class Bounds:
    """The allowed values of one setting. A float must be finite (unless ``finite=False``);
    ``ge``/``gt``/``le``/``lt`` bound a number, ``choices`` lists the allowed values, ``odd``
    asks for an odd integer."""

    ge: float | None = None
    gt: float | None = None
    le: float | None = None
    lt: float | None = None
    choices: tuple | None = None
    odd: bool = False
    finite: bool = True

    def problem(self, value) -> str | None:
        """What is wrong with ``value``, or None when it is allowed."""
        if self.choices is not None:
            if value not in self.choices:
                return f"expected one of {', '.join(map(repr, self.choices))}, got {_shown(value)}"
            return None
        if isinstance(value, float) and value != value:
            return "expected float, got nan"
        if self.finite and isinstance(value, float) and value in (math.inf, -math.inf):
            return f"must be finite, got {value}"
        for limit, ok, op in ((self.ge, operator.ge, ">="), (self.gt, operator.gt, ">"),
                              (self.le, operator.le, "<="), (self.lt, operator.lt, "<")):
            if limit is not None and not ok(value, limit):
                return f"must be {op} {limit:g}, got {_shown(value)}" if isinstance(limit, float) \
                    else f"must be {op} {limit}, got {_shown(value)}"
        if self.odd and value % 2 == 0:
            return f"must be odd, got {value}"
        return None


def setting(default, **bounds):
    """A settings dataclass field with :class:`Bounds`, checked by :func:`check_settings`:
    ``tau: float = setting(0.2, ge=0)``."""
    return dataclasses.field(default=default, metadata={"bounds": Bounds(**bounds)})


def _shown(value) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:39] + "…"


def setting_kind(field: dataclasses.Field) -> tuple[str | None, bool]:
    """(``"bool"``, ``"int"``, ``"float"``, ``"str"`` or None for other types, whether None is allowed)."""
    annotation = field.type if isinstance(field.type, str) else getattr(field.type, "__name__", str(field.type))
    parts = [part.strip() for part in annotation.split("|")]
    optional = "None" in parts
    kinds = [part for part in parts if part in ("bool", "int", "float", "str")]
    return (kinds[0] if len(kinds) == 1 and len(parts) - optional == 1 else None), optional


def _number_tuple_length(field: dataclasses.Field) -> int | None:
    """N for a field of type ``tuple[float, ...]`` of N floats (``tuple[float, float]``), else None."""
    annotation = field.type if isinstance(field.type, str) else str(field.type)
    match = re.fullmatch(r"tuple\[(float(?:, float)*)\](?: \| None)?", annotation.strip())
    return match.group(1).count("float") if match else None


def _type_problem(kind: str | None, value) -> str | None:
    if kind == "bool":
        ok = isinstance(value, bool)
    elif kind == "int":
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif kind == "float":
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    elif kind == "str":
        ok = isinstance(value, str)
    else:
        return None
    return None if ok else f"expected {kind}, got {_shown(value)}"


def check_settings(settings) -> None:
    """Check every field of a settings dataclass: its type, its :class:`Bounds` (a float must be
    finite even without bounds) and what the settings imply together (the class's
    ``implied_problems()``, when it has one: ``[(name, problem), ...]``).

    Raises the first problem as an :class:`InputError` naming the setting (no file: whoever
    read the settings adds it, see :func:`settings_from`). Call it from ``__post_init__``.
    """
    for field in fields(settings):
        value = getattr(settings, field.name)
        kind, optional = setting_kind(field)
        if value is None and optional:
            continue
        problem = _type_problem(kind, value)
        if problem is None and kind in ("int", "float"):
            problem = field.metadata.get("bounds", Bounds()).problem(value)
        elif problem is None and "bounds" in field.metadata:
            problem = field.metadata["bounds"].problem(value)
        if problem:
            raise InputError(None, field.name, problem)
    for name, problem in getattr(settings, "implied_problems", list)():
        raise InputError(None, name, problem)


def coerce_setting(cls, name: str, value, source: str | Path | None):
    """``value`` (a TOML value, or the text of ``--set``) as the type of field ``name`` of the
    settings dataclass ``cls``; an unknown name or a wrong type raises an InputError naming
    ``source`` and the setting."""
    by_name = {f.name: f for f in fields(cls)}
    if name not in by_name:
        raise InputError(source, name, f"unknown setting (known: {', '.join(sorted(by_name))})")
    kind, optional = setting_kind(by_name[name])
    if optional and (value is None or (isinstance(value, str) and value.lower() in ("none", "null", ""))):
        return None
    numbers = _number_tuple_length(by_name[name])
    if numbers is not None:
        if not (isinstance(value, (list, tuple)) and len(value) == numbers
                and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
            raise InputError(source, name, f"expected {numbers} numbers, got {_shown(value)}")
        return tuple(float(v) for v in value)
    try:
        if kind == "bool":
            if isinstance(value, str) and value.lower() in _BOOLS:
                return _BOOLS[value.lower()]
            if not isinstance(value, bool):
                raise ValueError
            return value
        if kind in ("int", "float") and isinstance(value, bool):
            raise ValueError
        if kind == "int":
            if isinstance(value, float):
                if not value.is_integer():
                    raise ValueError
                return int(value)
            return int(value) if isinstance(value, int) else int(str(value).strip(), 10)
        if kind == "float":
            return float(value)
        if kind == "str" and not isinstance(value, str):
            raise ValueError
        return value
    except (TypeError, ValueError, OverflowError):
        raise InputError(source, name, f"expected {kind}, got {_shown(value)}") from None


_BOOLS = {"true": True, "false": False, "1": True, "0": False, "yes": True, "no": False}


def nested_settings(cls, name: str, base=None):
    """The default (or ``base``'s value) of field ``name`` of ``cls`` when it is itself a
    settings dataclass (a sub-table of a settings file, e.g. ``detect.rtm``), else None."""
    field = {f.name: f for f in fields(cls)}.get(name)
    if field is None:
        return None
    if base is not None:
        value = getattr(base, name)
    elif field.default is not dataclasses.MISSING:
        value = field.default
    elif field.default_factory is not dataclasses.MISSING:
        value = field.default_factory()
    else:
        return None
    return value if dataclasses.is_dataclass(value) and not isinstance(value, type) else None


def settings_from(cls, values: dict, source: str | Path | None, base=None, sources: dict | None = None):
    """A settings dataclass ``cls`` (or ``base`` with changes) from ``values`` read from
    ``source`` (a file, or an option such as ``--set``): every value is coerced and checked
    before any work, and a bad one raises an InputError naming the source and the setting.
    ``sources`` gives another source for some names (e.g. ``--set`` over a file). A field that
    is itself a settings dataclass takes a table of its own settings (named ``field.key``)."""
    sources = sources or {}
    coerced = {}
    for k, v in values.items():
        nested = nested_settings(cls, k, base)
        if nested is not None and isinstance(v, dict):
            try:
                coerced[k] = settings_from(type(nested), v, sources.get(k, source), base=nested)
            except InputError as e:
                raise InputError(e.path, f"{k}.{e.field}", e.problem) from None
        else:
            coerced[k] = coerce_setting(cls, k, v, sources.get(k, source))
    try:
        return dataclasses.replace(base, **coerced) if base is not None else cls(**coerced)
    except InputError as e:
        if e.path is not None:
            raise
        raise InputError(sources.get(e.field, source), e.field, e.problem) from None


@dataclass(frozen=True)
class Config:
    # --- affinity (Eq. 1, 2) -------------------------------------------------------------
    #: Keypoints with confidence below this are treated as missing everywhere. [0-1]
    keypoint_threshold: float = setting(0.2, ge=0, le=1)
    #: γ of Eq. 1, applied to D expressed in the unit ``distance_scale``. [1]
    gamma: float = setting(1.0, gt=0)
    #: The unit of the epipolar distance D, as a fraction of the focal length: D is divided
    #: by ``distance_scale · f`` pixels, so the same γ works at every image resolution. [focal]
    distance_scale: float = setting(0.01, gt=0)
    #: The unit of D grows with the detector's noise measured once in each scene (in each rig's
    #: capture): the lower quartile of every 2D pose's distance to the nearest pose of every
    #: other view (most of them its own person's, whose distance is the noise) is brought down to
    #: at most this many units, the unit growing up to 4-fold
    #: (:func:`mvm.core.affinity.measured_unit_factor`).
    #: A noisier detector (a small model on large frames) then keeps its true matches; lower it to
    #: grow the unit sooner, raise it to hold ``distance_scale`` for noisier data; 0 always holds
    #: ``distance_scale``. [units of D]
    distance_quartile: float = setting(0.45, ge=0)
    #: Poses sharing fewer keypoints than this have affinity 0. [keypoints]
    min_common_keypoints: int = setting(3, ge=1, le=17)
    #: Use the annotations' appearance descriptors (cosine similarity S) when present. [bool]
    use_appearance: bool = True
    # --- grouping (Algorithm 1) ----------------------------------------------------------
    #: A candidate joins a group while its confidence-weighted mean affinity to the group's
    #: members is at least τ. Affinities lie in [0, 0.5] (0.5 at D = 0). [affinity]
    tau: float = setting(0.2, ge=0)
    #: Poses with a score below this never seed nor join a group. [0-1]
    min_pose_score: float = setting(0.05, ge=0, le=1)
    #: Groups with fewer 2D poses than this are discarded (their poses stay unmatched). [poses]
    min_group_size: int = setting(3, ge=1)
    #: On a longer video the grouping (whose cost grows as the square of the poses it compares)
    #: runs on this many frames only, evenly spread along the video (by camera position for
    #: unordered photos); the association in 3D then brings every other frame's poses in by
    #: reprojection, at a cost linear in the frames, and groups what no person explains in
    #: windows of this many consecutive frames (with ``association = "paper"``: one round of the
    #: assignment brings the other frames in). A scene of this many frames or fewer is grouped
    #: whole. [frames]
    keyframes: int = setting(150, ge=3)
    #: Persons with fewer reconstructed joints than this are discarded. [joints]
    min_person_joints: int = setting(5, ge=1, le=17)
    # --- triangulation -------------------------------------------------------------------
    #: A 2D keypoint is a RANSAC inlier when its reprojection error is below this, in person
    #: sizes (pixels divided by the median over the people detected in that view of the square
    #: root of their keypoints' box area, as OKS; :mod:`mvm.core.image_units`), so one value
    #: serves every resolution and distance: lower it to reject more keypoints (fewer, cleaner
    #: inliers), raise it for a noisier detector. With ``ransac_threshold_sigmas`` it starts
    #: the first triangulation and bounds the scene's own threshold to half to twice it.
    #: [person sizes]
    ransac_threshold: float = setting(0.12, gt=0)
    #: The RANSAC threshold of each scene (each instant of a rig) is this many standard
    #: deviations of its detector noise, measured from the inliers of a first triangulation (their
    #: median reprojection error over 1.18, the median of a 2D Gaussian error of deviation 1):
    #: raise it to keep more keypoints, lower it to reject more; 0 holds ``ransac_threshold``.
    #: The refinement's ``robust_scale`` and ``prior_weight`` follow the same measure of the
    #: noise (scaled by the scene's threshold over ``ransac_threshold``, the weight by its square).
    #: [standard deviations]
    ransac_threshold_sigmas: float = setting(4.5, ge=0)
    #: Number of RANSAC hypotheses (two-view triangulations) per joint; a joint with no more
    #: pairs of views than this tries each pair once. [1]
    ransac_hypotheses: int = setting(48, ge=1, le=10_000)
    #: A person seen in more views than this (a long video) draws and scores its RANSAC
    #: hypotheses on this many of them, well spread along the video and confident; its
    #: inliers are then taken among all its views, and the triangulation uses them all. [views]
    max_triangulation_views: int = setting(150, ge=2)
    #: Use RANSAC; off, every keypoint of a group is used (the paper's "w/o RANSAC"). [bool]
    ransac: bool = True
    #: Two persons whose joints are closer than this fraction of the torso length (the upper
    #: quartile over their joints: a stray joint does not keep them apart) are one person split
    #: into two groups, and are merged; 0 disables. [torso lengths]
    merge_distance: float = setting(0.3, ge=0)
    # --- association consistent in 3D ----------------------------------------------------
    #: How 2D poses become persons: "paper" keeps the groups of Algorithm 1 (Tables 1-2);
    #: "3d" then reassigns every 2D pose to the triangulated person whose reprojection explains
    #: it, one pose per person per view, and re-triangulates until (almost) nothing changes
    #: (slower, fewer identity switches in crowds); "auto": "3d" for scenes, "paper" for the instants of
    #: a rig (where the epipolar grouping is rarely wrong and "3d" costs about half of the
    #: reconstruction time for no gain). [-]
    association: str = setting("auto", choices=("auto", "paper", "3d"))
    #: A 2D pose joins a person only when its keypoints lie (median over joints) closer than
    #: this to the person's reprojection, in person sizes (sqrt of its image box area, as OKS);
    #: lower refuses noisy poses, higher lets neighbours' poses in. [person sizes]
    association_gate: float = setting(0.15, gt=0)
    #: Rounds of assignment and re-triangulation at most (most scenes settle in 2-3). [1]
    association_iterations: int = setting(4, ge=1)
    #: Random RANSAC hypotheses per joint when re-triangulating a person during the
    #: association, besides its previous 3D joint (which is nearly always the best). [1]
    association_hypotheses: int = setting(8, ge=1)
    #: The frames of a scene are a video (in the order of their names, numbers as numbers): a
    #: pose close to a person's pose in a neighbouring frame (at most 3 frames away) may join
    #: it although its distance to the reprojection is up to twice the gate. Off for unordered
    #: photos; never used for the cameras of a rig. [bool]
    video_order: bool = True
    #: A person must explain at least this fraction of the views it projects into, else it is
    #: refused (false positives that happen to agree in a few views, or a second person of a
    #: few views beside a true one). [0-1]
    association_min_support: float = setting(0.2, ge=0, le=1)
    #: The same for a person of a rig instant, whose cameras stand around the people and see
    #: each one from every side at once (a hand-held video's frames follow one another along
    #: an arc, so a person hidden behind another stays hidden for a long stretch of them):
    #: a cluster of false poses that agree in three of eighteen cameras is refused. [0-1]
    rig_min_support: float = setting(0.3, ge=0, le=1)
    #: A person whose bone lengths deviate from human proportions by more than this (median
    #: over the bones, after fitting the scale; a real person: about 0.05, up to 0.3 on short
    #: arcs) is refused unless it explains half the views it projects into: false positives
    #: that agree in a few close views triangulate to no body (or to joints no three of its
    #: views agree on, refused alike). [fraction]
    association_max_proportion_deviation: float = setting(0.4, gt=0)
    #: Minimum number of inlier views to reconstruct a joint. [views]
    min_views: int = setting(2, ge=2)
    #: A joint whose inlier rays span less than this angle is left unreconstructed. [deg]
    min_parallax_deg: float = setting(3.0, ge=0, lt=180)
    #: A joint whose bones all come out more than this many times their human proportion at the
    #: person's scale (a real person: 1 ± 0.3) is left unreconstructed, before the refinement:
    #: its views agree on a point far along their rays (a narrow arc, a keypoint of the other
    #: side among them). A bone longer than this whose ends no view sees together splits a
    #: person into the two people it holds (association in 3D). Raise it to keep such joints;
    #: 0 keeps all and splits none. [1]
    max_bone_ratio: float = setting(2.0, ge=0)
    # --- refinement (Eq. bundle) ---------------------------------------------------------
    #: Run the refinement (reprojection + λ·pose prior). [bool]
    refine: bool = True
    #: λ, the weight of the pose prior's negative log-likelihood against the robust
    #: reprojection error, whose residuals are in person sizes (as ``ransac_threshold``), for a
    #: person seen from all around (cameras around the people): raise it to trust the prior more
    #: than the keypoints, lower it to trust the keypoints. A person whose views constrain its
    #: depth less gets more, up to 5 times (its views' spread, :mod:`mvm.core.refine_units`: a
    #: hand-held tour's narrow arc), and each scene (rig instant) weighs it by the square of its
    #: noise relative to ``ransac_threshold`` (its RANSAC threshold over ``ransac_threshold``,
    #: see ``ransac_threshold_sigmas``), as the variance of a Gaussian likelihood would; the
    #: weight used is in poses3d.json. [person sizes² per nat]
    prior_weight: float = setting(1.5e-4, ge=0)
    #: Scale of the robust (soft-L1) loss on reprojection residuals: residuals beyond it count
    #: linearly, not quadratically; lower it to discount large residuals more. Each scene (rig
    #: instant) scales it by its RANSAC threshold over ``ransac_threshold``, so that it stays the
    #: same number of standard deviations of the measured noise. [person sizes]
    robust_scale: float = setting(0.07, gt=0)
    #: Levenberg-Marquardt steps of the refinement per person and outer iteration (one
    #: evaluation of the objective each). [1]
    refine_max_iterations: int = setting(30, ge=1, le=10_000)
    #: Complete every person: joints not reconstructed are inferred from the pose prior given the
    #: others (rigs: first interpolated along the track), each joint flagged observed /
    #: interpolated / inferred; off leaves them null. None: off for scenes, on for rigs. [bool]
    complete: bool | None = None
    # --- random numbers ------------------------------------------------------------------
    #: Seed of RANSAC's sampling: a scene gives the same result every run. [1]
    seed: int = setting(0, ge=0, le=2**63 - 1)
    # --- resources -----------------------------------------------------------------------
    #: Largest memory the affinity of a scene may take: ``4 N²`` bytes for N 2D poses
    #: (``8 N²`` with appearance descriptors). A larger scene is refused before any work,
    #: with a message giving the amount needed. [bytes]
    max_affinity_bytes: int = setting(4 * 2**30, ge=1)
    #: How long a run waits for another run writing the same scene's output. [s]
    lock_timeout_s: float = setting(600.0, ge=0)

    def __post_init__(self):
        check_settings(self)

    def replace(self, **changes) -> Config:
        return dataclasses.replace(self, **changes)

    def for_driver(self, driver: str) -> Config:
        """These settings as ``driver`` (``"scene"`` or ``"rig"``) runs them: every setting left
        to the driver (``association = "auto"``, ``complete`` None) takes the driver's default
        (:data:`DRIVER_DEFAULTS`). Settings already resolved come back as they are."""
        changes = {name: value for name, value in DRIVER_DEFAULTS[driver].items()
                   if getattr(self, name) == _LEFT_TO_DRIVER[name]}
        return self.replace(**changes) if changes else self

    @property
    def resolved(self) -> bool:
        """Whether no setting is left to the driver: these are the settings a driver runs with
        (:meth:`for_driver`). Each driver resolves its settings once, at its entry
        (:func:`mvm.core.reconstruct.scene_config`, :func:`mvm.rig.reconstruct_rig.rig_config`);
        the functions below it take them resolved."""
        return all(getattr(self, name) != value for name, value in _LEFT_TO_DRIVER.items())


#: The frame rate of footage that gives none (a rig's pose files, a video header without one,
#: a simulated rig). [Hz]
DEFAULT_FRAME_RATE_HZ = 30.0

#: The value of a setting that leaves it to the driver.
_LEFT_TO_DRIVER = {"association": "auto", "complete": None}
#: Each driver's default of the settings left to it: static scenes (``mvm reconstruct``,
#: ``run``, ``batch``, ``demo``) and the instants of a rig (``mvm rig reconstruct``).
DRIVER_DEFAULTS = {"scene": {"association": "3d", "complete": False},
                   "rig": {"association": "paper", "complete": True}}
#: Settings of :class:`Config` a driver never reads: given to it, they are refused, not ignored.
UNUSED_BY_DRIVER = {"scene": ("rig_min_support",),
                    "rig": ("video_order", "max_affinity_bytes", "keyframes", "association_min_support")}
