"""Reading 6-DOF sensor recordings in any supported format: bonefit sensor CSV, tracker
ASCII and NPZ.

The formats live in :mod:`.sensor_csv`, :mod:`.tracker` and :mod:`.sensor_npz`, what they share
in :mod:`.sensor_common`, format detection and summaries in :mod:`.sniff`; their public names
are importable from here as before.

Every reader returns a :class:`~bonefit.estimation.recording.SensorRecording` in metres with unit
scalar-first quaternions (sensor → source frame) and NaN for dropped samples, and raises
:class:`~bonefit.estimation.errors.InputError` naming the line, column, field or sensor at fault.
The formats are described in ``docs/skeleton-io.md``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from ..progress import Progress
from ..recording import SensorRecording

if TYPE_CHECKING:
    from .tracker import TrackerLayout

from .sensor_common import MAX_BODY_EXTENT_M as MAX_BODY_EXTENT_M
from .sensor_common import MIN_BODY_EXTENT_M as MIN_BODY_EXTENT_M
from .sensor_common import QUATERNION_TOLERANCE as QUATERNION_TOLERANCE
from .sensor_common import UNITS as UNITS
from .sensor_common import PathLike as PathLike
from .sensor_common import check_recording as check_recording
from .sensor_common import example_path as example_path
from .sensor_common import fps_from_time as fps_from_time
from .sensor_common import metadata_comment as metadata_comment
from .sensor_common import normalise_quaternions as normalise_quaternions
from .sensor_common import open_text as open_text
from .sensor_common import parse_fps as parse_fps
from .sensor_common import time_from_fps as time_from_fps
from .sensor_common import unit_scale as unit_scale
from .sensor_csv import COMPONENTS as COMPONENTS
from .sensor_csv import read_sensor_csv as read_sensor_csv
from .sensor_csv import write_sensor_csv as write_sensor_csv
from .sensor_npz import read_sensor_npz as read_sensor_npz
from .sensor_npz import write_sensor_npz as write_sensor_npz
from .sniff import FORMATS as FORMATS
from .sniff import RowCounter as RowCounter
from .sniff import detect_format as detect_format
from .sniff import resolve_sensor_format
from .sniff import sniff_recording as sniff_recording


def read_recording(path: PathLike, *, format: str = "auto", units: str | None = None,
                   fps: float | None = None,
                   stations: Mapping[Any, Any] | str | None = None,
                   tracker_layout: str | TrackerLayout | None = None,
                   progress: Progress | None = None) -> SensorRecording:
    """Read a sensor recording in any supported format.

    Parameters
    ----------
    path : path
    format : {"auto", "csv", "tracker", "npz"}
        ``"auto"`` detects it with :func:`detect_format`.
    units : {"m", "cm", "mm", "in"}, optional
        Units of the file's positions; default metres (inches for tracker files).
    fps : float, optional
        Frame rate, Hz; required for tracker files and CSV files without a ``time`` column.
    stations : mapping or str, optional
        Station → segment mapping of tracker files (see
        :func:`~bonefit.estimation.io.tracker.parse_stations`).
    tracker_layout : str, optional
        Column layout of a tracker file (see
        :func:`~bonefit.estimation.io.tracker.parse_tracker_layout`); detected from the file when
        omitted.
    progress : callable, optional
        ``progress(fraction, "reading")`` while a sensor CSV is parsed (per block); the
        other formats report nothing within the read.

    Returns
    -------
    SensorRecording
        Positions in metres, unit quaternions, NaN for dropped samples.

    Raises
    ------
    InputError
        See the format-specific readers.
    FileNotFoundError
        If ``path`` does not exist.
    """
    fmt = resolve_sensor_format(path, format)
    if units is not None:
        unit_scale(units)
    if fmt == "csv":
        return read_sensor_csv(path, units=units, fps=fps, progress=progress)
    if fmt == "tracker":
        from .tracker import read_tracker_ascii

        return read_tracker_ascii(path, stations=stations, units=units, fps=fps,
                                  layout=tracker_layout)
    return read_sensor_npz(path, units=units, fps=fps)


