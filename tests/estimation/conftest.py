"""Small shared fixtures for the estimation tests: synthetic rigs and simulated recordings.

Stable interface (other test modules use these):

- ``rig_factory(kind="ball"|"hinge", n_frames=400, rom_deg=60, noise_m=0, seed=0)`` returns a
  ``Rig`` with sensor poses of two bodies joined at a known centre.
- ``example_clip``: a 360-frame, 60 fps synthetic whole-body ``BvhMotion`` (cm).
- ``sim15`` / ``sim11``: ``(SensorRecording, SimulationTruth)`` simulated from ``example_clip``
  with the evaluation protocol's noise (2 mm, 0.5°, 5 mm slip, 1 % dropped).
- ``clean15``: the same 15-sensor recording without noise, slip or drops.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from bonefit.estimation.bvh import BvhMotion
from bonefit.estimation.recording import SensorRecording
from bonefit.estimation.simulate.sensors import SimulationTruth, example_motion, simulate_sensors


@dataclass(frozen=True)
class Rig:
    """Two rigid bodies a and b joined at one point, each carrying a 6-DOF sensor."""

    positions_a: NDArray[np.float64]
    rotations_a: Rotation
    positions_b: NDArray[np.float64]
    rotations_b: Rotation
    local_a: NDArray[np.float64]   # true centre in sensor a's frame
    local_b: NDArray[np.float64]   # true centre in sensor b's frame
    centre: NDArray[np.float64]    # (F, 3) true world centre
    axis_a: NDArray[np.float64]    # hinge axis in frame a (ball: zeros)


def make_rig(kind: str = "ball", *, n_frames: int = 400, rom_deg: float = 60.0,
             noise_m: float = 0.0, noise_deg: float = 0.0, seed: int = 0) -> Rig:
    """A rig whose body a wanders and turns while b rotates about the joint."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, n_frames)
    freqs = rng.uniform(0.5, 3.0, size=(3, 3))
    phases = rng.uniform(0, 2 * np.pi, size=(3, 3))

    def wave(k: int, amp: float) -> NDArray[np.float64]:
        return np.asarray(amp * np.sum(np.sin(2 * np.pi * freqs[k][None, :] * t[:, None]
                                              + phases[k][None, :]), axis=1) / 3.0)

    ra = Rotation.from_rotvec(np.column_stack([wave(0, 0.6), wave(1, 0.6), wave(2, 0.6)]))
    pa = np.column_stack([wave(1, 0.3), 1.0 + wave(2, 0.1), wave(0, 0.3)])
    local_a = np.array([0.02, -0.25, 0.05])
    local_b = np.array([-0.04, 0.18, 0.03])
    half = np.deg2rad(rom_deg) / 2.0
    if kind == "hinge":
        axis = np.array([1.0, 0.2, -0.1])
        axis /= np.linalg.norm(axis)
        angle = half * np.sin(2 * np.pi * 1.3 * t + 0.3) + half
        rel = Rotation.from_rotvec(angle[:, None] * axis[None, :])
    elif kind == "ball":
        axis = np.zeros(3)
        rel = Rotation.from_rotvec(np.column_stack([
            half * np.sin(2 * np.pi * 1.1 * t), half * np.sin(2 * np.pi * 0.7 * t + 1.0),
            half * np.sin(2 * np.pi * 1.7 * t + 2.0)]))
    else:
        raise ValueError(kind)
    rb = ra * rel
    centre = ra.apply(local_a) + pa
    pb = centre - rb.apply(local_b)
    if noise_m > 0:
        pa = pa + rng.normal(scale=noise_m, size=pa.shape)
        pb = pb + rng.normal(scale=noise_m, size=pb.shape)
    if noise_deg > 0:
        ra = ra * Rotation.from_rotvec(rng.normal(scale=np.deg2rad(noise_deg),
                                                  size=(n_frames, 3)))
        rb = rb * Rotation.from_rotvec(rng.normal(scale=np.deg2rad(noise_deg),
                                                  size=(n_frames, 3)))
    return Rig(pa, ra, pb, rb, local_a, local_b, centre, axis)


@pytest.fixture(scope="session")
def rig_factory() -> Callable[..., Rig]:
    """``make_rig`` as a fixture."""
    return make_rig


@pytest.fixture(scope="session")
def example_clip() -> BvhMotion:
    """A 6 s, 60 fps synthetic whole-body clip in cm (``cmu_bvh11`` node names)."""
    return example_motion(360, fps=60.0, seed=3)


@pytest.fixture(scope="session")
def sim15(example_clip: BvhMotion) -> tuple[SensorRecording, SimulationTruth]:
    """15 sensors with protocol noise (2 mm, 0.5°, 5 mm slip, 1 % dropped)."""
    return simulate_sensors(example_clip, units_m=0.01, n_sensors=15, seed=11)


@pytest.fixture(scope="session")
def sim11(example_clip: BvhMotion) -> tuple[SensorRecording, SimulationTruth]:
    """The reduced 11-sensor suit with protocol noise."""
    return simulate_sensors(example_clip, units_m=0.01, n_sensors=11, seed=11)


@pytest.fixture(scope="session")
def clean15(example_clip: BvhMotion) -> tuple[SensorRecording, SimulationTruth]:
    """15 sensors without noise, slip or dropped samples."""
    return simulate_sensors(example_clip, units_m=0.01, n_sensors=15, seed=11,
                            position_noise_m=0.0, orientation_noise_deg=0.0, slip_m=0.0,
                            drop_fraction=0.0)


def two_feet_motion(values: NDArray[np.float64], fps: float) -> BvhMotion:
    """A hips-and-two-feet BVH (cm, root with position channels) driven by ``values`` (F, 12)."""
    names = ("Hips", "LeftFoot", "LeftFoot_end", "RightFoot", "RightFoot_end")
    parents = (-1, 0, 1, 0, 3)
    offsets = np.array([[0, 90, 0], [10, -80, 0], [0, -7, 15], [-10, -80, 0], [0, -7, 15]],
                       dtype=float)
    channels = (("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation",
                 "Yrotation"), ("Zrotation", "Xrotation", "Yrotation"), (),
                ("Zrotation", "Xrotation", "Yrotation"), ())
    return BvhMotion(names, parents, offsets, channels, 1.0 / fps, values)
