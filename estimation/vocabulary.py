"""The names users choose from: methods, optimizers, formats and units, each defined once.

Each choice is a ``Literal`` (for type checkers and the service's pydantic models) and a tuple
of its values (for the library's checks, the CLI's ``choices`` and messages), derived from it
with :func:`typing.get_args` so the two never drift. The tables that go with some of them
(metres per unit, an acceleration unit's scale) live beside the code that uses them and are
keyed by these names; a test checks that their keys match.
"""

from __future__ import annotations

from typing import Final, Literal, get_args

SkeletonMethod = Literal["auto", "llsf", "gdke", "reduced"]
"""``method`` of :func:`bonefit.estimation.skeleton.estimate_skeleton`."""
SKELETON_METHODS: Final[tuple[str, ...]] = get_args(SkeletonMethod)

Optimizer = Literal["least-squares", "nelder-mead"]
"""Minimiser of the reduced method's cost (``optimizer`` of ``estimate_skeleton``)."""
OPTIMIZERS: Final[tuple[str, ...]] = get_args(Optimizer)

TorsoEstimator = Literal["llsf", "gdke"]
"""Estimator of the torso joints under ``method="reduced"`` (``torso``)."""
TORSO_ESTIMATORS: Final[tuple[str, ...]] = get_args(TorsoEstimator)

AnthropometryTable = Literal["aist", "winter"]
"""Named anthropometric tables (:mod:`bonefit.estimation.anthropometry`)."""
ANTHROPOMETRY_TABLES: Final[tuple[str, ...]] = get_args(AnthropometryTable)

AnthropometryKey = Literal["torso", "thigh", "shank", "upperarm", "forearm"]
"""Keys of a custom anthropometric table (``limbs.standard_lengths``)."""
ANTHROPOMETRY_KEYS: Final[tuple[str, ...]] = get_args(AnthropometryKey)

TranslationMethod = Literal["contact", "hachaj2018"]
"""``method`` of :func:`bonefit.estimation.translation.estimate_translation`."""
TRANSLATION_METHODS: Final[tuple[str, ...]] = get_args(TranslationMethod)

SensorFormat = Literal["csv", "tracker", "npz"]
"""Formats of a 6-DOF sensor recording (:func:`bonefit.estimation.io.sensors.read_recording`)."""
SENSOR_FORMATS: Final[tuple[str, ...]] = get_args(SensorFormat)

KinematicsFormat = Literal["kinematics-csv", "bvh", "mvnx"]
"""Formats of an inertial-suit recording
(:func:`bonefit.estimation.io.kinematics.read_kinematics`)."""
KINEMATICS_FORMATS: Final[tuple[str, ...]] = get_args(KinematicsFormat)

TranslationOutputFormat = Literal["kinematics-csv", "bvh", "mvnx", "json"]
"""Formats a translation result is written in (``write_translation``)."""
TRANSLATION_OUTPUT_FORMATS: Final[tuple[str, ...]] = get_args(TranslationOutputFormat)

PositionUnit = Literal["m", "cm", "mm", "in"]
"""Units of a sensor recording's positions (``units`` of ``read_recording``)."""
POSITION_UNITS: Final[tuple[str, ...]] = get_args(PositionUnit)

LengthUnit = Literal["m", "cm", "mm", "in", "ft", "cmu"]
"""Named length units of a BVH or kinematics CSV (``units`` of ``read_kinematics``;
``cmu``: the CMU database's 1/0.45 inch)."""
LENGTH_UNIT_NAMES: Final[tuple[str, ...]] = get_args(LengthUnit)

AccelerationUnit = Literal["g", "m/s2", "free-g", "free-m/s2", "second-differences"]
"""Declarable units of foot accelerations (``acceleration_units`` of ``read_kinematics``)."""
ACCELERATION_UNIT_NAMES: Final[tuple[str, ...]] = get_args(AccelerationUnit)
