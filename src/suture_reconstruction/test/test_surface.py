# SPDX-License-Identifier: Apache-2.0
"""The surface beside a thread along the image rows as a witness of its depth
(suture_reconstruction.surface)."""

from __future__ import annotations

import numpy as np
import pytest

from suture_common.camera import StereoCamera
from suture_reconstruction import ReconstructionParams, ThreadBehindSurfaceError, reconstruct
from suture_reconstruction.surface import refuse_behind_surface, surface_gap_px

LENIENT = dict(max_grasp_uncertainty_mm=1000.0, max_unexplained_arc_mm=1000.0, max_arc_image_ratio=1000.0)


def thread_along_rows() -> np.ndarray:
    """A thread 95 mm away (m, every 0.05 mm): 20 mm from the tip at 30 degrees to the image rows,
    then 50 mm at 1 degree (the grasp point, 50 mm from the tip, on the stretch along the rows),
    then 10 mm at 30 degrees again, so that no end's depth rests on its pair alone
    (:func:`suture_reconstruction.ends.match_unanchored_ends` leaves it to the pairs)."""
    s = np.arange(0.0, 0.08, 5e-5)
    heading = np.radians(np.where((s < 0.02) | (s >= 0.07), 30.0, 1.0))
    xy = np.cumsum(np.column_stack([-np.cos(heading), np.sin(heading)]) * 5e-5, axis=0)
    return np.column_stack([xy + np.array([0.035, -0.01]), np.full(len(s), 0.095)])


def test_the_surface_gap_is_the_planes_disparity_less_the_threads(textured_pair):
    camera = StereoCamera.default(640, 480)
    images = textured_pair(camera, 30)
    gap = surface_gap_px(images, np.array([320.0, 240.0]), 24.5)
    assert gap == pytest.approx(5.5, abs=0.2)
    flat = tuple(np.full_like(image, 128) for image in images)
    assert surface_gap_px(flat, np.array([320.0, 240.0]), 24.5) is None  # no texture, no evidence
    assert surface_gap_px(images, np.array([320.0, 5.0]), 24.5) is None  # a window off the image


def test_only_a_thread_along_the_rows_and_well_behind_the_surface_is_refused():
    refuse_behind_surface(None, 1.0, 3.0)
    refuse_behind_surface(2.5, 1.0, 3.0)
    refuse_behind_surface(8.0, 20.0, 3.0)  # its depth is measured there: the thread is the witness
    with pytest.raises(ThreadBehindSurfaceError, match=r"8\.0 px of disparity behind the tissue"):
        refuse_behind_surface(8.0, 1.0, 3.0)


def test_a_thread_along_the_rows_reconstructed_behind_the_tissue_is_refused(exact_views, textured_pair):
    camera = StereoCamera.default(640, 480)
    curve = thread_along_rows()
    left, right = exact_views(camera, curve)
    thread_disparity = float(camera.disparity(0.095))  # 27.4 px
    params = ReconstructionParams(**LENIENT)
    # The tissue 1 px behind the thread: the thread rests on it, the grasp is published.
    result = reconstruct(left, right, camera, params, images=textured_pair(camera, 26))
    assert result.uncertainty.row_angle_deg < 5.0 and np.isfinite(result.grasp_position).all()
    # The tissue 6 px in front of the reconstructed thread: its carried depth is inside the tissue.
    behind = textured_pair(camera, round(thread_disparity) + 6)
    with pytest.raises(ThreadBehindSurfaceError, match="inside the surface"):
        reconstruct(left, right, camera, params, images=behind)
    reconstruct(left, right, camera, params)  # without images there is no witness
    reconstruct(left, right, camera, params.replace(max_behind_surface_px=10.0), images=behind)
    with pytest.raises(ValueError, match="max_behind_surface_px"):
        ReconstructionParams(max_behind_surface_px=0.0)
