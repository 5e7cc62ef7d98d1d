# SPDX-License-Identifier: Apache-2.0
"""Training data: PNG folders of images and masks, and random training crops from them.

Folder format (what ``suture-sim --png-dir`` writes and what ``suture-seg finetune --images
DIR --masks DIR`` reads from a user's own annotations)::

    images/000012_left.png   the camera frame, 8-bit RGB (or grey) PNG/JPEG
    masks/000012_left.png    same file name, same size, single channel 8-bit:
                             0 = background, any value > 127 = suture

An image without a mask of the same name (and the other way round) is an error, not skipped:
a silently smaller training set is worse than a clear message.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from skimage.morphology import skeletonize

from suture_common.image_files import IMAGE_SUFFIXES
from suture_common.image_files import image_files as common_image_files


class DatasetError(ValueError):
    """A training/evaluation folder is missing, empty or inconsistent."""


@dataclass
class LabelledImages:
    """Images and masks in memory.

    Attributes:
        names: file names, sorted.
        images: list of (H, W, 3) uint8 RGB.
        masks: list of (H, W) bool, True = suture.
    """

    names: list[str]
    images: list[np.ndarray]
    masks: list[np.ndarray]

    def __len__(self) -> int:
        return len(self.names)

    def subset(self, indices: list[int] | np.ndarray) -> LabelledImages:
        return LabelledImages(
            [self.names[i] for i in indices],
            [self.images[i] for i in indices],
            [self.masks[i] for i in indices],
        )


def read_rgb(path: str | Path) -> np.ndarray:
    """(H, W, 3) uint8 RGB from an image file; raises DatasetError if it cannot be read."""
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise DatasetError(f"cannot read image {path}")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def image_files(folder: str | Path) -> list[Path]:
    """The image files (:data:`IMAGE_SUFFIXES`) of ``folder``, sorted by name.

    Raises DatasetError if ``folder`` is not a folder or holds no image.
    """
    return common_image_files(folder, "image", DatasetError)


def load_folder(images_dir: str | Path, masks_dir: str | Path, limit: int | None = None) -> LabelledImages:
    """Read every image of ``images_dir`` with its mask of the same name in ``masks_dir``.

    Args:
        images_dir, masks_dir: folders in the format of the module docstring.
        limit: read only the first ``limit`` images (sorted by name); None reads all.

    Raises:
        DatasetError: a folder is missing or empty, a mask is missing, unreadable or of another size.
    """
    images_dir, masks_dir = Path(images_dir), Path(masks_dir)
    for folder in (images_dir, masks_dir):
        if not folder.is_dir():
            raise DatasetError(f"{folder} is not a folder")
    paths = image_files(images_dir)
    if limit is not None:
        paths = paths[:limit]
    names, images, masks = [], [], []
    for path in paths:
        candidates = [masks_dir / path.name, *(masks_dir / (path.stem + s) for s in IMAGE_SUFFIXES)]
        mask_path = next((c for c in candidates if c.is_file()), None)
        if mask_path is None:
            raise DatasetError(f"no mask for {path.name} in {masks_dir} (masks share the image's file name)")
        image = read_rgb(path)
        mask = cv2.imread(str(mask_path), cv2.IMREAD_GRAYSCALE)
        if mask is None:
            raise DatasetError(f"cannot read mask {mask_path}")
        if mask.shape != image.shape[:2]:
            raise DatasetError(
                f"mask {mask_path} is {mask.shape[::-1]} but its image is {image.shape[1::-1]}"
            )
        names.append(path.name)
        images.append(image)
        masks.append(mask > 127)
    return LabelledImages(names, images, masks)


class CropSampler:
    """Random square training crops, most of them on the thread, with flips and 90-degree turns.

    Args:
        data: the labelled images.
        crop: crop side in pixels (a multiple of 16; images smaller than it are padded).
        on_thread: fraction of crops centred on a random suture pixel (the rest are uniform,
            so the background clutter is learnt too).
        rng: random generator (seeded by the caller for reproducible training).
        photometric: give 80 % of the crops another look (:func:`photometric_jitter`); the
            labels are unchanged.
        structure: fraction of crops centred on an end or a junction of the thread
            (:func:`structure_points`: the cut tip with its hook or loop, crossings,
            self-intersections), where the ordering depends on a few pixels of the mask and a
            crop on a random thread pixel seldom lands; taken from the ``on_thread`` share.
    """

    def __init__(
        self,
        data: LabelledImages,
        crop: int,
        on_thread: float,
        rng: np.random.Generator,
        photometric: bool = False,
        structure: float = 0.0,
    ) -> None:
        if len(data) == 0:
            raise DatasetError("no training images")
        if not 0.0 <= structure <= on_thread:
            raise ValueError(f"structure must be in [0, on_thread={on_thread}], got {structure}")
        self.data, self.crop, self.on_thread, self.rng = data, crop, on_thread, rng
        self.photometric, self.structure = photometric, structure
        self._suture_pixels = [np.flatnonzero(m) for m in data.masks]
        self._structure_pixels: dict[int, np.ndarray] = {}

    def batch(self, size: int) -> tuple[np.ndarray, np.ndarray]:
        """(size, 3, crop, crop) float32 images in [0, 1] and (size, crop, crop) int64 labels."""
        images = np.empty((size, 3, self.crop, self.crop), np.float32)
        labels = np.empty((size, self.crop, self.crop), np.int64)
        for k in range(size):
            image, mask = self._one()
            images[k] = image.transpose(2, 0, 1) / np.float32(255.0)
            labels[k] = mask
        return images, labels

    def _one(self) -> tuple[np.ndarray, np.ndarray]:
        i = int(self.rng.integers(len(self.data)))
        image, mask = self.data.images[i], self.data.masks[i]
        height, width = mask.shape
        half = self.crop // 2
        pixels, jitter = self._suture_pixels[i], half // 2
        draw = self.rng.random()
        if draw < self.structure:
            if i not in self._structure_pixels:
                self._structure_pixels[i] = structure_points(mask)
            pixels, jitter = self._structure_pixels[i], half // 4
        if pixels.size and draw < self.on_thread:
            centre = int(pixels[self.rng.integers(pixels.size)])
            cy, cx = divmod(centre, width)
            cy += int(self.rng.integers(-jitter, jitter + 1))
            cx += int(self.rng.integers(-jitter, jitter + 1))
        else:
            cy, cx = int(self.rng.integers(height)), int(self.rng.integers(width))
        top = int(np.clip(cy - half, 0, max(height - self.crop, 0)))
        left = int(np.clip(cx - half, 0, max(width - self.crop, 0)))
        image = image[top : top + self.crop, left : left + self.crop]
        mask = mask[top : top + self.crop, left : left + self.crop]
        if image.shape[:2] != (self.crop, self.crop):
            pad = ((0, self.crop - image.shape[0]), (0, self.crop - image.shape[1]))
            image = np.pad(image, (*pad, (0, 0)), mode="edge")
            mask = np.pad(mask, pad)
        turns = int(self.rng.integers(4))
        image, mask = np.rot90(image, turns), np.rot90(mask, turns)
        if self.rng.random() < 0.5:
            image, mask = image[:, ::-1], mask[:, ::-1]
        image = image.astype(np.float32)
        if self.photometric and self.rng.random() < 0.8:
            image = photometric_jitter(image, self.rng)
        return image, mask.astype(np.int64)


def structure_points(mask: np.ndarray) -> np.ndarray:
    """Flat indices into ``mask`` ((H, W) bool) of the ends and junctions of its skeleton.

    A skeleton pixel is an end where its 8 neighbours, read round the ring, hold one run of
    skeleton pixels, and a junction where they hold three or more (the crossing number: unlike
    a count of neighbours, it does not take a staircase step of a slanted line for a junction).
    """
    skeleton = np.pad(skeletonize(mask), 1)
    height, width = mask.shape
    ring = [(-1, -1), (-1, 0), (-1, 1), (0, 1), (1, 1), (1, 0), (1, -1), (0, -1)]
    neighbours = [skeleton[1 + dy : 1 + dy + height, 1 + dx : 1 + dx + width] for dy, dx in ring]
    runs = sum(
        (a & ~b).astype(np.uint8) for a, b in zip(neighbours, neighbours[1:] + neighbours[:1], strict=True)
    )
    core = skeleton[1:-1, 1:-1]
    return np.flatnonzero(core & (runs != 2))


def photometric_jitter(image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The crop as another endoscope might show it: white balance, exposure, contrast, tone
    curve, focus and noise drawn at random.

    ``image``: (H, W, 3) float32 in [0, 255]; returns a new (H, W, 3) float32 array in [0, 255].
    Channel gains 0.8-1.2 times an exposure of 0.7-1.3, contrast 0.7-1.3 about the mean, gamma
    0.7-1.4, a Gaussian blur of sigma 0.3-1.0 px on 30 % of the crops, Gaussian noise of sigma
    0-3 % of full scale. Trained on such variations, the feature extractor that transfer
    learning freezes does not key on the training domain's colours (docs/results.md, Table I).
    Generic on purpose, not the simulator's ``sample_look``: the stages do not depend on the
    simulator, and drawing its on-site looks would show M-oST the target domain.
    """
    image = image * (rng.uniform(0.8, 1.2, 3) * rng.uniform(0.7, 1.3)).astype(np.float32)
    mean = image.mean()
    image = (image - mean) * np.float32(rng.uniform(0.7, 1.3)) + mean
    image = 255.0 * (np.clip(image, 0.0, 255.0) / 255.0) ** np.float32(rng.uniform(0.7, 1.4))
    if rng.random() < 0.3:
        image = cv2.GaussianBlur(image, (0, 0), float(rng.uniform(0.3, 1.0)))
    noise = rng.normal(0.0, rng.uniform(0.0, 0.03) * 255.0, image.shape).astype(np.float32)
    return np.clip(image + noise, 0.0, 255.0).astype(np.float32)
