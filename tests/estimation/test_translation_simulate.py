"""Synthetic inertial recordings: stripped root, accelerometer physics, saturation, rates."""

from __future__ import annotations

import numpy as np
import pytest

from bonefit.estimation.bvh import BvhMotion, forward_kinematics
from bonefit.estimation.io.kinematics import GRAVITY
from bonefit.estimation.simulate.inertial import simulate_inertial, simulate_walker
from tests.estimation.conftest import two_feet_motion


def standing_then_walking(n: int = 240, fps: float = 120.0) -> BvhMotion:
    t = np.arange(n) / fps
    values = np.zeros((n, 12))
    values[:, 0] = np.where(t < 1.0, 0.0, 100 * (t - 1.0) ** 2)  # still, then accelerate
    values[:, 1] = 90
    values[:, 4] = np.where(t < 1.0, 0.0, 10 * (t - 1.0))  # then pitch
    return two_feet_motion(values, fps)


def test_strips_the_root_and_keeps_the_truth() -> None:
    motion = standing_then_walking()
    rec, truth = simulate_inertial(motion, noise_g=0.0)
    hips = rec.positions[:, rec.index("Hips")]
    np.testing.assert_allclose(hips, np.broadcast_to(hips[0], hips.shape), atol=1e-9)
    world, _ = forward_kinematics(motion)
    np.testing.assert_allclose(truth.root, world[:, 0] * 0.01, atol=1e-9)
    assert rec.toes == {"LeftFoot": "LeftFoot_end", "RightFoot": "RightFoot_end"}


def test_accelerometer_reads_one_g_at_rest_and_follows_the_motion() -> None:
    motion = standing_then_walking()
    rec, _truth = simulate_inertial(motion, noise_g=0.0)
    mag = np.linalg.norm(rec.accelerations["LeftFoot"], axis=1) / GRAVITY
    still = rec.time < 0.8
    np.testing.assert_allclose(mag[still], 1.0, atol=1e-6)
    # root accelerates at 2 m/s² along x after 1 s; the feet follow (plus small rotation)
    moving = (rec.time > 1.2) & (rec.time < 1.8)
    expected = np.hypot(1.0, 2.0 / GRAVITY)
    assert np.median(mag[moving]) == pytest.approx(expected, abs=0.05)


def test_rates_noise_and_saturation() -> None:
    motion = standing_then_walking()
    rec, truth = simulate_inertial(motion, fps=30.0, noise_g=0.02, clip_g=1.0, seed=4)
    assert rec.fps == 30.0
    assert rec.n_frames == 60
    assert truth.root.shape == (60, 3)
    a = rec.accelerations["RightFoot"] / GRAVITY
    assert np.abs(a).max() <= 1.0 + 1e-12
    assert np.std(np.linalg.norm(a[:20], axis=1)) > 0.005


def test_walker_truth_is_consistent() -> None:
    rec, truth, contacts = simulate_walker(fps=100)
    assert set(contacts) == {"left", "right", "both", "none"}
    left = rec.index("LeftFoot")
    planted = np.isin(contacts, ("left", "both"))
    speed = np.linalg.norm(np.diff(truth.positions[:, left], axis=0), axis=1) * 100
    assert speed[planted[:-1] & planted[1:]].max() < 1e-6
    err = truth.horizontal_errors(truth.root)
    assert err["mean_pct"] == 0.0
    assert err["path_m"] == pytest.approx(2.1, abs=0.05)
