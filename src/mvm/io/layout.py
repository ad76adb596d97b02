"""The folder layouts mvm reads and writes, declared once: a scene directory and a rig directory.

Every module names these files and folders through this one: the names as constants, and a
folder's paths as the properties of :class:`SceneLayout` and :class:`RigLayout`. The record of
each output (``<output>.inputs.json``, :mod:`mvm.io.provenance`) lies beside it.

A scene directory (one moving camera, ``docs/architecture.md``)::

    scene/
      sparse/                COLMAP model, text or binary: cameras, images (pose of every frame), points3D
      poses2d.json           2D poses, COCO keypoints dataset format
      frames/                optional: the images, named as in poses2d.json
      frames.json            optional: frame number and timestamp of every image (a video's order)
      sfm/report.json        what the SfM did (mvm sfm); sfm/scale.json: the metric scale applied to sparse/
      ../scene.groundtruth.json   a simulated scene's ground truth, beside the folder
      detections.json        optional (mvm batch): the clip's imported 2D poses (or a detections/ folder)
      mvm/                   everything mvm writes for this scene (the output name can be changed)
        poses3d.json         the persons in 3D
        timings.json         the seconds each step of the reconstruction took
        supervision/annotations.json   the export: 3D poses projected into every frame
        report.html          the page (mvm report); overlay/ or overlay.mp4: the overlays (mvm overlay)

A rig directory (synchronized static cameras)::

    RIG_DIR/
      Calib.toml | calibration/*.toml | sparse/ (COLMAP)   the cameras (or --calib PATH)
      calibration/intrinsics/, calibration/extrinsics/     videos or photos of a board (mvm rig calibrate)
      sync.toml                                           frame offsets (optional, mvm.io.sync_toml)
      sync.inputs.json, <calibration>.inputs.json         records of mvm's outputs (mvm.io.provenance), not cameras
      videos/<camera>.<ext>                               the cameras' videos (optional: mvm rig detect, overlays)
      pose/ (or RIG_DIR itself)
        <camera>/          OpenPose or OpenPifPaf JSON, one file per frame (frame number in the name)
        <camera>.json      or one COCO keypoints file per camera (frame number in file_name; its
                           info.video, written by mvm rig detect, gives the video's frame rate)
        <camera>.inputs.json  the record of a pose file mvm made (mvm.io.provenance), not a camera
      ../RIG_DIR.groundtruth.json, .groundtruth.toml   a simulated rig's truth and true calibration
      mvm/ (or -o)         the output set of mvm rig reconstruct, replaced whole (mvm.rig.output_set)
        poses3d.jsonl      the persons of every instant
        tracks/track_<id>.trc   one track per person
        recap.json         the run's recap
        report.html, overlay/   the page and the overlays (mvm report, mvm overlay)
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

#: The folder of a scene's or a rig's outputs when none is named (``--output-name``, ``-o``).
DEFAULT_OUTPUT = "mvm"
#: A COLMAP model: a scene's cameras, or a rig's calibration.
SPARSE = "sparse"

# -- a scene directory ------------------------------------------------------------------------
#: The 2D poses of a scene (COCO keypoints dataset format).
POSES2D = "poses2d.json"
#: The images of a scene.
FRAMES = "frames"
#: The frame number and timestamp of every image of ``frames/`` (a video's order).
FRAMES_INDEX = "frames.json"
#: The SfM's working folder, with its report and the metric scale applied to ``sparse/``.
SFM_DIR = "sfm"
SFM_REPORT = "report.json"
SCALE_FILE = "scale.json"
#: The 3D poses of a scene, in its output folder.
POSES3D = "poses3d.json"
#: The seconds each step of a scene's reconstruction took, beside its ``poses3d.json`` (which
#: holds nothing that depends on the run).
TIMINGS = "timings.json"
#: The export of a scene's 3D poses projected into its frames, in its output folder.
SUPERVISION_DIR = "supervision"
SUPERVISION_FILE = "annotations.json"
#: The ground truth of a simulated scene or rig lies beside its folder: ``<folder>.groundtruth.json``
#: (and a rig's true calibration, ``<folder>.groundtruth.toml``).
TRUTH_SUFFIX = ".groundtruth.json"
TRUE_CALIBRATION_SUFFIX = ".groundtruth.toml"
#: A clip's imported 2D poses in ``mvm batch``: ``detections.json`` or ``detections/`` in its
#: scene directory, or ``<video stem>.detections.json`` / ``.detections`` beside its video.
DETECTIONS = "detections"
#: The entries that make a folder a scene directory: what its stages read.
SCENE_INPUTS = (SPARSE, POSES2D, FRAMES, FRAMES_INDEX)

# -- what draws a reconstruction, a scene's or a rig's -----------------------------------------
#: The HTML page of a reconstruction (``mvm report``), in its output folder.
REPORT_PAGE = "report.html"
#: The overlays of a reconstruction (``mvm overlay``), in its output folder.
OVERLAY = "overlay"
#: The page of many scenes (``mvm batch``).
SUMMARY_PAGE = "summary.html"

# -- a rig directory ---------------------------------------------------------------------------
#: A rig's calibration as mvm writes it.
CALIB_TOML = "Calib.toml"
#: A folder of a rig's calibration files.
CALIBRATION_DIR = "calibration"
#: Videos or photos of a board in ``calibration/`` (``mvm rig calibrate --checkerboard | --charuco``):
#: the intrinsics' and the extrinsics' (else ``calibration/<camera>.<ext>`` serve both).
INTRINSICS_DIR = "intrinsics"
EXTRINSICS_DIR = "extrinsics"
#: A rig's frame offsets (:mod:`mvm.io.sync_toml`).
SYNC = "sync.toml"
#: TOML files at a rig's top that are no calibration: settings files and :data:`SYNC`.
NOT_CALIBRATIONS = ("config.toml", "mvm.toml", SYNC)
#: The folder of a rig's pose files (else the rig folder itself holds them).
POSE_DIR = "pose"
#: The cameras' videos: ``RIG_DIR/videos/<camera>.<ext>``.
VIDEOS = "videos"
#: A rig's output set: the persons of every instant, one ``.trc`` track per person, the recap.
RIG_POSES3D = "poses3d.jsonl"
TRACKS_DIR = "tracks"
#: The ``.trc`` file of a track in ``tracks/``: ``TRACK_FILE.format(track=7)``.
TRACK_FILE = "track_{track}.trc"
RECAP = "recap.json"


def _beside(folder: Path, suffix: str) -> Path:
    """The file ``<folder><suffix>`` beside ``folder``."""
    return folder.parent / (folder.name + suffix)


@dataclass(frozen=True)
class SceneLayout:
    """The paths of a scene directory ``root`` whose output folder is named ``output``.

    >>> SceneLayout(Path("clip")).poses3d.as_posix()
    'clip/mvm/poses3d.json'
    """

    root: Path
    output: str = DEFAULT_OUTPUT

    def __post_init__(self):
        object.__setattr__(self, "root", Path(self.root))

    @property
    def sparse(self) -> Path:
        return self.root / SPARSE

    @property
    def truth(self) -> Path:
        """The ground truth of a simulated scene, beside the folder."""
        return _beside(self.root, TRUTH_SUFFIX)

    @property
    def poses2d(self) -> Path:
        return self.root / POSES2D

    @property
    def frames(self) -> Path:
        return self.root / FRAMES

    @property
    def frames_index(self) -> Path:
        return self.root / FRAMES_INDEX

    @property
    def sfm_report(self) -> Path:
        return self.root / SFM_DIR / SFM_REPORT

    @property
    def scale_file(self) -> Path:
        return self.root / SFM_DIR / SCALE_FILE

    @property
    def out_dir(self) -> Path:
        """The output folder, unchecked (:func:`mvm.io.scene_dir.output_dir` checks it)."""
        return self.root / self.output

    @property
    def poses3d(self) -> Path:
        return self.out_dir / POSES3D

    @property
    def supervision(self) -> Path:
        return self.out_dir / SUPERVISION_DIR


@dataclass(frozen=True)
class RigLayout:
    """The paths of a rig directory ``root`` whose output set is ``output`` (a name in ``root``,
    or any folder: an absolute path is kept as it is).

    >>> RigLayout(Path("rig")).poses3d.as_posix()
    'rig/mvm/poses3d.jsonl'
    """

    root: Path
    output: str | Path = DEFAULT_OUTPUT

    def __post_init__(self):
        object.__setattr__(self, "root", Path(self.root))

    @property
    def truth(self) -> Path:
        """The ground truth of a simulated rig, beside the folder."""
        return _beside(self.root, TRUTH_SUFFIX)

    @property
    def true_calibration(self) -> Path:
        """The true calibration of a simulated rig, beside the folder."""
        return _beside(self.root, TRUE_CALIBRATION_SUFFIX)

    @property
    def calib_toml(self) -> Path:
        return self.root / CALIB_TOML

    @property
    def calibration_dir(self) -> Path:
        return self.root / CALIBRATION_DIR

    @property
    def sparse(self) -> Path:
        return self.root / SPARSE

    @property
    def sync(self) -> Path:
        return self.root / SYNC

    @property
    def pose_dir(self) -> Path:
        return self.root / POSE_DIR

    @property
    def videos(self) -> Path:
        return self.root / VIDEOS

    @property
    def out_dir(self) -> Path:
        return self.root / self.output

    @property
    def poses3d(self) -> Path:
        return self.out_dir / RIG_POSES3D

    @property
    def recap(self) -> Path:
        return self.out_dir / RECAP
