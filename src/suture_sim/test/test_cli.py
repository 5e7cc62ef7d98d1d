# SPDX-License-Identifier: Apache-2.0
"""suture-sim's command line: bags and PNG folders it writes, and one-line errors on bad input."""

from __future__ import annotations

import subprocess
import sys

import cv2
import numpy as np
import pytest

from suture_common import topics
from suture_common.bag_io import bag_summary, read_messages
from suture_sim.cli import main


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "suture_sim.cli", *args], capture_output=True, text=True, timeout=120
    )


def test_writes_bag_with_every_design_topic_and_png_folders(tmp_path, capsys):
    bag, png = tmp_path / "bag", tmp_path / "png"
    code = main(
        [
            "--topology",
            "mixed",
            "--frames",
            "5",
            "--seed",
            "3",
            "--resolution",
            "320x240",
            "--out",
            str(bag),
            "--png-dir",
            str(png),
            "--quiet",
            "--workers",
            "2",
        ]
    )
    assert code == 0
    assert "wrote 5 frames" in capsys.readouterr().out
    summary = bag_summary(bag)
    for topic in (*topics.INPUT_TOPICS, *topics.GROUND_TRUTH_TOPICS):
        assert summary[topic][1] == 5, topic
    assert summary[topics.LEFT_IMAGE][0] == "sensor_msgs/msg/Image"
    assert summary[topics.GT_PATH][0] == "nav_msgs/msg/Path"
    images = sorted(p.name for p in (png / "images").iterdir())
    masks = sorted(p.name for p in (png / "masks").iterdir())
    assert images == masks and len(images) == 10
    mask = cv2.imread(str(png / "masks" / images[0]), cv2.IMREAD_UNCHANGED)
    image = cv2.imread(str(png / "images" / images[0]), cv2.IMREAD_UNCHANGED)
    assert mask.shape == (240, 320) and set(np.unique(mask)) == {0, 255}
    assert image.shape == (240, 320, 3)


@pytest.mark.parametrize(
    ("arguments", "expected"),
    [
        (["--topology", "spiral"], "invalid choice: 'spiral'"),
        (["--topology", "curved", "--frames", "-3"], "must be positive"),
        (["--topology", "curved", "--baseline", "-0.005"], "must be positive"),
        (["--topology", "curved", "--fx", "-520"], "must be positive"),
        (["--topology", "curved", "--resolution", "-640x480"], "resolution"),
        (["--topology", "curved", "--resolution", "big"], "resolution must look like 640x480"),
        (["--topology", "curved"], "nothing to write"),
        (["--topology", "curved", "--out", "/proc/no_such_dir/bag"], "/proc/no_such_dir/bag"),
    ],
)
def test_bad_arguments_give_one_clear_line(arguments, expected):
    result = _run(*arguments, "--quiet", "--frames", "1") if "--frames" not in arguments else _run(*arguments)
    assert result.returncode != 0
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert expected in lines[0]
    assert "Traceback" not in result.stderr


def test_existing_output_is_not_overwritten(tmp_path):
    (tmp_path / "bag").mkdir()
    result = _run("--topology", "curved", "--out", str(tmp_path / "bag"))
    assert result.returncode == 2
    assert "exists already" in result.stderr and len(result.stderr.strip().splitlines()) == 1


def test_impossible_intrinsics_fail_cleanly(tmp_path):
    # A 1 px focal length cannot see a thread at 50-150 mm large enough to draw.
    result = _run(
        "--topology", "straight", "--frames", "1", "--fx", "1", "--quiet", "--out", str(tmp_path / "b")
    )
    assert result.returncode == 1
    assert len(result.stderr.strip().splitlines()) == 1 and "Traceback" not in result.stderr
    assert not (tmp_path / "b").exists()


def test_help_and_errors_name_the_hard_topologies(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    help_text = capsys.readouterr().out
    for name in ("hooked", "wide_occlusion", "along_rows", "hard"):
        assert name in help_text
    result = _run("--topology", "hooks", "--out", str(tmp_path / "b"))
    assert "'wide_occlusion'" in result.stderr and "'hard'" in result.stderr


def test_hard_mixture_writes_its_three_topologies(tmp_path, capsys):
    bag = tmp_path / "bag"
    code = main(
        ["--topology", "hard", "--frames", "3", "--resolution", "320x240", "--out", str(bag), "--quiet"]
    )
    assert code == 0 and "wrote 3 frames" in capsys.readouterr().out
    labels = [r.message.data for r in read_messages(bag, [topics.GT_TOPOLOGY])]
    assert labels == ["hooked", "wide_occlusion", "along_rows"]
