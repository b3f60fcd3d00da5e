"""Filling dropped samples (NaN) in sensor pose streams."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation

from .errors import InputError


def _neighbours(valid: NDArray[np.bool_]) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Index of the last valid sample at or before, and the first at or after, each frame
    (ends clamp to the nearest valid sample)."""
    n = valid.size
    idx = np.arange(n)
    prev = np.maximum.accumulate(np.where(valid, idx, -1))
    nxt = np.minimum.accumulate(np.where(valid, idx, n)[::-1])[::-1]
    prev = np.where(prev < 0, nxt, prev)
    nxt = np.where(nxt >= n, prev, nxt)
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
    n_frames, n_sensors = pos.shape[:2]
    t = np.arange(n_frames, dtype=float) if time is None else np.asarray(time, dtype=float)
    valid = np.isfinite(pos).all(axis=-1) & np.isfinite(quat).all(axis=-1)
    norms = np.linalg.norm(np.where(valid[..., None], quat, 1.0), axis=-1)
    valid &= norms > 1e-9
    for s in range(n_sensors):
        ok = valid[:, s]
        if ok.all():
            continue
        if not ok.any():
            raise InputError(f"sensor column {s} has no valid sample", sensor=str(s))
        prev, nxt = _neighbours(ok)
        bad = np.flatnonzero(~ok)
        span = (t[nxt[bad]] - t[prev[bad]])
        frac = np.where(span > 0, (t[bad] - t[prev[bad]]) / np.where(span > 0, span, 1.0), 0.0)
        good = np.flatnonzero(ok)
        interior = (bad > good[0]) & (bad < good[-1])
        if method == "cubic" and good.size >= 4:
            spline = CubicSpline(t[good], pos[good, s])
            pos[bad, s] = np.where(interior[:, None], spline(t[bad]), pos[prev[bad], s])
        else:
            p0, p1 = pos[prev[bad], s], pos[nxt[bad], s]
            pos[bad, s] = p0 + frac[:, None] * (p1 - p0)
        r0 = Rotation.from_quat(quat[prev[bad], s], scalar_first=True)
        r1 = Rotation.from_quat(quat[nxt[bad], s], scalar_first=True)
        step = Rotation.from_rotvec(frac[:, None] * (r0.inv() * r1).as_rotvec())
        quat[bad, s] = (r0 * step).as_quat(scalar_first=True)
    filled = ~valid
    if single:
        return pos[:, 0], quat[:, 0], filled[:, 0]
    return pos, quat, filled
