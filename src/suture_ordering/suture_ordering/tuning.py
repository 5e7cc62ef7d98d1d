# SPDX-License-Identifier: Apache-2.0
"""The composite cost of Eq. (5) over the tuning grid of Eq. (7).

Each candidate node ``A_j`` of a step costs::

    C_j = log(ε1 * O_j + μ) + ε2 * |A_j - V^t| * exp(ε3 * sin(δ_j / 2))

ε1, ε2, ε3 take ``grid_size`` evenly spaced values in R1, R2, R3 (27 sets by default), and
every parameter set is evaluated at once: one (sets x nodes) array per step
(:meth:`Tuning.cost`). How the search forks where the sets disagree is in
:mod:`suture_ordering.search`. The grid depends on the parameters only, so each
:class:`Tuning` is built once and shared by every mask ordered with them (:func:`tuning_for`).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from suture_ordering.nodes import Candidates
from suture_ordering.params import OrderingParams


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


class Tuning:
    """The grid of parameter sets and the costs of Eq. (5) under them.

    ``grid``: (G, 3) (ε1, ε2, ε3), the centre first. ``zone_dominates``: whether leaving the
    zone by 1 px always costs more than any turn on one circle within ``max_reach`` px (true
    for the paper's ranges and μ): then among equidistant nodes those with O = 0 always win.
    """

    def __init__(self, params: OrderingParams, max_reach: int) -> None:
        self.grid = parameter_grid(params)
        self.grid.setflags(write=False)  # shared between searches (tuning_for)
        self.mu = params.mu
        self.log_mu = math.log(params.mu)
        self.eps3_max = float(self.grid[:, 2].max())
        eps1, eps2, eps3 = self.grid.T
        gain = np.log(eps1 + params.mu) - self.log_mu
        self.zone_dominates = bool(np.all(gain > eps2 * max_reach * np.expm1(eps3)))

    def cost(self, rows: np.ndarray, nodes: Candidates) -> np.ndarray:
        """Eq. (5) for parameter sets ``rows`` (G_b,) and nodes (k,): (G_b, k)."""
        eps = self.grid[rows]
        return np.log(eps[:, :1] * nodes.out[None, :] + self.mu) + eps[:, 1:2] * nodes.radius[
            None, :
        ] * np.exp(eps[:, 2:3] * np.sin(nodes.delta[None, :] / 2.0))

    def least_cost_at(self, rows: np.ndarray, r: float) -> np.ndarray:
        """(G_b,) the least cost any node at distance ``r`` can have (O = 0, δ = 0) per set."""
        return self.log_mu + self.grid[rows, 1] * r


@functools.lru_cache(maxsize=32)
def tuning_for(params: OrderingParams, max_reach: int) -> Tuning:
    """The :class:`Tuning` of ``params`` and ``max_reach``, built once and then shared (read-only)."""
    return Tuning(params, max_reach)
