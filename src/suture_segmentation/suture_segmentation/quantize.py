# SPDX-License-Identifier: Apache-2.0
"""Int8 ONNX models: the suture U-Net quantised for faster CPU inference (``suture-seg export --int8``).

Static quantisation with ONNX Runtime in the QDQ format: weights int8 per output channel in 7
bits (-64..64, ``reduce_range``), activations uint8 with ranges calibrated (min/max) on sample
images of the camera the model will see. The model keeps the interface of
:func:`~suture_segmentation.checkpoint.onnx_bytes` (``image`` in, ``logits`` out), so
``segmentation_node`` and ``suture-eval`` run it as any other ``.onnx`` weights file with the
``onnx`` backend.

The 7 bits keep the integer arithmetic exact on every x86 CPU. Without int8 dot-product
instructions (VNNI: AMD before Zen 4, Intel before Cascade Lake) ONNX Runtime multiplies uint8
by int8 with ``VPMADDUBSW``, which saturates the sum of each pair of products at 16 bits:
255 * 127 * 2 overflows it, 255 * 64 * 2 does not. With full-range weights such a CPU loses
most of the thread (docs/results.md, "Int8 models on CPUs without VNNI").

On a CPU with int8 dot-product instructions (AVX-512 VNNI, AVX-VNNI) the earlier export with
8-bit weights ran about a fifth faster than float32 (docs/results.md, "Segmentation speed"); the
7-bit models' masks agree with the float32 ones to a mean IoU of 0.91-0.95 over the test's frames.
Without those instructions int8 need not be faster (on an AMD EPYC: 321 against 293 ms per
pair): measure with ``suture-seg bench --weights FILE.onnx --backends onnx``.
"""

from __future__ import annotations

import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from suture_segmentation.checkpoint import onnx_bytes
from suture_segmentation.core import image_batch
from suture_segmentation.data import DatasetError, image_files, read_rgb
from suture_segmentation.model import SutureUNet, pad_to_multiple


def calibration_images(folder: str | Path, count: int = 16) -> list[np.ndarray]:
    """``count`` images spread evenly over the sorted image files of ``folder``, (H, W, 3) uint8 RGB.

    Raises DatasetError if ``folder`` is not a folder of images or ``count`` is below 1.
    """
    if count < 1:
        raise DatasetError(f"the calibration needs at least one image, got count {count}")
    paths = image_files(folder)
    picks = np.unique(np.linspace(0, len(paths) - 1, min(count, len(paths))).round().astype(int))
    return [read_rgb(paths[i]) for i in picks]


def quantized_onnx_bytes(model: SutureUNet, images: Sequence[np.ndarray]) -> bytes:
    """The int8 ONNX model of ``model``, its activation ranges calibrated on ``images``.

    ``images``: (H, W, 3) uint8 RGB frames of the target camera (sizes may differ); each is run
    as a batch of one, padded as :class:`~suture_segmentation.core.Segmenter` pads.
    """
    from onnxruntime.quantization import (
        CalibrationDataReader,
        CalibrationMethod,
        QuantFormat,
        QuantType,
        quantize_static,
    )
    from onnxruntime.quantization.shape_inference import quant_pre_process

    if not images:
        raise DatasetError("the calibration needs at least one image")
    batches = [{"image": pad_to_multiple(image_batch([image]))[0].numpy()} for image in images]

    class Batches(CalibrationDataReader):
        def __init__(self) -> None:
            self._batches = iter(batches)

        def get_next(self) -> dict[str, np.ndarray] | None:
            return next(self._batches, None)

    with tempfile.TemporaryDirectory() as folder:
        float_model, prepared, quantized = (Path(folder) / n for n in ("float.onnx", "pre.onnx", "int8.onnx"))
        float_model.write_bytes(onnx_bytes(model))
        # The shapes are dynamic (batch, height, width), so symbolic inference cannot complete.
        quant_pre_process(str(float_model), str(prepared), skip_symbolic_shape=True)
        quantize_static(
            str(prepared),
            str(quantized),
            Batches(),
            quant_format=QuantFormat.QDQ,
            per_channel=True,
            reduce_range=True,  # 7-bit weights: no 16-bit saturation without VNNI (module docstring)
            activation_type=QuantType.QUInt8,
            weight_type=QuantType.QInt8,
            calibrate_method=CalibrationMethod.MinMax,
        )
        return quantized.read_bytes()
