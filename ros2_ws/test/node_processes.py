# SPDX-License-Identifier: Apache-2.0
"""A small harness for tests that run the pipeline's nodes as separate processes.

:class:`NodeProcess` starts one installed node executable (``.venv/bin/<name>``, what
``ros2 run`` starts on a full install) with ``ros2_ws/params/pipeline.yaml`` and extra
``--ros-args``, in its own process group, on a given ``ROS_DOMAIN_ID``, with its standard
output and error in a log file; it can be killed (SIGKILL: a crash), stopped (SIGINT, then
SIGTERM, then SIGKILL), restarted, and its log read. :func:`pipeline` starts the four nodes
of the graph and always stops them. :class:`Driver` is the test's own rclpy node, in its own
``rclpy.Context`` on the same domain: it publishes the frames of ``bags/sample`` (or any
message) and collects ``/suture/grasp_pose``, ``/grasp_executor/target_pose`` and
``/grasp_executor/state``.

Import it from a test file by path (pytest runs with ``--import-mode=importlib``, and
``ros2_ws/test`` is no package), e.g. with ``importlib.util.spec_from_file_location``.
Importing it selects the graph's Fast DDS profile for this process (see
:func:`use_graph_transport_profile`).
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import rclpy
from rclpy.executors import SingleThreadedExecutor

from suture_common import topics
from suture_common.bag_io import read_raw
from suture_common.ros import RELIABLE_QOS, SENSOR_DATA_QOS, from_cdr, message_class

ROOT = Path(__file__).resolve().parents[2]
PARAMS_FILE = ROOT / "ros2_ws" / "params" / "pipeline.yaml"
FASTDDS_PROFILE = ROOT / "ros2_ws" / "params" / "fastdds.xml"
SAMPLE_BAG = ROOT / "bags" / "sample"

PIPELINE: tuple[str, ...] = ("segmentation_node", "ordering_node", "reconstruction_node", "executor_node")
"""The graph's executables, upstream first."""
NODE_NAMES: dict[str, str] = {
    "segmentation_node": "segmentation_node",
    "ordering_node": "ordering_node",
    "reconstruction_node": "reconstruction_node",
    "executor_node": "grasp_executor",
}
"""ROS node name of each executable."""


def use_graph_transport_profile() -> None:
    """Use the Fast DDS profile that ``ros2_ws/launch.sh`` gives the graph (unless one is set).

    Without it a 640x480 RGB frame (900 KiB) does not fit Fast DDS's default 512 KiB
    shared-memory segment and goes over UDP in fragments, where best-effort subscribers (the
    segmentation node) lose most frames. Fast DDS reads the profile once per process, when the
    first participant is created, and the sender's segment is what counts: so this must run
    before the test process creates any rclpy context, which importing this module does.
    """
    if FASTDDS_PROFILE.is_file():
        os.environ.setdefault("FASTRTPS_DEFAULT_PROFILES_FILE", str(FASTDDS_PROFILE))


use_graph_transport_profile()


def bin_dir() -> Path:
    """Folder of the installed console scripts: the running interpreter's environment, else .venv/bin."""
    candidate = Path(sys.prefix) / "bin"
    return candidate if (candidate / PIPELINE[0]).exists() else ROOT / ".venv" / "bin"


# --------------------------------------------------------------------------- node processes


class NodeProcess:
    """One node executable in its own process group, logging to ``log_dir/<executable>.log``.

    Every (re)start appends to the same log file after a ``=== start N`` marker line.
    """

    def __init__(
        self,
        executable: str,
        log_dir: Path,
        domain_id: int,
        ros_args: Sequence[str] = (),
        params_file: Path | None = PARAMS_FILE,
    ) -> None:
        self.executable = executable
        self.log_path = Path(log_dir) / f"{executable}.log"
        self.domain_id = domain_id
        self.ros_args = list(ros_args)
        self.params_file = params_file
        self.starts = 0
        self._process: subprocess.Popen[bytes] | None = None

    @property
    def command(self) -> list[str]:
        command = [str(bin_dir() / self.executable), "--ros-args"]
        if self.params_file is not None:
            command += ["--params-file", str(self.params_file)]
        return command + self.ros_args

    @property
    def pid(self) -> int | None:
        return None if self._process is None else self._process.pid

    def start(self) -> None:
        """Start the process (it must not be running)."""
        if self.alive():
            raise RuntimeError(f"{self.executable} is running already (pid {self.pid})")
        env = dict(os.environ)
        env.update(
            ROS_DOMAIN_ID=str(self.domain_id),
            PYTHONUNBUFFERED="1",
            ROS_LOG_DIR=str(self.log_path.parent / "ros_log"),
        )
        self.starts += 1
        with self.log_path.open("ab") as log:
            log.write(f"=== start {self.starts}: {' '.join(self.command)}\n".encode())
            log.flush()
            self._process = subprocess.Popen(
                self.command,
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=subprocess.STDOUT,
                env=env,
                cwd=ROOT,
                start_new_session=True,  # own session and process group: signals reach only it
            )

    def alive(self) -> bool:
        return self._process is not None and self._process.poll() is None

    @property
    def returncode(self) -> int | None:
        return None if self._process is None else self._process.poll()

    def _signal(self, signum: int) -> None:
        assert self._process is not None
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self._process.pid, signum)

    def kill(self) -> int:
        """SIGKILL the process group (a crash: no clean-up runs); returns the exit status."""
        if self._process is None:
            raise RuntimeError(f"{self.executable} was never started")
        self._signal(signal.SIGKILL)
        return self._process.wait(10.0)

    def stop(self, timeout: float = 10.0) -> int | None:
        """SIGINT (Ctrl-C), then SIGTERM, then SIGKILL, ``timeout`` s apart; the exit status.

        None when the process was never started.
        """
        return stop_all([self], timeout)[0]

    def restart(self) -> None:
        """Stop the process if it runs and start it again."""
        self.stop()
        self.start()

    def wait_started(self, timeout: float, idle: Callable[[], None] | None = None) -> bool:
        """Wait until the latest start logged its node's first line (nodes log once their topics
        are set up), the process ended, or ``timeout`` s passed; returns whether it started.

        ``idle`` is called between looks at the log (default: sleep 0.1 s), e.g. to spin a node.
        """
        marker = f"=== start {self.starts}:"
        tag = f"[{NODE_NAMES.get(self.executable, self.executable)}]:"
        deadline = time.monotonic() + timeout
        while self.alive():
            text = self.log_text()
            if tag in text[text.rfind(marker) :]:
                return True
            if time.monotonic() > deadline:
                return False
            if idle is None:
                time.sleep(0.1)
            else:
                idle()
        return False

    def log_text(self) -> str:
        """Everything the process wrote so far, over all starts."""
        try:
            return self.log_path.read_text(errors="replace")
        except FileNotFoundError:
            return ""

    def log_tail(self, lines: int = 25) -> str:
        return "\n".join(self.log_text().splitlines()[-lines:])

    def describe(self) -> str:
        state = "alive" if self.alive() else f"exited with {self.returncode}"
        return f"{self.executable} (pid {self.pid}, {state})"


class Pipeline:
    """The node processes of one test, by executable name (``pipeline["ordering_node"]``)."""

    def __init__(self, processes: dict[str, NodeProcess]) -> None:
        self.processes = processes

    def __getitem__(self, executable: str) -> NodeProcess:
        return self.processes[executable]

    def __iter__(self) -> Iterator[NodeProcess]:
        return iter(self.processes.values())

    def dead(self) -> list[str]:
        return [p.executable for p in self if not p.alive()]

    def report(self, lines: int = 25) -> str:
        """State and log tail of every process, for assertion messages."""
        return "\n".join(
            f"\n----- {p.describe()}, log {p.log_path}:\n{p.log_tail(lines)}" for p in self.processes.values()
        )


def stop_all(processes: Sequence[NodeProcess], timeout: float = 10.0) -> list[int | None]:
    """Stop ``processes`` together, as :meth:`NodeProcess.stop` does one; their exit statuses."""
    running = [p._process for p in processes if p._process is not None]
    for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
        running = [process for process in running if process.poll() is None]
        for process in running:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signum)
        deadline = time.monotonic() + timeout
        for process in running:
            with contextlib.suppress(subprocess.TimeoutExpired):
                process.wait(max(0.0, deadline - time.monotonic()))
    return [None if p._process is None else p._process.wait(timeout) for p in processes]


@contextlib.contextmanager
def pipeline(
    log_dir: Path,
    domain_id: int,
    executables: Iterable[str] = PIPELINE,
    ros_args: dict[str, Sequence[str]] | None = None,
) -> Iterator[Pipeline]:
    """Start the node ``executables`` (default: the four of the graph) and stop them on exit.

    ``ros_args`` adds ``--ros-args`` arguments per executable (e.g. ``["-p", "name:=value"]``).
    Stopping happens however the ``with`` body ends; a node that ignores SIGINT and SIGTERM
    is killed.
    """
    ros_args = ros_args or {}
    log_dir = Path(log_dir)
    log_dir.mkdir(parents=True, exist_ok=True)
    processes = {name: NodeProcess(name, log_dir, domain_id, ros_args.get(name, ())) for name in executables}
    try:
        for process in processes.values():
            process.start()
        yield Pipeline(processes)
    finally:
        stop_all(list(processes.values()), timeout=5.0)


# --------------------------------------------------------------------------- the test's node


@dataclass
class Frame:
    """One frame of a bag as rclpy messages, published in this order by :meth:`Driver.publish_frame`."""

    stamp_ns: int
    messages: list[tuple[str, Any]]
    """(topic, rclpy message): camera_info left and right, tip hint, left and right image."""


FRAME_TOPICS = (
    topics.LEFT_CAMERA_INFO,
    topics.RIGHT_CAMERA_INFO,
    topics.TIP_HINT,
    topics.LEFT_IMAGE,
    topics.RIGHT_IMAGE,
)


def load_frames(bag: Path = SAMPLE_BAG) -> list[Frame]:
    """The frames of ``bag`` (input topics only) by stamp, oldest first."""
    by_stamp: dict[int, dict[str, Any]] = {}
    for topic, msgtype, _, data in read_raw(bag, FRAME_TOPICS):
        message = from_cdr(data, msgtype)
        by_stamp.setdefault(raw_stamp_ns(message.header.stamp), {})[topic] = message
    frames = []
    for stamp, messages in sorted(by_stamp.items()):
        missing = [t for t in FRAME_TOPICS if t not in messages]
        if missing:
            raise ValueError(f"{bag}: frame at {stamp} ns lacks {', '.join(missing)}")
        frames.append(Frame(stamp, [(t, messages[t]) for t in FRAME_TOPICS]))
    return frames


def set_stamp(message: Any, stamp_ns: int) -> Any:
    """Set ``message.header.stamp`` to ``stamp_ns`` (>= 0) in place; returns the message."""
    message.header.stamp.sec, message.header.stamp.nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return message


@dataclass
class Received:
    """One collected message: its header stamp (ns, None for String), content and arrival time."""

    stamp_ns: int | None
    message: Any
    monotonic: float


def raw_stamp_ns(stamp: Any) -> int:
    """sec * 1e9 + nanosec as sent, without the range check of ``ns_from_stamp``: the fuzz test
    keys its own malformed messages (negative or overflowing stamps) by it."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _received(message: Any) -> Received:
    header = getattr(message, "header", None)
    stamp = None if header is None else raw_stamp_ns(header.stamp)
    return Received(stamp, message, time.monotonic())


class Driver:
    """The test's rclpy node, on ``domain_id`` in its own Context, spun only by the test's calls.

    Publishers are created on first use with :data:`RELIABLE_QOS` (which best-effort
    subscribers hear too). ``grasp_poses``, ``target_poses`` and ``states`` collect what
    arrives on the graph's outputs while the test spins.
    """

    def __init__(self, domain_id: int, name: str = "graph_test_driver") -> None:
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._publishers: dict[str, Any] = {}
        self._watched: dict[str, list[Received]] = {}
        self.grasp_poses = self.watch(topics.GRASP_POSE)
        self.target_poses = self.watch(topics.TARGET_POSE)
        self.states = self.watch(topics.EXECUTOR_STATE)

    def watch(self, topic: str) -> list[Received]:
        """What arrives on ``topic`` (see docs/interfaces.md) from now on; the list fills as the test spins.

        Images are subscribed best effort (their publishers are), everything else reliable.
        """
        if topic not in self._watched:
            received: list[Received] = []
            msgtype = topics.TOPIC_TYPES[topic]
            qos = SENSOR_DATA_QOS if msgtype == "sensor_msgs/msg/Image" else RELIABLE_QOS
            self.node.create_subscription(
                message_class(msgtype), topic, lambda m: received.append(_received(m)), qos
            )
            self._watched[topic] = received
        return self._watched[topic]

    def stamps(self, topic: str) -> set[int]:
        """Header stamps of everything received on the watched ``topic``."""
        return {r.stamp_ns for r in self.watch(topic) if r.stamp_ns is not None}

    def publisher(self, topic: str, message_type: Any) -> Any:
        """The publisher of ``topic`` (``message_type``: an rclpy class or 'pkg/msg/Name')."""
        if topic not in self._publishers:
            if isinstance(message_type, str):
                message_type = message_class(message_type)
            self._publishers[topic] = self.node.create_publisher(message_type, topic, RELIABLE_QOS)
        return self._publishers[topic]

    def publish(self, topic: str, message: Any) -> None:
        self.publisher(topic, type(message)).publish(message)

    def publish_frame(self, frame: Frame, stamp_ns: int | None = None) -> int:
        """Publish ``frame`` with the stamp ``stamp_ns`` (default: its own); returns the stamp used.

        The frame's messages are restamped in place (each publish sets the stamp it uses).
        """
        stamp = frame.stamp_ns if stamp_ns is None else stamp_ns
        for topic, message in frame.messages:
            self.publish(topic, set_stamp(message, stamp))
        return stamp

    def play(self, frames: Sequence[Frame], period_s: float, cycle_offset_ns: int = 10**9) -> Player:
        """Publish ``frames`` in a loop, one every ``period_s`` while the test spins (see :class:`Player`)."""
        return Player(self, frames, period_s, cycle_offset_ns)

    def spin(self, seconds: float) -> None:
        """Process callbacks for ``seconds``."""
        deadline = time.monotonic() + seconds
        while (remaining := deadline - time.monotonic()) > 0:
            self.executor.spin_once(timeout_sec=min(0.05, remaining))

    def spin_until(self, predicate: Callable[[], bool], timeout: float) -> bool:
        """Spin until ``predicate()`` or ``timeout`` s; returns the final ``predicate()``."""
        deadline = time.monotonic() + timeout
        while not predicate():
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return bool(predicate())
            self.executor.spin_once(timeout_sec=min(0.05, remaining))
        return True

    def matched(self, topic: str) -> int:
        """Subscriptions matched with this driver's publisher of ``topic`` (a docs/interfaces.md topic)."""
        return self.publisher(topic, topics.TOPIC_TYPES[topic]).get_subscription_count()

    def wait_for_graph(self, expected: dict[str, int], timeout: float) -> bool:
        """Spin until each topic's publisher here has at least its expected matched subscriptions.

        That is DDS discovery done: what is published next reaches those subscribers.
        """
        return self.spin_until(lambda: all(self.matched(t) >= n for t, n in expected.items()), timeout)

    def grasp_stamps(self) -> set[int]:
        return self.stamps(topics.GRASP_POSE)

    def target_stamps(self) -> set[int]:
        return self.stamps(topics.TARGET_POSE)

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.executor.shutdown(timeout_sec=2.0)
        with contextlib.suppress(Exception):
            self.node.destroy_node()
        self.context.try_shutdown()


class Player:
    """Frames published in a loop from a timer of the driver node (so only while the test spins).

    Cycle ``c`` (from 1) publishes every frame with its stamp + ``c * cycle_offset_ns``, so
    every published frame has a fresh, increasing stamp. ``published`` lists (stamp, monotonic
    time) of every frame sent.
    """

    def __init__(
        self, driver: Driver, frames: Sequence[Frame], period_s: float, cycle_offset_ns: int
    ) -> None:
        if not frames:
            raise ValueError("no frames to play")
        span = frames[-1].stamp_ns - frames[0].stamp_ns
        if cycle_offset_ns <= span:
            raise ValueError(f"cycle_offset_ns {cycle_offset_ns} must exceed the frames' span, {span} ns")
        self.driver = driver
        self.frames = list(frames)
        self.cycle_offset_ns = cycle_offset_ns
        self.published: list[tuple[int, float]] = []
        self._count = 0
        self._timer = driver.node.create_timer(period_s, self._tick)

    def _tick(self) -> None:
        cycle, index = divmod(self._count, len(self.frames))
        frame = self.frames[index]
        stamp = self.driver.publish_frame(frame, frame.stamp_ns + (cycle + 1) * self.cycle_offset_ns)
        self.published.append((stamp, time.monotonic()))
        self._count += 1

    def stamps_since(self, monotonic: float) -> set[int]:
        """Stamps of the frames published at or after ``monotonic``."""
        return {stamp for stamp, sent in self.published if sent >= monotonic}

    def stop(self) -> None:
        self._timer.cancel()
        self.driver.node.destroy_timer(self._timer)


PIPELINE_INPUTS: dict[str, dict[str, int]] = {
    "segmentation_node": {topics.LEFT_IMAGE: 1, topics.RIGHT_IMAGE: 1},
    "ordering_node": {topics.LEFT_MASK: 1, topics.RIGHT_MASK: 1, topics.TIP_HINT: 1},
    "reconstruction_node": {topics.LEFT_SEQUENCE: 1, topics.RIGHT_SEQUENCE: 1},
    "executor_node": {topics.GRASP_POSE: 1, topics.PATH: 1},
}
"""Topics that only that node subscribes to in the graph (camera_info has two subscribers)."""


def graph_inputs(executables: Iterable[str] = PIPELINE) -> dict[str, int]:
    """Each input topic of the ``executables`` and how many of them subscribe to it.

    What :meth:`Driver.wait_for_graph` waits for when they have started.
    """
    expected: dict[str, int] = {}
    names = set(executables)
    for name in names:
        for topic, count in PIPELINE_INPUTS.get(name, {}).items():
            expected[topic] = expected.get(topic, 0) + count
    info = sum(1 for n in ("ordering_node", "reconstruction_node") if n in names)
    if info:
        expected[topics.LEFT_CAMERA_INFO] = info
        expected[topics.RIGHT_CAMERA_INFO] = info
    return expected
