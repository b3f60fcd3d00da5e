"""In-memory form of a 6-DOF sensor recording."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from . import _rows as rows
from .errors import InputError


@dataclass(frozen=True, eq=False)
class SensorRecording:
    """Positions and orientations of 6-DOF sensors, frame by frame.

    Attributes
    ----------
    sensors : tuple of str
        Segment name of each sensor (see ``bonefit.estimation.model.SEGMENTS``), length S.
    positions : ndarray, shape (F, S, 3)
        Sensor origin in the source (world) frame, metres. NaN where a sample was dropped.
    quaternions : ndarray, shape (F, S, 4)
        Sensor → source rotation, scalar-first ``(w, x, y, z)``, unit norm. NaN where dropped.
    fps : float
        Frame rate, Hz.
    time : ndarray, shape (F,)
        Time of each frame, seconds.
    warnings : tuple of str
        What the reader noticed and worked around (ignored stations, dropped frames);
        ``estimate_skeleton`` passes them on to its result.
    """

    sensors: tuple[str, ...]
    positions: NDArray[np.float64]
    quaternions: NDArray[np.float64]
    fps: float
    time: NDArray[np.float64]
    warnings: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        n_frames, n_sensors = self.positions.shape[:2]
        if self.positions.shape != (n_frames, n_sensors, 3):
            raise InputError(f"positions must have shape (F, S, 3), got {self.positions.shape}",
                             field="positions")
        if self.quaternions.shape != (n_frames, n_sensors, 4):
            raise InputError(
                f"quaternions must have shape {(n_frames, n_sensors, 4)}, "
                f"got {self.quaternions.shape}", field="quaternions")
        if len(self.sensors) != n_sensors:
            raise InputError(f"{len(self.sensors)} sensor names for {n_sensors} sensors",
                             field="sensors")
        if len(set(self.sensors)) != n_sensors:
            raise InputError("sensor names repeat", field="sensors")
        if self.time.shape != (n_frames,):
            raise InputError(f"time must have shape ({n_frames},)", field="time")
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise InputError(f"fps must be positive, got {self.fps}", field="fps")

    @property
    def n_frames(self) -> int:
        """Number of frames F."""
        return int(self.positions.shape[0])

    def index(self, sensor: str) -> int:
        """Column of ``sensor``; raises InputError naming the sensors present."""
        try:
            return self.sensors.index(sensor)
        except ValueError:
            raise InputError(
                f"sensor {sensor!r} is missing; the recording has {', '.join(self.sensors)}",
                sensor=sensor) from None

    def valid(self) -> NDArray[np.bool_]:
        """Mask (F, S) of samples with a finite position and orientation."""
        return rows.finite(self.positions) & rows.finite(self.quaternions)
