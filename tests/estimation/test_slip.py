"""Soft-tissue slip of every sensor from all joint equations at once (estimation.slip)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from estimation.joints import estimate_joint
from estimation.simulate.sensors import example_motion, simulate_sensors
from estimation.skeleton import estimate_skeleton
from estimation.slip import estimate_slip

FPS = 60.0
N = 600  # 10 s


def smooth_signal(rng: np.random.Generator, n: int, band_hz: tuple[float, float],
                  rms: float) -> NDArray[np.float64]:
    """(n, 3) sum of four sinusoids per axis in ``band_hz``, scaled to ``rms`` (norm)."""
    t = np.arange(n) / FPS
    out = np.zeros((n, 3))
    for axis in range(3):
        for _ in range(4):
            f = rng.uniform(*band_hz)
            out[:, axis] += np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi))
    return np.asarray(out * rms / np.sqrt(np.mean(np.sum(out**2, axis=1))))


class Rig(NamedTuple):
    positions: dict[str, NDArray[np.float64]]  # measured
    quaternions: dict[str, NDArray[np.float64]]
    slip: dict[str, NDArray[np.float64]]  # true, in each sensor's frame
    valid: dict[str, NDArray[np.bool_]]
    pairs: list[tuple[str, str]]
    paths: dict[tuple[str, str], NDArray[np.float64]]  # true joint paths


def star_rig(seed: int) -> Rig:
    """A hub sensor with three limbs, each joined to it by a ball joint that moves ±12°;
    every sensor slips 5 mm (0.05–0.4 Hz) in its own frame, 1 mm white position noise."""
    rng = np.random.default_rng(seed)
    hub_rot = Rotation.from_rotvec(smooth_signal(rng, N, (0.2, 0.8), 0.3))
    hub_pos = smooth_signal(rng, N, (0.1, 0.5), 0.3) + np.array([0.0, 1.0, 0.0])
    positions = {"hub": hub_pos}
    rotations = {"hub": hub_rot}
    paths: dict[tuple[str, str], NDArray[np.float64]] = {}
    pairs: list[tuple[str, str]] = []
    for k, name in enumerate(("left", "right", "top")):
        in_hub = rng.normal(scale=0.1, size=3)  # joint in the hub's frame
        in_limb = rng.normal(scale=0.1, size=3)  # joint in the limb sensor's frame
        rel = Rotation.from_rotvec(smooth_signal(rng, N, (0.5, 1.5), np.radians(12.0))
                                   + 0.2 * k)
        limb_rot = hub_rot * rel
        centre = hub_pos + hub_rot.apply(in_hub)
        positions[name] = centre - limb_rot.apply(in_limb)
        rotations[name] = limb_rot
        paths[("hub", name)] = centre
        pairs.append(("hub", name))
    slip = {s: smooth_signal(rng, N, (0.05, 0.4), 0.005) for s in positions}
    measured = {s: positions[s] + rotations[s].apply(slip[s])
                + rng.normal(scale=0.001, size=(N, 3)) for s in positions}
    quats = {s: rotations[s].as_quat(scalar_first=True) for s in positions}
    valid = {s: np.ones(N, dtype=np.bool_) for s in positions}
    return Rig(measured, quats, slip, valid, pairs, paths)


def test_recovers_each_sensors_slip_and_the_joint_paths() -> None:
    # measured on these rigs: slip to 1.1–1.9 mm of its 5 mm; joint paths 1.6–2.3 mm, against
    # 3.5–4.4 mm for plain LLSF and 2.3–3.2 mm for each joint's own slip model
    shared_mm, single_mm = [], []
    for seed in range(3):
        pos, quat, slip, valid, pairs, paths = star_rig(seed)
        fit = estimate_slip(pos, quat, valid, pairs, fps=FPS)
        assert set(fit.slip) == set(pos)
        for s, true in slip.items():
            # a constant slip is part of the centre: compare the varying part
            varying = true - true.mean(axis=0)
            err = np.sqrt(np.mean(np.sum((fit.slip[s] - varying) ** 2, axis=1)))
            rms = np.sqrt(np.mean(np.sum(varying**2, axis=1)))
            assert err < 0.45 * rms, (seed, s, err, rms)
        assert fit.centres.shape == (3, 2, 3)
        assert fit.covariances.shape == (3, 6, 6)
        for j, (a, b) in enumerate(pairs):
            cov = fit.covariances[j]
            assert np.allclose(cov, cov.T, atol=1e-12 * np.abs(cov).max())
            assert np.linalg.eigvalsh(cov).min() > 0.0
            ra = Rotation.from_quat(quat[a], scalar_first=True)
            rb = Rotation.from_quat(quat[b], scalar_first=True)
            # the joint with each sensor's estimated slip removed, against plain LLSF and
            # against the joint's own slip model (its two sensors' slips free)
            shared = 0.5 * (ra.apply(fit.centres[j, 0] - fit.slip[a]) + pos[a]
                            + rb.apply(fit.centres[j, 1] - fit.slip[b]) + pos[b])
            plain = estimate_joint(pos[a], ra, pos[b], rb, loss="linear").positions
            single = estimate_joint(pos[a], ra, pos[b], rb, loss="linear",
                                    slip_period=FPS / 0.5).positions
            e_shared, e_plain, e_single = (
                float(np.linalg.norm(p - paths[(a, b)], axis=1).mean())
                for p in (shared, plain, single))
            assert e_shared < 0.003, (seed, b, e_shared)
            assert e_shared < 0.7 * e_plain, (seed, b, e_shared, e_plain)
            shared_mm.append(e_shared)
            single_mm.append(e_single)
    assert np.mean(shared_mm) < 0.8 * np.mean(single_mm), (shared_mm, single_mm)


def test_without_slip_model_nothing_is_removed() -> None:
    pos, quat, _, valid, pairs, _ = star_rig(0)
    fit = estimate_slip(pos, quat, valid, pairs, fps=FPS, slip_hz=0.0)
    assert all(np.all(s == 0.0) for s in fit.slip.values())
    assert fit.centres.shape == (3, 2, 3)


def test_skeleton_uses_it_for_torso_joints_and_wrists() -> None:
    rec, truth = simulate_sensors(example_motion(240, fps=60.0, seed=3), units_m=0.01, seed=4)
    result = estimate_skeleton(rec)
    for name in ("waist", "neck", "l_shoulder", "r_shoulder", "l_hip", "r_hip"):
        assert result.quality[name]["estimator"] == "llsf-shared-slip"
    assert result.quality["l_knee"]["estimator"] == "llsf"
    off = estimate_skeleton(rec, slip_hz=0.0)
    assert off.quality["waist"]["estimator"] == "llsf"
    for name in ("waist", "l_shoulder", "l_wrist"):
        err = np.linalg.norm(result.joints[name] - truth.joints[name], axis=1).mean()
        assert err < 0.02, (name, err)
