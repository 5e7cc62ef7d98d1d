# SPDX-License-Identifier: Apache-2.0
"""docs/nodes.md, generated from the nodes themselves: topics, services and parameters of each.

``python -m suture_bench.nodes_doc [--check] [PATH]`` builds every node of the project in a
private rclpy context (no other process sees it: its topics go nowhere), reads what it
subscribes, publishes and serves from rclpy (``node.subscriptions``, ``node.publishers``,
``node.services`` and their QoS profiles) and its parameters from their descriptors
(``node.describe_parameters``: what ``ros2 param describe`` prints), and writes the page
(default ``docs/nodes.md``). ``--check`` writes nothing and exits 1 when the page differs from
what the code gives. The nodes are built with their defaults, except what a node needs to
start at all (:data:`NODES`: the player's bag, the recorder's output directory).
"""

from __future__ import annotations

import argparse
import importlib
import re
import sys
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import rclpy
from rcl_interfaces.msg import ParameterDescriptor, ParameterType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

REPOSITORY = Path(__file__).resolve().parents[3]
DEFAULT_OUTPUT = REPOSITORY / "docs" / "nodes.md"
SAMPLE_BAG = REPOSITORY / "bags" / "sample"

INFRASTRUCTURE_TOPICS = frozenset({"/rosout", "/parameter_events"})
"""Topics every rclpy node has; left out of the page."""

RCLPY_SERVICE_PACKAGES = frozenset({"rcl_interfaces", "type_description_interfaces"})
"""Packages of the services rclpy gives every node (parameters, type descriptions)."""

RCLPY_PARAMETERS = frozenset({"use_sim_time", "start_type_description_service"})
"""Parameters rclpy declares on every node."""


@dataclass(frozen=True)
class NodeEntry:
    """One executable: where its node class is, and what it needs to be built for the page."""

    package: str
    executable: str
    module: str
    class_name: str
    overrides: Callable[[Path], dict[str, Any]] = lambda _tmp: {}
    note: str = ""
    parameters_attribute: str = "PARAMETERS"


NODES: tuple[NodeEntry, ...] = (
    NodeEntry(
        "suture_segmentation",
        "segmentation_node",
        "suture_segmentation.segmentation_node",
        "SegmentationNode",
    ),
    NodeEntry("suture_ordering", "ordering_node", "suture_ordering.ordering_node", "OrderingNode"),
    NodeEntry(
        "suture_reconstruction",
        "reconstruction_node",
        "suture_reconstruction.reconstruction_node",
        "ReconstructionNode",
    ),
    NodeEntry(
        "grasp_executor",
        "executor_node",
        "grasp_executor.executor_node",
        "ExecutorNode",
        note="With backend `dvrk` it also talks to the arm's CRTK topics under `dvrk.namespace`.",
    ),
    NodeEntry("grasp_executor", "psm_sim_node", "grasp_executor.psm_sim_node", "PsmSimNode"),
    NodeEntry(
        "suture_replay",
        "player_node",
        "suture_replay.player_node",
        "PlayerNode",
        overrides=lambda _tmp: {"bag": str(SAMPLE_BAG)},
        note="Built here with `bag` = the bundled `bags/sample`: it publishes the `topics` found in the bag.",
    ),
    NodeEntry(
        "suture_replay",
        "recorder_node",
        "suture_replay.recorder_node",
        "RecorderNode",
        overrides=lambda tmp: {"output": str(tmp / "recording")},
        note="Built here with `output` = a temporary directory; it subscribes the `topics` parameter.",
    ),
)
"""Every node executable of the project, in pipeline order."""


@dataclass(frozen=True, order=True)
class Endpoint:
    name: str
    type: str
    qos: str


@dataclass(frozen=True)
class ParameterRow:
    name: str
    type: str
    default: Any
    range: str
    description: str


@dataclass(frozen=True)
class NodeDescription:
    entry: NodeEntry
    node_name: str
    summary: str
    subscriptions: list[Endpoint]
    publications: list[Endpoint]
    services: list[Endpoint]
    parameters: list[ParameterRow]


def plain_summary(docstring: str, executable: str) -> str:
    """The first line of a node module's docstring, without the executable's name and Sphinx roles."""
    line = docstring.strip().split("\n", 1)[0].removeprefix(f"{executable}: ")
    line = re.sub(r":\w+:`~?([^`]+)`", r"`\1`", line)
    return line.replace("``", "`")


def interface_name(cls: type) -> str:
    """'sensor_msgs/msg/Image' of an rclpy message or service class."""
    package, kind = cls.__module__.split(".")[:2]
    return f"{package}/{kind}/{cls.__name__}"


def qos_text(qos: QoSProfile) -> str:
    """E.g. 'reliable, keep last 10, volatile'."""
    reliability = {ReliabilityPolicy.RELIABLE: "reliable", ReliabilityPolicy.BEST_EFFORT: "best effort"}
    durability = {DurabilityPolicy.VOLATILE: "volatile", DurabilityPolicy.TRANSIENT_LOCAL: "transient local"}
    history = f"keep last {qos.depth}" if qos.history == HistoryPolicy.KEEP_LAST else "keep all"
    return ", ".join(
        (
            reliability.get(qos.reliability, qos.reliability.name.lower()),
            history,
            durability.get(qos.durability, qos.durability.name.lower()),
        )
    )


PARAMETER_TYPES = {
    ParameterType.PARAMETER_BOOL: "bool",
    ParameterType.PARAMETER_INTEGER: "integer",
    ParameterType.PARAMETER_DOUBLE: "double",
    ParameterType.PARAMETER_STRING: "string",
    ParameterType.PARAMETER_BOOL_ARRAY: "bool[]",
    ParameterType.PARAMETER_INTEGER_ARRAY: "integer[]",
    ParameterType.PARAMETER_DOUBLE_ARRAY: "double[]",
    ParameterType.PARAMETER_STRING_ARRAY: "string[]",
}


def _number(value: float) -> str:
    if value >= 2**63 - 1:
        return "inf"
    if value <= -(2**63):
        return "-inf"
    if float(value).is_integer() and abs(value) < 1e15:
        return str(int(value))
    return f"{value:.6g}"


def range_text(descriptor: ParameterDescriptor) -> str:
    """The descriptor's range as ``[low, high]``; "" when it has none."""
    ranges = [*descriptor.floating_point_range, *descriptor.integer_range]
    if not ranges:
        return ""
    return f"[{_number(ranges[0].from_value)}, {_number(ranges[0].to_value)}]"


def declared_parameters(node: Node) -> list[str]:
    """Names of the parameters ``node`` declared, in declaration order (rclpy's own left out)."""
    return [name for name in node.list_parameters([], 0).names if name not in RCLPY_PARAMETERS]


@contextmanager
def built_node(entry: NodeEntry, tmp: Path, domain_id: int | None = None) -> Iterator[Node]:
    """``entry``'s node with its defaults (and its :attr:`NodeEntry.overrides`), in its own context.

    The node is never spun: it sends nothing but DDS discovery (on ``domain_id``, default
    ``ROS_DOMAIN_ID``).
    """
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    node = None
    try:
        cls = getattr(importlib.import_module(entry.module), entry.class_name)
        overrides = [Parameter(name, value=value) for name, value in entry.overrides(tmp).items()]
        node = cls(context=context, parameter_overrides=overrides)
        yield node
    finally:
        if node is not None:
            if hasattr(node, "close"):
                node.close()
            node.destroy_node()
        rclpy.shutdown(context=context)


def describe(entry: NodeEntry, tmp: Path, domain_id: int | None = None) -> NodeDescription:
    """What ``entry``'s node subscribes, publishes, serves and declares, read from the built node."""
    module = importlib.import_module(entry.module)
    summary = plain_summary(module.__doc__ or "", entry.executable)
    with built_node(entry, tmp, domain_id) as node:
        subscriptions = sorted(
            Endpoint(s.topic_name, interface_name(s.msg_type), qos_text(s.qos_profile))
            for s in node.subscriptions
            if s.topic_name not in INFRASTRUCTURE_TOPICS
        )
        publications = sorted(
            Endpoint(p.topic_name, interface_name(p.msg_type), qos_text(p.qos_profile))
            for p in node.publishers
            if p.topic_name not in INFRASTRUCTURE_TOPICS
        )
        services = sorted(
            Endpoint(s.srv_name, interface_name(s.srv_type), "")
            for s in node.services
            if s.srv_type.__module__.split(".")[0] not in RCLPY_SERVICE_PACKAGES
        )
        names = declared_parameters(node)
        specs = getattr(module, entry.parameters_attribute)
        parameters = []
        for name, descriptor in zip(names, node.describe_parameters(names), strict=True):
            spec = specs[name]
            if not descriptor.dynamic_typing:
                kind = PARAMETER_TYPES[descriptor.type]
            else:  # any type is accepted; the node checks it
                kind = "number" if spec.numeric else spec.kind.replace("_array", "[]")
            parameters.append(
                ParameterRow(name, kind, spec.default, range_text(descriptor), descriptor.description)
            )
        return NodeDescription(
            entry, node.get_name(), summary, subscriptions, publications, services, parameters
        )


def _default_text(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_default_text(v) for v in value) + "]"
    return repr(value)


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def render(descriptions: list[NodeDescription]) -> str:
    """The Markdown page."""
    lines = [
        "# ROS nodes",
        "",
        "<!-- Generated by `python -m suture_bench.nodes_doc` from the nodes' code; do not edit. -->",
        "",
        "Every node of the pipeline: what it subscribes, publishes and serves, and its parameters,",
        "read from the node built with its defaults (`ros2 param describe NODE PARAM` prints the same",
        "descriptions and ranges). A value of the wrong type or outside its range stops the node at",
        "start-up with one line on standard error; the topic contract is `docs/interfaces.md`.",
        "",
    ]
    for d in descriptions:
        e = d.entry
        lines += [
            f"## {e.executable}",
            "",
            f"`ros2 run {e.package} {e.executable}` (node name `{d.node_name}`): {d.summary}",
            "",
        ]
        if e.note:
            lines += [e.note, ""]
        for title, endpoints in (("Subscribes", d.subscriptions), ("Publishes", d.publications)):
            if endpoints:
                lines += [f"### {title}", "", "| topic | type | QoS |", "|---|---|---|"]
                lines += [f"| `{p.name}` | `{p.type}` | {p.qos} |" for p in endpoints]
                lines.append("")
        if d.services:
            lines += ["### Services", "", "| service | type |", "|---|---|"]
            lines += [f"| `{s.name}` | `{s.type}` |" for s in d.services]
            lines.append("")
        lines += [
            f"### Parameters ({len(d.parameters)})",
            "",
            "| name | type | default | range | description |",
            "|---|---|---|---|---|",
        ]
        for p in d.parameters:
            default = _cell(_default_text(p.default))
            lines.append(f"| `{p.name}` | {p.type} | `{default}` | {p.range} | {_cell(p.description)} |")
        lines.append("")
    return "\n".join(lines)


def describe_all(domain_id: int | None = None) -> list[NodeDescription]:
    """Every node of :data:`NODES`, described."""
    with tempfile.TemporaryDirectory(prefix="nodes_doc_") as tmp:
        return [describe(entry, Path(tmp), domain_id) for entry in NODES]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m suture_bench.nodes_doc", description=__doc__.split("\n")[0]
    )
    parser.add_argument(
        "path", nargs="?", type=Path, default=DEFAULT_OUTPUT, help="page to write (docs/nodes.md)"
    )
    parser.add_argument("--check", action="store_true", help="exit 1 if the page is not what the code gives")
    args = parser.parse_args(argv)
    page = render(describe_all())
    if args.check:
        current = args.path.read_text(encoding="utf-8") if args.path.exists() else ""
        if current != page:
            print(
                f"nodes_doc: {args.path} is out of date; run python -m suture_bench.nodes_doc",
                file=sys.stderr,
            )
            return 1
        return 0
    args.path.write_text(page, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
