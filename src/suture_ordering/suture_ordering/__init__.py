# SPDX-License-Identifier: Apache-2.0
"""Ordering stage: the pixel sequence of the target thread from its cut tip, in both views.

ROS-free core (paper Section II.B): :func:`order_sequence` for one view and
:func:`order_stereo` for a rectified pair, with :class:`OrderingParams`; errors
are :class:`OrderingError` subclasses. ``ordering_node`` is the thin rclpy adapter.
"""

from suture_ordering.core import OrderingResult, StereoOrdering, order_sequence, order_stereo
from suture_ordering.errors import (
    EmptyMaskError,
    InvalidInputError,
    NoFreeEndError,
    OrderingError,
    TipNotOnThreadError,
    TipOutsideImageError,
    UnexplainedTipError,
)
from suture_ordering.params import OrderingParams

__all__ = [
    "EmptyMaskError",
    "InvalidInputError",
    "NoFreeEndError",
    "OrderingError",
    "OrderingParams",
    "OrderingResult",
    "StereoOrdering",
    "TipNotOnThreadError",
    "TipOutsideImageError",
    "UnexplainedTipError",
    "order_sequence",
    "order_stereo",
]
