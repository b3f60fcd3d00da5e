"""The NPZ sensor recording: ``positions`` (F,S,3), ``quaternions`` (F,S,4), ``sensors``,
``fps`` (reader, writer and a summary read from the archive's headers)."""

from __future__ import annotations

import zipfile
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ..errors import InputError
from ..model import SEGMENTS
from ..recording import SensorRecording
from . import limits

if TYPE_CHECKING:
    pass

from .sensor_common import (
    PathLike,
    check_recording,
    normalise_quaternions,
    parse_fps,
    time_from_fps,
    unit_scale,
)


def read_sensor_npz(path: PathLike, *, units: str | None = None,
                    fps: float | None = None) -> SensorRecording:
    """Read a recording saved with ``numpy.savez``.

    Parameters
    ----------
    path : path
        Archive with ``positions`` (F, S, 3), ``quaternions`` (F, S, 4) scalar-first,
        ``sensors`` (S,) strings and ``fps`` (scalar); optionally ``time`` (F,) seconds and
        ``units`` (string). Loaded with ``allow_pickle=False``: object arrays are refused.
    units : {"m", "cm", "mm", "in"}, optional
        Overrides the archive's ``units`` (default metres).
    fps : float, optional
        Overrides the archive's ``fps``.

    Returns
    -------
    SensorRecording

    Raises
    ------
    InputError
        Missing array, wrong shape, unknown sensor name, non-unit quaternion, all-NaN sensor.
    """
    with limits.open_npz(path) as archive:
        _npz_frames(archive)
        positions = _npz_floats(archive, "positions")
        quats = _npz_floats(archive, "quaternions")
        sensors = tuple(_npz_sensor_names(_npz_small(archive, "sensors", "US")))
        names = set(archive.namelist())
        if fps is None:
            if "fps.npy" not in names:
                raise InputError("NPZ archive lacks the array 'fps' (or give fps)", field="fps")
            fps = _npz_scalar(_npz_small(archive, "fps", "biuf"), "fps")
        time = _npz_floats(archive, "time") if "time.npy" in names else None
        if units is None and "units.npy" in names:
            units = _npz_units(_npz_small(archive, "units", "US"))
    _check_npz_shapes(sensors, positions, quats)
    units = units or "m"
    rate = parse_fps(fps)
    _check_npz_values(sensors, positions, quats, time)
    values = np.concatenate([positions * unit_scale(units), quats], axis=-1)
    values[~np.isfinite(values).all(axis=-1)] = np.nan
    quats_n = normalise_quaternions(values[..., 3:], sensors, None)
    if time is None:
        time = time_from_fps(positions.shape[0], rate)
    rec = SensorRecording(sensors, values[..., :3], quats_n, rate, time)
    return check_recording(rec, units)


def _check_npz_shapes(sensors: tuple[str, ...], positions: NDArray[np.float64],
                      quats: NDArray[np.float64]) -> None:
    """Known sensor names, positions (F, S, 3) and quaternions (F, S, 4)."""
    for name in sensors:
        if name not in SEGMENTS:
            raise InputError(f"unknown sensor {name!r}; segments are {', '.join(SEGMENTS)}",
                             sensor=name, field="sensors")
    if positions.ndim != 3 or positions.shape[-1] != 3:
        raise InputError(f"positions must have shape (F, S, 3), got {positions.shape}",
                         field="positions")
    if quats.shape != (*positions.shape[:2], 4):
        raise InputError(f"quaternions must have shape {(*positions.shape[:2], 4)}, "
                         f"got {quats.shape}", field="quaternions")


def _check_npz_values(sensors: tuple[str, ...], positions: NDArray[np.float64],
                      quats: NDArray[np.float64], time: NDArray[np.float64] | None) -> None:
    """Values within the limits (``bonefit.estimation.io.limits``; NaN is a gap) and, when
    given, a time (F,) without NaN."""
    for key, array in (("positions", positions), ("quaternions", quats)):
        bad = limits.first_bad_value(array)
        if bad is not None:
            limits.check_value(float(array[bad]), field=key, sensor=sensors[bad[1]]
                               if len(bad) > 1 and bad[1] < len(sensors) else None)
    if time is not None:
        if time.shape != positions.shape[:1]:
            raise InputError(f"time must have shape {positions.shape[:1]}, got {time.shape}",
                             field="time")
        bad = limits.first_bad_value(time, nan_ok=False)
        if bad is not None:
            limits.check_value(float(time[bad]), field="time", nan_ok=False)


def _npz_floats(archive: zipfile.ZipFile, key: str) -> NDArray[np.float64]:
    """A numeric member as float64, after its declared shape and size are checked."""
    return np.asarray(limits.load_npy(archive, key), dtype=np.float64)


def write_sensor_npz(recording: SensorRecording, path: PathLike) -> None:
    """Save ``recording`` as an NPZ archive readable by :func:`read_sensor_npz` (metres)."""
    np.savez_compressed(path, positions=recording.positions,
                        quaternions=recording.quaternions,
                        sensors=np.array(recording.sensors, dtype=str),
                        fps=np.float64(recording.fps), time=recording.time,
                        units=np.str_("m"))



def sniff_npz(path: PathLike) -> dict[str, Any]:
    """Shapes from the NPY headers, names and scalars from the small members: nothing is
    decompressed before its declared size is checked (``bonefit.estimation.io.limits``)."""
    with limits.open_npz(path) as archive:
        frames = _npz_frames(archive)
        names = set(archive.namelist())
        sensors = (_npz_sensor_names(_npz_small(archive, "sensors", "US"))
                   if "sensors.npy" in names else [])
        fps = (_npz_scalar(_npz_small(archive, "fps", "biuf"), "fps")
               if "fps.npy" in names else None)
        units = (_npz_units(_npz_small(archive, "units", "US"))
                 if "units.npy" in names else "m")
    return {"format": "npz", "frames": frames, "sensors": sensors, "fps": fps, "units": units}


def _npz_small(archive: zipfile.ZipFile, key: str, kinds: str) -> NDArray[Any]:
    """A member holding names or a scalar, within ``MAX_NPZ_SMALL_BYTES``."""
    return limits.load_npy(archive, key, kinds=kinds, small=True)


def _npz_frames(archive: zipfile.ZipFile) -> int:
    """Frames that ``positions`` declares, within ``MAX_FRAMES`` (its header only)."""
    shape, _ = limits.check_npy(archive, "positions")
    frames = shape[0] if shape else 0
    limits.check_count("frames", frames, "MAX_FRAMES", field="positions")
    return frames


def _npz_sensor_names(names: NDArray[Any]) -> list[str]:
    """The ``sensors`` array as names, within ``MAX_SENSORS`` and ``MAX_NAME_CHARS``."""
    flat = names.reshape(-1)
    limits.check_count("sensors", flat.size, "MAX_SENSORS", field="sensors")
    out = [str(s) for s in flat]
    for name in out:
        limits.check_count("characters in a sensor name", len(name), "MAX_NAME_CHARS",
                           field="sensors")
    return out


def _npz_scalar(value: NDArray[Any], key: str) -> float:
    if value.size != 1:
        raise InputError(f"{key} must be one number, got an array of shape {value.shape}",
                         field=key)
    number = float(value.reshape(-1)[0])
    limits.check_value(number, field=key, nan_ok=False)
    return number


def _npz_units(value: NDArray[Any]) -> str:
    if value.size != 1:
        raise InputError(f"units must be one string, got an array of shape {value.shape}",
                         field="units")
    text = str(value.reshape(-1)[0])
    limits.check_count("characters in units", len(text), "MAX_NAME_CHARS", field="units")
    return text
