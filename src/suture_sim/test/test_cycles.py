# SPDX-License-Identifier: Apache-2.0
"""The Cycles renderer draws the raster renderer's scene: the same ground truth, its own image.

Its ground truth is also checked by every test of ``test_ground_truth`` (the ``cycles-640x480``
frames); these tests compare it with the raster renderer frame for frame.
"""

from __future__ import annotations

import sys

import cv2
import numpy as np
import pytest

from suture_common.camera import StereoCamera
from suture_sim import cli
from suture_sim.scene import SimConfig, SimFrame, generate_frame


@pytest.fixture(scope="module")
def frame_pairs(blender) -> list[tuple[SimFrame, SimFrame]]:
    """(raster, cycles) renders of an occluded, a crossed and a wide_occlusion frame at 320x240, 4 samples."""
    camera = StereoCamera.default(320, 240)
    pairs = []
    for topology in ("occluded", "crossed", "wide_occlusion"):
        frames = [
            generate_frame(SimConfig(topology, camera, seed=23, renderer=renderer, samples=4), 0)
            for renderer in ("raster", "cycles")
        ]
        pairs.append(tuple(frames))
    return pairs


def _within_one_pixel(mask: np.ndarray, other: np.ndarray) -> float:
    """Fraction of ``mask``'s pixels within one pixel (8-neighbourhood) of one of ``other``'s."""
    near = cv2.dilate(other, np.ones((3, 3), np.uint8)) > 0
    return float(np.mean(near[mask > 0]))


def test_same_geometry_and_masks_within_a_pixel_of_the_raster_renderer(frame_pairs):
    for raster, cycles in frame_pairs:
        np.testing.assert_array_equal(cycles.path, raster.path)
        np.testing.assert_array_equal(cycles.grasp_position, raster.grasp_position)
        for view in ("left", "right"):
            ours, theirs = getattr(cycles, f"{view}_sequence"), getattr(raster, f"{view}_sequence")
            np.testing.assert_array_equal(ours[:, :2], theirs[:, :2])
            # Occlusion flags differ at most at the edges of what an instrument or strand hides.
            assert np.mean(ours[:, 2] == theirs[:, 2]) > 0.97, (cycles.topology, view)
            ours, theirs = getattr(cycles, f"{view}_mask"), getattr(raster, f"{view}_mask")
            assert _within_one_pixel(ours, theirs) > 0.99, (cycles.topology, view)
            assert _within_one_pixel(theirs, ours) > 0.99, (cycles.topology, view)
            assert 0.8 < np.count_nonzero(ours) / np.count_nonzero(theirs) < 1.3


def test_cycles_image_is_its_own_and_shows_the_thread(frame_pairs):
    for raster, cycles in frame_pairs:
        image = cycles.left_image.astype(np.float64)
        assert 25 < image.mean() < 220  # lit, not saturated
        assert np.abs(image - raster.left_image).mean() > 5  # not the raster renderer's picture
        thread = cycles.left_mask > 0
        ring = (cv2.dilate(cycles.left_mask, np.ones((9, 9), np.uint8)) > 0) & ~thread
        contrast = np.abs(image[thread].mean(axis=0) - image[ring].mean(axis=0)).max()
        assert contrast > 10, cycles.topology


def test_same_seed_same_cycles_frame(frame_pairs):
    _, crossed = frame_pairs[1]
    again = generate_frame(SimConfig("crossed", crossed.camera, seed=23, renderer="cycles", samples=4), 0)
    np.testing.assert_array_equal(again.left_image, crossed.left_image)
    np.testing.assert_array_equal(again.right_mask, crossed.right_mask)


def test_cycles_camera_is_the_pinhole_model_with_any_intrinsics(blender):
    """fx != fy and an off-centre principal point: the Cycles masks still lie on the raster's."""
    camera = StereoCamera(320, 240, fx=250.0, fy=275.0, cx=171.3, cy=108.6, baseline=0.004)
    raster, cycles = (
        generate_frame(SimConfig("curved", camera, seed=4, renderer=renderer, samples=1), 0)
        for renderer in ("raster", "cycles")
    )
    for view in ("left", "right"):
        ours, theirs = getattr(cycles, f"{view}_mask"), getattr(raster, f"{view}_mask")
        assert _within_one_pixel(ours, theirs) > 0.99 and _within_one_pixel(theirs, ours) > 0.99, view
        sequence = getattr(cycles, f"{view}_sequence")
        pixels = np.rint(sequence[sequence[:, 2] == 1, :2]).astype(int)
        assert np.all(ours[pixels[:, 1], pixels[:, 0]] == 255), view


def test_cycles_without_blender_is_a_one_line_error(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "bpy", None)  # `import bpy` raises ImportError
    argv = ["--topology", "straight", "--frames", "1", "--renderer", "cycles", "--workers", "1"]
    assert cli.main([*argv, "--resolution", "160x120", "--png-dir", str(tmp_path / "png"), "--quiet"]) == 1
    error = capsys.readouterr().err.strip()
    assert "\n" not in error and "--with-blender" in error
