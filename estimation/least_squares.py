"""Levenberg–Marquardt on small normal equations, for sums of squares over many frames.

The limb fits (``bonefit.estimation.limbs``) minimise sums of squares with 6 or 7 unknowns over
thousands of frames; forming the ``P × P`` normal equations in one pass over the frames and
solving them directly costs less than MINPACK's QR of the full Jacobian at every iteration.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, Final, NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import lapack

__all__ = ["RTOL", "Normal", "levenberg_marquardt", "normal_from_residuals"]

Float = NDArray[np.float64]

Normal = tuple[float, Float, Float] | tuple[float, Float, Float, Float]
"""``(E, g, H[, K])`` at a point: the cost, ``g = Jᵀr`` (half its gradient), ``H = JᵀJ`` and
optionally ``K = JᵀJ + Σ r ∇²r`` (half the exact Hessian)."""

RTOL: Final[float] = 1e-10
"""Relative change of E (and of its linear model) at which least-squares fits stop: E then
lies within ~1e-12 (relative) of its minimum, far inside the 1e-6 agreement with Nelder–Mead
that the tests and benchmarks check."""

NEWTON_CONSTANT: Final[float] = 1e4
"""Bound on C in "the next Newton decrease is about C·δ² after a decrease δ" (relative to E),
used to stop without a last pass over the frames; C up to ~200 was seen on the simulated
clips."""


def levenberg_marquardt(cost: Callable[[Float], float], normal: Callable[[Float], Normal],
                        x0: Float, *, rtol: float = RTOL, max_iter: int = 200,
                        damping: float = 1e-6, newton_rtol: float | None = None,
                        ) -> tuple[Float, int, bool]:
    """Minimise a sum of squares ``E(θ) = Σ r(θ)²`` by Levenberg–Marquardt.

    Parameters
    ----------
    cost : callable
        ``θ (P,) → E``.
    normal : callable
        ``θ (P,) → (E, Jᵀr (P,), JᵀJ (P, P)[, K (P, P)])``: the Gauss–Newton normal
        equations and optionally half the exact Hessian ``K``, used (Newton–LM) wherever
        ``K + μD`` is positive definite.
    x0 : ndarray, shape (P,)
        Start.
    rtol : float
        Stop when an accepted step lowered E by at most ``rtol·E`` and the model predicted
        no more (MINPACK's ``ftol`` test); when the model predicts a decrease of at most
        ``rtol·E`` (no step can lower E by more); or when a Newton step (exact curvature)
        that the model predicted within 10 % lowered E by at most ``√(rtol/C)·E`` with
        ``C = 1e4`` (quadratic convergence: the next step would gain at most ``rtol·E``).
    max_iter : int
        Maximum number of normal-equation evaluations.
    damping : float
        Initial ``μ`` (relative to ``D``): small for starts near the minimum (a converged
        subsample fit), larger for rough geometric starts.
    newton_rtol : float, optional
        Relative decrease of a confirmed Newton step below which to stop; default
        ``√(rtol/C)`` (see ``rtol``).

    Returns
    -------
    x : ndarray, shape (P,)
    n_evaluations : int
        Evaluations of ``cost`` plus of ``normal``.
    converged : bool

    Notes
    -----
    With P ≤ 7 the ``P × P`` system ``(JᵀJ + μD) s = −Jᵀr`` (``D`` the diagonal of ``JᵀJ``:
    Marquardt's scaling, as ``x_scale="jac"`` in scipy) is solved directly. MINPACK's QR of
    the N × P Jacobian, which ``scipy.optimize.least_squares(method="lm")`` runs at every
    iteration, cost more than the residuals themselves at N ≈ 12,600 (6,283 frames). The
    damping ``μ`` follows Nielsen's rule (Madsen, Nielsen & Tingleff, "Methods for non-linear
    least squares problems", 2nd ed., 2004, §3.2); it starts small because every start here
    comes from a converged fit on a subsample or from geometry, so the first steps are
    Gauss–Newton steps.
    """
    x = np.array(x0, dtype=float)
    newton_stop = np.sqrt(rtol / NEWTON_CONSTANT) if newton_rtol is None else newton_rtol
    e, g, h, curv = _unpack(normal(x))
    n_eval = 1
    damp = _Damping(damping, 2.0)
    for _ in range(max_iter):
        x, used, damp, verdict = _lm_iteration(cost, x, (e, g, h, curv), damp, rtol=rtol,
                                               newton_stop=newton_stop)
        n_eval += used
        if verdict is not None:
            return x, n_eval, verdict
        e, g, h, curv = _unpack(normal(x))
        n_eval += 1
    return x, n_eval, False


class _Damping(NamedTuple):
    """Levenberg–Marquardt damping ``μ`` (relative to the diagonal) and its growth ``ν``."""

    mu: float
    nu: float


def _lm_iteration(cost: Callable[[Float], float], x: Float,
                  at_x: tuple[float, Float, Float, Float | None], damp: _Damping, *,
                  rtol: float, newton_stop: float
                  ) -> tuple[Float, int, _Damping, bool | None]:
    """One Levenberg–Marquardt iteration from ``x`` (``at_x``: E, g, H, K there): damped
    steps, the damping raised after each rejected one, until one lowers E.

    Returns the new point, the evaluations of ``cost`` used, the damping, and the verdict:
    None to go on, True to stop converged (see ``levenberg_marquardt``'s ``rtol``), False to
    stop without (the model broke down)."""
    e, g, h, curv = at_x
    mu, nu = damp
    diag = h.diagonal()
    # ufunc reductions, not the array methods' Python wrappers (µs an iteration)
    diag = np.maximum(diag, 1e-12 * max(float(np.maximum.reduce(diag)), 1e-300))
    n_eval = 0
    while True:
        step, model = _damped_step(curv, h, mu * diag, g)
        # decrease of the quadratic model, E − (E + 2gᵀs + sᵀMs), positive when
        # M + μD is positive definite
        predicted = float(-2.0 * (g @ step) - step @ model @ step)
        if not math.isfinite(predicted):
            return x, n_eval, _Damping(mu, nu), False
        if predicted <= rtol * e:
            # nothing left to gain: x is the minimum up to rounding
            return x, n_eval, _Damping(mu, nu), True
        x_new = x + step
        e_new = cost(x_new)
        n_eval += 1
        if e_new < e:
            rho = (e - e_new) / predicted
            mu *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            done = e - e_new <= rtol * e and predicted <= rtol * e
            if model is curv and abs(rho - 1.0) < 0.1 and e - e_new <= newton_stop * e:
                # Newton converges quadratically once its model holds (ρ ≈ 1): after a
                # decrease of δ·E the next one is about C·δ²·E ≤ rtol·E
                done = True
            return x_new, n_eval, _Damping(mu, 2.0), True if done else None
        mu *= nu
        nu *= 2.0
        if mu > 1e16:
            return x, n_eval, _Damping(mu, nu), True


def _unpack(n: Normal) -> tuple[float, Float, Float, Float | None]:
    return (n[0], n[1], n[2], n[3]) if len(n) == 4 else (n[0], n[1], n[2], None)


def _damped_step(curv: Float | None, h: Float, damping: Float, g: Float,
                 ) -> tuple[Float, Float]:
    """Solve ``(M + diag(damping)) s = −g`` with ``M`` the exact curvature when given and
    the damped system is positive definite there, else ``M = JᵀJ``; returns ``s`` and ``M``."""
    for model in (curv, h):
        if model is None:
            continue
        a = model.copy()
        a.flat[::a.shape[0] + 1] += damping
        # LAPACK's dposv: a Cholesky factorisation, which fails (info > 0) unless the matrix
        # is positive definite, and the solve, in one call (7 µs against 21 for numpy's two)
        _, step, info = lapack.dposv(a, -g, overwrite_a=True)
        if info == 0 and np.logical_and.reduce(np.isfinite(step)):
            return step, model
    return np.full(g.shape, np.nan), h


def normal_from_residuals(fun: Callable[[Float], Float], jac: Callable[[Float], Float],
                          ) -> tuple[Callable[[Float], float], Callable[[Float], Normal]]:
    """``cost`` and ``normal`` for :func:`levenberg_marquardt` from residuals and their
    Jacobian (the Jacobian is small enough here to form)."""
    last: dict[str, Any] = {}

    def residuals(theta: Float) -> Float:
        if last.get("theta") is None or not np.array_equal(last["theta"], theta):
            last["theta"], last["r"] = theta.copy(), fun(theta)
        return last["r"]  # type: ignore[no-any-return]

    def cost(theta: Float) -> float:
        r = residuals(theta)
        return float(r @ r)

    def normal(theta: Float) -> Normal:
        r = residuals(theta)
        j = jac(theta)
        return float(r @ r), j.T @ r, j.T @ j

    return cost, normal
