# SPDX-License-Identifier: Apache-2.0
"""``suture-fewshot``: how many labelled images of a new camera the segmentation model needs.

The first step on a new camera is to label a few of its frames and fine-tune. This measures
the curve: for each count N, the base model fine-tuned on the first N labelled images
(sorted by name; :func:`suture_segmentation.train.finetune`, feature extractor frozen,
validated on those same N images) is run through the whole pipeline on held-out bags of that
camera by :func:`suture_bench.evaluate.evaluate` (masks predicted, sequences predicted), the
code of ``suture-eval``. N = 0 is the base model as given. Each row holds the segmentation
figures (IoU, precision, recall, centreline recall and precision, clDice), the grasps within
5 mm and their median error, the grasps produced and those more than 10 mm off::

    suture-fewshot --images DIR --masks DIR --test BAG [BAG ...] --counts 0,10,20,40 \\
        --base m_ost --out DIR [--epochs N --steps-per-epoch N ...]

``DIR/curve.md`` and ``DIR/curve.json`` hold the table, ``DIR/n<N>/`` each fine-tuned model
(``best.pt``, ``last.pt``, ``log.jsonl``); a rerun with the same base, labelled images and
training options evaluates the models already there (on other test bags, say) instead of
training them again. The labelled folders are in the format of
:mod:`suture_segmentation.data` (``suture-import --png-dir`` or ``suture-sim --png-dir``
write them); the test bags need true masks for the segmentation figures and a true grasp
pose for the grasp figures, and are scored on what they carry. Errors print one line on
stderr and exit with status 2.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

from suture_bench.evaluate import evaluate
from suture_bench.frames import EvaluationError, find_bags
from suture_segmentation.checkpoint import WeightsError, load_checkpoint
from suture_segmentation.cli import add_training_options, training_config
from suture_segmentation.data import DatasetError, load_folder
from suture_segmentation.train import TrainConfig, finetune

DEFAULT_COUNTS = (0, 10, 20, 40)
#: (key, column heading, format) of the table, in order; a figure that could not be measured is "n/a".
COLUMNS = (
    ("images", "labelled images", "{:d}"),
    ("iou", "IoU", "{:.3f}"),
    ("precision", "precision", "{:.3f}"),
    ("recall", "recall", "{:.3f}"),
    ("centreline_recall", "centreline recall", "{:.3f}"),
    ("centreline_precision", "centreline precision", "{:.3f}"),
    ("cldice", "clDice", "{:.3f}"),
    ("within_5mm", "grasps within 5 mm", "{:.1%}"),
    ("grasp_median_mm", "grasp median (mm)", "{:.2f}"),
    ("produced", "grasps produced", "{:d}"),
    ("beyond_10mm", "> 10 mm off", "{:d}"),
    ("finetune_s", "fine-tune (s)", "{:.0f}"),
)


def parse_counts(text: str) -> list[int]:
    """Sorted distinct counts from "0,10,20,40"; raises ValueError on anything else."""
    try:
        counts = sorted({int(item) for item in text.split(",")})
    except ValueError:
        raise ValueError(f"--counts must be comma-separated whole numbers, got {text!r}") from None
    if counts[0] < 0:
        raise ValueError(f"--counts must not be negative, got {text!r}")
    return counts


def curve_row(images: int, summary: dict[str, Any], finetune_s: float | None) -> dict[str, Any]:
    """One row of the curve from ``suture_bench.evaluate.evaluate``'s summary."""
    segmentation, grasp = summary["segmentation"], summary["grasp"]
    return {
        "images": images,
        **{key: segmentation.get(key) for key in ("iou", "precision", "recall")},
        **{key: segmentation.get(key) for key in ("centreline_recall", "centreline_precision", "cldice")},
        "within_5mm": grasp["within_5mm"],
        "grasp_median_mm": grasp["median_error_mm"],
        "produced": grasp["produced"],
        "beyond_10mm": grasp["beyond_10mm"],
        "frames": summary["frames"],
        "refused": grasp["refused"],
        "finetune_s": finetune_s,
    }


def fewshot_curve(
    images_dir: str | Path,
    masks_dir: str | Path,
    test_paths: Sequence[str | Path],
    counts: Sequence[int],
    base: str | Path,
    config: TrainConfig,
    out_dir: str | Path,
    device: str = "cpu",
    progress: bool = True,
) -> dict[str, Any]:
    """Fine-tune ``base`` on the first N labelled images for each N of ``counts`` and evaluate.

    Returns ``{"base", "images", "config", "test", "frames", "rows"}``; ``rows`` holds one
    :func:`curve_row` per count, in the order of ``counts``, with ``reused``: whether the model
    was already in ``out_dir/n<N>/`` (:func:`_same_finetune`). Models go to ``out_dir/n<N>/``.

    Raises:
        DatasetError: the labelled folders are unreadable or hold fewer images than a count.
        WeightsError: ``base`` cannot be loaded.
        EvaluationError: the test bags cannot be read.
    """
    find_bags(test_paths)  # a missing test bag fails now, not after the fine-tunes
    pool = load_folder(images_dir, masks_dir, limit=max(counts))
    if len(pool) < max(counts):
        raise DatasetError(
            f"{images_dir} holds {len(pool)} labelled images, fewer than the count {max(counts)}"
        )
    out_dir = Path(out_dir)
    rows = []
    for count in counts:
        weights, seconds, reused = str(base), None, False
        if count > 0:
            labelled = pool.subset(range(count))
            folder = out_dir / f"n{count}"
            reused = _same_finetune(folder, base, labelled.names, config)
            if not reused:
                meta = {"fewshot_images": labelled.names}
                finetune(base, labelled, labelled, config, folder, meta, device, progress)
            weights, seconds = str(folder / "best.pt"), _training_seconds(folder)
        summary = evaluate(test_paths, masks="predicted", sequences="predicted", seg_weights=weights)
        rows.append({**curve_row(count, summary, seconds), "reused": reused})
        if progress:
            print(markdown_row(rows[-1]), flush=True)
    return {
        "base": str(base),
        "images": [str(images_dir), str(masks_dir)],
        "config": asdict(config),
        "test": [str(path) for path in test_paths],
        "frames": rows[0]["frames"],
        "rows": rows,
    }


def _same_finetune(folder: Path, base: str | Path, names: list[str], config: TrainConfig) -> bool:
    """Whether ``folder/best.pt`` was fine-tuned from ``base`` on the images ``names`` with
    ``config``: then a rerun (on other test bags, say) evaluates it instead of training again."""
    if not (folder / "best.pt").is_file() or not (folder / "log.jsonl").is_file():
        return False
    _, meta = load_checkpoint(folder / "best.pt")
    wanted = (str(base), names, asdict(config))
    return (meta.get("finetuned_from"), meta.get("fewshot_images"), meta.get("config")) == wanted


def _training_seconds(folder: Path) -> float:
    """Seconds the fine-tune in ``folder`` trained (its log's last epoch)."""
    lines = (folder / "log.jsonl").read_text().splitlines()
    return float(json.loads(lines[-1])["elapsed_s"])


def markdown_row(row: dict[str, Any]) -> str:
    cells = ["n/a" if row[key] is None else fmt.format(row[key]) for key, _, fmt in COLUMNS]
    return "| " + " | ".join(cells) + " |"


def markdown_table(curve: dict[str, Any]) -> str:
    """The curve as a markdown table, one row per count."""
    lines = [
        "| " + " | ".join(heading for _, heading, _ in COLUMNS) + " |",
        "|" + "---|" * len(COLUMNS),
        *(markdown_row(row) for row in curve["rows"]),
    ]
    return "\n".join(lines)


def write_curve(curve: dict[str, Any], out_dir: str | Path) -> tuple[Path, Path]:
    """Write ``curve.json`` and ``curve.md`` (the command, the table, the setting) into ``out_dir``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    json_path, md_path = out_dir / "curve.json", out_dir / "curve.md"
    json_path.write_text(json.dumps(curve, indent=2) + "\n")
    config = curve["config"]
    reused_counts = [str(row["images"]) for row in curve["rows"] if row.get("reused")]
    reused = f" Models reused from an earlier run: N = {', '.join(reused_counts)}." if reused_counts else ""
    md_path.write_text(
        f"```bash\n{curve['command']}\n```\n\n{markdown_table(curve)}\n\n"
        f"Base model {curve['base']}; {curve['frames']} test frames ({', '.join(curve['test'])}); "
        f"fine-tuning {config['epochs']} epochs x {config['steps_per_epoch']} steps of "
        f"{config['batch_size']} crops of {config['crop']} px, loss {config['loss']}, "
        f"seed {config['seed']}. Grasps within 5 mm: share of all test frames (no grasp = miss). "
        f"Fine-tune (s): the training loop's time, all epochs.{reused}\n"
    )
    return json_path, md_path


def _build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="suture-fewshot",
        description="How many labelled images of a new camera the segmentation model needs: fine-tune "
        "on the first N for each N, evaluate each model on held-out bags, write the table.",
    )
    parser.add_argument("--images", required=True, help="labelled images of the new camera (the pool)")
    parser.add_argument("--masks", required=True, help="their masks (same file names)")
    parser.add_argument(
        "--test", required=True, nargs="+", metavar="BAG", help="held-out bags of the new camera"
    )
    parser.add_argument(
        "--counts",
        default=",".join(str(count) for count in DEFAULT_COUNTS),
        help="labelled images per point, comma-separated (default 0,10,20,40; 0 = the base model)",
    )
    parser.add_argument(
        "--base", default="m_ost", help="model to fine-tune: a .pt or a shipped name (default m_ost)"
    )
    parser.add_argument("--out", required=True, help="output folder: curve.md, curve.json, n<N>/best.pt")
    add_training_options(parser, epochs=10)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = _build_parser()
    args = parser.parse_args(argv)
    try:
        curve = fewshot_curve(
            args.images,
            args.masks,
            args.test,
            parse_counts(args.counts),
            args.base,
            training_config(args),
            args.out,
            args.device,
            progress=not args.quiet,
        )
        curve = {"command": "suture-fewshot " + shlex.join(argv), **curve}
        json_path, md_path = write_curve(curve, args.out)
    except (DatasetError, WeightsError, EvaluationError, ValueError, OSError) as error:
        print(f"suture-fewshot: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("suture-fewshot: interrupted", file=sys.stderr)
        return 130
    print(markdown_table(curve))
    print(f"suture-fewshot: {md_path}, {json_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
