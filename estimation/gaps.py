"""Filling dropped samples (NaN) in sensor pose streams."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from . import _rows as rows
from .errors import InputError
from .quaternions import as_rotvec, from_rotvec, multiply, relative


def _neighbours(valid: NDArray[np.bool_]) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Index of the last valid sample at or before, and the first at or after, each frame,
    along axis 0; -1 (n) where there is none."""
    n = valid.shape[0]
    idx = np.arange(n).reshape((n,) + (1,) * (valid.ndim - 1))
    prev = np.maximum.accumulate(np.where(valid, idx, -1), axis=0)
    nxt = np.minimum.accumulate(np.where(valid, idx, n)[::-1], axis=0)[::-1]
    return prev, nxt


def gap_lengths(valid: NDArray[np.bool_]) -> NDArray[np.intp]:
    """Lengths (in frames) of the runs of ``False`` in a 1-D mask."""
    padded = np.concatenate(([True], np.asarray(valid, dtype=bool), [True]))
    change = np.diff(padded.astype(np.int8))
    starts = np.flatnonzero(change == -1)
    stops = np.flatnonzero(change == 1)
    return np.asarray(stops - starts, dtype=np.intp)


def fill_gaps(
    positions: NDArray[np.float64],
    quaternions: NDArray[np.float64],
    *,
    time: NDArray[np.float64] | None = None,
    method: str = "cubic",
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Interpolate dropped samples of sensor poses.

    Parameters
    ----------
    positions : ndarray, shape (F, S, 3) or (F, 3)
        Positions, NaN where dropped.
    quaternions : ndarray, shape (F, S, 4) or (F, 4)
        Scalar-first rotations, NaN where dropped.
    time : ndarray, shape (F,), optional
        Sample times; defaults to the frame index.
    method : {"cubic", "linear"}
        Position interpolant across interior gaps. Rotations always use spherical linear
        interpolation (Slerp) between the samples bracketing the gap.

    Returns
    -------
    positions, quaternions : ndarray
        Copies with every sample finite. Samples before the first (after the last) valid one
        repeat it.
    filled : ndarray of bool, shape (F, S) or (F,)
        Samples that were interpolated.

    Raises
    ------
    InputError
        If a sensor has no valid sample at all (``sensor`` is its column index).
    """
    if method not in ("cubic", "linear"):
        raise InputError(f"unknown gap-filling method {method!r}", field="method")
    single = positions.ndim == 2
    pos = np.array(positions[:, None] if single else positions, dtype=float)
    quat = np.array(quaternions[:, None] if single else quaternions, dtype=float)
    n_frames = pos.shape[0]
    t = np.arange(n_frames, dtype=float) if time is None else np.asarray(time, dtype=float)
    valid = rows.finite(pos) & rows.finite(quat)
    valid &= rows.dots(quat, quat) > 1e-18  # NaN compares False: no mask needed
    empty = ~valid.any(axis=0)
    if empty.any():
        s = int(np.flatnonzero(empty)[0])
        raise InputError(f"sensor column {s} has no valid sample", sensor=str(s))
    prev, nxt = _neighbours(valid)
    frame, sensor = np.nonzero(~valid)
    i0, i1 = prev[frame, sensor], nxt[frame, sensor]
    interior = (i0 >= 0) & (i1 < n_frames)
    # outside the valid range, repeat the nearest valid sample
    i0 = np.where(i0 < 0, i1, i0)
    i1 = np.where(i1 >= n_frames, i0, i1)
    span = t[i1] - t[i0]
    frac = np.where(span > 0, (t[frame] - t[i0]) / np.where(span > 0, span, 1.0), 0.0)
    p0, p1 = pos[i0, sensor], pos[i1, sensor]
    filled_pos = p0 + frac[:, None] * (p1 - p0)
    if method == "cubic":
        # local cubic through two valid samples each side of the gap: one vectorised step
        # for all sensors instead of a global spline per sensor
        before = np.where(interior & (i0 > 0), prev[np.maximum(i0 - 1, 0), sensor], -1)
        after = np.where(interior & (i1 < n_frames - 1),
                         nxt[np.minimum(i1 + 1, n_frames - 1), sensor], n_frames)
        cubic = (before >= 0) & (after < n_frames)
        if cubic.any():
            knots = np.stack([before[cubic], i0[cubic], i1[cubic], after[cubic]], axis=1)
            filled_pos[cubic] = _lagrange(t[knots], pos[knots, sensor[cubic, None]],
                                          t[frame[cubic]])
    pos[frame, sensor] = filled_pos
    q0, q1 = quat[i0, sensor], quat[i1, sensor]
    q0 = q0 / rows.norms(q0)[:, None]
    q1 = q1 / rows.norms(q1)[:, None]
    quat[frame, sensor] = multiply(q0, from_rotvec(frac[:, None] * as_rotvec(relative(q0, q1))))
    filled = ~valid
    if single:
        return pos[:, 0], quat[:, 0], filled[:, 0]
    return pos, quat, filled


def _lagrange(knots_t: NDArray[np.float64], knots_p: NDArray[np.float64],
              t: NDArray[np.float64]) -> NDArray[np.float64]:
    """Cubic through four (time, point) knots per row, evaluated at ``t``.

    ``knots_t`` (G, 4), ``knots_p`` (G, 4, 3), ``t`` (G,) → (G, 3).
    """
    out = np.zeros((t.size, knots_p.shape[-1]))
    for k in range(4):
        weight = np.ones(t.size)
        for m in range(4):
            if m != k:
                weight *= (t - knots_t[:, m]) / (knots_t[:, k] - knots_t[:, m])
        out += weight[:, None] * knots_p[:, k]
    return out
