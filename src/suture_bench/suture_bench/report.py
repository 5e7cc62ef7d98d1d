# SPDX-License-Identifier: Apache-2.0
"""A report folder of what the pipeline did on each frame of a bag, for ``suture-eval --report``
and ``suture-graph-report`` (one writer, so both show the same pictures and records)::

    OUT/summary.json         the evaluation summary (without its per-frame list)
    OUT/frames.json          every frame's record: stage results, refusal and its reason, figures
    OUT/frames/NNNN.json     the same, one file per frame (NNNN: the frame's index in the run)
    OUT/overlays/NNNN_<topology>.png
                             left image, the masks the ordering used (magenta), the sequence
                             from blue (cut tip) to red, the predicted grasp point (yellow ring)
                             and, where the bag has it, the true one (cyan cross)
    OUT/centreline_3d.png    reconstructed (red) against true (black, where known) 3D centrelines
                             of the first ten frames with a reconstruction
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import cv2
import numpy as np

from suture_bench.evaluate import StageOutputs
from suture_bench.frames import Frame
from suture_ordering.figures import draw_sequence

PANELS = 10


def draw_overlay(frame: Frame, outputs: StageOutputs, error_mm: float | None) -> np.ndarray:
    """(H, W, 3) uint8 RGB: the left image, the masks, the sequence and the grasp points."""
    canvas = np.ascontiguousarray(frame.left_image.copy())
    masks = outputs.masks if outputs.masks is not None else outputs.used_masks
    if masks is not None:
        mask = np.asarray(masks[0]) > 0
        canvas[mask] = (0.5 * canvas[mask] + 0.5 * np.array([255, 0, 255])).astype(np.uint8)
    if outputs.sequences is not None and len(outputs.sequences[0]) > 1:
        left = outputs.sequences[0]
        sequence = SimpleNamespace(points=left, bridged=np.zeros(len(left), bool), tip=left[0])
        canvas = draw_sequence(canvas, sequence)
    if frame.true_grasp is not None:
        true_uv = frame.camera.project(frame.true_grasp[None], "left")[0]
        if np.isfinite(true_uv).all():
            cross = tuple(round(float(x)) for x in true_uv)
            cv2.drawMarker(canvas, cross, (0, 255, 255), cv2.MARKER_CROSS, 14, 2)
    if outputs.grasp is not None:
        uv = frame.camera.project(np.asarray(outputs.grasp)[None], "left")[0]
        if np.isfinite(uv).all():
            cv2.circle(canvas, tuple(round(float(x)) for x in uv), 8, (255, 255, 0), 2, cv2.LINE_AA)
    if outputs.failure or outputs.not_run:
        status = outputs.failure or "not run"
    elif error_mm is not None:
        status = f"grasp error {error_mm:.2f} mm"
    else:
        status = "grasp produced" if outputs.grasp is not None else "no grasp"
    text = f"{frame.topology}  {status}"
    cv2.putText(canvas, text, (10, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 2, cv2.LINE_AA)
    return canvas


def plot_centrelines(panels: list[tuple[Frame, StageOutputs]], path: Path) -> None:
    """Reconstructed (red) and true (black) 3D centrelines of up to 10 frames, mm, camera frame."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = panels[:PANELS]
    columns = min(5, max(1, len(panels)))
    rows = max(1, -(-len(panels) // columns))
    figure = plt.figure(figsize=(3.2 * columns, 3.2 * rows))
    for index, (frame, outputs) in enumerate(panels):
        axes = figure.add_subplot(rows, columns, index + 1, projection="3d")
        shown = []
        if frame.true_path is not None:
            true = 1000 * frame.true_path
            axes.plot(true[:, 0], true[:, 1], true[:, 2], color="black", linewidth=1.5, label="true")
            shown.append(true)
            if frame.true_grasp is not None:
                axes.scatter(*(1000 * frame.true_grasp), color="black", s=20)
        if outputs.path is not None:
            ours = 1000 * np.asarray(outputs.path)
            axes.plot(ours[:, 0], ours[:, 1], ours[:, 2], color="red", linewidth=1, label="reconstructed")
            axes.scatter(*(1000 * np.asarray(outputs.grasp)), color="red", s=20)
            shown.append(ours)
        if shown:  # equal scale on all axes: depth errors look as large as they are, not stretched
            axes.set_box_aspect(np.maximum(np.ptp(np.vstack(shown), axis=0), 1.0))
        axes.set_title(frame.topology, fontsize=9)
        axes.invert_zaxis()
        axes.tick_params(labelsize=6)
        axes.zaxis.set_major_locator(plt.MaxNLocator(2))
        if index == 0:
            axes.legend(fontsize=7, loc="upper left")
    figure.suptitle("3D centreline, left camera frame (mm): reconstructed (red) vs true (black)", fontsize=10)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


class ReportWriter:
    """Writes the report folder frame by frame: :meth:`add` each frame, then :meth:`finish`."""

    def __init__(self, out: str | Path, max_overlays: int = 20) -> None:
        self.out = Path(out)
        self.max_overlays = max_overlays
        try:
            (self.out / "overlays").mkdir(parents=True, exist_ok=True)
            (self.out / "frames").mkdir(exist_ok=True)
        except OSError as error:
            raise OSError(f"cannot create the report folder {self.out}: {error.strerror or error}") from error
        self.records: list[dict[str, Any]] = []
        self.panels: list[tuple[Frame, StageOutputs]] = []

    def add(self, frame: Frame, outputs: StageOutputs, record: dict[str, Any]) -> None:
        """Write one frame's JSON and, for the first ``max_overlays`` frames with images, its overlay."""
        index = len(self.records)
        record = {"index": index, **record, "latency_ms": outputs.latency_ms}
        self.records.append(record)
        (self.out / "frames" / f"{index:04d}.json").write_text(json.dumps(record, indent=1))
        if index < self.max_overlays and frame.left_image is not None:
            picture = draw_overlay(frame, outputs, record.get("grasp_error_mm"))
            name = f"{index:04d}_{frame.topology}.png"
            cv2.imwrite(str(self.out / "overlays" / name), cv2.cvtColor(picture, cv2.COLOR_RGB2BGR))
        if outputs.path is not None and len(self.panels) < PANELS:
            self.panels.append((frame, outputs))

    def finish(self, summary: dict[str, Any]) -> None:
        """Write summary.json, frames.json and the 3D plot (when a frame was reconstructed)."""
        kept = {k: v for k, v in summary.items() if k != "per_frame"}
        (self.out / "summary.json").write_text(json.dumps(kept, indent=2))
        (self.out / "frames.json").write_text(json.dumps(self.records, indent=2))
        if self.panels:
            plot_centrelines(self.panels, self.out / "centreline_3d.png")
