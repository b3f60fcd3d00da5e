"""Generate the bundled example recording ``estimation/examples/walk.csv``.

A synthetic 15-segment body (rigid segments, joint centres exact) walks forward for 5 s at
60 fps with sinusoidal joint angles on incommensurate frequencies, so that every joint turns
about more than one axis (the hinges, knee and elbow, about one). One virtual 6-DOF sensor
sits on each segment 3–7 cm off the bone with a random orientation; positions get 0.5 mm and
orientations 0.2° of white noise, and a few samples are dropped. Deterministic (fixed seed).

Run from the repository root::

    .venv/bin/python scripts/make_example.py
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from bonefit.estimation.io.sensors import write_sensor_csv
from bonefit.estimation.model import SEGMENTS
from bonefit.estimation.recording import SensorRecording

OUT = Path(__file__).resolve().parents[1] / "estimation" / "examples" / "walk.csv"

# segment: (parent segment, joint it turns about, joint position in the parent frame at rest
# relative to the parent's own joint, the segment's far end (for sensor placement), and the
# joint's angle amplitudes about x (flexion), z (abduction), y (twist) in degrees, hinge=True
# when only x moves.
Body = dict[str, tuple[str | None, tuple[float, float, float], tuple[float, float, float],
                       tuple[float, float, float], float]]
BODY: Body = {
    # name        parent        joint offset         far end               amplitudes  bias
    "pelvis":     (None,        (0.0, 0.95, 0.0),    (0.0, 0.10, 0.0),     (6, 5, 10), 0),
    "chest":      ("pelvis",    (0.0, 0.10, 0.0),    (0.0, 0.42, 0.0),     (20, 15, 20), 0),
    "head":       ("chest",     (0.0, 0.42, 0.0),    (0.0, 0.22, 0.0),     (25, 20, 30), 0),
    "l_upperarm": ("chest",     (0.17, 0.38, 0.0),   (0.0, -0.29, 0.0),    (40, 25, 30), 25),
    "l_forearm":  ("l_upperarm", (0.0, -0.29, 0.0),  (0.0, -0.26, 0.0),    (45, 0, 0), 55),
    "l_hand":     ("l_forearm", (0.0, -0.26, 0.0),   (0.0, -0.08, 0.0),    (35, 20, 10), 0),
    "r_upperarm": ("chest",     (-0.17, 0.38, 0.0),  (0.0, -0.29, 0.0),    (40, 25, 30), 25),
    "r_forearm":  ("r_upperarm", (0.0, -0.29, 0.0),  (0.0, -0.26, 0.0),    (45, 0, 0), 55),
    "r_hand":     ("r_forearm", (0.0, -0.26, 0.0),   (0.0, -0.08, 0.0),    (35, 20, 10), 0),
    "l_thigh":    ("pelvis",    (0.09, -0.05, 0.0),  (0.0, -0.42, 0.0),    (35, 15, 20), 0),
    "l_shank":    ("l_thigh",   (0.0, -0.42, 0.0),   (0.0, -0.41, 0.0),    (35, 0, 0), 40),
    "l_foot":     ("l_shank",   (0.0, -0.41, 0.0),   (0.0, -0.04, 0.14),   (30, 18, 12), 0),
    "r_thigh":    ("pelvis",    (-0.09, -0.05, 0.0), (0.0, -0.42, 0.0),    (35, 15, 20), 0),
    "r_shank":    ("r_thigh",   (0.0, -0.42, 0.0),   (0.0, -0.41, 0.0),    (35, 0, 0), 40),
    "r_foot":     ("r_shank",   (0.0, -0.41, 0.0),   (0.0, -0.04, 0.14),   (30, 18, 12), 0),
}


def segment_poses(n_frames: int, fps: float, rng: np.random.Generator
                  ) -> tuple[dict[str, Rotation], dict[str, NDArray[np.float64]]]:
    """World orientation and proximal-joint position of every segment, per frame."""
    t = np.arange(n_frames) / fps
    gait = 0.9  # Hz
    rotations: dict[str, Rotation] = {}
    origins: dict[str, NDArray[np.float64]] = {}
    for name, (parent, offset, _, amp, bias) in BODY.items():
        angles = np.empty((n_frames, 3))
        for k in range(3):
            freqs = gait * np.array([1.0, 1.7 + 0.3 * k, 2.9 + 0.2 * k])
            phases = rng.uniform(0, 2 * np.pi, 3)
            weights = np.array([0.6, 0.25, 0.15])
            angles[:, k] = amp[k] * (weights[:, None] * np.sin(
                2 * np.pi * freqs[:, None] * t + phases[:, None])).sum(axis=0)
        angles[:, 0] += bias
        local = Rotation.from_euler("XZY", angles, degrees=True)
        if parent is None:
            rotations[name] = local
            path = np.column_stack([0.05 * np.sin(2 * np.pi * gait * t / 2),
                                    0.02 * np.sin(2 * np.pi * 2 * gait * t),
                                    0.6 * t])
            origins[name] = np.asarray(offset) + path
        else:
            rotations[name] = rotations[parent] * local
            origins[name] = origins[parent] + rotations[parent].apply(np.asarray(offset))
    return rotations, origins


def make_recording(n_frames: int = 300, fps: float = 60.0, seed: int = 7,
                   drop: int = 12) -> SensorRecording:
    """The synthetic walk as a 15-sensor recording (metres)."""
    rng = np.random.default_rng(seed)
    rotations, origins = segment_poses(n_frames, fps, rng)
    positions = np.empty((n_frames, len(SEGMENTS), 3))
    quats = np.empty((n_frames, len(SEGMENTS), 4))
    for s, name in enumerate(SEGMENTS):
        far = np.asarray(BODY[name][2])
        direction = rng.normal(size=3)
        direction -= direction.dot(far) / max(far.dot(far), 1e-12) * far
        direction /= np.linalg.norm(direction)
        local = rng.uniform(0.3, 0.7) * far + rng.uniform(0.03, 0.07) * direction
        mount = Rotation.random(rng=rng)
        noise = Rotation.from_rotvec(rng.normal(scale=np.radians(0.2), size=(n_frames, 3)))
        positions[:, s] = (origins[name] + rotations[name].apply(local)
                           + rng.normal(scale=0.0005, size=(n_frames, 3)))
        quats[:, s] = (rotations[name] * mount * noise).as_quat(scalar_first=True)
    quats *= np.sign(quats[..., :1])  # w ≥ 0 reads better and is the same rotation
    frames = rng.integers(0, n_frames, drop)
    sensors = rng.integers(0, len(SEGMENTS), drop)
    positions[frames, sensors] = np.nan
    quats[frames, sensors] = np.nan
    return SensorRecording(SEGMENTS, positions, quats, fps, np.arange(n_frames) / fps)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("-o", "--output", type=Path, default=OUT)
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--fps", type=float, default=60.0)
    args = parser.parse_args()
    rec = make_recording(args.frames, args.fps)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    write_sensor_csv(rec, args.output, decimals=6)
    print(f"wrote {args.output} ({args.output.stat().st_size / 1e3:.0f} kB, "
          f"{rec.n_frames} frames, {len(rec.sensors)} sensors)")


if __name__ == "__main__":
    main()
