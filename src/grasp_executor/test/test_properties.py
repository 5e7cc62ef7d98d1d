# SPDX-License-Identifier: Apache-2.0
"""Property tests: whatever the grasp pose, hand-eye transform and workspace box, no command sent to a
backend lies outside the box or beyond the maximum step, and NaN never reaches a backend.

The backend is a recording fake that answers every move by being at the target
plus a random tracking error, so the measured pose drifts from the plan as a
real arm's does; it can also start reporting NaN mid-run.
"""

from __future__ import annotations

import math
import threading

import numpy as np
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from grasp_executor.backends.base import AbortedError
from grasp_executor.executor import GraspExecutor, InvalidInputError
from grasp_executor.geometry import Pose
from grasp_executor.handeye import HandEye
from grasp_executor.keypoints import KeypointConfig
from grasp_executor.planning import GraspConfig
from grasp_executor.safety import RefusedError, SafetyGate, SafetyLimits

NOW_NS = 1_700_000_000_000_000_000
SETTINGS = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])

finite = st.floats(-1.0, 1.0, allow_nan=False)
bad = st.sampled_from([math.nan, math.inf, -math.inf])


def vectors(size: int, low: float, high: float):
    return st.lists(st.floats(low, high, allow_nan=False), min_size=size, max_size=size).map(np.array)


def _normalised(q: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(q)
    return q / norm if norm > 1e-3 else np.array([0.0, 0.0, 0.0, 1.0])


quaternions = vectors(4, -1.0, 1.0).map(_normalised)


@st.composite
def maybe_nan(draw, values: np.ndarray, probability_weight: int = 8) -> np.ndarray:
    """``values``, or (one time in ``probability_weight``) a copy with one element NaN or infinite."""
    if draw(st.integers(0, probability_weight - 1)) != 0:
        return values
    values = values.copy()
    values[draw(st.integers(0, len(values) - 1))] = draw(bad)
    return values


class Recorder:
    """A backend that records each command with the measured pose at the moment it was sent."""

    name = "recorder"

    def __init__(self, start: Pose, has_jaw: bool, tracking_error: np.ndarray, nan_after: int | None) -> None:
        self.pose = start
        self.has_jaw = has_jaw
        self.tracking_error = tracking_error
        self.nan_after = nan_after
        self.moves: list[tuple[Pose, Pose | None]] = []
        self.jaws: list[float] = []

    def prepare(self, first_target: Pose) -> None:
        pass

    def measured_pose(self) -> Pose | None:
        return self.pose

    def move_to(self, target: Pose, timeout_s: float, cancel: threading.Event) -> None:
        if cancel.is_set():
            raise AbortedError("cancelled")
        self.moves.append((target, self.pose))
        self.pose = target.translated(self.tracking_error)
        if self.nan_after is not None and len(self.moves) >= self.nan_after:
            self.pose = self.pose.translated([math.nan, 0.0, 0.0])

    def move_jaw(self, angle: float, timeout_s: float, cancel: threading.Event) -> None:
        self.jaws.append(angle)

    def stop(self) -> str:
        return "stopped"

    def close(self) -> None:
        pass


def assert_every_command_was_safe(recorder: Recorder, limits: SafetyLimits) -> None:
    low, high = np.array(limits.workspace_min), np.array(limits.workspace_max)
    for target, measured in recorder.moves:
        assert target.is_finite(), "NaN reached the backend"
        assert measured is not None and measured.is_finite(), "a move was sent against a NaN measured pose"
        assert np.all(target.position >= low) and np.all(target.position <= high), "target outside the box"
        assert np.linalg.norm(target.position - measured.position) <= limits.max_step, "step too large"
        assert abs(np.linalg.norm(target.quaternion) - 1.0) < 1e-6
    for angle in recorder.jaws:
        assert math.isfinite(angle) and limits.jaw_min <= angle <= limits.jaw_max


@st.composite
def scenes(draw):
    hand_eye = HandEye(draw(vectors(3, -0.5, 0.5)), draw(quaternions), "camera", "base")
    position = np.array([draw(st.floats(-0.1, 0.1)), draw(st.floats(-0.1, 0.1)), draw(st.floats(0.05, 0.5))])
    grasp = Pose(draw(maybe_nan(position)), draw(maybe_nan(draw(quaternions))), "camera")
    anchor = hand_eye.transform_points(position)
    centre = anchor + draw(vectors(3, -0.05, 0.05))
    half = draw(vectors(3, 0.005, 0.3))
    limits = SafetyLimits(
        workspace_min=tuple(centre - half),
        workspace_max=tuple(centre + half),
        max_step=draw(st.floats(0.001, 0.15)),
        max_age=1.0,
    )
    start = Pose(draw(maybe_nan(anchor + draw(vectors(3, -0.05, 0.05)))), draw(quaternions), "base")
    recorder = Recorder(
        start,
        has_jaw=draw(st.booleans()),
        tracking_error=draw(vectors(3, -0.01, 0.01)),
        nan_after=draw(st.one_of(st.none(), st.integers(1, 4))),
    )
    config = GraspConfig(
        approach_offset=draw(st.floats(0.0, 0.05)),
        lift_distance=draw(st.floats(0.0, 0.05)),
        jaw_open=draw(st.floats(-0.5, 1.6)),
        jaw_close=draw(st.floats(-0.5, 1.6)),
    )
    return hand_eye, grasp, limits, recorder, config


def make_executor(hand_eye, limits, recorder, config, keypoints=None) -> GraspExecutor:
    return GraspExecutor(
        recorder,
        SafetyGate(limits, armed=True),
        hand_eye,
        config,
        keypoints or KeypointConfig(dwell=0.0),
        clock=lambda: NOW_NS,
    )


@SETTINGS
@given(scenes())
def test_no_unsafe_command_reaches_a_backend(scene):
    hand_eye, grasp, limits, recorder, config = scene
    executor = make_executor(hand_eye, limits, recorder, config)
    try:
        executor.on_grasp_pose(grasp, NOW_NS)
    except InvalidInputError:
        assert not grasp.is_finite()
    outcome = executor.execute()
    event(outcome.message.split(":")[0])
    assert_every_command_was_safe(recorder, limits)
    if not grasp.is_finite():
        assert recorder.moves == [] and recorder.jaws == []
        assert outcome.message == "refused: no valid grasp pose received yet"
    assert outcome.success == (len(recorder.moves) == 3), outcome.message
    assert outcome.message.split(":")[0] in ("done", "refused", "fault")


@SETTINGS
@given(scenes(), st.integers(1, 12), st.lists(vectors(3, -0.02, 0.02), min_size=2, max_size=6))
def test_no_unsafe_key_point_command_reaches_a_backend(scene, count, offsets):
    hand_eye, grasp, limits, recorder, config = scene
    path = grasp.position + np.cumsum(offsets, axis=0)
    executor = make_executor(hand_eye, limits, recorder, config, KeypointConfig(count=count, dwell=0.0))
    try:
        executor.on_path(path, "camera", NOW_NS)
    except InvalidInputError:
        assert not np.isfinite(path).all()
    outcome = executor.visit_keypoints()
    event(outcome.message.split(":")[0])
    assert_every_command_was_safe(recorder, limits)
    if not np.isfinite(path).all():
        assert recorder.moves == []
    assert outcome.success == (len(recorder.moves) == 3 * count), outcome.message


@SETTINGS
@given(scenes())
def test_safe_plans_are_executed(scene):
    """The converse: a box and a step limit that fit the plan never refuse it (the checks are not vacuous)."""
    hand_eye, grasp, _, recorder, config = scene
    grasp = Pose(np.nan_to_num(grasp.position, posinf=0.1, neginf=0.1, nan=0.1), [0, 0, 0, 1], "camera")
    recorder.tracking_error = np.zeros(3)
    recorder.nan_after = None
    plan = make_executor(hand_eye, SafetyLimits((-9, -9, -9), (9, 9, 9)), recorder, config).on_grasp_pose(
        grasp, 0
    )
    positions = np.array([pose.position for _, pose in plan.moves()])
    recorder.pose = Pose(positions[0], [0, 0, 0, 1], "base")
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    limits = SafetyLimits(
        workspace_min=tuple(positions.min(axis=0) - 1e-6),
        workspace_max=tuple(positions.max(axis=0) + 1e-6),
        max_step=float(steps.max()) + 1e-6,
        jaw_min=min(config.jaw_open, config.jaw_close) - 1e-6,
        jaw_max=max(config.jaw_open, config.jaw_close) + 1e-6,
    )
    executor = make_executor(hand_eye, limits, recorder, config)
    executor.on_grasp_pose(grasp, NOW_NS)
    outcome = executor.execute()
    assert outcome.message == "done", outcome.message
    assert_every_command_was_safe(recorder, limits)


@SETTINGS
@given(
    maybe_nan(np.zeros(3), 3).map(lambda offset: offset + np.array([0.4, 0.0, 0.1])),
    vectors(3, -0.2, 0.2),
    st.one_of(quaternions, st.just(np.array([0.0, 0.0, 0.0, 0.0])), st.just(np.array([math.nan, 0, 0, 1]))),
    st.floats(0.001, 0.2),
)
def test_the_gate_passes_only_safe_targets(measured_position, delta, quaternion, max_step):
    limits = SafetyLimits((0.3, -0.1, 0.0), (0.5, 0.1, 0.3), max_step=max_step)
    gate = SafetyGate(limits, armed=True)
    measured = Pose(measured_position, [0, 0, 0, 1], "base")
    target = Pose(
        np.nan_to_num(measured_position, nan=0.4, posinf=0.4, neginf=0.4) + delta, quaternion, "base"
    )
    try:
        gate.check_move(target, measured, "target")
    except RefusedError as refusal:
        assert refusal.reason
        return
    recorder = Recorder(measured, False, np.zeros(3), None)
    recorder.moves.append((target, measured))
    assert_every_command_was_safe(recorder, limits)
