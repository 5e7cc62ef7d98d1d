# SPDX-License-Identifier: Apache-2.0
"""Frame generation over worker processes, in frame order.

Frames are independent (each is drawn from its own seed and index), so they
render in parallel; the caller receives them in index order, one at a time,
so memory stays bounded whatever the number of frames.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Iterable, Iterator
from functools import partial

import cv2

from suture_sim.scene import SimConfig, SimFrame, generate_frame


def _init_worker() -> None:
    cv2.setNumThreads(1)  # one process per core; nested OpenCV threads only contend


def generate_frames(config: SimConfig, indices: Iterable[int], workers: int = 1) -> Iterator[SimFrame]:
    """Yield ``generate_frame(config, i)`` for each index, in order, using ``workers`` processes."""
    indices = list(indices)
    if workers <= 1 or len(indices) < 2:
        yield from (generate_frame(config, i) for i in indices)
        return
    # spawn, not fork: forking after OpenCV or BLAS started threads can deadlock the child.
    context = multiprocessing.get_context("spawn")
    with context.Pool(min(workers, len(indices)), initializer=_init_worker) as pool:
        yield from pool.imap(partial(generate_frame, config), indices, chunksize=1)
