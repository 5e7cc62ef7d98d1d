# SPDX-License-Identifier: Apache-2.0
"""What stays fixed during one ordering search: the mask reader, the parameters in pixels and
the tuning grid, passed to every step of :mod:`suture_ordering.search`."""

from __future__ import annotations

from dataclasses import dataclass

from suture_ordering.nodes import MaskReader
from suture_ordering.params import OrderingParams, ScaledParams
from suture_ordering.tuning import Tuning


@dataclass(frozen=True)
class SearchContext:
    """``reader``: the cleaned mask; ``params`` and ``scaled``: the parameters and their pixel
    values for this mask's width; ``tuning``: Eq. (5) over the grid of Eq. (7);
    ``thickness``: width (px) of the traversed path drawn into a branch's ``consumed`` raster,
    2 x the detection radius."""

    reader: MaskReader
    params: OrderingParams
    scaled: ScaledParams
    tuning: Tuning
    thickness: int
