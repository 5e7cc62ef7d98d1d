# SPDX-License-Identifier: Apache-2.0
"""Suture centreline shapes: planar curves by topology, crossings, and lifting onto a tissue surface.

A thread is first drawn as a planar curve (arrays of shape (N, 2), metres) by
integrating a smooth random curvature profile, so its length is exact and its
shape is smooth. The curve is then lifted onto the tissue surface
(``lift_onto_surface``) and, where two strands cross, the upper strand is raised
so that the two threads touch instead of passing through each other
(``raise_over_crossings``). ``hooked_curve`` and ``along_rows_curve`` draw the
shapes of the hard topologies. Everything is numpy-vectorised and deterministic
under the ``np.random.Generator`` passed in.

Units: metres everywhere; curvature in 1/m; angles in radians.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.spatial import cKDTree

#: Spacing of the dense centreline samples, metres. Fine enough that a 1280x1024
#: view at 50 mm sees at most ~2 px between samples.
SAMPLE_STEP = 1e-4


class ShapeError(RuntimeError):
    """A random shape could not satisfy its constraints (caller retries with new draws)."""


@dataclass(frozen=True)
class Crossing:
    """Where a thread passes over another strand (of itself or of another thread).

    ``s_first``/``s_second`` are arc lengths (m) on the two strands; ``angle`` is the
    crossing angle in [0, pi/2] (rad).
    """

    s_first: float
    s_second: float
    point: np.ndarray
    angle: float


def planar_curve(length: float, curvature: np.ndarray, heading: float = 0.0) -> np.ndarray:
    """Integrate a curvature profile into an (N, 2) planar curve starting at the origin.

    ``curvature`` holds N samples (1/m) at spacing ``length / (N - 1)``.
    """
    n = curvature.size
    step = length / (n - 1)
    theta = heading + np.concatenate([[0.0], np.cumsum(0.5 * (curvature[1:] + curvature[:-1]) * step)])
    increments = np.stack([np.cos(theta), np.sin(theta)], axis=1) * step
    return np.concatenate([np.zeros((1, 2)), np.cumsum(0.5 * (increments[1:] + increments[:-1]), axis=0)])


def smooth_noise(n: int, correlation_samples: float, rng: np.random.Generator) -> np.ndarray:
    """Zero-mean, unit-std smooth random profile of n samples."""
    raw = gaussian_filter1d(rng.standard_normal(n), correlation_samples, mode="reflect")
    return (raw - raw.mean()) / (raw.std() + 1e-12)


def curvature_profile(topology: str, length: float, rng: np.random.Generator) -> np.ndarray:
    """A random curvature profile (1/m) for ``topology``, sampled every ``SAMPLE_STEP``.

    * ``straight``: total turning below ~15 degrees.
    * ``curved``: gentle bends, 60 to 270 degrees of total absolute turning.
    * ``loop``: a curved base plus one bump of 2*pi + 0.4..1.3 rad turning, which
      makes the curve cross itself once.
    """
    n = round(length / SAMPLE_STEP) + 1
    s = np.linspace(0.0, length, n)
    if topology == "straight":
        kappa = smooth_noise(n, n / 4, rng)
        return kappa * np.radians(rng.uniform(2, 15)) / (np.abs(kappa).mean() * length + 1e-12)
    base = smooth_noise(n, 0.02 / SAMPLE_STEP, rng) + rng.uniform(-0.6, 0.6)
    if topology == "curved":
        turning = np.radians(rng.uniform(60, 270))
        return base * turning / (np.abs(base).mean() * length)
    if topology == "loop":
        base *= np.radians(rng.uniform(20, 90)) / (np.abs(base).mean() * length)
        radius = rng.uniform(0.006, 0.012)
        loop_length = 2 * np.pi * radius
        centre = rng.uniform(0.35, 0.65) * length
        bump = np.exp(-0.5 * ((s - centre) / (loop_length / 4)) ** 2)
        turning = 2 * np.pi + rng.uniform(0.4, 1.3)
        bump *= turning / (bump.sum() * SAMPLE_STEP)
        return base + rng.choice([-1.0, 1.0]) * bump
    raise ValueError(f"unknown curvature topology {topology!r}")


def find_crossings(
    first: np.ndarray, second: np.ndarray | None = None, min_arc_separation: float = 0.004
) -> list[Crossing]:
    """Crossings of two (N, 2) polylines, or self-crossings of ``first`` when ``second`` is None.

    Self-crossings need the two strands to be at least ``min_arc_separation`` metres apart
    along the thread. Segments are tested exactly after a k-d tree pre-selection.
    """
    other = first if second is None else second
    a0, a1 = first[:-1], first[1:]
    b0, b1 = other[:-1], other[1:]
    seg_a = np.linalg.norm(a1 - a0, axis=1)
    seg_b = np.linalg.norm(b1 - b0, axis=1)
    reach = float(max(seg_a.max(), seg_b.max()))
    pairs = cKDTree(0.5 * (a0 + a1)).query_ball_tree(cKDTree(0.5 * (b0 + b1)), r=reach)
    i_idx = np.repeat(np.arange(len(pairs)), [len(p) for p in pairs])
    j_idx = np.concatenate([np.asarray(p, dtype=int) for p in pairs]) if i_idx.size else np.zeros(0, int)
    if second is None:
        keep = j_idx > i_idx + int(np.ceil(min_arc_separation / SAMPLE_STEP))
        i_idx, j_idx = i_idx[keep], j_idx[keep]
    if i_idx.size == 0:
        return []
    da, db = a1[i_idx] - a0[i_idx], b1[j_idx] - b0[j_idx]
    offset = b0[j_idx] - a0[i_idx]
    denom = da[:, 0] * db[:, 1] - da[:, 1] * db[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (offset[:, 0] * db[:, 1] - offset[:, 1] * db[:, 0]) / denom
        u = (offset[:, 0] * da[:, 1] - offset[:, 1] * da[:, 0]) / denom
    hit = (np.abs(denom) > 1e-18) & (t >= 0) & (t < 1) & (u >= 0) & (u < 1)
    angles = np.arccos(np.clip(np.abs(np.sum(da * db, axis=1)) / (seg_a[i_idx] * seg_b[j_idx]), 0.0, 1.0))
    return [
        Crossing(
            s_first=float((i + ti) * SAMPLE_STEP),
            s_second=float((j + uj) * SAMPLE_STEP),
            point=a0[i] + ti * (a1[i] - a0[i]),
            angle=float(angle),
        )
        for i, j, ti, uj, angle in zip(i_idx[hit], j_idx[hit], t[hit], u[hit], angles[hit], strict=True)
    ]


def has_close_approach(
    first: np.ndarray,
    second: np.ndarray | None,
    crossings: list[Crossing],
    distance: float,
    crossing_exclusion: float = 0.005,
) -> bool:
    """True when two curves (or one curve and itself) come closer than ``distance`` anywhere
    except within ``crossing_exclusion`` metres of arc from one of ``crossings``.

    Near-tangent touches are what makes crossings ambiguous; the simulator rejects them so
    every crossing in a bag is a clear one. Self tests ignore samples less than 6 mm apart
    along the thread.
    """
    stride = 5  # test every 0.5 mm
    a = first[::stride]
    b = a if second is None else second[::stride]
    pairs = cKDTree(a).sparse_distance_matrix(cKDTree(b), distance, output_type="ndarray")
    i = pairs["i"] * stride * SAMPLE_STEP
    j = pairs["j"] * stride * SAMPLE_STEP
    keep = np.ones(i.size, dtype=bool) if second is not None else (j - i) > 0.006
    for crossing in crossings:
        near_first = np.abs(i - crossing.s_first) < crossing_exclusion
        near_second = np.abs(j - crossing.s_second) < crossing_exclusion
        keep &= ~(near_first & near_second)
        if second is None:  # a self pair may be listed either way round
            keep &= ~(np.abs(j - crossing.s_first) < crossing_exclusion) | ~(
                np.abs(i - crossing.s_second) < crossing_exclusion
            )
    return bool(np.any(keep))


def rotate(points: np.ndarray, angle: float) -> np.ndarray:
    """Rotate (N, 2) points by ``angle`` radians about the origin."""
    c, s = np.cos(angle), np.sin(angle)
    return points @ np.array([[c, s], [-s, c]])


def tangent_at(curve: np.ndarray, arc: float) -> np.ndarray:
    """Unit tangent (2,) of an (N, 2) curve sampled every SAMPLE_STEP, at arc length ``arc``."""
    i = int(np.clip(round(arc / SAMPLE_STEP), 1, len(curve) - 2))
    d = curve[i + 1] - curve[i - 1]
    return d / np.linalg.norm(d)


def lift_onto_surface(
    curve: np.ndarray,
    surface_depth: Callable[[np.ndarray, np.ndarray], np.ndarray],
    radius: float,
    lift: np.ndarray,
) -> np.ndarray:
    """(N, 3) centreline: planar (x, y) samples resting on the surface, raised by ``lift``.

    ``surface_depth(x, y)`` gives the tissue depth z (m) under a point; the camera looks
    along +z, so "above the tissue" means a smaller z. The axis sits ``radius`` above the
    surface plus ``lift`` (N,) metres.
    """
    z = surface_depth(curve[:, 0], curve[:, 1]) - radius - lift
    return np.column_stack([curve, z])


def raise_over_crossings(
    lifts: list[np.ndarray],
    base_depths: list[np.ndarray],
    crossings: list[tuple[int, int, Crossing]],
    radii: list[float],
    rng: np.random.Generator,
) -> list[tuple[int, int, Crossing]]:
    """Raise the upper strand at each crossing so that it rests on the lower one.

    Thread k's axis depth is ``base_depths[k] - lifts[k]`` (both (N_k,), metres).
    ``crossings`` lists (thread_a, thread_b, crossing); which strand goes over is drawn at
    random. A Gaussian bump (sigma 2..4 mm of arc) is added to the upper strand's lift so
    that its axis is r_a + r_b + 0.05 mm nearer the camera than the lower axis. ``lifts``
    is updated in place. Returns (upper_thread, lower_thread, crossing) with
    ``crossing.s_first`` on the upper strand.
    """
    ordered = []
    for thread_a, thread_b, crossing in crossings:
        over_first = rng.random() < 0.5
        upper, lower = (thread_a, thread_b) if over_first else (thread_b, thread_a)
        s_upper, s_lower = (
            (crossing.s_first, crossing.s_second) if over_first else (crossing.s_second, crossing.s_first)
        )
        iu = min(round(s_upper / SAMPLE_STEP), lifts[upper].size - 1)
        il = min(round(s_lower / SAMPLE_STEP), lifts[lower].size - 1)
        z_upper = base_depths[upper][iu] - lifts[upper][iu]
        z_lower = base_depths[lower][il] - lifts[lower][il]
        deficit = z_upper - z_lower + radii[upper] + radii[lower] + 5e-5
        if deficit > 0:
            s = np.arange(lifts[upper].size) * SAMPLE_STEP
            sigma = rng.uniform(0.002, 0.004)
            lifts[upper] += deficit * np.exp(-0.5 * ((s - s_upper) / sigma) ** 2)
        ordered.append((upper, lower, Crossing(s_upper, s_lower, crossing.point, crossing.angle)))
    return ordered


def random_lift(length_samples: int, rng: np.random.Generator) -> np.ndarray:
    """Where the thread drapes off the tissue: zero, or one or two smooth bumps of 1..6 mm."""
    lift = np.zeros(length_samples)
    s = np.arange(length_samples)
    for _ in range(rng.choice([0, 1, 1, 2])):
        centre = rng.uniform(0.15, 1.0) * length_samples
        width = rng.uniform(0.004, 0.015) / SAMPLE_STEP
        lift += rng.uniform(0.001, 0.006) * np.exp(-0.5 * ((s - centre) / width) ** 2)
    return lift


def resample_by_arc_length(points: np.ndarray, step: float = SAMPLE_STEP) -> np.ndarray:
    """Resample an (N, D) polyline at uniform arc-length ``step``; keeps both ends' positions
    up to the last whole step."""
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    cumulative = np.concatenate([[0.0], np.cumsum(seg)])
    targets = np.arange(0.0, cumulative[-1] + 1e-12, step)
    return np.column_stack([np.interp(targets, cumulative, points[:, k]) for k in range(points.shape[1])])


def arc_length(points: np.ndarray) -> float:
    """Length (m) of an (N, D) polyline."""
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())


@dataclass(frozen=True)
class Hook:
    """The curled cut end of a ``hooked`` thread; arc lengths (m) from the cut tip.

    ``bend_radius`` is the tightest radius of the bend; the bend ends at ``bend_end``;
    beyond ``free_from`` the thread no longer runs alongside its own tip arm.
    ``crossing`` tells a hook whose tip arm is crossed by the thread from a hairpin
    whose arms lie side by side.
    """

    bend_radius: float
    bend_end: float
    free_from: float
    crossing: bool


#: Where a hook may curl: its bend ends within this arc (m) of the cut tip.
HOOK_REACH = 0.015


def hooked_curve(length: float, thread_radius: float, rng: np.random.Generator) -> tuple[np.ndarray, Hook]:
    """(N, 2) planar curve from the cut tip, sampled every ``SAMPLE_STEP``, whose cut end
    curls into a hook or hairpin ending within ``HOOK_REACH`` of the tip.

    A straight tip arm leads into a bend of radius 0.3 to 2 mm. A hairpin (60 %) turns
    by pi plus twice a small outward counter-bend, so that its second arm returns
    alongside the tip arm with a gap between the two threads' surfaces of 0 to one
    thread diameter (``thread_radius`` is the thread's radius, m). A crossing hook
    turns by pi + 25..70 degrees so that the thread crosses its tip arm 1 to 5 mm from
    the tip. Beyond the hook the thread bends gently (60 to 270 degrees in all).
    """
    for _ in range(100):
        bend_radius = rng.uniform(3e-4, 2e-3)
        if rng.random() < 0.6:
            arm = rng.uniform(0.001, 0.008)
            centre_gap = 2 * thread_radius + rng.uniform(0.0, 2 * thread_radius)
            counter_radius = bend_radius * rng.uniform(1.0, 3.0)
            # Half-width of the arms at the neck: r cos(a) - R (1 - cos(a)) = centre_gap / 2.
            cos_alpha = min(1.0, (centre_gap / 2 + counter_radius) / (bend_radius + counter_radius))
            alpha = float(np.arccos(cos_alpha))
            pieces = [
                (arm, 0.0),
                (counter_radius * alpha, -1.0 / counter_radius),
                ((np.pi + 2 * alpha) * bend_radius, 1.0 / bend_radius),
                (counter_radius * alpha, -1.0 / counter_radius),
            ]
            bend_end = sum(p[0] for p in pieces)
            free_from = bend_end + arm + 0.003
            crossing = False
        else:
            beta = np.radians(rng.uniform(25, 70))
            # Straight from the end of the bend to the tip arm's line, then across it.
            to_line = bend_radius * (1 + np.cos(beta)) / np.sin(beta)
            arm = rng.uniform(0.001, 0.005) + bend_radius * np.sin(beta) + np.cos(beta) * to_line
            pieces = [(arm, 0.0), ((np.pi + beta) * bend_radius, 1.0 / bend_radius)]
            bend_end = arm + (np.pi + beta) * bend_radius
            free_from = bend_end + to_line + 0.003
            crossing = True
        if bend_end <= HOOK_REACH and free_from < length - 0.02:
            break
    else:
        raise ShapeError("no hook fits the thread")
    # Integrate on a 10x finer grid: a 0.3 mm bend turns by pi within 1 mm.
    fine = SAMPLE_STEP / 10
    n = round(length / fine) + 1
    s = np.linspace(0.0, length, n)
    kappa = np.zeros(n)
    start = 0.0
    for piece_length, curvature in pieces:
        kappa[(s >= start) & (s < start + piece_length)] = curvature
        start += piece_length
    rest = smooth_noise(n, 0.02 / fine, rng) + rng.uniform(-0.6, 0.6)
    ramp = np.clip((s - free_from) / 0.005, 0.0, 1.0)
    rest *= ramp * np.radians(rng.uniform(60, 270)) / (np.abs(rest * ramp).mean() * length + 1e-12)
    side = rng.choice([-1.0, 1.0])
    curve = resample_by_arc_length(planar_curve(length, side * (kappa + rest)))
    return curve, Hook(float(bend_radius), float(bend_end), float(free_from), crossing)


def along_rows_curve(
    length: float, stretch_start: float, stretch_length: float, rng: np.random.Generator
) -> np.ndarray:
    """(N, 2) planar curve sampled every ``SAMPLE_STEP`` that runs straight along the x axis
    (within +-6 degrees, either way) from arc ``stretch_start`` for ``stretch_length``
    metres and bends gently elsewhere."""
    kappa = curvature_profile("curved", length, rng)
    s = np.arange(kappa.size) * SAMPLE_STEP
    edge = 0.003  # the bends fade out over 3 mm at each end of the stretch
    outside = np.maximum(stretch_start - s, s - stretch_start - stretch_length)
    kappa *= np.clip(outside / edge, 0.0, 1.0)
    curve = planar_curve(length, kappa)
    first = round(stretch_start / SAMPLE_STEP)
    last = min(round((stretch_start + stretch_length) / SAMPLE_STEP), len(curve) - 1)
    chord = curve[last] - curve[first]
    heading = np.radians(rng.uniform(-6, 6)) + rng.choice([0.0, np.pi])
    return rotate(curve, heading - np.arctan2(chord[1], chord[0]))


def taper(length_samples: int, start: float, stop: float) -> np.ndarray:
    """(N,) weights along a curve sampled every ``SAMPLE_STEP``: 1 before arc ``start``, 0
    from arc ``stop`` on, linear between (with ``stop < start`` it rises instead)."""
    s = np.arange(length_samples) * SAMPLE_STEP
    return np.clip((stop - s) / (stop - start), 0.0, 1.0)
