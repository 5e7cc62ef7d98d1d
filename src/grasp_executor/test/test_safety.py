# SPDX-License-Identifier: Apache-2.0
"""SafetyGate: every refusal reason, with numbers a person can act on; GuardedBackend never bypasses it."""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest

from grasp_executor.geometry import Pose
from grasp_executor.safety import GuardedBackend, RefusedError, SafetyGate, SafetyLimits

IDENTITY = [0.0, 0.0, 0.0, 1.0]
LIMITS = SafetyLimits(
    workspace_min=(0.3, -0.1, 0.0), workspace_max=(0.5, 0.1, 0.3), max_step=0.05, max_age=1.0
)


def pose(x: float, y: float, z: float, frame: str = "base", q=IDENTITY) -> Pose:
    return Pose([x, y, z], q, frame)


@pytest.fixture
def gate() -> SafetyGate:
    return SafetyGate(LIMITS, armed=True)


MEASURED = pose(0.4, 0.0, 0.1)


def refusal(check, *args) -> str:
    with pytest.raises(RefusedError) as info:
        check(*args)
    assert info.value.reason == str(info.value)
    return info.value.reason


def test_a_good_target_passes(gate):
    gate.check_move(pose(0.41, 0.01, 0.12), MEASURED, "grasp")
    gate.check_move(
        pose(0.5, 0.1, 0.3).translated([0, 0, 0]), pose(0.48, 0.08, 0.28), "corner"
    )  # bounds included


def test_not_armed_by_default():
    gate = SafetyGate(LIMITS)
    assert not gate.armed
    assert refusal(gate.check_move, pose(0.4, 0, 0.1), MEASURED, "grasp") == (
        "not armed: set the parameter armed to true to allow motion"
    )
    gate.set_armed(True)
    gate.check_move(pose(0.4, 0, 0.1), MEASURED, "grasp")


def test_outside_workspace_names_axis_and_distance(gate):
    reason = refusal(gate.check_move, pose(0.4, 0.0, 0.3123), pose(0.4, 0.0, 0.29), "grasp")
    assert reason == "grasp 12.3 mm outside workspace box on z (z = 0.3123 m, box 0.0000 .. 0.3000 m)"
    reason = refusal(gate.check_workspace, pose(0.296, 0.13, 0.1), "lift")
    assert reason.startswith("lift 30.0 mm outside workspace box on y")
    assert reason.endswith("; also 4.0 mm on x")


def test_step_too_large(gate):
    reason = refusal(gate.check_move, pose(0.46, 0.0, 0.1), MEASURED, "pre_grasp")
    assert reason == (
        "pre_grasp is 60.0 mm from the measured tool position (max step 50.0 mm); move the robot closer first"
    )


def test_age_in_both_directions(gate):
    gate.check_age(0.99)
    gate.check_age(-0.5)
    assert refusal(gate.check_age, 2.4) == "grasp pose is 2.4 s old (max 1.0 s)"
    assert refusal(gate.check_age, -3.0, "suture path").startswith(
        "suture path is stamped 3.0 s in the future (max 1.0 s)"
    )
    assert refusal(gate.check_age, math.nan) == "grasp pose has an invalid stamp"


@pytest.mark.parametrize(
    ("target", "reason"),
    [
        (pose(math.nan, 0.0, 0.1), "grasp position contains NaN or inf"),
        (pose(0.4, 0.0, math.inf), "grasp position contains NaN or inf"),
        (pose(0.4, 0.0, 0.1, q=[0.0, math.nan, 0.0, 1.0]), "grasp orientation contains NaN or inf"),
        (pose(0.4, 0.0, 0.1, q=[0.0, 0.0, 0.0, 0.0]), "grasp orientation is not a unit quaternion (norm 0)"),
    ],
)
def test_nan_targets(gate, target, reason):
    assert refusal(gate.check_move, target, MEASURED, "grasp") == reason


def test_measured_pose_problems(gate):
    target = pose(0.4, 0.0, 0.1)
    assert refusal(gate.check_move, target, None, "grasp", "dvrk") == (
        "no measured tool pose from the dvrk backend; is the robot connected?"
    )
    assert refusal(gate.check_move, target, pose(math.nan, 0, 0), "grasp") == (
        "measured tool pose position contains NaN or inf"
    )
    assert "robot measures in 'PSM1_base'" in refusal(
        gate.check_move, target, pose(0.4, 0, 0.1, frame="PSM1_base"), "grasp"
    )
    gate.check_move(target, pose(0.4, 0, 0.1, frame=""), "grasp")  # an unnamed frame is not a mismatch


def test_jaw_limits(gate):
    gate.check_jaw(1.4)
    assert (
        refusal(gate.check_jaw, 1.9, "open_jaw")
        == "open_jaw angle 1.900 rad outside jaw limits -0.350 .. 1.400 rad"
    )
    assert refusal(gate.check_jaw, math.nan) == "jaw angle is NaN or inf"


def test_plan_check_chains_steps_from_the_measured_pose(gate):
    moves = [
        ("pre_grasp", pose(0.4, 0.0, 0.14)),
        ("grasp", pose(0.4, 0.0, 0.13)),
        ("lift", pose(0.4, 0.0, 0.2)),
    ]
    gate.check_plan(moves[:2], [("open_jaw", 0.5)], MEASURED)
    assert refusal(gate.check_plan, moves, [], MEASURED).startswith("lift is 70.0 mm from the measured")
    assert refusal(gate.check_plan, moves[:1], [], pose(0.4, 0.0, 0.05)).startswith("pre_grasp is 90.0 mm")
    assert refusal(gate.check_plan, moves[:1], [("close_jaw", -1.0)], MEASURED).startswith("close_jaw angle")
    assert refusal(gate.check_plan, [("x", pose(0.4, 0, 0.31))], [], pose(0.4, 0, 0.29)).startswith(
        "x 10.0 mm"
    )


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"workspace_min": (0, 0, 0), "workspace_max": (1, 1, 0)}, "min < max"),
        ({"workspace_min": (0, 0), "workspace_max": (1, 1, 1)}, "3 values"),
        ({"workspace_min": (0, 0, math.nan), "workspace_max": (1, 1, 1)}, "finite"),
        ({"max_step": 0.0}, "max_step must be a positive"),
        ({"max_age": -1.0}, "max_age must be a positive"),
        ({"jaw_min": 1.0, "jaw_max": 0.0}, "jaw_min < jaw_max"),
    ],
)
def test_limits_validation(kwargs, match):
    arguments = {"workspace_min": (0, 0, 0), "workspace_max": (1, 1, 1), **kwargs}
    with pytest.raises(ValueError, match=match):
        SafetyLimits(**arguments)


def test_guarded_backend_never_passes_a_refused_command(gate, fakes):
    backend = fakes.Recording(MEASURED)
    guarded = GuardedBackend(backend, gate)
    cancel = threading.Event()
    guarded.move_to(pose(0.41, 0.0, 0.1), 1.0, cancel, "ok")
    for target in (pose(0.41, 0.0, 0.5), pose(math.nan, 0, 0), pose(0.3, 0.1, 0.0)):
        with pytest.raises(RefusedError):
            guarded.move_to(target, 1.0, cancel, "bad")
    with pytest.raises(RefusedError):
        guarded.move_jaw(2.0, 1.0, cancel)
    gate.set_armed(False)
    with pytest.raises(RefusedError, match="not armed"):
        guarded.move_jaw(0.5, 1.0, cancel)
    with pytest.raises(RefusedError, match="not armed"):
        guarded.prepare(pose(0.41, 0.0, 0.1))
    assert [target for target, _ in backend.moves] == [pose(0.41, 0.0, 0.1)]
    assert backend.jaws == [] and backend.prepared == []
    np.testing.assert_allclose(guarded.measured_pose().position, [0.41, 0.0, 0.1])


def test_box_and_step_checks_fail_closed_on_nan(gate):
    """Each check refuses NaN by itself, not only because check_finite runs first."""
    assert refusal(gate.check_workspace, pose(math.nan, 0.0, 0.1), "t") == "t position contains NaN or inf"
    assert refusal(gate.check_step, pose(math.nan, 0.0, 0.1), MEASURED, "t").startswith("t is nan mm")
    assert refusal(gate.check_step, MEASURED, pose(0.4, math.inf, 0.1), "t").startswith("t is inf mm")
