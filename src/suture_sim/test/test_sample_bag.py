# SPDX-License-Identifier: Apache-2.0
"""The committed sample bag: small, complete, readable by rosbags and by the mcap tools, reproducible."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from suture_common import messages, topics
from suture_common.bag_io import bag_summary, read_messages, read_raw
from suture_common.camera import StereoCamera
from suture_common.messages import TYPESTORE
from suture_sim.scene import TOPOLOGIES, SimConfig, generate_frame

SAMPLE = Path(__file__).resolve().parents[3] / "bags" / "sample"
MCAP_FILE = SAMPLE / "sample.mcap"
# The command that made it (also in bags/README.md):
# suture-sim --topology mixed --frames 10 --seed 2026 --resolution 640x480 --domain legacy \
#   --compression-level 19 --out bags/sample
SEED, FRAMES = 2026, 10


def test_small_with_every_topic_and_two_frames_per_topology():
    assert MCAP_FILE.stat().st_size < 10_000_000
    summary = bag_summary(SAMPLE)
    assert set(summary) == {*topics.INPUT_TOPICS, *topics.GROUND_TRUTH_TOPICS}
    assert {count for _, count in summary.values()} == {FRAMES}
    labels = Counter(record.message.data for record in read_messages(SAMPLE, [topics.GT_TOPOLOGY]))
    assert set(labels) == set(TOPOLOGIES) and min(labels.values()) >= 2
    # Every topic carries the same stamps, and every header carries its log time.
    stamps: dict[str, list[int]] = {}
    for record in read_messages(SAMPLE):
        stamps.setdefault(record.topic, []).append(record.timestamp_ns)
        header = getattr(record.message, "header", None)
        if header is not None:
            assert messages.ns_from_stamp(header.stamp) == record.timestamp_ns
    assert len({tuple(v) for v in stamps.values()}) == 1


def test_mcap_reader_sees_the_same_bytes_as_rosbags_and_decodes_with_embedded_schemas():
    by_rosbags = list(read_raw(SAMPLE))
    with MCAP_FILE.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        chunk_compression = {index.compression for index in reader.get_summary().chunk_indexes}
        by_mcap = []
        decoded = {}
        for schema, channel, message, ros_message in reader.iter_decoded_messages():
            assert schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
            by_mcap.append((channel.topic, schema.name, message.log_time, bytes(message.data)))
            decoded[(channel.topic, message.log_time)] = ros_message
    assert chunk_compression == {"zstd"}
    assert sorted(by_mcap) == sorted((t, m, s, bytes(d)) for t, m, s, d in by_rosbags)
    for topic, msgtype, stamp, data in by_rosbags:
        ours = TYPESTORE.deserialize_cdr(data, msgtype)
        assert bytes(TYPESTORE.serialize_cdr(ours, msgtype)) == bytes(data)  # unchanged round trip
        theirs = decoded[(topic, stamp)]
        if msgtype == "sensor_msgs/msg/Image":
            assert bytes(theirs.data) == bytes(ours.data) and theirs.encoding == ours.encoding
        elif msgtype == "nav_msgs/msg/Path":
            mcap_points = [[p.pose.position.x, p.pose.position.y, p.pose.position.z] for p in theirs.poses]
            np.testing.assert_array_equal(np.array(mcap_points), messages.path_to_array(ours))


def test_the_recorded_command_regenerates_the_bag():
    config = SimConfig(topology="mixed", camera=StereoCamera.default(640, 480), seed=SEED)
    frame = generate_frame(config, 3)
    records = {r.topic: r.message for r in read_messages(SAMPLE) if r.timestamp_ns == frame.stamp_ns}
    np.testing.assert_allclose(messages.path_to_array(records[topics.GT_PATH]), frame.path, atol=1e-9)
    image = messages.image_to_array(records[topics.LEFT_IMAGE]).astype(int)
    assert np.abs(image - frame.left_image.astype(int)).mean() < 0.5
    assert records[topics.GT_TOPOLOGY].data == frame.topology


def test_bag_info_lists_frames_and_writes_a_contact_sheet(tmp_path):
    from suture_sim.describe import contact_sheet, describe

    text = describe(str(SAMPLE))
    for topology in TOPOLOGIES:
        assert text.count(f"  {topology} ") == 2, topology
    assert "/ground_truth/grasp_pose" in text
    rows = contact_sheet(str(SAMPLE), str(tmp_path / "sheet.png"))
    import cv2

    sheet = cv2.imread(str(tmp_path / "sheet.png"))
    assert rows == FRAMES and sheet.shape == (FRAMES * 240, 3 * 320, 3)
