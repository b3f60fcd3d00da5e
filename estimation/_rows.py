"""Row-wise norms, dot products, finiteness and rotations of (..., 3) and (..., 4) arrays.

numpy reduces a short last axis slowly (``np.linalg.norm(v, axis=-1)`` on 6,000 × 3 takes
three times as long as these column-wise sums, ``np.einsum("fij,j->fi", m, v)`` on 6,000
matrices three times as long as ``apply``), and these run on every frame of every sensor.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def norms(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """Euclidean norm of each row (over the last axis) of ``v``."""
    return np.asarray(np.sqrt(dots(v, v)))


def dots(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Dot product of each row (over the last axis) of ``a`` with that of ``b``.

    Rows of the same shape are multiplied in one pass over all their entries (contiguous:
    7.0 against 9.1 µs for 6,283 × 3) and the products summed over strided columns in the
    same order; a row broadcast against ``a`` (one vector) is multiplied column by column,
    as numpy loops slowly over a short broadcast axis."""
    if a.shape == b.shape and a.shape[-1] > 1:
        products = np.multiply(a, b)
        out = products[..., 0] + products[..., 1]
        for k in range(2, a.shape[-1]):
            out += products[..., k]
        return np.asarray(out)
    out = a[..., 0] * b[..., 0]
    for k in range(1, a.shape[-1]):
        out += a[..., k] * b[..., k]
    return np.asarray(out)


def apply(m: NDArray[np.float64], v: NDArray[np.float64]) -> NDArray[np.float64]:
    """``m @ v`` for each matrix of ``m`` (..., 3, 3) and one vector ``v`` (3,).

    A C-contiguous ``m`` goes to BLAS as one (3F, 3) × (3,) product: one pass over the
    matrices, 0.54 ms for 36,000 frames against 8.2 ms by strided columns (which a
    transposed view still takes: reshaping it would copy)."""
    if m.flags.c_contiguous and m.dtype == np.float64:
        return np.asarray(m.reshape(-1, 3) @ v).reshape(m.shape[:-1])
    out = m[..., 0] * v[0]
    out += m[..., 1] * v[1]
    out += m[..., 2] * v[2]
    return np.asarray(out)


def sum_transposed(m: NDArray[np.float64], v: NDArray[np.float64]) -> NDArray[np.float64]:
    """``Σ_t m[t]ᵀ v[t]`` over matrices ``m`` (F, 3, 3) and rows ``v`` (F, 3), giving (3,),
    or matrices ``v`` (F, 3, 3), giving (3, 3): one product over the stacked rows of every
    ``m[t]``.

    Of two C-contiguous stacks of matrices: the (9, 9) Gram matrix of their flattened
    entries, one (9, F) × (F, 9) product, and the sum of its three diagonal blocks, 0.85 ms
    for 36,000 frames against 4.5 for the (3, 3F) × (3F, 3) product, whose tiny outer
    dimensions BLAS handles slowly."""
    if v.ndim == 3 and m.flags.c_contiguous and v.flags.c_contiguous:
        n = m.shape[0]
        gram = m.reshape(n, 9).T @ v.reshape(n, 9)
        return np.asarray(gram[:3, :3] + gram[3:6, 3:6] + gram[6:, 6:])
    return np.asarray(m.reshape(-1, 3).T @ v.reshape(3 * m.shape[0], *v.shape[2:]))


def transform(m: NDArray[np.float64], v: NDArray[np.float64], p: NDArray[np.float64],
              out: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """``m[t] @ v + p[t]`` for each matrix of ``m`` (F, 3, 3), one vector ``v`` (3,) and rows
    ``p`` (F, 3): one matrix-vector product over the stacked rows of every ``m[t]`` (less
    than half the time of ``apply``), then one addition in place; into ``out`` (F, 3,
    C-contiguous) when given."""
    flat = np.matmul(m.reshape(-1, 3), v, out=None if out is None else out.reshape(-1))
    flat += p.reshape(-1)
    return flat.reshape(-1, 3)


def finite(v: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Whether every value of each row (over the last axis) of ``v`` is finite."""
    ok = np.isfinite(v[..., 0])
    for k in range(1, v.shape[-1]):
        ok &= np.isfinite(v[..., k])
    return ok


def apply_each(m: NDArray[np.float64], v: NDArray[np.float64]) -> NDArray[np.float64]:
    """``m[t] @ v[t]`` for each matrix of ``m`` (F, 3, 3) and row of ``v`` (F, 3).

    Component by component over strided columns: 0.11 ms for 6,283 frames (0.08 for a
    transposed view ``m.transpose(0, 2, 1)``), against 0.17 (0.28) broadcasting over rows
    and 0.19 for ``np.einsum``."""
    out = np.empty((m.shape[0], 3))
    for i in range(3):
        col = out[:, i]
        np.multiply(m[:, i, 0], v[:, 0], out=col)
        col += m[:, i, 1] * v[:, 1]
        col += m[:, i, 2] * v[:, 2]
    return out


def copy_into(out: NDArray[np.float64], v: NDArray[np.float64]) -> None:
    """``out[...] = v`` for (N, K) float64 rows whose entries are contiguous, one row at a
    time as a K × 8-byte item: a copy from a strided column of an (F, S, 3) recording runs
    numpy's inner loop over frames instead of over 3 components (0.18 against 0.30 ms for
    11 sensors of 6,283 frames; the same bytes, NaN included)."""
    item = np.dtype((np.void, 8 * v.shape[-1]))
    if (v.ndim == out.ndim == 2 and v.dtype == out.dtype == np.float64
            and v.strides[-1] == out.strides[-1] == 8 and v.shape == out.shape):
        out.view(item)[:, 0] = v.view(item)[:, 0]
    else:
        out[...] = v
