# SPDX-License-Identifier: Apache-2.0
"""Stereo pairing: row crossings, monotone selection where rows cross the thread several times, disparity."""

from __future__ import annotations

import numpy as np
import pytest

from suture_reconstruction.pairing import (
    DisparitySmoothing,
    PairingParams,
    pair_sequences,
    regularise_disparity,
    row_crossings,
)
from suture_reconstruction.sequences import resample, smooth_sequence


def test_row_crossings_are_sub_pixel_and_on_the_row():
    left = np.column_stack([np.full(11, 100.0), np.arange(10.0, 21.0) + 0.25])
    right = np.column_stack([np.linspace(70.0, 80.0, 12), np.arange(9.0, 21.0)])  # slanted, 45 deg
    ones = np.ones(len(right))
    c = row_crossings(left, right, np.zeros(len(right) - 1, bool), np.ones(len(left)), ones)
    assert np.array_equal(c.left, np.arange(10))  # the last row, 20.25, is past the right's end
    expected_u = 70.0 + (left[:10, 1] - 9.0) * 10 / 11  # linear interpolation along the right polyline
    np.testing.assert_allclose(c.u_right, expected_u)
    np.testing.assert_allclose(c.disparity, 100.0 - expected_u)
    np.testing.assert_allclose(c.t, left[:10, 1] - 9.0)


def test_horizontal_segments_and_jumps_give_no_crossing():
    left = np.array([[50.0, 5.0], [51.0, 5.5]])
    right = np.array([[20.0, 5.0], [30.0, 5.0], [31.0, 6.0], [40.0, 0.0]])
    jumps = np.array([False, False, True])
    c = row_crossings(left, right, jumps, np.ones(2), np.ones(4))
    # row 5.0: the horizontal segment crosses nothing, the vertex (30, 5) starts the next segment
    assert c.left.tolist() == [0, 1]
    assert c.u_right.tolist() == pytest.approx([30.0, 30.5])


def loop_sequences(rng: np.random.Generator, noise: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Image sequences of a thread that loops (rows cross it up to four times), with a known disparity."""
    s = np.linspace(0.0, 1.0, 4000)
    angle = 2 * np.pi * 1.15 * s
    u = 200 + 600 * s * 0.4 + 60 * np.sin(angle)
    v = 240 - 60 * np.cos(angle) + 80 * s
    disparity = 30 + 4 * np.sin(3 * np.pi * s)
    left = np.column_stack([u, v])
    right = np.column_stack([u - disparity, v])

    def sample(curve: np.ndarray) -> np.ndarray:
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(curve, axis=0), axis=1))])
        at = np.concatenate([[0.0], np.arange(rng.uniform(0, 1), arc[-1], rng.uniform(0.95, 1.05))])
        out = np.column_stack([np.interp(at, arc, curve[:, 0]), np.interp(at, arc, curve[:, 1])])
        return out + rng.normal(0, noise, out.shape)

    return sample(left), sample(right), np.column_stack([u, v, disparity])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_pairs_follow_the_thread_through_its_loop(seed):
    rng = np.random.default_rng(seed)
    left_raw, right_raw, truth = loop_sequences(rng, 0.3)
    left = resample(smooth_sequence(left_raw, 9), 1.0)
    right = resample(smooth_sequence(right_raw, 9), 1.0)
    candidates = row_crossings(
        left.points,
        right.points,
        np.zeros(len(right.points) - 1, bool),
        np.ones(len(left.points)),
        np.ones(len(right.points)),
    )
    assert np.bincount(candidates.left).max() >= 3  # rows cross the thread several times
    pairs = pair_sequences(
        left.points, left.observed, right.points, right.observed, (5.0, 80.0), PairingParams()
    )
    assert len(pairs.rows) > 0.85 * len(left.points)
    assert np.all(np.diff(pairs.t[1:-1]) > -1.0)  # monotone along the thread (up to the back tolerance)
    # each pair's disparity is that of the same stretch of thread, never another strand's
    nearest = np.argmin(
        np.linalg.norm(left.points[pairs.rows][:, None] - truth[None, ::4, :2], axis=2), axis=1
    )
    errors = pairs.disparity - truth[::4, 2][nearest]
    assert np.percentile(np.abs(errors), 95) < 2.0
    smooth = regularise_disparity(
        len(left.points), pairs.rows, pairs.disparity, pairs.weight, DisparitySmoothing()
    )
    nearest_all = np.argmin(np.linalg.norm(left.points[:, None] - truth[None, ::4, :2], axis=2), axis=1)
    assert np.mean(np.abs(smooth.value - truth[::4, 2][nearest_all])) < 0.25


def test_pairs_outside_the_disparity_limits_are_rejected():
    rng = np.random.default_rng(4)
    left_raw, right_raw, _ = loop_sequences(rng, 0.0)
    left, right = resample(left_raw, 1.0), resample(right_raw, 1.0)
    pairs = pair_sequences(
        left.points, left.observed, right.points, right.observed, (31.0, 80.0), PairingParams()
    )
    assert np.all(pairs.disparity >= 31.0) and pairs.rejected["disparity_range"] > 0


def test_regularisation_rejects_outliers_and_keeps_a_sharp_bump():
    rng = np.random.default_rng(5)
    n = 400
    x = np.arange(n, dtype=float)
    truth = 25 + 0.004 * x + 1.2 * np.exp(-0.5 * ((x - 200) / 8) ** 2)
    rows = np.arange(n)
    measured = truth + rng.normal(0, 0.2, n)
    measured[[50, 300]] += 6.0  # two wrong crossings
    result = regularise_disparity(n, rows, measured, np.ones(n), DisparitySmoothing())
    assert not result.inlier[50] and not result.inlier[300] and result.inlier.sum() >= n - 6
    away = np.abs(x - 200) > 40
    assert np.abs(result.value - truth)[away].max() < 0.1
    assert result.value[200] - result.value[150] > 0.8  # the bump (sigma 8 px) keeps two thirds of its height
    assert result.bandwidth[200] < result.bandwidth[100]  # by smoothing less there


@pytest.mark.parametrize("weak", [False, True])
def test_regularisation_follows_exact_pairs_over_a_lifted_stretch(weak):
    """Exact pairs of a 2.5 px disparity bump (a thread lifted over a crossing), on a steep
    stretch or one 5 degrees off the rows (weight 0.008): all kept, and followed to 0.2 px."""
    n = 300
    x = np.arange(n, dtype=float)
    truth = 27 + 0.003 * x + 2.5 * np.exp(-0.5 * ((x - 150) / (15 if weak else 12)) ** 2)
    weight = np.ones(n)
    if weak:
        weight[100:200] = np.sin(np.radians(5)) ** 2
    result = regularise_disparity(n, np.arange(n), truth, weight, DisparitySmoothing())
    assert result.inlier.all()
    assert np.abs(result.value - truth).max() < 0.2


def test_regularised_disparity_has_no_steps_between_scales():
    """Neighbouring samples that pick different smoothing lengths must not step the disparity
    (0.1 px is 0.4 mm of depth: a saw-tooth along the thread)."""
    n = 300
    x = np.arange(n, dtype=float)
    truth = 27 + 2.5 * np.exp(-0.5 * ((x - 150) / 12) ** 2)  # |second difference| <= 0.018 px
    for seed in range(3):
        rng = np.random.default_rng(seed)
        measured = truth + rng.normal(0, 0.2, n)
        result = regularise_disparity(n, np.arange(n), measured, np.ones(n), DisparitySmoothing())
        assert np.abs(np.diff(result.value, 2)).max() < 0.04


def test_extrapolation_is_limited():
    rows = np.arange(100, 200)
    result = regularise_disparity(
        400, rows, np.full(100, 20.0), np.ones(100), DisparitySmoothing(max_gap_px=40)
    )
    assert (
        result.supported[60:240].all()
        and not result.supported[:60].any()
        and not result.supported[240:].any()
    )
    assert np.isnan(result.value[0])
