# SPDX-License-Identifier: Apache-2.0
"""Fast 1D smoothers on uniform grids, shared by the pairing and curve steps.

* :func:`savgol` - Savitzky-Golay filtering (value or first derivative) along
  axis 0, with the ends fitted by one-sided polynomials like
  ``scipy.signal.savgol_filter(mode='interp')``; the edge operators are cached,
  so a call costs two small matrix products and one correlation.
* :func:`whittaker` - the Whittaker smoother (a discrete cubic smoothing spline):
  ``argmin_z sum_i w_i (y_i - z_i)^2 + lam sum_i (z[i-1] - 2 z[i] + z[i+1])^2``,
  solved as one symmetric banded system (``scipy.linalg.solveh_banded``), O(n).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.linalg import solveh_banded
from scipy.ndimage import correlate1d
from scipy.signal import savgol_coeffs


@lru_cache(maxsize=32)
def _savgol_operators(window: int, order: int, deriv: int) -> tuple[np.ndarray, np.ndarray]:
    """Interior coefficients (window,) and the left-edge operator (window // 2, window)."""
    half = window // 2
    interior = savgol_coeffs(window, order, deriv=deriv, use="dot")
    x = np.arange(window, dtype=np.float64)
    fit = np.vander(x, order + 1, increasing=True)  # polynomial in the sample position
    powers = np.arange(order + 1)
    # the polynomial's value, or its derivative: d/dx sum_k c_k x^k = sum_k k c_k x^(k - 1)
    evaluate = powers * x[:half, None] ** np.maximum(powers - 1, 0) if deriv else x[:half, None] ** powers
    return interior, evaluate @ np.linalg.pinv(fit)


def savgol(values: np.ndarray, window: int, order: int = 2, deriv: int = 0) -> np.ndarray:
    """Savitzky-Golay filter of (n, ...) ``values`` along axis 0 (``window`` odd; shorter inputs shrink it).

    Inputs shorter than ``order + 2`` samples are returned as they are (deriv 0)
    or by finite differences (deriv 1).
    """
    values = np.asarray(values, dtype=np.float64)
    n = len(values)
    window = min(int(window) | 1, n if n % 2 else n - 1)
    if window <= order + 1:
        return values.copy() if deriv == 0 else np.gradient(values, axis=0)
    interior, edge = _savgol_operators(window, order, deriv)
    half = window // 2
    out = correlate1d(values, interior, axis=0, mode="nearest")
    flat = values.reshape(n, -1)
    out = out.reshape(n, -1)
    out[:half] = edge @ flat[:window]
    right = edge @ flat[::-1][:window]  # the right edge is the left edge of the reversed signal
    out[n - half :] = (right if deriv == 0 else -right)[::-1]
    return out.reshape(values.shape)


def whittaker(values: np.ndarray, weights: np.ndarray, lam: float) -> np.ndarray:
    """Whittaker smoother of (n,) or (n, k) ``values`` with (n,) ``weights`` >= 0 (module docstring).

    Inputs must be finite (they are not checked again: the disparity regulariser
    calls this a dozen times per frame)."""
    values = np.asarray(values, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    n = len(w)
    rhs = values * (w if values.ndim == 1 else w[:, None])
    if n < 3:
        total = max(float(w.sum()), 1e-300)
        return np.broadcast_to(rhs.sum(axis=0) / total, values.shape).copy()
    # D^T D of the (n - 2, n) second-difference matrix, in solveh_banded's upper form.
    main = np.full(n, 6.0)
    main[[0, -1]] = 1.0
    main[[1, -2]] = 5.0 if n > 3 else 4.0
    first = np.full(n - 1, -4.0)
    first[[0, -1]] = -2.0
    # A tiny ridge towards the weighted mean keeps the system definite when fewer than two
    # samples carry weight, without pulling weakly observed stretches towards zero.
    ridge = 1e-12 * (lam + 1.0)
    mean = rhs.sum(axis=0) / max(float(w.sum()), 1e-300)
    bands = np.zeros((3, n))
    bands[0, 2:] = lam
    bands[1, 1:] = lam * first
    bands[2] = lam * main + w + ridge
    return solveh_banded(bands, rhs + ridge * mean, check_finite=False)
