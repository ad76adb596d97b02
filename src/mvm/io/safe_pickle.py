"""Pickles read without running code from them: numpy arrays and plain containers only.

:func:`pickle.load` calls whatever function a file names, so a data file can run a command
(``os.system``) as it is read. :func:`load_pickle` reads the file the guarded way
(:func:`mvm.io.checks.read_bytes`: a regular file of bounded size, no FIFO) and unpickles it
with :class:`RestrictedUnpickler`, which admits only what a pickle of numpy arrays needs:
``numpy.ndarray``, ``numpy.dtype``, numpy's reconstruct helpers and scalars, sets, complex
numbers and the byte encoding helper of Python 2 pickles (latin-1 only). Dicts, lists, tuples,
strings and numbers need no class.
Anything else is refused in one :class:`InputError` line naming the file and the type.

An array is allocated only as large as the file could fill: a pickle that asks for a
terabyte of empty array is refused, not allocated.
"""
from __future__ import annotations

import _compat_pickle
import codecs
import importlib
import io
import pickle
from pathlib import Path

import numpy as np

from mvm.errors import InputError
from mvm.io.checks import read_bytes


def _numpy_core(module: str):
    """``numpy._core.<module>`` (numpy 2), else ``numpy.core.<module>`` (numpy 1)."""
    try:
        return importlib.import_module(f"numpy._core.{module}")
    except ImportError:                                  # numpy 1.x
        return importlib.import_module(f"numpy.core.{module}")


class UnsafePickle(InputError):
    """A pickle that names a function or class outside the allowed numpy types."""


class RestrictedUnpickler(pickle.Unpickler):
    """An unpickler whose :meth:`find_class` admits only numpy arrays, dtypes and scalars.

    ``path`` names the file in refusals; ``max_bytes`` bounds the size of an array that a
    reconstruct call may allocate before its data is filled in (default: unbounded).
    """

    def __init__(self, file, path: str | Path, max_bytes: int | None = None, **kwargs):
        super().__init__(file, **kwargs)
        self.path = Path(path)
        self.max_bytes = max_bytes
        multiarray, numeric = _numpy_core("multiarray"), _numpy_core("numeric")
        reconstruct, frombuffer = multiarray._reconstruct, numeric._frombuffer

        def bounded(shape, dtype) -> None:
            try:
                count = int(np.prod(np.asarray(shape, dtype=object).reshape(-1), dtype=object))
                size = count * np.dtype(dtype).itemsize
            except (TypeError, ValueError, OverflowError):
                return                                   # numpy gives its own refusal
            if self.max_bytes is not None and size > self.max_bytes:
                raise InputError(self.path, None, f"an array of {size} bytes is more than the file holds")

        def ndarray(shape, dtype=float, *args, **kwargs):
            bounded(shape, dtype)
            return np.ndarray(shape, dtype, *args, **kwargs)

        def reconstruct_array(subtype, shape, dtype):
            if subtype is not ndarray and subtype is not np.ndarray:
                raise UnsafePickle(self.path, None, "refusing to rebuild an array of a type other than numpy.ndarray")
            bounded(shape, dtype)
            return reconstruct(np.ndarray, shape, dtype)

        def encode(text, encoding="utf-8", errors="strict"):
            """Python 2 byte strings as Python 3 pickles them: latin-1 text to bytes, nothing else."""
            if codecs.lookup(encoding).name != "iso8859-1":
                raise UnsafePickle(self.path, None, f"refusing to decode bytes with the codec {encoding!r}")
            return codecs.encode(text, "latin-1", errors)

        self._allowed = {("numpy", "ndarray"): ndarray, ("numpy", "dtype"): np.dtype,
                         ("_codecs", "encode"): encode, ("builtins", "set"): set,
                         ("builtins", "frozenset"): frozenset, ("builtins", "complex"): complex}
        for package in ("numpy.core", "numpy._core"):
            self._allowed[(f"{package}.multiarray", "_reconstruct")] = reconstruct_array
            self._allowed[(f"{package}.multiarray", "scalar")] = multiarray.scalar
            self._allowed[(f"{package}.numeric", "_frombuffer")] = frombuffer

    def find_class(self, module: str, name: str):
        if (module, name) in _compat_pickle.NAME_MAPPING:        # Python 2 names, as pickle maps them
            module, name = _compat_pickle.NAME_MAPPING[(module, name)]
        module = _compat_pickle.IMPORT_MAPPING.get(module, module)
        found = self._allowed.get((module, name))
        if found is None:
            raise UnsafePickle(self.path, None, f"refusing to load {module}.{name}: only numpy arrays, "
                                                "scalars and plain containers may be read from a pickle")
        return found

    def persistent_load(self, pid):
        raise UnsafePickle(self.path, None, "refusing a persistent reference in a pickle")


def load_pickle(path: str | Path, root: str | Path | None = None, encoding: str = "latin1"):
    """The object pickled in the file ``path`` (inside ``root`` when given), read by
    :class:`RestrictedUnpickler`; ``encoding`` decodes Python 2 byte strings (``latin1`` keeps
    numpy's arrays intact). A file that cannot be read, a refused type and a broken pickle raise
    one :class:`InputError` line naming the file."""
    data = read_bytes(path, root)
    try:
        return RestrictedUnpickler(io.BytesIO(data), path, max_bytes=max(len(data), 1 << 16),
                                   encoding=encoding).load()
    except InputError:
        raise
    except RecursionError:
        raise InputError(path, None, "not a valid pickle: nested too deeply") from None
    except MemoryError:
        raise InputError(path, None, "not a valid pickle: more memory than available") from None
    except Exception as e:  # noqa: BLE001 - pickle and numpy raise many types for broken data
        problem = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise InputError(path, None, f"not a valid pickle: {problem}") from None
