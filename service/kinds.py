"""Job kinds: per kind, a params model and a run function that calls ``estimation``."""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, PositiveFloat

from estimation.progress import Progress, scaled

SENSOR_FORMATS = {"sensor-csv": "csv", "tracker": "tracker", "npz": "npz"}
"""API format name → ``estimation.io.sensors`` format name."""
KINEMATICS_FORMATS = {"kinematics-csv": "kinematics-csv", "bvh": "bvh", "mvnx": "mvnx"}
"""API format name → ``estimation.io.kinematics`` format name."""


@dataclass(frozen=True)
class Input:
    """A recording handed to a run function: a local path and its API format name."""

    path: Path
    format: str


NUMERICAL_MODULES = ("estimation.skeleton", "estimation.translation", "estimation.io.sensors",
                     "estimation.io.skeleton", "estimation.io.kinematics")
"""What the run functions import: the API process never needs them (nor scipy)."""


def preload() -> None:
    """Import the estimation code the kinds run, so that a worker's first job does not wait
    for numpy and scipy to load (~0.5 s)."""
    for name in NUMERICAL_MODULES:
        importlib.import_module(name)


Runner = Callable[[Mapping[str, Input], Any, Progress, Path], dict[str, Path]]
"""``run(inputs, params, progress, outdir) -> {result format: file}``; inputs["recording"]."""


class JointOffsetIn(BaseModel):
    """Where a joint sits in one sensor's frame (an entry of a skeleton result's
    ``offsets``)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    sensor: str = Field(min_length=1, max_length=100)
    local: tuple[float, float, float] = Field(description="Metres, in the sensor's frame.")


class SkeletonParams(BaseModel):
    """Parameters of a skeleton job (magnetic 6-DOF trackers)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    method: Literal["auto", "llsf", "gdke", "reduced"] = "auto"
    optimizer: Literal["least-squares", "nelder-mead"] = "least-squares"
    torso: Literal["llsf", "gdke"] = "llsf"
    anthropometry: Literal["aist", "winter"] | dict[str, float] = "aist"
    w_s: float = Field(0.01, ge=0)
    w_l: float = Field(0.01, ge=0)
    smooth: bool | None = None
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    i0: int = Field(0, ge=0, description="Calibration frame of hands, feet and head.")
    units: Literal["m", "cm", "mm", "in"] | None = None
    fps: float | None = Field(None, gt=0)
    stations: dict[str, str] | None = Field(None, description="Tracker station → segment.")
    offsets: dict[str, JointOffsetIn] | None = Field(
        None, max_length=64,
        description="A calibration: the `offsets` of an earlier skeleton result of the same "
                    "suit. Every joint is placed at its offset instead of being fitted "
                    "(method and fit options are then ignored).")


class TranslationParams(BaseModel):
    """Parameters of a translation job (inertial suits)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    method: Literal["contact", "hachaj2018"] = "contact"
    left_foot: str | None = Field(None, min_length=1, max_length=100,
                                  description="Default: found by name or topology.")
    right_foot: str | None = Field(None, min_length=1, max_length=100)
    units: Literal["auto", "m", "cm", "mm", "in", "ft", "cmu"] | PositiveFloat = Field(
        "auto", description="Length unit of a BVH or kinematics CSV: auto (from the legs' "
                            "length), a name, or metres per unit (> 0).")
    acceleration_units: Literal["g", "m/s2", "free-g", "free-m/s2",
                                "second-differences"] | None = None
    options: dict[str, float | int | bool | str] = Field(
        default_factory=dict, description="Method options (hachaj2018: window, eps).")


def run_skeleton(inputs: Mapping[str, Input], params: SkeletonParams, progress: Progress,
                 outdir: Path) -> dict[str, Path]:
    """Read the sensor recording, estimate the skeleton, write JSON, BVH and CSV."""
    from estimation.io.sensors import read_recording
    from estimation.io.skeleton import (
        offsets_from_dict,
        write_skeleton_bvh,
        write_skeleton_csv,
        write_skeleton_json,
    )
    from estimation.skeleton import estimate_skeleton

    source = inputs["recording"]
    progress(0.0, "reading")
    recording = read_recording(source.path, format=SENSOR_FORMATS.get(source.format, "auto"),
                               units=params.units, fps=params.fps, stations=params.stations)
    result = estimate_skeleton(
        recording, method=params.method, optimizer=params.optimizer, torso=params.torso,
        up=params.up, i0=params.i0, anthropometry=params.anthropometry, w_s=params.w_s,
        w_l=params.w_l, smooth=params.smooth,
        offsets=None if params.offsets is None else offsets_from_dict(
            {k: v.model_dump() for k, v in params.offsets.items()}),
        progress=scaled(progress, 0.02, 0.95))
    progress(0.95, "writing")
    out = {"json": outdir / "skeleton.json", "bvh": outdir / "skeleton.bvh",
           "csv": outdir / "skeleton.csv"}
    write_skeleton_json(result, out["json"])
    write_skeleton_bvh(result, out["bvh"])
    write_skeleton_csv(result, out["csv"])
    return out


def run_translation(inputs: Mapping[str, Input], params: TranslationParams, progress: Progress,
                    outdir: Path) -> dict[str, Path]:
    """Read the kinematics (and accelerations), estimate the root path, write the results."""
    from estimation.io.kinematics import read_kinematics, write_translation
    from estimation.translation import estimate_translation

    source = inputs["recording"]
    progress(0.0, "reading")
    accelerations = inputs.get("accelerations")
    recording = read_kinematics(
        source.path, format=KINEMATICS_FORMATS.get(source.format, "auto"),
        accelerations=accelerations.path if accelerations else None,
        left_foot=params.left_foot, right_foot=params.right_foot,
        acceleration_units=params.acceleration_units, units=params.units)
    result = estimate_translation(recording, method=params.method,
                                  left_foot=recording.left_foot, right_foot=recording.right_foot,
                                  progress=scaled(progress, 0.02, 0.95), **params.options)
    progress(0.95, "writing")
    out = {"json": outdir / "translation.json", "bvh": outdir / "translation.bvh"}
    if source.format == "kinematics-csv":  # a corrected CSV needs a CSV input to correct
        out["csv"] = outdir / "translation.csv"
    writers = {"json": "json", "bvh": "bvh", "csv": "kinematics-csv"}
    for fmt, path in out.items():
        write_translation(result, recording, path, format=writers[fmt])
    return out


@dataclass(frozen=True)
class Kind:
    """A job kind: how to validate its params and run it."""

    name: str
    params: type[BaseModel]
    run: Runner
    inputs: tuple[str, ...] = ()
    """Names of extra recordings the kind accepts in ``inputs``."""


def default_kinds() -> dict[str, Kind]:
    """The job kinds the service offers."""
    return {
        "skeleton": Kind("skeleton", SkeletonParams, run_skeleton),
        "translation": Kind("translation", TranslationParams, run_translation,
                            inputs=("accelerations",)),
    }


MEDIA_TYPES = {"json": "application/json", "bvh": "application/x-bvh",
               "csv": "text/csv; charset=utf-8"}
"""Content type of each result format."""
