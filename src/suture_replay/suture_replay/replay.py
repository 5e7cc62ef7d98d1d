# SPDX-License-Identifier: Apache-2.0
"""Bag replay and recording without ROS: frames of a bag, the replay plan, latency and the report.

:mod:`suture_replay.player_node` and :mod:`suture_replay.recorder_node` are thin rclpy
adapters over this module, which holds everything that can be tested without a ROS graph:

- :func:`load_frames` reads the selected topics of a bag (:mod:`suture_common.bag_io`)
  and groups them into :class:`Frame` objects: all messages sharing one ``header.stamp``.
  A message without a header is grouped by its bag (receive) timestamp instead, so it
  joins the frame whose stamp equals that time, if any. Within a frame the messages are
  in publishing order: camera_info first, then everything else (the tip hint), then
  images, each group in the order of the requested topics. Frames are ordered by when
  they were recorded (the earliest bag timestamp of their messages), then by stamp.
- :func:`plan` repeats the frames ``loops`` times and says when to publish each one.
  Loop ``k`` adds ``k * (stamp span + median stamp period)`` to the header stamps and
  ``k * (recorded span + median recorded period)`` to the recorded times, so stamps stay
  unique and the loops follow each other at the bag's own frame rate. A bag of a single
  frame has no period; :data:`SINGLE_FRAME_PERIOD_NS` (1 s) is used then.
- :class:`PlayerSettings` and :class:`RecorderSettings` check the nodes' parameters.
- :class:`FrameRecord`, :func:`latency_stats`, :func:`build_report` and
  :func:`summary_line` turn publish and output times into the player's JSON report.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from suture_common.bag_io import bag_summary, read_raw
from suture_common.messages import TYPESTORE
from suture_common.parameters import described
from suture_common.topics import GRASP_POSE, INPUT_TOPICS, PIPELINE_OUTPUT_TOPICS, TOPIC_TYPES

IMAGE_TYPES = frozenset({"sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage"})
"""Message types published last in a frame and subscribed best effort by the recorder."""
CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"

SINGLE_FRAME_PERIOD_NS = 1_000_000_000
"""Loop period of a bag holding a single frame (it has no frame period of its own)."""

FrameMessage = tuple[str, str, bytes]
"""``(topic, msgtype, cdr_bytes)`` of one message of a frame."""


@dataclass(frozen=True)
class Frame:
    """The messages of the selected topics that share one header stamp.

    ``stamp_ns``: the shared ``header.stamp`` (for a frame of header-less messages, their
    bag timestamp); ``recorded_ns``: the earliest bag timestamp of the messages, i.e. when
    the frame was recorded; ``messages``: ``(topic, msgtype, cdr)`` in publishing order;
    ``stamped``: per message, whether it has a top-level ``header`` (whose stamp a loop
    offset changes).
    """

    stamp_ns: int
    recorded_ns: int
    messages: tuple[FrameMessage, ...]
    stamped: tuple[bool, ...]


@dataclass(frozen=True)
class LoadedBag:
    """What :func:`load_frames` found: frames, the selected topics present and absent, their types."""

    frames: list[Frame]
    found: list[str]
    missing: list[str]
    types: dict[str, str]


def load_frames(path: str | Path, topics: Sequence[str]) -> LoadedBag:
    """Read ``topics`` of the bag at ``path`` and group them into frames (see the module docstring).

    Topics absent from the bag are listed in :attr:`LoadedBag.missing`. Raises
    :class:`suture_common.bag_io.BagError` (an ``OSError``) when the bag cannot be read.
    """
    if isinstance(topics, str):
        raise TypeError(f"topics must be a sequence of topic names, got the string {topics!r}")
    summary = bag_summary(path)
    found = [topic for topic in dict.fromkeys(topics) if topic in summary]
    missing = [topic for topic in dict.fromkeys(topics) if topic not in summary]
    types = {topic: summary[topic][0] for topic in found}
    topic_rank = {topic: rank for rank, topic in enumerate(found)}

    grouped: dict[int, list[tuple[tuple[int, int, int], int, FrameMessage, bool]]] = {}
    for position, (topic, msgtype, timestamp, data) in enumerate(read_raw(path, found)):
        stamp = header_stamp_ns(msgtype, data)
        key = timestamp if stamp is None else stamp
        order = (_type_rank(msgtype), topic_rank[topic], position)
        grouped.setdefault(key, []).append((order, timestamp, (topic, msgtype, data), stamp is not None))
    frames = []
    for stamp_ns, entries in grouped.items():
        entries.sort(key=lambda entry: entry[0])
        frames.append(
            Frame(
                stamp_ns=stamp_ns,
                recorded_ns=min(entry[1] for entry in entries),
                messages=tuple(entry[2] for entry in entries),
                stamped=tuple(entry[3] for entry in entries),
            )
        )
    frames.sort(key=lambda frame: (frame.recorded_ns, frame.stamp_ns))
    return LoadedBag(frames, found, missing, types)


def header_stamp_ns(msgtype: str, cdr: bytes) -> int | None:
    """``header.stamp`` of a serialised message in ns, or None if the type has no top-level header.

    Types outside :data:`suture_common.messages.TYPESTORE` count as header-less.
    """
    if msgtype not in TYPESTORE.types:
        return None
    fields = TYPESTORE.get_msgdef(msgtype).fields
    if not any(name == "header" and kind[1] == "std_msgs/msg/Header" for name, kind in fields):
        return None
    header = TYPESTORE.deserialize_cdr(cdr, msgtype).header
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def _type_rank(msgtype: str) -> int:
    if msgtype == CAMERA_INFO_TYPE:
        return 0
    if msgtype in IMAGE_TYPES:
        return 2
    return 1


# --------------------------------------------------------------------------- the plan


@dataclass(frozen=True)
class PlannedFrame:
    """One frame as it will be published: which frame, which loop, its stamp and when.

    ``offset_ns`` is added to the frame's header stamps (``stamp_ns = frame.stamp_ns +
    offset_ns``); ``due_s`` is the time after the start of the replay at which it is
    published when following the recorded timing.
    """

    index: int
    loop: int
    frame_index: int
    frame: Frame
    offset_ns: int
    stamp_ns: int
    due_s: float


def loop_period_ns(values: Iterable[int]) -> int:
    """Span of ``values`` plus their median step: the shift that puts a copy right after them.

    The median is taken over the positive steps between sorted distinct values; with
    fewer than two distinct values :data:`SINGLE_FRAME_PERIOD_NS` is used as the step.
    """
    ordered = sorted(set(values))
    if len(ordered) < 2:
        return SINGLE_FRAME_PERIOD_NS
    step = int(np.median(np.diff(np.asarray(ordered, dtype=np.int64))))
    return ordered[-1] - ordered[0] + step


def plan(frames: Sequence[Frame], rate: float = 1.0, loops: int = 1) -> list[PlannedFrame]:
    """The replay of ``frames`` ``loops`` times at ``rate`` (2.0 = twice as fast), in order.

    ``due_s`` of the first frame is 0; the others follow their recorded times divided by
    ``rate``. Loop offsets as in the module docstring.
    """
    if not rate > 0 or not math.isfinite(rate):
        raise ValueError(f"rate must be a finite number > 0, got {rate}")
    if loops < 1:
        raise ValueError(f"loops must be at least 1, got {loops}")
    if not frames:
        return []
    stamp_period = loop_period_ns(frame.stamp_ns for frame in frames)
    recorded_period = loop_period_ns(frame.recorded_ns for frame in frames)
    start = frames[0].recorded_ns
    planned = []
    for loop in range(loops):
        for frame_index, frame in enumerate(frames):
            offset = loop * stamp_period
            recorded = frame.recorded_ns - start + loop * recorded_period
            planned.append(
                PlannedFrame(
                    index=len(planned),
                    loop=loop,
                    frame_index=frame_index,
                    frame=frame,
                    offset_ns=offset,
                    stamp_ns=frame.stamp_ns + offset,
                    due_s=recorded / 1e9 / rate,
                )
            )
    return planned


# --------------------------------------------------------------------------- parameters


def _finite(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{name} must be a number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value}")
    return value


def _topic_list(name: str, topics: Any) -> tuple[str, ...]:
    """``topics`` checked, as a tuple; a single name is a list of one (``-p topics:=/a`` at start-up)."""
    if isinstance(topics, str):
        topics = [topics]
    if not all(isinstance(t, str) for t in topics):
        raise ValueError(f"{name} must be a list of topic names, got {topics!r}")
    topics = tuple(topics)
    if not topics:
        raise ValueError(f"{name} is empty; name at least one topic")
    for topic in topics:
        if not topic.startswith("/"):
            raise ValueError(f"topic {topic!r} in {name} must be absolute (start with '/')")
    return topics


@dataclass(frozen=True)
class PlayerSettings:
    """The player's parameters, checked (a bad value raises ValueError naming the parameter).

    Each field's metadata holds its description and range as a ROS parameter of player_node."""

    bag: str = field(metadata=described("rosbag2 MCAP directory or .mcap file to replay (required)"))
    topics: tuple[str, ...] = field(
        default=INPUT_TOPICS, metadata=described("topics to replay; those absent from the bag are skipped")
    )
    rate: float = field(
        default=1.0,
        metadata=described("speed factor of the recorded timing (2.0 = twice as fast); > 0", (0.0, 1000.0)),
    )
    wait_for_output: bool = field(
        default=False,
        metadata=described(
            "publish the next frame once the output of the previous one arrived (or wait_timeout)"
        ),
    )
    output_topic: str = field(
        default=GRASP_POSE, metadata=described("output matched to frames by header stamp for latency")
    )
    wait_timeout: float = field(
        default=2.0,
        metadata=described("seconds to wait for a frame's output in wait_for_output mode", (0.0, 3600.0)),
    )
    loops: int = field(
        default=1,
        metadata=described(
            "times to replay the bag; later loops shift stamps by the bag span + one period", (1, 1_000_000)
        ),
    )
    start_timeout: float = field(
        default=15.0,
        metadata=described("seconds to wait for image subscribers and an output publisher", (0.0, 3600.0)),
    )
    linger: float = field(
        default=1.0,
        metadata=described("seconds to keep receiving outputs after the last frame", (0.0, 3600.0)),
    )
    report: str = field(default="", metadata=described("JSON report file to write at the end; empty: none"))

    def __post_init__(self) -> None:
        if not isinstance(self.bag, str):
            raise ValueError(f"bag must be a path, got {self.bag!r}")
        if not self.bag:
            raise ValueError("parameter 'bag' is required: a rosbag2 MCAP directory or .mcap file")
        object.__setattr__(self, "topics", _topic_list("topics", self.topics))
        for name in ("rate", "wait_timeout", "start_timeout", "linger"):
            object.__setattr__(self, name, _finite(name, getattr(self, name)))
        if self.rate <= 0:
            raise ValueError(f"rate must be > 0 (1.0 = recorded speed), got {self.rate}")
        if self.wait_timeout <= 0:
            raise ValueError(f"wait_timeout must be > 0 s, got {self.wait_timeout}")
        for name in ("start_timeout", "linger"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0 s, got {getattr(self, name)}")
        loops = _finite("loops", self.loops)
        if loops != int(loops) or loops < 1:
            raise ValueError(f"loops must be a whole number >= 1, got {self.loops}")
        object.__setattr__(self, "loops", int(loops))
        if not isinstance(self.output_topic, str) or not self.output_topic.startswith("/"):
            raise ValueError(f"output_topic {self.output_topic!r} must be absolute (start with '/')")
        if not isinstance(self.wait_for_output, bool):
            raise ValueError(f"wait_for_output must be true or false, got {self.wait_for_output!r}")
        if not isinstance(self.report, str):
            raise ValueError(f"report must be a file path, got {self.report!r}")


@dataclass(frozen=True)
class RecorderSettings:
    """The recorder's parameters, checked; ``types`` maps each topic to its type (TOPIC_TYPES).

    ``output`` and ``topics`` carry their description as ROS parameters of recorder_node."""

    output: str = field(metadata=described("rosbag2 directory to create (required; must not exist)"))
    topics: tuple[str, ...] = field(
        default=PIPELINE_OUTPUT_TOPICS,
        metadata=described(
            "topics to record (those of docs/interfaces.md only); a single name is a list of one"
        ),
    )
    types: dict[str, str] = field(init=False)

    def __post_init__(self) -> None:
        if not isinstance(self.output, str):
            raise ValueError(f"output must be a path, got {self.output!r}")
        if not self.output:
            raise ValueError("parameter 'output' is required: the rosbag2 directory to create")
        if Path(self.output).exists() or Path(self.output).is_symlink():
            raise ValueError(f"output {self.output} exists already; choose a new bag path")
        topics = _topic_list("topics", self.topics)
        unknown = [topic for topic in topics if topic not in TOPIC_TYPES]
        if unknown:
            raise ValueError(
                f"topic {unknown[0]} has no known type (the recorder records the docs/interfaces.md topics "
                f"of suture_common.topics.TOPIC_TYPES only)"
            )
        object.__setattr__(self, "topics", tuple(dict.fromkeys(topics)))
        object.__setattr__(self, "types", {topic: TOPIC_TYPES[topic] for topic in self.topics})


# --------------------------------------------------------------------------- latency and report


@dataclass
class FrameRecord:
    """Wall times (s since the epoch) of one replayed frame: published, and its output received."""

    stamp_ns: int
    published_s: float
    output_s: float | None = None

    @property
    def latency_ms(self) -> float | None:
        """Publish-to-output time in ms, or None without an output."""
        if self.output_s is None:
            return None
        return (self.output_s - self.published_s) * 1000.0


def latency_stats(latencies_ms: Iterable[float | None]) -> dict[str, float | None]:
    """``{"median", "p95", "max"}`` of the measured latencies (None entries ignored; all None if none).

    p95 is numpy's linearly interpolated 95th percentile.
    """
    values = np.asarray([v for v in latencies_ms if v is not None], dtype=np.float64)
    if values.size == 0:
        return {"median": None, "p95": None, "max": None}
    return {
        "median": float(np.median(values)),
        "p95": float(np.percentile(values, 95)),
        "max": float(values.max()),
    }


def build_report(records: Sequence[FrameRecord], mode: str, rate: float) -> dict[str, Any]:
    """The player's JSON report: keys always present, null where a value cannot be measured.

    ``fps`` = outputs / (last output time - first publish time).
    """
    if mode not in ("graph", "recorded"):
        raise ValueError(f"mode must be 'graph' or 'recorded', got {mode!r}")
    outputs = [r.output_s for r in records if r.output_s is not None]
    fps = None
    if outputs:
        span = max(outputs) - min(r.published_s for r in records)
        if span > 0:
            fps = len(outputs) / span
    return {
        "frames": len(records),
        "outputs": len(outputs),
        "latency_ms": latency_stats(r.latency_ms for r in records),
        "fps": fps,
        "mode": mode,
        "rate": float(rate),
        "per_frame": [
            {
                "stamp_ns": r.stamp_ns,
                "published_s": r.published_s,
                "output_s": r.output_s,
                "latency_ms": r.latency_ms,
            }
            for r in records
        ],
    }


def summary_line(report: dict[str, Any]) -> str:
    """``replayed N frames, M outputs, latency median X ms p95 Y ms, Z fps`` ('n/a' where null)."""

    def show(value: float | None, digits: int) -> str:
        return "n/a" if value is None else f"{value:.{digits}f}"

    latency = report["latency_ms"]
    return (
        f"replayed {report['frames']} frames, {report['outputs']} outputs, "
        f"latency median {show(latency['median'], 1)} ms p95 {show(latency['p95'], 1)} ms, "
        f"{show(report['fps'], 2)} fps"
    )


def write_report(path: str | Path, report: dict[str, Any]) -> None:
    """Write ``report`` as JSON to ``path``, creating its parent directories."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(report, indent=2) + "\n")
