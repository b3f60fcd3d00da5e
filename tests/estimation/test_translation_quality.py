"""A translation's quality is a typed structure that still reads as the JSON's mapping."""

from __future__ import annotations

import json

import pytest

from bonefit.estimation.io.result_json import translation_from_dict
from bonefit.estimation.io.translation_files import translation_to_dict
from bonefit.estimation.results import Figures, JointQuality, TranslationQuality
from bonefit.estimation.simulate.inertial import simulate_walker
from bonefit.estimation.translation import estimate_translation


def test_the_estimate_has_typed_figures_in_the_documents_order() -> None:
    rec, _, _ = simulate_walker(fps=30)
    result = estimate_translation(rec)
    quality = result.quality
    assert isinstance(quality, TranslationQuality)
    assert isinstance(quality.closure_cm, float)
    assert quality.closure_cm == quality["closure_cm"]
    assert isinstance(quality.flight_frames, int)
    assert quality.details["contacts_source"] == "accelerometers"
    keys = list(quality)
    assert keys[:len(TranslationQuality.typed_figures())] == list(
        TranslationQuality.typed_figures())
    assert "floor_levels" in keys
    # the JSON document keeps every key; reading it back gives equal figures
    doc = json.loads(json.dumps(translation_to_dict(result, rec)))
    assert list(doc["quality"]) == keys
    again = translation_from_dict(doc).quality
    assert isinstance(again, TranslationQuality)
    assert dict(again) == doc["quality"]
    assert again.path_length_m == pytest.approx(quality.path_length_m)


def test_figures_of_a_mapping() -> None:
    quality = TranslationQuality.of({"closure_cm": 12.5, "floor_penetration_cm": None,
                                     "ground_m": 0.1})
    assert (quality.closure_cm, quality.floor_penetration_cm) == (12.5, None)
    # a figure reported as null stays a key of the mapping, as in the JSON
    assert dict(quality) == {"closure_cm": 12.5, "floor_penetration_cm": None,
                             "ground_m": 0.1}
    assert TranslationQuality.of(quality) is quality
    with pytest.raises(KeyError):
        quality["max_vertical_jump_cm"]
    assert JointQuality.typed_figures()[0] == "estimator"
    assert issubclass(JointQuality, Figures)
    assert issubclass(TranslationQuality, Figures)
