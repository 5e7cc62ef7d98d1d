# SPDX-License-Identifier: Apache-2.0
"""How the search reads the mask (suture_ordering.nodes.MaskReader) and the shared tuning: the
fast paths read exactly what the plain formulas read."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from suture_ordering import OrderingParams
from suture_ordering.cleaning import clean_mask
from suture_ordering.geometry import fixed_point
from suture_ordering.nodes import MaskReader, circle_samples
from suture_ordering.params import ScaledParams
from suture_ordering.tuning import parameter_grid, tuning_for

W, H = 640, 480


def _reader(pad: int = 74) -> tuple[MaskReader, np.ndarray]:
    """A reader of a mask with threads of several widths and angles, and the padded mask as float32."""
    mask = np.zeros((H, W), np.uint8)
    cv2.line(mask, (0, 30), (639, 470), 1, 3)
    cv2.line(mask, (20, 460), (600, 10), 1, 5)
    cv2.ellipse(mask, (320, 240), (150, 90), 20, 0, 300, 1, 2)
    cv2.line(mask, (0, 0), (639, 0), 1, 1)  # along the image's edge
    clean = clean_mask(mask, ScaledParams.from_params(OrderingParams(), W), 1, pad)
    return MaskReader(clean, 1.6, 8), clean.padded.astype(np.float32)


def test_circle_samples_read_the_whole_mask_exactly():
    """A window of the mask holds every sample's neighbours: the same samples as cv2.remap over the
    whole padded mask, bit for bit, anywhere (also at the image's edge and beyond the padding)."""
    reader, whole = _reader(pad=20)
    rng = np.random.default_rng(7)
    points = np.vstack([rng.uniform(-20, [W + 20, H + 20], (300, 2)), [[0.0, 0.0], [639.5, 479.5]]])
    for vertex in points:
        for r in (2, 8, 24, 63):
            centre = (vertex + reader.pad).astype(np.float32)
            where = circle_samples(r)[0] + centre
            expected = cv2.remap(whole, where, None, cv2.INTER_LINEAR).reshape(-1)
            assert np.array_equal(reader._bilinear(where, centre, r), expected)


def test_nodes_lie_on_the_centreline_of_each_cross_section():
    mask = np.zeros((H, W), np.uint8)
    cv2.line(mask, (100, 240), (500, 240), 1, 5)
    cv2.line(mask, (300, 100), (300, 400), 1, 3)
    reader = MaskReader(clean_mask(mask, ScaledParams.from_params(OrderingParams(), W), 1, 74), 1.6, 8)
    nodes = reader.nodes(np.array([300.0, 240.0]), 20, None)
    assert nodes is not None and nodes.radius == 20
    angles = sorted(math.degrees(math.atan2(y - 240, x - 300)) % 360 for x, y in nodes.position)
    assert angles == pytest.approx([0, 90, 180, 270], abs=0.5)
    assert np.allclose(np.hypot(*(nodes.position - [300, 240]).T), 20)
    across = {0: mask[:, 200].sum(), 90: mask[150, :].sum()}  # the threads' widths in the mask
    expected = [across[round(a) % 180] for a in angles]
    assert np.allclose(sorted(nodes.width), sorted(expected), atol=0.1)
    assert reader.nodes(np.array([300.0, 240.0]), 1, None) is None  # inside the mask all round


def test_flat_indices_are_the_rounded_pixels_of_the_padded_arrays():
    reader, _ = _reader()
    points = np.array([[[0.4, 0.6], [639.5, 2.5]], [[10.49, 479.0], [-3.2, 481.7]]])
    flat = reader.flat(points)
    assert flat.shape == (2, 2)
    rows, cols = np.unravel_index(flat, reader.mask.shape)
    assert np.array_equal(cols - reader.pad, np.rint(points[..., 0]))
    assert np.array_equal(rows - reader.pad, np.rint(points[..., 1]))


def test_fixed_point_rounds_half_to_even_like_numpy():
    for x in (0.5 / 16, 1.5 / 16, 2.5 / 16, 123.46875, -0.03125, 77.0):
        point = np.array([x, -x])
        assert fixed_point(point) == tuple(int(v) for v in np.rint(point * 16))


def test_the_tuning_is_built_once_per_parameters_and_cannot_be_changed():
    params = OrderingParams()
    tuning = tuning_for(params, 63)
    assert tuning_for(OrderingParams(), 63) is tuning
    assert tuning_for(params.with_updates(grid_size=1), 63) is not tuning
    assert np.array_equal(tuning.grid, parameter_grid(params))
    with pytest.raises(ValueError):
        tuning.grid[0, 0] = 1.0


def test_the_padded_arrays_hold_the_mask_and_its_zone_with_zeros_around():
    mask = np.zeros((H, W), np.uint8)
    cv2.line(mask, (0, 100), (639, 300), 255, 3)  # reaches the image's edges
    clean = clean_mask(mask, ScaledParams.from_params(OrderingParams(), W), 1, 30)
    inner = (slice(30, 30 + H), slice(30, 30 + W))
    assert clean.padded.shape == clean.zone.shape == (H + 60, W + 60)
    assert np.array_equal(clean.padded[inner], (mask > 0).astype(np.uint8))
    expected_zone = cv2.dilate((mask > 0).astype(np.uint8), np.ones((3, 3), np.uint8))
    assert np.array_equal(clean.zone[inner], expected_zone)
    for array in (clean.padded, clean.zone):  # nothing in the padding, not even beside the edge
        assert array.sum() == array[inner].sum()
