"""Soft-tissue slip of every sensor from all joint equations at once (bonefit.estimation.slip)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from bonefit.estimation.joints import estimate_joint, slip_basis
from bonefit.estimation.simulate.sensors import example_motion, simulate_sensors
from bonefit.estimation.skeleton import estimate_skeleton
from bonefit.estimation.slip import (
    EIV_SIGNAL_SHARE,
    SlipLayout,
    estimate_slip,
    joint_block,
    rotation_noise_variance,
)

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
        assert isinstance(result.quality[name]["rotation_noise_corrected"], bool)
    assert result.quality["l_knee"]["estimator"] == "llsf"
    off = estimate_skeleton(rec, slip_hz=0.0)
    assert off.quality["waist"]["estimator"] == "llsf"
    for name in ("waist", "l_shoulder", "l_wrist"):
        err = np.linalg.norm(result.joints[name] - truth.joints[name], axis=1).mean()
        assert err < 0.02, (name, err)


def noisy_star(seed: int, motion_deg: float, noise_deg: float, n: int = 1800
               ) -> tuple[dict[str, NDArray[np.float64]], dict[str, NDArray[np.float64]],
                          dict[str, NDArray[np.bool_]], list[tuple[str, str]],
                          list[NDArray[np.float64]]]:
    """A hub and three limbs whose ball joints move ``motion_deg`` (RMS of the rotation
    vector's norm), 30 s at 60 fps, white orientation noise of ``noise_deg`` per axis on
    every sensor, 1 mm position noise, no slip. Returns positions, quaternions, valid masks,
    pairs and the true centres (6,) in the two frames."""
    rng = np.random.default_rng(seed)
    hub_rot = Rotation.from_rotvec(smooth_signal(rng, n, (0.2, 0.8), 0.3))
    hub_pos = smooth_signal(rng, n, (0.1, 0.5), 0.3) + np.array([0.0, 1.0, 0.0])
    pos, rot = {"hub": hub_pos}, {"hub": hub_rot}
    truth, pairs = [], []
    for k, name in enumerate(("left", "right", "top")):
        in_hub, in_limb = rng.normal(scale=0.1, size=3), rng.normal(scale=0.1, size=3)
        rel = Rotation.from_rotvec(smooth_signal(rng, n, (0.5, 1.5), np.radians(motion_deg))
                                   + 0.2 * k)
        limb = hub_rot * rel
        pos[name] = hub_pos + hub_rot.apply(in_hub) - limb.apply(in_limb)
        rot[name] = limb
        truth.append(np.concatenate([in_hub, in_limb]))
        pairs.append(("hub", name))
    measured = {s: pos[s] + rng.normal(scale=0.001, size=(n, 3)) for s in pos}
    quats = {s: (rot[s] * Rotation.from_rotvec(rng.normal(scale=np.radians(noise_deg),
                                                           size=(n, 3)))
                 ).as_quat(scalar_first=True) for s in rot}
    valid = {s: np.ones(n, dtype=np.bool_) for s in pos}
    return measured, quats, valid, pairs, truth


def test_rotation_noise_variance_recovers_the_noise_level() -> None:
    # measured: 0.977–0.990° for 1°
    for seed in range(3):
        _, quats, valid, _, _ = noisy_star(seed, 4.0, 1.0)
        v = rotation_noise_variance(quats, valid)
        assert abs(np.degrees(np.sqrt(v)) - 1.0) < 0.05, (seed, v)
    assert rotation_noise_variance({"a": np.tile([1.0, 0, 0, 0], (5, 1))},
                                   {"a": np.ones(5, dtype=np.bool_)}) == 0.0


def test_errors_in_variables_correction_removes_the_attenuation_bias() -> None:
    # joints moving 4° under 1° of orientation noise: the plain centres are pulled toward the
    # sensors (measured 7.5–17.4 mm off), the corrected ones are not (2.6–4.2 mm)
    for seed in range(3):
        pos, quats, valid, pairs, truth = noisy_star(seed, 4.0, 1.0)
        plain = estimate_slip(pos, quats, valid, pairs, fps=FPS)
        fit = estimate_slip(pos, quats, valid, pairs, fps=FPS,
                            rotation_noise=rotation_noise_variance(quats, valid))
        assert plain.corrected == (False,) * 3
        assert fit.corrected == (True,) * 3
        for j in range(3):
            e_plain = np.linalg.norm(plain.centres[j].reshape(6) - truth[j])
            e_fit = np.linalg.norm(fit.centres[j].reshape(6) - truth[j])
            assert e_fit < 0.006, (seed, j, e_fit)
            assert e_fit < 0.6 * e_plain, (seed, j, e_fit, e_plain)
            assert np.linalg.eigvalsh(fit.covariances[j]).min() > 0.0
        # the slips are those of the uncorrected system
        assert all(np.array_equal(fit.slip[s], plain.slip[s]) for s in plain.slip)


def test_no_correction_where_the_noise_rivals_the_motion() -> None:
    # 3° of motion under 1.5° of noise: the correction would remove more than a fifth of the
    # weakest eigenvalue, so the centres stay the uncorrected ones
    pos, quats, valid, pairs, _ = noisy_star(0, 3.0, 1.5)
    plain = estimate_slip(pos, quats, valid, pairs, fps=FPS)
    fit = estimate_slip(pos, quats, valid, pairs, fps=FPS,
                        rotation_noise=rotation_noise_variance(quats, valid))
    assert fit.corrected == (False,) * 3
    assert np.array_equal(fit.centres, plain.centres)


def test_signal_share_tells_motion_from_orientation_noise() -> None:
    # the share of each joint's weakest eigenvalue that is motion: near 1 for 4° under
    # 0.25° of noise, below EIV_SIGNAL_SHARE for 3° under 1.5°; 1 without a noise level
    for motion_deg, noise_deg, high in ((4.0, 0.25, True), (3.0, 1.5, False)):
        pos, quats, valid, pairs, _ = noisy_star(0, motion_deg, noise_deg)
        fit = estimate_slip(pos, quats, valid, pairs, fps=FPS,
                            rotation_noise=rotation_noise_variance(quats, valid))
        assert len(fit.signal_share) == len(pairs)
        for share in fit.signal_share:
            assert (share > 0.95) if high else (share < EIV_SIGNAL_SHARE), (motion_deg, share)
    plain = estimate_slip(pos, quats, valid, pairs, fps=FPS)
    assert plain.signal_share == (1.0,) * len(pairs)


def test_signal_share_of_a_hinge_is_noise() -> None:
    # a joint turning 40° about one axis: along the axis only the noise "rotates"
    rng = np.random.default_rng(5)
    n = 1200
    hub = Rotation.from_rotvec(smooth_signal(rng, n, (0.2, 0.8), 0.3))
    angle = smooth_signal(rng, n, (0.3, 1.0), np.radians(40.0))[:, 0]
    limb = hub * Rotation.from_rotvec(angle[:, None] * np.array([0.0, 0.0, 1.0]))
    hub_pos = smooth_signal(rng, n, (0.1, 0.5), 0.3)
    in_hub, in_limb = np.array([0.0, -0.2, 0.03]), np.array([0.0, 0.15, 0.04])
    pos = {"hub": hub_pos, "limb": hub_pos + hub.apply(in_hub) - limb.apply(in_limb)}
    noise = np.radians(0.5)
    quats = {s: (r * Rotation.from_rotvec(rng.normal(scale=noise, size=(n, 3)))
                 ).as_quat(scalar_first=True) for s, r in (("hub", hub), ("limb", limb))}
    valid = {s: np.ones(n, dtype=np.bool_) for s in pos}
    fit = estimate_slip(pos, quats, valid, [("hub", "limb")], fps=FPS,
                        rotation_noise=rotation_noise_variance(quats, valid))
    assert fit.signal_share[0] < 0.5, fit.signal_share


def test_filled_gaps_carry_no_weight() -> None:
    # the rotations are low-passed before they enter the joint equations: a filled gap must
    # not leak into the measured frames around it, whatever values the filler guessed (two
    # gaps 2 frames apart on the hub leave frames with under four measured neighbours)
    for seed in range(3):
        pos, quats, _, pairs, truth = noisy_star(seed, 30.0, 0.0, n=600)
        rng = np.random.default_rng(seed)
        valid = {}
        for s in pos:
            ok = np.ones(600, dtype=np.bool_)
            for start in rng.choice(np.arange(20, 560), size=4, replace=False):
                ok[start:start + 5] = False
            if s == "hub":
                ok[300:305] = ok[307:312] = False
            valid[s] = ok
        held, scrambled = {}, {}
        for s, q in quats.items():
            last = np.maximum.accumulate(np.where(valid[s], np.arange(600), 0))
            held[s] = q[last]  # the last measured sample
            scrambled[s] = q.copy()
            scrambled[s][~valid[s]] = np.roll(q, 40, axis=0)[~valid[s]]
        fits = [estimate_slip(pos, filled, valid, pairs, fps=FPS, slip_hz=0.5)
                for filled in (held, scrambled)]
        assert np.allclose(fits[0].centres, fits[1].centres, rtol=0, atol=1e-9), seed
        for j, true in enumerate(truth):
            err = np.abs(fits[1].centres[j].reshape(6) - true).max()
            assert err < 5e-4, (seed, j, err)


def test_slips_do_not_drift_together_on_a_long_precise_recording() -> None:
    # 60 s at 30 fps: 16 cosines model the slip only up to 0.13 Hz, the rest of its 0.05–0.5 Hz
    # is noise to the model; with no white noise, weighting the rows by the white part alone
    # let the slips drift as one (the whole body shifting, which no joint equation sees):
    # measured 7.5–11.8 mm RMS of common world-frame slip, 4.0–4.9 mm with the unmodelled
    # share counted (the true common part: 2 mm)
    n, fps = 1800, 30.0
    for seed in range(4):
        rng = np.random.default_rng(seed)
        rot = {"hub": Rotation.from_rotvec(smooth_signal(rng, n, (0.02, 0.1), 0.05))}
        pos = {"hub": smooth_signal(rng, n, (0.1, 0.5), 0.3)}
        pairs: list[tuple[str, str]] = []
        parent = "hub"
        for k, name in enumerate("abcde"):
            in_parent, in_child = rng.normal(scale=0.1, size=3), rng.normal(scale=0.1, size=3)
            rel = Rotation.from_rotvec(smooth_signal(rng, n, (0.3, 1.0), np.radians(10.0))
                                       + 0.2 * k)
            rot[name] = rot[parent] * rel
            pos[name] = pos[parent] + rot[parent].apply(in_parent) - rot[name].apply(in_child)
            pairs.append((parent, name))
            parent = name
        slip = {s: smooth_signal(rng, n, (0.05, 0.5), 0.005) for s in pos}
        measured = {s: pos[s] + rot[s].apply(slip[s]) for s in pos}
        quats = {s: r.as_quat(scalar_first=True) for s, r in rot.items()}
        valid = {s: np.ones(n, dtype=np.bool_) for s in pos}
        fit = estimate_slip(measured, quats, valid, pairs, fps=fps)
        common = np.mean([rot[s].apply(fit.slip[s]) for s in pos], axis=0)
        rms = float(np.sqrt(np.mean(np.sum(common**2, axis=1))))
        assert rms < 0.006, (seed, rms)


def test_slip_layout_puts_every_sensors_slip_first_and_the_centres_last() -> None:
    layout = SlipLayout.of(["hub", "left", "top"], 2, N, FPS, 0.5)
    k = slip_basis(N, FPS / 0.5).shape[1]
    assert layout.k == k
    assert layout.index == {"hub": 0, "left": 3 * k, "top": 6 * k}
    assert (layout.n_s, layout.size) == (9 * k, 9 * k + 12)
    no_slip = SlipLayout.of(["hub", "left"], 1, N, FPS, 0.0)
    assert (no_slip.k, no_slip.n_s, no_slip.size, no_slip.unmodelled) == (0, 0, 6, 1.0)


def test_a_joint_block_is_symmetric_touches_its_unknowns_and_fits_a_clean_joint() -> None:
    """Noise-free, slip-free joint: the block is symmetric positive semi-definite over the
    joint's centres and its two sensors' slips, and the true centres with zero slip solve its
    normal equations (the right-hand side is the block times that solution)."""
    rng = np.random.default_rng(3)
    hub_rot = Rotation.from_rotvec(smooth_signal(rng, N, (0.2, 0.8), 0.3))
    rel = Rotation.from_rotvec(smooth_signal(rng, N, (0.5, 1.5), np.radians(20.0)))
    limb_rot = hub_rot * rel
    in_hub, in_limb = np.array([0.1, -0.05, 0.02]), np.array([0.0, 0.12, -0.03])
    hub_pos = smooth_signal(rng, N, (0.1, 0.5), 0.3)
    centre = hub_pos + hub_rot.apply(in_hub)
    limb_pos = centre - limb_rot.apply(in_limb)
    layout = SlipLayout.of(["hub", "limb"], 2, N, FPS, 0.5)
    # component-major: matrices (9, F), the offset (3, F)
    rows = tuple(np.ascontiguousarray(r.as_matrix().reshape(N, 9).T) for r in (hub_rot, limb_rot))
    block = joint_block(layout, 1, ("hub", "limb"), (rows[0], rows[1]),
                        np.ascontiguousarray((limb_pos - hub_pos).T), w=np.ones(N), v_eiv=0.0)
    k = layout.k
    assert block.eiv is None
    assert block.share == 1.0
    assert list(block.idx[:6]) == list(range(layout.n_s + 6, layout.n_s + 12))
    assert list(block.idx[6:]) == list(range(6 * k))
    assert np.allclose(block.normal, block.normal.T)
    assert np.linalg.eigvalsh(block.normal).min() > -1e-9 * np.abs(block.normal).max()
    truth = np.concatenate([in_hub, in_limb, np.zeros(6 * k)])
    assert np.allclose(block.normal @ truth, block.rhs, rtol=1e-9,
                       atol=1e-9 * np.abs(block.rhs).max())
