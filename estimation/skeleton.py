"""Skeleton (joint centres, bone lengths, segment orientations) from 6-DOF sensor recordings."""

from __future__ import annotations

import math
import time as _time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar, Final, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from . import _rows as rows
from .errors import EstimationError, InputError
from .gaps import FilledGaps, fill_sensor_major
from .joints import (
    HINGE_RULE_SD_M,
    RULE_GATE_SIGMA,
    JointFit,
    effective_samples,
    estimate_joint,
    fit_sd,
    range_of_motion,
)
from .limbs import estimate_limb, standard_lengths, torso_length
from .model import BONES, JOINT_SEGMENTS, JOINTS, LIMBS, REDUCED_SEGMENTS, SEGMENTS, Limb
from .orientations import estimate_orientations
from .params import (
    WEIGHT_MAX,
    check_fps,
    check_integer,
    check_number,
    options_of,
    resolved_options,
)
from .progress import Progress, no_progress, scaled
from .recording import SensorRecording
from .results import JointOffset, JointQuality, SkeletonResult
from .rigid import rigid_paths
from .savgol import savgol_filter
from .slip import EIV_SIGNAL_SHARE, SlipFit, estimate_slip, rotation_noise_variance
from .threads import Report, batches, ignore, run_each, staged, unstaged
from .vocabulary import OPTIMIZERS, SKELETON_METHODS, TORSO_ESTIMATORS

METHODS: Final[tuple[str, ...]] = SKELETON_METHODS

HUMAN_RANGE_M: Final[dict[str, tuple[float, float]]] = {
    "torso": (0.2, 1.0),
    "chest": (0.15, 0.9),
    "l_upperarm": (0.12, 0.55), "r_upperarm": (0.12, 0.55),
    "l_forearm": (0.1, 0.5), "r_forearm": (0.1, 0.5),
    "l_thigh": (0.2, 0.7), "r_thigh": (0.2, 0.7),
    "l_shank": (0.2, 0.7), "r_shank": (0.2, 0.7),
}
"""Plausible adult bone lengths, metres; outside them the units are probably wrong."""

_TORSO_JOINTS: Final[tuple[str, ...]] = ("l_hip", "r_hip", "l_shoulder", "r_shoulder",
                                         "waist", "neck")
# left/right joint pairs mirrored about the mid-sagittal plane of the segment carrying them
_MIRRORED_PAIRS: Final[dict[tuple[str, str], str]] = {("l_shoulder", "r_shoulder"): "chest",
                                                      ("l_hip", "r_hip"): "pelvis"}
# joints fitted by estimate_joint on the sensor positions without the shared model's slip
_DESLIPPED: Final[frozenset[str]] = frozenset(("l_wrist", "r_wrist"))
# limb joints that take their centre from the shared model where it sees enough motion
_LIMB_SHARED: Final[frozenset[str]] = frozenset(("l_elbow", "r_elbow", "l_wrist", "r_wrist",
                                                 "l_knee", "r_knee", "l_ankle", "r_ankle"))
_MIRRORED: Final[frozenset[str]] = frozenset(j for pair in _MIRRORED_PAIRS for j in pair)
# joint -> the pair of joints it sits midway between (sideways), in the same sensor frame
_MIDLINE: Final[dict[str, tuple[str, str]]] = {"waist": ("l_hip", "r_hip"),
                                               "neck": ("l_shoulder", "r_shoulder")}


NECK_RISE: Final[float] = 0.15
"""Neck prior: height above the shoulders' midpoint as a fraction of the shoulder width
(0.05–0.2 in the CMU and Bandai Namco rigs)."""
PRIOR_SIGMA_M: Final[dict[str, float]] = {"neck": 0.03, "mirror": 0.03}
"""Standard deviation of each anatomical prior, metres."""
LIMB_PRIOR_SIGMA_M: Final[float] = 0.02
# a joint whose own fit locates it to this (``quality["fit_sd_m"]``, metres) keeps it: the
# shared slip model and the priors can only add their own misfit there (issue 20 §2)
GOOD_DATA_SD_M: Final[float] = 0.002
# a torso joint's own data-only fit joins the shared model's centre (by their precisions)
# where it locates the joint to this (``quality["fit_sd_m"]``, metres): a poorer one's sd is
# itself unreliable (short takes: centres 40-100 mm off at a stated 20-40 mm; issue 20 §2)
OWN_DATA_SD_M: Final[float] = 0.005
# a joint is labelled "data" only where the recording alone locates it to this (metres,
# ``quality["data_sd_m"]``; issue 20 §4)
DATA_LABEL_SD_M: Final[float] = 0.01
"""Standard deviation (metres) of the prior that a limb joint's own robust fit (with its
hinge rule) puts on its centre from the shared slip model."""
SHARED_SD_FACTOR: Final[float] = 2.0
"""How much larger (in sd) a centre is taken to be uncertain than the shared slip model's
posterior says: along a hinge's axis, where the model meets the straight-limb rule, in a
torso joint's ``data_sd_m``, and where a torso joint's own data-only fit joins the model's
centre (``OWN_DATA_SD_M``). The model's posterior is optimistic (the example motion's
torso joints, 4 motions x 5 sensor seeds: centre error / posterior sd 1.6-2.3 RMS;
benchmark hinges along their axes, 20 pairs of seed 1: 1.5, with tails to 5)."""
SYMMETRY_SIGMA_M: Final[float] = 0.03
"""Standard deviation of the waist (neck) across the hips' (shoulders') mid-plane, metres,
when the joint's centre comes from the shared slip model."""


def estimate_chest(waist: NDArray[np.float64], neck: NDArray[np.float64],
                   l_shoulder: NDArray[np.float64], r_shoulder: NDArray[np.float64]
                   ) -> NDArray[np.float64]:
    """Chest joint C from the torso joints (Miura et al. 2015, eq. 1).

    Parameters
    ----------
    waist, neck, l_shoulder, r_shoulder : ndarray, shape (F, 3)
        World positions of W, N, LS, RS, metres.

    Returns
    -------
    ndarray, shape (F, 3)
        ``q_C = W + α (q'_C − W)/|q'_C − W|`` where ``q'_C`` is the midpoint of the common
        perpendicular of lines W–N and LS–RS and ``α = mean_t |q'_C − W|``.

    Notes
    -----
    Miura, Kaiga, Tajima, Shibata & Tamamoto, J. Inf. Process. 23(5):704–707 (2015), eq. 1.
    Parallel lines (a degenerate frame) use the foot of the perpendicular from W.
    """
    w, n, ls, rs = waist, neck, l_shoulder, r_shoulder
    d1, d2, r = n - w, rs - ls, w - ls
    a, b, c = rows.dots(d1, d1), rows.dots(d1, d2), rows.dots(d2, d2)
    d, e = rows.dots(d1, r), rows.dots(d2, r)
    ac = a * c
    den = ac - b * b
    parallel = den <= 1e-12 * np.maximum(ac, 1e-300)
    if parallel.any():
        safe = np.where(parallel, 1.0, den)
        s = np.where(parallel, 0.0, (b * e - c * d) / safe)
        t = np.where(parallel, e / np.where(c > 0, c, 1.0), (a * e - b * d) / safe)
    else:  # the selections would pick the general case everywhere: the same values
        s = (b * e - c * d) / den
        t = (a * e - b * d) / den
    # v = q'_C − W = 0.5 ((W + s d1) + (LS + t d2)) − W, the same operations in place
    # (fewer new (F, 3) arrays, whose first touch costs as much as the arithmetic); d1
    # and d2 are spent
    v = np.multiply(s[:, None], d1, out=d1)
    v += w
    tail = np.multiply(t[:, None], d2, out=d2)
    tail += ls
    v += tail
    v *= 0.5
    v -= w
    dist = rows.norms(v)
    alpha = float(np.mean(dist))
    v /= (dist if (dist > 0).all() else np.where(dist > 0, dist, 1.0))[:, None]
    v *= alpha
    v += w
    return v


def estimate_root(waist: NDArray[np.float64], l_hip: NDArray[np.float64],
                  r_hip: NDArray[np.float64]) -> NDArray[np.float64]:
    """Root R: centroid of W, LH and RH per frame (Miura et al. 2015, §2.1)."""
    return np.asarray((waist + l_hip + r_hip) / 3.0)


def _parse_up(up: ArrayLike) -> NDArray[np.float64]:
    vec = np.asarray(up, dtype=float).reshape(-1)
    if vec.shape != (3,) or not np.all(np.isfinite(vec)) or np.linalg.norm(vec) == 0:
        raise InputError(f"up must be a non-zero 3-vector, got {up!r}", field="up")
    return np.asarray(vec / np.linalg.norm(vec))


def _units_hint(length: float, low: float, high: float) -> str:
    typical = np.sqrt(low * high)
    ratio = length / typical
    for factor, unit in ((1000.0, "millimetres"), (100.0, "centimetres"),
                         (39.37, "inches"), (3.281, "feet")):
        if 0.5 * factor < ratio < 2.0 * factor:
            return f"; the positions look like {unit}: convert them to metres (or pass units)"
    return "; check the units of the positions and that each sensor carries the right name"


def _check_units(bone_lengths: Mapping[str, float], warnings: list[str]) -> None:
    """EstimationError when the bones are, as a whole, far outside human size (wrong units);
    a warning for a single implausible bone (a badly located joint)."""
    ratios = {seg: length / float(np.sqrt(np.prod(HUMAN_RANGE_M[seg])))
              for seg, length in bone_lengths.items() if seg in HUMAN_RANGE_M}
    typical = float(np.median(list(ratios.values())))
    if not 1.0 / 3.0 <= typical <= 3.0:
        seg = max(ratios, key=lambda k: abs(np.log(max(ratios[k], 1e-12))))
        low, high = HUMAN_RANGE_M[seg]
        length = bone_lengths[seg]
        raise EstimationError(
            f"the {seg} bone is {length:.3g} m long, outside the human range "
            f"{low}–{high} m{_units_hint(length, low, high)}", field=seg)
    for seg in ratios:
        low, high = HUMAN_RANGE_M[seg]
        if not low <= bone_lengths[seg] <= high:
            warnings.append(f"{seg}: bone length {bone_lengths[seg]:.3f} m is outside the "
                            f"human range {low}–{high} m; its joints are poorly located")


SMOOTH_GATE: Final[float] = 6.0
"""A smoothed sample is kept only while it moved less than this many noise sds (3-D) from
the measured one; beyond, the filter is smearing a jump of the data, not removing noise."""


def _smooth(x: NDArray[np.float64], fps: float) -> NDArray[np.float64]:
    """Zero-phase Savitzky–Golay smoothing over ~0.1 s (cubic), for white sensor noise.

    Samples that the filter would move by more than ``SMOOTH_GATE`` white-noise sds keep
    their measured value: there the path jumps (a take starting from a T-pose frame, a
    glitch) and a window spanning the jump would drag each joint of a rigid bone along its
    own polynomial, stretching the bone by up to tens of centimetres.
    """
    window = round(0.1 * fps) | 1
    if window < 5 or x.shape[0] <= window:
        return x
    smoothed = np.asarray(savgol_filter(x, window, 3, axis=0, mode="interp"))
    dd = x[2:] - 2.0 * x[1:-1] + x[:-2]
    noise = float(np.sqrt(np.sum(np.median(dd ** 2, axis=0)) / 0.4549 / 6.0))
    jumps = np.linalg.norm(smoothed - x, axis=-1) > SMOOTH_GATE * noise
    if not jumps.any():
        return smoothed
    out = x.copy()
    # smooth each stretch between jumps on its own, so no window reaches across one
    edges = np.flatnonzero(np.diff(np.concatenate([[1], jumps.astype(int), [1]])))
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        if stop - start > window:
            out[start:stop] = savgol_filter(x[start:stop], window, 3, axis=0, mode="interp")
    return out


def _unit(v: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.asarray(v / max(float(np.linalg.norm(v)), 1e-9))


def _neck_prior(fits: Mapping[str, JointFit]) -> tuple[NDArray[np.float64], float]:
    """Anatomical prior of the neck in the chest sensor's frame (point, standard deviation,
    metres): above the shoulders' midpoint, away from the waist, by ``NECK_RISE`` times the
    shoulder width (the base of the neck sits a little above the shoulder joints)."""
    left, right = fits["l_shoulder"].local_a, fits["r_shoulder"].local_a
    mid = 0.5 * (left + right)
    up = _unit(mid - fits["waist"].local_b)
    return mid + NECK_RISE * float(np.linalg.norm(left - right)) * up, PRIOR_SIGMA_M["neck"]


def _sagittal_plane(segment: str, fits: Mapping[str, JointFit]
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Mid-sagittal plane (point, unit normal) in the chest or pelvis sensor frame: through
    the waist–neck line (chest) or the waist (pelvis), normal along the left–right axis."""
    if segment == "chest":
        left, right = fits["l_shoulder"].local_a, fits["r_shoulder"].local_a
        base, top = fits["waist"].local_b, fits["neck"].local_a
    else:
        left, right = fits["l_hip"].local_a, fits["r_hip"].local_a
        base = fits["waist"].local_a
        top = base + (base - 0.5 * (left + right))
    along = _unit(top - base)
    across = left - right
    return base, _unit(across - float(across @ along) * along)


def _reflect(point: NDArray[np.float64], plane: tuple[NDArray[np.float64], NDArray[np.float64]]
             ) -> NDArray[np.float64]:
    base, normal = plane
    return np.asarray(point - 2.0 * float((point - base) @ normal) * normal)


@dataclass(frozen=True)
class Anchor:
    """How uncertain the estimated joints are that a prior is built from, in sensor a's
    frame: the covariance (3, 3) of the prior's point and the variance (m²) of a symmetry
    plane's position across it. A prior is only as certain as what it is anchored to."""

    point: NDArray[np.float64] | None = None
    plane: float = 0.0


class PairPoses(NamedTuple):
    """A joint's two sensors for ``shared_fit``: positions (F, 3) without their estimated
    slip, sensor → world rotations and valid samples (F,), of sensor a and of sensor b."""

    pa_true: NDArray[np.float64]
    ra_rot: Rotation
    pb_true: NDArray[np.float64]
    rb_rot: Rotation
    ok_a: NDArray[np.bool_]
    ok_b: NDArray[np.bool_]


class SharedPriors(NamedTuple):
    """What ``shared_fit`` combines with the shared model's centre: a symmetry plane and a
    Gaussian prior (as in ``joints.estimate_joint``), the ``Anchor`` of both, a hinge
    axis (3,) in frame a along which the prior's sd is ``joints.HINGE_RULE_SD_M`` (a limb
    joint's own fit there is its hinge rule's point), and the joint's own data-only centre
    (6,) with its precision (6, 6), m⁻² (``JointFit.data_centre``, ``data_information``)."""

    symmetry: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None
    prior: tuple[NDArray[np.float64], float] | None = None
    anchor: Anchor | None = None
    hinge_axis: NDArray[np.float64] | None = None
    own: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None


def shared_fit(fit: JointFit, shared: SlipFit, j: int, poses: PairPoses, priors: SharedPriors
               ) -> tuple[JointFit, NDArray[np.float64]]:
    """The joint's centre from the shared slip model (posterior mean and covariance of its
    centre, every sensor's slip integrated out) combined with its priors (Gaussian, in
    absolute units: a prior of ``s0`` adds ``1/s0²`` to the precision, less where its
    ``anchor`` is itself uncertain), and its path from the sensor positions without their
    estimated slip (``poses``). Along ``hinge_axis`` (in frame a) the prior is the hinge
    rule's, as wide as knees and elbows sit off their neighbours' line: the model (whose
    joints here move well above the orientation noise, ``shared_role``) outweighs it where
    it locates the centre along the axis better. With the joint's ``own`` data-only centre
    (the plain joint equation on the raw positions, slip counted as correlated noise), the
    model's precision is first made honest (``_with_own_reading``) and the two readings
    of the recording are combined by their precisions: where the joint's own data locate it
    well they are not overridden (issue 20 §2). Also returns the posterior covariance of
    the centre in frame a (3, 3)."""
    pa_true, ra_rot, pb_true, rb_rot, ok_a, ok_b = poses
    symmetry, prior, anchor, hinge_axis, own = priors
    mean = shared.centres[j].reshape(6)
    ra, rb = ra_rot.as_matrix(), rb_rot.as_matrix()
    both = ok_a & ok_b
    count = max(int(both.sum()), 1)
    # frame a to frame b over the frames: c_b = N̄ c_a + o, N̄ = mean R_bᵀR_a (frame a's
    # directions in frame b), o = mean R_bᵀ(p_a − p_b); needed only for a prior or an axis
    n_bar = (np.einsum("tji,tjk->ik", rb[both], ra[both]) / count
             if prior is not None or hinge_axis is not None or own is not None
             else np.eye(3))
    precision = _hinge_precision(shared, j, n_bar, hinge_axis, prior)
    rhs = precision @ mean
    own_share = 0.0
    if own is not None:
        precision, rhs, own_share = _with_own_reading(
            precision, mean, own, _residual_information(ra, rb, poses, n_bar, mean))
    normal = precision.copy()
    prior_precision = np.zeros((6, 6))
    if prior is not None:
        offset_b = rows.sum_transposed(rb[both], pa_true[both] - pb_true[both]) / count
        prior_precision, point = _prior_terms(prior, anchor, n_bar, offset_b, hinge_axis)
        normal += prior_precision
        rhs += prior_precision @ point
    if symmetry is not None:
        var = SYMMETRY_SIGMA_M**2 + (0.0 if anchor is None else anchor.plane)
        g = np.concatenate([symmetry[1], np.zeros(3)])
        normal += np.outer(g, g) / var
        rhs += g * float(symmetry[1] @ symmetry[0]) / var
    normal += 1e-12 * float(np.trace(normal)) * np.eye(6)
    c = np.linalg.solve(normal, rhs)
    rec_a = rows.apply(ra, c[:3]) + pa_true
    rec_b = rows.apply(rb, c[3:]) + pb_true
    gap = rec_a - rec_b
    share_b = np.where(ok_a == ok_b, 0.5, ok_b.astype(float))
    quality = dict(fit.quality)
    quality["estimator"] = "llsf-shared-slip"
    quality["rotation_noise_corrected"] = shared.corrected[j]
    quality["rms_residual_m"] = float(np.sqrt(np.mean(rows.norms(gap)[both] ** 2)))
    quality["signal_share"] = shared.signal_share[j]
    if own is not None:
        quality["own_data_share"] = own_share
    if prior is not None:
        quality.update(_prior_quality(precision, prior_precision, prior, anchor,
                                      float(np.linalg.norm(c[:3] - mean[:3]))))
    path = rec_a - share_b[:, None] * gap
    if own_share > 0.0:  # the own reading's path: its fit on the raw positions
        path = (1.0 - own_share) * path + own_share * fit.positions
    fitted = replace(fit, local_a=c[:3].copy(), local_b=c[3:].copy(), positions=path,
                     residuals=rows.norms(gap), quality=JointQuality.of(quality))
    return fitted, np.asarray(np.linalg.inv(normal)[:3, :3], dtype=np.float64)


def _hinge_precision(shared: SlipFit, j: int, n_bar: NDArray[np.float64],
                     hinge_axis: NDArray[np.float64] | None,
                     prior: tuple[NDArray[np.float64], float] | None) -> NDArray[np.float64]:
    """The shared model's precision (6, 6) of joint ``j``'s centre. Along ``hinge_axis``
    (frame a; ``n_bar`` carries it to frame b) its sd is ``SHARED_SD_FACTOR`` times
    larger and its covariance is widened by the attenuation bias orientation noise may
    leave there (the weakest eigenvalue's noise part,
    ``1 − signal_share``, times the centre's coordinate along that direction: errors in
    variables, see ``slip``), and the precision is dropped there when the model and the
    hinge rule's point (``prior``) disagree along the axis by more than
    ``joints.RULE_GATE_SIGMA`` standard deviations of their difference: the model's
    uncertainty along a hinge axis then does not hold."""
    cov = shared.covariances[j]
    if hinge_axis is None:
        return _data_precision(cov)
    axis = hinge_axis / max(float(np.linalg.norm(hinge_axis)), 1e-12)
    g = np.concatenate([axis, n_bar @ axis])
    g /= np.linalg.norm(g)
    mean = shared.centres[j].reshape(6)
    bias = (1.0 - shared.signal_share[j]) * float(g @ mean)
    widened = cov + ((SHARED_SD_FACTOR**2 - 1.0) * float(g @ cov @ g) + bias**2) \
        * np.outer(g, g)
    gap = float(axis @ (mean[:3] - prior[0])) if prior is not None else 0.0
    spread = float(axis @ widened[:3, :3] @ axis) + HINGE_RULE_SD_M**2
    precision = _data_precision(widened)
    if gap**2 <= RULE_GATE_SIGMA**2 * spread:
        return precision
    keep = np.eye(6) - np.outer(g, g)
    return np.asarray(keep @ precision @ keep, dtype=np.float64)


def _with_own_reading(precision: NDArray[np.float64], mean: NDArray[np.float64],
                      own: tuple[NDArray[np.float64], NDArray[np.float64]],
                      calibration: tuple[NDArray[np.float64], float]
                      ) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """The shared model's reading of a centre (``precision`` (6, 6), ``mean`` (6,))
    combined with the joint's ``own`` data-only one (centre (6,), precision (6, 6)): the
    combined precision, its right-hand side, and the own reading's share of it (frame a:
    1 − tr C / tr C_model, 0 where it adds nothing, 1 where it alone decides). The model's
    precision is made honest first: its covariance taken ``SHARED_SD_FACTOR``² larger,
    plus the covariance its own residual leaves, ``σ²/N_eff · N⁻¹`` of the plain joint
    equation on the positions without slip at ``mean`` (``calibration``: ``N`` (6, 6) and
    ``σ²/N_eff``, ``_residual_information``). The model's posterior counts every frame as
    independent; slip its basis does not reach (16 cosines: up to ``8 / duration`` Hz in
    takes over 16 s) stays in the residual, slow and correlated."""
    normal, v = calibration
    model = _inverse(SHARED_SD_FACTOR**2 * _inverse(precision) + v * _inverse(normal))
    combined = model + own[1]
    share = 1.0 - (fit_sd(combined) / fit_sd(model)) ** 2
    return combined, model @ mean + own[1] @ own[0], min(max(share, 0.0), 1.0)


def _residual_information(ra: NDArray[np.float64], rb: NDArray[np.float64],
                          poses: PairPoses, n_bar: NDArray[np.float64],
                          centre: NDArray[np.float64]) -> tuple[NDArray[np.float64], float]:
    """The plain joint equation's normalised normal matrix (6, 6) on the frames where both
    sensors were measured, ``[[I, −N̄ᵀ], [−N̄, I]]`` (``n_bar`` = N̄, the mean ``R_bᵀR_a``),
    and its residual's variance per unit of information ``σ²/N_eff`` (as
    ``joints.JointModel.variance_per_information``) at ``centre`` (6,) on ``poses``
    (matrices ``ra``, ``rb`` (F, 3, 3))."""
    w = (poses.ok_a & poses.ok_b).astype(float)
    res = (rows.apply(ra, centre[:3]) + poses.pa_true
           - rows.apply(rb, centre[3:]) - poses.pb_true) * w[:, None]
    sigma2 = float(np.einsum("ti,ti->", res, res)) / (3.0 * max(float(w.sum()), 1.0))
    normal = np.eye(6)
    normal[:3, 3:] = -n_bar.T
    normal[3:, :3] = -n_bar
    return normal, sigma2 / effective_samples(res, w)


def _inverse(m: NDArray[np.float64]) -> NDArray[np.float64]:
    """The inverse of a symmetric positive semi-definite (6, 6) matrix, its eigenvalues
    floored at 1e-12 of the largest (an undetermined direction gets a huge but finite
    variance)."""
    lam, vec = np.linalg.eigh(m)
    lam = np.maximum(lam, 1e-12 * max(float(lam[-1]), 1e-300))
    return np.asarray((vec / lam) @ vec.T, dtype=np.float64)


def _data_precision(cov: NDArray[np.float64]) -> NDArray[np.float64]:
    """The data's precision (6, 6) of the centre from its covariance ``cov`` (a flat prior
    leaves static directions with ~zero precision)."""
    scale = float(np.trace(cov)) / 6.0
    lam, vec = np.linalg.eigh(cov / scale)
    precision = (vec / np.maximum(lam, 1e-300)) @ vec.T / scale
    return np.asarray(precision, dtype=np.float64)


def _prior_terms(prior: tuple[NDArray[np.float64], float], anchor: Anchor | None,
                 n_bar: NDArray[np.float64], offset_b: NDArray[np.float64],
                 hinge_axis: NDArray[np.float64] | None = None
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The prior's precision (6, 6, block-diagonal: frame a, frame b) and point (6,):
    ``s0² I`` (``HINGE_RULE_SD_M²`` along ``hinge_axis``, frame a) widened by the anchor's
    covariance, the point carried to frame b by ``c_b = N̄ c_a + o``."""
    x0 = np.asarray(prior[0], dtype=float)
    x0_b = n_bar @ x0 + offset_b
    spread = np.zeros((3, 3)) if anchor is None or anchor.point is None else anchor.point
    base = prior[1] ** 2 * np.eye(3)
    if hinge_axis is not None:
        axis = hinge_axis / max(float(np.linalg.norm(hinge_axis)), 1e-12)
        base += (HINGE_RULE_SD_M**2 - prior[1] ** 2) * np.outer(axis, axis)
    prior_precision = np.zeros((6, 6))
    prior_precision[:3, :3] = np.linalg.inv(base + spread)
    prior_precision[3:, 3:] = np.linalg.inv(base + n_bar @ spread @ n_bar.T)
    return prior_precision, np.concatenate([x0, x0_b])


def _prior_quality(precision: NDArray[np.float64], prior_precision: NDArray[np.float64],
                   prior: tuple[NDArray[np.float64], float], anchor: Anchor | None,
                   shift: float) -> dict[str, Any]:
    """The quality figures of a prior: the data's share along their weakest direction, the
    prior's sd, the shift it caused (metres) and its anchor's sd."""
    lam_data, vec_data = np.linalg.eigh(precision)
    tau = float(vec_data[:, 0] @ prior_precision @ vec_data[:, 0])
    quality: dict[str, Any] = {"data_weight": float(lam_data[0]) / (float(lam_data[0]) + tau),
                               "prior_sigma_m": float(prior[1]), "prior_shift_m": shift}
    if anchor is not None and anchor.point is not None:
        quality["prior_anchor_sd_m"] = float(np.sqrt(np.trace(anchor.point) / 3.0))
    return quality


def unit_rotations(quaternions: NDArray[np.float64], norms2: NDArray[np.float64]) -> list[Rotation]:
    """``Rotation.from_quat(q.T, scalar_first=True)`` of each sensor's quaternions ``q`` in
    rows 0 to 3 of ``quaternions`` (S, 5, F), given their squared norms (S, F) as
    ``FilledGaps.norms2`` sums them: the same rotations bit for bit. The quaternions are
    normalised in place and row 4 set to row 0 (w), so that rows 1 to 4 are the unit
    quaternions in scipy's scalar-last order: the rotations wrap views of them.

    scipy normalises and reorders quaternion by quaternion into a new array (0.15 ms per
    6,283 rotations, and the first touch of new memory costs as much again); here one
    division over contiguous rows, in place. scipy reads the strided views as fast."""
    unit = quaternions[:, :4]
    np.divide(unit, np.sqrt(norms2)[:, None], out=unit)
    quaternions[:, 4] = quaternions[:, 0]
    return [Rotation(q[1:].T, normalize=False, copy=False) for q in quaternions]


@dataclass(frozen=True)
class SensorPoses:
    """The poses of the sensors used, gaps filled, by segment name."""

    positions: dict[str, NDArray[np.float64]]  # (F, 3) each, rows of ``stacked``
    rotations: dict[str, Rotation]
    ok: dict[str, NDArray[np.bool_]]  # measured (not interpolated) samples
    # (F, 4) scalar-first, filled and normalised: transposed rows, each component contiguous
    quaternions: dict[str, NDArray[np.float64]]
    stacked: NDArray[np.float64]  # (S, F, 3), sensor-major in the order used

    @classmethod
    def of(cls, recording: SensorRecording, use: Sequence[str], warnings: list[str],
           progress: Progress = no_progress) -> SensorPoses:
        """Fill the gaps of the sensors ``use``: all in one step on a short recording, sensor
        by sensor two at a time on a long one (``threads.batches``, ``threads.run_each``;
        ``progress(fraction, "gaps")``); warn about gaps longer than 0.5 s; raise InputError
        naming a sensor with no valid sample (the first in ``use``)."""
        n = recording.n_frames
        # each sensor's positions contiguous, and each component of its quaternions; a
        # fifth row per sensor for unit_rotations
        pos = np.empty((len(use), n, 3))
        quat = np.empty((len(use), 5, n))

        def fill(ks: range) -> Callable[[Report], tuple[FilledGaps, list[Rotation]]]:
            def task(_report: Report) -> tuple[FilledGaps, list[Rotation]]:
                for k in ks:
                    col = recording.index(use[k])
                    rows.copy_into(pos[k], recording.positions[:, col])
                    quat[k, :4] = recording.quaternions[:, col].T
                part = slice(ks.start, ks.stop)
                try:
                    gaps = fill_sensor_major(pos[part], quat[part, :4], time=recording.time)
                except InputError as exc:
                    if exc.sensor is None:
                        raise
                    name = use[ks.start + int(exc.sensor)]
                    raise InputError(f"sensor {name!r} has no valid sample (NaN or a zero "
                                     "quaternion in every frame)", sensor=name) from None
                return gaps, unit_rotations(quat[part], gaps.norms2)
            return task

        pieces = batches(len(use), frames=n)
        filled = run_each([fill(ks) for ks in pieces], progress, "gaps", frames=n)
        rotations, ok = {}, {}
        for ks, (gaps, rots) in zip(pieces, filled, strict=True):
            for i, k in enumerate(ks):
                rotations[use[k]], ok[use[k]] = rots[i], gaps.valid[i]
                longest = int(gaps.longest[i])
                if longest > 0.5 * recording.fps:
                    warnings.append(f"sensor {use[k]!r}: a gap of {longest / recording.fps:.2f} "
                                    "s was interpolated")
        return cls(positions={s: pos[k] for k, s in enumerate(use)}, rotations=rotations, ok=ok,
                   quaternions={s: quat[k, :4].T for k, s in enumerate(use)}, stacked=pos)


@dataclass(frozen=True, kw_only=True)
class SkeletonOptions:
    """What every method of :func:`estimate_skeleton` takes: the base of each method's options
    dataclass (``METHOD_OPTIONS``), not used alone.

    Attributes
    ----------
    up : (float, float, float)
        World up direction (segment orientations only); any non-zero 3-vector, kept as a unit
        vector.
    i0 : int
        Calibration frame of hands, feet and head orientations (paper eq. 7).
    smooth : bool
        Smooth the joint paths (Savitzky–Golay, 0.1 s); the default only for ``"auto"``.
    min_range_deg : float
        A joint whose two segments rotate less than this relative to each other
        (``joints.range_of_motion``) is still estimated, from the anatomical priors where
        ``"auto"`` has them, but flagged: ``quality[joint].reliability == "prior"`` and a
        warning naming it. When more than half of the two-sensor joints are that still, the
        recording as a whole is refused (EstimationError, ``field="motion"``).
    """

    method: ClassVar[str]
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    i0: int = 0
    smooth: bool = False
    min_range_deg: float = 2.0

    def __post_init__(self) -> None:
        if getattr(type(self), "method", None) is None:
            raise TypeError("SkeletonOptions is the base of the methods' options; use one of "
                            "METHOD_OPTIONS (AutoOptions, LlsfOptions, GdkeOptions, "
                            "ReducedOptions)")
        x, y, z = _parse_up(self.up).tolist()
        object.__setattr__(self, "up", (x, y, z))
        object.__setattr__(self, "i0", check_integer(self.i0, "i0", low=0, high=2**53))
        if not isinstance(self.smooth, bool | np.bool_):
            raise InputError(f"smooth must be true or false, got {self.smooth!r}", field="smooth")
        check_number(self.min_range_deg, "min_range_deg", low=0.0, high=180.0, unit="°")

    @property
    def plain(self) -> bool:
        """Every joint by one published estimator (``llsf`` or ``gdke``)."""
        return self.method in ("llsf", "gdke")

    @property
    def estimator(self) -> str:
        """``estimate_joint``'s method for the joints between two sensors."""
        return self.method

    @property
    def loss(self) -> str:
        """``estimate_joint``'s loss (robust for ``auto`` only)."""
        return "linear"

    def highpass(self, fps: float) -> int:
        """``estimate_joint``'s high-pass length, frames (``auto`` only)."""
        return 0


@dataclass(frozen=True, kw_only=True)
class LlsfOptions(SkeletonOptions):
    """Options of ``method="llsf"``: every joint between two sensors by LLSF as published
    (plain least squares, no hinge rule); needs all 15 sensors. Fields: those of
    :class:`SkeletonOptions`.

    Examples
    --------
    >>> LlsfOptions(smooth=True, up=(0, 0, 2)).up
    (0.0, 0.0, 1.0)
    """

    method: ClassVar[str] = "llsf"


@dataclass(frozen=True, kw_only=True)
class GdkeOptions(SkeletonOptions):
    """Options of ``method="gdke"``: as :class:`LlsfOptions` with GDKE for every joint."""

    method: ClassVar[str] = "gdke"


@dataclass(frozen=True, kw_only=True)
class VarianceCostOptions(SkeletonOptions):
    """What the methods that fit limbs by the paper's variance cost E (``reduced``, and
    ``auto`` for a limb without its middle sensor) add to :class:`SkeletonOptions`.

    Attributes
    ----------
    anthropometry : str or mapping
        Table of standard segment lengths (``limbs.standard_lengths``).
    w_s, w_l : float
        Weights of the paper's eq. 5 (0 … ``params.WEIGHT_MAX``).
    """

    anthropometry: str | Mapping[str, float] = "aist"
    w_s: float = 0.01
    w_l: float = 0.01

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("w_s", "w_l"):
            check_number(getattr(self, name), name, low=0.0, high=WEIGHT_MAX)


@dataclass(frozen=True, kw_only=True)
class ReducedOptions(VarianceCostOptions):
    """Options of ``method="reduced"``: the paper exactly. The torso joints by ``torso``, root
    and chest by eq. 1, the four limbs by the variance cost E (eqs. 2–5,
    ``limbs.estimate_limb(method="paper")``) from the thigh/foot and upper-arm/hand sensors;
    works with 11 or 15 sensors (extra sensors are ignored).

    Attributes
    ----------
    optimizer : {"least-squares", "nelder-mead"}
        Minimiser of E.
    torso : {"llsf", "gdke"}
        Estimator of the torso joints.

    Examples
    --------
    >>> ReducedOptions(optimizer="nelder-mead", torso="gdke").estimator
    'gdke'
    """

    method: ClassVar[str] = "reduced"
    optimizer: str = "least-squares"
    torso: str = "llsf"

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.optimizer not in OPTIMIZERS:
            raise InputError(f"unknown optimizer {self.optimizer!r}; use "
                             f"{' or '.join(OPTIMIZERS)}", field="optimizer")
        if self.torso not in TORSO_ESTIMATORS:
            raise InputError(f"unknown torso estimator {self.torso!r}; use "
                             f"{' or '.join(TORSO_ESTIMATORS)}", field="torso")

    @property
    def estimator(self) -> str:
        """``torso``: the estimator of the torso joints."""
        return self.torso


@dataclass(frozen=True, kw_only=True)
class AutoOptions(VarianceCostOptions):
    """Options of ``method="auto"`` (the default): every sensor present and the best estimator
    per joint.

    Every sensor's soft-tissue slip from all the joint equations at once
    (``slip.estimate_slip``, corrected for the attenuation bias of orientation noise where
    the motion is well above it), the torso joints (waist, neck, shoulders, hips) from that
    shared model with their anatomical priors (below) and, where it locates them to
    ``OWN_DATA_SD_M``, their own data-only fit (both readings by their precisions, the
    model's made honest; paths mixed alike), robust LLSF (Huber IRLS) for the limb
    joints, hinge knees and elbows resolved by the straight-limb rule, wrists fitted on the
    positions without slip and, when they twist, placed by the bone-length rule
    (``joints.estimate_joint``); limb joints whose motion is well above the orientation noise
    (``SlipFit.signal_share`` at least ``slip.EIV_SIGNAL_SHARE``) then take their centre from
    the shared model, with that fit as a prior (``LIMB_PRIOR_SIGMA_M``; along a hinge axis,
    where that fit is the straight-limb rule's point, ``joints.HINGE_RULE_SD_M``); limbs
    whose middle sensor is missing by
    ``estimate_limb(method="improved")`` on the frames in which both their sensors were
    measured, and zero-phase smoothing of the joint paths. Gap-filled samples never enter a
    fit (nor, through the slip model's rotation filter, the frames around them); the joints
    are placed in every frame.

    Attributes
    ----------
    smooth : bool
        As in :class:`SkeletonOptions`, default True.
    highpass_s : float
        Remove a moving average of this length (seconds, 0 … 60) from each LLSF system,
        cancelling sensor slip slower than the motion (0: off, the default; see
        ``joints.estimate_joint(highpass=...)``).
    slip_hz : float
        Model each sensor's soft-tissue slip below this frequency (at most half the frame
        rate) as a smooth displacement in its frame, estimated from the equations of all
        joints at once (``slip.estimate_slip``; 0: off: the torso joints are then fitted one
        by one by ``joints.estimate_joint``, the wrists without a slip model). Not used with
        ``highpass_s``.

    Notes
    -----
    Priors (Gaussian priors on the centre, in both sensor frames; with the shared slip
    model their precision ``1/s0²`` is added to the posterior precision of the joint's
    centre, every sensor's slip integrated out; without it,
    ``joints.estimate_joint(prior=...)`` weighs them by ``σ²/(N_eff s0²)`` against the data;
    either way they act only along the directions the motion leaves undetermined):

    - neck: ``NECK_RISE`` × shoulder width above the shoulders' midpoint, away from the
      waist, in the chest sensor's frame (``s0 = PRIOR_SIGMA_M["neck"]``);
    - shoulders and hips: the mirror image of the opposite joint about the trunk's
      mid-sagittal plane (through the waist–neck line, normal along the left–right axis;
      for the pelvis through the waist), ``s0 = PRIOR_SIGMA_M["mirror"]``. Left/right
      symmetry of the skeleton does not depend on where the sensors sit;
    - waist and neck: the mid-plane between the hips (shoulders), ``s0 =
      SYMMETRY_SIGMA_M`` across it (``estimate_joint(symmetry_weight=0.01)`` of the
      normalised LLSF cost without the shared model).

    These priors are built from other estimated joints; with the shared model each one's
    covariance is widened by those joints' posterior covariance (the neck's by that of the
    shoulders' midpoint, a mirror image's by that of the mirrored joint, a mid-plane's by
    that of the pair's midpoint across it), so a prior anchored on joints that barely move
    pulls less (``quality[joint].details["prior_anchor_sd_m"]``).

    Quality per joint: ``reliability`` is ``"data"``, ``"prior-assisted"`` (the prior
    carries more than half the weight along the weakest direction) or ``"prior"`` (the joint
    rotates less than ``min_range_deg``). With the shared slip model, every joint between two
    sensors also has ``data_sd_m``: the standard deviation (metres, root of the trace of its
    covariance in the first sensor's frame) of its centre from the recording alone, before
    any prior or hinge rule; along a hinge's axis, where orientation noise passes for
    rotation, it is optimistic.

    Examples
    --------
    >>> opt = AutoOptions(slip_hz=0.0, smooth=False)
    >>> opt.method, opt.loss, opt.highpass(100.0)
    ('auto', 'huber', 0)
    """

    method: ClassVar[str] = "auto"
    smooth: bool = True
    highpass_s: float = 0.0
    slip_hz: float = 0.5

    def __post_init__(self) -> None:
        super().__post_init__()
        check_number(self.highpass_s, "highpass_s", low=0.0, high=60.0, unit=" s")
        check_number(self.slip_hz, "slip_hz", low=0.0, unit=" Hz")  # ≤ fps/2: check_recording

    @property
    def estimator(self) -> str:
        """LLSF (robust) for the joints between two sensors."""
        return "llsf"

    @property
    def loss(self) -> str:
        """Huber IRLS."""
        return "huber"

    def highpass(self, fps: float) -> int:
        """``highpass_s`` in frames at ``fps``."""
        return round(self.highpass_s * fps)


METHOD_OPTIONS: Final[dict[str, type[SkeletonOptions]]] = {
    "auto": AutoOptions, "llsf": LlsfOptions, "gdke": GdkeOptions, "reduced": ReducedOptions}
"""The options dataclass of each method of :func:`estimate_skeleton`."""


def skeleton_options(method: str, values: Mapping[str, Any]) -> SkeletonOptions:
    """The options of ``method`` from keyword values, checked.

    Parameters
    ----------
    method : {"auto", "llsf", "gdke", "reduced"}
    values : mapping of str to object
        Field values of ``METHOD_OPTIONS[method]``; missing fields take their defaults.

    Returns
    -------
    SkeletonOptions
        An ``AutoOptions``, ``LlsfOptions``, ``GdkeOptions`` or ``ReducedOptions``.

    Raises
    ------
    InputError
        Unknown method, an option the method does not take (``field`` names the first) or a
        value out of range (``field`` names it).

    Examples
    --------
    >>> skeleton_options("reduced", {"optimizer": "nelder-mead"})
    ReducedOptions(up=(0.0, 1.0, 0.0), i0=0, smooth=False, min_range_deg=2.0, \
anthropometry='aist', w_s=0.01, w_l=0.01, optimizer='nelder-mead', torso='llsf')
    """
    return options_of(method, METHOD_OPTIONS, values)


def check_recording(recording: SensorRecording, options: SkeletonOptions) -> None:
    """Refuse a recording ``options`` cannot be applied to: a frame rate outside
    ``params.MIN_FPS`` … ``MAX_FPS``, ``slip_hz`` above half of it, ``i0`` outside the frames
    (InputError naming the field), fewer than 10 frames (EstimationError)."""
    check_fps(recording.fps)
    if isinstance(options, AutoOptions):
        check_number(options.slip_hz, "slip_hz", low=0.0, high=recording.fps / 2, unit=" Hz")
    _check_frames(recording, options.i0)


def _check_frames(recording: SensorRecording, i0: int) -> None:
    n_frames = recording.n_frames
    if not 0 <= i0 < max(n_frames, 1):
        raise InputError(f"i0={i0} is outside the recording's {n_frames} frames", field="i0")
    if n_frames < 10:
        raise EstimationError(f"the recording has {n_frames} frames; at least 10 are needed",
                              field="frames")


def sensors_used(recording: SensorRecording, method: str, warnings: list[str],
                 progress: Progress = no_progress) -> SensorPoses:
    """The poses of the sensors ``method`` uses (every one present; the 11 of the reduced
    suit for ``reduced``), gaps filled (``progress(fraction, "gaps")``); InputError naming a
    missing sensor, EstimationError when no sensor moves."""
    required: Sequence[str] = SEGMENTS if method in ("llsf", "gdke") else REDUCED_SEGMENTS
    for seg in required:
        recording.index(seg)  # raises InputError naming the missing sensor
    use = list(REDUCED_SEGMENTS) if method == "reduced" else [
        s for s in SEGMENTS if s in recording.sensors]
    sensors = SensorPoses.of(recording, use, warnings, progress)
    # every sample equal to its sensor's first one: one elementwise pass
    stacked = sensors.stacked
    if not (np.any(stacked[:, -1] != stacked[:, 0]) or np.any(stacked != stacked[:, :1])):
        raise EstimationError("no sensor moves: a recording with motion of every joint is "
                              "needed", field="motion")
    return sensors


class JointMotion(NamedTuple):
    """How much each joint between two sensors of a recording rotates."""

    pairs: list[str]  # the joints fitted between two sensors, in model order
    rom: dict[str, float]  # range of motion, degrees (``joints.range_of_motion``)
    static: list[str]  # the joints rotating less than ``min_range_deg``


def joint_motion(sensors: SensorPoses, method: str, min_range_deg: float,
                 progress: Progress = no_progress) -> JointMotion:
    """Every two-sensor joint's range of motion (the torso's only for ``reduced``): a joint
    that barely rotates is located from priors and flagged; only a recording in which most
    joints barely rotate is refused (EstimationError)."""
    positions, quat, ok = sensors.positions, sensors.quaternions, sensors.ok
    pairs = [j for j, (a, b) in JOINT_SEGMENTS.items() if a in positions and b in positions
             and (method != "reduced" or j in _TORSO_JOINTS)]

    def rom_of(a: str, b: str) -> Callable[[Report], float]:
        def task(_report: Report) -> float:
            return range_of_motion(quat[a], quat[b], ok[a] & ok[b])
        return task

    ranges = run_each([rom_of(*JOINT_SEGMENTS[j]) for j in pairs], progress, "gaps",
                      frames=sensors.stacked.shape[1])
    rom = dict(zip(pairs, ranges, strict=True))
    static = [j for j in pairs if rom[j] < min_range_deg]
    if 2 * len(static) > len(pairs):
        raise EstimationError(
            f"too little motion: {len(static)} of {len(pairs)} joints rotate less than "
            f"{min_range_deg:g}° ({', '.join(static)}); record a calibration motion of every "
            "joint", field="motion")
    return JointMotion(pairs, rom, static)


@dataclass(frozen=True, eq=False)
class SharedSlip:
    """Every sensor's soft-tissue slip from all the joint equations at once
    (``slip.estimate_slip``): the torso joints take their centres from it, the wrists are
    fitted on the positions without it."""

    fit: SlipFit  # its ``slip`` emptied: removed from the positions into ``without_slip``
    without_slip: dict[str, NDArray[np.float64]]  # each sensor's p − R s, (F, 3)
    index: dict[str, int]  # joint -> its row in ``fit``


def shared_slip(sensors: SensorPoses, pairs: Sequence[str], fps: float, slip_hz: float,
                progress: Progress = no_progress) -> SharedSlip:
    """The shared slip model of the joints ``pairs``, corrected for orientation noise."""
    by_sensor = {s: sensors.quaternions[s] for s in sensors.positions}
    # orientation noise biases the centres of joints that rotate a few degrees toward their
    # sensors (errors in variables); the shared model corrects for it
    noise = rotation_noise_variance(by_sensor, sensors.ok, progress=scaled(progress, 0.0, 0.1))
    fit = estimate_slip(sensors.positions, by_sensor, sensors.ok,
                        [JOINT_SEGMENTS[j] for j in pairs], fps=fps, slip_hz=slip_hz,
                        rotation_noise=noise, progress=scaled(progress, 0.1, 0.9))

    def without_slip(s: str) -> Callable[[Report], NDArray[np.float64]]:
        def task(_report: Report) -> NDArray[np.float64]:
            return sensors.positions[s] - rows.apply_each(sensors.rotations[s].as_matrix(),
                                                          fit.slip[s])
        return task

    without = dict(zip(fit.slip, run_each([without_slip(s) for s in fit.slip],
                                          scaled(progress, 0.9, 1.0), "slip",
                                          frames=sensors.stacked.shape[1]), strict=True))
    # the slips live on in ``without``; not keeping them saves (F, 3) per sensor
    return SharedSlip(replace(fit, slip={}), without, {j: i for i, j in enumerate(pairs)})


@dataclass(frozen=True, eq=False)
class SkeletonContext:
    """What every joint's fit in one ``estimate_skeleton`` call shares."""

    sensors: SensorPoses
    options: SkeletonOptions
    motion: JointMotion
    shared: SharedSlip | None
    highpass: int  # frames
    # rotation matrices (F, 3, 3) of sensors that several joints of a stage share, converted
    # once for it (``locate_torso``'s own context); empty otherwise
    matrices: dict[str, NDArray[np.float64]] = field(default_factory=dict)


def skeleton_context(sensors: SensorPoses, options: SkeletonOptions, fps: float,
                     progress: Progress = no_progress) -> SkeletonContext:
    """The context of a fit: each joint's motion, and the shared slip model when ``auto``
    uses it (``slip_hz`` > 0 and no high-pass). ``progress``: the ranges of motion (stage
    ``gaps``) up to 0.15, the slip model (``slip``) from there."""
    motion = joint_motion(sensors, options.method, options.min_range_deg,
                          scaled(progress, 0.0, 0.15))
    highpass = options.highpass(fps)
    shared = (shared_slip(sensors, motion.pairs, fps, options.slip_hz,
                          scaled(progress, 0.15, 1.0))
              if isinstance(options, AutoOptions) and options.slip_hz > 0 and highpass <= 1
              else None)
    return SkeletonContext(sensors, options, motion, shared, highpass)


@dataclass(frozen=True, eq=False)
class JointPlan:
    """How one joint between two sensors is located: its estimator and what
    ``joints.estimate_joint`` and the shared model get for it."""

    name: str
    estimator: str
    neighbours: tuple[NDArray[np.float64] | None, NDArray[np.float64] | None] = (None, None)
    bone_length: float | None = None
    symmetry: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None
    prior: tuple[NDArray[np.float64], float] | None = None
    anchor: Anchor | None = None
    quiet: bool = False  # its warnings wait for a refit


def shared_role(ctx: SkeletonContext, name: str) -> str | None:
    """Whether and how a joint joins the shared slip model: ``"torso"`` (its centre from
    the model with its anatomical priors), ``"limb"`` (a limb joint moving well above the
    orientation noise: the model's centre with its own robust fit as a prior) or None."""
    shared = ctx.shared
    if shared is None:
        return None
    if name in _TORSO_JOINTS:
        return "torso"
    if name in _LIMB_SHARED and name in shared.index \
            and shared.fit.signal_share[shared.index[name]] >= EIV_SIGNAL_SHARE:
        return "limb"
    return None


def own_fit(ctx: SkeletonContext, plan: JointPlan, report: Report = ignore) -> JointFit:
    """``joints.estimate_joint`` of the joint (for the wrists, when the shared model runs
    and the raw positions do not locate them to ``GOOD_DATA_SD_M``, on the positions
    without slip); EstimationError naming the joint. ``report(fraction)`` within."""
    a, b = JOINT_SEGMENTS[plan.name]
    sensors = ctx.sensors
    refit = ctx.shared is not None and plan.name in _DESLIPPED
    fit = _fit_on(ctx, plan, sensors.positions[a], sensors.positions[b],
                  scaled(unstaged(report), 0.0, 0.5 if refit else 1.0))
    if ctx.shared is not None and refit and fit.quality["fit_sd_m"] > GOOD_DATA_SD_M:
        fit = _fit_on(ctx, plan, ctx.shared.without_slip[a], ctx.shared.without_slip[b],
                      scaled(unstaged(report), 0.5, 1.0))
    return fit


def _fit_on(ctx: SkeletonContext, plan: JointPlan, pa: NDArray[np.float64],
            pb: NDArray[np.float64], progress: Progress) -> JointFit:
    """``estimate_joint`` of the joint on the sensor positions ``pa``, ``pb``; with ``auto``
    the data alone decide where they locate the centre to ``GOOD_DATA_SD_M``."""
    a, b = JOINT_SEGMENTS[plan.name]
    sensors, opt = ctx.sensors, ctx.options
    auto = opt.method == "auto"
    rom = ctx.motion.rom.get(plan.name)
    # the torso's matrices where converted: estimate_joint takes them with a measured range
    ra, rb = ((ctx.matrices.get(a, sensors.rotations[a]),
               ctx.matrices.get(b, sensors.rotations[b]))
              if rom is not None else (sensors.rotations[a], sensors.rotations[b]))
    try:
        return estimate_joint(
            pa, ra, pb, rb, method=plan.estimator,
            # (F, 2) as a transposed view: each sensor's column contiguous
            loss=opt.loss, valid=np.stack([sensors.ok[a], sensors.ok[b]]).T,
            neighbours=plan.neighbours, hinge_prior=0.0 if opt.plain else 0.01,
            trust_data_sd_m=GOOD_DATA_SD_M if auto else 0.0,
            highpass=ctx.highpass, bone_length=plan.bone_length, min_range_deg=0.0,
            symmetry=plan.symmetry, prior=plan.prior if auto else None,
            range_of_motion_deg=rom, progress=progress)
    except EstimationError as exc:
        raise EstimationError(f"{plan.name}: {exc.detail}", field=plan.name) from None


class LocatedJoint(NamedTuple):
    """A joint's final fit, ``estimate_joint``'s own one and, with the shared model, the
    posterior covariance (3, 3) of its centre in the first sensor's frame."""

    fit: JointFit
    own: JointFit
    posterior: NDArray[np.float64] | None


def locate_joint(ctx: SkeletonContext, plan: JointPlan, own: JointFit | None = None,
                 report: Report = ignore) -> LocatedJoint:
    """Locate a joint by its plan. ``own``: its earlier ``estimate_joint`` fit, reused for
    a torso joint whose centre comes from the shared model (a refit with another prior
    would not change its quality figures). ``report(fraction)`` within its own fit."""
    role = shared_role(ctx, plan.name)
    if role != "torso" or own is None:
        own = own_fit(ctx, plan, report)
    fit, posterior = own, None
    if role is not None and own.quality.get("fit_sd_m", math.inf) <= GOOD_DATA_SD_M:
        role = None
    if ctx.shared is not None and role is not None:
        a, b = JOINT_SEGMENTS[plan.name]
        sensors, without = ctx.sensors, ctx.shared.without_slip
        axis = own.quality.get("axis") if own.quality.get("hinge") else None
        poses = PairPoses(without[a], sensors.rotations[a], without[b], sensors.rotations[b],
                          sensors.ok[a], sensors.ok[b])
        data = (None if own.data_centre is None or own.data_information is None
                or own.quality.get("fit_sd_m", math.inf) > OWN_DATA_SD_M
                else (own.data_centre, own.data_information))
        priors = (SharedPriors(plan.symmetry, plan.prior, plan.anchor, own=data)
                  if role == "torso"
                  else SharedPriors(prior=(own.local_a, LIMB_PRIOR_SIGMA_M),
                                    hinge_axis=None if axis is None
                                    else np.asarray(axis, dtype=float)))
        fit, posterior = shared_fit(own, ctx.shared.fit, ctx.shared.index[plan.name], poses,
                                    priors)
    return LocatedJoint(_with_reliability(ctx, plan, _with_data_sd(ctx, plan.name, fit)), own,
                        posterior)


def _with_data_sd(ctx: SkeletonContext, name: str, fit: JointFit) -> JointFit:
    """How well the recording alone locates the centre (``data_sd_m``, frame a). For a torso
    joint that moves well above the orientation noise (``signal_share`` at least
    ``slip.EIV_SIGNAL_SHARE``), whose centre the shared model gives: ``SHARED_SD_FACTOR``
    times the model's posterior sd with a flat prior (every sensor's slip integrated out;
    ``shared_sd_m``). Otherwise the larger of that sd and the joint's own data-only fit's
    (``fit_sd_m``, slip counted as correlated noise, pessimistic by about 5x where the
    shared model applies: the example motion's neck, 11 mm against errors of 2-6 mm): the
    shared model alone is overconfident along a hinge's axis and for joints that rotate a
    few degrees (orientation noise passes for motion)."""
    if ctx.shared is None or name not in ctx.shared.index:
        return fit
    j = ctx.shared.index[name]
    cov_a = ctx.shared.fit.covariances[j][:3, :3]
    shared_sd = float(np.sqrt(np.trace(cov_a)))
    if name in _TORSO_JOINTS and ctx.shared.fit.signal_share[j] >= EIV_SIGNAL_SHARE:
        sd = SHARED_SD_FACTOR * shared_sd
    else:
        sd = max(shared_sd, float(fit.quality.get("fit_sd_m", 0.0)))
    return replace(fit, quality=JointQuality.of(
        {**fit.quality, "shared_sd_m": shared_sd, "data_sd_m": sd}))


def _with_reliability(ctx: SkeletonContext, plan: JointPlan, fit: JointFit) -> JointFit:
    """``quality["reliability"]``, and the warning of a joint that barely rotates. "data"
    only where the data carry the estimate (``data_weight`` >= 0.5) and locate it to
    ``DATA_LABEL_SD_M``."""
    name = plan.name
    if name in ctx.motion.static:
        source = ("anatomical priors" if plan.prior is not None or plan.neighbours[0] is not None
                  else "the few frames available")
        note = (f"rotates only {ctx.motion.rom[name]:.1f}° (< {ctx.options.min_range_deg:g}°): "
                f"located from {source}, unreliable")
        return replace(fit, quality=JointQuality.of({**fit.quality, "reliability": "prior"}),
                       warnings=(note, *(w for w in fit.warnings
                                         if not w.startswith("small range"))))
    assisted = (fit.quality.get("data_weight", 1.0) < 0.5
                or fit.quality.get("data_sd_m", 0.0) > DATA_LABEL_SD_M)
    label = "prior-assisted" if assisted else "data"
    return replace(fit, quality=JointQuality.of({**fit.quality, "reliability": label}))


@dataclass(eq=False)
class LocatedJoints:
    """The joints located so far in one ``estimate_skeleton`` call, and its warnings."""

    warnings: list[str]
    fits: dict[str, JointFit] = field(default_factory=dict)
    # estimate_joint's own fits of the joints that reuse them (torso, shared model)
    own: dict[str, JointFit] = field(default_factory=dict)
    # the shared model's posterior covariance of each centre, frame a
    posterior: dict[str, NDArray[np.float64]] = field(default_factory=dict)
    joints: dict[str, NDArray[np.float64]] = field(default_factory=dict)
    offsets: dict[str, JointOffset] = field(default_factory=dict)
    quality: dict[str, Mapping[str, Any]] = field(default_factory=dict)

    def locate(self, ctx: SkeletonContext, plan: JointPlan, report: Report = ignore
               ) -> JointFit:
        """Locate a joint by its plan, keep its own fit and posterior, and warn (unless
        ``plan.quiet``); the fit is not recorded (``record``). ``report(fraction)``
        within."""
        found = locate_joint(ctx, plan, self.own.get(plan.name), report)
        if shared_role(ctx, plan.name) == "torso":  # the only ones reused (locate_joint)
            self.own[plan.name] = found.own
        if found.posterior is not None:
            self.posterior[plan.name] = found.posterior
        if not plan.quiet:
            self.warnings.extend(f"{plan.name}: {w}" for w in found.fit.warnings)
        return found.fit

    def branch(self) -> LocatedJoints:
        """An empty record for one limb located on its own (``run_each``), seeing the joints
        and reused fits located so far; ``merge`` takes it back."""
        return LocatedJoints(warnings=[], own=dict(self.own), joints=dict(self.joints))

    def merge(self, branch: LocatedJoints) -> None:
        """Take what ``branch`` located, and its warnings after the ones so far."""
        self.warnings.extend(branch.warnings)
        self.fits.update(branch.fits)
        self.own.update(branch.own)
        self.posterior.update(branch.posterior)
        self.joints.update(branch.joints)
        self.offsets.update(branch.offsets)
        self.quality.update(branch.quality)

    def release(self) -> None:
        """Drop the fits once every joint is located: their paths are in ``joints``, which
        ``_smoothed`` then replaces path by path (a long take's memory)."""
        self.fits.clear()
        self.own.clear()
        self.posterior.clear()

    def record(self, name: str, fit: JointFit) -> None:
        """Take ``fit`` as the joint's result."""
        self.fits[name] = fit
        self.joints[name] = fit.positions
        self.offsets[name] = JointOffset(JOINT_SEGMENTS[name][0], fit.local_a)
        self.quality[name] = fit.quality


def torso_plan(ctx: SkeletonContext, located: LocatedJoints, name: str) -> JointPlan:
    """The first plan of a torso joint: with ``auto``, the waist and neck on the mid-plane
    of the hips (shoulders), as uncertain as the pair's midpoint, and the neck's prior."""
    auto = ctx.options.method == "auto"
    sym = None
    anchor = None
    if name in _MIDLINE and auto:
        pair = _MIDLINE[name]
        left, right = (located.fits[j].local_a for j in pair)
        across = left - right
        sym = (0.5 * (left + right), across / max(float(np.linalg.norm(across)), 1e-9))
        if all(j in located.posterior for j in pair):
            # the mid-plane and the neck prior are as uncertain as the pair's midpoint
            spread = 0.25 * (located.posterior[pair[0]] + located.posterior[pair[1]])
            anchor = Anchor(point=spread if name == "neck" else None,
                            plane=float(sym[1] @ spread @ sym[1]))
    prior = _neck_prior(located.fits) if name == "neck" and auto else None
    # shoulders and hips are refitted with their mirror priors: warn only then
    return JointPlan(name, ctx.options.estimator, symmetry=sym, prior=prior, anchor=anchor,
                     quiet=auto and name in _MIRRORED)


def locate_torso(ctx: SkeletonContext, located: LocatedJoints, report: Progress) -> None:
    """The six torso joints, in ``_TORSO_JOINTS`` order: the hips and shoulders, which need
    no other joint, two at a time (``threads.run_each``, each on a ``branch`` of
    ``located``, merged in that order), then the waist and the neck between them;
    ``report(fraction, "torso")`` as they are located."""
    first = [name for name in _TORSO_JOINTS if name not in _MIDLINE]
    rotations = ctx.sensors.rotations
    # each torso sensor serves up to three joints: its matrices converted once, held only
    # while the torso is located (7 × F × 72 bytes)
    ctx = replace(ctx, matrices={s: rotations[s].as_matrix() for s in dict.fromkeys(
        s for name in _TORSO_JOINTS for s in JOINT_SEGMENTS[name])})

    def locate_alone(name: str) -> Callable[[Report], LocatedJoints]:
        def task(report_joint: Report) -> LocatedJoints:
            branch = located.branch()
            branch.record(name, branch.locate(ctx, torso_plan(ctx, branch, name),
                                              report_joint))
            return branch
        return task

    share = len(first) / len(_TORSO_JOINTS)
    for branch in run_each([locate_alone(name) for name in first], scaled(report, 0.0, share),
                           "torso", frames=ctx.sensors.stacked.shape[1]):
        located.merge(branch)
    for k, name in enumerate(_MIDLINE):
        step = (1 - share) / len(_MIDLINE)
        within = scaled(report, share + k * step, share + (k + 1) * step)
        located.record(name, located.locate(ctx, torso_plan(ctx, located, name),
                                            staged(within, "torso")))


def mirror_torso(ctx: SkeletonContext, located: LocatedJoints,
                 report: Progress = no_progress) -> None:
    """Left/right symmetry: each shoulder (hip) refitted with a prior toward the mirror image
    of the other about the trunk's mid-sagittal plane, along its weakly excited
    directions. ``report(fraction, "torso")`` after each of the four."""
    fits = located.fits
    for p, (pair, seg) in enumerate(_MIRRORED_PAIRS.items()):
        plane = _sagittal_plane(seg, fits)
        mirrored = {a: _reflect(fits[b].local_a, plane) for a, b in (pair, pair[::-1])}
        # the mirror image is as uncertain as the joint it mirrors
        flip = np.eye(3) - 2.0 * np.outer(plane[1], plane[1])
        anchors = {a: Anchor(point=flip @ located.posterior[b] @ flip)
                   for a, b in (pair, pair[::-1]) if b in located.posterior}
        for i, name in enumerate(pair):
            plan = JointPlan(name, ctx.options.estimator,
                             prior=(mirrored[name], PRIOR_SIGMA_M["mirror"]),
                             anchor=anchors.get(name))
            located.record(name, located.locate(ctx, plan))
            report((2 * p + i + 1) / (2 * len(_MIRRORED_PAIRS)), "torso")


def derived_torso(ctx: SkeletonContext, located: LocatedJoints) -> None:
    """Root and chest from the torso joints (Miura et al. 2015, §2.1 and eq. 1)."""
    joints, offsets = located.joints, located.offsets
    joints["root"] = estimate_root(joints["waist"], joints["l_hip"], joints["r_hip"])
    joints["chest"] = estimate_chest(joints["waist"], joints["neck"], joints["l_shoulder"],
                                     joints["r_shoulder"])
    offsets["root"] = JointOffset("pelvis", (offsets["waist"].local + offsets["l_hip"].local
                                             + offsets["r_hip"].local) / 3.0)
    # the mean of R_tᵀ (C − p) over the frames: the chest joint in the chest sensor's frame
    sensors = ctx.sensors
    chest_local = rows.sum_transposed(sensors.rotations["chest"].as_matrix(),
                                      joints["chest"] - sensors.positions["chest"]
                                      ) / joints["chest"].shape[0]
    offsets["chest"] = JointOffset("chest", chest_local)
    located.quality["root"] = {"estimator": "centroid of waist and hips (paper §2.1)"}
    located.quality["chest"] = {"estimator": "eq. 1 of the paper", "alpha_m": float(
        rows.norms(joints["chest"] - joints["waist"]).mean())}


def locate_limb_joints(ctx: SkeletonContext, located: LocatedJoints, limb: Limb,
                       std: Mapping[str, float], stage: Progress = no_progress) -> None:
    """A limb with its middle sensor: the distal joint, the middle one (with the straight-limb
    rule), and for ``auto`` arms the wrist again with its hinge rule; ``stage(fraction,
    "limbs")`` after each fit."""
    prox, mid, dist = limb.joints
    estimator = ctx.options.estimator
    plain = ctx.options.plain
    refit_wrist = not plain and limb.is_arm
    d_fit = located.locate(ctx, JointPlan(dist, estimator, quiet=refit_wrist),
                           staged(scaled(stage, 0.0, 1 / 3), "limbs"))
    neighbours = (None, None) if plain else (located.joints[prox], d_fit.positions)
    m_fit = located.locate(ctx, JointPlan(mid, estimator, neighbours),
                           staged(scaled(stage, 1 / 3, 2 / 3), "limbs"))
    if refit_wrist and mid in ctx.motion.static:
        # an elbow located from priors would carry its error into the wrist's rule
        located.warnings.extend(f"{dist}: {w}" for w in d_fit.warnings)
    elif refit_wrist:
        # the wrist's own hinge rule needs the elbow, and the forearm length when the wrist
        # mostly twists about the forearm: the measured upper arm times the table's forearm /
        # upper-arm ratio
        upper_len = float(rows.norms(m_fit.positions - located.joints[prox]).mean())
        forearm = upper_len * std["forearm"] / std["upperarm"]
        d_fit = located.locate(ctx, JointPlan(dist, estimator, (m_fit.positions, None),
                                              bone_length=forearm),
                               staged(scaled(stage, 2 / 3, 1.0), "limbs"))
    located.record(mid, m_fit)
    located.record(dist, d_fit)


def locate_limb_by_variance(ctx: SkeletonContext, located: LocatedJoints, limb: Limb,
                            std: Mapping[str, float], stage: Progress) -> None:
    """A limb without its middle sensor (or ``reduced``): ``limbs.estimate_limb``."""
    _, mid, dist = limb.joints
    upper, _, distal = limb.segments
    sensors, opt = ctx.sensors, ctx.options
    assert isinstance(opt, VarianceCostOptions)  # llsf and gdke need every sensor
    keys = limb.length_keys
    lf = estimate_limb(
        located.joints[limb.joints[0]], sensors.positions[upper], sensors.rotations[upper],
        sensors.positions[distal], sensors.rotations[distal],
        standard_lengths=(std[keys[0]], std[keys[1]]),
        method="paper" if opt.method == "reduced" else "improved",
        optimizer=opt.optimizer if isinstance(opt, ReducedOptions) else "least-squares",
        w_s=opt.w_s, w_l=opt.w_l, progress=stage, distal_in_line=limb.is_arm,
        valid=sensors.ok[upper] & sensors.ok[distal] if opt.method == "auto" else None)
    located.joints[mid] = lf.middle
    located.joints[dist] = lf.distal
    located.offsets[mid] = JointOffset(upper, lf.middle_local)
    located.offsets[dist] = JointOffset(distal, lf.distal_local)
    lq = dict(lf.quality)
    lq.update({"estimator": f"limb-{lq.get('method', '')}", "cost": lf.cost,
               "n_evaluations": lf.n_evaluations})
    located.quality[mid] = lq
    located.quality[dist] = dict(lq)


def locate_limbs(ctx: SkeletonContext, located: LocatedJoints, std: Mapping[str, float],
                 report: Progress) -> None:
    """The four limbs, each by its joints or by the variance cost, two at a time
    (``threads.run_each``; each on a ``branch`` of ``located``, merged in limb order: the same
    result in any order); ``report(fraction, "limbs")`` within each. The variance cost's fits
    spend most of their time in numpy calls over every frame, which release the GIL: two at a
    time took 0.75× the time of one after the other at 144k frames × 11 sensors."""
    def by_joints(limb: Limb) -> bool:
        return limb.segments[1] in ctx.sensors.positions and ctx.options.method != "reduced"

    def limb_task(limb: Limb) -> Callable[[Report], LocatedJoints]:
        def locate(report_limb: Report) -> LocatedJoints:
            branch = located.branch()
            stage = unstaged(report_limb)
            if by_joints(limb):
                locate_limb_joints(ctx, branch, limb, std, stage)
            else:
                locate_limb_by_variance(ctx, branch, limb, std, stage)
            return branch
        return locate

    report(0.0, "limbs")
    for branch in run_each([limb_task(limb) for limb in LIMBS.values()], report, "limbs",
                           frames=ctx.sensors.stacked.shape[1]):
        located.merge(branch)




def estimate_skeleton(
    recording: SensorRecording,
    *,
    method: str | None = None,
    progress: Progress | None = None,
    options: SkeletonOptions | None = None,
    **method_options: Any,
) -> SkeletonResult:
    """Joint centres, bone lengths and segment orientations from a sensor recording.

    Parameters
    ----------
    recording : SensorRecording
        15 sensors (full suit) or the 11 of the reduced suit (``model.REDUCED_SEGMENTS``),
        positions in metres. Dropped samples (NaN) are filled by interpolation.
    method : {"auto", "llsf", "gdke", "reduced"}, optional
        Described by its options class (``METHOD_OPTIONS[method]``: :class:`AutoOptions`,
        :class:`LlsfOptions`, :class:`GdkeOptions`, :class:`ReducedOptions`); default the
        method of ``options``, else ``"auto"``.
    progress : callable, optional
        ``progress(fraction, stage)`` with stages ``gaps`` (filling, ranges of motion),
        ``slip`` (the shared slip model of ``"auto"``), ``torso``, ``limbs``,
        ``orientations`` (with the smoothing of the paths); within each, after every
        joint, limb, chunk of frames or smoothed path, so that a long take reports often.
    options : SkeletonOptions, optional
        The method's options as one object; default: from ``method_options``.
    **method_options
        Instead of ``options``, its fields as keywords (``up``, ``i0``, ``smooth``,
        ``min_range_deg`` for every method; ``anthropometry``, ``w_s``, ``w_l`` for ``auto``
        and ``reduced``; ``optimizer``, ``torso`` for ``reduced``; ``highpass_s``,
        ``slip_hz`` for ``auto``).

    Returns
    -------
    SkeletonResult
        ``joints`` holds all 16 joints of ``model.JOINTS`` with no NaN.

    Raises
    ------
    InputError
        A required sensor is missing (naming it and the sensors present), a sensor has no
        valid sample, an unknown method, an option the method does not take, both
        ``options`` and keywords, an option out of range (``field`` names it).
    EstimationError
        No sensor moves, or most joints rotate less than ``min_range_deg`` (too little
        motion in the recording as a whole), or bone lengths outside human range (wrong
        units).

    Notes
    -----
    The steps: ``skeleton_options`` and ``check_recording``, ``locate_joints`` (``sensors_used``,
    ``skeleton_context``, ``locate_torso``, ``mirror_torso``, ``derived_torso``,
    ``locate_limbs``) and ``skeleton_result`` (smoothing; with ``auto``, the paths held on a
    rigid tree of bones, ``rigid.rigid_paths``, so that the BVH says what the joints say;
    bone lengths, orientations).

    Miura, Kaiga, Tajima, Shibata & Tamamoto, "Sensor Number Reduction in Skeleton
    Estimation from Magnetic Motion Capture Data", J. Inf. Process. 23(5):704–707 (2015);
    O'Brien et al., Graphics Interface 2000 (LLSF); Knight & Semwal, WSCG 2007 (GDKE).
    """
    started = _time.perf_counter()
    report = progress or no_progress
    if method is None:
        method = "auto" if options is None else options.method
    if "smooth" in method_options and method_options["smooth"] is None:
        del method_options["smooth"]  # None: the method's default, as before the options
    options = resolved_options(method, METHOD_OPTIONS, options, method_options)
    check_recording(recording, options)
    rotations, located = locate_joints(recording, options, report)
    return skeleton_result(recording, options, rotations, located,
                           report=scaled(report, 0.9, 1.0), started=started)


def skeleton_result(recording: SensorRecording, options: SkeletonOptions,
                    rotations: Mapping[str, Rotation], located: LocatedJoints, *,
                    report: Progress, started: float) -> SkeletonResult:
    """``estimate_skeleton``'s result from the located joints and the sensors' rotations:
    the paths completed (``_smoothed``; with ``auto``, ``rigid.rigid_paths`` weighted by each
    joint's ``rms_residual_m``; ``_completed``: bone lengths, orientations;
    ``report(fraction, "orientations")``), ``started`` the ``time.perf_counter()`` of the
    call."""
    completed = _smoothed(located.joints, recording.fps, smooth=options.smooth, report=report)
    if options.method == "auto":
        # weighted by the joint's frame-to-frame disagreement (its two reconstructions'
        # RMS distance), not data_sd_m: a knee's sd along its hinge axis is large, but that
        # constant error does not change bone lengths; moving the knee by the hip's and
        # ankle's jitter made it worse (hinge median +0.5 mm over the 38 clips)
        completed = rigid_paths(completed, {name: float(q["rms_residual_m"])
                                            for name, q in located.quality.items()
                                            if q.get("rms_residual_m") is not None})
    bone_lengths, orientations = _completed(completed, rotations,
                                            up=np.asarray(options.up),
                                            i0=options.i0, warnings=located.warnings,
                                            report=report)
    return SkeletonResult(
        method=options.method,
        fps=recording.fps,
        joints={name: completed[name] for name in JOINTS},
        offsets={name: located.offsets[name] for name in JOINTS},
        bone_lengths=bone_lengths,
        orientations=orientations,
        quality={name: JointQuality.of(located.quality[name]) for name in JOINTS},
        warnings=tuple(located.warnings),
        timings={"estimate_s": _time.perf_counter() - started},
    )


def locate_joints(recording: SensorRecording, options: SkeletonOptions, report: Progress
                  ) -> tuple[dict[str, Rotation], LocatedJoints]:
    """Every joint of ``estimate_skeleton`` located, before the paths are completed: the
    rotations of the sensors used and the located joints (their fits released).
    ``report(fraction, stage)`` of the whole fit, up to 0.9, with the stages ``gaps``,
    ``slip``, ``torso``, ``limbs``.

    Only the rotations outlive the call: the gap-filled positions (S × F × 3, 1.7 MB for
    11 sensors at RT1 size) go before the orientations allocate theirs. An estimate's
    memory above what the previous one left is faulted in page by page (about 3,000
    minor faults, 10-15 % of its CPU time)."""
    method = options.method
    located = LocatedJoints(warnings=list(recording.warnings))
    report(0.0, "gaps")
    sensors = sensors_used(recording, method, located.warnings, scaled(report, 0.0, 0.03))
    ctx = skeleton_context(sensors, options, recording.fps, scaled(report, 0.03, 0.3))
    report(0.3, "torso")
    locate_torso(ctx, located, scaled(report, 0.3, 0.45 if method == "auto" else 0.55))
    if method == "auto":
        mirror_torso(ctx, located, scaled(report, 0.45, 0.55))
    derived_torso(ctx, located)
    joints = located.joints
    lt = torso_length(joints["waist"], joints["l_hip"], joints["r_hip"], joints["chest"])
    _check_units({"torso": lt}, located.warnings)  # before the limbs: their priors assume metres
    # llsf and gdke fit every limb joint between two sensors: no standard length is used
    std = (standard_lengths(lt, options.anthropometry)
           if isinstance(options, VarianceCostOptions) else {})
    locate_limbs(ctx, located, std, scaled(report, 0.55, 0.9))
    located.release()
    return sensors.rotations, located


def estimate_skeleton_from_offsets(
    recording: SensorRecording,
    offsets: Mapping[str, JointOffset],
    *,
    up: ArrayLike = (0.0, 1.0, 0.0),
    i0: int = 0,
    smooth: bool = False,
    progress: Progress | None = None,
) -> SkeletonResult:
    """Joints at known offsets in their sensors' frames: a calibration applied to a take.

    Parameters
    ----------
    recording : SensorRecording
        The take, with the sensors the offsets name, positions in metres.
    offsets : mapping of str to JointOffset
        Every joint of ``model.JOINTS``: its offset in a sensor's frame from an earlier
        estimate with the same sensor placement (``SkeletonResult.offsets`` of a
        calibration recording in which every joint moves; from a file:
        ``io.read_skeleton_offsets(path)``).
    up : array_like, shape (3,)
        World up direction (segment orientations only).
    i0 : int
        Calibration frame of hands, feet and head orientations (paper eq. 7).
    smooth : bool
        Smooth the joint paths (Savitzky–Golay, 0.1 s).
    progress : callable, optional
        ``progress(fraction, stage)`` with stages ``gaps``, ``joints``, ``orientations``.

    Returns
    -------
    SkeletonResult
        Method ``"offsets"``: nothing is fitted, each joint is one rigid transform per frame
        of its sensor's pose. For takes in which some joints barely move: no recording
        locates a joint that does not rotate, but a calibration does.

    Raises
    ------
    InputError
        An offset missing or malformed (``field`` ``offsets.<joint>``), a sensor it names
        missing, a sensor with no valid sample, ``up`` or ``i0`` invalid.
    EstimationError
        Fewer than 10 frames, or bone lengths outside human range (wrong units).
    """
    started = _time.perf_counter()
    report = progress or no_progress
    up_vec = _parse_up(up)
    check_fps(recording.fps)
    check_integer(i0, "i0", low=0, high=2**53)
    _check_frames(recording, i0)
    local = _checked_offsets(recording, offsets)
    warnings: list[str] = list(recording.warnings)
    report(0.0, "gaps")
    use = [s for s in SEGMENTS if s in recording.sensors]
    sensors = SensorPoses.of(recording, use, warnings, scaled(report, 0.0, 0.3))
    report(0.3, "joints")
    mats = {seg: sensors.rotations[seg].as_matrix() for seg in {seg for seg, _ in local.values()}}
    joints = {name: sensors.positions[seg] + rows.apply(mats[seg], vec)
              for name, (seg, vec) in local.items()}
    finish = scaled(report, 0.6, 1.0)
    joints = _smoothed(joints, recording.fps, smooth=smooth, report=finish)
    bone_lengths, orientations = _completed(joints, sensors.rotations, up=up_vec, i0=i0,
                                            warnings=warnings, report=finish)
    return SkeletonResult(
        method="offsets",
        fps=recording.fps,
        joints=joints,
        offsets={name: JointOffset(seg, vec.copy()) for name, (seg, vec) in local.items()},
        bone_lengths=bone_lengths,
        orientations=orientations,
        quality={name: JointQuality("given offset", details={"sensor": seg})
                 for name, (seg, _) in local.items()},
        warnings=tuple(warnings),
        timings={"estimate_s": _time.perf_counter() - started},
    )


def _checked_offsets(recording: SensorRecording, offsets: Mapping[str, JointOffset]
                     ) -> dict[str, tuple[str, NDArray[np.float64]]]:
    """Each joint's (sensor, offset (3,)); InputError for a missing or malformed one."""
    local: dict[str, tuple[str, NDArray[np.float64]]] = {}
    for name in JOINTS:
        off = offsets.get(name)
        if off is None:
            raise InputError(f"no offset for joint {name!r}; a calibration gives all "
                             f"{len(JOINTS)} ({', '.join(JOINTS)})", field=f"offsets.{name}")
        vec = np.asarray(off.local, dtype=float)
        if vec.shape != (3,) or not np.isfinite(vec).all():
            raise InputError(f"offset of {name!r} must be 3 finite numbers (metres)",
                             field=f"offsets.{name}")
        if off.sensor not in recording.sensors:
            raise InputError(f"joint {name!r} is calibrated on sensor {off.sensor!r}, which "
                             f"the recording lacks; it has {', '.join(recording.sensors)}",
                             sensor=off.sensor)
        local[name] = (off.sensor, vec)
    return local


def _smoothed(joints: dict[str, NDArray[np.float64]], fps: float, *, smooth: bool,
              report: Progress) -> dict[str, NDArray[np.float64]]:
    """The joint paths, smoothed if asked: in ``joints``, path by path, so that each
    unsmoothed one can go at once; ``report(fraction, "orientations")`` at 0 and after each
    smoothed path, up to 0.6 (``_completed`` follows)."""
    report(0.0, "orientations")
    if smooth:
        def smooth_one(name: str) -> Callable[[Report], None]:
            def task(_report: Report) -> None:
                # replacing the value of a key present: the dict's order stays
                joints[name] = _smooth(joints[name], fps)
            return task

        frames = next(iter(joints.values())).shape[0]
        run_each([smooth_one(name) for name in joints], scaled(report, 0.0, 0.6),
                 "orientations", frames=frames)
    return joints


def _completed(joints: dict[str, NDArray[np.float64]], rotations: Mapping[str, Rotation], *,
               up: NDArray[np.float64], i0: int, warnings: list[str], report: Progress,
               ) -> tuple[dict[str, float], dict[str, NDArray[np.float64]]]:
    """Bone lengths (checked against human size) and segment orientations of the final
    joint paths (``_smoothed``); ``report(fraction, "orientations")`` from 0.6 to 1."""
    bone_lengths = {seg: float(rows.norms(joints[b] - joints[a]).mean())
                    for seg, (a, b) in BONES.items()}
    _check_units(bone_lengths, warnings)
    report(0.6, "orientations")
    orientations = estimate_orientations(joints, rotations, i0=i0, up=up,
                                         progress=scaled(report, 0.6, 1.0))
    return bone_lengths, orientations
