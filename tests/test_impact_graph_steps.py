"""The impact graph's bring-up steps, each alone: the parameters in their named pieces
(check_approach, sensing_scenario, add_start_barrier), plan_impact_graph (checks, nothing
started), then an ImpactSession's spawn, bring_up, record, run, summarize, stop and collect on a
short run that equals the ROS-free study, and stop after a failed start."""

from __future__ import annotations

import os
import time

import pytest

from ffmpc_core.errors import ConfigError
from ffmpc_core.impact.scenario import load_impact_config
from ffmpc_ros import topics
from ffmpc_ros.impact_graph import (
    ImpactOptions,
    ImpactSession,
    add_start_barrier,
    check_approach,
    compare_with_runner,
    graph_nodes,
    impact_node_parameters,
    plan_impact_graph,
    sensing_scenario,
)
from studies.impact_study import run_impact

#: 20 plant cycles of the paper's scheme, 5 cm above the dice (no contact yet).
SHORT = ("strategy=prior", "approach_height=0.05", "duration=0.02")


def test_the_parameter_pieces() -> None:
    with pytest.raises(ConfigError, match="approach must be one of"):
        check_approach("gentle", "admittance")
    with pytest.raises(ConfigError, match="regulation one of"):
        check_approach("maximal", "pid")
    check_approach("baseline", "ff_mpc")
    # the sensors measure the true state: no delay, no noise, every force component
    sensing = sensing_scenario(0.002)
    assert sensing.plant.time_step == 0.002 and sensing.robot == "panda"
    assert sensing.joint_sensor.delay_cycles == 0 and sensing.ft_sensor.force_noise_std == 0.0
    assert sensing.joint_sensor.position_noise_std == 0.0 and sensing.mpc.contact.dimension == 3
    # the start barrier: two /clock readers per node (and the recorder's two), every node's
    # token for the plant
    params: dict[str, dict] = {name: {} for name in graph_nodes("baseline")}
    add_start_barrier(params, record=False)
    assert params["dice_plant"]["start_nodes"] == 6 == len(params)
    assert {v["start_clock_subscribers"] for v in params.values()} == {12}
    params = {name: {} for name in graph_nodes("maximal")}
    add_start_barrier(params, record=True)
    assert params["dice_plant"]["start_nodes"] == 7
    assert {v["start_clock_subscribers"] for v in params.values()} == {16}
    # and the whole: the recorder is one more joint-state reader the plant waits for
    _, plain = impact_node_parameters("maximal", "admittance", overrides=SHORT)
    _, recorded = impact_node_parameters("maximal", "admittance", overrides=SHORT, record=True)
    assert (
        recorded["dice_plant"]["start_subscribers"] == plain["dice_plant"]["start_subscribers"] + 1
    )
    assert recorded["joint_sensor"]["start_clock_subscribers"] == 16


def test_plan_checks_before_anything_starts(tmp_path) -> None:
    with pytest.raises(ConfigError):
        plan_impact_graph("maximal", "admittance", ImpactOptions(overrides=["planner.horizon=1"]))
    with pytest.raises(ConfigError):
        plan_impact_graph("maximal", "admittance", ImpactOptions(namespace="a b"))
    existing = tmp_path / "there.mcap"
    existing.write_bytes(b"")
    from ffmpc_ros.bag.errors import BagExistsError

    with pytest.raises(BagExistsError):
        plan_impact_graph("maximal", "admittance", ImpactOptions(record=str(existing)))
    options = ImpactOptions(overrides=SHORT, domain_id=7, namespace="arm1")
    plan = plan_impact_graph("baseline", "ff_mpc", options)
    assert plan.domain == 7 and plan.namespace == "/arm1" and plan.steps == 20
    assert "impact_planner" not in plan.nodes and set(plan.params) == set(plan.nodes)
    assert not plan.learning  # the baseline plans nothing
    touch = ImpactOptions(overrides=["strategy=touch_first"])
    assert plan_impact_graph("maximal", "admittance", touch).learning
    # the graph's QoS overrides name the namespace's topics
    assert any(k.startswith("qos_overrides./arm1/") for k in plan.params["dice_plant"])


def test_session_steps_run_a_short_graph_equal_to_the_ros_free_run() -> None:
    plan = plan_impact_graph("maximal", "admittance", ImpactOptions(overrides=SHORT, timeout=300))
    session = ImpactSession(plan, time.perf_counter())
    try:
        session.spawn()
        assert list(session.children) == list(plan.nodes)  # one process per node
        session.bring_up()
        session.record()  # no bag asked: nothing more started
        assert "recorder" not in session.children
        session.run()
        assert session.probe.complete and session.probe.cycle == plan.steps
        session.summarize()
        assert session.metrics["learner_samples"] == 0 and session.safe
    finally:
        outputs = session.stop()
    assert not session.context.ok() and not os.path.exists(session.tmp.name)
    assert all(child.poll() is not None for child in session.children.values())
    # every node process wrote its rejections (none)
    assert outputs.bag is None and outputs.rejected == {n: {} for n in plan.nodes}
    result = session.collect(outputs)
    assert result.sim_time == pytest.approx(0.02) and result.wall_time >= 0.0
    values = {k: float(v) if k != "strategy" else v for k, v in (i.split("=") for i in SHORT)}
    runner = run_impact("maximal", "admittance", load_impact_config("impact", values))
    differ = compare_with_runner(result, runner)
    # before any contact the learner has published no estimate: the graph reports NaN, the
    # ROS-free run 0.0 (with contact both learn the same: tests/test_impact_graph.py)
    assert {k: v for k, v in differ.items() if not k.startswith("learned_")} == {}


def test_stop_after_a_failed_start_releases_everything() -> None:
    options = ImpactOptions(overrides=SHORT, namespace=topics.ROOT_NAMESPACE)
    session = ImpactSession(plan_impact_graph("baseline", "admittance", options), 0.0)
    directory = session.tmp.name
    outputs = session.stop()  # nothing spawned (the foreign check refused, say)
    assert outputs.rejected == {} and outputs.bag is None
    assert not session.context.ok() and not os.path.exists(directory)
