"""Every node's parameters come from the declarations (ffmpc_ros.params.NODE_SPECS over the one
scenario schema, ffmpc_core.scenario.SCENARIO_SCHEMA, and the impact study's IMPACT_SCHEMA): a
parameter a node declares by hand, or a scenario parameter no node declares, fails here."""

from __future__ import annotations

import pytest
from ros_helpers import overrides

from ffmpc_core.impact.scenario import IMPACT_SCHEMA
from ffmpc_core.scenario import BASE_KEY, SCENARIO_SCHEMA, SCHEMA, Scenario, load_scenario
from ffmpc_ros.graph_nodes import LFC_NODE, METRICS_NODE, NODES, load_node_class
from ffmpc_ros.params import (
    NODE_SPECS,
    node_impact_names,
    node_scenario_names,
    scenario_flat,
)

#: The class of every node of NODE_SPECS (the polishing graph's, the LFC law, the impact graph's).
CLASSES = {
    **NODES,
    "metrics": METRICS_NODE,
    "lfc": LFC_NODE,
    "dice_plant": "ffmpc_ros.dice_plant_node:DicePlantNode",
    "impact_planner": "ffmpc_ros.impact_planner_node:ImpactPlannerNode",
    "contact_learner": "ffmpc_ros.contact_learner_node:ContactLearnerNode",
    "impact_controller": "ffmpc_ros.impact_controller_node:ImpactControllerNode",
}
#: Parameters rclpy itself declares (use_sim_time, start_type_description_service; the QoS
#: overrides of the node's endpoints are left out below) and the scenario file's ``base``
#: every node reads.
NOT_FROM_A_SPEC = ("use_sim_time", "start_type_description_service", BASE_KEY)


def declared_from_specs(node: str) -> set[str]:
    """The ROS names node ``node`` declares, built from its spec and the schemas alone."""
    spec = NODE_SPECS[node]
    scenario = set(node_scenario_names(spec, scenario_flat(Scenario(name="names"))))
    graph = {g.name for g in spec.graph_parameters}
    return scenario | set(node_impact_names(spec)) | graph | set(NOT_FROM_A_SPEC)


def test_every_node_class_is_listed():
    assert set(CLASSES) == set(NODE_SPECS)


@pytest.mark.parametrize("node", sorted(NODE_SPECS))
def test_a_node_declares_exactly_what_its_spec_and_the_schemas_say(ros, node):
    """Built and brought up (configure, activate), the node has declared its spec's names and
    nothing else: a ``declare_parameter`` by hand anywhere in the node fails this test."""
    cls = load_node_class(CLASSES[node])
    # the impact experiment's robot is the Panda (its data sheet has acceleration limits)
    robot = "panda" if NODE_SPECS[node].impact else "iiwa"
    values = overrides(node, load_scenario("polishing", {"robot": robot}))
    built = ros.add(cls(context=ros.context, parameter_overrides=values))
    ros.spin_for(0.05)
    names = {n for n in built._parameters if not n.startswith("qos_overrides.")}
    expected = declared_from_specs(node)
    assert names - expected == set(), f"{node} declares parameters by hand"
    assert expected - names == set(), f"{node} does not declare its spec's parameters"


def test_every_scenario_parameter_has_a_node_that_declares_it():
    """Each name of the scenario schema is declared by at least one node of the polishing
    graph, and every name a node takes from a scenario is one of the schema's."""
    flat = scenario_flat(Scenario(name="names"))
    assert set(flat) == set(SCHEMA)
    taken: set[str] = set()
    for spec in NODE_SPECS.values():
        taken |= set(node_scenario_names(spec, flat).values())
    assert set(SCHEMA) - taken == set(), "scenario parameters no node declares"
    assert taken <= set(SCHEMA)
    impact_taken = {n for spec in NODE_SPECS.values() for n in node_impact_names(spec)}
    assert set(IMPACT_SCHEMA.params) - impact_taken == set(), "impact names no node declares"


def test_the_scenario_is_a_schema_tree_flattened_and_built_back():
    """SCENARIO_SCHEMA.flatten and build are inverse (weights entries included)."""
    scenario = load_scenario("polishing")
    flat = SCENARIO_SCHEMA.flatten(scenario)
    assert any(k.startswith("mpc.weights.force_feedback.") for k in flat)
    assert SCENARIO_SCHEMA.build(flat, Scenario(name=scenario.name)) == scenario
    assert flat["mpc.contact.stiffness"] == scenario.mpc.contact.stiffness
