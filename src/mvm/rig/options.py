"""Settings of the rig pipeline that the per-scene :class:`mvm.core.config.Config` does not hold."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from mvm.core.config import check_settings, setting


@dataclass(frozen=True)
class RigOptions:
    #: Instants reconstructed together (one batched affinity, triangulation and refinement);
    #: larger is faster per instant and uses more memory. [instants]
    batch_size: int = setting(64, ge=1, le=100_000)
    #: A person links to a track when its mean joint distance to the track's last pose is below
    #: this; raise it for fast motion or low frame rates. [metres]
    max_link_distance_m: float = setting(0.5, gt=0)
    #: A track not seen for more than this many instants ends; a person seen later gets a new id.
    #: [instants]
    max_gap: int = setting(10, ge=0)
    #: Tracks shorter than this are dropped from the .trc output (they stay in the JSON Lines). [instants]
    min_track_length: int = setting(1, ge=1)
    #: Temporal smoothing of each track: "none", "butterworth" (zero-phase low-pass) or "savgol". [-]
    smoothing: str = setting("none", choices=("none", "butterworth", "savgol"))
    #: Cut-off of the Butterworth filter; lower smooths more. [Hz]
    cutoff_hz: float = setting(6.0, gt=0)
    #: Order of the Butterworth filter. [1]
    filter_order: int = setting(4, ge=1, le=16)
    #: Window of the Savitzky-Golay filter (odd); longer smooths more. [instants]
    savgol_window: int = setting(9, ge=3, odd=True)
    #: Frame rate of the rig, for times in .trc files and the filter. [Hz]
    frame_rate: float = setting(30.0, gt=0)
    #: Size of one world unit in metres (Pose2Sim calibrations: 1; anipose in mm: 0.001;
    #: Panoptic: 0.01). [m / unit]
    metres_per_unit: float = setting(1.0, gt=0)
    #: The world's up axis, for the Y-up .trc files: "+z", "-z", "+y" or "-y". [-]
    up: str = setting("+z", choices=("+z", "-z", "+y", "-y"))

    def __post_init__(self):
        check_settings(self)

    def implied_problems(self) -> list[tuple[str, str]]:
        """The Butterworth cut-off must lie below the Nyquist frequency of the frame rate."""
        if self.smoothing == "butterworth" and not self.cutoff_hz < self.frame_rate / 2:
            return [("cutoff_hz", f"must be below half the frame rate ({self.frame_rate / 2:g} Hz at "
                                  f"frame_rate {self.frame_rate:g}), got {self.cutoff_hz:g}")]
        return []

    def replace(self, **changes) -> RigOptions:
        return dataclasses.replace(self, **changes)
