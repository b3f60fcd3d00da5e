"""The vocabulary is defined once: every table keyed by a choice has exactly its names, and
the CLI, the service and the library accept the same ones."""

from __future__ import annotations

import argparse
from typing import Any, get_args

import pytest

from bonefit.cli import build_parser
from bonefit.estimation import anthropometry, skeleton, translation, vocabulary
from bonefit.estimation.io import body, kinematics, sensors
from bonefit.service import kinds


def test_tables_are_keyed_by_the_vocabulary() -> None:
    assert tuple(sensors.UNITS) == vocabulary.POSITION_UNITS
    assert tuple(body.LENGTH_UNITS) == vocabulary.LENGTH_UNIT_NAMES
    assert tuple(kinematics.ACCELERATION_UNITS) == vocabulary.ACCELERATION_UNIT_NAMES
    assert set(anthropometry.TABLES) == set(vocabulary.ANTHROPOMETRY_TABLES)
    assert ("torso", *anthropometry.LIMB_KEYS) == vocabulary.ANTHROPOMETRY_KEYS


def test_library_checks_use_the_vocabulary() -> None:
    assert skeleton.METHODS == vocabulary.SKELETON_METHODS
    assert translation.METHODS == vocabulary.TRANSLATION_METHODS
    assert sensors.FORMATS == vocabulary.SENSOR_FORMATS
    assert kinematics.FORMATS == vocabulary.KINEMATICS_FORMATS
    assert kinematics.OUTPUT_FORMATS == vocabulary.TRANSLATION_OUTPUT_FORMATS


def _field_values(model: Any, name: str) -> set[Any]:
    """The literal values a pydantic field accepts (union arms flattened)."""
    values: set[Any] = set()
    stack = [model.model_fields[name].annotation]
    while stack:
        tp = stack.pop()
        args = get_args(tp)
        if getattr(tp, "__origin__", None) is None and not args:
            continue
        stack.extend(a for a in args if not isinstance(a, str | type(None)))
        values.update(a for a in args if isinstance(a, str))
    return values


@pytest.mark.parametrize(("model", "name", "expected"), [
    (kinds.SkeletonParams, "method", vocabulary.SKELETON_METHODS),
    (kinds.SkeletonParams, "optimizer", vocabulary.OPTIMIZERS),
    (kinds.SkeletonParams, "torso", vocabulary.TORSO_ESTIMATORS),
    (kinds.SkeletonParams, "anthropometry", vocabulary.ANTHROPOMETRY_TABLES),
    (kinds.SkeletonParams, "units", vocabulary.POSITION_UNITS),
    (kinds.TranslationParams, "method", vocabulary.TRANSLATION_METHODS),
    (kinds.TranslationParams, "units", ("auto", *vocabulary.LENGTH_UNIT_NAMES)),
    (kinds.TranslationParams, "acceleration_units", vocabulary.ACCELERATION_UNIT_NAMES),
])
def test_service_params_accept_the_vocabulary(model: Any, name: str,
                                              expected: tuple[str, ...]) -> None:
    assert _field_values(model, name) == set(expected)


def _subcommand(name: str) -> argparse.ArgumentParser:
    parser = build_parser([name])
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    sub: argparse.ArgumentParser = action.choices[name]
    return sub


def test_translate_cli_choices_are_the_vocabulary() -> None:
    options = {a.dest: a for a in _subcommand("translate")._actions}
    assert tuple(options["method"].choices or ()) == vocabulary.TRANSLATION_METHODS
    assert tuple(options["format"].choices or ()) == ("auto", *vocabulary.KINEMATICS_FORMATS)


def test_service_formats_are_one_list() -> None:
    declared = set(get_args(kinds.RecordingFormat))
    assert set(kinds.SENSOR_FORMATS) | set(kinds.KINEMATICS_FORMATS) <= declared
    assert set(kinds.SENSOR_FORMATS.values()) == set(vocabulary.SENSOR_FORMATS)
    assert set(kinds.KINEMATICS_FORMATS.values()) == set(vocabulary.KINEMATICS_FORMATS)
    assert set(kinds.MEDIA_TYPES) == set(get_args(kinds.ResultFormat))
