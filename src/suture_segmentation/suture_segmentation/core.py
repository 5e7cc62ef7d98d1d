# SPDX-License-Identifier: Apache-2.0
"""Inference: suture masks from camera images, with a PyTorch or an ONNX Runtime backend.

This is the ROS-free entry point that ``segmentation_node`` and ``suture-eval`` both call.

* :class:`Segmenter` holds one loaded model; :meth:`Segmenter.segment_pair` runs a stereo pair
  as one batch (of four by default: each view and its mirror image, whose probabilities are
  averaged); :meth:`Segmenter.segment_pair_with_low` also gives the pair's low masks
  (hysteresis down to ``low_threshold``), which the node graph publishes for the ordering stage.
* :func:`segment_stereo` is the same with the shipped on-site model ``m_onsite_half`` (its int8 export
  on ONNX Runtime, CPU), loaded once per process.

Images are (H, W, 3) uint8 RGB or (H, W) uint8 grey; masks are (H, W) uint8, 0 or 255. Both
backends give the same masks up to pixels whose suture probability is within about 1e-4 of
the threshold (float rounding differences between the two runtimes).
"""

from __future__ import annotations

import functools
from pathlib import Path

import cv2
import numpy as np
import torch
from torch.nn import functional

from suture_segmentation.checkpoint import WeightsError, load_checkpoint, onnx_bytes, resolve_weights
from suture_segmentation.model import BACKGROUND, STRIDE, SUTURE, pad_to_multiple, suture_probability

BACKENDS = ("onnx", "torch")
#: Default lower threshold of the low masks (:meth:`Segmenter.segment_pair_with_low`): where a
#: faint thread's probability stays between it and the mask threshold, the low mask keeps the
#: thread whole. It serves the low masks only: as the mask threshold itself it would widen every
#: mask and move the centrelines traced on them.
LOW_THRESHOLD = 0.3
#: The shipped on-site model that ``weights=None`` loads on ONNX Runtime on the CPU: its int8 export,
#: faster than the float model on CPUs with int8 dot-product instructions (quantize.py).
DEFAULT_CPU_WEIGHTS = "m_onsite_half_int8"


class SegmentationInputError(ValueError):
    """An image cannot be segmented (wrong dtype or shape, empty, left/right sizes differ)."""


class StereoSizeMismatchError(SegmentationInputError):
    """The left and right images of a stereo pair differ in size."""


class Segmenter:
    """A loaded suture U-Net that turns camera images into thread masks.

    Parameters
    ----------
    weights : str or pathlib.Path, optional
        A ``.pt`` checkpoint (``suture-seg train|finetune`` writes them), an ``.onnx`` file
        (``suture-seg export [--int8]``; ONNX backend only), ``"m_ost"``/``"m_ost_hard"``/
        ``"m_onsite_half"``/``"m_onsite"``/``"m_tosot"``/``"m_general"`` (or their int8 ONNX
        exports, ``"m_ost_int8"`` ...) for a shipped model, or None for the shipped on-site model
        ``m_onsite_half``: its int8 export with the ONNX backend on the CPU (``suture-seg bench``
        times it on yours), the float model otherwise.
    backend : {"onnx", "torch"}
        ONNX Runtime or PyTorch.
    device : str
        ``"cpu"`` or ``"cuda"`` (``"cuda:1"`` ...); ONNX on CUDA needs onnxruntime-gpu.
    threshold : float
        Suture probability above which a pixel is suture, in (0, 1).
    input_size : (int, int), optional
        (width, height) in px to resize images to before inference (masks are resized back);
        None runs at the image's own size. Smaller is faster, thin threads suffer.
    threads : int, optional
        CPU threads of the backend; None: the runtime's default.
    low_threshold : float, optional
        The lower threshold of the *low masks* (:meth:`segment_pair_with_low`): pixels above it
        that connect to a pixel above ``threshold`` (hysteresis), in (0, threshold]; None: no
        low masks.
    flip_average : bool
        Average the suture probability of each image with that of its mirror image (flipped
        left to right, run in the same batch, flipped back). It about doubles the inference
        time; the model's errors on a noisy camera differ between the two, and fewer survive
        the average: fewer broken threads and false positives (``docs/results.md``).

    Raises
    ------
    WeightsError
        The weights cannot be loaded.
    ValueError
        Unknown backend or device, a threshold outside its range, a bad input size.

    Notes
    -----
    Images are (H, W, 3) uint8 RGB or (H, W) uint8 grey; masks are (H, W) uint8, 0 or 255, of
    the image's size. Bad images raise :class:`SegmentationInputError`.

    Examples
    --------
    A dark thread 2 px wide drawn on reddish tissue, segmented by the shipped model on the CPU:

    >>> import cv2
    >>> import numpy as np
    >>> from suture_segmentation.core import Segmenter
    >>> segmenter = Segmenter(threads=1)
    >>> image = np.full((96, 128, 3), (170, 90, 90), np.uint8)
    >>> thread = np.array([[10, 20], [60, 50], [118, 70]], np.int32)
    >>> _ = cv2.polylines(image, [thread], False, (40, 30, 120), 2)
    >>> left_mask, right_mask = segmenter.segment_pair(image, image)
    >>> left_mask.shape, left_mask.dtype, np.unique(left_mask).tolist()
    ((96, 128), dtype('uint8'), [0, 255])
    >>> drawn = np.zeros((96, 128), np.uint8)
    >>> _ = cv2.polylines(drawn, [thread], False, 255, 2)
    >>> bool((left_mask[drawn > 0] == 255).mean() > 0.8)
    True
    """

    def __init__(
        self,
        weights: str | Path | None = None,
        backend: str = "onnx",
        device: str = "cpu",
        threshold: float = 0.5,
        input_size: tuple[int, int] | None = None,
        threads: int | None = None,
        low_threshold: float | None = LOW_THRESHOLD,
        flip_average: bool = True,
    ) -> None:
        if backend not in BACKENDS:
            raise ValueError(f"unknown backend {backend!r}; choose {' or '.join(BACKENDS)}")
        if not 0.0 < threshold < 1.0:
            raise ValueError(f"threshold must be in (0, 1), got {threshold}")
        if low_threshold is not None and not 0.0 < low_threshold <= threshold:
            raise ValueError(f"low_threshold must be in (0, threshold={threshold}], got {low_threshold}")
        if input_size is not None and (len(input_size) != 2 or min(input_size) < STRIDE):
            raise ValueError(f"input_size must be (width, height) of at least {STRIDE} px, got {input_size}")
        if not (device == "cpu" or device.startswith("cuda")):
            raise ValueError(f"unknown device {device!r}; use cpu or cuda[:N]")
        if device.startswith("cuda") and backend == "torch" and not torch.cuda.is_available():
            raise ValueError("device cuda requested but torch sees no CUDA GPU")
        self.backend, self.device, self.threshold = backend, device, float(threshold)
        self.low_threshold = None if low_threshold is None else float(low_threshold)
        self.flip_average = bool(flip_average)
        self.input_size = tuple(int(v) for v in input_size) if input_size is not None else None
        if not weights and backend == "onnx" and device == "cpu":
            weights = DEFAULT_CPU_WEIGHTS
        self.weights = resolve_weights(weights)
        if backend == "torch":
            if threads:
                torch.set_num_threads(threads)
            self._model, self.meta = load_checkpoint(self.weights, device)
        else:
            self._session = self._onnx_session(threads)

    def _onnx_session(self, threads: int | None):  # -> onnxruntime.InferenceSession
        import onnxruntime

        if self.weights.suffix == ".onnx":
            if not self.weights.is_file():
                raise WeightsError(f"weights file {self.weights} does not exist")
            model: bytes | str = str(self.weights)
            self.meta = {}
        else:
            torch_model, self.meta = load_checkpoint(self.weights)
            model = onnx_bytes(torch_model)
        options = onnxruntime.SessionOptions()
        # Idle worker threads sleep instead of spinning: on a few cores, spinning ones take CPU
        # from the other nodes and from the next run itself (docs/results.md, "Node graph latency").
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")
        if threads:
            options.intra_op_num_threads = threads
        providers = ["CPUExecutionProvider"]
        if self.device.startswith("cuda"):
            if "CUDAExecutionProvider" not in onnxruntime.get_available_providers():
                raise ValueError("device cuda with the onnx backend needs onnxruntime-gpu")
            index = int(self.device.split(":")[1]) if ":" in self.device else 0
            providers = [("CUDAExecutionProvider", {"device_id": index}), "CPUExecutionProvider"]
        try:
            return onnxruntime.InferenceSession(model, options, providers=providers)
        except Exception as error:  # onnxruntime raises its own Fail/InvalidProtobuf types
            raise WeightsError(f"{self.weights} is not a loadable ONNX model ({error})") from error

    def probabilities(self, images: list[np.ndarray]) -> np.ndarray:
        """(B, H, W) float32 suture probability of equally sized images (one batch; with
        ``flip_average`` the mean of each image's and its mirror image's)."""
        batch = image_array(images)
        if not self.flip_average:
            return self._batch_probabilities(batch)
        count = len(batch)
        suture = self._batch_probabilities(np.concatenate([batch, batch[..., ::-1]]))
        return (suture[:count] + suture[count:, :, ::-1]) * np.float32(0.5)

    def _batch_probabilities(self, batch: np.ndarray) -> np.ndarray:
        """(B, H, W) float32 suture probability of a (B, 3, H, W) float32 batch."""
        if self.backend == "onnx" and self.input_size is None:
            return self._onnx_probabilities(batch)
        tensor = torch.from_numpy(batch)
        height, width = tensor.shape[-2:]
        if self.input_size is not None and (width, height) != self.input_size:
            tensor = functional.interpolate(
                tensor, size=self.input_size[::-1], mode="bilinear", align_corners=False
            )
        if self.backend == "torch":
            suture = suture_probability(self._model, tensor.to(self.device)).cpu()
        else:
            padded, (h, w) = pad_to_multiple(tensor)
            (logits,) = self._session.run(["logits"], {"image": padded.numpy()})
            suture = torch.softmax(torch.from_numpy(logits), dim=1)[:, SUTURE, :h, :w]
        if suture.shape[-2:] != (height, width):
            suture = functional.interpolate(suture[:, None], size=(height, width), mode="bilinear")[:, 0]
        return suture.numpy()

    def _onnx_probabilities(self, batch: np.ndarray) -> np.ndarray:
        """ONNX Runtime on a (B, 3, H, W) batch with numpy around it, not torch: torch's OpenMP
        workers spin after each frame's few milliseconds of pre- and post-processing, beside the
        runtime's own threads (10 % of a core in the node graph at 5 frames/s)."""
        height, width = batch.shape[-2:]
        padded, _ = pad_to_multiple(torch.from_numpy(batch))  # no torch work where none is needed
        (logits,) = self._session.run(["logits"], {"image": padded.numpy()})
        # the two-class softmax of the suture class, 1 / (1 + exp(l_background - l_suture)), in
        # place; far from the boundary exp overflows to inf and the probability is 0
        margin = logits[:, BACKGROUND, :height, :width] - logits[:, SUTURE, :height, :width]
        with np.errstate(over="ignore"):
            np.exp(margin, out=margin)
        margin += np.float32(1.0)
        return np.reciprocal(margin, out=margin).astype(np.float32, copy=False)

    def segment(self, images: list[np.ndarray]) -> list[np.ndarray]:
        """(H, W) uint8 masks (0 or 255) of equally sized images, run as one batch."""
        return [_as_mask(p > self.threshold) for p in self.probabilities(images)]

    def segment_pair(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(H, W) uint8 masks (0 or 255) of a stereo pair, run as one batch of two.

        Raises
        ------
        StereoSizeMismatchError
            Left and right differ in size.
        SegmentationInputError
            An image cannot be segmented.
        """
        _check_same_size(left, right)
        left_mask, right_mask = self.segment([left, right])
        return left_mask, right_mask

    def segment_pair_with_low(
        self, left: np.ndarray, right: np.ndarray
    ) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray] | None]:
        """The masks of a stereo pair and its *low masks* (one batch of two).

        A low mask adds to the mask the pixels above ``low_threshold`` connected to it
        (hysteresis, :func:`hysteresis_mask`): where the thread is
        faint the model's probability often stays between the two thresholds, and the mask
        breaks there. The ordering stage takes the low masks' sequences when they reach
        farther (:func:`suture_ordering.order_stereo`). Both are (H, W) uint8, 0 or 255; the
        low masks are None when ``low_threshold`` is None.

        Raises
        ------
        StereoSizeMismatchError, SegmentationInputError
            As :meth:`segment_pair`.
        """
        _check_same_size(left, right)
        probability = self.probabilities([left, right])
        masks = [_as_mask(p > self.threshold) for p in probability]
        if self.low_threshold is None:
            return (masks[0], masks[1]), None
        low = [hysteresis_mask(p, self.low_threshold, self.threshold) for p in probability]
        return (masks[0], masks[1]), (_as_mask(low[0]), _as_mask(low[1]))


def hysteresis_mask(probability: np.ndarray, low: float, high: float) -> np.ndarray:
    """(H, W) bool: the pixels of ``probability`` (H, W) above ``low`` whose 4-connected region
    of such pixels holds one above ``high``; the same as
    :func:`skimage.filters.apply_hysteresis_threshold`, a few times faster."""
    count, labels = cv2.connectedComponents((probability > low).astype(np.uint8), connectivity=4)
    keep = np.zeros(count, dtype=bool)
    keep[labels[probability > high]] = True
    keep[0] = False
    return keep[labels]


def _as_mask(thread: np.ndarray) -> np.ndarray:
    """(H, W) uint8 0/255 mask of a boolean array."""
    return np.where(thread, 255, 0).astype(np.uint8)


def _check_same_size(left: np.ndarray, right: np.ndarray) -> None:
    left_size, right_size = np.shape(left)[1::-1], np.shape(right)[1::-1]
    if left_size != right_size:
        raise StereoSizeMismatchError(
            f"left image is {left_size[0]}x{left_size[1]} but right image is {right_size[0]}x{right_size[1]}"
        )


def image_batch(images: list[np.ndarray]) -> torch.Tensor:
    """:func:`image_array` as a torch tensor (the torch backend, training, calibration)."""
    return torch.from_numpy(image_array(images))


def image_array(images: list[np.ndarray]) -> np.ndarray:
    """(B, 3, H, W) float32 in [0, 1] from uint8 RGB or grey images; raises SegmentationInputError."""
    if not images:
        raise SegmentationInputError("no images to segment")
    arrays = []
    for k, image in enumerate(images):
        image = np.asarray(image)
        if image.dtype != np.uint8:
            raise SegmentationInputError(f"image {k} has dtype {image.dtype}; expected uint8")
        if image.ndim == 2:
            image = np.repeat(image[..., None], 3, axis=2)
        if image.ndim != 3 or image.shape[2] != 3:
            raise SegmentationInputError(
                f"image {k} has shape {image.shape}; expected (H, W, 3) RGB or (H, W) grey"
            )
        if image.shape[0] == 0 or image.shape[1] == 0:
            raise SegmentationInputError(f"image {k} has no pixels ({image.shape[1]}x{image.shape[0]})")
        arrays.append(image)
    if any(a.shape != arrays[0].shape for a in arrays):
        sizes = ", ".join(f"{a.shape[1]}x{a.shape[0]}" for a in arrays)
        raise SegmentationInputError(f"images of one batch must have one size, got {sizes}")
    batch = np.ascontiguousarray(np.stack(arrays).transpose(0, 3, 1, 2), dtype=np.float32)
    batch /= np.float32(255.0)
    return batch


@functools.cache
def default_segmenter() -> Segmenter:
    """The process-wide segmenter with the shipped ``m_onsite_half`` weights (ONNX Runtime, CPU)."""
    return Segmenter()


def segment_stereo(left_image: np.ndarray, right_image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Masks of a stereo pair with the shipped ``m_onsite_half`` model; see :class:`Segmenter`."""
    return default_segmenter().segment_pair(left_image, right_image)
