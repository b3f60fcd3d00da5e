"""Vectorised rotation helpers on scalar-first quaternion arrays ``(..., 4)`` = ``(w, x, y, z)``.

``scipy.spatial.transform.Rotation`` stays the project's rotation type (conversions, single
rotations, public signatures). On long arrays of rotations some of its operations are slow
in scipy 1.17: for 6,283 rotations, measured here, ``Rotation.__mul__`` takes 2.7–4 ms,
``as_rotvec`` 2.9 ms and ``from_matrix`` 2.1 ms, whereas the numpy expressions below take
0.1–0.35 ms (8–20× faster), and ``as_quat``, ``from_quat``, ``as_matrix`` cost 0.03–0.1 ms.
Hot paths that compose or compare rotations frame by frame therefore work on quaternion
arrays (or on ``(F, 3, 3)`` matrices) with these functions.

Conventions: quaternions are unit, scalar first, and map the body frame to the world frame
like a ``Rotation``; ``q`` and ``−q`` are the same rotation. Every function broadcasts over
the leading axes and returns new arrays.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["angle", "as_matrix", "as_matrix_rows", "as_rotvec", "conjugate", "continuous",
           "continuous_rows", "from_axes",
           "from_axis_rows", "from_matrix", "from_rotvec", "mean", "multiply", "relative",
           "rotate"]

Float = NDArray[np.float64]


def _q(q: ArrayLike) -> Float:
    arr = np.asarray(q, dtype=float)
    if arr.shape[-1:] != (4,):
        raise ValueError(f"quaternions must have shape (..., 4), got {arr.shape}")
    return arr


def multiply(p: ArrayLike, q: ArrayLike) -> Float:
    """Hamilton product ``p ⊗ q``: the rotation ``q`` followed by ``p``.

    Parameters
    ----------
    p, q : array_like, shape (..., 4)
        Scalar-first quaternions (broadcast against each other).

    Returns
    -------
    ndarray, shape (..., 4)
        The same as ``(Rotation(p) * Rotation(q)).as_quat(scalar_first=True)`` up to sign.
    """
    a, b = _q(p), _q(q)
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def conjugate(q: ArrayLike) -> Float:
    """Conjugate ``(w, −x, −y, −z)``: the inverse rotation of a unit quaternion.

    Parameters
    ----------
    q : array_like, shape (..., 4)

    Returns
    -------
    ndarray, shape (..., 4)
    """
    out = np.array(_q(q), dtype=float)
    out[..., 1:] *= -1.0
    return out


def continuous(q: ArrayLike) -> Float:
    """A time series of rotations with each quaternion's sign chosen so that consecutive ones
    lie in the same hemisphere (``q_t · q_{t−1} ≥ 0``): its components then vary smoothly,
    as filters and finite differences need.

    Parameters
    ----------
    q : array_like, shape (F, ..., 4)
        Quaternions, time first (any further leading axes: independent series).

    Returns
    -------
    ndarray, shape (F, ..., 4)
        A copy; the first frame keeps its sign.
    """
    out = np.array(_q(q), dtype=float)
    flips = np.einsum("...i,...i->...", out[1:], out[:-1]) < 0.0
    odd = np.cumsum(flips, axis=0) % 2 == 1
    out[1:][odd] *= -1.0
    return out


def third_difference_median(squared: NDArray[np.float64], valid: NDArray[np.bool_]
                            ) -> float | None:
    """Median of a series' squared third differences (F - 3,) over the windows whose four
    samples are all valid (``valid`` (F,)), or None with 10 such windows or fewer: the white
    noise level of an orientation series, where smooth motion up to quadratic in time cancels
    (``slip.rotation_noise_variance``, ``joints.rotation_noise_variance``)."""
    ok = np.convolve(valid.astype(float), np.ones(4), "valid") > 3.5
    return float(np.median(squared[ok])) if ok.sum() > 10 else None


def continuous_rows(q: NDArray[np.float64]) -> Float:
    """``continuous`` of component-major quaternions (..., 4, F), time last: a copy with
    the sign of each quaternion chosen so that consecutive ones lie in the same hemisphere.
    Every step runs along contiguous rows of frames."""
    out = np.array(q, dtype=float, order="C")
    flips = np.einsum("...ct,...ct->...t", out[..., 1:], out[..., :-1]) < 0.0
    odd = np.cumsum(flips, axis=-1) % 2 == 1
    sign = np.where(odd, -1.0, 1.0)
    out[..., 1:] *= sign[..., None, :]
    return out


def as_matrix_rows(q: NDArray[np.float64], out: Float | None = None) -> Float:
    """``as_matrix`` of unit quaternions given component-major (..., 4, F), also
    component-major: (..., 9, F), row ``3i + j`` the entry (i, j) of every matrix, from
    arithmetic on contiguous rows of frames (into ``out`` when given)."""
    w, x, y, z = (q[..., i, :] for i in range(4))
    if out is None:
        out = np.empty((*q.shape[:-2], 9, q.shape[-1]))
    squares = (x * x, y * y, z * z)
    for e, (i, j) in ((0, (1, 2)), (4, (0, 2)), (8, (0, 1))):
        np.add(squares[i], squares[j], out=out[..., e, :])
        out[..., e, :] *= -2.0
        out[..., e, :] += 1.0
    del squares
    for (e, f), (a, b), (c, d) in (((1, 3), (x, y), (w, z)), ((2, 6), (x, z), (w, y)),
                                   ((5, 7), (y, z), (w, x))):
        product, turn = a * b, c * d
        # (e: product − turn, f: product + turn), each doubled; the sign of the turn flips
        # for the entry below the diagonal except in (0, 2), where it is the other way
        sign = 1.0 if e == 2 else -1.0
        for entry, s in ((e, sign), (f, -sign)):
            np.multiply(turn, s, out=out[..., entry, :])
            out[..., entry, :] += product
            out[..., entry, :] *= 2.0
    return out


# qa⁻¹ ⊗ qb component by component: each a sum, left to right, of a_0 b_k and three signed
# products a_i b_j
_RELATIVE_TERMS = (((1, 1, 1), (2, 2, 1), (3, 3, 1)),
                   ((1, 0, -1), (2, 3, -1), (3, 2, 1)),
                   ((1, 3, 1), (2, 0, -1), (3, 1, -1)),
                   ((1, 2, -1), (2, 1, 1), (3, 0, -1)))


def _components(q: ArrayLike, axis: int) -> Float:
    """``q`` with its four quaternion components along ``axis`` moved to the front."""
    arr = np.asarray(q, dtype=float)
    if axis != 0:
        arr = np.moveaxis(arr, axis, 0)
    if arr.shape[0] != 4:
        raise ValueError(f"quaternions must have 4 components along axis {axis}, got "
                         f"{arr.shape[0]}")
    return arr


def relative(qa: ArrayLike, qb: ArrayLike, axis: int = -1) -> Float:
    """Rotation of body b in body a's frame, ``qa⁻¹ ⊗ qb`` (``Ra.inv() * Rb``).

    Parameters
    ----------
    qa, qb : array_like, shape (..., 4)
        Body → world rotations (broadcast against each other), components along ``axis``.
    axis : int, default -1
        Axis of ``qa``, ``qb`` and the result that holds the four components (``0`` for
        (4, N) rows, on which the products run several times faster).

    Returns
    -------
    ndarray, shape (..., 4)
    """
    a, b = _components(qa, axis), _components(qb, axis)
    shape = np.broadcast_shapes(a.shape[1:], b.shape[1:])
    out = np.empty((4, *shape))
    term = np.empty(shape)  # one scratch row: no temporary per product
    for k, terms in enumerate(_RELATIVE_TERMS):
        row = out[k, ...]  # an array also for single quaternions
        np.multiply(a[0], b[k], out=row)
        for i, j, sign in terms:
            np.multiply(a[i], b[j], out=term)
            (np.add if sign > 0 else np.subtract)(row, term, out=row)
    return _components_back(out, axis)


def _components_back(rows: Float, axis: int) -> Float:
    """``rows`` (components first) with the components moved to ``axis``, C-contiguous."""
    return rows if axis == 0 else np.ascontiguousarray(np.moveaxis(rows, 0, axis))


def relative_matrix(q: Float) -> Float:
    """The matrix ``L`` (4, 4) of ``p ↦ relative(q, p)`` for one quaternion ``q`` (4,), which
    is linear in ``p``: ``relative(q, np.eye(4)).T`` up to the sign of zeros, without its
    dozen small ufunc calls. One (4, 4) × (4, N) product then applies ``q⁻¹`` to N
    quaternions stored as rows."""
    w, x, y, z = q
    return np.array([[w, x, y, z], [-x, w, z, -y], [-y, -z, w, x], [-z, y, -x, w]])


def rotate(q: ArrayLike, v: ArrayLike) -> Float:
    """Apply rotations to vectors, ``R(q) v`` (``Rotation.apply``).

    Parameters
    ----------
    q : array_like, shape (..., 4)
        Unit quaternions.
    v : array_like, shape (..., 3)
        Vectors (broadcast against ``q``'s leading axes).

    Returns
    -------
    ndarray, shape (..., 3)
        ``v + 2w (u × v) + 2 u × (u × v)`` with ``u`` the vector part of ``q``.
    """
    qq = _q(q)
    vec = np.asarray(v, dtype=float)
    u = qq[..., 1:]
    t = 2.0 * np.cross(u, vec)
    return np.asarray(vec + qq[..., :1] * t + np.cross(u, t))


def as_matrix(q: ArrayLike) -> Float:
    """Rotation matrices of unit quaternions.

    Parameters
    ----------
    q : array_like, shape (..., 4)

    Returns
    -------
    ndarray, shape (..., 3, 3)
        Body → world matrices (columns are the body axes in the world frame).
    """
    qq = _q(q)
    w, x, y, z = qq[..., 0], qq[..., 1], qq[..., 2], qq[..., 3]
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz, wx, wy, wz = x * y, x * z, y * z, w * x, w * y, w * z
    rows = [1.0 - 2.0 * (yy + zz), 2.0 * (xy - wz), 2.0 * (xz + wy),
            2.0 * (xy + wz), 1.0 - 2.0 * (xx + zz), 2.0 * (yz - wx),
            2.0 * (xz - wy), 2.0 * (yz + wx), 1.0 - 2.0 * (xx + yy)]
    return np.stack(rows, axis=-1).reshape(*qq.shape[:-1], 3, 3)


def from_matrix(m: ArrayLike) -> Float:
    """Unit quaternions of rotation matrices that are orthonormal by construction.

    Parameters
    ----------
    m : array_like, shape (..., 3, 3)
        Proper rotation matrices. They are not re-orthogonalised (``Rotation.from_matrix``
        does that, at 2 ms per 6,283 matrices); a skewed matrix gives a nearby rotation.

    Returns
    -------
    ndarray, shape (..., 4)
        Scalar-first, normalised, with ``w ≥ 0``.

    Notes
    -----
    Shepperd's method (J. Guidance Control 1(3):223–224, 1978): each quaternion is computed
    from the largest of ``w², x², y², z²``, which keeps it accurate for every rotation.
    """
    mm = np.asarray(m, dtype=float)
    if mm.shape[-2:] != (3, 3):
        raise ValueError(f"matrices must have shape (..., 3, 3), got {mm.shape}")
    return _shepperd(tuple(mm.reshape(-1, 9).T)).reshape(*mm.shape[:-2], 4)


def from_axes(x: ArrayLike, y: ArrayLike, z: ArrayLike) -> Float:
    """Unit quaternions of the rotations whose body axes are ``x``, ``y``, ``z``.

    Parameters
    ----------
    x, y, z : array_like, shape (..., 3)
        The body axes in the world frame (the columns of the rotation matrix), orthonormal
        and right-handed by construction.

    Returns
    -------
    ndarray, shape (..., 4)
        ``from_matrix`` of the matrix with these columns, without building it.
    """
    xx, yy, zz = (np.asarray(v, dtype=float) for v in (x, y, z))
    m00, m10, m20 = (xx[..., k].reshape(-1) for k in range(3))
    m01, m11, m21 = (yy[..., k].reshape(-1) for k in range(3))
    m02, m12, m22 = (zz[..., k].reshape(-1) for k in range(3))
    entries = (m00, m01, m02, m10, m11, m12, m20, m21, m22)
    return _shepperd(entries).reshape(*xx.shape[:-1], 4)


def from_axis_rows(x: ArrayLike, y: ArrayLike, z: ArrayLike, *,
                   out: Float | None = None) -> Float:
    """``from_axes`` of axes given component-major, as rows.

    Parameters
    ----------
    x, y, z : array_like, shape (3, N)
        The body axes in the world frame, a row per component (orthonormal and right-handed
        by construction).
    out : ndarray, shape (N, 4), optional
        Where to write the result.

    Returns
    -------
    ndarray, shape (N, 4)
        The same values as ``from_axes(x.T, y.T, z.T)``.
    """
    xx, yy, zz = (np.asarray(v, dtype=float) for v in (x, y, z))
    if not xx.shape == yy.shape == zz.shape or xx.ndim != 2 or xx.shape[0] != 3:
        raise ValueError(f"axes must be (3, N) rows, got {xx.shape}, {yy.shape}, {zz.shape}")
    return _shepperd((xx[0], yy[0], zz[0], xx[1], yy[1], zz[1], xx[2], yy[2], zz[2]), out=out)


def _shepperd(entries: tuple[Float, ...], out: Float | None = None) -> Float:
    """(N, 4) quaternions from the nine (N,) matrix entries, row by row (into ``out`` if
    given)."""
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = entries
    # 4·(w², x², y², z²) on the diagonal of 4 q qᵀ; each of its rows is a multiple of q,
    # and the row of the largest diagonal entry is the accurate one. Steps run in place
    # (a new array per step costs about as much as the arithmetic)
    plus, minus = 1.0 + m00, 1.0 - m00
    d0 = plus + m11
    d0 += m22
    d1 = plus - m11
    d1 -= m22
    d2 = minus + m11
    d2 -= m22
    d3 = minus - m11
    d3 += m22
    wx, wy, wz = m21 - m12, m02 - m20, m10 - m01
    xy, xz, yz = m01 + m10, m02 + m20, m12 + m21
    p1 = (d1 > d0) & (d1 >= d2) & (d1 >= d3)
    p2 = ~p1 & (d2 > d0) & (d2 >= d3)
    p3 = ~p1 & ~p2 & (d3 > d0)
    # (4, N) rows, each the row of 4 q qᵀ chosen per matrix by masked copies: successive
    # frames of a motion mostly choose the same row, and then these take half the time of
    # nested np.where (on rotations in random order, twice as long)
    q = np.empty((4, d0.shape[0]))
    for row, candidates in zip(q, ((d0, wx, wy, wz), (wx, d1, xy, xz), (wy, xy, d2, yz),
                                   (wz, xz, yz, d3)), strict=True):
        np.copyto(row, candidates[0])
        for chosen, value in zip((p1, p2, p3), candidates[1:], strict=True):
            np.copyto(row, value, where=chosen)
    norm = np.sqrt(np.einsum("ij,ij->j", q, q))
    # normalised through a transposed view of the (N, 4) result: scaling (N, 4) rows by a
    # per-row factor broadcasts over a length-4 axis, which numpy loops over slowly
    if out is None:
        out = np.empty((d0.shape[0], 4))
    np.divide(q, np.copysign(norm, q[0], out=norm), out=out.T)
    return out


def angle(q: ArrayLike) -> Float:
    """Rotation angle of each quaternion, radians in ``[0, π]``.

    Parameters
    ----------
    q : array_like, shape (..., 4)

    Returns
    -------
    ndarray, shape (...)
        ``2 atan2(|(x, y, z)|, |w|)`` (the same as ``Rotation.magnitude()``; accurate near 0
        and π, unlike ``2 arccos|w|``).
    """
    qq = _q(q)
    s = np.sqrt(np.einsum("...i,...i->...", qq[..., 1:], qq[..., 1:]))
    return np.asarray(2.0 * np.arctan2(s, np.abs(qq[..., 0])))


def as_rotvec(q: ArrayLike, axis: int = -1) -> Float:
    """Rotation vectors (axis × angle, radians) of unit quaternions (``Rotation.as_rotvec``).

    Parameters
    ----------
    q : array_like, shape (..., 4)
        Unit quaternions, components along ``axis``.
    axis : int, default -1
        Axis of ``q`` that holds the four components (``0`` for (4, N) rows: numpy loops over
        the last axis, so per-rotation arithmetic on rows runs several times faster).

    Returns
    -------
    ndarray
        Rotation vectors, the three components along ``axis``; angles in ``[0, π]``.
    """
    arr = _components(q, axis)
    w, v = arr[0], arr[1:]
    s = v[0] * v[0]
    term = v[1] * v[1]
    s += term
    np.multiply(v[2], v[2], out=term)
    s += term
    np.sqrt(s, out=s)
    theta = np.abs(w, out=term)
    np.arctan2(s, theta, out=theta)
    theta *= 2.0
    # θ / sin(θ/2) = θ / |v| for a unit quaternion: no cancellation at small angles, where
    # atan2 keeps θ accurate; the sign turns q into the w ≥ 0 representative. Selected by
    # np.where rather than computed under ufuncs' ``where=`` masks, whose buffered loops took
    # a third of the function (the same values, bit for bit)
    # (where every rotation turns, or every or no w < 0, as in most calls, a selection
    # would pick one side only: skipped, the same values)
    turning = s > 0
    if turning.all():
        scale = np.divide(theta, s, out=theta)
    else:
        np.divide(theta, np.where(turning, s, 1.0), out=theta)
        scale = np.where(turning, theta, 2.0)
    negative = w < 0
    if negative.all():
        np.negative(scale, out=scale)
    elif negative.any():
        scale = np.where(negative, -scale, scale)
    return _components_back(v * scale, axis)


def from_rotvec(v: ArrayLike) -> Float:
    """Unit quaternions of rotation vectors (``Rotation.from_rotvec``).

    Parameters
    ----------
    v : array_like, shape (..., 3)
        Axis × angle, radians.

    Returns
    -------
    ndarray, shape (..., 4)
        ``(cos(θ/2), sin(θ/2) v/θ)``.
    """
    vec = np.asarray(v, dtype=float)
    if vec.shape[-1:] != (3,):
        raise ValueError(f"rotation vectors must have shape (..., 3), got {vec.shape}")
    theta = np.sqrt(np.einsum("...i,...i->...", vec, vec))
    # sin(θ/2)/θ, with its series below 1e-4 rad (the selection skipped without any)
    small = theta < 1e-4
    if small.any():
        safe = np.where(small, 1.0, theta)
        scale = np.where(small, 0.5 - theta * theta / 48.0, np.sin(0.5 * theta) / safe)
    else:
        scale = np.sin(0.5 * theta) / theta
    return np.concatenate([np.cos(0.5 * theta)[..., None], vec * scale[..., None]], axis=-1)


def mean(q: ArrayLike, weights: ArrayLike | None = None) -> Float:
    """Chordal L2 mean of rotations (``Rotation.mean``).

    Parameters
    ----------
    q : array_like, shape (N, 4)
        Unit quaternions.
    weights : array_like, shape (N,), optional
        Non-negative weights.

    Returns
    -------
    ndarray, shape (4,)
        The unit eigenvector of ``Σ w_i q_i q_iᵀ`` with the largest eigenvalue, ``w ≥ 0``.

    Notes
    -----
    Markley, Cheng, Crassidis & Oshman, "Averaging quaternions", J. Guidance Control Dyn.
    30(4):1193–1197, 2007. Independent of the sign of each ``q_i``.
    """
    qq = _q(q).reshape(-1, 4)
    k = qq.T @ qq if weights is None else (qq * np.asarray(weights, dtype=float)[:, None]).T @ qq
    _, vecs = np.linalg.eigh(k)
    out = vecs[:, -1]
    return np.asarray(out if out[0] >= 0 else -out)
