"""Synthetic recordings with exact ground truth, built from real BVH clips (docs/benchmarks.md,
"The evaluation protocol")."""

from .inertial import InertialTruth, simulate_inertial, simulate_walker
from .sensors import SimulationTruth, example_motion, simulate_sensors

__all__ = [
    "InertialTruth",
    "SimulationTruth",
    "example_motion",
    "simulate_inertial",
    "simulate_sensors",
    "simulate_walker",
]
