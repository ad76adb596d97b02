"""Inline SVG plots (strings), drawn from arrays: no plotting library, no I/O."""
from __future__ import annotations

import math
from html import escape

import numpy as np


def _nice_max(value: float) -> float:
    """A round axis maximum >= ``value``."""
    if not math.isfinite(value) or value <= 0:
        return 1.0
    exponent = 10 ** math.floor(math.log10(value))
    for step in (1, 2, 2.5, 5, 10):
        if step * exponent >= value:
            return step * exponent
    return 10 * exponent


def bar_chart(labels, values, title: str, unit: str, whiskers=None, markers=None,
              color: str = "#4c78a8", width: int = 640, height: int = 260,
              value_note: str = "", whisker_note: str = "", marker_note: str = "") -> str:
    """A vertical bar chart as an ``<svg>`` string.

    Args:
        labels: ``K`` category names (drawn rotated under the bars).
        values: ``(K,)`` bar heights; NaN draws no bar (and "–" in the tooltip).
        whiskers: ``(K,)`` optional upper values drawn as a tick above the bar (e.g. a 90th
            percentile or a maximum); markers: ``(K,)`` optional values drawn as dots.
        unit: the value axis' unit; ``*_note``: what each mark means (legend and tooltips).
    """
    values = np.asarray(values, dtype=float).reshape(-1)
    K = len(values)
    if len(labels) != K:
        raise ValueError(f"labels: expected {K} names, got {len(labels)}")
    extra = [np.asarray(a, dtype=float).reshape(-1) for a in (whiskers, markers) if a is not None]
    for a in extra:
        if len(a) != K:
            raise ValueError(f"whiskers/markers: expected {K} values, got {len(a)}")
    everything = np.concatenate([values] + extra)
    top = _nice_max(float(np.nanmax(everything)) if np.isfinite(everything).any() else 0.0)
    left, right, upper, lower = 48, 12, 30, 88
    plot_w, plot_h = width - left - right, height - upper - lower
    slot = plot_w / max(K, 1)
    y = lambda v: upper + plot_h * (1 - min(max(v / top, 0.0), 1.0))  # noqa: E731
    out = [f'<svg class="plot" xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {width} {height}" '
           f'width="{width}" height="{height}" role="img" aria-label="{escape(title)}">',
           f'<text x="{left}" y="18" class="plot-title">{escape(title)}</text>']
    for i in range(5):
        v = top * i / 4
        yy = y(v)
        out.append(f'<line x1="{left}" x2="{width - right}" y1="{yy:.1f}" y2="{yy:.1f}" class="grid"/>')
        out.append(f'<text x="{left - 6}" y="{yy + 4:.1f}" text-anchor="end" class="tick">{v:g}</text>')
    out.append(f'<text transform="translate(12,{upper + plot_h / 2:.0f}) rotate(-90)" '
               f'text-anchor="middle" class="tick">{escape(unit)}</text>')
    whisker = extra[0] if whiskers is not None else None
    marker = extra[-1] if markers is not None else None
    for k in range(K):
        x0 = left + k * slot
        cx = x0 + slot / 2
        tip = [f"{labels[k]}: {_fmt(values[k])} {unit}{(' ' + value_note) if value_note else ''}"]
        if whisker is not None:
            tip.append(f"{whisker_note or 'upper'} {_fmt(whisker[k])}")
        if marker is not None:
            tip.append(f"{marker_note or 'marker'} {_fmt(marker[k])}")
        out.append(f'<g><title>{escape("; ".join(tip))}</title>')
        if math.isfinite(values[k]):
            out.append(f'<rect x="{x0 + 0.15 * slot:.1f}" y="{y(values[k]):.1f}" width="{0.7 * slot:.1f}" '
                       f'height="{upper + plot_h - y(values[k]):.1f}" fill="{color}"/>')
        if whisker is not None and math.isfinite(whisker[k]):
            yy = y(whisker[k])
            base = y(values[k]) if math.isfinite(values[k]) else yy
            out.append(f'<path d="M{cx:.1f} {base:.1f}V{yy:.1f}M{cx - 0.2 * slot:.1f} {yy:.1f}'
                       f'H{cx + 0.2 * slot:.1f}" class="whisker"/>')
        if marker is not None and math.isfinite(marker[k]):
            out.append(f'<circle cx="{cx:.1f}" cy="{y(marker[k]):.1f}" r="3" class="marker"/>')
        out.append("</g>")
        out.append(f'<text transform="translate({cx + 4:.1f},{upper + plot_h + 8}) rotate(-60)" '
                   f'text-anchor="end" class="tick">{escape(str(labels[k]))}</text>')
    out.append(f'<line x1="{left}" x2="{width - right}" y1="{upper + plot_h}" y2="{upper + plot_h}" class="axis"/>')
    legend = [n for n in (value_note and f"bar: {value_note}", whisker is not None and whisker_note
                          and f"tick: {whisker_note}", marker is not None and marker_note
                          and f"dot: {marker_note}") if n]
    if legend:
        out.append(f'<text x="{width - right}" y="18" text-anchor="end" class="tick">'
                   f'{escape(" · ".join(legend))}</text>')
    out.append("</svg>")
    return "".join(out)


def _fmt(value: float) -> str:
    return f"{value:.3g}" if math.isfinite(value) else "–"


def _ticks(low: float, high: float, count: int = 6) -> np.ndarray:
    """Round tick values spanning ``[low, high]``: ``(k,)``."""
    span = max(high - low, 1e-9)
    raw = span / count
    exponent = 10 ** math.floor(math.log10(raw))
    step = next(s * exponent for s in (1, 2, 2.5, 5, 10) if s * exponent >= raw)
    return np.arange(math.ceil(low / step) * step, high + 1e-9 * step, step)


def _polylines(x: np.ndarray, y: np.ndarray, sx, sy) -> str:
    """An SVG path through the finite points of ``y: (n,)`` over ``x: (n,)``, broken at NaN."""
    ok = np.isfinite(y)
    if not ok.any():
        return ""
    px, py = sx(x), sy(np.where(ok, y, 0.0))
    start = ok & ~np.concatenate([[False], ok[:-1]])
    return "".join(("M" if s else "L") + f"{a:.1f} {b:.1f}" for a, b, s, k in zip(px, py, start, ok) if k)


def line_chart(x, series, names, colors, title: str, unit: str, x_label: str = "frame", faint=None,
               width: int = 640, height: int = 240, note: str = "", top: float | None = None) -> str:
    """Lines over a shared axis as an ``<svg>`` string.

    Args:
        x: ``(n,)`` increasing positions (frame numbers); series: ``(S, n)`` values, NaN breaks
            a line; names, colors: ``S`` legend names and CSS colours.
        faint: ``(S, n)`` optional bool: those points are also drawn as a light dashed line
            (and left out of the solid one), e.g. values from joints that were not observed.
        top: the value axis' maximum (default: a round value above the largest).
    """
    x = np.asarray(x, dtype=float).reshape(-1)
    series = np.asarray(series, dtype=float).reshape(-1, len(x))
    S = len(series)
    if len(names) != S or len(colors) != S:
        raise ValueError(f"names, colors: expected {S} each, got {len(names)} and {len(colors)}")
    faint = np.zeros(series.shape, bool) if faint is None else np.asarray(faint, bool).reshape(series.shape)
    finite = series[np.isfinite(series)]
    top = top if top is not None else _nice_max(float(finite.max()) if len(finite) else 0.0)
    left, right, upper, lower = 48, 12, 30, 40
    plot_w, plot_h = width - left - right, height - upper - lower
    x0, x1 = (float(x.min()), float(x.max())) if len(x) else (0.0, 1.0)
    x1 = x1 if x1 > x0 else x0 + 1
    sx = lambda v: left + plot_w * (np.asarray(v, dtype=float) - x0) / (x1 - x0)  # noqa: E731
    sy = lambda v: upper + plot_h * (1 - np.clip(np.asarray(v, dtype=float) / top, 0.0, 1.0))  # noqa: E731
    out = [f'<svg class="plot" xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {width} {height}" '
           f'width="{width}" height="{height}" role="img" aria-label="{escape(title)}">',
           f'<text x="{left}" y="18" class="plot-title">{escape(title)}</text>']
    for v in np.linspace(0, top, 5):
        yy = float(sy(v))
        out.append(f'<line x1="{left}" x2="{width - right}" y1="{yy:.1f}" y2="{yy:.1f}" class="grid"/>'
                   f'<text x="{left - 6}" y="{yy + 4:.1f}" text-anchor="end" class="tick">{v:g}</text>')
    for v in _ticks(x0, x1):
        xx = float(sx(v))
        out.append(f'<line x1="{xx:.1f}" x2="{xx:.1f}" y1="{upper + plot_h}" y2="{upper + plot_h + 4}" '
                   f'class="axis"/><text x="{xx:.1f}" y="{upper + plot_h + 16}" text-anchor="middle" '
                   f'class="tick">{v:g}</text>')
    out.append(f'<text transform="translate(12,{upper + plot_h / 2:.0f}) rotate(-90)" text-anchor="middle" '
               f'class="tick">{escape(unit)}</text><text x="{left + plot_w / 2:.0f}" y="{height - 4}" '
               f'text-anchor="middle" class="tick">{escape(x_label)}</text>')
    for s in range(S):
        solid = np.where(faint[s], np.nan, series[s])
        light = np.where(faint[s] | np.concatenate([faint[s, 1:], [False]]) | np.concatenate([[False], faint[s, :-1]]),
                         series[s], np.nan) if faint[s].any() else np.full(len(x), np.nan)
        out.append(f'<g data-series="{escape(str(names[s]))}"><title>{escape(str(names[s]))}</title>')
        if np.isfinite(light).any():
            out.append(f'<path d="{_polylines(x, light, sx, sy)}" fill="none" stroke="{colors[s]}" '
                       'stroke-opacity="0.45" stroke-dasharray="3 3" stroke-width="1.2"/>')
        out.append(f'<path d="{_polylines(x, solid, sx, sy)}" fill="none" stroke="{colors[s]}" stroke-width="1.5"/>'
                   "</g>")
    labels = "".join(f'<tspan fill="{colors[s]}">{escape(str(names[s]))}</tspan>  ' for s in range(S))
    out.append(f'<text x="{width - right}" y="18" text-anchor="end" class="tick">{labels}'
               f'{escape(note)}</text></svg>')
    return "".join(out)


def flag_timeline(runs: np.ndarray, t0: float, t1: float, colors, title: str, joint_names,
                  width: int = 640, row: int = 3) -> str:
    """One track's joints along time as an ``<svg>`` string: a row per joint, a rectangle per
    run of one flag.

    ``runs: (R, 4)`` rows ``(joint, start, stop, flag)`` in time units (stop excluded);
    ``[t0, t1)`` the axis; ``colors``: CSS colour of each flag code (None: not drawn);
    ``joint_names``: ``J`` row names (tooltips)."""
    J = len(joint_names)
    left, right, upper = 48, 12, 18
    height = upper + J * row + 4
    scale = (width - left - right) / max(t1 - t0, 1e-9)
    out = [f'<svg class="timeline" xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {width} {height}" '
           f'width="{width}" height="{height}" role="img" aria-label="{escape(title)}">',
           f'<text x="0" y="12" class="plot-title">{escape(title)}</text>']
    for joint, start, stop, flag in np.asarray(runs, dtype=float).reshape(-1, 4):
        color = colors[int(flag)]
        if color is None:
            continue
        out.append(f'<rect x="{left + (start - t0) * scale:.1f}" y="{upper + joint * row:.0f}" '
                   f'width="{max((stop - start) * scale, 0.5):.1f}" height="{row}" fill="{color}"/>')
    out.append(f'<text x="{left - 4}" y="{upper + J * row / 2 + 4:.0f}" text-anchor="end" class="tick">'
               f'{J} joints</text></svg>')
    return "".join(out)
