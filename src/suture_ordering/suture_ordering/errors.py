# SPDX-License-Identifier: Apache-2.0
"""Exceptions of the ordering stage.

Every failure of :func:`suture_ordering.order_sequence` and
:func:`suture_ordering.order_stereo` is an :class:`OrderingError` (a
``ValueError``) whose message says what is wrong and what to do about it, so a
node can drop the frame with one log line and a caller can catch one type.
``view`` is ``'left'``, ``'right'`` or ``None`` (a single-view call).
"""

from __future__ import annotations


class OrderingError(ValueError):
    """The ordered sequence cannot be inferred; the text names the problem and a remedy."""

    def __init__(self, message: str, view: str | None = None) -> None:
        super().__init__(message if view is None else f"{view} view: {message}")
        self.view = view


class InvalidInputError(OrderingError):
    """A mask, tip or camera argument has the wrong shape, dtype, size or a NaN."""


class EmptyMaskError(OrderingError):
    """The mask holds no thread pixel (after removing specks)."""


class TipOutsideImageError(OrderingError):
    """The tip hint lies outside the image."""


class TipNotOnThreadError(OrderingError):
    """No thread pixel lies near the tip hint (or, in the right view, on the tip's epipolar band)."""


class NoFreeEndError(OrderingError):
    """The thread near the tip has no free end there (a closed ring, or a hint away from the cut end)."""


class UnexplainedTipError(OrderingError):
    """Thread near the cut tip, or in line beyond it, lies off the ordered sequence (a hook or loop
    the search skipped, or one whose arms the mask lost): the grasp point's arc from the tip would
    be too short."""
