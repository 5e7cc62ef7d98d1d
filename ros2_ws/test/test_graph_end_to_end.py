# SPDX-License-Identifier: Apache-2.0
"""The running system end to end: ros2_ws/launch.sh replays the bundled bag through the node graph.

The four pipeline nodes, the player and the recorder run as separate processes on the
real middleware (as `bash ros2_ws/demo.sh` runs them). The tests check the grasp error
of every frame against the ground truth, that the graph publishes the same grasp poses
as ``suture-eval`` computes from the same core functions, and that Ctrl-C stops every
node cleanly with the recording finalised.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from suture_bench.evaluate import evaluate
from suture_bench.graph_report import write_report
from suture_common import topics
from suture_common.bag_io import read_messages

REPO = Path(__file__).resolve().parents[2]
LAUNCH = REPO / "ros2_ws" / "launch.sh"
SAMPLE = REPO / "bags" / "sample"
MAX_FRAME_ERROR_MM = 5.0
MAX_MEDIAN_ERROR_MM = 2.0


def _env(domain_id: int) -> dict[str, str]:
    return {**os.environ, "ROS_DOMAIN_ID": str(domain_id), "PYTHONUNBUFFERED": "1"}


def _logs(log_dir: Path) -> str:
    return "\n".join(f"--- {p.name}\n{p.read_text()[-1500:]}" for p in sorted(log_dir.glob("*.log")))


@pytest.fixture(scope="module")
def replay(tmp_path_factory, ros_domain_id) -> dict[str, Path]:
    """One replay of the bundled bag through the graph, frame by frame, with its report."""
    out = tmp_path_factory.mktemp("graph")
    command = [
        "bash", str(LAUNCH), "--bag", str(SAMPLE), "--as-fast-as-graph",
        "--record", str(out / "outputs"), "--report", str(out / "player.json"),
        "--memory", str(out / "memory.json"), "--log-dir", str(out / "logs"),
    ]  # fmt: skip
    run = subprocess.run(command, env=_env(ros_domain_id), capture_output=True, text=True, timeout=240)
    assert run.returncode == 0, f"{run.stdout}\n{run.stderr}\n{_logs(out / 'logs')}"
    return {"out": out, "stdout": run.stdout}


def test_the_graph_grasps_every_frame_of_the_bundled_bag_within_tolerance(replay, capsys):
    out = replay["out"]
    player = json.loads((out / "player.json").read_text())
    assert player["frames"] == 10 and player["outputs"] == 10, _logs(out / "logs")
    summary = write_report(SAMPLE, out / "outputs", out / "report", player_report=player, echo=False)
    frames = json.loads((out / "report" / "frames.json").read_text())
    errors = [frame["grasp_error_mm"] for frame in frames]
    assert None not in errors, frames
    assert max(errors) < MAX_FRAME_ERROR_MM, errors
    assert summary["grasp"]["median_error_mm"] < MAX_MEDIAN_ERROR_MM
    # the dry_run executor planned every grasp in the robot base frame
    assert all(frame["grasp_robot_m"] is not None for frame in frames)
    assert summary["segmentation"]["iou"] > 0.7
    assert set(json.loads((out / "memory.json").read_text())) >= {
        "segmentation_node", "ordering_node", "reconstruction_node", "executor_node"
    }  # fmt: skip
    assert "replayed 10 frames" in replay["stdout"]


def test_the_graph_publishes_the_grasp_poses_that_suture_eval_computes(replay):
    recorded = {
        record.message.header.stamp.sec * 10**9 + record.message.header.stamp.nanosec: record.message
        for record in read_messages(replay["out"] / "outputs", [topics.GRASP_POSE])
    }
    # the weights of params/pipeline.yaml
    offline = evaluate([SAMPLE], masks="predicted", seg_weights="m_ost_int8")["per_frame"]
    assert len(recorded) == len(offline) == 10
    for frame in offline:
        position = recorded[frame["stamp_ns"]].pose.position
        graph = np.array([position.x, position.y, position.z])
        # same core functions; only float32 message fields separate them
        assert np.linalg.norm(graph - np.array(frame["grasp_position"])) < 1e-4, frame["topology"]


def _default_interrupt() -> None:
    """SIGINT at its default in the launched shell: a test run started as a background job inherits
    it ignored, and bash cannot trap a signal that was ignored when it started."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_ctrl_c_stops_every_node_and_finalises_the_recording(tmp_path, ros_domain_id):
    command = [
        "bash",
        str(LAUNCH),
        "--record",
        str(tmp_path / "outputs"),
        "--log-dir",
        str(tmp_path / "logs"),
    ]
    launch = subprocess.Popen(
        command,
        env=_env(ros_domain_id),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        preexec_fn=_default_interrupt,
    )
    started: dict[str, int] = {}
    deadline = time.monotonic() + 30
    while len(started) < 5 and time.monotonic() < deadline:
        line = launch.stdout.readline()
        if match := re.match(r"launch: started (\S+) \(pid (\d+)", line):
            started[match[1]] = int(match[2])
    assert set(started) == {
        "recorder",
        "segmentation_node",
        "ordering_node",
        "reconstruction_node",
        "executor_node",
    }
    # wait until every node is up (its log says so or the process has been running a while)
    time.sleep(8)
    assert all(_alive(pid) for pid in started.values()), _logs(tmp_path / "logs")
    launch.send_signal(signal.SIGINT)
    rest, _ = launch.communicate(timeout=40)
    assert launch.returncode == 130, rest
    assert not any(_alive(pid) for pid in started.values())
    assert "launch: stopped" in rest
    assert list(read_messages(tmp_path / "outputs")) is not None  # a finalised, readable bag
    assert (tmp_path / "outputs" / "metadata.yaml").exists()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie is not running: check its state
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    except OSError:
        return False
