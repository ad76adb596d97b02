"""One immutable configuration object for every threshold of the reconstruction.

Every field has a unit and a sentence in the README (section "Configuration"). A config is
read from a TOML file (flat keys, or under a ``[reconstruct]`` table) and overridden from the
command line with ``--set key=value``.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, fields
from pathlib import Path

from mvm.errors import InputError


#: The ways 2D poses become persons (``Config.association``).
ASSOCIATIONS: tuple[str, ...] = ("paper", "3d")


@dataclass(frozen=True)
class Config:
    # --- affinity (Eq. 1, 2) -------------------------------------------------------------
    #: Keypoints with confidence below this are treated as missing everywhere. [0-1]
    keypoint_threshold: float = 0.2
    #: γ of Eq. 1, applied to D expressed in the unit ``distance_scale``. [1]
    gamma: float = 1.0
    #: The unit of the epipolar distance D, as a fraction of the focal length: D is divided
    #: by ``distance_scale · f`` pixels, so the same γ works at every image resolution. [focal]
    distance_scale: float = 0.01
    #: Poses sharing fewer keypoints than this have affinity 0. [keypoints]
    min_common_keypoints: int = 3
    #: Use the annotations' appearance descriptors (cosine similarity S) when present. [bool]
    use_appearance: bool = True
    # --- grouping (Algorithm 1) ----------------------------------------------------------
    #: A candidate joins a group while its confidence-weighted mean affinity to the group's
    #: members is at least τ. Affinities lie in [0, 0.5] (0.5 at D = 0). [affinity]
    tau: float = 0.2
    #: Poses with a score below this never seed nor join a group. [0-1]
    min_pose_score: float = 0.05
    #: Groups with fewer 2D poses than this are discarded (their poses stay unmatched). [poses]
    min_group_size: int = 3
    #: Persons with fewer reconstructed joints than this are discarded. [joints]
    min_person_joints: int = 5
    # --- triangulation -------------------------------------------------------------------
    #: A 2D keypoint is a RANSAC inlier when its reprojection error is below this. [px]
    ransac_threshold_px: float = 15.0
    #: Number of RANSAC hypotheses (two-view triangulations) per joint. [1]
    ransac_hypotheses: int = 48
    #: Use RANSAC; off, every keypoint of a group is used (the paper's "w/o RANSAC"). [bool]
    ransac: bool = True
    #: Two persons whose joints are on average closer than this fraction of the torso length
    #: are one person split into two groups, and are merged; 0 disables. [torso lengths]
    merge_distance: float = 0.3
    # --- association consistent in 3D ----------------------------------------------------
    #: How 2D poses become persons: "paper" keeps the groups of Algorithm 1 (Tables 1-2);
    #: "3d" then reassigns every 2D pose to the triangulated person whose reprojection explains
    #: it, one pose per person per view, and re-triangulates until nothing changes. [name]
    association: str = "3d"
    #: A 2D pose joins a person only when its keypoints lie, on average, closer than this to
    #: the person's reprojection, in person sizes (sqrt of its image box area, as OKS); lower
    #: refuses noisy poses, higher lets neighbours' poses in. [person sizes]
    association_gate: float = 0.15
    #: Rounds of assignment and re-triangulation at most (most scenes settle in 2-3). [1]
    association_iterations: int = 4
    #: Random RANSAC hypotheses per joint when re-triangulating a person during the
    #: association, besides its previous 3D joint (which is nearly always the best). [1]
    association_hypotheses: int = 8
    #: The frames of a scene are a video (in the order of their names, numbers as numbers): a
    #: pose close to a person's pose in a neighbouring frame (at most 3 frames away) may join
    #: it although its distance to the reprojection is up to twice the gate. Off for unordered
    #: photos. [bool]
    video_order: bool = True
    #: A person must explain at least this fraction of the views it projects into, else it is
    #: refused (false positives that happen to agree in a few views). [0-1]
    association_min_support: float = 0.2
    #: A person whose bone lengths deviate from human proportions by more than this (median
    #: over the bones, after fitting the scale; a real person: about 0.05, up to 0.3 on short
    #: arcs) is refused unless it explains half the views it projects into: false positives
    #: that agree in a few close views triangulate to no body. [fraction]
    association_max_proportion_deviation: float = 0.4
    #: Minimum number of inlier views to reconstruct a joint. [views]
    min_views: int = 2
    #: A joint whose inlier rays span less than this angle is left unreconstructed. [deg]
    min_parallax_deg: float = 3.0
    # --- refinement (Eq. bundle) ---------------------------------------------------------
    #: Run the refinement (reprojection + λ·pose prior). [bool]
    refine: bool = True
    #: λ, the weight of the pose prior's negative log-likelihood against the robust
    #: reprojection error (summed squared pixels). [px² per nat]
    prior_weight: float = 10.0
    #: Scale of the robust (soft-L1) loss on reprojection residuals. [px]
    robust_scale_px: float = 5.0
    #: Iterations of the solver (function evaluations ≈ 50 × this). [1]
    refine_max_iterations: int = 30
    # --- random numbers ------------------------------------------------------------------
    #: Seed of RANSAC's sampling: a scene gives the same result every run. [1]
    seed: int = 0
    # --- resources -----------------------------------------------------------------------
    #: Largest memory the affinity of a scene may take: ``4 N²`` bytes for N 2D poses
    #: (``8 N²`` with appearance descriptors). A larger scene is refused before any work,
    #: with a message giving the amount needed. [bytes]
    max_affinity_bytes: int = 4 * 2**30
    #: How long a run waits for another run writing the same scene's output. [s]
    lock_timeout_s: float = 600.0

    def replace(self, **changes) -> "Config":
        return dataclasses.replace(self, **changes)


def _coerce(name: str, value, source: str) -> object:
    """Convert ``value`` to the type of field ``name``; raise an InputError naming ``source``."""
    types = {f.name: f.type for f in fields(Config)}
    if name not in types:
        known = ", ".join(sorted(types))
        raise InputError(source, name, f"unknown setting (known: {known})")
    kind = types[name]
    try:
        if kind == "bool":
            if isinstance(value, str):
                if value.lower() not in ("true", "false", "1", "0", "yes", "no"):
                    raise ValueError
                return value.lower() in ("true", "1", "yes")
            if not isinstance(value, bool):
                raise ValueError
            return value
        if kind == "str":
            if not isinstance(value, str):
                raise ValueError
            return value
        if kind == "int":
            if isinstance(value, bool) or (isinstance(value, float) and not value.is_integer()):
                raise ValueError
            return int(value)
        if isinstance(value, bool):
            raise ValueError
        number = float(value)
        if number != number or number in (float("inf"), float("-inf")):
            raise ValueError
        return number
    except (TypeError, ValueError, OverflowError):
        shown = repr(value) if len(repr(value)) <= 40 else repr(value)[:39] + "…"
        raise InputError(source, name, f"expected {kind}, got {shown}") from None


def load_config(path: str | Path | None = None, overrides: dict | None = None) -> Config:
    """Read a TOML config (flat, or under ``[reconstruct]``) and apply ``overrides``."""
    values: dict = {}
    if path is not None:
        path = Path(path)
        from mvm.io.checks import load_toml

        data = load_toml(path)
        data = data.get("reconstruct", data)
        if not isinstance(data, dict):
            raise InputError(path, "reconstruct", "expected a table of settings")
        values.update({k: _coerce(k, v, str(path)) for k, v in data.items()})
    for k, v in (overrides or {}).items():
        values[k] = _coerce(k, v, "--set")
    config = Config(**values)
    _validate(config, str(path) if path else "--set")
    return config


def _validate(config: Config, source: str) -> None:
    positive = ("gamma", "distance_scale", "ransac_threshold_px", "robust_scale_px")
    for name in positive:
        if getattr(config, name) <= 0:
            raise InputError(source, name, f"must be > 0, got {getattr(config, name)}")
    for name in ("prior_weight", "tau", "merge_distance", "keypoint_threshold", "min_pose_score", "min_parallax_deg",
                 "lock_timeout_s"):
        if getattr(config, name) < 0:
            raise InputError(source, name, f"must be >= 0, got {getattr(config, name)}")
    if config.association not in ASSOCIATIONS:
        raise InputError(source, "association", f"unknown method {config.association!r} (known: {', '.join(ASSOCIATIONS)})")
    if config.association_max_proportion_deviation <= 0:
        raise InputError(source, "association_max_proportion_deviation",
                         f"must be > 0, got {config.association_max_proportion_deviation}")
    if not 0 < config.association_gate:
        raise InputError(source, "association_gate", f"must be > 0, got {config.association_gate}")
    if not 0 <= config.association_min_support <= 1:
        raise InputError(source, "association_min_support", f"must be in [0, 1], got {config.association_min_support}")
    if config.min_views < 2:
        raise InputError(source, "min_views", f"must be >= 2, got {config.min_views}")
    for name in ("ransac_hypotheses", "association_iterations", "association_hypotheses", "min_group_size", "min_person_joints", "min_common_keypoints", "refine_max_iterations",
                 "max_affinity_bytes"):
        if getattr(config, name) < 1:
            raise InputError(source, name, f"must be >= 1, got {getattr(config, name)}")
