# SPDX-License-Identifier: Apache-2.0
"""The surface beside the thread as a witness of the thread's depth where the pair does not measure it.

Rectified stereo measures a thread's depth only where it crosses the image rows. Where the thread
runs along the rows at the grasp point, any shift along the row matches the thread to itself, and
its depth there is carried from the stretches that cross the rows (or from the two views' tips),
which a few tenths of a pixel of row offset between the views tilt by several pixels of disparity
over tens of millimetres. The tissue just above and below such a stretch has texture in both
directions, so its disparity is measured there. A thread rests on or above that surface, never
inside it: :func:`surface_gap_px` measures how far (px of disparity) the reconstructed grasp point
lies behind the surface beside it, and :func:`refuse_behind_surface` raises
:class:`~suture_reconstruction.errors.ThreadBehindSurfaceError` when that exceeds
``max_behind_surface_px``.

The surface is matched in two square windows of :data:`PATCH_HALF_PX` * 2 + 1 px, centred
:data:`PATCH_OFFSET_PX` rows above and below the grasp point (clear of a thread of a few pixels'
width), by normalised cross-correlation along the same rows of the right image within
:data:`SEARCH_PX` of the thread's disparity, with a parabola through the peak. A window without
texture (grey-level standard deviation below :data:`MIN_TEXTURE`, 8-bit scale) or without a clear
match (peak correlation below :data:`MIN_CORRELATION`) is no evidence; the gap is the smaller of
the two windows' gaps (both must show the surface in front of the thread), and None when either
gives no evidence (nothing is refused then).

Units: pixels; images (H, W) or (H, W, C), uint8 or float (floats up to 1.0 are taken as 0-1).
"""

from __future__ import annotations

import cv2
import numpy as np

from suture_reconstruction.errors import ThreadBehindSurfaceError
from suture_reconstruction.uncertainty import UNSUPPORTED_ROW_DEG

#: Half size (px) of the square surface windows.
PATCH_HALF_PX = 10
#: Rows (px) between the grasp point and the centre of each surface window.
PATCH_OFFSET_PX = 14
#: Half range (px) of disparities searched around the thread's own.
SEARCH_PX = 12
#: Least grey-level standard deviation (8-bit scale) of a window for its match to count.
MIN_TEXTURE = 3.0
#: Least normalised cross-correlation of a window's best match for it to count.
MIN_CORRELATION = 0.9


def _grey(image: np.ndarray) -> np.ndarray:
    """(H, W) float32 grey levels on the 8-bit scale."""
    grey = np.asarray(image, dtype=np.float32)
    if grey.ndim == 3:
        grey = grey.mean(axis=2)
    if not np.issubdtype(np.asarray(image).dtype, np.integer) and grey.size and float(grey.max()) <= 1.0:
        grey = grey * 255.0
    return grey


def surface_disparity(
    images: tuple[np.ndarray, np.ndarray], uv: np.ndarray, thread_disparity: float
) -> list[float | None]:
    """The surface's disparity (px) in the windows above and below the left pixel ``uv`` (2,),
    searched within :data:`SEARCH_PX` of ``thread_disparity``; None for a window outside the image,
    without texture or without a clear match (module docstring)."""
    u, row = float(uv[0]), float(uv[1])
    return [
        window_disparity(images, np.array([u, row + offset]), thread_disparity)
        for offset in (-PATCH_OFFSET_PX, PATCH_OFFSET_PX)
    ]


def window_disparity(
    images: tuple[np.ndarray, np.ndarray],
    centre: np.ndarray,
    around: float,
    min_texture: float = MIN_TEXTURE,
) -> float | None:
    """The disparity (px) of the square window of the left image centred on the pixel ``centre``
    (2,) (u, v), :data:`PATCH_HALF_PX` * 2 + 1 px wide, matched by normalised cross-correlation
    along the same rows of the right image within :data:`SEARCH_PX` of ``around``, with a parabola
    through the peak; None for a window outside the image, with a grey-level standard deviation
    below ``min_texture`` (8-bit scale) or a best match below :data:`MIN_CORRELATION`."""
    height, width = np.asarray(images[0]).shape[:2]
    half = PATCH_HALF_PX
    u, v = round(float(centre[0])), round(float(centre[1]))
    if v - half < 0 or v + half >= height or u - half < 0 or u + half >= width:
        return None
    band = slice(v - half, v + half + 1)  # only the rows the window covers are converted
    left, right = _grey(np.asarray(images[0])[band]), _grey(np.asarray(images[1])[band])
    patch = left[:, u - half : u + half + 1]
    lo = max(int(np.floor(u - around - SEARCH_PX)) - half, 0)
    hi = min(int(np.ceil(u - around + SEARCH_PX)) + half + 1, width)
    if float(patch.std()) < min_texture or hi - lo < patch.shape[1] + 2:
        return None
    score = cv2.matchTemplate(right[:, lo:hi], patch, cv2.TM_CCOEFF_NORMED)[0]
    best = int(np.argmax(score))
    if score[best] < MIN_CORRELATION:
        return None
    shift = 0.0
    if 0 < best < len(score) - 1:
        below, peak, above = score[best - 1], score[best], score[best + 1]
        curvature = below - 2 * peak + above
        if curvature < 0:
            shift = float(0.5 * (below - above) / curvature)
    return float(u - (lo + half + best + shift))


def surface_gap_px(
    images: tuple[np.ndarray, np.ndarray], uv: np.ndarray, thread_disparity: float
) -> float | None:
    """How far (px of disparity) the thread at left pixel ``uv`` (2,) with disparity
    ``thread_disparity`` lies behind the surface beside it: the smaller of the two windows'
    surface disparity minus the thread's; None unless both windows give evidence."""
    found = surface_disparity(images, uv, thread_disparity)
    if any(value is None for value in found):
        return None
    return min(float(value) for value in found if value is not None) - float(thread_disparity)


def refuse_behind_surface(gap_px: float | None, row_angle_deg: float, max_gap_px: float) -> None:
    """Raise ThreadBehindSurfaceError when the grasp point, whose depth the pair does not measure
    (``row_angle_deg``, the thread's angle to the image rows there, below
    :data:`~suture_reconstruction.uncertainty.UNSUPPORTED_ROW_DEG`), lies more than ``max_gap_px``
    behind the surface beside it (``gap_px`` from :func:`surface_gap_px`; None: no evidence)."""
    if gap_px is None or row_angle_deg >= UNSUPPORTED_ROW_DEG or gap_px <= max_gap_px:
        return
    raise ThreadBehindSurfaceError(
        f"the thread runs at {row_angle_deg:.1f} deg to the image rows at the grasp point, where the "
        "stereo pair does not measure its depth, and the depth carried there puts it "
        f"{gap_px:.1f} px of disparity behind the tissue beside it (more than max_behind_surface_px "
        f"{max_gap_px:g}), inside the surface it rests on: its depth, and the arc length that places "
        "the grasp point, are wrong; turn the camera or the thread so that it crosses the image rows"
    )
