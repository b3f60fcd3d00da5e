"""Limb joints without forearm and lower-leg sensors (Miura et al. 2015, §2.1, eqs. 2–5).

A leg (arm) carries a sensor on the thigh (upper arm) and on the foot (hand); the hip
(shoulder) is known from the torso step. The knee (elbow) is a point fixed in the upper
sensor's frame and the ankle (wrist) a point fixed in the distal sensor's frame; because the
shank (forearm) is rigid, the distance between the two stays constant.

Two estimators:

``method="paper"``
    The paper's cost ``E`` (eq. 5) minimised either by Nelder–Mead (``optimizer=
    "nelder-mead"``, the paper's simplex method) or, by default, by Levenberg–Marquardt with
    analytic derivatives of ``E`` written as a sum of squares (Gauss–Newton normal equations
    plus the exact second-order term, 6 × 6 systems formed in one pass over the frames).
    Both reach the same minimum.
``method="improved"``
    A free shank length instead of the variance, a soft-L1 robust loss against slip and outlier
    frames, a hinge rule that fixes the two directions the data cannot see (the flexion axis
    of the knee or elbow is estimated from the motion of the distal joint in the upper sensor
    frame, and the knee and the ankle are put in the plane through the hip perpendicular to
    that axis), weak priors instead of the paper's pull towards the sensor origins, and
    plausibility bounds; the priors grow when the limb hardly moves.

Details
-------
``E`` is a sum of squares because ``Var_t(l) = Σ_t ((l(t) − l̄)/√M)²``; with
``u = (ankle − knee)/l`` the Jacobian rows are ``∂l/∂s_j = −uᵀP_k`` and
``∂l/∂s_{j+1} = uᵀP_{k+1}`` (computed in the upper sensor frame, where
``P_kᵀP_{k+1}`` is precomputed once), so one evaluation costs O(F).

The Nelder–Mead path uses scipy's implementation with an initial simplex of 5 cm steps
around the start, ``xatol=1e-6`` m and ``fatol`` 1e-9·E, and restarts from its own
result with a shrinking simplex until a restart lowers E by less than 1e-9 (relative):
it then converges as far as the least-squares path (within ~1e-10 of the same minimum).

``"improved"`` replaces ``Var_t(l)`` by ``Σ_t ρ(l(t) − L)`` with a free length ``L`` and
the soft-L1 loss ``ρ``, drops the ``|s|²`` term (it pulls the joints towards the sensor
origins, a bias of centimetres), and adds the hinge rule: with ``n`` the flexion axis in
the upper frame (least-scatter direction of the distal joint's path there), the middle
joint lies in the plane of the distal joint's arc (``nᵀ(x̄ − s_j) = 0``) and, at a quarter
of that weight, in the plane through the proximal joint (``nᵀ(s_j − h) = 0``): a hinge's
motion does not locate the middle joint along its axis, the flexion-plane rows below do
locate the distal joint's plane, and the proximal joint sits off it wherever the upper bone
is not square to the axis. The distal joint's path across that plane,
``nᵀ(x(t) − x̄)``, is penalised in every frame (weight 0.2 relative to the data rows): the
ankle (wrist) centre is the one point of the foot (hand) that a twist of the shank
(forearm) about its own axis leaves on the flexion arc, which singles it out where the
length of the shank (forearm) alone hardly varies (-1.5 to -2 mm on the 11-sensor limb
median, every seed of the accuracy benchmark). The rule is switched off when that path is
not a clean arc (least over middle variance above 0.4) wider than 1 cm. Weak priors (per
frame, relative to the data rows: 1e-4 on the two standard lengths, 3e-4 on the middle joint
lying on the proximal–distal line at the standard length ratio, across that line in the
flexion plane only as far as the limb passes through straight (a limb that stays bent has its
middle joint off the line there), and on the distal joint lying near its sensor) keep a
motionless limb well posed; they are raised by ``(20°/motion)²`` (at most 100×) when the
relative rotation of the two sensors stays under 20°. For a hand (``distal_in_line``) the
standard forearm length gets up to 3e-3 more where the data locate the wrist along the
forearm far less than across it (a hand that hardly turns against the forearm), against the
prior towards the hand sensor, which sits beyond the wrist. Flat-bottomed bounds reject segment
lengths beyond ±30 % of the standard ones and a distal joint over 0.2 m from its sensor. Starts:
the paper's least-squares solution, the geometric point and a straight limb through the
distal sensor; the alternation between axis and joints runs on a 400-frame subsample
from each start and the best is polished on every frame. Weights were chosen on
simulated clips (see ``docs/skeleton-limbs.md``).

Least-squares fits first converge on a subsample of about 400 frames and are then
polished on all frames, stopping when E changes by less than 1e-10 (relative). The
full-frame fits solve the 6 × 6 (7 × 7) normal equations directly instead of running
MINPACK's QR on the (2F + 7)-row Jacobian: for the paper's E the normal equations and the
exact Hessian come from per-frame sums (``paper_normal``), so the full-size polish is
two Newton steps, each one pass over the frames; the improved objective's Jacobian is
formed and multiplied out. The improved method's alternations from rough starts keep
MINPACK (``scipy.optimize.least_squares``) on the subsample: its objective has several
local minima and the optimizer's steps decide which one a start falls into.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares, minimize
from scipy.spatial.transform import Rotation

from . import _rows as rows
from .anthropometry import LIMB_KEYS, TABLES
from .errors import EstimationError, InputError
from .least_squares import Normal, levenberg_marquardt, normal_from_residuals
from .params import check_number, resolved_options
from .progress import Progress, no_progress
from .results import LimbQuality
from .vocabulary import OPTIMIZERS

__all__ = ["LimbFit", "LimbInUpperFrame", "LimbOptions", "estimate_limb", "limb_in_upper_frame",
           "paper_cost", "standard_lengths", "torso_length"]

Float = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class LimbFit:
    """Result of :func:`estimate_limb`.

    Attributes
    ----------
    middle_local : ndarray, shape (3,)
        Middle joint (knee, elbow) in the upper sensor frame (thigh, upper arm), metres.
    distal_local : ndarray, shape (3,)
        Distal joint (ankle, wrist) in the distal sensor frame (foot, hand), metres.
    middle, distal : ndarray, shape (F, 3)
        World positions of the two joints per frame, metres.
    cost : float
        The paper's ``E`` (eq. 5, with the ``w_s``, ``w_l`` and standard lengths given) at the
        solution, m². For ``method="improved"`` this is E evaluated at its solution, which is
        not E's minimiser.
    n_evaluations : int
        Cost (or residual) evaluations used.
    quality : LimbQuality
        Typed: ``method``, ``optimizer``, ``upper_length_m`` (mean proximal–middle distance),
        ``lower_length_m`` (mean middle–distal distance), ``lower_length_sd_m`` (its standard
        deviation over frames: 0 for a rigid segment), ``converged``; for ``"improved"`` also
        ``hinge_axis_local`` (flexion axis in the upper sensor frame), ``hinge_doubt`` (0 when
        the distal joint's path in the upper frame is a clean, wide circle arc, 1 when it
        gives no usable axis: then the hinge rule is off), ``flexion_range_deg`` (about that
        axis, 2.5–97.5 percentiles; None without a usable axis), ``relative_motion_deg``
        (90th percentile of the distal–upper rotation's deviation from its mean) and
        ``prior_gain`` (factor on the prior weights, > 1 when that motion is under 20°).
    """

    middle_local: Float
    distal_local: Float
    middle: Float
    distal: Float
    cost: float
    n_evaluations: int
    quality: LimbQuality = field(default_factory=LimbQuality)


def torso_length(waist: ArrayLike, l_hip: ArrayLike, r_hip: ArrayLike,
                 chest: ArrayLike) -> float:
    """Subject's torso length ``L'_T`` (paper, below eq. 4).

    Parameters
    ----------
    waist, l_hip, r_hip, chest : array_like, shape (F, 3)
        World positions of W, LH, RH and C per frame, metres.

    Returns
    -------
    float
        ``mean_t(|W − (LH + RH)/2| + |C − W|)``, metres.

    Notes
    -----
    Miura et al., "Sensor Number Reduction in Skeleton Estimation from Magnetic Motion Capture
    Data", J. Inf. Process. 23(5), 2015, eq. 4.
    """
    w, lh, rh, c = (np.asarray(v, dtype=float).reshape(-1, 3)
                    for v in (waist, l_hip, r_hip, chest))
    lower = rows.norms(w - 0.5 * (lh + rh))
    upper = rows.norms(c - w)
    value = float(np.mean(lower + upper))
    if not np.isfinite(value):
        raise EstimationError("torso length is undefined (NaN in the torso joints)",
                              field="torso")
    return value


def standard_lengths(torso_length: float,
                     table: str | Mapping[str, float] = "aist") -> dict[str, float]:
    """Standard limb-segment lengths scaled to the subject, ``L = L_β · L'_T / L_T``.

    Parameters
    ----------
    torso_length : float
        The subject's torso length ``L'_T`` (see :func:`torso_length`), metres.
    table : str or mapping, default "aist"
        ``"aist"`` or ``"winter"`` (see :mod:`bonefit.estimation.anthropometry`), or a mapping with
        keys ``torso``, ``thigh``, ``shank``, ``upperarm``, ``forearm`` giving lengths or
        ratios in any one unit.

    Returns
    -------
    dict of str to float
        ``thigh``, ``shank``, ``upperarm``, ``forearm`` lengths, metres.

    Notes
    -----
    Miura et al. 2015, eq. 4.
    """
    if isinstance(table, str):
        try:
            ratios = TABLES[table]
        except KeyError:
            raise InputError(f"unknown anthropometric table {table!r}; use one of "
                             f"{', '.join(TABLES)} or a mapping", field="anthropometry") from None
    else:
        ratios = table
    missing = [k for k in ("torso", *LIMB_KEYS) if k not in ratios]
    if missing:
        raise InputError(f"anthropometric table lacks {', '.join(missing)}",
                         field="anthropometry")
    for key in ("torso", *LIMB_KEYS):
        check_number(ratios[key], f"anthropometry.{key}", low=0.0, low_open=True)
    ref = float(ratios["torso"])
    if not (np.isfinite(torso_length) and torso_length > 0 and np.isfinite(ref) and ref > 0):
        raise InputError("torso lengths must be positive", field="anthropometry")
    return {k: float(ratios[k]) * torso_length / ref for k in LIMB_KEYS}


class LimbRows(NamedTuple):
    """A :class:`LimbInUpperFrame`'s arrays component-major, a contiguous row per component:
    ``b`` and ``h`` (3, F), ``q`` (9, F) with row ``3i + j`` the entry (i, j) of every
    frame's matrix. The passes of the paper's E over the frames run along these rows."""

    b: Float
    q: Float
    h: Float


@dataclass(frozen=True)
class LimbInUpperFrame:
    """A limb's data expressed in the upper sensor frame, where the costs are cheapest
    (:func:`limb_in_upper_frame`).

    Attributes
    ----------
    b : ndarray, shape (F, 3)
        Distal sensor origin, metres.
    q : ndarray, shape (F, 3, 3)
        Distal → upper sensor rotation matrices.
    h : ndarray, shape (F, 3)
        Proximal joint, metres.
    by_component : LimbRows, optional
        The same values component-major, when they were built that way (else
        :meth:`component_major` transposes them).
    """

    b: Float
    q: Float
    h: Float
    by_component: LimbRows | None = field(default=None, repr=False, compare=False)

    @property
    def n(self) -> int:
        return int(self.b.shape[0])

    def component_major(self) -> LimbRows:
        """``by_component``, or the arrays transposed into contiguous rows."""
        if self.by_component is not None:
            return self.by_component
        return LimbRows(np.ascontiguousarray(self.b.T),
                        np.ascontiguousarray(self.q.reshape(self.n, 9).T),
                        np.ascontiguousarray(self.h.T))

    def frame_major(self) -> LimbInUpperFrame:
        """The same limb with ``b``, ``q``, ``h`` in contiguous memory (copies of transposed
        views), for the fits whose passes run frame by frame."""
        if all(a.flags.c_contiguous for a in (self.b, self.q, self.h)):
            return self
        return LimbInUpperFrame(b=np.ascontiguousarray(self.b), q=np.ascontiguousarray(self.q),
                                h=np.ascontiguousarray(self.h), by_component=self.by_component)

    def every(self, step: int) -> LimbInUpperFrame:
        """Every ``step``-th frame (views)."""
        cm = self.by_component
        return LimbInUpperFrame(
            b=self.b[::step], q=self.q[::step], h=self.h[::step],
            by_component=None if cm is None else LimbRows(*(r[:, ::step] for r in cm)))

    def distal(self, a: Float) -> Float:
        """Distal joint (F,3) in the upper frame for ``a`` in the distal frame.

        Hot loops avoid BLAS (no matmul): on a loaded machine a threaded BLAS call on these
        thin arrays can cost milliseconds instead of microseconds."""
        return np.asarray(self.b + rows.apply(self.q, a))


def _as_frames(name: str, value: ArrayLike) -> Float:
    arr = np.asarray(value, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputError(f"{name} must have shape (F, 3), got {arr.shape}", field=name)
    if not np.isfinite(arr).all():
        raise InputError(f"{name} contains NaN or inf; fill gaps first", field=name)
    return arr


class _World(NamedTuple):
    """A limb's inputs, validated: world positions (F, 3) and sensor → world matrices
    (F, 3, 3)."""

    hip: Float
    pu: Float
    ru: Float
    pd: Float
    rd: Float


def _world(proximal: ArrayLike, upper_positions: ArrayLike, upper_rotations: Rotation,
           distal_positions: ArrayLike, distal_rotations: Rotation) -> _World:
    hip = _as_frames("proximal", proximal)
    pu = _as_frames("upper_positions", upper_positions)
    pd = _as_frames("distal_positions", distal_positions)
    n = hip.shape[0]
    if pu.shape[0] != n or pd.shape[0] != n or len(upper_rotations) != n \
            or len(distal_rotations) != n:
        raise InputError("limb inputs have different numbers of frames", field="frames")
    if n < 3:
        raise EstimationError(f"{n} frames are too few to locate limb joints", field="frames")
    return _World(hip, pu, upper_rotations.as_matrix(), pd, distal_rotations.as_matrix())


def _in_upper_frame(world: _World) -> LimbInUpperFrame:
    """The limb in the upper frame, computed component-major (``LimbRows``: a numpy loop per
    row over the frames instead of one per frame: 4x faster than the batched matmul of
    (F, 3, 3) stacks for ``q``); the frame-major arrays are transposed views of the rows
    (``LimbInUpperFrame.frame_major`` copies them for the fits that run frame by frame)."""
    n = world.hip.shape[0]
    u = _by_component(world.ru.reshape(n, 9)).reshape(3, 3, n)
    q = np.einsum("kim,kjm->ijm", u, _by_component(world.rd.reshape(n, 9)).reshape(3, 3, n))
    # Rᵤᵀ v per frame: b_i = Σ_k u_ki v_k, the differences v formed component-major
    b = np.einsum("kim,km->im", u, np.subtract(world.pd.T, world.pu.T, out=np.empty((3, n))))
    h = np.einsum("kim,km->im", u, np.subtract(world.hip.T, world.pu.T, out=np.empty((3, n))))
    if not (np.isfinite(q).all() and np.isfinite(b).all()):
        raise InputError("limb rotations contain NaN; fill gaps first", field="rotations")
    q = q.reshape(9, n)
    return LimbInUpperFrame(b=b.T, q=q.T.reshape(n, 3, 3), h=h.T,
                            by_component=LimbRows(b, q, h))


def _by_component(a: Float) -> Float:
    """A 2-D array transposed into contiguous memory."""
    return np.ascontiguousarray(a.T)


def limb_in_upper_frame(proximal: ArrayLike, upper_positions: ArrayLike,
                        upper_rotations: Rotation, distal_positions: ArrayLike,
                        distal_rotations: Rotation) -> LimbInUpperFrame:
    """A limb's inputs (as for :func:`estimate_limb`), checked and expressed in the upper
    sensor's frame: the first step of every limb fit.

    Raises
    ------
    InputError
        Bad shapes, different numbers of frames, NaN or inf.
    EstimationError
        Fewer than 3 frames.
    """
    return _in_upper_frame(_world(proximal, upper_positions, upper_rotations, distal_positions,
                                  distal_rotations))


def paper_residuals(limb: LimbInUpperFrame, lengths: tuple[float, float], w_s: float,
                    w_l: float) -> tuple[Callable[[Float], Float], Callable[[Float], Float]]:
    """``E`` as a sum of squares: residuals r(θ) with Σ r² = E, and their Jacobian.

    θ = (s_j, s_{j+1}). Per frame the variance and lower-length terms share l, and
    ``(l − l̄)²/M + w(l − L)²/M = (1 + w)(l − c)²/M + w(l̄ − L)²/(M(1 + w))`` with
    ``c = (l̄ + wL)/(1 + w)``, so E needs M rows ``√((1+w)/M)(l − c)``, one row
    ``√(w/(1+w))(l̄ − L)``, M rows ``√(w/M)(l_{j−1,j} − L_{j−1,j})`` and 6 rows ``√w_S θ``:
    2M + 7 rows instead of 3M + 6.
    """
    m = limb.n
    l_up, l_low = lengths
    root_c = np.sqrt((1.0 + w_l) / m)
    root_bar = np.sqrt(w_l / (1.0 + w_l))
    root_l = np.sqrt(w_l / m)
    root_s = np.sqrt(w_s)
    cache: dict[str, Any] = {}

    def geometry(theta: Float) -> tuple[Float, Float, Float, Float]:
        # the residuals and then the Jacobian are asked for at the same point
        if cache.get("theta") is not None and np.array_equal(cache["theta"], theta):
            return cache["value"]  # type: ignore[no-any-return]
        k, a = theta[:3], theta[3:]
        d = limb.distal(a) - k
        ll = rows.norms(d)
        e = limb.h - k
        lu = rows.norms(e)
        cache["theta"], cache["value"] = theta.copy(), (d, ll, e, lu)
        return d, ll, e, lu

    def fun(theta: Float) -> Float:
        _, ll, _, lu = geometry(theta)
        mean = ll.mean()
        out = np.empty(2 * m + 7)
        out[:m] = root_c * (ll - (mean + w_l * l_low) / (1.0 + w_l))
        out[m] = root_bar * (mean - l_low)
        out[m + 1:2 * m + 1] = root_l * (lu - l_up)
        out[2 * m + 1:] = root_s * theta
        return out

    def jac(theta: Float) -> Float:
        d, ll, e, lu = geometry(theta)
        u = d / ll[:, None]
        out = np.empty((2 * m + 7, 6))
        jl = out[:m]
        jl[:, :3] = -u
        jl[:, 3:] = np.einsum("fi,fij->fj", u, limb.q)
        jl_bar = jl.mean(axis=0)
        jl -= jl_bar / (1.0 + w_l)
        jl *= root_c
        out[m] = root_bar * jl_bar
        out[m + 1:2 * m + 1, :3] = e / lu[:, None] * -root_l
        out[m + 1:2 * m + 1, 3:] = 0.0
        out[2 * m + 1:] = root_s * np.eye(6)
        return out

    return fun, jac


_SIGN = np.array([-1.0, -1.0, -1.0, 1.0, 1.0, 1.0])
_SIGN_OUTER = np.outer(_SIGN, _SIGN)
_NEGATIVE_SIGN_OUTER = -_SIGN_OUTER

class PaperObjective(NamedTuple):
    """The paper's E at θ, its normal equations, and the two segment lengths per frame; the
    three share one pass over the frames at the last point asked for."""

    cost: Callable[[Float], float]
    normal: Callable[[Float], Normal]
    lengths: Callable[[Float], tuple[Float, Float]]


def paper_normal(limb: LimbInUpperFrame, lengths: tuple[float, float], w_s: float,
                 w_l: float, exact: bool = True) -> PaperObjective:
    """``E`` and its Gauss–Newton normal equations, without the (2M + 7)-row Jacobian.

    Returns ``cost(θ) → E``, ``normal(θ) → (E, Jᵀr, JᵀJ)`` with ``r``, ``J`` those of
    :func:`paper_residuals`, and ``lengths(θ) → (l_{j,j+1}(t), l_{j−1,j}(t))``. With
    ``j_t = ∂l_t/∂θ = (−u_t, u_tᵀQ_t)`` (rows of an (M, 6) array), ``ê_t`` the unit
    hip → knee direction and ``c_t = (1 + w)l_t − l̄ − wL``::

        Jᵀr = (1/M) Σ c_t j_t + (w/M) Σ (l_{j−1,j}(t) − L_{j−1,j}) (ê_t, 0) + w_S θ
        JᵀJ = ((1 + w)/M) Σ j_t j_tᵀ − j̄ j̄ᵀ + (w/M) Σ (ê_t, 0)(ê_t, 0)ᵀ + w_S I

    (the variance's mean term collapses to ``−j̄ j̄ᵀ``), two (M, 6) × (M, 6) products
    instead of a QR of (2M + 7) × 6. ``cost`` evaluates eq. 5 directly, as the Nelder–Mead
    path does. With ``exact``, ``normal`` also returns half the exact Hessian
    ``JᵀJ + Σ r_i ∇²r_i``: the residuals (frame-to-frame scatter of l) do not vanish at the
    minimum, so Gauss–Newton alone converges only linearly (5–9 full-size iterations
    measured on the RT1-size benchmark), Newton quadratically.
    """
    terms = _PaperTerms(limb, lengths, w_s, w_l, exact)
    return PaperObjective(terms.cost, terms.normal, terms.segment_lengths)


class _Geometry(NamedTuple):
    """Per-frame geometry of a limb at θ: middle → distal vectors ``d`` (3, M, a row per
    component) and their lengths ``ll``, proximal → middle vectors ``e`` (3, M) and their
    lengths ``lu``; E, and the mean of ``ll``."""

    d: Float
    ll: Float
    e: Float
    lu: Float
    value: float
    ll_mean: float


class _Passes:
    """The buffers of one limb's passes over the frames, allocated at its first normal
    equations, and the views of them that every pass uses: each slice or transpose is a numpy
    call (about 0.3 µs), some 30 a pass, which the subsample's passes over ~400 frames feel.

    ``z`` holds the rows of ``_PaperTerms._rows``; ``by_j`` (8, 16) and ``by_e`` (4, 8) the
    two products of ``_PaperTerms.normal``; ``cross`` (3, 3) ``Σ (c/l) Q``; ``h`` and
    ``second`` (6, 6) JᵀJ and ``Σ r ∇²r`` before ``normal`` copies them out."""

    def __init__(self, m: int, exact: bool) -> None:
        # every row is written at each pass but these: ones, zeros, and without ``exact``
        # the second-order rows (zeros, as in their products' unused entries)
        z = np.empty((24, m))
        z[6] = 1.0
        z[23] = 0.0
        if not exact:
            z[8:14] = 0.0
            z[20:23] = 0.0
        self.z = z
        self.u, self.uq, self.j, self.second_j = z[:3], z[3:6], z[:6], z[8:14]
        self.c, self.cl, self.cul = z[7], z[14], z[15]
        self.e, self.cu, self.second_e = z[16:19], z[19], z[20:23]
        self.rows_j, self.cols_j = z[:8], z[:16].T
        self.rows_e, self.cols_e = z[16:20], z[16:24].T
        by_j, by_e = np.empty((8, 16)), np.empty((4, 8))
        self.by_j, self.by_e = by_j, by_e
        self.jj, self.j_bar, self.jc = by_j[:6, :6], by_j[:6, 6], by_j[:6, 7]
        self.jj_cl = by_j[:6, 8:14]
        self.ee, self.ec, self.ee_cul = by_e[:3, :3], by_e[:3, 3], by_e[:3, 4:7]
        self.cross_flat = np.empty(9)
        self.cross = self.cross_flat.reshape(3, 3)
        self.cross_t = self.cross.T
        # JᵀJ and Σ r ∇²r formed in place, with views of their diagonals and blocks
        self.h, self.second, self.upper = np.empty((6, 6)), np.empty((6, 6)), np.empty((3, 3))
        self.h_diagonal, self.h_kk = self.h.reshape(36)[::7], self.h[:3, :3]
        self.second_diagonal = self.second.reshape(36)[::7]
        self.second_kk, self.second_ka = self.second[:3, :3], self.second[:3, 3:]
        self.second_ak, self.upper_diagonal = self.second[3:, :3], self.upper.reshape(9)[::4]


def _lengths(v: Float, scratch: Float) -> Float:
    """Lengths of the columns of ``v`` (3, M), the squares through ``scratch`` (3, M): as
    ``einsum("im,im->m")`` adds them (the same bits), in three calls that take 0.7–0.8 of
    its time (1.4 against 1.8 µs over 400 frames, 4.5 against 6.3 over 6,283)."""
    np.multiply(v, v, out=scratch)
    lengths: Float = scratch[0] + scratch[1]
    lengths += scratch[2]
    np.sqrt(lengths, out=lengths)
    return lengths


class _PaperTerms:
    """The paper's E of one limb and its normal equations (see ``paper_normal``), sharing
    one pass over the frames at the last point asked for.

    The limb's data are kept component-major (``LimbRows``): every pass then runs along
    contiguous rows instead of strided columns of (M, 3, 3). The sums over a component
    are ``einsum`` calls, which add the terms in the same order as the row-by-row loops
    they replace (the same bits), in one call instead of nine."""

    def __init__(self, limb: LimbInUpperFrame, lengths: tuple[float, float], w_s: float, w_l: float,
                 exact: bool) -> None:
        self.limb, self.lengths, self.w_s, self.w_l, self.exact = limb, lengths, w_s, w_l, exact
        # the last point as a list of floats, and its geometry: comparing lists takes a
        # tenth of np.array_equal's 5-10 µs (30-50 calls per limb, a coarse pass over 400
        # frames takes about 60)
        self._last: tuple[list[float], _Geometry] | None = None
        self.b, self.q, self.h = (np.ascontiguousarray(r) for r in limb.component_major())
        m = limb.n
        self.q3 = self.q.reshape(3, 3, m)
        self._scratch = np.empty((3, m))  # squares of components, then E's three deviations
        # the signs (exact) folded into the constants: one product instead of two
        self._hessian_scale = (1.0 + w_l) / m * _SIGN_OUTER
        self._signed_m = _SIGN * m
        self._passes: _Passes | None = None  # allocated at the first normal equations

    def geometry(self, theta: Float) -> _Geometry:
        """The geometry at ``theta`` (cached: ``normal`` is asked for at the point ``cost``
        has just accepted)."""
        point = theta.tolist()
        if self._last is not None and self._last[0] == point:
            return self._last[1]
        m, (l_up, l_low), w_l = self.limb.n, self.lengths, self.w_l
        k = theta[:3, None]
        # the distal joint b + Q a in the upper frame, less the middle one: (3, M) rows
        d = theta[3:] @ self.q3  # Σ_j a_j Q_ij: a BLAS product per row i
        d += self.b
        d -= k
        ll = _lengths(d, self._scratch)
        e = k - self.h
        lu = _lengths(e, self._scratch)
        ll_mean = np.einsum("f->", ll) / m
        offsets = self._scratch
        np.subtract(ll, ll_mean, out=offsets[0])
        np.subtract(lu, l_up, out=offsets[1])
        np.subtract(ll, l_low, out=offsets[2])
        # each row's sum in the order of a one-row einsum: the same bits
        dev, off_up, off_low = np.einsum("if,if->i", offsets, offsets)
        value = float((dev + w_l * (off_up + off_low)) / m
                      + self.w_s * np.einsum("i,i->", theta, theta))
        geometry = _Geometry(d, ll, e, lu, value, float(ll_mean))
        self._last = (point, geometry)
        return geometry

    def cost(self, theta: Float) -> float:
        """E at ``theta``."""
        return self.geometry(theta).value

    def segment_lengths(self, theta: Float) -> tuple[Float, Float]:
        """``(l_{j,j+1}(t), l_{j−1,j}(t))`` at ``theta``."""
        g = self.geometry(theta)
        return g.ll, g.lu

    def normal(self, theta: Float) -> Normal:
        """``(E, Jᵀr, JᵀJ[, K])`` at ``theta``."""
        geo = self.geometry(theta)
        if self._passes is None:
            self._passes = _Passes(self.limb.n, self.exact)
        p = self._passes
        self._rows(geo, p)
        m, w_l = self.limb.n, self.w_l
        # every sum is an entry of one of two products of rows of z (see ``_rows``), 8 × 16
        # and 4 × 8 rows: shapes OpenBLAS's 4 × 8 kernels fill, 72 µs for 6,283 frames where
        # three products, (10, 14), (6, 6) and (3, 3) rows, took 131. A BLAS product adds
        # each entry's terms in the same order whatever the shapes: the same bits
        np.matmul(p.rows_j, p.cols_j, out=p.by_j)
        np.matmul(p.rows_e, p.cols_e, out=p.by_e)
        g = _SIGN * p.jc + self.w_s * theta
        g[:3] += p.ec
        j_bar = p.j_bar / self._signed_m
        np.multiply(self._hessian_scale, p.jj, out=p.h)
        p.h -= j_bar[:, None] * j_bar  # j̄ j̄ᵀ as np.outer forms it, without its checks
        p.h_diagonal += self.w_s  # + w_S I (no identity matrices: µs each, 23 passes a limb)
        p.h_kk += w_l / m * p.ee
        h = p.h.copy()
        if not self.exact:
            return geo.value, g, h
        self._second_order(p)
        return geo.value, g, h, p.h + p.second

    def _rows(self, geo: _Geometry, p: _Passes) -> None:
        """Rows (24, M) of ``p.z`` in two groups, the rows of ``normal``'s two products: 0–5
        u, uᵀQ (j up to the sign of its first block), 6 ones, 7 c, 8–13 u and uᵀQ times c/l
        (with ``exact``), 14 c/l, 15 c_u/l_u; then 16–18 ê, 19 c_u, 20–22 ê times c_u/l_u
        (with ``exact``), 23 zeros (the second product's fourth row of four).

        Every sum of the normal equations is an entry of a product of rows of z. z is
        component-major so that numpy's loops run over frames, not over 3 components."""
        m, (l_up, l_low), w_l = self.limb.n, self.lengths, self.w_l
        inv_l = 1.0 / geo.ll
        inv_lu = 1.0 / geo.lu
        np.multiply(geo.d, inv_l, out=p.u)
        np.einsum("im,ijm->jm", p.u, self.q3, out=p.uq)  # uᵀQ
        np.multiply(geo.e, inv_lu, out=p.e)
        c, cu = p.c, p.cu
        np.multiply(geo.ll, (1.0 + w_l) / m, out=c)
        c -= (geo.ll_mean + w_l * l_low) / m
        np.subtract(geo.lu, l_up, out=cu)
        cu *= w_l / m
        np.multiply(c, inv_l, out=p.cl)
        np.multiply(cu, inv_lu, out=p.cul)
        if self.exact:
            np.multiply(p.j, p.cl, out=p.second_j)
            np.multiply(p.e, p.cul, out=p.second_e)

    def _second_order(self, p: _Passes) -> None:
        """``Σ r ∇²r`` (6, 6) into ``p.second``, from the row c/l and the two products of
        ``normal``."""
        # Newton: add Σ r ∇²r. ∇²l = Dᵀ(I − uuᵀ)D/l with D = ∂d/∂θ = (−I, Q), and
        # QᵀQ = I, so Σ c ∇²l = (Σ c/l) I − Σ (c/l) j jᵀ with −Σ (c/l) Q in the (k, a)
        # block; ∇²l_{j−1,j} = (I − êêᵀ)/l_{j−1,j} on the k block.
        # a I − X as −X with a added to its diagonal: the same values, bit for bit
        np.multiply(_NEGATIVE_SIGN_OUTER, p.jj_cl, out=p.second)
        p.second_diagonal += p.by_j[6, 14]
        np.matmul(self.q, p.cl, out=p.cross_flat)
        p.second_ka -= p.cross
        p.second_ak -= p.cross_t
        np.negative(p.ee_cul, out=p.upper)
        p.upper_diagonal += p.by_j[6, 15]
        p.second_kk += p.upper


def paper_cost(theta: ArrayLike, limb: LimbInUpperFrame, *,
               standard_lengths: tuple[float, float], w_s: float = 0.01,
               w_l: float = 0.01) -> float:
    """The paper's cost ``E`` (eq. 5) at ``theta = (s_j, s_{j+1})``.

    Parameters
    ----------
    theta : array_like, shape (6,)
        Middle joint in the upper sensor frame, then distal joint in the distal sensor frame,
        metres.
    limb : LimbInUpperFrame
        The proximal joint and the distal sensor in the upper sensor's frame, from the world
        poses by :func:`limb_in_upper_frame` (once for any number of ``theta``).
    standard_lengths : (float, float)
        ``L_{j−1,j}`` and ``L_{j,j+1}``, metres.
    w_s, w_l : float
        Weights of eqs. 3 and 4.

    Returns
    -------
    float
        ``E = Var_t(l) + w_S(|s_j|² + |s_{j+1}|²) + w_L mean_t[(l_{j−1,j} − L_{j−1,j})²
        + (l_{j,j+1} − L_{j,j+1})²]``, m².

    Notes
    -----
    Miura et al. 2015, eqs. 2–5.

    Examples
    --------
    >>> limb = limb_in_upper_frame(hip, thigh_p, thigh_r, foot_p, foot_r)  # doctest: +SKIP
    >>> paper_cost(np.zeros(6), limb, standard_lengths=(0.42, 0.41))  # doctest: +SKIP
    """
    fun, _ = paper_residuals(limb, standard_lengths, w_s, w_l)
    r = fun(np.asarray(theta, dtype=float).reshape(6))
    return float(np.einsum("i,i->", r, r))


def _initial_point(limb: LimbInUpperFrame, lengths: tuple[float, float]) -> Float:
    """Start from geometry: the knee one thigh length from the hip, through the thigh sensor
    (which sits on the bone); the ankle one shank length from that knee towards the foot
    sensor (which sits next to the ankle)."""
    h_bar = limb.h.mean(axis=0)
    norm = np.linalg.norm(h_bar)
    direction = -h_bar / norm if norm > 1e-9 else np.array([0.0, -1.0, 0.0])
    k0 = h_bar + lengths[0] * direction
    to_sensor = limb.b - k0
    dist = rows.norms(to_sensor)[:, None]
    ankle_upper = k0 + lengths[1] * to_sensor / np.maximum(dist, 1e-9)
    # Ankle into the distal frame: a = Qᵀ(x − b), averaged over frames.
    # Σ_t Q_tᵀ v_t is one product of the stacked (3F) rows
    a0 = (ankle_upper - limb.b).reshape(-1) @ limb.q.reshape(-1, 3) / limb.n
    return np.concatenate([k0, a0])


_ROUGH_START = 1e-3
"""Initial Levenberg–Marquardt damping for starts from geometry (Nielsen's suggestion)."""

_COARSE_FRAMES = 400
"""Least-squares fits first converge on every k-th frame (about this many frames), then
polish on all frames: the final point is the minimum of the full cost, reached with a few
full-size iterations instead of ~15."""


_COARSE_RTOL = 1e-6
"""Relative change of E at which the subsample fit stops: its minimum is itself ~1e-3 (relative
E) away from the full-frame one, so polishing it further only costs iterations; the full-frame
fit that follows still stops at ``least_squares.RTOL``."""


_COARSE_NEWTON_GAIN = 2e-3
"""Relative gain of a Newton step (its model confirmed, ρ ≈ 1) below which the subsample fit
stops without another pass: the next step would gain about C·(2e-3)² ≤ 1e-3 of E, no more
than the subsample's minimum differs from the full one (measured: the full-frame fit reaches
the same point, 3 of 17 subsample normal-equation passes fewer on the RT1-size benchmark)."""


def _coarse(limb: LimbInUpperFrame) -> LimbInUpperFrame | None:
    step = limb.n // _COARSE_FRAMES
    return limb.every(step) if step >= 2 else None


def _reporting(normal: Callable[[Float], Normal], report: Progress, start: float, end: float
               ) -> Callable[[Float], Normal]:
    """``normal`` reporting ``start`` → ``end`` (approached, never reached) in ever smaller
    steps before each call: one per Levenberg–Marquardt iteration, a pass over the frames,
    whose number is not known ahead. An exception ``report`` raises (a cancelled job) stops
    the fit."""
    count = itertools.count()

    def reported(theta: Float) -> Normal:
        report(end - (end - start) * 0.8 ** next(count), "limbs")
        return normal(theta)
    return reported


def _fit_paper_ls(limb: LimbInUpperFrame, x0: Float, lengths: tuple[float, float], *,
                  w_s: float, w_l: float, objective: PaperObjective, report: Progress
                  ) -> tuple[Float, int, bool]:
    """Least squares on E: on a subsample first, then on every frame (``objective``);
    ``report`` 0 → 0.3 from the iterations."""
    n_eval = 0
    coarse = _coarse(limb)
    if coarse is not None:
        sub = paper_normal(coarse, lengths, w_s, w_l)
        x0, n_coarse, _ = levenberg_marquardt(sub.cost, _reporting(sub.normal, report, 0.0, 0.1),
                                              x0, rtol=_COARSE_RTOL, damping=_ROUGH_START,
                                              newton_rtol=_COARSE_NEWTON_GAIN)
        n_eval += n_coarse
    x, n_full, ok = levenberg_marquardt(objective.cost,
                                        _reporting(objective.normal, report, 0.1, 0.3), x0,
                                        damping=_ROUGH_START if coarse is None else 1e-6)
    return x, n_eval + n_full, ok


_NM_XATOL_M = 1e-6
"""Simplex size (metres) at which a Nelder–Mead run may stop: a micrometre, a thousandth of
the sensors' noise."""

_NM_RTOL = 1e-9
"""Spread of E over the simplex (relative) at which a Nelder–Mead run may stop, and gain of a
restart (relative) below which the restarts stop. Chosen so that Nelder–Mead converges as far
as the least-squares path does: on the 152 limb fits of the accuracy benchmark's 11-sensor
runs it ends at most 1e-10 (relative) above the least-squares E, which itself lies within
~1e-10 of the minimum. Tighter settings (simplex 1e-10 m, spread 1e-18 m², restart gain
1e-13) cost 1.7× the evaluations for agreement the comparison cannot use."""


def _fit_paper_nm(limb: LimbInUpperFrame, x0: Float, lengths: tuple[float, float], *,
                  w_s: float, w_l: float, progress: Progress) -> tuple[Float, int, bool]:
    l_up, l_low = lengths

    def cost(theta: Float) -> float:
        # E directly (eq. 5), no residual vector: the cheapest honest evaluation
        k, a = theta[:3], theta[3:]
        ll = rows.norms(limb.distal(a) - k)
        lu = rows.norms(limb.h - k)
        dev = ll - ll.mean()
        e_var = np.einsum("f,f->", dev, dev) / limb.n
        e_len = (np.einsum("f,f->", lu - l_up, lu - l_up)
                 + np.einsum("f,f->", ll - l_low, ll - l_low)) / limb.n
        return float(e_var + w_s * np.einsum("i,i->", theta, theta) + w_l * e_len)

    x = np.asarray(x0, dtype=float)
    f = cost(x)
    n_eval = 1
    step = 0.05
    converged = False
    # Nelder–Mead stalls on elongated valleys; restarting it from its own result with a
    # fresh simplex is the classic remedy and still the plain simplex method.
    for restart in range(30):
        simplex = np.vstack([x, x + step * np.eye(6)])
        res = minimize(cost, x, method="Nelder-Mead",
                       options={"initial_simplex": simplex, "xatol": _NM_XATOL_M,
                                "fatol": _NM_RTOL * f, "maxiter": 20000, "maxfev": 20000})
        n_eval += int(res.nfev)
        improved = f - float(res.fun)
        x, f = np.asarray(res.x, dtype=float), float(res.fun)
        progress(min(0.9, 0.2 + 0.1 * restart), "limbs")
        if improved <= _NM_RTOL * max(f, 1e-300):
            converged = True
            break
        step = max(step * 0.3, 1e-4)
    return x, n_eval, converged


def _soft_l1(r: Float, scale: float) -> tuple[Float, Float]:
    """Residuals whose squares are the soft-L1 loss of ``r``, and their derivative."""
    u2 = (r / scale) ** 2
    s = np.sqrt(1.0 + u2)
    return r * np.sqrt(2.0 / (s + 1.0)), np.sqrt(0.5 * (s + 1.0)) / s


def _hinge_state(limb: LimbInUpperFrame, x: Float) -> tuple[Float, float, float]:
    """At ``x`` = (middle, distal, ...): the flexion axis and the doubt about it
    (``_hinge_axis``), and the straight-limb prior's share across the chord
    (``_straight_share``), from one distal joint path."""
    path, proximal = limb.distal(x[3:6]), limb.h.mean(axis=0)
    axis, doubt = _hinge_axis(path, proximal, x[:3])
    return axis, doubt, _straight_share(path, proximal, x[:3])


def _along_weight(limb: LimbInUpperFrame, x: Float, gain: float) -> float:
    """Weight of the prior holding the lower segment at its standard length, at ``x`` =
    (middle, distal, ...), for a distal segment in line with the lower one (a hand:
    ``LimbOptions.distal_in_line``).

    The data rows' information on the distal joint ``a`` (the Schur complement of their
    normal matrix, the middle joint and the free length eliminated) is small along the
    lower segment when the distal segment hardly turns against it: the segment's length
    then barely varies wherever ``a`` sits on it. There the prior near the distal sensor,
    which sits beyond the joint along the segment, and the flexion-plane rows, which favour
    points near the middle joint where the joint is not a pure hinge, place the joint; the
    standard length, at ``_W_ALONG``, holds it instead, in full when that information is
    small against the least across the segment (``_ALONG_RATIO``), and divided by
    ``gain²`` for a limb that hardly moves, where the data locate it in no direction."""
    d = limb.distal(x[3:6]) - x[:3]
    u = d / np.maximum(rows.norms(d), 1e-12)[:, None]
    dl_da = np.einsum("fi,fij->fj", u, limb.q)
    j = np.column_stack([dl_da, -u, np.ones(limb.n)])
    h = j.T @ j
    # the middle joint and the length eliminated (a ridge for a limb that does not move)
    rest = h[3:, 3:] + 1e-12 * np.trace(h) * np.eye(4)
    info = h[:3, :3] - h[:3, 3:] @ np.linalg.solve(rest, h[3:, :3])
    e = dl_da.mean(axis=0)
    e /= max(float(np.linalg.norm(e)), 1e-12)
    off = np.eye(3) - np.outer(e, e)
    across = float(np.linalg.eigvalsh(off @ info @ off)[1])  # [0]: the 0 along e
    ratio = max(float(e @ info @ e), 0.0) / max(across, 1e-30)
    return _W_ALONG / (1.0 + (ratio / _ALONG_RATIO) ** 2) / gain ** 2


def _hinge_axis(path: Float, proximal: Float, middle: Float) -> tuple[Float, float]:
    """Flexion axis in the upper frame from the distal joint's ``path`` (F, 3) there, and the
    doubt about it.

    The distal joint circles around the axis, so the axis is its path's direction of least
    scatter. An arc a few degrees long is nearly straight, though: across its tangent the
    radial scatter (the sagitta) is then no larger than the noise's and the smallest
    eigenvector is as likely to be the radial direction as the axis (measured on the
    accuracy benchmark's limbs: 10–75° off where the path's radial sd is 5–8 mm). The axis
    of a knee (elbow) also runs across the thigh (upper arm), the hinge rule's own premise,
    so the proximal → middle direction ``g`` enters as one more scatter: the axis minimises
    ``nᵀ(C + κ ĝĝᵀ)n``, ``C`` the path's covariance and ``κ = _ARC_MIN_M²``, an arc of
    the noise's width along ``g``. Where the path is a clean arc wider than that, its own
    scatter decides; where it is not, the axis is the one across both the tangent and the
    thigh.

    Second value: how far that path is from a clean circle arc, 0 (planar and wide) to 1
    (no usable axis): the planarity ratio (least over middle variance) relative to
    ``_PLANARITY_OFF``, or the arc being no wider than the noise (middle spread under
    ``_ARC_MIN_M``)."""
    cov = np.cov(path, rowvar=False)
    vals = np.linalg.eigvalsh(cov)
    planarity = float(vals[0] / vals[1]) if vals[1] > 0 else 1.0
    spread = float(np.sqrt(max(vals[1], 0.0)))
    width = float(np.clip((spread - _ARC_MIN_M) / _ARC_MIN_M, 0.0, 1.0))
    g = proximal - middle
    g /= max(float(np.linalg.norm(g)), 1e-12)
    _, vecs = np.linalg.eigh(cov + _ARC_MIN_M ** 2 * np.outer(g, g))
    return vecs[:, 0], float(1.0 - (1.0 - min(planarity / _PLANARITY_OFF, 1.0)) * width)


def improved_problem(limb: LimbInUpperFrame, lengths: tuple[float, float], axis: Float,
                     weights: PriorWeights, *, robust_scale: float | None,
                     ) -> tuple[Callable[[Float], Float], Callable[[Float], Float]]:
    """θ = (k, a, L): middle joint (upper frame), distal joint (distal frame), lower length.

    Rows: M data rows ρ(l(t) − L); 2 hinge rows (middle joint in the plane through the
    proximal joint, at ``_HIP_PLANE_SHARE`` of the weight, and in the distal joint's plane);
    3 straight-limb rows (middle joint at the standard length ratio on the line from the
    proximal joint to the distal joint's mean position in the upper frame, along that line
    and the axis, across it by ``PriorWeights.across``, ``_line_projector``); 2 length
    rows (the lower one at ``PriorWeights.along`` more, ``_along_weight``); 3 distal-offset
    rows; 3 plausibility rows (zero unless a segment length leaves ±30
    % of its standard length or the distal joint lies more than 0.2 m from its sensor); M
    flexion-plane rows nᵀ(x(t) − x̄), the distal joint's path across the flexion plane. The
    ankle (wrist) centre is the one point of the foot (hand) that moves with the shank
    (forearm) alone, and a twist of the shank (forearm) about its own axis leaves it in
    place, so in the thigh (upper-arm) frame its path follows the flexion arc; points beside
    it also swing with the ankle (wrist) and the twist.
    """
    problem = _ImprovedProblem(limb, lengths, axis, weights, robust_scale)
    return problem.residuals, problem.jacobian


class PriorWeights(NamedTuple):
    """Per-frame weights of the improved method's prior rows (see ``improved_problem``)."""

    hinge: float
    line: float
    length: float
    distal: float
    plane: float
    across: float
    along: float = 0.0


def _prior_weights(doubt: float, gain: float, across: float, along: float) -> PriorWeights:
    """The improved method's prior weights: the hinge's from the doubt about its axis, the
    straight-limb, length and distal-offset ones scaled by ``gain`` (little motion), the
    straight-limb prior's share across the chord ``across`` (``_straight_share``), the
    lower length's extra weight ``along`` (``_along_weight``)."""
    return PriorWeights(_hinge_weight(doubt), gain * _W_LINE, gain * _W_LENGTH,
                        gain * _W_DISTAL, _W_PLANE, across, along)


def _outside(value: float, target: float, tol: float) -> tuple[float, float]:
    """Flat-bottomed penalty and its derivative: zero within ±tol of ``target``, linear
    beyond."""
    dev = value - target
    excess = abs(dev) - tol
    return (float(np.sign(dev) * excess), float(np.sign(dev))) if excess > 0 else (0.0, 0.0)


def _line_projector(axis: Float, chord: Float, across_share: float) -> Float:
    """(3, 3) map that keeps the straight-limb prior's components along the flexion ``axis``
    and along the ``chord`` (proximal joint → distal sensor, upper frame), and scales the one
    across the chord in the flexion plane by ``across_share`` (``_straight_share``): a limb
    flexed throughout has its middle joint off the chord there by the sagitta, and pulling it
    onto the chord shortened both segments (the lower one by 11–16 mm in the median of the
    accuracy benchmark's limbs)."""
    across = np.cross(axis, chord)
    across /= max(float(np.linalg.norm(across)), 1e-12)
    return np.eye(3) - (1.0 - across_share) * np.outer(across, across)


def _straight_share(path: Float, proximal: Float, middle: Float) -> float:
    """How far the limb passes through straight, 1 (it does) to 0 (it stays bent):
    ``1 / (1 + (φ/_BENT_REF_DEG)²)``, ``φ`` the low (``_BENT_PERCENTILE``) percentile over
    frames of the flexion angle between the ``proximal`` → ``middle`` and middle → distal
    (``path``, (F, 3)) directions."""
    upper = middle - proximal
    lower = path - middle
    cos = lower @ upper / np.maximum(rows.norms(lower) * np.linalg.norm(upper), 1e-12)
    bent = float(np.degrees(np.arccos(np.clip(np.percentile(cos, 100 - _BENT_PERCENTILE),
                                              -1.0, 1.0))))
    return 1.0 / (1.0 + (bent / _BENT_REF_DEG) ** 2)


class _ImprovedProblem:
    """Residuals and Jacobian of the improved objective of one limb (``improved_problem``);
    θ = (k, a, L)."""

    def __init__(self, limb: LimbInUpperFrame, lengths: tuple[float, float], axis: Float,
                 weights: PriorWeights, robust_scale: float | None) -> None:
        m = limb.n
        self.limb, self.lengths, self.axis, self.robust_scale = limb, lengths, axis, robust_scale
        self.h_bar = limb.h.mean(axis=0)
        self.b_bar = limb.b.mean(axis=0)
        self.q_bar = limb.q.mean(axis=0)
        self.c_h = np.sqrt(m * weights.hinge)
        self.c_hip = np.sqrt(m * weights.hinge * _HIP_PLANE_SHARE)
        self.c_s = np.sqrt(m * weights.line)
        self.line_p = _line_projector(axis, self.b_bar - self.h_bar, weights.across)
        self.c_l = np.sqrt(m * weights.length)
        self.c_low = np.sqrt(m * (weights.length + weights.along))
        self.c_d = np.sqrt(m * weights.distal)
        self.c_b = np.sqrt(m * _W_BOUND)
        l_up, l_low = lengths
        self.tol_up, self.tol_low = _BOUND * l_up, _BOUND * l_low
        self.ratio = l_up / (l_up + l_low)
        self.c_p = np.sqrt(weights.plane)
        self.q_dev = np.einsum("i,fij->fj", axis, limb.q - self.q_bar) \
            if weights.plane > 0 else None
        self.b_dev = (limb.b - self.b_bar) @ axis if weights.plane > 0 else None

    def residuals(self, theta: Float) -> Float:
        """The data rows, the 13 prior rows, then the flexion-plane rows when weighted."""
        k, a, length = theta[:3], theta[3:6], theta[6]
        ll = rows.norms(self.limb.distal(a) - k)
        r = ll - length
        if self.robust_scale is not None:
            r, _ = _soft_l1(r, self.robust_scale)
        tail = self._prior_rows(k, a, length)
        if self.q_dev is not None and self.b_dev is not None:
            return np.concatenate([r, tail, self.c_p * (self.b_dev + self.q_dev @ a)])
        return np.concatenate([r, tail])

    def _prior_rows(self, k: Float, a: Float, length: float) -> Float:
        """Hinge (2), straight-limb (3), length (2), distal-offset (3) and plausibility (3)
        rows."""
        h_bar, axis, c_h, c_b = self.h_bar, self.axis, self.c_h, self.c_b
        l_up, l_low = self.lengths
        x_bar = self.b_bar + self.q_bar @ a
        lu = np.linalg.norm(k - h_bar)
        return np.concatenate([
            [self.c_hip * axis @ (k - h_bar), c_h * axis @ (x_bar - k)],
            self.c_s * self.line_p @ (k - h_bar - self.ratio * (x_bar - h_bar)),
            [self.c_l * (lu - l_up), self.c_low * (length - l_low)],
            self.c_d * a,
            [c_b * _outside(float(lu), l_up, self.tol_up)[0],
             c_b * _outside(float(length), l_low, self.tol_low)[0],
             c_b * _outside(float(np.linalg.norm(a)), 0.0, _DISTAL_REACH)[0]],
        ])

    def jacobian(self, theta: Float) -> Float:
        """Jacobian of :meth:`residuals`, (rows, 7)."""
        m, q_dev = self.limb.n, self.q_dev
        k, a, length = theta[:3], theta[3:6], theta[6]
        d = self.limb.distal(a) - k
        ll = rows.norms(d)
        u = d / ll[:, None]
        j = np.zeros((m + 13 + (m if q_dev is not None else 0), 7))
        if q_dev is not None:
            j[m + 13:, 3:6] = self.c_p * q_dev
        j[:m, :3] = -u
        j[:m, 3:6] = np.einsum("fi,fij->fj", u, self.limb.q)
        j[:m, 6] = -1.0
        if self.robust_scale is not None:
            _, dr = _soft_l1(ll - length, self.robust_scale)
            j[:m] *= dr[:, None]
        self._prior_jacobian(j[m:m + 13], k, a, length)
        return j

    def _prior_jacobian(self, j: Float, k: Float, a: Float, length: float) -> None:
        """Rows (13, 7) of the prior rows' Jacobian, written into ``j``."""
        axis, c_h, c_s, c_b, q_bar = self.axis, self.c_h, self.c_s, self.c_b, self.q_bar
        l_up, l_low = self.lengths
        j[0, :3] = self.c_hip * axis
        j[1, :3] = -c_h * axis
        j[1, 3:6] = c_h * axis @ q_bar
        j[2:5, :3] = c_s * self.line_p
        j[2:5, 3:6] = -c_s * self.ratio * self.line_p @ q_bar
        e = k - self.h_bar
        j[5, :3] = self.c_l * e / np.linalg.norm(e)
        j[6, 6] = self.c_low
        j[7:10, 3:6] = self.c_d * np.eye(3)
        j[10, :3] = c_b * _outside(float(np.linalg.norm(e)), l_up, self.tol_up)[1] * e \
            / np.linalg.norm(e)
        j[11, 6] = c_b * _outside(float(length), l_low, self.tol_low)[1]
        reach = float(np.linalg.norm(a))
        if reach > 0:
            j[12, 3:6] = c_b * _outside(reach, 0.0, _DISTAL_REACH)[1] * a / reach


# Weights of the improved method's priors, per frame (the data rows have unit weight and
# residuals of a few millimetres). Chosen on simulated clips (benchmarks/skeleton_accuracy.py
# protocol): they only matter along directions the motion does not determine.
_W_HINGE = 0.01     # hinge rule, fully on for planar distal paths. 0.03 until issue 20 §3: at
# that weight the rule overrode what the data locate of a knee (elbow) off its neighbours'
# line or not a pure hinge (on the realistic rigs its rows cost 3-10x the data's gain at the
# true joints); 0.01 lowers the 11-sensor limb median on both rigs and every seed
_HIP_PLANE_SHARE = 0.25  # the hinge rule's row putting the middle joint in the proximal
# joint's plane, relative to its row putting it in the distal joint's: a hinge turns the
# distal joint in a plane through the middle one, which the flexion-plane rows locate, while
# the proximal joint sits off that plane wherever the upper bone is not square to the axis
# (a carrying angle); the middle joint's offset along the axis itself is seen by neither
_W_LINE = 3e-4      # middle joint on the proximal–distal line at the standard length ratio
# (across the line scaled by _straight_share: see _line_projector)
_BENT_REF_DEG = 10.0  # least flexion at which the straight-limb prior keeps half its pull
# across the chord (10 and 40 tie on the limb median of realistic seeds 1-2 and BVH 1, 20 is
# 0.2-0.8 mm worse; on held-out realistic 3-5 and BVH 2, 40 is 0.3-1.3 mm worse than 10, and
# 10 is within 0.4 mm of no pull across the chord at all)
_BENT_PERCENTILE = 10.0  # the limb's least flexion: this low percentile over frames
_W_LENGTH = 1e-4    # standard lengths (anthropometric tables are ±20 % off real subjects)
_W_DISTAL = 3e-4    # distal joint near its sensor (as the paper's w_S, weaker, distal only)
_W_PLANE = 0.2      # distal joint's path in the flexion plane, per frame (see improved_problem)
_W_BOUND = 1.0      # lengths beyond ±_BOUND of the standard ones (implausible): strong
_BOUND = 0.3
_DISTAL_REACH = 0.2  # m: the ankle (wrist) lies within this distance of the foot (hand) sensor
_PLANARITY_OFF = 0.4  # hinge rule off when the distal path is this far from planar (0.2
# until its rows agreed with the distal joint's plane: a knee or elbow that turns about
# the shank or forearm as it flexes leaves estimated paths less planar than 0.2)
_ARC_MIN_M = 0.01     # ... or when its in-plane spread is below 1 cm (noise, not flexion)
_W_ALONG = 3e-3     # the lower segment at its standard length where the data do not locate the
# distal joint along it (_along_weight; a hand in line with the forearm only): 1e-3 and 3e-3
# both lower the limb median of realistic seeds 1-2 and BVH seed 1, 3e-3 by more
_ALONG_RATIO = 0.3  # information along the segment / least across it at which that prior
# keeps 1/2 of its weight (0.1 and 1.0 give the same limb medians within 0.2 mm)
_ALTERNATE = 2      # axis ↔ joints alternations


_MOTION_REF_DEG = 20.0  # relative rotation (90th percentile) below which priors are raised


def _relative_motion_deg(limb: LimbInUpperFrame) -> float:
    """90th percentile of the angle between the distal–upper relative rotation and its mean
    (chordal mean), degrees: how much the limb moves."""
    u, _, vt = np.linalg.svd(limb.q.mean(axis=0))
    mean = u @ np.diag([1.0, 1.0, float(np.linalg.det(u @ vt))]) @ vt
    cos = (np.einsum("ij,fij->f", mean, limb.q) - 1.0) / 2.0
    return float(np.degrees(np.percentile(np.arccos(np.clip(cos, -1.0, 1.0)), 90)))


def _hinge_weight(doubt: float) -> float:
    return _W_HINGE * (1.0 - doubt)


_MIN_MEASURED = 10


def _measured(limb: LimbInUpperFrame, valid: ArrayLike | None) -> LimbInUpperFrame:
    """The frames of ``limb`` flagged in ``valid`` (all of them without a mask, or with fewer
    than ``_MIN_MEASURED`` flagged)."""
    if valid is None:
        return limb
    keep = np.asarray(valid, dtype=bool)
    if keep.shape != (limb.n,):
        raise InputError(f"valid must have shape ({limb.n},), got {keep.shape}", field="valid")
    if keep.all() or keep.sum() < _MIN_MEASURED:
        return limb
    return LimbInUpperFrame(b=limb.b[keep], q=limb.q[keep], h=limb.h[keep])


@dataclass(frozen=True)
class LimbOptions:
    """The method options of :func:`estimate_limb` (its keywords of the same names).

    Attributes
    ----------
    method : {"improved", "paper"}
        ``"paper"``: minimise the paper's E (eq. 5). ``"improved"``: see the module
        docstring.
    optimizer : {"least-squares", "nelder-mead"}
        For ``method="paper"``: Levenberg–Marquardt with analytic derivatives (default) or
        Nelder–Mead on E (the paper's simplex method). Both start from the same geometric
        initial point and reach the same minimum. ``"improved"`` always uses
        Levenberg–Marquardt.
    w_s, w_l : float
        Weights of the paper's eqs. 3 and 4 (0.01 in the paper; lengths in metres).
    robust_scale : float or None
        ``"improved"`` only: residual scale (metres) of the soft-L1 loss; None for plain
        least squares.
    distal_in_line : bool
        ``"improved"`` only: the distal segment continues the lower one (a hand beyond the
        forearm; a foot, across the shank, does not), so its sensor sits beyond the distal
        joint along the lower segment. Where the data do not locate that joint along the
        segment (the hand hardly turns against the forearm), the standard lower length
        then holds it there (``_along_weight``) against the prior towards the sensor.

    Examples
    --------
    >>> LimbOptions(method="paper", optimizer="nelder-mead").w_s
    0.01
    """

    method: str = "improved"
    optimizer: str = "least-squares"
    w_s: float = 0.01
    w_l: float = 0.01
    robust_scale: float | None = 0.01
    distal_in_line: bool = False

    def __post_init__(self) -> None:
        if self.method not in ("paper", "improved"):
            raise InputError(f"unknown limb method {self.method!r}; use 'paper' or "
                             "'improved'", field="method")
        if self.optimizer not in OPTIMIZERS:
            raise InputError(f"unknown optimizer {self.optimizer!r}; use "
                             f"{' or '.join(map(repr, OPTIMIZERS))}", field="optimizer")


def _checked_lengths(standard_lengths: tuple[float, float]) -> tuple[float, float]:
    """The standard lengths as floats, positive and finite."""
    lengths = (float(standard_lengths[0]), float(standard_lengths[1]))
    if not all(np.isfinite(v) and v > 0 for v in lengths):
        raise InputError("standard lengths must be positive", field="standard_lengths")
    return lengths


def _straight_start(limb: LimbInUpperFrame, lengths: tuple[float, float]) -> Float:
    """A straight limb: the middle joint one upper length from the proximal joint towards
    the distal sensor, the distal joint at its sensor's origin."""
    h_bar = limb.h.mean(axis=0)
    toward = limb.b.mean(axis=0) - h_bar
    return np.concatenate([
        h_bar + lengths[0] * toward / max(float(np.linalg.norm(toward)), 1e-9), np.zeros(3)])


def _hinge_and_weights(limb: LimbInUpperFrame, coarse: LimbInUpperFrame, x: Float,
                       gain: float, options: LimbOptions) -> tuple[Float, float, PriorWeights]:
    """At ``x`` = (middle, distal, ...): the flexion axis and the doubt about it
    (:func:`_hinge_state` on every frame of ``limb``) and the prior weights they give, the
    lower length's extra from the subsample ``coarse`` for a hand (``_along_weight``)."""
    axis, doubt, share = _hinge_state(limb, x)
    along = _along_weight(coarse, x, gain) if options.distal_in_line else 0.0
    return axis, doubt, _prior_weights(doubt, gain, share, along)


def _fit_improved(limb: LimbInUpperFrame, starts: list[Float], lengths: tuple[float, float],
                  options: LimbOptions, report: Progress,
                  ) -> tuple[Float, int, bool, dict[str, Any]]:
    """The improved objective from each start on the subsample, the best polished on every
    frame; ``report`` 0.3 → 0.6 by subsample fit, 0.6 → 1 from the polish's iterations."""
    robust_scale = options.robust_scale
    n_eval, ok = 0, False
    fits = itertools.count(1)
    coarse = _coarse(limb) or limb
    motion_deg = _relative_motion_deg(limb)
    # Little relative rotation between the two sensors means the data hardly constrain the
    # joints (and their noise would be fitted): lean on the priors accordingly.
    gain = float(np.clip((_MOTION_REF_DEG / max(motion_deg, 1e-3)) ** 2, 1.0, 100.0))
    best: tuple[float, Float, Float, float, PriorWeights] | None = None
    # Several starts on the subsample (the objective has local minima when the limb moves
    # little); the best one is polished on every frame.
    for start in starts:
        axis, doubt, weights = _hinge_and_weights(limb, coarse, start, gain, options)
        length = float(rows.norms(limb.distal(start[3:6]) - start[:3]).mean())
        x = np.concatenate([start[:6], [length]])
        # The axis depends on the distal joint and vice versa: alternate.
        for _ in range(_ALTERNATE):
            fun, jac = improved_problem(coarse, lengths, axis, weights, robust_scale=robust_scale)
            # MINPACK's trust region from these rough starts: the objective has several
            # local minima and its steps decide the basin (cheap on the subsample)
            sol = least_squares(fun, x, jac=jac, method="lm", x_scale="jac",
                                ftol=1e-10, xtol=1e-10, gtol=1e-10, max_nfev=200)
            n_eval += int(sol.nfev + sol.njev)
            x, ok = np.asarray(sol.x, dtype=float), bool(sol.status > 0)
            report(0.3 + 0.3 * next(fits) / (len(starts) * _ALTERNATE), "limbs")
            new_axis, doubt, weights = _hinge_and_weights(limb, coarse, x, gain, options)
            if new_axis @ axis < 0:
                new_axis = -new_axis
            moved = float(np.arccos(np.clip(new_axis @ axis, -1.0, 1.0)))
            axis = new_axis
            if moved < 1e-4:
                break
        fun, _ = improved_problem(coarse, lengths, axis, weights, robust_scale=robust_scale)
        r = fun(x)
        value = float(r @ r)
        if best is None or value < best[0]:
            best = (value, x, axis, doubt, weights)
    assert best is not None
    _, x, axis, doubt, weights = best
    fun, jac = improved_problem(limb, lengths, axis, weights, robust_scale=robust_scale)
    if coarse is not limb:
        cost, normal = normal_from_residuals(fun, jac)
        x, more, ok = levenberg_marquardt(cost, _reporting(normal, report, 0.6, 1.0), x)
        n_eval += more
    r = fun(x)
    return x[:6], n_eval, ok, {
        "objective": float(r @ r),
        "hinge_axis_local": axis.tolist(),
        "hinge_doubt": doubt,
        "relative_motion_deg": motion_deg,
        "prior_gain": gain,
        "flexion_range_deg": _flexion_range_deg(limb, x, axis) if doubt < 1.0 else None,
    }


def _flexion_range_deg(limb: LimbInUpperFrame, x: Float, axis: Float) -> float:
    """Range (2.5–97.5 percentiles, degrees) of the middle → distal direction's angle about
    the flexion ``axis`` in the upper frame, at ``x`` = (middle, distal, ...)."""
    v = limb.distal(x[3:6]) - x[:3]
    v -= np.outer(v @ axis, axis)
    v /= np.maximum(rows.norms(v), 1e-12)[:, None]
    mean_dir = v.mean(axis=0)
    angles = np.degrees(np.arccos(np.clip(v @ (mean_dir / np.linalg.norm(mean_dir)), -1, 1)))
    side = np.sign(np.cross(v, mean_dir) @ axis)
    signed = angles * np.where(side == 0, 1.0, side)
    return float(np.percentile(signed, 97.5) - np.percentile(signed, 2.5))


# five input arrays, scipy style (as estimate_joint's four), the subject's lengths, the
# measured frames, progress and the options object: nine
def estimate_limb(proximal: ArrayLike, upper_positions: ArrayLike, upper_rotations: Rotation,  # noqa: PLR0913
                  distal_positions: ArrayLike, distal_rotations: Rotation, *,
                  standard_lengths: tuple[float, float], valid: ArrayLike | None = None,
                  progress: Progress | None = None, options: LimbOptions | None = None,
                  **keywords: Any) -> LimbFit:
    """Knee and ankle (elbow and wrist) from the thigh and foot (upper-arm and hand) sensors.

    Parameters
    ----------
    proximal : array_like, shape (F, 3)
        Hip (shoulder) world positions per frame, metres, from the torso step.
    upper_positions : array_like, shape (F, 3)
        Thigh (upper-arm) sensor origin per frame, world frame, metres.
    upper_rotations : Rotation, length F
        Thigh (upper-arm) sensor → world rotation per frame.
    distal_positions : array_like, shape (F, 3)
        Foot (hand) sensor origin per frame, world frame, metres.
    distal_rotations : Rotation, length F
        Foot (hand) sensor → world rotation per frame.
    standard_lengths : (float, float)
        Standard upper and lower segment lengths ``L_{j−1,j}``, ``L_{j,j+1}`` (thigh and shank,
        or upper arm and forearm), metres; see :func:`standard_lengths`.
    valid : array_like of bool, shape (F,), optional
        ``"improved"`` only: the frames in which both sensors were measured (not gap-filled).
        The joints are fitted on those alone (when there are at least 10) and placed in every
        frame: an interpolated pose during fast motion is a guess, which the fit would trust.
        The paper's method uses every frame, as published.
    progress : callable, optional
        ``progress(fraction, stage)``.
    options : LimbOptions, optional
        The method options as one object; default: from ``keywords``.
    **keywords
        Instead of ``options``, its fields: ``method`` ("improved"), ``optimizer``,
        ``w_s``, ``w_l``, ``robust_scale``.

    Returns
    -------
    LimbFit

    Raises
    ------
    InputError
        Bad shapes, NaN in the inputs, unknown method or optimizer.
    EstimationError
        Fewer than 3 frames.

    Notes
    -----
    Miura, Kaiga, Tajima, Shibata, Tamamoto, "Sensor Number Reduction in Skeleton Estimation
    from Magnetic Motion Capture Data", J. Inf. Process. 23(5):704–707, 2015, eqs. 2–5.
    Nelder & Mead, Comput. J. 7:308–313, 1965.

    The cost's derivatives, the optimizers and the improved objective are described in the
    module docstring.
    """
    report = progress or no_progress
    opt = resolved_options("estimate_limb", {"estimate_limb": LimbOptions}, options, keywords)
    lengths = _checked_lengths(standard_lengths)
    report(0.0, "limbs")
    world = _world(proximal, upper_positions, upper_rotations, distal_positions,
                   distal_rotations)
    # the two paths of the result before the fit's temporaries: those then come and go as
    # one block of memory, which the next limb reuses instead of growing the heap
    paths = np.empty((2, world.hip.shape[0], 3))
    limb = _in_upper_frame(world)
    objective = paper_normal(limb, lengths, opt.w_s, opt.w_l)
    theta, n_eval, ok, quality = _fit_limb(limb, _measured(limb, valid), objective, opt,
                                           lengths=lengths, report=report)
    fit = _limb_fit(world, objective, theta, n_eval=n_eval, ok=ok, quality=quality,
                    out=paths)
    report(1.0, "limbs")
    return fit


def _limb_fit(world: _World, objective: PaperObjective, theta: Float, *, n_eval: int, ok: bool,
              quality: dict[str, Any], out: Float) -> LimbFit:
    """The joints of ``theta`` placed in every frame (into ``out`` (2, F, 3): middle, then
    distal), E and the segment lengths there."""
    # after least squares on E, its last point: cached, no extra pass over the frames
    cost = objective.cost(theta)
    ll, lu = objective.lengths(theta)
    k, a = theta[:3], theta[3:]
    quality.update({
        "upper_length_m": float(lu.mean()),
        "lower_length_m": float(ll.mean()),
        "lower_length_sd_m": float(ll.std()),
        "converged": ok,
        "n_evaluations": n_eval,
    })
    middle = rows.transform(world.ru, k, world.pu, out=out[0])
    distal = rows.transform(world.rd, a, world.pd, out=out[1])
    return LimbFit(middle_local=k.copy(), distal_local=a.copy(), middle=middle, distal=distal,
                   cost=cost, n_evaluations=n_eval, quality=LimbQuality.of(quality))


def _fit_limb(limb: LimbInUpperFrame, measured: LimbInUpperFrame, objective: PaperObjective,
              options: LimbOptions, *, lengths: tuple[float, float], report: Progress
              ) -> tuple[Float, int, bool, dict[str, Any]]:
    """θ of the method and optimizer asked for, the evaluations used, whether it converged
    and the method's quality figures; ``measured`` the frames the improved method fits."""
    method, w_s, w_l = options.method, options.w_s, options.w_l
    # a start needs only means over the frames: the subsample's are as good
    x0 = _initial_point(_coarse(limb) or limb, lengths)
    quality: dict[str, Any] = {"method": method}
    if method == "paper" and options.optimizer == "nelder-mead":
        theta, n_eval, ok = _fit_paper_nm(limb.frame_major(), x0, lengths, w_s=w_s, w_l=w_l,
                                          progress=report)
        quality["optimizer"] = "nelder-mead"
        return theta, n_eval, ok, quality
    theta, n_eval, ok = _fit_paper_ls(limb, x0, lengths, w_s=w_s, w_l=w_l, objective=objective,
                                      report=report)
    quality["optimizer"] = "least-squares"
    if method == "improved":
        report(0.3, "limbs")
        measured = measured.frame_major()
        theta, more, ok, extra = _fit_improved(
            measured, [theta, x0, _straight_start(measured, lengths)], lengths, options, report)
        n_eval += more
        quality.update(extra)
        quality["fitted_frames"] = measured.n
    return theta, n_eval, ok, quality
