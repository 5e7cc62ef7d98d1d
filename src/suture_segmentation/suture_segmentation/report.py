# SPDX-License-Identifier: Apache-2.0
"""Table I / Fig. 5 reproduction and the inference benchmark behind ``suture-seg evaluate|bench``.

* :func:`evaluate_models` scores several checkpoints on several labelled test sets, per image;
* :func:`markdown_table` renders the paper's Table I layout (mean IoU, precision, recall, F1 per
  set and model);
* :func:`write_report` writes ``table.md``, ``scores.json``, ``per_image.png`` (per-image IoU and
  F1 of every model, like Fig. 5(a)) and ``overlays_<set>.png`` (typical results, like Fig. 5(b):
  true positives green, false positives red, missed suture blue);
* :func:`benchmark` times :class:`~suture_segmentation.core.Segmenter` on a stereo pair.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from suture_segmentation.checkpoint import resolve_weights
from suture_segmentation.core import Segmenter
from suture_segmentation.data import LabelledImages
from suture_segmentation.metrics import MaskScores, mean_scores, score_mask

#: The paper's Table I (percent): set -> model -> metric.
PAPER_TABLE_I: dict[str, dict[str, dict[str, float]]] = {
    "Set 1": {
        "M-oST": {"iou": 55.8, "precision": 84.6, "recall": 61.8},
        "M-TOT": {"iou": 62.9, "precision": 63.2, "recall": 96.2},
        "M-ToSOT": {"iou": 71.1, "precision": 72.5, "recall": 97.3},
    },
    "Set 2": {
        "M-oST": {"iou": 59.8},
        "M-TOT": {"iou": 60.8},
        "M-ToSOT": {"iou": 72.1},
    },
}

METRICS = ("iou", "precision", "recall", "f1", "centreline_recall", "centreline_precision", "cldice")
_LABELS = {
    "iou": "IoU",
    "precision": "Precision",
    "recall": "Recall",
    "f1": "F1",
    "centreline_recall": "Centreline recall",
    "centreline_precision": "Centreline precision",
    "cldice": "clDice",
}

#: results[set][model] = per-image scores, in the set's file-name order.
Results = dict[str, dict[str, list[MaskScores]]]


def evaluate_models(
    models: dict[str, str | Path],
    sets: dict[str, LabelledImages],
    threshold: float = 0.5,
    flip_average: bool = True,
) -> Results:
    """Per-image scores of every model (name -> weights) on every set (name -> images).

    ``threshold`` and ``flip_average`` as in :class:`Segmenter` (its defaults: what the node
    publishes).
    """
    results: Results = {name: {} for name in sets}
    for model_name, weights in models.items():
        segmenter = scoring_segmenter(weights, threshold, flip_average)
        for set_name, data in sets.items():
            results[set_name][model_name] = [
                score_mask(segmenter.segment([image])[0], mask)
                for image, mask in zip(data.images, data.masks, strict=True)
            ]
    return results


def scoring_segmenter(weights: str | Path, threshold: float, flip_average: bool = True) -> Segmenter:
    """PyTorch for a checkpoint (the reference), ONNX Runtime for an ``.onnx`` file (e.g. int8)."""
    backend = "onnx" if resolve_weights(weights).suffix == ".onnx" else "torch"
    return Segmenter(weights, backend=backend, threshold=threshold, flip_average=flip_average)


def markdown_table(results: Results) -> str:
    """Table I layout: one row per set and metric, one column per model (means, percent)."""
    models = list(next(iter(results.values())))
    lines = ["| set | metric | " + " | ".join(models) + " |", "|---|---|" + "---:|" * len(models)]
    for set_name, by_model in results.items():
        means = {m: mean_scores(scores) for m, scores in by_model.items()}
        for metric in METRICS:
            values = [getattr(means[m], metric) for m in models]
            if any(v is None for v in values):
                continue
            best = int(np.argmax(values))
            cells = [f"**{100 * v:.1f}**" if k == best else f"{100 * v:.1f}" for k, v in enumerate(values)]
            lines.append(f"| {set_name} | {_LABELS[metric]} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def paper_table() -> str:
    """The paper's Table I in the same layout (percent; '-' where the paper gives no figure)."""
    models = ["M-oST", "M-TOT", "M-ToSOT"]
    lines = ["| set | metric | " + " | ".join(models) + " |", "|---|---|" + "---:|" * len(models)]
    for set_name, by_model in PAPER_TABLE_I.items():
        for metric in ("iou", "precision", "recall"):
            cells = [f"{by_model[m][metric]:.1f}" if metric in by_model[m] else "-" for m in models]
            lines.append(f"| {set_name} | {_LABELS[metric]} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_report(
    results: Results,
    sets: dict[str, LabelledImages],
    folder: str | Path,
    models: dict[str, str | Path] | None = None,
    threshold: float = 0.5,
    flip_average: bool = True,
) -> str:
    """Write table.md, scores.json, per_image.png and (with ``models``) one overlays PNG per set.

    The overlays show the two images of median IoU of the last model: typical results.
    Returns the table.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    table = markdown_table(results)
    (folder / "table.md").write_text(
        "# Suture segmentation (mean over images, percent)\n\n"
        + table
        + "\n\n## Paper, Table I\n\n"
        + paper_table()
        + "\n"
    )
    scores = {
        set_name: {
            model: {
                "mean": mean_scores(per_image).as_dict(),
                "per_image": {n: s.as_dict() for n, s in zip(sets[set_name].names, per_image, strict=True)},
            }
            for model, per_image in by_model.items()
        }
        for set_name, by_model in results.items()
    }
    (folder / "scores.json").write_text(json.dumps(scores, indent=1))
    _plot_per_image(results, folder / "per_image.png")
    if models:
        last = list(models)[-1]
        for set_name, data in sets.items():
            order = np.argsort([s.iou for s in results[set_name][last]])
            middle = len(order) // 2
            typical = sorted({int(order[middle]), int(order[max(middle - 1, 0)])})
            slug = set_name.lower().replace(" ", "")
            write_overlays(models, data, typical, folder / f"overlays_{slug}.png", threshold, flip_average)
    return table


def _plot_per_image(results: Results, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot

    figure, axes = pyplot.subplots(
        2, len(results), figsize=(5.5 * len(results), 6), squeeze=False, sharey=True
    )
    for column, (set_name, by_model) in enumerate(results.items()):
        for row, metric in enumerate(("iou", "f1")):
            axis = axes[row, column]
            for model, per_image in by_model.items():
                values = [getattr(s, metric) for s in per_image]
                axis.plot(
                    np.arange(1, len(values) + 1), values, marker="o", markersize=3, linewidth=1, label=model
                )
            axis.set_title(f"{set_name}: {_LABELS[metric]} per image")
            axis.set_xlabel("test image")
            axis.set_ylim(0, 1)
            axis.grid(alpha=0.3)
    axes[0, 0].legend(loc="lower left")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    pyplot.close(figure)


def overlay(image: np.ndarray, predicted: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 RGB: true positives green, false positives red, missed suture blue."""
    out = (0.6 * image).astype(np.uint8)
    predicted, truth = predicted > 0, truth > 0
    out[predicted & truth] = (40, 230, 40)
    out[predicted & ~truth] = (255, 40, 40)
    out[~predicted & truth] = (60, 120, 255)
    return out


def write_overlays(
    models: dict[str, str | Path],
    data: LabelledImages,
    indices: list[int],
    path: str | Path,
    threshold: float = 0.5,
    flip_average: bool = True,
) -> Path:
    """A grid (rows: images, columns: input then each model) of :func:`overlay` images."""
    segmenters = {name: scoring_segmenter(w, threshold, flip_average) for name, w in models.items()}
    rows = []
    for i in indices:
        tiles = [data.images[i]]
        for name, segmenter in segmenters.items():
            tile = overlay(data.images[i], segmenter.segment([data.images[i]])[0], data.masks[i])
            cv2.putText(tile, name, (8, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (255, 255, 255), 2)
            tiles.append(tile)
        rows.append(np.hstack(tiles))
    grid = np.vstack(rows)
    path = Path(path)
    cv2.imwrite(str(path), cv2.cvtColor(grid, cv2.COLOR_RGB2BGR))
    return path


def benchmark(
    weights: str | Path | None,
    backend: str,
    device: str,
    resolution: tuple[int, int],
    pairs: int,
    threads: int | None = None,
    flip_average: bool = True,
) -> dict[str, Any]:
    """Median and 95th-percentile milliseconds per stereo pair after warm-up: the masks and low
    masks, as segmentation_node makes them (one batch: the two views, and with ``flip_average``
    their mirror images)."""
    import torch

    segmenter = Segmenter(weights, backend=backend, device=device, threads=threads, flip_average=flip_average)
    width, height = resolution
    rng = np.random.default_rng(0)
    left = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
    right = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
    for _ in range(3):
        segmenter.segment_pair_with_low(left, right)
    times = []
    for _ in range(pairs):
        start = time.perf_counter()
        segmenter.segment_pair_with_low(left, right)
        if device.startswith("cuda") and backend == "torch":
            torch.cuda.synchronize()
        times.append(1000 * (time.perf_counter() - start))
    return {
        "median_ms": float(np.median(times)),
        "p95_ms": float(np.percentile(times, 95)),
        "pairs": pairs,
        "weights": segmenter.weights.name,
        "threads": threads or (torch.get_num_threads() if backend == "torch" else "default"),
    }
