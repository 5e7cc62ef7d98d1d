# SPDX-License-Identifier: Apache-2.0
"""The ordering search of the paper's Section II.B (Eq. 4-7), vectorised per step.

Starting at the cut tip ``V^1``, each loop ``t`` elects the next vertex
``V^{t+1}`` among the *active nodes* ``A^t`` by the composite cost of Eq. (5)::

    C_j = log(ε1 * O_j + μ) + ε2 * |A_j - V^t| * exp(ε3 * sin(δ_j / 2))

with argmin selection (Eq. 6), the admissibility / termination thresholds
``O_j < τ_O`` and ``δ_j < τ_V`` and the tuning of (ε1, ε2, ε3) over R1 x R2 x R3
that maximises the sequence length (Eq. 7).

This module runs the search (:class:`Searcher`); each choice where the paper is
ambiguous is described in the module that makes it (and tested in ``test/test_search.py``):

* :mod:`suture_ordering.nodes`: centreline nodes on circles and the out-of-zone number O;
* :mod:`suture_ordering.steps`: active, detected and far nodes, the next vertex;
* :mod:`suture_ordering.path`: the traversed path and the turning angle δ;
* :mod:`suture_ordering.bridging`: τ_O and gaps in the mask;
* :mod:`suture_ordering.occluders`: wider gaps, where an instrument lies across the thread;
* :mod:`suture_ordering.junctions`: crossings, the thread's own loops, touching threads;
* :mod:`suture_ordering.loops`: leaving a loop across the first pass;
* :mod:`suture_ordering.hooks`: the start through a hook at the cut tip;
* :mod:`suture_ordering.ending`: termination and the free end;
* :mod:`suture_ordering.tuning`: Eq. (5) over the grid of Eq. (7);
* :mod:`suture_ordering.geometry`: angles, bends and the Hermite curve of a smooth step.

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

from dataclasses import dataclass

import numpy as np

from suture_ordering.cleaning import CleanMask
from suture_ordering.context import SearchContext
from suture_ordering.ending import append_tail, end_status
from suture_ordering.hooks import HookStart, follow
from suture_ordering.junctions import STOP
from suture_ordering.loops import across_own_path
from suture_ordering.nodes import Candidates, MaskReader
from suture_ordering.occluders import across_occluder
from suture_ordering.params import OrderingParams, ScaledParams
from suture_ordering.path import Branch, advance
from suture_ordering.steps import next_candidates
from suture_ordering.tuning import parameter_grid, tuning_for

__all__ = ["SearchResult", "Searcher", "parameter_grid"]


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


class Searcher:
    """The search of one cleaned mask; :meth:`run` orders the thread from a tip.

    Raises ValueError when the mask's padding is smaller than the search's reach.
    """

    def __init__(self, clean: CleanMask, params: OrderingParams, scaled: ScaledParams) -> None:
        if clean.pad < scaled.max_reach + scaled.step_radius + 2:
            raise ValueError("mask padding is smaller than the search reach")
        self.context = SearchContext(
            reader=MaskReader(clean, params.wide_arc_factor, scaled.step_radius),
            params=params,
            scaled=scaled,
            tuning=tuning_for(params, scaled.max_reach),
            thickness=max(1, round(2 * scaled.detect_radius)),
        )

    def run(self, tip: np.ndarray, hook: HookStart | None = None) -> SearchResult:
        """Order the thread from ``tip`` ((2,) float (u, v), a free end on the mask), or along
        ``hook`` (a walk through a hook from the tip, :mod:`suture_ordering.hooks`) and on."""
        context = self.context
        grid = context.tuning.grid
        start = np.asarray(tip, float) if hook is None else hook.points[0]
        consumed = np.zeros(context.reader.mask.shape, dtype=np.uint8)  # calloc'd: no blank copy
        root = Branch(rows=np.arange(len(grid)), consumed=consumed, vertices=[start])
        if hook is not None:
            follow(context, root, hook)
        pending = [root]
        finished: list[Branch] = []
        forks = 0
        while pending:
            branch = pending.pop()
            while True:
                if branch.steps >= context.params.max_steps:
                    branch.status = "max_steps"
                    break
                found = next_candidates(context, branch)
                on_strand = found is STOP
                if found is None or on_strand:
                    found = across_own_path(context, branch, on_strand)
                if found is None:
                    found = across_occluder(context, branch, on_strand)
                if found is None:
                    append_tail(context, branch)
                    branch.status = end_status(context, branch.vertices[-1])
                    break
                if found.decided is not None:  # every parameter set takes this node
                    _step_to(context, branch, found, found.decided)
                    continue
                choice = np.argmin(context.tuning.cost(branch.rows, found), axis=1)
                chosen = np.unique(choice)
                if len(chosen) > 1:  # the parameter sets disagree: fork
                    forks += len(chosen) - 1
                    for j in chosen[1:]:
                        other = branch.fork(branch.rows[choice == j])
                        _step_to(context, other, found, j)
                        pending.append(other)
                    branch.rows = branch.rows[choice == chosen[0]]
                _step_to(context, branch, found, int(chosen[0]))
            finished.append(branch)
        best = max(finished, key=lambda b: (b.length, 0 in b.rows, -int(b.rows.min())))
        return self._result(best, forks)

    def _result(self, branch: Branch, forks: int) -> SearchResult:
        start = branch.vertices[0][None, :]
        points = np.vstack([start, *branch.segments]) if branch.segments else start.copy()
        bridged = np.zeros(len(points), dtype=bool)
        offset = 1
        for segment, is_bridge in zip(branch.segments, branch.segment_bridged, strict=True):
            if is_bridge:
                bridged[offset : offset + len(segment) - 1] = True  # the far end is on the thread
            offset += len(segment)
        row = 0 if 0 in branch.rows else int(branch.rows[0])
        eps = tuple(float(x) for x in self.context.tuning.grid[row])
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


def _step_to(context: SearchContext, branch: Branch, found: Candidates, j: int) -> None:
    """Advance ``branch`` to candidate ``j`` of ``found``."""
    advance(context, branch, found.position[j], float(found.width[j]), found.continuation[j], found.bridge[j])
