# SPDX-License-Identifier: Apache-2.0
"""Predicted masks kept on disk, so that the ordering and 3D stages can be scored again without
segmenting again.

Segmentation takes most of an evaluation's time with predicted masks (about 0.15 s of the 0.2 s
per frame on two cores). A change to the ordering or the 3D stage leaves the masks as they were,
so ``suture-eval --mask-cache FILE`` writes every frame's masks and low masks to ``FILE`` (one
compressed ``.npz``) on the first run and reads them back on the next. The file records what made
the masks: the model file's SHA-256, the mirror averaging and the low masks' threshold. A run with
other settings, or over a bag with frames the file lacks, stops with
:class:`~suture_bench.frames.EvaluationError` instead of scoring stale masks.

Masks are stored as bits (``np.packbits`` of ``mask > 0``) with their (H, W) shape, and come back
as uint8 0/255, as segmentation_node publishes them.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from suture_bench.frames import EvaluationError

Masks = tuple[np.ndarray, np.ndarray]


def weights_digest(path: str | Path) -> str:
    """SHA-256 (hex) of the model file at ``path``."""
    digest = hashlib.sha256()
    with open(path, "rb") as stream:
        for block in iter(lambda: stream.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


class MaskCache:
    """Masks and low masks per frame key (``bag name/stamp_ns``) in the ``.npz`` at ``path``.

    ``settings``: what made the masks (JSON-serialisable); an existing file made with other
    settings raises :class:`~suture_bench.frames.EvaluationError`. :meth:`get` returns a frame's
    masks or None, :meth:`put` adds them, :meth:`save` writes the file when something was added.
    """

    def __init__(self, path: str | Path, settings: dict) -> None:
        self.path = Path(path)
        self.settings = settings
        self._frames: dict[str, tuple[Masks, Masks | None]] = {}
        self._added = False
        self.loaded = self.path.exists()
        if self.loaded:
            self._load()

    def _load(self) -> None:
        try:
            with np.load(self.path, allow_pickle=False) as data:
                header = json.loads(str(data["header"]))
                stored = header["settings"]
                if stored != self.settings:
                    raise EvaluationError(
                        f"mask cache {self.path} was made with {stored}, not {self.settings}: give another "
                        "file, or delete it to segment again"
                    )
                for index, (key, shape, has_low) in enumerate(header["frames"]):
                    masks = tuple(_unpack(data[f"{index}_{side}"], shape) for side in ("l", "r"))
                    low = None
                    if has_low:
                        low = tuple(_unpack(data[f"{index}_low_{side}"], shape) for side in ("l", "r"))
                    self._frames[key] = (masks, low)
        except (OSError, ValueError, KeyError) as error:
            raise EvaluationError(f"mask cache {self.path} cannot be read ({error}); delete it") from error

    def get(self, key: str) -> tuple[Masks, Masks | None] | None:
        """The (left, right) masks and low masks (or None) of frame ``key``; None if not cached."""
        return self._frames.get(key)

    def put(self, key: str, masks: Masks, low_masks: Masks | None) -> None:
        """Keep frame ``key``'s masks and low masks (uint8, nonzero = thread)."""
        self._frames[key] = (masks, low_masks)
        self._added = True

    def save(self) -> None:
        """Write every frame to the file (parent folders created) if :meth:`put` added any."""
        if not self._added:
            return
        arrays: dict[str, np.ndarray] = {}
        frames = []
        for index, (key, (masks, low)) in enumerate(self._frames.items()):
            frames.append((key, list(masks[0].shape), low is not None))
            for side, mask in zip(("l", "r"), masks, strict=True):
                arrays[f"{index}_{side}"] = np.packbits(np.asarray(mask) > 0)
            if low is not None:
                for side, mask in zip(("l", "r"), low, strict=True):
                    arrays[f"{index}_low_{side}"] = np.packbits(np.asarray(mask) > 0)
        header = json.dumps({"settings": self.settings, "frames": frames})
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with open(self.path, "wb") as stream:
            np.savez_compressed(stream, header=np.array(header), **arrays)
        self._added = False


def _unpack(bits: np.ndarray, shape: list[int]) -> np.ndarray:
    height, width = shape
    return (np.unpackbits(bits)[: height * width].reshape(height, width) * 255).astype(np.uint8)
