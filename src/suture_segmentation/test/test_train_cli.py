# SPDX-License-Identifier: Apache-2.0
"""Training learns, fine-tuning keeps the extractor, and the ``suture-seg`` commands work end to end."""

from __future__ import annotations

import argparse
import json
import shlex
from pathlib import Path

import numpy as np
import pytest
import torch

from suture_segmentation.checkpoint import SHIPPED, load_checkpoint, onnx_metadata
from suture_segmentation.cli import add_training_options, main, training_config
from suture_segmentation.core import Segmenter
from suture_segmentation.data import load_folder
from suture_segmentation.model import SutureUNet
from suture_segmentation.train import TrainConfig, evaluate_model, segmentation_loss, train, tubed_skeleton

TINY = ["--epochs", "2", "--steps-per-epoch", "15", "--batch-size", "4", "--crop", "48", "--quiet"]


def test_training_learns_thin_lines(tmp_path: Path, make_folder) -> None:
    data = load_folder(*(make_folder(tmp_path / "train", 8, seed=5) / sub for sub in ("images", "masks")))
    test = load_folder(*(make_folder(tmp_path / "test", 4, seed=6) / sub for sub in ("images", "masks")))
    torch.manual_seed(0)
    model = SutureUNet((8, 8, 16, 16, 16))
    before = evaluate_model(model, test)["iou"]
    config = TrainConfig(
        epochs=3, steps_per_epoch=25, batch_size=4, crop=48, learning_rate=1e-2, loss="ce_dice"
    )
    best = train(model, data, test, config, tmp_path / "run", progress=False)
    assert best["val_iou"] > max(0.5, before + 0.3)
    log = [json.loads(line) for line in (tmp_path / "run" / "log.jsonl").read_text().splitlines()]
    assert [line["epoch"] for line in log] == [1, 2, 3]
    assert {"loss", "val_iou", "val_precision", "val_recall", "val_f1"} <= set(log[0])


def test_train_finetune_export_evaluate_bench_commands(
    tmp_path: Path, capsys: pytest.CaptureFixture, make_folder
) -> None:
    folder = make_folder(tmp_path / "data", 4, seed=2)
    images, masks = str(folder / "images"), str(folder / "masks")
    data = load_folder(images, masks)
    assert (
        main(
            [
                "train",
                "--images",
                images,
                "--masks",
                masks,
                "--out",
                str(tmp_path / "a"),
                "--widths",
                "4,4,8,8,8",
                *TINY,
            ]
        )
        == 0
    )
    source = tmp_path / "a" / "best.pt"
    model, meta = load_checkpoint(source)
    assert meta["command"].startswith("suture-seg train --images") and meta["config"]["seed"] == 0

    assert (
        main(
            [
                "finetune",
                "--weights",
                str(source),
                "--images",
                images,
                "--masks",
                masks,
                "--out",
                str(tmp_path / "b"),
                *TINY,
            ]
        )
        == 0
    )
    tuned, tuned_meta = load_checkpoint(tmp_path / "b" / "last.pt")
    assert tuned_meta["finetuned_from"] == str(source)
    _assert_same_extractor(model, tuned)

    assert main(["export", "--weights", str(source), "--out", str(tmp_path / "m.onnx")]) == 0
    assert (tmp_path / "m.onnx").stat().st_size > 1000
    int8 = ["export", "--weights", str(source), "--out", str(tmp_path / "m8.onnx"), "--int8"]
    assert main([*int8, "--calibration-images", images, "--calibration-count", "2"]) == 0
    assert onnx_metadata(tmp_path / "m8.onnx")["command"] == "suture-seg " + shlex.join(
        [*int8, "--calibration-images", images, "--calibration-count", "2"]
    )
    quantized = Segmenter(tmp_path / "m8.onnx").probabilities(data.images[:2])
    reference = Segmenter(source, backend="torch").probabilities(data.images[:2])
    assert quantized.shape == reference.shape and np.abs(quantized - reference).mean() < 0.05

    report = tmp_path / "report"
    weights = f"A={source},B={tmp_path / 'b' / 'last.pt'}"
    args = ["evaluate", "--weights", weights, "--images", images, "--masks", masks, "--report", str(report)]
    assert main(args) == 0
    table = (report / "table.md").read_text()
    assert "| Set 1 | IoU |" in table and "| A | B |" in table.replace("metric | ", "")
    scores = json.loads((report / "scores.json").read_text())
    assert len(scores["Set 1"]["A"]["per_image"]) == 4
    # thin-structure figures beside IoU
    assert "| Set 1 | Centreline recall |" in table and "| Set 1 | clDice |" in table
    assert 0 <= scores["Set 1"]["A"]["mean"]["centreline_recall"] <= 1
    assert (report / "per_image.png").stat().st_size > 0
    assert (report / "overlays_set1.png").stat().st_size > 0

    capsys.readouterr()
    assert main(["bench", "--weights", str(source), "--resolution", "64x48", "--pairs", "2"]) == 0
    out = capsys.readouterr().out
    assert "onnx" in out and "torch" in out and "ms per stereo pair" in out


@pytest.mark.parametrize(
    "args",
    [
        ["train", "--images", "/nonexistent", "--masks", "/nonexistent", "--out", "/tmp/x"],
        ["export", "--weights", "/nonexistent.pt", "--out", "/tmp/x.onnx"],
        ["export", "--weights", "m_ost", "--out", "/tmp/x.onnx", "--int8"],
        ["export", "--weights", "m_ost_int8", "--out", "/tmp/x.onnx"],
        ["bench", "--weights", "/nonexistent.pt", "--pairs", "1"],
    ],
)
def test_command_errors_are_one_line(args: list[str], capsys: pytest.CaptureFixture) -> None:
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"suture-seg {args[0]}: error:") and "\n" not in err


def test_train_init_continues_every_layer_of_a_checkpoint(tmp_path: Path, make_folder) -> None:
    folder = make_folder(tmp_path / "data", 4, seed=3)
    images, masks = str(folder / "images"), str(folder / "masks")
    first = ["train", "--images", images, "--masks", masks, "--widths", "4,4,8,8,8", *TINY]
    assert main([*first, "--out", str(tmp_path / "a")]) == 0
    start, _ = load_checkpoint(tmp_path / "a" / "best.pt")
    again = ["train", "--images", images, "--masks", masks, "--init", str(tmp_path / "a" / "best.pt"), *TINY]
    assert main([*again, "--out", str(tmp_path / "b")]) == 0
    model, meta = load_checkpoint(tmp_path / "b" / "last.pt")
    assert meta["initialised_from"]["weights"].endswith("best.pt")
    assert meta["initialised_from"]["command"].startswith("suture-seg train")
    assert model.widths == start.widths  # the checkpoint's architecture, whatever --widths says
    changed = [
        name
        for (name, a), (_, b) in zip(start.state_dict().items(), model.state_dict().items(), strict=True)
        if a.dtype.is_floating_point and not torch.equal(a, b)
    ]
    assert any(name.startswith("feature_extractor") for name in changed)  # not frozen, unlike finetune


def test_train_half_resolution_from_a_full_resolution_checkpoint(tmp_path: Path, make_folder) -> None:
    folder = make_folder(tmp_path / "data", 4, seed=3)
    images, masks = str(folder / "images"), str(folder / "masks")
    first = ["train", "--images", images, "--masks", masks, "--widths", "4,4,8,8,8", *TINY]
    assert main([*first, "--out", str(tmp_path / "a")]) == 0
    half = ["train", "--images", images, "--masks", masks, "--init", str(tmp_path / "a" / "best.pt")]
    half += ["--half-resolution", *TINY]
    assert main([*half, "--out", str(tmp_path / "b")]) == 2  # a 48 px crop does not fold into 32 px blocks
    assert main([*half, "--crop", "64", "--out", str(tmp_path / "b")]) == 0
    model, meta = load_checkpoint(tmp_path / "b" / "last.pt")
    assert model.half_resolution and model.widths == (24, 4, 8, 8, 8)
    assert meta["initialised_from"]["tensors_copied"] > 0
    assert (
        main(["export", "--weights", str(tmp_path / "b" / "last.pt"), "--out", str(tmp_path / "h.onnx")]) == 0
    )
    onnx = Segmenter(tmp_path / "h.onnx").probabilities(load_folder(images, masks).images[:1])
    reference = Segmenter(tmp_path / "b" / "last.pt", backend="torch").probabilities(
        load_folder(images, masks).images[:1]
    )
    assert np.abs(onnx - reference).max() < 1e-4


def test_finetune_starts_from_the_shipped_m_ost_by_default(tmp_path: Path, make_folder) -> None:
    folder = make_folder(tmp_path / "data", 2, seed=4)
    args = ["finetune", "--images", str(folder / "images"), "--masks", str(folder / "masks")]
    short = ["--epochs", "1", "--steps-per-epoch", "2", "--batch-size", "2", "--crop", "48", "--quiet"]
    assert main([*args, "--out", str(tmp_path / "b"), *short]) == 0
    shipped, _ = load_checkpoint(SHIPPED["m_ost"])
    tuned, meta = load_checkpoint(tmp_path / "b" / "last.pt")
    assert meta["finetuned_from"] == "m_ost"
    _assert_same_extractor(shipped, tuned)


def test_finetune_with_all_layers_trains_the_extractor_too(tmp_path: Path, make_folder) -> None:
    folder = make_folder(tmp_path / "data", 2, seed=4)
    args = ["finetune", "--images", str(folder / "images"), "--masks", str(folder / "masks")]
    short = ["--epochs", "1", "--steps-per-epoch", "2", "--batch-size", "2", "--crop", "48", "--quiet"]
    assert main([*args, "--all-layers", "--out", str(tmp_path / "b"), *short]) == 0
    shipped, _ = load_checkpoint(SHIPPED["m_ost"])
    tuned, meta = load_checkpoint(tmp_path / "b" / "last.pt")
    assert meta["finetuned_from"] == "m_ost" and meta["config"]["all_layers"] is True
    with pytest.raises(AssertionError):
        _assert_same_extractor(shipped, tuned)


def _assert_same_extractor(source: SutureUNet, tuned: SutureUNet) -> None:
    """Fine-tuning left every tensor of the 13-layer extractor as it was."""
    tuned_state = tuned.feature_extractor.state_dict()
    for key, value in source.feature_extractor.state_dict().items():
        assert torch.equal(value, tuned_state[key]), key


def test_skeleton_recall_loss_punishes_a_gap_across_the_thread_more_than_a_frayed_edge() -> None:
    labels = np.zeros((1, 32, 32), np.int64)
    labels[0, 10:15, :] = 1  # a 5 px thread along the rows
    tube = tubed_skeleton(labels)[0]
    assert tube[11:14, 3:-3].all() and not tube[[10, 14], 3:-3].any()  # centre line, 3 px

    def logits_missing(rows: slice, columns: slice) -> torch.Tensor:
        suture = np.where(labels[0] == 1, 4.0, -4.0)
        suture[rows, columns] = -4.0  # ten thread pixels predicted as background
        return torch.from_numpy(np.stack([-suture, suture])[None]).float()

    gap = logits_missing(slice(10, 15), slice(15, 17))
    frayed = logits_missing(slice(10, 11), slice(15, 25))
    truth = torch.from_numpy(labels)
    ce = [segmentation_loss(x, truth, "ce").item() for x in (gap, frayed)]
    skeleton = [segmentation_loss(x, truth, "ce_skeleton").item() for x in (gap, frayed)]
    assert ce[0] == pytest.approx(ce[1])  # cross-entropy cannot tell them apart
    assert skeleton[0] > skeleton[1] + 0.005
    heavier = segmentation_loss(gap, truth, "ce_skeleton", skeleton_weight=0.3).item()
    assert heavier - ce[0] == pytest.approx(3 * (skeleton[0] - ce[0]), rel=1e-4)  # the term scales
    assert segmentation_loss(gap, truth, "ce_skeleton", skeleton_weight=0.0).item() == pytest.approx(ce[0])


def test_training_options_carry_the_skeleton_weight_and_refuse_a_negative_one() -> None:
    parser = argparse.ArgumentParser()
    add_training_options(parser, epochs=3)
    config = training_config(parser.parse_args(["--loss", "ce_skeleton", "--skeleton-weight", "0.03"]))
    assert (config.loss, config.skeleton_weight) == ("ce_skeleton", 0.03)
    assert training_config(parser.parse_args([])).skeleton_weight == TrainConfig().skeleton_weight == 0.1
    with pytest.raises(ValueError, match="skeleton weight"):
        TrainConfig(loss="ce_skeleton", skeleton_weight=-0.1)


def test_training_options_carry_the_structure_crops_within_the_crops_on_the_thread() -> None:
    parser = argparse.ArgumentParser()
    add_training_options(parser, epochs=3)
    assert training_config(parser.parse_args(["--structure-crops", "0.35"])).structure_crops == 0.35
    assert training_config(parser.parse_args([])).structure_crops == 0.0
    with pytest.raises(ValueError, match="structure crops"):
        TrainConfig(structure_crops=0.8, on_thread=0.7)
