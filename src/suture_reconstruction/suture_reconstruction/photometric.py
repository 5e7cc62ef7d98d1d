# SPDX-License-Identifier: Apache-2.0
"""Photometric refinement of the disparity along the thread: the images, not the masks, say where it is.

The pairs of :mod:`suture_reconstruction.pairing` come from the two views'
centrelines, traced on binary masks. Their disparity is right on average, but a
mask edge that sits a pixel off in one view moves that view's centreline by
half a pixel or more over a stretch, and with an endoscope's 5 mm baseline half
a pixel of disparity is 2-3 mm of depth at 100-120 mm: on predicted sequences
such biases (0.5-3 px), not the ordering, cause most grasps more than 5 mm off
(with the true disparity the same sequences give grasps within 3 mm). The
images carry the thread's position to a tenth of a pixel.

:func:`match_along_rows` matches, for left samples of the thread, a small
window of the left image around the thread against the right image along the
same row (a rectified pair), near the disparity the pairs gave:

* Both images are blurred first (Gaussian, ``blur_sigma_px``). A braided thread
  1-2 px wide has texture near the pixel pitch, which each view samples at its
  own phase (aliasing): unblurred, matched windows disagree by up to 1.5 px on
  such threads; blurred, the thread's profile and edges remain and match.
* The window is the thread's own neighbourhood: the pixels within
  ``radius_px`` along the local tangent and ``half_width_px`` across it, so
  little background (at another depth where the thread lies above the tissue)
  enters.
* The cost of a shift is the zero-mean sum of squared differences over the
  window and the colour channels (window means removed, so a brightness
  difference between the cameras does not bias it), at ``fine_step_px`` steps
  within ``search_px`` of the given disparity; a parabola through the best shift
  and its neighbours gives the sub-pixel minimum.
* Its confidence is the parabola's curvature over the residual cost at the
  minimum (plus one grey level squared of noise): the inverse of the
  estimate's variance up to a factor. On predicted sequences the median error
  is 0.33 px at confidence below 0.1 and 0.03 px above 2, against 0.09-0.2 px
  for the mask pairs; a thread
  along the rows (shifting it along itself changes nothing) and a window the
  right view does not see give low confidence.

:func:`refine_disparity` then fuses those matches with the mask pairs and
regularises the disparity again (:func:`~suture_reconstruction.pairing.regularise_disparity`):
matches of at least ``min_confidence`` weighted by their confidence (capped at
``max_confidence``), the mask pairs elsewhere at ``mask_pair_weight`` of theirs.
Matches within ``gap_guard_px`` samples of a stretch the sequence jumped over
(an instrument or the other strand on top: its edge lies in the window, at
another depth) and matches more than ``max_change_px`` from the mask pairs' fit
are not used.

Shapes and units: images (H, W) or (H, W, C) uint8 (grey levels; other dtypes
are taken as they are, and the noise term assumes a 0-255 scale), both views of
the same shape, rectified; pixels (u, v) = (column, row) with the centre of the
top-left pixel at (0, 0); disparities in pixels (u_left - u_right).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.ndimage import binary_dilation

from suture_reconstruction.errors import ImagePairError
from suture_reconstruction.pairing import Disparity, DisparitySmoothing, Pairs, regularise_disparity

#: Fewer usable matches than this and the mask pairs' disparity is kept as it is.
MIN_MATCHES = 8
#: Cost of one grey level of noise per pixel (squared), added to the residual in the confidence.
NOISE_COST = 1.0


@dataclass(frozen=True)
class PhotometricParams:
    """Parameters of :func:`match_along_rows` and :func:`refine_disparity` (pixels, samples).

    Matching: ``blur_sigma_px`` (Gaussian blur of both images), ``radius_px`` (window
    half-length along the thread), ``half_width_px`` (half-width across it),
    ``search_px`` (the shifts searched either side of the given disparity),
    ``fine_step_px`` (their spacing). Fusion: ``min_confidence``,
    ``max_confidence``, ``mask_pair_weight``, ``gap_guard_px``, ``max_change_px`` (see the
    module docstring) and ``noise_floor_px``, the noise floor of the fused pairs: on a faint
    thread the matches' errors are correlated over tens of px (the background's texture pulls
    them), so the fit must not follow them closely: 0.3 px rather than 0.05 gives more grasps
    within 5 mm at a slightly larger median error.
    """

    blur_sigma_px: float = 1.0
    radius_px: int = 3
    half_width_px: float = 2.0
    search_px: int = 2
    fine_step_px: float = 0.25
    min_confidence: float = 0.2
    max_confidence: float = 4.0
    mask_pair_weight: float = 0.04
    gap_guard_px: int = 6
    max_change_px: float = 1.5
    noise_floor_px: float = 0.3

    def __post_init__(self) -> None:
        if self.radius_px < 1 or self.search_px < 1:
            raise ValueError(
                f"radius_px and search_px must be at least 1, got {self.radius_px}, {self.search_px}"
            )
        if not 0 < self.fine_step_px <= 0.5:
            raise ValueError(f"fine_step_px must be in (0, 0.5], got {self.fine_step_px}")
        for name in ("half_width_px", "max_change_px"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        for name in ("blur_sigma_px", "min_confidence", "mask_pair_weight", "gap_guard_px", "noise_floor_px"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must not be negative, got {getattr(self, name)}")
        if not self.max_confidence > self.min_confidence:
            raise ValueError("max_confidence must exceed min_confidence")


@dataclass(frozen=True)
class Matches:
    """:func:`match_along_rows` for K samples: ``disparity`` (K,) px (the given one where not
    ``matched``), ``matched`` (K,) bool, ``confidence`` (K,) (0 where not matched)."""

    disparity: np.ndarray
    matched: np.ndarray
    confidence: np.ndarray


def check_image_pair(
    images: tuple[np.ndarray, np.ndarray], width: int | None = None, height: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The (left, right) ``images`` as arrays, if they can be matched: each (H, W) or (H, W, C) with
    H, W >= 2, of the camera's ``width`` x ``height`` when given, and of the same shape.

    Raises :class:`ImagePairError` naming what is wrong.
    """
    try:
        left, right = (np.asarray(image) for image in images)
    except (TypeError, ValueError):
        raise ImagePairError("images must be a (left, right) pair of arrays") from None
    for name, image in (("left", left), ("right", right)):
        if image.ndim not in (2, 3) or min(image.shape[:2]) < 2:
            raise ImagePairError(
                f"{name} image must be (H, W) or (H, W, C) with H, W >= 2, got {image.shape}"
            )
        if width is not None and image.shape[:2] != (height, width):
            raise ImagePairError(
                f"{name} image has shape {image.shape}, but camera_info says {width}x{height} "
                "(expected (H, W) or (H, W, C) of the rectified view)"
            )
    if left.shape != right.shape:
        raise ImagePairError(f"left image is {left.shape} but right image is {right.shape}")
    return left, right


def prepare_images(
    left_image: np.ndarray, right_image: np.ndarray, blur_sigma_px: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """Both views blurred, as (H, W, C) arrays of their dtype, for :func:`match_along_rows`.

    Raises :class:`ImagePairError` as :func:`check_image_pair`.
    """
    left, right = check_image_pair((left_image, right_image))
    prepared = []
    for image in (left, right):
        if blur_sigma_px > 0:
            # uint8 in, uint8 out is several times faster than float; the rounding (0.5 grey
            # level at most) is below the noise term of the confidence
            image = cv2.GaussianBlur(image, (0, 0), blur_sigma_px)
        prepared.append(image.reshape(*left.shape[:2], -1))
    return prepared[0], prepared[1]


def match_along_rows(
    left: np.ndarray,
    right: np.ndarray,
    points: np.ndarray,
    tangents: np.ndarray,
    disparity: np.ndarray,
    params: PhotometricParams | None = None,
) -> Matches:
    """Refine the disparity of K left samples by matching the thread's window along its row.

    ``left``, ``right``: (H, W, C) from :func:`prepare_images`. ``points`` (K, 2) left
    pixels (u, v); ``tangents`` (K, 2) the thread's direction there (any non-zero length);
    ``disparity`` (K,) the starting disparity (px). A sample whose window, or its shifted
    window, leaves the image is not matched.
    """
    params = params or PhotometricParams()
    height, width, _ = left.shape
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    disparity = np.asarray(disparity, dtype=np.float64).reshape(-1)
    count = len(points)
    if count == 0:
        return Matches(disparity.copy(), np.zeros(0, dtype=bool), np.zeros(0))
    tangents = np.asarray(tangents, dtype=np.float64).reshape(-1, 2)
    tangents = tangents / np.maximum(np.hypot(tangents[:, 0], tangents[:, 1]), 1e-12)[:, None]

    # The window: whole pixels near the sample within the thread-aligned rectangle,
    # compacted to the most any sample has (the rest padded with weight 0).
    radius = params.radius_px
    offset_v, offset_u = (a.ravel() for a in np.mgrid[-radius : radius + 1, -radius : radius + 1])
    centre_u = np.rint(points[:, 0]).astype(np.int64)
    centre_v = np.rint(points[:, 1]).astype(np.int64)
    rel_u = centre_u[:, None] + offset_u[None] - points[:, :1]
    rel_v = centre_v[:, None] + offset_v[None] - points[:, 1:]
    along = rel_u * tangents[:, :1] + rel_v * tangents[:, 1:]
    across = rel_u * tangents[:, 1:] - rel_v * tangents[:, :1]
    window = (np.abs(across) <= params.half_width_px) & (np.abs(along) <= radius)
    size = int(window.sum(1).max())
    order = np.argsort(~window, axis=1, kind="stable")[:, :size]
    window = np.take_along_axis(window, order, axis=1)
    pixel_u = centre_u[:, None] + offset_u[order]  # (K, P)
    pixel_v = centre_v[:, None] + offset_v[order]

    search, step = params.search_px, params.fine_step_px
    usable = (
        np.isfinite(disparity)
        & (centre_v - radius >= 0)
        & (centre_v + radius < height)
        & (centre_u - radius >= 0)
        & (centre_u + radius < width)
        & (centre_u - radius - disparity - search - 2 >= 0)
        & (centre_u + radius - disparity + search + 2 < width)
    )
    start = np.where(usable, disparity, 0.0)
    whole = np.floor(start).astype(np.int64)
    weight = (window & usable[:, None]).astype(np.float64)
    pixel_u = np.clip(pixel_u, 0, width - 1)
    pixel_v = np.clip(pixel_v, 0, height - 1)
    left_values = left.reshape(height * width, -1)[pixel_v * width + pixel_u].astype(np.float64)  # (K, P, C)
    w = weight[:, :, None]
    n = np.maximum(weight.sum(1), 1.0)[:, None]  # (K, 1)
    left_mean = (left_values * w).sum(1, keepdims=True) / n[:, :, None]
    left_zero = (left_values - left_mean) * w

    # Every shift's window is a linear interpolation between two whole-pixel columns of
    # the right image, the same two for all its pixels; so gather the whole columns once
    # (centred on the left window's mean, against cancellation) and take their moments.
    columns = np.arange(-search - 1, search + 3)  # (J,) offsets j: column u - floor(d) - j
    right_u = np.clip(pixel_u[:, :, None] - whole[:, None, None] - columns[None, None], 0, width - 1)
    flat = right.reshape(height * width, -1)
    strip = flat[pixel_v[:, :, None] * width + right_u].astype(np.float64)  # (K, P, J, C)
    strip -= left_mean[:, :, None]
    cross = np.einsum("kpc,kpjc->kjc", left_zero, strip)
    first = np.einsum("kp,kpjc->kjc", weight, strip)
    second = np.einsum("kp,kpjc->kjc", weight, strip * strip)
    mixed = np.einsum("kp,kpjc->kjc", weight, strip[:, :, :-1] * strip[:, :, 1:])
    left_energy = (left_zero * left_zero).sum((1, 2))

    shifts = np.arange(-search, search + 0.5 * step, step)  # (S,)
    t = (start - whole)[:, None] + shifts[None]  # disparity - floor(d), (K, S)
    j = np.floor(t).astype(np.int64) - columns[0]
    f = (t - np.floor(t))[:, :, None]
    k = np.arange(count)[:, None]
    sum_cross = (1 - f) * cross[k, j] + f * cross[k, j + 1]
    sum_first = (1 - f) * first[k, j] + f * first[k, j + 1]
    sum_second = (1 - f) ** 2 * second[k, j] + 2 * f * (1 - f) * mixed[k, j] + f**2 * second[k, j + 1]
    # ZSSD = sum (l0 - r + mean r)^2 = |l0|^2 - 2 l0.r + sum r^2 - (sum r)^2 / n, as l0 sums to 0
    right_energy = (sum_second - sum_first**2 / n[:, :, None]).sum(2)
    cost = (left_energy[:, None] - 2 * sum_cross.sum(2) + right_energy) / n

    best = np.argmin(cost, axis=1)
    inside = (best > 0) & (best < shifts.size - 1)
    centre = np.clip(best, 1, shifts.size - 2)
    k = k[:, 0]
    c_minus, c_zero, c_plus = cost[k, centre - 1], cost[k, centre], cost[k, centre + 1]
    curvature = c_minus - 2 * c_zero + c_plus
    confidence = np.where(
        usable & inside & (curvature > 0), curvature / (np.maximum(c_zero, 0.0) + NOISE_COST), 0.0
    )
    offset = np.where(curvature > 0, 0.5 * (c_minus - c_plus) / np.where(curvature > 0, curvature, 1.0), 0.0)
    refined = start + shifts[centre] + step * np.clip(offset, -0.5, 0.5)
    matched = confidence > 0
    return Matches(np.where(matched, refined, disparity), matched, confidence)


def refine_disparity(
    images: tuple[np.ndarray, np.ndarray],
    points: np.ndarray,
    observed: np.ndarray,
    initial: Disparity,
    pairs: Pairs,
    smoothing: DisparitySmoothing,
    params: PhotometricParams | None = None,
    end_matcher: Callable[[Disparity, tuple[np.ndarray, np.ndarray]], tuple[np.ndarray, np.ndarray] | None]
    | None = None,
) -> tuple[Disparity, int]:
    """The disparity along the N left samples ``points`` (N, 2), refined by the images.

    ``images``: the rectified (left, right) views as given to
    :func:`suture_reconstruction.core.reconstruct`; ``observed`` (N,) False inside jumps;
    ``initial``: the mask pairs' regularised disparity; ``pairs``: those pairs. Returns
    the regularised fused disparity and the number of image matches used (0: fewer than
    :data:`MIN_MATCHES` samples could be matched, and ``initial`` is the fused disparity).

    ``end_matcher``: given the fused disparity and both views as :func:`prepare_images` blurred
    them, the thread's ends matched in the images as (rows (E,) int, disparities (E,) px) or None
    (:func:`suture_reconstruction.ends.match_unanchored_ends`); those are fused again with the
    same matches, in place of the pairs at their samples and with the weight of the most
    confident match (``max_confidence``); with too few matches along the thread the mask pairs
    keep their full weight beside them.
    """
    params = params or PhotometricParams()
    left, right = prepare_images(*images, blur_sigma_px=params.blur_sigma_px)
    candidate = observed & initial.supported
    if params.gap_guard_px > 0 and not observed.all():
        candidate &= ~binary_dilation(~observed, iterations=params.gap_guard_px)
    index = np.flatnonzero(candidate)
    tangents = np.gradient(points, axis=0) if len(points) > 1 else np.ones_like(points)
    matches = match_along_rows(left, right, points[index], tangents[index], initial.value[index], params)
    keep = (
        matches.matched
        & (matches.confidence >= params.min_confidence)
        & (np.abs(matches.disparity - initial.value[index]) <= params.max_change_px)
    )
    rows = index[keep]
    values = matches.disparity[keep]
    weight = np.minimum(matches.confidence[keep], params.max_confidence)
    pair_weight = params.mask_pair_weight
    if rows.size < MIN_MATCHES:
        rows, values, weight, pair_weight = rows[:0], values[:0], weight[:0], 1.0
    used = rows.size
    own = np.isin(pairs.rows, rows)
    rows = np.concatenate([rows, pairs.rows[~own]])
    values = np.concatenate([values, pairs.disparity[~own]])
    weight = np.concatenate([weight, pair_weight * pairs.weight[~own]])
    fused = initial if used == 0 else _fuse(len(points), rows, values, weight, smoothing, params)
    end_matches = end_matcher(fused, (left, right)) if end_matcher is not None else None
    if end_matches is None:
        return fused, used
    end_rows, end_values = end_matches
    replaced = np.isin(rows, end_rows)
    rows = np.concatenate([rows[~replaced], end_rows])
    values = np.concatenate([values[~replaced], end_values])
    weight = np.concatenate([weight[~replaced], np.full(len(end_rows), params.max_confidence)])
    return _fuse(len(points), rows, values, weight, smoothing, params), used


def _fuse(
    n: int,
    rows: np.ndarray,
    values: np.ndarray,
    weight: np.ndarray,
    smoothing: DisparitySmoothing,
    params: PhotometricParams,
) -> Disparity:
    """The disparity regularised over ``n`` samples through the observations (rows, values, weight)."""
    order = np.argsort(rows, kind="stable")
    return regularise_disparity(
        n, rows[order], values[order], weight[order], smoothing, params.noise_floor_px
    )
