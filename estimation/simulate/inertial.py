"""Synthetic inertial-suit recordings with a known root path, from real BVH clips.

The protocol of docs/benchmarks.md ("The evaluation protocol", translation): strip the root
translation of a real clip, compute the foot accelerometer signals from the true motion
(sensor frame, g, gravity included, white noise, optional saturation), resample to the rate of
a suit, and keep the true hips path for scoring.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import CubicSpline
from scipy.signal import savgol_filter
from scipy.spatial.transform import Rotation

from ..bvh import BvhMotion, forward_kinematics
from ..errors import InputError
from ..io.body import longest_child, varying_root
from ..kinematics import GRAVITY, KinematicsRecording
from ..params import resolved_options

FOOT_NAMES: Final[tuple[tuple[str, str], ...]] = (
    ("LeftFoot", "RightFoot"),
    ("Foot_L", "Foot_R"),
    ("LeftAnkle", "RightAnkle"),
    ("lFoot", "rFoot"),
)
"""Foot joint names tried, in order, when none are given (generic, Bandai Namco, CMU
subject 131, Daz-style)."""


@dataclass(frozen=True, eq=False)
class InertialTruth:
    """Ground truth of a simulated inertial recording.

    Attributes
    ----------
    root : ndarray, shape (F, 3)
        True world path of the root joint (hips), metres, +Y up.
    positions : ndarray, shape (F, J, 3)
        True world joint positions, metres.
    root_joint : str
        Name of the root joint.
    sensor_offsets : mapping of str to ndarray, shape (3,)
        Foot → offset of its accelerometer from the foot joint in the foot joint's frame,
        metres (zero at the ankle).
    """

    root: NDArray[np.float64]
    positions: NDArray[np.float64]
    root_joint: str
    sensor_offsets: Mapping[str, NDArray[np.float64]] = field(default_factory=dict)

    def horizontal_errors(self, estimated_root: NDArray[np.float64]
                          ) -> dict[str, float]:
        """Mean and final horizontal hips error as % of the true horizontal path length.

        Both paths start at the same point (the stripped clip keeps frame 0's root position).
        """
        true_h = self.root[:, [0, 2]]
        est_h = estimated_root[:, [0, 2]] - estimated_root[0, [0, 2]] + true_h[0]
        err = np.linalg.norm(est_h - true_h, axis=1)
        length = float(np.linalg.norm(np.diff(true_h, axis=0), axis=1).sum())
        scale = 100.0 / length if length > 0 else float("nan")
        return {"mean_pct": float(err.mean() * scale), "final_pct": float(err[-1] * scale),
                "path_m": length, "mean_m": float(err.mean()), "final_m": float(err[-1])}


def foot_names(motion: BvhMotion) -> tuple[str, str]:
    """The first pair of :data:`FOOT_NAMES` present in ``motion``."""
    for left, right in FOOT_NAMES:
        if left in motion.names and right in motion.names:
            return left, right
    raise InputError("cannot find the foot joints; pass left_foot and right_foot "
                     f"(joints: {', '.join(motion.names)})", field="left_foot")


@dataclass(frozen=True)
class FootMount:
    """Where a suit straps the foot accelerometer, drawn per recording and foot.

    The offset is in an anatomical frame of the foot fixed to its bone: ``forward`` along the
    ankle → toe bone, ``up`` perpendicular to it (towards the sky when the foot stands),
    ``lateral`` the third axis. Each is drawn uniformly from its (low, high) range, metres.

    Attributes
    ----------
    forward_m, up_m, lateral_m : tuple of float
        Ranges of the sensor's offset from the ankle joint, metres.
    keep_toes : bool
        Give the estimator the toe joints (and everything below the feet); False drops them,
        as in files without toe joints, and gives each foot an End Site (``<foot>_end``)
        instead: a point rigid with the foot where the toe joint's offset, scaled by 0.7–1.5
        and turned by up to 20° about a random axis, puts it (files put their foot End
        Sites anywhere from the ball to the tip of the foot).
    bias_g : float
        Standard deviation of a constant per-axis accelerometer bias, g.
    """

    forward_m: tuple[float, float] = (0.0, 0.0)
    up_m: tuple[float, float] = (0.0, 0.0)
    lateral_m: tuple[float, float] = (0.0, 0.0)
    keep_toes: bool = True
    bias_g: float = 0.0

    def draw(self, rng: np.random.Generator) -> NDArray[np.float64]:
        """Offset (3,) forward, up, lateral, metres."""
        return np.array([rng.uniform(*self.forward_m), rng.uniform(*self.up_m),
                         rng.uniform(*self.lateral_m)])


ANKLE_MOUNT: Final[FootMount] = FootMount()
"""The sensor exactly at the ankle joint (the protocol before issue 20)."""

INSTEP_MOUNT: Final[FootMount] = FootMount(forward_m=(0.03, 0.08), up_m=(0.02, 0.06),
                                           lateral_m=(-0.015, 0.015), bias_g=0.01)
"""The sensor on the instep as suits strap it: 3–8 cm ahead of the ankle, 2–6 cm above the
foot bone, ±1.5 cm sideways, a random mounting rotation, a bias of 0.01 g per axis."""


@dataclass(frozen=True)
class InertialSimulation:
    """The foot accelerometers of :func:`simulate_inertial` (its keywords of the same names).

    Attributes
    ----------
    left_foot, right_foot : str, optional
        Foot joints carrying the accelerometers; default from :data:`FOOT_NAMES`.
    noise_g : float
        Standard deviation of white accelerometer noise per axis, g.
    clip_g : float, optional
        Accelerometer range: components saturate at ±clip_g (2 for the Shadow suit).
    mount : FootMount
        :data:`ANKLE_MOUNT` (default, at the joint) or :data:`INSTEP_MOUNT` (suits' placement).

    Examples
    --------
    >>> InertialSimulation(noise_g=0.0, clip_g=2.0, mount=INSTEP_MOUNT).mount.bias_g
    0.01
    """

    left_foot: str | None = None
    right_foot: str | None = None
    noise_g: float = 0.01
    clip_g: float | None = None
    mount: FootMount = ANKLE_MOUNT


def simulate_inertial(
    motion: BvhMotion,
    *,
    fps: float | None = None,
    source_fps: float | None = None,
    length_units_m: float = 0.01,
    seed: int = 0,
    options: InertialSimulation | None = None,
    **settings: Any,
) -> tuple[KinematicsRecording, InertialTruth]:
    """Turn a BVH clip into an inertial-suit recording with a known root path.

    Parameters
    ----------
    motion : BvhMotion
        Real motion (Y up).
    fps : float, optional
        Rate of the simulated suit (e.g. 30, 60, 100 Hz); default the clip's.
    source_fps : float, optional
        True rate of the clip when its header is wrong (CMU salsa: 60, not 120).
    length_units_m : float
        Metres per BVH unit (0.01 for cm, 0.05644 for CMU units).
    seed : int
    options : InertialSimulation, optional
        The accelerometers as one object; default: from ``settings``.
    **settings
        Instead of ``options``, its fields (``left_foot``, ``right_foot``, ``noise_g``,
        ``clip_g``, ``mount``).

    Returns
    -------
    recording : KinematicsRecording
        Positions without root translation (root frozen at frame 0), foot accelerometers
        (sensor frame = foot frame times a random fixed mounting rotation, gravity included).
    truth : InertialTruth

    Notes
    -----
    Second derivatives of a Savitzky–Golay fit (0.1 s, cubic) of the sensor point's path
    (ankle + R_foot r: lever-arm terms α×r + ω×(ω×r) exact), band-limited, then resampled.
    """
    opt = resolved_options("simulate_inertial", {"simulate_inertial": InertialSimulation},
                           options, settings)
    left_foot, right_foot, mount = opt.left_foot, opt.right_foot, opt.mount
    if left_foot is None or right_foot is None:
        left_foot, right_foot = foot_names(motion)
    feet = (left_foot, right_foot)
    for foot in feet:
        motion.index(foot)
    rate = float(source_fps) if source_fps is not None else motion.fps
    target = float(fps) if fps is not None else rate
    rng = np.random.default_rng(seed)
    world, rotations = forward_kinematics(motion)
    world = world * length_units_m
    root = varying_root(motion)
    t_src = np.arange(motion.n_frames) / rate
    offsets = _sensor_offsets(motion, world, rotations, feet, mount=mount, seed=seed)
    sensor = _mounted_accelerometers(motion, world, rotations, offsets, rate=rate, rng=rng)
    t_new = np.arange(0.0, t_src[-1] + 0.5 / target, 1.0 / target)
    t_new = t_new[t_new <= t_src[-1] + 1e-9]
    names, given = _given_joints(motion, world, rotations, feet, mount=mount, seed=seed)
    positions = CubicSpline(t_src, given - (world[:, root] - world[0, root])[:, None, :],
                            axis=0)(t_new)
    true_pos = CubicSpline(t_src, world, axis=0)(t_new)
    bias_rng = np.random.default_rng([seed, 2])
    out_acc = {foot: _accelerometer_readings(CubicSpline(t_src, acc, axis=0)(t_new),
                                             opt.noise_g, opt.clip_g, rng)
               + bias_rng.normal(0.0, mount.bias_g * GRAVITY, 3)
               for foot, acc in sensor.items()}
    recording = KinematicsRecording(
        joints=names, positions=positions, fps=target,
        time=t_new, accelerations=out_acc, acceleration_frame="sensor", left_foot=left_foot,
        right_foot=right_foot, toes=_toes(motion, feet) if mount.keep_toes else {},
        source_format="simulated", length_scale=length_units_m, root=motion.names[root],
        notes=(f"simulated from a {rate:g} fps clip at {target:g} fps",))
    truth = InertialTruth(root=true_pos[:, root].copy(), positions=true_pos,
                          root_joint=motion.names[root], sensor_offsets=offsets)
    return recording, truth


def _toes(motion: BvhMotion, feet: tuple[str, str]) -> dict[str, str]:
    """Foot → its longest child (toe joint or end site), for the feet that have one."""
    toes = {}
    for foot in feet:
        child = longest_child(motion, motion.names.index(foot))
        if child is not None:
            toes[foot] = motion.names[child]
    return toes


def _given_joints(motion: BvhMotion, world: NDArray[np.float64], rotations: list[Rotation],
                  feet: tuple[str, str], *, mount: FootMount, seed: int
                  ) -> tuple[tuple[str, ...], NDArray[np.float64]]:
    """Names and world paths (F, J', 3) of the joints given to the estimator: all, or (no toe
    joints) all but those below the feet plus an End Site per foot."""
    keep = _kept_joints(motion, feet, mount.keep_toes)
    names = tuple(motion.names[j] for j in keep)
    ends = {} if mount.keep_toes else _foot_end_sites(motion, world, rotations, feet,
                                                         seed=seed)
    if not ends:
        return names, world[:, keep]
    return (names + tuple(f"{foot}_end" for foot in ends),
            np.concatenate([world[:, keep], np.stack(list(ends.values()), axis=1)], axis=1))


def _foot_end_sites(motion: BvhMotion, world: NDArray[np.float64],
                    rotations: list[Rotation], feet: tuple[str, str], *, seed: int
                    ) -> dict[str, NDArray[np.float64]]:
    """Path (F, 3) of an End Site rigid with each foot that has a child: the child's offset
    (of ``world`` (F, J, 3), metres, in the foot's frame) scaled by 0.7–1.5 and turned by up
    to 20° about a random axis (see :class:`FootMount`)."""
    rng = np.random.default_rng([seed, 3])
    out = {}
    for foot in feet:
        j = motion.names.index(foot)
        child = longest_child(motion, j)
        if child is None:
            continue
        local = rotations[j][0].inv().apply(world[0, child] - world[0, j])
        axis = rng.normal(size=3)
        turn = Rotation.from_rotvec(axis / np.linalg.norm(axis)
                                    * np.radians(rng.uniform(-20.0, 20.0)))
        offset = turn.apply(local) * rng.uniform(0.7, 1.5)
        out[foot] = world[:, j] + rotations[j].apply(offset)
    return out


def _kept_joints(motion: BvhMotion, feet: tuple[str, str], keep_toes: bool) -> list[int]:
    """Indices of the joints given to the estimator: all, or all but those below the feet."""
    if keep_toes:
        return list(range(len(motion.names)))
    below = {motion.names.index(f) for f in feet}
    dropped: set[int] = set()
    for j, parent in enumerate(motion.parents):  # parents come before their children
        if parent in below or parent in dropped:
            dropped.add(j)
    return [j for j in range(len(motion.names)) if j not in dropped]


def _sensor_offsets(motion: BvhMotion, world: NDArray[np.float64], rotations: list[Rotation],
                    feet: tuple[str, str], *, mount: FootMount, seed: int
                    ) -> dict[str, NDArray[np.float64]]:
    """Offset (3,) of each foot's sensor from its ankle in the foot joint's own frame,
    metres: ``mount``'s forward/up/lateral draw on the foot's axes averaged over the take
    in the foot frame (up: world up; forward: the horizontal ankle → toe direction, made
    perpendicular to up), i.e. the axes of the foot as it stands."""
    rng = np.random.default_rng([seed, 1])
    out = {}
    for foot in feet:
        j = motion.names.index(foot)
        drawn = mount.draw(rng)
        child = longest_child(motion, j)
        if not drawn.any() or child is None:
            out[foot] = np.zeros(3)
            continue
        ahead = world[:, child] - world[:, j]
        ahead[:, 1] = 0.0
        ahead /= np.maximum(np.linalg.norm(ahead, axis=1, keepdims=True), 1e-12)
        up = rotations[j].inv().apply(np.array([0.0, 1.0, 0.0])).mean(axis=0)
        up /= np.linalg.norm(up)
        forward = rotations[j].inv().apply(ahead).mean(axis=0)
        forward -= up * (up @ forward)
        forward /= np.linalg.norm(forward)
        out[foot] = drawn @ np.stack([forward, up, np.cross(forward, up)])
    return out


def _mounted_accelerometers(motion: BvhMotion, world: NDArray[np.float64],
                            rotations: list[Rotation], offsets: dict[str, NDArray[np.float64]],
                            *, rate: float, rng: np.random.Generator
                            ) -> dict[str, NDArray[np.float64]]:
    """Noise-free accelerometer readings (F, 3) of each foot at the clip's rate, m/s²:
    second derivatives of a Savitzky–Golay fit (0.1 s, cubic) of the path of the sensor point
    (foot joint of ``world`` (F, J, 3, metres) plus the foot's rotation times its offset in
    ``offsets``, metres), plus gravity, in the foot frame times a random mounting rotation."""
    window = max(5, round(0.1 * rate) | 1)
    if window >= motion.n_frames:
        raise InputError("clip too short to simulate accelerations", field="frames")
    accelerations = {}
    up = np.array([0.0, GRAVITY, 0.0])
    for foot, offset in offsets.items():
        j = motion.names.index(foot)
        point = world[:, j] + rotations[j].apply(offset)
        acc = savgol_filter(point, window, 3, deriv=2, delta=1.0 / rate, axis=0)
        mount = Rotation.random(random_state=int(rng.integers(2**31)))
        accelerations[foot] = (rotations[j] * mount).inv().apply(acc + up)
    return accelerations


def _accelerometer_readings(exact: NDArray[np.float64], noise_g: float,
                            clip_g: float | None, rng: np.random.Generator
                            ) -> NDArray[np.float64]:
    """``exact`` readings (F, 3, m/s²) with white noise of ``noise_g`` g per axis, clipped at
    ±``clip_g`` g when given, m/s²."""
    a = exact / GRAVITY
    a = a + rng.normal(0.0, noise_g, a.shape)
    if clip_g is not None:
        a = np.clip(a, -clip_g, clip_g)
    return np.asarray(a * GRAVITY)


def _min_jerk(u: NDArray[np.float64]) -> NDArray[np.float64]:
    return u ** 3 * (10 - 15 * u + 6 * u ** 2)


def simulate_walker(
    *,
    fps: float = 100.0,
    platform: float = 0.15,
    hop: float = 0.15,
    noise_g: float = 0.01,
    clip_g: float | None = None,
    seed: int = 0,
) -> tuple[KinematicsRecording, InertialTruth, NDArray[np.str_]]:
    """A procedural walker with an exactly known path and contacts.

    Stands 1 s, walks four steps (double support between them), crouches and hops in place
    ``hop`` metres high (ballistic flight of 0.35 s for 15 cm), then steps onto a platform
    ``platform`` metres high and walks on it.
    Joints: ``Hips``, ``LeftFoot``, ``LeftToe``, ``RightFoot``, ``RightToe``; the feet stay
    flat (ankle 8 cm, toe 1 cm above the floor when planted).

    Returns
    -------
    recording : KinematicsRecording
        Positions without root translation, foot accelerometers (g, gravity, sensor frame =
        world frame, noise, optional clipping) in m/s².
    truth : InertialTruth
    contacts : ndarray of str, shape (F,)
        True ``"left"``, ``"right"``, ``"both"`` or ``"none"`` per frame.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, _WALKER_S + 1e-9, 1.0 / _FINE_HZ)
    feet, planted = _walker_feet(t, platform)
    hips = np.stack([gaussian_smooth(0.5 * (feet["L"][:, 0] + feet["R"][:, 0]), 0.1 * _FINE_HZ),
                     0.9 + gaussian_smooth(0.5 * (feet["L"][:, 1] + feet["R"][:, 1])
                                           - _ANKLE_M, 0.1 * _FINE_HZ),
                     np.zeros_like(t)], axis=1)
    _hop(t, hops=hop, hips=hips, feet=feet, planted=planted)
    toes = {f: feet[f] + np.array([_TOE_FORWARD_M, _TOE_UP_M - _ANKLE_M, 0.0]) for f in feet}
    world = np.stack([hips, feet["L"], toes["L"], feet["R"], toes["R"]], axis=1)
    t_out = np.arange(0.0, _WALKER_S + 1e-9, 1.0 / fps)
    acc = {f: _resample(t_out, t, np.gradient(np.gradient(feet[f], 1.0 / _FINE_HZ, axis=0),
                                              1.0 / _FINE_HZ, axis=0))
           for f in ("L", "R")}
    world = _resample(t_out, t, world)
    stripped = world - (world[:, 0] - world[0, 0])[:, None, :]
    names = ("Hips", "LeftFoot", "LeftToe", "RightFoot", "RightToe")
    accelerations = {}
    for f, name in (("L", "LeftFoot"), ("R", "RightFoot")):
        accelerations[name] = _accelerometer_readings(acc[f] + np.array([0.0, GRAVITY, 0.0]),
                                                      noise_g, clip_g, rng)
    nearest = np.clip(np.round(t_out * _FINE_HZ).astype(int), 0, t.shape[0] - 1)
    left, right = planted["L"][nearest], planted["R"][nearest]
    labels = np.asarray(("none", "left", "right", "both"), dtype="<U5")[
        left.astype(int) + 2 * right.astype(int)]
    recording = KinematicsRecording(
        joints=names, positions=stripped, fps=fps, time=t_out, accelerations=accelerations,
        acceleration_frame="sensor", left_foot="LeftFoot", right_foot="RightFoot",
        toes={"LeftFoot": "LeftToe", "RightFoot": "RightToe"}, source_format="simulated",
        length_scale=1.0, root="Hips", notes=("procedural walker",))
    truth = InertialTruth(root=world[:, 0].copy(), positions=world, root_joint="Hips")
    return recording, truth, labels


_FINE_HZ = 1000.0
"""Rate at which the walker is built before it is sampled at the wanted one, Hz."""
_WALKER_S = 7.5
"""Duration of the walker, seconds."""
_ANKLE_M, _TOE_UP_M, _TOE_FORWARD_M = 0.08, 0.01, 0.15
"""Heights of a planted ankle and toe above the floor, and the toe ahead of the ankle, m."""
_TAKE_OFF_S = 4.0
"""Time of the walker's hop."""
_PUSH_S = 0.2
"""Duration of the hop's push-off, of its landing and of each crouch, seconds."""


def _walker_swings(platform: float) -> list[tuple[str, float, float, float, float]]:
    """(foot, start s, end s, target x, target floor level) of every step of the walker."""
    return [
        ("R", 1.00, 1.40, 0.3, 0.0), ("L", 1.55, 1.95, 0.6, 0.0),
        ("R", 2.10, 2.50, 0.9, 0.0), ("L", 2.65, 3.05, 1.2, 0.0),
        ("R", 3.20, 3.60, 1.2, 0.0),
        ("L", 4.80, 5.20, 1.5, platform), ("R", 5.35, 5.75, 1.8, platform),
        ("L", 5.90, 6.30, 2.1, platform), ("R", 6.45, 6.85, 2.1, platform),
    ]


def _walker_feet(t: NDArray[np.float64], platform: float
                 ) -> tuple[dict[str, NDArray[np.float64]], dict[str, NDArray[np.bool_]]]:
    """Ankle positions (F, 3) and planted flags (F,) of each foot ("L", "R") at times ``t``:
    minimum-jerk swings with an 8 cm bump, flat on the floor or the platform between."""
    side = {"L": 0.1, "R": -0.1}
    feet = {}
    planted = {}
    for foot in ("L", "R"):
        x = np.zeros_like(t)
        y = np.full_like(t, _ANKLE_M)
        on = np.ones(t.shape, dtype=bool)
        cur_x, cur_level = 0.0, 0.0
        for f, t0, t1, tx, level in _walker_swings(platform):
            if f != foot:
                continue
            u = np.clip((t - t0) / (t1 - t0), 0.0, 1.0)
            s = _min_jerk(u)
            inside = (t >= t0) & (t < t1)
            after = t >= t1
            bump = 0.08 * np.sin(np.pi * u) ** 2
            x = np.where(inside, cur_x + (tx - cur_x) * s, np.where(after, tx, x))
            y = np.where(inside, _ANKLE_M + cur_level + (level - cur_level) * s + bump,
                         np.where(after, _ANKLE_M + level, y))
            on &= ~inside
            cur_x, cur_level = tx, level
        feet[foot] = np.stack([x, y, np.full_like(t, side[foot])], axis=1)
        planted[foot] = on
    return feet, planted


def _hop(t: NDArray[np.float64], *, hops: float, hips: NDArray[np.float64],
         feet: dict[str, NDArray[np.float64]], planted: dict[str, NDArray[np.bool_]]) -> None:
    """Add the hop of ``hops`` metres at ``_TAKE_OFF_S`` to ``hips`` and ``feet`` in place
    and clear ``planted`` in flight.

    Crouch, push off (hips accelerate up over the planted feet), ballistic flight, absorb
    the landing, stand up; the take-off speed is what the legs gave the hips."""
    v0 = float(np.sqrt(2.0 * GRAVITY * hops))
    span = 2.0 * v0 / GRAVITY
    push = _PUSH_S
    depth = v0 * push / 2.0
    t_off = _TAKE_OFF_S
    t_on = t_off + span
    crouch = np.zeros_like(t)
    u = np.clip((t - (t_off - 2 * push)) / push, 0.0, 1.0)
    crouch -= depth * _min_jerk(u)
    pushing = (t >= t_off - push) & (t < t_off)
    tau = t[pushing] - (t_off - push)
    crouch[pushing] = -depth + v0 * tau ** 2 / (2 * push)
    in_air = (t >= t_off) & (t < t_on)
    crouch[in_air] = 0.0
    landing = (t >= t_on) & (t < t_on + push)
    tau = t[landing] - t_on
    crouch[landing] = -(v0 * tau - v0 * tau ** 2 / (2 * push))
    rise = t >= t_on + push
    crouch[rise] = -depth * (1.0 - _min_jerk(np.clip((t[rise] - t_on - push) / push, 0.0, 1.0)))
    hips[:, 1] += crouch
    tau = t[in_air] - t_off
    lift = v0 * tau - 0.5 * GRAVITY * tau ** 2
    for foot in ("L", "R"):
        feet[foot][in_air, 1] += lift
        planted[foot] &= ~in_air
    hips[in_air, 1] += lift


def _resample(t_out: NDArray[np.float64], t: NDArray[np.float64], x: NDArray[np.float64]
              ) -> NDArray[np.float64]:
    """``x`` (F, ...) sampled at times ``t`` linearly interpolated at ``t_out``."""
    flat = x.reshape(x.shape[0], -1)
    cols = [np.interp(t_out, t, flat[:, c]) for c in range(flat.shape[1])]
    return np.stack(cols, axis=1).reshape((t_out.shape[0], *x.shape[1:]))


def gaussian_smooth(x: NDArray[np.float64], sigma: float) -> NDArray[np.float64]:
    """Gaussian smoothing with edge replication (σ in samples)."""
    from scipy.ndimage import gaussian_filter1d

    out: NDArray[np.float64] = gaussian_filter1d(x, sigma, mode="nearest")
    return out
