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
