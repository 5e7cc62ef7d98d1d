# SPDX-License-Identifier: Apache-2.0
"""docs/nodes.md is what the nodes' code gives, and every node parameter is described and bounded."""

from __future__ import annotations

import pytest

from suture_bench.nodes_doc import DEFAULT_OUTPUT, NODES, NodeDescription, describe_all, render


@pytest.fixture(scope="module")
def descriptions(ros_domain_id: int) -> list[NodeDescription]:
    return describe_all(ros_domain_id)


def test_docs_nodes_md_is_generated_from_the_code(descriptions):
    assert DEFAULT_OUTPUT.read_text(encoding="utf-8") == render(descriptions), (
        "docs/nodes.md is out of date: run python -m suture_bench.nodes_doc"
    )


def test_every_parameter_has_a_description_and_every_number_a_range(descriptions):
    assert [d.entry.executable for d in descriptions] == [entry.executable for entry in NODES]
    counts = {d.entry.executable: len(d.parameters) for d in descriptions}
    assert counts == {
        "segmentation_node": 12,
        "ordering_node": 45,
        "reconstruction_node": 26,
        "executor_node": 32,
        "psm_sim_node": 9,
        "player_node": 10,
        "recorder_node": 2,
    }
    for d in descriptions:
        for parameter in d.parameters:
            where = f"{d.entry.executable} {parameter.name}"
            assert parameter.description.strip(), f"{where} has no description"
            numeric = parameter.type in ("integer", "double", "number")
            assert bool(parameter.range) == numeric, (
                f"{where}: {parameter.type} with range {parameter.range!r}"
            )


def test_the_page_lists_topics_services_and_qos(descriptions):
    page = render(descriptions)
    assert "| `/suture/left/mask` | `sensor_msgs/msg/Image` | best effort, keep last 5, volatile |" in page
    assert (
        "| `/suture/grasp_pose` | `geometry_msgs/msg/PoseStamped` | reliable, keep last 10, volatile |"
        in page
    )
    assert "| `/grasp_executor/execute` | `std_srvs/srv/Trigger` |" in page
    assert "| `low_mask_wait` | double | `0.1` | [0, 60] |" in page
