"""Settings of the rig pipeline that the per-scene :class:`mvm.core.config.Config` does not hold."""
from __future__ import annotations

import dataclasses
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
    #: Tracks shorter than this are dropped from the .trc output (they stay in the JSON Lines). [instants]
    min_track_length: int = 1
    #: Temporal smoothing of each track: "none", "butterworth" (zero-phase low-pass) or "savgol". [-]
    smoothing: str = "none"
    #: Cut-off of the Butterworth filter; lower smooths more. [Hz]
    cutoff_hz: float = 6.0
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

    def __post_init__(self):
        if self.smoothing not in ("none", "butterworth", "savgol"):
            raise ValueError(f"smoothing: expected 'none', 'butterworth' or 'savgol', got {self.smoothing!r}")
        if self.up not in ("+z", "-z", "+y", "-y"):
            raise ValueError(f"up: expected '+z', '-z', '+y' or '-y', got {self.up!r}")
        for name in ("batch_size", "max_gap", "min_track_length", "filter_order", "savgol_window"):
            if getattr(self, name) < (0 if name == "max_gap" else 1):
                raise ValueError(f"{name}: must be positive, got {getattr(self, name)}")
        for name in ("max_link_distance_m", "cutoff_hz", "frame_rate", "metres_per_unit"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}: must be > 0, got {getattr(self, name)}")

    def replace(self, **changes) -> "RigOptions":
        return dataclasses.replace(self, **changes)
