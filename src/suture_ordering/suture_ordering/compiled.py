# SPDX-License-Identifier: Apache-2.0
"""Compiled (numba) kernels of the ordering search's innermost steps, run once or more per
search step, where numpy's per-call overhead on a few dozen values outweighs the arithmetic.

Each kernel does exactly the arithmetic of the numpy code it replaces, in the same order and
the same precision (float32 where the mask samples are float32), so that its results are the
same to the bit (``test/test_compiled.py`` compares them with numpy references on random
inputs). Compiled on first use and cached on disk (``cache=True``: later processes load the
machine code, in about 0.1 s; the first compilation takes a few seconds); :func:`warm_up` runs
when this module is imported, so no ordering pays for the compilation.
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def circle_runs(
    values: np.ndarray, spacing: float, wide: float, width_samples: float
) -> tuple[np.ndarray, np.ndarray]:
    """The cross-sections of threads on one circle of mask samples: their centres and widths.

    ``values``: (n,) float32 samples ~1 px apart along the circle (the bilinear mask, 0..1);
    ``spacing``: the arc between two samples (px); ``wide``: a run of samples above 0.5 whose
    arc (px) is larger than this is split in two (two threads side by side: one node per edge);
    ``width_samples``: the thread's width in samples (its width / ``spacing``), for the split.

    Returns ``centres`` (m,) float64, each run's weighted centre in sample indices (0..n, along
    the circle from sample 0), and ``widths`` (m,) float32, the runs' arcs (px); m = 0 when no
    sample lies above 0.5 or every sample does (the circle lies wholly inside the mask). Runs
    first in circle order, then the split runs' nodes half a width inside their first edges,
    then those inside their second edges.

    The circle is read from its emptiest sample ``k0`` on, so that no run wraps round the end;
    a run's centre is the mean of its sample indices weighted by the samples, its partial edge
    samples included; its mass (sum of those samples) is accumulated in float32 like
    ``np.cumsum`` of the float32 samples, and the moments in float64.
    """
    n = values.shape[0]
    k0 = 0
    for k in range(1, n):
        if values[k] < values[k0]:
            k0 = k
    empty_f = np.empty(0, dtype=np.float64)
    empty_w = np.empty(0, dtype=np.float32)
    if values[k0] > 0.5:
        return empty_f, empty_w
    rolled = np.empty(n, dtype=np.float32)
    for k in range(n):
        rolled[k] = values[(k0 + k) % n]
    weight = np.empty(n, dtype=np.float32)
    moment = np.empty(n, dtype=np.float64)
    edges = np.empty(n + 1, dtype=np.int64)
    count = 0
    total = np.float32(0.0)
    accumulated = 0.0
    for k in range(n):
        total = np.float32(total + rolled[k])
        weight[k] = total
        accumulated = accumulated + np.float64(rolled[k]) * np.float64(k)
        moment[k] = accumulated
        if k > 0 and (rolled[k] > 0.5) != (rolled[k - 1] > 0.5):
            edges[count] = k - 1
            count += 1
    if count == 0:
        return empty_f, empty_w
    if rolled[n - 1] > 0.5:  # a run still open at the end closes on the last sample
        edges[count] = n - 2
        count += 1
    runs = count // 2
    spacing32 = np.float32(spacing)
    wide32 = np.float32(wide)
    samples32 = np.float32(width_samples)
    middles = np.empty(runs, dtype=np.float64)
    arcs = np.empty(runs, dtype=np.float32)
    halves = np.empty(runs, dtype=np.float32)
    split = np.zeros(runs, dtype=np.bool_)
    splits = 0
    for j in range(runs):
        lo, hi = edges[2 * j], edges[2 * j + 1] + 1  # with the partial edge samples
        first = rolled[lo]
        mass = np.float32(np.float32(weight[hi] - weight[lo]) + first)
        middles[j] = (moment[hi] - moment[lo] + np.float64(first) * lo) / np.float64(mass) + k0
        arcs[j] = np.float32(mass * spacing32)
        if arcs[j] > wide32:
            split[j] = True
            halves[j] = np.float32(np.float32(mass - samples32) / np.float32(2.0))
            splits += 1
    m = runs + splits
    centres = np.empty(m, dtype=np.float64)
    widths = np.empty(m, dtype=np.float32)
    k = 0
    for j in range(runs):
        if not split[j]:
            centres[k], widths[k] = middles[j], arcs[j]
            k += 1
    for sign in (-1.0, 1.0):
        for j in range(runs):
            if split[j]:
                centres[k], widths[k] = middles[j] + sign * np.float64(halves[j]), arcs[j]
                k += 1
    return centres, widths


@numba.njit(cache=True, nogil=True)
def admissible_nodes(
    position: np.ndarray,
    delta: np.ndarray,
    width: np.ndarray,
    tau_v: float,
    consumed_flat: np.ndarray,
    zone_flat: np.ndarray,
    padded_width: int,
    pad: int,
    vertex_u: float,
    vertex_v: float,
    r: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The nodes on the circle of radius ``r`` around the vertex that may be stepped to, and O.

    ``position``: (k, 2) float64 (u, v) nodes; ``delta``: (k,) float64 their turns (rad);
    ``width``: (k,) float32 their cross-sections (px); ``consumed_flat`` and ``zone_flat``: the
    branch's traversed-path raster and the zone, flat uint8 arrays of the padded mask (rows
    ``padded_width`` long, the image offset by ``pad``).

    A node is kept when its pixel (its rounded position) lies off the path and ``delta < tau_v``.
    Returns the kept nodes' ``position``, ``delta`` and ``width``, their O (int64: the samples of
    the chord vertex -> node at fractions 1/r .. (r-1)/r that round onto a pixel outside the
    zone; 0 for r < 2), their distance ``r`` (float64) and whether O > 0 (a bridged gap).
    """
    k = position.shape[0]
    keep = np.empty(k, dtype=np.bool_)
    out = np.zeros(k, dtype=np.int64)
    offset = pad * (1 + padded_width)
    # + 0.5 then truncation: rounding (coordinates in the padded arrays are positive)
    shift_u = (vertex_u + pad) + 0.5
    shift_v = (vertex_v + pad) + 0.5
    kept = 0
    for j in range(k):
        flat = int(np.rint(position[j, 0])) + padded_width * int(np.rint(position[j, 1])) + offset
        keep[j] = consumed_flat[flat] == 0 and delta[j] < tau_v
        if not keep[j]:
            continue
        kept += 1
        if r < 2:
            continue
        du, dv = position[j, 0] - vertex_u, position[j, 1] - vertex_v
        count = 0
        for i in range(1, r):
            fraction = i / r
            u = int(fraction * du + shift_u)
            v = int(fraction * dv + shift_v)
            if zone_flat[u + padded_width * v] == 0:
                count += 1
        out[j] = count
    kept_position = np.empty((kept, 2))
    kept_delta = np.empty(kept)
    kept_width = np.empty(kept, dtype=width.dtype)
    kept_out = np.empty(kept, dtype=np.int64)
    radius = np.full(kept, float(r))
    bridge = np.empty(kept, dtype=np.bool_)
    m = 0
    for j in range(k):
        if keep[j]:
            kept_position[m, 0], kept_position[m, 1] = position[j, 0], position[j, 1]
            kept_delta[m], kept_width[m], kept_out[m] = delta[j], width[j], out[j]
            bridge[m] = out[j] > 0
            m += 1
    return kept_position, kept_delta, kept_width, kept_out, radius, bridge


@numba.njit(cache=True, nogil=True)
def circle_points(
    offsets: np.ndarray, vertex_u: float, vertex_v: float, pad: int, reach: int
) -> tuple[np.ndarray, int, int]:
    """The points where a circle around a vertex is sampled, in a window of the padded mask.

    ``offsets``: (n, 1, 2) float32 samples of the circle (:func:`suture_ordering.nodes.circle_samples`);
    ``vertex_u``, ``vertex_v``: the vertex (image pixels); ``pad``: the padding of the mask;
    ``reach``: the circle's radius (px). The window's corner (u0, v0) lies ``reach + 2`` px
    up and left of the vertex's pixel in the padded mask (an integer: the points keep their
    fractions exactly). Returns the (n, 1, 2) float32 points relative to the corner, computed as
    ``(offsets + float32(vertex + pad)) - (u0, v0)`` in float32, and u0, v0.
    """
    centre_u, centre_v = np.float32(vertex_u + pad), np.float32(vertex_v + pad)
    u0, v0 = int(centre_u) - reach - 2, int(centre_v) - reach - 2
    corner_u, corner_v = np.float32(u0), np.float32(v0)
    where = np.empty_like(offsets)
    for i in range(offsets.shape[0]):
        where[i, 0, 0] = np.float32(np.float32(offsets[i, 0, 0] + centre_u) - corner_u)
        where[i, 0, 1] = np.float32(np.float32(offsets[i, 0, 1] + centre_v) - corner_v)
    return where, u0, v0


@numba.njit(cache=True, nogil=True)
def chord_points(
    start_u: float, start_v: float, target_u: float, target_v: float
) -> tuple[np.ndarray, float, np.ndarray]:
    """A step along the chord start -> target: the chord ((2,) float64 (u, v)), its length (px)
    and its points after the start, n = max(1, ceil(length)) of them ((n, 2) float64), at the
    fractions 1/n .. n/n of the chord: ``start + fraction * chord``."""
    chord = np.empty(2)
    chord[0], chord[1] = target_u - start_u, target_v - start_v
    length = np.hypot(chord[0], chord[1])
    n = max(1, math.ceil(length))
    points = np.empty((n, 2))
    for i in range(n):
        fraction = (i + 1) / n
        points[i, 0] = start_u + fraction * chord[0]
        points[i, 1] = start_v + fraction * chord[1]
    return chord, length, points


def warm_up() -> None:
    """Compile (or load from the cache) every kernel, so that no search pays for it."""
    circle_runs(np.array([0.0, 1.0, 1.0, 0.0], dtype=np.float32), 1.0, np.inf, 0.0)
    circle_points(np.zeros((8, 1, 2), dtype=np.float32), 0.0, 0.0, 2, 1)
    chord_points(0.0, 0.0, 1.0, 1.0)
    raster = np.zeros(25, dtype=np.uint8)
    admissible_nodes(
        np.full((1, 2), 2.0),
        np.zeros(1),
        np.ones(1, dtype=np.float32),
        1.0,
        raster,
        raster,
        5,
        0,
        0.0,
        0.0,
        2,
    )


warm_up()
