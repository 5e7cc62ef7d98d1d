"""What player_node and recorder_node share: their parameter declaration."""

from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node


def declare_parameters(node: Node, parameters: dict[str, tuple[Any, str]]) -> dict[str, Any]:
    """Declare ``parameters`` (name -> (default, description)) on ``node``; their values by name.

    Numbers may be given as int or double (dynamic typing); a single string given for the
    string-array parameter ``topics`` counts as a list of one.
    """
    values = {}
    for name, (default, description) in parameters.items():
        descriptor = ParameterDescriptor(description=description, dynamic_typing=True)
        values[name] = node.declare_parameter(name, default, descriptor).value
    if isinstance(values.get("topics"), str):
        values["topics"] = [values["topics"]]
    return values
