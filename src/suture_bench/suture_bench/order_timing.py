# SPDX-License-Identifier: Apache-2.0
"""Timing worker of ``suture-order-bench --baseline``: orders a file of stereo frames with whichever
``suture_ordering`` its interpreter imports, and writes the times and the sequences.

Run as a script by path (``PYTHON -P order_timing.py FRAMES OUT``), so that the interpreter of another
checkout (the baseline) times its own code on the same frames; it needs only that checkout's
``suture_ordering.order_stereo``. FRAMES: a pickle of tuples ``(left_bits, right_bits, shape,
tip_hint, camera)``, the masks packed with ``np.packbits``; OUT: a
pickle of one tuple per frame, ``(left_ms, right_ms, cpu_ms, left, right)`` with the views'
``elapsed_ms``, the thread's CPU time of the pair (ms) and the (N, 2) sequences, or
``(None, None, None, error message)`` when the ordering refused. The first frame is ordered once
before timing (imports, caches).
"""

from __future__ import annotations

import contextlib
import pickle
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from suture_ordering import OrderingError, order_stereo


def pack_mask(mask: np.ndarray) -> np.ndarray:
    """(H, W) mask as the packed bits of a FRAMES file."""
    return np.packbits(np.asarray(mask) > 0)


def _unpack(bits: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    return np.unpackbits(bits)[: shape[0] * shape[1]].reshape(shape).astype(bool)


def time_frames(frames_file: Path, out_file: Path) -> None:
    """Order every frame of ``frames_file`` once (one core, one OpenCV thread) and pickle the results."""
    cv2.setNumThreads(1)
    with open(frames_file, "rb") as stream:
        frames = pickle.load(stream)
    masks = [(_unpack(left, shape), _unpack(right, shape)) for left, right, shape, _, _ in frames]
    if frames:
        with contextlib.suppress(OrderingError):  # warm-up
            order_stereo(*masks[0], frames[0][3], frames[0][4])
    results = []
    for (left, right), (_, _, _, hint, camera) in zip(masks, frames, strict=True):
        started = time.thread_time()
        try:
            ordering = order_stereo(left, right, hint, camera)
        except OrderingError as error:
            results.append((None, None, None, str(error)))
            continue
        cpu_ms = (time.thread_time() - started) * 1e3
        results.append(
            (
                ordering.left_result.elapsed_ms,
                ordering.right_result.elapsed_ms,
                cpu_ms,
                ordering.left,
                ordering.right,
            )
        )
    with open(out_file, "wb") as stream:
        pickle.dump(results, stream)


if __name__ == "__main__":
    time_frames(Path(sys.argv[1]), Path(sys.argv[2]))
