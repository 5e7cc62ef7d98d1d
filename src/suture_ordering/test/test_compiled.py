# SPDX-License-Identifier: Apache-2.0
"""The compiled kernels give, to the bit, what the numpy code they replace gave."""

from __future__ import annotations

import math

import numpy as np
import pytest

from suture_ordering.compiled import admissible_nodes, chord_points, circle_points, circle_runs
from suture_ordering.nodes import circle_samples


def _circle_runs_numpy(
    values: np.ndarray, spacing: float, width: float | None, factor: float
) -> tuple[list[float], list[np.float32]] | None:
    """The numpy reading of one circle that :func:`circle_runs` replaces."""
    n = len(values)
    index = np.arange(n, dtype=np.float64)
    k0 = int(values.argmin())
    if values[k0] > 0.5:
        return None
    rolled = np.concatenate((values[k0:], values[:k0]))
    inside = rolled > 0.5
    edges = (inside[1:] != inside[:-1]).nonzero()[0].tolist()
    if not edges:
        return None
    if inside[-1]:
        edges.append(n - 2)
    weight = rolled.cumsum()
    moment = (rolled * index).cumsum()
    centres, widths, split = [], [], []
    for start, end in zip(edges[0::2], edges[1::2], strict=True):
        lo, hi = start, end + 1
        first = rolled[lo]
        mass = weight[hi] - weight[lo] + first
        middle = (float(moment[hi]) - float(moment[lo]) + float(first) * lo) / float(mass) + k0
        arc = mass * spacing
        if width is not None and arc > factor * width:
            split.append((middle, arc, (mass - width / spacing) / 2))
        else:
            centres.append(middle)
            widths.append(arc)
    centres += [middle - float(half) for middle, _, half in split]
    centres += [middle + float(half) for middle, _, half in split]
    widths += [arc for _, arc, _ in split] * 2
    return centres, widths


@pytest.mark.parametrize("seed", range(40))
def test_circle_runs_matches_numpy(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(8, 160))
    # Runs of mask with soft edges, as the bilinear samples of a mask give them.
    values = (rng.random(n) < rng.uniform(0.1, 0.9)).astype(np.float32)
    soft = rng.random(n) < 0.3
    values[soft] = rng.random(int(np.count_nonzero(soft)))
    if seed % 10 == 0:
        values = np.full(n, 0.75, dtype=np.float32)  # a circle inside the mask
    spacing = 2 * math.pi * rng.uniform(2, 25) / n
    for width in (None, float(rng.uniform(0.5, 6.0))):
        expected = _circle_runs_numpy(values, spacing, width, 1.6)
        wide, samples = (math.inf, 0.0) if width is None else (1.6 * width, width / spacing)
        centres, widths = circle_runs(values, spacing, wide, samples)
        if expected is None:
            assert len(centres) == 0 and len(widths) == 0
            continue
        np.testing.assert_array_equal(centres, np.array(expected[0]))
        np.testing.assert_array_equal(widths, np.array(expected[1], dtype=np.float32))
        assert widths.dtype == np.float32


@pytest.mark.parametrize("seed", range(20))
def test_admissible_nodes_match_numpy(seed: int) -> None:
    rng = np.random.default_rng(seed)
    pad, height, width = 12, 40, 50
    zone = (rng.random((height + 2 * pad, width + 2 * pad)) < 0.6).astype(np.uint8)
    consumed = (rng.random(zone.shape) < 0.3).astype(np.uint8)
    padded_width = zone.shape[1]
    vertex = rng.uniform(10, 35, 2)
    r = int(rng.integers(1, 9))
    angle = rng.uniform(0, 2 * math.pi, int(rng.integers(1, 7)))
    position = vertex + r * np.column_stack((np.cos(angle), np.sin(angle)))
    delta = rng.uniform(0, math.pi, len(angle))
    widths = rng.uniform(1, 5, len(angle)).astype(np.float32)
    found = admissible_nodes(
        position,
        delta,
        widths,
        2.0,
        consumed.ravel(),
        zone.ravel(),
        padded_width,
        pad,
        vertex[0],
        vertex[1],
        r,
    )
    weights = np.array([1, padded_width])
    flat = np.rint(position).astype(np.intp).dot(weights) + pad * (1 + padded_width)
    keep = (consumed.ravel()[flat] == 0) & (delta < 2.0)
    if r < 2:
        out = np.zeros(int(keep.sum()), dtype=np.int64)
    else:
        samples = (np.arange(1, r) / r)[None, :, None] * (position[keep] - vertex)[:, None, :]
        samples += vertex + pad + 0.5
        out = (zone.ravel()[samples.astype(np.intp).dot(weights)] == 0).sum(axis=1)
    expected = (position[keep], delta[keep], widths[keep], out, np.full(len(out), float(r)), out > 0)
    for got, want in zip(found, expected, strict=True):
        assert got.dtype == want.dtype
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("seed", range(10))
def test_circle_points_matches_numpy(seed: int) -> None:
    rng = np.random.default_rng(seed)
    for _ in range(50):
        r, pad = int(rng.integers(1, 30)), int(rng.integers(30, 80))
        vertex = rng.uniform(0, 1300, 2)
        offsets = circle_samples(r)[0]
        where, u0, v0 = circle_points(offsets, vertex[0], vertex[1], pad, r)
        centre = (vertex + pad).astype(np.float32)
        assert (u0, v0) == (int(centre[0]) - r - 2, int(centre[1]) - r - 2)
        expected = offsets + centre
        expected -= np.array((u0, v0), dtype=np.float32)
        np.testing.assert_array_equal(where, expected)
        assert where.dtype == np.float32


def test_chord_points_match_numpy() -> None:
    rng = np.random.default_rng(0)
    for _ in range(2000):
        start = rng.uniform(-50, 700, 2)
        target = start + rng.normal(0, rng.choice([0.3, 3.0, 30.0]), 2)
        chord, length, points = chord_points(start[0], start[1], target[0], target[1])
        expected_chord = target - start
        expected_length = float(np.hypot(*expected_chord))
        n = max(1, math.ceil(expected_length))
        np.testing.assert_array_equal(chord, expected_chord)
        assert length == expected_length
        np.testing.assert_array_equal(points, start + (np.arange(1, n + 1) / n)[:, None] * expected_chord)
