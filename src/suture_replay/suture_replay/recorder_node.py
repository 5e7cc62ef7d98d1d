# SPDX-License-Identifier: Apache-2.0
"""recorder_node: record pipeline topics into a rosbag2 MCAP bag, like ``ros2 bag record``.

Parameters (read at start-up; :data:`PARAMETERS`):

- ``output`` (string, required): the rosbag2 directory to create; it must not exist,
  its parent is created if missing.
- ``topics`` (string array, default suture_common.topics.PIPELINE_OUTPUT_TOPICS: masks,
  sequences, points, path, grasp pose, markers, executor target pose and state).
  Types come from suture_common.topics.TOPIC_TYPES, not from the graph, so the recorder
  can subscribe before anyone publishes; a topic outside that table is an error
  (one line, exit 1) rather than a guess.

Image topics (sensor_msgs/Image) are subscribed best effort (the sensor-data profile
with depth 50), all others reliable with depth 100. Each message is written as received,
in its serialised form (a raw subscription: the CDR bytes that rclpy's
``serialize_message`` would give), with the receive time of the node clock as the bag
timestamp. On SIGINT, SIGTERM or node destruction the bag is finalised (MCAP summary
and ``metadata.yaml``) and ``recorded N messages on K topics to PATH`` is logged; a
recording without messages is still a valid, empty bag. A bad parameter or an
uncreatable bag: one line ``recorder_node: ...`` on standard error, exit 1.

Once every recorded topic has a matched publisher the node logs ``every recorded topic
has a publisher`` (once): messages published before their publisher matched the recorder
are not recorded, so ``ros2_ws/launch.sh`` waits for that line before it starts a replay.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from suture_common.bag_io import BagWriter
from suture_common.parameters import ParameterSpec, field_parameter, spec_table
from suture_common.ros import SENSOR_DATA_QOS, ThrottledWarnings, declare_parameters, message_class, run_node
from suture_replay.replay import IMAGE_TYPES, RecorderSettings

NODE_NAME = "recorder"
EXECUTABLE = "recorder_node"
WARN_PERIOD_S = 5.0
MATCH_POLL_S = 0.1

IMAGE_QOS = QoSProfile(
    depth=50,
    history=HistoryPolicy.KEEP_LAST,
    reliability=SENSOR_DATA_QOS.reliability,
    durability=SENSOR_DATA_QOS.durability,
)
"""Images: the sensor-data profile (best effort, volatile) with a deeper queue."""
RECORD_QOS = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE)
"""Everything else: reliable, keep last 100, volatile."""

PARAMETERS: dict[str, ParameterSpec] = spec_table(
    (
        field_parameter(RecorderSettings, "output", default="", dynamic_typing=True),  # required
        field_parameter(RecorderSettings, "topics", dynamic_typing=True),
    )
)
"""Every parameter, by name: fields of :class:`RecorderSettings` (descriptions there)."""


class RecorderNode(Node):
    """Writes every message of its topics to a bag; :meth:`close` (or destruction) finalises it."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self._bag: BagWriter | None = None
        try:
            self._setup()
        except BaseException:
            if self._bag is not None:  # no half-made recording left behind
                self._bag.abort()
                self._bag = None
            self.destroy_node()
            raise

    def _setup(self) -> None:
        values = declare_parameters(self, PARAMETERS.values())
        self.settings = settings = RecorderSettings(**values)  # ValueError on a bad value
        classes = {topic: message_class(msgtype) for topic, msgtype in settings.types.items()}

        self.counts: dict[str, int] = {}
        """Messages written, by topic."""
        self._warnings = ThrottledWarnings(self.get_logger(), WARN_PERIOD_S)
        path = Path(settings.output)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            self._bag = BagWriter(path).open()
        except OSError as exc:  # BagError names the path
            raise ValueError(f"cannot create bag {path}: {exc}") from exc
        self._subscriptions_unmatched = []  # emptied by _check_matched as publishers match
        for topic, msgtype in settings.types.items():
            qos = IMAGE_QOS if msgtype in IMAGE_TYPES else RECORD_QOS
            subscription = self.create_subscription(
                classes[topic],
                topic,
                lambda data, topic=topic, msgtype=msgtype: self._on_message(topic, msgtype, data),
                qos,
                raw=True,
            )
            self._subscriptions_unmatched.append(subscription)
        self.get_logger().info(f"recording {len(settings.topics)} topics to {path}")
        self._match_timer = self.create_timer(MATCH_POLL_S, self._check_matched)

    def _check_matched(self) -> None:
        unmatched = [s for s in self._subscriptions_unmatched if s.get_publisher_count() < 1]
        self._subscriptions_unmatched = unmatched
        if not unmatched:
            self._match_timer.cancel()
            count = len(self.settings.topics)
            self.get_logger().info(f"every recorded topic has a publisher ({count} topics)")

    def _on_message(self, topic: str, msgtype: str, data: bytes) -> None:
        if self._bag is None:
            return
        try:
            self._bag.write_raw(topic, msgtype, data, self.get_clock().now().nanoseconds)
        except (OSError, ValueError) as exc:  # e.g. a full disk: keep serving, say why
            self._warnings.warn("write", f"dropped a message on {topic}: {exc}")
            return
        self.counts[topic] = self.counts.get(topic, 0) + 1

    @property
    def matched(self) -> bool:
        """Whether every topic has had a matched publisher (the node then logged so, once)."""
        return not self._subscriptions_unmatched

    @property
    def path(self) -> Path:
        """The bag directory."""
        return Path(self.settings.output)

    def close(self) -> None:
        """Finalise the bag and log what was recorded. Idempotent; raises BagError if finalising fails."""
        bag, self._bag = self._bag, None
        if bag is None:
            return
        bag.close()
        self.get_logger().info(
            f"recorded {sum(self.counts.values())} messages on {len(self.counts)} topics to {bag.path}"
        )

    def destroy_node(self) -> None:
        """Finalise the bag, then destroy the node."""
        try:
            self.close()
        finally:
            super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """``ros2 run suture_replay recorder_node --ros-args -p output:=BAG``: record until SIGINT/SIGTERM."""
    return run_node(
        RecorderNode,
        EXECUTABLE,
        args,
        finish=lambda node: node.close(),
    )


if __name__ == "__main__":
    sys.exit(main())
