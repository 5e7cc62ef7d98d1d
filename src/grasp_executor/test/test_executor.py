# SPDX-License-Identifier: Apache-2.0
"""GraspExecutor (ROS-free): states, refusals, faults with a stop, abort, key-point mode; all backends.

The scene is the hand-eye worked example of docs/executor.md: the camera looks
straight down from 0.5 m, so a grasp point 0.45 m in front of it lies 0.05 m
above the table and the approach axis points down.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field

import numpy as np
import pytest

from grasp_executor.backends.base import AbortedError, NotReadyError
from grasp_executor.backends.dry_run import DryRunBackend
from grasp_executor.backends.dvrk import DvrkBackend
from grasp_executor.backends.ur import UrBackend
from grasp_executor.executor import (
    DONE,
    EXECUTING,
    IDLE,
    PLANNED,
    GraspExecutor,
    InvalidInputError,
    Listeners,
)
from grasp_executor.geometry import Pose, rotation_angle
from grasp_executor.handeye import HandEye
from grasp_executor.keypoints import KeypointConfig
from grasp_executor.planning import GraspConfig
from grasp_executor.safety import SafetyGate, SafetyLimits
from suture_common.grasp import grasp_rotation, rotation_to_quaternion

HAND_EYE = HandEye(
    [0.4, 0.0, 0.5], [math.sqrt(0.5), -math.sqrt(0.5), 0.0, 0.0], "left_camera_optical_frame", "base"
)
LIMITS = SafetyLimits(
    workspace_min=(0.3, -0.1, 0.0), workspace_max=(0.5, 0.1, 0.3), max_step=0.05, max_age=1.0
)
P_CAMERA = np.array([0.02, -0.01, 0.45])
GRASP_CAMERA = Pose(
    P_CAMERA, rotation_to_quaternion(grasp_rotation(P_CAMERA, [1.0, 0.0, 0.0])), HAND_EYE.camera_frame
)
NOW_NS = 1_700_000_000_000_000_000
CONFIG = GraspConfig(approach_offset=0.01, lift_distance=0.015, jaw_open=0.8, jaw_close=-0.1)


def grasp_plan():
    executor = GraspExecutor(DryRunBackend(log=lambda line: None), SafetyGate(LIMITS), HAND_EYE, CONFIG)
    return executor.on_grasp_pose(GRASP_CAMERA, NOW_NS)


PLAN = grasp_plan()
PRE_GRASP = dict(PLAN.moves())["pre_grasp"]
START = PRE_GRASP.translated([0.004, 0.0, 0.01])  # the robot waits 11 mm from the pre-grasp pose


@dataclass
class Harness:
    executor: GraspExecutor
    states: list[str] = field(default_factory=list)
    targets: list[tuple[Pose, int]] = field(default_factory=list)
    keypoints: list = field(default_factory=list)
    clock_ns: list[int] = field(default_factory=lambda: [NOW_NS])

    def advance(self, seconds: float) -> None:
        self.clock_ns[0] += int(seconds * 1e9)


def harness(backend, armed: bool = True, limits: SafetyLimits = LIMITS, **keypoints) -> Harness:
    h = Harness(executor=None)  # type: ignore[arg-type]
    listeners = Listeners(
        state=h.states.append,
        target=lambda pose, stamp: h.targets.append((pose, stamp)),
        keypoint=h.keypoints.append,
    )
    h.executor = GraspExecutor(
        backend,
        SafetyGate(limits, armed=armed),
        HAND_EYE,
        CONFIG,
        KeypointConfig(**{"count": 3, "dwell": 0.0, **keypoints}),
        motion_timeout=2.0,
        clock=lambda: h.clock_ns[0],
        listeners=listeners,
    )
    return h


# ---------------------------------------------------------------------------- the normal walk


def test_dry_run_walks_planned_executing_done():
    lines: list[str] = []
    h = harness(DryRunBackend(log=lines.append))
    assert h.executor.state == IDLE
    h.executor.on_grasp_pose(GRASP_CAMERA, NOW_NS)
    assert h.states == [PLANNED]
    h.executor.on_grasp_pose(GRASP_CAMERA, NOW_NS + 1)  # a repeat of the same state is not republished
    assert h.states == [PLANNED]
    outcome = h.executor.execute()
    assert (outcome.success, outcome.message) == (True, DONE)
    assert h.states == [PLANNED, EXECUTING, DONE]
    assert [line.split(" ")[1] for line in lines] == ["jaw", "move_to", "move_to", "jaw", "move_to"]
    assert h.executor.gate.armed  # a dry run rehearses the armed path; nothing moved


def test_commands_follow_the_plan_and_targets_carry_the_input_stamp(fakes):
    backend = fakes.Recording(START)
    h = harness(backend)
    h.executor.on_grasp_pose(GRASP_CAMERA, NOW_NS - 200_000_000)
    assert h.executor.execute().success
    assert [target for target, _ in backend.moves] == [pose for _, pose in PLAN.moves()]
    assert backend.jaws == [0.8, -0.1]
    assert backend.prepared == [PRE_GRASP]
    grasp = dict(PLAN.moves())["grasp"]
    np.testing.assert_allclose(grasp.position, [0.41, -0.02, 0.05], atol=1e-12)
    # published when planned and again when commanded, with the grasp pose's stamp
    assert h.targets == [(grasp, NOW_NS - 200_000_000)] * 2


def test_a_new_pose_during_a_run_does_not_change_the_run(fakes):
    backend = fakes.Recording(START)
    h = harness(backend)
    h.executor.on_grasp_pose(GRASP_CAMERA, NOW_NS)
    moved = Pose(P_CAMERA + np.array([0.01, 0.0, 0.0]), GRASP_CAMERA.quaternion, GRASP_CAMERA.frame_id)
    original = backend.move_to

    def move_to(target, timeout_s, cancel):
        h.executor.on_grasp_pose(moved, NOW_NS)
        original(target, timeout_s, cancel)

    backend.move_to = move_to
    assert h.executor.execute().success
    assert h.states == [PLANNED, EXECUTING, DONE]
    assert [target for target, _ in backend.moves] == [pose for _, pose in PLAN.moves()]
    h.executor.on_grasp_pose(moved, NOW_NS)
    assert h.states[-1] == PLANNED


# ---------------------------------------------------------------------------- refusals


def refused(h: Harness, expected: str) -> str:
    outcome = h.executor.execute()
    assert not outcome.success
    assert outcome.message.startswith("refused: "), outcome.message
    assert expected in outcome.message
    assert h.states[-1] == outcome.message
    return outcome.message


def test_refused_when_not_armed(fakes):
    backend = fakes.Recording(START)
    h = harness(backend, armed=False)
    h.executor.on_grasp_pose(GRASP_CAMERA, NOW_NS)
    refused(h, "not armed: set the parameter armed to true")
    assert backend.moves == [] and backend.prepared == []


def test_refused_without_a_grasp_pose(fakes):
    h = harness(fakes.Recording(START))
    assert refused(h, "no valid grasp pose received yet") == "refused: no valid grasp pose received yet"


def test_refused_when_the_pose_is_too_old_or_from_the_future(fakes):
    backend = fakes.Recording(START)
    h = harness(backend)
    h.executor.on_grasp_pose(GRASP_CAMERA, NOW_NS)
    h.advance(2.4)
    assert refused(h, "grasp pose is 2.4 s old (max 1.0 s)") == "refused: grasp pose is 2.4 s old (max 1.0 s)"
    h.executor.on_grasp_pose(GRASP_CAMERA, h.clock_ns[0] + 3_000_000_000)
    refused(h, "stamped 3.0 s in the future")
    assert backend.moves == []


def test_refused_outside_the_workspace(fakes):
    backend = fakes.Recording(START)
    low_ceiling = SafetyLimits(workspace_min=(0.3, -0.1, 0.0), workspace_max=(0.5, 0.1, 0.055), max_step=0.05)
    h = harness(backend, limits=low_ceiling)
    h.executor.on_grasp_pose(GRASP_CAMERA, NOW_NS)
    message = refused(h, "pre_grasp 5.0 mm outside workspace box on z")
    assert "box 0.0000 .. 0.0550 m" in message
    assert backend.moves == []


def test_refused_beyond_the_maximum_step(fakes):
    backend = fakes.Recording(PRE_GRASP.translated([0.0, 0.0, 0.08]))
    h = harness(backend)
    h.executor.on_grasp_pose(GRASP_CAMERA, NOW_NS)
    refused(h, "pre_grasp is 80.0 mm from the measured tool position (max step 50.0 mm)")
    assert backend.moves == []


def test_refused_without_or_with_a_nan_measured_pose(fakes):
    h = harness(fakes.Recording(None))
    h.executor.on_grasp_pose(GRASP_CAMERA, NOW_NS)
    refused(h, "no measured tool pose from the recording backend")
    h = harness(fakes.Recording(START.translated([math.nan, 0.0, 0.0])))
    h.executor.on_grasp_pose(GRASP_CAMERA, NOW_NS)
    refused(h, "measured tool pose position contains NaN or inf")


def test_refused_when_the_backend_is_not_ready(fakes):
    backend = fakes.Recording(START)

    def not_ready(first_target):
        raise NotReadyError("cannot connect to the UR controller: timed out")

    backend.prepare = not_ready
    h = harness(backend)
    h.executor.on_grasp_pose(GRASP_CAMERA, NOW_NS)
    assert refused(h, "cannot connect") == "refused: cannot connect to the UR controller: timed out"
    assert backend.stops == 0


def test_refused_while_busy(fakes):
    backend = fakes.Recording(START)
    h = harness(backend)
    h.executor.on_grasp_pose(GRASP_CAMERA, NOW_NS)
    answers = []
    original = backend.move_to

    def move_to(target, timeout_s, cancel):
        answers.append(h.executor.execute())
        answers.append(h.executor.visit_keypoints())
        original(target, timeout_s, cancel)

    backend.move_to = move_to
    assert h.executor.execute().success
    assert {a.message for a in answers} == {"refused: busy: a run is executing; wait for it or call abort"}
    assert len(backend.moves) == 3


def test_refusal_after_motion_began_stops_the_robot(fakes):
    backend = fakes.Recording(START, tracking_error=np.array([0.0, 0.0, 0.2]))  # the arm ends up 0.2 m off
    h = harness(backend)
    h.executor.on_grasp_pose(GRASP_CAMERA, NOW_NS)
    message = refused(h, "grasp is 210.0 mm from the measured tool position (max step 50.0 mm)")
    assert message.endswith("; recording: stopped")
    assert len(backend.moves) == 1 and backend.stops == 1


def test_invalid_inputs_are_rejected_and_change_nothing():
    h = harness(DryRunBackend(log=lambda line: None))
    with pytest.raises(InvalidInputError, match="NaN"):
        h.executor.on_grasp_pose(Pose([math.nan, 0, 0.4], [0, 0, 0, 1], HAND_EYE.camera_frame), NOW_NS)
    with pytest.raises(InvalidInputError, match="in frame 'base'"):
        h.executor.on_grasp_pose(Pose([0, 0, 0.4], [0, 0, 0, 1], "base"), NOW_NS)
    with pytest.raises(InvalidInputError, match="at least 2 points"):
        h.executor.on_path(np.zeros((1, 3)), HAND_EYE.camera_frame, NOW_NS)
    with pytest.raises(InvalidInputError, match="NaN"):
        h.executor.on_path(np.array([[0, 0, 0.4], [np.nan, 0, 0.4]]), HAND_EYE.camera_frame, NOW_NS)
    with pytest.raises(InvalidInputError, match="suture path is in frame"):
        h.executor.on_path(np.array([[0, 0, 0.4], [0.01, 0, 0.4]]), "base", NOW_NS)
    assert h.states == [] and h.executor.state == IDLE


# ---------------------------------------------------------------------------- faults: the robot is stopped


def test_dvrk_motion_timeout_stops_the_arm(fakes, fake_clock):
    transport = fakes.Crtk(fake_clock, START, mode="never")
    backend = DvrkBackend(transport, clock=fake_clock, sleep=fake_clock.sleep)
    h = harness(backend)
    h.executor.on_grasp_pose(GRASP_CAMERA, NOW_NS)
    outcome = h.executor.execute()
    assert not outcome.success
    assert outcome.message.startswith("fault: motion timeout: jaw goal not reached within 2.0 s")
    assert outcome.message.endswith("sent move_cp to the last measured pose (hold) on /PSM1")
    assert h.states == [PLANNED, EXECUTING, outcome.message]
    assert transport.jaw_goals == [0.8]
    assert transport.goals == [START]  # the hold goal, nothing else


def test_dvrk_connection_lost_mid_motion_stops_the_arm(fakes, fake_clock):
    transport = fakes.Crtk(fake_clock, START, duration=5.0)
    transport.lose_after_waits = 3
    backend = DvrkBackend(transport, measured_timeout=0.5, clock=fake_clock, sleep=fake_clock.sleep)
    h = harness(backend)
    h.executor.on_grasp_pose(GRASP_CAMERA, NOW_NS)
    outcome = h.executor.execute()
    assert outcome.message == (
        "fault: connection lost while moving to the jaw goal: no message on /PSM1/measured_cp for 0.52 s "
        "(max 0.50 s); sent move_cp to the last measured pose (hold) on /PSM1"
    )
    assert h.states[-1] == outcome.message
    assert transport.goals == [START]


def test_ur_motion_timeout_sends_stopl(fakes, fake_clock):
    ur = fakes.Ur(fake_clock, fakes.ur_pose(START), stuck=True)
    backend = UrBackend(ur.connect, speed=0.05, acceleration=0.2, clock=fake_clock, sleep=fake_clock.sleep)
    h = harness(backend)
    h.executor.on_grasp_pose(GRASP_CAMERA, NOW_NS)
    outcome = h.executor.execute()
    assert outcome.message.startswith(
        "fault: motion timeout: moveL not finished within 2.0 s (TCP still 10.8 mm"
    )
    assert outcome.message.endswith("sent stopL (2.0 m/s^2)")
    assert ur.stop_calls == [2.0]
    assert len(ur.move_calls) == 1


def test_ur_connection_lost_mid_motion_sends_stopl_and_faults(fakes, fake_clock):
    ur = fakes.Ur(fake_clock, fakes.ur_pose(START), disconnect_at=fake_clock.now + 0.1)
    backend = UrBackend(ur.connect, speed=0.05, clock=fake_clock, sleep=fake_clock.sleep)
    h = harness(backend)
    h.executor.on_grasp_pose(GRASP_CAMERA, NOW_NS)
    outcome = h.executor.execute()
    assert outcome.message.startswith("fault: connection to the UR controller lost during moveL")
    assert "stopL could not be sent: fake: RTDE control connection lost" in outcome.message
    assert ur.stop_calls == [2.0]  # the stop was attempted
    assert h.states[-1] == outcome.message


def test_ur_grasp_succeeds_without_jaw_steps(fakes, fake_clock):
    ur = fakes.Ur(fake_clock, fakes.ur_pose(START))
    backend = UrBackend(ur.connect, speed=0.05, acceleration=0.3, clock=fake_clock, sleep=fake_clock.sleep)
    h = harness(backend)
    h.executor.on_grasp_pose(GRASP_CAMERA, NOW_NS)
    assert h.executor.execute().message == DONE
    ur_plan = [pose for name, pose in PLAN.moves()]
    assert [call[1:] for call in ur.move_calls] == [(0.05, 0.3, True)] * 3
    for (values, *_), pose in zip(ur.move_calls, ur_plan, strict=True):
        np.testing.assert_allclose(values, fakes.ur_pose(pose), atol=1e-12)
    np.testing.assert_allclose(ur.tcp, fakes.ur_pose(dict(PLAN.moves())["lift"]), atol=1e-12)
    assert ur.stop_calls == []


class BlockingBackend:
    """Blocks in move_to until cancelled, like a slow motion."""

    name = "blocking"
    has_jaw = False

    def __init__(self) -> None:
        self.moving = threading.Event()
        self.stops = 0

    def prepare(self, first_target):
        pass

    def measured_pose(self):
        return START

    def move_to(self, target, timeout_s, cancel):
        self.moving.set()
        if cancel.wait(10.0):
            raise AbortedError("aborted during move")

    def move_jaw(self, angle, timeout_s, cancel):
        pass

    def stop(self):
        self.stops += 1
        return "blocking: stopped"

    def close(self):
        pass


@pytest.mark.parametrize("how", ["abort", "disarm"])
def test_abort_and_disarm_stop_a_running_motion(how):
    backend = BlockingBackend()
    h = harness(backend)
    h.executor.on_grasp_pose(GRASP_CAMERA, NOW_NS)
    assert h.executor.abort().message == "nothing to abort: no run is executing"
    result = []
    thread = threading.Thread(target=lambda: result.append(h.executor.execute()))
    thread.start()
    assert backend.moving.wait(10.0)
    if how == "abort":
        assert h.executor.abort().success
        expected = "fault: aborted on request: aborted during move; blocking: stopped"
    else:
        h.executor.set_armed(False)
        expected = "fault: disarmed: aborted during move; blocking: stopped"
    thread.join(10.0)
    assert result[0].message == expected
    assert backend.stops == 1
    assert h.states[-1] == expected


# ---------------------------------------------------------------------------- key-point mode


PATH_CAMERA = np.array([[-0.02, 0.0, 0.45], [0.0, 0.0, 0.45], [0.0, 0.02, 0.45]])  # two 20 mm legs


def test_keypoints_visit_each_point_and_record_the_measured_pose(fakes):
    backend = fakes.Recording(START, has_jaw=False, tracking_error=np.array([0.0003, 0.0, 0.0]))
    h = harness(backend, count=3, approach_offset=0.01)
    h.executor.on_path(PATH_CAMERA, HAND_EYE.camera_frame, NOW_NS)
    outcome = h.executor.visit_keypoints()
    assert outcome.success, outcome.message
    assert outcome.message == "done: visited 3 key points, max deviation 0.30 mm"
    assert h.states == [EXECUTING, DONE]
    expected = HAND_EYE.transform_points(PATH_CAMERA)
    touches = [target for target, _ in backend.moves[1::3]]
    np.testing.assert_allclose([t.position for t in touches], expected, atol=1e-12)
    # the tool keeps the orientation it had at the start; it approaches along its own z axis
    for target, _ in backend.moves:
        assert rotation_angle(target.quaternion, START.quaternion) < 1e-12
    np.testing.assert_allclose(backend.moves[0][0].position - expected[0], 0.01 * -START.axis(2), atol=1e-12)
    assert [r.index for r in h.keypoints] == [0, 1, 2]
    np.testing.assert_allclose([r.commanded for r in h.keypoints], expected, atol=1e-12)
    np.testing.assert_allclose(h.keypoints[1].commanded_camera, [0.0, 0.0, 0.45])
    assert h.keypoints[1].deviation == pytest.approx(0.0003)
    assert [stamp for _, stamp in h.targets] == [NOW_NS] * 3


def test_keypoints_with_a_fixed_orientation_in_a_dry_run():
    h = harness(DryRunBackend(log=lambda line: None), count=5, orientation_from_robot=False)
    h.executor.on_path(PATH_CAMERA, HAND_EYE.camera_frame, NOW_NS)
    outcome = h.executor.visit_keypoints()
    assert outcome.message == "done: visited 5 key points, max deviation 0.00 mm"
    assert len(h.keypoints) == 5
    assert rotation_angle(h.keypoints[0].measured.quaternion, [1.0, 0.0, 0.0, 0.0]) < 1e-12


def test_keypoints_refusals(fakes):
    backend = fakes.Recording(START, has_jaw=False)
    h = harness(backend, count=3)
    assert h.executor.visit_keypoints().message == "refused: no valid suture path received yet"
    h.executor.on_path(PATH_CAMERA, HAND_EYE.camera_frame, NOW_NS)
    h.advance(1.5)
    assert h.executor.visit_keypoints().message == "refused: suture path is 1.5 s old (max 1.0 s)"
    h.executor.on_path(PATH_CAMERA * [1, 1, 1.6], HAND_EYE.camera_frame, h.clock_ns[0])  # below the table
    message = h.executor.visit_keypoints().message
    assert message.startswith("refused: key point 1/3 approach") and "outside workspace box on z" in message
    h.executor.on_path(np.zeros((2, 3)) + 0.4, HAND_EYE.camera_frame, h.clock_ns[0])
    assert h.executor.visit_keypoints().message == "refused: suture path unusable: path has zero length"
    assert backend.moves == []


def test_a_bug_in_a_backend_still_stops_the_robot(fakes):
    backend = fakes.Recording(START)

    def broken(target, timeout_s, cancel):
        raise ZeroDivisionError("division by zero")

    backend.move_to = broken
    h = harness(backend)
    h.executor.on_grasp_pose(GRASP_CAMERA, NOW_NS)
    outcome = h.executor.execute()
    assert outcome.message == "fault: unexpected ZeroDivisionError: division by zero; recording: stopped"
    assert backend.stops == 1 and h.states[-1] == outcome.message
    assert h.executor.execute().message == outcome.message  # the executor keeps serving
