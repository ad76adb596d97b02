"""What the ``report`` and ``overlay`` stages share: the reconstruction they draw (:class:`ViewJob`,
a scene directory or a rig folder), what they read (:func:`view_inputs`), and where their
records may lie (:func:`check_record_name`). Their records lie beside the page, the video or
the image folder; one written into a rig's output set is listed in the set's marker, so that the
next ``mvm rig reconstruct`` replaces it with the set (:func:`list_in_output_set`)."""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class ViewJob:
    """A reconstruction to draw: ``folder`` (a scene directory, or a rig folder reconstructed by
    ``mvm rig reconstruct``), ``output`` (the name of its output folder), ``out`` (the page, the
    video or the image folder to write; None: in the output folder), ``calib`` (a rig's; None:
    the one its reconstruction used), ``frames`` (a scene page's overlay strip) and the
    overlay's ``step``, ``max_width``, ``fps`` and ``image_format`` (a scene's)."""

    folder: Path
    output: str = "mvm"
    out: Path | None = None
    calib: Path | None = None
    frames: int = 8
    step: int = 1
    max_width: int | None = None
    fps: float = 10.0
    image_format: str = ".jpg"

    @property
    def rig(self) -> bool:
        """Whether ``folder`` is a rig folder (:func:`mvm.report.rig_load.is_rig_dir`)."""
        from mvm.report.rig_load import is_rig_dir

        return is_rig_dir(self.folder, self.output)

    @property
    def out_dir(self) -> Path:
        """The reconstruction's output folder (a scene's name checked:
        :func:`mvm.io.scene_dir.output_dir`)."""
        if self.rig:
            return Path(self.folder) / self.output
        from mvm.io.scene_dir import output_dir

        return output_dir(self.folder, self.output)


def not_reconstructed(job: ViewJob) -> str | None:
    """Why there is nothing to draw in ``job`` (None: it is reconstructed)."""
    reconstructed = job.out_dir / ("poses3d.jsonl" if job.rig else "poses3d.json")
    return None if reconstructed.is_file() else f"not reconstructed (no {reconstructed.name})"


def view_inputs(job: ViewJob, videos: bool = False) -> dict:
    """What a page or an overlay of ``job`` is drawn from, by name: a scene's 3D poses (with
    their timings), 2D poses, cameras, frames and ground truth; a rig's output set
    (``poses3d.jsonl``, ``recap.json``), what it was made from (the calibration, ``sync.toml``,
    the pose sources) and its ground truth; with ``videos``, the rig's ``videos/`` folder too."""
    folder = Path(job.folder)
    if job.rig:
        from mvm.io.rig_truth import rig_truth_path
        from mvm.report.rig_load import POSES3D, RECAP, VIDEOS, report_calibration
        from mvm.rig.reconstruct_rig import rig_fingerprint_inputs

        truth = rig_truth_path(folder)
        inputs = {**rig_fingerprint_inputs(folder, report_calibration(folder, job.output, job.calib)),
                  f"{job.output}/{POSES3D}": job.out_dir / POSES3D, f"{job.output}/{RECAP}": job.out_dir / RECAP,
                  f"../{truth.name}": truth}
        return {**inputs, VIDEOS: folder / VIDEOS} if videos else inputs
    from mvm.io.scene_dir import TIMINGS
    from mvm.report.load import truth_path

    truth = truth_path(folder)
    out_dir = job.out_dir
    return {f"{job.output}/poses3d.json": out_dir / "poses3d.json", f"{job.output}/{TIMINGS}": out_dir / TIMINGS,
            "poses2d.json": folder / "poses2d.json", "sparse": folder / "sparse", "frames": folder / "frames",
            "frames.json": folder / "frames.json", f"../{truth.name}": truth}


def check_record_name(out: Path, inputs: dict, title: str) -> None:
    """Refuse, in one line naming ``out``, an ``out`` that is, holds or lies inside one of
    ``inputs`` (:func:`mvm.io.outputs.check_output_location`), or whose record
    (``<stem>.inputs.json``) would be another output's: an input's record (``-o
    SCENE/poses2d.html`` beside ``poses2d.json``), a record another stage wrote, or a file that
    is no record of mvm's (a user's own). Called before the record is removed."""
    from mvm.errors import InputError
    from mvm.io.outputs import check_output_location
    from mvm.io.provenance import read_record, record_path

    paths = [p for p in inputs.values() if isinstance(p, Path)]
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
