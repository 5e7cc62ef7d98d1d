# SPDX-License-Identifier: Apache-2.0
"""The ROS-free core of the player and recorder: frames, plan, settings, latency report, signals."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from suture_common import topics
from suture_common.bag_io import BagError, BagWriter
from suture_common.camera import StereoCamera
from suture_common.messages import (
    TYPESTORE,
    camera_info_message,
    image_message,
    point_message,
    pose_message,
    string_message,
)
from suture_replay.replay import (
    SINGLE_FRAME_PERIOD_NS,
    Frame,
    FrameRecord,
    PlayerSettings,
    RecorderSettings,
    build_report,
    header_stamp_ns,
    latency_stats,
    load_frames,
    loop_period_ns,
    plan,
    summary_line,
    write_report,
)

T0 = 1_700_000_000_000_000_000
PERIOD = 100_000_000
CAMERA = StereoCamera.default(32, 24)
SAMPLE_BAG = Path(__file__).resolve().parents[3] / "bags" / "sample"


def write_input_bag(path: Path, frames: int = 3, delays_ns: tuple[int, ...] = (0,)) -> Path:
    """``frames`` stereo frames at 10 Hz, images first in the bag; bag time = stamp + a per-topic delay.

    Also a header-less String on /ground_truth/topology at each stamp's bag time.
    """
    image = np.zeros((24, 32, 3), np.uint8)
    with BagWriter(path) as bag:
        for index in range(frames):
            stamp = T0 + index * PERIOD
            messages = [
                (topics.LEFT_IMAGE, image_message(image, "rgb8", stamp, topics.LEFT_FRAME)),
                (topics.RIGHT_IMAGE, image_message(image, "rgb8", stamp, topics.RIGHT_FRAME)),
                (topics.TIP_HINT, point_message(np.array([3.0, 4.0, 0.0]), stamp, topics.LEFT_FRAME)),
                (topics.RIGHT_CAMERA_INFO, camera_info_message(CAMERA, "right", stamp, topics.RIGHT_FRAME)),
                (topics.LEFT_CAMERA_INFO, camera_info_message(CAMERA, "left", stamp, topics.LEFT_FRAME)),
            ]
            for k, (topic, message) in enumerate(messages):
                bag.write(topic, message, stamp + delays_ns[k % len(delays_ns)])
            bag.write(topics.GT_TOPOLOGY, string_message("straight"), stamp)
    return path


# --------------------------------------------------------------------------- frames


def test_frames_group_by_stamp_in_publishing_order(tmp_path):
    bag = write_input_bag(tmp_path / "b", delays_ns=(5_000_000, 4_000_000, 3_000_000, 2_000_000, 1_000_000))
    loaded = load_frames(bag, [*topics.INPUT_TOPICS, "/not/in/bag"])
    assert loaded.found == list(topics.INPUT_TOPICS)
    assert loaded.missing == ["/not/in/bag"]
    assert loaded.types == {topic: topics.TOPIC_TYPES[topic] for topic in topics.INPUT_TOPICS}
    assert [f.stamp_ns for f in loaded.frames] == [T0, T0 + PERIOD, T0 + 2 * PERIOD]
    for frame in loaded.frames:
        assert frame.recorded_ns == frame.stamp_ns + 1_000_000  # the earliest bag time of the frame
        # camera_info first, then the tip hint, then images; each group in the order of `topics`
        assert [m[0] for m in frame.messages] == [
            topics.LEFT_CAMERA_INFO,
            topics.RIGHT_CAMERA_INFO,
            topics.TIP_HINT,
            topics.LEFT_IMAGE,
            topics.RIGHT_IMAGE,
        ]
        assert frame.stamped == (True,) * 5
        for topic, msgtype, cdr in frame.messages:
            assert msgtype == topics.TOPIC_TYPES[topic]
            assert header_stamp_ns(msgtype, cdr) == frame.stamp_ns


def test_topic_order_follows_the_request(tmp_path):
    bag = write_input_bag(tmp_path / "b", frames=1)
    frame = load_frames(bag, [topics.RIGHT_IMAGE, topics.LEFT_IMAGE]).frames[0]
    assert [m[0] for m in frame.messages] == [topics.RIGHT_IMAGE, topics.LEFT_IMAGE]


def test_header_less_messages_group_by_bag_time(tmp_path):
    bag = write_input_bag(tmp_path / "b", frames=2)
    with BagWriter(tmp_path / "extra") as extra:  # a String between the frames: a frame of its own
        extra.write(topics.GT_TOPOLOGY, string_message("alone"), T0 + PERIOD // 2)
    loaded = load_frames(bag, [topics.LEFT_IMAGE, topics.GT_TOPOLOGY])
    for frame in loaded.frames:
        assert [m[0] for m in frame.messages] == [topics.GT_TOPOLOGY, topics.LEFT_IMAGE]
        assert frame.stamped == (False, True)
    alone = load_frames(tmp_path / "extra", [topics.GT_TOPOLOGY]).frames
    assert [(f.stamp_ns, f.recorded_ns, f.stamped) for f in alone] == [(T0 + PERIOD // 2,) * 2 + ((False,),)]


def test_frames_follow_recorded_order(tmp_path):
    """A frame recorded earlier is replayed earlier even if its stamp is later."""
    with BagWriter(tmp_path / "b") as bag:
        for stamp, received in ((T0 + PERIOD, T0 + PERIOD), (T0, T0 + 2 * PERIOD)):
            bag.write(topics.TIP_HINT, point_message(np.zeros(3), stamp, "f"), received)
    frames = load_frames(tmp_path / "b", [topics.TIP_HINT]).frames
    assert [(f.stamp_ns, f.recorded_ns) for f in frames] == [
        (T0 + PERIOD, T0 + PERIOD),
        (T0, T0 + 2 * PERIOD),
    ]


def test_sample_bag_frames():
    loaded = load_frames(SAMPLE_BAG, topics.INPUT_TOPICS)
    assert loaded.missing == []
    assert len(loaded.frames) == 10
    assert [f.stamp_ns for f in loaded.frames] == [T0 + k * PERIOD for k in range(10)]
    assert all(len(f.messages) == 5 for f in loaded.frames)


def test_load_errors(tmp_path):
    with pytest.raises(BagError, match="does not exist"):
        load_frames(tmp_path / "nope", topics.INPUT_TOPICS)
    with pytest.raises(TypeError, match="sequence of topic names"):
        load_frames(SAMPLE_BAG, topics.LEFT_IMAGE)
    assert load_frames(SAMPLE_BAG, ["/not/in/bag"]).frames == []


def test_header_stamp_of_types_without_header():
    cdr = bytes(TYPESTORE.serialize_cdr(string_message("x"), "std_msgs/msg/String"))
    assert header_stamp_ns("std_msgs/msg/String", cdr) is None
    assert header_stamp_ns("my_msgs/msg/Unknown", cdr) is None
    pose = pose_message(np.zeros(3), np.array([0, 0, 0, 1.0]), T0 + 7, "f")
    cdr = bytes(TYPESTORE.serialize_cdr(pose, "geometry_msgs/msg/PoseStamped"))
    assert header_stamp_ns("geometry_msgs/msg/PoseStamped", cdr) == T0 + 7


# --------------------------------------------------------------------------- plan


def frame(stamp_ns: int, recorded_ns: int | None = None) -> Frame:
    return Frame(stamp_ns, stamp_ns if recorded_ns is None else recorded_ns, (), ())


def test_plan_follows_recorded_times_scaled_by_rate():
    frames = [
        frame(T0, T0 + 3),
        frame(T0 + PERIOD, T0 + 3 + 150_000_000),
        frame(T0 + 2 * PERIOD, T0 + 3 + 2 * PERIOD),
    ]
    planned = plan(frames, rate=2.0)
    assert [p.due_s for p in planned] == pytest.approx([0.0, 0.075, 0.1])
    assert [p.stamp_ns for p in planned] == [f.stamp_ns for f in frames]
    assert [p.index for p in planned] == [0, 1, 2]
    assert all(p.loop == 0 and p.offset_ns == 0 for p in planned)


def test_plan_loops_shift_stamps_and_schedule():
    frames = [frame(T0 + k * PERIOD) for k in range(10)]
    planned = plan(frames, rate=1.0, loops=3)
    assert len(planned) == 30
    stamps = [p.stamp_ns for p in planned]
    assert len(set(stamps)) == 30 and stamps == sorted(stamps)
    assert stamps[10] == T0 + 10 * PERIOD  # span 0.9 s + one period
    assert [p.loop for p in planned] == [0] * 10 + [1] * 10 + [2] * 10
    assert [p.frame_index for p in planned[10:20]] == list(range(10))
    assert [p.offset_ns for p in planned[::10]] == [0, 10 * PERIOD, 20 * PERIOD]
    assert [p.due_s for p in planned] == pytest.approx([k * 0.1 for k in range(30)])


def test_plan_of_a_single_frame_and_of_nothing():
    planned = plan([frame(T0)], loops=3, rate=2.0)
    assert [p.stamp_ns for p in planned] == [T0 + k * SINGLE_FRAME_PERIOD_NS for k in range(3)]
    assert [p.due_s for p in planned] == pytest.approx([0.0, 0.5, 1.0])
    assert plan([], loops=2) == []


def test_loop_period_uses_the_median_step():
    assert loop_period_ns([0, 10, 20, 100]) == 110
    assert loop_period_ns([5, 5]) == SINGLE_FRAME_PERIOD_NS


@pytest.mark.parametrize("kwargs", [dict(rate=0.0), dict(rate=-1.0), dict(rate=float("nan")), dict(loops=0)])
def test_plan_rejects_bad_values(kwargs):
    with pytest.raises(ValueError):
        plan([frame(T0)], **kwargs)


# --------------------------------------------------------------------------- settings


def test_player_settings_defaults():
    settings = PlayerSettings(bag="b")
    assert settings.topics == topics.INPUT_TOPICS
    assert (settings.rate, settings.loops, settings.wait_timeout) == (1.0, 1, 2.0)
    assert (settings.start_timeout, settings.linger, settings.report) == (15.0, 1.0, "")
    assert settings.output_topic == topics.GRASP_POSE and settings.wait_for_output is False
    converted = PlayerSettings(bag="b", rate=2, loops=3.0, topics=["/a"])
    assert converted.rate == 2.0 and isinstance(converted.rate, float)
    assert converted.loops == 3 and isinstance(converted.loops, int)
    assert converted.topics == ("/a",)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(bag=""), "'bag' is required"),
        (dict(bag=3), "bag must be a path"),
        (dict(rate=0.0), "rate must be > 0"),
        (dict(rate=-2.0), "rate must be > 0"),
        (dict(rate="fast"), "rate must be a number"),
        (dict(rate=float("inf")), "rate must be finite"),
        (dict(loops=0), "loops must be a whole number >= 1"),
        (dict(loops=1.5), "loops must be a whole number"),
        (dict(wait_timeout=0.0), "wait_timeout must be > 0"),
        (dict(start_timeout=-1.0), "start_timeout must be >= 0"),
        (dict(linger=-0.1), "linger must be >= 0"),
        (dict(topics=[]), "topics is empty"),
        (dict(topics=["stereo/left"]), "must be absolute"),
        (dict(output_topic="pose"), "output_topic 'pose' must be absolute"),
        (dict(wait_for_output="yes"), "wait_for_output must be true or false"),
    ],
)
def test_player_settings_errors(kwargs, match):
    with pytest.raises(ValueError, match=match):
        PlayerSettings(**{"bag": "b", **kwargs})


def test_recorder_settings(tmp_path):
    settings = RecorderSettings(str(tmp_path / "new"))
    assert settings.topics == topics.PIPELINE_OUTPUT_TOPICS
    assert settings.types == {topic: topics.TOPIC_TYPES[topic] for topic in topics.PIPELINE_OUTPUT_TOPICS}
    with pytest.raises(ValueError, match="'output' is required"):
        RecorderSettings("")
    with pytest.raises(ValueError, match="exists already"):
        RecorderSettings(str(tmp_path))
    with pytest.raises(ValueError, match="topic /foo has no known type"):
        RecorderSettings(str(tmp_path / "new"), topics=(topics.GRASP_POSE, "/foo"))
    with pytest.raises(ValueError, match="topics is empty"):
        RecorderSettings(str(tmp_path / "new"), topics=())


def test_topic_tables():
    """Every docs/interfaces.md topic has a type that the bag type store knows; the tuples agree with it."""
    assert set(topics.INPUT_TOPICS) | set(topics.PIPELINE_OUTPUT_TOPICS) | set(
        topics.GROUND_TRUTH_TOPICS
    ) == set(topics.TOPIC_TYPES)
    assert len(topics.PIPELINE_OUTPUT_TOPICS) == 12
    assert topics.TOPIC_TYPES[topics.TARGET_POSE] == "geometry_msgs/msg/PoseStamped"
    assert topics.TOPIC_TYPES[topics.EXECUTOR_STATE] == "std_msgs/msg/String"
    assert all(msgtype in TYPESTORE.types for msgtype in topics.TOPIC_TYPES.values())


# --------------------------------------------------------------------------- report


def test_latency_stats():
    assert latency_stats([None, None]) == {"median": None, "p95": None, "max": None}
    stats = latency_stats([*range(1, 101), None])
    assert stats == {"median": 50.5, "p95": pytest.approx(95.05), "max": 100.0}


def test_report_and_summary_line(tmp_path):
    records = [
        FrameRecord(T0, 10.0, 10.05),
        FrameRecord(T0 + PERIOD, 10.1, None),
        FrameRecord(T0 + 2 * PERIOD, 10.2, 10.45),
    ]
    report = build_report(records, "graph", 1.0)
    assert report["frames"] == 3 and report["outputs"] == 2
    assert report["latency_ms"]["median"] == pytest.approx(150.0)
    assert report["latency_ms"]["max"] == pytest.approx(250.0)
    assert report["fps"] == pytest.approx(2 / 0.45)
    assert report["mode"] == "graph" and report["rate"] == 1.0
    assert report["per_frame"][1] == {
        "stamp_ns": T0 + PERIOD,
        "published_s": 10.1,
        "output_s": None,
        "latency_ms": None,
    }
    assert report["per_frame"][0]["latency_ms"] == pytest.approx(50.0)
    assert summary_line(report) == (
        "replayed 3 frames, 2 outputs, latency median 150.0 ms p95 240.0 ms, 4.44 fps"
    )
    write_report(tmp_path / "sub" / "report.json", report)
    assert json.loads((tmp_path / "sub" / "report.json").read_text()) == report


def test_report_without_outputs():
    report = build_report([FrameRecord(T0, 1.0)], "recorded", 2.0)
    assert report["outputs"] == 0 and report["fps"] is None
    assert report["latency_ms"] == {"median": None, "p95": None, "max": None}
    assert summary_line(report) == "replayed 1 frames, 0 outputs, latency median n/a ms p95 n/a ms, n/a fps"
    assert build_report([], "recorded", 1.0)["frames"] == 0
    with pytest.raises(ValueError, match="mode"):
        build_report([], "fast", 1.0)
