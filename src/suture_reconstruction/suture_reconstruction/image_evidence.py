# SPDX-License-Identifier: Apache-2.0
"""Stretches a view's mask lost that its image still shows: a thin line along the sequence.

The ordering bridges a gap in a view's mask and flags the bridged stretch not seen: under an
instrument shaft the thread is hidden, but where the segmenter merely lost a faint stretch the
thread is there in the image, and a grasp point on it is refused as not seen all the same. The
image tells the two apart. A thread is a thin line: across it, the image at the thread differs
from the image a few pixels to either side by the thread's contrast (per colour channel).
Across a shaft, at the place the bridged curve runs, there is no such line.

:func:`seen_in_image` measures that contrast (the image at a sample minus the mean of the image
``FLANK_PX`` to either side, across the sequence) on the observed samples within
``REFERENCE_ARC_PX`` of arc before and after each run of unobserved samples: their median is the
thread's contrast c there. The reference must stand clear of the image's texture: the median of
the observed samples' contrasts along c at least ``REFERENCE_SNR`` times their robust spread
(1.4826 x the median absolute deviation). Each sample of the run then shows the line when its
contrast along c is at least ``SAMPLE_SHARE`` of c's, at the sample or a pixel to either side
(the interpolated curve may run a pixel beside the thread). A run at least ``SEEN_SHARE`` of
whose samples show it is seen in the image.

Only the grasp's refusal and uncertainty read this (:func:`suture_reconstruction.uncertainty.
assess_grasp`): a bridged stretch's depth is still interpolated from the seen thread on either
side, never matched between the views (:mod:`suture_reconstruction.not_seen`).

Units: pixels; the distances scale with the image width (at 640 px as written). Images are
(H, W) or (H, W, C) of any numeric dtype.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from suture_reconstruction.sequences import Resampled

#: The image this far (px) to either side of the sequence, across it, is the thread's background.
FLANK_PX = 3.0
#: Observed samples within this arc (px) of a run, before and after it, give the thread's contrast.
REFERENCE_ARC_PX = 20.0
#: At least this many observed samples must give it.
MIN_REFERENCE_SAMPLES = 5
#: The reference contrast must be this many times the spread of the observed samples' contrasts.
REFERENCE_SNR = 1.0
#: A sample shows the line when its contrast along the reference is at least this share of it ...
SAMPLE_SHARE = 0.5
#: ... and a run is seen in the image when at least this share of its samples show it.
SEEN_SHARE = 0.8
#: Runs shorter than this many samples are left as they are.
MIN_RUN = 3


def seen_in_image(view: Resampled, image: np.ndarray) -> Resampled:
    """``view`` (a sequence resampled every 1 px, :class:`~suture_reconstruction.sequences.
    Resampled`) with its unobserved runs that ``image`` ((H, W) or (H, W, C)) shows as thread
    marked observed; the others, and the points, unchanged."""
    unobserved = ~view.observed
    if not unobserved.any() or view.observed.sum() < MIN_REFERENCE_SAMPLES:
        return view
    scale = image.shape[1] / 640.0
    flank, reach = FLANK_PX * scale, REFERENCE_ARC_PX * scale
    picture = np.asarray(image, dtype=np.float32)
    if picture.ndim == 2:
        picture = picture[..., None]
    points = view.points[:, :2]
    normals = _normals(points)
    observed = view.observed.copy()
    edges = np.diff(np.concatenate(([0], unobserved.astype(np.int8), [0])))
    for start, stop in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
        if stop - start < MIN_RUN:
            continue
        near = view.observed & (
            ((view.arc >= view.arc[start] - reach) & (view.arc < view.arc[start]))
            | ((view.arc > view.arc[stop - 1]) & (view.arc <= view.arc[stop - 1] + reach))
        )
        if near.sum() < MIN_REFERENCE_SAMPLES:
            continue
        seen_contrast = _contrast(picture, points[near], normals[near], flank)
        reference = np.median(seen_contrast, axis=0)
        power = float(reference @ reference)
        if power <= 0.0:
            continue
        along = seen_contrast @ reference / power
        spread = 1.4826 * float(np.median(np.abs(along - np.median(along))))
        if float(np.median(along)) < REFERENCE_SNR * spread:
            continue
        run_points, run_normals = points[start:stop], normals[start:stop]
        shifted = (run_points + shift * run_normals for shift in (-1.0, 0.0, 1.0))
        shown = np.max([_contrast(picture, at, run_normals, flank) @ reference for at in shifted], axis=0)
        if float(np.mean(shown >= SAMPLE_SHARE * power)) >= SEEN_SHARE:
            observed[start:stop] = True
    return dataclasses.replace(view, observed=observed)


def _normals(points: np.ndarray) -> np.ndarray:
    """(K, 2) unit normals of the (K, 2) polyline, from its direction over a few samples."""
    tangents = np.gradient(cv2.GaussianBlur(points.reshape(-1, 1, 2), (1, 7), 0).reshape(-1, 2), axis=0)
    tangents /= np.maximum(np.linalg.norm(tangents, axis=1, keepdims=True), 1e-9)
    return np.column_stack([-tangents[:, 1], tangents[:, 0]])


def _contrast(picture: np.ndarray, points: np.ndarray, normals: np.ndarray, flank: float) -> np.ndarray:
    """(K, C): the (H, W, C) ``picture`` at ``points`` minus the mean of it ``flank`` px to
    either side along ``normals`` (bilinear)."""
    beside = _sample(picture, points + flank * normals) + _sample(picture, points - flank * normals)
    return _sample(picture, points) - 0.5 * beside


def _sample(picture: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(K, C): the (H, W, C) float32 ``picture`` at the (K, 2) ``points`` (u, v), bilinear, the
    border mirrored."""
    maps = points.astype(np.float32).reshape(-1, 1, 2)
    values = cv2.remap(picture, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    return values.reshape(len(points), picture.shape[2])
