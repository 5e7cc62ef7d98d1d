# SPDX-License-Identifier: Apache-2.0
"""The nodes' ROS parameters as data: name, default, description and range, without rclpy.

Every node lists its parameters as :class:`ParameterSpec` objects; :func:`suture_common.ros.
declare_parameters` declares them with a ``ParameterDescriptor`` carrying the description and,
for numbers, the range, so that ``ros2 param describe`` explains each one and rclpy refuses a
value outside its range. Parameters read from a dataclass keep their description and range
next to the field, in its metadata (:func:`described`), and :func:`dataclass_parameters` turns
the fields into specs, so the two cannot diverge.

Ranges are inclusive, as in ``rcl_interfaces/FloatingPointRange`` and ``IntegerRange``; a value
that must be strictly positive has the range [0, ...] and the check of the code that uses it.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

PARAMETER_METADATA = "ros_parameter"
"""Key of a dataclass field's metadata that holds its (description, range)."""

INT64_MAX = 2**63 - 1

Range = tuple[float, float]


class ParameterValueError(ValueError):
    """A parameter value given to a node is of the wrong type or outside its range."""


def described(description: str, value_range: Range | None = None) -> dict[str, Any]:
    """Dataclass field metadata: the parameter's description and, for a number, its range."""
    return {PARAMETER_METADATA: (description, value_range)}


def _kind(value: Any) -> str:
    if isinstance(value, bool):
        return "bool"
    if isinstance(value, int):
        return "integer"
    if isinstance(value, float):
        return "double"
    if isinstance(value, str):
        return "string"
    if isinstance(value, (list, tuple)) and value:
        item = _kind(value[0])
        if all(_kind(v) == item for v in value) and item in ("bool", "integer", "double", "string"):
            return f"{item}_array"
    raise TypeError(f"no ROS parameter type for {value!r}")


def _a(kind: str) -> str:
    return f"an {kind}" if kind[0] in "aeiou" else f"a {kind}"


def _format_number(value: float) -> str:
    if value == math.inf:
        return "inf"
    if value == -math.inf:
        return "-inf"
    return f"{value:g}" if isinstance(value, float) else str(value)


@dataclass(frozen=True)
class ParameterSpec:
    """One ROS parameter: its name, default (which fixes its type), description and range.

    ``dynamic_typing`` lets a number be given as an integer or a double (the node converts it);
    otherwise the type of the default is the only type accepted.
    """

    name: str
    default: Any
    description: str
    range: Range | None = None
    dynamic_typing: bool = False

    def __post_init__(self) -> None:
        kind = self.kind  # TypeError for a default ROS cannot hold
        if not self.description.strip():
            raise ValueError(f"parameter {self.name} has no description")
        if self.range is not None:
            if kind not in ("integer", "double"):
                raise ValueError(f"parameter {self.name} is a {kind}: only numbers have a range")
            low, high = self.range
            if not low <= high:
                raise ValueError(f"parameter {self.name}: empty range {self.range}")
            problem = self.problem(self.default)
            if problem:
                raise ValueError(f"default of {problem}")

    @property
    def kind(self) -> str:
        """The ROS type of the default: bool, integer, double, string or ``<type>_array``."""
        return _kind(self.default)

    @property
    def numeric(self) -> bool:
        return self.kind in ("integer", "double")

    def range_text(self) -> str:
        """The range as ``[low, high]``, or "" when there is none."""
        if self.range is None:
            return ""
        low, high = self.range
        return f"[{_format_number(low)}, {_format_number(high)}]"

    def problem(self, value: Any) -> str | None:
        """Why ``value`` is refused (type or range), naming the parameter; None if it is accepted."""
        expected = self.kind
        try:
            given = _kind(value)
        except TypeError:
            given = type(value).__name__
        numbers = ("integer", "double")
        if given != expected and not self.dynamic_typing:  # with dynamic typing the node checks it
            return f"{self.name} must be {_a(expected)}, got {value!r} ({_a(given)})"
        if self.range is not None and given in numbers:
            low, high = self.range
            if not low <= value <= high:
                return f"{self.name} must be in {self.range_text()}, got {value!r}"
        return None


def dataclass_parameters(
    cls: type,
    default_of: Callable[[dataclasses.Field[Any]], Any] = lambda field: field.default,
) -> list[ParameterSpec]:
    """One :class:`ParameterSpec` per field of the dataclass ``cls``, from the fields' metadata.

    ``default_of`` gives the parameter default of a field (e.g. a tuple as a list). A field
    without :func:`described` metadata is a TypeError: every field must say what it is.
    """
    return [field_parameter(cls, field.name, default=default_of(field)) for field in dataclasses.fields(cls)]


def field_parameter(
    cls: type,
    field_name: str,
    name: str | None = None,
    default: Any = dataclasses.MISSING,
    dynamic_typing: bool = False,
) -> ParameterSpec:
    """The :class:`ParameterSpec` of one field of the dataclass ``cls``, for a node that exposes
    some fields of its core's dataclasses.

    ``name`` (default: the field's) is the parameter's name; ``default`` (default: the field's,
    a tuple as a list) its default. A field without :func:`described` metadata is a TypeError.
    """
    field = {f.name: f for f in dataclasses.fields(cls)}[field_name]
    if PARAMETER_METADATA not in field.metadata:
        raise TypeError(f"{cls.__name__}.{field_name} has no parameter description (described())")
    description, value_range = field.metadata[PARAMETER_METADATA]
    if default is dataclasses.MISSING:
        default = field.default
    if default is dataclasses.MISSING:
        raise TypeError(f"{cls.__name__}.{field_name} has no default; give the parameter's")
    if isinstance(default, tuple):
        default = list(default)
    return ParameterSpec(name or field_name, default, description, value_range, dynamic_typing)


def spec_table(specs: Iterable[ParameterSpec]) -> dict[str, ParameterSpec]:
    """Specs by name; a name given twice is a ValueError."""
    table: dict[str, ParameterSpec] = {}
    for spec in specs:
        if spec.name in table:
            raise ValueError(f"parameter {spec.name} is declared twice")
        table[spec.name] = spec
    return table
