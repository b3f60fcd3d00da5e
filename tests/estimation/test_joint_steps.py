"""The named steps of ``estimate_joint``: data, normal equations, robust loop, priors, hinge
decision, GDKE and reconstruction, each on a rig with a known centre."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from bonefit.estimation.errors import EstimationError
from bonefit.estimation.joints import (
    HingeRule,
    JointModel,
    Priors,
    gdke_centre,
    hinge_decision,
    hinge_value,
    joint_data,
    joint_model,
    reconstruct,
    robust_fit,
    with_priors,
)

RigFactory = Callable[..., Any]  # conftest.make_rig -> Rig


def data_of(rig: Any, valid: np.ndarray | None = None) -> Any:
    return joint_data(rig.positions_a, rig.rotations_a, rig.positions_b, rig.rotations_b,
                      valid)


def test_joint_data_fits_only_frames_where_both_sensors_are_valid(
        rig_factory: RigFactory) -> None:
    rig = rig_factory("ball", n_frames=100)
    pa = rig.positions_a.copy()
    pa[10:13] = np.nan
    valid = np.ones((100, 2), dtype=bool)
    valid[50, 1] = False
    data = joint_data(pa, rig.rotations_a, rig.positions_b, rig.rotations_b, valid)
    assert data.excluded.tolist() == [10, 11, 12, 50]
    assert data.n_both == 96
    assert np.isfinite(data.pa).all()  # interpolated, for the reconstruction
    assert data.w0[[10, 50]].tolist() == [0.0, 0.0]
    assert data.ok_a[50]
    assert not data.ok_b[50]
    np.testing.assert_array_equal(data.d, data.pb - data.pa)


def test_joint_data_refuses_fewer_than_three_common_frames(rig_factory: RigFactory) -> None:
    rig = rig_factory("ball", n_frames=20)
    valid = np.zeros(20, dtype=bool)
    valid[:2] = True
    with pytest.raises(EstimationError, match="fewer than 3 frames"):
        data_of(rig, valid)


@pytest.mark.parametrize("variant", [{}, {"slip_period": 100.0}, {"highpass": 31}])
def test_normal_equations_of_every_variant_locate_an_exact_rig(
        rig_factory: RigFactory, variant: dict[str, float]) -> None:
    rig = rig_factory("ball", rom_deg=60.0, seed=2)
    model = joint_model(data_of(rig), **variant)  # type: ignore[arg-type]
    assert (model.slip is not None) == ("slip_period" in variant)
    assert (model.highpass is not None) == ("highpass" in variant)
    fit = robust_fit(model, loss="linear")
    np.testing.assert_allclose(fit.c[:3], rig.local_a, atol=1e-6)
    np.testing.assert_allclose(fit.c[3:], rig.local_b, atol=1e-6)
    assert hinge_value(fit.sv) > 0.3  # a ball joint: no weak direction


def test_robust_fit_down_weights_outlier_frames(rig_factory: RigFactory) -> None:
    rig = rig_factory("ball", rom_deg=60.0, noise_m=0.001, seed=3)
    pb = rig.positions_b.copy()
    bad = np.arange(5, 400, 20)
    pb[bad] += 0.05  # 5 cm jumps in 5 % of the frames
    data = joint_data(rig.positions_a, rig.rotations_a, pb, rig.rotations_b)
    plain = robust_fit(JointModel(data), loss="linear")
    robust = robust_fit(JointModel(data), loss="huber")
    assert robust.w[bad].max() < 0.5
    assert np.median(robust.w[np.setdiff1d(np.arange(400), bad)]) == 1.0
    error = {name: float(np.linalg.norm(f.c[:3] - rig.local_a))
             for name, f in (("plain", plain), ("robust", robust))}
    assert error["robust"] < 0.5 * error["plain"]


def test_with_priors_moves_the_centre_only_along_the_hinge_axis(
        rig_factory: RigFactory) -> None:
    rig = rig_factory("hinge", rom_deg=60.0, noise_m=0.002, seed=4)
    model = JointModel(data_of(rig))
    w = model.data.w0
    system = model.normal_equations(w, first=True)
    free = robust_fit(model, loss="linear")
    target = free.c[:3] + 0.05 * rig.axis_a  # 5 cm along the axis
    c, weight = with_priors(model, system, free.c_data, w, Priors(prior=(target, 0.01)))
    moved = c[:3] - free.c_data[:3]
    along = float(moved @ rig.axis_a)
    assert weight > 0.0
    assert along > 0.025  # most of the way toward the prior, along the weak direction
    assert np.linalg.norm(moved - along * rig.axis_a) < 0.003  # barely across it
    unchanged, no_weight = with_priors(model, system, free.c_data, w, Priors())
    assert unchanged is free.c_data
    assert no_weight == 0.0


def test_hinge_decision_puts_the_centre_on_the_straight_limb(rig_factory: RigFactory) -> None:
    rig = rig_factory("hinge", rom_deg=60.0, seed=5)
    model = JointModel(data_of(rig))
    fit = robust_fit(model, loss="linear")
    assert hinge_value(fit.sv) < 0.3
    # neighbours on a line through the true centre, across the axis: the rule's target
    across = np.cross(rig.axis_a, [0.0, 0.0, 1.0])
    ends = tuple(rig.rotations_a.apply(rig.local_a + s * 0.3 * across) + rig.positions_a
                 for s in (1.0, -1.0))
    off = fit.c + 0.04 * fit.weak / np.linalg.norm(fit.weak[:3])  # 4 cm off along the axis
    decision = hinge_decision(model, fit, off, HingeRule((ends[0], ends[1]), None, 1e3))
    assert decision.rule == "straight-limb"
    assert decision.blend < 1e-3  # a strong rule
    assert np.linalg.norm(decision.c[:3] - rig.local_a) < 1e-3
    none = hinge_decision(model, fit, off, HingeRule())
    assert none.rule is None
    assert none.c is off


def test_gdke_centre_agrees_with_llsf_without_noise(rig_factory: RigFactory) -> None:
    rig = rig_factory("ball", rom_deg=60.0, seed=6)
    data = data_of(rig)
    c = gdke_centre(data, data.w0, bias_compensation=False)
    np.testing.assert_allclose(c[:3], rig.local_a, atol=1e-6)
    np.testing.assert_allclose(c[3:], rig.local_b, atol=1e-6)


def test_reconstruct_takes_the_measured_side_where_one_sensor_dropped(
        rig_factory: RigFactory) -> None:
    rig = rig_factory("ball", rom_deg=60.0, noise_m=0.002, seed=7)
    valid = np.ones((400, 2), dtype=bool)
    valid[100, 1] = False
    model = JointModel(data_of(rig, valid))
    fit = robust_fit(model, loss="linear")
    rec = reconstruct(model, fit.c, fit.back)
    from_a = rig.rotations_a[100].apply(fit.c[:3]) + rig.positions_a[100]
    from_b = rig.rotations_b[101].apply(fit.c[3:]) + rig.positions_b[101]
    np.testing.assert_allclose(rec.positions[100], from_a, atol=1e-12)
    both_101 = 0.5 * (rig.rotations_a[101].apply(fit.c[:3]) + rig.positions_a[101] + from_b)
    np.testing.assert_allclose(rec.positions[101], both_101, atol=1e-12)
    np.testing.assert_allclose(rec.residuals ** 2, rec.squared, rtol=1e-12)
