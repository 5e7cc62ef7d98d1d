# SPDX-License-Identifier: Apache-2.0
"""The hook checks draw only the part of the path near their window, and paint the same pixels."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from suture_ordering.hooks import _pieces_near


@pytest.mark.parametrize("seed", range(10))
def test_pieces_near_the_window_paint_what_the_whole_path_paints(seed: int) -> None:
    rng = np.random.default_rng(seed)
    for _ in range(100):
        steps = rng.normal(0.0, rng.choice([1.0, 3.0, 20.0]), (int(rng.integers(1, 300)), 2))
        polyline = (np.cumsum(steps, axis=0) + rng.uniform(-60, 200, 2)).round().astype(np.int32)
        shape = (int(rng.integers(20, 150)), int(rng.integers(20, 150)))
        thickness = 2 * int(rng.integers(1, 12)) + 1
        whole, near = np.zeros(shape, np.uint8), np.zeros(shape, np.uint8)
        cv2.polylines(whole, [polyline], False, 1, thickness)
        cv2.polylines(near, _pieces_near(polyline, shape, thickness), False, 1, thickness)
        np.testing.assert_array_equal(near, whole)
