"""The metrics of a training run: ``metrics.jsonl`` (and TensorBoard events when installed)."""
from __future__ import annotations

import json
import math
import time
from pathlib import Path


class MetricsLog:
    """``metrics.jsonl`` in the run directory: one JSON object per line, ``{"step", "time", …}``
    (losses every ``log_every`` steps, validations), plus TensorBoard events under ``tb/``
    when the ``tensorboard`` package is installed. Appends, so a resumed run continues it."""

    def __init__(self, out_dir: Path, enabled: bool = True):
        self.path, self.file, self.tb = Path(out_dir) / "metrics.jsonl", None, None
        if not enabled:
            return
        self.file = self.path.open("a")
        try:
            from torch.utils.tensorboard import SummaryWriter
            self.tb = SummaryWriter(str(Path(out_dir) / "tb"))
        except ImportError:
            pass

    def write(self, step: int, record: dict) -> None:
        if self.file is None:
            return
        self.file.write(json.dumps(finite_or_none({"step": step, "time": time.time(), **record})) + "\n")
        self.file.flush()
        if self.tb is not None:
            for name, value in _scalars(record):
                self.tb.add_scalar(name, value, step)

    def close(self) -> None:
        if self.file is not None:
            self.file.close()
        if self.tb is not None:
            self.tb.close()


def _scalars(record: dict, prefix: str = ""):
    for key, value in record.items():
        if isinstance(value, dict):
            yield from _scalars(value, f"{prefix}{key}/")
        elif isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
            yield f"{prefix}{key}", value


def read_metrics_log(path: str | Path) -> list[dict]:
    """The records of a ``metrics.jsonl``; a truncated last line (a killed run) is skipped."""
    records = []
    for line in Path(path).read_text().splitlines():
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return records


def finite_or_none(obj):
    """``obj`` with every NaN or infinite float replaced by None (JSON ``null``)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_or_none(v) for v in obj]
    return obj
