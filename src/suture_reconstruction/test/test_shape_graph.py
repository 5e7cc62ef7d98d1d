# SPDX-License-Identifier: Apache-2.0
"""Algorithm 1 (Eq. 8-12): the sparse implementation against a literal dense one, and the self-crossing."""

from __future__ import annotations

import numpy as np
import pytest

from suture_reconstruction.errors import TooFewPointsError
from suture_reconstruction.shape_graph import (
    ShapeGraphParams,
    optimise_shape,
    order_penalty,
    vertex_penalties,
)


def dense_algorithm_1(vertices: np.ndarray, params: ShapeGraphParams) -> tuple[list[int], float, float]:
    """Algorithm 1 written out literally with w1 x w1 matrices and a textbook O(n^2) Dijkstra.

    Lengths in mm (the module's unit choice). Returns (path, tau_L in m, L_min).
    """
    v = vertices * 1000.0
    n = len(v)
    radius, nu1 = params.upsilon3 * 1000.0, params.nu1 * 1000.0
    distance = np.sqrt(((v[:, None, :] - v[None, :, :]) ** 2).sum(axis=2))
    p1 = np.empty(n)
    for t in range(n):  # for V^t: the vertices within the sphere of radius Upsilon_3, then Eq. 9
        inside = [j for j in range(n) if j != t and distance[t, j] <= radius]
        if inside:
            count = len(inside)
            p1[t] = (
                params.scale
                / count
                * np.exp(-count / (2 * params.sigma1))
                * sum(np.log(distance[t, j] + nu1) for j in inside)
            )
        else:
            p1[t] = params.scale * np.log(radius + nu1)
    weights = np.ones((n, n))  # W_G, diagonal 1
    for i in range(n):
        for t in range(n):
            if i != t:
                order = abs(i - t) / params.order_scale - params.order_offset  # Eq. 11: / 20 - 2
                weights[i, t] = p1[i] * p1[t] * (1 + np.exp(order))  # Eq. 10, 11, 12
    tau = params.tau_l * 1000.0
    while True:
        lengths = np.where(distance <= tau, distance, np.inf)  # D_G, Eq. 8
        np.fill_diagonal(lengths, np.inf)
        graph = np.maximum(lengths * weights, 1e-12)  # Hadamard product (and the module's cost floor)
        best = np.full(n, np.inf)
        best[0] = 0.0
        previous = np.full(n, -1)
        done = np.zeros(n, dtype=bool)
        for _ in range(n):
            open_ = np.where(done, np.inf, best)
            u = int(np.argmin(open_))
            if not np.isfinite(open_[u]):
                break
            done[u] = True
            for w in range(n):
                if not done[w] and best[u] + graph[u, w] < best[w]:
                    best[w] = best[u] + graph[u, w]
                    previous[w] = u
        if np.isfinite(best[n - 1]):
            break
        tau += params.tau_step * 1000.0
    path = [n - 1]
    while path[-1] != 0:
        path.append(int(previous[path[-1]]))
    return path[::-1], tau / 1000.0, float(best[n - 1])


def noisy_chain(rng: np.random.Generator, n: int, step: float, noise: float) -> np.ndarray:
    """A wavy 3D chain of n vertices about ``step`` m apart with ``noise`` m of jitter (a zig-zag thread)."""
    s = np.arange(n) * step
    chain = np.column_stack([s, 0.004 * np.sin(s / 0.006), 0.08 + 0.002 * np.cos(s / 0.009)])
    return chain + rng.normal(0.0, noise, chain.shape)


@pytest.mark.parametrize("seed", range(6))
def test_sparse_equals_literal_dense_implementation(seed):
    rng = np.random.default_rng(seed)
    vertices = noisy_chain(rng, int(rng.integers(20, 70)), 2e-4, 1e-4)
    params = ShapeGraphParams(
        tau_l=float(rng.uniform(0.0004, 0.0012)), upsilon3=float(rng.uniform(5e-4, 1.5e-3))
    )
    result = optimise_shape(vertices, params)
    path, tau, cost = dense_algorithm_1(vertices, params)
    assert result.indices.tolist() == path
    assert result.tau_l == pytest.approx(tau)
    assert result.cost == pytest.approx(cost, rel=1e-9)


def test_tau_growth_matches_the_literal_loop_across_a_gap():
    rng = np.random.default_rng(11)
    vertices = noisy_chain(rng, 40, 2e-4, 5e-5)
    vertices[20:] += np.array([0.0031, 0.0, 0.0])  # a 3.1 mm gap: tau_L must grow from 0.5 mm
    params = ShapeGraphParams(tau_l=0.0005)
    result = optimise_shape(vertices, params)
    path, tau, _ = dense_algorithm_1(vertices, params)
    assert result.steps == round((tau - params.tau_l) / params.tau_step) > 0
    assert result.tau_l == pytest.approx(tau)
    assert result.indices.tolist() == path


def test_vertex_penalties_follow_eq_9():
    vertices = np.array([[0.0, 0, 0], [0.0004, 0, 0], [0.0010, 0, 0], [0.0100, 0, 0]])
    params = ShapeGraphParams(upsilon3=0.001, sigma1=5.0, scale=2.0, nu1=0.001)
    p1 = vertex_penalties(vertices * 1000, params)
    # vertex 0 sees 0.4 mm and 1.0 mm (on the sphere: included), vertex 3 sees nobody
    expected0 = 2.0 / 2 * np.exp(-2 / 10) * (np.log(0.4 + 1) + np.log(1.0 + 1))
    assert p1[0] == pytest.approx(expected0)
    assert p1[3] == pytest.approx(2.0 * np.log(1.0 + 1.0))
    assert order_penalty(np.array(0), np.array(40), params) == pytest.approx(1 + np.exp(40 / 3 - 2))


def loop_with_close_strands(gap: float, step: float = 1e-4) -> tuple[np.ndarray, int, int]:
    """A thread that makes one loop (turning 2 pi + 0.8 rad, loop radius ~6 mm) and crosses itself at ~45 deg.

    The later strand is lifted towards the camera near the crossing so that the two
    strands' axes pass ``gap`` m apart in 3D. Returns the vertices every ``step`` m
    and the indices of the two strands at the crossing.
    """
    length = 0.09
    s = np.arange(0.0, length, step)
    bump = np.exp(-0.5 * ((s - length / 2) / 0.012) ** 2)
    curvature = bump * (2 * np.pi + 0.8) / (bump.sum() * step)
    heading = np.cumsum(curvature) * step
    xy = np.cumsum(np.column_stack([np.cos(heading), np.sin(heading)]) * step, axis=0)
    far = np.abs(np.arange(len(s))[:, None] - np.arange(len(s))[None, :]) > 150
    planar = np.linalg.norm(xy[:, None] - xy[None, :], axis=2)
    i, j = np.unravel_index(np.argmin(np.where(far, planar, np.inf)), planar.shape)
    i, j = min(i, j), max(i, j)
    z = 0.1 - gap * np.exp(-0.5 * ((s - s[j]) / 0.003) ** 2)
    return np.column_stack([xy, z]), int(i), int(j)


@pytest.mark.parametrize("gap", [9e-4, 5e-4, 1e-4])
def test_dijkstra_never_takes_the_short_cut_across_a_self_crossing(gap):
    vertices, i, j = loop_with_close_strands(gap)
    assert j - i > 250  # the strands meet after more than 25 mm of thread (the loop)
    closest = np.linalg.norm(vertices[i] - vertices[j])
    assert closest <= 1e-3  # the two strands pass within 1 mm of each other in 3D
    result = optimise_shape(vertices, ShapeGraphParams(tau_l=0.001))
    assert result.tau_l == pytest.approx(0.001)  # the crossing edges exist from the start
    # The path never jumps along the thread by more than the vertices one edge can span...
    assert np.diff(result.indices).max() <= 12
    # ...so it goes round the loop: its length is the thread's, not the short cut's.
    thread = np.linalg.norm(np.diff(vertices, axis=0), axis=1).sum()
    assert result.length == pytest.approx(thread, rel=0.01)


def test_short_cut_would_be_taken_without_the_order_penalty():
    """The test above is meaningful: with a flat order penalty the crossing edge is the cheaper way."""
    vertices, _, _ = loop_with_close_strands(1e-4)
    flat = ShapeGraphParams(tau_l=0.001, order_scale=1e9, order_offset=0.0)
    result = optimise_shape(vertices, flat)
    assert np.diff(result.indices).max() > 100


def hairpin_at_the_tip(arm: float, gap: float = 3e-4, step: float = 1e-4) -> np.ndarray:
    """A cut end that runs ``arm`` m, bends back round a half circle of diameter ``gap`` m (the
    two arms touching: a hairpin) and goes on past the tip for 60 mm, every ``step`` m."""
    out = np.arange(0.0, arm, step)
    bend = np.linspace(0.0, np.pi, max(3, int(np.pi * gap / 2 / step)))
    back = np.arange(0.0, arm + 0.06, step)
    xy = np.vstack(
        [
            np.column_stack([-out, np.zeros_like(out)]),
            np.column_stack([-arm - gap / 2 * np.sin(bend), gap / 2 * (1 - np.cos(bend))]),
            np.column_stack([-arm + back, np.full_like(back, gap)]),
        ]
    )
    return np.column_stack([xy, np.full(len(xy), 0.1)])


@pytest.mark.parametrize("arm", [1e-3, 3e-3, 8e-3])
def test_dijkstra_goes_round_a_hairpin_at_the_tip(arm):
    """The arms of a hook at the cut end touch for its whole length; the path goes round the
    bend instead of across, keeping the arc length from the tip (where the grasp point is) up to
    the bend's own rounding: within 1 mm of the bend, crossing between the arms is cheaper than
    the half circle, whatever the arms' length."""
    rng = np.random.default_rng(5)
    vertices = hairpin_at_the_tip(arm) + rng.normal(0.0, 3e-5, (1, 3))
    result = optimise_shape(vertices)
    thread = np.linalg.norm(np.diff(vertices, axis=0), axis=1).sum()
    assert thread - 1.5e-3 < result.length <= thread
    across = ShapeGraphParams(order_scale=20.0)  # a gentler order penalty cuts across
    assert optimise_shape(vertices, across).length < thread - arm


def test_removes_zig_zags_and_keeps_the_ends():
    rng = np.random.default_rng(3)
    vertices = noisy_chain(rng, 200, 1e-4, 1.5e-4)
    result = optimise_shape(vertices)
    assert result.indices[0] == 0 and result.indices[-1] == len(vertices) - 1
    assert np.all(
        np.diff(result.indices) > -3
    )  # it may step back one vertex where the noise exceeds the spacing
    zigzag = np.linalg.norm(np.diff(vertices, axis=0), axis=1).sum()
    assert result.length < 0.8 * zigzag


def test_too_few_vertices():
    with pytest.raises(TooFewPointsError):
        optimise_shape(np.zeros((1, 3)))


def test_the_apex_of_a_tight_hairpin_is_not_cut():
    # A cut end bent into a hairpin of radius 0.3 mm (the arms 0.6 mm apart, their vertices
    # dense where they touch): the path goes round the apex instead of across it.
    radius, step = 0.0003, 1e-4
    arm = np.column_stack([np.arange(0.0, 0.005, step), np.zeros(50)])
    angle = np.arange(step / radius, np.pi, step / radius)
    bend = np.column_stack([0.005 + radius * np.sin(angle), radius - radius * np.cos(angle)])
    back = np.column_stack([np.arange(0.005, -0.02, -step), np.full(250, 2 * radius)])
    planar = np.vstack([arm, bend, back])
    vertices = np.column_stack([planar, np.full(len(planar), 0.1)])
    length = float(np.linalg.norm(np.diff(vertices, axis=0), axis=1).sum())
    result = optimise_shape(vertices)
    assert result.length == pytest.approx(length, abs=2e-4)
    assert len(vertices) - len(result.indices) <= 2
