"""Synthetic 6-DOF sensor recordings with exact joint centres, from BVH motion.

Follows the evaluation protocol of docs/benchmarks.md: a rigid 15-segment body is built from a BVH
clip (the rotations of any joints between two model segments are folded into the pivot joint,
so the true centres are exact), virtual sensors are attached 3–7 cm off each bone with random
orientations, and the recording is corrupted by white noise, slow soft-tissue slip and dropped
samples.

Each segment's orientation is the global rotation of its most distal BVH node inside the
segment, and every joint is a fixed point of the rest pose in its parent segment's frame, so
the two sensors adjoining a joint agree on its position exactly (before noise). Sensors sit at
30–70 % along the bone, 3–7 cm off it in a random perpendicular direction, with a uniformly
random orientation.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from ..bvh import BvhMotion, forward_kinematics
from ..errors import InputError
from ..model import JOINT_SEGMENTS, JOINTS, LIMBS, REDUCED_SEGMENTS, SEGMENTS
from ..params import resolved_options
from ..recording import SensorRecording
from ..skeleton import estimate_chest, estimate_root

# Roles of BVH nodes in the rigid model.  Joints: node at the joint centre.  Segments: node
# whose global rotation is the segment orientation (the most distal node inside the segment,
# so that rotations of intermediate nodes are folded in).  Ends: node marking the far end of
# a segment without a distal joint (for sensor placement only).
_ROLES: Final = (
    "pelvis", "spine_top", "head_node",
    "waist", "neck", "head_end",
    "l_shoulder", "l_elbow", "l_wrist", "l_hand_end",
    "r_shoulder", "r_elbow", "r_wrist", "r_hand_end",
    "l_hip", "l_knee", "l_ankle", "l_toe",
    "r_hip", "r_knee", "r_ankle", "r_toe",
)

SKELETON_MAPS: Final[dict[str, dict[str, str]]] = {
    "cmu_bvh11": {
        "pelvis": "Hips", "spine_top": "Chest2", "head_node": "Head",
        "waist": "Chest", "neck": "Neck", "head_end": "Head_end",
        "l_shoulder": "LeftShoulder", "l_elbow": "LeftElbow", "l_wrist": "LeftWrist",
        "l_hand_end": "LFingers",
        "r_shoulder": "RightShoulder", "r_elbow": "RightElbow", "r_wrist": "RightWrist",
        "r_hand_end": "RFingers",
        "l_hip": "LeftHip", "l_knee": "LeftKnee", "l_ankle": "LeftAnkle", "l_toe": "LeftToe",
        "r_hip": "RightHip", "r_knee": "RightKnee", "r_ankle": "RightAnkle",
        "r_toe": "RightToe",
    },
    "cmu_fairmotion": {
        "pelvis": "Hips", "spine_top": "Spine1", "head_node": "Head",
        "waist": "Spine", "neck": "Neck1", "head_end": "Head_end",
        "l_shoulder": "LeftArm", "l_elbow": "LeftForeArm", "l_wrist": "LeftHand",
        "l_hand_end": "LFingers",
        "r_shoulder": "RightArm", "r_elbow": "RightForeArm", "r_wrist": "RightHand",
        "r_hand_end": "RFingers",
        "l_hip": "LeftUpLeg", "l_knee": "LeftLeg", "l_ankle": "LeftFoot",
        "l_toe": "LeftToeBase",
        "r_hip": "RightUpLeg", "r_knee": "RightLeg", "r_ankle": "RightFoot",
        "r_toe": "RightToeBase",
    },
    "cmu_acrnn": {
        "pelvis": "hip", "spine_top": "chest", "head_node": "head",
        "waist": "abdomen", "neck": "neck", "head_end": "leftEye",
        "l_shoulder": "lShldr", "l_elbow": "lForeArm", "l_wrist": "lHand",
        "l_hand_end": "lMid1",
        "r_shoulder": "rShldr", "r_elbow": "rForeArm", "r_wrist": "rHand",
        "r_hand_end": "rMid1",
        "l_hip": "lThigh", "l_knee": "lShin", "l_ankle": "lFoot", "l_toe": "lFoot_end",
        "r_hip": "rThigh", "r_knee": "rShin", "r_ankle": "rFoot", "r_toe": "rFoot_end",
    },
    "bandai_namco": {
        "pelvis": "Hips", "spine_top": "Chest", "head_node": "Head",
        "waist": "Spine", "neck": "Neck", "head_end": "Head_end",
        "l_shoulder": "UpperArm_L", "l_elbow": "LowerArm_L", "l_wrist": "Hand_L",
        "l_hand_end": "Hand_L_end",
        "r_shoulder": "UpperArm_R", "r_elbow": "LowerArm_R", "r_wrist": "Hand_R",
        "r_hand_end": "Hand_R_end",
        "l_hip": "UpperLeg_L", "l_knee": "LowerLeg_L", "l_ankle": "Foot_L", "l_toe": "Toes_L",
        "r_hip": "UpperLeg_R", "r_knee": "LowerLeg_R", "r_ankle": "Foot_R", "r_toe": "Toes_R",
    },
}
"""BVH node names of each model role, per data set of the accuracy benchmarks (CMU, Bandai
Namco). ``example_motion`` uses the ``cmu_bvh11`` names."""

# segment -> (orientation role, origin joint role, bone start role, bone end role)
_SEGMENT_DEF: Final[dict[str, tuple[str, str, str, str]]] = {
    "pelvis": ("pelvis", "pelvis", "hips_mid", "waist"),
    "chest": ("spine_top", "waist", "waist", "neck"),
    "head": ("head_node", "neck", "neck", "head_end"),
    "l_upperarm": ("l_shoulder", "l_shoulder", "l_shoulder", "l_elbow"),
    "l_forearm": ("l_elbow", "l_elbow", "l_elbow", "l_wrist"),
    "l_hand": ("l_wrist", "l_wrist", "l_wrist", "l_hand_end"),
    "r_upperarm": ("r_shoulder", "r_shoulder", "r_shoulder", "r_elbow"),
    "r_forearm": ("r_elbow", "r_elbow", "r_elbow", "r_wrist"),
    "r_hand": ("r_wrist", "r_wrist", "r_wrist", "r_hand_end"),
    "l_thigh": ("l_hip", "l_hip", "l_hip", "l_knee"),
    "l_shank": ("l_knee", "l_knee", "l_knee", "l_ankle"),
    "l_foot": ("l_ankle", "l_ankle", "l_ankle", "l_toe"),
    "r_thigh": ("r_hip", "r_hip", "r_hip", "r_knee"),
    "r_shank": ("r_knee", "r_knee", "r_knee", "r_ankle"),
    "r_foot": ("r_ankle", "r_ankle", "r_ankle", "r_toe"),
}

# joint role -> segment carrying it (rigid model topology, parents before children)
# the segment whose frame carries each two-segment joint: its proximal one
_JOINT_CARRIER: Final[dict[str, str]] = {j: segs[0] for j, segs in JOINT_SEGMENTS.items()}


@dataclass(frozen=True, eq=False)
class SimulationTruth:
    """Exact ground truth of a simulated recording.

    Attributes
    ----------
    joints : dict of str to ndarray, shape (F, 3)
        Every joint of ``bonefit.estimation.model.JOINTS`` in the world frame, metres. ``root`` and
        ``chest`` are derived from the true centres as in Miura et al. (2015), eq. 1.
    segment_rotations : dict of str to Rotation
        Segment frame → world rotation of each of the 15 segments, length F.
    sensor_local : dict of str to ndarray, shape (3,)
        Mean sensor origin in its segment frame (before slip), metres.
    bone_lengths : dict of str to float
        Distance between the two joints of each limb segment, metres.
    dataset : str
        Key of ``SKELETON_MAPS`` used to read the BVH names.
    """

    joints: dict[str, NDArray[np.float64]]
    segment_rotations: dict[str, Rotation]
    sensor_local: dict[str, NDArray[np.float64]]
    bone_lengths: dict[str, float]
    dataset: str


def detect_skeleton(motion: BvhMotion) -> str:
    """Key of ``SKELETON_MAPS`` whose node names all occur in ``motion``.

    Raises
    ------
    InputError
        If no known naming scheme matches.
    """
    names = set(motion.names)
    for key, mapping in SKELETON_MAPS.items():
        if set(mapping.values()) <= names:
            return key
    raise InputError("unknown BVH skeleton; pass mapping= with the node of each role "
                     f"({', '.join(_ROLES)})", field="mapping")


def rigid_body_model(
    motion: BvhMotion, *, units_m: float, mapping: Mapping[str, str] | None = None,
    rig: HingeRig | None = None,
) -> tuple[dict[str, NDArray[np.float64]], dict[str, Rotation],
           dict[str, NDArray[np.float64]], dict[str, tuple[NDArray[np.float64],
                                                            NDArray[np.float64]]]]:
    """The rigid 15-segment body driven by a BVH clip.

    Parameters
    ----------
    motion : BvhMotion
    units_m : float
        Metres per BVH unit.
    mapping : mapping of role to node name, optional
        Defaults to the entry of ``SKELETON_MAPS`` detected from the node names.
    rig : HingeRig, optional
        Knees and elbows off their neighbours' line with an axial rotation coupled to
        flexion; by default the BVH's own (near-ideal) hinges.

    Returns
    -------
    origins : dict segment -> (F, 3)
        World position of each segment's origin (its proximal joint; the BVH root for the
        pelvis), metres.
    rotations : dict segment -> Rotation
        Segment → world rotation, length F (global rotation of the segment's most distal node).
    joints : dict joint -> (F, 3)
        The 14 two-segment joints, metres, exact for the rigid model.
    bones : dict segment -> ((3,), (3,))
        Start and end of each segment's bone in the segment frame, metres.
    """
    roles = dict(mapping) if mapping is not None else SKELETON_MAPS[detect_skeleton(motion)]
    idx = {role: motion.index(roles[role]) for role in _ROLES}
    positions, global_rots = forward_kinematics(motion)
    positions = positions * units_m
    node = {role: positions[:, i] for role, i in idx.items()}
    node["hips_mid"] = 0.5 * (node["l_hip"] + node["r_hip"])
    rotations = {seg: global_rots[idx[d[0]]] for seg, d in _SEGMENT_DEF.items()}

    def local(seg: str, role: str) -> NDArray[np.float64]:
        # the rigid body closest to the clip: mean position of the node in the segment frame
        # (this folds the rotations of nodes inside the segment at their mean)
        rel = node[role] - node[_SEGMENT_DEF[seg][1]]
        return np.asarray(rotations[seg].inv().apply(rel).mean(axis=0))

    carried = {joint: local(seg, joint) for joint, seg in _JOINT_CARRIER.items()}
    bones = {seg: (local(seg, d[2]), local(seg, d[3])) for seg, d in _SEGMENT_DEF.items()}
    if rig is not None:
        _realistic_hinges(rig, rotations, carried, bones)
    origins: dict[str, NDArray[np.float64]] = {"pelvis": node["pelvis"]}
    joints: dict[str, NDArray[np.float64]] = {}
    # segments in topological order: each origin is a joint carried by an earlier segment
    for seg in SEGMENTS:
        if seg != "pelvis":
            origins[seg] = joints[_SEGMENT_DEF[seg][1]]
        for joint, carrier in _JOINT_CARRIER.items():
            if carrier == seg:
                joints[joint] = origins[seg] + rotations[seg].apply(carried[joint])
    return origins, rotations, joints, bones


@dataclass(frozen=True)
class HingeRig:
    """Knees and elbows as they are (issue 20 §3), for ``simulate_sensors(rig=...)``.

    BVH skeletons put the knee and the elbow on the straight line of their neighbours to
    about a millimetre, and make them pure hinges. Real knees sit up to about 15 mm off the
    hip–ankle line and rotate a few degrees about the shank as they flex (the screw-home
    motion; the forearm likewise). With a ``HingeRig`` each knee and elbow is moved
    ``offset_range_m`` off the line in a random direction across the proximal bone (the
    distal joint stays where it was at the clip's mean pose), and the shank (forearm)
    turns about its own long axis by ``c · (θ − median θ)``, ``θ`` the flexion angle, ``c``
    of random sign and magnitude in ``coupling_range`` (radians per radian: 0.05 is 4.5°
    over 90° of flexion).

    Attributes
    ----------
    offset_range_m : (float, float)
        Range of the middle joint's distance off its neighbours' line, metres.
    coupling_range : (float, float)
        Range of the axial rotation per flexion, radians per radian.
    seed : int or None
        Seed of the rig's own draws (independent of the sensors', so the sensor placement,
        noise and slip of a seed are the same with and without the rig).
    """

    offset_range_m: tuple[float, float] = (0.005, 0.015)
    coupling_range: tuple[float, float] = (0.03, 0.10)
    seed: int | None = 0


def _realistic_hinges(rig: HingeRig, rotations: dict[str, Rotation],
                      carried: dict[str, NDArray[np.float64]],
                      bones: dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]]
                      ) -> None:
    """Move each limb's middle joint off its neighbours' line and couple an axial rotation
    of the middle segment to flexion (``HingeRig``), in place."""
    rng = np.random.default_rng(rig.seed)
    for limb in LIMBS.values():
        upper, middle, _ = limb.segments
        _, mid, dist = limb.joints
        knee = carried[mid]  # in the upper segment's frame, from the proximal joint
        along = knee / max(float(np.linalg.norm(knee)), 1e-12)
        d = rng.normal(size=3)
        d -= d.dot(along) * along
        d *= rng.uniform(*rig.offset_range_m) / max(float(np.linalg.norm(d)), 1e-12)
        # the distal joint stays put at the mean pose: -d in the middle segment's frame
        mean_rel = (rotations[upper].inv() * rotations[middle]).mean()
        shin = carried[dist] - mean_rel.inv().apply(d)
        carried[mid] = knee + d
        carried[dist] = shin
        bones[upper] = (bones[upper][0], bones[upper][1] + d)
        bones[middle] = (bones[middle][0], shin)
        shin_dir = shin / max(float(np.linalg.norm(shin)), 1e-12)
        cos = np.einsum("ti,ti->t", rotations[upper].apply(along),
                        rotations[middle].apply(shin_dir))
        flexion = np.arccos(np.clip(cos, -1.0, 1.0))
        coupling = rng.choice((-1.0, 1.0)) * rng.uniform(*rig.coupling_range)
        twist = coupling * (flexion - np.median(flexion))
        rotations[middle] = rotations[middle] * Rotation.from_rotvec(
            twist[:, None] * shin_dir[None, :])


def derived_joints(joints: Mapping[str, NDArray[np.float64]]) -> dict[str, NDArray[np.float64]]:
    """``root`` and ``chest`` from the other joint centres (Miura et al. 2015, §2.1, eq. 1).

    Parameters
    ----------
    joints : mapping with ``waist, neck, l_hip, r_hip, l_shoulder, r_shoulder`` (F, 3)

    Returns
    -------
    dict with ``root`` (centroid of W, LH, RH) and ``chest`` (see
    ``bonefit.estimation.skeleton.estimate_chest``).
    """
    return {
        "root": estimate_root(joints["waist"], joints["l_hip"], joints["r_hip"]),
        "chest": estimate_chest(joints["waist"], joints["neck"], joints["l_shoulder"],
                                joints["r_shoulder"]),
    }


def _smooth_slip(rng: np.random.Generator, time: NDArray[np.float64], amplitude: float,
                 n: int) -> NDArray[np.float64]:
    """(F, n, 3) smooth displacements: sums of slow sinusoids (0.05–0.5 Hz), RMS norm =
    ``amplitude``."""
    if amplitude <= 0:
        return np.zeros((time.size, n, 3))
    freqs = rng.uniform(0.05, 0.5, size=(4, n, 3))
    phases = rng.uniform(0, 2 * np.pi, size=(4, n, 3))
    amps = rng.normal(size=(4, n, 3))
    out = np.sum(amps * np.sin(2 * np.pi * freqs * time[:, None, None, None] + phases), axis=1)
    rms = np.sqrt(np.mean(np.sum(out**2, axis=-1), axis=0))
    return np.asarray(out / np.where(rms > 0, rms, 1.0)[None, :, None] * amplitude)


def _drop_mask(rng: np.random.Generator, n_frames: int, n: int,
               fraction: float) -> NDArray[np.bool_]:
    """(F, n) mask of dropped samples: short bursts of 1–5 frames, ``fraction`` in total."""
    mask = np.zeros((n_frames, n), dtype=bool)
    if fraction <= 0 or n_frames < 3:
        return mask
    n_gaps = max(1, round(fraction * n_frames / 3.0))
    for s in range(n):
        starts = rng.integers(1, n_frames - 1, size=n_gaps)
        lengths = rng.integers(1, 6, size=n_gaps)
        for start, length in zip(starts, lengths, strict=True):
            mask[start:min(start + length, n_frames - 1), s] = True
    return mask


@dataclass(frozen=True)
class SensorSimulation:
    """How :func:`simulate_sensors` builds the body, places the sensors and makes them err
    (its keywords of the same names).

    Attributes
    ----------
    position_noise_m : float
        Standard deviation of white position noise per axis, metres.
    orientation_noise_deg : float
        Standard deviation of white orientation noise per rotation-vector axis, degrees.
    slip_m : float
        RMS magnitude of the slow (0.05–0.5 Hz) soft-tissue displacement of each sensor along
        its segment, metres.
    drop_fraction : float
        Fraction of samples per sensor set to NaN, in bursts of 1–5 frames.
    offset_range_m : (float, float)
        Range of the sensor distance from the bone, metres.
    mapping : mapping of role to BVH node name, optional
        For skeletons not in ``SKELETON_MAPS``.
    rig : HingeRig, optional
        Realistic knees and elbows (off their neighbours' line, axial rotation coupled to
        flexion); by default the BVH's near-ideal hinges.

    Examples
    --------
    >>> SensorSimulation(slip_m=0.0, drop_fraction=0.0).position_noise_m
    0.002
    """

    position_noise_m: float = 0.002
    orientation_noise_deg: float = 0.5
    slip_m: float = 0.005
    drop_fraction: float = 0.01
    offset_range_m: tuple[float, float] = (0.03, 0.07)
    mapping: Mapping[str, str] | None = None
    rig: HingeRig | None = None


def simulate_sensors(
    motion: BvhMotion,
    *,
    units_m: float,
    n_sensors: int = 15,
    segments: Sequence[str] | None = None,
    seed: int | None = 0,
    fps: float | None = None,
    options: SensorSimulation | None = None,
    **settings: Any,
) -> tuple[SensorRecording, SimulationTruth]:
    """Virtual 6-DOF sensors on a rigid body driven by a BVH clip, with exact truth.

    Parameters
    ----------
    motion : BvhMotion
        A clip whose node names match one of ``SKELETON_MAPS`` (or pass ``mapping``).
    units_m : float
        Metres per BVH unit (CMU: 0.05644; cm: 0.01).
    n_sensors : {15, 11}
        Full suit or the reduced suit without forearm and shank sensors.
    segments : sequence of str, optional
        Explicit sensor set; overrides ``n_sensors``.
    seed : int or None
        Seed of the random generator (sensor placement, noise, slip, drops).
    fps : float, optional
        Frame rate overriding the BVH header (some clips declare a wrong one).
    options : SensorSimulation, optional
        Body, placement and errors as one object; default: from ``settings``.
    **settings
        Instead of ``options``, its fields (``position_noise_m``, ``orientation_noise_deg``,
        ``slip_m``, ``drop_fraction``, ``offset_range_m``, ``mapping``, ``rig``).

    Returns
    -------
    recording : SensorRecording
    truth : SimulationTruth

    Raises
    ------
    InputError
        An unknown setting (``field`` names it), both ``options`` and settings, unknown
        segments or sensor count.

    Notes
    -----
    The body and the sensors' placement are described in the module docstring.
    """
    opt = resolved_options("simulate_sensors", {"simulate_sensors": SensorSimulation}, options,
                           settings)
    segments = _sensor_segments(n_sensors, segments)
    rng = np.random.default_rng(seed)
    origins, rotations, joints, bones = rigid_body_model(motion, units_m=units_m,
                                                         mapping=opt.mapping, rig=opt.rig)
    rate = float(fps) if fps is not None else motion.fps
    n_frames = motion.n_frames
    time = np.arange(n_frames) / rate
    local, offsets_rot = _place_sensors(bones, rng, opt.offset_range_m)
    slip = _smooth_slip(rng, time, opt.slip_m, len(segments))
    dropped = _drop_mask(rng, n_frames, len(segments), opt.drop_fraction)
    positions, quats = _sensor_poses(segments, (origins, rotations), (local, offsets_rot),
                                     slip, rng=rng,
                                     orientation_noise_deg=opt.orientation_noise_deg)
    if opt.position_noise_m > 0:
        positions += rng.normal(scale=opt.position_noise_m, size=positions.shape)
    positions[dropped] = np.nan
    quats[dropped] = np.nan
    recording = SensorRecording(segments, positions, quats, rate, time)
    truth = _truth(joints, rotations, local, bones,
                   dataset=detect_skeleton(motion) if opt.mapping is None else "custom")
    return recording, truth


def _truth(joints: Mapping[str, NDArray[np.float64]], rotations: dict[str, Rotation],
           local: dict[str, NDArray[np.float64]],
           bones: Mapping[str, tuple[NDArray[np.float64], NDArray[np.float64]]], *,
           dataset: str) -> SimulationTruth:
    """The exact joints (with the derived ones), rotations, sensor offsets and bone lengths."""
    all_joints = dict(joints)
    all_joints.update(derived_joints(joints))
    return SimulationTruth(
        joints={j: all_joints[j] for j in JOINTS}, segment_rotations=rotations,
        sensor_local=local,
        bone_lengths={seg: float(np.linalg.norm(bones[seg][1] - bones[seg][0]))
                      for seg in _TRUE_BONES},
        dataset=dataset)


_TRUE_BONES: Final = ("l_upperarm", "l_forearm", "r_upperarm", "r_forearm",
                      "l_thigh", "l_shank", "r_thigh", "r_shank")
"""Segments whose length ``SimulationTruth.bone_lengths`` gives."""


def _sensor_poses(segments: Sequence[str],
                  body: tuple[Mapping[str, NDArray[np.float64]], Mapping[str, Rotation]],
                  placement: tuple[Mapping[str, NDArray[np.float64]], Mapping[str, Rotation]],
                  slip: NDArray[np.float64], *, rng: np.random.Generator,
                  orientation_noise_deg: float
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Positions (F, S, 3, metres) and scalar-first quaternions (F, S, 4) of the sensors on
    ``segments``: the segments' ``body`` pose (origins, rotations) carrying each sensor's
    ``placement`` (local origin, mounting rotation) displaced by ``slip`` (F, S, 3), with
    white orientation noise (degrees per rotation-vector axis)."""
    origins, rotations = body
    local, offsets_rot = placement
    n_frames = slip.shape[0]
    positions = np.empty((n_frames, len(segments), 3))
    quats = np.empty((n_frames, len(segments), 4))
    for k, seg in enumerate(segments):
        rot = rotations[seg]
        positions[:, k] = origins[seg] + rot.apply(local[seg] + slip[:, k])
        sensor_rot = rot * offsets_rot[seg]
        if orientation_noise_deg > 0:
            noise = Rotation.from_rotvec(
                rng.normal(scale=np.deg2rad(orientation_noise_deg), size=(n_frames, 3)))
            sensor_rot = sensor_rot * noise
        quats[:, k] = sensor_rot.as_quat(scalar_first=True)
    return positions, quats


def _sensor_segments(n_sensors: int, segments: Sequence[str] | None) -> tuple[str, ...]:
    """The segments carrying a sensor: ``segments``, else the 15- or 11-sensor suit."""
    if segments is None:
        if n_sensors == 15:
            segments = SEGMENTS
        elif n_sensors == 11:
            segments = REDUCED_SEGMENTS
        else:
            raise InputError(f"n_sensors must be 15 or 11, got {n_sensors}", field="n_sensors")
    segments = tuple(segments)
    unknown = [s for s in segments if s not in SEGMENTS]
    if unknown:
        raise InputError(f"unknown segment(s) {', '.join(unknown)}", field="segments")
    return segments


def _place_sensors(bones: Mapping[str, tuple[NDArray[np.float64], NDArray[np.float64]]],
                   rng: np.random.Generator, offset_range_m: tuple[float, float]
                   ) -> tuple[dict[str, NDArray[np.float64]], dict[str, Rotation]]:
    """Each segment's sensor origin in the segment frame (30–70 % along the bone, offset in
    a random perpendicular direction) and its random mounting rotation.

    Drawn for all 15 segments, so the 11-sensor suit shares the 15's sensors."""
    local: dict[str, NDArray[np.float64]] = {}
    offsets_rot: dict[str, Rotation] = {}
    for seg in SEGMENTS:
        start, end = bones[seg]
        axis = end - start
        length = float(np.linalg.norm(axis))
        axis = axis / length if length > 0 else np.array([0.0, 1.0, 0.0])
        perp = rng.normal(size=3)
        perp -= perp.dot(axis) * axis
        perp /= np.linalg.norm(perp)
        u = rng.uniform(0.3, 0.7)
        local[seg] = start + u * (end - start) + rng.uniform(*offset_range_m) * perp
        offsets_rot[seg] = Rotation.random(rng=rng)
    return local, offsets_rot


_EXAMPLE_HIERARCHY: Final = (
    # name, parent, offset (cm), rotating
    ("Hips", "", (0.0, 0.0, 0.0)),
    ("Chest", "Hips", (0.0, 10.0, 0.0)),
    ("Chest2", "Chest", (0.0, 20.0, 0.0)),
    ("Neck", "Chest2", (0.0, 20.0, 0.0)),
    ("Head", "Neck", (0.0, 8.0, 0.0)),
    ("Head_end", "Head", (0.0, 15.0, 0.0)),
    ("LeftShoulder", "Chest2", (18.0, 15.0, 0.0)),
    ("LeftElbow", "LeftShoulder", (0.0, -29.0, 0.0)),
    ("LeftWrist", "LeftElbow", (0.0, -26.0, 0.0)),
    ("LFingers", "LeftWrist", (0.0, -9.0, 0.0)),
    ("RightShoulder", "Chest2", (-18.0, 15.0, 0.0)),
    ("RightElbow", "RightShoulder", (0.0, -29.0, 0.0)),
    ("RightWrist", "RightElbow", (0.0, -26.0, 0.0)),
    ("RFingers", "RightWrist", (0.0, -9.0, 0.0)),
    ("LeftHip", "Hips", (9.0, -6.0, 0.0)),
    ("LeftKnee", "LeftHip", (0.0, -42.0, 0.0)),
    ("LeftAnkle", "LeftKnee", (0.0, -41.0, 0.0)),
    ("LeftToe", "LeftAnkle", (0.0, -6.0, 14.0)),
    ("RightHip", "Hips", (-9.0, -6.0, 0.0)),
    ("RightKnee", "RightHip", (0.0, -42.0, 0.0)),
    ("RightAnkle", "RightKnee", (0.0, -41.0, 0.0)),
    ("RightToe", "RightAnkle", (0.0, -6.0, 14.0)),
)

# (amplitude deg about x, y, z; hinge joints move about x only)
_EXAMPLE_RANGES: Final[dict[str, tuple[float, float, float]]] = {
    "Hips": (15.0, 60.0, 10.0), "Chest": (15.0, 15.0, 10.0), "Chest2": (10.0, 10.0, 5.0),
    "Neck": (25.0, 40.0, 15.0), "Head": (0.0, 0.0, 0.0),
    "LeftShoulder": (60.0, 35.0, 45.0), "RightShoulder": (60.0, 35.0, 45.0),
    "LeftElbow": (55.0, 0.0, 0.0), "RightElbow": (55.0, 0.0, 0.0),
    "LeftWrist": (35.0, 20.0, 25.0), "RightWrist": (35.0, 20.0, 25.0),
    "LeftHip": (45.0, 25.0, 20.0), "RightHip": (45.0, 25.0, 20.0),
    "LeftKnee": (45.0, 0.0, 0.0), "RightKnee": (45.0, 0.0, 0.0),
    "LeftAnkle": (25.0, 15.0, 15.0), "RightAnkle": (25.0, 15.0, 15.0),
}
# hinge offsets so knees/elbows flex one way (degrees about x at mid-range)
_EXAMPLE_BIAS: Final[dict[str, float]] = {
    "LeftElbow": -60.0, "RightElbow": -60.0, "LeftKnee": 50.0, "RightKnee": 50.0,
}


def example_motion(n_frames: int = 240, *, fps: float = 60.0, seed: int = 0,
                   scale: float = 1.0) -> BvhMotion:
    """A small synthetic whole-body BVH clip (cm, ``cmu_bvh11`` node names).

    Every joint swings with a sum of two random sinusoids (0.2–1.2 Hz); knees and elbows
    are pure hinges about their local x axis, the other joints move about all three axes.
    Useful for tests and examples: ``simulate_sensors(example_motion(), units_m=0.01)``.

    Parameters
    ----------
    n_frames : int
    fps : float
    seed : int
    scale : float
        Multiplies every amplitude (0 gives a motionless clip).
    """
    rng = np.random.default_rng(seed)
    names = tuple(n for n, _, _ in _EXAMPLE_HIERARCHY)
    parents = tuple(names.index(p) if p else -1 for _, p, _ in _EXAMPLE_HIERARCHY)
    offsets = np.array([o for _, _, o in _EXAMPLE_HIERARCHY], dtype=float)
    t = np.arange(n_frames) / fps
    channels: list[tuple[str, ...]] = []
    columns: list[NDArray[np.float64]] = []
    for name in names:
        if name == "Hips":
            channels.append(("Xposition", "Yposition", "Zposition",
                             "Zrotation", "Xrotation", "Yrotation"))
            columns += [20.0 * scale * np.sin(2 * np.pi * 0.2 * t),
                        95.0 + 3.0 * scale * np.sin(2 * np.pi * 0.9 * t),
                        15.0 * scale * np.sin(2 * np.pi * 0.13 * t)]
        elif name in _EXAMPLE_RANGES:
            channels.append(("Zrotation", "Xrotation", "Yrotation"))
        else:
            channels.append(())
            continue
        amp = _EXAMPLE_RANGES[name]
        angles = {}
        for axis, a in zip("xyz", amp, strict=True):
            f = rng.uniform(0.2, 1.2, size=2)
            ph = rng.uniform(0, 2 * np.pi, size=2)
            wave = np.sin(2 * np.pi * f[0] * t + ph[0]) + 0.5 * np.sin(2 * np.pi * f[1] * t + ph[1])
            angles[axis] = scale * a * wave / 1.5
        angles["x"] = angles["x"] + scale * _EXAMPLE_BIAS.get(name, 0.0)
        columns += [angles["z"], angles["x"], angles["y"]]
    values = np.column_stack(columns)
    return BvhMotion(names, parents, offsets, tuple(channels), 1.0 / fps, values)
