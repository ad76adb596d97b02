"""The zero-phase Butterworth low-pass that smooths rig tracks, in numpy.

:func:`butter_lowpass` gives the same coefficients as ``scipy.signal.butter(order, wn)`` (the
analog prototype's poles, prewarped, mapped by the bilinear transform) and :func:`filtfilt` the
same result as ``scipy.signal.filtfilt(b, a, x, axis=0)`` with its defaults (odd extension of
``3 * max(len(a), len(b))`` samples, steady-state initial conditions, forward then backward
pass in the transposed direct form II), to the last bit on the rig's tracks. Importing
``scipy.signal`` imports ``scipy.stats`` too: about 0.7 s of every ``mvm rig reconstruct``
process, as much as all the numpy and scipy the rest of the rig pipeline needs; the tests pin
both functions to ``scipy.signal``. No I/O.
"""
from __future__ import annotations

import numpy as np


def min_cutoff(order: int) -> float:
    """The lowest cut-off (a fraction of the Nyquist frequency) at which a Butterworth low-pass of
    ``order`` is computed reliably in double precision: ``10 ** (-9 / order)``.

    As the cut-off ``wn`` falls, the poles crowd towards 1 and the steady-state system of
    :func:`filtfilt` gets singular: the error on a constant series grows like ``wn ** -order``
    (measured: 5e-10 at order 2 and wn 1e-4, 1e-5 at order 4 and wn 1e-3, a singular matrix at
    wn 1e-11). At this bound it stays near 1e-8 of the signal for every order up to 8."""
    return 10.0 ** (-9.0 / order)


def butter_lowpass(order: int, wn: float) -> tuple[np.ndarray, np.ndarray]:
    """Digital Butterworth low-pass of ``order`` with cut-off ``wn`` (a fraction of the Nyquist
    frequency, in [:func:`min_cutoff`, 1)) -> ``(b: (order + 1,), a: (order + 1,))``, ``a[0] == 1``."""
    if order < 1:
        raise ValueError(f"butter_lowpass: the order must be >= 1, got {order}")
    if not 0 < wn < 1:
        raise ValueError(f"butter_lowpass: the cut-off must be in (0, 1) of the Nyquist frequency, got {wn}")
    if wn < min_cutoff(order):
        raise ValueError(f"butter_lowpass: a cut-off of {wn:.3g} of the Nyquist frequency is below the "
                         f"{min_cutoff(order):.3g} an order-{order} filter is reliable at")
    warped = 4.0 * np.tan(np.pi * wn / 2.0)                            # prewarped cut-off, sampling rate 2
    analog = warped * -np.exp(1j * np.pi * np.arange(-order + 1, order, 2) / (2 * order))   # (order,) poles
    poles = (4.0 + analog) / (4.0 - analog)                                           # bilinear transform
    gain = warped ** order * np.real(1.0 / np.prod(4.0 - analog))
    b = gain * np.real(np.poly(-np.ones(order)))
    a = np.real(np.poly(poles))
    return b, a


def _steady_state(b: np.ndarray, a: np.ndarray) -> np.ndarray:
    """The initial state of the transposed direct form II for a unit step: ``(n - 1,)``
    (``scipy.signal.lfilter_zi``)."""
    n = len(a)
    companion = np.zeros((n - 1, n - 1))
    companion[0] = -a[1:]
    companion[1:, :-1] += np.eye(n - 2) if n > 2 else 0.0
    return np.linalg.solve(np.eye(n - 1) - companion.T, b[1:] - a[1:] * b[0])


def _lfilter(b: np.ndarray, a: np.ndarray, x: np.ndarray, state: np.ndarray) -> np.ndarray:
    """Filter ``x: (L, C)`` along its first axis from ``state: (n - 1, C)`` (transposed direct
    form II, ``a[0] == 1``) -> ``(L, C)``."""
    y = np.empty_like(x)
    z = state.copy()
    n = len(a)
    for t in range(len(x)):
        xt = x[t]
        yt = z[0] + b[0] * xt
        for k in range(n - 2):
            z[k] = z[k + 1] + b[k + 1] * xt - a[k + 1] * yt
        z[n - 2] = b[n - 1] * xt - a[n - 1] * yt
        y[t] = yt
    return y


def filtfilt(b: np.ndarray, a: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Zero-phase filtering of ``x: (L, ...)`` along its first axis -> same shape; ``L`` must
    exceed ``3 * max(len(a), len(b))`` (the odd extension at each end)."""
    x = np.asarray(x, dtype=float)
    return filtfilt_many(b, a, [x.reshape(len(x), -1)])[0].reshape(x.shape)


def filtfilt_many(b: np.ndarray, a: np.ndarray, series: list) -> list:
    """:func:`filtfilt` of every ``(L_i, C_i)`` array of ``series``, all in one pass: the series
    are the columns of one array, each starting at row 0 (then, reversed, each ending there), so
    that the recursion runs once over the longest. Returns the list of ``(L_i, C_i)`` results."""
    b = np.asarray(b, dtype=float) / a[0]
    a = np.asarray(a, dtype=float) / a[0]
    n = max(len(a), len(b))
    b, a = np.pad(b, (0, n - len(b))), np.pad(a, (0, n - len(a)))
    pad = 3 * n
    if not series:
        return []
    for x in series:
        if len(x) <= pad:
            raise ValueError(f"filtfilt: the series must be longer than {pad} samples, got {len(x)}")
    lengths = np.array([len(x) + 2 * pad for x in series])
    widths = [x.shape[1] for x in series]
    ext = np.zeros((lengths.max(), sum(widths)))                                    # (T, C)
    column = 0
    for x, width in zip(series, widths):
        x = np.asarray(x, dtype=float)
        ext[:len(x) + 2 * pad, column:column + width] = np.concatenate(
            [2 * x[0] - x[pad:0:-1], x, 2 * x[-1] - x[-2:-pad - 2:-1]])           # odd extension
        column += width
    end = np.repeat(lengths, widths)                                                # (C,) rows of each column
    rows = end[None, :] - 1 - np.arange(len(ext))[:, None]                          # (T, C) each column reversed
    inside = rows >= 0
    rows = np.maximum(rows, 0)

    def reverse(y: np.ndarray) -> np.ndarray:
        return np.where(inside, np.take_along_axis(y, rows, axis=0), 0.0)

    zi = _steady_state(b, a)[:, None]
    forward = reverse(_lfilter(b, a, ext, zi * ext[0]))
    backward = reverse(_lfilter(b, a, forward, zi * forward[0]))
    out, column = [], 0
    for x, width in zip(series, widths):
        out.append(backward[pad:pad + len(x), column:column + width])
        column += width
    return out
