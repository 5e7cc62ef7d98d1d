# SPDX-License-Identifier: Apache-2.0
"""``suture-seg``: train, fine-tune, evaluate, export and benchmark the suture U-Net.

Sub-commands::

    suture-seg train     --images DIR --masks DIR --out DIR [--val-images DIR --val-masks DIR] ...
    suture-seg finetune  --weights PT --images DIR --masks DIR --out DIR [--all-layers] ...
    suture-seg evaluate  --weights PT[,PT...] --images DIR --masks DIR [--report DIR] ...
    suture-seg export    --weights PT --out FILE.onnx [--int8 --calibration-images DIR]
    suture-seg bench     [--weights PT] [--backends onnx,torch] [--device cpu|cuda] ...

Folders are in the format of :mod:`suture_segmentation.data` (``images/`` and ``masks/`` with the
same file names; masks 0 = background, 255 = suture), which is what ``suture-sim --png-dir``
writes. Errors print one line on stderr and exit with status 2.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from suture_segmentation.checkpoint import WeightsError

DEFAULT_EPOCHS = {"train": 20, "finetune": 10}
NO_FLIP_AVERAGE_HELP = (
    "segment each image alone, not averaged with its mirror image (segmentation_node's flip_average false)"
)


def _training_arguments(parser: argparse.ArgumentParser, command: str) -> None:
    parser.add_argument("--images", required=True, help="folder of training images")
    parser.add_argument("--masks", required=True, help="folder of their masks (same file names)")
    parser.add_argument("--val-images", help="validation images (default: the training images)")
    parser.add_argument("--val-masks", help="validation masks")
    parser.add_argument("--limit", type=int, help="use only the first N training images (sorted by name)")
    parser.add_argument("--out", required=True, help="output folder: best.pt, last.pt, log.jsonl")
    add_training_options(parser, DEFAULT_EPOCHS[command])


def add_training_options(parser: argparse.ArgumentParser, epochs: int) -> None:
    """The hyper-parameter options of :class:`~suture_segmentation.train.TrainConfig` (read back by
    :func:`training_config`), shared by ``suture-seg train|finetune`` and ``suture-fewshot``."""
    from suture_segmentation.train import LOSSES, TrainConfig

    defaults = TrainConfig()
    parser.add_argument("--epochs", type=int, default=epochs)
    parser.add_argument("--steps-per-epoch", type=int, default=defaults.steps_per_epoch)
    parser.add_argument("--batch-size", type=int, default=defaults.batch_size)
    parser.add_argument(
        "--crop",
        type=int,
        default=defaults.crop,
        help="crop side in pixels (multiple of 16; of 32 with a half-resolution model)",
    )
    parser.add_argument("--lr", type=float, default=defaults.learning_rate, help="initial learning rate")
    parser.add_argument(
        "--loss",
        choices=LOSSES,
        default=defaults.loss,
        help="ce (the paper), ce_dice, or ce_skeleton (plus skeleton recall)",
    )
    parser.add_argument(
        "--skeleton-weight",
        type=float,
        default=defaults.skeleton_weight,
        help="weight of the skeleton recall term of ce_skeleton (thicker strokes as it grows)",
    )
    parser.add_argument(
        "--structure-crops",
        type=float,
        default=defaults.structure_crops,
        help="fraction of training crops centred on the thread's ends and junctions (cut tip, "
        "crossings); part of the crops on the thread",
    )
    parser.add_argument(
        "--photometric",
        action="store_true",
        help="vary colour, exposure, contrast, tone, focus and noise of the training crops",
    )
    parser.add_argument(
        "--augment",
        action="store_true",
        help="warp (rotation, scale, shear, perspective) and re-colour (colour, gamma, blur, noise) "
        "every training batch with kornia, image and mask alike",
    )
    parser.add_argument(
        "--all-layers",
        action="store_true",
        help="fine-tune every layer, the feature extractor too, instead of freezing it "
        "(finetune and suture-fewshot; train always trains every layer)",
    )
    parser.add_argument("--seed", type=int, default=defaults.seed)
    parser.add_argument("--threads", type=int, help="CPU threads (default: all)")
    parser.add_argument("--device", default="cpu", help="cpu or cuda")
    parser.add_argument("--quiet", action="store_true", help="no progress bar or per-epoch lines")


def _build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="suture-seg", description=__doc__.split("\n\n")[0].replace("``", "")
    )
    commands = parser.add_subparsers(dest="command", required=True)

    train = commands.add_parser("train", help="train every layer from scratch (M-oST, M-TOT)")
    _training_arguments(train, "train")
    train.add_argument(
        "--widths",
        help="channel widths C1..C5 (default 8,16,32,48,64; with --half-resolution 24,16,32,48,64)",
    )
    train.add_argument(
        "--half-resolution",
        action="store_true",
        help="the half-resolution variant (about half the run time; model.py); with --init, the "
        "checkpoint's tensors that fit are copied",
    )
    train.add_argument(
        "--init", help="continue from this checkpoint or shipped name (every layer trained; --widths ignored)"
    )

    finetune = commands.add_parser(
        "finetune", help="transfer: freeze the 13-layer extractor, train the rest (--all-layers: every layer)"
    )
    finetune.add_argument(
        "--weights", default="m_ost", help="checkpoint to start from (default: shipped M-oST)"
    )
    _training_arguments(finetune, "finetune")

    evaluate = commands.add_parser("evaluate", help="IoU, precision, recall, F1 per image and mean")
    evaluate.add_argument("--weights", required=True, help="NAME=PT pairs or PT paths, comma-separated")
    evaluate.add_argument("--images", required=True, action="append", help="test images (repeat per set)")
    evaluate.add_argument("--masks", required=True, action="append", help="test masks (repeat per set)")
    evaluate.add_argument(
        "--set-names", help="names of the sets, comma-separated (default: Set 1, Set 2 ...)"
    )
    evaluate.add_argument("--threshold", type=float, default=0.5)
    evaluate.add_argument("--no-flip-average", action="store_true", help=NO_FLIP_AVERAGE_HELP)
    evaluate.add_argument("--report", help="folder for table.md, scores.json, per-image plot and overlays")

    export = commands.add_parser("export", help="write an ONNX model")
    export.add_argument(
        "--weights", default="m_onsite_half", help="checkpoint (default: shipped m_onsite_half)"
    )
    export.add_argument("--out", required=True, help="ONNX file to write")
    export.add_argument(
        "--int8",
        action="store_true",
        help="quantise to int8 (faster on CPUs with VNNI), calibrated on --calibration-images",
    )
    export.add_argument("--calibration-images", help="folder of frames from the target camera (with --int8)")
    export.add_argument("--calibration-count", type=int, default=16, help="calibration frames used (spread)")

    bench = commands.add_parser("bench", help="milliseconds per stereo pair for each backend")
    bench.add_argument(
        "--weights",
        help="default: the node's (m_onsite_half: its int8 export with onnx on the CPU, else the "
        "float model)",
    )
    bench.add_argument("--backends", default="onnx,torch")
    bench.add_argument("--device", default="cpu", help="cpu or cuda")
    bench.add_argument("--resolution", default="640x480", help="WxH")
    bench.add_argument("--pairs", type=int, default=30, help="timed stereo pairs per backend")
    bench.add_argument("--threads", type=int, help="CPU threads (default: all)")
    bench.add_argument("--no-flip-average", action="store_true", help=NO_FLIP_AVERAGE_HELP)
    return parser


def training_config(args: argparse.Namespace):  # -> TrainConfig
    """The :class:`~suture_segmentation.train.TrainConfig` of the options of :func:`add_training_options`."""
    from suture_segmentation.train import TrainConfig

    return TrainConfig(
        epochs=args.epochs,
        steps_per_epoch=args.steps_per_epoch,
        batch_size=args.batch_size,
        crop=args.crop,
        learning_rate=args.lr,
        loss=args.loss,
        skeleton_weight=args.skeleton_weight,
        structure_crops=args.structure_crops,
        photometric=args.photometric,
        augment=args.augment,
        all_layers=args.all_layers,
        seed=args.seed,
        threads=args.threads,
    )


def _datasets(args: argparse.Namespace):  # -> tuple[LabelledImages, LabelledImages]
    from suture_segmentation.data import DatasetError, load_folder

    training = load_folder(args.images, args.masks, args.limit)
    if (args.val_images is None) != (args.val_masks is None):
        raise DatasetError("give both --val-images and --val-masks, or neither")
    validation = load_folder(args.val_images, args.val_masks) if args.val_images else training
    return training, validation


def _model_to_train(args: argparse.Namespace, seed: int, meta: dict):  # -> SutureUNet
    """The model ``suture-seg train`` starts from: ``--init``'s checkpoint (its tensors that fit
    copied into a new half-resolution model with ``--half-resolution``; the new layers' initial
    weights drawn with ``seed``), else a new model of ``--widths``. Records the start in ``meta``."""
    import torch

    from suture_segmentation.checkpoint import copy_fitting_tensors, load_checkpoint
    from suture_segmentation.model import DEFAULT_WIDTHS, HALF_RESOLUTION_WIDTHS, SutureUNet

    if not args.init:
        default = HALF_RESOLUTION_WIDTHS if args.half_resolution else DEFAULT_WIDTHS
        widths = [int(w) for w in args.widths.split(",")] if args.widths else default
        return SutureUNet(widths, args.half_resolution)
    model, source = load_checkpoint(args.init, args.device)
    meta["initialised_from"] = {"weights": str(args.init), "command": source.get("command")}
    if not args.half_resolution or model.half_resolution:
        return model
    torch.manual_seed(seed)
    half = SutureUNet((HALF_RESOLUTION_WIDTHS[0], *model.widths[1:]), half_resolution=True)
    meta["initialised_from"]["tensors_copied"] = copy_fitting_tensors(model, half)
    return half


def _run_training(args: argparse.Namespace, argv: list[str]) -> int:
    from suture_segmentation.train import finetune, train

    config = training_config(args)
    training, validation = _datasets(args)
    meta = {"command": "suture-seg " + shlex.join(argv)}
    progress = not args.quiet
    if args.command == "train":
        model = _model_to_train(args, config.seed, meta)
        best = train(model, training, validation, config, args.out, meta, args.device, progress)
    else:
        best = finetune(args.weights, training, validation, config, args.out, meta, args.device, progress)
    print(
        f"suture-seg {args.command}: {len(training)} images; best epoch {best['epoch']} "
        f"(val IoU {best['val_iou']:.3f}, recall {best['val_recall']:.3f}) -> {Path(args.out) / 'best.pt'}"
    )
    return 0


def _run_evaluate(args: argparse.Namespace) -> int:
    from suture_segmentation.data import DatasetError, load_folder
    from suture_segmentation.report import evaluate_models, markdown_table, write_report

    if len(args.images) != len(args.masks):
        raise DatasetError("give one --masks per --images")
    models = {}
    for k, item in enumerate(args.weights.split(",")):
        name, _, path = item.rpartition("=")
        models[name or Path(path).stem or f"model {k + 1}"] = path
    set_names = (
        args.set_names.split(",") if args.set_names else [f"Set {k + 1}" for k in range(len(args.images))]
    )
    if len(set_names) != len(args.images):
        raise DatasetError("give one set name per --images")
    sets = {name: load_folder(i, m) for name, i, m in zip(set_names, args.images, args.masks, strict=True)}
    flip_average = not args.no_flip_average
    results = evaluate_models(models, sets, args.threshold, flip_average)
    if args.report:
        print(write_report(results, sets, args.report, models, args.threshold, flip_average))
    else:
        print(markdown_table(results))
    if args.report:
        print(f"suture-seg evaluate: report in {args.report}")
    return 0


def _run_export(args: argparse.Namespace, argv: list[str]) -> int:
    from suture_segmentation.checkpoint import export_onnx, load_checkpoint

    if args.int8 != bool(args.calibration_images):
        raise ValueError("--int8 and --calibration-images DIR (frames of the target camera) go together")
    model, _ = load_checkpoint(args.weights)
    frames = None
    if args.int8:
        from suture_segmentation.quantize import calibration_images

        frames = calibration_images(args.calibration_images, args.calibration_count)
    command = {"command": "suture-seg " + shlex.join(argv)}
    path = export_onnx(model, args.out, metadata=command, calibration=frames)
    print(f"suture-seg export: wrote {path} ({path.stat().st_size / 1024:.0f} KiB)")
    return 0


def _run_bench(args: argparse.Namespace) -> int:
    from suture_segmentation.report import benchmark

    width, height = (int(v) for v in args.resolution.lower().split("x"))
    for backend in args.backends.split(","):
        stats = benchmark(
            args.weights,
            backend,
            args.device,
            (width, height),
            args.pairs,
            args.threads,
            flip_average=not args.no_flip_average,
        )
        print(
            f"{backend:6s} {args.device:5s} {width}x{height} {stats['weights']}: "
            f"median {stats['median_ms']:.1f} ms, p95 {stats['p95_ms']:.1f} ms per stereo pair "
            f"({stats['pairs']} pairs, {stats['threads']} threads)"
        )
    return 0


def main(argv: list[str] | None = None) -> int:
    from suture_segmentation.data import DatasetError

    argv = sys.argv[1:] if argv is None else list(argv)
    args = _build_parser().parse_args(argv)
    try:
        if args.command in ("train", "finetune"):
            return _run_training(args, argv)
        if args.command == "export":
            return _run_export(args, argv)
        return {"evaluate": _run_evaluate, "bench": _run_bench}[args.command](args)
    except (DatasetError, WeightsError, ValueError, OSError) as error:
        print(f"suture-seg {args.command}: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"suture-seg {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
