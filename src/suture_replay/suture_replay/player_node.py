# SPDX-License-Identifier: Apache-2.0
"""player_node: replay a bag's input topics into the ROS graph and measure the pipeline's latency.

What ``ros2 bag play`` does for this project (which has no rosbag2), plus a latency
probe. The selected topics of the bag are read, grouped into frames (all messages with
one ``header.stamp``) and deserialised into rclpy messages before the first one is
published, so publishing costs nothing at replay time (:mod:`suture_replay.replay`).
Header stamps are kept as recorded (plus the loop offset), never replaced by now.

Parameters (read at start-up; numbers accept ints or doubles; :data:`PARAMETERS`):

- ``bag`` (string, required): rosbag2 MCAP directory or ``.mcap`` file.
- ``topics`` (string array, default the inputs of docs/interfaces.md: stereo images, camera_info,
  tip hint). Topics absent from the bag are skipped with one info line; a bag with none
  of them is an error.
- ``rate`` (double, default 1.0): recorded timing divided by this (2.0 = twice as fast).
- ``wait_for_output`` (bool, default false): publish each frame as soon as the previous
  one's output arrived on ``output_topic`` (or ``wait_timeout`` passed), i.e. as fast as
  the graph keeps up, instead of following the recorded timing.
- ``output_topic`` (string, default ``/suture/grasp_pose``): where outputs are matched to
  frames by header stamp. Its type is geometry_msgs/PoseStamped, or the docs/interfaces.md type
  when the topic is one of suture_common.topics.TOPIC_TYPES (e.g. ``/suture/left/mask``
  to time the segmentation alone; image topics are then subscribed best effort).
- ``wait_timeout`` (double s, default 2.0): longest wait for one frame's output. The first
  frame doubles as a probe of the whole graph: without its output it is sent again, at most
  :data:`FIRST_FRAME_RESENDS` times, because matched player topics do not mean that the nodes
  have discovered each other (on a loaded machine a node's reliable output written before its
  subscriber matched is lost to it, and the discovery retry comes seconds later).
- ``loops`` (int, default 1): replay the bag this many times; loop k shifts header stamps
  and the schedule by k * (bag span + median frame period).
- ``start_timeout`` (double s, default 15.0): before the first frame, wait until every
  replayed topic has a subscriber, every subscriber the graph knows of on the replayed topics
  is matched, and ``output_topic`` has a publisher, at most this long, then
  start anyway with a warning naming what is missing; the first frame follows
  :data:`SETTLE_S` later (a best-effort sample sent at discovery can be lost); during that
  settle the first frame's camera_info and tip hint go out every :data:`PRIME_PERIOD_S`, as
  from a running camera driver, so a subscriber whose side of the match completes late
  still has them for the first frame.
- ``linger`` (double s, default 1.0): after the last frame, keep receiving outputs this
  long (with ``wait_for_output``: until the last frame's output or ``wait_timeout``).
- ``report`` (string, default ""): JSON report file to write (see
  :func:`suture_replay.replay.build_report`), latency measured from publishing a frame's
  first image to receiving the output with its stamp.

Within a frame camera_info is published first, then the tip hint, then the images.
Publishers are reliable, keep last 10, like ``ros2 bag play``: both best-effort and
reliable subscribers receive them. At the end the node logs ``replayed N frames, M
outputs, latency median X ms p95 Y ms, Z fps`` and the executable exits 0; SIGINT and
SIGTERM stop it early the same way (report written for what was played). A bad
parameter or unreadable bag: one line ``player_node: ...`` on standard error, exit 1.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from suture_common.parameters import ParameterSpec, field_parameter, spec_table
from suture_common.ros import (
    RELIABLE_QOS,
    SENSOR_DATA_QOS,
    declare_parameters,
    from_cdr,
    message_class,
    run_node,
)
from suture_common.topics import TOPIC_TYPES
from suture_replay.replay import (
    IMAGE_TYPES,
    FrameRecord,
    PlannedFrame,
    PlayerSettings,
    build_report,
    load_frames,
    plan,
    summary_line,
    write_report,
)

NODE_NAME = "player"
EXECUTABLE = "player_node"
DEFAULT_OUTPUT_TYPE = "geometry_msgs/msg/PoseStamped"
START_POLL_S = 0.05
SETTLE_S = 1.0
"""Seconds between finding every endpoint and the first frame (see the "settling" phase)."""
PRIME_PERIOD_S = 0.2
"""While settling, the first frame's camera_info and tip hint are sent this often."""
FIRST_FRAME_RESENDS = 2
"""Graph mode: times the first frame is sent again when its output does not come (see wait_timeout)."""

PUBLISH_QOS = QoSProfile(depth=10, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE)
"""What ``ros2 bag play`` offers by default: reliable, keep last 10, volatile."""

PARAMETERS: dict[str, ParameterSpec] = spec_table(
    # dynamic typing: numbers may be given as ints or doubles, ``topics`` as a single string;
    # ``bag`` is required: empty by default
    field_parameter(
        PlayerSettings, name, default="" if name == "bag" else dataclasses.MISSING, dynamic_typing=True
    )
    for name in (field.name for field in dataclasses.fields(PlayerSettings))
)
"""Every parameter, by name: the fields of :class:`PlayerSettings` (descriptions and ranges there)."""


class PlayerNode(Node):
    """Publishes the frames of a bag on a timer (recorded timing) or as outputs arrive (graph mode).

    Spin it with any executor until :attr:`finished`; :meth:`finish` ends it early.
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        try:
            self._setup()
        except BaseException:
            self.destroy_node()
            raise

    def _setup(self) -> None:
        values = declare_parameters(self, PARAMETERS.values())
        self.settings = settings = PlayerSettings(**values)  # ValueError on a bad value
        output_type = TOPIC_TYPES.get(settings.output_topic, DEFAULT_OUTPUT_TYPE)
        output_class = message_class(output_type)
        if not hasattr(output_class, "header"):
            raise ValueError(f"output_topic {settings.output_topic} ({output_type}) has no header stamp")

        try:
            loaded = load_frames(settings.bag, settings.topics)
        except OSError as exc:  # BagError: the text names the path and the problem
            raise ValueError(str(exc)) from exc
        if not loaded.frames:
            raise ValueError(f"bag {settings.bag} has no messages on {', '.join(settings.topics)}")
        for topic in loaded.missing:
            self.get_logger().info(f"topic {topic} is not in {settings.bag}; skipped")

        self._frame_publishers = {
            topic: self.create_publisher(message_class(msgtype), topic, PUBLISH_QOS)
            for topic, msgtype in loaded.types.items()
        }
        # Deserialised once; a loop only rewrites the header stamps of these objects.
        self._messages = [
            [
                (self._frame_publishers[topic], from_cdr(cdr, msgtype), stamped, msgtype in IMAGE_TYPES)
                for (topic, msgtype, cdr), stamped in zip(frame.messages, frame.stamped, strict=True)
            ]
            for frame in loaded.frames
        ]
        # The plan needs stamps and times only; dropping the CDR bytes halves the memory held.
        bare = [dataclasses.replace(frame, messages=(), stamped=()) for frame in loaded.frames]
        self._plan: list[PlannedFrame] = plan(bare, settings.rate, settings.loops)
        output_qos = SENSOR_DATA_QOS if output_type in IMAGE_TYPES else RELIABLE_QOS
        self.create_subscription(output_class, settings.output_topic, self._on_output, output_qos)

        self.records: list[FrameRecord] = []
        """One per published frame, in publishing order."""
        self.report: dict[str, Any] | None = None
        """The report dict, once finished."""
        self.finished = False
        self._by_stamp: dict[int, FrameRecord] = {}
        self._next = 0  # index into self._plan of the next frame to publish
        self._pending: int | None = None  # stamp awaited in wait_for_output mode
        self._resends = 0  # of the first frame, in wait_for_output mode
        self._phase = "starting"
        self._settled_at = 0.0
        self._created = time.monotonic()
        self._t0 = 0.0
        self._linger_until = 0.0
        self._timer = self.create_timer(
            START_POLL_S, self._on_timer, clock=Clock(clock_type=ClockType.STEADY_TIME)
        )
        self.get_logger().info(
            f"loaded {len(loaded.frames)} frames on {len(loaded.found)} topics from {settings.bag}; "
            f"{len(self._plan)} frames to replay "
            + ("as fast as the graph keeps up" if settings.wait_for_output else f"at rate {settings.rate:g}")
        )

    # ------------------------------------------------------------------ state machine

    def _arm(self, delay_s: float) -> None:
        """Fire the timer once more, ``delay_s`` from now."""
        self._timer.timer_period_ns = max(1000, int(delay_s * 1e9))
        self._timer.reset()

    def _missing_endpoints(self) -> list[str]:
        # every replayed topic needs a subscriber: with images only, a node that comes up late
        # (ordering_node under load) missed the first frame's camera_info, tip hint and masks
        missing = [
            f"a subscriber on {topic}"
            for topic, publisher in self._frame_publishers.items()
            if publisher.get_subscription_count() < 1
        ]
        # every subscriber the graph already knows of must be matched too (e.g. camera_info of the
        # ordering and reconstruction nodes), or the first frame's messages can miss it
        missing += [
            f"a match with every subscriber on {topic}"
            for topic, publisher in self._frame_publishers.items()
            if publisher.get_subscription_count() < self.count_subscribers(topic)
        ]
        if self.count_publishers(self.settings.output_topic) < 1:
            missing.append(f"a publisher on {self.settings.output_topic}")
        return missing

    def _on_timer(self) -> None:
        if self.finished:
            return
        now = time.monotonic()
        if self._phase == "starting":
            missing = self._missing_endpoints()
            if missing and now - self._created < self.settings.start_timeout:
                return
            if missing:
                self.get_logger().warning(
                    f"starting after {self.settings.start_timeout:g} s without {', '.join(missing)}"
                )
            # Matched is not yet ready: a best-effort sample sent right after discovery can be
            # lost while the subscriber's transport is still being set up, so let it settle, and
            # meanwhile send the first frame's camera_info and tip hint, repeatedly, as a camera
            # driver would have been doing all along: a node that lost them would drop the first
            # frame for want of camera_info, or order it from the wrong end without its hint.
            self._prime_first_frame()
            self._phase = "settling"
            self._settled_at = now + SETTLE_S
            self._arm(PRIME_PERIOD_S)
        elif self._phase == "settling" and now < self._settled_at:
            self._prime_first_frame()
            self._arm(min(PRIME_PERIOD_S, self._settled_at - now))
        elif self._phase == "settling":
            self._phase = "playing"
            self._t0 = time.monotonic()
            if self.settings.wait_for_output:
                self._publish_next_and_wait()
            else:
                self._publish_due()
        elif self._phase == "playing":
            if self.settings.wait_for_output and self._next == 1 and self._resends < FIRST_FRAME_RESENDS:
                self._resend_first_frame()
            elif self.settings.wait_for_output:  # wait_timeout passed without the output
                self.get_logger().debug(f"no output for stamp {self._pending} within wait_timeout")
                self._publish_next_and_wait()
            else:
                self._publish_due()
        elif self._phase == "lingering" and now >= self._linger_until:
            self.finish()
        elif self._phase == "lingering":
            self._arm(self._linger_until - now)

    def _publish_due(self) -> None:
        """Recorded timing: publish every frame that is due, then sleep until the next one."""
        while self._next < len(self._plan):
            wait = self._plan[self._next].due_s - (time.monotonic() - self._t0)
            if wait > 0:
                self._arm(wait)
                return
            self._publish(self._plan[self._next])
            self._next += 1
        self._phase = "lingering"
        self._linger_until = time.monotonic() + self.settings.linger
        self._arm(self.settings.linger)

    def _publish_next_and_wait(self) -> None:
        """Graph mode: publish the next frame and wait for its output, or finish after the last."""
        if self._next >= len(self._plan):
            self.finish()
            return
        planned = self._plan[self._next]
        self._next += 1
        self._pending = planned.stamp_ns
        self._publish(planned)
        self._arm(self.settings.wait_timeout)

    def _resend_first_frame(self) -> None:
        """Graph mode: the first frame's output did not come; publish that frame again."""
        self._resends += 1
        self.get_logger().info(
            f"no output for the first frame within {self.settings.wait_timeout:g} s; sending it again "
            f"({self._resends}/{FIRST_FRAME_RESENDS}: the nodes may still be discovering each other)"
        )
        record = self.records.pop()  # timed from the last send
        del self._by_stamp[record.stamp_ns]
        self._next = 0
        self._publish_next_and_wait()

    def _prime_first_frame(self) -> None:
        """Publish the first frame's messages other than its images (camera_info, tip hint)."""
        first = self._plan[0] if self._plan else None
        if first is None:
            return
        sec, nanosec = divmod(first.stamp_ns, 1_000_000_000)
        for publisher, message, stamped, is_image in self._messages[first.frame_index]:
            if not is_image:
                if stamped:
                    message.header.stamp.sec, message.header.stamp.nanosec = sec, nanosec
                publisher.publish(message)

    def _publish(self, planned: PlannedFrame) -> None:
        sec, nanosec = divmod(planned.stamp_ns, 1_000_000_000)
        published = None
        for publisher, message, stamped, is_image in self._messages[planned.frame_index]:
            if stamped:
                message.header.stamp.sec = sec
                message.header.stamp.nanosec = nanosec
            if published is None and is_image:
                published = time.time()
            publisher.publish(message)
        if published is None:  # a frame without images: timed from its first message
            published = time.time()
        record = FrameRecord(planned.stamp_ns, published)
        self.records.append(record)
        self._by_stamp[planned.stamp_ns] = record
        self.get_logger().debug(
            f"frame {planned.index + 1}/{len(self._plan)} (loop {planned.loop}) stamp {planned.stamp_ns}"
        )

    def _on_output(self, message: Any) -> None:
        received = time.time()
        stamp = message.header.stamp
        stamp_ns = int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
        record = self._by_stamp.get(stamp_ns)
        if record is None or record.output_s is not None:
            return  # not ours, or a second output of one frame: the first one counts
        record.output_s = received
        if self.settings.wait_for_output and stamp_ns == self._pending and not self.finished:
            self._pending = None
            self._publish_next_and_wait()

    # ------------------------------------------------------------------ end

    def finish(self) -> dict[str, Any]:
        """Stop publishing, build the report (and write it if ``report`` is set), log the summary.

        Idempotent; returns the report. Raises OSError when the report file cannot be written.
        """
        if self.report is not None:
            return self.report
        self.finished = True
        self._timer.cancel()
        mode = "graph" if self.settings.wait_for_output else "recorded"
        self.report = build_report(self.records, mode, self.settings.rate)
        self.get_logger().info(summary_line(self.report))
        if self.settings.report:
            write_report(self.settings.report, self.report)
        return self.report


def main(args: list[str] | None = None) -> int:
    """``ros2 run suture_replay player_node --ros-args -p bag:=BAG``: replay, report, exit status."""
    return run_node(
        PlayerNode,
        EXECUTABLE,
        args,
        finished=lambda node: node.finished,
        finish=lambda node: node.finish(),
        finish_error=lambda node, exc: f"cannot write report {node.settings.report}: {exc}",
    )


if __name__ == "__main__":
    sys.exit(main())
