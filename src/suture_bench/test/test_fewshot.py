# SPDX-License-Identifier: Apache-2.0
"""suture-fewshot: each row is suture-eval's evaluation of the model fine-tuned on the first N
labelled images; N = 0 is the base model as given."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from suture_bench.evaluate import evaluate
from suture_bench.fewshot import curve_row, main, parse_counts
from suture_common.bag_io import BagWriter
from suture_common.camera import StereoCamera
from suture_segmentation.checkpoint import load_checkpoint, save_checkpoint
from suture_segmentation.model import SutureUNet
from suture_sim.output import export_png, write_frame
from suture_sim.scene import SimConfig, generate_frame

TINY_TRAINING = ["--epochs", "1", "--steps-per-epoch", "1", "--batch-size", "2", "--crop", "32", "--quiet"]


@pytest.fixture(scope="module")
def camera_data(tmp_path_factory) -> dict[str, Path]:
    """A labelled pool (2 frames, 4 images) and a test bag (2 frames) from different seeds, and a
    tiny untrained model."""
    root = tmp_path_factory.mktemp("fewshot")
    camera = StereoCamera.default(160, 128)
    for index in range(2):
        export_png(
            generate_frame(SimConfig(topology="curved", camera=camera, seed=611), index), root / "pool"
        )
    with BagWriter(root / "test_bag") as writer:
        for index in range(2):
            write_frame(writer, generate_frame(SimConfig(topology="mixed", camera=camera, seed=612), index))
    base = save_checkpoint(SutureUNet([4, 4, 8, 8, 8]), root / "tiny.pt")
    return {"pool": root / "pool", "test": root / "test_bag", "base": base}


def _figures(row: dict) -> dict:
    return {key: value for key, value in row.items() if key not in ("finetune_s", "reused")}


def test_each_row_is_the_evaluation_of_its_model(camera_data, tmp_path):
    pool, out = camera_data["pool"], tmp_path / "curve"
    args = ["--images", str(pool / "images"), "--masks", str(pool / "masks")]
    args += ["--test", str(camera_data["test"]), "--base", str(camera_data["base"]), "--counts", "2,0"]
    assert main([*args, "--out", str(out), *TINY_TRAINING]) == 0

    curve = json.loads((out / "curve.json").read_text())
    assert [row["images"] for row in curve["rows"]] == [0, 2]
    assert curve["command"].startswith("suture-fewshot --images") and curve["frames"] == 2

    def direct(weights: Path) -> dict:
        summary = evaluate(
            [camera_data["test"]], masks="predicted", sequences="predicted", seg_weights=weights
        )
        return _figures(curve_row(0, summary, None))

    base_row, tuned_row = curve["rows"]
    assert _figures(base_row) == direct(camera_data["base"])
    assert base_row["finetune_s"] is None and base_row["iou"] is not None
    tuned = out / "n2" / "best.pt"
    _, meta = load_checkpoint(tuned)
    assert meta["fewshot_images"] == ["000000_left.png", "000000_right.png"]
    assert meta["finetuned_from"] == str(camera_data["base"])
    assert _figures(tuned_row) == {**direct(tuned), "images": 2}
    last_epoch = json.loads((out / "n2" / "log.jsonl").read_text().splitlines()[-1])
    assert tuned_row["finetune_s"] == last_epoch["elapsed_s"] >= 0  # 0.1 s steps: a tiny run may read 0

    table = (out / "curve.md").read_text()
    assert curve["command"] in table
    assert "| labelled images | IoU |" in table
    assert table.count("\n| 0 | ") == 1 and table.count("\n| 2 | ") == 1
    assert not tuned_row["reused"] and "reused" not in table

    # the same settings again: the model there is evaluated, not trained; another seed trains anew
    trained_at = tuned.stat().st_mtime_ns
    assert main([*args, "--out", str(out), *TINY_TRAINING]) == 0
    rerun = json.loads((out / "curve.json").read_text())
    assert tuned.stat().st_mtime_ns == trained_at and rerun["rows"][1]["reused"]
    assert [_figures(row) for row in rerun["rows"]] == [_figures(row) for row in curve["rows"]]
    assert "reused from an earlier run: N = 2." in (out / "curve.md").read_text()
    assert main([*args, "--out", str(out), *TINY_TRAINING, "--seed", "1"]) == 0
    assert tuned.stat().st_mtime_ns != trained_at
    assert not json.loads((out / "curve.json").read_text())["rows"][1]["reused"]


def test_too_few_images_or_a_missing_test_bag_is_one_line_and_status_2(camera_data, tmp_path, capsys):
    pool = camera_data["pool"]
    args = [
        "--images",
        str(pool / "images"),
        "--masks",
        str(pool / "masks"),
        "--test",
        str(camera_data["test"]),
    ]
    assert main([*args, "--counts", "0,5", "--out", str(tmp_path / "c"), *TINY_TRAINING]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "holds 4 labelled images, fewer than the count 5" in error
    assert not (tmp_path / "c" / "curve.json").exists()
    args[-1] = str(tmp_path / "no_bag")
    assert main([*args, "--counts", "2", "--out", str(tmp_path / "c"), *TINY_TRAINING]) == 2
    assert f"{tmp_path / 'no_bag'} does not exist" in capsys.readouterr().err
    assert not (tmp_path / "c").exists()  # refused before any fine-tune


@pytest.mark.parametrize("text", ["0,ten", "-1,10", ""])
def test_counts_must_be_whole_numbers_not_below_zero(text):
    with pytest.raises(ValueError, match="--counts"):
        parse_counts(text)


def test_counts_are_sorted_and_distinct():
    assert parse_counts("20,0,10,20") == [0, 10, 20]
