# SPDX-License-Identifier: Apache-2.0
"""The nodes over real rclpy topics and services: executor_node with the dvrk backend against psm_sim_node,
key-point mode, a lost connection mid-motion, bad input, arming, parameters and main().

Each test has its own rclpy Context on a DDS domain derived from the process id;
the executor node spins on a MultiThreadedExecutor in a background thread (its
execute service blocks while the arm moves), the simulated arm on its own
executor, so that stopping it is a lost connection.
"""

from __future__ import annotations

import csv
import math
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
import rclpy
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path as PathMsg
from rclpy.executors import MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.parameter import Parameter, parameter_dict_from_yaml_file
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import Trigger

from grasp_executor.executor_node import (
    ABORT,
    DEFAULTS,
    EXECUTE,
    STATE,
    TARGET_POSE,
    VISIT_KEYPOINTS,
    ConfigError,
    ExecutorNode,
)
from grasp_executor.geometry import Pose
from grasp_executor.handeye import HandEye
from grasp_executor.planning import GraspConfig, plan_grasp
from grasp_executor.psm_sim_node import PsmSimNode
from suture_common.grasp import grasp_rotation, rotation_to_quaternion
from suture_common.messages import ns_from_stamp, path_message, pose_to_arrays
from suture_common.ros import RELIABLE_QOS, to_rclpy
from suture_common.topics import GRASP_POSE, PATH

CONFIG = Path(__file__).resolve().parents[1] / "config"
CAMERA = "left_camera_optical_frame"
HAND_EYE = HandEye([0.4, 0.0, 0.5], [math.sqrt(0.5), -math.sqrt(0.5), 0.0, 0.0], CAMERA, "base")
P_CAMERA = np.array([0.02, -0.01, 0.45])
Q_CAMERA = rotation_to_quaternion(grasp_rotation(P_CAMERA, [1.0, 0.0, 0.0]))
GRASP = GraspConfig(approach_offset=0.01, lift_distance=0.01, jaw_open=0.8, jaw_close=-0.1)
PLAN = dict(plan_grasp(HAND_EYE.transform_pose(Pose(P_CAMERA, Q_CAMERA, CAMERA)), GRASP).moves())
START = PLAN["pre_grasp"].translated([0.004, -0.003, 0.008])  # the arm waits 9.4 mm from the pre-grasp pose
TIMEOUT = 30.0


def executor_parameters(**overrides) -> list[Parameter]:
    values = {
        "backend": "dvrk",
        "armed": True,
        "hand_eye.translation": HAND_EYE.translation.tolist(),
        "hand_eye.quaternion": HAND_EYE.quaternion.tolist(),
        "workspace.min": [0.3, -0.1, 0.0],
        "workspace.max": [0.5, 0.1, 0.2],
        "max_step": 0.05,
        "max_age": 10.0,
        "approach_offset": GRASP.approach_offset,
        "lift_distance": GRASP.lift_distance,
        "jaw.open": GRASP.jaw_open,
        "jaw.close": GRASP.jaw_close,
        "motion_timeout": 10.0,
        **overrides,
    }
    return [Parameter(name, value=value) for name, value in values.items()]


def sim_parameters(**overrides) -> list[Parameter]:
    values = {
        "rate": 100.0,
        "linear_speed": 0.1,
        "angular_speed": 2.0,
        "jaw_speed": 4.0,
        "initial_position": START.position.tolist(),
        "initial_orientation": START.quaternion.tolist(),
        **overrides,
    }
    return [Parameter(name, value=value) for name, value in values.items()]


def wait_until(predicate: Callable[[], bool], timeout: float = TIMEOUT, what: str = "condition") -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.01)


class Ros:
    """One rclpy Context; nodes spin in background threads until the test ends."""

    def __init__(self, domain_id: int) -> None:
        self.domain_id = domain_id
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self._spinning: list[tuple[object, list, threading.Thread]] = []

    def spin(self, *nodes, threads: int = 1) -> Callable[[], None]:
        """Spin ``nodes`` on their own executor; returns a function that stops and destroys them."""
        executor = (
            MultiThreadedExecutor(num_threads=threads, context=self.context)
            if threads > 1
            else SingleThreadedExecutor(context=self.context)
        )
        for node in nodes:
            executor.add_node(node)
        thread = threading.Thread(target=executor.spin, daemon=True)
        thread.start()
        entry = (executor, list(nodes), thread)
        self._spinning.append(entry)

        def stop() -> None:
            if entry in self._spinning:
                self._spinning.remove(entry)
                _stop(*entry)

        return stop

    def shutdown(self) -> None:
        while self._spinning:
            _stop(*self._spinning.pop())
        self.context.try_shutdown()


def _stop(executor, nodes, thread) -> None:
    executor.shutdown(timeout_sec=10.0)
    thread.join(10.0)
    for node in nodes:
        if hasattr(node, "close"):
            node.close()
        node.destroy_node()


@pytest.fixture
def ros(ros_domain_id: int) -> Iterator[Ros]:
    ros = Ros(ros_domain_id)
    try:
        yield ros
    finally:
        ros.shutdown()


class Probe:
    """A test node: publishes inputs, records every output, calls the services."""

    def __init__(self, ros: Ros, namespace: str = "/PSM1") -> None:
        self.node = rclpy.create_node("probe", context=ros.context)
        node = self.node
        self.lock = threading.Lock()
        self.states: list[str] = []
        self.targets: list[PoseStamped] = []
        self.measured: list[np.ndarray] = []
        self.goals: list[tuple[float, np.ndarray]] = []
        self.jaw_goals: list[float] = []
        self.jaw_measured: list[float] = []
        self.grasp_pub = node.create_publisher(PoseStamped, GRASP_POSE, RELIABLE_QOS)
        self.path_pub = node.create_publisher(PathMsg, PATH, RELIABLE_QOS)
        self.state_sub = node.create_subscription(
            String, STATE, self._record(self.states, lambda m: m.data), 50
        )
        node.create_subscription(
            PoseStamped, TARGET_POSE, self._record(self.targets, lambda m: m), RELIABLE_QOS
        )
        position = lambda m: pose_to_arrays(m)[0]  # noqa: E731
        node.create_subscription(
            PoseStamped, f"{namespace}/measured_cp", self._record(self.measured, position), 100
        )
        goal = lambda m: (time.monotonic(), pose_to_arrays(m)[0])  # noqa: E731
        node.create_subscription(PoseStamped, f"{namespace}/move_cp", self._record(self.goals, goal), 50)
        jaw = lambda m: m.position[0]  # noqa: E731
        node.create_subscription(
            JointState, f"{namespace}/jaw/move_jp", self._record(self.jaw_goals, jaw), 50
        )
        node.create_subscription(
            JointState, f"{namespace}/jaw/measured_js", self._record(self.jaw_measured, jaw), 100
        )
        self.execute = node.create_client(Trigger, EXECUTE)
        self.keypoints = node.create_client(Trigger, VISIT_KEYPOINTS)
        self.abort = node.create_client(Trigger, ABORT)
        ros.spin(node)

    def _record(self, into: list, convert: Callable) -> Callable:
        def callback(message) -> None:
            with self.lock:
                into.append(convert(message))

        return callback

    def now_ns(self) -> int:
        return self.node.get_clock().now().nanoseconds

    def publish_grasp(
        self, position=P_CAMERA, quaternion=Q_CAMERA, frame: str = CAMERA, age_s: float = 0.0
    ) -> int:
        stamp = self.now_ns() - int(age_s * 1e9)
        message = PoseStamped()
        message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp, 10**9)
        message.header.frame_id = frame
        message.pose.position.x, message.pose.position.y, message.pose.position.z = map(float, position)
        o = message.pose.orientation
        o.x, o.y, o.z, o.w = map(float, quaternion)
        self.grasp_pub.publish(message)
        return stamp

    def call(self, client, timeout: float = TIMEOUT) -> Trigger.Response:
        future = self.call_async(client)
        done = threading.Event()
        future.add_done_callback(lambda _: done.set())
        assert done.wait(timeout), f"no response from {client.srv_name} within {timeout} s"
        return future.result()

    def call_async(self, client):
        assert client.wait_for_service(timeout_sec=TIMEOUT), f"{client.srv_name} is not available"
        return client.call_async(Trigger.Request())

    def wait_for_state(self, state: str, count: int = 1) -> None:
        wait_until(lambda: self.states.count(state) >= count, what=f"state {state!r} (got {self.states})")

    def connected_to(self, executor: ExecutorNode) -> bool:
        """Inputs, state output and (for the dvrk backend) the arm's feedback are all connected."""
        topics = (
            self.grasp_pub.get_subscription_count() >= 1
            and self.path_pub.get_subscription_count() >= 1
            and self.state_sub.get_publisher_count() >= 1
        )
        feedback = executor.core.backend_name != "dvrk" or executor.core.measured_pose() is not None
        return topics and feedback


def closest(samples: list[np.ndarray], target: np.ndarray) -> tuple[int, float]:
    distances = np.linalg.norm(np.array(samples) - target, axis=1)
    return int(np.argmin(distances)), float(distances.min())


def start_dvrk(ros: Ros, executor_overrides: dict | None = None, sim_overrides: dict | None = None):
    sim = PsmSimNode(context=ros.context, parameter_overrides=sim_parameters(**(sim_overrides or {})))
    stop_sim = ros.spin(sim)
    executor = ExecutorNode(
        context=ros.context, parameter_overrides=executor_parameters(**(executor_overrides or {}))
    )
    ros.spin(executor, threads=4)
    probe = Probe(ros)
    wait_until(lambda: probe.connected_to(executor), what="topics, services and measured_cp to connect")
    return sim, stop_sim, executor, probe


# ---------------------------------------------------------------------------- end to end


def test_dvrk_end_to_end_grasp_with_the_simulated_psm(ros):
    sim, _, _, probe = start_dvrk(ros)
    stamp = probe.publish_grasp()
    probe.wait_for_state("planned")
    response = probe.call(probe.execute)
    assert (response.success, response.message) == (True, "done")
    probe.wait_for_state("done")
    assert probe.states[-3:] == ["planned", "executing", "done"]

    # the arm passed through the pre-grasp and grasp poses within 1 mm, in that order, and lifted
    with probe.lock:
        measured = list(probe.measured)
    at_pre, pre_error = closest(measured, PLAN["pre_grasp"].position)
    at_grasp, grasp_error = closest(measured, PLAN["grasp"].position)
    assert pre_error < 1e-3 and grasp_error < 1e-3 and at_pre < at_grasp
    np.testing.assert_allclose(sim.psm.pose.position, PLAN["lift"].position, atol=1e-9)
    assert [g[1].tolist() for g in probe.goals] == [
        PLAN[n].position.tolist() for n in ("pre_grasp", "grasp", "lift")
    ]
    # the jaw opened before the approach and closed on the thread
    assert probe.jaw_goals == [0.8, -0.1]
    assert sim.psm.jaw == pytest.approx(-0.1)
    wait_until(lambda: probe.jaw_measured and abs(probe.jaw_measured[-1] + 0.1) < 1e-9, what="jaw closed")
    # the commanded grasp pose, in the base frame, with the grasp pose's stamp
    target = probe.targets[-1]
    assert target.header.frame_id == "base" and ns_from_stamp(target.header.stamp) == stamp
    np.testing.assert_allclose(pose_to_arrays(target)[0], [0.41, -0.02, 0.05], atol=1e-9)


def test_keypoint_mode_over_rclpy_logs_commanded_and_measured_points(ros, tmp_path):
    log = tmp_path / "keypoints.csv"
    overrides = {"keypoints.count": 3, "keypoints.dwell": 0.05, "keypoints.log_file": str(log)}
    _, _, executor, probe = start_dvrk(ros, overrides)
    path_camera = np.array([[0.0, -0.01, 0.45], [0.01, -0.01, 0.45], [0.01, 0.0, 0.45]])  # two 10 mm legs
    probe.path_pub.publish(to_rclpy(path_message(path_camera, probe.now_ns(), CAMERA)))
    wait_until(lambda: executor.core.has_path, what="the path to arrive")
    response = probe.call(probe.keypoints)
    assert response.success, response.message
    assert response.message == "done: visited 3 key points, max deviation 0.00 mm"
    rows = list(csv.DictReader(log.open()))
    assert [row["index"] for row in rows] == ["1", "2", "3"]
    commanded = np.array([[float(row[f"commanded_{a}"]) for a in "xyz"] for row in rows])
    measured = np.array([[float(row[f"measured_{a}"]) for a in "xyz"] for row in rows])
    np.testing.assert_allclose(commanded, HAND_EYE.transform_points(path_camera), atol=1e-6)
    np.testing.assert_allclose(measured, commanded, atol=1e-3)
    assert {row["frame_id"] for row in rows} == {"base"}
    assert len(probe.targets) == 3  # each touch point, as commanded
    assert probe.jaw_goals == []  # key-point mode never moves the jaw


def test_connection_lost_mid_motion_stops_the_arm_and_faults(ros):
    _, stop_sim, _, probe = start_dvrk(ros, {"dvrk.measured_timeout": 0.5}, {"jaw_speed": 0.1})
    probe.publish_grasp()
    probe.wait_for_state("planned")
    future = probe.call_async(probe.execute)
    wait_until(lambda: probe.jaw_goals == [0.8], what="the jaw goal")  # the jaw now opens for 15 s
    wait_until(lambda: "executing" in probe.states, what="executing")
    stop_sim()  # the arm's topics go silent
    done = threading.Event()
    future.add_done_callback(lambda _: done.set())
    assert done.wait(TIMEOUT)
    message = future.result().message
    assert message.startswith(
        "fault: connection lost while moving to the jaw goal: no message on /PSM1/measured_cp"
    )
    assert message.endswith("sent move_cp to the last measured pose (hold) on /PSM1")
    probe.wait_for_state(message)
    assert probe.states[-3:] == ["planned", "executing", message]
    # the stop command: a move_cp goal at the last measured pose, and no other goal
    wait_until(lambda: len(probe.goals) == 1, what="the hold goal")
    np.testing.assert_allclose(probe.goals[0][1], probe.measured[-1], atol=1e-9)
    np.testing.assert_allclose(probe.goals[0][1], START.position, atol=1e-9)


# ---------------------------------------------------------------------------- bad input, arming, services


def test_dry_run_node_survives_bad_input_and_refuses_with_reasons(ros):
    # max_age 30 s: the fresh pose must stay fresh while a loaded CI machine delivers and plans it
    # (7.6 s seen); the stale one is published a minute old
    parameters = executor_parameters(backend="dry_run", armed=False, max_age=30.0)
    executor = ExecutorNode(context=ros.context, parameter_overrides=parameters)
    ros.spin(executor, threads=4)
    probe = Probe(ros)
    wait_until(lambda: probe.connected_to(executor), what="topics to connect")

    probe.publish_grasp(position=[math.nan, 0.0, 0.4])
    probe.publish_grasp(quaternion=[0.0, 0.0, 0.0, 0.0])
    probe.publish_grasp(frame="right_camera_optical_frame")
    bad_path = path_message(np.array([[0.0, 0.0, 0.4], [0.01, 0.0, 0.4]]), probe.now_ns(), CAMERA)
    bad_path.poses[1].pose.position.x = math.nan
    probe.path_pub.publish(to_rclpy(bad_path))

    response = probe.call(probe.execute)
    assert (response.success, response.message) == (
        False,
        "refused: not armed: set the parameter armed to true to allow motion",
    )
    probe.wait_for_state(response.message)
    assert "planned" not in probe.states  # the bad poses were dropped
    # counted per problem, so a wrong frame is warned about at once after a NaN pose
    wait_until(lambda: sum(executor.dropped.values()) == 4, what="the four bad inputs to be dropped")
    assert executor.dropped == {
        f"{GRASP_POSE} MessageConversionError": 2,  # NaN position, zero quaternion
        f"{GRASP_POSE} frame": 1,
        f"{PATH} MessageConversionError": 1,
    }

    assert executor.set_parameters([Parameter("armed", value=True)])[0].successful
    rejected = executor.set_parameters([Parameter("max_step", value=1.0)])[0]
    assert not rejected.successful and "read at start-up" in rejected.reason
    assert executor.get_parameter("max_step").value == 0.05
    assert probe.call(probe.execute).message == "refused: no valid grasp pose received yet"
    assert probe.call(probe.keypoints).message == "refused: no valid suture path received yet"

    probe.publish_grasp(age_s=60.0)
    probe.wait_for_state("planned")
    # its age when execute is called: a minute plus the delivery and the planning
    stale = re.fullmatch(
        r"refused: grasp pose is (\d+\.\d) s old \(max 30\.0 s\)", probe.call(probe.execute).message
    )
    assert stale and 60.0 <= float(stale.group(1)) < 90.0
    probe.publish_grasp()
    probe.wait_for_state("planned", count=2)
    assert probe.call(probe.execute).message == "done"
    probe.wait_for_state("done")
    assert probe.states[-3:] == ["planned", "executing", "done"]
    assert probe.call(probe.abort).message == "nothing to abort: no run is executing"


def test_example_config_file_starts_the_node(ros):
    values = parameter_dict_from_yaml_file(str(CONFIG / "executor.yaml"), target_nodes=["grasp_executor"])
    overrides = [Parameter.from_parameter_msg(message) for message in values.values()]
    assert len(overrides) == len(DEFAULTS)  # the example file documents every parameter
    executor = ExecutorNode(context=ros.context, parameter_overrides=overrides)
    try:
        assert executor.core.backend_name == "dry_run" and not executor.core.gate.armed
        assert executor.core.gate.limits.workspace_min == (0.25, -0.2, 0.0)
        np.testing.assert_allclose(executor.core.hand_eye.matrix, HAND_EYE.matrix, atol=1e-9)
    finally:
        executor.destroy_node()


@pytest.mark.parametrize(
    ("overrides", "match"),
    [
        ({"backend": "kuka"}, "parameter backend is 'kuka'; use one of dry_run, dvrk, ur"),
        ({"workspace.min": [0.6, 0.0, 0.0]}, "min < max"),
        ({"hand_eye.quaternion": [0.0, 0.0, 0.0, 2.0]}, "unit quaternion"),
        ({"hand_eye.translation": [0.0, 0.0]}, "hand_eye.translation must be a list of 3 numbers"),
        ({"max_step": "far"}, "max_step must be a number"),
        ({"hand_eye.file": "/nonexistent/hand_eye.yaml"}, "cannot read hand-eye file"),
        ({"backend": "ur", "ur.host": ""}, "ur.host"),
    ],
)
def test_bad_configuration_is_reported(ros, overrides, match):
    with pytest.raises(ConfigError, match=match):
        ExecutorNode(context=ros.context, parameter_overrides=executor_parameters(**overrides))


def _run_main(args: list[str], domain: int) -> subprocess.Popen:
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain), "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen(
        [sys.executable, "-m", "grasp_executor.executor_node", "--ros-args", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
    )


def test_main_exits_cleanly_on_ctrl_c_and_with_one_line_on_bad_config(ros_domain_id):
    process = _run_main(["-p", "backend:=bogus"], ros_domain_id)
    output, _ = process.communicate(timeout=TIMEOUT)
    assert process.returncode == 1
    assert (
        output.strip().splitlines()[-1]
        == "executor_node: parameter backend is 'bogus'; use one of dry_run, dvrk, ur"
    )

    process = _run_main([], ros_domain_id)
    lines = []
    for line in process.stdout:
        lines.append(line)
        if EXECUTE in line:
            break
    assert "dry_run backend, not armed" in "".join(lines)
    process.send_signal(signal.SIGINT)
    output, _ = process.communicate(timeout=TIMEOUT)
    assert process.returncode == 0, output
    assert "Traceback" not in output


def test_ctrl_c_during_a_motion_stops_the_arm_before_ros_shuts_down(ros):
    sim = PsmSimNode(context=ros.context, parameter_overrides=sim_parameters(jaw_speed=0.1))
    ros.spin(sim)
    probe = Probe(ros)
    arguments = []
    for parameter in executor_parameters(motion_timeout=30.0):
        value = parameter.value
        arguments += ["-p", f"{parameter.name}:={str(value).lower() if isinstance(value, bool) else value}"]
    process = _run_main(arguments, ros.domain_id)
    try:
        wait_until(lambda: probe.grasp_pub.get_subscription_count() >= 1, what="executor_node to start")
        probe.publish_grasp()
        probe.wait_for_state("planned")
        future = probe.call_async(probe.execute)
        wait_until(lambda: probe.jaw_goals == [0.8], what="the jaw goal")  # the jaw now opens for 15 s
        process.send_signal(signal.SIGINT)
        output, _ = process.communicate(timeout=TIMEOUT)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 0, output
    assert "Traceback" not in output
    # the run was aborted and the arm told to hold while ROS was still up
    wait_until(lambda: len(probe.goals) == 1, what="the hold goal")
    np.testing.assert_allclose(probe.goals[0][1], START.position, atol=1e-9)
    done = threading.Event()
    future.add_done_callback(lambda _: done.set())
    assert done.wait(TIMEOUT)
    assert future.result().message == (
        "fault: executor shutting down: aborted while moving to the jaw goal; "
        "sent move_cp to the last measured pose (hold) on /PSM1"
    )
