# SPDX-License-Identifier: Apache-2.0
"""Mask cleaning: input checks, small holes filled, specks removed, the search's padded lookup arrays.

The ordering search only needs the cleaned mask and a slightly dilated "zone"
(for the out-of-zone count O of Eq. 5), both padded so that RoI circles around
any mask pixel never leave the array. Cleaning uses one ``cv2.findContours``
pass (outer contours and holes, about 0.1 ms for a 640x480 mask):

* holes (background enclosed by the mask) of at most ``max_hole_area`` px² are
  filled: segmentation dropouts inside a thick thread or at a crossing, and the
  slit a pixel wide between the merged arms of a hairpin; a loop's interior is
  far larger and is kept, and so is a small hole that holds a square of
  background ``min_eye_width`` px wide: the eye of a small loop, typically at the
  bend of a hairpin at the cut tip. Filled, the eye becomes a blob that the
  search enters and leaves, and the sequence misses the loop's arc, so the grasp
  lands that much too far along (5-9 mm on simulated hooks at 640x480);
* components whose bounding box is smaller than ``min_blob_extent`` px in both
  directions are removed: specks that are no thread.

Spurs need no pruning here: the search never walks the skeleton (it reads
cross-sections of the mask on circles, see :mod:`suture_ordering.nodes`); the
skeleton is used only near the cut tip (:mod:`suture_ordering.tip`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from suture_ordering.errors import EmptyMaskError, InvalidInputError
from suture_ordering.params import ScaledParams


@dataclass(frozen=True)
class CleanMask:
    """A cleaned mask and the padded arrays the search reads.

    ``mask``: (H, W) uint8, 1 on the thread. ``padded`` and ``zone``: (H + 2 pad, W + 2 pad)
    uint8, the mask and the mask dilated by the zone margin, 0 in the padding. Pixel (u, v)
    of the image is ``padded[v + pad, u + pad]``.
    """

    mask: np.ndarray
    padded: np.ndarray
    zone: np.ndarray
    pad: int

    @property
    def shape(self) -> tuple[int, int]:
        return self.mask.shape  # type: ignore[return-value]


def as_binary_mask(mask: np.ndarray, view: str | None = None) -> np.ndarray:
    """Check a mask argument and return it as (H, W) uint8 in {0, 1} (nonzero = thread).

    Accepts (H, W) uint8 (0/255 as on ``/suture/*/mask``, any nonzero value counts) or bool.
    Raises InvalidInputError for other shapes or dtypes and EmptyMaskError for an all-zero mask.
    """
    array = np.asarray(mask)
    if array.ndim != 2 or array.shape[0] < 2 or array.shape[1] < 2:
        raise InvalidInputError(f"mask must be a 2D (H, W) array, got shape {array.shape}", view)
    if array.dtype == np.bool_:
        binary = array.view(np.uint8)
    elif array.dtype == np.uint8:
        binary = (array > 0).view(np.uint8)
    else:
        raise InvalidInputError(
            f"mask must be uint8 (0/255) or bool, got {array.dtype}; "
            "convert with (mask > 0).astype(np.uint8)",
            view,
        )
    binary = np.ascontiguousarray(binary)
    if cv2.countNonZero(binary) == 0:
        raise EmptyMaskError("mask is empty: no thread pixel (segmentation found no suture)", view)
    return binary


def clean_mask(
    mask: np.ndarray, scaled: ScaledParams, zone_margin: int, pad: int, view: str | None = None
) -> CleanMask:
    """Validate, clean and pad ``mask`` ((H, W) uint8 0/255 or bool) for the search.

    ``pad`` is the padding in pixels (at least the farthest the search looks from a mask
    pixel). Raises InvalidInputError or EmptyMaskError (also when only specks remain).
    """
    binary = as_binary_mask(mask, view)
    if np.may_share_memory(binary, mask):  # a bool mask's view: cleaned in a copy
        binary = binary.copy()
    return clean_binary(binary, scaled, zone_margin, pad, view)


def fill_holes_remove_specks(
    binary: np.ndarray, max_hole_area: float, min_blob_extent: float = 0.0, min_eye_width: int = 0
) -> None:
    """Fill, in place, the holes of ``binary`` ((H, W) uint8 0/1) of at most ``max_hole_area`` px²
    except those that hold a square of background ``min_eye_width`` px wide (0: none kept), and
    remove its components whose bounding box is under ``min_blob_extent`` px both ways (0: none),
    in one ``cv2.findContours`` pass (module docstring)."""
    contours, hierarchy = cv2.findContours(binary, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE)
    if hierarchy is None:
        return
    parents = hierarchy[0][:, 3].tolist()
    # Each contour is drawn on its own (passing all of them to every call would convert
    # them all each time: quadratic in the number of specks of a noisy mask).
    for parent, contour in zip(parents, contours, strict=True):
        if parent < 0:  # outer boundary of a component
            _, _, w, h = cv2.boundingRect(contour)
            if max(w, h) < min_blob_extent:
                cv2.drawContours(binary, [contour], 0, 0, thickness=cv2.FILLED)
        elif cv2.contourArea(contour) <= max_hole_area and not _is_eye(binary, contour, min_eye_width):
            cv2.drawContours(binary, [contour], 0, 1, thickness=cv2.FILLED)


def _is_eye(binary: np.ndarray, hole: np.ndarray, width: int) -> bool:
    """Whether the hole inside the contour ``hole`` (of ``binary``, (H, W) uint8 0/1) is the eye
    of a loop: it holds a ``width`` x ``width`` square of background, and the mask round it (within
    ``2 * width`` px) is at most 2 px thicker than the hole is wide, as a loop of thread is round
    its eye; a dropout inside a thick stroke is not (False for ``width`` 0)."""
    if width <= 0:
        return False
    x, y, w, h = cv2.boundingRect(hole)
    if min(w, h) < width + 2:  # the contour runs on the mask round the hole
        return False
    reach = 2 * width
    margin = 2 * reach + 2  # the stroke's depth is measured clear of the window's edge
    x0, y0 = max(0, x - margin), max(0, y - margin)
    window = binary[y0 : y + h + margin, x0 : x + w + margin]
    inside = np.zeros(window.shape, dtype=np.uint8)
    cv2.drawContours(inside, [hole], 0, 1, thickness=cv2.FILLED, offset=(-x0, -y0))
    background = inside & (window == 0)
    if not cv2.erode(background, np.ones((width, width), np.uint8)).any():
        return False
    hole_depth = cv2.distanceTransform(background, cv2.DIST_L2, cv2.DIST_MASK_PRECISE).max()
    ring = cv2.dilate(background, np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)) & window
    stroke_depth = cv2.distanceTransform(window, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)[ring > 0].max()
    return bool(stroke_depth <= hole_depth + 1.0)


def clean_binary(
    binary: np.ndarray, scaled: ScaledParams, zone_margin: int, pad: int, view: str | None = None
) -> CleanMask:
    """:func:`clean_mask` of a mask already checked by :func:`as_binary_mask` ((H, W) uint8 0/1,
    not empty), which is cleaned in place (pass a copy to keep it)."""
    fill_holes_remove_specks(binary, scaled.max_hole_area, scaled.min_blob_extent, scaled.min_eye_width)
    if cv2.countNonZero(binary) == 0:
        raise EmptyMaskError(
            f"mask holds only specks smaller than {scaled.min_blob_extent:.0f} px: no thread", view
        )
    # The padded arrays are filled in place (fewer large temporaries to allocate per view).
    height, width = binary.shape
    inner = (slice(pad, pad + height), slice(pad, pad + width))
    padded = np.zeros((height + 2 * pad, width + 2 * pad), dtype=np.uint8)
    padded[inner] = binary
    zone = np.zeros(padded.shape, dtype=np.uint8)  # calloc'd, unlike np.zeros_like
    if zone_margin > 0:
        size = 2 * zone_margin + 1
        cv2.dilate(binary, cv2.getStructuringElement(cv2.MORPH_RECT, (size, size)), dst=zone[inner])
    else:
        zone[inner] = binary
    return CleanMask(
        mask=binary,
        padded=padded,
        zone=zone,
        pad=pad,
    )
