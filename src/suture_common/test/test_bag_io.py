# SPDX-License-Identifier: Apache-2.0
"""MCAP bag writing and reading: rosbags round trip, independent mcap decoding, errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from suture_common.bag_io import (
    BagDamage,
    BagError,
    BagMessage,
    BagWriter,
    bag_summary,
    read_messages,
    read_raw,
)
from suture_common.camera import StereoCamera
from suture_common.messages import (
    TYPESTORE,
    camera_info_message,
    image_message,
    image_to_array,
    ns_from_stamp,
    path_message,
    path_to_array,
    point_message,
    point_to_array,
    polygon_message,
    polygon_to_array,
    pose_message,
    pose_to_arrays,
    string_message,
)

STAMPS = [1_700_000_000_000_000_000 + i * 33_333_333 for i in range(3)]
OPTICAL = "left_camera_optical_frame"
CAMERA = StereoCamera.default(32, 24)

TYPES = {
    "/stereo/left/image_rect": "sensor_msgs/msg/Image",
    "/stereo/right/image_rect": "sensor_msgs/msg/Image",
    "/stereo/left/camera_info": "sensor_msgs/msg/CameraInfo",
    "/stereo/right/camera_info": "sensor_msgs/msg/CameraInfo",
    "/suture/tip_hint": "geometry_msgs/msg/PointStamped",
    "/suture/left/mask": "sensor_msgs/msg/Image",
    "/suture/left/sequence": "geometry_msgs/msg/PolygonStamped",
    "/suture/path": "nav_msgs/msg/Path",
    "/suture/grasp_pose": "geometry_msgs/msg/PoseStamped",
    "/ground_truth/topology": "std_msgs/msg/String",
    "/grasp_executor/state": "std_msgs/msg/String",
}


def frame_content(index: int) -> dict[str, object]:
    """Array/str content of every topic in frame ``index`` (what the readers should return)."""
    rng = np.random.default_rng(index)
    quaternion = rng.normal(size=4)
    return {
        "/stereo/left/image_rect": rng.integers(0, 256, (24, 32, 3), dtype=np.uint8),
        "/stereo/right/image_rect": rng.integers(0, 256, (24, 32, 3), dtype=np.uint8),
        "/stereo/left/camera_info": CAMERA.P("left"),
        "/stereo/right/camera_info": CAMERA.P("right"),
        "/suture/tip_hint": np.array([3.5 + index, 7.25, 0.0]),
        "/suture/left/mask": (rng.random((24, 32)) > 0.5).astype(np.uint8) * 255,
        "/suture/left/sequence": np.column_stack([np.arange(5.0) + index, np.arange(5.0) * 0.5, np.zeros(5)]),
        "/suture/path": rng.normal(size=(6, 3)) * 0.01 + [0, 0, 0.1],
        "/suture/grasp_pose": (rng.normal(size=3) * 0.01, quaternion / np.linalg.norm(quaternion)),
        "/ground_truth/topology": ["straight", "curved", "crossed"][index],
        "/grasp_executor/state": f"refused: step {index}",
    }


def frame_messages(index: int) -> dict[str, object]:
    """The messages of frame ``index``, built from :func:`frame_content`."""
    content, stamp = frame_content(index), STAMPS[index]
    position, quaternion = content["/suture/grasp_pose"]
    return {
        "/stereo/left/image_rect": image_message(content["/stereo/left/image_rect"], "rgb8", stamp, OPTICAL),
        "/stereo/right/image_rect": image_message(
            content["/stereo/right/image_rect"], "rgb8", stamp, "right_camera_optical_frame"
        ),
        "/stereo/left/camera_info": camera_info_message(CAMERA, "left", stamp, OPTICAL),
        "/stereo/right/camera_info": camera_info_message(
            CAMERA, "right", stamp, "right_camera_optical_frame"
        ),
        "/suture/tip_hint": point_message(content["/suture/tip_hint"], stamp, OPTICAL),
        "/suture/left/mask": image_message(content["/suture/left/mask"], "mono8", stamp, OPTICAL),
        "/suture/left/sequence": polygon_message(content["/suture/left/sequence"][:, :2], stamp, OPTICAL),
        "/suture/path": path_message(content["/suture/path"], stamp, OPTICAL),
        "/suture/grasp_pose": pose_message(position, quaternion, stamp, OPTICAL),
        "/ground_truth/topology": string_message(content["/ground_truth/topology"]),
        "/grasp_executor/state": string_message(content["/grasp_executor/state"]),
    }


def extract(topic: str, message: object) -> object:
    """Content of a message (rosbags, rclpy or mcap_ros2 decoded) via the duck-typed readers."""
    msgtype = TYPES[topic]
    if msgtype == "sensor_msgs/msg/Image":
        return image_to_array(message)
    if msgtype == "sensor_msgs/msg/CameraInfo":
        return np.asarray(message.p, dtype=np.float64).reshape(3, 4)
    if msgtype == "geometry_msgs/msg/PointStamped":
        return point_to_array(message)
    if msgtype == "geometry_msgs/msg/PolygonStamped":
        return polygon_to_array(message)
    if msgtype == "nav_msgs/msg/Path":
        return path_to_array(message)
    if msgtype == "geometry_msgs/msg/PoseStamped":
        return pose_to_arrays(message)
    return message.data


def assert_same(topic: str, got: object, expected: object) -> None:
    if isinstance(expected, tuple):
        for a, b in zip(got, expected, strict=True):
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-15, err_msg=topic)
    elif isinstance(expected, str):
        assert got == expected, topic
    else:
        np.testing.assert_array_equal(got, expected, err_msg=topic)


def write_sample_bag(path: Path, compress: bool = True) -> Path:
    """A bag with every DESIGN message type on its topic, for 3 stamps (written frame by frame)."""
    with BagWriter(path, compress=compress) as bag:
        for index, stamp in enumerate(STAMPS):
            for topic, message in frame_messages(index).items():
                bag.write(topic, message, stamp)
    return path


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_sample_bag(tmp_path_factory.mktemp("bags") / "sample")


def mcap_file(bag_path: Path) -> Path:
    return bag_path / f"{bag_path.name}.mcap"


# --------------------------------------------------------------------------- layout and metadata


def test_layout_and_metadata(bag):
    assert sorted(p.name for p in bag.iterdir()) == ["metadata.yaml", "sample.mcap"]
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["version"] == 9
    assert info["storage_identifier"] == "mcap"
    assert info["relative_file_paths"] == ["sample.mcap"]
    assert info["message_count"] == 3 * len(TYPES)
    assert info["starting_time"]["nanoseconds_since_epoch"] == STAMPS[0]
    assert info["duration"]["nanoseconds"] == STAMPS[-1] - STAMPS[0]
    topics = {t["topic_metadata"]["name"]: t for t in info["topics_with_message_count"]}
    assert set(topics) == set(TYPES)
    for name, entry in topics.items():
        assert entry["topic_metadata"]["type"] == TYPES[name]
        assert entry["topic_metadata"]["serialization_format"] == "cdr"
        assert entry["topic_metadata"]["type_description_hash"].startswith("RIHS01_")
        assert entry["message_count"] == 3


def test_summary(bag):
    assert bag_summary(bag) == {topic: (msgtype, 3) for topic, msgtype in sorted(TYPES.items())}


# --------------------------------------------------------------------------- rosbags round trip


def test_read_messages_round_trip(bag):
    messages = list(read_messages(bag))
    assert len(messages) == 3 * len(TYPES)
    assert all(isinstance(m, BagMessage) for m in messages)
    assert [m.timestamp_ns for m in messages] == sorted(m.timestamp_ns for m in messages)
    for index, stamp in enumerate(STAMPS):
        frame = {m.topic: m for m in messages if m.timestamp_ns == stamp}
        assert set(frame) == set(TYPES)
        content = frame_content(index)
        for topic, message in frame.items():
            assert message.msgtype == TYPES[topic] == message.message.__msgtype__
            assert_same(topic, extract(topic, message.message), content[topic])
            if hasattr(message.message, "header"):
                assert ns_from_stamp(message.message.header.stamp) == stamp


def test_read_raw_is_the_serialised_message(bag):
    raw = list(read_raw(bag))
    assert len(raw) == 3 * len(TYPES)
    for topic, msgtype, stamp, data in raw:
        assert isinstance(data, bytes) and data[:4] == b"\x00\x01\x00\x00"  # CDR little endian
        expected = frame_messages(STAMPS.index(stamp))[topic]
        assert msgtype == TYPES[topic]
        assert data == bytes(TYPESTORE.serialize_cdr(expected, msgtype))


def test_topic_filter(bag):
    wanted = ["/suture/path", "/stereo/left/camera_info", "/not/in/bag"]
    messages = list(read_messages(bag, topics=wanted))
    assert [m.topic for m in messages] == ["/stereo/left/camera_info", "/suture/path"] * 3
    assert list(read_raw(bag, topics=["/not/in/bag"])) == []
    with pytest.raises(TypeError, match="collection of topic names"):
        read_raw(bag, topics="/suture/path")


def test_messages_come_sorted_by_time(tmp_path):
    with BagWriter(tmp_path / "unordered") as bag:
        for stamp in (30, 10, 20):
            bag.write("/grasp_executor/state", string_message(str(stamp)), stamp)
    got = [(m.timestamp_ns, m.message.data) for m in read_messages(tmp_path / "unordered")]
    assert got == [(10, "10"), (20, "20"), (30, "30")]


def test_single_mcap_file_and_metadata_less_directory(bag, tmp_path):
    expected = [(t, s, bytes(d)) for t, _, s, d in read_raw(bag)]
    assert [(t, s, d) for t, _, s, d in read_raw(mcap_file(bag))] == expected
    assert bag_summary(mcap_file(bag)) == bag_summary(bag)
    bare = tmp_path / "exported"
    bare.mkdir()
    (bare / "recording.mcap").write_bytes(mcap_file(bag).read_bytes())
    assert [(t, s, d) for t, _, s, d in read_raw(bare)] == expected


# --------------------------------------------------------------------------- independent MCAP decoding


def test_mcap_decodes_with_embedded_schemas(bag):
    """The mcap reference reader with only the embedded ros2msg schemas sees the same content."""
    seen = 0
    with mcap_file(bag).open("rb") as stream:
        reader = make_reader(stream, validate_crcs=True, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        assert header.profile == "ros2"
        summary = reader.get_summary()
        assert {s.name: s.encoding for s in summary.schemas.values()} == {
            t: "ros2msg" for t in TYPES.values()
        }
        assert {c.topic: c.message_encoding for c in summary.channels.values()} == {t: "cdr" for t in TYPES}
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            assert schema.name == TYPES[channel.topic]
            assert message.log_time == message.publish_time
            content = frame_content(STAMPS.index(message.log_time))
            assert_same(channel.topic, extract(channel.topic, decoded), content[channel.topic])
            if hasattr(decoded, "header"):
                assert decoded.header.stamp.sec * 10**9 + decoded.header.stamp.nanosec == message.log_time
            seen += 1
    assert seen == 3 * len(TYPES)


@pytest.mark.parametrize(("compress", "expected"), [(True, "zstd"), (False, "")])
def test_chunk_compression(tmp_path, compress, expected):
    path = write_sample_bag(tmp_path / "bag", compress=compress)
    with mcap_file(path).open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary.chunk_indexes
    assert {chunk.compression for chunk in summary.chunk_indexes} == {expected}
    if compress:
        assert all(chunk.compressed_size < chunk.uncompressed_size for chunk in summary.chunk_indexes)


# --------------------------------------------------------------------------- errors


def test_bag_error_is_os_error():
    assert issubclass(BagError, OSError)


def test_writer_refuses_existing_path(bag, tmp_path):
    with pytest.raises(BagError, match="exists already"):
        BagWriter(bag)
    (tmp_path / "file").write_text("x")
    with pytest.raises(BagError, match="exists already"):
        BagWriter(tmp_path / "file")


def test_writer_refuses_mcap_suffix(tmp_path):
    with pytest.raises(BagError, match="without the .mcap suffix"):
        BagWriter(tmp_path / "out.mcap")


def test_writer_unwritable_location(tmp_path):
    (tmp_path / "plain_file").write_text("x")
    with (
        pytest.raises(BagError, match="cannot create bag directory .*parent directory"),
        BagWriter(tmp_path / "plain_file" / "bag"),
    ):
        pass


def test_writer_removes_partial_bag_on_error(tmp_path):
    path = tmp_path / "partial"
    with pytest.raises(RuntimeError, match="boom"), BagWriter(path) as bag:
        bag.write("/grasp_executor/state", string_message("idle"), 1)
        raise RuntimeError("boom")
    assert not path.exists()


def test_writer_misuse(tmp_path):
    writer = BagWriter(tmp_path / "b")
    with pytest.raises(BagError, match="not open"):
        writer.write("/x", string_message("a"), 0)
    with writer as bag:
        with pytest.raises(TypeError, match="needs a rosbags message"):
            bag.write("/x", "a plain string", 0)
        with pytest.raises(ValueError, match="non-negative int"):
            bag.write("/x", string_message("a"), -1)
        with pytest.raises(ValueError, match="absolute"):
            bag.write("x", string_message("a"), 0)
        bag.write("/x", string_message("a"), 0)
        with pytest.raises(ValueError, match="already carries std_msgs/msg/String"):
            bag.write("/x", point_message([0, 0, 0], 0, "f"), 0)
    with pytest.raises(BagError, match="not open"):
        writer.write("/x", string_message("a"), 1)
    assert bag_summary(tmp_path / "b") == {"/x": ("std_msgs/msg/String", 1)}


def test_write_raw_copies_a_bag(bag, tmp_path):
    """read_raw -> write_raw gives the same messages, types, timestamps and bytes."""
    copy = tmp_path / "copy"
    with BagWriter(copy) as out:
        for topic, msgtype, stamp, data in read_raw(bag):
            out.write_raw(topic, msgtype, data, stamp)
    assert bag_summary(copy) == bag_summary(bag)
    assert list(read_raw(copy)) == list(read_raw(bag))
    for original, copied in zip(read_messages(bag), read_messages(copy), strict=True):
        assert (copied.topic, copied.msgtype, copied.timestamp_ns) == (
            original.topic,
            original.msgtype,
            original.timestamp_ns,
        )


def test_write_raw_mixes_with_write(tmp_path):
    pose = pose_message(np.array([0.1, 0.2, 0.3]), np.array([0.0, 0.0, 0.0, 1.0]), 5, OPTICAL)
    cdr = bytes(TYPESTORE.serialize_cdr(pose, "geometry_msgs/msg/PoseStamped"))
    with BagWriter(tmp_path / "b") as bag:
        bag.write_raw("/suture/grasp_pose", "geometry_msgs/msg/PoseStamped", cdr, 7)
        bag.write("/suture/grasp_pose", pose, 8)
        bag.write_raw("/grasp_executor/state", "std_msgs/msg/String", bytearray(b"\0\1\0\0\2\0\0\0a\0"), 9)
    messages = list(read_messages(tmp_path / "b"))
    assert [(m.topic, m.timestamp_ns) for m in messages] == [
        ("/suture/grasp_pose", 7),
        ("/suture/grasp_pose", 8),
        ("/grasp_executor/state", 9),
    ]
    for message in messages[:2]:
        position, quaternion = pose_to_arrays(message.message)
        assert np.allclose(position, [0.1, 0.2, 0.3]) and np.allclose(quaternion, [0, 0, 0, 1])
    assert messages[2].message.data == "a"


def test_write_raw_misuse(tmp_path):
    cdr = bytes(TYPESTORE.serialize_cdr(string_message("a"), "std_msgs/msg/String"))
    writer = BagWriter(tmp_path / "b")
    with pytest.raises(BagError, match="not open"):
        writer.write_raw("/x", "std_msgs/msg/String", cdr, 0)
    with writer as bag:
        with pytest.raises(ValueError, match="not a ROS 2 Jazzy standard message"):
            bag.write_raw("/x", "std_msgs/String", cdr, 0)
        with pytest.raises(ValueError, match="not a ROS 2 Jazzy standard message"):
            bag.write_raw("/x", "my_msgs/msg/Thing", cdr, 0)
        with pytest.raises(TypeError, match="cdr must be bytes"):
            bag.write_raw("/x", "std_msgs/msg/String", "a", 0)
        with pytest.raises(ValueError, match="too short"):
            bag.write_raw("/x", "std_msgs/msg/String", b"\0\1", 0)
        with pytest.raises(ValueError, match="non-negative int"):
            bag.write_raw("/x", "std_msgs/msg/String", cdr, -1)
        with pytest.raises(ValueError, match="non-negative int"):
            bag.write_raw("/x", "std_msgs/msg/String", cdr, 1.5)
        with pytest.raises(ValueError, match="absolute"):
            bag.write_raw("x", "std_msgs/msg/String", cdr, 0)
        bag.write_raw("/x", "std_msgs/msg/String", cdr, 0)
        with pytest.raises(ValueError, match="already carries std_msgs/msg/String"):
            bag.write_raw("/x", "geometry_msgs/msg/PointStamped", cdr, 0)
    assert bag_summary(tmp_path / "b") == {"/x": ("std_msgs/msg/String", 1)}


@pytest.mark.parametrize("reader", [read_messages, read_raw, bag_summary])
def test_missing_bag(tmp_path, reader):
    with pytest.raises(BagError, match="does not exist"):
        reader(tmp_path / "nope")  # raised on the call, not at the first next()


@pytest.mark.parametrize("reader", [read_messages, read_raw, bag_summary])
def test_not_a_bag(tmp_path, reader):
    empty = tmp_path / "empty_dir"
    empty.mkdir()
    with pytest.raises(BagError, match="no metadata.yaml and no .mcap file"):
        reader(empty)
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(BagError, match="not a bag"):
        reader(tmp_path / "notes.txt")
    (tmp_path / "garbage.mcap").write_bytes(b"not an mcap file at all, just some bytes" * 4)
    with pytest.raises(BagError, match="not a readable rosbag2/MCAP bag"):
        reader(tmp_path / "garbage.mcap")
    (tmp_path / "empty.mcap").write_bytes(b"")
    with pytest.raises(BagError, match="not a readable"):
        reader(tmp_path / "empty.mcap")


def test_broken_metadata(bag, tmp_path):
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed")
    with pytest.raises(BagError, match="not a readable"):
        bag_summary(broken)
    # metadata that names a missing storage file
    (broken / "metadata.yaml").write_text((bag / "metadata.yaml").read_text())
    with pytest.raises(BagError, match="not a readable"):
        list(read_messages(broken))


def test_truncated_mcap(bag, tmp_path):
    data = mcap_file(bag).read_bytes()
    (tmp_path / "cut.mcap").write_bytes(data[: len(data) // 2])
    with pytest.raises(BagError):
        list(read_raw(tmp_path / "cut.mcap"))


def test_a_cut_bag_is_read_up_to_the_cut_with_the_loss_stated(tmp_path):
    bag = Path(__file__).resolve().parents[3] / "bags" / "sample"  # several chunks
    whole = list(read_raw(bag))
    cut = tmp_path / "cut"
    cut.mkdir()
    (cut / "metadata.yaml").write_text((bag / "metadata.yaml").read_text())
    data = mcap_file(bag).read_bytes()
    (cut / mcap_file(bag).name).write_bytes(data[: len(data) // 2])
    damage = BagDamage()
    salvaged = list(read_raw(cut, damage=damage))
    assert damage.damaged and "cut short" in damage.error
    assert 0 < len(salvaged) < len(whole)
    assert salvaged == whole[: len(salvaged)]  # in time order, the same bytes
    expected = {topic: count for topic, (_, count) in bag_summary(bag).items()}
    assert damage.expected == expected
    assert sum(damage.lost(topic) for topic in expected) == len(whole) - len(salvaged)
    # deserialised as well; a whole bag reports no damage
    assert len(list(read_messages(cut, damage=BagDamage()))) == len(salvaged)
    intact = BagDamage()
    assert len(list(read_raw(bag, damage=intact))) == len(whole) and not intact.damaged
    # not an MCAP file at all: still refused
    (tmp_path / "junk.mcap").write_bytes(b"not an mcap file at all")
    with pytest.raises(BagError):
        read_raw(tmp_path / "junk.mcap", damage=BagDamage())
