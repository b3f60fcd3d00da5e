"""One frozen options dataclass per skeleton method: keywords and objects, checked alike."""

from __future__ import annotations

import doctest
from dataclasses import FrozenInstanceError, fields

import numpy as np
import pytest

import bonefit.estimation.skeleton as skeleton
from bonefit.estimation.errors import InputError
from bonefit.estimation.io.sensors import example_path, read_recording
from bonefit.estimation.pipeline import (
    SensorSource,
    SkeletonOutputs,
    SkeletonRunOptions,
    run_skeleton,
)
from bonefit.estimation.recording import SensorRecording
from bonefit.estimation.simulate.sensors import SimulationTruth
from bonefit.estimation.skeleton import (
    METHOD_OPTIONS,
    AutoOptions,
    GdkeOptions,
    LlsfOptions,
    ReducedOptions,
    SkeletonOptions,
    estimate_skeleton,
    skeleton_options,
)
from bonefit.estimation.vocabulary import SKELETON_METHODS

Sim = tuple[SensorRecording, SimulationTruth]


def test_each_method_has_its_options_class() -> None:
    assert tuple(METHOD_OPTIONS) == SKELETON_METHODS
    for method, cls in METHOD_OPTIONS.items():
        assert cls.method == method
        assert cls().method == method
    assert {f.name for f in fields(LlsfOptions)} == {"up", "i0", "smooth", "min_range_deg"}
    assert {f.name for f in fields(ReducedOptions)} - {f.name for f in fields(AutoOptions)} == {
        "optimizer", "torso"}
    assert {f.name for f in fields(AutoOptions)} - {f.name for f in fields(ReducedOptions)} == {
        "highpass_s", "slip_hz"}
    # the smoothing default of each method, as before the options objects
    assert [cls().smooth for cls in METHOD_OPTIONS.values()] == [True, False, False, False]


def test_the_docstring_examples_run() -> None:
    finder = doctest.DocTestFinder()
    runner = doctest.DocTestRunner(optionflags=doctest.NORMALIZE_WHITESPACE)
    examples = 0
    for obj in (LlsfOptions, ReducedOptions, AutoOptions, skeleton_options):
        for test in finder.find(obj, globs=vars(skeleton)):
            examples += len(test.examples)
            runner.run(test)
    assert examples >= 4
    assert runner.failures == 0


def test_options_are_frozen_and_checked_on_construction() -> None:
    opt = ReducedOptions(optimizer="nelder-mead")
    with pytest.raises(FrozenInstanceError):
        opt.optimizer = "least-squares"  # type: ignore[misc]
    assert AutoOptions(up=(0.0, 0.0, 5.0)).up == (0.0, 0.0, 1.0)
    assert AutoOptions(i0=3.0).i0 == 3  # type: ignore[arg-type]
    for make, field in ((lambda: ReducedOptions(optimizer="bfgs"), "optimizer"),
                        (lambda: ReducedOptions(torso="auto"), "torso"),
                        (lambda: AutoOptions(w_s=-1.0), "w_s"),
                        (lambda: AutoOptions(slip_hz=-0.1), "slip_hz"),
                        (lambda: LlsfOptions(up=(0, 0, 0)), "up"),
                        (lambda: GdkeOptions(smooth="yes"), "smooth")):  # type: ignore[arg-type]
        with pytest.raises(InputError) as info:
            make()
        assert info.value.field == field
    with pytest.raises(TypeError, match="METHOD_OPTIONS"):
        SkeletonOptions()


def test_an_option_of_another_method_is_refused_naming_it(sim15: Sim) -> None:
    rec, _ = sim15
    for method, option, value in (("auto", "optimizer", "nelder-mead"),
                                  ("llsf", "slip_hz", 0.0), ("reduced", "highpass_s", 1.0),
                                  ("gdke", "anthropometry", "winter")):
        with pytest.raises(InputError) as info:
            estimate_skeleton(rec, method=method, **{option: value})  # type: ignore[arg-type]
        assert info.value.field == option
        assert method in info.value.detail


def test_options_object_or_keywords_not_both(sim15: Sim) -> None:
    rec, _ = sim15
    with pytest.raises(InputError) as info:
        estimate_skeleton(rec, options=AutoOptions(), slip_hz=0.0)
    assert info.value.field == "slip_hz"
    with pytest.raises(InputError) as info:
        estimate_skeleton(rec, method="llsf", options=GdkeOptions())
    assert info.value.field == "options"


def test_an_options_object_gives_the_keyword_result(sim11: Sim) -> None:
    rec, truth = sim11
    by_keywords = estimate_skeleton(rec, method="reduced", torso="gdke", smooth=None)
    by_object = estimate_skeleton(rec, options=ReducedOptions(torso="gdke"))
    assert by_object.method == by_keywords.method == "reduced"
    for name, path in by_keywords.joints.items():
        np.testing.assert_array_equal(by_object.joints[name], path)
    assert by_object.quality["waist"].estimator == "gdke"
    torso = ("waist", "neck", "l_hip", "r_hip", "l_shoulder", "r_shoulder")
    errors = [np.linalg.norm(by_object.joints[j] - truth.joints[j], axis=1).mean()
              for j in torso]
    assert np.median(errors) < 0.015  # as test_skeleton's reduced-with-GDKE-torso


def test_a_run_passes_each_method_only_its_own_options() -> None:
    # the CLI and a job's params give every option whatever the method: the run passes on
    # those of the method (here none of optimizer, w_s) and the result is the plain call's
    run = run_skeleton(SensorSource(example_path()),
                       SkeletonRunOptions(method="llsf", optimizer="nelder-mead", w_s=2.0),
                       SkeletonOutputs())
    plain = estimate_skeleton(read_recording(example_path()), method="llsf")
    assert run.result.method == "llsf"
    for name, path in plain.joints.items():
        np.testing.assert_array_equal(run.result.joints[name], path)
