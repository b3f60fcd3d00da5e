"""Accuracy of skeleton estimation on sensor recordings simulated from real motion capture.

For every BVH clip under ``<data>/motions`` a rigid 15-segment body is driven by the clip and
virtual sensors are attached (``bonefit.estimation.simulate.sensors``: 3–7 cm off the bone, random
orientation, 2 mm / 0.5° white noise, 5 mm slow slip, 1 % dropped samples). Each method's
joint paths are compared with the exact centres.

Usage::

    .venv/bin/python benchmarks/skeleton_accuracy.py [--data ../shared/data] [--max-frames 1500]

Clips longer than ``--max-frames`` are decimated by an integer stride (same duration, lower
frame rate) to keep the run to a few minutes on two cores. ``--only`` (substring of the clip
name) and ``--runs`` (labels such as ``auto:15,llsf:15``) restrict the run while iterating;
``--seeds 1,2,3,4,5`` prints only the summary statistics for each simulation seed.
``--noise`` changes the simulated noise (``none``, or e.g. ``orientation=0,slip=0,drop=0`` for
the white position noise alone) to tell which noise source an error comes from; the
acceptance verdicts are printed only for the protocol's levels. ``--true-lengths`` gives the
methods that use standard limb lengths (``auto`` with 11 sensors, ``reduced``) the rig's own
instead of the anthropometric table scaled by the torso, to tell how much of their limb error
the table causes (a diagnostic: no verdicts).

Reports, per method and sensor count: the acceptance statistic of the skeleton issue — the
mean error of each joint over the frames of each clip, then the median and 95th percentile
over all (clip, joint) pairs — next to the pooled per-frame median and 95th percentile, the
same for the limb joints (elbows, wrists, knees, ankles), the worst (clip, joint) pairs, the
joints flagged ``"prior"`` (rotating less than 2°), refusals, and a PASS/FAIL line per
acceptance criterion (15 sensors: every clip estimated, median <= 10 mm, p95 <= 25 mm;
11 sensors: limb median <= 25 mm and at least 30 % below the paper's method).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bonefit.estimation.bvh import BvhMotion, read_bvh  # noqa: E402
from bonefit.estimation.errors import BonefitError  # noqa: E402
from bonefit.estimation.limbs import torso_length  # noqa: E402
from bonefit.estimation.model import JOINTS  # noqa: E402
from bonefit.estimation.recording import SensorRecording  # noqa: E402
from bonefit.estimation.simulate.sensors import (  # noqa: E402
    HingeRig,
    SimulationTruth,
    simulate_sensors,
)
from bonefit.estimation.skeleton import estimate_skeleton  # noqa: E402

# folder -> (metres per unit, fps override per clip-name prefix)
DATASETS = {
    "cmu_bvh11": (0.05644, {}),
    "cmu_fairmotion": (0.05644, {}),
    "cmu_acrnn": (0.01, {"salsa": 60.0}),
    "bandai_namco": (0.01, {}),
}
LIMB_JOINTS = ("l_elbow", "r_elbow", "l_wrist", "r_wrist", "l_knee", "r_knee",
               "l_ankle", "r_ankle")
HINGE_JOINTS = ("l_elbow", "r_elbow", "l_knee", "r_knee")
# (label, n_sensors, estimate_skeleton kwargs)
RUNS = [
    ("llsf", 15, {"method": "llsf"}),
    ("gdke", 15, {"method": "gdke"}),
    ("reduced-nm", 15, {"method": "reduced", "optimizer": "nelder-mead"}),
    ("auto", 15, {"method": "auto"}),
    ("reduced-nm", 11, {"method": "reduced", "optimizer": "nelder-mead"}),
    ("auto", 11, {"method": "auto"}),
]
# the evaluation protocol's noise (docs/benchmarks.md): white position noise (mm), white orientation
# noise (degrees per axis), slow soft-tissue slip (mm RMS), share of dropped samples
PROTOCOL_NOISE = {"position": 2.0, "orientation": 0.5, "slip": 5.0, "drop": 0.01}
# acceptance of the skeleton issue, on the per-(clip, joint) mean errors (mm)
MAX_FRAMES = 1500
MEDIAN_15_MM = 10.0
P95_15_MM = 25.0
LIMB_MEDIAN_11_MM = 25.0
LIMB_GAIN_11 = 0.30
SD_BINS_MM = ((0.0, 5.0), (5.0, 10.0), (10.0, 15.0), (15.0, 25.0), (25.0, 50.0),
              (50.0, math.inf))
# issue 20: realistic rigs (knees, elbows off the line), do no harm where the data are good,
# calibrated uncertainty
REALISTIC_MEDIAN_15_MM = 6.0
REALISTIC_HINGE_15_MM = 10.0
REALISTIC_LIMB_11_MM = 20.0
GOOD_DATA_SD_MM = 2.0  # data_sd_m at or below: the recording alone locates the joint
NO_HARM_MM = 0.5  # the default may be at most this much worse than llsf there
CALIBRATION_K = 3.0  # a "data" joint's error should be below K · data_sd_m + 5 mm
CALIBRATION_FLOOR_MM = 5.0
CALIBRATION_SHARE = 0.95
LOW_NOISE = {"position": 1.0, "orientation": 0.3, "slip": 0.0, "drop": 0.01}


def clips(data: Path) -> list[tuple[str, Path, float, float | None]]:
    out = []
    for folder, (units, fps_override) in DATASETS.items():
        for path in sorted((data / "motions" / folder).rglob("*.bvh")):
            rel = path.relative_to(data / "motions" / folder)
            fps = next((f for prefix, f in fps_override.items()
                        if str(rel).startswith(prefix)), None)
            out.append((f"{folder}/{rel.with_suffix('')}", path, units, fps))
    return out


def thinned(path: Path, fps: float | None, max_frames: int = MAX_FRAMES
            ) -> tuple[BvhMotion, float]:
    """A clip and its frame rate (``fps`` or the file's), every k-th frame kept so that at
    most ``max_frames`` remain (same duration, lower rate)."""
    motion = read_bvh(path)
    rate = fps if fps is not None else motion.fps
    stride = max(1, math.ceil(motion.n_frames / max_frames))
    if stride > 1:
        motion = motion.with_values(motion.values[::stride])
        rate = rate / stride
    return motion, rate


def parse_noise(text: str) -> dict[str, float]:
    """``--noise``: ``none`` (a noise-free simulation) or ``key=value`` pairs overriding the
    protocol's levels, e.g. ``position=2,orientation=0,slip=0,drop=0``."""
    if text.strip() == "none":
        return dict.fromkeys(PROTOCOL_NOISE, 0.0)
    noise = dict(PROTOCOL_NOISE)
    for item in filter(None, text.split(",")):
        key, sep, value = item.partition("=")
        if key not in noise or not sep:
            raise argparse.ArgumentTypeError(
                f"{item!r}: use none or key=value with key one of {', '.join(noise)}")
        try:
            level = float(value)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{item!r}: {value!r} is not a number") from None
        if not (math.isfinite(level) and level >= 0.0):
            raise argparse.ArgumentTypeError(f"{item!r}: a level is a number >= 0")
        noise[key] = level
    return noise


def simulation_noise(noise: dict[str, float]) -> dict[str, float]:
    """``simulate_sensors`` keyword arguments for ``--noise`` levels."""
    return {"position_noise_m": noise["position"] / 1000.0,
            "orientation_noise_deg": noise["orientation"], "slip_m": noise["slip"] / 1000.0,
            "drop_fraction": noise["drop"]}


def summarise(per_joint: dict[str, list[np.ndarray]], clips_done: int,
              seconds: float) -> dict[str, float]:
    """Pooled per-frame and per-(clip, joint) mean statistics of one run, mm."""
    pooled = np.concatenate([e for per in per_joint.values() for e in per])
    limbs = np.concatenate([e for j in LIMB_JOINTS for e in per_joint[j]])
    cj = [float(e.mean()) for per in per_joint.values() for e in per]
    limb_cj = [float(e.mean()) for j in LIMB_JOINTS for e in per_joint[j]]
    hinge_cj = [float(e.mean()) for j in HINGE_JOINTS for e in per_joint[j]]
    return {"clips": clips_done, "median": float(np.median(pooled)),
            "p95": float(np.percentile(pooled, 95)), "limb_median": float(np.median(limbs)),
            "clip_joint_median": float(np.median(cj)),
            "clip_joint_p95": float(np.percentile(cj, 95)),
            "limb_clip_joint_median": float(np.median(limb_cj)),
            "limb_clip_joint_p95": float(np.percentile(limb_cj, 95)),
            "hinge_clip_joint_median": float(np.median(hinge_cj)), "seconds": seconds}


def no_harm(labels: dict[str, dict[tuple[str, str], Label]], n: int, *, shared: bool = False
            ) -> tuple[int, float, float, int, list[tuple[float, float, str, str]]] | None:
    """Issue 20 §2 on the (clip, joint) pairs the recording alone locates well
    (``auto``'s ``data_sd_m`` <= 2 mm; ``shared``: its ``shared_sd_m``, data_sd_m's
    definition before issue 20): their count, the median error of ``auto`` and ``llsf``,
    how many of them ``auto`` loses by more than 0.5 mm, and those (auto, llsf, clip,
    joint), worst first. None without both runs."""
    auto, llsf = labels.get(f"auto:{n}"), labels.get(f"llsf:{n}")
    if auto is None or llsf is None:
        return None
    good = [(lab.error_mm, llsf[k].error_mm, *k) for k, lab in auto.items()
            if (lab.shared_sd_mm if shared else lab.sd_mm) <= GOOD_DATA_SD_MM and k in llsf]
    if not good:
        return 0, math.nan, math.nan, 0, []
    a, b = np.array([g[:2] for g in good]).T
    worse = sorted((g for g in good if g[0] > g[1] + NO_HARM_MM),
                   key=lambda g: g[1] - g[0])
    return len(good), float(np.median(a)), float(np.median(b)), len(worse), worse


def calibration(labels: dict[tuple[str, str], Label]
                ) -> tuple[int, float, list[tuple[float, float, str, str]]]:
    """Issue 20 §4: of the pairs labelled ``"data"`` that carry ``data_sd_m``, how many,
    the share whose error is below 3 · data_sd_m + 5 mm, and the others (error, sd, clip,
    joint), worst first."""
    data = [(lab.error_mm, lab.sd_mm, *k) for k, lab in labels.items()
            if lab.reliability == "data" and math.isfinite(lab.sd_mm)]
    if not data:
        return 0, math.nan, []
    bad = sorted((d for d in data if d[0] >= CALIBRATION_K * d[1] + CALIBRATION_FLOOR_MM),
                 reverse=True)
    return len(data), 1.0 - len(bad) / len(data), bad


def acceptance(summary: dict[str, dict[str, float]], refused: dict[str, list[str]],
               n_total: int) -> list[tuple[str, bool]]:
    """The issue's accuracy criteria as (description, passed) lines."""
    out: list[tuple[str, bool]] = []
    if "auto:15" in summary:
        s = summary["auto:15"]
        n = int(s["clips"])
        out.append((f"auto:15 estimates every clip ({n} of {n_total}, "
                    f"{len(refused.get('auto:15', []))} refused)", n == n_total))
        out.append((f"auto:15 clip-joint median {s['clip_joint_median']:.1f} mm <= "
                    f"{MEDIAN_15_MM:g} (pooled per-frame: {s['median']:.1f})",
                    s["clip_joint_median"] <= MEDIAN_15_MM))
        out.append((f"auto:15 clip-joint p95 {s['clip_joint_p95']:.1f} mm <= {P95_15_MM:g} "
                    f"(pooled per-frame: {s['p95']:.1f})", s["clip_joint_p95"] <= P95_15_MM))
    if "auto:11" in summary and "reduced-nm:11" in summary:
        a = summary["auto:11"]["limb_clip_joint_median"]
        p = summary["reduced-nm:11"]["limb_clip_joint_median"]
        n = int(summary["auto:11"]["clips"])
        out.append((f"auto:11 estimates every clip ({n} of {n_total})", n == n_total))
        out.append((f"auto:11 limb clip-joint median {a:.1f} mm <= {LIMB_MEDIAN_11_MM:g}",
                    a <= LIMB_MEDIAN_11_MM))
        out.append((f"auto:11 limb clip-joint median / paper's method (reduced-nm:11, "
                    f"{p:.1f} mm) = {a / p:.2f} <= {1 - LIMB_GAIN_11:.2f} "
                    f"({100 * (1 - a / p):.0f} % lower)", a / p <= 1 - LIMB_GAIN_11))
    return out


class Evaluation(NamedTuple):
    """Per-frame errors and bookkeeping of one pass over the clips (one simulation seed)."""

    errors: dict[str, dict[str, list[np.ndarray]]]  # run -> joint -> per-clip errors, mm
    n_clips: dict[str, int]
    seconds: dict[str, float]
    failures: list[str]
    refused: dict[str, list[str]]
    priors: list[str]
    pairs: dict[str, list[tuple[float, str, str]]]  # run -> (mean error mm, clip, joint)
    n_total: int
    # run -> (mean error mm, quality data_sd_m in mm) of the pairs that carry it
    data_sd: dict[str, list[tuple[float, float]]]
    # run -> (clip, joint) -> (mean error mm, data_sd_m in mm or nan, reliability,
    # shared_sd_m in mm or nan: the shared slip model's part of data_sd_m, which is all
    # data_sd_m was before issue 20)
    labels: dict[str, dict[tuple[str, str], Label]]


class Label(NamedTuple):
    """One (clip, joint) of one run: its mean error and what the result says of it."""

    error_mm: float
    sd_mm: float  # quality["data_sd_m"], nan where absent
    reliability: str
    shared_sd_mm: float  # quality["shared_sd_m"] (before issue 20: data_sd_m), nan if absent


def joint_label(mean_mm: float, q: dict[str, Any]) -> Label:
    """The ``Label`` of a joint with mean error ``mean_mm`` and quality ``q``."""
    sd_mm = 1000.0 * float(q.get("data_sd_m", math.nan))
    shared_mm = 1000.0 * float(q.get("shared_sd_m", q.get("data_sd_m", math.nan)))
    return Label(mean_mm, sd_mm, str(q.get("reliability", "")), shared_mm)


class Variant(NamedTuple):
    """What is simulated: the noise levels and the rig (None: the BVH's own hinges); with
    ``true_lengths`` the methods that use standard limb lengths (``auto`` for 11 sensors,
    ``reduced``) get the rig's own instead of the scaled anthropometric table: how much of
    their error is the table's."""

    noise: dict[str, float]
    realistic: bool = False
    true_lengths: bool = False

    def options(self, kwargs: dict[str, str], truth: SimulationTruth) -> dict[str, Any]:
        """``estimate_skeleton``'s keywords of a run on the recording of ``truth``."""
        if not (self.true_lengths and kwargs["method"] in ("auto", "reduced")):
            return dict(kwargs)
        t = truth.joints
        table = {"torso": torso_length(t["waist"], t["l_hip"], t["r_hip"], t["chest"])}
        for key in ("thigh", "shank", "upperarm", "forearm"):
            table[key] = 0.5 * (truth.bone_lengths[f"l_{key}"] + truth.bone_lengths[f"r_{key}"])
        return {**kwargs, "anthropometry": table}

    def simulate(self, motion: BvhMotion, units: float, n: int, rate: float, seed: int
                 ) -> tuple[SensorRecording, SimulationTruth]:
        """The recording and truth of one clip with ``n`` sensors and ``seed``."""
        rig = HingeRig(seed=seed) if self.realistic else None
        return simulate_sensors(motion, units_m=units, n_sensors=n, fps=rate, seed=seed,
                                rig=rig, **simulation_noise(self.noise))


def evaluate(data: Path, runs: list[tuple[str, int, dict[str, str]]], *, seed: int,  # noqa: C901
             max_frames: int, only: str, verbose: bool,
             variant: Variant | None = None) -> Evaluation:
    """Simulate every clip with ``seed`` (and ``variant``, by default the protocol's noise
    on the BVH rigs) and run every method on it."""
    variant = Variant(PROTOCOL_NOISE) if variant is None else variant
    errors: dict[str, dict[str, list[np.ndarray]]] = {}
    n_clips: dict[str, int] = {}
    seconds: dict[str, float] = {}
    failures: list[str] = []
    refused: dict[str, list[str]] = {}
    priors: list[str] = []
    pairs: dict[str, list[tuple[float, str, str]]] = {}
    data_sd: dict[str, list[tuple[float, float]]] = {}
    labels: dict[str, dict[tuple[str, str], Label]] = {}
    n_total = 0
    for name, path, units, fps in clips(data):
        if only and only not in name:
            continue
        n_total += 1
        motion, rate = thinned(path, fps, max_frames)
        line = [f"{name:50s} {motion.n_frames:5d} fr {rate:5.1f} fps"]
        for n in sorted({r[1] for r in runs}, reverse=True):
            rec, truth = variant.simulate(motion, units, n, rate, seed)
            for label, n_sensors, kwargs in runs:
                if n_sensors != n:
                    continue
                key = f"{label}:{n}"
                t0 = time.perf_counter()
                try:
                    result = estimate_skeleton(rec, **variant.options(kwargs, truth))
                except BonefitError as exc:
                    failures.append(f"{key} {name}: {exc.detail}")
                    refused.setdefault(key, []).append(name)
                    line.append(f"{key}=REFUSED")
                    continue
                spent = time.perf_counter() - t0
                seconds[key] = seconds.get(key, 0.0) + spent
                flagged = [j for j in JOINTS if result.quality[j].get("reliability") == "prior"]
                if flagged:
                    priors.append(f"{key} {name}: {', '.join(flagged)}")
                n_clips[key] = n_clips.get(key, 0) + 1
                per = errors.setdefault(key, {})
                means = []
                for joint in JOINTS:
                    e = np.linalg.norm(result.joints[joint] - truth.joints[joint], axis=1)
                    mean_mm = float(e.mean() * 1000.0)
                    per.setdefault(joint, []).append(e * 1000.0)
                    means.append(mean_mm)
                    pairs.setdefault(key, []).append((mean_mm, name, joint))
                    lab = joint_label(mean_mm, result.quality[joint])
                    labels.setdefault(key, {})[(name, joint)] = lab
                    if math.isfinite(lab.sd_mm):
                        data_sd.setdefault(key, []).append((mean_mm, lab.sd_mm))
                line.append(f"{key}={np.median(means):.1f}/{np.max(means):.0f}")
        if verbose:
            print("  ".join(line), flush=True)
    return Evaluation(errors, n_clips, seconds, failures, refused, priors, pairs, n_total,
                      data_sd, labels)


def seed_table(data: Path, runs: list[tuple[str, int, dict[str, str]]], seeds: list[int], *,
               max_frames: int, only: str, variant: Variant) -> list[dict[str, Any]]:
    """The acceptance statistics of every run for each simulation seed: how much of a
    figure is the particular draw of sensor placement, noise, slip and rig. Returns the
    printed figures, one dict per (seed, run) and per (seed, sensors) for §2."""
    rows: list[dict[str, Any]] = []
    print(f"{'seed':>4s}  {'method:sensors':16s}{'clip-joint median':>18s}{'p95':>7s}"
          f"{'pairs > 25 mm':>15s}{'limb median':>12s}{'limb p95':>9s}{'hinge median':>13s}"
          f"{'pooled p95':>11s}{'calibrated (n)':>18s}")
    for seed in seeds:
        ev = evaluate(data, runs, seed=seed, max_frames=max_frames, only=only, verbose=False,
                      variant=variant)
        for key, per in ev.errors.items():
            s = summarise(per, ev.n_clips[key], ev.seconds[key])
            over = sum(e > P95_15_MM for e, _, _ in ev.pairs[key])
            n_cal, share, _ = calibration(ev.labels[key])
            cal = f"{100 * share:.1f} % ({n_cal})" if n_cal else "-"
            rows.append({"seed": seed, "run": key, **s, "pairs_over_25": over,
                         "calibration_n": n_cal, "calibration_share": share})
            print(f"{seed:4d}  {key:16s}{s['clip_joint_median']:18.1f}{s['clip_joint_p95']:7.1f}"
                  f"{over:15d}{s['limb_clip_joint_median']:12.1f}{s['limb_clip_joint_p95']:9.1f}"
                  f"{s['hinge_clip_joint_median']:13.1f}{s['p95']:11.1f}{cal:>18s}", flush=True)
        for n in (15, 11):
            for shared, name in ((False, "data_sd_m"), (True, "shared_sd_m")):
                harm = no_harm(ev.labels, n, shared=shared)
                if harm is not None:
                    rows.append({"seed": seed, "no_harm": n, "sd": name, "pairs": harm[0],
                                 "auto_median": harm[1], "llsf_median": harm[2],
                                 "violations": harm[3], "worst": harm[4][:10]})
                    print(f"{seed:4d}  no harm, {n} sensors: {harm[0]} pairs with {name} <= "
                          f"{GOOD_DATA_SD_MM:g} mm, median auto {harm[1]:.2f} / llsf "
                          f"{harm[2]:.2f} mm, auto worse by > {NO_HARM_MM:g} mm on {harm[3]}",
                          flush=True)
    return rows


def print_realistic(summary: dict[str, dict[str, float]]) -> None:
    """Issue 20 §3's acceptance on the realistic rigs."""
    print("\nRealistic rigs (issue 20 §3)")
    if "auto:15" in summary:
        s = summary["auto:15"]
        for text, value, bound in (
                ("auto:15 clip-joint median", s["clip_joint_median"], REALISTIC_MEDIAN_15_MM),
                ("auto:15 hinge clip-joint median", s["hinge_clip_joint_median"],
                 REALISTIC_HINGE_15_MM)):
            verdict = "PASS" if value <= bound else "FAIL"
            print(f"  {verdict}  {text} {value:.1f} mm <= {bound:g}")
    if "auto:11" in summary:
        value = summary["auto:11"]["limb_clip_joint_median"]
        print(f"  {'PASS' if value <= REALISTIC_LIMB_11_MM else 'FAIL'}  auto:11 limb "
              f"clip-joint median {value:.1f} mm <= {REALISTIC_LIMB_11_MM:g}")


def print_checks(ev: Evaluation, summary: dict[str, dict[str, float]], variant: Variant) -> None:
    """Issue 20's figures of one evaluation: the realistic-rig statistics, do no harm where
    the data are good, and the calibration of the "data" label."""
    if variant.realistic and variant.noise == PROTOCOL_NOISE and not variant.true_lengths:
        print_realistic(summary)
    for n, shared in ((15, False), (15, True), (11, False)):
        harm = no_harm(ev.labels, n, shared=shared)
        if harm is None:
            continue
        name = "shared_sd_m" if shared else "data_sd_m"
        print(f"\nDo no harm (issue 20 §2), {n} sensors: {harm[0]} (clip, joint) pairs with "
              f"{name} <= {GOOD_DATA_SD_MM:g} mm; median auto {harm[1]:.2f} mm, llsf "
              f"{harm[2]:.2f} mm; auto worse by more than {NO_HARM_MM:g} mm on {harm[3]}")
        for a, b, clip, joint in harm[4][:10]:
            print(f"  {a:6.1f} vs {b:6.1f}  {clip:50s} {joint}")
    for key, found in ev.labels.items():
        n_cal, share, bad = calibration(found)
        if not n_cal:
            continue
        verdict = "PASS" if share >= CALIBRATION_SHARE else "FAIL"
        print(f"\nCalibration (issue 20 §4), {key}: {n_cal} pairs labelled \"data\"; "
              f"{100 * share:.1f} % with error < {CALIBRATION_K:g} x data_sd_m + "
              f"{CALIBRATION_FLOOR_MM:g} mm ({verdict}: target >= {100 * CALIBRATION_SHARE:g} %)")
        for e, sd, clip, joint in bad[:8]:
            print(f"  {e:6.1f} mm, data_sd_m {sd:5.1f} mm  {clip:50s} {joint}")


def print_worst(pairs: dict[str, list[tuple[float, str, str]]], priors: list[str]) -> None:
    """The worst (clip, joint) pairs of auto:15 and the joints flagged "prior"."""
    if "auto:15" in pairs:
        print("\nWorst (clip, joint) mean errors of auto:15 (mm)")
        for err, clip, joint in sorted(pairs["auto:15"], reverse=True)[:12]:
            print(f"  {err:6.1f}  {clip:50s} {joint}")
    for item in priors:
        print("  flagged \"prior\" (rotates < 2°; auto uses its priors there):", item)


def print_sd_bins(data_sd: dict[str, list[tuple[float, float]]]) -> None:
    """The (clip, joint) pairs of each run by their ``data_sd_m``."""
    for key, found in data_sd.items():
        print(f"\n{key}: (clip, joint) pairs by quality[joint][\"data_sd_m\"] (how well the "
              "recording alone locates the joint)")
        print(f"{'data_sd_m (mm)':>16s}{'pairs':>7s}{'median error':>14s}"
              f"{f'above {P95_15_MM:g} mm':>13s}")
        err, sd = np.array(found).T
        for lo, hi in SD_BINS_MM:
            inside = (sd >= lo) & (sd < hi)
            if inside.any():
                print(f"{f'{lo:g}–{hi:g}':>16s}{inside.sum():7d}{np.median(err[inside]):14.1f}"
                      f"{np.sum(err[inside] > P95_15_MM):13d}")


def run_seeds(args: argparse.Namespace, runs: list[tuple[str, int, dict[str, str]]],
              variant: Variant) -> int:
    """``--seeds``: the per-seed table, and its figures as ``--json``."""
    rows = seed_table(args.data, runs, [int(x) for x in args.seeds.split(",")],
                      max_frames=args.max_frames, only=args.only, variant=variant)
    if args.json:
        args.json.write_text(json.dumps({"noise": args.noise, "rig": args.rig,
                                         "true_lengths": args.true_lengths,
                                         "max_frames": args.max_frames, "rows": rows},
                                        indent=1))
    return 0


def main(argv: list[str] | None = None) -> int:  # noqa: C901
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--max-frames", type=int, default=MAX_FRAMES)
    parser.add_argument("--only", default="", help="substring filter on clip names")
    parser.add_argument("--runs", default="", help="comma-separated labels like auto:15")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--seeds", default="",
                        help="comma-separated seeds: only the summary statistics per seed")
    parser.add_argument("--json", type=Path, help="write the raw numbers here")
    parser.add_argument("--rig", choices=("bvh", "realistic"), default="bvh",
                        help="realistic: knees and elbows 5-15 mm off their neighbours' line "
                             "with an axial rotation coupled to flexion (HingeRig)")
    parser.add_argument("--true-lengths", action="store_true",
                        help="give auto (11 sensors) and reduced the rig's own limb lengths "
                             "instead of the anthropometric table scaled by the torso: how "
                             "much of the 11-sensor limb error is the table's")
    parser.add_argument("--low-noise", action="store_true",
                        help="1 mm, 0.3 degrees, no slip (issue 20 §2; overrides --noise)")
    parser.add_argument("--noise", type=parse_noise, default=dict(PROTOCOL_NOISE),
                        help="none, or levels overriding the protocol's "
                             "(position=2,orientation=0.5,slip=5,drop=0.01: mm, degrees, mm, "
                             "share); no acceptance verdicts unless they are the protocol's")
    args = parser.parse_args(argv)
    if args.low_noise:
        args.noise = dict(LOW_NOISE)
    variant = Variant(args.noise, args.rig == "realistic", args.true_lengths)
    protocol = args.noise == PROTOCOL_NOISE and not (variant.realistic or args.true_lengths)
    print("noise: " + ", ".join(f"{k} {v:g}" for k, v in args.noise.items())
          + ("" if args.noise == PROTOCOL_NOISE else " (not the evaluation protocol's)")
          + f"; rig: {args.rig}" + ("; the rig's own limb lengths (no verdicts)"
                                    if args.true_lengths else ""))
    if not (args.data / "motions").is_dir():
        print(f"no motions under {args.data}", file=sys.stderr)
        return 2
    runs = RUNS
    if args.runs:
        wanted = set(args.runs.split(","))
        runs = [r for r in RUNS if f"{r[0]}:{r[1]}" in wanted]
    if args.seeds:
        return run_seeds(args, runs, variant)
    ev = evaluate(args.data, runs, seed=args.seed, max_frames=args.max_frames, only=args.only,
                  verbose=True, variant=variant)
    errors, n_clips, seconds, failures, refused, priors, pairs, n_total, data_sd, _ = ev

    keys = [f"{label}:{n}" for label, n, _ in runs if f"{label}:{n}" in errors]
    print("\nMean error per joint (mm), averaged over clips")
    print(f"{'joint':12s}" + "".join(f"{k:>15s}" for k in keys))
    for joint in JOINTS:
        print(f"{joint:12s}" + "".join(
            f"{np.mean([e.mean() for e in errors[k][joint]]):15.1f}" for k in keys))
    summary = {k: summarise(errors[k], n_clips[k], seconds[k]) for k in keys}
    print(f"\nSummary (mm). 'clip-joint': the mean error of each joint over the frames of each"
          f" clip, then the\nmedian / 95th percentile over all (clip, joint) pairs (the acceptance"
          f" statistic); 'pooled': every\nframe of every joint of every clip; 'limb': elbows,"
          f" wrists, knees, ankles. {n_total} clips.")
    print(f"{'method:sensors':16s}{'clips':>6s}{'clip-joint median':>18s}{'p95':>7s}"
          f"{'pooled median':>15s}{'p95':>7s}{'limb clip-joint median':>24s}"
          f"{'limb pooled median':>20s}{'hinge clip-joint median':>25s}{'time s':>8s}")
    for k in keys:
        s = summary[k]
        print(f"{k:16s}{s['clips']:6d}{s['clip_joint_median']:18.1f}{s['clip_joint_p95']:7.1f}"
              f"{s['median']:15.1f}{s['p95']:7.1f}{s['limb_clip_joint_median']:24.1f}"
              f"{s['limb_median']:20.1f}{s['hinge_clip_joint_median']:25.1f}"
              f"{s['seconds']:8.1f}")
    print_worst(pairs, priors)
    print_sd_bins(data_sd)
    print_checks(ev, summary, variant)
    for f in failures:
        print("  refused:", f)
    verdicts = acceptance(summary, refused, n_total) if protocol else []
    if protocol:
        print("\nAcceptance (skeleton issue), per-(clip, joint) mean errors over all clips")
        for text, ok in verdicts:
            print(f"  {'PASS' if ok else 'FAIL'}  {text}")
        print(f"  overall: {'PASS' if verdicts and all(ok for _, ok in verdicts) else 'FAIL'}")
    else:
        print("\nNo acceptance verdicts: the acceptance criteria hold for the protocol's noise "
              "and the BVH rigs.")
    if args.json:
        args.json.write_text(json.dumps({"summary": summary, "per_joint": {
            k: {j: float(np.mean([e.mean() for e in errors[k][j]])) for j in JOINTS}
            for k in keys}, "clip_joint": pairs, "failures": failures,
            "acceptance": verdicts, "noise": args.noise}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
