"""Quaternion-array helpers (bonefit.estimation.quaternions) against scipy's Rotation."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from bonefit.estimation import _rows as rows
from bonefit.estimation import quaternions as quat


def _same_rotation(p: NDArray[np.float64], q: NDArray[np.float64], atol: float = 1e-12) -> None:
    """Equal up to the sign of each quaternion."""
    dot = np.abs(np.einsum("...i,...i->...", p, q))
    np.testing.assert_allclose(dot, 1.0, atol=atol)


@pytest.fixture
def rots() -> tuple[Rotation, Rotation]:
    a = Rotation.random(500, rng=np.random.default_rng(1))
    b = Rotation.random(500, rng=np.random.default_rng(2))
    return a, b


def _wxyz(r: Rotation) -> NDArray[np.float64]:
    return np.asarray(r.as_quat(scalar_first=True))


def test_multiply_conjugate_relative_match_scipy(rots: tuple[Rotation, Rotation]) -> None:
    a, b = rots
    _same_rotation(quat.multiply(_wxyz(a), _wxyz(b)), _wxyz(a * b))
    _same_rotation(quat.conjugate(_wxyz(a)), _wxyz(a.inv()))
    _same_rotation(quat.relative(_wxyz(a), _wxyz(b)), _wxyz(a.inv() * b))
    # one rotation against many broadcasts
    _same_rotation(quat.multiply(_wxyz(a[0]), _wxyz(b)), _wxyz(a[0] * b))


def test_rotate_and_matrix_match_scipy(rots: tuple[Rotation, Rotation]) -> None:
    a, _ = rots
    v = np.random.default_rng(3).normal(size=(500, 3))
    np.testing.assert_allclose(quat.rotate(_wxyz(a), v), a.apply(v), atol=1e-12)
    np.testing.assert_allclose(quat.rotate(_wxyz(a), v[0]), a.apply(v[0]), atol=1e-12)
    np.testing.assert_allclose(quat.as_matrix(_wxyz(a)), a.as_matrix(), atol=1e-12)
    np.testing.assert_allclose(quat.as_matrix(_wxyz(a)[:7].reshape(7, 1, 4)),
                               a[:7].as_matrix()[:, None], atol=1e-12)


def test_from_matrix_round_trip_including_half_turns(rots: tuple[Rotation, Rotation]) -> None:
    a, _ = rots
    # every branch of Shepperd's method: identity-like, and half turns about x, y and z
    special = Rotation.from_rotvec(np.array([[0, 0, 0], [np.pi, 0, 0], [0, np.pi, 0],
                                             [0, 0, np.pi], [1e-9, 0, 0],
                                             [np.pi - 1e-9, 0, 0]], dtype=float))
    axes = np.random.default_rng(5).normal(size=(200, 3))
    half_turns = Rotation.from_rotvec(np.pi * axes / np.linalg.norm(axes, axis=1)[:, None])
    for r in (a, special, half_turns):
        q = quat.from_matrix(r.as_matrix())
        assert np.all(q[:, 0] >= 0)
        np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-14)
        _same_rotation(q, _wxyz(r))
        m = r.as_matrix()
        np.testing.assert_array_equal(quat.from_axes(m[..., 0], m[..., 1], m[..., 2]), q)
    assert quat.from_matrix(np.eye(3)).shape == (4,)
    assert quat.from_axes(*np.eye(3)).shape == (4,)


def test_from_axis_rows_matches_scipy_and_writes_into_out(
        rots: tuple[Rotation, Rotation]) -> None:
    a, _ = rots
    m = a.as_matrix()
    x, y, z = (np.ascontiguousarray(m[..., k].T) for k in range(3))
    q = quat.from_axis_rows(x, y, z)
    assert q.shape == (500, 4)
    assert np.all(q[:, 0] >= 0)
    _same_rotation(q, _wxyz(a))
    np.testing.assert_array_equal(q, quat.from_axes(m[..., 0], m[..., 1], m[..., 2]))
    block = np.zeros((2, 500, 4))
    out = block[1]
    assert quat.from_axis_rows(x, y, z, out=out) is out
    np.testing.assert_array_equal(block[1], q)
    assert not block[0].any()
    with pytest.raises(ValueError, match="rows"):
        quat.from_axis_rows(x.T, y.T, z.T)


def test_angle_and_rotvec_match_scipy(rots: tuple[Rotation, Rotation]) -> None:
    a, b = rots
    rel = a.inv() * b
    np.testing.assert_allclose(quat.angle(_wxyz(rel)), rel.magnitude(), atol=1e-12)
    np.testing.assert_allclose(quat.as_rotvec(_wxyz(rel)), rel.as_rotvec(), atol=1e-12)
    # components along the first axis: (4, N) in, (3, N) out
    np.testing.assert_allclose(quat.as_rotvec(_wxyz(rel).T, axis=0), rel.as_rotvec().T,
                               atol=1e-12)
    with pytest.raises(ValueError, match="4 components along axis 0"):
        quat.as_rotvec(_wxyz(rel), axis=0)
    # sign of q does not matter; small angles keep their digits
    tiny = Rotation.from_rotvec([[1e-9, -2e-9, 3e-9], [0.0, 0.0, 0.0], [0.0, 2e-5, 0.0]])
    np.testing.assert_allclose(quat.as_rotvec(-_wxyz(tiny)), tiny.as_rotvec(), rtol=1e-9,
                               atol=1e-20)
    np.testing.assert_allclose(quat.angle(-_wxyz(tiny)), tiny.magnitude(), rtol=1e-9,
                               atol=1e-20)
    for r in (rel, tiny):
        _same_rotation(quat.from_rotvec(r.as_rotvec()), _wxyz(r))
        np.testing.assert_allclose(quat.as_rotvec(quat.from_rotvec(r.as_rotvec())),
                                   r.as_rotvec(), atol=1e-12)


def test_mean_matches_scipy(rots: tuple[Rotation, Rotation]) -> None:
    a, _ = rots
    near = Rotation.from_rotvec([0.3, -0.2, 0.5]) * Rotation.from_rotvec(
        np.random.default_rng(4).normal(scale=0.2, size=(300, 3)))
    for r in (a, near):
        q = _wxyz(r)
        q[::2] *= -1.0  # the mean ignores each quaternion's sign
        _same_rotation(quat.mean(q), _wxyz(r.mean()), atol=1e-10)
    w = np.linspace(0.0, 1.0, 300)
    _same_rotation(quat.mean(_wxyz(near), w), _wxyz(near.mean(weights=w)), atol=1e-10)


def test_shape_errors() -> None:
    with pytest.raises(ValueError, match=r"\(\.\.\., 4\)"):
        quat.multiply(np.zeros((2, 3)), np.zeros((2, 4)))
    with pytest.raises(ValueError, match=r"\(\.\.\., 3, 3\)"):
        quat.from_matrix(np.zeros((2, 3)))


def test_continuous_keeps_consecutive_quaternions_in_one_hemisphere() -> None:
    q = _wxyz(Rotation.from_rotvec(np.outer(np.linspace(0.0, 3.0, 40), [0.3, -1.0, 0.5])))
    flipped = q * np.where(np.random.default_rng(2).random(40) < 0.5, -1.0, 1.0)[:, None]
    got = quat.continuous(flipped)
    assert np.all(np.einsum("ti,ti->t", got[1:], got[:-1]) > 0.0)
    np.testing.assert_allclose(np.abs(np.einsum("ti,ti->t", got, q)), 1.0, atol=1e-12)
    np.testing.assert_array_equal(got[0], flipped[0])
    # independent series on a further axis: (F, S, 4)
    both = quat.continuous(np.stack([flipped, -flipped], axis=1))
    np.testing.assert_array_equal(both[:, 0], got)
    np.testing.assert_array_equal(both[:, 1], -got)


def test_row_helpers_for_rotation_matrices_match_scipy() -> None:
    """``_rows.apply_each`` and ``_rows.sum_transposed``."""
    upper = Rotation.random(50, rng=3)
    v = np.random.default_rng(5).normal(size=(50, 3))
    np.testing.assert_allclose(rows.apply_each(upper.as_matrix(), v), upper.apply(v),
                               atol=1e-14)
    # a transposed view (strided columns)
    np.testing.assert_allclose(rows.apply_each(upper.as_matrix().transpose(0, 2, 1), v),
                               upper.inv().apply(v), atol=1e-14)
    np.testing.assert_allclose(rows.sum_transposed(upper.as_matrix(), v),
                               upper.inv().apply(v).sum(axis=0), atol=1e-13)


def test_relative_on_component_rows_and_as_a_matrix(rots: tuple[Rotation, Rotation]) -> None:
    """``relative(..., axis=0)`` on (4, N) rows equals the (N, 4) result bit for bit, and
    ``relative_matrix(q) @ p`` is ``relative(q, p)``."""
    a, b = _wxyz(rots[0]), _wxyz(rots[1])
    np.testing.assert_array_equal(quat.relative(a.T, b.T, axis=0), quat.relative(a, b).T)
    np.testing.assert_array_equal(quat.relative(a[0], b[1]), quat.relative(a[:1], b[1:2])[0])
    np.testing.assert_allclose(quat.relative_matrix(a[0]) @ b.T, quat.relative(a[0], b).T,
                               atol=1e-15)
    with pytest.raises(ValueError, match="4 components along axis 0"):
        quat.relative(a, b, axis=0)


def test_row_helpers_transform_and_sum_of_matrix_products() -> None:
    """``_rows.transform`` (m[t] v + p[t], optionally into ``out``) and ``_rows.sum_transposed``
    of two stacks of matrices (Σ m[t]ᵀ n[t])."""
    m, n = Rotation.random(50, rng=6).as_matrix(), Rotation.random(50, rng=7).as_matrix()
    rng = np.random.default_rng(8)
    v, p = rng.normal(size=3), rng.normal(size=(50, 3))
    expected = np.einsum("tij,j->ti", m, v) + p
    np.testing.assert_allclose(rows.transform(m, v, p), expected, atol=1e-14)
    out = np.empty((50, 3))
    into = rows.transform(m, v, p, out=out)
    assert np.shares_memory(into, out)
    np.testing.assert_allclose(out, expected, atol=1e-14)
    np.testing.assert_allclose(rows.sum_transposed(m, n), np.einsum("tji,tjk->ik", m, n),
                               atol=1e-13)


def test_apply_and_sum_transposed_on_contiguous_stacks_and_on_views() -> None:
    """``_rows.apply`` (m[t] v): the BLAS path of a C-contiguous stack (also with more
    leading axes) and the strided path of a transposed view give ``m[t] @ v``."""
    m = Rotation.random(60, rng=9).as_matrix()
    v = np.random.default_rng(10).normal(size=3)
    np.testing.assert_allclose(rows.apply(m, v), np.einsum("tij,j->ti", m, v), atol=1e-14)
    view = m.transpose(0, 2, 1)
    np.testing.assert_allclose(rows.apply(view, v), np.einsum("tji,j->ti", m, v), atol=1e-14)
    stacked = m.reshape(4, 15, 3, 3)
    got = rows.apply(stacked, v)
    assert got.shape == (4, 15, 3)
    np.testing.assert_allclose(got, np.einsum("stij,j->sti", stacked, v), atol=1e-14)
    # sum_transposed of two stacks: the Gram path (contiguous) and the strided one (a view)
    n = Rotation.random(60, rng=11).as_matrix()
    np.testing.assert_allclose(rows.sum_transposed(m, n), np.einsum("tji,tjk->ik", m, n),
                               atol=1e-13)
    np.testing.assert_allclose(rows.sum_transposed(view, n), np.einsum("tij,tjk->ik", m, n),
                               atol=1e-13)
