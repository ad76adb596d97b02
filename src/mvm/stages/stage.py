"""What a stage is: its declaration (:class:`Stage`), what it runs on (:class:`Job`, a clip;
:class:`RigJob`, a rig folder) and what it gives back (:class:`Done`).

A stage declares its name, the settings tables that configure it, the output whose record says
what it was made from (:mod:`mvm.io.provenance`), its inputs, the settings that record keeps,
the files it commits, and a ``run``. The runner (:mod:`mvm.stages.stage_runner`) runs a list of them;
``mvm status`` and ``mvm batch`` read the same declarations to say what is out of date.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from mvm.io.layout import RigLayout, SceneLayout
from mvm.stages.scene_options import SceneOptions


@dataclass(frozen=True)
class Job:
    """One clip through the scene stages: its scene directory, its settings, and what it is
    made from (``video``; ``detections``: imported 2D poses in ``detections_format``, None: the
    format the file implies; ``cameras``: a COLMAP model or a camera file used instead of
    SfM). ``progress(stage, done, total)`` hears each stage advance (it stays in this process:
    a batch's workers get None)."""

    scene: Path
    options: SceneOptions = field(default_factory=SceneOptions)
    video: Path | None = None
    detections: Path | None = None
    detections_format: str | None = None
    cameras: Path | None = None
    progress: Callable[[str, int, int | None], None] | None = field(default=None, compare=False)

    @property
    def folder(self) -> Path:
        """The folder the stages write in."""
        return self.scene

    @property
    def layout(self) -> SceneLayout:
        """The paths of the clip's scene directory and its output folder."""
        return SceneLayout(self.scene, self.options.output)

    def tick(self, stage: str) -> Callable[[int, int], None] | None:
        """``progress`` of ``stage`` as ``(done, total)``, or None."""
        return _tick(self.progress, stage)


def _tick(progress: Callable[[str, int, int | None], None] | None, stage: str) -> Callable[[int, int], None] | None:
    """``progress`` of ``stage`` as ``(done, total)``, or None."""
    if progress is None:
        return None
    return lambda done, total: progress(stage, done, total)


@dataclass
class Done:
    """What a stage's ``run`` gives back: its ``result`` (the stage's own report: a frame index,
    an SfM report, ...), ``why`` it was made (None: kept, up to date) and the ``seconds`` it took."""

    result: object
    why: str | None
    seconds: float = 0.0


def _applies(job: Job) -> str | None:
    return None


@dataclass(frozen=True)
class Stage:
    """The declaration of one stage. Its callables take the job the stage runs on: a
    :class:`Job` (a clip, for the scene stages) or a :class:`RigJob` (a rig folder).

    Attributes:
        name: as ``--force``, ``--stages`` and the batch manifest name it (``"reconstruct"``).
        title: the stage in the reasons of a rerun (``"the reconstruction"``).
        tables: the tables of a settings file that configure it.
        record: ``record(job)``, the output whose record says what the stage made it from.
        inputs: ``inputs(job)``, ``{name: Path or value}`` (:func:`mvm.io.provenance.fingerprints`).
        settings: ``settings(job)``, the settings the record keeps.
        files: ``files(job)``, the files the stage commits (sorted; empty when absent), which
            ``mvm batch`` checksums.
        run: ``run(job, force) -> Done``: makes the outputs when they are not up to date (or
            ``force``) through :func:`mvm.io.provenance.produce`, else keeps them.
        reason: ``reason(job)``, why the stage must run; None: its outputs are up to date.
            By default the record of ``record(job)`` compared with ``inputs`` and ``settings``;
            a stage whose outputs may be the clip's own input (cameras, 2D poses made
            elsewhere) says so with its own.
        applies: ``applies(job)``, why the stage has nothing to do for ``job`` (None: it applies).
    """

    name: str
    title: str
    tables: tuple[str, ...]
    record: Callable[[Job], Path]
    inputs: Callable[[Job], dict]
    settings: Callable[[Job], dict]
    files: Callable[[Job], list[Path]]
    run: Callable[[Job, bool], Done]
    reason: Callable[[Job], str | None] | None = None
    applies: Callable[[Job], str | None] = _applies

    def why(self, job: Job) -> str | None:
        """Why the stage must run for ``job`` (:attr:`reason`); None: its outputs are up to date."""
        if self.reason is not None:
            return self.reason(job)
        from mvm.io.provenance import why_redo

        return why_redo(self.record(job), self.inputs(job), self.settings(job), self.title)


def present(*paths: Path) -> list[Path]:
    """The regular files of ``paths``, in order."""
    return [p for p in paths if p.is_file()]


@dataclass(frozen=True)
class RigJob:
    """One rig folder through the rig stages: ``rig_dir``; ``detect`` and ``checkpoint``: the
    2D detector of its videos; ``config`` and ``options``: the reconstruction's settings (the
    ``[reconstruct]`` and ``[rig]`` tables; None: the defaults); ``calib`` (None: found in the
    folder: the calibration the synchronization and the reconstruction use), ``frames``
    (``START:STOP``) and ``output`` (None: ``RIG_DIR/mvm``) of the reconstruction;
    ``max_offset`` of the synchronization (None: its default); ``calibration``: what the
    calibration makes (:class:`mvm.stages.rig_calibrate.Calibration`; None: the stage does not
    apply). ``progress(what, done, total)`` hears each stage advance."""

    rig_dir: Path
    detect: object = None
    checkpoint: Path | None = None
    config: object = None
    options: object = None
    calib: Path | None = None
    frames: str | None = None
    output: Path | None = None
    max_offset: int | None = None
    calibration: object = None
    progress: Callable[[str, int, int | None], None] | None = field(default=None, compare=False)

    @property
    def folder(self) -> Path:
        """The folder the stages write in."""
        return self.rig_dir

    @property
    def layout(self) -> RigLayout:
        """The paths of the rig folder's inputs. Not of its output set, which ``output`` may put
        anywhere: that folder is :func:`mvm.rig.output_set.check_rig_output`'s."""
        return RigLayout(self.rig_dir)

    def tick(self, what: str) -> Callable[[int, int], None] | None:
        """``progress`` of ``what`` as ``(done, total)``, or None."""
        return _tick(self.progress, what)
