"""The summary page of a data set: one row per scene with its metrics and a link to its
report (when both exist)."""
from __future__ import annotations

import logging
import math
import os
from html import escape
from pathlib import Path
from urllib.parse import quote

from mvm.errors import InputError
from mvm.io.checks import load_json
from mvm.io.files import OutputError, atomic_write_text
from mvm.io.layout import DEFAULT_OUTPUT, REPORT_PAGE, SUMMARY_PAGE, SceneLayout

log = logging.getLogger(__name__)

_TITLE = b"<title>mvm summary: "
_COLUMNS = (("persons", "persons", 0), ("matched_poses", "matched", 0), ("unmatched_poses", "unmatched", 0),
            ("E_R_px", "E<sub>R</sub> px", 2), ("outliers", "outliers", 1), ("G_k", "|G<sub>k</sub>|", 1))


def _metrics(poses3d: Path) -> dict | None:
    try:
        document = load_json(poses3d)
    except InputError as e:
        log.warning("%s", e)
        return None
    metrics = document.get("metrics") if isinstance(document, dict) else None
    if metrics is not None and not isinstance(metrics, dict):
        log.warning("%s: metrics: expected an object, got %s; not shown", poses3d, type(metrics).__name__)
        return None
    return metrics


def _cell(value, digits: int) -> str:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return "–"
    return f"{value:.{digits}f}" if digits else str(int(value))


def summary_html(root: Path, scene_dirs: list[Path], output: str = DEFAULT_OUTPUT) -> tuple[str, int]:
    """The summary page as a string (links relative to ``root``) and the number of reports linked."""
    rows, linked = [], 0
    for scene in scene_dirs:
        report = scene / output / REPORT_PAGE
        metrics = _metrics(SceneLayout(scene, output).poses3d)
        name = escape(scene.name)
        if report.is_file():
            href = quote(Path(os.path.relpath(report, root)).as_posix())
            first = f'<a href="{href}">{name}</a>'
            linked += 1
        else:
            first = f'{name} <span class="note">(no report)</span>'
        cells = "".join(f"<td>{_cell((metrics or {}).get(key), d)}</td>" for key, _, d in _COLUMNS)
        state = "reconstructed" if metrics is not None else "not reconstructed"
        rows.append(f"<tr><td>{first}</td>{cells}<td>{state}</td></tr>")
    head = "".join(f"<th>{label}</th>" for _, label, _ in _COLUMNS)
    html = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>mvm summary: {escape(root.name)}</title><style>
body{{font:14px/1.45 system-ui,sans-serif;margin:24px;color:#222}}table{{border-collapse:collapse}}
td,th{{border-bottom:1px solid #eee;padding:4px 12px;text-align:right}}td:first-child,th:first-child{{text-align:left}}
.note{{color:#888;font-size:12px}}</style></head><body><h1>mvm summary: {escape(root.name)}</h1>
<p>{len(scene_dirs)} scenes, {linked} reports.</p><table><thead><tr><th>scene</th>{head}<th>state</th></tr></thead>
<tbody>{"".join(rows)}</tbody></table></body></html>
"""
    return html, linked


def _check_replaceable(path: Path) -> None:
    """Refuse, in one line, to replace at ``path`` anything but a summary page mvm wrote: a
    folder, a link, a FIFO or a user's own file of that name."""
    if not os.path.lexists(path):
        return
    if path.is_symlink() or not path.is_file():
        raise OutputError(path, None, "exists and is not a file: move it away, the summary page is written here")
    with open(path, "rb") as f:
        head = f.read(512)
    if _TITLE not in head:
        raise OutputError(path, None, "is not a summary page mvm wrote: move it away, the summary page is written here")


def write_summary(root: str | Path, scene_dirs, output: str = DEFAULT_OUTPUT) -> Path:
    """Write ``<root>/summary.html`` linking the report of every scene in ``scene_dirs`` that has
    one (scenes without a report are listed, unlinked). Returns the page's path."""
    root = Path(root)
    scenes = [Path(s) for s in scene_dirs]
    path = root / SUMMARY_PAGE
    _check_replaceable(path)
    html, linked = summary_html(root, scenes, output)
    atomic_write_text(path, html)
    log.info("%s: %d scenes, %d reports linked", path, len(scenes), linked)
    return path
