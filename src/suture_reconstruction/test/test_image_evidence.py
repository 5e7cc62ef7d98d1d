# SPDX-License-Identifier: Apache-2.0
"""A stretch the masks lost but the images show counts as seen for the grasp's refusal; one under
an instrument shaft does not (suture_reconstruction.image_evidence)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from suture_common.camera import StereoCamera
from suture_reconstruction import GraspNotSeenError, ReconstructionParams, reconstruct
from suture_reconstruction.image_evidence import seen_in_image
from suture_reconstruction.sequences import Resampled, resample

THREAD_COLOUR = np.array([40.0, 70.0, 50.0])
SHAFT_COLOUR = np.array([150.0, 150.0, 160.0])


def drawn_thread(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """``image`` with a dark 2 px thread drawn along the (N, 2) pixels ``uv``."""
    mask = np.zeros(image.shape[:2], np.uint8)
    cv2.polylines(mask, [np.rint(uv * 16).astype(np.int32)], False, 255, 2, cv2.LINE_AA, shift=4)
    alpha = mask[..., None] / 255.0
    return np.clip(image * (1 - alpha) + THREAD_COLOUR * alpha, 0, 255).astype(np.uint8)


def drawn_shaft(image: np.ndarray, centre: np.ndarray, direction: np.ndarray, width: float) -> np.ndarray:
    """``image`` with a uniform shaft ``width`` px wide through ``centre`` (u, v) along ``direction``."""
    shaft = image.copy()
    ends = np.rint(np.vstack([centre - 1000 * direction, centre + 1000 * direction])).astype(np.int32)
    cv2.line(shaft, tuple(ends[0]), tuple(ends[1]), SHAFT_COLOUR.tolist(), round(width))
    return shaft


def flagged_by_arc(
    camera: StereoCamera, curve: np.ndarray, sequence: np.ndarray, view: str, start: float, end: float
) -> np.ndarray:
    """(N, 3): ``sequence`` with its points on arc ``start``-``end`` (m) of ``curve`` flagged not seen."""
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(curve, axis=0), axis=1))])
    uv = camera.project(curve, view)
    nearest = np.argmin(np.linalg.norm(sequence[:, None, :] - uv[None, ::10, :], axis=2), axis=1) * 10
    return np.column_stack([sequence, ((arc[nearest] > start) & (arc[nearest] < end)).astype(float)])


def test_a_grasp_on_a_stretch_the_masks_lost_is_published_where_the_images_show_the_thread(
    make_scene, textured_pair
):
    scene = make_scene("curved", seed=3)
    camera = scene.camera
    left, right = (
        flagged_by_arc(camera, scene.path, sequence, view, 0.045, 0.056)
        for sequence, view in ((scene.left, "left"), (scene.right, "right"))
    )
    plane = textured_pair(camera, round(float(camera.disparity(0.12))))
    images = tuple(
        drawn_thread(image, camera.project(scene.path, view))
        for image, view in zip(plane, ("left", "right"), strict=True)
    )
    result = reconstruct(left, right, camera, images=images)
    assert result.uncertainty.grasp_not_seen == ()
    assert np.linalg.norm(result.grasp_position - scene.grasp) < 0.002
    # Without the images' evidence, or without images, the same grasp point is not seen.
    with pytest.raises(GraspNotSeenError, match="left and right views do not see"):
        reconstruct(left, right, camera, ReconstructionParams(image_evidence=False), images=images)
    with pytest.raises(GraspNotSeenError):
        reconstruct(left, right, camera)
    # A shaft 40 px wide lies across the stretch in both views: what the images show there is no
    # thread, and the grasp point is refused as not seen.
    shafted = []
    for image, view in zip(images, ("left", "right"), strict=True):
        uv = camera.project(scene.path, view)
        at = np.argmin(np.linalg.norm(scene.path - scene.grasp, axis=1))
        along = uv[at + 20] - uv[at - 20]
        across = np.array([-along[1], along[0]]) / np.linalg.norm(along)
        shafted.append(drawn_shaft(image, uv[at], across, 40.0))
    with pytest.raises(GraspNotSeenError, match="left and right views do not see"):
        reconstruct(left, right, camera, images=tuple(shafted))


def straight_view(unobserved: slice) -> Resampled:
    """A straight sequence across a 640x480 view, resampled every 1 px, ``unobserved`` not observed."""
    points = np.column_stack([np.linspace(100.0, 540.0, 50), np.linspace(150.0, 330.0, 50)])
    view = resample(points, 1.0)
    view.observed[unobserved] = False
    return view


def test_a_run_is_seen_only_where_the_image_shows_a_line_of_the_threads_contrast():
    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur(rng.uniform(0, 255, (480, 640)).astype(np.float32), (0, 0), 2.0)
    background = np.dstack([np.clip(128 + 3 * (texture - texture.mean()), 0, 255)] * 3).astype(np.uint8)
    run = slice(200, 260)
    view = straight_view(run)
    with_line = drawn_thread(background, view.points)
    assert seen_in_image(view, with_line).observed.all()
    # The line stops where the run starts: nothing of the thread's contrast along the run.
    cut = drawn_thread(background, view.points[:200])
    cut = drawn_thread(cut, view.points[260:])
    assert not seen_in_image(view, cut).observed[run].any()
    # A shaft across the run, its edges crossing the line: not the thread.
    middle = view.points[230]
    direction = view.points[231] - view.points[229]
    across = np.array([-direction[1], direction[0]]) / np.linalg.norm(direction)
    assert not seen_in_image(view, drawn_shaft(with_line, middle, across, 50.0)).observed[run].any()
    # A faint thread (a tenth of the contrast) is still a line where the image is clean.
    faint = np.clip(
        128 + (drawn_thread(np.full_like(background, 128), view.points).astype(float) - 128) / 10, 0, 255
    ).astype(np.uint8)
    assert seen_in_image(view, faint).observed.all()
    # The observed samples show no line at all (a background of noise alone): nothing to compare with.
    assert not seen_in_image(view, background).observed[run].any()
