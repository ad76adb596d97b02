"""Settings of the rig driver that the per-scene :class:`mvm.core.config.Config` does not hold
(the reconstruction's, ``association`` and ``complete`` included, are all there)."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from mvm.core.config import DEFAULT_FRAME_RATE_HZ, check_settings, setting


@dataclass(frozen=True)
class RigOptions:
    #: Instants reconstructed together (one batched affinity, triangulation and refinement);
    #: larger is faster per instant and uses more memory. The batches are shared out whole among
    #: the workers, so the result does not depend on their number. [instants]
    batch_size: int = setting(32, ge=1, le=100_000)
    #: Processes reading, reconstructing and refining in parallel; 0: one per core this process
    #: may use (or ``$MVM_WORKERS``), 1: everything in this process. [processes]
    workers: int = setting(0, ge=0, le=1024)
    #: A person links to a track when its mean joint distance to the track's last pose is below
    #: this; raise it for fast motion or low frame rates. [metres]
    max_link_distance_m: float = setting(0.5, gt=0)
    #: A track not seen for more than this many instants ends; a person seen later gets a new id.
    #: [instants]
    max_gap: int = setting(10, ge=0)
    #: A person joins a track only when their distance is measured over at least this many shared
    #: joints (fewer if the person has fewer); lower lets sparse persons jump between tracks. [joints]
    min_link_joints: int = setting(4, ge=1, le=17)
    #: Tracks seen at fewer instants than this (the instants a track was filled at do not count)
    #: are dropped from the .trc output (they stay in the JSON Lines). [instants]
    min_track_length: int = setting(1, ge=1)
    #: Temporal smoothing of each track: "none", "butterworth" (zero-phase low-pass) or "savgol". [-]
    smoothing: str = setting("butterworth", choices=("none", "butterworth", "savgol"))
    #: Cut-off of the Butterworth filter; lower smooths more. None: 6 Hz, or a fifth of the frame
    #: rate for rigs slower than 30 Hz. Must stay below the Nyquist frequency (half the frame rate). [Hz]
    cutoff_hz: float | None = setting(None, gt=0)
    #: Order of the Butterworth filter. [1]
    filter_order: int = setting(4, ge=1, le=16)
    #: Window of the Savitzky-Golay filter (odd); longer smooths more. [instants]
    savgol_window: int = setting(9, ge=3, odd=True)
    #: Frame rate of the rig, for times in .trc files and the filter. None: the rate of the videos
    #: that ``mvm rig detect`` recorded in the pose files, else 30 Hz. [Hz]
    frame_rate: float | None = setting(None, gt=0)
    #: Size of one world unit in metres (Pose2Sim calibrations: 1; anipose in mm: 0.001;
    #: Panoptic: 0.01). [m / unit]
    metres_per_unit: float = setting(1.0, gt=0)
    #: The world's up axis, for the Y-up .trc files: "+z", "-z", "+y" or "-y". [-]
    up: str = setting("+z", choices=("+z", "-z", "+y", "-y"))
    #: Weight of the soft bone-length term in the refinement: each person's bones are pulled
    #: to its track's median lengths. A bone 1 % off costs ``bone_weight / 10⁴`` squared person
    #: sizes, as the refinement's reprojection residuals (3.2e-5 by default, a residual of 0.6 %
    #: of the person's size, in the capture's noise units: a noisier detector's keypoints weigh
    #: less against it); raise it for a more rigid skeleton, 0 turns the term off. [person sizes²]
    bone_weight: float = setting(0.32, ge=0)
    #: Longest run of missing instants a joint is interpolated over; longer gaps are left to the
    #: pose prior. [instants]
    max_interpolation_gap: int = setting(30, ge=0)
    #: Runs of missing instants of a limb joint (elbow, wrist, knee, ankle) are filled from the
    #: track's motion, its bone lengths, the pose prior and the views that still see the joint
    #: (:mod:`mvm.rig.occlusions`); runs from this long, and those at a track's end, are flagged
    #: inferred, shorter ones interpolated. [instants]
    occlusion_inferred_gap: int = setting(5, ge=1)
    #: The longest run a limb joint is filled over that way (longer ones are left to the pose
    #: prior); 0 turns it off. [instants]
    occlusion_max_gap: int = setting(90, ge=0)
    #: Write inferred joints into the .trc files too (by default they carry only observed and
    #: interpolated markers). [bool]
    trc_inferred: bool = False

    def __post_init__(self):
        check_settings(self)

    @property
    def rate(self) -> float:
        """The frame rate in use: ``frame_rate``, else :data:`mvm.core.config.DEFAULT_FRAME_RATE_HZ`. [Hz]"""
        return self.frame_rate if self.frame_rate is not None else DEFAULT_FRAME_RATE_HZ

    @property
    def cutoff(self) -> float:
        """The Butterworth cut-off in use: ``cutoff_hz``, else 6 Hz capped at a fifth of the frame rate. [Hz]"""
        return self.cutoff_hz if self.cutoff_hz is not None else min(6.0, self.rate / 5)

    def implied_problems(self) -> list[tuple[str, str]]:
        """The Butterworth cut-off must lie below the Nyquist frequency of the frame rate."""
        if self.smoothing == "butterworth" and not self.cutoff < self.rate / 2:
            return [("cutoff_hz", f"must be below half the frame rate ({self.rate / 2:g} Hz at "
                                  f"frame_rate {self.rate:g}), got {self.cutoff:g}")]
        return []

    def replace(self, **changes) -> RigOptions:
        return dataclasses.replace(self, **changes)
