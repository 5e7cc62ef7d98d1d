# SPDX-License-Identifier: Apache-2.0
"""ParameterSpec and declare_parameters: descriptions and ranges reach rclpy, bad values are refused."""

from __future__ import annotations

import dataclasses
import math

import pytest
import rclpy
from rcl_interfaces.msg import ParameterType
from rclpy.parameter import Parameter

from suture_common.parameters import (
    ParameterSpec,
    ParameterValueError,
    dataclass_parameters,
    described,
    field_parameter,
    spec_table,
)
from suture_common.ros import declare_parameters

SPECS = spec_table(
    (
        ParameterSpec("wait", 0.1, "seconds to wait", (0.0, 60.0)),
        ParameterSpec("depth", 10, "queue depth", (1, 100)),
        ParameterSpec("rate", 1.0, "speed factor", (0.0, math.inf), dynamic_typing=True),
        ParameterSpec("frame", "left", "output frame"),
        ParameterSpec("gains", [1.0, 2.0], "two gains"),
    )
)


@pytest.fixture
def context(ros_domain_id):
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=ros_domain_id)
    yield context
    rclpy.shutdown(context=context)


def node_with(context, **overrides):
    parameters = [Parameter(name, value=value) for name, value in overrides.items()]
    return rclpy.create_node("parameters_test", context=context, parameter_overrides=parameters)


def test_specs_check_themselves():
    assert SPECS["gains"].kind == "double_array" and not SPECS["gains"].numeric
    assert SPECS["depth"].range_text() == "[1, 100]" and SPECS["rate"].range_text() == "[0, inf]"
    with pytest.raises(ValueError, match="no description"):
        ParameterSpec("x", 1.0, " ")
    with pytest.raises(ValueError, match="only numbers have a range"):
        ParameterSpec("x", "a", "text", (0, 1))
    with pytest.raises(ValueError, match="default of x must be in"):
        ParameterSpec("x", 2.0, "number", (0.0, 1.0))
    with pytest.raises(ValueError, match="declared twice"):
        spec_table([SPECS["wait"], SPECS["wait"]])
    assert SPECS["wait"].problem(61.0) == "wait must be in [0, 60], got 61.0"
    assert SPECS["wait"].problem(math.nan) == "wait must be in [0, 60], got nan"
    assert SPECS["wait"].problem(1) == "wait must be a double, got 1 (an integer)"
    assert SPECS["rate"].problem(2) is None  # dynamic typing: an integer is a number too


def test_dataclass_fields_carry_their_parameters():
    @dataclasses.dataclass
    class Settings:
        gain: float = dataclasses.field(default=0.5, metadata=described("a gain", (0.0, 1.0)))
        pair: tuple[float, float] = dataclasses.field(default=(1.0, 2.0), metadata=described("a pair"))

    specs = dataclass_parameters(
        Settings, lambda f: list(f.default) if isinstance(f.default, tuple) else f.default
    )
    assert [(s.name, s.default, s.range) for s in specs] == [
        ("gain", 0.5, (0.0, 1.0)),
        ("pair", [1.0, 2.0], None),
    ]

    @dataclasses.dataclass
    class Undescribed:
        gain: float = 0.5

    with pytest.raises(TypeError, match="Undescribed.gain has no parameter description"):
        dataclass_parameters(Undescribed)
    assert field_parameter(Settings, "gain") == specs[0]
    with pytest.raises(TypeError, match="Undescribed.gain"):
        field_parameter(Undescribed, "gain")


def test_descriptors_carry_description_type_and_range(context):
    node = node_with(context, rate=3)
    try:
        values = declare_parameters(node, SPECS.values())
        assert values == {"wait": 0.1, "depth": 10, "rate": 3, "frame": "left", "gains": [1.0, 2.0]}
        wait, depth, rate = node.describe_parameters(["wait", "depth", "rate"])
        assert wait.description == "seconds to wait" and wait.type == ParameterType.PARAMETER_DOUBLE
        assert (wait.floating_point_range[0].from_value, wait.floating_point_range[0].to_value) == (0.0, 60.0)
        assert (depth.integer_range[0].from_value, depth.integer_range[0].to_value) == (1, 100)
        assert rate.dynamic_typing and rate.integer_range[0].to_value == 2**63 - 1
        # at run time, rclpy itself refuses a value outside the range
        assert not node.set_parameters([Parameter("wait", value=-1.0)])[0].successful
        assert not node.set_parameters([Parameter("rate", value=-1)])[0].successful
        assert node.set_parameters([Parameter("depth", value=100)])[0].successful
    finally:
        node.destroy_node()


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"wait": -1.0}, "wait must be in [0, 60], got -1.0"),
        ({"depth": 0}, "depth must be in [1, 100], got 0"),
        ({"depth": 1.5}, "depth must be an integer, got 1.5 (a double)"),
        ({"rate": -2}, "rate must be in [0, inf], got -2"),
        ({"frame": 3}, "frame must be a string, got 3 (an integer)"),
    ],
)
def test_a_bad_start_up_value_is_one_clear_value_error(context, overrides, message):
    node = node_with(context, **overrides)
    try:
        with pytest.raises(ParameterValueError) as raised:
            declare_parameters(node, SPECS.values())
        assert str(raised.value) == message
    finally:
        node.destroy_node()
