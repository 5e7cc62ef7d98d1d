# SPDX-License-Identifier: Apache-2.0
"""ros2_ws/launch.sh keeps discovery on this host unless the user chose otherwise.

Runs ``launch.sh --dry-run``, which sets up the environment the nodes would inherit, prints it
and each node's command line, and starts nothing.
"""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import pytest

LAUNCH = Path(__file__).resolve().parents[1] / "launch.sh"
NETWORK_VARIABLES = ("ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_STATIC_PEERS", "ROS_LOCALHOST_ONLY")


def dry_run(tmp_path: Path, **environment: str) -> tuple[dict[str, str], str]:
    """launch.sh --dry-run under ``environment`` (network variables unset otherwise): (settings, output)."""
    env = {k: v for k, v in os.environ.items() if k not in NETWORK_VARIABLES}
    env.update(environment)
    run = subprocess.run(
        ["bash", str(LAUNCH), "--dry-run", "--log-dir", str(tmp_path / "logs")],
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    first = run.stdout.splitlines()[0]
    assert first.startswith("launch: ROS_AUTOMATIC_DISCOVERY_RANGE="), run.stdout
    settings = dict(re.findall(r"(\w+)=(\S*)", first))
    return settings, run.stdout


def test_discovery_is_limited_to_this_host_by_default(tmp_path: Path) -> None:
    settings, output = dry_run(tmp_path)
    assert settings["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    # Nothing started, nothing written: four nodes would start, and no log folder exists.
    started = re.findall(r"^launch: would start (\w+):", output, re.MULTILINE)
    assert started == ["segmentation_node", "ordering_node", "reconstruction_node", "executor_node"]
    assert "launch: started" not in output
    assert not (tmp_path / "logs").exists()


def test_an_empty_range_counts_as_unset(tmp_path: Path) -> None:
    """rcl reads an empty ROS_AUTOMATIC_DISCOVERY_RANGE as its default (SUBNET): replace it."""
    settings, _ = dry_run(tmp_path, ROS_AUTOMATIC_DISCOVERY_RANGE="")
    assert settings["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"


@pytest.mark.parametrize("chosen", ["SUBNET", "SYSTEM_DEFAULT", "OFF", "LOCALHOST"])
def test_a_range_the_user_set_is_kept(tmp_path: Path, chosen: str) -> None:
    settings, _ = dry_run(tmp_path, ROS_AUTOMATIC_DISCOVERY_RANGE=chosen)
    assert settings["ROS_AUTOMATIC_DISCOVERY_RANGE"] == chosen


def test_static_peers_are_kept_and_reached_from_localhost(tmp_path: Path) -> None:
    """With LOCALHOST, rmw_fastrtps still contacts the hosts in ROS_STATIC_PEERS (and only them)."""
    settings, _ = dry_run(tmp_path, ROS_STATIC_PEERS="192.168.10.20;seg-host.local")
    assert settings["ROS_STATIC_PEERS"] == "192.168.10.20;seg-host.local"
    assert settings["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    settings, _ = dry_run(tmp_path, ROS_STATIC_PEERS="192.168.10.20", ROS_AUTOMATIC_DISCOVERY_RANGE="SUBNET")
    assert settings == {
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET",
        "ROS_STATIC_PEERS": "192.168.10.20",
        "ROS_DOMAIN_ID": os.environ.get("ROS_DOMAIN_ID", "0"),
    }


def test_the_printed_settings_are_what_the_nodes_inherit(tmp_path: Path) -> None:
    """The dry run's line comes from the exported variables: run the script's own export lines."""
    text = LAUNCH.read_text()
    exports = [line for line in text.splitlines() if line.startswith("export ROS_")]
    assert exports, "launch.sh exports no ROS_ variable"
    script = "\n".join(exports) + "\nbash -c 'echo \"$ROS_AUTOMATIC_DISCOVERY_RANGE\"'"
    env = {k: v for k, v in os.environ.items() if k not in NETWORK_VARIABLES}
    child = subprocess.run(["bash", "-c", script], env=env, capture_output=True, text=True, timeout=10)
    assert child.stdout.strip() == "LOCALHOST"


def test_a_node_left_to_another_host_is_not_started(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k not in NETWORK_VARIABLES}
    command = ["bash", str(LAUNCH), "--dry-run", "--without", "segmentation_node"]
    run = subprocess.run(command, env=env, capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    started = re.findall(r"^launch: would start (\w+):", run.stdout, re.MULTILINE)
    assert started == ["ordering_node", "reconstruction_node", "executor_node"]
    assert "not starting segmentation_node here" in run.stdout


def test_an_unknown_node_to_leave_out_is_refused() -> None:
    run = subprocess.run(
        ["bash", str(LAUNCH), "--dry-run", "--without", "segmentation"], capture_output=True, text=True
    )
    assert run.returncode == 2
    assert run.stderr.strip().startswith("launch: --without segmentation: not one of")
