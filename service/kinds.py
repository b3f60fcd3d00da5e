"""Job kinds: per kind, a params model and a run function that calls ``estimation``."""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal, cast

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    PositiveFloat,
    StrictBool,
    TypeAdapter,
    ValidationInfo,
    field_validator,
)

from bonefit.estimation.params import (
    CONTACT_OPTION_RANGES,
    HACHAJ_EPS_RANGE,
    HACHAJ_WINDOW_RANGE,
    MAX_FPS,
    MIN_FPS,
    WEIGHT_MAX,
)
from bonefit.estimation.progress import Progress
from bonefit.estimation.vocabulary import (
    ANTHROPOMETRY_KEYS,
    ANTHROPOMETRY_TABLES,
    RESULT_FORMATS,
    AccelerationUnit,
    AnthropometryKey,
    AnthropometryTable,
    LengthUnit,
    Optimizer,
    PositionUnit,
    ResultFormat,
    SkeletonMethod,
    TorsoEstimator,
    TranslationMethod,
)

RecordingFormat = Literal["sensor-csv", "tracker", "npz", "kinematics-csv", "bvh", "mvnx",
                          "accelerations-csv"]
"""API names of the recording formats an upload may declare (or ``"auto"``)."""

SENSOR_FORMATS = {"sensor-csv": "csv", "tracker": "tracker", "npz": "npz"}
"""API format name → ``bonefit.estimation.io.sensors`` format name."""
KINEMATICS_FORMATS = {"kinematics-csv": "kinematics-csv", "bvh": "bvh", "mvnx": "mvnx"}
"""API format name → ``bonefit.estimation.io.kinematics`` format name."""


@dataclass(frozen=True)
class Input:
    """A recording handed to a run function: a local path and its API format name."""

    path: Path
    format: str


NUMERICAL_MODULES = ("bonefit.estimation.skeleton", "bonefit.estimation.translation",
                     "bonefit.estimation.io.sensors", "bonefit.estimation.io.skeleton",
                     "bonefit.estimation.io.kinematics", "bonefit.estimation.pipeline")
"""What the run functions import: the API process never needs them (nor scipy)."""


def preload() -> None:
    """Import the estimation code the kinds run, so that a worker's first job does not wait
    for numpy and scipy to load (~0.5 s)."""
    for name in NUMERICAL_MODULES:
        importlib.import_module(name)


Runner = Callable[[Mapping[str, Input], Any, Progress, Path], dict[str, Path]]
"""``run(inputs, params, progress, outdir) -> {result format: file}``; inputs["recording"]."""


def _with_json(formats: tuple[ResultFormat, ...]) -> tuple[ResultFormat, ...]:
    if "json" not in formats:
        raise ValueError("formats must include 'json': it is the job's result document, which "
                         "the studio and the clients read")
    return tuple(dict.fromkeys(formats))


ResultFormats = Annotated[
    tuple[ResultFormat, ...],
    Field(min_length=1, max_length=len(RESULT_FORMATS),
          description="Result files the job writes, 'json' among them (default all four). "
                      "On a long take each costs time and space: ask only for those you "
                      "will download."),
    AfterValidator(_with_json)]
"""The ``formats`` parameter of every kind: which results a job writes."""

ALL_FORMATS = cast(tuple[ResultFormat, ...], RESULT_FORMATS)


class JointOffsetIn(BaseModel):
    """Where a joint sits in one sensor's frame (an entry of a skeleton result's
    ``offsets``)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    sensor: str = Field(min_length=1, max_length=100)
    local: tuple[float, float, float] = Field(description="Metres, in the sensor's frame.")


ANTHROPOMETRY_TABLE: TypeAdapter[dict[AnthropometryKey, float]] = TypeAdapter(
    dict[AnthropometryKey, Annotated[float, Field(gt=0, le=1000, allow_inf_nan=False)]])
"""A custom table: positive, finite lengths or ratios, in any one unit."""


class SkeletonParams(BaseModel):
    """Parameters of a skeleton job (magnetic 6-DOF trackers)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    method: SkeletonMethod = "auto"
    optimizer: Optimizer = "least-squares"
    torso: TorsoEstimator = "llsf"
    anthropometry: AnthropometryTable | dict[str, float] = Field(
        "aist", description="A table name, or lengths (or ratios) of torso, thigh, shank, "
                            "upperarm and forearm in any one unit.")
    w_s: float = Field(0.01, ge=0, le=WEIGHT_MAX, description="Weight of eq. 5's length term.")
    w_l: float = Field(0.01, ge=0, le=WEIGHT_MAX, description="Weight of eq. 5's ratio term.")
    smooth: StrictBool | None = None
    up: tuple[float, float, float] = Field(
        (0.0, 1.0, 0.0), description="World up direction of the source frame (non-zero).")
    i0: int = Field(0, ge=0, le=2**31, description="Calibration frame of hands, feet and head.")
    units: PositionUnit | None = None
    fps: float | None = Field(None, ge=MIN_FPS, le=MAX_FPS,
                              description="Frame rate, Hz (tracker files).")
    stations: dict[Annotated[str, Field(min_length=1, max_length=100)],
                   Annotated[str, Field(min_length=1, max_length=100)]] | None = Field(
        None, max_length=64, description="Tracker station → segment.")
    tracker_layout: str | None = Field(
        None, max_length=200,
        description="Tracker columns, e.g. 'frame,station,x,y,z,az,el,roll' or "
                    "'time,x,y,z,qx,qy,qz,qw;time=ns' (docs/skeleton-io.md); default detected.")
    offsets: dict[str, JointOffsetIn] | None = Field(
        None, max_length=64,
        description="A calibration: the `offsets` of an earlier skeleton result of the same "
                    "suit. Every joint is placed at its offset instead of being fitted "
                    "(method and fit options are then ignored).")
    formats: ResultFormats = ALL_FORMATS

    @field_validator("anthropometry", mode="before")
    @classmethod
    def _table(cls, value: Any) -> Any:
        """One error at ``anthropometry`` or ``anthropometry.<key>``, not one per union arm."""
        if isinstance(value, dict):
            return ANTHROPOMETRY_TABLE.validate_python(value)
        if value not in ANTHROPOMETRY_TABLES:
            raise ValueError(f"use 'aist', 'winter' or a table of {', '.join(ANTHROPOMETRY_KEYS)}; "
                             f"got {value!r}")
        return value

    @field_validator("up")
    @classmethod
    def _non_zero(cls, up: tuple[float, float, float]) -> tuple[float, float, float]:
        if not any(up):
            raise ValueError("up must be a non-zero direction")
        return up


def _ranged(default: float | None, name: str, description: str) -> Any:
    """A field bounded as ``bonefit.estimation.params.CONTACT_OPTION_RANGES[name]``."""
    low, high, low_open = CONTACT_OPTION_RANGES[name]
    if low_open:
        return Field(default, gt=low, le=high, description=description)
    return Field(default, ge=low, le=high, description=description)


class ContactOptionsIn(BaseModel):
    """Options of the ``contact`` translation method
    (``bonefit.estimation.translation.ContactOptions``: times in seconds, lengths in metres)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    smoothing_s: float = _ranged(0.03, "smoothing_s", "Gaussian σ of positions, s.")
    sigma_acc: float = _ranged(1.5, "sigma_acc", "Scale of acceleration residuals, m/s².")
    relative_sigma_acc: float = _ranged(0.0, "relative_sigma_acc",
                                        "Growth of that scale with the acceleration.")
    swing_weight: float = _ranged(0.0, "swing_weight", "Weight of a swinging foot's residual.")
    residual_cap: float = _ranged(9.0, "residual_cap", "Cap of a residual's cost.")
    swing_cost: float = _ranged(1.0, "swing_cost", "Cost per 10 ms of a foot in the air.")
    flight_cost: float = _ranged(3.0, "flight_cost", "Extra cost per 10 ms of flight.")
    switch_cost: float = _ranged(6.0, "switch_cost", "Cost of a change of contact state.")
    sigma_relative_speed: float = _ranged(0.15, "sigma_relative_speed",
                                          "Scale of the feet's relative speed, m/s.")
    adapt_relative_speed: StrictBool = True
    height_tolerance: float = _ranged(0.03, "height_tolerance", "m.")
    sigma_height: float = _ranged(0.02, "sigma_height", "m.")
    floor_tolerance: float = _ranged(0.05, "floor_tolerance", "Same floor level within, m.")
    floor_ramp_s: float = _ranged(0.25, "floor_ramp_s", "Ease onto a floor level, s.")
    use_toes: StrictBool = True
    extrapolate_toes: StrictBool = False
    choose_toes: StrictBool = True
    lever_arm_prior_m: float = _ranged(0.0, "lever_arm_prior_m",
                                       "Prior scale of the foot sensor's offset, m (0: off).")
    use_file_contacts: StrictBool = True
    clip_g: float | None = _ranged(None, "clip_g", "Accelerometer range, g (null: detect).")


class Hachaj2018OptionsIn(BaseModel):
    """Options of the ``hachaj2018`` translation method."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    window: int = Field(100, ge=HACHAJ_WINDOW_RANGE[0], le=HACHAJ_WINDOW_RANGE[1],
                        description="Gaussian window, samples.")
    eps: float = Field(0.05, gt=HACHAJ_EPS_RANGE[0], le=HACHAJ_EPS_RANGE[1],
                       description="Pass-2 threshold, m.")

    @field_validator("window", mode="before")
    @classmethod
    def _not_bool(cls, value: Any) -> Any:
        if isinstance(value, bool):
            raise ValueError(f"window must be a number of samples, got {value!r}")
        return value


OPTION_MODELS: dict[str, type[ContactOptionsIn] | type[Hachaj2018OptionsIn]] = {
    "contact": ContactOptionsIn, "hachaj2018": Hachaj2018OptionsIn}
"""Translation method → the model of its ``options``."""


class TranslationParams(BaseModel):
    """Parameters of a translation job (inertial suits)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    method: TranslationMethod = "contact"
    left_foot: str | None = Field(None, min_length=1, max_length=100,
                                  description="Default: found by name or topology.")
    right_foot: str | None = Field(None, min_length=1, max_length=100)
    units: Literal["auto", LengthUnit] | PositiveFloat = Field(
        "auto", description="Length unit of a BVH or kinematics CSV: auto (from the legs' "
                            "length), a name, or metres per unit (> 0).")
    acceleration_units: AccelerationUnit | None = None
    subject: str | None = Field(
        None, min_length=1, max_length=100,
        description="MVNX subject to read, by label or 1-based number; default the first.")
    options: ContactOptionsIn | Hachaj2018OptionsIn = Field(
        default_factory=ContactOptionsIn, validate_default=True,
        description="Options of `method`, validated by its model: contact: "
                    "`ContactOptionsIn`; hachaj2018: `window` (samples), `eps` (m).")
    formats: ResultFormats = ALL_FORMATS

    @field_validator("options", mode="before")
    @classmethod
    def _options_of_method(cls, value: Any, info: ValidationInfo) -> Any:
        """Validate ``options`` by the model of ``method`` (errors at ``options.<key>``)."""
        model = OPTION_MODELS.get(info.data.get("method", ""))
        if model is None:  # the method itself is invalid and reported
            return ContactOptionsIn()
        if isinstance(value, BaseModel):
            value = value.model_dump(exclude_unset=True)
        return model.model_validate(value)


def run_skeleton(inputs: Mapping[str, Input], params: SkeletonParams, progress: Progress,
                 outdir: Path) -> dict[str, Path]:
    """Read the sensor recording, estimate the skeleton, write the results of
    ``params.formats``."""
    from bonefit.estimation import pipeline
    from bonefit.estimation.io.result_json import offsets_from_dict

    source = inputs["recording"]
    out: dict[str, Path] = {fmt: outdir / f"skeleton.{fmt}" for fmt in params.formats}
    pipeline.run_skeleton(
        pipeline.SensorSource(source.path, format=SENSOR_FORMATS.get(source.format, "auto"),
                              units=params.units, fps=params.fps, stations=params.stations,
                              tracker_layout=params.tracker_layout),
        pipeline.SkeletonRunOptions(
            method=params.method, optimizer=params.optimizer, torso=params.torso,
            up=params.up, i0=params.i0, anthropometry=params.anthropometry, w_s=params.w_s,
            w_l=params.w_l, smooth=params.smooth,
            offsets=None if params.offsets is None else offsets_from_dict(
                {k: v.model_dump() for k, v in params.offsets.items()})),
        pipeline.SkeletonOutputs(json=out.get("json"), bvh=out.get("bvh"),
                                 csv=out.get("csv"), npz=out.get("npz")),
        progress=progress)
    return out


def run_translation(inputs: Mapping[str, Input], params: TranslationParams, progress: Progress,
                    outdir: Path) -> dict[str, Path]:
    """Read the kinematics (and accelerations), estimate the root path, write the results of
    ``params.formats``."""
    from bonefit.estimation import pipeline

    source = inputs["recording"]
    accelerations = inputs.get("accelerations")
    out: dict[str, Path] = {fmt: outdir / f"translation.{fmt}" for fmt in params.formats
           # a corrected CSV needs a CSV input to correct
           if fmt != "csv" or source.format == "kinematics-csv"}
    writers = {"json": "json", "bvh": "bvh", "csv": "kinematics-csv", "npz": "npz"}
    pipeline.run_translation(
        pipeline.KinematicsSource(
            source.path, format=KINEMATICS_FORMATS.get(source.format, "auto"),
            accelerations=accelerations.path if accelerations else None,
            left_foot=params.left_foot, right_foot=params.right_foot,
            acceleration_units=params.acceleration_units, units=params.units,
            subject=params.subject),
        pipeline.TranslationRunOptions(params.method, params.options.model_dump()),
        [(writers[f], p) for f, p in out.items()],
        progress=progress)
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


MEDIA_TYPES: dict[ResultFormat, str] = {"json": "application/json", "bvh": "application/x-bvh",
                                        "csv": "text/csv; charset=utf-8",
                                        "npz": "application/x-npz"}
"""Content type of each result format."""
