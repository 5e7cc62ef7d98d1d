# SPDX-License-Identifier: Apache-2.0
"""The SROS2 policy (ros2_ws/security/policy.xml) against the topics and services the nodes use.

The policy is read as sros2 reads it (policy format 0.2.0: enclaves, profiles, topics with
publish/subscribe, services with reply/request). The names each node uses are read from its
source file: the second argument of every ``create_publisher``, ``create_subscription`` and
``create_service`` call, resolved through the module's constants and
``suture_common.topics``, so a topic added to a node without its permission fails here.
The recorder's and player's topics are parameters; their defaults come from suture_common.topics.
Last, ``launch.sh --dry-run`` with ``ROS_SECURITY_ENABLE=true`` must give each node its enclave.
"""

from __future__ import annotations

import ast
import os
import re
import subprocess
import xml.etree.ElementTree as ElementTree
from collections import defaultdict
from pathlib import Path

import pytest

from suture_common import topics

REPO = Path(__file__).resolve().parents[1].parent
POLICY = REPO / "ros2_ws" / "security" / "policy.xml"
SRC = REPO / "src"
DVRK_NAMESPACE = "/PSM1"  # the default of executor_node's dvrk.namespace and psm_sim_node's namespace

#: Topics and services every rclpy node uses by itself (logging, parameters, sim time).
ROS_PUBLISH = {"/rosout", "/parameter_events"}
ROS_SUBSCRIBE = {"/parameter_events", "/clock"}
PARAMETER_SERVICES = (
    "describe_parameters",
    "get_parameter_types",
    "get_parameters",
    "list_parameters",
    "set_parameters",
    "set_parameters_atomically",
    "get_type_description",
)

#: enclave -> (node name, source files whose calls belong to it)
NODE_SOURCES = {
    "/suture/segmentation_node": [
        ("segmentation_node", SRC / "suture_segmentation/suture_segmentation/segmentation_node.py")
    ],
    "/suture/ordering_node": [("ordering_node", SRC / "suture_ordering/suture_ordering/ordering_node.py")],
    "/suture/reconstruction_node": [
        ("reconstruction_node", SRC / "suture_reconstruction/suture_reconstruction/reconstruction_node.py")
    ],
    "/suture/executor_node": [
        ("grasp_executor", SRC / "grasp_executor/grasp_executor/executor_node.py"),
        ("grasp_executor_crtk_feedback", SRC / "grasp_executor/grasp_executor/crtk_ros.py"),
    ],
    "/suture/psm_sim": [("psm_sim", SRC / "grasp_executor/grasp_executor/psm_sim_node.py")],
}

CALL_KINDS = {"create_publisher": "publish", "create_subscription": "subscribe", "create_service": "reply"}


def load_policy() -> dict[str, dict[str, set[str]]]:
    """enclave path -> {"publish"|"subscribe"|"reply"|"request"|"nodes": names}."""
    root = ElementTree.parse(POLICY).getroot()
    assert root.tag == "policy" and root.get("version") == "0.2.0"
    enclaves: dict[str, dict[str, set[str]]] = {}
    for enclave in root.findall("./enclaves/enclave"):
        path = enclave.get("path")
        assert path not in enclaves, f"enclave {path} listed twice"
        rules: dict[str, set[str]] = defaultdict(set)
        for profile in enclave.findall("./profiles/profile"):
            assert profile.get("ns") == "/"
            rules["nodes"].add(profile.get("node"))
            for group in profile:
                assert group.tag in ("topics", "services"), f"{path}: unexpected <{group.tag}>"
                for kind, value in group.attrib.items():
                    assert value == "ALLOW", f"{path}: only ALLOW rules are used ({kind}={value})"
                    for item in group:
                        name = item.text.strip()
                        assert name.startswith("/"), f"{path}: {name} is not a fully qualified name"
                        rules[kind].add(name)
        enclaves[path] = rules
    return enclaves


def _constants(tree: ast.Module) -> dict[str, str]:
    """Module-level names bound to a topic name.

    ``X = "/a"``, ``X = topics.Y`` and ``from suture_common.topics import Y``.
    """
    values: dict[str, str] = {}
    for statement in tree.body:
        if isinstance(statement, ast.ImportFrom) and statement.module == "suture_common.topics":
            for alias in statement.names:
                values[alias.asname or alias.name] = getattr(topics, alias.name)
        elif isinstance(statement, ast.Assign) and len(statement.targets) == 1:
            target, value = statement.targets[0], statement.value
            if not isinstance(target, ast.Name):
                continue
            if (
                isinstance(value, ast.Constant)
                and isinstance(value.value, str)
                and value.value.startswith("/")
            ):
                values[target.id] = value.value
            elif (
                isinstance(value, ast.Attribute)
                and isinstance(value.value, ast.Name)
                and value.value.id == "topics"
            ):
                values[target.id] = getattr(topics, value.attr)
    return values


def _name(argument: ast.expr, constants: dict[str, str], source: Path) -> str:
    if isinstance(argument, ast.Name):
        return constants[argument.id]
    if isinstance(argument, ast.Constant):
        return argument.value
    if isinstance(argument, ast.JoinedStr):  # f"{namespace}/move_cp": the dVRK arm's namespace
        head, *tail = argument.values
        assert isinstance(head, ast.FormattedValue) and all(isinstance(t, ast.Constant) for t in tail), source
        return DVRK_NAMESPACE + "".join(t.value for t in tail)
    raise AssertionError(f"{source}: cannot read the topic of {ast.unparse(argument)}")


def used_names(source: Path) -> dict[str, set[str]]:
    """ "publish"/"subscribe"/"reply" -> the names that ``source``'s create_* calls use."""
    tree = ast.parse(source.read_text())
    constants = _constants(tree)
    used: dict[str, set[str]] = defaultdict(set)
    for call in ast.walk(tree):
        if (
            isinstance(call, ast.Call)
            and isinstance(call.func, ast.Attribute)
            and call.func.attr in CALL_KINDS
        ):
            used[CALL_KINDS[call.func.attr]].add(_name(call.args[1], constants, source))
    return used


def test_only_reconstruction_node_may_publish_the_grasp_pose() -> None:
    enclaves = load_policy()
    publishers = [path for path, rules in enclaves.items() if topics.GRASP_POSE in rules["publish"]]
    assert publishers == ["/suture/reconstruction_node"]


def test_only_the_executor_serves_and_only_the_operator_calls_the_executor_services() -> None:
    enclaves = load_policy()
    services = used_names(SRC / "grasp_executor/grasp_executor/executor_node.py")["reply"]
    assert "/grasp_executor/execute" in services and len(services) == 3
    for service in services:
        servers = [path for path, rules in enclaves.items() if service in rules["reply"]]
        clients = [path for path, rules in enclaves.items() if service in rules["request"]]
        assert servers == ["/suture/executor_node"], service
        assert clients == ["/suture/operator"], service


def test_only_the_operator_may_set_the_executors_parameters() -> None:
    """``armed`` is a parameter: whoever may call set_parameters may arm the robot."""
    enclaves = load_policy()
    for service in ("/grasp_executor/set_parameters", "/grasp_executor/set_parameters_atomically"):
        clients = [path for path, rules in enclaves.items() if service in rules["request"]]
        assert clients == ["/suture/operator"], service


def test_only_the_executor_commands_the_robot() -> None:
    enclaves = load_policy()
    for command in (f"{DVRK_NAMESPACE}/move_cp", f"{DVRK_NAMESPACE}/jaw/move_jp"):
        publishers = [path for path, rules in enclaves.items() if command in rules["publish"]]
        assert publishers == ["/suture/executor_node"], command


@pytest.mark.parametrize("enclave", sorted(NODE_SOURCES))
def test_each_node_is_allowed_exactly_what_its_code_uses(enclave: str) -> None:
    rules = load_policy()[enclave]
    expected: dict[str, set[str]] = {
        "publish": set(ROS_PUBLISH),
        "subscribe": set(ROS_SUBSCRIBE),
        "reply": set(),
    }
    for node, source in NODE_SOURCES[enclave]:
        for kind, names in used_names(source).items():
            expected[kind] |= names
        if node != "grasp_executor_crtk_feedback":  # created with start_parameter_services=False
            expected["reply"] |= {f"/{node}/{service}" for service in PARAMETER_SERVICES}
    assert rules["nodes"] == {node for node, _ in NODE_SOURCES[enclave]}
    for kind in ("publish", "subscribe", "reply"):
        assert rules[kind] == expected[kind], f"{enclave} {kind}"
    assert not rules["request"], f"{enclave} calls no service"


def test_replay_and_recording_enclaves_match_their_default_topics() -> None:
    enclaves = load_policy()
    player, recorder = enclaves["/suture/player"], enclaves["/suture/recorder"]
    assert player["publish"] == ROS_PUBLISH | set(topics.INPUT_TOPICS)
    assert player["subscribe"] == ROS_SUBSCRIBE | {topics.GRASP_POSE}
    assert recorder["publish"] == ROS_PUBLISH
    assert recorder["subscribe"] == ROS_SUBSCRIBE | set(topics.PIPELINE_OUTPUT_TOPICS)


def test_every_topic_a_node_subscribes_has_an_allowed_publisher() -> None:
    enclaves = load_policy()
    published = set().union(*(rules["publish"] for rules in enclaves.values()))
    for path, rules in enclaves.items():
        missing = rules["subscribe"] - published - {"/clock"}  # /clock: a simulator's, none here
        assert not missing, f"{path} subscribes {missing}, which no enclave may publish"


def test_launch_puts_each_node_in_its_enclave_when_security_is_enabled(tmp_path: Path) -> None:
    """``ROS_SECURITY_ENABLE=true bash ros2_ws/launch.sh``: every node gets an enclave of the policy."""
    env = {**os.environ, "ROS_SECURITY_ENABLE": "true"}
    command = ["bash", str(REPO / "ros2_ws/launch.sh"), "--dry-run", "--bag", str(REPO / "bags/sample")]
    command += ["--record", str(tmp_path / "outputs")]
    run = subprocess.run(command, env=env, capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    started = dict(re.findall(r"^launch: would start (\w+):.* --enclave (\S+)", run.stdout, re.MULTILINE))
    assert started == {
        "recorder": "/suture/recorder",
        "segmentation_node": "/suture/segmentation_node",
        "ordering_node": "/suture/ordering_node",
        "reconstruction_node": "/suture/reconstruction_node",
        "executor_node": "/suture/executor_node",
        "player": "/suture/player",
    }
    assert set(started.values()) <= set(load_policy())
    plain = subprocess.run(
        command[:3], env={**os.environ, "ROS_SECURITY_ENABLE": ""}, capture_output=True, text=True
    )
    assert "--enclave" not in plain.stdout
