# SPDX-License-Identifier: Apache-2.0
"""Backends through their interface with the robot seam replaced: dvrk (fake CRTK transport), ur (fake RTDE).

Also the kinematic PSM model behind psm_sim_node.
"""

from __future__ import annotations

import math
import subprocess
import sys
import threading

import numpy as np
import pytest

from grasp_executor.backends.base import (
    AbortedError,
    Backend,
    BackendError,
    ConnectionLostError,
    MotionTimeoutError,
    NotReadyError,
)
from grasp_executor.backends.dry_run import DryRunBackend
from grasp_executor.backends.dvrk import DvrkBackend
from grasp_executor.backends.ur import UrBackend, rtde_connector
from grasp_executor.geometry import Pose, quaternion_multiply, rotation_angle, rotvec_to_quaternion
from grasp_executor.psm_sim import KinematicPsm

DOWN = rotvec_to_quaternion([math.pi, 0.0, 0.0])
START = Pose([0.40, 0.0, 0.10], DOWN, "base")
GOAL = Pose([0.41, -0.01, 0.08], DOWN, "base")


def test_every_backend_implements_the_interface(fakes, fake_clock):
    backends = [
        DryRunBackend(log=lambda line: None),
        DvrkBackend(fakes.Crtk(fake_clock, START)),
        UrBackend(fakes.Ur(fake_clock, fakes.ur_pose(START)).connect),
    ]
    assert all(isinstance(backend, Backend) for backend in backends)
    assert [(b.name, b.has_jaw) for b in backends] == [("dry_run", True), ("dvrk", True), ("ur", False)]


# ---------------------------------------------------------------------------- dvrk


@pytest.fixture
def dvrk(fakes, fake_clock):
    transport = fakes.Crtk(fake_clock, START, duration=0.3)
    return transport, DvrkBackend(transport, clock=fake_clock, sleep=fake_clock.sleep)


def test_dvrk_move_and_jaw(dvrk):
    transport, backend = dvrk
    cancel = threading.Event()
    backend.prepare(GOAL)
    backend.move_to(GOAL, 2.0, cancel)
    backend.move_jaw(-0.1, 2.0, cancel)
    assert transport.goals == [GOAL]
    assert transport.jaw_goals == [-0.1]
    assert backend.measured_pose() == GOAL


def test_dvrk_not_ready_without_fresh_feedback(fakes, fake_clock):
    backend = DvrkBackend(fakes.Crtk(fake_clock, None))
    with pytest.raises(
        NotReadyError, match="no message on /PSM1/measured_cp yet: is the dVRK console running"
    ):
        backend.prepare(GOAL)
    transport = fakes.Crtk(fake_clock, START)
    fake_clock.sleep(2.0)
    with pytest.raises(NotReadyError, match="/PSM1/measured_cp is 2.00 s old"):
        DvrkBackend(transport).prepare(GOAL)
    assert transport.goals == []


def test_dvrk_timeout_goal_not_reached_and_drift(fakes, fake_clock):
    cancel = threading.Event()
    for mode, error, match in [
        ("never", MotionTimeoutError, "motion timeout: move_cp goal not reached within 1.0 s"),
        ("false", BackendError, "reported goal_reached false for the move_cp goal"),
        ("drift", BackendError, "goal_reached, but /PSM1/measured_cp is 5.0 mm from the move_cp goal"),
    ]:
        transport = fakes.Crtk(fake_clock, START, mode=mode)
        backend = DvrkBackend(transport, position_tolerance=0.002, clock=fake_clock, sleep=fake_clock.sleep)
        with pytest.raises(error, match=match):
            backend.move_to(GOAL, 1.0, cancel)


def test_dvrk_abort_and_stop(dvrk):
    transport, backend = dvrk
    cancel = threading.Event()
    cancel.set()
    with pytest.raises(AbortedError):
        backend.move_to(GOAL, 1.0, cancel)
    assert backend.stop() == "sent move_cp to the last measured pose (hold) on /PSM1"
    assert transport.goals[-1] == START


def test_dvrk_stop_never_raises(fakes, fake_clock):
    transport = fakes.Crtk(fake_clock, None)
    assert DvrkBackend(transport).stop() == "no measured_cp to hold; nothing sent"
    transport.pose = START

    def broken(pose):
        raise RuntimeError("publisher gone")

    transport.send_goal = broken
    assert DvrkBackend(transport).stop() == "stop could not be sent: publisher gone"


def test_dvrk_refuses_to_send_without_a_connection(fakes, fake_clock):
    transport = fakes.Crtk(fake_clock, START)
    fake_clock.sleep(1.0)
    with pytest.raises(ConnectionLostError, match="connection lost before move_cp"):
        DvrkBackend(transport).move_to(GOAL, 1.0, threading.Event())
    assert transport.goals == []


# ---------------------------------------------------------------------------- ur


def test_ur_movel_with_limits_and_rotation_vector(fakes, fake_clock):
    ur = fakes.Ur(fake_clock, fakes.ur_pose(START))
    backend = UrBackend(ur.connect, speed=0.04, acceleration=0.5, clock=fake_clock, sleep=fake_clock.sleep)
    assert backend.measured_pose() is None  # not connected before the first run
    backend.prepare(GOAL)
    backend.move_to(GOAL, 5.0, threading.Event())
    ((pose, speed, acceleration, asynchronous),) = ur.move_calls
    assert (speed, acceleration, asynchronous) == (0.04, 0.5, True)
    np.testing.assert_allclose(pose, [0.41, -0.01, 0.08, math.pi, 0.0, 0.0], atol=1e-12)
    measured = backend.measured_pose()
    np.testing.assert_allclose(measured.position, GOAL.position, atol=1e-12)
    assert rotation_angle(measured.quaternion, DOWN) < 1e-9 and measured.frame_id == "base"
    # 24.5 mm at 40 mm/s: the motion took about 0.6 s of (fake) time, polled every 10 ms
    assert fake_clock.now - 1000.0 == pytest.approx(0.62, abs=0.02)
    assert ur.connects == 1
    backend.prepare(GOAL)
    assert ur.connects == 1  # still connected: no reconnect


def test_ur_not_ready(fakes, fake_clock):
    ur = fakes.Ur(fake_clock, fakes.ur_pose(START), disconnect_at=fake_clock.now)
    with pytest.raises(NotReadyError, match="cannot connect to the UR controller: fake: cannot connect"):
        UrBackend(ur.connect).prepare(GOAL)
    ur = fakes.Ur(fake_clock, fakes.ur_pose(START), safety_mode=3)
    with pytest.raises(
        NotReadyError, match="UR safety mode is protective stop; clear it on the teach pendant"
    ):
        UrBackend(ur.connect).prepare(GOAL)
    assert ur.move_calls == []


def test_ur_faults_during_motion(fakes, fake_clock):
    ur = fakes.Ur(fake_clock, fakes.ur_pose(START))
    backend = UrBackend(ur.connect, clock=fake_clock, sleep=fake_clock.sleep)
    backend.prepare(GOAL)
    ur.safety_mode = 3
    with pytest.raises(BackendError, match="UR entered protective stop during moveL"):
        backend.move_to(GOAL, 5.0, threading.Event())
    ur.safety_mode = 1
    ur.accept = False
    with pytest.raises(BackendError, match="rejected moveL"):
        backend.move_to(GOAL, 5.0, threading.Event())
    ur.accept = True
    cancel = threading.Event()
    cancel.set()
    with pytest.raises(AbortedError, match="aborted during moveL"):
        backend.move_to(START, 5.0, cancel)
    assert backend.stop() == "sent stopL (2.0 m/s^2)"
    ur.disconnect_at = fake_clock.now
    with pytest.raises(ConnectionLostError, match="lost before moveL"):
        backend.move_to(GOAL, 5.0, threading.Event())
    assert backend.measured_pose() is None


def test_ur_has_no_jaw_and_validates_limits(fakes, fake_clock):
    backend = UrBackend(fakes.Ur(fake_clock, fakes.ur_pose(START)).connect)
    with pytest.raises(BackendError, match="no jaw"):
        backend.move_jaw(0.5, 1.0, threading.Event())
    assert backend.stop() == "not connected; nothing to stop"
    with pytest.raises(ValueError, match="ur.speed must be positive"):
        UrBackend(fakes.Ur(fake_clock, fakes.ur_pose(START)).connect, speed=0.0)
    with pytest.raises(ValueError, match=r"ur\.host"):
        rtde_connector("")


def test_ur_module_imports_without_loading_ur_rtde():
    code = (
        "import sys, grasp_executor.backends.ur as ur; ur.rtde_connector('ur5'); "
        "print('rtde_control' in sys.modules)"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60
    )
    assert result.stdout.strip() == "False"


# ---------------------------------------------------------------------------- kinematic PSM


def test_kinematic_psm_follows_a_goal_then_reports_goal_reached():
    psm = KinematicPsm(START, 0.0, linear_speed=0.05, angular_speed=1.0, jaw_speed=1.0)
    turned = Pose(GOAL.position, quaternion_multiply(DOWN, rotvec_to_quaternion([0.0, 0.0, 0.8])), "ignored")
    assert rotation_angle(turned.quaternion, DOWN) == pytest.approx(0.8)
    assert psm.move_cp(turned, now=10.0) == []
    duration = 1.875 * 0.8 / 1.0  # the rotation (0.8 rad at 1 rad/s) takes longer than 24.5 mm at 50 mm/s
    half = psm.update(10.0 + duration / 2)
    assert half == []
    midpoint = (START.position + GOAL.position) / 2
    np.testing.assert_allclose(psm.pose.position, midpoint, atol=1e-12)  # quintic scaling: s(1/2) = 1/2
    assert rotation_angle(psm.pose.quaternion, DOWN) == pytest.approx(0.4)
    assert psm.update(10.0 + duration - 1e-6) == []
    assert psm.update(10.0 + duration) == [True]
    np.testing.assert_allclose(psm.pose.position, GOAL.position)
    assert rotation_angle(psm.pose.quaternion, turned.quaternion) < 1e-12
    assert psm.pose.frame_id == "base" and not psm.moving
    assert psm.update(20.0) == []


def test_kinematic_psm_jaw_preemption_and_bad_goals():
    psm = KinematicPsm(START, 0.0, jaw_speed=2.0)
    assert psm.move_jaw(0.8, now=0.0) == []
    assert psm.move_jaw(-0.1, now=0.1) == [False]  # the interrupted jaw goal is not reached
    assert psm.update(0.1 + 1.875 * abs(-0.1 - psm.jaw) / 2.0) == [True]
    assert psm.jaw == -0.1
    assert psm.move_cp(GOAL, 1.0) == []
    assert psm.move_cp(START, 1.1) == [False]
    with pytest.raises(ValueError, match="NaN"):
        psm.move_cp(Pose([math.nan, 0, 0], DOWN), 2.0)
    with pytest.raises(ValueError, match="unit quaternion"):
        psm.move_cp(Pose([0, 0, 0], [0, 0, 0, 0.5]), 2.0)
    with pytest.raises(ValueError, match="NaN"):
        psm.move_jaw(math.nan, 2.0)
