"""``bonefit skeleton``: joint centres, bone lengths and orientations from a sensor recording."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

from ..errors import InputError
from ..io.sensor_common import UNITS, example_path
from ..io.sniff import FORMATS, resolve_sensor_format
from ..io.tracker import (
    TrackerLayout,
    detect_tracker_layout,
    parse_stations,
    parse_tracker_layout,
)
from ..model import JOINTS
from ..params import check_fps
from ..pipeline import SensorSource, SkeletonOutputs, SkeletonRunOptions, run_skeleton
from ..recording import SensorRecording
from ..results import SkeletonResult
from ..vocabulary import ANTHROPOMETRY_TABLES, OPTIMIZERS, SKELETON_METHODS, TORSO_ESTIMATORS
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


def register(sub: Any, summary: str) -> None:
    """Add the ``skeleton`` command to the sub-parsers."""
    parser: argparse.ArgumentParser = sub.add_parser(
        "skeleton",
        help=summary,
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
    parser.add_argument("--torso", default="llsf", metavar="{llsf,gdke}",
                        help="estimator of the torso joints with --method reduced "
                             "(default: llsf)")
    parser.add_argument("--anthropometry", default="aist", metavar="{aist,winter}|TABLE.json",
                        help="anthropometric table of the reduced method's priors, or a JSON "
                             "file of torso, thigh, shank, upperarm and forearm lengths (or "
                             "ratios) in any one unit (default: aist)")
    parser.add_argument("--w-s", default="0.01", metavar="W",
                        help="weight of the reduced method's length term (eq. 5; default 0.01)")
    parser.add_argument("--w-l", default="0.01", metavar="W",
                        help="weight of the reduced method's ratio term (eq. 5; default 0.01)")
    parser.add_argument("--smooth", action=argparse.BooleanOptionalAction, default=None,
                        help="smooth the joint paths (Savitzky-Golay, 0.1 s; default: only "
                             "with --method auto)")
    parser.add_argument("--offsets", default=None, metavar="CALIBRATION.json",
                        help="place every joint at its offset from an earlier result of the "
                             "same suit (its JSON, -o) instead of fitting: for takes in which "
                             "some joints do not move")
    parser.add_argument("-o", "--output", default=None, metavar="OUT.json",
                        help="write the result as JSON")
    parser.add_argument("--bvh", default=None, metavar="OUT.bvh", help="write a BVH file (cm)")
    parser.add_argument("--bvh-slip-chains", action=argparse.BooleanOptionalAction,
                        default=True,
                        help="in the BVH, put every joint exactly where the JSON has it even "
                             "where its bone length varies (the papers' methods, --offsets): "
                             "three rotation-only slip nodes above such a joint (default; the "
                             "default method's joints lie on a rigid skeleton, so its BVH has "
                             "none); --no-bvh-slip-chains writes the rigid skeleton of mean "
                             "OFFSETs only")
    parser.add_argument("--csv", default=None, metavar="OUT.csv",
                        help="write joint trajectories as CSV (metres)")
    parser.add_argument("--npz", default=None, metavar="OUT.npz",
                        help="write the result as NPZ: the JSON's names, arrays binary at full "
                             "precision (for long takes; numpy reads it)")
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


def _weight(value: str, option: str) -> float:
    try:
        return float(value)
    except ValueError:
        raise InputError(f"{option} must be a number, got {value!r}", field=option) from None


def _anthropometry(value: str) -> str | dict[str, float]:
    """A table name, or a JSON file of lengths (or ratios) by key."""
    key = value.strip().lower()
    if key in ANTHROPOMETRY_TABLES:
        return key
    path = Path(value)
    if not path.is_file():
        raise InputError(f"--anthropometry must be {' or '.join(ANTHROPOMETRY_TABLES)} or a "
                         f"JSON file of lengths, got {value!r}", field="--anthropometry")
    try:
        table = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"--anthropometry {value}: not a JSON object ({exc})",
                         field="--anthropometry") from None
    if not isinstance(table, dict):
        raise InputError(f"--anthropometry {value}: expected a JSON object of lengths by key, "
                         f"got {type(table).__name__}", field="--anthropometry")
    return table


def run(args: argparse.Namespace) -> int:
    """Run ``bonefit skeleton``; returns the exit code (bad input raises InputError)."""
    fmt = _choice(args.format, ["auto", *FORMATS], "--format")
    options = _run_options(args)
    units = _choice(args.units, list(UNITS), "--units") if args.units is not None else None
    fps = _number(args.fps, "--fps", float)
    if fps is not None:
        check_fps(fps, "--fps")
    stations = parse_stations(args.stations) if args.stations is not None else None
    if args.offsets is not None:
        from ..io.skeleton import read_skeleton_offsets  # scipy: only with a calibration

        options = dataclasses.replace(options, offsets=read_skeleton_offsets(args.offsets))
    source = _source_path(args)
    _check_output_dirs(args)

    fmt = resolve_sensor_format(source, fmt)  # detected once, here: the reader is told
    layout = _tracker_layout(source, fmt, args.tracker_layout)

    bar = None if args.quiet else ProgressBar()

    def on_read(recording: SensorRecording) -> None:
        if bar is not None:
            bar.frames = recording.n_frames
        if layout is not None and args.tracker_layout is None:
            print(f"detected: {layout.describe()}", file=sys.stderr)
        if options.i0 >= recording.n_frames:
            raise InputError(f"--i0 {options.i0} is past the last frame "
                             f"({recording.n_frames - 1})", field="--i0")

    outputs = SkeletonOutputs(json=args.output, bvh=args.bvh, csv=args.csv, npz=args.npz,
                              bvh_slip_chains=args.bvh_slip_chains)
    try:
        done = run_skeleton(SensorSource(source, format=fmt, units=units, fps=fps,
                                         stations=stations, tracker_layout=layout),
                            options, outputs, progress=bar, on_read=on_read)
    except OSError as exc:
        raise _write_error(exc, outputs) from None
    finally:
        if bar is not None:
            bar.close()
    if args.output is None:
        print(summary(done.result, done.recording))
    return 0


def _run_options(args: argparse.Namespace) -> SkeletonRunOptions:
    """The estimator's options from the command line (offsets are read separately)."""
    up = UP_AXES.get(args.up.strip().lower())
    if up is None:
        raise InputError(f"--up must be one of {', '.join(UP_AXES)}, got {args.up!r}",
                         field="--up")
    return SkeletonRunOptions(
        method=_choice(args.method, SKELETON_METHODS, "--method"),
        optimizer=_choice(args.optimizer, OPTIMIZERS, "--optimizer"),
        torso=_choice(args.torso, TORSO_ESTIMATORS, "--torso"), up=up,
        i0=_number(args.i0, "--i0", int), anthropometry=_anthropometry(args.anthropometry),
        w_s=_weight(args.w_s, "--w-s"), w_l=_weight(args.w_l, "--w-l"), smooth=args.smooth)


def _source_path(args: argparse.Namespace) -> Path:
    if args.example:
        if args.input is not None:
            raise InputError("give INPUT or --example, not both", field="input")
        return example_path()
    if args.input is None:
        raise InputError("no INPUT recording given (or use --example)", field="input")
    return Path(args.input)


def _check_output_dirs(args: argparse.Namespace) -> None:
    for out in [Path(p) for p in (args.output, args.bvh, args.csv, args.npz) if p is not None]:
        if not out.parent.is_dir():
            raise InputError(f"cannot write {out}: directory {out.parent} does not exist",
                             field="output")


def _write_error(exc: OSError, outputs: SkeletonOutputs) -> Exception:
    """An output that cannot be written is the user's to fix (exit 2); other OS errors
    (the input) go on as they are."""
    written = {str(Path(p)) for p in (outputs.json, outputs.bvh, outputs.csv, outputs.npz)
               if p is not None}
    if exc.filename is None or str(Path(exc.filename)) not in written:
        return exc
    return InputError(f"cannot write {exc.filename}: {exc.strerror}", field="output")


def _tracker_layout(source: Path, fmt: str, spec: str | None) -> TrackerLayout | None:
    """The layout of a tracker input (``fmt``, not ``auto``): ``spec``, or detected (printed
    once the file is read)."""
    if spec is not None:
        return parse_tracker_layout(spec)
    if fmt != "tracker":
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
