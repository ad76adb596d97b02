"""Settings read from a TOML file (one table per settings object) and ``--set`` overrides.

A settings file holds one table per settings object (:data:`TABLES`: ``[reconstruct]``,
``[rig]``, ``[simulate]``, ...), each read by the commands that use it; keys outside any table
are the reconstruction's (``[reconstruct]``). ``mvm config`` prints the file of every setting
with its default (:mod:`mvm.settings.reference`).
"""
from __future__ import annotations

from pathlib import Path

from mvm.core.config import Config, settings_from
from mvm.errors import InputError

#: The tables of a settings file, one per settings object: ``{table: (settings, readers)}``, the
#: settings dataclass as ``module:class`` (imported when the table is read or printed, by
#: :func:`mvm.settings.reference.table_class`: the video stages import OpenCV, training torch) and the
#: commands that read it. A nested settings dataclass is a sub-table (``[detect.rtm]``).
TABLES = {
    "reconstruct": ("mvm.core.config:Config",
                    "The reconstruction: mvm reconstruct, run, batch, demo and rig reconstruct (--config, --set)."),
    "rig": ("mvm.rig.options:RigOptions", "The rig driver: mvm rig reconstruct (--config, --rig-set)."),
    "simulate": ("mvm.sim.simulate:SimConfig",
                 "The simulated scene: mvm simulate (over its --preset) and demo (--config; their options win)."),
    "frames": ("mvm.video.frames:FrameOptions",
               "Frame sampling: mvm frames, run and batch (--config; their options win)."),
    "sfm": ("mvm.video.sfm:SfmOptions", "Structure from motion: mvm sfm, run and batch (--config; their options win)."),
    "detect": ("mvm.video.detect:DetectOptions",
               "2D detection: mvm detect, run and batch (--config; their options win)."),
    "batch": ("mvm.stages.scene_options:SceneOptions",
              "mvm batch's own settings (--config; each stage's are in its own table)."),
    "train": ("mvm.net.train_config:TrainConfig",
              "Training: mvm train CONFIG reads these keys at the top level of its file."),
}


def read_tables(path: str | Path) -> dict[str, dict]:
    """The tables of the settings file ``path``: ``{table: values}``, keys outside any table
    under ``"reconstruct"``; an unknown table raises an InputError naming the file."""
    from mvm.io.checks import load_toml  # numpy: not for the help of the options of settings

    path = Path(path)
    tables: dict[str, dict] = {}
    flat: dict = {}
    for name, value in load_toml(path).items():
        if not isinstance(value, dict):
            if name in TABLES:
                raise InputError(path, name, "expected a table of settings")
            flat[name] = value
        elif name in TABLES:
            tables[name] = value
        else:
            raise InputError(path, name, f"unknown table (known: {', '.join(TABLES)})")
    if flat:
        tables["reconstruct"] = {**flat, **tables.get("reconstruct", {})}
    return tables


def load_settings(cls, table: str, path: str | Path | None = None, overrides: dict | None = None,
                  sources: dict | None = None, base=None):
    """The settings dataclass ``cls`` of the ``table`` of the settings file ``path`` (none: the
    defaults, or ``base``) with ``overrides`` (from the command line, each named in messages by
    ``sources[key]``, default ``--set``); every setting is checked here, a bad one raises an
    InputError naming the file or the option and the setting."""
    values = dict(read_tables(path).get(table, {})) if path is not None else {}
    overrides = overrides or {}
    values.update(overrides)
    return settings_from(cls, values, str(path) if path is not None else "--set", base=base,
                         sources={k: (sources or {}).get(k, "--set") for k in overrides})


def load_config(path: str | Path | None = None, overrides: dict | None = None) -> Config:
    """Read the reconstruction settings of a TOML file (its ``[reconstruct]`` table, or flat
    keys) and apply ``overrides`` (from ``--set``); every setting is checked here, with the
    file or ``--set`` in the message."""
    return load_settings(Config, "reconstruct", path, overrides)
