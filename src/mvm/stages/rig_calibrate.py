"""The rig's ``calibrate``: a Calib.toml (``Calibration.output``) made one of four ways, its record
beside it (``<stem>.inputs.json``: never a camera's pose file, :func:`mvm.rig.rigdir.pose_sources`;
never a calibration, which is a ``.toml``):

- ``people``: every camera's pose from the people's 2D poses
  (:func:`mvm.rig.prepare.calibrate_rig_from_people`); inputs: the intrinsics' calibration,
  ``sync.toml`` and every pose source;
- ``checkerboard`` or ``charuco``: intrinsics, lenses and poses from videos or photos of the board
  in ``RIG_DIR/calibration/`` (:func:`mvm.rig.board_videos.calibrate_rig_from_board`); inputs:
  each camera's videos or photos (and ``intrinsics``, when given);
- ``intrinsics``: the lenses alone from the board
  (:func:`mvm.rig.board_intrinsics.calibrate_intrinsics_from_board`);
- ``convert``: another system's calibration converted for the rig's cameras
  (:func:`mvm.rig.convert.convert_rig_calibration`); inputs: its files and the rig's camera names.

The settings the record keeps are the rest of :class:`Calibration`. The stage applies to a
:class:`~mvm.stages.stage.RigJob` whose ``calibration`` is set.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

from mvm.stages.stage import Done, RigJob, Stage, present

#: The stage in the reasons of a rerun.
TITLE = "the calibration"
#: The ways of calibrating, :attr:`Calibration.method`.
METHODS = ("people", "checkerboard", "charuco", "intrinsics", "convert")


@dataclass(frozen=True)
class Calibration:
    """What ``mvm rig calibrate`` makes: the Calib.toml ``output``, by ``method`` (:data:`METHODS`),
    from ``intrinsics`` (a Calib.toml; None: the rig's calibration from the people, calibrated
    from the board); ``seed`` and ``refine_focal`` of the people's; ``board``
    (:class:`mvm.rig.boards.Board`), ``world``, ``fisheye`` and ``world_frame`` of a board's;
    ``source``, ``format`` and ``binning`` of a conversion."""

    method: str
    output: Path
    intrinsics: Path | None = None
    seed: int = 0
    refine_focal: bool = False
    board: object = None
    world: str = "board"
    fisheye: bool = False
    world_frame: int | None = None
    source: Path | None = None
    format: str | None = None
    binning: float = 1.0


def _output(job: RigJob) -> Path:
    return Path(job.calibration.output)


def _inputs(job: RigJob) -> dict:
    from mvm.rig.output_set import named_inputs

    c, rig_dir = job.calibration, Path(job.rig_dir)
    if c.method == "people":
        from mvm.rig.reconstruct_rig import rig_fingerprint_inputs

        return rig_fingerprint_inputs(rig_dir, c.intrinsics)
    if c.method == "convert":
        from mvm.io.calibrations import detect_format, source_files
        from mvm.rig.convert import rig_camera_sources

        source = Path(c.source)
        files = named_inputs(rig_dir, [source, *source_files(source, c.format or detect_format(source))])
        cameras = {group: sorted(entries) for group, entries in rig_camera_sources(rig_dir).items()}
        return {**files, "cameras": cameras}
    if c.method == "intrinsics":
        from mvm.rig.board_intrinsics import intrinsic_sources

        return named_inputs(rig_dir, intrinsic_sources(rig_dir).values())
    from mvm.rig.board_videos import rig_videos

    intrinsic, extrinsic = rig_videos(rig_dir)
    return named_inputs(rig_dir, [*intrinsic.values(), *extrinsic.values(), *([c.intrinsics] if c.intrinsics else [])])


def _read(job: RigJob, inputs: dict) -> list[Path]:
    """Every file and folder the calibration reads besides a board's ``calibration/`` folder and
    ``intrinsics`` (checked in :func:`_run` before anything is listed): its ``inputs``
    (:func:`_inputs`), the rig's videos and pose sources (a conversion matches their names)."""

    c, rig_dir = job.calibration, Path(job.rig_dir)
    read = [p for p in inputs.values() if isinstance(p, Path)]
    if c.method == "convert":
        from mvm.rig.convert import rig_camera_sources

        read += [p for entries in rig_camera_sources(rig_dir).values() for p in entries.values()]
    return read


def _settings(job: RigJob) -> dict:
    settings = asdict(job.calibration)
    settings.pop("output")
    return settings


def _make(job: RigJob):
    c, rig_dir = job.calibration, Path(job.rig_dir)
    if c.method == "people":
        from mvm.rig.prepare import calibrate_rig_from_people

        return calibrate_rig_from_people(rig_dir, c.output, c.intrinsics, c.seed, c.refine_focal)
    if c.method == "convert":
        from mvm.rig.convert import convert_rig_calibration

        return convert_rig_calibration(rig_dir, c.source, c.output, c.format, c.binning)
    if c.method == "intrinsics":
        from mvm.rig.board_intrinsics import calibrate_intrinsics_from_board

        return calibrate_intrinsics_from_board(rig_dir, c.output, c.board, progress=job.progress, fisheye=c.fisheye)
    from mvm.rig.board_videos import calibrate_rig_from_board

    return calibrate_rig_from_board(rig_dir, c.output, c.board, c.intrinsics, c.world, progress=job.progress,
                                    fisheye=c.fisheye, world_frame=c.world_frame)


def _run(job: RigJob, force: bool) -> Done:
    """``Done.result``: what the calibration found (its ``calibration``, ``path``, ...), or None
    when ``output`` was kept."""
    from mvm.io.outputs import check_output_location
    from mvm.io.provenance import produce

    if job.calibration.method not in METHODS:
        raise ValueError(f"unknown calibration method {job.calibration.method!r}: expected one of {METHODS}")
    output = _output(job)
    if job.calibration.method in ("checkerboard", "charuco", "intrinsics"):   # before any input is listed
        check_output_location(output, [job.layout.calibration_dir, *([job.calibration.intrinsics]
                                                                     if job.calibration.intrinsics else [])],
                              replaced=False)
    inputs = _inputs(job)
    check_output_location(output, _read(job, inputs), replaced=False)   # before its record is removed
    result, why = produce(output, TITLE, inputs, _settings(job), lambda why, hashed: _make(job), None,
                          force=force, lock=output if output.parent.is_dir() else None)
    return Done(result, why)


def _applies(job: RigJob) -> str | None:
    return None if job.calibration is not None else "no calibration asked for (mvm rig calibrate makes one)"


STAGE = Stage("calibrate", TITLE, (), _output, _inputs, _settings, lambda job: present(_output(job)), _run,
              applies=_applies)
