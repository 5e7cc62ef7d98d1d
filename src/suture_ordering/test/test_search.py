# SPDX-License-Identifier: Apache-2.0
"""The choices made where the paper is ambiguous (see suture_ordering.search), the tuning grid,
the parameters, the stamp pairer and the node's parameter mapping."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from suture_ordering import OrderingParams, order_sequence
from suture_ordering.cleaning import clean_mask
from suture_ordering.core import _prepare
from suture_ordering.nodes import Candidates
from suture_ordering.ordering_node import _parameter_defaults, params_from_values
from suture_ordering.params import ScaledParams
from suture_ordering.tuning import parameter_grid

W, H = 640, 480


def _line_mask(a, b, width=3, gap=None):
    mask = np.zeros((H, W), np.uint8)
    cv2.line(mask, a, b, 255, width)
    if gap is not None:
        cv2.rectangle(mask, gap[0], gap[1], 0, -1)
    return mask


def test_tuning_grid_spans_the_paper_ranges_with_the_centre_first():
    grid = parameter_grid(OrderingParams())
    assert grid.shape == (27, 3)
    assert np.allclose(grid[0], [3.0, 0.3, 0.06])
    for column, (low, high) in enumerate([(1, 5), (0.1, 0.5), (0.02, 0.1)]):
        assert grid[:, column].min() == pytest.approx(low) and grid[:, column].max() == pytest.approx(high)
    assert len({tuple(row) for row in grid}) == 27
    assert parameter_grid(OrderingParams(grid_size=1)).shape == (1, 3)


def test_cost_is_eq5_and_orders_out_of_zone_then_distance_then_turn():
    tuning = _prepare(_line_mask((100, 100), (500, 100)), OrderingParams(), None).searcher.context.tuning
    nodes = Candidates(
        position=np.zeros((4, 2)),
        radius=np.array([8.0, 8.0, 12.0, 8.0]),
        out=np.array([0, 0, 0, 3]),
        delta=np.array([0.0, 0.5, 0.0, 0.0]),
        width=np.ones(4),
        continuation=[None] * 4,
        bridge=np.zeros(4, bool),
    )
    rows = np.arange(len(tuning.grid))
    cost = tuning.cost(rows, nodes)
    eps1, eps2, eps3 = tuning.grid.T
    expected = np.log(eps1[:, None] * nodes.out + 0.01) + eps2[:, None] * nodes.radius * np.exp(
        eps3[:, None] * np.sin(nodes.delta / 2)
    )
    assert np.allclose(cost, expected)
    assert np.all(cost[:, 0] < cost[:, 1])  # same distance: the smaller turn wins, however small eps3
    assert np.all(cost[:, 0] < cost[:, 2])  # nearer wins
    assert np.all(cost[:, 2] < cost[:, 3])  # leaving the zone costs more than 4 px of distance


def test_out_of_zone_count_is_the_gap_length_in_pixels():
    mask = _line_mask((100, 240), (500, 240), gap=((300, 200), (319, 300)))  # 20 px gap
    reader = _prepare(mask, OrderingParams(zone_margin_px=0), None).searcher.context.reader
    out = reader.out_of_zone(np.array([280.0, 240.0]), np.array([[340.0, 240.0], [280.0, 200.0]]), 60)
    assert out[0] == pytest.approx(20, abs=1)
    assert out[1] >= 35  # a chord off the thread is out of zone for most of its length
    # With the default 1 px zone margin the gap looks 2 px shorter.
    reader = _prepare(mask, OrderingParams(), None).searcher.context.reader
    assert reader.out_of_zone(np.array([280.0, 240.0]), np.array([[340.0, 240.0]]), 60)[0] == pytest.approx(
        18, abs=1
    )


def test_tau_o_is_a_pixel_length_proportional_to_the_roi():
    scaled = ScaledParams.from_params(OrderingParams(), 640)
    assert scaled.tau_o == pytest.approx(2.6 * 24)
    assert ScaledParams.from_params(OrderingParams(), 1280).tau_o == pytest.approx(2.6 * 48)
    # A 50 px gap is bridged with the default tau_O = 62 px, not with tau_O = 2.6 * 16 = 42 px.
    mask = _line_mask((60, 240), (580, 240), gap=((300, 200), (349, 300)))
    assert order_sequence(mask, np.array([60.0, 240.0])).bridges == 1
    short = order_sequence(
        mask, np.array([60.0, 240.0]), OrderingParams(roi_radius_px=16, occluder_reach_px=0.0)
    )
    assert short.bridges == 0 and short.points[-1, 0] < 300


def test_a_gap_at_a_corner_is_not_bridged():
    """Bridging needs the thread to go on smoothly: across the gap and beyond it."""
    mask = np.zeros((H, W), np.uint8)
    cv2.line(mask, (60, 240), (300, 240), 255, 3)
    cv2.line(mask, (325, 245), (380, 445), 255, 3)  # goes on at ~75 degrees after the gap
    result = order_sequence(mask, np.array([60.0, 240.0]))
    assert result.bridges == 0 and result.points[-1, 0] <= 301


def test_curvature_prediction_can_be_switched_off():
    angle = np.linspace(0, 1.6 * np.pi, 1500)
    spiral = np.column_stack(
        [320 + (40 + 25 * angle) * np.cos(angle), 240 + (40 + 25 * angle) * np.sin(angle)]
    )
    mask = np.zeros((H, W), np.uint8)
    cv2.polylines(mask, [np.rint(spiral).astype(np.int32)], False, 255, 3)
    for flag in (True, False):
        result = order_sequence(mask, spiral[0], OrderingParams(curvature_prediction=flag))
        assert np.hypot(*(result.points[-1] - spiral[-1])) < 4.0


@settings(max_examples=25, deadline=None)
@given(
    st.floats(20, 600),
    st.floats(20, 440),
    st.floats(0, 2 * math.pi),
    st.floats(60, 400),
    st.integers(2, 6),
)
# thinning left this diagonal thread's skeleton 7 px short of its end, and the tip was taken there
@example(u=20.0, v=20.0, angle=0.75, length=60.0, width=3)
def test_any_straight_thread_is_ordered_from_either_given_end(u, v, angle, length, width):
    a = np.array([u, v])
    b = np.clip(a + length * np.array([math.cos(angle), math.sin(angle)]), [5, 5], [W - 6, H - 6])
    if np.hypot(*(b - a)) < 40:
        return
    mask = np.zeros((H, W), np.uint8)
    cv2.line(mask, tuple(np.rint(a).astype(int)), tuple(np.rint(b).astype(int)), 255, width)
    result = order_sequence(mask, a)
    assert np.hypot(*(result.points[0] - a)) <= 3.0
    assert np.hypot(*(result.points[-1] - b)) <= 3.0
    projection = (result.points - a) @ (b - a) / np.hypot(*(b - a))
    assert np.all(np.diff(projection) > 0)


def test_cleaning_fills_small_holes_and_removes_specks_only():
    mask = np.zeros((H, W), np.uint8)
    cv2.line(mask, (50, 240), (590, 240), 255, 9)
    mask[239:241, 100:102] = 0  # a 2x2 hole
    cv2.circle(mask, (320, 100), 60, 255, 3)  # a ring: its inside is no hole to fill
    mask[400:402, 400:402] = 255  # a speck
    clean = clean_mask(mask, ScaledParams.from_params(OrderingParams(), W), 1, 80).mask
    assert clean[240, 100] == 1 and clean[401, 401] == 0
    assert clean[100, 320] == 0 and clean[40, 320] == 1


def test_params_are_validated():
    with pytest.raises(ValueError, match="step_radius_px"):
        OrderingParams(step_radius_px=30)
    with pytest.raises(ValueError, match="eps1_range"):
        OrderingParams(eps1_range=(5.0, 1.0))
    with pytest.raises(ValueError, match="mu"):
        OrderingParams(mu=0.0)
    with pytest.raises(ValueError, match="stereo_fill_max_gap_px"):
        OrderingParams(stereo_fill_max_gap_px=-1.0)
    assert OrderingParams().with_updates(grid_size=1).grid_size == 1


def test_node_parameters_round_trip_to_ordering_params():
    defaults = _parameter_defaults()
    assert defaults["eps2_range"] == [0.1, 0.5] and defaults["reference_width_px"] == 640.0
    assert params_from_values(defaults) == OrderingParams()
    unscaled = params_from_values(defaults | {"reference_width_px": 0.0, "grid_size": 2})
    assert unscaled.reference_width_px is None and unscaled.grid_size == 2
