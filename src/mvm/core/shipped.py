"""The data shipped in the package (``mvm/data``: the pose bank and the pose prior), read as
named arrays from ``.npz`` files."""
from __future__ import annotations

import importlib.resources
from pathlib import Path

import numpy as np

from mvm.errors import InputError


def read_arrays(path: str | Path | None, default: str, keys: tuple[str, ...], what: str) -> dict[str, np.ndarray]:
    """The arrays ``keys`` of the ``.npz`` file ``path``, or of the shipped ``mvm/data/<default>``
    when ``path`` is None. Any problem raises :class:`InputError` naming the file (``what``: the
    kind of file, for the message)."""
    if path is None:
        resource = importlib.resources.files("mvm").joinpath(f"data/{default}")
        with importlib.resources.as_file(resource) as file:
            return read_arrays(file, default, keys, what)
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            return {key: data[key] for key in keys}
    except FileNotFoundError:
        raise InputError(path, None, "file not found") from None
    except KeyError as e:
        raise InputError(path, str(e.args[0]), "array missing") from None
    except (OSError, ValueError) as e:
        raise InputError(path, None, f"not {what} .npz: {e}") from None
