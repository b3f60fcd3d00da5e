"""Filling dropped samples (NaN) in sensor pose streams."""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from . import _rows as rows
from .errors import InputError
from .quaternions import as_rotvec, from_rotvec, multiply, relative


def sensor_major(samples: NDArray[np.float64], columns: Sequence[int]) -> NDArray[np.float64]:
    """A sensor-major copy of some sensors' samples.

    Parameters
    ----------
    samples : ndarray, shape (F, S, K)
        Per-frame samples of S sensors (positions: K = 3, quaternions: K = 4).
    columns : sequence of int
        The sensors to copy, in order.

    Returns
    -------
    ndarray, shape (len(columns), F, K)
        A new C-contiguous float64 array: each sensor's samples are contiguous.
    """
    arr = np.ascontiguousarray(samples, dtype=float)
    # each K-vector copied as one opaque item: twice as fast as numpy's fancy indexing of
    # the float array, which copies element by element
    items = arr.view(np.dtype((np.void, arr.itemsize * arr.shape[2]))).reshape(arr.shape[:2])
    out = items.T[list(columns)]
    return out.view(np.float64).reshape(len(columns), arr.shape[0], arr.shape[2])


def component_major(samples: NDArray[np.float64], columns: Sequence[int],
                    out: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """A component-major copy of some sensors' samples.

    Parameters
    ----------
    samples : ndarray, shape (F, S, K)
        Per-frame samples of S sensors (quaternions: K = 4).
    columns : sequence of int
        The sensors to copy, in order.
    out : ndarray, shape (len(columns), K, F), optional
        float64 array to copy into (for instance the first K rows of each sensor's block
        of a larger array); returned.

    Returns
    -------
    ndarray, shape (len(columns), K, F)
        A new C-contiguous float64 array (or ``out``): each component of each sensor is one
        contiguous row, so that per-sample arithmetic on the components runs on whole rows.
    """
    cols = list(columns)
    arr = np.asarray(samples)
    if cols != list(range(arr.shape[1])):
        arr = np.take(arr, cols, axis=1)
    if out is None:
        return np.array(arr.transpose(1, 2, 0), dtype=float, order="C")
    np.copyto(out, arr.transpose(1, 2, 0))
    return out


class FilledGaps(NamedTuple):
    """Where samples of sensor-major pose streams were dropped (``fill_sensor_major``)."""

    valid: NDArray[np.bool_]  # (S, F) measured samples
    longest: NDArray[np.intp]  # (S,) each sensor's longest run of dropped samples, frames
    norms2: NDArray[np.float64]  # (S, F) squared norms of the quaternions, after filling,
    # summed as scipy does (x² + y² + z² + w²): dividing by their roots gives the unit
    # quaternions of ``Rotation.from_quat`` bit for bit


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
    single = positions.ndim == 2
    if single:
        positions, quaternions = positions[:, None], quaternions[:, None]
    every = range(positions.shape[1])
    pos, quat = sensor_major(positions, every), component_major(quaternions, every)
    filled = ~fill_sensor_major(pos, quat, time=time, method=method).valid
    if single:
        return pos[0], quat[0].T, filled[0]
    return pos.swapaxes(0, 1), quat.transpose(2, 0, 1), filled.T


def fill_sensor_major(
    positions: NDArray[np.float64],
    quaternions: NDArray[np.float64],
    *,
    time: NDArray[np.float64] | None = None,
    method: str = "cubic",
) -> FilledGaps:
    """``fill_gaps`` in place, without copying, on the layouts of ``sensor_major`` and
    ``component_major``.

    Parameters
    ----------
    positions : ndarray, shape (S, F, 3)
        C-contiguous float64 positions, NaN where dropped; filled in place.
    quaternions : ndarray, shape (S, 4, F)
        float64 scalar-first rotations, component-major (each sensor's (4, F) block
        C-contiguous, as in ``component_major``'s result or the first four rows of each
        block of an (S, 5, F) array), NaN where dropped; filled in place.
    time, method
        As for ``fill_gaps``.

    Returns
    -------
    FilledGaps
        The measured samples, each sensor's longest gap and the quaternions' squared norms.

    Raises
    ------
    InputError
        If a sensor has no valid sample at all (``sensor`` is its index along axis 0).
    """
    if method not in ("cubic", "linear"):
        raise InputError(f"unknown gap-filling method {method!r}", field="method")
    for arr, layout in ((positions, positions), (quaternions, quaternions[0])):
        if arr.dtype != np.float64 or not layout.flags.c_contiguous:
            raise ValueError("fill_sensor_major fills C-contiguous float64 arrays (for the "
                             "quaternions: blocks per sensor) in place")
    n_sensors, n_frames = positions.shape[:2]
    t = np.arange(n_frames, dtype=float) if time is None else np.asarray(time, dtype=float)
    valid, norms2 = _measured(positions, quaternions)
    longest = np.zeros(n_sensors, dtype=np.intp)
    gaps = _Gaps.of(valid)
    if gaps is None:
        return FilledGaps(valid, longest, norms2)
    np.maximum.at(longest, gaps.run_sensor, gaps.hi - gaps.lo - 1)
    span = t[gaps.i1] - t[gaps.i0]
    frac = np.where(span > 0, (t[gaps.frame] - t[gaps.i0]) / np.where(span > 0, span, 1.0),
                    0.0)
    _fill_positions(positions, gaps, t, frac, method)
    _fill_quaternions(quaternions, norms2, gaps, frac)
    return FilledGaps(valid, longest, norms2)


def _measured(positions: NDArray[np.float64], quaternions: NDArray[np.float64]
              ) -> tuple[NDArray[np.bool_], NDArray[np.float64]]:
    """Measured samples (S, F) of sensor-major positions and component-major quaternions,
    and the quaternions' squared norms (S, F); InputError naming a sensor with none."""
    # isfinite of each component straight into the mask: half the time of one isfinite
    # over the whole (S, F, 3) block followed by three strided ands
    valid = rows.finite(positions)
    # the quaternions' squared norms tell most: a NaN component makes them NaN, which
    # compares False; an infinite one makes them infinite, as does (hardly ever) the
    # overflow of finite ones, so those few samples are checked component by component
    norms2 = _norms2(*quaternions.transpose(1, 0, 2))
    valid &= norms2 > 1e-18
    infinite = norms2 == np.inf
    if infinite.any():  # np.nonzero of the (S, F) mask: 0.14 ms for 11 × 6,283 samples
        sensor_inf, frame_inf = np.nonzero(infinite)
        valid[sensor_inf, frame_inf] &= rows.finite(quaternions[sensor_inf, :, frame_inf])
    empty = ~valid.any(axis=1)
    if empty.any():
        s = int(np.flatnonzero(empty)[0])
        raise InputError(f"sensor column {s} has no valid sample", sensor=str(s))
    return valid, norms2


class _Gaps(NamedTuple):
    """The dropped samples of sensor-major streams and the runs they form.

    Per dropped sample (sensor-major order): ``bad`` its flat index, ``sensor``, ``frame``,
    ``run`` its run, ``i0``/``i1`` the valid samples it is interpolated between (the same
    one outside the valid range) and ``interior`` whether it has valid samples on both
    sides. Per run: ``run_sensor`` and the bracketing frames ``lo = first − 1`` and
    ``hi = last + 1`` (−1, F: none)."""

    bad: NDArray[np.intp]
    sensor: NDArray[np.intp]
    frame: NDArray[np.intp]
    run: NDArray[np.intp]
    run_sensor: NDArray[np.intp]
    lo: NDArray[np.intp]
    hi: NDArray[np.intp]
    i0: NDArray[np.intp]
    i1: NDArray[np.intp]
    interior: NDArray[np.bool_]

    @classmethod
    def of(cls, valid: NDArray[np.bool_]) -> _Gaps | None:
        """The gaps of ``valid`` (S, F); None without any."""
        n_frames = valid.shape[1]
        bad = np.flatnonzero(~valid.reshape(-1))
        if bad.size == 0:
            return None
        sensor, frame = np.divmod(bad, n_frames)
        starts = np.ones(bad.size, dtype=bool)
        starts[1:] = (bad[1:] != bad[:-1] + 1) | (sensor[1:] != sensor[:-1])
        run = np.cumsum(starts) - 1
        lo = frame[starts] - 1
        hi = frame[np.append(starts[1:], True)] + 1
        i0, i1 = lo[run], hi[run]
        interior = (i0 >= 0) & (i1 < n_frames)
        # outside the valid range, repeat the nearest valid sample
        i0 = np.where(i0 < 0, i1, i0)
        i1 = np.where(i1 >= n_frames, i0, i1)
        return cls(bad, sensor, frame, run, sensor[starts], lo, hi, i0, i1, interior)


def _fill_positions(positions: NDArray[np.float64], gaps: _Gaps, t: NDArray[np.float64],
                    frac: NDArray[np.float64], method: str) -> None:
    """Fill the dropped positions (S, F, 3) in place: linearly at ``frac`` between the
    bracketing samples, or (``"cubic"``) by the cubic through two valid samples each side
    of an interior gap where there are two."""
    n_frames = positions.shape[1]
    pos = positions.reshape(-1, 3)
    # each sample's 3 floats gathered and scattered as one opaque item: a third less time
    # than row indexing, the same bytes
    items = pos.view(np.dtype((np.void, 24)))[:, 0]
    base = gaps.sensor * n_frames
    p0, p1 = (items[base + i].view(np.float64).reshape(-1, 3) for i in (gaps.i0, gaps.i1))
    filled_pos = p0 + frac[:, None] * (p1 - p0)
    if method == "cubic":
        before, after = _outer_knots(gaps, n_frames)
        cubic = (before >= 0) & (after < n_frames)
        if cubic.any():
            knots = np.stack([before[cubic], gaps.i0[cubic], gaps.i1[cubic], after[cubic]],
                             axis=1)
            knots_p = items[base[cubic, None] + knots].view(np.float64).reshape(-1, 4, 3)
            filled_pos[cubic] = _lagrange(t[knots], knots_p, t[gaps.frame[cubic]])
    items[gaps.bad] = filled_pos.view(items.dtype)[:, 0]


def _outer_knots(gaps: _Gaps, n_frames: int) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Per dropped sample, the valid samples before ``i0`` and after ``i1`` (−1 and
    ``n_frames`` outside an interior gap).

    Local cubics through two valid samples each side of the gap: one vectorised step for
    all sensors instead of a global spline per sensor. The valid sample before lo is
    lo − 1 unless that was dropped: then the previous run of the sensor ends there, and its
    own lo is the one."""
    lo, hi, run_sensor = gaps.lo, gaps.hi, gaps.run_sensor
    same_prev = np.zeros(lo.size, dtype=bool)
    same_prev[1:] = (run_sensor[1:] == run_sensor[:-1]) & (hi[:-1] == lo[1:])
    before_run = np.where(same_prev, np.roll(lo, 1), lo - 1)
    same_next = np.zeros(hi.size, dtype=bool)
    same_next[:-1] = same_prev[1:]
    after_run = np.where(same_next, np.roll(hi, -1), hi + 1)
    before = np.where(gaps.interior, before_run[gaps.run], -1)
    after = np.where(gaps.interior, after_run[gaps.run], n_frames)
    return before, after


def _fill_quaternions(quaternions: NDArray[np.float64], norms2: NDArray[np.float64],
                      gaps: _Gaps, frac: NDArray[np.float64]) -> None:
    """Fill the dropped quaternions (S, 4, F) in place by Slerp at ``frac`` between the
    bracketing samples, and their squared norms (S, F)."""
    sensor, frame = gaps.sensor, gaps.frame
    # the bracketing quaternions gathered as (4, G) rows, on which the relative rotation
    # and its rotation vector run without moving their components (the same arithmetic)
    q0, q1 = (quaternions.transpose(1, 0, 2)[:, sensor, i] for i in (gaps.i0, gaps.i1))
    q0 /= rows.norms(q0.T)
    q1 /= rows.norms(q1.T)
    rotvec = as_rotvec(relative(q0, q1, axis=0), axis=0)
    # as C-contiguous (G, 3) rows: from_rotvec's einsum sums a transposed view otherwise,
    # with other roundings
    step = np.multiply(frac[:, None], rotvec.T, order="C")
    filled_quat = multiply(q0.T, from_rotvec(step))
    quaternions[sensor, :, frame] = filled_quat
    norms2[sensor, frame] = _norms2(*filled_quat.T)


def _norms2(w: NDArray[np.float64], x: NDArray[np.float64], y: NDArray[np.float64],
            z: NDArray[np.float64]) -> NDArray[np.float64]:
    """``x² + y² + z² + w²`` of quaternions given by their components, in that order (the
    same sums as the expression, in two arrays instead of seven: on 11 sensors × 6,283
    frames each new one is 550 kB of fresh memory)."""
    out = np.multiply(x, x)
    square = np.multiply(y, y)
    out += square
    out += np.multiply(z, z, out=square)
    out += np.multiply(w, w, out=square)
    return out


def _lagrange(knots_t: NDArray[np.float64], knots_p: NDArray[np.float64],
              t: NDArray[np.float64]) -> NDArray[np.float64]:
    """Cubic through four (time, point) knots per row, evaluated at ``t``.

    ``knots_t`` (G, 4), ``knots_p`` (G, 4, 3), ``t`` (G,) → (G, 3).
    """
    out = np.zeros((t.size, knots_p.shape[-1]))
    ahead = [t - knots_t[:, m] for m in range(4)]  # the same for every k: once each
    for k in range(4):
        f0, f1, f2 = (ahead[m] / (knots_t[:, k] - knots_t[:, m]) for m in range(4) if m != k)
        weight = f0 * f1  # = (1 · f0) · f1, bit for bit
        weight *= f2
        out += weight[:, None] * knots_p[:, k]
    return out
