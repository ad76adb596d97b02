"""Checkpoints of a training run: state dicts and JSON metadata, never a pickled module.

A checkpoint is two files: ``checkpoint-NNNNNNN.pt`` (``{"model", "ema", "optimizer",
"ema_updates"}``: state dicts, tensors only) and ``checkpoint-NNNNNNN.json`` (the metadata: the
checkpoint format, the model spec, the step, the configuration, losses, validation,
throughput). The ``.pt`` is read with ``torch.load(..., weights_only=True)``: a file holding
anything else than tensors and containers of them is refused, never unpickled.
"""
from __future__ import annotations

import io
import pickle
from pathlib import Path

import torch

from mvm.errors import InputError
from mvm.io.checks import load_json_object
from mvm.io.files import atomic_write_bytes, atomic_write_json
from mvm.net.metrics_log import finite_or_none

CHECKPOINT_FORMAT = "mvm.net.checkpoint/1"
#: The entries of a ``.pt`` that are state dicts of a network: names to tensors.
_WEIGHTS = ("model", "ema")


def checkpoint_paths(out_dir: str | Path, step: int) -> tuple[Path, Path]:
    """The ``.pt`` and ``.json`` of the checkpoint of ``step`` in ``out_dir``."""
    stem = Path(out_dir) / f"checkpoint-{step:07d}"
    return stem.with_suffix(".pt"), stem.with_suffix(".json")


def save_checkpoint(out_dir: str | Path, step: int, state: dict, meta: dict) -> Path:
    """Write ``state`` (state dicts: ``{"model": ..., "ema": ..., "optimizer": ...}``), then
    the JSON metadata ``meta`` (with at least ``"model"``, the model spec), each atomically;
    returns the ``.pt`` path.

    The metadata is written last and records the ``.pt``'s size, so a pair is complete only
    when both writes finished (see :func:`latest_checkpoint`). Non-finite numbers of ``meta``
    are written as null.
    """
    pt, js = checkpoint_paths(out_dir, step)
    buffer = io.BytesIO()
    torch.save(state, buffer)
    data = buffer.getvalue()
    atomic_write_bytes(pt, data)
    atomic_write_json(js, finite_or_none({"format": CHECKPOINT_FORMAT, "model": meta["model"], "step": step,
                                          "torch": torch.__version__, "weights_bytes": len(data), **meta}),
                      pretty=True)
    return pt


def read_checkpoint(path: str | Path) -> tuple[dict, dict]:
    """-> (state dicts, metadata) of a checkpoint ``.pt`` and its ``.json``.

    An InputError of one line names the file when the metadata is missing or of another
    format, or the ``.pt`` cannot be read as tensors only, or is not a dict whose ``"model"``
    (and ``"ema"``, when present) maps names to tensors.
    """
    path = Path(path)
    js = path.with_suffix(".json")
    if not js.exists():
        raise InputError(js, None, "checkpoint metadata not found (expected beside the .pt)")
    meta = load_json_object(js, what="checkpoint metadata (an object)")
    if meta.get("format") != CHECKPOINT_FORMAT:
        raise InputError(js, "format", f"expected {CHECKPOINT_FORMAT!r}, got {meta.get('format')!r}")
    state = _load_tensors(path)
    if not isinstance(state, dict) or "model" not in state:
        raise InputError(path, None, "not a checkpoint: expected a dict with a 'model' state dict")
    for name in _WEIGHTS:
        problem = _state_dict_problem(state.get(name, {}))
        if problem:
            raise InputError(path, name, f"not a checkpoint: {problem}")
    return state, meta


def _load_tensors(path: Path):
    """``torch.load`` of tensors only; what torch refuses is one line in our words."""
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise InputError(path, None, "file not found") from None
    except IsADirectoryError:
        raise InputError(path, None, "is a directory, expected a checkpoint .pt") from None
    except OSError as e:
        raise InputError(path, None, f"cannot read: {e.strerror or type(e).__name__}") from None
    except pickle.UnpicklingError:
        raise InputError(path, None, "not a checkpoint: it holds objects other than tensors "
                                     "(checkpoints are read as tensors only)") from None
    except Exception:       # torch reports a damaged archive with many exception types and lines
        raise InputError(path, None, "not a checkpoint: not a torch file, or truncated") from None


def _state_dict_problem(weights) -> str | None:
    """What keeps ``weights`` from being a state dict (names to tensors), or None."""
    if not isinstance(weights, dict):
        return f"expected a state dict (names to tensors), got {type(weights).__name__}"
    for key, value in weights.items():
        if not isinstance(key, str) or not isinstance(value, torch.Tensor):
            return f"expected a state dict (names to tensors), {key!r} is {type(value).__name__}"
    return None


def _complete(pt: Path) -> bool:
    """Whether ``pt`` and its ``.json`` form a complete pair: the metadata parses, has the
    checkpoint format and records the byte size the ``.pt`` has."""
    try:
        meta = load_json_object(pt.with_suffix(".json"))
        return meta.get("format") == CHECKPOINT_FORMAT and meta.get("weights_bytes") in (None, pt.stat().st_size)
    except (OSError, ValueError, AttributeError):
        return False


def list_checkpoints(out_dir: str | Path) -> list[Path]:
    """The ``.pt`` of every complete checkpoint pair in ``out_dir``, by step."""
    return sorted(p for p in Path(out_dir).glob("checkpoint-*.pt") if _complete(p))


def latest_checkpoint(out_dir: str | Path) -> Path | None:
    """The ``.pt`` of the highest step in ``out_dir`` whose pair is complete, or None.

    A ``.pt`` without its ``.json`` (a run killed between the two writes), or whose ``.json``
    records another size, is skipped.
    """
    found = list_checkpoints(out_dir)
    return found[-1] if found else None


def prune_checkpoints(out_dir: str | Path, keep_last: int, keep_best: str = "",
                      higher_is_better: bool = True) -> list[Path]:
    """Delete complete checkpoint pairs beyond the ``keep_last`` most recent (0: keep all).

    With ``keep_best`` (a validation metric, e.g. ``"AP"``), the checkpoint with the best
    recorded value of it is kept too. Returns the deleted ``.pt`` paths.
    """
    found = list_checkpoints(out_dir)
    if keep_last <= 0 or len(found) <= keep_last:
        return []
    keep = set(found[-keep_last:])
    if keep_best:
        best = _best_checkpoint(found, keep_best, higher_is_better)
        if best is not None:
            keep.add(best)
    deleted = []
    for pt in found:
        if pt not in keep:
            pt.with_suffix(".json").unlink(missing_ok=True)       # the pair is incomplete from here on
            pt.unlink(missing_ok=True)
            deleted.append(pt)
    return deleted


def _best_checkpoint(found: list[Path], metric: str, higher_is_better: bool) -> Path | None:
    scored = []
    for pt in found:
        meta = load_json_object(pt.with_suffix(".json"))
        value = ((meta.get("validation") or {}).get("metrics") or {}).get(metric)
        if isinstance(value, (int, float)):
            scored.append((value if higher_is_better else -value, pt))
    return max(scored)[1] if scored else None
