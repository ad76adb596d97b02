"""The report of a rig: one self-contained HTML page (``RIG_DIR/mvm/report.html``) with the recap
of the reconstruction, the 3D view with a time slider over the instants and the cameras, every
track's timeline of observed / interpolated / inferred joints, the reprojection error of each
camera over time and the joint angles of each track. Works offline, like the scene report
(:mod:`mvm.report.page`, whose viewer, styles and plots it shares)."""
from __future__ import annotations

import json
import logging
import math
import time
from html import escape
from pathlib import Path

import numpy as np

from mvm import __version__
from mvm.core.completion import FLAG_NAMES, INFERRED, INTERPOLATED, OBSERVED
from mvm.core.config import DEFAULT_FRAME_RATE_HZ
from mvm.core.joint_angles import JOINT_ANGLES
from mvm.core.keypoints import COCO_KEYPOINTS, COCO_SKELETON
from mvm.io.files import atomic_write_text
from mvm.io.layout import REPORT_PAGE, RIG_POSES3D
from mvm.io.outputs import add_to_output_set, check_output_location
from mvm.report import analysis, rig_analysis
from mvm.report.page import CSS, ERROR_HOOK, fmt_cell, nice_step, viewer_script
from mvm.report.plots import flag_timeline, line_chart
from mvm.report.rig_load import RigReportData, in_output_set

log = logging.getLogger(__name__)

#: Time bins of the camera-error plot at most (longer captures are binned). [bins]
MAX_ERROR_BINS = 600
#: Tracks whose joint angles are plotted at most (the longest ones). [tracks]
MAX_ANGLE_TRACKS = 12


class RigFigures:
    """What the page draws, computed once from a :class:`RigReportData` (arrays, no HTML)."""

    def __init__(self, data: RigReportData, max_bins: int = MAX_ERROR_BINS):
        p = data.poses
        self.data = data
        self.tracks, self.rank = np.unique(p.track, return_inverse=True)          # (K,), (Q,)
        self.colors = [analysis.hex_color(c) for c in analysis.person_colors(len(self.tracks))]
        self.camera_colors = [analysis.hex_color(c) for c in analysis.person_colors(len(data.names))[::-1]]
        self.errors = rig_analysis.keypoint_errors(p.X, p.flags, data.detection, data.detections.keypoints,
                                                   data.calibration.cameras.P)                # (Q, V, J)
        self.bounds = rig_analysis.time_bins(len(p.frames), max_bins)
        self.error_series, self.error_counts = rig_analysis.camera_error_series(self.errors, p.instant, self.bounds)
        self.error_summary = rig_analysis.camera_error_summary(self.errors)
        self.angles, self.angle_flags = rig_analysis.track_angles(p.X, p.flags)           # (Q, A)
        self.truth = self.comparison = None
        if data.truth is not None:
            t = data.truth
            self.truth = rig_analysis.truth_at_frames(p.frames, t.instants, t.poses3d, t.offsets[data.names[0]])
            true_centers = t.centers[[t.cameras.index(n) for n in data.names]]
            self.comparison = rig_analysis.compare_with_truth(p.X, p.flags, p.instant, self.rank, len(self.tracks),
                                                              data.calibration.cameras.centers, true_centers,
                                                              self.truth)

    def track_rows(self, k: int) -> np.ndarray:
        return np.flatnonzero(self.rank == k)

    def payload(self) -> dict:
        """The numbers the page plots, for readers of the page (``mvm-data`` ``figures``)."""
        p = self.data.poses
        angles = {}
        for k, track in enumerate(self.tracks):
            rows = self.track_rows(k)
            angles[str(int(track))] = {"frames": p.frames[p.instant[rows]].tolist(),
                                       "degrees": _rounded(self.angles[rows], 2),
                                       "flags": self.angle_flags[rows].tolist()}
        return {"cameras": self.data.names, "angle_names": list(JOINT_ANGLES), "truth": self.truth_payload(),
                "camera_error": {"frames": p.frames[self.bounds[:-1]].tolist(),
                                 "median_px": _rounded(self.error_series, 3),
                                 "keypoints": self.error_counts.tolist(),
                                 "overall_median_px": _rounded(self.error_summary["median"], 3),
                                 "overall_p90_px": _rounded(self.error_summary["p90"], 3),
                                 "overall_keypoints": self.error_summary["count"].tolist()},
                "angles": angles, "tracks": [int(t) for t in self.tracks]}

    def truth_payload(self) -> dict | None:
        """The comparison with a simulated rig's truth (``figures.truth``), or None."""
        c = self.comparison
        if c is None:
            return None
        return {"scale": round(c["scale"], 6), "camera_residual_m": _rounded(c["camera_residual"], 5),
                "mpjpe_m": {k: None if not math.isfinite(v) else round(v, 5) for k, v in c["mpjpe"].items()},
                "tracks": {str(int(k)): {"true_person": int(c["truth_of"][i]),
                                         "mpjpe_m": _rounded(c["track_mpjpe"][i], 5),
                                         "angle_error_deg": _rounded(c["track_angle_error"][i], 3)}
                           for i, k in enumerate(self.tracks)}}

    def truth_in_view(self, to_display) -> list | None:
        """The true persons of every instant in the display frame: ``T`` lists of flat joints."""
        if self.comparison is None:
            return None
        c = self.comparison
        world = np.einsum("ji,...j->...i", c["R"], self.truth - c["t"]) / c["scale"]   # into the estimate's frame
        flat = np.round(to_display(world).reshape(world.shape[0], world.shape[1], -1), 3)
        return np.where(np.isfinite(flat), flat, None).tolist()


def _rounded(a: np.ndarray, digits: int):
    """Nested lists of ``a`` rounded, NaN as None."""
    a = np.round(np.asarray(a, dtype=float), digits)
    return np.where(np.isfinite(a), a, None).tolist()


def rig_view_payload(fig: RigFigures) -> dict:
    """The 3D view's data in a display frame (up = +z, the people at the origin): the persons of
    every instant, the cameras' frustums and names, the floor grid."""
    data, p = fig.data, fig.data.poses
    cams = data.calibration.cameras
    finite = p.X[np.isfinite(p.X).all(-1)]
    M, origin = analysis.display_frame(analysis.up_direction(cams.R), finite.mean(0) if len(finite)
                                       else cams.centers.mean(0))
    to_display = lambda a: (np.asarray(a, dtype=float) - origin) @ M.T  # noqa: E731
    Xd, Cd = to_display(p.X), to_display(cams.centers)
    people = Xd[np.isfinite(Xd).all(-1)]
    spread = np.concatenate([people, Cd])
    radius = max(float(np.percentile(np.linalg.norm(spread[:, :2], axis=1), 95)), float(np.ptp(spread[:, 2])) / 2,
                 1e-3)
    heights = np.ptp(np.where(np.isfinite(Xd), Xd, np.nanmean(Xd, axis=1, keepdims=True))[..., 2], axis=1)
    person_scale = float(np.nanmedian(heights)) if np.isfinite(heights).any() else radius / 3
    floor = float(np.percentile(people[:, 2], 1)) if len(people) else float(Cd[:, 2].min() - person_scale)
    frustums = analysis.frustums(cams.K, cams.R, cams.t, cams.size, 0.1 * radius)
    flat = np.round(Xd.reshape(len(Xd), 3 * Xd.shape[1]), 3)
    xyz = np.where(np.isfinite(flat), flat, None).tolist()
    flags = ["".join(map(str, row)) for row in np.asarray(p.flags, dtype=int).tolist()]
    bounds = np.searchsorted(p.instant, np.arange(len(p.frames) + 1))
    persons = [{"id": int(p.track[q]), "color": fig.colors[fig.rank[q]], "xyz": xyz[q], "flags": flags[q]}
               for q in range(len(p))]
    instants = [{"frame": int(f), "persons": persons[bounds[t]:bounds[t + 1]]} for t, f in enumerate(p.frames.tolist())]
    truth = fig.truth_in_view(to_display)
    if truth is not None:
        for t, instant in enumerate(instants):
            instant["truth"] = [{"id": g, "color": "#222222", "xyz": xyz} for g, xyz in enumerate(truth[t])
                                if any(v is not None for v in xyz)]
    step = nice_step(2 * radius)
    return {"persons": [], "instants": instants, "truth": None if truth is None else [],
            "skeleton": [list(e) for e in COCO_SKELETON], "path": [], "points": [],
            "frustums": _rounded(to_display(frustums), 4),
            "camera_labels": [{"name": n, "at": _rounded(c + [0, 0, 0.05 * radius], 4)}
                              for n, c in zip(cams.names, Cd)],
            "radius": round(radius, 4), "person_scale": round(person_scale, 4), "center_z": 0.0,
            "heading": round(float(math.atan2(Cd[0, 1], Cd[0, 0])), 4), "rate": _frame_rate(data.recap),
            "grid": {"z": round(floor, 4), "half": round(step * math.ceil(1.1 * radius / step), 4),
                     "step": round(step, 4)}}


def _frame_rate(recap: dict) -> float:
    rate = (recap.get("options") or {}).get("frame_rate") if isinstance(recap.get("options"), dict) else None
    usable = isinstance(rate, (int, float)) and not isinstance(rate, bool) and 0 < rate < 1e4
    return float(rate) if usable else DEFAULT_FRAME_RATE_HZ


def _cards(items) -> str:
    """Cards of ``(name, value)``: names are text (escaped here; a recap's may be anything),
    values already HTML (:func:`~mvm.report.page.fmt_cell`)."""
    return '<div class="cards">' + "".join(f'<div class="card"><div class="value">{v}</div><div class="name">'
                                           f"{escape(n)}</div></div>" for n, v in items) + "</div>"


def recap_section(data: RigReportData) -> str:
    """The recap of ``recap.json``: counts, shares of joint flags, offsets, and per keypoint the
    error, the views and the share each camera had excluded (as ``mvm rig reconstruct`` prints)."""
    r = data.recap
    flags = r.get("joint_flags") or {}
    offsets = r.get("sync_offsets") or {}
    cards = [("instants", fmt_cell(r.get("instants"))), ("tracks", fmt_cell(r.get("tracks"))),
             ("persons (all instants)", fmt_cell(r.get("persons"))),
             ("persons per instant", fmt_cell(r.get("persons_per_instant"))),
             ("reprojection error (px)", fmt_cell(r.get("reprojection_error_px"))),
             ("instants / s", fmt_cell(r.get("instants_per_s"), 1)),
             *[(f"{k} joints", f"{100 * v:.1f} %") for k, v in flags.items() if isinstance(v, (int, float))]]
    names = list((r.get("excluded_per_camera") or {}).keys())
    head = "".join(f"<th>excl. {escape(n)}</th>" for n in names)
    rows = []
    for j, kp in enumerate(r.get("keypoints") or COCO_KEYPOINTS):
        cells = "".join(f"<td>{fmt_cell(_at(r['excluded_per_camera'][n], j))}</td>" for n in names)
        rows.append(f"<tr><td>{escape(str(kp))}</td><td>{fmt_cell(_at(r.get('error_per_keypoint_px'), j))}</td>"
                    f"<td>{fmt_cell(_at(r.get('views_per_keypoint'), j))}</td>{cells}</tr>")
    sync = (", ".join(f"{escape(n)} {o:+d}" for n, o in offsets.items()) if offsets
            else "none (frame numbers as they are)")
    return (f'<section id="recap"><h2>Recap</h2>{_cards(cards)}<p class="note">Calibration '
            f"<code>{escape(str(data.calib))}</code> · frame offsets (sync.toml): {sync} · frames "
            f"{int(data.poses.frames[0])}–{int(data.poses.frames[-1])}</p>"
            '<table class="small" id="recap-keypoints"><thead><tr><th>keypoint</th><th>error px</th><th>views</th>'
            f'{head}</tr></thead><tbody>{"".join(rows)}</tbody></table><p class="note">excl.: share of a camera\'s '
            "keypoints that triangulation excluded as outliers (RANSAC).</p></section>")


def _at(values, j):
    return values[j] if isinstance(values, list) and j < len(values) and isinstance(values[j], (int, float)) else None


def tracks_section(fig: RigFigures) -> str:
    """A row per track (frames, instants seen, shares of each flag) and its joints' timeline."""
    p = fig.data.poses
    t0, t1 = float(p.frames[0]), float(p.frames[-1] + 1)
    rows, lines = [], []
    for k, track in enumerate(fig.tracks):
        rows_k = fig.track_rows(k)
        instants, flags = rig_analysis.dense_track(p.flags, p.instant, p.track, int(track), fill=0)
        frames = p.frames[instants]
        runs = rig_analysis.flag_runs(flags)
        # runs in frame numbers: a run ends where the next instant begins (or one frame on)
        ends = np.append(frames[1:], frames[-1] + 1)
        runs = np.stack([runs[:, 0], frames[runs[:, 1]], ends[runs[:, 2] - 1], runs[:, 3]], axis=1)
        color = fig.colors[k]
        palette = {OBSERVED: color, INTERPOLATED: color + "66", INFERRED: "#9a9a9a"}
        lines.append(flag_timeline(runs, t0, t1, [palette.get(c) for c in range(len(FLAG_NAMES))],
                                   f"track {int(track)}", COCO_KEYPOINTS))
        share = np.bincount(p.flags[rows_k].ravel().astype(int), minlength=len(FLAG_NAMES)) / p.flags[rows_k].size
        rows.append(f'<tr><td><span class="swatch" style="background:{color}"></span>{int(track)}</td>'
                    f"<td>{int(frames[0])}–{int(frames[-1])}</td><td>{len(rows_k)}</td>"
                    + "".join(f"<td>{100 * share[c]:.1f}</td>" for c in (OBSERVED, INTERPOLATED, INFERRED)) + "</tr>")
    return ('<section id="tracks"><h2>Tracks</h2><table class="small"><thead><tr><th>track</th><th>frames</th>'
            "<th>instants seen</th><th>observed %</th><th>interpolated %</th><th>inferred %</th></tr></thead>"
            f'<tbody>{"".join(rows)}</tbody></table><p class="note">Each track\'s 17 joints (rows, nose at the top) '
            "over the frames: observed in the track's colour, interpolated light, inferred grey, empty where "
            f'the joint (or the track) is missing.</p><div class="timelines">{"".join(lines)}</div></section>')


def cameras_section(fig: RigFigures) -> str:
    """The median reprojection error of each camera over time, and per camera over the capture."""
    data, s = fig.data, fig.error_summary
    frames = data.poses.frames[fig.bounds[:-1]]
    binned = len(fig.bounds) - 1 < len(data.poses.frames)
    chart = line_chart(frames, fig.error_series.T, data.names, fig.camera_colors,
                       "Reprojection error per camera over time", "px (median)",
                       note=f"bins of {len(data.poses.frames) / (len(fig.bounds) - 1):.1f} instants" if binned else "")
    excluded = data.recap.get("excluded_overall_per_camera") or {}
    rows = "".join(f'<tr><td><span class="swatch" style="background:{fig.camera_colors[v]}"></span>{escape(n)}</td>'
                   f"<td>{fmt_cell(float(s['median'][v]))}</td><td>{fmt_cell(float(s['p90'][v]))}</td>"
                   f"<td>{int(s['count'][v])}</td><td>{fmt_cell(excluded.get(n), 3)}</td></tr>"
                   for v, n in enumerate(data.names))
    return ('<section id="cameras"><h2>Cameras</h2><p class="note">The distance between each 2D keypoint a '
            "person was matched to and its observed 3D joint projected into that camera (lens undone), median "
            "over the camera's keypoints of each instant. A camera that drifts, slips out of sync or was "
            f'moved stands out.</p><div class="plotbox">{chart}</div><table class="small" id="camera-errors"><thead>'
            "<tr><th>camera</th><th>median px</th><th>90th percentile px</th><th>keypoints</th>"
            f"<th>excluded share (recap)</th></tr></thead><tbody>{rows}</tbody></table></section>")


def angles_section(fig: RigFigures) -> str:
    """The flexion of the knees, hips and elbows along each track (the longest ones)."""
    p = fig.data.poses
    lengths = np.bincount(fig.rank, minlength=len(fig.tracks))
    shown = np.argsort(-lengths, kind="stable")[:MAX_ANGLE_TRACKS]
    names = list(JOINT_ANGLES)
    blocks = []
    for k in shown:
        rows = fig.track_rows(k)
        frames = p.frames[p.instant[rows]]
        charts = []
        for joint in ("knee", "hip", "elbow"):
            a = [names.index(f"{side} {joint}") for side in ("left", "right")]
            charts.append(line_chart(frames, fig.angles[rows][:, a].T, ["left", "right"], ["#4c78a8", "#e15759"],
                                     f"track {int(fig.tracks[k])}: {joint} flexion", "degrees", width=420,
                                     height=200, faint=(fig.angle_flags[rows][:, a] != OBSERVED).T, top=180.0))
        blocks.append(f'<div class="plots" data-track="{int(fig.tracks[k])}">'
                      + "".join(f'<div class="plotbox">{c}</div>' for c in charts) + "</div>")
    more = (f'<p class="note">The {MAX_ANGLE_TRACKS} longest of {len(fig.tracks)} tracks are shown.</p>'
            if len(fig.tracks) > MAX_ANGLE_TRACKS else "")
    return ('<section id="angles"><h2>Joint angles</h2><p class="note">Flexion, 0° for a straight limb: knee '
            "(hip–knee–ankle), hip (shoulder–hip–knee), elbow (shoulder–elbow–wrist); dashed where one of the "
            f"three joints was interpolated or inferred.</p>{more}{''.join(blocks)}</section>")


def truth_section(fig: RigFigures) -> str:
    """The reconstruction against a simulated rig's truth: errors per flag, per track, and the
    similarity that brought the estimate into the truth's frame."""
    c = fig.comparison
    if c is None:
        return ""
    mm = lambda v: fmt_cell(1000 * float(v), 1)  # noqa: E731
    cards = [*[(f"MPJPE, {k} joints (mm)", mm(v)) for k, v in c["mpjpe"].items()],
             ("tracks on a true person", f"{int((c['truth_of'] >= 0).sum())} / {len(fig.tracks)}"),
             ("true persons", str(fig.data.truth.poses3d.shape[1])),
             ("camera centres after the similarity (mean, cm)", fmt_cell(100 * float(c["camera_residual"].mean()))),
             ("scale of the similarity", fmt_cell(c["scale"], 4))]
    rows = "".join(f'<tr><td><span class="swatch" style="background:{fig.colors[k]}"></span>{int(track)}</td>'
                   f"<td>{c['truth_of'][k] if c['truth_of'][k] >= 0 else '–'}</td><td>{mm(c['track_mpjpe'][k])}</td>"
                   f"<td>{fmt_cell(float(c['track_angle_error'][k]), 1)}</td></tr>"
                   for k, track in enumerate(fig.tracks))
    return (f'<section id="truth"><h2>Ground truth (simulated rig)</h2>{_cards(cards)}<p class="note">The estimate '
            "is moved by the similarity that maps its camera centres onto the true ones (the identity with the true "
            "calibration); each track is compared with the true person closest to it. The 3D view draws the true "
            'bodies as dashed dark skeletons (toggle <em>ground truth</em>).</p><table class="small" id="truth-tracks">'
            "<thead><tr><th>track</th><th>true person</th><th>MPJPE, observed joints (mm)</th><th>joint angle error, "
            f"median (°)</th></tr></thead><tbody>{rows}</tbody></table></section>")


def rig_report_html(data: RigReportData) -> str:
    """The whole page as a string."""
    fig = RigFigures(data)
    payload = {"view": rig_view_payload(fig), "figures": fig.payload()}
    text = json.dumps(payload, allow_nan=False, separators=(",", ":")).replace("</", "<\\/")
    legend = "".join(f'<div><span class="swatch" style="background:{c}"></span>track {int(t)}</div>'
                     for t, c in zip(fig.tracks, fig.colors))
    title = escape(data.rig_dir.name or str(data.rig_dir))
    truth_box = ('<label><input type="checkbox" data-show="truth"> ground truth (dashed)</label>'
                 if fig.comparison is not None else "")
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><meta name="viewport" content="width=device-width,initial-scale=1">
<title>mvm rig report: {title}</title><style>{CSS}.timelines svg{{display:block;margin:4px 0}}</style>
<script>{ERROR_HOOK}</script></head>
<body><header><h1>mvm rig report: {title}</h1><p>{escape(str(data.rig_dir))} · {escape(data.out_dir.name)}/{RIG_POSES3D}
· {len(data.names)} cameras · mvm {escape(__version__)} · written {time.strftime("%Y-%m-%d %H:%M")}</p></header><main>
{recap_section(data)}
<section id="view3d"><h2>3D view</h2><div id="viewer"><div class="viewbox"><canvas id="mvm-view"></canvas>
<div><button id="mvm-play" type="button">play</button> <input id="mvm-time" type="range" min="0" value="0" step="1"
style="width:70%"> <span id="mvm-time-label"></span></div>
<div id="mvm-status" data-state="loading">3D view: loading…</div></div>
<div class="legend"><p class="note">Drag to rotate, shift- or right-drag to pan, wheel to zoom, double-click to
reset; the slider picks the instant. Dots: observed joints filled, interpolated white, inferred grey.</p>
<label><input type="checkbox" data-show="cameras"> cameras</label>
<label><input type="checkbox" data-show="floor"> floor grid</label>
<label><input type="checkbox" data-show="labels"> track and camera names</label>{truth_box}<h3>Tracks</h3>{legend}
</div></div></section>
{tracks_section(fig)}
{cameras_section(fig)}
{angles_section(fig)}
{truth_section(fig)}
</main><script type="application/json" id="mvm-data">{text}</script><script>{viewer_script()}</script></body></html>
"""


def write_rig_report(data: RigReportData, inputs: list[Path], path: str | Path | None = None) -> Path:
    """Write the report of a reconstructed rig, ``data`` (:func:`mvm.stages.view.load_rig_view`;
    default ``RIG_DIR/<output>/report.html``, listed in the output set, so that the next
    ``mvm rig reconstruct`` replaces it with the set) and return its path. A ``path`` that is,
    holds or lies inside one of ``inputs`` (what the page is drawn from) is refused
    (:func:`mvm.io.outputs.check_output_location`)."""
    out_dir = data.out_dir
    target = Path(path) if path is not None else out_dir / REPORT_PAGE
    check_output_location(target, inputs, replaced=False)
    html = rig_report_html(data)
    if in_output_set(target, out_dir):
        add_to_output_set(out_dir, target.name, lambda p: atomic_write_text(p, html))
    else:
        atomic_write_text(target, html)
    log.info("%s: rig report written (%.1f kB)", target, len(html.encode()) / 1e3)
    return target
