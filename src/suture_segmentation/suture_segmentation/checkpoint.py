# SPDX-License-Identifier: Apache-2.0
"""Checkpoint files (.pt) and ONNX export of :class:`~suture_segmentation.model.SutureUNet`.

A checkpoint is a ``torch.save`` dict loaded with ``weights_only=True`` (no pickled code)::

    {"format": "suture-unet/1", "widths": [8, 16, 32, 48, 64], "half_resolution": False,
     "state_dict": {...}, "meta": {"command": "...", "seed": 0, "epochs": ..., ...}}

(``half_resolution`` absent: False, as in the checkpoints written before the variant existed.)

ONNX models take ``image`` (B, 3, H, W) float32 RGB in [0, 1] (H, W multiples of 32) and give
``logits`` (B, 2, H, W); batch, height and width are dynamic axes.
"""

from __future__ import annotations

import io
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch

from suture_segmentation.model import SutureUNet

FORMAT = "suture-unet/1"
#: The weights shipped with the package (docs/results.md gives the commands that made them); the
#: ``_int8`` ones are ONNX models (``suture-seg export --int8``), for the onnx backend only.
WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
SHIPPED = {
    "m_ost": WEIGHTS_DIR / "m_ost.pt",
    "m_tosot": WEIGHTS_DIR / "m_tosot.pt",
    "m_ost_int8": WEIGHTS_DIR / "m_ost_int8.onnx",
    "m_tosot_int8": WEIGHTS_DIR / "m_tosot_int8.onnx",
    # M-oST continued on the hard scenes (hooks at the cut end, wide instrument shafts, threads
    # along the rows) and the paper's five, in legacy and randomised looks: the legacy camera's
    # model where those scenes occur.
    "m_ost_hard": WEIGHTS_DIR / "m_ost_hard.pt",
    "m_ost_hard_int8": WEIGHTS_DIR / "m_ost_hard_int8.onnx",
    # M-oST continued on domain-randomised and legacy frames with augmentation: for a camera not
    # seen yet.
    "m_general": WEIGHTS_DIR / "m_general.pt",
    "m_general_int8": WEIGHTS_DIR / "m_general_int8.onnx",
    # M-oST fine-tuned every layer on 800 labelled on-site images (M-ToSOT has 40): the on-site
    # endoscope's default.
    "m_onsite": WEIGHTS_DIR / "m_onsite.pt",
    "m_onsite_int8": WEIGHTS_DIR / "m_onsite_int8.onnx",
    # m_onsite's half-resolution variant (model.py), trained on the same 800 images: as good on
    # site, about 0.6 of the time per pair. The on-site default.
    "m_onsite_half": WEIGHTS_DIR / "m_onsite_half.pt",
    "m_onsite_half_int8": WEIGHTS_DIR / "m_onsite_half_int8.onnx",
}
DEFAULT_WEIGHTS = SHIPPED["m_onsite_half"]
ONNX_OPSET = 17


class WeightsError(RuntimeError):
    """A weights file is missing, unreadable, corrupt or not a suture U-Net."""


def resolve_weights(weights: str | Path | None) -> Path:
    """Path of ``weights``: None is the shipped ``m_onsite_half``, a key of :data:`SHIPPED` a shipped
    model."""
    if weights is None or str(weights) == "":
        return DEFAULT_WEIGHTS
    if str(weights) in SHIPPED:
        return SHIPPED[str(weights)]
    return Path(weights).expanduser()


def save_checkpoint(model: SutureUNet, path: str | Path, meta: dict[str, Any] | None = None) -> Path:
    """Write ``model`` to ``path`` (parent folders created); returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().cpu().clone() for k, v in model.state_dict().items()}
    torch.save(
        {
            "format": FORMAT,
            "widths": list(model.widths),
            "half_resolution": model.half_resolution,
            "state_dict": state,
            "meta": meta or {},
        },
        path,
    )
    return path


def load_checkpoint(path: str | Path, device: str = "cpu") -> tuple[SutureUNet, dict[str, Any]]:
    """The model (in eval mode, on ``device``) and its metadata from a checkpoint file.

    ``path``: a .pt file, or a shipped model's name (``"m_ost"``, ``"m_onsite_half"``, ``"m_tosot"``,
    ``"m_general"``; :func:`resolve_weights`).

    Raises:
        WeightsError: missing file, not a torch file, wrong format or mismatching tensors.
    """
    path = resolve_weights(path)
    if not path.is_file():
        raise WeightsError(f"weights file {path} does not exist")
    if path.suffix == ".onnx":
        raise WeightsError(f"{path} is an ONNX model: run it with the onnx backend, or give a .pt checkpoint")
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # torch raises several types for corrupt files
        raise WeightsError(
            f"weights file {path} is not a readable checkpoint ({error.__class__.__name__})"
        ) from error
    if not isinstance(blob, dict) or blob.get("format") != FORMAT:
        raise WeightsError(f"{path} is not a suture U-Net checkpoint (expected format {FORMAT!r})")
    try:
        model = SutureUNet(blob["widths"], bool(blob.get("half_resolution", False)))
        model.load_state_dict(blob["state_dict"])
    except (KeyError, RuntimeError, ValueError, TypeError) as error:
        raise WeightsError(f"{path}: tensors do not match a suture U-Net ({error})") from error
    return model.to(device).eval(), dict(blob.get("meta", {}))


def copy_fitting_tensors(source: SutureUNet, target: SutureUNet) -> int:
    """Copy into ``target`` every tensor of ``source`` with the same name and shape; returns how many.

    Starts a half-resolution model from a full-resolution one: the layers from 4 on and the
    first three decoder stages fit (their resolution level differs, their shapes do not).
    """
    wanted = target.state_dict()
    fitting = {k: v for k, v in source.state_dict().items() if k in wanted and wanted[k].shape == v.shape}
    target.load_state_dict(fitting, strict=False)
    return len(fitting)


def onnx_bytes(model: SutureUNet) -> bytes:
    """The model as an ONNX protobuf (dynamic batch, height and width), see the module docstring."""
    model = model.to("cpu").eval()
    buffer = io.BytesIO()
    example = torch.zeros(1, 3, 64, 64)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the TorchScript-based exporter announces its deprecation
        torch.onnx.export(
            model,
            (example,),
            buffer,
            input_names=["image"],
            output_names=["logits"],
            dynamic_axes={
                "image": {0: "batch", 2: "height", 3: "width"},
                "logits": {0: "batch", 2: "height", 3: "width"},
            },
            opset_version=ONNX_OPSET,
            dynamo=False,
        )
    return buffer.getvalue()


def with_metadata(model: bytes, metadata: dict[str, str]) -> bytes:
    """The ONNX ``model`` with ``metadata`` added to its metadata_props (e.g. the export command)."""
    import onnx

    proto = onnx.load_from_string(model)
    onnx.helper.set_model_props(proto, {**{p.key: p.value for p in proto.metadata_props}, **metadata})
    return proto.SerializeToString()


def onnx_metadata(path: str | Path) -> dict[str, str]:
    """The metadata_props of an ONNX file (``suture-seg export`` records its command there)."""
    import onnx

    return {p.key: p.value for p in onnx.load(str(path), load_external_data=False).metadata_props}


def export_onnx(
    model: SutureUNet,
    path: str | Path,
    metadata: dict[str, str] | None = None,
    calibration: list[np.ndarray] | None = None,
) -> Path:
    """Write the ONNX model to ``path``; returns the path.

    ``metadata`` goes to the model's metadata_props (``suture-seg export`` records its command).
    With ``calibration`` images ((H, W, 3) uint8 RGB of the target camera) the model is
    quantised to int8 (:func:`suture_segmentation.quantize.quantized_onnx_bytes`).
    """
    if calibration is None:
        exported = onnx_bytes(model)
    else:
        from suture_segmentation.quantize import quantized_onnx_bytes  # it builds on onnx_bytes

        exported = quantized_onnx_bytes(model, calibration)
    if metadata:
        exported = with_metadata(exported, metadata)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(exported)
    return path
