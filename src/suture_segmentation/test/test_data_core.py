# SPDX-License-Identifier: Apache-2.0
"""PNG folders, training crops, and inference: backends agree, bad input and bad weights are refused."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from skimage.filters import apply_hysteresis_threshold

from suture_segmentation.checkpoint import WeightsError, export_onnx, load_checkpoint
from suture_segmentation.core import SegmentationInputError, Segmenter, hysteresis_mask
from suture_segmentation.data import (
    CropSampler,
    DatasetError,
    LabelledImages,
    load_folder,
    photometric_jitter,
    structure_points,
)


def test_folder_loads_images_with_their_masks(line_folder: Path) -> None:
    data = load_folder(line_folder / "images", line_folder / "masks")
    assert len(data) == 6 and data.names[0] == "000.png"
    assert data.images[0].shape == (64, 96, 3) and data.images[0].dtype == np.uint8
    assert data.masks[0].dtype == bool and data.masks[0].any()
    # the dark line is where the mask says
    assert data.images[0][data.masks[0]].mean() < data.images[0][~data.masks[0]].mean()


def test_folder_errors_name_the_problem(line_folder: Path, tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="is not a folder"):
        load_folder(tmp_path / "nope", line_folder / "masks")
    (line_folder / "masks" / "002.png").unlink()
    with pytest.raises(DatasetError, match="no mask for 002.png"):
        load_folder(line_folder / "images", line_folder / "masks")
    cv2.imwrite(str(line_folder / "masks" / "002.png"), np.zeros((10, 10), np.uint8))
    with pytest.raises(DatasetError, match="mask .*002.png is"):
        load_folder(line_folder / "images", line_folder / "masks")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(DatasetError, match="no images"):
        load_folder(empty, empty)


def test_crops_keep_image_and_mask_aligned(line_folder: Path) -> None:
    data = load_folder(line_folder / "images", line_folder / "masks")
    sampler = CropSampler(data, crop=32, on_thread=1.0, rng=np.random.default_rng(0))
    images, labels = sampler.batch(16)
    assert images.shape == (16, 3, 32, 32) and labels.shape == (16, 32, 32)
    assert images.dtype == np.float32 and images.min() >= 0.0 and images.max() <= 1.0
    assert labels.any(axis=(1, 2)).all()  # on_thread=1: every crop sees the thread
    # after flips and turns the label still marks the dark line pixels
    red = images[:, 0]
    assert red[labels == 1].mean() < 0.3 < red[labels == 0].mean()


def test_photometric_crops_change_the_look_and_keep_the_labels(line_folder: Path) -> None:
    data = load_folder(line_folder / "images", line_folder / "masks")
    changed = []
    for seed in range(30):  # the first crop of a seed: same position, turn and flip either way
        plain = CropSampler(data, crop=32, on_thread=1.0, rng=np.random.default_rng(seed)).batch(1)
        varied = CropSampler(
            data, crop=32, on_thread=1.0, rng=np.random.default_rng(seed), photometric=True
        ).batch(1)
        assert np.array_equal(varied[1], plain[1])
        image, label = varied[0][0], varied[1][0]
        assert image.dtype == np.float32 and image.min() >= 0.0 and image.max() <= 1.0
        assert image[0][label == 1].mean() < image[0][label == 0].mean()  # the thread stays dark
        changed.append(np.abs(image - plain[0][0]).mean() > 0.01)
    assert 0.6 <= np.mean(changed) < 1.0  # about 80 % of the crops get another look


def test_photometric_jitter_spans_colour_tone_and_noise() -> None:
    grey = np.full((24, 24, 3), 128.0, np.float32)
    looks = [photometric_jitter(grey, np.random.default_rng(seed)) for seed in range(30)]
    means = np.array([look.mean(axis=(0, 1)) for look in looks])
    assert np.ptp(means, axis=0).min() > 40  # exposure and white balance vary
    assert np.ptp(means[:, 0] - means[:, 2]) > 10  # so does the colour
    assert max(float(look.std()) for look in looks) > 3  # and the noise
    assert all(look.dtype == np.float32 and look.min() >= 0 and look.max() <= 255 for look in looks)


def _hooked_thread() -> np.ndarray:
    """A 400 x 400 mask: a thread from the left edge whose end curls into a small closed loop."""
    mask = np.zeros((400, 400), np.uint8)
    cv2.line(mask, (0, 200), (300, 200), 1, 3)
    cv2.circle(mask, (306, 194), 6, 1, 2)
    return mask.astype(bool)


def test_structure_points_are_the_ends_and_junctions_not_the_slanted_strokes() -> None:
    slanted = np.zeros((120, 120), np.uint8)
    cv2.line(slanted, (10, 20), (110, 57), 1, 3)  # a staircase skeleton: no junction on it
    ends = np.column_stack(np.divmod(structure_points(slanted.astype(bool)), 120))
    assert len(ends) == 2 and (np.abs(ends[:, 1] - 60) > 40).all()  # the two ends only
    crossed = slanted.copy()
    cv2.line(crossed, (60, 0), (60, 119), 1, 3)
    rows, cols = np.divmod(structure_points(crossed.astype(bool)), 120)
    assert len(rows) >= 5  # four ends and the crossing
    assert (np.hypot(rows - 38, cols - 60) < 4).any()
    hooked = structure_points(_hooked_thread())
    rows, cols = np.divmod(hooked, 400)
    assert (np.hypot(rows - 200, cols - 300) < 8).any()  # where the loop closes on the thread


def test_structure_crops_hold_the_hook_at_the_tip() -> None:
    mask = _hooked_thread()
    image = np.where(mask[..., None], 40, 200).astype(np.uint8).repeat(3, axis=2)
    data = LabelledImages(["hook.png"], [image], [mask])

    def crops_holding_the_loop(structure: float) -> int:
        sampler = CropSampler(data, 64, 1.0, np.random.default_rng(5), structure=structure)
        labels = sampler.batch(200)[1]
        # the loop is the only place where a crop's thread is more than a straight stroke wide
        return int(sum(label.sum(axis=0).max() > 6 and label.sum(axis=1).max() > 6 for label in labels))

    assert crops_holding_the_loop(1.0) > 2 * crops_holding_the_loop(0.0)
    with pytest.raises(ValueError, match="structure must be in"):
        CropSampler(data, 64, 0.5, np.random.default_rng(0), structure=0.6)


def test_crops_larger_than_the_image_are_padded(line_folder: Path) -> None:
    data = load_folder(line_folder / "images", line_folder / "masks")
    images, labels = CropSampler(data, crop=128, on_thread=0.5, rng=np.random.default_rng(1)).batch(2)
    assert images.shape == (2, 3, 128, 128) and labels.shape == (2, 128, 128)


@pytest.fixture()
def pair() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    return (
        rng.integers(0, 256, (50, 70, 3), dtype=np.uint8),
        rng.integers(0, 256, (50, 70, 3), dtype=np.uint8),
    )


def test_onnx_and_torch_backends_give_the_same_masks(random_checkpoint: Path, pair, tmp_path: Path) -> None:
    torch_segmenter = Segmenter(random_checkpoint, backend="torch")
    onnx_segmenter = Segmenter(random_checkpoint, backend="onnx")
    p_torch = torch_segmenter.probabilities(list(pair))
    p_onnx = onnx_segmenter.probabilities(list(pair))
    assert p_torch.shape == (2, 50, 70)
    assert np.abs(p_torch - p_onnx).max() < 1e-4
    threshold = float(np.median(p_torch))  # a threshold that splits the random-weights output
    masks_torch = (p_torch > threshold).astype(np.uint8)
    masks_onnx = (p_onnx > threshold).astype(np.uint8)
    near = np.abs(p_torch - threshold) < 1e-4
    assert np.array_equal(masks_torch[~near], masks_onnx[~near])
    # an exported .onnx file is accepted as weights too
    onnx_file = export_onnx(load_checkpoint(random_checkpoint)[0], tmp_path / "model.onnx")
    assert np.abs(Segmenter(onnx_file).probabilities(list(pair)) - p_onnx).max() < 1e-5


@pytest.mark.parametrize("backend", ["torch", "onnx"])
def test_flip_average_is_the_mean_of_an_image_and_its_mirror_image(
    random_checkpoint: Path, pair, backend: str
) -> None:
    images = list(pair)
    mirrored = [np.ascontiguousarray(image[:, ::-1]) for image in images]
    plain = Segmenter(random_checkpoint, backend=backend, flip_average=False)
    averaged = Segmenter(random_checkpoint, backend=backend).probabilities(images)
    expected = (plain.probabilities(images) + plain.probabilities(mirrored)[..., ::-1]) / 2
    assert averaged.shape == (2, 50, 70) and averaged.dtype == np.float32
    assert np.abs(averaged - expected).max() < 1e-5
    # so the masks do not depend on which way round the camera sees the scene, which the plain
    # model's do (random weights: far from mirror-symmetric)
    assert np.abs(plain.probabilities(mirrored)[..., ::-1] - plain.probabilities(images)).max() > 1e-3
    averaged_mirrored = Segmenter(random_checkpoint, backend=backend).probabilities(mirrored)
    assert np.abs(averaged_mirrored[..., ::-1] - averaged).max() < 1e-5


@pytest.mark.parametrize("low, high", [(0.3, 0.5), (0.1, 0.9), (0.5, 0.5)])
def test_hysteresis_mask_is_skimages_hysteresis(low: float, high: float) -> None:
    rng = np.random.default_rng(11)
    for _ in range(5):  # smooth random fields: blobs and threads of every size, touching diagonally too
        field = cv2.GaussianBlur(rng.random((60, 80)).astype(np.float32), (0, 0), rng.uniform(0.5, 3))
        field = (field - field.min()) / (field.max() - field.min())
        expected = apply_hysteresis_threshold(field, low, high)
        assert 0 < expected.sum() < field.size
        assert np.array_equal(hysteresis_mask(field, low, high), expected)


def test_onnx_worker_threads_sleep_when_idle(random_checkpoint: Path) -> None:
    # spinning threads took the CPU of the other nodes on 2 cores (README, "Node graph latency")
    options = Segmenter(random_checkpoint, backend="onnx")._session.get_session_options()
    assert options.get_session_config_entry("session.intra_op.allow_spinning") == "0"


def test_masks_are_mono8_of_the_input_size(random_checkpoint: Path, pair) -> None:
    left, right = Segmenter(random_checkpoint, backend="torch").segment_pair(*pair)
    for mask in (left, right):
        assert mask.shape == (50, 70) and mask.dtype == np.uint8
        assert set(np.unique(mask)) <= {0, 255}
    grey = Segmenter(random_checkpoint, backend="torch", input_size=(32, 32)).segment([pair[0][..., 0]])
    assert grey[0].shape == (50, 70)


@pytest.mark.parametrize(
    ("images", "message"),
    [
        ([np.zeros((10, 10, 3), np.float32)], "dtype float32"),
        ([np.zeros((10, 10, 4), np.uint8)], "shape"),
        ([np.zeros((0, 0, 3), np.uint8)], "no pixels"),
        ([np.zeros((10, 10, 3), np.uint8), np.zeros((12, 10, 3), np.uint8)], "one size"),
        ([], "no images"),
    ],
)
def test_bad_images_raise_a_specific_error(random_checkpoint: Path, images, message: str) -> None:
    with pytest.raises(SegmentationInputError, match=message):
        Segmenter(random_checkpoint, backend="torch").segment(images)


def test_missing_or_corrupt_weights_raise_weights_error(tmp_path: Path) -> None:
    with pytest.raises(WeightsError, match="does not exist"):
        Segmenter(tmp_path / "missing.pt")
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(b"\x00garbage" * 100)
    for backend in ("torch", "onnx"):
        with pytest.raises(WeightsError, match="not a readable checkpoint"):
            Segmenter(corrupt, backend=backend)
    bad_onnx = tmp_path / "bad.onnx"
    bad_onnx.write_bytes(b"not onnx")
    with pytest.raises(WeightsError, match="not a loadable ONNX model"):
        Segmenter(bad_onnx)


def test_bad_options_are_refused(random_checkpoint: Path) -> None:
    with pytest.raises(ValueError, match="unknown backend"):
        Segmenter(random_checkpoint, backend="tensorrt")
    with pytest.raises(ValueError, match="threshold"):
        Segmenter(random_checkpoint, threshold=1.5)
    with pytest.raises(ValueError, match="input_size"):
        Segmenter(random_checkpoint, input_size=(8, 8))
    with pytest.raises(ValueError, match="unknown device"):
        Segmenter(random_checkpoint, device="tpu")
