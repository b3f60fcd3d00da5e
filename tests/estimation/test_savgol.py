"""``estimation.savgol``: scipy.signal's Savitzky–Golay numbers, bit for bit, without importing
scipy.signal (and scipy.stats) in the estimators."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy import signal

from bonefit.estimation.savgol import savgol_coeffs, savgol_filter


@pytest.mark.parametrize("window", [4, 5, 7, 25, 49, 97])
def test_coefficients_are_scipys(window: int) -> None:
    assert np.array_equal(savgol_coeffs(window, 3), signal.savgol_coeffs(window, 3))
    assert np.array_equal(savgol_coeffs(window, 2), signal.savgol_coeffs(window, 2))


@pytest.mark.parametrize(("shape", "axis"), [((300, 3), 0), ((1, 4, 200), -1), ((5, 40, 2), 1),
                                             ((25, 3), 0)])
@pytest.mark.parametrize("window", [5, 25])
def test_the_filter_is_scipys_interp_mode(shape: tuple[int, ...], axis: int,
                                          window: int) -> None:
    x = np.random.default_rng(window).normal(size=shape).cumsum(axis=axis)
    expected = signal.savgol_filter(x, window, 3, axis=axis, mode="interp")
    assert np.array_equal(savgol_filter(x, window, 3, axis=axis), expected)


def test_a_cubic_passes_unchanged_edges_included() -> None:
    t = np.arange(60.0)
    x = 0.5 - 0.1 * t + 0.02 * t ** 2 - 0.001 * t ** 3
    np.testing.assert_allclose(savgol_filter(x, 11, 3), x, atol=1e-9)


def test_bad_arguments_are_refused() -> None:
    with pytest.raises(ValueError, match="longer"):
        savgol_filter(np.zeros(4), 5, 3)
    with pytest.raises(ValueError, match="order"):
        savgol_coeffs(3, 3)
    with pytest.raises(ValueError, match="mode"):
        savgol_filter(np.zeros(9), 5, 3, mode="mirror")


def test_the_estimators_do_not_import_scipy_signal() -> None:
    code = ("import sys; import bonefit.estimation.skeleton, bonefit.estimation.slip; "
            "print(sorted(m for m in ('scipy.signal', 'scipy.stats') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == "[]"
