"""Translation jobs: feet found without params, ``units`` passed through and checked."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from pydantic import ValidationError

from bonefit.estimation.errors import InputError
from bonefit.estimation.io.body import LENGTH_UNITS
from bonefit.estimation.progress import no_progress
from bonefit.service.kinds import Input, TranslationParams, run_translation
from tests.estimation.bvh_corpus import CONVENTIONS, accelerations_csv, body_motion, bvh_text


def test_units_param_values() -> None:
    assert TranslationParams().units == "auto"
    assert TranslationParams().left_foot is None
    assert TranslationParams(units=0.05644).units == 0.05644
    assert TranslationParams.model_validate({"units": "cmu"}).units == "cmu"
    for bad in ("furlong", -1.0, 0, float("nan")):
        with pytest.raises(ValidationError, match="units"):
            TranslationParams.model_validate({"units": bad})


@pytest.fixture
def xsens_cmu(tmp_path: Path) -> dict[str, Input]:
    """An Xsens-named BVH in CMU units with its foot accelerometers (named LeftFoot)."""
    bvh = tmp_path / "take.bvh"
    bvh.write_text(bvh_text(body_motion(CONVENTIONS["xsens-mvn"], unit_m=LENGTH_UNITS["cmu"])))
    acc = accelerations_csv(tmp_path / "feet.csv", "LeftFoot", "RightFoot")
    return {"recording": Input(bvh, "bvh"), "accelerations": Input(acc, "accelerations-csv")}


def test_run_translation_finds_feet_and_unit(xsens_cmu: dict[str, Input],
                                             tmp_path: Path) -> None:
    out = run_translation(xsens_cmu, TranslationParams(), no_progress, tmp_path)
    data = json.loads(out["json"].read_text())
    assert data["feet"]["left"] == "LeftAnkle"
    assert data["input_length_unit_m"] == LENGTH_UNITS["cmu"]
    (tmp_path / "declared").mkdir()
    declared = run_translation(xsens_cmu, TranslationParams(units=LENGTH_UNITS["cmu"]),
                               no_progress, tmp_path / "declared")
    assert json.loads(declared["json"].read_text())["root"] == data["root"]


def test_run_translation_refuses_an_implausible_unit(xsens_cmu: dict[str, Input],
                                                     tmp_path: Path) -> None:
    with pytest.raises(InputError, match="pass units=cmu") as info:
        run_translation(xsens_cmu, TranslationParams(units="cm"), no_progress, tmp_path)
    assert info.value.field == "units"
