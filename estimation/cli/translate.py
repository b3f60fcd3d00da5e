"""``bonefit translate``: root path of an inertial-suit recording."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import InputError
from ..vocabulary import KINEMATICS_FORMATS, TRANSLATION_METHODS
from .progress import ProgressBar

if TYPE_CHECKING:
    from ..kinematics import KinematicsRecording

EXAMPLES = """\
examples:
  bonefit translate heian_shodan.csv -o heian_translated.csv --json heian.json
  bonefit translate kata.csv --method hachaj2018 -o kata_paper.csv
  bonefit translate walk.bvh --accelerations walk_feet.csv -o walk_translated.bvh
  bonefit translate 131_01.bvh --accelerations feet.csv --units cmu -o 131_translated.bvh
  bonefit translate take.bvh --accelerations feet.csv --left-foot "Bip01 L Foot" \\
      --right-foot "Bip01 R Foot" --acceleration-units g -o take_translated.bvh
  bonefit translate take.mvnx -o take_translated.mvnx --bvh take.bvh

OUT is written in the input's own format (a kinematics CSV keeps every column and its
order, with corrected positions); --bvh adds a BVH with the root path, --json the root path,
per-frame contacts and quality figures. The feet (by name or, in a BVH, by topology) and the
length unit (from the legs' length) are found without flags and printed; --left-foot,
--right-foot and --units override them. Bad input exits with code 2 and a one-line reason.
"""


def register(sub: Any, summary: str) -> None:
    """Add the ``translate`` command to the sub-parsers."""
    parser: argparse.ArgumentParser = sub.add_parser(
        "translate",
        help=summary,
        description="Estimate the root path (translation) of an inertial motion-capture "
                    "recording from its kinematics and foot accelerometers.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("input", metavar="INPUT",
                        help="kinematics CSV, BVH (with --accelerations) or MVNX file")
    parser.add_argument("--accelerations", metavar="FILE",
                        help="foot accelerations CSV (time,<Foot>.ax,...) for a BVH input")
    parser.add_argument("--acceleration-units", metavar="UNITS", default=None,
                        help="g, m/s2, free-g, free-m/s2 or second-differences "
                             "(default: g, checked against the data)")
    parser.add_argument("--format", default="auto",
                        choices=("auto", *KINEMATICS_FORMATS),
                        help="input format (default: from the file's content)")
    parser.add_argument("--method", default="contact", choices=TRANSLATION_METHODS,
                        help="contact (default): stance model; hachaj2018: the paper's "
                             "method exactly")
    parser.add_argument("--left-foot", default=None, metavar="NAME",
                        help="left foot joint (default: found by name, e.g. LeftFoot, "
                             "LeftAnkle, Foot_L, or by the hierarchy's legs)")
    parser.add_argument("--right-foot", default=None, metavar="NAME",
                        help="right foot joint (default: found like the left one)")
    parser.add_argument("--units", default="auto", metavar="UNIT",
                        help="length unit of a BVH or kinematics CSV: auto (default, from the "
                             "legs' length), m, cm, mm, in, ft, cmu (CMU's 0.05644 m) or "
                             "metres per unit")
    parser.add_argument("--subject", default=None, metavar="LABEL|N",
                        help="MVNX subject to read, by label or 1-based number (default: "
                             "the first, with a warning when there are several)")
    parser.add_argument("-o", "--output", required=True, metavar="OUT",
                        help="output in the input's format")
    parser.add_argument("--bvh", metavar="OUT.bvh", help="also write a BVH with the root path")
    parser.add_argument("--json", metavar="OUT.json",
                        help="also write root path, contacts and quality as JSON")
    parser.add_argument("--npz", metavar="OUT.npz",
                        help="also write the JSON's content as NPZ (arrays binary, full "
                             "precision)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Execute ``bonefit translate``; returns the exit code."""
    from ..pipeline import SAME_AS_INPUT, KinematicsSource, TranslationRunOptions, run_translation

    if not Path(args.input).is_file():
        raise InputError(f"no such file: {args.input}", field="input")
    outputs = [(SAME_AS_INPUT, args.output)]
    if args.bvh:
        outputs.append(("bvh", args.bvh))
    if args.json:
        outputs.append(("json", args.json))
    if args.npz:
        outputs.append(("npz", args.npz))
    bar = None if args.quiet else ProgressBar(sys.stderr)
    try:
        done = run_translation(
            KinematicsSource(args.input, format=args.format, accelerations=args.accelerations,
                             left_foot=args.left_foot, right_foot=args.right_foot,
                             acceleration_units=args.acceleration_units, units=args.units,
                             subject=args.subject),
            TranslationRunOptions(args.method), outputs, progress=bar, on_read=_notes(bar))
    finally:
        if bar is not None:
            bar.close()
    result = done.result
    q = result.quality
    print(f"{args.method}: {result.n_frames} frames, path {q['path_length_m']:.2f} m, "
          f"closure {q['closure_cm']:.1f} cm, foot skate {q['foot_skate_cm_s']:.1f} cm/s, "
          f"floor penetration {q['floor_penetration_cm']:.1f} cm "
          f"(read {result.timings['read_s']:.2f} s, "
          f"estimate {result.timings.get('estimate_s', 0.0):.2f} s)", file=sys.stderr)
    return 0


def _notes(bar: ProgressBar | None) -> Callable[[KinematicsRecording], None]:
    """The ``on_read`` of a run: the take's length to the bar, then :func:`_print_notes`."""

    def on_read(recording: KinematicsRecording) -> None:
        if bar is not None:
            bar.frames = recording.n_frames
        _print_notes(recording)

    return on_read


def _print_notes(recording: KinematicsRecording) -> None:
    """What the reader found or assumed (feet, units), on stderr."""
    for note in recording.notes:
        print(note if note.startswith("warning:") else f"bonefit: {note}", file=sys.stderr)
