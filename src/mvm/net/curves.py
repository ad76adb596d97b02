"""Training curves from a run's ``metrics.jsonl`` (see :class:`mvm.net.metrics_log.MetricsLog`)."""
from __future__ import annotations

from pathlib import Path

from mvm.errors import InputError
from mvm.io.files import atomic_write_bytes

#: Loss components drawn, and the validation metrics (when present).
LOSSES = ("total", "L_PIF", "L_PAF", "L_PDF")
VALIDATION = ("AP", "AP50", "depth_error", "depth_error_flat")


def curves(records: list[dict]) -> dict[str, tuple[list[int], list[float]]]:
    """``{name: (steps, values)}`` of the losses, the learning rate and the validation metrics
    of a run's records; a metric that was missing (null) at a step is left out there."""
    out: dict[str, tuple[list[int], list[float]]] = {}

    def add(name, step, value):
        if isinstance(value, (int, float)):
            out.setdefault(name, ([], []))
            out[name][0].append(step)
            out[name][1].append(float(value))

    for r in records:
        for k in LOSSES:
            add(k, r["step"], (r.get("losses") or {}).get(k))
        add("lr", r["step"], r.get("lr"))
        for k in VALIDATION:
            add(f"val/{k}", r["step"], ((r.get("validation") or {}).get("metrics") or {}).get(k))
    return out


def plot_metrics(metrics: str | Path, out: str | Path) -> Path:
    """Draw the loss, learning-rate and validation curves of ``metrics`` (``metrics.jsonl``) into ``out`` (PNG)."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mvm.net.metrics_log import read_metrics_log

    metrics, out = Path(metrics), Path(out)
    if not metrics.is_file():
        raise InputError(metrics, None, "not found: train first (mvm train writes it in out_dir)")
    data = curves(read_metrics_log(metrics))
    if not data:
        raise InputError(metrics, None, "no losses logged yet")
    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    for k in LOSSES:
        if k in data:
            axes[0].plot(*data[k], label=k)
    axes[0].set(xlabel="step", ylabel="loss", yscale="log", title="training loss")
    axes[0].legend()
    if "lr" in data:
        axes[1].plot(*data["lr"])
    axes[1].set(xlabel="step", ylabel="learning rate", title="learning rate")
    for k in VALIDATION:
        if f"val/{k}" in data:
            axes[2].plot(*data[f"val/{k}"], marker="o", label=k)
    axes[2].set(xlabel="step", title="validation (EMA weights)")
    if any(f"val/{k}" in data for k in VALIDATION):
        axes[2].legend()
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=100)
    plt.close(fig)
    atomic_write_bytes(out, buffer.getvalue())
    return out
