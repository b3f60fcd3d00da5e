"""Soft-tissue slip of every sensor at once, from all the joint equations of the suit.

A sensor strapped on soft tissue moves slowly against the bone (a few millimetres below about
0.5 Hz). ``joints.estimate_joint(slip_period=...)`` models that slip joint by joint, with the
slips of both sensors as free unknowns of one joint equation; here every sensor's slip enters
the equations of all its joints (the chest sensor's, for instance, those of the waist, neck and
both shoulders), so the joints that share a sensor pin its slip down together, as in the
Cramér–Rao bound of ``benchmarks/skeleton_bound.py``. The estimated slip is then removed from
the sensor positions and the joints are located as usual.

Model
-----
Joint j between sensors a and b: ``R_a (c_a − s_a(t)) + p_a = R_b (c_b − s_b(t)) + p_b``
with ``s(t) = Σ_k φ_k(t) β_k`` over the cosines of ``joints.estimate_joint``'s slip
model (every period down to ``1 / slip_hz``, at most 16, no constant). Unknowns: every
joint's centre in both frames (a negligible ridge) and every sensor's coefficients, each
with a Gaussian prior of variance ``λ_s = v_s / (2K)`` per axis (``v_s`` the mean slow
residual variance of the plain fits of the sensor's joints: total minus white, the white
part from second differences). The rows of joint j are weighted by the inverse of the
residual variance the model leaves: the white part, plus the share of the slow part above
the basis's highest frequency where 16 cosines do not reach ``slip_hz`` (recordings over
``16 / (2 slip_hz)`` seconds; a flat slip spectrum assumed). Weighting by the white part
alone let the data outweigh the slip prior wherever the white noise is small (a precise
tracker): the slips then drift along the directions the equations barely see, the whole
body moving as one (a 63 s dance simulated with 5 mm of slip and no white noise: 20 mm
RMS of common slip and every joint 70 mm off, 3–4 mm with this weighting). The maximum a
posteriori slip is the solution of one sparse-ish linear system ((6J + 3KS) unknowns),
whose blocks are sums of ``φ_k φ_l M_t`` terms (``M_t = R_aᵀR_b``) as in
``joints._slip_system``. The rotations used as regressors are low-passed
(``ROTATION_SMOOTH_S``, on the measured samples: a filled gap carries no weight); the
measured ones serve to remove the slip.

Errors in variables (``rotation_noise``): a rotation with white noise of variance ``v``
per axis has ``E[R] = (1 − v) R̄``, so the sums ``Σ R_aᵀR_b`` of a joint come out
``(1 − v)²`` times their noise-free value and the ``Σ R_aᵀ d`` sums ``(1 − v)`` times:
the weakest eigenvalues of a joint that rotates a few degrees gain about ``2v`` and its
centre is pulled toward the sensors (attenuation bias). With ``v`` scaled by the
smoothing filter's noise gain, the M-dependent blocks of joint j are divided by
``(1 − v)²`` and its right-hand side by ``(1 − v)`` in a second system (same
assembly, one more factorisation), where this leaves ``EIV_SIGNAL_SHARE`` of the joint's
weakest eigenvalue; its centre and covariance replace the uncorrected ones when the two
centres differ by more than ``EIV_CHI2`` in Mahalanobis distance. The slips stay those of
the uncorrected system. Corrected least squares for measurement error: Fuller,
*Measurement Error Models*, Wiley 1987, §2.2.

Soft-tissue artefact of skin-mounted sensors: Leardini, Chiari, Della Croce & Cappozzo,
"Human movement analysis using stereophotogrammetry. Part 3: Soft tissue artifact
assessment and compensation", Gait & Posture 21(2):212–225, 2005. Savitzky & Golay,
Anal. Chem. 36(8):1627–1639, 1964.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Final, NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import cho_factor, cho_solve, solve_triangular
from scipy.signal import savgol_coeffs, savgol_filter

from . import _rows as rows
from . import quaternions as quat
from .joints import slip_basis, white_variance

ROTATION_SMOOTH_S: Final[float] = 0.2
"""Window (seconds) of the cubic Savitzky–Golay filter applied to the sensor rotations used
as regressors of the slip model: orientation noise is white, body rotation is smooth."""
EIV_SIGNAL_SHARE: Final[float] = 0.8
"""A joint's rotation sums are corrected for orientation noise (errors in variables) only
when the correction leaves at least this share of the weakest eigenvalue of its plain normal
matrix: where the motion is not well above the noise the correction is mostly noise itself."""
EIV_CHI2: Final[float] = 6.0
"""A corrected centre replaces the uncorrected one only when they differ by more than this
squared Mahalanobis distance (the mean of χ² with 6 degrees of freedom) under the
uncorrected posterior covariance: a correction within the centre's own uncertainty only adds
the variance of the noise estimate."""


@dataclass(frozen=True, eq=False)
class SlipFit:
    """Every sensor's slip and every joint's centre from the joint equations of a suit.

    Attributes
    ----------
    slip : dict of str to ndarray, shape (F, 3)
        Each sensor's slip in its own frame, metres (``p − R s`` is the position without it).
    centres : ndarray, shape (J, 2, 3)
        Each joint's centre in the frames of its two sensors (posterior mean, flat prior).
    covariances : ndarray, shape (J, 6, 6)
        Posterior covariance of ``centres[j]`` (flattened), the slip integrated out, m².
    """

    slip: dict[str, NDArray[np.float64]]
    centres: NDArray[np.float64]
    covariances: NDArray[np.float64]
    corrected: tuple[bool, ...]
    """Per joint: its centre and covariance come from the system corrected for orientation
    noise (``estimate_slip(rotation_noise=...)``)."""
    signal_share: tuple[float, ...]
    """Per joint: the share of the weakest eigenvalue of its plain normal matrix that is
    motion rather than orientation noise (1 without a noise level; 0 where the noise alone
    explains it, as along a hinge's axis)."""


def rotation_noise_variance(quaternions: Mapping[str, NDArray[np.float64]],
                            valid: Mapping[str, NDArray[np.bool_]]) -> float:
    """Per-axis variance (rad²) of the sensors' white orientation noise, or 0 if unknown.

    Each sensor's quaternion series (one hemisphere frame to frame) gives the variance of its
    third differences, where smooth motion up to quadratic in time cancels: white noise of
    ``v`` per axis moves a unit quaternion by ``ε/2`` in the three directions across it
    (``v/4`` each), and a third difference has 20 times the variance of its terms, so the
    squared norm of a third difference is ``5v χ²₃`` (its median, against outliers: 2.366).
    The sensors of one tracker share one noise level, and
    fast motion at a low frame rate only inflates an estimate, so the smallest over the
    sensors is taken.
    """
    estimates = []
    for name, q in quaternions.items():
        d3 = np.diff(quat.continuous(q), n=3, axis=0)
        ok = np.convolve(valid[name].astype(float), np.ones(4), "valid") > 3.5
        if ok.sum() > 10:
            estimates.append(float(np.median(rows.dots(d3[ok], d3[ok]))) / (5.0 * 2.366))
    return min(estimates) if estimates else 0.0


def _solve_system(normal: NDArray[np.float64], rhs: NDArray[np.float64], n_s: int
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Solution and the centres' 6 × 6 covariance blocks of the slip model's normal
    equations (centres after the ``n_s`` slip unknowns), from one Cholesky factorisation:
    with ``A = UᵀU`` (U upper triangular) the inverse's last block is ``U₂₂⁻¹ U₂₂⁻ᵀ``."""
    factor = cho_factor(normal)
    x = cho_solve(factor, rhs)
    inv22 = solve_triangular(np.triu(factor[0][n_s:, n_s:]), np.eye(normal.shape[0] - n_s))
    cov = inv22 @ inv22.T
    blocks = np.stack([cov[i:i + 6, i:i + 6] for i in range(0, cov.shape[0], 6)]) \
        if cov.shape[0] else np.zeros((0, 6, 6))
    return np.asarray(x), blocks


def _noise_gain(n: int, fps: float) -> float:
    """Variance of white noise after ``_smoothed_rotations``' filter, per unit before."""
    window = round(ROTATION_SMOOTH_S * fps) | 1
    if 5 <= window < n:
        # a least-squares smoother: Σ h_i² equals its central coefficient
        return float(savgol_coeffs(window, 3)[window // 2])
    return 1.0


def _smoothed_rotations(quaternions: NDArray[np.float64], valid: NDArray[np.bool_],
                        fps: float) -> NDArray[np.float64]:
    """Rotation matrices (F, S, 3, 3) of sensors' quaternions (F, S, 4), low-passed; samples
    with ``valid`` (F, S) False (filled gaps) carry no weight.

    White orientation noise in the regressors of a linear model biases it (errors in
    variables) and, with a slip term able to absorb anything slow, makes the slip estimate
    follow the noise; a cubic Savitzky–Golay filter over ``ROTATION_SMOOTH_S`` keeps the motion
    (cubic over 0.2 s) and averages the noise.
    """
    q = quat.continuous(quaternions)
    window = round(ROTATION_SMOOTH_S * fps) | 1
    if 5 <= window < q.shape[0]:
        smooth = savgol_filter(q, window, 3, axis=0, mode="interp")
        _refit_around_gaps(q, valid, window, out=smooth)
        q = smooth
    q /= np.sqrt(rows.dots(q, q))[:, :, None]
    return quat.as_matrix(q)


def _refit_around_gaps(q: NDArray[np.float64], valid: NDArray[np.bool_], window: int, *,
                       out: NDArray[np.float64]) -> None:
    """Where the filter's window holds a filled sample, ``out`` becomes the cubic fitted to
    the measured samples of the window alone, or the sample itself where fewer than four
    are measured.

    An interpolated gap is a guess at the rotation; through the filter it would bias the
    measured frames around it, which the joint equations then trust (a 20-frame clip with a
    5-frame gap: 12 mm on the waist's centre, noise-free)."""
    n = q.shape[0]
    half = window // 2
    # the filter's window of each frame, shifted inside the recording at its ends
    # (savgol_filter's mode="interp")
    win = np.clip(np.arange(n) - half, 0, n - window)[:, None] + np.arange(window)
    frames, sensors = np.nonzero(~valid[win].all(axis=1))
    w = valid[win[frames], sensors[:, None]].astype(float)  # (m, W)
    enough = w.sum(axis=1) >= 4
    out[frames[~enough], sensors[~enough]] = q[frames[~enough], sensors[~enough]]
    frames, sensors, w = frames[enough], sensors[enough], w[enough]
    if frames.size == 0:
        return
    cols = win[frames]
    powers = ((cols - frames[:, None]) / half)[:, :, None] ** np.arange(4)  # (m, W, 4)
    weighted = powers * w[:, :, None]
    normal = np.einsum("mwp,mwq->mpq", weighted, powers)
    rhs = np.einsum("mwp,mwc->mpc", weighted, q[cols, sensors[:, None]])
    # the polynomial's value at the frame itself: its constant term
    out[frames, sensors] = np.linalg.solve(normal, rhs)[:, 0]


def estimate_slip(
    positions: Mapping[str, NDArray[np.float64]],
    quaternions: Mapping[str, NDArray[np.float64]],
    valid: Mapping[str, NDArray[np.bool_]],
    pairs: Sequence[tuple[str, str]],
    *,
    fps: float,
    slip_hz: float = 0.5,
    rotation_noise: float = 0.0,
) -> SlipFit:
    """Slow displacement of every sensor against its bone, from all joints at once.

    Parameters
    ----------
    positions : mapping of str to ndarray, shape (F, 3)
        Sensor positions (gaps filled), metres, by sensor name.
    quaternions : mapping of str to ndarray, shape (F, 4)
        Sensor → world rotations, scalar first (gaps filled).
    valid : mapping of str to ndarray of bool, shape (F,)
        Measured (not interpolated) samples.
    pairs : sequence of (str, str)
        The two sensors of each joint (a point fixed in both frames).
    fps : float
        Frame rate, Hz.
    slip_hz : float
        Highest slip frequency modelled, Hz.
    rotation_noise : float
        Per-axis variance (rad²) of the white orientation noise of the measured rotations
        (``rotation_noise_variance``); 0: no errors-in-variables correction.

    Returns
    -------
    SlipFit
        Each sensor's slip in its own frame, metres (the measured position is
        ``p(t) = p_true(t) + R(t) s(t)``, so ``p − R s`` is the position without slip;
        sensors in no pair are absent), and each joint's centre with its covariance.

    Notes
    -----
    The model, its weighting and the errors-in-variables correction are described in the
    module docstring.
    """
    sensors = sorted({s for pair in pairs for s in pair})
    n = next(iter(positions.values())).shape[0]
    layout = SlipLayout.of(sensors, len(pairs), n, fps, slip_hz)
    smoothed = _smoothed_rotations(np.stack([quaternions[s] for s in sensors], axis=1),
                                    np.stack([valid[s] for s in sensors], axis=1), fps)
    rot = {s: smoothed[:, i] for i, s in enumerate(sensors)}
    v_eiv = rotation_noise * _noise_gain(n, fps)
    blocks = [joint_block(layout, j, (a, b), (rot[a], rot[b]), positions[b] - positions[a],
                          (valid[a] & valid[b]).astype(float), v_eiv)
              for j, (a, b) in enumerate(pairs)]
    normal, rhs_all = _assemble(layout, blocks)
    x, blocks_c = _solve_system(normal, rhs_all, layout.n_s)
    centres = x[layout.n_s:].reshape(-1, 2, 3)
    k = layout.k
    slip = {s: layout.basis @ x[layout.index[s]:layout.index[s] + 3 * k].reshape(k, 3)
            for s in sensors}
    share = tuple(block.share for block in blocks)
    if not any(block.eiv is not None for block in blocks):
        return SlipFit(slip, centres, blocks_c, (False,) * len(pairs), share)
    centres, blocks_c, corrected = _errors_in_variables(
        normal, rhs_all, layout.n_s, blocks, centres, blocks_c)
    return SlipFit(slip, centres, blocks_c, corrected, share)


@dataclass(frozen=True, eq=False)
class SlipLayout:
    """Where each unknown of the slip model sits in its normal equations.

    Attributes
    ----------
    sensors : tuple of str
        Sensors of the joints' pairs, sorted; S of them.
    basis : ndarray, shape (F, K)
        The slip model's cosines (``joints.slip_basis``); K = 0 without slip.
    unmodelled : float
        Share of the slow residual above the basis's highest frequency (at most
        ``joints.SLIP_BASIS_MAX`` cosines: on a long recording only the slowest slip is
        modelled, and the rest, for a flat spectrum up to ``slip_hz``, is noise to the model).
    index : dict of str to int
        First unknown of each sensor's 3K slip coefficients.
    n_s : int
        Number of slip unknowns, 3KS; every joint's 6 centre unknowns follow them (last, so
        that their covariance is the inverse of the factor's last block alone).
    size : int
        Number of unknowns, ``n_s + 6J``.
    """

    sensors: tuple[str, ...]
    basis: NDArray[np.float64]
    unmodelled: float
    index: dict[str, int]
    n_s: int
    size: int

    @property
    def k(self) -> int:
        """Number of cosines K."""
        return int(self.basis.shape[1])

    @classmethod
    def of(cls, sensors: Sequence[str], n_joints: int, n: int, fps: float,
           slip_hz: float) -> SlipLayout:
        """The layout for ``sensors``, ``n_joints`` joints, ``n`` frames at ``fps`` Hz and
        slip up to ``slip_hz`` (0: no slip unknowns)."""
        basis = slip_basis(n, fps / slip_hz) if slip_hz > 0 else np.zeros((n, 0))
        k = basis.shape[1]
        unmodelled = 1.0 - min(1.0, k / (2.0 * n * slip_hz / fps)) if slip_hz > 0 else 1.0
        n_s = 3 * k * len(sensors)
        return cls(tuple(sensors), basis, unmodelled,
                   {s: 3 * k * i for i, s in enumerate(sensors)}, n_s, n_s + 6 * n_joints)


class JointNoise(NamedTuple):
    """Residual levels of one joint's plain fit (no slip), per axis, m²."""

    total: float
    white: float


class JointBlock(NamedTuple):
    """One joint's rows of the slip model, weighted and ready to add.

    ``idx`` are the unknowns they touch (the joint's centres, then both sensors' slip
    coefficients); ``normal`` and ``rhs`` their normal-equation block and right-hand side;
    ``eiv`` the errors-in-variables change of both, or None where the joint is not corrected;
    ``share`` as ``SlipFit.signal_share``."""

    idx: NDArray[np.intp]
    normal: NDArray[np.float64]
    rhs: NDArray[np.float64]
    sensors: tuple[str, str]
    noise: JointNoise
    eiv: tuple[NDArray[np.float64], NDArray[np.float64]] | None
    share: float


def joint_block(layout: SlipLayout, j: int, pair: tuple[str, str],  # noqa: PLR0917
                rotations: tuple[NDArray[np.float64], NDArray[np.float64]],
                d: NDArray[np.float64], w: NDArray[np.float64], v_eiv: float) -> JointBlock:
    """The weighted rows of joint ``j`` between sensors ``pair`` in the slip model.

    Parameters
    ----------
    layout : SlipLayout
    j : int
        The joint's number (its centres' place among the unknowns).
    pair : (str, str)
        Its sensors a and b.
    rotations : (ndarray, ndarray), shape (F, 3, 3) each
        Their smoothed sensor → world rotations.
    d : ndarray, shape (F, 3)
        ``p_b − p_a``, metres.
    w : ndarray, shape (F,)
        1 where both samples are measured, else 0.
    v_eiv : float
        Orientation noise variance after smoothing, rad² (0: no correction).

    Returns
    -------
    JointBlock
    """
    ra, rb = rotations
    n = d.shape[0]
    m9 = rows.relative_matrices(ra, rb).reshape(n, 9)  # M_t = R_aᵀ R_b
    ra_d = rows.apply_each(ra.transpose(0, 2, 1), d)  # R_aᵀ d
    rb_d = rows.apply_each(rb.transpose(0, 2, 1), d)
    total = max(float(w.sum()), 1.0)
    msum = (w @ m9).reshape(3, 3)
    eye3 = np.eye(3)
    plain = np.block([[total * eye3, -msum], [-msum.T, total * eye3]])
    prhs = np.concatenate([w @ ra_d, -(w @ rb_d)])
    noise = _plain_noise(plain, prhs, rotations, d, w)
    row_var = noise.white + layout.unmodelled * max(noise.total - noise.white, 0.0)
    big, rhs = _slip_rows(layout.basis, w, m9, (ra_d, rb_d), plain, prhs)
    k = layout.k
    a, b = pair
    idx = np.concatenate([np.arange(layout.n_s + 6 * j, layout.n_s + 6 * j + 6),
                          np.arange(layout.index[a], layout.index[a] + 3 * k),
                          np.arange(layout.index[b], layout.index[b] + 3 * k)])
    share, eiv = 1.0, None
    if v_eiv > 0.0:
        share, eiv = _eiv_change(big, rhs, msum / total, v_eiv, k)
    if eiv is not None:
        eiv = (eiv[0] / row_var, eiv[1] / row_var)
    return JointBlock(idx, big / row_var, rhs / row_var, pair, noise, eiv, share)


def _plain_noise(plain: NDArray[np.float64], prhs: NDArray[np.float64],
                 rotations: tuple[NDArray[np.float64], NDArray[np.float64]],
                 d: NDArray[np.float64], w: NDArray[np.float64]) -> JointNoise:
    """Total and white residual variance per axis of the plain LLSF of one joint (normal
    equations ``plain``, ``prhs``), m²; the white part from second differences, the total
    where too few frames give it, at least 1e-12."""
    c0 = np.asarray(np.linalg.lstsq(plain, prhs, rcond=None)[0], dtype=np.float64)
    ra, rb = rotations
    res = rows.apply(ra, c0[:3]) - rows.apply(rb, c0[3:]) - d
    use = w > 0
    total_var = float(np.mean(res[use] ** 2)) if use.any() else 1e-6
    white_var = white_variance(res, use)
    return JointNoise(total_var, max(total_var if white_var is None else white_var, 1e-12))


_CA, _CB = slice(0, 3), slice(3, 6)


def _slip_rows(basis: NDArray[np.float64], w: NDArray[np.float64], m9: NDArray[np.float64],  # noqa: PLR0917
               rotated_d: tuple[NDArray[np.float64], NDArray[np.float64]],
               plain: NDArray[np.float64], prhs: NDArray[np.float64]
               ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Unweighted normal-equation block (6 + 6K square) and right-hand side of one joint's
    unknowns ``[c_a, c_b, β_a, β_b]``, from the weights ``w`` (F,), ``M_t`` (F, 9) and
    ``R_aᵀd``, ``R_bᵀd`` (F, 3 each)."""
    k = basis.shape[1]
    ra_d, rb_d = rotated_d
    wphi = basis * w[:, None]
    phiphi = wphi.T @ basis  # Σ w φ_k φ_l
    # Σ w φ_k φ_l M[i, j]: one (K, F) × (F, K) product per entry of M, ordered (k, i, l, j)
    entries = np.empty((k, k, 9))
    for e in range(9):
        entries[:, :, e] = (wphi * m9[:, e, None]).T @ basis
    t_kl = entries.reshape(k, k, 3, 3).transpose(0, 2, 1, 3).reshape(3 * k, 3 * k)
    phim = (wphi.T @ m9).reshape(k, 3, 3)  # Σ w φ_k M
    sum_phi = wphi.sum(axis=0)
    eye3 = np.eye(3)
    big = np.zeros((6 + 6 * k, 6 + 6 * k))
    big[:6, :6] = plain
    ba, bb = slice(6, 6 + 3 * k), slice(6 + 3 * k, None)
    big[_CA, ba] = -np.kron(sum_phi[None, :], eye3)
    big[_CA, bb] = phim.transpose(1, 0, 2).reshape(3, 3 * k)
    big[_CB, ba] = phim.transpose(2, 0, 1).reshape(3, 3 * k)
    big[_CB, bb] = -np.kron(sum_phi[None, :], eye3)
    big[ba, ba] = big[bb, bb] = np.kron(phiphi, eye3)
    big[ba, bb] = -t_kl
    big[6:, :6] = big[:6, 6:].T
    big[bb, ba] = big[ba, bb].T
    rhs = np.concatenate([prhs, -(wphi.T @ ra_d).reshape(-1), (wphi.T @ rb_d).reshape(-1)])
    return big, rhs


def _eiv_change(big: NDArray[np.float64], rhs: NDArray[np.float64],
                mean_m: NDArray[np.float64], v_eiv: float, k: int
                ) -> tuple[float, tuple[NDArray[np.float64], NDArray[np.float64]] | None]:
    """Signal share of one joint and, where it is at least ``EIV_SIGNAL_SHARE``, the
    errors-in-variables change of its unweighted block and right-hand side (see
    ``estimate_slip``); ``mean_m`` is the joint's weighted mean ``M_t``."""
    gain = 1.0 / (1.0 - v_eiv) ** 2
    s_max = float(np.linalg.svd(mean_m, compute_uv=False)[0])
    # weakest eigenvalue of the plain block: 1 − s_max before, 1 − gain·s_max after
    share = max((1.0 - gain * s_max) / max(1.0 - s_max, 1e-300), 0.0)
    if share < EIV_SIGNAL_SHARE:
        return share, None
    ba, bb = slice(6, 6 + 3 * k), slice(6 + 3 * k, None)
    mdep = np.zeros_like(big)
    for r_, c_ in ((_CA, _CB), (_CA, bb), (_CB, ba), (ba, bb)):
        mdep[r_, c_] = big[r_, c_]
    mdep += mdep.T
    return share, ((gain - 1.0) * mdep, (np.sqrt(gain) - 1.0) * rhs)


def _assemble(layout: SlipLayout, blocks: Sequence[JointBlock]
              ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The slip model's normal equations: every joint's block plus a negligible ridge on the
    centres and each sensor's slip prior (variance: half the slow residual of its joints,
    at least half the median white residual)."""
    size = layout.size
    normal = np.zeros((size, size))
    rhs_all = np.zeros(size)
    for block in blocks:
        normal[np.ix_(block.idx, block.idx)] += block.normal
        rhs_all[block.idx] += block.rhs
    ridge = np.full(size, 1e-9 * float(np.max(np.diag(normal))))
    floor = float(np.median([block.noise.white for block in blocks]))
    k = layout.k
    for s in layout.sensors:
        slow = [max(block.noise.total - block.noise.white, 0.0)
                for block in blocks for sensor in block.sensors if sensor == s]
        var = max(0.5 * float(np.mean(slow)), 0.5 * floor)
        ridge[layout.index[s]:layout.index[s] + 3 * k] = k / var
    normal[np.diag_indices(size)] += ridge
    return normal, rhs_all


def _errors_in_variables(normal: NDArray[np.float64], rhs_all: NDArray[np.float64], n_s: int,  # noqa: PLR0917
                         blocks: Sequence[JointBlock], centres: NDArray[np.float64],
                         covariances: NDArray[np.float64]
                         ) -> tuple[NDArray[np.float64], NDArray[np.float64], tuple[bool, ...]]:
    """Centres, covariances and per-joint flags after the errors-in-variables correction:
    a corrected joint's centre replaces the plain one where they differ by more than
    ``EIV_CHI2`` (squared Mahalanobis distance); none where the corrected system is not
    positive definite. ``normal`` and ``rhs_all`` are changed in place."""
    for block in blocks:
        if block.eiv is not None:
            normal[np.ix_(block.idx, block.idx)] += block.eiv[0]
            rhs_all[block.idx] += block.eiv[1]
    try:
        x_e, blocks_e = _solve_system(normal, rhs_all, n_s)
    except np.linalg.LinAlgError:  # the corrections together left no positive definite system
        return centres, covariances, (False,) * len(blocks)
    centres_e = x_e[n_s:].reshape(-1, 2, 3)
    centres, covariances = centres.copy(), covariances.copy()
    corrected = [block.eiv is not None for block in blocks]
    for j in range(len(blocks)):
        if not corrected[j]:
            continue
        shift = (centres_e[j] - centres[j]).reshape(6)
        if float(shift @ np.linalg.solve(covariances[j], shift)) > EIV_CHI2:
            centres[j] = centres_e[j]
            covariances[j] = blocks_e[j]
        else:
            corrected[j] = False
    return centres, covariances, tuple(corrected)
