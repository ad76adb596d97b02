"""Reconstruction settings read from a TOML file and ``--set`` overrides."""
from __future__ import annotations

from pathlib import Path

from mvm.core.config import Config, settings_from
from mvm.errors import InputError
from mvm.io.checks import load_toml


def load_config(path: str | Path | None = None, overrides: dict | None = None) -> Config:
    """Read a TOML config (flat, or under ``[reconstruct]``) and apply ``overrides`` (from
    ``--set``); every setting is checked here, with the file or ``--set`` in the message."""
    values: dict = {}
    if path is not None:
        path = Path(path)
        data = load_toml(path)
        data = data.get("reconstruct", data)
        if not isinstance(data, dict):
            raise InputError(path, "reconstruct", "expected a table of settings")
        values.update(data)
    overrides = overrides or {}
    values.update(overrides)
    return settings_from(Config, values, str(path) if path is not None else "--set",
                         sources={k: "--set" for k in overrides})
