# SPDX-License-Identifier: Apache-2.0
"""The fast smoothers against their definitions."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import savgol_filter

from suture_reconstruction.smoothing import savgol, whittaker


@pytest.mark.parametrize("window", [5, 9, 21])
@pytest.mark.parametrize("deriv", [0, 1])
def test_savgol_matches_scipy_interp_mode(window, deriv):
    values = np.random.default_rng(window).normal(size=(60, 2)).cumsum(axis=0)
    expected = savgol_filter(values, window, 2, deriv=deriv, axis=0, mode="interp")
    np.testing.assert_allclose(savgol(values, window, 2, deriv), expected, atol=1e-10)


def test_savgol_short_inputs():
    values = np.arange(4.0)
    np.testing.assert_allclose(savgol(values, 9), savgol_filter(values, 3, 2, mode="interp"), atol=1e-12)
    np.testing.assert_allclose(savgol(np.arange(2.0), 9), [0.0, 1.0])


@pytest.mark.parametrize("n", [3, 4, 9, 40])
def test_whittaker_solves_its_normal_equations(n):
    rng = np.random.default_rng(n)
    weights = rng.uniform(0, 1, n)
    weights[rng.integers(0, n)] = 0.0
    values = rng.normal(size=n)
    lam = 7.0
    second = np.diff(np.eye(n), 2, axis=0)
    ridge = 1e-12 * (lam + 1)
    mean = (weights * values).sum() / weights.sum()
    matrix = np.diag(weights) + lam * second.T @ second + ridge * np.eye(n)
    expected = np.linalg.solve(matrix, weights * values + ridge * mean)
    np.testing.assert_allclose(whittaker(values, weights, lam), expected, atol=1e-9)


def test_whittaker_interpolates_gaps_linearly_and_does_not_pull_to_zero():
    weights = np.zeros(200)
    weights[[0, 199]] = 0.1  # only the two ends are observed, weakly
    values = np.zeros(200)
    values[[0, 199]] = [20.0, 30.0]
    result = whittaker(values, weights, 1e4)
    np.testing.assert_allclose(result, np.linspace(20.0, 30.0, 200), atol=1e-4)
