# SPDX-License-Identifier: Apache-2.0
"""How the ordering search reads the cleaned mask: centreline nodes on circles, the out-of-zone
count O, the thread's tangent at a node, and how far the mask reaches along a direction.

Centreline nodes.
    The paper moves the suture's edge elements to its centreline. Here the nodes
    are found where they are needed: on a circle of integer radius ``r`` around
    the current vertex the mask is read at ~1 px spacing; each run of mask pixels
    (a cross-section of a thread, bounded by two edge elements) gives one node at
    its middle, i.e. both edges moved to the centreline. A run wider than
    ``wide_arc_factor`` times the thread's width (two threads side by side, or a
    crossing) gives one node per edge, moved inward by half the thread width, so
    that the search can stay on its side. The thread width is the running median
    of the cross-sections the search has walked through. No skeleton is walked,
    so holes and spurs of the mask do not create false branches.

Out-of-zone number O.
    The chord ``V^t A_j`` is sampled at 1 px spacing and O is the number of
    samples outside the *zone*, the mask dilated by ``zone_margin`` px (so a
    1-px-wide thread and rasterisation do not count as leaving the mask). O is
    therefore a length in pixels, and so is τ_O = 2.6 Υ.

Pixels are (u, v) float64 image coordinates; the reader adds the cleaned mask's padding.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np

from suture_ordering.cleaning import CleanMask
from suture_ordering.compiled import circle_points, circle_runs

#: Share of a smooth (Hermite) step that may leave the zone.
MAX_OUTSIDE_ZONE = 0.1


@functools.lru_cache(maxsize=256)
def circle_samples(r: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, 1, 2) float32 offsets of n ~1 px spaced samples on the circle of radius ``r``, in angle
    order starting at angle 0 (n = max(8, ceil(2 pi r))), and (n,) float64 sample indices."""
    n = max(8, math.ceil(2 * math.pi * r))
    angle = 2 * math.pi * np.arange(n) / n
    offsets = (r * np.column_stack((np.cos(angle), np.sin(angle)))).astype(np.float32).reshape(-1, 1, 2)
    return offsets, np.arange(n, dtype=np.float64)


@dataclass(frozen=True)
class _Circle:
    """What :meth:`MaskReader.nodes` needs of the circle of radius r, computed once per radius:
    the sample offsets of :func:`circle_samples`, the arc between two samples (px) and the
    angle between two samples (rad)."""

    offsets: np.ndarray
    spacing: float
    angle_step: float


@functools.lru_cache(maxsize=256)
def _circle(r: int) -> _Circle:
    offsets, index = circle_samples(r)
    n = len(index)
    return _Circle(offsets, 2 * math.pi * r / n, 2 * math.pi / n)


@functools.lru_cache(maxsize=256)
def chord_fractions(r: int) -> np.ndarray:
    """(1, r - 1, 1) fractions 1/r .. (r-1)/r: the 1 px spaced interior samples of a chord of length r."""
    return (np.arange(1, r) / r)[None, :, None]


@dataclass
class Nodes:
    """Centreline nodes on one circle (arrays of equal length k)."""

    position: np.ndarray  # (k, 2) float (u, v)
    width: np.ndarray  # (k,) cross-section width, px
    radius: int


@dataclass
class Candidates:
    """Admissible nodes of one step (arrays of equal length k)."""

    position: np.ndarray  # (k, 2)
    radius: np.ndarray  # (k,) distance to the vertex, px
    out: np.ndarray  # (k,) O
    delta: np.ndarray  # (k,) δ, rad
    width: np.ndarray  # (k,)
    continuation: list[np.ndarray | None]  # tangent at the node for a curved step, else None
    bridge: np.ndarray  # (k,) bool: the step crosses a gap in the mask
    decided: int | None = None  # the node every parameter set chooses, when known without costs

    @classmethod
    def smooth_step(
        cls,
        point: np.ndarray,
        radius: float,
        delta: np.ndarray,
        width: np.ndarray,
        tangent: np.ndarray | None,
    ) -> Candidates:
        """The one candidate of a smooth (Hermite) step inside the zone to ``point`` (2,), arriving
        along ``tangent``; ``delta`` and ``width`` are (1,) arrays."""
        return cls(
            point[None, :],
            np.array([float(radius)]),
            np.zeros(1, dtype=np.int64),
            delta,
            width,
            [tangent],
            np.array([False]),
        )

    @classmethod
    def concatenate(cls, parts: list[Candidates]) -> Candidates:
        if len(parts) == 1:
            return parts[0]
        return cls(
            np.concatenate([p.position for p in parts]),
            np.concatenate([p.radius for p in parts]),
            np.concatenate([p.out for p in parts]),
            np.concatenate([p.delta for p in parts]),
            np.concatenate([p.width for p in parts]),
            [c for p in parts for c in p.continuation],
            np.concatenate([p.bridge for p in parts]),
        )


class MaskReader:
    """The padded arrays of a :class:`~suture_ordering.cleaning.CleanMask`, read at sub-pixel points.

    ``image_shape``: (H, W) of the unpadded mask. ``wide_arc_factor``: a cross-section wider
    than this many thread widths gives one node per edge. ``step_radius``: r_s (px), which
    sets the circle of :meth:`tangent` and the reach of :meth:`extent`.
    """

    def __init__(self, clean: CleanMask, wide_arc_factor: float, step_radius: int) -> None:
        self.image_shape = clean.shape
        self.pad = clean.pad
        self.padded_height, self.padded_width = clean.padded.shape
        self.mask = clean.padded
        self.zone_flat = clean.zone.reshape(-1)
        self.wide_arc_factor = wide_arc_factor
        self.step_radius = step_radius
        # (u, v) -> flat index of the padded arrays: u + W v, and the padding's share of it.
        self._flat_weights = np.array([1, self.padded_width], dtype=np.intp)
        self._flat_offset = self.pad * (1 + self.padded_width)

    def flat(self, points: np.ndarray) -> np.ndarray:
        """Flat indices into the padded arrays of (..., 2) float (u, v) points (rounded)."""
        return np.rint(points).astype(np.intp).dot(self._flat_weights) + self._flat_offset

    def nodes(self, vertex: np.ndarray, r: int, width: float | None) -> Nodes | None:
        """Centreline nodes on the circle of radius ``r`` around ``vertex`` (sub-pixel).

        The mask is sampled bilinearly ~1 px apart along the circle; each run of samples
        above 0.5 is a cross-section of a thread and gives a node at its weighted centre.
        With the thread's ``width`` known, a run wider than ``wide_arc_factor`` widths gives
        one node per edge, half a width inside it. The sample points and the runs are computed by
        kernels of :mod:`suture_ordering.compiled`; the samples by cv2.remap.
        """
        circle = _circle(r)
        where, u0, v0 = circle_points(circle.offsets, float(vertex[0]), float(vertex[1]), self.pad, r)
        if self._window_fits(u0, v0, r):
            values = self._remap_window(where, u0, v0, r)
        else:  # beyond the padding (the search stays within it)
            centre = (vertex + self.pad).astype(np.float32)
            values = self._bilinear(circle.offsets + centre, centre, r)
        if width is None:
            centres, widths = circle_runs(values, circle.spacing, math.inf, 0.0)
        else:
            centres, widths = circle_runs(
                values, circle.spacing, self.wide_arc_factor * width, width / circle.spacing
            )
        if not len(centres):
            return None  # no thread on the circle, or the circle lies wholly inside the mask
        angle = centres * circle.angle_step
        position = np.empty((len(angle), 2))
        np.cos(angle, out=position[:, 0])
        np.sin(angle, out=position[:, 1])
        position *= r
        position += vertex
        return Nodes(position, widths, r)

    def _bilinear(self, where: np.ndarray, centre: np.ndarray, reach: int) -> np.ndarray:
        """(n,) the mask sampled bilinearly (cv2.remap) at ``where``, (n, 1, 2) float32 points of
        the padded arrays that lie within ``reach`` px of ``centre`` (2,); ``where`` is reused.

        Only the window around ``centre`` is converted to float32 (the whole padded mask would be
        2 MB to allocate per view). The window's corner is an integer, so the points shifted into
        it keep their fractions exactly and the samples are those of the whole mask.
        """
        u0, v0 = int(centre[0]) - reach - 2, int(centre[1]) - reach - 2
        if not self._window_fits(u0, v0, reach):
            # Beyond the padding (the search stays within it): cv2.remap's own border handling.
            return cv2.remap(self.mask.astype(np.float32), where, None, cv2.INTER_LINEAR).reshape(-1)
        where -= np.array((u0, v0), dtype=np.float32)
        return self._remap_window(where, u0, v0, reach)

    def _window_fits(self, u0: int, v0: int, reach: int) -> bool:
        """Whether the window of :meth:`_remap_window` at (u0, v0) lies within the padded arrays."""
        size = 2 * reach + 5
        return u0 >= 0 and v0 >= 0 and u0 + size <= self.padded_width and v0 + size <= self.padded_height

    def _remap_window(self, where: np.ndarray, u0: int, v0: int, reach: int) -> np.ndarray:
        """(n,) the mask sampled bilinearly at ``where`` ((n, 1, 2) float32 points relative to the
        window's corner (u0, v0), within ``reach`` + 2 px of the window's centre)."""
        size = 2 * reach + 5
        window = self.mask[v0 : v0 + size, u0 : u0 + size].astype(np.float32)
        return cv2.remap(window, where, None, cv2.INTER_LINEAR).reshape(-1)

    def out_of_zone(self, start: np.ndarray, ends: np.ndarray, r: int) -> np.ndarray:
        """O: samples of the chords start -> ends (k, 2), 1 px apart, outside the zone."""
        if r < 2:
            return np.zeros(len(ends), dtype=np.int64)
        samples = chord_fractions(r) * (ends - start)[:, None, :]
        samples += start + self.pad + 0.5
        # + 0.5 then truncation: rounding (coordinates are positive)
        return (self.zone_flat[samples.astype(np.intp).dot(self._flat_weights)] == 0).sum(axis=1)

    def tangent(
        self, point: np.ndarray, direction: np.ndarray, consumed_flat: np.ndarray | None = None
    ) -> np.ndarray | None:
        """Unit tangent of the thread through ``point`` (a node), oriented along ``direction``.

        Central difference of the two nodes on a circle of radius r_s / 2 around ``point`` that
        lie most nearly ahead and behind along ``direction`` (each within 60 degrees); None if
        either is missing. With ``consumed_flat``, detected nodes are not used ahead.
        """
        radius = max(2, self.step_radius // 2)
        nodes = self.nodes(point, radius, None)
        if nodes is None:
            return None
        offset = nodes.position - point
        along = (offset @ direction) / (radius * float(np.hypot(*direction)))
        ahead = along.copy()
        if consumed_flat is not None:
            ahead[consumed_flat[self.flat(nodes.position)] != 0] = -1.0
        i, j = int(np.argmax(ahead)), int(np.argmin(along))
        if ahead[i] < 0.5 or along[j] > -0.5:
            return None
        tangent = nodes.position[i] - nodes.position[j]
        return tangent / float(np.hypot(*tangent))

    def extent(self, start: np.ndarray, unit: np.ndarray) -> float:
        """Distance (px, 0.5 px steps, at most r_s) from ``start`` along ``unit`` to where the mask ends."""
        along = np.arange(0.5, self.step_radius + 0.01, 0.5)
        where = (start + self.pad + along[:, None] * unit).astype(np.float32).reshape(-1, 1, 2)
        centre = (start + self.pad).astype(np.float32)
        # A low threshold and gaps of one sample tolerated: along a thin diagonal thread the
        # bilinear mask dips at the staircase's corners.
        inside = self._bilinear(where, centre, self.step_radius + 1) > 0.25
        outside = np.flatnonzero(~inside[:-1] & ~inside[1:])
        end = outside[0] if outside.size else len(along)
        covered = np.flatnonzero(inside[:end])
        return float(along[covered[-1]]) if covered.size else 0.0
