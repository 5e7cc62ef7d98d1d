# SPDX-License-Identifier: Apache-2.0
"""Ctrl-C at a random moment ends every node executable cleanly: exit status 0, no traceback.

Each executable is started :data:`INTERRUPTS_PER_NODE` times, :data:`CONCURRENT` at a time,
beside two CPU-bound processes (a loaded machine widens every race), and sent one SIGINT at a
random moment between its start-up log line and :data:`LATEST_INTERRUPT_S` after it: during
the end of construction, the first spins, callbacks and idle waits. The moments come from a
generator seeded per executable, so a failure names a delay that can be replayed.
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SAMPLE = REPO / "bags" / "sample"
BIN = Path(sys.executable).parent
INTERRUPTS_PER_NODE = 20
CONCURRENT = 4
LATEST_INTERRUPT_S = 1.0
START_TIMEOUT_S = 60.0
EXIT_TIMEOUT_S = 30.0


def _arguments(executable: str, scratch: Path) -> list[str]:
    """Parameters under which the executable starts and keeps running until interrupted."""
    if executable == "player_node":
        return ["-p", f"bag:={SAMPLE}", "-p", "loops:=1000", "-p", "start_timeout:=0.3"]
    if executable == "recorder_node":
        return ["-p", f"output:={scratch / 'recording'}"]
    return []


EXECUTABLES = [
    "segmentation_node",
    "ordering_node",
    "reconstruction_node",
    "executor_node",
    "psm_sim_node",
    "player_node",
    "recorder_node",
]


@pytest.fixture(scope="module")
def cpu_load() -> Iterator[None]:
    """Two processes that keep both cores busy while the module runs."""
    burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    try:
        yield
    finally:
        for burner in burners:
            burner.kill()
            burner.wait()


def _interrupt_once(executable: str, delay_s: float, scratch: Path, domain_id: int) -> tuple[int | None, str]:
    """Start ``executable``, SIGINT it ``delay_s`` after its first log line; (exit status, output)."""
    scratch.mkdir(parents=True)
    process = subprocess.Popen(
        [str(BIN / executable), "--ros-args", *_arguments(executable, scratch)],
        env={**os.environ, "ROS_DOMAIN_ID": str(domain_id), "PYTHONUNBUFFERED": "1"},
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    lines: list[str] = []
    started = threading.Event()

    def read() -> None:
        assert process.stdout is not None
        for line in process.stdout:
            lines.append(line)
            started.set()
        started.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        if not started.wait(START_TIMEOUT_S):
            return None, f"no start-up line in {START_TIMEOUT_S:.0f} s"
        time.sleep(delay_s)
        process.send_signal(signal.SIGINT)
        status = process.wait(timeout=EXIT_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        status = None
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        reader.join(5.0)
    return status, "".join(lines)


@pytest.mark.parametrize("executable", EXECUTABLES)
def test_ctrl_c_at_random_moments_under_load_exits_cleanly(executable, cpu_load, ros_domain_id, tmp_path):
    rng = random.Random(executable)
    delays = [rng.uniform(0.0, LATEST_INTERRUPT_S) for _ in range(INTERRUPTS_PER_NODE)]
    with ThreadPoolExecutor(CONCURRENT) as pool:
        results = list(
            pool.map(
                lambda k: _interrupt_once(executable, delays[k], tmp_path / str(k), ros_domain_id),
                range(INTERRUPTS_PER_NODE),
            )
        )
    failures = [
        f"SIGINT {delays[k]:.3f} s after start-up: exit status {status}\n{output[-2000:]}"
        for k, (status, output) in enumerate(results)
        if status != 0 or "Traceback" in output
    ]
    assert not failures, (
        f"{len(failures)} of {INTERRUPTS_PER_NODE} runs of {executable} failed:\n" + "\n".join(failures)
    )
