"""What the ``report`` and ``overlay`` stages share: the reconstruction they draw (:class:`ViewJob`,
a scene directory or a rig folder), what they read (:func:`view_inputs`; a rig is read here, with
the rig's readers, and handed to the drawing as data: :func:`load_rig_view`, :func:`camera_videos`),
and where their records may lie (:func:`check_record_name`). Their records lie beside the page, the
video or the image folder; one written into a rig's output set is listed in the set's marker, so
that the next ``mvm rig reconstruct`` replaces it with the set (:func:`list_in_output_set`)."""
from __future__ import annotations

import os
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

from mvm.io.layout import (
    DEFAULT_OUTPUT,
    FRAMES,
    FRAMES_INDEX,
    POSES2D,
    POSES3D,
    RECAP,
    RIG_POSES3D,
    SPARSE,
    TIMINGS,
    VIDEOS,
    RigLayout,
    SceneLayout,
)


@dataclass(frozen=True)
class ViewJob:
    """A reconstruction to draw: ``folder`` (a scene directory, or a rig folder reconstructed by
    ``mvm rig reconstruct``), ``output`` (the name of its output folder), ``out`` (the page, the
    video or the image folder to write; None: in the output folder), ``calib`` (a rig's; None:
    the one its reconstruction used), ``frames`` (a scene page's overlay strip) and the
    overlay's ``step``, ``max_width``, ``fps`` and ``image_format`` (a scene's)."""

    folder: Path
    output: str = DEFAULT_OUTPUT
    out: Path | None = None
    calib: Path | None = None
    frames: int = 8
    step: int = 1
    max_width: int | None = None
    fps: float = 10.0
    image_format: str = ".jpg"

    @cached_property
    def rig(self) -> bool:
        """Whether ``folder`` is a rig folder (:func:`mvm.report.rig_load.is_rig_dir`), looked at
        once per job: a stage's steps agree, and the folder is not listed at each."""
        from mvm.report.rig_load import is_rig_dir

        return is_rig_dir(self.folder, self.output)

    @property
    def out_dir(self) -> Path:
        """The reconstruction's output folder (a scene's name checked:
        :func:`mvm.io.scene_dir.output_dir`)."""
        if self.rig:
            return RigLayout(self.folder, self.output).out_dir
        from mvm.io.scene_dir import output_dir

        return output_dir(self.folder, self.output)


def not_reconstructed(job: ViewJob) -> str | None:
    """Why there is nothing to draw in ``job`` (None: it is reconstructed)."""
    reconstructed = job.out_dir / (RIG_POSES3D if job.rig else POSES3D)
    return None if reconstructed.is_file() else f"not reconstructed (no {reconstructed.name})"


def rig_calibration(job: ViewJob) -> tuple[Path, bool]:
    """The calibration a page or the overlays of the reconstructed rig read: ``job.calib``, else
    the one its reconstruction was given, else the rig's own
    (:func:`mvm.rig.rigdir.find_calibration`); and whether it was given (not the rig's own). A
    rig not reconstructed is refused first."""
    from mvm.report.rig_load import given_calibration, reconstructed
    from mvm.rig.rigdir import find_calibration

    given = given_calibration(reconstructed(job.folder, job.output), job.calib)
    return (given, True) if given is not None else (find_calibration(Path(job.folder)), False)


def load_rig_view(job: ViewJob, workers: int | None = None):
    """What a page or the overlays of a reconstructed rig draw
    (:class:`~mvm.report.rig_load.RigReportData`): its output set, checked up to date, and the rig
    read as its reconstruction read it (:func:`mvm.rig.rigdir.read_rig`, the pose files on
    ``workers`` processes)."""
    from mvm.report.rig_load import checked_set, frames_setting, reconstructed, rig_command, rig_report_data
    from mvm.rig.reconstruct_rig import rig_fingerprint_inputs
    from mvm.rig.rigdir import read_rig

    folder = Path(job.folder)
    calib, given = rig_calibration(job)
    command = rig_command(folder, calib, given, job.output)
    recap = checked_set(folder, job.output, rig_fingerprint_inputs(folder, calib), command)
    rig = read_rig(folder, calib, frames_setting(reconstructed(folder, job.output)), workers)
    return rig_report_data(folder, job.output, rig, calib, recap, command)


def camera_videos(job: ViewJob, names: list[str]) -> dict[str, Path]:
    """The video of each camera of ``names`` that has one: ``RIG_DIR/videos/<camera>.<ext>``,
    matched to the camera names as pose folders are (:func:`mvm.rig.rigdir.match_cameras`)."""
    from mvm.errors import InputError
    from mvm.io.paths import videos_by_name
    from mvm.rig.rigdir import match_cameras

    folder = RigLayout(job.folder).videos
    files = list(videos_by_name(folder).values())
    try:
        matched = match_cameras(names, [p.stem for p in files])
    except ValueError as e:
        raise InputError(folder, None, str(e).replace("pose sources", "videos")) from None
    return {names[c]: files[e] for c, e in sorted(matched.items())}


def view_inputs(job: ViewJob, videos: bool = False) -> dict:
    """What a page or an overlay of ``job`` is drawn from, by name: a scene's 3D poses (with
    their timings), 2D poses, cameras, frames and ground truth; a rig's output set
    (``poses3d.jsonl``, ``recap.json``), what it was made from (the calibration, ``sync.toml``,
    the pose sources) and its ground truth; with ``videos``, the rig's ``videos/`` folder too."""
    if job.rig:
        from mvm.rig.reconstruct_rig import rig_fingerprint_inputs

        rig = RigLayout(job.folder, job.output)
        inputs = {**rig_fingerprint_inputs(rig.root, rig_calibration(job)[0]),
                  f"{job.output}/{RIG_POSES3D}": rig.poses3d, f"{job.output}/{RECAP}": rig.recap,
                  f"../{rig.truth.name}": rig.truth}
        return {**inputs, VIDEOS: rig.videos} if videos else inputs
    scene = SceneLayout(job.folder, job.output)
    out_dir = job.out_dir
    return {f"{job.output}/{POSES3D}": out_dir / POSES3D, f"{job.output}/{TIMINGS}": out_dir / TIMINGS,
            POSES2D: scene.poses2d, SPARSE: scene.sparse, FRAMES: scene.frames,
            FRAMES_INDEX: scene.frames_index, f"../{scene.truth.name}": scene.truth}


def input_paths(inputs: dict) -> list[Path]:
    """The paths among ``inputs`` (:func:`view_inputs`), for the checks of an output's location."""
    return [p for p in inputs.values() if isinstance(p, Path)]


def check_record_name(out: Path, inputs: dict, title: str) -> None:
    """Refuse, in one line naming ``out``, an ``out`` that is, holds or lies inside one of
    ``inputs`` (:func:`mvm.io.outputs.check_output_location`), or whose record
    (``<stem>.inputs.json``) would be another output's: an input's record (``-o
    SCENE/poses2d.html`` beside ``poses2d.json``), a record another stage wrote, or a file that
    is no record of mvm's (a user's own). Called before the record is removed."""
    from mvm.errors import InputError
    from mvm.io.outputs import check_output_location
    from mvm.io.provenance import read_record, record_path

    paths = input_paths(inputs)
    check_output_location(out, paths, replaced=False)
    record = record_path(out)
    other = read_record(out) if record.is_file() else None
    if record in {record_path(p) for p in paths} or (other is not None and other.get("stage") != title):
        raise InputError(out, None, f"its record would be {record.name}, the record of another output: "
                                    "choose another name")
    if os.path.lexists(record) and other is None:              # a page or video beside a user's own file
        raise InputError(out, None, f"its record would replace {record.name}, which is no record of mvm's: "
                                    "move it or choose another name")


def list_in_output_set(job: ViewJob, out: Path) -> None:
    """List the record of ``out`` in the rig's output set when ``out`` lies at its top (where
    :func:`mvm.io.outputs.add_to_output_set` wrote it): the next reconstruction replaces both."""
    if not job.rig:
        return
    from mvm.io.outputs import add_to_output_set
    from mvm.io.provenance import record_path
    from mvm.report.rig_load import in_output_set

    if in_output_set(out, job.out_dir):
        add_to_output_set(job.out_dir, record_path(out).name, lambda path: None)
