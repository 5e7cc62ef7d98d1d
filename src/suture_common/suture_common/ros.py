# SPDX-License-Identifier: Apache-2.0
"""rclpy glue shared by the nodes and node tests: message classes, CDR, QoS, spinning.

This is the only module of ``suture_common`` that imports rclpy; everything else
stays ROS-free. Messages built by :mod:`suture_common.messages` (rosbags
dataclasses) are published as their CDR bytes (:func:`serialized`) or become rclpy
messages through them (:func:`to_rclpy`), which is also how bag messages are replayed
(:func:`from_cdr`). :class:`ThrottledWarnings`
is the nodes' one way of reporting dropped input (docs/interfaces.md, "Bad input").
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import importlib
import math
import os
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from typing import Any, TypeVar

import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException, ParameterException
from rclpy.executors import (
    ConditionReachedException,
    Executor,
    ExternalShutdownException,
    ShutdownException,
    SingleThreadedExecutor,
    TimeoutException,
)
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.serialization import deserialize_message, serialize_message
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future, Task

from suture_common.messages import TYPESTORE, MessageConversionError, ns_from_stamp
from suture_common.parameters import INT64_MAX, ParameterSpec, ParameterValueError
from suture_common.stop_signals import StopSignals

N = TypeVar("N", bound=Node)

STOP_POLL_S = 0.1
"""Longest wait of a node's spin loop before it looks at the stop flag again (s)."""

TEARDOWN_TIMEOUT_S = 10.0
"""Longest the middleware's teardown (executor, node, context) may take once a node's own
clean-up is done (s); past it the process exits with its status without waiting for it."""

SENSOR_DATA_QOS: QoSProfile = qos_profile_sensor_data
"""Images: best effort, keep last 5, volatile (rclpy's sensor-data profile)."""


def sensor_data_qos(depth: int) -> QoSProfile:
    """:data:`SENSOR_DATA_QOS` keeping the last ``depth`` messages (>= 1; ValueError otherwise)."""
    if depth < 1:
        raise ValueError(f"queue depth must be at least 1, got {depth}")
    sensor = qos_profile_sensor_data
    return QoSProfile(
        depth=depth, history=sensor.history, reliability=sensor.reliability, durability=sensor.durability
    )


RELIABLE_QOS = QoSProfile(depth=10, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE)
"""Poses, sequences, commands: reliable, keep last 10, volatile."""


def message_class(msgtype: str) -> Any:
    """The rclpy message class of ``msgtype``, e.g. 'sensor_msgs/msg/Image' -> sensor_msgs.msg.Image.

    The short form 'sensor_msgs/Image' is accepted too. Raises ValueError when the
    name is malformed or its package is not installed.
    """
    parts = msgtype.split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3 or not all(parts) or parts[1] not in ("msg", "srv", "action"):
        raise ValueError(f"message type {msgtype!r} is not of the form 'package/msg/Name'")
    package, kind, name = parts
    try:
        module = importlib.import_module(f"{package}.{kind}")
    except ImportError as exc:
        wheel = "ros-jazzy-" + package.replace("_", "-")
        raise ValueError(
            f"no Python module for message package {package!r} ({exc}); "
            f"install {wheel} or source its workspace"
        ) from None
    try:
        cls = getattr(module, name)
    except AttributeError:
        raise ValueError(f"package {package} has no {kind} type {name!r}") from None
    return cls


def from_cdr(cdr_bytes: bytes | memoryview, msgtype: str) -> Any:
    """Deserialise CDR bytes (with encapsulation header, as stored in bags) into an rclpy message."""
    return deserialize_message(bytes(cdr_bytes), message_class(msgtype))


def to_cdr(message: Any) -> bytes:
    """CDR bytes of an rclpy message (the inverse of :func:`from_cdr`)."""
    return bytes(serialize_message(message))


def to_rclpy(message: Any) -> Any:
    """The rclpy equivalent of a rosbags message (e.g. from :mod:`suture_common.messages`)."""
    msgtype = message.__msgtype__
    return from_cdr(TYPESTORE.serialize_cdr(message, msgtype), msgtype)


def serialized(message: Any) -> bytes:
    """CDR bytes of a rosbags message, for ``Publisher.publish`` of its rclpy type.

    rclpy publishes bytes as they are. Going through :func:`to_rclpy` instead costs a
    conversion into Python objects and rclpy's own serialisation of them: publishing a
    200-pose Path took 6.0 ms that way against 1.6 ms, a 450-point polygon 1.35 against 0.41 ms.
    """
    return bytes(TYPESTORE.serialize_cdr(message, message.__msgtype__))


def parameter_descriptor(spec: ParameterSpec) -> ParameterDescriptor:
    """The descriptor of ``spec``: its description, its type, and its range for a number.

    A dynamically typed number gets both an integer and a floating-point range, since rclpy
    checks the one of the type it is given.
    """
    descriptor = ParameterDescriptor(description=spec.description, dynamic_typing=spec.dynamic_typing)
    if spec.range is not None:
        low, high = spec.range
        if spec.kind == "double" or spec.dynamic_typing:
            float_range = FloatingPointRange(from_value=float(low), to_value=float(high))
            descriptor.floating_point_range = [float_range]
        if spec.kind == "integer" or spec.dynamic_typing:
            int_low = -INT64_MAX - 1 if low == -math.inf else math.ceil(low)
            int_high = INT64_MAX if high == math.inf else math.floor(high)
            descriptor.integer_range = [IntegerRange(from_value=int_low, to_value=int_high)]
    return descriptor


def declare_parameters(node: Node, specs: Iterable[ParameterSpec]) -> dict[str, Any]:
    """Declare ``specs`` on ``node`` (with :func:`parameter_descriptor`); their values by name.

    A value given at start-up of the wrong type or outside its range raises
    :class:`~suture_common.parameters.ParameterValueError` naming the parameter, the value and
    what is accepted (for the executable: one line on standard error, exit status 1).
    """
    values = {}
    for spec in specs:
        try:
            parameter = node.declare_parameter(spec.name, spec.default, parameter_descriptor(spec))
        except (InvalidParameterTypeException, InvalidParameterValueException) as exc:
            given = node._parameter_overrides.get(spec.name)  # the refused start-up value
            problem = spec.problem(given.value) if given is not None else None
            raise ParameterValueError(problem or f"parameter {spec.name}: {exc}") from None
        values[spec.name] = parameter.value
    return values


def spin_until(executor: Executor, predicate: Callable[[], bool], timeout_s: float) -> bool:
    """Spin ``executor`` until ``predicate()`` is true or ``timeout_s`` seconds pass.

    Returns the final ``predicate()``, so tests can write ``assert spin_until(...)``.
    """
    deadline = time.monotonic() + timeout_s
    while not predicate():
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            return bool(predicate())
        executor.spin_once(timeout_sec=min(0.05, remaining))
    return True


class ThrottledWarnings:
    """Per-reason throttled warnings of a node: what it logs when it drops an input.

    :meth:`warn` logs the first warning of a reason at once and then at most one every
    ``period_s`` seconds (monotonic clock), so a stream of identical bad frames gives one
    line per period while a new problem is reported immediately. Every call is counted in
    :attr:`counts`, logged or not. ``logger`` is anything with a ``warning(str)`` method,
    e.g. ``node.get_logger()``.
    """

    def __init__(self, logger: Any, period_s: float, clock: Callable[[], float] = time.monotonic) -> None:
        self.logger = logger
        self.period_s = float(period_s)
        self._clock = clock
        self._last: dict[str, float] = {}
        self.counts: dict[str, int] = {}
        """Calls of :meth:`warn` by reason (the inputs dropped for that reason)."""

    def warn(self, reason: str, text: str) -> bool:
        """Count ``reason`` and log ``text`` unless ``reason`` was logged within the period.

        Returns whether the line was logged.
        """
        self.counts[reason] = self.counts.get(reason, 0) + 1
        now = self._clock()
        last = self._last.get(reason)
        if last is not None and now - last < self.period_s:
            return False
        self._last[reason] = now
        self.logger.warning(text)
        return True


def stamp_or_drop(message: Any, drop: Callable[[str, str], object], what: str) -> int | None:
    """The header stamp (ns) of ``message``, or None after ``drop("bad_stamp", text)``.

    ``drop`` is the node's per-reason warning, e.g. :meth:`ThrottledWarnings.warn`; a stamp no
    output could carry (see :func:`suture_common.messages.ns_from_stamp`) drops ``what``.
    """
    try:
        return ns_from_stamp(message.header.stamp)
    except MessageConversionError as exc:
        drop("bad_stamp", f"dropped {what}: {exc}")
        return None


class ThreadPoolExecutor(Executor):
    """rclpy's multi-threaded executor with a shutdown that no callback outlives.

    Like ``rclpy.executors.MultiThreadedExecutor``, :meth:`spin_once` hands each ready callback
    to a pool of ``num_threads`` threads, so a service callback that waits for a robot does not
    block the subscriptions that end the wait. Its :meth:`shutdown` first lets the callbacks
    already handed to the pool finish (a service answering "aborted"), up to
    ``drain_timeout_s``, so none runs against a node or executor that is being destroyed.
    """

    def __init__(self, num_threads: int, *, context: Any = None, drain_timeout_s: float = 5.0) -> None:
        super().__init__(context=context)
        self._pool = concurrent.futures.ThreadPoolExecutor(num_threads)
        self._drain_timeout_s = drain_timeout_s
        self._running: list[tuple[concurrent.futures.Future, Task]] = []

    def spin_once(self, timeout_sec: float | None = None) -> None:
        """Wait up to ``timeout_sec`` for one ready callback and start it on the pool.

        A callback that has raised since the last call raises here, as in rclpy's executors.
        """
        self._spin_once(timeout_sec)

    def spin_once_until_future_complete(self, future: Future, timeout_sec: float | None = None) -> None:
        """:meth:`spin_once` that also returns as soon as ``future`` is done."""
        future.add_done_callback(lambda _: self.wake())
        self._spin_once(timeout_sec, future.done)

    def _spin_once(self, timeout_sec: float | None, condition: Callable[[], bool] = lambda: False) -> None:
        try:
            handler, _, _ = self.wait_for_ready_callbacks(timeout_sec, None, condition)
        except (ShutdownException, TimeoutException, ExternalShutdownException, ConditionReachedException):
            pass
        else:
            self._running.append((self._pool.submit(handler), handler))
        finished = [entry for entry in self._running if entry[0].done()]
        for entry in finished:
            self._running.remove(entry)
        for _, task in finished:
            task.result()  # rclpy's Task keeps a callback's exception; it is raised here

    def shutdown(self, timeout_sec: float | None = None) -> bool:
        """Let the callbacks handed to the pool finish (bounded), then shut the executor down."""
        # before rclpy's shutdown, which destroys the guard condition that callbacks still trigger
        concurrent.futures.wait([future for future, _ in self._running], timeout=self._drain_timeout_s)
        self._pool.shutdown(wait=False, cancel_futures=True)
        return super().shutdown(timeout_sec)


def run_node(
    make_node: Callable[[], N],
    name: str,
    args: list[str] | None = None,
    *,
    make_executor: Callable[[], Executor] = SingleThreadedExecutor,
    finished: Callable[[N], bool] | None = None,
    finish: Callable[[N], None] | None = None,
    finish_error: Callable[[N, OSError], str] = lambda node, exc: str(exc),
) -> int:
    """The body of every node executable's ``main()`` (what ``ros2 run PKG EXE`` runs).

    Turns SIGINT and SIGTERM into a flag (:class:`~suture_common.stop_signals.StopSignals`;
    rclpy's own handlers are off), initialises rclpy, builds the node, and spins it until a
    signal, an external shutdown or ``finished(node)``. Then ``finish(node)`` runs while ROS is
    still up (a recorder finalises its bag, the executor tells the arm to hold), and the
    executor, the node and the context are shut down in that order. A signal at any moment,
    during construction included, leaves through this path: no traceback, exit status 0. Should
    that teardown stall in the middleware for :data:`TEARDOWN_TIMEOUT_S`, the process ends there
    with its status and a line on standard error.

    A ``ValueError`` or rclpy ``ParameterException`` while building the node (a bad
    parameter) and an ``OSError`` from ``finish`` (worded by ``finish_error``) are one line on
    standard error, ``"{name}: {problem}"``, and exit status 1. ``make_executor`` chooses the
    executor (single-threaded by default). Returns the exit status.
    """
    with StopSignals() as stop:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
        node: N | None = None
        executor: Executor | None = None
        status = 1  # an exception leaving the body
        try:
            try:
                node = make_node()
            except (ValueError, ParameterException) as exc:
                print(f"{name}: {exc}", file=sys.stderr)
                return status
            executor = make_executor()
            executor.add_node(node)
            with contextlib.suppress(ExternalShutdownException):
                while stop.received is None and not (finished is not None and finished(node)):
                    executor.spin_once(timeout_sec=STOP_POLL_S)
            if finish is not None:
                try:
                    finish(node)
                except OSError as exc:
                    print(f"{name}: {finish_error(node, exc)}", file=sys.stderr)
                    return status
            status = 0
            return status
        finally:
            with _exit_if_teardown_stalls(name, lambda: status):
                if executor is not None:
                    executor.shutdown()
                if node is not None:
                    node.destroy_node()
                rclpy.try_shutdown()


@contextlib.contextmanager
def _exit_if_teardown_stalls(name: str, status: Callable[[], int]) -> Iterator[None]:
    """Run the body (the middleware's teardown); if it has not returned after
    :data:`TEARDOWN_TIMEOUT_S`, say so on standard error and end the process with ``status()``
    at once. On a loaded machine the middleware's teardown has been seen to stall for more than
    30 s; by then the node's work is done and its files are closed, and a node that never exits
    keeps its launcher and the operator waiting."""

    def give_up() -> None:
        print(
            f"{name}: the middleware's shutdown did not finish within {TEARDOWN_TIMEOUT_S:g} s; "
            "exiting without it",
            file=sys.stderr,
        )
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status())

    watchdog = threading.Timer(TEARDOWN_TIMEOUT_S, give_up)
    watchdog.daemon = True
    watchdog.start()
    try:
        yield
    finally:
        watchdog.cancel()
