"""The ordering search of the paper's Section II.B (Eq. 4-7), vectorised per step.

Starting at the cut tip ``V^1``, each loop ``t`` elects the next vertex
``V^{t+1}`` among the *active nodes* ``A^t`` by the composite cost of Eq. (5)::

    C_j = log(ε1 * O_j + μ) + ε2 * |A_j - V^t| * exp(ε3 * sin(δ_j / 2))

with argmin selection (Eq. 6), the admissibility / termination thresholds
``O_j < τ_O`` and ``δ_j < τ_V`` and the tuning of (ε1, ε2, ε3) over R1 x R2 x R3
that maximises the sequence length (Eq. 7).

Choices where the paper is ambiguous (each is tested in ``test/test_search.py``)
------------------------------------------------------------------------------

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

Active, detected and far nodes.
    The RoI is the annulus ``r_s <= |A - V^t| <= Υ`` (``step_radius``,
    ``roi_radius``): nodes nearer than ``r_s`` lie between ``V^t`` and the next
    vertex and are covered by the chord to it. *Detected* nodes are those within
    ``detect_radius`` of the polyline traversed so far (kept as a raster). Since
    the distance term prefers the nearest ring, circles are read lazily, from
    ``r_s`` outward, and stop as soon as no farther node can have a lower cost
    for any parameter set (every node at radius ``r`` costs at least
    ``log(μ) + ε2 r``). Nodes on one circle are equidistant, so among them the
    turning angle decides exactly, however small ε3 is.

Out-of-zone number O.
    The chord ``V^t A_j`` is sampled at 1 px spacing and O is the number of
    samples outside the *zone*, the mask dilated by ``zone_margin`` px (so a
    1-px-wide thread and rasterisation do not count as leaving the mask). O is
    therefore a length in pixels, and so is τ_O = 2.6 Υ.

τ_O and gaps.
    Inside the RoI O <= |A - V| <= Υ < τ_O, so τ_O only binds when the RoI holds
    no admissible node: then the circles continue beyond Υ up to τ_O (the
    farthest a node with O < τ_O can lie), which bridges gaps of up to τ_O px
    (62 px at 640 px width, e.g. an instrument lying across the thread). A node
    whose chord leaves the zone (O > 0: a bridged gap) must also turn by less
    than ``bridge_turn_max``, the thread must *start* there facing the gap, and
    continue beyond it so that the connection bends like one arc (turns into and
    out of the chord differing by less than ``bridge_bend_max``, measured one and
    two steps beyond); otherwise it is not admissible (a thread that ends near
    another one is not joined to it). Bridged stretches are filled with a cubic
    Hermite curve matching the thread's direction at both ends and flagged.

Turning angle δ.
    Eq. (4) measures δ from the last chord ``V^t - V^{t-1}``; on a curved thread
    that makes every step look like a turn, and a crossing strand can look
    straighter than the thread's own curling continuation. δ is therefore
    measured from the direction the thread's curvature predicts: the last chord
    turned by the last turn (the angle between the two previous chords), i.e. the
    next chord of the circle through the last three vertices; for a straight
    thread this is the paper's δ (``curvature_prediction=False`` gives Eq. 4 as
    written). Steps through merged cross-sections (a crossing) do not update the
    prediction for up to Υ; longer merged stretches (threads side by side) do.
    δ = 0 for the first step (t = 1), which has no previous vertex.

Junctions (crossings, the thread's own loops, touching threads).
    When the nodes on the first circle show several branches, or a cross-section
    wider than a thread, or every one of them turns by more than
    ``sharp_step_turn`` (a small loop entered tangentially runs merged with the
    way out past that circle, and its one node there is the way out's), the
    search decides across the whole junction instead of
    on the biased near nodes, with the arms on the circle of radius Υ (see
    :meth:`Searcher._junction_step`): a loop the thread forms here is entered
    first (two arms connected outside the junction), a crossing is crossed
    straight (the arm opposite ours in angular order), otherwise the arm that
    continues the thread like one arc wins; the step is a Hermite curve to that
    arm. If every arm bends sharply, the thread ends there (it ends on another
    strand). Our tangent there is the last steps' track unless the path over the
    last Υ (the circle through the points Υ and Υ/2 back and the vertex) points more
    than 5° elsewhere: on a segmenter's mask the step into a junction is often pulled
    towards the other strand.

Leaving a loop across the first pass.
    Back round a loop at its own crossing, the way out may share the first
    pass's track for a few pixels (strands meeting at a shallow angle): every
    nearer node ahead is detected and the chord to the first free one cuts the
    curve outside the zone, like a gap that the bridge checks refuse. Before the
    search ends, a free node ahead within ``bridge_turn_max`` is taken when the
    smooth step to it (Hermite, bending less than ``bridge_bend_max``) stays in
    the zone and crosses the traversed path (:meth:`Searcher._across_own_path`).

Termination.
    The search ends when no admissible node (not detected, O < τ_O, δ < τ_V)
    exists up to τ_O, nor a step out of a loop across the first pass, or at a
    junction without a smooth continuation; the last,
    shorter piece to the free end is then appended, and the sequence ends half a
    thread width before the end of the mask (where the centreline of a rounded
    end ends).

Tuning (Eq. 7).
    ε1, ε2, ε3 take ``grid_size`` evenly spaced values in R1, R2, R3 (27 sets by
    default). All parameter sets are searched together: at every step the argmin
    of Eq. (5) is computed for each set (one (sets x nodes) array), and the search
    only forks when the sets disagree, each fork carrying the sets that agree.
    On clean masks the sets rarely disagree, so the whole grid costs about one
    search (and when the nodes of a step lie on one circle inside the zone, every
    set picks the smallest δ, so no cost array is needed at all). The result is the
    longest sequence (most 1-px points); ties go to
    the fork holding the grid's centre, then to the lowest grid index.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from suture_ordering.cleaning import CleanMask
from suture_ordering.params import OrderingParams, ScaledParams

_LINE_SHIFT = 4  # cv2 drawing with 1/16 px precision


class _Stop:
    """Marker: the search ends at this junction."""


_STOP = _Stop()
_TAIL_MAX_TURN = math.pi / 3
_PULLED_TURN = math.radians(5.0)
_MAX_OUTSIDE_ZONE = 0.1  # share of a smooth (Hermite) step that may leave the zone


@dataclass(frozen=True)
class SearchResult:
    """Outcome of one search from the tip.

    ``points``: (N, 2) float64 (u, v), ~1 px apart, from the tip. ``bridged``: (N,) bool,
    True for points interpolated across a gap. ``vertices``: (K, 2) the elected vertices
    V^1..V^K. ``eps``: (ε1, ε2, ε3) of the chosen parameter set. ``status``: 'free_end'
    (the thread ended), 'image_border' (it left the image) or 'max_steps'.
    """

    points: np.ndarray
    bridged: np.ndarray
    vertices: np.ndarray
    status: str
    eps: tuple[float, float, float]
    steps: int
    bridges: int
    forks: int


@functools.lru_cache(maxsize=256)
def _circle(r: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, 1, 2) float32 offsets of n ~1 px spaced samples on the circle of radius ``r``, in angle
    order starting at angle 0 (n = max(8, ceil(2 pi r))), and (n,) float64 sample indices."""
    n = max(8, math.ceil(2 * math.pi * r))
    angle = 2 * math.pi * np.arange(n) / n
    offsets = (r * np.column_stack((np.cos(angle), np.sin(angle)))).astype(np.float32).reshape(-1, 1, 2)
    return offsets, np.arange(n, dtype=np.float64)


@functools.lru_cache(maxsize=256)
def _chord_steps(r: int) -> np.ndarray:
    """(1, r - 1, 1) fractions 1/r .. (r-1)/r: the 1 px spaced interior samples of a chord of length r."""
    return (np.arange(1, r) / r)[None, :, None]


def parameter_grid(params: OrderingParams) -> np.ndarray:
    """(G, 3) float64 (ε1, ε2, ε3) sets of the tuning grid of Eq. (7), the centre first."""
    axes = [
        np.linspace(low, high, params.grid_size) if params.grid_size > 1 else np.array([(low + high) / 2])
        for low, high in (params.eps1_range, params.eps2_range, params.eps3_range)
    ]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    centre = np.array([axis[len(axis) // 2] for axis in axes])
    first = int(np.argmin(np.abs(grid - centre).sum(axis=1)))
    order = np.r_[first, np.delete(np.arange(len(grid)), first)]
    return grid[order]


@dataclass
class _Branch:
    """One fork of the search: the parameter sets (rows of the grid) that agreed so far."""

    rows: np.ndarray
    consumed: np.ndarray
    vertices: list[np.ndarray]
    segments: list[np.ndarray] = field(default_factory=list)
    segment_bridged: list[bool] = field(default_factory=list)
    junctions: int = 0
    widths: list[float] = field(default_factory=list)
    heading: np.ndarray | None = None
    track: np.ndarray | None = None
    turn: float = 0.0
    clean_steps: int = 0
    merged_steps: int = 0
    steps: int = 0
    bridges: int = 0
    status: str = ""

    def fork(self, rows: np.ndarray) -> _Branch:
        return _Branch(
            rows=rows,
            consumed=self.consumed.copy(),
            vertices=list(self.vertices),
            segments=list(self.segments),
            segment_bridged=list(self.segment_bridged),
            junctions=self.junctions,
            widths=list(self.widths),
            heading=None if self.heading is None else self.heading.copy(),
            track=None if self.track is None else self.track.copy(),
            turn=self.turn,
            clean_steps=self.clean_steps,
            merged_steps=self.merged_steps,
            steps=self.steps,
            bridges=self.bridges,
        )

    @property
    def length(self) -> int:
        return 1 + sum(len(s) for s in self.segments)


@dataclass
class _Nodes:
    """Candidate nodes on one circle (arrays of equal length k)."""

    position: np.ndarray  # (k, 2) float (u, v)
    width: np.ndarray  # (k,) cross-section width, px
    radius: int


@dataclass
class _Candidates:
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
    def concatenate(cls, parts: list[_Candidates]) -> _Candidates:
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


class Searcher:
    """The search of one cleaned mask; :meth:`run` orders the thread from a tip."""

    def __init__(self, clean: CleanMask, params: OrderingParams, scaled: ScaledParams) -> None:
        self.params = params
        self.scaled = scaled
        self.height, self.width = clean.shape
        self.pad = clean.pad
        self.padded_width = clean.padded.shape[1]
        self.mask = clean.padded
        self.sampled = clean.sampled
        self.zone_flat = clean.zone.reshape(-1)
        self.consumed0 = np.zeros_like(clean.padded)
        self.grid = parameter_grid(params)
        self.log_mu = math.log(params.mu)
        self.eps3_max = float(self.grid[:, 2].max())
        # Whether leaving the zone by 1 px always costs more than any turn on one circle (true for
        # the paper's ranges and μ): then among equidistant nodes those with O = 0 always win.
        eps1, eps2, eps3 = self.grid.T
        gain = np.log(eps1 + params.mu) - self.log_mu
        self.zone_dominates = bool(np.all(gain > eps2 * scaled.max_reach * np.expm1(eps3)))
        self.thickness = max(1, round(2 * scaled.detect_radius))
        if clean.pad < scaled.max_reach + scaled.step_radius + 2:
            raise ValueError("mask padding is smaller than the search reach")

    # ------------------------------------------------------------------ helpers

    def _flat(self, points: np.ndarray) -> np.ndarray:
        """Flat indices into the padded arrays of (..., 2) float (u, v) points (rounded)."""
        p = np.rint(points).astype(np.intp) + self.pad
        return p[..., 1] * self.padded_width + p[..., 0]

    def _nodes(self, vertex: np.ndarray, r: int, width: float | None) -> _Nodes | None:
        """Centreline nodes on the circle of radius ``r`` around ``vertex`` (sub-pixel).

        The mask is sampled bilinearly ~1 px apart along the circle; each run of samples
        above 0.5 is a cross-section of a thread and gives a node at its weighted centre.
        """
        offsets, index = _circle(r)
        n = len(index)
        where = offsets + (vertex + self.pad).astype(np.float32)
        values = cv2.remap(self.sampled, where, None, cv2.INTER_LINEAR).reshape(-1)
        k0 = int(np.argmin(values))
        if values[k0] > 0.5:
            return None  # the circle lies wholly inside the mask: no thread structure
        rolled = np.concatenate((values[k0:], values[:k0]))
        inside = rolled > 0.5
        edges = np.flatnonzero(inside[1:] != inside[:-1]) + 1
        if edges.size == 0:
            return None
        if inside[-1]:
            edges = np.append(edges, n)
        lo, hi = edges[0::2] - 1, np.minimum(edges[1::2], n - 1)  # with the partial edge samples
        weight = np.cumsum(rolled)
        moment = np.cumsum(rolled * index)
        mass = weight[hi] - weight[lo] + rolled[lo]
        centre = (moment[hi] - moment[lo] + rolled[lo] * lo) / mass + k0
        spacing = 2 * math.pi * r / n
        widths = mass * spacing
        if width is not None:
            wide = widths > self.params.wide_arc_factor * width
            if wide.any():
                half = (mass[wide] - width / spacing) / 2
                centre = np.concatenate((centre[~wide], centre[wide] - half, centre[wide] + half))
                widths = np.concatenate((widths[~wide], widths[wide], widths[wide]))
        angle = centre * (2 * math.pi / n)
        position = vertex + r * np.column_stack((np.cos(angle), np.sin(angle)))
        return _Nodes(position, widths, r)

    def _out_of_zone(self, start: np.ndarray, ends: np.ndarray, r: int) -> np.ndarray:
        """O: samples of the chords start -> ends (k, 2), 1 px apart, outside the zone."""
        if r < 2:
            return np.zeros(len(ends), dtype=np.int64)
        samples = (start + self.pad + 0.5) + _chord_steps(r) * (ends - start)[:, None, :]
        p = samples.astype(np.intp)  # + 0.5 then truncation: rounding (coordinates are positive)
        return (self.zone_flat[p[..., 1] * self.padded_width + p[..., 0]] == 0).sum(axis=1)

    @staticmethod
    def _turn(direction: np.ndarray, heading: np.ndarray | None) -> np.ndarray:
        """δ (rad) between each row of ``direction`` (k, 2) and ``heading`` (2,); 0 without heading."""
        if heading is None:
            return np.zeros(len(direction))
        norm = np.sqrt((direction * direction).sum(axis=1) * float(heading @ heading))
        cos = (direction @ heading) / np.maximum(norm, 1e-12)
        return np.arccos(np.clip(cos, -1.0, 1.0))

    def _tangent(
        self, point: np.ndarray, direction: np.ndarray, consumed_flat: np.ndarray | None = None
    ) -> np.ndarray | None:
        """Unit tangent of the thread through ``point`` (a node), oriented along ``direction``.

        Central difference of the two nodes on a circle of radius r_s / 2 around ``point`` that
        lie most nearly ahead and behind along ``direction`` (each within 60 degrees); None if
        either is missing. With ``consumed_flat``, detected nodes are not used ahead.
        """
        radius = max(2, self.scaled.step_radius // 2)
        nodes = self._nodes(point, radius, None)
        if nodes is None:
            return None
        offset = nodes.position - point
        along = (offset @ direction) / (radius * float(np.hypot(*direction)))
        ahead = along.copy()
        if consumed_flat is not None:
            ahead[consumed_flat[self._flat(nodes.position)] != 0] = -1.0
        i, j = int(np.argmax(ahead)), int(np.argmin(along))
        if ahead[i] < 0.5 or along[j] > -0.5:
            return None
        tangent = nodes.position[i] - nodes.position[j]
        return tangent / float(np.hypot(*tangent))

    def _continuation(
        self, point: np.ndarray, chord: np.ndarray, heading: np.ndarray | None, consumed: np.ndarray
    ) -> np.ndarray | None:
        """Unit direction in which the thread leaves a gap at ``point``, or None when the bridge
        ``chord`` is not a smooth continuation.

        With α1 the turn from ``heading`` to the chord and α2 the turn from the chord to the
        thread beyond the gap, a bridge needs |α2| < bridge_turn_max and |α1 - α2| <
        bridge_bend_max: the connection must bend like one smooth arc, not like a corner. The
        thread beyond must also *start* at ``point``, facing the gap (no mask within
        bridge_turn_max of the way back along the chord): a gap ends where the thread emerges,
        not on the side of another thread.
        """
        r = self.scaled.step_radius
        nodes = self._nodes(point, r, None)
        if nodes is None:
            return None
        ahead = nodes.position - point
        if np.any(self._turn(ahead, -chord) < self.params.bridge_turn_max):
            return None
        alpha1 = 0.0 if heading is None else _signed_angle(heading, chord)
        alpha2 = np.arctan2(chord[0] * ahead[:, 1] - chord[1] * ahead[:, 0], ahead @ chord)
        bend = np.abs(alpha1 - alpha2)
        ok = (np.abs(alpha2) < self.params.bridge_turn_max) & (bend < self.params.bridge_bend_max)
        ok &= consumed.reshape(-1)[self._flat(nodes.position)] == 0
        if not ok.any():
            return None
        ok &= self._out_of_zone(point, nodes.position, r) == 0
        if not ok.any():
            return None
        j = int(np.flatnonzero(ok)[np.argmin(bend[ok])])
        # Measure the thread's direction one step farther on too (a rounded or frayed end biases
        # the first chord) and require both to continue the arc.
        farther = self._nodes(nodes.position[j], r, None)
        if farther is not None:
            onward = farther.position - nodes.position[j]
            turn = self._turn(onward, ahead[j])
            if turn.min() < self.params.bridge_turn_max:
                direction = onward[int(np.argmin(turn))]
                beyond = _signed_angle(chord, direction)
                if (
                    abs(beyond) >= self.params.bridge_turn_max
                    or abs(alpha1 - beyond) >= self.params.bridge_bend_max
                ):
                    return None
        return ahead[j] / float(np.hypot(*ahead[j]))

    def _at_junction(self, nodes: _Candidates, width: float | None) -> bool:
        """Several branches ahead (nodes farther apart than a thread width), or a merged
        cross-section (wider than ``wide_arc_factor`` thread widths): a crossing or touching
        threads."""
        if width is None:
            return False
        if np.any(nodes.width > self.params.wide_arc_factor * width):
            return True
        return len(nodes.width) > 1 and float(np.ptp(nodes.position, axis=0).max()) > max(2.0, width)

    def _turns_sharply_or_branches(self, nodes: _Candidates, width: float | None) -> bool:
        """Whether the step is decided across the whole junction (:meth:`_junction_step`): a
        junction on the nearest circle (:meth:`_at_junction`), or every near node turning by more
        than ``sharp_step_turn`` (a strand that leaves ours at a shallow angle may still run
        merged with it there, and the near node be that strand's)."""
        return self._at_junction(nodes, width) or float(nodes.delta.min()) > self.params.sharp_step_turn

    def _loop_entry(
        self,
        vertex: np.ndarray,
        tangent: np.ndarray,
        points: np.ndarray,
        tangents: list[np.ndarray | None],
        ahead: np.ndarray,
    ) -> int | None:
        """Index of the arm that enters a loop the thread forms at this junction, or None.

        Two arms (separate cross-sections of the circle of radius Υ) that are connected
        through the mask outside the junction (the disc of radius Υ - 2 around V cut out) are
        the two ends of a loop: at its own crossing, a thread must go round its loop
        before it can leave through the remaining arm. With three arms (two strands crossing)
        the loop is entered straight across, through the arm opposite ours in angular order;
        otherwise, of the loop arms ahead, the one continuing the thread more smoothly
        (smaller bend) is taken.
        """
        if len(points) < 3:
            return None
        scratch = self.mask.copy()
        centre = (round(float(vertex[0])) + self.pad, round(float(vertex[1])) + self.pad)
        cv2.circle(scratch, centre, self.scaled.roi_radius - 2, 0, thickness=cv2.FILLED)
        seeds: list[tuple[int, int] | None] = []
        for point in points:
            u, v = (round(float(x)) + self.pad for x in point)
            window = scratch[v - 1 : v + 2, u - 1 : u + 2]
            on = np.argwhere(window == 1)
            seeds.append(None if on.size == 0 else (u - 1 + int(on[0, 1]), v - 1 + int(on[0, 0])))
        label = 2
        groups: dict[int, list[int]] = {}
        for k, seed in enumerate(seeds):
            if seed is None:
                continue
            value = int(scratch[seed[1], seed[0]])
            if value == 1:
                cv2.floodFill(scratch, None, seed, label, flags=8)
                value, label = label, label + 1
            groups.setdefault(value, []).append(k)
        loops = [arms for arms in groups.values() if len(arms) == 2]
        if len(loops) != 1:
            return None
        entries = [k for k in loops[0] if ahead[k]]
        if len(points) == 3:  # a crossing of two strands: the loop is entered straight across
            opposite = self._opposite_arm(vertex, tangent, points)
            entries = [k for k in entries if k == opposite]
        if not entries:
            return None
        bends = [
            np.inf if tangents[k] is None else _bend(vertex, tangent, points[k], tangents[k]) for k in entries
        ]
        return entries[int(np.argmin(bends))]

    def _opposite_arm(self, vertex: np.ndarray, tangent: np.ndarray, points: np.ndarray) -> int:
        """Index (into the three ``points``) of the arm opposite ours in angular order around V."""
        back = -tangent / float(np.hypot(*tangent))
        arms = np.vstack([back, points - vertex])
        order = list(np.argsort(np.arctan2(arms[:, 1], arms[:, 0])))
        return int(order[(order.index(0) + 2) % 4]) - 1

    def _crossing_exit(
        self, vertex: np.ndarray, tangent: np.ndarray, points: np.ndarray, ahead: np.ndarray
    ) -> int | None:
        """Index of the arm that crosses the other strand, if the junction is a crossing.

        Four arms around V (ours coming in, three on the circle): if our thread crosses the
        other strand, it leaves through the arm opposite ours in angular order (one arm on each
        side). That pairing implies two strands, both passing within r_s of V, meeting at the
        angle between their chords; when it is at least ``min_crossing_angle`` the junction is
        taken to be a crossing. A smaller
        angle means two threads touching without crossing (or no clear evidence): None.
        """
        back = vertex - tangent * (self.scaled.roi_radius / float(np.hypot(*tangent)))
        opposite = self._opposite_arm(vertex, tangent, points)
        if not ahead[opposite]:
            return None
        i, j = (m for m in range(3) if m != opposite)
        ours = points[opposite] - back
        other = points[j] - points[i]
        # Both strands must pass near V (the junction lies between the arms).
        for start, chord in ((back, ours), (points[i], other)):
            offset = vertex - start
            if (
                abs(chord[0] * offset[1] - chord[1] * offset[0]) / float(np.hypot(*chord))
                > self.scaled.step_radius
            ):
                return None
        cos = abs(float(ours @ other)) / (float(np.hypot(*ours)) * float(np.hypot(*other)) + 1e-12)
        if math.acos(min(1.0, cos)) < self.params.min_crossing_angle:
            return None
        return opposite

    def _junction_step(
        self, branch: _Branch, heading: np.ndarray, consumed_flat: np.ndarray
    ) -> _Candidates | _Stop | None:
        """One step across a junction ahead (a crossing, a loop's crossing, touching threads).

        Inside the junction the cross-sections merge and near nodes are biased, so it is
        crossed in one step to a node N on the circle of radius Υ around the vertex V, where
        the branches are apart again. A branch that leaves through N with outward tangent t_N
        continues a strand that passed through M (tangent t_M, pointing in) smoothly when the
        chord M N bends like one arc: ``bend(M, N) = |α1 - α2|``, α1 the turn from t_M to the
        chord and α2 the turn from the chord to t_N (curvature does not matter; joining two
        different strands costs about their crossing angle). For our thread M = V with the
        track's tangent.

        With exactly three undetected branches on the circle (two strands, four arms) a
        crossing is recognised first (:meth:`_crossing_exit`): our thread leaves through the
        opposite arm. If the arms do not form a clear crossing (threads touching), the choice
        of our branch k also decides how the other strand passes, so the hypothesis with the
        smallest ``bend(V, N_k) + bend(N_i, N_j)`` wins. Otherwise the branch with the smallest
        ``bend(V, N_k)`` wins if it is below ``bridge_bend_max`` and smaller than the next by
        ``junction_tie`` (else the near nodes decide: in a band of two threads side by side
        the search keeps to its side). Only arms that can be reached through the mask count
        (at most 10 % of the Hermite step outside the zone). The step is drawn as a cubic
        Hermite curve matching both tangents. If every branch ahead bends by at least
        ``junction_bend_max`` the thread ends at this junction (it ends on another strand, or a
        short stub remains): :data:`_STOP`. None when the evidence is missing (the search then
        decides on the near nodes as usual).
        """
        vertex = branch.vertices[-1]
        radius = self.scaled.roi_radius
        tangent = self._junction_tangent(branch, radius)
        far = self._nodes(vertex, radius, None)  # one node per arm: merged arms stay one
        if far is None or tangent is None:
            return None
        free = np.flatnonzero(consumed_flat[self._flat(far.position)] == 0)
        points = far.position[free]
        tangents = [self._tangent(p, p - vertex, consumed_flat) for p in points]
        ahead = self._turn(points - vertex, heading) < self.params.tau_v
        # A branch whose chord runs mostly over the traversed path leads back, not across.
        t = np.linspace(0.25, 0.75, 5)
        along = vertex + t[None, :, None] * (points - vertex)[:, None, :]
        ahead &= (consumed_flat[self._flat(along)] != 0).sum(axis=1) <= 2
        ours = [
            _bend(vertex, tangent, p, t) if t is not None and ok else np.inf
            for p, t, ok in zip(points, tangents, ahead, strict=True)
        ]
        if int(ahead.sum()) < 2:
            return None  # one branch ahead after all: the near nodes follow it
        # The step to a branch is a Hermite curve; it must run through the thread, not across the
        # background to some other strand (at most 10 % of it outside the zone).
        for k in np.flatnonzero(ahead):
            end_tangent = tangents[k] if tangents[k] is not None else (points[k] - vertex) / radius
            curve = _hermite(
                vertex, points[k], tangent / float(np.hypot(*tangent)) * radius, end_tangent * radius
            )
            ahead[k] = (self.zone_flat[self._flat(curve)] == 0).mean() <= _MAX_OUTSIDE_ZONE
        choice = self._loop_entry(vertex, tangent, points, tangents, ahead)
        if choice is None and len(points) == 3:
            choice = self._crossing_exit(vertex, tangent, points, ahead)
        if choice is None and len(points) == 3 and all(t is not None for t in tangents):
            totals = []
            for k in range(3):
                i, j = (m for m in range(3) if m != k)
                other = min(
                    _bend(points[i], -tangents[i], points[j], tangents[j]),  # type: ignore[operator]
                    _bend(points[j], -tangents[j], points[i], tangents[i]),  # type: ignore[operator]
                )
                totals.append(ours[k] + other)
            if np.isfinite(min(totals)):
                choice = int(np.argmin(totals))
        if choice is None and ours and min(ours) < self.params.bridge_bend_max:
            ranked = sorted(ours)
            if len(ranked) > 1 and ranked[1] - ranked[0] < self.params.junction_tie:
                return None  # two branches continue about equally well: decide on the near nodes
            choice = int(np.argmin(ours))
        if choice is None:
            measured = [b for b, t, ok in zip(ours, tangents, ahead, strict=True) if ok and t is not None]
            if (
                measured
                and len(measured) == int(ahead.sum())
                and min(measured) >= self.params.junction_bend_max
            ):
                return _STOP  # only sharp turns onto other strands: the thread ends here
            return None
        point = points[choice]
        return _Candidates(
            point[None, :],
            np.array([float(radius)]),
            np.zeros(1, dtype=np.int64),
            self._turn((point - vertex)[None, :], heading),
            np.array([float(far.width[free[choice]])]),
            [tangents[choice]],
            np.array([False]),
        )

    # ------------------------------------------------------------------ one step

    @staticmethod
    def _entry_point(branch: _Branch, radius: float) -> np.ndarray | None:
        """Where the path traversed so far last enters the circle of ``radius`` around the vertex."""
        vertex = branch.vertices[-1]
        for segment in reversed(branch.segments):
            outside = np.flatnonzero(np.hypot(*(segment - vertex).T) >= radius)
            if outside.size:
                return segment[outside[-1]]
        return None

    def _junction_tangent(self, branch: _Branch, radius: float) -> np.ndarray | None:
        """Our thread's tangent at a junction's vertex, from the path over the last ``radius`` px.

        The step that reached the junction is often pulled towards the other strand (the merged
        cross-section's nodes are biased): when the tangent of the circle through the path points
        ``radius`` and ``radius / 2`` back and the vertex differs from the last steps' track by
        more than ``_PULLED_TURN``, it replaces the track.
        """
        track = self._tangent_at_vertex(branch)
        far, mid = self._entry_point(branch, radius), self._entry_point(branch, radius / 2)
        if far is None or mid is None or track is None:
            return track
        chord = branch.vertices[-1] - mid
        path = _rotate(chord, _signed_angle(mid - far, chord) / 2)
        return path if abs(_signed_angle(track, path)) > _PULLED_TURN else track

    def _predicted(self, branch: _Branch) -> np.ndarray | None:
        """Direction δ is measured from: the thread's track turned by its last turn."""
        if branch.track is None or branch.turn == 0.0:
            return branch.track
        return _rotate(branch.track, branch.turn)

    def _tangent_at_vertex(self, branch: _Branch) -> np.ndarray | None:
        """The thread's tangent at the current vertex: the track turned by half the last turn."""
        if branch.track is None or branch.turn == 0.0:
            return branch.track
        return _rotate(branch.track, branch.turn / 2)

    def _admissible(
        self, branch: _Branch, nodes: _Nodes, heading: np.ndarray | None, consumed_flat: np.ndarray
    ) -> _Candidates | None:
        """The admissible nodes among ``nodes``: not detected, δ < τ_V, O < τ_O (and bridge checks)."""
        vertex = branch.vertices[-1]
        position = nodes.position
        direction = position - vertex
        if heading is None:
            delta = np.zeros(len(position))
        else:  # |direction| = r for nodes on the circle around the vertex
            cos = (direction @ heading) / (nodes.radius * math.hypot(heading[0], heading[1]))
            delta = np.arccos(np.clip(cos, -1.0, 1.0))
        keep = (consumed_flat[self._flat(position)] == 0) & (delta < self.params.tau_v)
        if not keep.all():
            if not keep.any():
                return None
            position, delta, direction = position[keep], delta[keep], direction[keep]
            widths = nodes.width[keep]
        else:
            widths = nodes.width
        out = self._out_of_zone(vertex, position, nodes.radius)
        continuation: list[np.ndarray | None] = [None] * len(position)
        if not out.any():
            return _Candidates(
                position,
                np.full(len(position), float(nodes.radius)),
                out,
                delta,
                widths,
                continuation,
                out > 0,
            )
        keep = out < self.scaled.tau_o
        for j in np.flatnonzero(out > 0):  # bridged gaps: few, checked one by one
            if not keep[j] or delta[j] >= self.params.bridge_turn_max:
                keep[j] = False
                continue
            continuation[j] = self._continuation(
                position[j], direction[j], self._tangent_at_vertex(branch), branch.consumed
            )
            keep[j] = continuation[j] is not None
        if not keep.any():
            return None
        return _Candidates(
            position[keep],
            np.full(int(keep.sum()), float(nodes.radius)),
            out[keep],
            delta[keep],
            widths[keep],
            [continuation[j] for j in np.flatnonzero(keep)],
            out[keep] > 0,
        )

    def _thread_width(self, branch: _Branch) -> float | None:
        if not branch.widths:
            return None
        recent = sorted(branch.widths[-9:])
        return recent[len(recent) // 2]

    def _candidates(self, branch: _Branch) -> _Candidates | None:
        """Admissible nodes of the current RoI (widened across a gap if it has none), or None.

        Circles are read from r_s outward and only while a farther node could still cost less
        for some parameter set; beyond Υ only if the RoI held no admissible node.
        """
        vertex = branch.vertices[-1]
        heading = self._predicted(branch)
        consumed_flat = branch.consumed.reshape(-1)
        width = self._thread_width(branch)
        r_s = self.scaled.step_radius
        found: list[_Candidates] = []
        best = np.full(len(branch.rows), np.inf)
        nodes = self._nodes(vertex, r_s, width)
        if nodes is not None:
            first = self._admissible(branch, nodes, heading, consumed_flat)
            if first is not None and heading is not None and self._turns_sharply_or_branches(first, width):
                junction = self._junction_step(branch, heading, consumed_flat)
                if junction is _STOP:
                    return None
                if junction is not None:
                    return junction
            if first is not None:
                inside = first.out == 0
                if inside.any() and self.zone_dominates:
                    # Equidistant nodes inside the zone: every parameter set prefers the smallest
                    # turn, and no farther node can do better if even the largest ε3 keeps that
                    # cost below the cheapest node one pixel farther (no cost matrix needed).
                    turn = float(first.delta[inside].min())
                    if math.exp(self.eps3_max * math.sin(turn / 2)) <= (r_s + 1) / r_s:
                        first.decided = int(np.flatnonzero(inside)[np.argmin(first.delta[inside])])
                        return first
                found.append(first)
                best = self._cost(branch.rows, first).min(axis=1)
                if np.all(best <= self.log_mu + self.grid[branch.rows, 1] * (r_s + 1)):
                    return first
        for r in self._farther_radii(branch, vertex, heading):
            if found and (
                r > self.scaled.roi_radius or np.all(best <= self.log_mu + self.grid[branch.rows, 1] * r)
            ):
                break
            nodes = self._nodes(vertex, r, width)
            if nodes is None:
                continue
            more = self._admissible(branch, nodes, heading, consumed_flat)
            if more is None:
                continue
            found.append(more)
            best = np.minimum(best, self._cost(branch.rows, more).min(axis=1))
        return _Candidates.concatenate(found) if found else None

    def _across_own_path(self, branch: _Branch) -> _Candidates | None:
        """The step out of a loop across the thread's own earlier pass, where the search found
        nothing: the candidate, or None (the thread ends here).

        Coming round a loop back to its crossing, the nearer nodes ahead lie on the path traversed
        before (detected), and where the strands meet at a shallow angle the way out shares the
        first pass's track for a while: the first free node of the exit lies beyond the RoI's
        nearest circles, and the chord to it, cutting the curve, leaves the zone by a few pixels, so
        that it is taken for a gap and refused. Here a free node ahead (turning less than
        ``bridge_turn_max``) is taken when the smooth step to it (a Hermite curve along both
        tangents, bending less than ``bridge_bend_max``) runs within the zone (at most 10 %
        outside) and over the traversed path (crossing it), nearest first.
        """
        heading = self._predicted(branch)
        tangent = self._tangent_at_vertex(branch)
        if heading is None or tangent is None:
            return None
        vertex = branch.vertices[-1]
        consumed_flat = branch.consumed.reshape(-1)
        unit = tangent / float(np.hypot(*tangent))
        for r in range(self.scaled.step_radius + 1, self.scaled.roi_radius + 1):
            nodes = self._nodes(vertex, r, None)
            if nodes is None:
                continue
            delta = self._turn(nodes.position - vertex, heading)
            free = consumed_flat[self._flat(nodes.position)] == 0
            for j in np.flatnonzero(free & (delta < self.params.bridge_turn_max)):
                point = nodes.position[j]
                onward = self._tangent(point, point - vertex, consumed_flat)
                if onward is None or _bend(vertex, unit, point, onward) >= self.params.bridge_bend_max:
                    continue
                curve = self._flat(_hermite(vertex, point, unit * r, onward * r))
                outside = (self.zone_flat[curve] == 0).mean()
                if outside > _MAX_OUTSIDE_ZONE or (consumed_flat[curve] != 0).sum() < 2:
                    continue
                return _Candidates(
                    point[None, :],
                    np.array([float(r)]),
                    np.zeros(1, dtype=np.int64),
                    delta[j : j + 1],
                    nodes.width[j : j + 1],
                    [onward],
                    np.array([False]),
                )
        return None

    def _farther_radii(self, branch: _Branch, vertex: np.ndarray, heading: np.ndarray | None) -> list[int]:
        """Radii in (r_s, max_reach] whose circles meet an undetected mask pixel ahead, ascending."""
        reach = self.scaled.max_reach
        cu, cv = round(float(vertex[0])) + self.pad, round(float(vertex[1])) + self.pad
        window = (slice(cv - reach - 1, cv + reach + 2), slice(cu - reach - 1, cu + reach + 2))
        rows, cols = np.nonzero(self.mask[window] > branch.consumed[window])
        if rows.size == 0:
            return []
        offset = (
            np.column_stack((cols + (cu - reach - 1 - self.pad), rows + (cv - reach - 1 - self.pad))) - vertex
        )
        distance = np.sqrt((offset * offset).sum(axis=1))
        near = (distance > self.scaled.step_radius) & (distance < reach + 1)
        if heading is not None:
            slack = math.asin(min(1.0, 1.0 / self.scaled.step_radius))
            near &= self._turn(offset, heading) < self.params.tau_v + slack
        distance = distance[near]
        radii = np.unique(np.concatenate((np.floor(distance), np.ceil(distance))).astype(int))
        return [int(r) for r in radii if self.scaled.step_radius < r <= reach]

    def _cost(self, rows: np.ndarray, nodes: _Candidates) -> np.ndarray:
        """Eq. (5) for parameter sets ``rows`` (G_b,) and nodes (k,): (G_b, k)."""
        eps = self.grid[rows]
        return np.log(eps[:, :1] * nodes.out[None, :] + self.params.mu) + eps[:, 1:2] * nodes.radius[
            None, :
        ] * np.exp(eps[:, 2:3] * np.sin(nodes.delta[None, :] / 2.0))

    def _advance(
        self,
        branch: _Branch,
        target: np.ndarray,
        width: float,
        continuation: np.ndarray | None = None,
        bridge: bool = False,
    ) -> None:
        """Append the step V^t -> target to ``branch``: a chord, or a cubic Hermite curve ending
        along ``continuation`` (across a gap when ``bridge``, else across a junction)."""
        start = branch.vertices[-1]
        chord = target - start
        length = float(np.hypot(*chord))
        if continuation is None:
            n = max(1, math.ceil(length))
            segment = start + (np.arange(1, n + 1) / n)[:, None] * chord
            cv2.line(
                branch.consumed,
                _fixed(start + self.pad),
                _fixed(target + self.pad),
                1,
                self.thickness,
                cv2.LINE_8,
                _LINE_SHIFT,
            )
        else:
            before = self._tangent_at_vertex(branch)
            before = chord if before is None else before
            segment = _hermite(start, target, before / np.linalg.norm(before) * length, continuation * length)
            pts = np.rint((np.vstack((start, segment)) + self.pad) * (1 << _LINE_SHIFT)).astype(np.int32)
            cv2.polylines(branch.consumed, [pts], False, 1, self.thickness, cv2.LINE_8, _LINE_SHIFT)
            if bridge:
                branch.bridges += 1
            else:
                branch.junctions += 1
        branch.segments.append(segment)
        branch.segment_bridged.append(bridge)
        branch.vertices.append(target)
        expected = self._thread_width(branch)
        clean = continuation is None and (expected is None or width <= self.params.wide_arc_factor * expected)
        if clean:
            branch.widths.append(width)
        branch.heading = chord
        if continuation is not None:  # after a gap or junction: go on along the thread's tangent there
            branch.track, branch.turn, branch.clean_steps = continuation * length, 0.0, 0
        elif not clean:  # a merged cross-section (a crossing, touching threads)
            branch.merged_steps += 1
            if (
                branch.merged_steps * self.scaled.step_radius <= self.scaled.roi_radius
                or branch.track is None
            ):
                # keep the track through a junction (up to Υ) ...
                branch.track = chord if branch.track is None else _rotate(branch.track, branch.turn)
            else:  # ... but follow a longer merged stretch (two threads side by side)
                branch.track, branch.turn = chord, 0.0
            branch.clean_steps = 0
        else:
            if branch.track is not None and branch.clean_steps > 0 and self.params.curvature_prediction:
                branch.turn = _signed_angle(branch.track, chord)
            branch.track = chord
            branch.clean_steps += 1
            branch.merged_steps = 0
        branch.steps += 1

    def _mask_extent(self, start: np.ndarray, unit: np.ndarray) -> float:
        """Distance (px, 0.5 px steps, at most r_s) from ``start`` along ``unit`` to where the mask ends."""
        along = np.arange(0.5, self.scaled.step_radius + 0.01, 0.5)
        where = (start + self.pad + along[:, None] * unit).astype(np.float32).reshape(-1, 1, 2)
        # A low threshold and gaps of one sample tolerated: along a thin diagonal thread the
        # bilinear mask dips at the staircase's corners.
        inside = cv2.remap(self.sampled, where, None, cv2.INTER_LINEAR).reshape(-1) > 0.25
        outside = np.flatnonzero(~inside[:-1] & ~inside[1:])
        end = outside[0] if outside.size else len(along)
        covered = np.flatnonzero(inside[:end])
        return float(along[covered[-1]]) if covered.size else 0.0

    def _tail(self, branch: _Branch) -> None:
        """End the sequence at the free end: the centreline's end lies half the thread's width
        before the end of the mask (a thread's end is rounded).

        The last piece, shorter than r_s, goes towards the farthest node nearer than r_s
        (turning less than 60 degrees, O = 0) as far as the mask reaches less half a width.
        If the last vertex already lies on the rounded end, the last step is shortened instead.
        """
        vertex = branch.vertices[-1]
        consumed_flat = branch.consumed.reshape(-1)
        half = max(0.0, ((self._thread_width(branch) or 1.0) - 1.0) / 2.0)
        heading = self._predicted(branch)
        for r in range(self.scaled.step_radius - 1, math.ceil(self.scaled.detect_radius), -1):
            nodes = self._nodes(vertex, r, None)
            if nodes is None:
                continue
            delta = self._turn(nodes.position - vertex, heading)
            ok = (consumed_flat[self._flat(nodes.position)] == 0) & (delta < _TAIL_MAX_TURN)
            ok &= self._out_of_zone(vertex, nodes.position, r) == 0
            if not ok.any():
                continue
            j = np.flatnonzero(ok)[np.argmin(delta[ok])]
            unit = (nodes.position[j] - vertex) / r
            length = self._mask_extent(vertex, unit) - half
            if length >= 1.0:
                self._advance(branch, vertex + unit * length, float(nodes.width[j]))
                return
            break
        else:  # no node left on any circle: the end is nearer than that; go on straight to it
            if heading is not None:
                unit = heading / float(np.hypot(*heading))
                length = self._mask_extent(vertex, unit) - half
                if length >= 1.0:
                    self._advance(branch, vertex + unit * length, self._thread_width(branch) or 1.0)
                    return
        if not branch.segments or branch.segment_bridged[-1] or half <= 0:
            return
        last = branch.segments[-1]
        start = branch.vertices[-2]
        chord = branch.vertices[-1] - start
        length = float(np.hypot(*chord))
        unit = chord / max(length, 1e-9)
        shorten = half - self._mask_extent(branch.vertices[-1], unit)
        if 0 < shorten < length - 1.0:
            keep = np.hypot(*(last - start).T) <= length - shorten + 1e-9
            end = start + unit * (length - shorten)
            branch.segments[-1] = (
                np.vstack([last[keep], end]) if not np.allclose(last[keep][-1:], end) else last[keep]
            )
            branch.vertices[-1] = end

    # ------------------------------------------------------------------ the search

    def run(self, tip: np.ndarray) -> SearchResult:
        """Order the thread from ``tip`` ((2,) float (u, v), a free end on the mask)."""
        root = _Branch(
            rows=np.arange(len(self.grid)), consumed=self.consumed0.copy(), vertices=[np.asarray(tip, float)]
        )
        pending = [root]
        finished: list[_Branch] = []
        forks = 0
        while pending:
            branch = pending.pop()
            while True:
                if branch.steps >= self.params.max_steps:
                    branch.status = "max_steps"
                    break
                found = self._candidates(branch)
                if found is None:
                    found = self._across_own_path(branch)
                if found is None:
                    self._tail(branch)
                    branch.status = self._end_status(branch.vertices[-1])
                    break
                if found.decided is not None:
                    choice = np.full(len(branch.rows), found.decided)
                    chosen = np.array([found.decided])
                else:
                    choice = np.argmin(self._cost(branch.rows, found), axis=1)
                    chosen = np.unique(choice)
                if len(chosen) > 1:  # the parameter sets disagree: fork
                    forks += len(chosen) - 1
                    for j in chosen[1:]:
                        other = branch.fork(branch.rows[choice == j])
                        self._advance(
                            other,
                            found.position[j],
                            float(found.width[j]),
                            found.continuation[j],
                            found.bridge[j],
                        )
                        pending.append(other)
                    branch.rows = branch.rows[choice == chosen[0]]
                j = int(chosen[0])
                self._advance(
                    branch, found.position[j], float(found.width[j]), found.continuation[j], found.bridge[j]
                )
            finished.append(branch)
        best = max(finished, key=lambda b: (b.length, 0 in b.rows, -int(b.rows.min())))
        return self._result(best, forks)

    def _end_status(self, vertex: np.ndarray) -> str:
        margin = self.scaled.step_radius
        u, v = vertex
        if u < margin or v < margin or u > self.width - 1 - margin or v > self.height - 1 - margin:
            return "image_border"
        return "free_end"

    def _result(self, branch: _Branch, forks: int) -> SearchResult:
        start = branch.vertices[0][None, :]
        points = np.vstack([start, *branch.segments]) if branch.segments else start.copy()
        bridged = np.zeros(len(points), dtype=bool)
        offset = 1
        for segment, is_bridge in zip(branch.segments, branch.segment_bridged, strict=True):
            if is_bridge:
                bridged[offset : offset + len(segment) - 1] = True  # the far end is on the thread
            offset += len(segment)
        row = 0 if 0 in branch.rows else int(branch.rows[0])
        eps = tuple(float(x) for x in self.grid[row])
        return SearchResult(
            points=points,
            bridged=bridged,
            vertices=np.array(branch.vertices),
            status=branch.status,
            eps=eps,  # type: ignore[arg-type]
            steps=branch.steps,
            bridges=branch.bridges,
            forks=forks,
        )


def _bend(start: np.ndarray, t_start: np.ndarray, end: np.ndarray, t_end: np.ndarray) -> float:
    """|α1 - α2| of the chord start -> end: α1 from ``t_start`` to the chord, α2 from the chord
    to ``t_end`` (0 for any circular arc; large for a corner)."""
    chord = end - start
    return abs(_signed_angle(t_start, chord) - _signed_angle(chord, t_end))


def _rotate(v: np.ndarray, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])


def _signed_angle(a: np.ndarray, b: np.ndarray) -> float:
    """Angle (rad) that turns direction ``a`` into ``b``, in (-pi, pi]."""
    return math.atan2(a[0] * b[1] - a[1] * b[0], a[0] * b[0] + a[1] * b[1])


def _fixed(point: np.ndarray) -> tuple[int, int]:
    scaled = np.rint(point * (1 << _LINE_SHIFT)).astype(int)
    return int(scaled[0]), int(scaled[1])


def _hermite(start: np.ndarray, end: np.ndarray, tangent0: np.ndarray, tangent1: np.ndarray) -> np.ndarray:
    """Points (excluding ``start``) ~1 px apart on the cubic Hermite curve start -> end."""
    n = max(2, math.ceil(1.2 * float(np.hypot(*(end - start)))))
    t = (np.arange(1, n + 1) / n)[:, None]
    t2, t3 = t * t, t * t * t
    return (
        (2 * t3 - 3 * t2 + 1) * start
        + (t3 - 2 * t2 + t) * tangent0
        + (-2 * t3 + 3 * t2) * end
        + (t3 - t2) * tangent1
    )
