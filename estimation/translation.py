"""Root translation of inertial-suit recordings from foot accelerometers and kinematics.

Two estimators share one entry point, :func:`estimate_translation`:

``hachaj2018``
    Hachaj & Ogiela's heuristic exactly as their published R implementation computes it
    (docs/translation.md, "Methods and what they assume"), in O(N).
``contact`` (default)
    A stance model: per-frame foot contacts (left, right, both, none) chosen by Viterbi
    decoding of how well each hypothesis explains the measured foot accelerations, then a
    root path that keeps planted heel/toe points still, follows a ballistic arc in flight and
    keeps each contact on its own floor level.

T. Hachaj and M. R. Ogiela, "Heuristic method for calculating the translation of human body
recordings using data from an inertial motion capture costume", Journal of Advances in
Information Technology 9(4), 2018; reference implementation
github.com/browarsoftware/ShadowMoCap. The contact model is this project's: Viterbi decoding
(Rabiner 1989) of contact states scored by the foot accelerometers against the accelerations
each state predicts from the kinematics.
"""

from __future__ import annotations

import math
import time as _time
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any, Final, NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import gaussian_filter1d, maximum_filter1d

from .errors import EstimationError, InputError
from .kinematics import GRAVITY, KinematicsRecording
from .params import (
    CONTACT_OPTION_RANGES,
    HACHAJ_EPS_RANGE,
    HACHAJ_WINDOW_RANGE,
    check_fps,
    check_integer,
    check_number,
    options_of,
    resolved_options,
)
from .progress import Progress, no_progress
from .results import TranslationQuality
from .results import TranslationResult as TranslationResult  # defined there, numpy only
from .stance import (
    INSTEP_SENSOR,
    ball_on_foot,
    body_heading,
    estimate_sensor_offset,
    foot_axes,
    foot_point,
    heading_by_knees,
    leg_joints,
    leg_length,
    rise_tilt,
    roll_advance,
    sensor_track,
)
from .vocabulary import TRANSLATION_METHODS

METHODS: Final[tuple[str, ...]] = TRANSLATION_METHODS
"""Names accepted by :func:`estimate_translation`."""

CONTACT_LABELS: Final[tuple[str, ...]] = ("none", "left", "right", "both")
"""Per-frame contact labels, in state order of the contact model."""

HACHAJ_WINDOW: Final[int] = 100
"""Gaussian window of the reference implementation, in samples."""

HACHAJ_EPS_M: Final[float] = 0.05
"""Pass-2 threshold of the reference implementation (5 cm)."""

POSE_JUMP_FACTOR: Final[float] = 2.0
"""A carried step faster than this times the recording's 99th percentile of carried speeds
is a jump of the pose, not a movement of the body (:func:`pose_jumps`)."""

POSE_JUMP_MIN_SPEED: Final[float] = 2.0
"""m/s: slower steps are never taken for a jump of the pose (:func:`pose_jumps`)."""


# --------------------------------------------------------------------------- shared pieces


def hachaj_window_length(n_frames: int, window: int = HACHAJ_WINDOW) -> int:
    """Window length the reference implementation ends up with for ``n_frames`` samples.

    The R code passes ``window / n`` as a fraction and the smoother multiplies it back and
    truncates, so ``int(100 / n * n)`` is 99 for some n (161, 167, 193, ...).
    """
    return int(window / n_frames * n_frames)


def hachaj_smooth(x: NDArray[np.float64], window: int = HACHAJ_WINDOW) -> NDArray[np.float64]:
    """Gaussian smoothing of the reference implementation (R ``smoother::smth``).

    Parameters
    ----------
    x : ndarray, shape (N,)
    window : int
        Nominal window in samples; the effective length is :func:`hachaj_window_length`.

    Returns
    -------
    ndarray, shape (N,)
        Output i averages samples i−⌊w/2⌋ … i+(w−⌊w/2⌋)−1 with the kernel
        exp(−½(2.5(j − ⌊w/2⌋)/(w/2))²); the first ⌊w/2⌋ and last w−⌊w/2⌋ outputs are
        undefined in R and set to 0, as the authors do.
    """
    n = x.shape[0]
    w = hachaj_window_length(n, window)
    out = np.zeros(n)
    h = w // 2
    if w < 1 or n - (w - h) <= h:
        return out
    j = np.arange(w)
    kernel = np.exp(-0.5 * (2.5 * (j - h) / (w / 2.0)) ** 2)
    kernel /= kernel.sum()
    valid = np.convolve(x, kernel[::-1], mode="valid")
    out[h:n - (w - h)] = valid[:n - (w - h) - h]
    return out


def _planted_pairs(right: NDArray[np.float64], left: NDArray[np.float64]
                   ) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """Both-frames rule: the left foot is planted on pair (a, a+1) when the right signal is
    larger on both frames, and vice versa; crossings and ties do nothing."""
    left_planted = (right[:-1] > left[:-1]) & (right[1:] > left[1:])
    right_planted = (right[:-1] < left[:-1]) & (right[1:] < left[1:])
    return left_planted, right_planted


def _chain(left: NDArray[np.float64], right: NDArray[np.float64],
           left_planted: NDArray[np.bool_], right_planted: NDArray[np.bool_]
           ) -> NDArray[np.float64]:
    """Shift (F, 3) the reference loop applies: from every later frame it subtracts the
    displacement of the planted foot (positions ``left``/``right``, (F, 3)). The loop's
    corrections commute, so their sum is a cumulative sum: O(N) instead of O(N²)."""
    step = np.zeros((left.shape[0] - 1, 3))
    step[left_planted] = np.diff(left, axis=0)[left_planted]
    step[right_planted] += np.diff(right, axis=0)[right_planted]
    shift = np.zeros((left.shape[0], 3))
    np.cumsum(step, axis=0, out=shift[1:])
    return shift


def _contact_labels(left: NDArray[np.bool_], right: NDArray[np.bool_]) -> NDArray[np.str_]:
    state = left.astype(int) + 2 * right.astype(int)
    labels: NDArray[np.str_] = np.asarray(CONTACT_LABELS, dtype="<U5")[state]
    return labels


@dataclass(frozen=True)
class _Feet:
    """Heel/toe contact points of one foot: a soft blend of heel and toe by which is lower.

    The toe is the file's toe joint, or else the ball of the foot placed by ``ball`` on the
    axes of the ankle and a point rigid with the foot (``end``, e.g. an End Site); the heel
    is the ankle, or with ``end`` the point ``heel_at`` on those axes."""

    heel: int
    toe: int | None
    drop: float  # heel height above the toe when the foot is flat, m
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)  # sensor in foot_axes, m
    # Without a toe: (F, 3) the ankle's forward advance as the heel rolls over the ball,
    # summed along the foot's heading as it changes, m; the contact point is the ankle moved
    # back by it (turning the heading moves nothing).
    roll: NDArray[np.float64] | None = field(default=None, compare=False, repr=False)
    end: int | None = None  # a joint rigid with the foot, when there is no toe joint
    ball: tuple[float, float, float] = (0.0, 0.0, 0.0)  # in foot_axes(heel, end), m
    heel_at: tuple[float, float, float] = (0.0, 0.0, 0.0)  # likewise, m

    def heel_path(self, p: NDArray[np.float64]) -> NDArray[np.float64]:
        """Path (F, 3) of the heel point: the ankle, or ``heel_at`` on the foot's axes."""
        if self.end is None or not any(self.heel_at):
            out: NDArray[np.float64] = p[:, self.heel]
            return out
        return sensor_track(p[:, self.heel], self.axes(p), np.asarray(self.heel_at))

    @property
    def has_toe(self) -> bool:
        """Whether the foot has a toe point (a toe joint, or a ball placed on ``end``)."""
        return self.toe is not None or self.end is not None

    def toe_path(self, p: NDArray[np.float64]) -> NDArray[np.float64]:
        """Path (F, 3) of the toe point (only for :attr:`has_toe`)."""
        if self.toe is not None:
            return p[:, self.toe]
        assert self.end is not None
        return sensor_track(p[:, self.heel], self.axes(p), np.asarray(self.ball))

    def axes(self, p: NDArray[np.float64]) -> NDArray[np.float64]:
        """:func:`stance.foot_axes` (F, 3, 3) of the ankle and the toe joint or ``end``."""
        tip = self.toe if self.toe is not None else self.end
        assert tip is not None
        return foot_axes(p[:, self.heel], p[:, tip])

    def sensor(self, p: NDArray[np.float64]) -> NDArray[np.float64]:
        """Path (F, 3) of the foot's accelerometer: the ankle moved by ``offset`` along the
        foot's axes (the ankle itself without a toe point or an offset)."""
        if not self.has_toe or not any(self.offset):
            return p[:, self.heel].copy()
        return sensor_track(p[:, self.heel], self.axes(p), np.asarray(self.offset))

    def blend(self, p: NDArray[np.float64]
              ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """The heel's weight (F,) in the contact point, by which of heel (lowered by ``drop``)
        and toe is lower, with the heel and toe paths (F, 3 each) it blends (only for
        :attr:`has_toe`): each path computed once for every use."""
        heel, toe = self.heel_path(p), self.toe_path(p)
        gap = toe[:, 1] - (heel[:, 1] - self.drop)
        return 0.5 * (1.0 + np.tanh(gap / 0.02)), heel, toe

    def weights(self, p: NDArray[np.float64]) -> NDArray[np.float64]:
        if not self.has_toe:
            return np.ones(p.shape[0])
        return self.blend(p)[0]

    def sole(self, p: NDArray[np.float64]) -> NDArray[np.float64]:
        """Height of the contact point (toe frame: heel heights lowered by ``drop``)."""
        if not self.has_toe:
            return p[:, self.heel, 1].copy()
        w, heel, toe = self.blend(p)
        out: NDArray[np.float64] = w * (heel[:, 1] - self.drop) + (1 - w) * toe[:, 1]
        return out

    def point(self, p: NDArray[np.float64]) -> NDArray[np.float64]:
        if not self.has_toe:
            if self.roll is None:
                return p[:, self.heel].copy()
            out: NDArray[np.float64] = p[:, self.heel] - self.roll
            return out
        w, heel, toe = self.blend(p)
        blended: NDArray[np.float64] = w[:, None] * heel + (1 - w[:, None]) * toe
        return blended

    def steps(self, p: NDArray[np.float64]) -> NDArray[np.float64]:
        """Displacement (F−1, 3) of the contact point between frames, the point chosen on the
        earlier frame (so switching heel→toe moves nothing)."""
        if not self.has_toe:
            return np.diff(self.point(p), axis=0)
        weights, heel, toe = self.blend(p)
        w = 0.5 * (weights[:-1] + weights[1:])[:, None]
        out: NDArray[np.float64] = w * (heel[1:] - heel[:-1]) + (1 - w) * (toe[1:] - toe[:-1])
        return out


def _feet(recording: KinematicsRecording, left_foot: str, right_foot: str,
          use_toes: bool, *, balls: bool = False, sole: bool = False) -> tuple[_Feet, _Feet]:
    """Both feet's contact points: with ``use_toes`` the toe joints named by the recording,
    else (``balls``) the ball of the foot on a point rigid with it (with ``sole``, heel and
    ball on the sole: ``stance.ball_on_foot``); each toe's ``drop`` from the frames where it
    is the lower."""
    p = recording.positions
    bare = []
    for joint in (left_foot, right_foot):
        name = recording.toes.get(joint) if use_toes else None
        bare.append(_Feet(recording.index(joint), recording.index(name) if name else None,
                          0.0))
    if use_toes and balls:
        bare = _balls(p, bare, recording.index(recording.root), sole=sole)
    toes = [f.toe_path(p) if f.has_toe else None for f in bare]
    out = []
    for k, foot in enumerate(bare):
        toe, other_toe = toes[k], toes[1 - k]
        if toe is None:
            out.append(foot)
            continue
        other = other_toe[:, 1] if other_toe is not None else p[:, bare[1 - k].heel, 1]
        own = toe[:, 1] if other_toe is not None else p[:, foot.heel, 1]
        lower = own <= other
        gap = foot.heel_path(p)[:, 1] - toe[:, 1]
        drop = float(np.median(gap[lower] if lower.sum() > 10 else gap))
        out.append(replace(foot, drop=drop))
    return out[0], out[1]


def _balls(p: NDArray[np.float64], feet: list[_Feet], root: int, *, sole: bool
           ) -> list[_Feet]:
    """``feet`` where a foot without a toe joint but with a point rigid with it
    (``stance.foot_point``) gets the ball of the foot and the heel point on that point
    (``stance.ball_on_foot`` of ``sole``, flat where its ankle is the lower)."""
    out = []
    for k, foot in enumerate(feet):
        ankle, other = p[:, foot.heel], p[:, feet[1 - k].heel]
        leg = leg_length(p, foot.heel, root)
        end = foot_point(p, foot.heel, leg) if foot.toe is None and leg > 0 else None
        if end is not None:
            ball, heel = ball_on_foot(ankle, p[:, end], ankle[:, 1] <= other[:, 1], leg,
                                      sole=sole)
            foot = replace(foot, end=end, ball=(float(ball[0]), float(ball[1]), 0.0),
                           heel_at=(float(heel[0]), float(heel[1]), 0.0),
                           offset=INSTEP_SENSOR)
        out.append(foot)
    return out


def _swing_floor(level: NDArray[np.float64], floor: NDArray[np.float64]
                 ) -> NDArray[np.float64]:
    """Per-frame floor under one foot: its contact level, and in the air the lower of the
    levels before and after (``floor`` where it has never touched down)."""
    n = level.shape[0]
    idx = np.where(np.isnan(level), -1, np.arange(n))
    before = np.maximum.accumulate(idx)
    idx_after = np.where(np.isnan(level), n, np.arange(n))
    after = np.minimum.accumulate(idx_after[::-1])[::-1]
    prev = np.where(before >= 0, level[np.clip(before, 0, n - 1)], np.nan)
    nxt = np.where(after < n, level[np.clip(after, 0, n - 1)], np.nan)
    out = np.fmin(prev, nxt)
    return np.where(np.isnan(out), floor, out)


def translation_quality(positions: NDArray[np.float64], fps: float, root: int,
                        feet: tuple[_Feet, _Feet], *, contacts: NDArray[np.str_],
                        floor: NDArray[np.float64],
                        levels: NDArray[np.float64] | None = None) -> dict[str, Any]:
    """Quality figures of corrected positions (see :class:`TranslationResult`).

    ``levels`` (F, 2) is the floor level under each foot while it is in contact (NaN in the
    air); a foot in the air is measured against the lower of the levels it left and lands
    on (stepping onto a platform is not a penetration of it). Without ``levels`` both feet
    are measured against ``floor``.
    """
    hips = positions[:, root]
    n = positions.shape[0]
    horiz = hips[:, [0, 2]]
    steps = np.linalg.norm(np.diff(horiz, axis=0), axis=1) if n > 1 else np.zeros(0)
    dy = np.diff(hips[:, 1])
    jumps = np.abs(dy[1:-1] - 0.5 * (dy[:-2] + dy[2:])) if n > 3 else np.zeros(0)
    skate = []
    for k, foot in enumerate(feet):
        label = ("left", "right")[k]
        planted = (contacts == label) | (contacts == "both")
        pair = planted[:-1] & planted[1:]
        if pair.any():
            d = foot.steps(positions)[pair][:, [0, 2]]
            skate.append(np.linalg.norm(d, axis=1) * fps)
    skate_all = np.concatenate(skate) if skate else np.zeros(0)
    soles = np.stack([f.sole(positions) for f in feet], axis=1)
    under = np.repeat(floor[:, None], 2, axis=1)
    if levels is not None:
        for k in range(2):
            under[:, k] = _swing_floor(levels[:, k], floor)
    penetration = np.maximum(under - soles, 0.0).max(axis=1)
    in_contact = contacts != "none"
    return {
        "foot_skate_cm_s": float(skate_all.mean() * 100) if skate_all.size else 0.0,
        "foot_skate_p95_cm_s": float(np.percentile(skate_all, 95) * 100)
        if skate_all.size else 0.0,
        "floor_penetration_cm": float(penetration.max() * 100) if n else 0.0,
        "floor_penetration_p99_cm": float(np.percentile(penetration, 99) * 100) if n else 0.0,
        "max_vertical_jump_cm": float(jumps.max() * 100) if jumps.size else 0.0,
        "max_vertical_step_cm": float(np.abs(dy).max() * 100) if dy.size else 0.0,
        "closure_cm": float(np.linalg.norm(horiz[-1] - horiz[0]) * 100),
        "path_length_m": float(steps.sum()),
        "contact_fraction": float(in_contact.mean()) if n else 0.0,
        "flight_frames": int((~in_contact).sum()),
    }


# --------------------------------------------------------------------------- hachaj2018


def _hachaj(recording: KinematicsRecording, joints: tuple[int, int], names: tuple[str, str],
            progress: Progress, opt: HachajOptions
            ) -> tuple[NDArray[np.float64], NDArray[np.str_], float]:
    (li, ri), (left_foot, right_foot), window, eps = joints, names, opt.window, opt.eps
    p0 = recording.positions
    a_l, a_r = recording.accelerations[left_foot], recording.accelerations[right_foot]
    mag_l = np.sqrt(np.einsum("ij,ij->i", a_l, a_l))
    mag_r = np.sqrt(np.einsum("ij,ij->i", a_r, a_r))
    z_r, z_l = hachaj_smooth(mag_r, window), hachaj_smooth(mag_l, window)
    left1, right1 = _planted_pairs(z_r, z_l)
    foot_l, foot_r = p0[:, li], p0[:, ri]
    shift1 = _chain(foot_l, foot_r, left1, right1)
    foot_l, foot_r = foot_l - shift1, foot_r - shift1  # only the feet: every joint moves alike
    progress(0.4, "pass 1")
    h_r, h_l = hachaj_smooth(foot_r[:, 1], window), hachaj_smooth(foot_l[:, 1], window)
    apart = np.abs(h_r - h_l)[:-1] > eps
    left2, right2 = _planted_pairs(h_r, h_l)
    left2 &= apart
    right2 &= apart
    shift2 = _chain(foot_l, foot_r, left2, right2)
    foot_l, foot_r = foot_l - shift2, foot_r - shift2
    progress(0.7, "pass 2")
    ground = foot_r[0, 1]
    lower = np.where(h_r >= h_l, foot_l[:, 1], foot_r[:, 1])
    translation = -(shift1 + shift2)
    translation[:, 1] -= lower - ground
    # Per-frame contacts: the foot a pass held still on the pair ending at this frame (pass 2
    # overrides pass 1 where it acted).
    left_c = np.zeros(p0.shape[0], dtype=bool)
    right_c = np.zeros(p0.shape[0], dtype=bool)
    acted2 = left2 | right2
    left_c[1:] = np.where(acted2, left2, left1)
    right_c[1:] = np.where(acted2, right2, right1)
    left_c[0], right_c[0] = left_c[1], right_c[1]
    return translation, _contact_labels(left_c, right_c), float(ground)


@dataclass(frozen=True)
class HachajOptions:
    """Parameters of ``hachaj2018`` (the reference implementation's constants).

    Attributes
    ----------
    window : int
        Gaussian window, samples (``HACHAJ_WINDOW_RANGE``); the effective length is
        :func:`hachaj_window_length`.
    eps : float
        Pass-2 threshold on the feet's smoothed height difference, metres
        (``HACHAJ_EPS_RANGE``).
    """

    window: int = HACHAJ_WINDOW
    eps: float = HACHAJ_EPS_M

    def __post_init__(self) -> None:
        low, high = HACHAJ_WINDOW_RANGE
        window = check_integer(self.window, "window", low=low, high=high)
        eps_low, eps_high = HACHAJ_EPS_RANGE
        eps = check_number(self.eps, "eps", low=eps_low, high=eps_high, low_open=True,
                           unit=" m")
        object.__setattr__(self, "window", window)
        object.__setattr__(self, "eps", eps)


# --------------------------------------------------------------------------- contact model


@dataclass(frozen=True)
class ContactOptions:
    """Parameters of the contact model (times in seconds, lengths in metres).

    Attributes
    ----------
    smoothing_s : float
        Gaussian σ applied to positions before differentiating and to the acceleration
        residuals (a time, so the model behaves the same at 30 and 120 fps).
    sigma_acc : float
        Scale of the acceleration residuals, m/s².
    relative_sigma_acc : float
        Growth of that scale with the size of the (non-gravity) acceleration.
    swing_weight : float
        Weight of a swinging foot's residual (its predicted reading) against a planted
        foot's. The swing prediction is exact on synthetic data but the least reliable part on
        a real suit (sensor placement, impacts, kinematic errors); see docs/translation.md.
    swing_cost : float
        Cost per 10 ms of declaring a foot in the air.
    flight_cost : float
        Extra cost per 10 ms of declaring both feet in the air.
    switch_cost : float
        Cost of one change of contact state (hysteresis).
    sigma_relative_speed : float
        Scale of the relative speed of the two feet's contact points in double support, m/s.
    adapt_relative_speed : bool
        Widen that scale to 1.5 × the median relative speed of the feet on frames where both
        accelerometers are at rest (the kinematics' own drift between planted feet).
    height_tolerance, sigma_height : float
        A planted foot more than ``height_tolerance`` above the other foot costs
        ((excess)/σ)² — the other would be below the floor.
    floor_tolerance : float
        A new contact whose floor height is within this of a known floor level is put on that
        level (flat floors stay flat; steps of 10 cm and more become platforms).
    floor_ramp_s : float
        Time over which a new contact eases from the height that keeps the body continuous
        onto its floor level (no vertical jumps when the supporting foot changes).
    use_toes : bool
        Use heel/toe contact points when the recording names toe joints.
    extrapolate_toes : bool
        Without toe joints, a toe point at the ball of the foot: on a point rigid with the
        foot (an End Site; ``stance.foot_point``), the ball L = 0.13 and d = 0.055 leg
        lengths ahead of and below the ankle of the foot standing flat
        (``stance.ball_on_foot``), a heel/toe point like a toe joint's, the sensor taken
        on the instep (``stance.INSTEP_SENSOR``; the lever-arm fit then has the foot's
        axes) for the decoding; the path then holds still the points of the sole the foot
        rolls over, heel and ball 0.08 leg lengths below the flat foot's ankle
        (``stance.SOLE_BELOW``); without such a point, the ankle rolled back by the
        heel lift read from its rise above the other ankle (``stance.rise_tilt``). Needs
        ``use_toes``. Off by default: it fails the real recording's held-out check
        (docs/translation.md); ``choose_toes`` decides instead.
    choose_toes : bool
        Where a foot has no toe joint but a toe point can be extrapolated (as
        ``extrapolate_toes`` does), decode the contacts with the ankle and with the toe
        point and keep the toe point unless the ankle's decoding costs less per 10 ms both
        in all and in its accelerometer residuals alone (:func:`ankle_explains_better`;
        quality ``toe_model``, ``decoded_cost_ankle``, ``decoded_cost_extrapolated``,
        ``decoded_accelerometer_cost_ankle``, ``decoded_accelerometer_cost_extrapolated``):
        a foot whose kinematics do not roll like the data says stays on the ankle. Doubles
        the decoding's cost on such files; nothing changes with toe joints.
    lever_arm_prior_m : float
        Scale of the prior on the foot accelerometer's offset from the ankle, m: the offset
        is fitted to the readings of the planted foot (``stance.estimate_sensor_offset``)
        and the contacts decoded again with the sensor's own acceleration; 0 takes the
        sensor at the ankle.
    use_file_contacts : bool
        Take contacts from the file (MVNX footContacts, ``<Foot>.c``) when present.
    clip_g : float or None
        Accelerometer range in g; None detects saturation from the data.
    """

    smoothing_s: float = 0.03
    sigma_acc: float = 1.5
    relative_sigma_acc: float = 0.0
    swing_weight: float = 0.0
    residual_cap: float = 9.0
    swing_cost: float = 1.0
    flight_cost: float = 3.0
    switch_cost: float = 6.0
    sigma_relative_speed: float = 0.15
    adapt_relative_speed: bool = True
    height_tolerance: float = 0.03
    sigma_height: float = 0.02
    floor_tolerance: float = 0.05
    floor_ramp_s: float = 0.25
    use_toes: bool = True
    extrapolate_toes: bool = False
    choose_toes: bool = True
    lever_arm_prior_m: float = 0.0
    use_file_contacts: bool = True
    clip_g: float | None = None

    def __post_init__(self) -> None:
        for name, (low, high, low_open) in CONTACT_OPTION_RANGES.items():
            value = getattr(self, name)
            if name == "clip_g" and value is None:
                continue
            check_number(value, name, low=low, high=high, low_open=low_open)
        for name in ("adapt_relative_speed", "use_toes", "extrapolate_toes", "choose_toes",
                     "use_file_contacts"):
            if not isinstance(getattr(self, name), bool | np.bool_):
                raise InputError(f"{name} must be true or false, got {getattr(self, name)!r}",
                                 field=name)


MethodOptions = ContactOptions | HachajOptions
"""Options of one translation method."""

METHOD_OPTIONS: Final[dict[str, type[MethodOptions]]] = {
    "contact": ContactOptions, "hachaj2018": HachajOptions}
"""The options dataclass of each method of :func:`estimate_translation`."""


def method_options(method: str, options: Mapping[str, Any]) -> MethodOptions:
    """The options of ``method`` from keyword values, checked.

    Parameters
    ----------
    method : {"contact", "hachaj2018"}
    options : mapping of str to object
        Field values of ``METHOD_OPTIONS[method]``; missing fields take their defaults.

    Returns
    -------
    ContactOptions or HachajOptions

    Raises
    ------
    InputError
        Unknown method, an unknown option (``field`` names the first) or a value out of
        range (``field`` names it).
    """
    return options_of(method, METHOD_OPTIONS, options)


def _saturated(raw: NDArray[np.float64], clip_g: float | None,
               frame: str) -> NDArray[np.bool_]:
    """Frames where a component sits at the accelerometer's range (the magnitude is then only
    a lower bound). Without ``clip_g`` the range is found as a pile-up of samples just under
    the largest values, which a saturating sensor produces and a free signal does not."""
    if frame != "sensor":
        return np.zeros(raw.shape[0], dtype=bool)
    peak = np.abs(raw).max(axis=1)
    if clip_g is not None:
        return np.asarray(peak >= 0.98 * clip_g * GRAVITY)
    ceiling = float(np.percentile(peak, 99.5))
    if ceiling <= 0:
        return np.zeros(raw.shape[0], dtype=bool)
    near = float(np.mean((peak >= 0.96 * ceiling) & (peak <= 1.05 * ceiling)))
    below = float(np.mean((peak >= 0.85 * ceiling) & (peak < 0.94 * ceiling)))
    if near > 0.01 and near > 3 * below:
        return np.asarray(peak >= 0.96 * ceiling)
    return np.zeros(raw.shape[0], dtype=bool)


def _viterbi(cost: NDArray[np.float64], switch: NDArray[np.float64]) -> NDArray[np.int64]:
    """Minimum-cost state path; cost (F, S) per frame, switch (S, S) per transition."""
    n, s = cost.shape
    back = np.empty((n, s), dtype=np.int64)
    acc = cost[0].copy()
    for t in range(1, n):
        total = acc[:, None] + switch
        back[t] = np.argmin(total, axis=0)
        acc = total[back[t], np.arange(s)] + cost[t]
    path = np.empty(n, dtype=np.int64)
    path[-1] = int(np.argmin(acc))
    for t in range(n - 1, 0, -1):
        path[t - 1] = back[t, path[t]]
    return path


def _second_derivative(x: NDArray[np.float64], fps: float) -> NDArray[np.float64]:
    out = np.empty_like(x)
    out[1:-1] = (x[2:] - 2 * x[1:-1] + x[:-2]) * fps * fps
    out[0], out[-1] = out[1], out[-2]
    return out


def _derivative(x: NDArray[np.float64], fps: float) -> NDArray[np.float64]:
    return np.gradient(x, 1.0 / fps, axis=0)


def _contact_states(recording: KinematicsRecording, feet: tuple[_Feet, _Feet],
                    names: tuple[str, str], root: int, opt: ContactOptions
                    ) -> tuple[NDArray[np.int64], dict[str, Any]]:
    """States 0 none, 1 left, 2 right, 3 both per frame, by Viterbi decoding; with a lever
    arm prior, decoded again once the sensors' offsets are fitted to the first decoding."""
    sigma = _smoothing_frames(opt, recording.fps)
    p = gaussian_filter1d(recording.positions, sigma, axis=0, mode="nearest")
    meas = [recording.accelerations[name] for name in names]
    sat = [_saturated(raw, opt.clip_g, recording.acceleration_frame) for raw in meas]
    states, info = _decode(recording, p, feet, root, readings=(meas, sat), opt=opt)
    if opt.lever_arm_prior_m > 0 and recording.acceleration_frame == "sensor" \
            and any(f.has_toe for f in feet):
        feet = _fitted_offsets(recording.fps, p, feet, states, readings=(meas, sat), opt=opt)
        states, info = _decode(recording, p, feet, root, readings=(meas, sat), opt=opt)
        info["sensor_offsets_m"] = {name: [round(v, 4) for v in f.offset]
                                    for name, f in zip(names, feet, strict=True)}
    info["saturated_fraction"] = float(np.mean(np.concatenate(sat)))
    return states, info


def _smoothing_frames(opt: ContactOptions, fps: float) -> float:
    """``smoothing_s`` in frames (at least half a frame): the Gaussian σ of the positions and
    of the acceleration residuals."""
    return max(opt.smoothing_s * fps, 0.5)


def _decode(recording: KinematicsRecording, p: NDArray[np.float64],
            feet: tuple[_Feet, _Feet], root: int, *,
            readings: tuple[list[NDArray[np.float64]], list[NDArray[np.bool_]]],
            opt: ContactOptions) -> tuple[NDArray[np.int64], dict[str, Any]]:
    """Viterbi states of the smoothed positions ``p`` and the feet's ``readings``."""
    fps = recording.fps
    sigma = _smoothing_frames(opt, fps)
    points = [f.point(p) for f in feet]
    acc = _acceleration_costs(recording, p, feet, root, points=points, readings=readings,
                              opt=opt)
    cost = acc.copy()
    rel_speed = np.linalg.norm(_derivative(points[0], fps) - _derivative(points[1], fps),
                               axis=1)
    rel_scale = _relative_speed_scale(readings[0], recording.acceleration_frame, rel_speed,
                                      sigma, opt)
    _add_state_priors(cost, [f.sole(p) for f in feet], rel_speed / rel_scale, opt)
    cost *= 100.0 / fps  # costs are per 10 ms, whatever the frame rate
    switch = _switch_costs(opt)
    states = _viterbi(cost, switch)
    on_path = np.arange(states.shape[0]), states
    total = float(cost[on_path].sum() + switch[states[:-1], states[1:]].sum())
    return states, {"relative_speed_scale_m_s": rel_scale,
                    "decoded_cost": total * fps / 100.0 / states.shape[0],
                    "decoded_accelerometer_cost": float(acc[on_path].mean())}


def _fitted_offsets(fps: float, p: NDArray[np.float64], feet: tuple[_Feet, _Feet],
                    states: NDArray[np.int64], *,
                    readings: tuple[list[NDArray[np.float64]], list[NDArray[np.bool_]]],
                    opt: ContactOptions) -> tuple[_Feet, _Feet]:
    """``feet`` with each accelerometer's offset from the ankle fitted on the frames where
    ``states`` has that foot planted: there its specific force is the ankle's acceleration
    relative to the planted point, plus the lever arm's terms, plus gravity."""
    meas, sat = readings
    out = []
    for k, foot in enumerate(feet):
        if not foot.has_toe:
            out.append(foot)
            continue
        heel = p[:, foot.heel]
        base = (_second_derivative(heel, fps) - _second_derivative(foot.point(p), fps)
                + np.array([0.0, GRAVITY, 0.0]))
        axes_acc = _second_derivative(foot.axes(p), fps)
        use = ((states == 1 + k) | (states == 3)) & ~sat[k]
        offset = estimate_sensor_offset(base, axes_acc, meas[k], use, sigma=opt.sigma_acc,
                                        prior_m=opt.lever_arm_prior_m)
        out.append(replace(foot, offset=(float(offset[0]), float(offset[1]),
                                         float(offset[2]))))
    return out[0], out[1]


def _acceleration_costs(recording: KinematicsRecording, p: NDArray[np.float64],
                        feet: tuple[_Feet, _Feet], root: int, *,
                        points: list[NDArray[np.float64]],
                        readings: tuple[list[NDArray[np.float64]], list[NDArray[np.bool_]]],
                        opt: ContactOptions) -> NDArray[np.float64]:
    """Cost (F, 4) of each contact state: how far the foot accelerometers are from what the
    state predicts (a planted contact point does not accelerate; in flight the hips fall).

    ``p`` are the smoothed positions, ``points`` each foot's contact point in them,
    ``readings`` each foot accelerometer's samples and saturated frames."""
    fps = recording.fps
    sigma = _smoothing_frames(opt, fps)
    meas, sat = readings
    a_sensor = [_second_derivative(f.sensor(p), fps) for f in feet]
    a_point = [_second_derivative(pt, fps) for pt in points]
    a_hips = _second_derivative(p[:, root], fps)
    up = np.array([0.0, GRAVITY, 0.0])
    hyp = {
        1: -a_point[0],
        2: -a_point[1],
        3: -0.5 * (a_point[0] + a_point[1]),
        0: -up - a_hips,
    }
    cost = np.zeros((recording.n_frames, 4))
    for state, root_acc in hyp.items():
        total = np.zeros(recording.n_frames)
        for k in range(2):
            weight = 1.0
            if state not in (0, 1 + k, 3):  # this foot swings in this state
                weight = opt.swing_weight
            if weight > 0:
                r, spread = _acceleration_residual(
                    a_sensor[k] + root_acc, meas[k], sat[k],
                    recording.acceleration_frame, opt)
                total += weight * gaussian_filter1d(
                    np.minimum((r / spread) ** 2, opt.residual_cap), sigma, mode="nearest")
        cost[:, state] = total
    return cost


def _acceleration_residual(world: NDArray[np.float64], measured: NDArray[np.float64],
                           saturated: NDArray[np.bool_], frame: str, opt: ContactOptions
                           ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Residual (F,) of one accelerometer against the predicted world acceleration ``world``
    (F, 3), m/s², and its scale (F,); a saturated reading below the prediction is no
    evidence."""
    if frame == "sensor":
        up = np.array([0.0, GRAVITY, 0.0])
        predicted = np.linalg.norm(world + up, axis=1)
        size_measured = np.linalg.norm(measured, axis=1)
        r = size_measured - predicted
        r = np.where(saturated & (r < 0), 0.0, r)
        size = np.maximum(np.abs(size_measured - GRAVITY), np.abs(predicted - GRAVITY))
    else:
        r = np.linalg.norm(measured - world, axis=1)
        size = np.maximum(np.linalg.norm(measured, axis=1), np.linalg.norm(world, axis=1))
    # impacts and swings are large and brief: their exact size matters less than
    # their presence, so the residual scale grows with the acceleration
    return r, opt.sigma_acc + opt.relative_sigma_acc * size


def _relative_speed_scale(meas: list[NDArray[np.float64]], frame: str,
                          rel_speed: NDArray[np.float64], sigma: float,
                          opt: ContactOptions) -> float:
    """Scale of the feet's relative speed in double support, m/s.

    Suits whose kinematics let two planted feet drift apart (IMU orientation errors) need a
    looser double-support test: measure that drift where both accelerometers are at rest."""
    rest = []
    for raw in meas:
        mag = np.linalg.norm(raw, axis=1)
        level = float(np.median(mag)) if frame == "sensor" else 0.0
        rest.append(gaussian_filter1d(np.abs(mag - level), sigma, mode="nearest")
                    < 0.08 * GRAVITY)
    quiet = rest[0] & rest[1]
    rel_scale = opt.sigma_relative_speed
    if opt.adapt_relative_speed and quiet.mean() > 0.05:
        rel_scale = max(rel_scale, 1.5 * float(np.median(rel_speed[quiet])))
    return rel_scale


def _add_state_priors(cost: NDArray[np.float64], sole: list[NDArray[np.float64]],
                      rel: NDArray[np.float64], opt: ContactOptions) -> None:
    """Add to ``cost`` (F, 4) what each state costs besides the accelerometers: a swinging
    foot, a planted foot above the other, feet moving apart in double support (``rel``, in
    units of their scale), flight."""
    excess_l = np.maximum(sole[0] - sole[1] - opt.height_tolerance, 0.0) / opt.sigma_height
    excess_r = np.maximum(sole[1] - sole[0] - opt.height_tolerance, 0.0) / opt.sigma_height
    cost[:, 1] += opt.swing_cost + excess_l ** 2
    cost[:, 2] += opt.swing_cost + excess_r ** 2
    cost[:, 3] += np.minimum(rel ** 2, 4 * opt.residual_cap)
    cost[:, 0] += 2 * opt.swing_cost + opt.flight_cost


def _switch_costs(opt: ContactOptions) -> NDArray[np.float64]:
    """Cost (4, 4) of going from one state to another; left to right directly costs 3×."""
    switch = np.full((4, 4), opt.switch_cost)
    np.fill_diagonal(switch, 0.0)
    switch[1, 2] = switch[2, 1] = 3 * opt.switch_cost
    return switch


def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """[start, stop) of each run of True."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    starts = np.flatnonzero(d == 1)
    stops = np.flatnonzero(d == -1)
    return list(zip(starts.tolist(), stops.tolist(), strict=True))


def _support_weights(states: NDArray[np.int64]) -> NDArray[np.float64]:
    """Weight of the left foot per frame (right = 1 − left on contact frames), ramped across
    double support from the foot before to the foot after, so nothing jumps."""
    w = np.where(states == 1, 1.0, 0.0)
    n = states.shape[0]
    for start, stop in _runs(states == 3):
        before = states[start - 1] if start > 0 else -1
        after = states[stop] if stop < n else -1
        a = 1.0 if before == 1 else 0.0 if before == 2 else math.nan
        b = 1.0 if after == 1 else 0.0 if after == 2 else math.nan
        if math.isnan(a):
            a = b
        if math.isnan(b):
            b = a
        if math.isnan(a):
            a = b = 0.5
        frac = (np.arange(start, stop) - start + 1) / (stop - start + 1)
        w[start:stop] = a + (b - a) * frac
    return w


def _contact_translation(recording: KinematicsRecording, feet: tuple[_Feet, _Feet],
                         states: NDArray[np.int64], root: int, *, opt: ContactOptions,
                         progress: Progress
                         ) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                    NDArray[np.float64], int]:
    """Translation (F, 3), floor height (F,), settled floor level under each foot (F, 2,
    NaN in the air) and number of floor levels, from the contact states."""
    p = recording.positions
    dt = 1.0 / recording.fps
    w_left = _support_weights(states)
    translation = _horizontal_path(p, feet, states, w_left, root=root, dt=dt)
    progress(0.8, "path")
    # Vertical: each contact sits on its own floor level. A new contact starts at the level
    # that keeps the body's height continuous, then eases onto a known level within
    # floor_tolerance (flat floors stay flat, platforms keep their own level).
    sole = np.stack([f.sole(p) for f in feet], axis=1)
    ramp = max(1, round(opt.floor_ramp_s * recording.fps))
    support = _Support(states, w_left, sole, p[:, root, 1], dt)
    level, settled, n_levels = _contact_levels(support, ramp, opt)
    y, floor = _contact_heights(support, level)
    _bridge_flights(support, y, floor)
    translation[:, 1] = _lift_above_floor(y, sole, settled, floor, ramp)
    return translation, floor, settled, n_levels


def _horizontal_path(p: NDArray[np.float64], feet: tuple[_Feet, _Feet],
                     states: NDArray[np.int64], w_left: NDArray[np.float64], *, root: int,
                     dt: float) -> NDArray[np.float64]:
    """Translation (F, 3) that keeps the supporting contact points still, with ballistic
    steps across flights and jumps of the pose (:func:`pose_jumps`; the take-off velocity
    of the last 50 ms held); its vertical component is replaced by the caller."""
    n = p.shape[0]
    in_contact = states != 0
    steps_l, steps_r = feet[0].steps(p), feet[1].steps(p)
    pair_contact = in_contact[:-1] & in_contact[1:]
    wl = 0.5 * (w_left[:-1] + w_left[1:])[:, None]
    steps = -(wl * steps_l + (1 - wl) * steps_r)
    pair_contact &= ~pose_jumps(steps, pair_contact, dt)
    steps[~pair_contact] = 0.0
    hips_steps = p[1:, root] - p[:-1, root]
    translation = np.zeros((n, 3))
    np.cumsum(steps, axis=0, out=translation[1:])
    for start, stop in _runs(~pair_contact):  # pair indices: pairs start..stop-1 are ballistic
        k = min(start, max(1, round(0.05 / dt)))
        if k >= 1 and start >= k:
            world = p[start - k:start + 1, root] + translation[start - k:start + 1]
            v0 = (world[-1] - world[0]) / (k * dt)
        else:
            v0 = np.zeros(3)
        ballistic = v0[None, :] * dt - hips_steps[start:stop]
        delta = ballistic - steps[start:stop]
        steps[start:stop] = ballistic
        translation[start + 1:] += np.concatenate(
            [np.cumsum(delta, axis=0), np.repeat(delta.sum(axis=0)[None], n - stop - 1, 0)])
    return translation


def pose_jumps(steps: NDArray[np.float64], carried: NDArray[np.bool_], dt: float
               ) -> NDArray[np.bool_]:
    """Frame pairs whose step no planted point can carry: a jump of the pose.

    Parameters
    ----------
    steps : ndarray, shape (F-1, 3)
        The body's displacement between frames that holding the supporting contact points
        still gives, m.
    carried : ndarray of bool, shape (F-1,)
        Pairs on which a contact point carries the body.
    dt : float
        Frame interval, s.

    Returns
    -------
    ndarray of bool, shape (F-1,)
        Carried pairs whose horizontal speed exceeds ``POSE_JUMP_FACTOR`` times the 99th
        percentile of the carried speeds (the recording's own fastest support) and
        ``POSE_JUMP_MIN_SPEED``: a pose that jumps between two frames (a file's first frame
        in another pose, a dropout) moves the feet, not the body, so the path bridges it
        like a flight instead of carrying the body by the jump.
    """
    speed = np.linalg.norm(steps[:, [0, 2]], axis=1) / dt
    if carried.sum() < 10:
        return np.zeros_like(carried)
    top = float(np.quantile(speed[carried], 0.99))
    out: NDArray[np.bool_] = carried & (speed > max(POSE_JUMP_FACTOR * top,
                                                    POSE_JUMP_MIN_SPEED))
    return out


class _Support(NamedTuple):
    """Per-frame support of the body: contact states, the left foot's share, the feet's
    contact heights (F, 2), the input's hips height and the frame interval."""

    states: NDArray[np.int64]
    w_left: NDArray[np.float64]
    sole: NDArray[np.float64]
    hips_y: NDArray[np.float64]
    dt: float

    def body(self, level: NDArray[np.float64], t: int) -> float:
        """World hips height on contact frame t from the floor ``level`` (F, 2) so far."""
        states = self.states
        w = self.w_left[t] if states[t] == 3 else 1.0 if states[t] == 1 else 0.0
        parts = [(w, 0), (1.0 - w, 1)]
        return float(sum(c * (level[t, k] - self.sole[t, k]) for c, k in parts if c > 0)
                     + self.hips_y[t])


def _contact_levels(support: _Support, ramp: int, opt: ContactOptions
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64], int]:
    """Floor level under each foot per frame while it is in contact (F, 2: easing onto its
    level over ``ramp`` frames; settled level), NaN in the air, and the number of levels."""
    states = support.states
    n = states.shape[0]
    level = np.full((n, 2), math.nan)
    settled = np.full((n, 2), math.nan)
    known: list[float] = []
    segments = sorted([(s, e, k) for k in range(2)
                       for s, e in _runs((states == 1 + k) | (states == 3))])
    last_level: float | None = None
    for start, stop, k in segments:
        candidate = _contact_start_level(support, level, start, k, last_level=last_level,
                                         opt=opt)
        near = [lv for lv in known if abs(lv - candidate) < opt.floor_tolerance]
        target = min(near, key=lambda lv: abs(lv - candidate)) if near else candidate
        if not near:
            known.append(target)
        m = min(ramp, stop - start)
        profile = np.full(stop - start, target)
        profile[:m] = candidate + (target - candidate) * np.arange(1, m + 1) / m
        level[start:stop, k] = profile
        settled[start:stop, k] = target
        last_level = target
    return level, settled, len(known)


def _contact_start_level(support: _Support, level: NDArray[np.float64], start: int, k: int,
                         *, last_level: float | None, opt: ContactOptions) -> float:
    """Floor level of foot ``k``'s contact starting at ``start`` that keeps the body's height
    continuous: from the other foot's level, after a flight from the ballistic take-off,
    on the first contact the input's own height."""
    sole, hips_y, dt = support.sole, support.hips_y, support.dt
    prev = start - 1
    if prev >= 0 and not math.isnan(level[prev, 1 - k]):
        return float(level[prev, 1 - k] - sole[prev, 1 - k] + sole[prev, k])
    if not math.isnan(level[start, 1 - k]):
        return float(level[start, 1 - k] - sole[start, 1 - k] + sole[start, k])
    if last_level is not None and start > 0:
        # Landing after a flight: where the ballistic take-off carries the body.
        t0 = int(np.flatnonzero((~np.isnan(level[:start])).any(axis=1))[-1])
        h0 = support.body(level, t0)
        v0 = (h0 - support.body(level, t0 - 1)) / dt \
            if t0 >= 1 and support.states[t0 - 1] != 0 else 0.0
        span = (start - t0) * dt
        landing = h0 + v0 * span - 0.5 * GRAVITY * span * span
        candidate = float(landing - hips_y[start] + sole[start, k])
        if abs(candidate - last_level) > 2 * opt.floor_tolerance:
            candidate = last_level  # a take-off speed that far off is not to be trusted
        return candidate
    return float(sole[start, k])  # first contact: keep the input's height


def _contact_heights(support: _Support, level: NDArray[np.float64]
                     ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Vertical translation (F,) on contact frames (NaN in flight) and the floor height (F,)
    under the body."""
    states, sole, w_left = support.states, support.sole, support.w_left
    y = np.full(states.shape[0], math.nan)
    for t_arr, k in ((np.flatnonzero(states == 1), 0), (np.flatnonzero(states == 2), 1)):
        y[t_arr] = level[t_arr, k] - sole[t_arr, k]
    both = np.flatnonzero(states == 3)
    wb = w_left[both]
    y[both] = (wb * (level[both, 0] - sole[both, 0])
               + (1 - wb) * (level[both, 1] - sole[both, 1]))
    floor = np.where(states == 1, level[:, 0], np.where(states == 2, level[:, 1],
                     w_left * level[:, 0] + (1 - w_left) * level[:, 1]))
    if np.isnan(y).all():
        y[:] = 0.0
        floor[:] = float(sole.min())
    return y, floor


def _bridge_flights(support: _Support, y: NDArray[np.float64],
                    floor: NDArray[np.float64]) -> None:
    """Fill the flights (NaN runs) of ``y`` in place with ballistic arcs from the take-off
    height and speed, continuous at both ends, and ``floor`` there linearly."""
    hips_y, dt = support.hips_y, support.dt
    n = y.shape[0]
    for start, stop in _runs(np.isnan(y)):
        t = np.arange(start, stop)
        if start > 0 and stop < n:
            h0 = y[start - 1] + hips_y[start - 1]
            h1 = y[stop] + hips_y[stop]
            t0, t1 = start - 1, stop
        elif start > 0:
            h0 = h1 = y[start - 1] + hips_y[start - 1]
            t0, t1 = start - 1, stop
        else:
            h0 = h1 = y[stop] + hips_y[stop]
            t0, t1 = -1, stop
        tau = (t - t0) * dt
        span = (t1 - t0) * dt
        if t0 >= 1 and not math.isnan(y[t0 - 1]):
            v0 = (y[t0] + hips_y[t0] - y[t0 - 1] - hips_y[t0 - 1]) / dt
        else:
            v0 = (h1 - h0) / span + 0.5 * GRAVITY * span
        # Ballistic from the take-off height and speed; a linear term absorbs the miss at
        # landing so both ends stay continuous.
        miss = h1 - (h0 + v0 * span - 0.5 * GRAVITY * span * span)
        arc = h0 + v0 * tau - 0.5 * GRAVITY * tau * tau + miss * tau / span
        if start == 0 or stop == n:
            arc = np.full(t.shape, h0)
        y[start:stop] = arc - hips_y[start:stop]
        f0 = floor[start - 1] if start > 0 else floor[stop]
        f1 = floor[stop] if stop < n else f0
        floor[start:stop] = f0 + (f1 - f0) * (t - start + 1) / (stop - start + 1)


def _lift_above_floor(y: NDArray[np.float64], sole: NDArray[np.float64],
                      settled: NDArray[np.float64], floor: NDArray[np.float64], ramp: int
                      ) -> NDArray[np.float64]:
    """``y`` raised where a foot of the model reaches below the level its contact settled on.

    Kinematics that disagree with the floor lift the body rather than sink a foot; the lift
    is spread over ``ramp`` frames so it makes no jump."""
    under = np.stack([_swing_floor(settled[:, k], floor) for k in range(2)], axis=1)
    need = np.maximum((under - sole - y[:, None]).max(axis=1), 0.0)
    if need.any():
        width = max(1, ramp)
        lift = gaussian_filter1d(maximum_filter1d(need, 2 * width + 1, mode="nearest"),
                                 width / 3.0, mode="nearest")
        y = y + np.maximum(lift, need)
    return y


def _file_states(recording: KinematicsRecording, names: tuple[str, str]) -> NDArray[np.int64]:
    left = recording.contacts[names[0]]
    right = recording.contacts[names[1]]
    return left.astype(np.int64) + 2 * right.astype(np.int64)


# --------------------------------------------------------------------------- entry point


def estimate_translation(
    recording: KinematicsRecording,
    *,
    method: str = "contact",
    left_foot: str | None = None,
    right_foot: str | None = None,
    progress: Progress | None = None,
    options: MethodOptions | None = None,
    **method_options: Any,
) -> TranslationResult:
    """Estimate the root path of an inertial-suit recording.

    Parameters
    ----------
    recording : KinematicsRecording
        Global joint positions (any root translation in them is replaced) and foot
        accelerometers.
    method : {"contact", "hachaj2018"}
        ``hachaj2018``: the authors' implementation exactly (window of 100 samples, three
        passes, ground at the right foot's first height); assumes at least one foot on a flat
        floor at all times, no sliding, and that the moving foot has the larger smoothed
        acceleration magnitude. ``contact``: the stance model of :class:`ContactOptions`.
    left_foot, right_foot : str, optional
        Foot joints; default the recording's.
    progress : callable, optional
        ``progress(fraction, stage)``.
    options : ContactOptions or HachajOptions, optional
        The method's options as one object (``METHOD_OPTIONS[method]``); default: from
        ``method_options``.
    **method_options
        Instead of ``options``, its fields as keywords: ``hachaj2018``: ``window`` (samples,
        100) and ``eps`` (m, 0.05) of :class:`HachajOptions`; ``contact``: any field of
        :class:`ContactOptions`.

    Returns
    -------
    TranslationResult

    Raises
    ------
    InputError
        Unknown method or option, both ``options`` and keywords, an option outside its range
        (``field`` names it: ``CONTACT_OPTION_RANGES``, ``HACHAJ_WINDOW_RANGE``,
        ``HACHAJ_EPS_RANGE``), a frame rate outside ``params.MIN_FPS`` … ``params.MAX_FPS``
        (``field="fps"``), unknown foot joint.
    EstimationError
        Fewer than 3 frames.

    Notes
    -----
    References in the module docstring.
    """
    report = progress or no_progress
    started = _time.perf_counter()
    if method not in METHODS:
        raise InputError(f"unknown method {method!r}; use {', '.join(METHODS)}", field="method")
    check_fps(recording.fps)
    names = _foot_names(recording, left_foot, right_foot)
    root = recording.index(recording.root)
    if recording.n_frames < 3:
        raise EstimationError("need at least 3 frames to estimate a translation",
                              field="frames")
    opt = resolved_options(method, METHOD_OPTIONS, options, method_options)
    report(0.0, method)
    timings: dict[str, float] = {}
    if isinstance(opt, HachajOptions):
        path = _hachaj_path(recording, names, opt, report)
    else:
        path = _contact_path(recording, names, root, opt, report=report, started=started)
        timings["contacts_s"] = path.contacts_s
    quality = translation_quality(path.corrected, recording.fps, root, path.feet,
                                  contacts=path.contacts, floor=path.floor, levels=path.levels)
    quality.update(path.extra)
    timings["estimate_s"] = _time.perf_counter() - started
    report(1.0, "done")
    return TranslationResult(root=path.corrected[:, root].copy(), translation=path.translation,
                             positions=path.corrected,
                             contacts=path.contacts, floor=path.floor,
                             quality=TranslationQuality.of(quality),
                             method=method, fps=recording.fps, timings=timings)


def _foot_names(recording: KinematicsRecording, left_foot: str | None,
                right_foot: str | None) -> tuple[str, str]:
    """The foot joints asked for (default the recording's), present with accelerations."""
    lf = left_foot or recording.left_foot
    rf = right_foot or recording.right_foot
    for foot in (lf, rf):
        recording.index(foot)  # InputError listing the joints when absent
    for foot in (lf, rf):
        if foot not in recording.accelerations:
            raise InputError(f"no accelerations for foot {foot!r}; sensors: "
                             f"{', '.join(recording.accelerations)}", sensor=foot)
    return lf, rf


class _Path(NamedTuple):
    """What a method found: the translation and what the quality figures need."""

    translation: NDArray[np.float64]  # (F, 3) added to every joint, m
    corrected: NDArray[np.float64]  # (F, J, 3)
    contacts: NDArray[np.str_]  # (F,) labels
    floor: NDArray[np.float64]  # (F,)
    levels: NDArray[np.float64] | None  # (F, 2) settled level under each foot, or None
    feet: tuple[_Feet, _Feet]
    extra: dict[str, Any]  # method-specific quality figures
    contacts_s: float = 0.0  # seconds from the estimate's start to the contacts


def _hachaj_path(recording: KinematicsRecording, names: tuple[str, str], opt: HachajOptions,
                 report: Progress) -> _Path:
    """``hachaj2018``'s translation; its floor is the median height of the planted soles."""
    lf, rf = names
    li, ri = recording.index(lf), recording.index(rf)
    feet = _feet(recording, lf, rf, use_toes=True)
    translation, contacts, ground = _hachaj(recording, (li, ri), names, report, opt)
    corrected = recording.positions + translation[:, None, :]
    soles = np.stack([f.sole(corrected) for f in feet], axis=1)
    planted = np.where(contacts == "right", soles[:, 1], soles[:, 0])
    floor = np.full(recording.n_frames, float(np.median(planted)))
    extra = {"ground_m": ground,
             "window_samples": hachaj_window_length(recording.n_frames, opt.window)}
    return _Path(translation, corrected, contacts, floor, None, feet, extra)


def _contact_path(recording: KinematicsRecording, names: tuple[str, str], root: int,
                  opt: ContactOptions, *, report: Progress, started: float) -> _Path:
    """The contact model's translation: contact states (from the file or decoded), then the
    path that keeps the planted feet still (a ball of the foot placed on an End Site: the
    sole's heel and ball, ``stance.ball_on_foot``); ``contacts_s`` counts from
    ``started``."""
    lf, rf = names
    feet = _feet(recording, lf, rf, use_toes=opt.use_toes)
    extra: dict[str, Any] = {}
    if opt.use_file_contacts and all(k in recording.contacts for k in names):
        # the file's contacts need no choice: toe points only where asked for outright
        extended = (_extended_feet(recording, names, root, sole=True)
                    if opt.use_toes and opt.extrapolate_toes else None)
        feet = extended if extended is not None else feet
        states = _file_states(recording, names)
        extra["contacts_source"] = "file"
    else:
        extended = _extended_feet(recording, names, root) if opt.use_toes else None
        feet, states, info = _chosen_feet(recording, feet, extended, names=names, root=root,
                                          opt=opt)
        if extended is not None and feet is extended:
            # decoded with the toe joint's ball, held still on the sole's points
            feet = _extended_feet(recording, names, root, sole=True) or feet
        extra.update(info)
        extra["contacts_source"] = "accelerometers"
    report(0.6, "contacts")
    contacts_s = _time.perf_counter() - started
    translation, floor, levels, n_levels = _contact_translation(
        recording, feet, states, root, opt=opt, progress=report)
    contacts = np.asarray(CONTACT_LABELS, dtype="<U5")[states]
    corrected = recording.positions + translation[:, None, :]
    extra["floor_levels"] = n_levels
    extra["toes"] = {name: recording.joints[f.toe] for name, f in zip(names, feet, strict=True)
                     if f.toe is not None}
    balls = {name: recording.joints[f.end] for name, f in zip(names, feet, strict=True)
             if f.end is not None}
    if balls:  # the ball of the foot placed on these points rigid with the foot
        extra["balls_on"] = balls
    return _Path(translation, corrected, contacts, floor, levels, feet, extra, contacts_s)


def _extended_feet(recording: KinematicsRecording, names: tuple[str, str], root: int, *,
                   sole: bool = False) -> tuple[_Feet, _Feet] | None:
    """The feet with a toe point extrapolated where the file has no toe joint: the ball of
    the foot on a point rigid with it (``sole``: see :func:`_feet`), else the rolled point
    (:func:`_rolling_feet`); None when that changes nothing (both feet have toe joints, or
    no leg is found)."""
    feet = _feet(recording, *names, use_toes=True, balls=True, sole=sole)
    feet = _rolling_feet(recording, feet, names, root)
    if all(f.toe is not None or (f.end is None and f.roll is None) for f in feet):
        return None
    return feet


def _chosen_feet(recording: KinematicsRecording, feet: tuple[_Feet, _Feet],
                 extended: tuple[_Feet, _Feet] | None, *, names: tuple[str, str], root: int,
                 opt: ContactOptions
                 ) -> tuple[tuple[_Feet, _Feet], NDArray[np.int64], dict[str, Any]]:
    """Feet and decoded states: with ``extended`` feet (toe points extrapolated) the toe
    point unless the ankle's decoding is the cheaper per 10 ms both in all and in its
    accelerometer part alone (``choose_toes``: :func:`ankle_explains_better`), or the
    extended one outright (``extrapolate_toes``)."""
    if extended is not None and opt.extrapolate_toes:
        feet = extended
    states, info = _contact_states(recording, feet, names, root, opt)
    chosen = "extrapolated" if feet is extended else "ankle"
    if extended is not None and opt.choose_toes and feet is not extended:
        states_x, info_x = _contact_states(recording, extended, names, root, opt)
        costs = {f"{key}_{model}": part[key] for model, part in
                 (("ankle", info), ("extrapolated", info_x))
                 for key in ("decoded_cost", "decoded_accelerometer_cost")}
        if not ankle_explains_better(info, info_x):
            feet, states, info, chosen = extended, states_x, info_x, "extrapolated"
        info.update(costs)
    if extended is not None:
        info["toe_model"] = chosen
    return feet, states, info


def ankle_explains_better(ankle: Mapping[str, float], toe: Mapping[str, float]) -> bool:
    """Whether ``choose_toes`` keeps the ankle held still rather than the toe point.

    Parameters
    ----------
    ankle, toe : mapping of str to float
        Each model's decoding: ``decoded_cost`` (the Viterbi path's cost per 10 ms) and
        ``decoded_accelerometer_cost`` (its accelerometer residuals alone, per 10 ms).

    Returns
    -------
    bool
        True when the ankle's decoding is the cheaper on both. The toe point's model holds
        the ankle still too while the foot stands flat, so it is kept unless the data favour
        the ankle outright: by the whole cost alone the priors (more single-support frames,
        more switches) outweighed a better accelerometer fit where the foot rolls only now
        and then (a kick's heel-off), by the accelerometer part alone a sensor near the ball
        read like the ankle's still point (docs/translation.md).
    """
    return bool(ankle["decoded_cost"] <= toe["decoded_cost"]
                and ankle["decoded_accelerometer_cost"] <= toe["decoded_accelerometer_cost"])


def _rolling_feet(recording: KinematicsRecording, feet: tuple[_Feet, _Feet],
                  names: tuple[str, str], root: int) -> tuple[_Feet, _Feet]:
    """``feet`` where a foot without a toe joint gets a contact point that rolls from the
    ankle over the ball of the foot: the ankle moved back along the body's heading (the hip
    line) by ``stance.roll_advance`` of the heel lift that raises it above the other ankle
    (``stance.rise_tilt``). A flat foot's point is the ankle, and the point moves only while
    the heel lifts (turning the heading with the heel up moves nothing), so a foot turning
    on the spot does not sweep it. Unchanged when the legs cannot be found."""
    if all(f.has_toe for f in feet):
        return feet
    p = recording.positions
    ankles = [f.heel for f in feet]
    leg = leg_length(p, ankles[0], root)
    found = [leg_joints(p, ankle, leg) for ankle in ankles]
    legs = [lg for lg in found if lg is not None]
    if len(legs) < 2 or leg <= 0:
        return feet
    heading = heading_by_knees(body_heading(p[:, legs[0][1]], p[:, legs[1][1]]),
                               [p[:, hip] for _knee, hip in legs],
                               [p[:, knee] for knee, _hip in legs], [p[:, a] for a in ankles])
    between = 0.5 * (heading[1:] + heading[:-1])
    out = []
    for k, foot in enumerate(feet):
        if not foot.has_toe:
            tilt = rise_tilt(p[:, ankles[k]], p[:, ankles[1 - k]], leg)
            shift = np.zeros((p.shape[0], 3))
            np.cumsum(between * np.diff(roll_advance(tilt, leg))[:, None], axis=0,
                      out=shift[1:])
            foot = replace(foot, roll=shift)
        out.append(foot)
    return out[0], out[1]

