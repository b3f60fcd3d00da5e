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

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Final, NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import cho_factor, cho_solve, solve_triangular

from . import quaternions as quat
from .joints import slip_basis, white_variance
from .params import check_number, resolved_options
from .progress import Progress, no_progress, scaled
from .savgol import savgol_coeffs, savgol_filter
from .threads import Report, run_each

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
                            valid: Mapping[str, NDArray[np.bool_]], *,
                            progress: Progress | None = None) -> float:
    """Per-axis variance (rad²) of the sensors' white orientation noise, or 0 if unknown.

    Each sensor's quaternion series (one hemisphere frame to frame) gives the variance of its
    third differences, where smooth motion up to quadratic in time cancels: white noise of
    ``v`` per axis moves a unit quaternion by ``ε/2`` in the three directions across it
    (``v/4`` each), and a third difference has 20 times the variance of its terms, so the
    squared norm of a third difference is ``5v χ²₃`` (its median, against outliers: 2.366).
    The sensors of one tracker share one noise level, and
    fast motion at a low frame rate only inflates an estimate, so the smallest over the
    sensors is taken. Sensor by sensor, two at a time (``threads.run_each``;
    ``progress(fraction, "slip")``).
    """
    def level_of(name: str) -> Callable[[Report], float | None]:
        def task(_report: Report) -> float | None:
            # component-major rows (4, F): the differences run along contiguous frames
            d3 = np.diff(quat.continuous_rows(np.asarray(quaternions[name]).T), n=3, axis=-1)
            return quat.third_difference_median(np.einsum("ct,ct->t", d3, d3), valid[name])
        return task

    frames = next(iter(quaternions.values())).shape[0] if quaternions else 0
    levels = run_each([level_of(name) for name in quaternions], progress or no_progress,
                      "slip", frames=frames)
    estimates = [level / (5.0 * 2.366) for level in levels if level is not None]
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


def _smoothed_rotations(quaternions: Sequence[NDArray[np.float64]],
                        valid: Sequence[NDArray[np.bool_]], fps: float,
                        report: Progress = no_progress) -> NDArray[np.float64]:
    """Sensors' quaternions, low-passed and normalised, component-major: (S, 4, F), from each
    sensor's quaternions given component-major (4, F); samples with ``valid`` (F,) False
    (filled gaps) carry no weight. Each joint's block makes their rotation matrices
    (``quaternions.as_matrix_rows``) for itself: kept for every sensor at once they took
    9 × 8 bytes per frame and sensor (1 GB at a million frames and 15 sensors), these 4 × 8.

    White orientation noise in the regressors of a linear model biases it (errors in
    variables) and, with a slip term able to absorb anything slow, makes the slip estimate
    follow the noise; a cubic Savitzky–Golay filter over ``ROTATION_SMOOTH_S`` keeps the motion
    (cubic over 0.2 s) and averages the noise. Sensor by sensor (two at a time,
    ``threads.run_each``), along contiguous rows of frames: the temporaries are those of
    one sensor per thread.
    """
    n = quaternions[0].shape[-1]
    out = np.empty((len(quaternions), 4, n))
    window = round(ROTATION_SMOOTH_S * fps) | 1

    def smooth_one(k: int) -> Callable[[Report], None]:
        def task(report: Report) -> None:
            q = quat.continuous_rows(quaternions[k])[None]
            if 5 <= window < n:
                smooth = savgol_filter(q, window, 3, axis=-1, mode="interp")
                report(0.6)
                _refit_around_gaps(q, valid[k][None], window, out=smooth)
                q = smooth
            np.divide(q, np.sqrt(np.einsum("sct,sct->st", q, q))[:, None], out=out[k:k + 1])
        return task

    run_each([smooth_one(k) for k in range(len(quaternions))], report, "slip", frames=n)
    return out


def _refit_around_gaps(q: NDArray[np.float64], valid: NDArray[np.bool_], window: int, *,
                       out: NDArray[np.float64]) -> None:
    """Where the filter's window holds a filled sample, ``out`` (S, 4, F) becomes the cubic
    fitted to the measured samples of the window alone, or the sample itself where fewer
    than four are measured; ``q`` (S, 4, F) the samples, ``valid`` (S, F).

    An interpolated gap is a guess at the rotation; through the filter it would bias the
    measured frames around it, which the joint equations then trust (a 20-frame clip with a
    5-frame gap: 12 mm on the waist's centre, noise-free). The windows holding a filled
    sample are found from a running count of the filled samples (one pass over (S, F)),
    and refitted ``REFIT_CHUNK`` at a time: memory bounded whatever the length of the take."""
    n = q.shape[-1]
    # the filter's window of each frame starts here, shifted inside the recording at its
    # ends (savgol_filter's mode="interp")
    start = np.clip(np.arange(n) - window // 2, 0, n - window)
    counts = np.zeros((valid.shape[0], n + 1), dtype=np.int32)
    np.cumsum(~valid, axis=1, out=counts[:, 1:])
    filled = counts[:, start + window] - counts[:, start]  # (S, F) filled samples per window
    sensors, frames = np.nonzero(filled)
    few = filled[sensors, frames] > window - 4
    out[sensors[few], :, frames[few]] = q[sensors[few], :, frames[few]]
    sensors, frames = sensors[~few], frames[~few]
    samples = Windows(np.ascontiguousarray(q).reshape(-1), np.ascontiguousarray(valid).reshape(-1),
                      q.shape[1], n, window)
    for first in range(0, frames.size, REFIT_CHUNK):
        part = slice(first, first + REFIT_CHUNK)
        out[sensors[part], :, frames[part]] = samples.refit(sensors[part], start[frames[part]],
                                                            frames[part])


REFIT_CHUNK: Final[int] = 4096
"""Windows refitted at once by ``_refit_around_gaps`` (a few MB of temporaries)."""


class Windows(NamedTuple):
    """Component-major samples of S sensors, flat: ``q`` (S·C·F), ``valid`` (S·F), with C
    components, F frames and the filter's window length."""

    q: NDArray[np.float64]
    valid: NDArray[np.bool_]
    n_components: int
    n_frames: int
    window: int

    def refit(self, sensors: NDArray[np.intp], starts: NDArray[np.intp],
              frames: NDArray[np.intp]) -> NDArray[np.float64]:
        """The constant term (m, C) of the cubic (in frames from the frame itself, scaled
        by half the window) fitted by least squares to the measured samples of each
        window (its sensor, first frame and frame). Windows whose frame sits at the same
        place in them (all but those near the ends) share their powers of the offsets:
        their normal matrices are one product of the weights by the powers' products."""
        c, n, window = self.n_components, self.n_frames, self.window
        base = sensors * n + starts
        steps = np.arange(window)
        # np.take of flat indices: ~100x faster than fancy indexing of the 3-D array
        w = np.take(self.valid, base[:, None] + steps).astype(float)  # (m, W)
        rows_ = (base + sensors * (c - 1) * n)[:, None, None] + (np.arange(c) * n)[:, None] \
            + steps
        samples = np.take(self.q, rows_)  # (m, C, W)
        samples *= w[:, None, :]
        shift = starts - frames  # the offset of each window's first sample
        fitted = np.empty((frames.size, c))
        offsets = np.unique(shift).tolist()
        for offset in offsets:
            some = np.flatnonzero(shift == offset) if len(offsets) > 1 else slice(None)
            powers = ((offset + steps) / (window // 2))[:, None] ** np.arange(4)  # (W, 4)
            pairs = (powers[:, :, None] * powers[:, None, :]).reshape(window, 16)
            normal = (w[some] @ pairs).reshape(-1, 4, 4)
            rhs = (samples[some] @ powers).transpose(0, 2, 1)  # (m, 4 powers, C)
            # the polynomial's value at the frame itself: its constant term
            fitted[some] = np.linalg.solve(normal, rhs)[:, 0]
        return fitted


@dataclass(frozen=True)
class SlipOptions:
    """The model options of :func:`estimate_slip` (its keywords of the same names).

    Attributes
    ----------
    slip_hz : float
        Highest slip frequency modelled, Hz (0: no slip, the joints' plain joint fit).
    rotation_noise : float
        Per-axis variance (rad²) of the white orientation noise of the measured rotations
        (``rotation_noise_variance``); 0: no errors-in-variables correction.

    Examples
    --------
    >>> SlipOptions(slip_hz=0.25)
    SlipOptions(slip_hz=0.25, rotation_noise=0.0)
    """

    slip_hz: float = 0.5
    rotation_noise: float = 0.0

    def __post_init__(self) -> None:
        check_number(self.slip_hz, "slip_hz", low=0.0, unit=" Hz")
        check_number(self.rotation_noise, "rotation_noise", low=0.0, unit=" rad²")


def estimate_slip(
    positions: Mapping[str, NDArray[np.float64]],
    quaternions: Mapping[str, NDArray[np.float64]],
    valid: Mapping[str, NDArray[np.bool_]],
    pairs: Sequence[tuple[str, str]],
    *,
    fps: float,
    progress: Progress | None = None,
    options: SlipOptions | None = None,
    **keywords: Any,
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
    progress : callable, optional
        ``progress(fraction, "slip")``: after the rotation filter (by windows refitted
        around gaps), after each joint's rows and between the solve's steps, so that a
        long take reports often.
    options : SlipOptions, optional
        ``slip_hz`` and ``rotation_noise`` as one object; default: from ``keywords``.
    **keywords
        Instead of ``options``, its fields: ``slip_hz`` (0.5 Hz), ``rotation_noise`` (0).

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
    opt = resolved_options("estimate_slip", {"estimate_slip": SlipOptions}, options, keywords)
    sensors = sorted({s for pair in pairs for s in pair})
    n = next(iter(positions.values())).shape[0]
    layout = SlipLayout.of(sensors, len(pairs), n, fps, opt.slip_hz)
    # component-major (4, F) per sensor: each component a contiguous row (the transposes
    # of skeleton.SensorPoses' quaternions are views of such rows)
    report = progress or no_progress
    report(0.0, "slip")
    smoothed = _smoothed_rotations([np.asarray(quaternions[s]).T for s in sensors],
                                   [valid[s] for s in sensors], fps, scaled(report, 0.0, 0.4))
    rot = dict(zip(sensors, smoothed, strict=True))
    v_eiv = opt.rotation_noise * _noise_gain(n, fps)
    blocks = _joint_blocks(layout, pairs, rot, positions, valid, v_eiv=v_eiv,
                           report=scaled(report, 0.4, 0.95))
    normal, rhs_all = _assemble(layout, blocks)
    report(0.96, "slip")
    x, blocks_c = _solve_system(normal, rhs_all, layout.n_s)
    report(0.97, "slip")
    centres = x[layout.n_s:].reshape(-1, 2, 3)
    k = layout.k
    slip = {s: layout.basis @ x[layout.index[s]:layout.index[s] + 3 * k].reshape(k, 3)
            for s in sensors}
    report(0.98, "slip")
    share = tuple(block.share for block in blocks)
    if not any(block.eiv is not None for block in blocks):
        return SlipFit(slip, centres, blocks_c, (False,) * len(pairs), share)
    centres, blocks_c, corrected = _errors_in_variables(
        normal, rhs_all, layout.n_s, blocks, centres, covariances=blocks_c)
    return SlipFit(slip, centres, blocks_c, corrected, share)


def _joint_blocks(layout: SlipLayout, pairs: Sequence[tuple[str, str]],
                  rotations: Mapping[str, NDArray[np.float64]],
                  positions: Mapping[str, NDArray[np.float64]],
                  valid: Mapping[str, NDArray[np.bool_]], *, v_eiv: float,
                  report: Progress) -> list[JointBlock]:
    """``joint_block`` of each joint of ``pairs``, two at a time (``threads.run_each``;
    ``report(fraction, "slip")``), from the smoothed quaternions (4, F) by sensor."""
    n = layout.basis.shape[0]

    def block_of(j: int, a: str, b: str) -> Callable[[Report], JointBlock]:
        def task(_report: Report) -> JointBlock:
            pair = (quat.as_matrix_rows(rotations[a]), quat.as_matrix_rows(rotations[b]))
            return joint_block(layout, j, (a, b), pair,
                               np.subtract(positions[b].T, positions[a].T, out=np.empty((3, n))),
                               w=(valid[a] & valid[b]).astype(float), v_eiv=v_eiv)
        return task

    return run_each([block_of(j, a, b) for j, (a, b) in enumerate(pairs)], report, "slip",
                    frames=n)


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


def joint_block(layout: SlipLayout, j: int, pair: tuple[str, str],
                rotations: tuple[NDArray[np.float64], NDArray[np.float64]],
                d: NDArray[np.float64], *, w: NDArray[np.float64], v_eiv: float) -> JointBlock:
    """The weighted rows of joint ``j`` between sensors ``pair`` in the slip model.

    Parameters
    ----------
    layout : SlipLayout
    j : int
        The joint's number (its centres' place among the unknowns).
    pair : (str, str)
        Its sensors a and b.
    rotations : (ndarray, ndarray), shape (9, F) each
        Their smoothed sensor → world rotation matrices, component-major: row ``3i + j``
        holds the entry (i, j) of every frame's matrix.
    d : ndarray, shape (3, F)
        ``p_b − p_a``, metres, component-major.
    w : ndarray, shape (F,)
        1 where both samples are measured, else 0.
    v_eiv : float
        Orientation noise variance after smoothing, rad² (0: no correction).

    Returns
    -------
    JointBlock
    """
    k = layout.k
    # Σ_t w_t g_t cos(πj t) of the joint's series g (cosine 0: the plain sums)
    sums = cosine_sums(joint_series(rotations, d, w), 2 * k + 1)
    total = max(float(w.sum()), 1.0)
    msum = sums[0, 1:10].reshape(3, 3)  # Σ w M_t, M_t = R_aᵀ R_b
    eye3 = np.eye(3)
    plain = np.block([[total * eye3, -msum], [-msum.T, total * eye3]])
    prhs = np.concatenate([sums[0, 10:13], -sums[0, 13:16]])
    noise = _plain_noise(plain, prhs, rotations, d, w)
    row_var = noise.white + layout.unmodelled * max(noise.total - noise.white, 0.0)
    big, rhs = _slip_rows(sums, k, plain, prhs)
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


def joint_series(rotations: tuple[NDArray[np.float64], NDArray[np.float64]],
                 d: NDArray[np.float64], w: NDArray[np.float64]) -> NDArray[np.float64]:
    """The weighted series (16, F) whose sums make a joint's normal equations: ``w``, then
    ``w M_t`` (``M_t = R_aᵀR_b``, row-major), ``w R_aᵀd`` and ``w R_bᵀd``, from
    component-major rotations (9, F) and ``d`` (3, F) (as ``joint_block``), row by
    contiguous row."""
    ra, rb = rotations
    out = np.empty((16, w.shape[0]))
    out[0] = w
    for i in range(3):
        for j in range(3):
            entry = np.multiply(ra[i], rb[j], out=out[1 + 3 * i + j])
            entry += ra[3 + i] * rb[3 + j]
            entry += ra[6 + i] * rb[6 + j]
        for first, r in ((10, ra), (13, rb)):
            entry = np.multiply(r[i], d[0], out=out[first + i])
            entry += r[3 + i] * d[1]
            entry += r[6 + i] * d[2]
    out[1:] *= w
    return out


def _plain_noise(plain: NDArray[np.float64], prhs: NDArray[np.float64],
                 rotations: tuple[NDArray[np.float64], NDArray[np.float64]],
                 d: NDArray[np.float64], w: NDArray[np.float64]) -> JointNoise:
    """Total and white residual variance per axis of the plain LLSF of one joint (normal
    equations ``plain``, ``prhs``; rotations and ``d`` component-major, as
    ``joint_block``), m²; the white part from second differences, the total where too few
    frames give it, at least 1e-12."""
    c0 = np.asarray(np.linalg.lstsq(plain, prhs, rcond=None)[0], dtype=np.float64)
    ra, rb = rotations
    res = -d  # R_a c_a − R_b c_b − d, (3, F)
    for i in range(3):
        for j in range(3):
            res[i] += ra[3 * i + j] * c0[j]
            res[i] -= rb[3 * i + j] * c0[3 + j]
    use = w > 0
    total_var = float(np.mean(res[:, use] ** 2)) if use.any() else 1e-6
    white_var = white_variance(res.T, use)
    return JointNoise(total_var, max(total_var if white_var is None else white_var, 1e-12))


_CA, _CB = slice(0, 3), slice(3, 6)


def _slip_rows(sums: NDArray[np.float64], k: int, plain: NDArray[np.float64],
               prhs: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Unweighted normal-equation block (6 + 6K square) and right-hand side of one joint's
    unknowns ``[c_a, c_b, β_a, β_b]``, from the cosine sums ``sums`` (2K + 1, 16) of its
    ``joint_series``.

    With ``φ_k = √2 cos(πk t)``, ``φ_k φ_l = cos(π(k − l)t) + cos(π(k + l)t)``, so every sum
    ``Σ w φ_k φ_l g`` is ``G[|k − l|] + G[k + l]`` with ``G[j] = Σ w g cos(πj t)``: 2K + 1
    cosine sums of 16 series instead of K² products of each (8× fewer operations at
    K = 16, and no (F, K) temporaries)."""
    lags = np.arange(1, k + 1)
    pair = sums[np.abs(lags[:, None] - lags)] + sums[lags[:, None] + lags]  # (K, K, 16)
    single = np.sqrt(2.0) * sums[1:k + 1]  # Σ w φ_k g, (K, 16)
    phiphi = pair[:, :, 0]
    t_kl = pair[:, :, 1:10].reshape(k, k, 3, 3).transpose(0, 2, 1, 3).reshape(3 * k, 3 * k)
    phim = single[:, 1:10].reshape(k, 3, 3)  # Σ w φ_k M
    sum_phi = single[:, 0]
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
    rhs = np.concatenate([prhs, -single[:, 10:13].reshape(-1), single[:, 13:16].reshape(-1)])
    return big, rhs


COSINE_CHUNK: Final[int] = 8192
"""Frames per pass of ``cosine_sums`` (its cosine table: a few MB)."""


def cosine_sums(series: NDArray[np.float64], n_terms: int) -> NDArray[np.float64]:
    """``Σ_t series[:, t] cos(πj (t + ½)/F)`` for ``j < n_terms`` (the arguments of
    ``joints.slip_basis``), shape (n_terms, C), for ``series`` (C, F).

    The frames go ``COSINE_CHUNK`` at a time; the cosines of each chunk by the Chebyshev
    recurrence ``cos jθ = 2 cos θ cos (j − 1)θ − cos (j − 2)θ`` (one multiply-add per
    value instead of a cosine; its error grows as j², ~1e-13 at j = 32)."""
    n = series.shape[-1]
    out = np.zeros((n_terms, series.shape[0]))
    for first in range(0, n, COSINE_CHUNK):
        part = series[:, first:first + COSINE_CHUNK]
        table = np.empty((n_terms, part.shape[1]))
        table[0] = 1.0
        if n_terms > 1:
            np.cos(np.pi / n * (np.arange(first, first + part.shape[1]) + 0.5), out=table[1])
        for j in range(2, n_terms):
            np.multiply(table[1], table[j - 1], out=table[j])
            table[j] *= 2.0
            table[j] -= table[j - 2]
        out += table @ part.T
    return out


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


def _errors_in_variables(normal: NDArray[np.float64], rhs_all: NDArray[np.float64], n_s: int,
                         blocks: Sequence[JointBlock], centres: NDArray[np.float64], *,
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
