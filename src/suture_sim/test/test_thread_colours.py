# SPDX-License-Identifier: Apache-2.0
"""Thread colours are drawn only among those an annotator could see on the frame's background."""

from __future__ import annotations

import numpy as np

from suture_sim import textures
from suture_sim.scene import THREAD_COLOURS, contrasting_colours


def _albedo(background: str, seed: int) -> np.ndarray:
    return textures.make_surface_texture(background, 128, 0.1, np.random.default_rng(seed)).albedo


def test_undyed_thread_is_not_used_on_a_pale_phantom() -> None:
    for seed in range(3):
        names = contrasting_colours(_albedo("phantom", seed))
        assert "undyed" not in names
        assert {"violet", "green", "blue", "black"} <= set(names)


def test_every_colour_is_visible_on_red_tissue() -> None:
    for seed in range(3):
        assert contrasting_colours(_albedo("tissue", seed)) == list(THREAD_COLOURS)


def test_a_grey_background_keeps_only_contrasting_colours() -> None:
    grey = np.full((4, 4, 3), 0.8, np.float32)
    names = contrasting_colours(grey)
    assert "white" not in names and "black" in names
