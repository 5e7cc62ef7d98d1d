# SPDX-License-Identifier: Apache-2.0
"""ordering_success: the docs/interfaces.md ordering criterion on hand-made truths and predictions."""

from __future__ import annotations

import numpy as np
import pytest

from suture_bench.ordering_metrics import ordering_success


def straight_truth(length: float = 300.0, hidden: tuple[int, int] | None = None) -> np.ndarray:
    """(N, 3) truth along y = 100 from x = 50, 1 px apart; ``hidden`` = (first, last) invisible samples."""
    x = np.arange(50.0, 50.0 + length + 1)
    truth = np.column_stack([x, np.full_like(x, 100.0), np.ones_like(x)])
    if hidden is not None:
        truth[hidden[0] : hidden[1] + 1, 2] = 0.0
    return truth


def loop_truth() -> np.ndarray:
    """A prolate cycloid with one self-crossing, ~1 px apart, all visible."""
    t = np.linspace(-1.1 * np.pi, 1.1 * np.pi, 20000)
    curve = np.column_stack([320 + 45 * t - 70 * np.sin(t), 240 - 70 * np.cos(t)])
    arc = np.r_[0, np.cumsum(np.hypot(*np.diff(curve, axis=0).T))]
    at = np.arange(0, arc[-1], 1.0)
    points = np.column_stack([np.interp(at, arc, curve[:, 0]), np.interp(at, arc, curve[:, 1])])
    return np.column_stack([points, np.ones(len(points))])


def test_the_truth_itself_succeeds():
    truth = straight_truth()
    score = ordering_success(truth[:, :2], truth)
    assert score.success and score.reason == "ok"
    assert (
        score.tip_error_px == 0 and score.max_deviation_px < 0.3 and score.coverage > 0.99 and score.in_order
    )


def test_a_sparse_prediction_is_resampled():
    truth = straight_truth()
    score = ordering_success(truth[::8, :2], truth)
    assert score.success, score.reason


def test_tip_more_than_5_px_away_fails():
    truth = straight_truth()
    assert ordering_success(truth[4:, :2], truth).success  # 4 px
    score = ordering_success(truth[6:, :2], truth)
    assert not score.success and "cut tip" in score.reason and score.tip_error_px == pytest.approx(6)


def test_leaving_the_corridor_fails():
    truth = straight_truth()
    predicted = truth[:, :2].copy()
    predicted[100:140, 1] += 2.8
    assert ordering_success(predicted, truth).success
    predicted[100:140, 1] += 0.5
    score = ordering_success(predicted, truth)
    assert not score.success and "leaves the true centreline" in score.reason
    assert score.max_deviation_px == pytest.approx(3.3, abs=0.05)


def test_reversed_order_fails():
    truth = straight_truth()
    predicted = np.vstack([truth[:150, :2], truth[100:50:-1, :2], truth[150:, :2]])
    score = ordering_success(predicted, truth)
    assert not score.success and not score.in_order and "backwards" in score.reason


def test_coverage_below_90_percent_fails():
    truth = straight_truth(300)
    assert ordering_success(truth[:275, :2], truth).success  # 91 %
    score = ordering_success(truth[:260, :2], truth)
    assert (
        not score.success
        and score.coverage == pytest.approx(259 / 300, abs=0.01)
        and "covers" in score.reason
    )


def test_hidden_stretches_do_not_count_but_must_be_passed_on_the_thread():
    truth = straight_truth(300, hidden=(120, 180))  # 61 hidden samples
    visible_part = np.vstack([truth[:120, :2], truth[181:, :2]])
    jump = ordering_success(visible_part, truth)  # jumps over the hidden stretch
    assert jump.success and jump.coverage > 0.99
    detour = truth[:, :2].copy()
    detour[130:170, 1] += 5.0  # a bridge that runs 5 px off where the hidden thread is
    assert not ordering_success(detour, truth).success


def test_a_jump_over_visible_thread_costs_coverage():
    truth = straight_truth(300)
    skipping = np.vstack([truth[:100, :2], truth[160:, :2]])  # skips 60 visible px (20 %)
    score = ordering_success(skipping, truth)
    assert not score.success and score.coverage == pytest.approx(0.8, abs=0.01)


def test_a_loop_is_mapped_through_its_own_crossing():
    truth = loop_truth()
    assert ordering_success(truth[:, :2], truth).success
    # Skipping the loop: from the crossing straight on to the second pass.
    points = truth[:, :2]
    i, j = np.unravel_index(
        np.argmin(
            np.where(
                np.abs(np.arange(len(points))[:, None] - np.arange(len(points))) > 50,
                np.hypot(*(points[:, None] - points[None]).transpose(2, 0, 1)),
                np.inf,
            )
        ),
        (len(points), len(points)),
    )
    first, second = sorted((int(i), int(j)))
    skipped = np.vstack([points[:first], points[second:]])
    score = ordering_success(skipped, truth)
    assert not score.success and "covers" in score.reason


def test_a_sequence_on_another_thread_fails():
    truth = straight_truth(300)
    wrong = np.vstack([truth[:150, :2], np.column_stack([np.full(100, 200.0), 100 + np.arange(1, 101)])])
    assert not ordering_success(wrong, truth).success


def test_empty_and_malformed_inputs():
    truth = straight_truth()
    empty = ordering_success(np.zeros((0, 2)), truth)
    assert not empty.success and empty.reason == "empty predicted sequence"
    with pytest.raises(ValueError, match="predicted"):
        ordering_success(np.zeros((5, 3)), truth)
    with pytest.raises(ValueError, match="truth"):
        ordering_success(truth[:, :2], truth[:, :2])
    with pytest.raises(ValueError, match="NaN"):
        ordering_success(np.full((3, 2), np.nan), truth)
