# SPDX-License-Identifier: Apache-2.0
"""Shared fixtures of the simulator's tests."""

from __future__ import annotations

import os

import pytest

from suture_sim.cycles import CyclesUnavailableError, import_bpy


@pytest.fixture(scope="session")
def blender():
    """Blender's ``bpy`` for the Cycles renderer.

    ``ros2_ws/test.sh`` (what CI runs) installs the Blender extra and sets
    ``SUTURE_REQUIRE_BLENDER=1``: there a missing ``bpy`` fails the test. A plain ``pytest`` in an
    environment set up without ``--with-blender`` skips it, saying so.
    """
    try:
        return import_bpy()
    except CyclesUnavailableError as error:
        if os.environ.get("SUTURE_REQUIRE_BLENDER") == "1":
            pytest.fail(f"SUTURE_REQUIRE_BLENDER=1 but {error}")
        pytest.skip(f"{error}; ros2_ws/test.sh installs it and runs this test")
