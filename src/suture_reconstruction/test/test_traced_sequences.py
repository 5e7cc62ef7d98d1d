# SPDX-License-Identifier: Apache-2.0
"""reconstruct() on sequences traced from pixel masks: no length inflation from their saw-tooth.

``data/traced_frames.npz`` holds three simulated frames (``suture-sim --topology mixed
--domain legacy --resolution 640x480 --seed 808``, frames 5, 30 and 80: straight threads
20-35 deg off the image rows) with the sequences that ``suture_ordering.core.order_stereo``
traced on their ground-truth masks (float32 px), the camera (width, height, fx, fy, cx, cy,
baseline), the true centreline (every 0.2 mm) and the true grasp point. Those sequences carry
the masks' quantisation saw-tooth; without the pairs' noise floor (``pair_noise_floor``) the
depth follows it and the threads come out 17-37 mm too long, the grasp 6-16 mm off.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from suture_common.camera import StereoCamera
from suture_reconstruction import reconstruct
from suture_reconstruction.pairing import DisparitySmoothing, pair_noise_floor
from suture_reconstruction.sequences import resample, roughness, smooth_sequence

DATA = Path(__file__).parent / "data" / "traced_frames.npz"
FRAMES = (5, 30, 80)


def traced_frame(index: int) -> tuple[np.ndarray, np.ndarray, StereoCamera, np.ndarray, np.ndarray]:
    with np.load(DATA) as data:
        width, height, fx, fy, cx, cy, baseline = data[f"f{index}_camera"]
        camera = StereoCamera(int(width), int(height), fx, fy, cx, cy, baseline)
        return (
            data[f"f{index}_left"].astype(np.float64),
            data[f"f{index}_right"].astype(np.float64),
            camera,
            data[f"f{index}_path"].astype(np.float64),
            data[f"f{index}_grasp"],
        )


@pytest.mark.parametrize("index", FRAMES)
def test_traced_sequences_give_the_true_length_and_grasp(index):
    left, right, camera, path, grasp = traced_frame(index)
    result = reconstruct(left, right, camera)
    true_length = float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())
    assert abs(result.length - true_length) < 3e-3, (result.length, true_length)
    assert np.linalg.norm(result.grasp_position - grasp) < 3.5e-3


@pytest.mark.parametrize("index", FRAMES)
def test_traced_sequences_raise_the_noise_floor(index):
    left, right, _, _, _ = traced_frame(index)
    points = [resample(smooth_sequence(s, 9), 1.0, 4.0).points for s in (left, right)]
    assert pair_noise_floor(*points, DisparitySmoothing()) > 0.2


def test_exact_and_white_noise_sequences_get_no_floor_of_their_own(make_scene):
    for noise, most in ((0.0, 0.0), (0.3, 0.05)):
        for kind in ("curved", "loop"):
            scene = make_scene(kind, 1, noise=noise)
            points = [resample(smooth_sequence(s, 9), 1.0, 4.0).points for s in (scene.left, scene.right)]
            assert pair_noise_floor(*points, DisparitySmoothing()) <= most, (noise, kind)


def test_roughness_is_zero_on_a_smooth_curve_and_tracks_noise():
    angle = np.linspace(0.0, 3.0, 400)
    circle = 60.0 * np.column_stack([np.cos(angle), np.sin(angle)]) + 200.0  # 1.35 px apart, r 60 px
    assert roughness(circle, 31, 4) < 1e-3
    noisy = circle + np.random.default_rng(0).normal(0.0, 0.2, circle.shape)
    assert 0.1 < roughness(noisy, 31, 4) < 0.25
    assert roughness(circle[:5], 31, 4) == 0.0
