"""``bonefit skeleton``: joint centres, bone lengths and orientations from a sensor recording."""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..errors import InputError
from ..io.sensors import FORMATS, UNITS, detect_format, example_path, read_recording
from ..io.skeleton import read_skeleton_offsets, write_skeleton_files
from ..io.tracker import (
    TrackerLayout,
    detect_tracker_layout,
    parse_stations,
    parse_tracker_layout,
)
from ..model import JOINTS
from ..params import check_fps
from ..recording import SensorRecording
from ..results import SkeletonResult
from ..vocabulary import OPTIMIZERS, SKELETON_METHODS
from .progress import ProgressBar

UP_AXES = {"+x": (1.0, 0.0, 0.0), "-x": (-1.0, 0.0, 0.0), "+y": (0.0, 1.0, 0.0),
           "-y": (0.0, -1.0, 0.0), "+z": (0.0, 0.0, 1.0), "-z": (0.0, 0.0, -1.0)}

EPILOG = """\
examples:
  bonefit skeleton --example                       summary of the bundled 15-sensor walk
  bonefit skeleton walk.csv -o walk.json --bvh walk.bvh --csv joints.csv
  bonefit skeleton walk.csv --method reduced --optimizer nelder-mead -o paper.json
  bonefit skeleton take3.npz --units mm --up +z -o take3.json
  bonefit skeleton rom.csv -o calibration.json      a take in which every joint moves
  bonefit skeleton take4.csv --offsets calibration.json -o take4.json
                                                   same suit: joints at the calibrated offsets
  bonefit skeleton liberty.txt --format tracker --fps 240 --up=-z \\
      --stations 1=pelvis,2=chest,3=head,4=l_upperarm,5=l_hand,6=r_upperarm,7=r_hand,\\
8=l_thigh,9=l_foot,10=r_thigh,11=r_foot -o take.json
  bonefit skeleton trakstar.txt --stations stations.json \
      --tracker-layout "station,x,y,z,az,el,roll,time,quality;time=s" -o take.json

input formats (docs/skeleton-io.md):
  csv      time,<segment>.x,.y,.z,.qw,.qx,.qy,.qz,...   metres unless --units
  tracker  station x y z azimuth elevation roll (or qw qx qy qz) per line, inches;
           header rows, frame counters, time and quality columns, FASTRAK records and
           ROS CSV are detected (printed as "detected: ..."), or give --tracker-layout
  npz      positions (F,S,3), quaternions (F,S,4), sensors (S,), fps

exit status: 0 on success, 2 with a one-line reason on bad input.
"""


def register(sub: Any) -> None:
    """Add the ``skeleton`` command to the sub-parsers."""
    parser: argparse.ArgumentParser = sub.add_parser(
        "skeleton",
        help="estimate joint centres, bone lengths and orientations from 6-DOF sensors",
        description="Estimate joint centres, bone lengths and segment orientations from a\n"
                    "magnetic 6-DOF tracker recording (15 or 11 sensors) and write them as\n"
                    "JSON, BVH or CSV. Without -o, prints a summary.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("input", nargs="?", metavar="INPUT",
                        help="sensor recording (.csv, tracker .txt, .npz)")
    parser.add_argument("--example", action="store_true",
                        help="use the bundled example recording instead of INPUT")
    parser.add_argument("--format", default="auto", metavar="{auto,csv,tracker,npz}",
                        help="input format (default: detected)")
    parser.add_argument("--method", default="auto", metavar="{auto,llsf,gdke,reduced}",
                        help="joint estimator (default: auto, best per joint)")
    parser.add_argument("--optimizer", default="least-squares",
                        metavar="{least-squares,nelder-mead}",
                        help="minimiser of the reduced method's cost (default: least-squares)")
    parser.add_argument("--units", default=None, metavar="{mm,cm,m,in}",
                        help="units of the input positions (default: m; in for tracker files)")
    parser.add_argument("--fps", default=None, metavar="N",
                        help="frame rate, Hz (needed for tracker files)")
    parser.add_argument("--stations", default=None, metavar="MAP",
                        help='tracker station map: "1=pelvis,2=chest,..." or a JSON file')
    parser.add_argument("--tracker-layout", default=None, metavar="SPEC",
                        help="tracker columns, e.g. 'frame,station,x,y,z,qw,qx,qy,qz' or "
                             "'time,x,y,z,qx,qy,qz,qw;time=ns' (default: detected)")
    parser.add_argument("--up", default="+y", metavar="{+y,-y,+z,-z,+x,-x}",
                        help="world up axis of the source frame (default: +y; write --up=-z "
                             "for a negative axis)")
    parser.add_argument("--i0", default="0", metavar="N",
                        help="calibration frame for hands, feet and head (default: 0)")
    parser.add_argument("--offsets", default=None, metavar="CALIBRATION.json",
                        help="place every joint at its offset from an earlier result of the "
                             "same suit (its JSON, -o) instead of fitting: for takes in which "
                             "some joints do not move")
    parser.add_argument("-o", "--output", default=None, metavar="OUT.json",
                        help="write the result as JSON")
    parser.add_argument("--bvh", default=None, metavar="OUT.bvh", help="write a BVH file (cm)")
    parser.add_argument("--csv", default=None, metavar="OUT.csv",
                        help="write joint trajectories as CSV (metres)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(run=run)


def _choice(value: str, choices: tuple[str, ...] | list[str], option: str) -> str:
    key = value.strip().lower()
    if key not in choices:
        raise InputError(f"{option} must be one of {', '.join(choices)}, got {value!r}",
                         field=option)
    return key


def _number(value: str | None, option: str, kind: type[int] | type[float]) -> Any:
    if value is None:
        return None
    try:
        number = kind(value)
    except ValueError:
        raise InputError(f"{option} must be a number, got {value!r}", field=option) from None
    if number < 0 or (kind is float and not number > 0):
        raise InputError(f"{option} must be positive, got {value!r}", field=option)
    return number


def _estimator() -> Callable[..., SkeletonResult]:
    # imported on use so that ``bonefit --help`` and the readers stay quick to load
    from ..skeleton import estimate_skeleton

    return estimate_skeleton


def run(args: argparse.Namespace) -> int:
    """Run ``bonefit skeleton``; returns the exit code (bad input raises InputError)."""
    fmt = _choice(args.format, ["auto", *FORMATS], "--format")
    method = _choice(args.method, SKELETON_METHODS, "--method")
    optimizer = _choice(args.optimizer, OPTIMIZERS, "--optimizer")
    units = _choice(args.units, list(UNITS), "--units") if args.units is not None else None
    up = UP_AXES.get(args.up.strip().lower())
    if up is None:
        raise InputError(f"--up must be one of {', '.join(UP_AXES)}, got {args.up!r}",
                         field="--up")
    fps = _number(args.fps, "--fps", float)
    if fps is not None:
        check_fps(fps, "--fps")
    i0 = _number(args.i0, "--i0", int)
    stations = parse_stations(args.stations) if args.stations is not None else None
    offsets = read_skeleton_offsets(args.offsets) if args.offsets is not None else None
    if args.example:
        if args.input is not None:
            raise InputError("give INPUT or --example, not both", field="input")
        source = example_path()
    elif args.input is None:
        raise InputError("no INPUT recording given (or use --example)", field="input")
    else:
        source = Path(args.input)
    outputs = [Path(p) for p in (args.output, args.bvh, args.csv) if p is not None]
    for out in outputs:
        if not out.parent.is_dir():
            raise InputError(f"cannot write {out}: directory {out.parent} does not exist",
                             field="output")

    start = time.perf_counter()
    layout = _tracker_layout(source, fmt, args.tracker_layout)
    recording = read_recording(source, format=fmt, units=units, fps=fps, stations=stations,
                               tracker_layout=layout)
    read_s = time.perf_counter() - start
    if layout is not None and args.tracker_layout is None:
        print(f"detected: {layout.describe()}", file=sys.stderr)
    if i0 >= recording.n_frames:
        raise InputError(f"--i0 {i0} is past the last frame ({recording.n_frames - 1})",
                         field="--i0")

    estimate = _estimator()
    bar = None if args.quiet else ProgressBar()
    start = time.perf_counter()
    try:
        result = estimate(recording, method=method, optimizer=optimizer, up=up, i0=i0,
                          offsets=offsets, progress=bar)
    finally:
        if bar is not None:
            bar.close()
    estimate_s = time.perf_counter() - start
    timings = dict(result.timings)
    timings["read_s"] = read_s
    timings.setdefault("estimate_s", estimate_s)
    result = dataclasses.replace(result, timings=timings)

    try:
        # write_s covers BVH, CSV and the JSON conversion; the final dump is not timed
        result = write_skeleton_files(result, json_path=args.output, bvh_path=args.bvh,
                                      csv_path=args.csv)
    except OSError as exc:
        raise InputError(f"cannot write {exc.filename}: {exc.strerror}",
                         field="output") from None
    if args.output is None:
        print(summary(result, recording))
    return 0


def _tracker_layout(source: Path, fmt: str, spec: str | None) -> TrackerLayout | None:
    """The layout of a tracker input: ``spec``, or detected (printed once the file is read)."""
    if spec is not None:
        return parse_tracker_layout(spec)
    if (detect_format(source) if fmt == "auto" else fmt) != "tracker":
        return None
    return detect_tracker_layout(source)


def summary(result: SkeletonResult, recording: SensorRecording | None = None) -> str:
    """Human-readable summary: bone lengths, per-joint quality, warnings, timings."""
    lines = []
    head = f"method {result.method}, {result.n_frames} frames at {result.fps:g} Hz"
    if recording is not None:
        head += f", {len(recording.sensors)} sensors"
    lines.append(head)
    if result.bone_lengths:
        lines.append("bone lengths (cm):")
        for name, length in result.bone_lengths.items():
            lines.append(f"  {name:<12} {100 * float(length):7.1f}")
    if result.quality:
        lines.append("joints:          rms mm  sv ratio  motion deg  data sd mm  hinge  "
                     "estimator")
        for name in [j for j in JOINTS if j in result.quality] + [
                j for j in result.quality if j not in JOINTS]:
            q = result.quality[name]
            lines.append(
                f"  {name:<12} {_fmt(q.get('rms_residual_m'), 1000, '8.1f')} "
                f"{_fmt(q.get('singular_value_ratio'), 1, '9.3g')} "
                f"{_fmt(q.get('range_of_motion_deg'), 1, '11.0f')} "
                f"{_fmt(q.get('data_sd_m'), 1000, '11.1f')}  "
                f"{'yes' if q.get('hinge') else 'no':<5}  {q.get('estimator', '-')}")
    for warning in result.warnings:
        lines.append(f"warning: {warning}")
    if result.timings:
        lines.append("timings: " + ", ".join(f"{k} {float(v):.3f}"
                                              for k, v in result.timings.items()))
    return "\n".join(lines)


def _fmt(value: Any, scale: float, spec: str) -> str:
    width = int(spec.split(".")[0]) if spec[0].isdigit() else 8
    try:
        return format(float(value) * scale, spec)
    except (TypeError, ValueError):
        return "-".rjust(width)
