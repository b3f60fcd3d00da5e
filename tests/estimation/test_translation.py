"""Root translation: the paper's method reproduced exactly, and the contact model against
synthetic recordings with a known path."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from bonefit.estimation.errors import EstimationError, InputError
from bonefit.estimation.io.kinematics import KinematicsRecording, read_kinematics
from bonefit.estimation.simulate.inertial import simulate_walker
from bonefit.estimation.translation import (
    HACHAJ_EPS_M,
    METHOD_OPTIONS,
    ContactOptions,
    HachajOptions,
    TranslationResult,
    estimate_translation,
    hachaj_smooth,
    hachaj_window_length,
    method_options,
    pose_jumps,
)

SHADOW = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "shadow"


# ----------------------------------------------------------------- plain transcriptions


def smooth_loop(x: NDArray[np.float64], window: int = 100) -> NDArray[np.float64]:
    """The reference smoother written out term by term (R ``smoother::smth``, gaussian)."""
    n = len(x)
    w = int(window / n * n)
    h = w // 2
    kernel = [np.exp(-0.5 * (2.5 * (j - h) / (w / 2)) ** 2) for j in range(w)]
    total = sum(kernel)
    out = np.zeros(n)
    for i in range(h, n - (w - h)):
        out[i] = sum(kernel[j] * x[i - h + j] for j in range(w)) / total
    return out


def hachaj_loop(p: NDArray[np.float64], acc_l: NDArray[np.float64],
                acc_r: NDArray[np.float64], li: int, ri: int) -> NDArray[np.float64]:
    """The authors' three passes as their R loop does them: O(N²) corrections."""
    p = p.copy()
    n = p.shape[0]
    z_r = smooth_loop(np.linalg.norm(acc_r, axis=1))
    z_l = smooth_loop(np.linalg.norm(acc_l, axis=1))
    for a in range(n - 1):
        if z_r[a] > z_l[a] and z_r[a + 1] > z_l[a + 1]:
            p[a + 1:] -= p[a + 1, li] - p[a, li]
        elif z_r[a] < z_l[a] and z_r[a + 1] < z_l[a + 1]:
            p[a + 1:] -= p[a + 1, ri] - p[a, ri]
    z_r = smooth_loop(p[:, ri, 1])
    z_l = smooth_loop(p[:, li, 1])
    for a in range(n - 1):
        if abs(z_r[a] - z_l[a]) > HACHAJ_EPS_M:
            if z_r[a] > z_l[a] and z_r[a + 1] > z_l[a + 1]:
                p[a + 1:] -= p[a + 1, li] - p[a, li]
            elif z_r[a] < z_l[a] and z_r[a + 1] < z_l[a + 1]:
                p[a + 1:] -= p[a + 1, ri] - p[a, ri]
    ground = p[0, ri, 1]
    for a in range(n):
        lower = li if z_r[a] >= z_l[a] else ri
        p[a, :, 1] -= p[a, lower, 1] - ground
    return p


# ----------------------------------------------------------------- faithful mode


def test_reference_match_on_heian_shodan() -> None:
    path = SHADOW / "heian_shodan.csv"
    ref_path = SHADOW / "heian_shodan.reference-hips.csv"
    if not path.is_file() or not ref_path.is_file():
        pytest.skip(f"real recording not available at {SHADOW}")
    recording = read_kinematics(path)
    reference = np.loadtxt(ref_path, delimiter=",", skiprows=1)
    result = estimate_translation(recording, method="hachaj2018")
    hips_cm = result.root * 100.0
    assert hips_cm.shape == reference[:, 1:].shape
    assert np.abs(hips_cm - reference[:, 1:]).max() < 1e-4
    assert result.quality["closure_cm"] == pytest.approx(16.4, abs=0.05)
    assert result.quality["window_samples"] == 100


def test_window_is_99_samples_for_some_lengths() -> None:
    assert hachaj_window_length(2600) == 100
    quirky = [n for n in range(100, 400) if hachaj_window_length(n) == 99]
    assert quirky[:3] == [161, 167, 193]
    assert all(int(100 / n * n) == 99 for n in quirky)


@pytest.mark.parametrize("n", [161, 250])
def test_smoother_matches_the_written_out_kernel(n: int) -> None:
    x = np.random.default_rng(n).normal(size=n)
    fast = hachaj_smooth(x)
    slow = smooth_loop(x)
    np.testing.assert_allclose(fast, slow, rtol=0, atol=1e-12)
    w = hachaj_window_length(n)
    h = w // 2
    assert not fast[:h].any()
    assert not fast[n - (w - h):].any()
    assert np.all(fast[h:n - (w - h)] != 0)


def test_quirky_window_shifts_the_defined_range() -> None:
    # 161 samples: window 99, centre tap 49, so outputs 49..110 are defined (0 elsewhere)
    defined = np.flatnonzero(hachaj_smooth(np.ones(161)))
    assert (defined.min(), defined.max()) == (49, 110)
    # 200 samples: window 100, centre tap 50, outputs 50..149
    defined = np.flatnonzero(hachaj_smooth(np.ones(200)))
    assert (defined.min(), defined.max()) == (50, 149)
    # normalised, symmetric kernel
    np.testing.assert_allclose(hachaj_smooth(np.ones(161))[49:111], 1.0)
    impulse = np.zeros(161)
    impulse[80] = 1.0
    out = hachaj_smooth(impulse)
    np.testing.assert_allclose(out[80 - 30:80], out[80 + 30:80:-1])
    assert out[80] == out.max()


def test_linear_passes_equal_the_quadratic_loop() -> None:
    rec, _, _ = simulate_walker(fps=60, seed=3)
    p = rec.positions[:300]
    small = KinematicsRecording(
        joints=rec.joints, positions=p, fps=rec.fps, time=rec.time[:300],
        accelerations={k: v[:300] for k, v in rec.accelerations.items()},
        left_foot=rec.left_foot, right_foot=rec.right_foot, root="Hips")
    li, ri = rec.index("LeftFoot"), rec.index("RightFoot")
    expected = hachaj_loop(p, small.accelerations["LeftFoot"], small.accelerations["RightFoot"],
                           li, ri)
    result = estimate_translation(small, method="hachaj2018")
    np.testing.assert_allclose(result.positions, expected, atol=1e-12)


# ----------------------------------------------------------------- contact mode


def horizontal_error_pct(result: TranslationResult, truth_root: NDArray[np.float64]) -> float:
    err = np.linalg.norm(result.root[:, [0, 2]] - truth_root[:, [0, 2]], axis=1)
    length = np.linalg.norm(np.diff(truth_root[:, [0, 2]], axis=0), axis=1).sum()
    return float(err.mean() / length * 100)


@pytest.mark.parametrize(("fps", "clip"), [(30.0, None), (60.0, 2.0), (100.0, None)])
def test_contact_mode_follows_the_walker(fps: float, clip: float | None) -> None:
    rec, truth, contacts = simulate_walker(fps=fps, clip_g=clip)
    result = estimate_translation(rec)  # defaults: planted feet scored only
    faithful = estimate_translation(rec, method="hachaj2018")
    error = horizontal_error_pct(result, truth.root)
    assert error < 1.5
    assert error < 0.5 * horizontal_error_pct(faithful, truth.root)
    assert np.mean(result.contacts == contacts) > 0.8
    assert np.mean(result.contacts[contacts == "both"] == "both") > 0.65
    hop = (rec.time > 4.05) & (rec.time < 4.3)
    assert np.mean(result.contacts[hop] == "none") > 0.6
    assert result.root[hop, 1].max() - result.root[0, 1] > 0.03
    assert result.quality["floor_penetration_cm"] < 1.0


@pytest.mark.parametrize("fps", [30.0, 60.0, 100.0])
def test_swing_residuals_resolve_the_hop(fps: float) -> None:
    # sensors exactly at the joints: the swinging foot's predicted reading is exact too
    rec, truth, contacts = simulate_walker(fps=fps, clip_g=2.0)
    result = estimate_translation(rec, swing_weight=1.0)
    assert horizontal_error_pct(result, truth.root) < 1.0
    assert np.mean(result.contacts == contacts) > 0.88
    assert np.mean(result.contacts[contacts == "both"] == "both") > 0.8
    hop = (rec.time > 4.05) & (rec.time < 4.3)
    assert np.mean(result.contacts[hop] == "none") > 0.9
    rise = result.root[hop, 1].max() - result.root[0, 1]
    true_rise = truth.root[hop, 1].max() - truth.root[0, 1]
    assert rise == pytest.approx(true_rise, abs=0.07)  # measured: 0.09–0.12 for 0.15


@pytest.mark.parametrize(("swing_weight", "tolerance"), [(1.0, 0.02), (0.0, 0.07)])
def test_contact_mode_finds_the_platform_level(swing_weight: float, tolerance: float) -> None:
    rec, truth, _ = simulate_walker(fps=100, platform=0.15)
    result = estimate_translation(rec, swing_weight=swing_weight)
    on_platform = rec.time > 7.0
    # the hips end 15 cm higher, as in the truth
    rise = result.root[on_platform, 1].mean() - result.root[0, 1]
    true_rise = truth.root[on_platform, 1].mean() - truth.root[0, 1]
    assert rise == pytest.approx(true_rise, abs=tolerance)
    assert result.quality["floor_levels"] >= 2
    # the faithful method keeps one floor: the body stays down
    faithful = estimate_translation(rec, method="hachaj2018")
    assert faithful.root[on_platform, 1].mean() - faithful.root[0, 1] < 0.05


def test_no_vertical_jumps_when_the_support_changes() -> None:
    rec, truth, _ = simulate_walker(fps=100, hop=0.0)
    result = estimate_translation(rec)
    dy = np.diff(result.root[:, 1])
    true_dy = np.diff(truth.root[:, 1])
    assert np.abs(dy).max() < np.abs(true_dy).max() + 0.01
    assert result.quality["max_vertical_jump_cm"] < 1.0


@pytest.mark.parametrize("fps", [30.0, 60.0, 100.0])
def test_a_first_frame_in_another_pose_does_not_move_the_body(fps: float) -> None:
    # Files often start in another pose (a T-pose, a calibration frame): every joint but the
    # hips jumps between frames 0 and 1. Holding a planted foot through that jump would carry
    # the body 30 cm; the walker's true path does not move (27.5 cm mean error before).
    rec, truth, _ = simulate_walker(fps=fps)
    positions = rec.positions.copy()
    hips = rec.index(rec.root)
    others = np.arange(positions.shape[1]) != hips
    positions[0, others] += np.array([0.25, -0.05, 0.15])
    jumped = replace(rec, positions=positions)
    clean = estimate_translation(rec)
    result = estimate_translation(jumped)
    moved = result.root[:, [0, 2]] - result.root[0, [0, 2]]
    true_moved = truth.root[:, [0, 2]] - truth.root[0, [0, 2]]
    error_m = np.linalg.norm(moved - true_moved, axis=1)
    assert error_m.mean() < 0.03  # measured: 0.018-0.021 m, as without the jump
    assert np.allclose(result.root[1:, [0, 2]] - result.root[1, [0, 2]],
                       clean.root[1:, [0, 2]] - clean.root[1, [0, 2]], atol=0.005)


def test_pose_jumps_are_steps_far_beyond_the_recordings_own_fastest_support() -> None:
    dt = 0.01
    rng = np.random.default_rng(3)
    # a sprinter carried at 8 m/s (±10 %): fast, but every step like the others
    speed = 8.0 * (1 + 0.1 * rng.standard_normal(500))
    steps = np.zeros((500, 3))
    steps[:, 2] = speed * dt
    carried = np.ones(500, dtype=bool)
    assert not pose_jumps(steps, carried, dt).any()
    # the pose jumps 20 cm between two frames; a pair in flight is never a jump
    steps[100, 0] = 0.2
    steps[300, 0] = 0.5
    carried[300] = False
    assert np.flatnonzero(pose_jumps(steps, carried, dt)).tolist() == [100]
    # a walker standing nearly still: drifts of 5 cm/s do not make a jump of 0.5 m/s
    slow = np.zeros((500, 3))
    slow[:, 0] = 0.0005 * rng.standard_normal(500)
    slow[200, 0] = 0.005
    assert not pose_jumps(slow, np.ones(500, dtype=bool), dt).any()


def test_contacts_from_the_file_are_used() -> None:
    rec, truth, contacts = simulate_walker(fps=60)
    flags = {"LeftFoot": np.isin(contacts, ("left", "both")),
             "RightFoot": np.isin(contacts, ("right", "both"))}
    given = KinematicsRecording(
        joints=rec.joints, positions=rec.positions, fps=rec.fps, time=rec.time,
        accelerations=rec.accelerations, toes=rec.toes, contacts=flags, root="Hips")
    result = estimate_translation(given)
    assert result.quality["contacts_source"] == "file"
    np.testing.assert_array_equal(result.contacts, contacts)
    assert horizontal_error_pct(result, truth.root) < 1.0
    ignored = estimate_translation(given, use_file_contacts=False)
    assert ignored.quality["contacts_source"] == "accelerometers"


def test_result_shapes_progress_and_quality() -> None:
    rec, _, _ = simulate_walker(fps=30)
    seen: list[tuple[float, str]] = []
    result = estimate_translation(rec, progress=lambda f, s: seen.append((f, s)))
    n = rec.n_frames
    assert result.root.shape == (n, 3)
    assert result.positions.shape == rec.positions.shape
    assert result.contacts.shape == (n,)
    assert set(result.contacts) <= {"left", "right", "both", "none"}
    np.testing.assert_allclose(result.positions - rec.positions,
                               np.broadcast_to(result.translation[:, None], rec.positions.shape),
                               atol=1e-12)
    fractions = [f for f, _ in seen]
    assert fractions == sorted(fractions)
    assert fractions[0] == 0.0
    assert fractions[-1] == 1.0
    for key in ("foot_skate_cm_s", "floor_penetration_cm", "max_vertical_jump_cm",
                "closure_cm", "path_length_m"):
        assert np.isfinite(result.quality[key])
    assert result.quality["path_length_m"] > 1.5


def test_bad_requests_raise() -> None:
    rec, _, _ = simulate_walker(fps=30)
    with pytest.raises(InputError, match="unknown method"):
        estimate_translation(rec, method="magic")
    with pytest.raises(InputError, match="unknown option"):
        estimate_translation(rec, bogus=1.0)
    with pytest.raises(InputError, match="unknown option"):
        estimate_translation(rec, method="hachaj2018", switch_cost=1.0)
    with pytest.raises(InputError, match="LeftFoot, LeftToe"):
        estimate_translation(rec, left_foot="lFoot")
    short = KinematicsRecording(
        joints=rec.joints, positions=rec.positions[:2], fps=30.0, time=rec.time[:2],
        accelerations={k: v[:2] for k, v in rec.accelerations.items()}, root="Hips")
    with pytest.raises(EstimationError):
        estimate_translation(short)


@pytest.mark.parametrize(("options", "field"), [
    ({"window": 0}, "window"), ({"window": -5}, "window"), ({"window": 2.5}, "window"),
    ({"window": 1e9}, "window"), ({"window": True}, "window"), ({"eps": "x"}, "eps"),
    ({"eps": 0.0}, "eps"), ({"eps": float("nan")}, "eps"), ({"bogus": 1}, "bogus")])
def test_hachaj2018_options_out_of_range_are_refused_naming_them(
        options: dict[str, object], field: str) -> None:
    rec, _, _ = simulate_walker(fps=30)
    with pytest.raises(InputError) as info:
        estimate_translation(rec, method="hachaj2018", **options)
    assert info.value.field == field


def test_hachaj2018_takes_an_integral_window_given_as_a_float() -> None:
    rec, _, _ = simulate_walker(fps=30)
    as_float = estimate_translation(rec, method="hachaj2018", window=50.0)
    as_int = estimate_translation(rec, method="hachaj2018", window=50)
    assert as_float.quality["window_samples"] == as_int.quality["window_samples"] == 50


@pytest.mark.parametrize(("options", "field"), [
    ({"window": 0}, "window"), ({"window": 2.5}, "window"), ({"eps": 0.0}, "eps"),
    ({"eps": 2.0}, "eps")])
def test_hachaj_options_refuse_values_out_of_range(options: dict[str, object],
                                                   field: str) -> None:
    with pytest.raises(InputError) as info:
        HachajOptions(**options)  # type: ignore[arg-type]
    assert info.value.field == field


def test_hachaj_options_keep_an_integral_window_given_as_a_float_as_an_int() -> None:
    window = HachajOptions(window=50.0).window  # type: ignore[arg-type]
    assert window == 50
    assert isinstance(window, int)


@pytest.mark.parametrize(("method", "options"), [
    ("hachaj2018", {"window": 40, "eps": 0.03}),
    ("contact", {"switch_cost": 3.0, "use_toes": False})])
def test_an_options_object_gives_the_same_path_as_keywords(method: str,
                                                            options: dict[str, object]) -> None:
    rec, _, _ = simulate_walker(fps=30)
    by_keywords = estimate_translation(rec, method=method, **options)
    by_object = estimate_translation(rec, method=method,
                                     options=METHOD_OPTIONS[method](**options))  # type: ignore[arg-type]
    assert np.array_equal(by_keywords.root, by_object.root)
    assert by_keywords.quality == by_object.quality


def test_options_are_given_one_way_and_of_the_method() -> None:
    rec, _, _ = simulate_walker(fps=30)
    with pytest.raises(InputError) as info:
        estimate_translation(rec, method="hachaj2018", options=HachajOptions(), window=40)
    assert info.value.field == "window"
    with pytest.raises(InputError) as info:
        estimate_translation(rec, method="hachaj2018", options=ContactOptions())
    assert info.value.field == "options"
    assert "HachajOptions" in str(info.value)


@pytest.mark.parametrize("method", ["contact", "hachaj2018"])
def test_method_options_name_an_unknown_option_and_list_the_known(method: str) -> None:
    with pytest.raises(InputError) as info:
        method_options(method, {"bogus": 1, "zzz": 2})
    assert info.value.field == "bogus"
    assert ", ".join(sorted(METHOD_OPTIONS[method].__dataclass_fields__)) in str(info.value)
    assert method_options(method, {}) == METHOD_OPTIONS[method]()


@pytest.mark.parametrize(("option", "value"), [
    ("switch_cost", -1.0), ("sigma_acc", 0.0), ("smoothing_s", float("inf")),
    ("clip_g", -2.0), ("use_toes", "yes"), ("floor_ramp_s", "0.2")])
def test_contact_options_out_of_range_are_refused_naming_them(option: str,
                                                              value: object) -> None:
    rec, _, _ = simulate_walker(fps=30)
    with pytest.raises(InputError) as info:
        estimate_translation(rec, **{option: value})
    assert info.value.field == option
    with pytest.raises(InputError):
        ContactOptions(**{option: value})  # type: ignore[arg-type]


@pytest.mark.parametrize("fps", [5e-324, 1e6])
def test_an_absurd_frame_rate_is_refused(fps: float) -> None:
    rec, _, _ = simulate_walker(fps=30)
    odd = KinematicsRecording(joints=rec.joints, positions=rec.positions, fps=fps,
                              time=rec.time, accelerations=rec.accelerations, root=rec.root)
    with pytest.raises(InputError) as info:
        estimate_translation(odd)
    assert info.value.field == "fps"
