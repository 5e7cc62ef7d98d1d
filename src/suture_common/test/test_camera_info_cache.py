# SPDX-License-Identifier: Apache-2.0
"""CameraInfoCache: the latest camera_info per view and the stereo camera built from them once."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from suture_common.camera import CameraInfoCache, CameraModelError, StereoCamera
from suture_common.messages import camera_info_message

CAMERA = StereoCamera.default(640, 480)


def info(camera: StereoCamera, view: str, stamp_ns: int = 1):
    return camera_info_message(camera, view, stamp_ns, f"{view}_frame")


def test_no_camera_until_both_views_spoke():
    cache = CameraInfoCache()
    assert cache.missing() == ["left", "right"] and cache.camera() is None
    cache.update("right", info(CAMERA, "right"))
    assert cache.missing() == ["left"] and cache.camera() is None
    cache.update("left", info(CAMERA, "left"))
    assert cache.missing() == [] and cache.camera() == CAMERA


def test_built_once_and_again_when_the_calibration_changes():
    cache = CameraInfoCache()
    cache.update("left", info(CAMERA, "left"))
    cache.update("right", info(CAMERA, "right"))
    first = cache.camera()
    cache.update("left", info(CAMERA, "left", stamp_ns=2))  # same calibration, new stamp
    assert cache.camera() is first
    wider = dataclasses.replace(CAMERA, baseline=2 * CAMERA.baseline)
    cache.update("right", info(wider, "right"))
    cache.update("left", info(wider, "left"))
    assert cache.camera() == wider


def test_an_unusable_pair_raises_until_it_is_replaced():
    cache = CameraInfoCache()
    cache.update("left", info(CAMERA, "left"))
    bad = info(CAMERA, "right")
    bad.p = np.array([np.nan] * 12)
    cache.update("right", bad)
    with pytest.raises(CameraModelError, match="NaN"):
        cache.camera()
    with pytest.raises(CameraModelError):  # tried again, not cached
        cache.camera()
    cache.update("right", info(CAMERA, "right"))
    assert cache.camera() == CAMERA


def test_unknown_side_is_refused():
    with pytest.raises(ValueError, match="side"):
        CameraInfoCache().update("middle", info(CAMERA, "left"))
