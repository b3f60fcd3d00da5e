"""Savitzky–Golay smoothing on scipy.linalg and scipy.ndimage: the numbers of
``scipy.signal.savgol_coeffs(window, order)`` and ``scipy.signal.savgol_filter(x, window,
order, axis=axis, mode="interp")``, operation for operation, without importing
``scipy.signal``, which pulls in ``scipy.stats`` (about 1.7 s on a loaded machine, more than
the estimate of a short take).

Only what the estimators use: smoothing (no derivative), unit sample spacing, the ``interp``
edges (the polynomial fitted to the first and the last window, evaluated over its outer
half).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import lstsq
from scipy.ndimage import convolve1d

Float = NDArray[np.float64]


def savgol_coeffs(window: int, order: int) -> Float:
    """Convolution coefficients of the least-squares polynomial of degree ``order`` over
    ``window`` samples, evaluated at the centre (``scipy.signal.savgol_coeffs`` with its
    defaults).

    Parameters
    ----------
    window : int
        Samples in the window (odd: the centre is a sample).
    order : int
        Degree of the polynomial, below ``window``.

    Returns
    -------
    ndarray, shape (window,)
    """
    if order >= window:
        raise ValueError("order must be less than window")
    half, odd = divmod(window, 2)
    pos = half if odd else half - 0.5
    x = np.flip(np.arange(-pos, window - pos, dtype=np.float64))  # reversed: a convolution
    design = x ** np.arange(order + 1, dtype=np.float64).reshape(-1, 1)
    target = np.zeros(order + 1)
    target[0] = 1.0
    coeffs = lstsq(design, target, cond=np.finfo(np.float64).eps * max(design.shape))[0]
    return np.asarray(coeffs)


def savgol_filter(x: NDArray[np.floating], window: int, order: int, *,
                  axis: int = -1, mode: str = "interp") -> Float:
    """``x`` smoothed along ``axis`` by the Savitzky–Golay filter (``mode="interp"``).

    Parameters
    ----------
    x : ndarray
        Samples, at least ``window`` along ``axis``.
    window, order : int
        As :func:`savgol_coeffs`.
    axis : int
        Axis of the samples.
    mode : {"interp"}
        The edges' treatment; the only one (named, so that calls read as scipy's).

    Returns
    -------
    ndarray, shape of ``x``
        Inner samples: the convolution with :func:`savgol_coeffs`; the first and last
        ``window // 2``: the polynomial fitted to the first (last) ``window`` samples.
    """
    if mode != "interp":
        raise ValueError(f"mode must be 'interp', got {mode!r}")
    samples: Float = np.asarray(x, dtype=np.float64)
    n = samples.shape[axis]
    if window > n:
        raise ValueError("window must not be longer than x along axis")
    y = np.asarray(convolve1d(samples, savgol_coeffs(window, order), axis=axis,
                              mode="constant"))
    half = window // 2
    _fit_edge(samples, (0, window), (0, half), axis=axis, order=order, y=y)
    _fit_edge(samples, (n - window, n), (n - half, n), axis=axis, order=order, y=y)
    return y


def _fit_edge(x: Float, fit: tuple[int, int], put: tuple[int, int], *, axis: int,
              order: int, y: Float) -> None:
    """``y[put]`` along ``axis`` becomes the polynomial fitted to ``x[fit]`` (as
    ``scipy.signal``'s ``_fit_edge``: samples swapped to the first axis, one column each)."""
    index = [slice(None)] * x.ndim
    index[axis] = slice(*fit)
    edge = np.swapaxes(x[tuple(index)], axis, 0)
    edge = edge.reshape(edge.shape[0], -1)
    coeffs = _polyfit(np.arange(0, fit[1] - fit[0], dtype=np.float64), edge, order)
    at = np.arange(put[0] - fit[0], put[1] - fit[0], dtype=np.float64).reshape(-1, 1)
    values = np.zeros_like(at)
    for c in coeffs:  # Horner, highest power first
        values = values * at + c
    shape = list(y.shape)
    shape[0], shape[axis] = shape[axis], shape[0]
    values = values.reshape((put[1] - put[0], *shape[1:]))
    index[axis] = slice(*put)
    y[tuple(index)] = np.swapaxes(values, 0, axis)


def _polyfit(t: Float, samples: Float, order: int) -> Float:
    """Coefficients (order + 1, C), highest power first, of the least-squares polynomials
    through each column of ``samples`` (T, C) at ``t`` (T,), columns of the Vandermonde
    matrix scaled to unit norm (``numpy.polyfit``)."""
    powers = np.flip(np.arange(order + 1, dtype=np.float64))
    lhs = t[:, None] ** powers[None, :]
    scale = np.sqrt(np.sum(lhs * lhs, axis=0))
    lhs /= scale
    coeffs = lstsq(lhs, samples, cond=t.shape[0] * np.finfo(np.float64).eps)[0]
    return np.asarray((coeffs.T / scale).T)
