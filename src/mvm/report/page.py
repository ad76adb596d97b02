"""The per-scene report: one self-contained HTML page (``SCENE/mvm/report.html``) with the
scene's metrics, an interactive 3D view, a strip of frames with overlays, per-joint plots and,
for simulated scenes, the comparison with ground truth. Works offline: the viewer script and
every image are inlined."""
from __future__ import annotations

import base64
import importlib.resources
import json
import logging
import math
import time
import warnings
from html import escape
from pathlib import Path

import numpy as np

from mvm import __version__
from mvm.core.keypoints import COCO_KEYPOINTS, COCO_SKELETON
from mvm.io.files import atomic_write_text
from mvm.io.layout import DEFAULT_OUTPUT, REPORT_PAGE
from mvm.io.outputs import check_output_location
from mvm.io.scene_dir import output_dir, scene_inputs
from mvm.report import analysis
from mvm.report.load import SceneResult, load_result
from mvm.report.plots import bar_chart

log = logging.getLogger(__name__)

#: Defaults: frames in the strip, width of a strip image (px), SfM points and camera
#: frustums drawn in the 3D view.
STRIP_FRAMES = 8
STRIP_WIDTH = 480
MAX_POINTS = 20000
MAX_FRUSTUMS = 40


def _round(a: np.ndarray, digits: int = 4):
    """Nested lists with NaN rows as None: ``(..., 3)`` -> lists."""
    a = np.asarray(a, dtype=float)
    if a.ndim == 1:
        return [round(float(v), digits) for v in a] if np.isfinite(a).all() else None
    return [_round(row, digits) for row in a]


def nice_step(span: float) -> float:
    """A round grid step (1, 2 or 5 times a power of ten) of about a tenth of ``span``."""
    raw = max(span, 1e-9) / 10
    exponent = 10 ** math.floor(math.log10(raw))
    return next(s * exponent for s in (1, 2, 5, 10) if s * exponent >= raw)


def view_payload(result: SceneResult, max_points: int = MAX_POINTS, max_frustums: int = MAX_FRUSTUMS,
                 seed: int = 0) -> dict:
    """The 3D view's data in a display frame (up = +z, the crowd at the origin): persons,
    ground truth, camera path, frustums, SfM points (at most ``max_points``), floor grid."""
    cams = result.scene.cameras
    X = result.persons.keypoints3d                                   # (P, J, 3)
    centers = cams.centers                                           # (V, 3)
    finite = X[np.isfinite(X).all(-1)]
    origin = finite.mean(0) if len(finite) else centers.mean(0)
    M, origin = analysis.display_frame(analysis.up_direction(cams.R), origin)
    to_display = lambda p: (np.asarray(p, dtype=float) - origin) @ M.T  # noqa: E731
    Xd, Cd = to_display(X), to_display(centers)
    spread = np.concatenate([Xd[np.isfinite(Xd).all(-1)], Cd])
    radius = float(np.percentile(np.linalg.norm(spread[:, :2], axis=1), 95)) if len(spread) else 1.0
    radius = max(radius, float(np.ptp(spread[:, 2])) / 2 if len(spread) else 0.0, 1e-3)
    heights = np.array([np.ptp(x[np.isfinite(x).all(-1), 2]) for x in Xd if np.isfinite(x).all(-1).sum() >= 2])
    person_scale = float(np.median(heights)) if len(heights) else radius / 3
    floor = float(np.nanmin(Xd[..., 2])) if len(finite) else float(Cd[:, 2].min() - person_scale)
    mean_cam = Cd.mean(0)
    points = np.asarray(result.scene.points3d, dtype=float).reshape(-1, 3)
    if len(points):
        Pd = to_display(points)
        Pd = Pd[np.linalg.norm(Pd, axis=1) < 3 * radius]
        if len(Pd) > max_points:
            Pd = Pd[np.sort(np.random.default_rng(seed).choice(len(Pd), max_points, replace=False))]
        points_flat = [round(float(v), 3) for v in Pd.reshape(-1)]
    else:
        points_flat = []
    shown = analysis.sample_views(len(cams), max_frustums)
    fr = analysis.frustums(cams.K[shown], cams.R[shown], cams.t[shown], cams.size[shown], 0.06 * radius)
    colors = analysis.person_colors(len(X))
    head_joints = [0, 1, 2, 3, 4]
    persons = []
    for p in range(len(X)):
        head = Xd[p, head_joints]
        head = head[np.isfinite(head).all(-1)]
        persons.append({"id": p, "color": analysis.hex_color(colors[p]), "joints": _round(Xd[p]),
                        "head": _round(head.mean(0) + [0, 0, 0.08 * person_scale]) if len(head) else None})
    truth = None
    if result.truth is not None:
        Td = to_display(result.truth.poses3d)
        truth = [{"id": g, "color": "#222222", "joints": _round(Td[g])} for g in range(len(Td))]
    half = nice_step(2 * radius) * math.ceil(1.1 * radius / nice_step(2 * radius))
    return {
        "persons": persons, "truth": truth, "skeleton": [list(e) for e in COCO_SKELETON],
        "path": _round(Cd), "frustums": _round(to_display(fr)), "points": points_flat,
        "radius": round(radius, 4), "person_scale": round(person_scale, 4), "center_z": 0.0,
        "heading": round(float(math.atan2(mean_cam[1], mean_cam[0])), 4) if len(Cd) else 0.0,
        "grid": {"z": round(floor, 4), "half": round(half, 4), "step": round(nice_step(2 * radius), 4)},
    }


def fmt_cell(value, digits: int = 2) -> str:
    """``value`` as HTML for a table cell: a float to ``digits`` decimals, "–" for none or non-finite."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return escape(str(value))


def _metric_cards(result: SceneResult) -> str:
    m = result.metrics
    cards = [("persons", fmt_cell(m.get("persons", len(result.persons)))),
             ("matched 2D poses", fmt_cell(m.get("matched_poses"))),
             ("unmatched 2D poses", fmt_cell(m.get("unmatched_poses"))),
             ("E<sub>R</sub> (px)", fmt_cell(m.get("E_R_px"))),
             ("outliers per 3D pose", fmt_cell(m.get("outliers"), 1)),
             ("|G<sub>k</sub>| (2D keypoints per joint)", fmt_cell(m.get("G_k"), 1)),
             ("views", fmt_cell(len(result.scene.cameras))),
             ("2D poses", fmt_cell(len(result.scene.poses)))]
    items = "".join(f'<div class="card"><div class="value">{v}</div><div class="name">{n}</div></div>'
                    for n, v in cards)
    timings = "".join(f"<tr><td>{escape(k.removesuffix('_s'))}</td><td>{fmt_cell(float(v), 3)}</td></tr>"
                      for k, v in result.timings.items() if isinstance(v, (int, float)))
    timing_table = (f'<table class="small"><thead><tr><th>stage</th><th>time (s)</th></tr></thead>'
                    f"<tbody>{timings}</tbody></table>") if timings else "<p>No timings in poses3d.json.</p>"
    return f'<div class="cards">{items}</div><h3>Time per stage</h3>{timing_table}'


def _persons_table(result: SceneResult, colors: np.ndarray, comparison: dict | None) -> str:
    persons = result.persons
    rows = []
    for p in range(len(persons)):
        joints = int(np.isfinite(persons.keypoints3d[p]).all(-1).sum())
        gt = ""
        if comparison is not None:
            g = comparison["truth_of"][p]
            gt = (f"<td>{g if g >= 0 else '–'}</td><td>{fmt_cell(1000 * comparison['person_mpjpe'][p], 0)}</td>"
                  f"<td>{fmt_cell(1000 * comparison['person_pa_mpjpe'][p], 0)}</td>")
        rows.append(f'<tr><td><span class="swatch" style="background:{analysis.hex_color(colors[p])}"></span>{p}</td>'
                    f"<td>{len(persons.members[p])}</td><td>{joints}/17</td>"
                    f"<td>{fmt_cell(float(persons.views_per_joint[p].mean()), 1)}</td>"
                    f"<td>{fmt_cell(float(persons.reprojection_error_px[p]))}</td>{gt}</tr>")
    head = ("<th>person</th><th>2D poses</th><th>joints</th><th>views per joint</th><th>E<sub>R</sub> (px)</th>"
            + ("<th>true person</th><th>MPJPE (mm)</th><th>PA-MPJPE (mm)</th>" if comparison else ""))
    return f'<table class="small"><thead><tr>{head}</tr></thead><tbody>{"".join(rows)}</tbody></table>'


def _strip(result: SceneResult, count: int, width: int) -> tuple[str, bool]:
    """Sampled frames with overlays as inline JPEGs; and whether real frames were used."""
    from mvm.report.overlay import ViewRenderer, opencv

    cv2 = opencv()
    renderer = ViewRenderer(result)
    poses = result.scene.poses
    figures = []
    for v in analysis.sample_views(len(result.scene.cameras), count):
        image = renderer.render(int(v), width)
        ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 82])
        if not ok:
            continue
        rows = poses.view == v
        matched = int((renderer.labels[rows] >= 0).sum())
        name = result.scene.cameras.names[v]
        data = base64.b64encode(jpeg.tobytes()).decode("ascii")
        figures.append(f'<figure><img alt="overlay of {escape(name)}" src="data:image/jpeg;base64,{data}">'
                       f"<figcaption>{escape(name)} · {int(rows.sum())} poses, {matched} matched</figcaption></figure>")
    return "".join(figures), renderer.has_frames


def _plots(result: SceneResult, comparison: dict | None) -> str:
    scene, persons = result.scene, result.persons
    labels = analysis.pose_labels(len(scene.poses), persons.members)
    errors = analysis.member_errors(persons.keypoints3d, labels, scene.poses.keypoints, scene.poses.view,
                                    scene.cameras.P)
    summary = analysis.joint_error_summary(errors)
    names = list(COCO_KEYPOINTS)
    views = persons.views_per_joint.astype(float)
    reconstructed = np.isfinite(persons.keypoints3d).all(-1)
    views = np.where(reconstructed, views, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        mean_views = np.nanmean(views, axis=0) if len(views) else np.full(17, np.nan)
        min_views = np.nanmin(views, axis=0) if len(views) else np.full(17, np.nan)
        max_views = np.nanmax(views, axis=0) if len(views) else np.full(17, np.nan)
    out = [bar_chart(names, summary["median"], "Reprojection error per joint", "px", whiskers=summary["p90"],
                     value_note="median over the matched 2D keypoints", whisker_note="90th percentile"),
           bar_chart(names, mean_views, "Views per joint (inlier 2D keypoints)", "views", whiskers=max_views,
                     markers=min_views, color="#59a14f", value_note="mean over persons",
                     whisker_note="max", marker_note="min")]
    if comparison is not None:
        out.append(bar_chart(names, 1000 * comparison["joint_error"], "3D error per joint against ground truth",
                             "mm", color="#e15759", value_note="mean over matched persons"))
    return "".join(f'<div class="plotbox">{svg}</div>' for svg in out)


def _truth_section(comparison: dict) -> str:
    cards = [("persons found / true", f"{comparison['found']} / {comparison['true']}"),
             ("matching precision", fmt_cell(comparison["precision"], 3)),
             ("matching recall", fmt_cell(comparison["recall"], 3)),
             ("MPJPE (mm)", fmt_cell(1000 * comparison["mpjpe"], 1)),
             ("PA-MPJPE (mm)", fmt_cell(1000 * comparison["pa_mpjpe"], 1))]
    items = "".join(f'<div class="card"><div class="value">{v}</div><div class="name">{n}</div></div>'
                    for n, v in cards)
    return (f'<section id="truth"><h2>Ground truth (simulated scene)</h2><div class="cards">{items}</div>'
            "<p>The 3D view draws the true poses as dashed dark skeletons beside the estimate "
            "(toggle <em>ground truth</em>). An estimate matches the true person with the lowest MPJPE "
            "below 0.5 m; precision and recall count pairs of 2D poses grouped together.</p></section>")


CSS = """
body{font:14px/1.45 system-ui,-apple-system,Segoe UI,sans-serif;margin:0;color:#222;background:#f4f4f4}
header{background:#20262e;color:#fff;padding:14px 24px}header h1{margin:0;font-size:20px}
header p{margin:4px 0 0;color:#c8cdd3;font-size:12px}
main{padding:12px 24px 40px;max-width:1400px}section{background:#fff;border-radius:6px;padding:12px 16px;margin:12px 0;
box-shadow:0 1px 2px rgba(0,0,0,.08)}h2{font-size:16px;margin:4px 0 10px}h3{font-size:14px;margin:14px 0 6px}
.cards{display:flex;flex-wrap:wrap;gap:10px}
.card{border:1px solid #e3e3e3;border-radius:5px;padding:8px 12px;min-width:120px}
.card .value{font-size:20px;font-weight:600}.card .name{font-size:12px;color:#666}
table.small{border-collapse:collapse;font-size:13px}
table.small td,table.small th{border-bottom:1px solid #eee;padding:3px 10px;text-align:right}
table.small th{color:#555;font-weight:600}
.swatch{display:inline-block;width:12px;height:12px;border-radius:2px;margin-right:6px;vertical-align:-1px}
#viewer{display:flex;gap:14px;align-items:flex-start}
#mvm-view{width:100%;height:560px;border:1px solid #ddd;border-radius:4px;cursor:grab;touch-action:none;display:block}
.viewbox{flex:1;min-width:0}.legend{width:230px;font-size:13px}
.legend label{display:block}.strip{display:flex;gap:8px;overflow-x:auto;padding-bottom:6px}
.strip figure{margin:0;flex:0 0 auto}.strip img{height:200px;display:block;border-radius:3px}
.strip figcaption{font-size:12px;color:#555}.plots{display:flex;flex-wrap:wrap;gap:10px}
.plot{max-width:100%;height:auto}.plot .plot-title{font-weight:600;font-size:13px}.plot .tick{font-size:11px;fill:#555}
.plot .grid{stroke:#eee}.plot .axis{stroke:#999}.plot .whisker{stroke:#333;fill:none}.plot .marker{fill:#333}
.note{color:#666;font-size:12px}#mvm-status{font-size:12px;color:#777}
"""

ERROR_HOOK = """window.mvmErrors=[];(function(){function note(m){window.mvmErrors.push(String(m));
var s=document.getElementById('mvm-status');if(s){s.setAttribute('data-state','error');
s.setAttribute('data-errors',window.mvmErrors.join(' | '));}}
window.addEventListener('error',function(e){note(e.message||e);});
var original=console.error;console.error=function(){note(Array.prototype.join.call(arguments,' '));
return original.apply(console,arguments);};})();"""


def viewer_script() -> str:
    """The 3D viewer (``viewer.js``, shipped with the package)."""
    return importlib.resources.files(__package__).joinpath("viewer.js").read_text(encoding="utf-8")


def report_html(result: SceneResult, strip: str, strip_on_frames: bool, max_points: int = MAX_POINTS) -> str:
    """The whole page as a string. ``strip``: the frames' HTML (figures of inline images)."""
    colors = analysis.person_colors(len(result.persons))
    comparison = None
    if result.truth is not None and result.true_person is not None:
        from mvm.metrics.poses import MATCH_DISTANCE_M

        comparison = analysis.compare_with_truth(result.persons.keypoints3d, result.persons.members,
                                                 result.truth.poses3d, result.true_person, MATCH_DISTANCE_M)
    payload = {"view": view_payload(result, max_points)}
    data = json.dumps(payload, allow_nan=False, separators=(",", ":")).replace("</", "<\\/")
    legend = "".join(f'<div><span class="swatch" style="background:{analysis.hex_color(c)}"></span>person {p} '
                     f'<span class="note">({len(result.persons.members[p])} poses)</span></div>'
                     for p, c in enumerate(colors))
    truth_box = ('<label><input type="checkbox" data-show="truth"> ground truth (dashed)</label>'
                 if result.truth is not None else "")
    background = ("on the scene's frames" if strip_on_frames else
                  "on a neutral background of the image size: this scene has no <code>frames/</code> folder")
    n_points = len(result.scene.points3d)
    title = escape(result.path.name)
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><meta name="viewport" content="width=device-width,initial-scale=1">
<title>mvm report: {title}</title><style>{CSS}</style><script>{ERROR_HOOK}</script></head>
<body><header><h1>mvm report: {title}</h1><p>{escape(str(result.path))} · {escape(result.output)}/poses3d.json ·
mvm {escape(__version__)} · written {time.strftime("%Y-%m-%d %H:%M")}</p></header><main>
<section id="metrics"><h2>Metrics</h2>{_metric_cards(result)}</section>
<section id="view3d"><h2>3D view</h2><div id="viewer"><div class="viewbox"><canvas id="mvm-view"></canvas>
<div id="mvm-status" data-state="loading">3D view: loading…</div></div>
<div class="legend"><p class="note">Drag to rotate, shift- or right-drag to pan, wheel to zoom,
double-click to reset.</p>
<label><input type="checkbox" data-show="cameras"> camera path and frustums</label>
<label><input type="checkbox" data-show="points"> SfM points ({n_points if n_points else "none in the model"})</label>
<label><input type="checkbox" data-show="floor"> floor grid</label>
<label><input type="checkbox" data-show="labels"> person numbers</label>{truth_box}<h3>Persons</h3>{legend}
</div></div></section>
<section id="frames"><h2>Frames with overlays</h2><p class="note">2D poses (thick) in the colour of the person they were
matched to, unmatched poses in grey, reprojected 3D poses (thin, light) over them; drawn {background}.</p>
<div class="strip">{strip}</div></section>
<section id="plots"><h2>Per joint</h2><div class="plots">{_plots(result, comparison)}</div></section>
{_truth_section(comparison) if comparison is not None else ""}
<section id="persons"><h2>Persons</h2>{_persons_table(result, colors, comparison)}</section>
</main><script type="application/json" id="mvm-data">{data}</script><script>{viewer_script()}</script></body></html>
"""


def write_report(scene_dir: str | Path, output: str = DEFAULT_OUTPUT, frames: int = STRIP_FRAMES,
                 frame_width: int = STRIP_WIDTH, max_points: int = MAX_POINTS, path: str | Path | None = None) -> Path:
    """Write the report of a reconstructed scene (default ``<scene_dir>/<output>/report.html``)
    and return its path; a ``path`` that is, holds or lies inside an input of the scene is
    refused before any work (:func:`mvm.io.outputs.check_output_location`)."""
    path = Path(path) if path is not None else output_dir(scene_dir, output) / REPORT_PAGE
    check_output_location(path, scene_inputs(scene_dir, output), replaced=False)
    result = load_result(scene_dir, output)
    strip, on_frames = _strip(result, frames, frame_width)
    html = report_html(result, strip, on_frames, max_points)
    atomic_write_text(path, html)
    log.info("%s: report written (%.1f kB)", path, len(html.encode()) / 1e3)
    return path
