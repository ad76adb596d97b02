"""Files of the benchmark (``mvm.eval.bench``): the tables in Markdown, the rows in CSV and the
log-log plot of matching time against the number of 2D poses. Written atomically."""
from __future__ import annotations

import csv
import io
from pathlib import Path

from mvm.eval.bench import COLUMNS, SWEEP_METHODS, BenchResult, markdown_table, sweep_table
from mvm.io.files import atomic_write_bytes, atomic_write_text
from mvm.io.outputs import writing_into

#: The files :func:`write_bench_report` writes into its folder.
BENCH_FILES = ("paper_tables.md", "clips.csv", "sweeps.csv", "matching_time.png")
#: The files :func:`write_crowd_report` writes into its folder.
CROWD_FILES = ("crowd.md", "crowd.csv", "crowd_sweeps.csv", "crowd.json")

TABLE_COLUMNS = [("method", "method", 0)] + list(COLUMNS)


def _csv(rows: list[dict]) -> str:
    keys = list(dict.fromkeys(k for r in rows for k in r))
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=keys)
    writer.writeheader()
    writer.writerows(rows)
    return buffer.getvalue()


def report_markdown(result: BenchResult, command: str, seconds: float) -> str:
    parts = [f"Regenerate with `{command}` ({seconds:.0f} s).\n",
             "### Table 1: matching methods (all clips)\n", markdown_table(result.table1, TABLE_COLUMNS),
             "\n### Table 1, lower part: clips under 50 frames (Dong et al. runs only there)\n",
             markdown_table(result.table1_short, TABLE_COLUMNS),
             "\n### Table 2: affinity ablation (all clips)\n", markdown_table(result.table2, TABLE_COLUMNS)]
    for axis in dict.fromkeys(r["axis"] for r in result.sweep_rows):
        for metric, name in (("f1", "matching F1"), ("mpjpe_mm", "MPJPE mm")):
            digits = 3 if metric == "f1" else 1
            columns = [(axis, axis, 0)] + [(m.label, m.label, digits) for m in SWEEP_METHODS]
            parts += [f"\n### Sweep of {axis}: {name}\n",
                      markdown_table(sweep_table(result.sweep_rows, axis, metric, SWEEP_METHODS), columns)]
    if result.speed:
        s = result.speed
        parts.append(f"\n### Speed on a paper-like clip ({s['frames']} frames, {s['people']} people, "
                     f"{s['poses']} 2D poses)\n\nMVM matching {s['mvm_matching_s']:.3f} s (F1 {s['mvm_f1']:.3f}); "
                     f"Dong et al. {s['dong_matching_s']:.2f} s (F1 {s['dong_f1']:.3f}): "
                     f"MVM is {s['speedup']:.0f}× faster.\n")
    return "\n".join(parts)


def plot_times(result: BenchResult) -> bytes:
    """Log-log scatter of matching time against the number of 2D poses, per method (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = result.rows + [dict(r, axis=None) for r in result.sweep_rows] + (result.speed or {}).get("rows", [])
    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    for method in dict.fromkeys(r["method"] for r in rows):
        pts = sorted((r["poses"], r["matching_s"]) for r in rows if r["method"] == method)
        ax.loglog([p for p, _ in pts], [t for _, t in pts], "o-", ms=3, lw=0.8, label=method)
    ax.set_xlabel("2D poses in the clip")
    ax.set_ylabel("matching time (s, affinity + grouping)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    buffer = io.BytesIO()
    fig.tight_layout()
    fig.savefig(buffer, format="png", dpi=120)
    plt.close(fig)
    return buffer.getvalue()


def write_bench_report(result: BenchResult, out: str | Path, command: str, seconds: float) -> Path:
    """Write ``paper_tables.md``, ``clips.csv``, ``sweeps.csv`` and ``matching_time.png`` to
    ``out``; returns the Markdown file's path."""
    out = Path(out)
    with writing_into(out, BENCH_FILES):              # a user's file of one of these names: refused
        atomic_write_text(out / "paper_tables.md", report_markdown(result, command, seconds))
        atomic_write_text(out / "clips.csv", _csv(result.rows))
        atomic_write_text(out / "sweeps.csv", _csv(result.sweep_rows))
        atomic_write_bytes(out / "matching_time.png", plot_times(result))
    return out / "paper_tables.md"


def crowd_markdown(result, command: str, seconds: float) -> str:
    """The crowd benchmark's tables (``result``: :class:`mvm.eval.crowd.CrowdResult`)."""
    from mvm.eval.crowd import COLUMNS as CROWD_COLUMNS
    from mvm.eval.crowd import PAPER_E_R_PX, SUMMARY_COLUMNS, SWEEP_COLUMNS, summary, table_rows

    parts = [f"Regenerate with `{command}` ({seconds:.0f} s). Oracle: the true grouping, RANSAC/DLT "
             f"triangulation, no refinement. The paper's E_R on real videos: {PAPER_E_R_PX} px. "
             "Persons: estimated / found (MPJPE within 0.5 m of a true person) / true.\n",
             "### Frozen crowds: summary\n", markdown_table(summary(result.rows), SUMMARY_COLUMNS),
             "\n### Frozen crowds: every scene\n", markdown_table(table_rows(result.rows), CROWD_COLUMNS)]
    for axis in dict.fromkeys(r["axis"] for r in result.sweep_rows):
        rows = [r for r in result.sweep_rows if r["axis"] == axis]
        parts += [f"\n### Sweep of {axis} (geometry only)\n", markdown_table(table_rows(rows), SWEEP_COLUMNS)]
    return "\n".join(parts)


def write_crowd_report(result, out: str | Path, command: str, seconds: float) -> Path:
    """Write ``crowd.md``, ``crowd.csv``, ``crowd_sweeps.csv`` and ``crowd.json`` to ``out``;
    returns the Markdown file's path."""
    from mvm.io.files import atomic_write_json

    out = Path(out)
    with writing_into(out, CROWD_FILES):              # a user's file of one of these names: refused
        atomic_write_text(out / "crowd.md", crowd_markdown(result, command, seconds))
        atomic_write_text(out / "crowd.csv", _csv(result.rows))
        atomic_write_text(out / "crowd_sweeps.csv", _csv(result.sweep_rows))
        atomic_write_json(out / "crowd.json", {"command": command, "seconds": seconds, "rows": result.rows,
                                               "sweep_rows": result.sweep_rows}, pretty=True)
    return out / "crowd.md"
