# SPDX-License-Identifier: Apache-2.0
"""run_node, the one process shell of every node executable: signals, bad parameters, finish.

These run the shell in the test process (the default rclpy context on this module's domain), so
the signal arrives exactly where the test puts it.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator

import pytest
import rclpy
from rclpy.node import Node

from suture_common.ros import ThreadPoolExecutor, run_node
from suture_common.stop_signals import StopSignals


@pytest.fixture(autouse=True)
def own_domain_and_signal_handlers(ros_domain_id: int, monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    monkeypatch.setenv("ROS_DOMAIN_ID", str(ros_domain_id))
    before = {sig: signal.getsignal(sig) for sig in StopSignals.SIGNALS}
    try:
        yield
    finally:
        for sig, handler in before.items():
            signal.signal(sig, handler)


class Interrupting(Node):
    """A node that sends its own process SIGINT from a timer callback, after ``ticks`` ticks."""

    def __init__(self, ticks: int = 3) -> None:
        super().__init__("interrupting_test_node")
        self.ticks = 0
        self.finished_while_ros_up: bool | None = None
        self.create_timer(0.01, self._tick)
        self._last = ticks

    def _tick(self) -> None:
        self.ticks += 1
        if self.ticks == self._last:
            os.kill(os.getpid(), signal.SIGINT)

    def finish(self) -> None:
        self.finished_while_ros_up = rclpy.ok()


@pytest.mark.parametrize("executor", ["single", "multi"])
def test_sigint_in_a_callback_ends_the_loop_then_finish_runs_while_ros_is_up(executor):
    nodes: list[Interrupting] = []

    def make() -> Interrupting:
        nodes.append(Interrupting())
        return nodes[-1]

    extra = {} if executor == "single" else {"make_executor": lambda: ThreadPoolExecutor(num_threads=2)}
    status = run_node(make, "test_node", [], finish=Interrupting.finish, **extra)
    assert status == 0
    assert nodes[0].ticks >= 3
    assert nodes[0].finished_while_ros_up is True
    assert not rclpy.ok()  # the context was shut down after finish
    assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN  # stopping: a second Ctrl-C changes nothing


def test_sigint_during_construction_skips_the_spin_and_exits_zero():
    built: list[Node] = []

    def make() -> Node:
        os.kill(os.getpid(), signal.SIGINT)  # no KeyboardInterrupt: construction goes on
        built.append(Node("constructing_test_node"))
        return built[0]

    assert run_node(make, "test_node", []) == 0
    assert built and not rclpy.ok()


def test_a_bad_parameter_is_one_line_and_status_one(capsys):
    def make() -> Node:
        raise ValueError("parameter rate is -1.0; use a value > 0")

    assert run_node(make, "test_node", []) == 1
    assert capsys.readouterr().err == "test_node: parameter rate is -1.0; use a value > 0\n"
    assert not rclpy.ok()


def test_an_os_error_of_finish_is_one_line_and_status_one(capsys):
    def finish(node: Node) -> None:
        raise OSError("disk full")

    status = run_node(
        lambda: Node("finishing_test_node"),
        "test_node",
        [],
        finished=lambda node: True,
        finish=finish,
        finish_error=lambda node, exc: f"cannot write the report: {exc}",
    )
    assert status == 1
    assert capsys.readouterr().err == "test_node: cannot write the report: disk full\n"


class Failing(Node):
    """A node whose timer callback raises."""

    def __init__(self) -> None:
        super().__init__("failing_test_node")
        self.create_timer(0.01, self._tick)

    def _tick(self) -> None:
        raise RuntimeError("callback failed")


@pytest.mark.parametrize("executor", ["single", "multi"])
def test_a_callback_exception_ends_the_node_and_is_raised(executor):
    extra = {} if executor == "single" else {"make_executor": lambda: ThreadPoolExecutor(num_threads=2)}
    with pytest.raises(RuntimeError, match="callback failed"):
        run_node(Failing, "test_node", [], **extra)
    assert not rclpy.ok()


STALLING_NODE = """
import sys, time
from rclpy.node import Node
from suture_common import ros

ros.TEARDOWN_TIMEOUT_S = 0.5


class Stalling(Node):
    def __init__(self):
        super().__init__("stalling_test_node")

    def destroy_node(self):  # a middleware teardown that never returns
        time.sleep(120)


sys.exit(ros.run_node(Stalling, "stalling_node", [], finished=lambda node: True))
"""


def test_a_teardown_that_stalls_ends_the_process_with_its_status_and_a_line():
    started = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-c", STALLING_NODE], capture_output=True, text=True, timeout=90, check=False
    )
    assert done.returncode == 0, done.stderr
    assert time.monotonic() - started < 60  # start-up and rclpy included; the stall is 120 s
    assert "stalling_node: the middleware's shutdown did not finish within 0.5 s" in done.stderr
    assert "Traceback" not in done.stderr
