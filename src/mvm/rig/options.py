"""Settings of the rig pipeline that the per-scene :class:`mvm.core.config.Config` does not hold."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass


@dataclass(frozen=True)
class RigOptions:
    #: Instants reconstructed together (one batched affinity, triangulation and refinement);
    #: larger is faster per instant and uses more memory. [instants]
    batch_size: int = 64
    #: A person links to a track when its mean joint distance to the track's last pose is below
    #: this; raise it for fast motion or low frame rates. [metres]
    max_link_distance_m: float = 0.5
    #: A track not seen for more than this many instants ends; a person seen later gets a new id.
    #: [instants]
    max_gap: int = 10
    #: A person joins a track only when their distance is measured over at least this many shared
    #: joints (fewer if the person has fewer); lower lets sparse persons jump between tracks. [joints]
    min_link_joints: int = 4
    #: Tracks shorter than this are dropped from the .trc output (they stay in the JSON Lines). [instants]
    min_track_length: int = 1
    #: Temporal smoothing of each track: "none", "butterworth" (zero-phase low-pass) or "savgol". [-]
    smoothing: str = "butterworth"
    #: Cut-off of the Butterworth filter; lower smooths more. None: 6 Hz, or a fifth of the frame
    #: rate for rigs slower than 30 Hz. Must stay below the Nyquist frequency (half the frame rate). [Hz]
    cutoff_hz: float | None = None
    #: Order of the Butterworth filter. [1]
    filter_order: int = 4
    #: Window of the Savitzky-Golay filter (odd); longer smooths more. [instants]
    savgol_window: int = 9
    #: Frame rate of the rig, for times in .trc files and the filter. [Hz]
    frame_rate: float = 30.0
    #: Size of one world unit in metres (Pose2Sim calibrations: 1; anipose in mm: 0.001;
    #: Panoptic: 0.01). [m / unit]
    metres_per_unit: float = 1.0
    #: The world's up axis, for the Y-up .trc files: "+z", "-z", "+y" or "-y". [-]
    up: str = "+z"
    #: Weight of the soft bone-length term in the refinement: each person's bones are pulled
    #: to its track's median lengths. A bone 1 % off costs ``bone_weight / 10⁴`` px² (2 px² by
    #: default); raise it for a more rigid skeleton, 0 turns the term off. [px²]
    bone_weight: float = 20000.0
    #: Complete every person: missing joints interpolated along the track, then inferred from the
    #: pose prior; each joint flagged observed / interpolated / inferred. [bool]
    complete: bool = True
    #: Longest run of missing instants a joint is interpolated over; longer gaps are left to the
    #: pose prior. [instants]
    max_interpolation_gap: int = 30
    #: Write inferred joints into the .trc files too (by default they carry only observed and
    #: interpolated markers). [bool]
    trc_inferred: bool = False

    def __post_init__(self):
        if self.smoothing not in ("none", "butterworth", "savgol"):
            raise ValueError(f"smoothing: expected 'none', 'butterworth' or 'savgol', got {self.smoothing!r}")
        if self.up not in ("+z", "-z", "+y", "-y"):
            raise ValueError(f"up: expected '+z', '-z', '+y' or '-y', got {self.up!r}")
        for name in ("batch_size", "max_gap", "min_track_length", "filter_order", "savgol_window",
                     "min_link_joints", "max_interpolation_gap"):
            if getattr(self, name) < (0 if name in ("max_gap", "max_interpolation_gap") else 1):
                raise ValueError(f"{name}: must be positive, got {getattr(self, name)}")
        if not (math.isfinite(self.bone_weight) and self.bone_weight >= 0):
            raise ValueError(f"bone_weight: must be a finite number >= 0, got {self.bone_weight}")
        for name in ("max_link_distance_m", "frame_rate", "metres_per_unit") + (
                ("cutoff_hz",) if self.cutoff_hz is not None else ()):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ValueError(f"{name}: must be a finite number > 0, got {getattr(self, name)}")
        if self.smoothing == "butterworth" and not self.cutoff < self.frame_rate / 2:
            raise ValueError(f"cutoff_hz: must be below the Nyquist frequency, half the frame rate "
                             f"({self.frame_rate / 2:g} Hz at frame_rate {self.frame_rate:g}), got {self.cutoff:g}")

    @property
    def cutoff(self) -> float:
        """The Butterworth cut-off in use: ``cutoff_hz``, else 6 Hz capped at a fifth of the frame rate. [Hz]"""
        return self.cutoff_hz if self.cutoff_hz is not None else min(6.0, self.frame_rate / 5)

    def replace(self, **changes) -> "RigOptions":
        return dataclasses.replace(self, **changes)
