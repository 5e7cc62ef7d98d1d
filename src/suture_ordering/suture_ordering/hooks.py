# SPDX-License-Identifier: Apache-2.0
"""The start of a thread whose cut end curls into a hook or hairpin: a walk from the cut tip
through the hook to where the thread leaves it, handed to the search of
:mod:`suture_ordering.search`.

A cut end that bends back on itself hides its tip from the search. The tip arm and the arm
coming back lie side by side and merge into one stroke of the mask, so that the tip sits in the
stroke's interior and the mask's free end nearest to it is the bend; or the thread crosses its
tip arm and closes a small loop next to the tip, or the tip sits at that crossing. The thread
runs from the tip along its arm to the bend, back along the other arm past the tip, and on;
over a merged stretch the sequence passes twice.

The walk follows the mask's skeleton within ``HOOK_WINDOW`` RoI radii Υ of the tip
(:func:`hook_walk`). The skeleton becomes a graph of branches between free ends, junctions, the
tip and the window's rim. A walk starts at the tip (or at a free end within ``NEAR`` px of it),
ends on the rim, passes every branch of the hook (each at most twice, a loop once; a branch
shorter than ``SPUR`` px to a free end is a spur of the thinning and may be left out, and so may
an arm of another thread that crosses ours and ends inside the window where the mask loses it: a
branch to a free end that runs on straight across its junction into a branch as wide as itself,
or, where the mask lost the other thread's far arm too, a branch no wider than ours at a junction
that our thread runs straight through, :func:`_passing_strands`; merged arms down to a hairpin's
bend are twice as wide as the arm that leaves them, and leave the junction beside the tip arm),
turns back only at free ends (at the mask's end, past the skeleton's), and goes on
at a junction through any branch. Of all such walks the one that turns least where it passes a
junction or the tip wins, then the shortest: each turn is the angle between the chords
``step_radius`` px along the walk before and after the pass (within a third of a loop the walk
enters or leaves through a crossing: a longer chord cuts across the loop), so a crossing is
crossed straight and a loop is gone round the way the tip arm enters it. Passes fewer than two
step radii apart along the walk are one place (a crossing at a shallow angle thins to two
junctions a few pixels apart, each of which the thread passes with a small turn one way and then
the other), its turn measured from the chord before the first to the chord after the last.
Where the walk passes merged arms down to a loop and back, the skeleton is one line the same
both ways round; the loop is gone round so that the walk leaves it by its arm on the stroke's
side that the thread leaves by
(:func:`_loop_against_side`). Over merged arms the walk's way down moves onto the tip arm and its
way back onto the returning arm (:func:`_split_merged_arms`), rather than both down the stroke's
centre. A branch leaves the window where its end, or its thread extended to the mask's end, lies
within the spur length plus 3 px of the window's edge (a thread cut slanting by the window thins
to a skeleton that stops short of it). The search then starts from the walk's end with the walk as
its path so far (:func:`follow`), so it neither goes back into the hook nor loses the thread's
track, and with the thread's width read where the walk leaves.

When (:func:`hook_start`, :func:`hook_after_search`): a hint with no free end within the tip
radius; or, after the search from the free end nearest to the hint, when that end lies farther
than ``NEAR`` px from the hint, when the mask branches nearer to the tip than one step of the
search (:func:`branched_near_tip`; the first step has no heading to choose a branch by), when the
search left pixels of the tip's thread near the tip unvisited (:func:`skipped_near_tip`), or when
it came back near the tip to where it had passed.
A walk is taken when it returns to a place it passed (a hook); where the search left pixels
unvisited, or came back to where it had passed, any walk out of the window is: arms that touch
without merging thin to one skeleton line along the thread (a walk that passes no place twice),
while the search steps across from one arm to the other where they touch.

Right view (:func:`stereo_tip`): a cut tip inside a hook is no free end on the epipolar band
either. The disparity of the tip's neighbourhood is the shift along the row that lays the
left mask's window around the left tip best onto the right mask, within the disparity range;
the right view's walk starts at the shifted left tip, and its smoothing keeps that start
(:func:`_smoothed`; the left tip was smoothed once already). It is used when the left view started
through a hook, and when the band holds no free end but the shifted tip lies on the mask.
Where the arms lie on top of each other, the skeleton is the same both ways round a loop at
their end and the least-turning rule may go round against the thread; with a *guide* (the left
view's sequence shifted by that disparity) the right view's walk is chosen among those that
stray least from it (:func:`_disagreement`, ``GUIDE_MARGIN``), so that both views go round the
same way; of those, the least turning wins. Where the right view's own choice is not among
them and the side rule set it apart in either view (a side of merged arms within a pixel's
noise outweighs the turn in one view and not in the other), each right walk is paired with the
left view's walk (of all the left view compared) that it strays least from, and the pair whose
scores sum least is taken in both views (:func:`_both_views`; the left view walks its hook
again along its walk of the pair). Where the views differ in turning only, the left view's
walk stands: it starts at the hint, the right view's at a pixel matched by disparity.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree
from skimage.morphology import skeletonize, thin

from suture_ordering.context import SearchContext
from suture_ordering.geometry import revisited
from suture_ordering.nodes import MaskReader
from suture_ordering.params import ScaledParams
from suture_ordering.path import Branch, advance, advance_along
from suture_ordering.tip import extend_to_end, free_ends

#: At most this many branches in a hook's graph (more: not a hook; the walk is not searched).
MAX_BRANCHES = 12
#: Walks longer than this many branch passes are not searched.
MAX_PASSES = 2 * MAX_BRANCHES + 2
#: The walks compared, and the search for them, are bounded (a hook has a handful).
MAX_WALKS = 200
MAX_CALLS = 20000
#: The pairs of the two views' walks compared where they disagree are bounded too (beyond, the
#: guide's choice stands).
MAX_PAIRS = 400
#: Points of the walk averaged (a moving average along it).
SMOOTHING = 7
#: The walk's window: this many RoI radii Υ around the tip.
HOOK_WINDOW = 3.0
#: Branches to a free end shorter than this (px at 640 px) are thinning spurs.
SPUR = 3.0
#: A free end this near (px at 640 px) to the tip's pixel is the cut tip.
NEAR = 5.0
#: A free end whose thread runs on ahead of it to the window's rim within this many steps is
#: the rim's (:func:`_runs_to_rim`): thinning eats a 2 px thread at 45 degrees back from any end.
RIM_REACH = 3.0
#: A branch to a free end that runs on across a junction within this turn (rad) into a branch
#: no thinner than it by this factor is another strand's arm (:func:`_passing_strands`).
PASSING_TURN = math.radians(30.0)
PASSING_WIDTH = 1.4
#: Spacing (px) of the search's vertices along the walk.
DENSE = 1.0
#: Unvisited pixels (at 640 px) of the tip's thread near the tip that suggest a hook.
SKIPPED = 6.0
#: Runs of mask on the circle of radius r_s about the cut tip from which the search's first
#: step is a guess (a junction lies nearer than one step), so the walk is compared.
BRANCHED_RUNS = 2
#: Added to a walk's turns (rad) when it goes round a loop against the merged arms' sides.
SIDE_PENALTY = math.pi
#: Side offsets (px) below this tell nothing.
LATERAL = 0.1
#: The line the thread leaves merged arms along is fitted over this arc (in step radii) past
#: their end.
LEAVE_FROM = 0.5
LEAVE_TO = 3.0
#: The stroke is measured against that line over this arc (in step radii) from where the thread
#: leaves it: farther, the thread's own bend moves the line off the stroke's arms.
SIDE_OVER = 1.0
#: Merged arms are moved apart where the thread leaves them at least this far (px) aside.
SPLIT_SIDE = 0.5
#: With a guide (the other view's walk), the walks that stray from it (:func:`_disagreement`)
#: at most this many px (at 640 px) more than the nearest one agree with it; of those, the
#: least turning wins.
GUIDE_MARGIN = 1.0
#: Arc (px at 640 px) by which a walk and its guide may be shifted along each other (their
#: tips are found apart).
GUIDE_SLACK = 6.0
#: Where a walk enters or leaves a loop, its turn is measured over at most this share of the
#: loop's length: a longer chord cuts across the loop and no longer points the way it leaves.
LOOP_CHORD = 1.0 / 3.0
#: Passes of junctions fewer than this many chord reaches apart along a walk are one place.
GROUP_SPAN = 2.0
_OFFSETS = ((0, 1), (1, 0), (1, 1), (1, -1))


@dataclass
class _Branch:
    """A skeleton branch: its pixels (K, 2) (u, v) from node ``a`` to node ``b``."""

    pixels: np.ndarray
    a: int
    b: int

    @property
    def is_loop(self) -> bool:
        """Whether the branch runs from a node back to itself."""
        return self.a == self.b

    @property
    def length(self) -> float:
        return float(np.hypot(*np.diff(self.pixels, axis=0).T).sum()) if len(self.pixels) > 1 else 0.0


@dataclass
class _Graph:
    branches: list[_Branch]
    kind: dict[int, str]  # node -> 'end', 'junction', 'rim', 'tip'
    tip: int


def _skeleton_graph(skeleton: np.ndarray, tip: np.ndarray, rim: np.ndarray) -> _Graph | None:
    """The branches of ``skeleton`` ((H, W) bool), split at its pixel ``tip`` ((2,) int (u, v));
    ``rim``: (H, W) bool, where a branch ending there leaves the window. None: no hook's graph
    (more than :data:`MAX_BRANCHES` branches, or a ring without junctions)."""
    v, u = np.nonzero(skeleton)
    n = len(u)
    index = np.full(skeleton.shape, -1, dtype=np.int64)
    index[v, u] = np.arange(n)
    padded = np.pad(index, 1, constant_values=-1)
    rows, cols, weights = [], [], []
    for dv, du in _OFFSETS:
        other = padded[1 + v + dv, 1 + u + du]
        ok = other >= 0
        if dv and du:  # a diagonal link beside a 4-neighbour path is no branch of its own
            ok &= (padded[1 + v, 1 + u + du] < 0) & (padded[1 + v + dv, 1 + u] < 0)
        rows.append(np.flatnonzero(ok))
        cols.append(other[ok])
        weights.append(np.full(int(ok.sum()), math.hypot(dv, du)))
    r, c, w = np.concatenate(rows), np.concatenate(cols), np.concatenate(weights)
    degree = np.bincount(np.concatenate([r, c]), minlength=n)
    tip_index = int(index[tip[1], tip[0]])
    # Junction pixels (3+ neighbours) grouped into clusters; the tip is a node of its own.
    # A junction is the skeleton's pixels within one pixel of a pixel with 3+ neighbours
    # (thinning leaves a crossing as a knot of such pixels, with stubs a pixel long).
    junction_image = np.zeros(skeleton.shape, np.uint8)
    junction_image[v[degree >= 3], u[degree >= 3]] = 1
    junction_image = cv2.dilate(junction_image, np.ones((3, 3), np.uint8)) & skeleton.astype(np.uint8)
    junction_image[tip[1], tip[0]] = 0
    special = junction_image[v, u] > 0
    count, labels = cv2.connectedComponents(junction_image, connectivity=8)
    special[tip_index] = True
    node_of = np.full(n, -1, dtype=np.int64)
    node_of[special] = labels[v[special], u[special]] - 1
    tip_node = count - 1
    node_of[tip_index] = tip_node
    kind = {k: "junction" for k in range(count - 1)}
    kind[tip_node] = "tip"
    # Branches: components of the remaining pixels, each ordered by the shortest path along it.
    plain = ~special
    inner = plain[r] & plain[c]
    graph = coo_matrix((w[inner], (r[inner], c[inner])), shape=(n, n)).tocsr()
    graph = graph + graph.T
    inner_degree = np.asarray(graph.getnnz(axis=1)).ravel()
    _, label_of = connected_components(graph, directed=False)
    label_of = np.where(plain, label_of + 1, 0)
    count_b = len(np.unique(label_of[plain])) + 1
    if count_b - 1 > MAX_BRANCHES:
        return None
    label_of[plain] = np.unique(label_of[plain], return_inverse=True)[1] + 1
    across = special[r] != special[c]  # a plain pixel next to a node's pixel
    contact_plain = np.where(plain[r[across]], r[across], c[across])
    contact_node = np.where(plain[r[across]], c[across], r[across])
    pixels_uv = np.column_stack([u, v])
    branches: list[_Branch] = []
    for label in range(1, count_b):
        members = np.flatnonzero(label_of == label)
        ends = members[inner_degree[members] <= 1]
        if len(ends) == 0 or len(ends) > 2:  # a ring without junctions, or not a thin line
            return None
        first, last = int(ends[0]), int(ends[-1])
        _, predecessors = dijkstra(graph, indices=first, return_predecessors=True)
        path = [last]
        while path[-1] != first and predecessors[path[-1]] >= 0:
            path.append(int(predecessors[path[-1]]))
        path.reverse()
        pixels = pixels_uv[path]
        ends_nodes: list[list[tuple[int, int]]] = []
        for end_pixel in (first, last):
            near_pixels = contact_node[contact_plain == end_pixel]
            by_node = dict(zip(node_of[near_pixels].tolist(), near_pixels.tolist(), strict=True))
            ends_nodes.append(list(by_node.items()))
        if first == last and len(ends_nodes[0]) > 1:  # one pixel between two nodes
            ends_nodes = [ends_nodes[0][:1], ends_nodes[0][1:2]]
        elif first == last:
            ends_nodes[1] = []
        nodes = []
        for side, (end_pixel, touching) in enumerate(zip((first, last), ends_nodes, strict=True)):
            if touching:
                node, joint = touching[0]
                nodes.append(node)
                pixels = np.vstack([pixels_uv[joint], pixels] if side == 0 else [pixels, pixels_uv[joint]])
            else:
                node = len(kind)
                kind[node] = "rim" if rim[v[end_pixel], u[end_pixel]] else "end"
                nodes.append(node)
        branches.append(_Branch(pixels, nodes[0], nodes[1]))
    # Nodes next to each other with no plain pixel between them.
    both = special[r] & special[c] & (node_of[r] != node_of[c])
    for a, b in zip(r[both], c[both], strict=True):
        branches.append(_Branch(pixels_uv[[a, b]], int(node_of[a]), int(node_of[b])))
    if len(branches) > MAX_BRANCHES:
        return None
    return _Graph(branches, kind, tip_node)


def _walks(graph: _Graph, spur: float, passing: frozenset[int] = frozenset()) -> list[list[tuple[int, bool]]]:
    """Every walk from the tip to the rim that passes each of the hook's branches once or twice
    (those of ``passing``, other strands' arms, at most; a loop, a branch from a junction back to
    itself, once: a thread does not coil twice over the same pixels) and turns back only at free
    ends (at most :data:`MAX_WALKS` of them): lists of (branch index, reversed)."""
    branches = graph.branches
    incident: dict[int, list[tuple[int, bool]]] = {}
    for k, branch in enumerate(branches):
        incident.setdefault(branch.a, []).append((k, False))
        incident.setdefault(branch.b, []).append((k, True))
    kinds = [(graph.kind[b.a], graph.kind[b.b]) for b in branches]
    # Optional: branches to the rim, spurs of the thinning (short, to a free end other than the
    # tip's), and short branches between two junctions or a junction and the tip (the little
    # cycles that thinning leaves where arms touch diagonally).
    required = [
        k
        for k, b in enumerate(branches)
        if "rim" not in kinds[k]
        and not (b.length < spur and ("end" not in kinds[k] or graph.tip not in (b.a, b.b)))
        and k not in passing
    ]
    found: list[list[tuple[int, bool]]] = []
    uses = [0] * len(branches)
    calls = [0]

    def extend(node: int, walk: list[tuple[int, bool]]) -> None:
        calls[0] += 1
        if len(found) >= MAX_WALKS or calls[0] > MAX_CALLS or len(walk) > MAX_PASSES:
            return
        if graph.kind[node] == "rim":
            if all(uses[k] for k in required):
                found.append(list(walk))
            return
        if walk and graph.kind[node] == "end":
            options = [(walk[-1][0], not walk[-1][1])]
        else:
            options = [o for o in incident.get(node, []) if not walk or o != (walk[-1][0], not walk[-1][1])]
        for k, rev in options:
            if uses[k] >= (1 if branches[k].is_loop else 2):  # a loop is gone round once
                continue
            uses[k] += 1
            walk.append((k, rev))
            extend(branches[k].a if rev else branches[k].b, walk)
            walk.pop()
            uses[k] -= 1

    extend(graph.tip, [])
    return found


def _passing_strands(
    graph: _Graph, places: dict[int, int], depth: np.ndarray, spur: float, step: float
) -> frozenset[int]:
    """The branches to a free end (not the tip's) that are the arm of another thread crossing ours,
    the mask having lost that thread inside the window: at a junction (its place,
    :func:`_places`) with four arms, the branch runs on within :data:`PASSING_TURN` into an arm no
    thinner than it by :data:`PASSING_WIDTH` (``depth``: (h, w) the window's distance transform)
    that leaves the window, and the other two arms run on into each other as straight, one of them
    out of the window too (an X). At a junction with three arms, where the mask lost the other
    thread on both sides of the crossing, the other two arms run on into each other as straight,
    one of them out of the window, and the branch is no wider than it by :data:`PASSING_WIDTH`
    (a T). A hairpin's merged arms meet the tip arm and the arm that leaves them in three arms
    too, but those two leave the junction side by side, and the merged arms are twice as wide; a
    loop at the tip crosses its tip arm with arms that stay in the window."""
    at_place: dict[int, list[tuple[int, bool]]] = {}
    for k, branch in enumerate(graph.branches):
        if branch.length < spur and "end" not in (graph.kind[branch.a], graph.kind[branch.b]):
            continue  # a little cycle of the thinning inside the junction
        at_place.setdefault(places[branch.a], []).append((k, False))  # its pixels leave a
        at_place.setdefault(places[branch.b], []).append((k, True))  # and run into b

    def outward(k: int, into: bool) -> tuple[np.ndarray, float, str]:
        """The unit direction in which branch ``k`` leaves its node (its end node ``b`` when
        ``into``), its width beyond 2 chords from there, and the kind of its far node."""
        branch = graph.branches[k]
        pixels = branch.pixels.astype(np.float64)
        ordered = pixels[::-1] if into else pixels
        direction = _within(ordered, 0.0, 2 * step)[-1] - ordered[0]
        cells = np.rint(_within(ordered, 2 * step, np.inf)).astype(int)
        width = float(np.median(depth[cells[:, 1], cells[:, 0]]))
        return (
            direction / max(float(np.hypot(*direction)), 1e-9),
            width,
            graph.kind[branch.a if into else branch.b],
        )

    def straight(one: tuple[np.ndarray, float, str], other: tuple[np.ndarray, float, str]) -> bool:
        return math.acos(float(np.clip(-one[0] @ other[0], -1.0, 1.0))) <= PASSING_TURN

    passing = set()
    for arms in at_place.values():
        if len(arms) not in (3, 4) or len({k for k, _ in arms}) != len(arms):
            continue
        measured = [outward(k, into) for k, into in arms]
        for i, (k, _) in enumerate(arms):
            if measured[i][2] != "end" or graph.tip in (graph.branches[k].a, graph.branches[k].b):
                continue
            if len(arms) == 3:
                one, other = (measured[m] for m in range(3) if m != i)
                leaving = [arm for arm in (one, other) if arm[2] == "rim"]
                if (
                    leaving
                    and straight(one, other)
                    and all(measured[i][1] <= PASSING_WIDTH * arm[1] for arm in leaving)
                ):
                    passing.add(k)
                continue
            for j in range(4):
                rest = [m for m in range(4) if m not in (i, j)]
                if (
                    j != i
                    and measured[j][2] == "rim"
                    and measured[i][1] <= PASSING_WIDTH * measured[j][1]
                    and straight(measured[i], measured[j])
                    and straight(measured[rest[0]], measured[rest[1]])
                    and "rim" in (measured[rest[0]][2], measured[rest[1]][2])
                ):
                    passing.add(k)
    return frozenset(passing)


def _places(graph: _Graph, spur: float) -> dict[int, int]:
    """Each node's place: nodes joined by a branch shorter than ``spur`` px between junctions
    or the tip (a little cycle of the thinning where arms touch) are one place."""
    place = {node: node for node in graph.kind}

    def root(node: int) -> int:
        while place[node] != node:
            node = place[node]
        return node

    for branch in graph.branches:
        kinds = (graph.kind[branch.a], graph.kind[branch.b])
        if branch.length < spur and "end" not in kinds and "rim" not in kinds:
            place[root(branch.a)] = root(branch.b)
    return {node: root(node) for node in graph.kind}


def _runs_to_rim(
    own: np.ndarray, rim: np.ndarray, end: np.ndarray, outward: np.ndarray, reach: float
) -> bool:
    """Whether the thread of ``own`` ((h, w) bool) runs on from the skeleton's free end ``end``
    ((2,) int (u, v)) ahead of it (on the side ``outward`` points to) to a ``rim`` pixel within
    ``reach`` px: a thin thread at 45 degrees cut by the window's edge, whose skeleton thinning
    ate back from that edge by more than a step."""
    height, width = own.shape
    r = math.ceil(reach)
    u0, v0 = max(0, int(end[0]) - r), max(0, int(end[1]) - r)
    u1, v1 = min(width, int(end[0]) + r + 1), min(height, int(end[1]) + r + 1)
    yy, xx = np.mgrid[v0:v1, u0:u1]
    du, dv = xx - end[0], yy - end[1]
    ahead = own[v0:v1, u0:u1] & (np.hypot(du, dv) <= reach) & (du * outward[0] + dv * outward[1] >= 0)
    _, pieces = cv2.connectedComponents(ahead.astype(np.uint8), connectivity=8)
    piece = pieces[int(end[1]) - v0, int(end[0]) - u0]
    return bool(piece and (rim[v0:v1, u0:u1] & (pieces == piece)).any())


def _along_mask(mask: np.ndarray, start: np.ndarray, stop: np.ndarray) -> np.ndarray:
    """The point ((2,) float64 (u, v)) of the segment from ``start`` towards ``stop`` up to
    which the segment runs on ``mask`` ((H, W) bool; samples every 0.5 px, each on it where
    its pixel is): the cut tip is not moved across a gap onto an arm beside it."""
    length = float(np.hypot(*(stop - start)))
    if length < 0.5:
        return stop
    at = np.arange(0.5, length + 0.25, 0.5) / length
    points = np.rint(start + at[:, None] * (stop - start)).astype(int)
    height, width = mask.shape
    inside = (points[:, 0] >= 0) & (points[:, 0] < width) & (points[:, 1] >= 0) & (points[:, 1] < height)
    on = np.zeros(len(at), dtype=bool)
    on[inside] = mask[points[inside, 1], points[inside, 0]] > 0
    off = np.flatnonzero(~on)
    if not len(off):
        return stop
    reach = 0.0 if off[0] == 0 else at[off[0] - 1]
    return start + reach * (stop - start)


def _to_tip(mask: np.ndarray, path: np.ndarray, hint: np.ndarray, step: float, half: float) -> np.ndarray:
    """``path`` ((N, 2) float64 (u, v), from the tip) with its start moved back along its own
    direction (from the mean of its first ``2 step`` px to its first point) as far as that
    line stays on ``mask`` (:func:`_along_mask`, at most ``2 step``) less ``half`` (px, the
    thread's half width less half a pixel: a thread's rounded end lies that far beyond its
    centreline's), and not past the foot of ``hint`` (the tip's pixel, (2,)) on the line.
    Where the tip lies inside a stroke of merged arms, the walk starts at the skeleton's pixel
    nearest the hint, short of the tip arm's end; the hint, a pixel at the cut end, bounds how
    far the start may move along a thread that runs on past the tip beside its arm."""
    axis = path[0] - _within(path, 0.0, 2 * step).mean(axis=0)
    norm = float(np.hypot(*axis))
    if norm < 1e-6:
        return path
    axis /= norm
    limit = float((hint - path[0]) @ axis)
    if limit < 1.0:
        return path
    outer = _along_mask(mask, path[0], path[0] + 2 * step * axis)
    reach = min(float((outer - path[0]) @ axis) - half, limit)
    if reach < 1.0:
        return path
    extra = path[0] + np.arange(math.floor(reach), 0, -1)[:, None] * axis
    return np.vstack([extra, path])


def _pieces(graph: _Graph, walk: list[tuple[int, bool]]) -> list[np.ndarray]:
    """The pixels of each of ``walk``'s branch passes, in its direction; a pixel shared with the
    previous pass is left out, so that the pieces stacked are the walk's pixels."""
    pieces: list[np.ndarray] = []
    for k, rev in walk:
        pixels = graph.branches[k].pixels
        pixels = pixels[::-1] if rev else pixels
        if pieces and np.array_equal(pieces[-1][-1], pixels[0]):
            pixels = pixels[1:]
        pieces.append(pixels)
    return pieces


def _turning(graph: _Graph, walk: list[tuple[int, bool]], reach: float) -> tuple[float, np.ndarray]:
    """Total turn (rad) of ``walk`` where it passes a node other than a free end, each measured
    between the chords ``reach`` px before and after along the walk (at most ``LOOP_CHORD`` of a
    loop's length where the pass enters or leaves a loop at a crossing); and the walk's pixels."""
    pieces, passes, reaches = _pieces(graph, walk), [], []
    count = 0
    for position, ((k, rev), pixels) in enumerate(zip(walk, pieces, strict=True)):
        if position and graph.kind[graph.branches[k].b if rev else graph.branches[k].a] != "end":
            passes.append(count - 1)
            loop = _crossed_loop(graph, walk, position, reach)
            reaches.append(reach if loop is None else min(reach, LOOP_CHORD * graph.branches[loop].length))
        count += len(pixels)
    path = np.vstack(pieces).astype(np.float64)
    along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(path, axis=0).T))])
    first, last, chord = _places_passed(np.asarray(passes, dtype=int), along, np.asarray(reaches))
    before = path[first] - path[np.searchsorted(along, np.maximum(along[first] - chord, 0.0))]
    after = path[np.minimum(np.searchsorted(along, along[last] + chord), len(path) - 1)] - path[last]
    norms = np.hypot(*before.T) * np.hypot(*after.T)
    cos = np.einsum("ij,ij->i", before, after) / np.maximum(norms, 1e-9)
    turns = np.where(norms > 0, np.arccos(np.clip(cos, -1.0, 1.0)), 0.0)
    return float(turns.sum()), path


def _places_passed(
    passes: np.ndarray, along: np.ndarray, reaches: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Passes (indices into a walk's pixels, ``along``: the arc at each pixel) closer to the
    previous one than ``GROUP_SPAN`` chord reaches (``reaches``, per pass), merged into one: a
    crossing that thinning split into two junctions a few pixels apart is one place, and the
    thread's turn there is measured across both. Returns each place's first and last pass and
    its chord reach (the least of its passes')."""
    if len(passes) < 2:
        return passes, passes, reaches
    apart = np.diff(along[passes]) >= GROUP_SPAN * np.minimum(reaches[1:], reaches[:-1])
    starts = np.concatenate([[True], apart])
    group = np.cumsum(starts) - 1
    first = passes[starts]
    last = passes[np.concatenate([np.flatnonzero(starts)[1:] - 1, [len(passes) - 1]])]
    reach = np.full(len(first), np.inf)
    np.minimum.at(reach, group, reaches)
    return first, last, reach


def _crossed_loop(graph: _Graph, walk: list[tuple[int, bool]], position: int, reach: float) -> int | None:
    """The loop that ``walk`` enters or leaves where it passes from branch ``position - 1`` to
    ``position``, when the thread crosses itself there: it comes to the loop by one branch and
    leaves by another, or by one branch shorter than ``GROUP_SPAN`` x ``reach`` that it walks
    both ways (the crossing thinned to two junctions) between two others. A walk back along a
    longer branch is a racket's neck: None, as where no loop is entered or left."""
    for loop in (position, position - 1):  # the pass enters the loop, or leaves it
        before, after, k = loop - 1, loop + 1, walk[loop][0]
        if not graph.branches[k].is_loop or before < 0 or after >= len(walk):
            continue
        if walk[before][0] == walk[after][0] and graph.branches[walk[before][0]].length < GROUP_SPAN * reach:
            before, after = before - 1, after + 1
            if before < 0 or after >= len(walk):
                continue
        if walk[before][0] != walk[after][0]:
            return k
    return None


def _oriented(graph: _Graph, k: int, rev: bool) -> np.ndarray:
    pixels = graph.branches[k].pixels.astype(np.float64)
    return pixels[::-1] if rev else pixels


def _within(pixels: np.ndarray, low: float, high: float) -> np.ndarray:
    """The ``pixels`` ((K, 2), along a line) between arc ``low`` and ``high`` px from the first."""
    along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pixels, axis=0).T))])
    chosen = pixels[(along >= low) & (along <= high)]
    return chosen if len(chosen) else pixels[-1:]


def _offset(points: np.ndarray, centre: np.ndarray, axis: np.ndarray) -> float:
    """Mean signed distance (px) of ``points`` (K, 2) from the line through ``centre`` along ``axis``."""
    relative = points - centre
    return float(np.mean(axis[0] * relative[:, 1] - axis[1] * relative[:, 0]))


def _stroke_side(
    graph: _Graph,
    stroke: tuple[int, bool],
    after: list[tuple[int, bool]],
    reach: float,
    thread: cKDTree,
) -> tuple[float, np.ndarray, np.ndarray] | None:
    """The side of the merged stroke (the branch pass ``stroke``) that the thread leaves it by
    (:func:`_loop_against_side`): the signed offset of the leaving line from the stroke's
    pixels, and that line (a point, a unit direction); None: the thread beyond is too short.

    The leaving line is fitted to the mask's pixels (``thread``) of the single thread beyond
    the stroke (the passes ``after`` the stroke's way back), from ``LEAVE_FROM`` to
    ``LEAVE_TO`` ``reach`` of arc past the stroke's end: not to its skeleton, which near the
    stroke bends over from the stroke's centre to the thread's and runs a pixel aside where
    the thread is one or two pixels wide; those offsets are the size of the side sought. The
    stroke is measured by its own mask pixels (not the thread's past its end) within
    ``reach / 2`` of its first ``SIDE_OVER`` ``reach`` of arc, where the thread leaves it: a
    line extended along a long stroke strays from it by a pixel where the thread bends gently."""
    pixels = _oriented(graph, *stroke)
    beyond = np.vstack([pixels[:1], *[_oriented(graph, k, r) for k, r in after]])
    leaving = _within(beyond, LEAVE_FROM * reach, LEAVE_TO * reach)
    if len(leaving) < 3:
        return None
    own = _near(thread, leaving, reach / 2)
    own = own[_nearer(own, leaving, pixels)]  # not the stroke's pixels next to the thread's start
    stroke_own = _near(thread, _within(pixels, 0.0, SIDE_OVER * reach), reach / 2)
    stroke_own = stroke_own[_nearer(stroke_own, pixels, beyond[1:])]  # nor the thread's past its end
    if len(own) < 3 or len(stroke_own) == 0:
        return None
    return _side_of_line(own, stroke_own)


def _near(thread: cKDTree, pixels: np.ndarray, radius: float) -> np.ndarray:
    """The thread's pixels (K, 2) within ``radius`` px of any of ``pixels`` (N, 2)."""
    return thread.data[sorted({k for found in thread.query_ball_point(pixels, radius) for k in found})]


def _nearer(points: np.ndarray, these: np.ndarray, those: np.ndarray) -> np.ndarray:
    """(K,) bool: which ``points`` lie nearer to ``these`` pixels than to ``those`` (neither empty)."""
    return cKDTree(these).query(points)[0] < cKDTree(those).query(points)[0]


def _side_of_line(points: np.ndarray, stroke: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """The offset of the ``stroke``'s pixels (K, 2) from the line fitted to ``points`` (J, 2),
    measured across it, with the line's centre and axis."""
    centre = points.mean(axis=0)
    axis = np.linalg.svd(points - centre, full_matrices=False)[2][0]
    return -_offset(stroke, centre, axis), centre, axis


def _loop_against_side(
    graph: _Graph, walk: list[tuple[int, bool]], reach: float, thread: cKDTree, sides: dict
) -> bool:
    """Whether ``walk`` goes round a loop at the far end of merged arms the wrong way.

    Where the walk passes a branch (the merged arms, the tip's arm at its start), a loop, and
    the branch back, the thread leaves the merged stroke along its returning arm: the line of
    the thread beyond the stroke (:func:`_stroke_side`) runs along the stroke's side
    that the returning arm lies on, half a thread's spacing from the stroke's pixels
    (``thread``: a tree of the mask's pixels (u, v) of the thread; the mean over its pixels
    near the branch, which a slit between the arms or a skeleton running along one arm does
    not shift). The loop is left by its arm on that side. Offsets nearer than ``LATERAL`` px
    tell nothing. ``sides``: the stroke's sides found so far, by (branch, reversed, next)."""
    for position in range(1, len(walk) - 1):
        (neck, rev), (loop, loop_rev), (back, back_rev) = walk[position - 1 : position + 2]
        if back != neck or back_rev == rev or not graph.branches[loop].is_loop:
            continue
        if sum(graph.branches[k].length for k, _ in walk[: position - 1]) >= reach:
            continue  # the tip's arm joins the stroke from aside: a crossing, not merged arms
        if position + 2 >= len(walk):
            continue
        key = (neck, rev, walk[position + 2])
        if key not in sides:
            sides[key] = _stroke_side(graph, walk[position - 1], walk[position + 2 :], reach, thread)
        found = sides[key]
        if found is None:
            continue
        side, centre, axis = found
        arc = _oriented(graph, loop, loop_rev)
        near, far = _arms_window(graph.branches[loop].length, reach)
        arms = _offset(_within(arc[::-1], near, far), centre, axis)
        arms -= _offset(_within(arc, near, far), centre, axis)
        if abs(side) >= LATERAL and abs(arms) >= LATERAL and side * arms < 0:
            return True
    return False


def _arms_window(loop_length: float, reach: float) -> tuple[float, float]:
    """The arc (px, from each end of a loop ``loop_length`` px long) over which its two arms are
    compared: ``reach / 2`` to ``reach``, but within a quarter of the loop, since past its half
    each end's samples lie on the other arm's side."""
    return min(reach / 2, loop_length / 8), min(reach, loop_length / 4)


def _merged_passes(graph: _Graph, walk: list[tuple[int, bool]], reach: float) -> list[tuple[int, int]]:
    """Positions (first, back) in ``walk`` of a branch passed down and back: merged arms,
    round a free end at its far end (a hairpin's bend), or round a loop there with the tip
    less than ``reach`` px before it (farther, the tip's arm may cross the thread)."""
    found = []
    for first in range(len(walk) - 1):
        k, rev = walk[first]
        far = graph.branches[k].a if rev else graph.branches[k].b
        if walk[first + 1] == (k, not rev) and graph.kind[far] == "end":
            found.append((first, first + 1))
        elif first + 2 < len(walk) and walk[first + 2] == (k, not rev):
            loop = graph.branches[walk[first + 1][0]]
            if loop.is_loop and sum(graph.branches[j].length for j, _ in walk[:first]) < reach:
                found.append((first, first + 2))
    return found


def _hairpin_turns(graph: _Graph, walk: list[tuple[int, bool]], passes: list[tuple[int, int]]) -> list[int]:
    """Indices into ``walk``'s pixels where it turns back at a free end (a hairpin's bend; of the
    ``passes`` of :func:`_merged_passes`) at the end of a branch at least ``SMOOTHING`` px long
    (a shorter one is a spur of the thinning or the stub of an arm the mask lost, which the
    smoothing averages away)."""
    ends = np.cumsum([len(piece) for piece in _pieces(graph, walk)]) - 1
    return [
        int(ends[first])
        for first, back in passes
        if back == first + 1 and graph.branches[walk[first][0]].length >= SMOOTHING
    ]


def _split_merged_arms(
    graph: _Graph,
    walk: list[tuple[int, bool]],
    passes: list[tuple[int, int]],
    reach: float,
    thread: cKDTree,
    depth: np.ndarray,
) -> np.ndarray:
    """``walk``'s pixels (N, 2) float64, those of merged arms (its ``passes`` down and back, from
    :func:`_merged_passes`) moved from the stroke's centre onto the arms: the way back to the
    side the thread leaves by (:func:`_stroke_side`), the way down to the other, each by the
    stroke's half width ``depth`` (the distance to the background at the pixel) less the leaving
    thread's, which is half the arms' spacing."""
    pieces = [piece.astype(np.float64) for piece in _pieces(graph, walk)]
    for first, back in passes:
        found = _stroke_side(graph, walk[first], walk[back + 1 :], reach, thread)
        if found is None or abs(found[0]) < SPLIT_SIDE:
            continue
        side, _, axis = found
        normal = np.array([-axis[1], axis[0]])
        if back + 1 == len(pieces):
            continue
        leaving = np.rint(_within(np.vstack(pieces[back + 1 :]), 0.0, 2 * reach)).astype(int)
        half = float(np.median(depth[leaving[:, 1], leaving[:, 0]]))
        for position, sign in ((first, -1.0), (back, 1.0)):
            pixels = pieces[position]
            if len(pixels) < 2:
                continue
            tangent = np.gradient(uniform_filter1d(pixels, SMOOTHING, axis=0, mode="nearest"), axis=0)
            normals = np.column_stack([-tangent[:, 1], tangent[:, 0]])
            normals /= np.maximum(np.hypot(*normals.T), 1e-9)[:, None]
            normals *= np.where(normals @ normal < 0, -1.0, 1.0)[:, None]
            ints = np.rint(pixels).astype(int)
            shift = np.clip(depth[ints[:, 1], ints[:, 0]] - half, 0.0, 2 * half)
            pieces[position] = pixels + (sign * math.copysign(1.0, side) * shift)[:, None] * normals
    return np.vstack(pieces)


def _resampled(points: np.ndarray, spacing: float = 1.0) -> np.ndarray:
    """``points`` ((K, 2), along a line) every ``spacing`` px of arc from the first."""
    along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))])
    at = np.arange(0.0, along[-1] + 1e-9, spacing)
    return np.column_stack([np.interp(at, along, points[:, 0]), np.interp(at, along, points[:, 1])])


def _disagreement(path: np.ndarray, guide: np.ndarray, slack: float) -> float:
    """How far (px) ``path`` strays from ``guide`` ((K, 2) each, from the tip): of each point
    of ``path`` (every 1 px of arc, over the shorter one's length), the distance to the nearest
    point of ``guide`` within ``slack`` px of the same arc length; the largest. Two walks round
    a loop differ only there, a tenth of the walk or less: a percentile would not see it."""
    a, b = _resampled(path), _resampled(guide)
    count = min(len(a), len(b))
    reach = math.ceil(slack)
    shifts = np.arange(-reach, reach + 1)
    index = np.clip(np.arange(count)[:, None] + shifts[None, :], 0, len(b) - 1)
    distance = np.hypot(*(a[:count, None, :] - b[index]).transpose(2, 0, 1)).min(axis=1)
    return float(distance.max())


def hook_walk(
    mask: np.ndarray,
    tip: np.ndarray,
    window_radius: float,
    step: float,
    spur: float,
    near: float,
    guide: np.ndarray | None = None,
    scale: float = 1.0,
    other: Alternatives | None = None,
    choice: int | None = None,
) -> _Walked | None:
    """(N, 2) float64 (u, v) pixels from the skeleton pixel nearest to ``tip`` through the hook
    to the rim of the window of ``window_radius`` px around it, or None (no walk: the thread
    does not leave the window, or the skeleton there is not a hook's). Zhang's thinning eats a
    2 px thread at 45 degrees back from its ends, by half the line's length: where no skeleton
    pixel lies within ``near`` of ``tip``, the window is thinned otherwise
    (:func:`skimage.morphology.thin`), and a free end whose thread runs on ahead of it to the
    window's edge is the edge's (:func:`_runs_to_rim`).

    ``mask``: (H, W) bool or 0/1, the cleaned mask; ``step``: chord length (px) of the turns;
    ``spur``: branches to a free end shorter than this are thinning spurs; ``near``: a free end
    this near to ``tip`` is the start; ``guide``: (K, 2) pixels of the same thread from its tip
    (the other view's, shifted by the disparity), or None; with it, only the walks within
    ``GUIDE_MARGIN`` px of the one that strays least from it compete, and the walk taken keeps
    its first point through the smoothing (:func:`_smoothed`); ``scale``: the image
    width / 640 (the guide's tolerances). Also whether the walk comes back to a node it passed,
    and the walks that competed (:class:`Alternatives`).

    ``other``: the other view's alternatives (shifted by the disparity), with a guide. Where the
    walk this view's own rule would take is not among those that agree with the guide, the
    views' evidence disagrees (one view's side of merged arms or turn says one way round a
    loop, the other's the other way); then each walk is paired with the other view's walk it
    strays least from, and of the walks whose pair lies within ``GUIDE_MARGIN`` px of the
    nearest pair, the one whose score and its pair's score sum least wins: both views' evidence
    counts. The pair's index is returned (``other_choice``), so that the other view can take
    it. ``choice``: the index of the walk to take (the pair the other view chose), or None.
    """
    height, width = mask.shape
    r = math.ceil(window_radius)
    cu, cv = round(float(tip[0])), round(float(tip[1]))
    u0, v0 = max(0, cu - r), max(0, cv - r)
    u1, v1 = min(width, cu + r + 1), min(height, cv + r + 1)
    window = np.asarray(mask[v0:v1, u0:u1], dtype=np.uint8)
    yy, xx = np.mgrid[v0:v1, u0:u1]
    inside = np.hypot(xx - cu, yy - cv) <= window_radius
    window = window * inside.astype(np.uint8)
    _, pieces = cv2.connectedComponents(window, connectivity=8)
    on = np.argwhere(window > 0)
    if on.size == 0:
        return None
    nearest = on[np.argmin(np.hypot(on[:, 1] + u0 - tip[0], on[:, 0] + v0 - tip[1]))]
    own = pieces == pieces[nearest[0], nearest[1]]
    skeleton = skeletonize(own)
    sv, su = np.nonzero(skeleton)
    if su.size < 2:
        return None
    distance = np.hypot(su + u0 - tip[0], sv + v0 - tip[1])
    if distance.min() > near:  # Zhang's thinning ate a thin diagonal end back: thin it otherwise
        thinned = thin(own)
        tv, tu = np.nonzero(thinned)
        reach = np.hypot(tu + u0 - tip[0], tv + v0 - tip[1])
        if tu.size >= 2 and reach.min() <= near:
            skeleton, su, sv, distance = thinned, tu, tv, reach
    start = int(np.argmin(distance))
    ends = free_ends(skeleton)
    if len(ends):  # the cut tip at a free end next to the pixel: start there
        gap = np.hypot(ends[:, 0] + u0 - tip[0], ends[:, 1] + v0 - tip[1])
        if gap.min() <= near:
            start = int(np.flatnonzero((su == ends[np.argmin(gap), 0]) & (sv == ends[np.argmin(gap), 1]))[0])
    rim = (np.hypot(xx - cu, yy - cv) >= window_radius - 3 - spur) | (xx < 2) | (yy < 2)
    rim |= (xx > width - 3) | (yy > height - 3)
    graph = _skeleton_graph(skeleton, np.array([su[start], sv[start]]), rim)
    if graph is None:
        return None
    # Thinning shortens a free end: the walk turns at the mask's end, and starts there when the
    # tip is a free end of the skeleton (one branch leaves it).
    tip_branches = sum((b.a == graph.tip) + (b.b == graph.tip) for b in graph.branches)
    for branch in graph.branches:
        for first, node in ((True, branch.a), (False, branch.b)):
            at_tip = node == graph.tip and tip_branches == 1
            if (graph.kind[node] != "end" and not at_tip) or branch.length < spur:
                continue
            end = branch.pixels[0] if first else branch.pixels[-1]
            inner = _within(
                (branch.pixels if first else branch.pixels[::-1]).astype(np.float64), 0.0, 2 * step
            )
            outward = end - inner.mean(axis=0)
            axis = outward if at_tip else None  # the cut tip's end may be eaten back far
            outer = extend_to_end(own, end.astype(np.float64), 2 * step if at_tip else step, axis)
            if at_tip:
                outer = _along_mask(own, end.astype(np.float64), outer)
            else:  # the thread cut by the window's edge, slanting, or thin and eaten back from it
                u, v = np.clip(np.rint(outer).astype(int), 0, np.array(own.shape[::-1]) - 1)
                if rim[v, u] or _runs_to_rim(own, rim, end, outward, RIM_REACH * step):
                    graph.kind[node] = "rim"
            reach = float(np.hypot(*(outer - end)))
            if reach >= 1.0:
                fractions = np.arange(1, math.ceil(reach) + 1)[:, None] / math.ceil(reach)
                extra = end + fractions * (outer - end)
                branch.pixels = np.vstack([extra[::-1], branch.pixels] if first else [branch.pixels, extra])
    depth = cv2.distanceTransform(own.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    places = _places(graph, spur)
    walks = _walks(graph, spur, _passing_strands(graph, places, depth, spur, step))
    thread, sides = cKDTree(np.argwhere(own)[:, ::-1].astype(np.float64)), {}
    if not walks:
        return None
    scored = []
    for walk in walks:
        turn, path = _turning(graph, walk, step)
        scored.append((turn + 1e-3 * len(path), path))
    against = [_loop_against_side(graph, walk, step, thread, sides) for walk in walks]
    for index, flagged in enumerate(against):
        if flagged:
            scored[index] = (scored[index][0] + SIDE_PENALTY, scored[index][1])
    best = min(range(len(scored)), key=lambda k: scored[k][0])
    offset = np.array([u0, v0], dtype=np.float64)
    smoothed = [uniform_filter1d(path, SMOOTHING, axis=0, mode="nearest") + offset for _, path in scored]
    other_choice = None
    if choice is not None and 0 <= choice < len(scored):
        best = choice
    elif guide is not None:
        apart = [_disagreement(path, guide, GUIDE_SLACK * scale) for path in smoothed]
        agreeing = [k for k in range(len(scored)) if apart[k] <= min(apart) + GUIDE_MARGIN * scale]
        pairs = len(scored) * (0 if other is None else len(other.paths))
        guided = min(agreeing, key=lambda k: scored[k][0])
        both = None
        if best not in agreeing and other is not None and len(other.paths) > 1 and pairs <= MAX_PAIRS:
            scores = [score for score, _ in scored]
            both = _both_views(smoothed, scores, against, other, scale, (best, guided))
        best, other_choice = (guided, None) if both is None else both
    passes = _merged_passes(graph, walks[best], step)
    path = _split_merged_arms(graph, walks[best], passes, step, thread, depth)
    turns = _hairpin_turns(graph, walks[best], passes)
    if tip_branches > 1:  # the tip inside a stroke: its arm may run on past the skeleton's pixel
        tail = np.rint(path[-max(2, len(path) // 3) :]).astype(int)
        half = max(0.0, float(np.median(depth[tail[:, 1], tail[:, 0]])) - 0.5)
        moved = _to_tip(own, path, np.asarray(tip, dtype=np.float64) - (u0, v0), step, half)
        turns = [turn + len(moved) - len(path) for turn in turns]
        path = moved
    nodes = [graph.tip] + [graph.branches[k].a if rev else graph.branches[k].b for k, rev in walks[best]]
    revisits = len({places[n] for n in nodes}) < len(nodes)
    path = _smoothed(path, keep_start=guide is not None, turns=turns)
    alternatives = Alternatives(tuple(smoothed), tuple(score for score, _ in scored), tuple(against), best)
    return _Walked(path + offset, revisits, alternatives, other_choice)


def _smoothed(path: np.ndarray, keep_start: bool, turns: list[int] | tuple[int, ...] = ()) -> np.ndarray:
    """``path`` ((N, 2) float64) averaged over ``SMOOTHING`` points (skeleton pixels zigzag by a
    pixel). The average pulls the first point inward along the path (about 0.9 px); with
    ``keep_start`` the path is first continued past its start by its own points mirrored
    through it, so that a straight start stays put: a walk from the other view's tip (already
    smoothed once) starts at that tip's match. At each of ``turns`` (indices where the walk
    turns back at a free end, a hairpin's bend, at the mask's end) the path is cut and each side
    smoothed as its own end kept in place: averaged across the U-turn, the bend would be pulled
    2-3 px in from where the walk turned, the bend's rim left off the sequence and its arc cut
    short. Kept at the mask's end, the bend lies half the thread's width beyond the centreline's,
    which about makes up the arc that the walk's sharp turn cuts from the bend's round one."""
    lead = SMOOTHING // 2
    cuts = [0, *sorted(turn for turn in turns if lead < turn < len(path) - 1 - lead), len(path) - 1]
    legs = []
    for number, (start, stop) in enumerate(itertools.pairwise(cuts)):
        leg = _smoothed_leg(path[start : stop + 1], keep_start or number > 0, number < len(cuts) - 2)
        legs.append(leg if number == 0 else leg[1:])
    return np.vstack(legs)


def _smoothed_leg(path: np.ndarray, keep_start: bool, keep_end: bool) -> np.ndarray:
    """``path`` ((N, 2) float64) averaged over ``SMOOTHING`` points, each end it keeps
    (``keep_start``, ``keep_end``) continued past it by the path's own points mirrored through
    it, so that a straight end stays put."""
    lead = SMOOTHING // 2
    keep_start, keep_end = keep_start and len(path) > lead, keep_end and len(path) > lead
    before = [2 * path[:1] - path[lead:0:-1]] if keep_start else []
    after = [2 * path[-1:] - path[-2 : -lead - 2 : -1]] if keep_end else []
    smoothed = uniform_filter1d(np.vstack([*before, path, *after]), SMOOTHING, axis=0, mode="nearest")
    first = lead if keep_start else 0
    return smoothed[first : first + len(path)]


def _both_views(
    paths: list[np.ndarray],
    scores: list[float],
    against: list[bool],
    other: Alternatives,
    scale: float,
    contested: tuple[int, int],
) -> tuple[int, int] | None:
    """The walk (an index of ``paths``, each (K, 2) float64 (u, v), with ``scores`` and the
    side rule's flags ``against``) and its pair among ``other``'s walks (an index) whose scores
    sum least, of the walks whose pair (the other view's walk each strays least from,
    :func:`_disagreement`) lies within ``GUIDE_MARGIN`` px (at 640 px) of the nearest pair.

    ``contested``: this view's own choice and the guide's. None where the side rule tells
    neither view's two ways apart (the views differ in turning only): the guide's choice
    stands, the other view's walk starting from the cut tip's pixel itself rather than one
    matched by disparity."""
    apart = np.array(
        [[_disagreement(path, theirs, GUIDE_SLACK * scale) for theirs in other.paths] for path in paths]
    )
    pair = np.argmin(apart, axis=1)
    own, guided = contested
    if against[own] == against[guided] and other.against[other.chosen] == other.against[pair[own]]:
        return None
    nearest = apart[np.arange(len(paths)), pair]
    matched = np.flatnonzero(nearest <= nearest.min() + GUIDE_MARGIN * scale)
    total = np.asarray(scores)[matched] + np.asarray(other.scores)[pair[matched]]
    best = int(matched[int(np.argmin(total))])
    return best, int(pair[best])


@dataclass(frozen=True)
class Alternatives:
    """The walks that competed through a hook (:func:`hook_walk`): ``paths``, each (K, 2)
    float64 (u, v) from the tip (the skeleton's pixels, smoothed); ``scores``: each walk's
    turning plus side penalty (rad, the least wins); ``against``: whether the side rule
    penalised each (:func:`_loop_against_side`); ``chosen``: the index taken."""

    paths: tuple[np.ndarray, ...]
    scores: tuple[float, ...]
    against: tuple[bool, ...]
    chosen: int

    def shifted(self, offset: np.ndarray) -> Alternatives:
        """The same walks moved by ``offset`` ((2,) px, u, v): the other view's."""
        moved = tuple(path + offset for path in self.paths)
        return Alternatives(moved, self.scores, self.against, self.chosen)


@dataclass(frozen=True)
class _Walked:
    """What :func:`hook_walk` found: the walk's ``points`` (N, 2) float64 (u, v), whether it
    ``revisits`` a node it passed, the ``alternatives`` that competed, and ``other_choice`` (see
    :class:`HookStart`)."""

    points: np.ndarray
    revisits: bool
    alternatives: Alternatives
    other_choice: int | None


@dataclass(frozen=True)
class HookStart:
    """The walk from the cut tip through a hook: ``points`` (N, 2) float64 (u, v) ~1 px apart,
    from the tip to the window's rim; ``width``: the thread's width (px) where it leaves, from the
    distance transform (a thread 2-3 px wide reads as 1 px; :func:`follow` reads it again as the
    search does and keeps this only where it finds no cross-section);
    ``alternatives``: the walks that competed; ``other_choice``: where both views' evidence
    chose the walk, the index of the other view's walk paired with it (:func:`hook_walk`),
    else None."""

    points: np.ndarray
    width: float
    alternatives: Alternatives | None = None
    other_choice: int | None = None


def hook_start(
    mask: np.ndarray,
    tip: np.ndarray,
    scaled: ScaledParams,
    require_return: bool = True,
    guide: np.ndarray | None = None,
    other: Alternatives | None = None,
    choice: int | None = None,
) -> HookStart | None:
    """The walk through a hook at ``tip`` ((2,) (u, v), a hint or a free end) in ``mask``
    ((H, W) 0/1, the cleaned mask), or None when there is no hook there: the thread runs from
    the tip straight out of the window (the search of :mod:`suture_ordering.search` orders it),
    or the window holds no walk.

    A hook is a walk that comes back to a place it has passed: a free end it turns back at
    (the bend of merged arms) or a junction it passes twice (a loop). ``require_return=False``:
    any walk out of the window is taken. ``guide``, ``other``, ``choice``: see :func:`hook_walk`.
    """
    window = HOOK_WINDOW * scaled.roi_radius
    found = hook_walk(
        mask,
        tip,
        window,
        float(scaled.step_radius),
        SPUR * scaled.scale,
        NEAR * scaled.scale,
        guide,
        scaled.scale,
        other,
        choice,
    )
    if found is None:
        return None
    points = found.points
    if require_return and not found.revisits:
        return None
    tail = np.rint(points[-max(2, len(points) // 3) :]).astype(int)
    r = int(np.ceil(window)) + 2
    u0, v0 = max(0, int(tip[0]) - r), max(0, int(tip[1]) - r)
    patch = np.ascontiguousarray(mask[v0 : int(tip[1]) + r + 1, u0 : int(tip[0]) + r + 1], dtype=np.uint8)
    depth = cv2.distanceTransform(patch, cv2.DIST_L2, 3)
    inside = (tail[:, 0] - u0 >= 0) & (tail[:, 0] - u0 < patch.shape[1]) & (tail[:, 1] - v0 >= 0)
    inside &= tail[:, 1] - v0 < patch.shape[0]
    tail = tail[inside]
    thread = float(np.median(depth[tail[:, 1] - v0, tail[:, 0] - u0])) if len(tail) else 1.0
    return HookStart(points, max(1.0, 2.0 * thread - 1.0), found.alternatives, found.other_choice)


def follow(context: SearchContext, branch: Branch, start: HookStart) -> None:
    """Advance ``branch`` (at the walk's first point) along the walk: a vertex wherever the walk
    has moved ``DENSE`` px from the last one (so the turn at a bend is kept), the last ``2 r_s``
    px in steps of r_s so that the search goes on with the thread's track and turn.

    The steps carry the thread's width where the walk leaves (:func:`_leaving_width`): the search
    takes a cross-section wider than ``wide_arc_factor`` times its widths so far for merged
    threads and steps along one edge of it, so a width too small would hold it to an edge."""
    points = start.points
    along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))])
    step = float(context.scaled.step_radius)
    marks = np.searchsorted(along, (along[-1] - step, along[-1]))
    behind, end = points[np.minimum(marks, len(points) - 1)]
    width = _leaving_width(context.reader, end, behind, int(step), start.width)
    last_steps = int(np.searchsorted(along, along[-1] - 2 * step))
    chosen, (last_u, last_v) = [], branch.vertices[-1].tolist()
    for k, (u, v) in enumerate(points[1:last_steps].tolist()):
        if math.hypot(u - last_u, v - last_v) >= DENSE:
            chosen.append(k + 1)
            last_u, last_v = u, v
    advance_along(context, branch, points[chosen], width)
    for point in (behind, end):
        if math.hypot(*(point - branch.vertices[-1])) >= 1.0:
            advance(context, branch, point, width)


def _leaving_width(
    reader: MaskReader, end: np.ndarray, behind: np.ndarray, radius: int, estimate: float
) -> float:
    """The thread's width (px) where a walk leaves the hook's window at ``end``, read as the
    search reads cross-sections: the run of mask on the circle of ``radius`` (r_s) about ``end``
    that the walk came in by, the one nearest ``behind`` (the walk's point ``radius`` px of arc
    back). ``estimate`` (from the distance transform, which reads a thread two or three pixels
    wide as one) where there is no such run within 2 px of ``behind``."""
    nodes = reader.nodes(end, radius, None)
    if nodes is None:
        return estimate
    offsets = np.hypot(*(nodes.position - behind).T)
    nearest = int(np.argmin(offsets))
    return float(nodes.width[nearest]) if offsets[nearest] <= 2.0 else estimate


def skipped_near_tip(mask: np.ndarray, points: np.ndarray, tip: np.ndarray, scaled: ScaledParams) -> bool:
    """Whether the ordered ``points`` ((N, 2) from the tip) leave pixels of the tip's thread
    within the hook window unvisited (farther than the detection radius from them): an arm
    or loop of a hook the search went past."""
    r = int(np.ceil(HOOK_WINDOW * scaled.roi_radius))
    height, width = mask.shape
    cu, cv = round(float(tip[0])), round(float(tip[1]))
    u0, v0 = max(0, cu - r), max(0, cv - r)
    window = np.ascontiguousarray(
        mask[v0 : min(height, cv + r + 1), u0 : min(width, cu + r + 1)], dtype=np.uint8
    )
    if not cv2.countNonZero(window):
        return False
    # The path visits the thread's whole cross-section: its half width plus the detection radius.
    polyline = np.rint(points - np.array([u0, v0])).astype(np.int32)
    on_window = (
        (polyline >= 0).all(axis=1) & (polyline[:, 0] < window.shape[1]) & (polyline[:, 1] < window.shape[0])
    )
    depth = cv2.distanceTransform(window, cv2.DIST_L2, 3)
    half = float(np.median(depth[polyline[on_window, 1], polyline[on_window, 0]])) if on_window.any() else 1.0
    visited = np.zeros_like(window)
    thickness = 2 * max(1, round(half + scaled.detect_radius)) + 1
    cv2.polylines(visited, _pieces_near(polyline, window.shape, thickness), False, 1, thickness)
    inside = np.zeros_like(window)
    cv2.circle(inside, (cu - u0, cv - v0), r - scaled.step_radius, 1, cv2.FILLED)
    unvisited = (window > 0) & (visited == 0) & (inside > 0)
    if np.count_nonzero(unvisited) <= SKIPPED * scaled.scale:
        return False  # too few unvisited pixels of any thread in the window
    _, pieces = cv2.connectedComponents(window, connectivity=8)
    on = np.argwhere(window > 0)
    nearest = on[np.argmin(np.hypot(on[:, 1] + u0 - tip[0], on[:, 0] + v0 - tip[1]))]
    thread = pieces == pieces[nearest[0], nearest[1]]
    return int((thread & unvisited).sum()) > SKIPPED * scaled.scale


def _pieces_near(polyline: np.ndarray, shape: tuple[int, int], thickness: int) -> list[np.ndarray]:
    """The stretches of ``polyline`` ((N, 2) int32 (u, v)) whose segments come within
    ``thickness`` px of an image of ``shape`` (H, W): drawn with that thickness, they paint the
    image's pixels that the whole polyline paints (each segment is drawn on its own, with
    round caps), and the other segments none."""
    if len(polyline) < 2:
        return [polyline]
    low = np.minimum(polyline[:-1], polyline[1:])
    high = np.maximum(polyline[:-1], polyline[1:])
    near = (
        (high >= -thickness).all(axis=1)
        & (low[:, 0] < shape[1] + thickness)
        & (low[:, 1] < shape[0] + thickness)
    )
    segments = np.flatnonzero(near)
    if not len(segments):
        return []
    starts = np.flatnonzero(np.diff(segments, prepend=-2) > 1)
    ends = np.append(starts[1:], len(segments)) - 1
    return [polyline[segments[a] : segments[b] + 2] for a, b in zip(starts, ends, strict=True)]


def hook_after_search(
    mask: np.ndarray,
    reader: MaskReader,
    hint: np.ndarray,
    tip: np.ndarray,
    points: np.ndarray,
    scaled: ScaledParams,
    guide: np.ndarray | None = None,
    other: Alternatives | None = None,
) -> HookStart | None:
    """The walk through a hook at ``hint`` when the search from the free end ``tip`` suggests
    one: that end lies farther than ``NEAR`` from the hint (the bend of merged arms, the cut
    tip in the stroke), the thread branches within one step of the tip
    (:func:`branched_near_tip`: the first step had no heading to choose a branch by), the
    search came back near the tip to where it had passed, or it left the tip's neighbourhood
    partly unvisited (:func:`skipped_near_tip`). In the last two cases any walk out of the
    window is taken: the search crossed from arm to arm where the skeleton goes on along one
    line; in the first two only a walk that returns to a place it passed (a hook). ``reader``:
    the search's :class:`~suture_ordering.nodes.MaskReader` of ``mask``. None: no hook; the
    search's sequence stands."""
    far = float(np.hypot(*(np.asarray(tip) - np.asarray(hint)))) > NEAR * scaled.scale
    skipped = skipped_near_tip(mask, points, tip, scaled)
    returns = _returns_near_tip(points, tip, scaled)
    if not (far or skipped or returns or branched_near_tip(reader, tip, scaled)):
        return None
    return hook_start(mask, hint, scaled, require_return=not (skipped or returns), guide=guide, other=other)


def branched_near_tip(reader: MaskReader, tip: np.ndarray, scaled: ScaledParams) -> bool:
    """Whether the circle of radius r_s (the search's step) about ``tip`` ((2,) (u, v)) crosses
    the mask in ``BRANCHED_RUNS`` or more separate runs, read as the search reads its
    cross-sections (``reader``: the search's :class:`~suture_ordering.nodes.MaskReader`): the
    thread forks, or another strand passes, nearer to the cut tip than one step, so the search's
    first step, which has no heading yet, picks a branch by its mask evidence alone."""
    nodes = reader.nodes(np.asarray(tip, dtype=np.float64), scaled.step_radius, None)
    return nodes is not None and len(nodes.position) >= BRANCHED_RUNS


def _returns_near_tip(points: np.ndarray, tip: np.ndarray, scaled: ScaledParams) -> bool:
    """Whether the ordered ``points`` come back, within the hook window, to within the
    detection radius of a point passed at least 2 Υ of arc before."""
    window = HOOK_WINDOW * scaled.roi_radius
    distance = np.hypot(*(points - np.asarray(tip)).T)
    outside = np.flatnonzero(distance > window)
    near = points[: outside[0] if outside.size else len(points)]
    return bool(revisited(near, max(1.0, scaled.detect_radius), 2 * scaled.roi_radius).any())


def stereo_tip(
    left: np.ndarray,
    right: np.ndarray,
    left_tip: np.ndarray,
    disparity_range: tuple[float, float],
    row_tolerance: float,
    scaled: ScaledParams,
) -> np.ndarray | None:
    """The right view's pixel of ``left_tip`` ((2,) (u, v)): the left tip shifted by the
    disparity (and row offset, within ``row_tolerance``) that lays the left mask's window
    around it (the hook window) best onto the right mask (most pixels in common); None when no
    shift in the range lays any pixel onto the right mask."""
    height, width = left.shape
    r = math.ceil(HOOK_WINDOW * scaled.roi_radius)
    u, v = round(float(left_tip[0])), round(float(left_tip[1]))
    tu0, tu1 = max(0, u - r), min(width, u + r + 1)
    tv0, tv1 = max(0, v - r), min(height, v + r + 1)
    d_min = int(np.floor(disparity_range[0] - row_tolerance))
    d_max = int(np.ceil(disparity_range[1] + row_tolerance))
    t = int(np.ceil(row_tolerance))
    iu0, iu1 = max(0, tu0 - d_max), min(width, tu1 - d_min)
    iv0, iv1 = max(0, tv0 - t), min(height, tv1 + t)
    template = np.asarray(left[tv0:tv1, tu0:tu1], dtype=np.float32)
    image = np.asarray(right[iv0:iv1, iu0:iu1], dtype=np.float32)
    if image.shape[0] < template.shape[0] or image.shape[1] < template.shape[1] or not template.any():
        return None
    score = cv2.matchTemplate(image, template, cv2.TM_CCORR)
    dv = np.arange(score.shape[0])[:, None] + iv0 - tv0
    score = score - 1e-3 * np.abs(dv)  # of equal overlaps, the nearest row
    y, x = np.unravel_index(int(np.argmax(score)), score.shape)
    if score[y, x] < 1.0:
        return None
    shift = _refined_shift(left, right, (u, v), (x + iu0 - tu0, y + iv0 - tv0), scaled.roi_radius)
    return np.asarray(left_tip, dtype=np.float64) + np.asarray(shift, dtype=np.float64)


def _refined_shift(
    left: np.ndarray, right: np.ndarray, tip: tuple[int, int], shift: tuple[int, int], radius: int
) -> tuple[int, int]:
    """The shift (du, 0) px along the row that lays the left mask's pixels within ``radius`` px
    (one RoI radius) of ``tip`` (u, v) best onto the right mask, within ``radius / 2`` px plus
    the row offset of ``shift`` (du, dv), the hook window's best shift: the thread's depth
    changes along it, so the window's shift suits the thread there as a whole rather than its
    tip; and a thread slanting across the rows matches nearly as well shifted along itself,
    so the window's shift may have traded a column for a row, which the rectified pair's rows
    do not. Of equal overlaps the one nearest ``shift``; ``shift`` where the tip's
    neighbourhood overlaps nothing."""
    height, width = left.shape
    u, v = tip
    reach = max(1, radius // 2) + abs(int(shift[1]))
    tu0, tu1 = max(0, u - radius), min(width, u + radius + 1)
    tv0, tv1 = max(0, v - radius), min(height, v + radius + 1)
    iu0, iu1 = tu0 + shift[0] - reach, tu1 + shift[0] + reach
    if iu0 < 0 or iu1 > width:
        return shift
    template = np.asarray(left[tv0:tv1, tu0:tu1], dtype=np.float32)
    if not template.any():
        return shift
    image = np.asarray(right[tv0:tv1, iu0:iu1], dtype=np.float32)
    score = cv2.matchTemplate(image, template, cv2.TM_CCORR)[0]
    du = np.arange(len(score)) - reach
    score = score - 1e-3 * np.abs(du)
    best = int(np.argmax(score))
    if score[best] < 1.0:
        return shift
    return int(shift[0] + du[best]), 0


def on_mask(mask: np.ndarray, point: np.ndarray, radius: float = 1.5) -> bool:
    """Whether a pixel of ``mask`` lies within ``radius`` px of ``point`` ((2,) (u, v))."""
    r = math.ceil(radius)
    u, v = round(float(point[0])), round(float(point[1]))
    rows, cols = np.nonzero(mask[max(0, v - r) : v + r + 1, max(0, u - r) : u + r + 1])
    offsets = np.hypot(cols + max(0, u - r) - point[0], rows + max(0, v - r) - point[1])
    return bool(np.any(offsets <= radius))
