"""What every ``mvm`` command shares: the one-line error path, consoles, progress bars, recap
tables, ``--set KEY=VALUE`` parsing and option types whose bounds are checked when read.

Only ``click`` is imported at module level: ``mvm --help`` and ``mvm --version`` must not pay
for rich, numpy or the pipeline. Everything heavier is imported where it is used.
"""
from __future__ import annotations

import functools
import logging
import math
import os
import sys
from contextlib import contextmanager

import click

from mvm.cli.setting_options import DETECT, setting_option
from mvm.core.config import Bounds
from mvm.errors import InputError
from mvm.io import paths
from mvm.io.layout import DEFAULT_OUTPUT


def refuse(error: Exception) -> None:
    """Print ``error`` as the one line ``mvm: error: ...`` on stderr and exit with status 2."""
    click.echo(f"mvm: error: {error}", err=True)
    sys.exit(2)


class _OneLineErrors:
    """An :class:`~mvm.errors.InputError` escaping a command (its options included) ends in one
    line and exit status 2, whether the command runs under ``mvm`` or on its own; SIGINT or
    SIGTERM (:mod:`mvm.cli.process`) in the line ``mvm: interrupted (SIGTERM)`` and the shell's
    status, 128 + the signal."""

    def main(self, *args, **kwargs):
        try:
            return super().main(*args, **kwargs)
        except InputError as e:
            refuse(e)

    def make_context(self, info_name, args, parent=None, **extra):
        """A path argument or option that click refuses (a folder where a file is wanted, a file
        that must exist and does not) is bad input too: one line naming the option and the path."""
        try:
            return super().make_context(info_name, args, parent=parent, **extra)
        except click.BadParameter as e:
            if e.param is None or not isinstance(e.param.type, click.Path):
                raise
            problem = "required, not given" if isinstance(e, click.MissingParameter) else e.message.rstrip(".")
            raise InputError(None, _option_name(e.param), problem) from None

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except KeyboardInterrupt as e:
            from mvm.cli.process import interrupted_line

            line, status = interrupted_line(e)
            click.echo(line, err=True)
            sys.exit(status)


class Command(_OneLineErrors, click.Command):
    pass


class Group(_OneLineErrors, click.Group):
    command_class = Command
    group_class = type        # subgroups are of this class too


def command(name: str | None = None, **kwargs):
    """``click.command`` with the one-line error path."""
    return click.command(name, cls=Command, **kwargs)


@contextmanager
def refused(*kinds: type[Exception]):
    """Report an error of ``kinds`` from a library call as bad input (one line, exit 2)."""
    try:
        yield
    except kinds as e:
        if isinstance(e, InputError):
            raise
        raise InputError(None, None, str(e)) from None


def is_terminal(stream) -> bool:
    """Whether ``stream`` is an interactive terminal (``FORCE_TERMINAL`` set to anything but
    empty or 0 says yes), without importing rich: outside a terminal the commands print plain
    lines and never need it."""
    force = os.environ.get("FORCE_TERMINAL")
    if force is not None:
        return force not in ("", "0")
    try:
        return stream.isatty()
    except (AttributeError, ValueError):
        return False


def say(text: str) -> None:
    """A line of results on stdout: through rich (highlighted) on a terminal, plain elsewhere."""
    if is_terminal(sys.stdout):
        out().print(text)
    else:
        click.echo(text)


@functools.cache
def out():
    """The console of results (stdout)."""
    from rich.console import Console

    return Console()


@functools.cache
def err():
    """The console of progress, warnings and errors (stderr)."""
    from rich.console import Console

    return Console(stderr=True)


class LogHandler(logging.Handler):
    """Log records on the stderr console through rich, which is imported at the first record
    (so that configuring logging costs nothing at start-up)."""

    @functools.cached_property
    def _rich(self):
        from rich.logging import RichHandler

        return RichHandler(console=err(), show_time=False, show_path=False)

    def emit(self, record: logging.LogRecord) -> None:
        self._rich.emit(record)


class _NoBar:
    """The progress bar where stderr is not a terminal (a pipe, a log file): it draws nothing,
    as a transient rich bar would not there, and imports nothing."""

    @property
    def console(self):
        return err()

    def __enter__(self) -> _NoBar:
        return self

    def __exit__(self, *exc) -> None:
        return None

    def add_task(self, *args, **kwargs) -> int:
        return 0

    def update(self, *args, **kwargs) -> None:
        return None

    def advance(self, *args, **kwargs) -> None:
        return None


def progress(*extra_columns):
    """A transient rich progress bar on stderr: description, bar, done/total, ``extra_columns``,
    time; nothing (:class:`_NoBar`) where stderr is not a terminal."""
    if not is_terminal(sys.stderr):
        return _NoBar()
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    return Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), *extra_columns,
                    TimeElapsedColumn(), console=err(), transient=True)


def rate_column():
    """A progress column of items (frames) per second."""
    from rich.progress import ProgressColumn
    from rich.text import Text

    class Rate(ProgressColumn):
        def render(self, task) -> Text:
            return Text(f"{task.speed:.1f}/s" if task.speed else "", style="progress.data.speed")

    return Rate()


@contextmanager
def stage_progress(*extra_columns):
    """A progress bar with one task per stage; yields ``update(stage, done, total)``."""
    with progress(*extra_columns) as bar:
        tasks: dict[str, int] = {}

        def update(stage: str, done: int, total: int | None) -> None:
            if stage not in tasks:
                tasks[stage] = bar.add_task(stage, total=total)
            bar.update(tasks[stage], completed=done, total=total)

        yield update


def fmt(value, digits: int = 2, thousands: bool = False) -> str:
    """A number for a recap table: ``–`` for None or NaN, ``digits`` decimals for a float."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    sep = "," if thousands else ""
    if isinstance(value, float):
        return f"{value:{sep}.{digits}f}"
    if isinstance(value, int) and not isinstance(value, bool):
        return f"{value:{sep}}"
    return str(value)


def print_table(title: str | None, columns, rows, fold_first: bool = False, caption: str | None = None,
                console=None) -> None:
    """Print a recap of text cells ``rows: [(cell, ...)]`` under ``columns`` (the first left-aligned,
    the others right-aligned): a rich table on a terminal; elsewhere (a file, a pipe) the title
    and the ``caption`` as ``# `` lines, then tab-separated lines under a header line, for scripts
    to read (and without rich's layout, about 1 ms a row).

    On a terminal the table keeps every cell whole within the console's width (80 columns and
    up): a table that would be wider drops its box's side lines; ``fold_first`` (paths) breaks a
    first-column cell after a ``/`` rather than mid-name. ``caption``: a line under the table
    (what its abbreviations mean)."""
    if not is_terminal(sys.stdout):
        lines = [f"# {text}" for text in (title, caption) if text is not None]
        click.echo("\n".join(lines + ["\t".join(row) for row in [tuple(columns), *rows]]))
        return
    from rich import box
    from rich.table import Table

    console = console or out()
    widths = _widths(columns, rows)
    wide = not table_fits(columns, rows, console.width)
    if wide:              # no side lines, one space of padding: a gap of 2 between columns
        table = Table(title=title, caption=caption, box=box.SIMPLE_HEAD, show_edge=False, pad_edge=False,
                      padding=(0, 1, 0, 0))
    else:
        table = Table(title=title, caption=caption)
    if fold_first and rows:
        room = console.width - sum(w + (2 if wide else 3) for w in widths[1:]) - (1 if wide else 4)
        rows = [(_fold_path(row[0], max(room, 12)), *row[1:]) for row in rows]
    table.add_column(columns[0], overflow="fold" if fold_first else "ellipsis")
    for column, width in zip(columns[1:], widths[1:]):       # numbers whole; a long text (a path) folds
        table.add_column(column, justify="right", overflow="fold", min_width=width if width <= 12 else len(column))
    for row in rows:
        table.add_row(*row)
    console.print(table)


def _widths(columns, rows) -> list[int]:
    """The widest line of every column's cells, header included."""
    return [max(len(line) for cell in cells for line in str(cell).splitlines() or [""])
            for cells in zip(columns, *rows)]


def table_fits(columns, rows, width: int) -> bool:
    """Whether a boxed rich table of ``columns`` and ``rows`` shows every cell whole in ``width`` columns."""
    return sum(_widths(columns, rows)) + 3 * len(columns) + 1 <= width


def _fold_path(path: str, width: int) -> str:
    """``path`` in lines of at most ``width`` characters, broken after a ``/`` (mid-name only
    where a name alone is longer)."""
    if len(path) <= width:
        return path
    lines, line = [], ""
    for part in path.replace("/", "/\0").split("\0"):
        if line and len(line) + len(part) > width:
            lines.append(line)
            line = ""
        line += part
    return "\n".join(lines + [line])


def measure_table(title: str, rows) -> None:
    """Print a two-column recap (measure, value) of ``rows``: ``[(label, text), ...]``."""
    print_table(title, ("measure", "value"), rows)


def print_line(text: str, console=None, **style) -> None:
    """Print ``text`` literally (no rich markup or highlighting), wrapped softly."""
    (console or err()).print(text, markup=False, highlight=False, soft_wrap=True, **style)


def parse_sets(pairs: tuple[str, ...], option: str = "--set") -> dict:
    """``("tau=0.25", "up=+z", "backbone='resnet18'")`` -> ``{"tau": 0.25, "up": "+z", ...}``.

    A value is read as a TOML value (numbers, booleans, quoted strings, ``inf``, ``nan``); a
    bare word is a string. The settings' types and bounds are checked by whoever reads them.
    """
    from mvm.io.checks import parse_toml

    values = {}
    for pair in pairs:
        if "=" not in pair:
            raise InputError(option, pair, "expected KEY=VALUE")
        key, value = (s.strip() for s in pair.split("=", 1))
        if not key:
            raise InputError(option, pair, "expected KEY=VALUE")
        try:
            values[key] = parse_toml(f"v = {value}", option)["v"]
        except InputError:
            values[key] = value
    return values


class Number(click.ParamType):
    """An int or float option whose bounds (:class:`mvm.core.config.Bounds`) are checked when
    read; a bad value ends in one line naming the option, e.g. ``--width: must be >= 16, got 0``.
    NaN and infinities are refused unless the bounds allow them."""

    def __init__(self, kind: type = float, **bounds):
        self.kind = kind
        self.name = kind.__name__
        self.bounds = Bounds(**bounds)

    def convert(self, value, param, ctx):
        if isinstance(value, self.kind) and not isinstance(value, bool):
            number = value
        else:
            try:
                number = self.kind(value) if self.kind is float else int(str(value), 10)
            except (TypeError, ValueError):
                raise InputError(None, _option_name(param), f"expected {self.name}, got {value!r}") from None
        problem = self.bounds.problem(number)
        if problem:
            raise InputError(None, _option_name(param), problem)
        return number

    def get_metavar(self, param, ctx=None):
        return self.name.upper()

    def __repr__(self):
        return f"Number({self.name}, {self.bounds})"


def _option_name(param) -> str:
    if param is None:
        return "value"
    longest = max(param.opts, key=len) if getattr(param, "opts", None) else param.name
    return longest.upper() if not longest.startswith("-") else longest


#: The option type of a focal length not set in a settings file (``mvm predict --focal``; the
#: options of settings take theirs from the declarations: :mod:`mvm.cli.setting_options`).
FOCAL = Number(float, gt=0)


#: ``--set`` and ``--refine/--no-refine``: the reconstruction settings of every command that reconstructs.
SET_OPTION = click.option("--set", "sets", multiple=True, metavar="KEY=VALUE",
                          help="Override one reconstruction setting, e.g. --set tau=0.25 (repeatable).")
REFINE_OPTION = click.option("--refine/--no-refine", default=None,
                             help="Run the pose-prior refinement (default: the settings file's, else on).")


def config_options(f):
    """``--config``, ``--set`` and ``--refine/--no-refine`` of the reconstruction settings."""
    for option in reversed([
        click.option("--config", "config_path", type=click.Path(dir_okay=False), default=None,
                     help="TOML settings file, one table per settings object (mvm config prints one)."),
        SET_OPTION, REFINE_OPTION,
    ]):
        f = option(f)
    return f


#: File suffixes that name an image or a video (lower case).
IMAGE_SUFFIXES = frozenset({".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp", ".gif"})
VIDEO_SUFFIXES = frozenset(paths.VIDEO_SUFFIXES) | {".gif"}


class OutputPath(click.ParamType):
    """``-o``: the path of a command's main product. ``suffixes``: the file formats the command
    writes (e.g. ``(".html",)``); ``folder``: a path without one of them is a folder. A name
    with an image or video suffix the command does not write is refused in one line, rather
    than becoming a folder named ``out.gif``."""

    name = "path"

    def __init__(self, suffixes: tuple[str, ...] = (), folder: bool = True, product: str = "a folder"):
        self.suffixes, self.folder, self.product = tuple(suffixes), folder, product

    def convert(self, value, param, ctx):
        from pathlib import Path

        path = str(value)
        suffix = Path(path).suffix.lower()
        if suffix in self.suffixes:
            return path
        if not self.folder or suffix in IMAGE_SUFFIXES | VIDEO_SUFFIXES:
            kind = "a video" if suffix in VIDEO_SUFFIXES - IMAGE_SUFFIXES else "an image" if suffix else "no file type"
            option = "-o" if "-o" in getattr(param, "opts", ()) else _option_name(param)
            raise InputError(None, option, f"{path} names {kind}{f' ({suffix})' if suffix else ''}, "
                                           f"but {command_name()} writes {self.product}")
        return path


def output_name_option(f):
    """``--output-name NAME``: the scene's output folder (``-o`` is a command's output path)."""
    return click.option("--output-name", "output", default=DEFAULT_OUTPUT, show_default=True, metavar="NAME",
                        help="The scene's output folder holding poses3d.json.")(f)


def command_name() -> str:
    """The running command as typed (``mvm rig reconstruct``), for messages."""
    ctx = click.get_current_context(silent=True)
    if ctx is None:
        return "mvm"
    names = ctx.command_path.split()
    return " ".join(["mvm"] + (names[1:] if ctx.find_root().command.name in ("main", "mvm") else names))


def refuse_unused(pairs: dict, cls, option: str = "--set", unused: tuple[str, ...] = (), other=None) -> None:
    """Refuse, naming the key and the command, an ``option`` key that the running command would
    not use: not a field of the settings dataclass ``cls``, or one of ``unused`` (fields the
    command's driver never reads). ``other``: ``(settings dataclass, option)`` of the command's
    other settings, named in the message when the key is one of them."""
    from dataclasses import fields

    known = {f.name for f in fields(cls)} - set(unused)
    for key in pairs:
        if key in unused:
            raise InputError(option, key, f"not used by {command_name()}")
        if key not in known:
            if other is not None and key in {f.name for f in fields(other[0])}:
                raise InputError(option, key, f"not taken by {option} of {command_name()}: give it with {other[1]}")
            raise InputError(option, key, f"not a setting of {command_name()} (known: {', '.join(sorted(known))})")


def read_config(config_path: str | None, sets: tuple[str, ...], driver: str = "scene", **flags):
    """The reconstruction :class:`~mvm.core.config.Config` of a TOML file (its ``[reconstruct]``
    table), ``--set`` pairs and command flags (a flag left at None keeps the file's value); every
    setting is checked here, and a ``--set`` key the command (its ``driver``, ``"scene"`` or
    ``"rig"``) would not use is refused (:func:`refuse_unused`)."""
    from mvm.core.config import UNUSED_BY_DRIVER, Config
    from mvm.settings.tables import load_config

    pairs = parse_sets(sets)
    if driver == "rig":
        from mvm.rig.options import RigOptions

        refuse_unused(pairs, Config, unused=UNUSED_BY_DRIVER[driver], other=(RigOptions, "--rig-set"))
    else:
        refuse_unused(pairs, Config)
    config = load_config(config_path, pairs)
    changes = {k: v for k, v in flags.items() if v is not None}
    return config.replace(**changes) if changes else config


def with_options(options):
    """A decorator that adds the click ``options`` (a list of ``click.option(...)``) to a command,
    in the order listed."""
    def wrap(f):
        for option in reversed(options):
            f = option(f)
        return f
    return wrap


#: The options that choose and run a 2D pose detector, the same in ``mvm detect``, ``mvm run``
#: and ``mvm rig detect`` (:class:`mvm.video.detect.DetectOptions`).
DETECTOR_OPTIONS = [
    click.option("--detector", type=click.Choice(["rtmo", "rtmpose", "yolo-pose", "mvm"]), default=None,
                 help="2D pose detector: rtmo (bottom-up), rtmpose (person boxes + top-down), yolo-pose (an "
                      "Ultralytics YOLO-pose ONNX export, --model), mvm (the project's network, --checkpoint). "
                      "Default: rtmo when ONNX Runtime is installed."),
    click.option("--model", type=click.Path(dir_okay=False), default=None,
                 help="The detector's ONNX model (.onnx, the published .zip or a URL; default: the published model, "
                      "downloaded once into $MVM_CACHE/models or ~/.cache/mvm/models; yolo-pose: required)."),
    click.option("--person-model", type=click.Path(dir_okay=False), default=None,
                 help="rtmpose's person detector (YOLOX ONNX model; default: the published one)."),
    setting_option(DETECT, "mode"),
    setting_option(DETECT, "device"),
    setting_option(DETECT, "batch_size"),
    click.option("--checkpoint", type=click.Path(dir_okay=False), default=None,
                 help="Checkpoint of mvm's pose network (local file; implies --detector mvm)."),
    setting_option(DETECT, "input_size"),
]
