# SPDX-License-Identifier: Apache-2.0
"""Spatial shape optimisation: Algorithm 1 of the paper (Section II.C, Eq. 8-12) on a sparse graph.

Given the dense 3D vertices V^1..V^w1 in thread order (from the cut tip), the
paper builds a graph whose edge (i, t) costs D^(i<->t) * W^(i<->t) (Hadamard
product of the length matrix D_G and the weight matrix W_G, Eq. 12) and takes
Dijkstra's shortest path from the first to the last vertex:

* **Length** (Eq. 8): D^(i<->t) = |V^i - V^t| if it is at most tau_L, else
  infinity (no edge); the diagonal is infinity (no self edges).
* **Density penalty** of a vertex (Eq. 9): with the N_t other vertices within a
  sphere of radius Upsilon_3 around V^t at distances d_j,
  P_1^t = S_f / N_t * exp(-N_t / (2 sigma_1)) * sum_j log(d_j + nu_1).
  Clustered vertices (the thread core) are cheap to pass through, isolated
  outliers are expensive. A vertex with no neighbour in its sphere (N_t = 0,
  where the formula is 0/0) gets the largest value a single neighbour could
  give: P_1^t = S_f * log(Upsilon_3 + nu_1).
* **Edge penalties**: P_1^(i<->t) = P_1^i * P_1^t (Eq. 10) and the order
  penalty P_2^(i<->t) = 1 + exp(|i - t| / 20 - 2) (Eq. 11; its 20 is
  ``order_scale``, below), so the path may
  skip a few vertices to remove zig-zags but never jumps between strands that
  are far apart along the thread (the short cut across a self-crossing).
  W^(i<->t) = P_1^(i<->t) * P_2^(i<->t); W's diagonal is 1.
* **Algorithm 1**: while Dijkstra finds no path (L_min = infinity), tau_L grows
  by 0.5.

Unit choices (the paper gives none):

* Lengths are in **millimetres** inside this module: D, tau_L, its step of 0.5
  (so 0.5 mm), Upsilon_3, nu_1 and the d_j in the logarithm of Eq. 9. The
  public parameters (:class:`ShapeGraphParams`) are in metres, as everywhere in
  the pipeline, and converted here. With nu_1 = 1 mm the logarithm is positive
  for every d_j > 0, so all edge costs are positive, as Dijkstra needs. A zero
  cost (all neighbours exactly on top of a vertex) is floored at 1e-12.
* The indices i, t in Eq. 11 are positions in the vertex sequence given here.
  The reconstruction resamples its vertices every ``vertex_step`` (0.1 mm by
  default) before this stage, so an index difference is a length along the
  thread whatever the camera resolution or depth. The order penalty is what
  keeps Dijkstra on the thread where two stretches of it touch in 3D: the
  strands of a self-crossing (0.3-0.7 mm apart in truth, less than the depth
  error) and the two arms of a hook or hairpin at the cut end (touching along
  1-10 mm), where the density penalty even makes the short cut cheaper. The
  paper's 20 in Eq. 11 is therefore ``order_scale`` = 3 vertices (0.3 mm):
  skipping 0.5 mm of a zig-zag costs 1.7 times its length, and the short cut
  between the two arms of a 2 mm hairpin (an index difference of 40) costs
  1 + e^11 times its length, more than walking round the bend. A scale of 20
  vertices (2 mm) would price it at 2 times its 0.3 mm, and Dijkstra would take
  it, moving the grasp point by twice the hook's length. At 5 vertices the apex
  of the tightest hairpins (radius 0.3 mm: 0.94 mm of arc, the arms 0.6 mm
  apart) was still cut, 9 vertices for 1.8 times 0.6 mm, cheaper than going
  round where the density penalty favours the touching arms: about 2 mm of arc
  lost before the grasp point.
* tau_L starts at 1 mm (10 vertex steps: consecutive vertices are always
  joined, and a hop may skip a zig-zag of up to 1 mm); it only grows where the
  vertex chain has a gap (a stretch without stereo pairs).
* sigma_1 and S_f are dimensionless (a neighbour count and a scale). With
  Upsilon_3 = 1 mm and 0.1 mm between vertices a vertex on a single strand has
  N ~ 20 neighbours; sigma_1 = 10 puts that at exp(-1) and a vertex at a
  crossing (N ~ 40) at exp(-2), so crossings are only e times cheaper per
  vertex (sigma_1 = 5 would make them e^2 cheaper, and did let Dijkstra cut
  one of 50 simulated loops) while isolated outliers (N ~ 0-2) still cost
  about 2.5 times more.

Sparse implementation: the only edges are vertex pairs within max(tau_L) of
each other, found with ``scipy.spatial.cKDTree``; penalties use the pairs within
Upsilon_3; Dijkstra is ``scipy.sparse.csgraph.dijkstra`` on the undirected CSR
graph. Growing tau_L one step at a time and stopping at the first value whose
graph joins the two ends is replaced by an exact binary search over the same
ladder tau_L0 + 0.5 k (whether a path exists is monotone in tau_L, and the
consecutive-vertex chain bounds the answer), checked with connected components;
the result, tau_L and path, is the one the loop gives. The test suite compares
it with a literal dense w1 x w1 implementation.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from suture_common.parameters import described
from suture_reconstruction.errors import TooFewPointsError

_MM = 1000.0
_COST_FLOOR = 1e-12


@dataclass(frozen=True)
class ShapeGraphParams:
    """Parameters of Algorithm 1, lengths in metres (converted to mm internally, see module docstring).

    ``tau_l``: initial edge length limit tau_L (1 mm); ``tau_step``: its growth
    step (the paper's 0.5, read as 0.5 mm); ``upsilon3``: radius of the density
    sphere Upsilon_3 (1 mm); ``sigma1``: steepness of the count term (10 neighbours);
    ``scale``: S_f; ``nu1``: nu_1 (1 mm); ``order_scale`` and ``order_offset``:
    Eq. 11's divisor, in vertices (the paper's 20; see the module docstring), and its 2;
    ``max_tau_l``: give up beyond this limit (m).
    """

    tau_l: float = field(
        default=0.001,
        metadata=described(
            "Algorithm 1: initial edge length limit tau_L (m)",
            (0.0, 0.1),
        ),
    )
    tau_step: float = field(
        default=0.0005,
        metadata=described(
            "Algorithm 1: growth step of tau_L (m; the paper's 0.5, read as 0.5 mm)",
            (0.0, 0.1),
        ),
    )
    upsilon3: float = field(
        default=0.001,
        metadata=described(
            "Algorithm 1: radius Upsilon_3 (m) of the density sphere of Eq. 9",
            (0.0, 0.1),
        ),
    )
    sigma1: float = field(
        default=10.0,
        metadata=described(
            "Algorithm 1: steepness sigma_1 (neighbour count) of Eq. 9",
            (0.0, 1000.0),
        ),
    )
    scale: float = 1.0
    nu1: float = field(
        default=0.001,
        metadata=described(
            "Algorithm 1: nu_1 (m) of Eq. 9",
            (0.0, 0.1),
        ),
    )
    order_scale: float = 3.0
    order_offset: float = 2.0
    max_tau_l: float = 0.1

    def __post_init__(self) -> None:
        for name in ("tau_l", "tau_step", "upsilon3", "sigma1", "scale", "nu1", "order_scale", "max_tau_l"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"shape graph parameter {name} must be positive and finite, got {value}")


@dataclass(frozen=True)
class ShapePath:
    """Result of Algorithm 1.

    ``indices`` (w2,) int: the vertices of the shortest path, first to last;
    ``tau_l`` (m): the edge limit at which a path was found; ``steps``: how many
    0.5 mm growth steps that took; ``cost``: L_min, the weighted path cost
    (mm, times the dimensionless weights); ``length`` (m): the path's geometric length.
    """

    indices: np.ndarray
    tau_l: float
    steps: int
    cost: float
    length: float


def vertex_penalties(vertices_mm: np.ndarray, params: ShapeGraphParams) -> np.ndarray:
    """P_1^t of Eq. 9 for (n, 3) vertices in millimetres, (n,) float64."""
    n = len(vertices_mm)
    radius = params.upsilon3 * _MM
    nu1 = params.nu1 * _MM
    pairs = cKDTree(vertices_mm).query_pairs(radius, output_type="ndarray")
    distance = np.linalg.norm(vertices_mm[pairs[:, 0]] - vertices_mm[pairs[:, 1]], axis=1)
    logs = np.log(distance + nu1)
    ends = pairs.ravel()  # each pair counts for both of its vertices
    count = np.bincount(ends, minlength=n)
    log_sum = np.bincount(ends, weights=np.repeat(logs, 2), minlength=n)
    with np.errstate(divide="ignore", invalid="ignore"):
        penalty = params.scale / count * np.exp(-count / (2.0 * params.sigma1)) * log_sum
    return np.where(count > 0, penalty, params.scale * np.log(radius + nu1))


def order_penalty(i: np.ndarray, t: np.ndarray, params: ShapeGraphParams) -> np.ndarray:
    """P_2 of Eq. 11: 1 + exp(|i - t| / order_scale - order_offset)."""
    return 1.0 + np.exp(np.abs(i - t) / params.order_scale - params.order_offset)


def optimise_shape(vertices: np.ndarray, params: ShapeGraphParams | None = None) -> ShapePath:
    """Algorithm 1 on (n, 3) vertices (m) ordered from the cut tip: the shortest path from first to last.

    Raises TooFewPointsError for fewer than 2 vertices and ValueError when no
    path exists below ``params.max_tau_l``.
    """
    params = params or ShapeGraphParams()
    vertices = np.asarray(vertices, dtype=np.float64)
    n = len(vertices)
    if n < 2:
        raise TooFewPointsError(f"the shape graph needs at least 2 vertices, got {n}")
    mm = vertices * _MM
    tree = cKDTree(mm)
    penalty = vertex_penalties(mm, params)
    tau0, step = params.tau_l * _MM, params.tau_step * _MM

    def pairs_within(tau: float) -> tuple[np.ndarray, np.ndarray]:
        pairs = tree.query_pairs(tau, output_type="ndarray")
        return pairs, np.linalg.norm(mm[pairs[:, 0]] - mm[pairs[:, 1]], axis=1)

    def joined(pairs: np.ndarray) -> bool:
        graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
        _, labels = connected_components(graph, directed=False)
        return bool(labels[0] == labels[-1])

    steps = 0
    pairs, distance = pairs_within(tau0)
    if not joined(pairs):
        # The chain of consecutive vertices joins the ends once tau_L reaches its longest step.
        longest = float(np.linalg.norm(np.diff(mm, axis=0), axis=1).max())
        cap = int(np.floor((params.max_tau_l * _MM - tau0) / step + 1e-9))
        low, high = 0, min(cap, max(1, int(np.ceil((longest - tau0) / step))))
        while not joined(pairs_within(tau0 + high * step)[0]):  # at most once, for rounding
            if high >= cap:
                raise ValueError(
                    f"no path between the thread's ends with edges up to {params.max_tau_l * 1000:.0f} mm"
                )
            high += 1
        while high - low > 1:  # invariant: low has no path, high has one
            middle = (low + high) // 2
            if joined(pairs_within(tau0 + middle * step)[0]):
                high = middle
            else:
                low = middle
        steps = high
        pairs, distance = pairs_within(tau0 + steps * step)
    tau = tau0 + steps * step

    i, t = pairs[:, 0], pairs[:, 1]
    weight = penalty[i] * penalty[t] * order_penalty(i, t, params)
    cost = np.maximum(distance * weight, _COST_FLOOR)
    graph = coo_matrix((cost, (i, t)), shape=(n, n)).tocsr()
    total, predecessors = dijkstra(graph, directed=False, indices=0, return_predecessors=True)
    if not np.isfinite(total[n - 1]):  # cannot happen: the ends are joined
        raise ValueError("Dijkstra found no path although the graph joins the thread's ends")
    indices = [n - 1]
    while indices[-1] != 0:
        indices.append(int(predecessors[indices[-1]]))
    indices = np.asarray(indices[::-1], dtype=np.int64)
    length = float(np.linalg.norm(np.diff(vertices[indices], axis=0), axis=1).sum())
    return ShapePath(indices, tau / _MM, steps, float(total[n - 1]), length)
