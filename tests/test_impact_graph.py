"""The impact experiment as a node graph (``ffmpc run impact``, ffmpc_ros.impact_graph) against
the ROS-free study (``studies.impact_study.run_impact``): same settings, same metrics bit for
bit; the bag of the run; the impact controller node's handling of a bad reference.

Short runs: the tool starts 5 cm (maximal approach) or 2 cm (baseline) above the dice instead
of 46 cm, so the contact comes at 0.178 s and 0.630 s, and the hand-over to the
force-feedback MPC at 0.282 s."""

from __future__ import annotations

import json

import numpy as np
import pytest
from rclpy.serialization import deserialize_message
from ros_helpers import joint_state, wrench
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from ffmpc_core.impact.scenario import IMPACT_SCHEMA, load_impact_config, start_pose
from ffmpc_core.robots import load_robot
from ffmpc_ros import layouts, topics
from ffmpc_ros.bag.reader import BagReader
from ffmpc_ros.bag.ros_types import message_class
from ffmpc_ros.impact_controller_node import ImpactControllerNode
from ffmpc_ros.impact_graph import (
    COMPARED,
    compare_with_runner,
    impact_node_parameters,
    run_impact_graph,
)
from ffmpc_ros.params import parameter_overrides
from studies.impact_study import run_impact

MAXIMAL = ["strategy=prior", "approach_height=0.05", "duration=0.35"]
#: The study's default strategy: the strike's contact at 0.199 s, the target decided (admitted)
#: at 0.248 s, the hand-over at 0.269 s.
STRIKE_FIRST = ["approach_height=0.05", "duration=0.5"]
#: Touch-first: touch at 0.199 s, strike decided at 0.349 s, the strike's contact at 1.034 s,
#: the hand-over at 1.129 s.
TOUCH_FIRST = ["strategy=touch_first", "approach_height=0.05", "duration=1.2"]
BASELINE = ["strategy=prior", "approach_height=0.02", "duration=0.7"]


def _runner(approach: str, regulation: str, items: list[str]):
    values = {k: float(v) if k != "strategy" else v for k, v in (i.split("=") for i in items)}
    return run_impact(approach, regulation, load_impact_config("impact", values))


@pytest.fixture(scope="module")
def maximal_ff_mpc(tmp_path_factory):
    """maximal + ff_mpc on the graph, recorded, and the same run ROS-free."""
    bag = tmp_path_factory.mktemp("impact_graph") / "run"
    graph = run_impact_graph("maximal", "ff_mpc", overrides=MAXIMAL, record=bag, timeout=180)
    return graph, _runner("maximal", "ff_mpc", MAXIMAL), bag


def test_maximal_graph_equals_the_ros_free_run_through_impact_and_handover(maximal_ff_mpc):
    graph, runner, _ = maximal_ff_mpc
    # the run covers what the metrics are about: the impact, the learner, the hand-over
    assert runner.contact_time == pytest.approx(0.178)
    assert runner.handover_time == pytest.approx(0.282)
    assert runner.learner_samples > 100 and runner.violations.total == 0
    assert compare_with_runner(graph, runner) == {}
    assert graph.metrics["peak_force"] == runner.peak_force  # (bit for bit, e.g.)
    assert graph.safe and graph.metrics["safe_hold_cycles"] == 0
    assert all(not counts for counts in graph.rejected.values()), graph.rejected


@pytest.fixture(scope="module")
def touch_first_ff_mpc(tmp_path_factory):
    """maximal + ff_mpc with the touch-first strategy on the graph, recorded, and ROS-free."""
    bag = tmp_path_factory.mktemp("impact_graph_touch") / "run"
    graph = run_impact_graph("maximal", "ff_mpc", overrides=TOUCH_FIRST, record=bag, timeout=300)
    return graph, _runner("maximal", "ff_mpc", TOUCH_FIRST), bag


def test_touch_first_graph_equals_the_ros_free_run(touch_first_ff_mpc):
    """The learner in its node (fed by the planner's learning gate), the touch-first phases in
    the planner node: touch, decision, retract, strike, hand-over all on the same cycles and
    every metric equal bit for bit."""
    graph, runner, _ = touch_first_ff_mpc
    assert runner.strategy == "touch_first"
    assert runner.touch_time == pytest.approx(0.199)
    assert runner.decision_time == pytest.approx(0.349)
    assert runner.contact_time == pytest.approx(1.034)
    assert runner.handover_time == pytest.approx(1.129)
    assert runner.learner_samples > 300 and runner.violations.total == 0
    assert compare_with_runner(graph, runner) == {}
    assert graph.metrics["touch_peak_force"] == runner.touch_peak_force
    assert graph.metrics["learned_damping"] == runner.learned_damping
    assert graph.safe and graph.metrics["safe_hold_cycles"] == 0
    assert all(not counts for counts in graph.rejected.values()), graph.rejected


def test_strike_first_graph_equals_the_ros_free_run():
    """The default strategy (strike-first) on the graph: the impact, the decision in contact
    from the learner node's estimates (fed by the planner's gate), the hand-over once the
    target is admitted, all on the same cycles and every metric equal bit for bit."""
    graph = run_impact_graph("maximal", "ff_mpc", overrides=STRIKE_FIRST, timeout=300)
    runner = _runner("maximal", "ff_mpc", STRIKE_FIRST)
    assert runner.strategy == "strike_first" and np.isnan(runner.touch_time)
    assert runner.contact_time == pytest.approx(0.199)
    assert runner.decision_time == pytest.approx(0.248)
    assert runner.handover_time == pytest.approx(0.269)
    assert runner.refusal == "" and runner.violations.total == 0
    assert compare_with_runner(graph, runner) == {}
    assert graph.metrics["learned_stiffness"] == runner.learned_stiffness
    assert graph.safe and graph.metrics["safe_hold_cycles"] == 0
    assert all(not counts for counts in graph.rejected.values()), graph.rejected


def test_touch_first_bag_holds_the_touch_the_strike_and_the_learner(touch_first_ff_mpc):
    graph, runner, path = touch_first_ff_mpc
    steps = 1200
    with BagReader(path) as bag:
        assert bag.recovery.complete
        refs = [
            layouts.IMPACT_REFERENCE.unpack(m) for m in _messages(bag, "/impact_planner/reference")
        ]
        phases = [layouts.impact_phase(r["phase"]) for r in refs if r["t"] < steps * 1e-3]
        assert len(phases) == steps
        # every phase of the strategy, in order
        order = [p for i, p in enumerate(phases) if i == 0 or p != phases[i - 1]]
        assert order == ["touch", "touch_contact", "retract", "strike", "contact"]
        # the pre-impact bound of the touch (robust, prior range) and of the strike (learned)
        touch = [r["pre_impact_velocity"] for r in refs[:199] if r["bound_valid"] > 0]
        strike = [
            r["pre_impact_velocity"]
            for r in refs
            if r["bound_valid"] > 0 and layouts.impact_phase(r["phase"]) == "strike"
        ]
        assert touch and strike and max(strike) > max(touch)
        # the learner's estimates with their standard errors (the last one: the run's)
        est = [
            layouts.CONTACT_ESTIMATE.unpack(m) for m in _messages(bag, "/contact_learner/estimate")
        ]
        last = [e for e in est if e["t"] < steps * 1e-3][-1]
        assert (last["stiffness"], last["damping"]) == (
            runner.learned_stiffness,
            runner.learned_damping,
        )
        assert (last["stiffness_std"], last["damping_std"]) == runner.learned_std
        assert last["samples"] == runner.learner_samples
        # torques, and the MPC's force after the hand-over
        torques = _messages(bag, "/impact_controller/torque")
        assert len(torques) == steps + 1
        status = [
            layouts.IMPACT_CONTROL.unpack(m, nv=7)
            for m in _messages(bag, "/impact_controller/status")
        ]
        assert np.array_equal(status[500]["torque"], np.asarray(torques[500].effort))
        after = [s for s in status if s["t"] >= runner.handover_time and s["t"] < steps * 1e-3]
        assert after and all(s["mpc_force"] > 0 for s in after[4:])
        params = bag.parameters
        assert params["/impact_planner"]["strategy"] == "touch_first"
        assert params["/contact_learner"]["planner_gate"] is True
        summary = json.loads(_messages(bag, "/impact_graph/summary")[0].data)
        assert summary["touch_time"] == runner.touch_time and summary["safe"] is True


def test_baseline_graph_equals_the_ros_free_run():
    """No planner node: the controller node runs the baseline approach and the admittance; the
    whole graph under a namespace (its clock too)."""
    graph = run_impact_graph(
        "baseline", "admittance", overrides=BASELINE, timeout=180, namespace="/cell_b"
    )
    runner = _runner("baseline", "admittance", BASELINE)
    assert runner.contact_time == pytest.approx(0.630)
    assert compare_with_runner(graph, runner) == {}
    assert set(graph.rejected) == {
        "dice_plant",
        "joint_sensor",
        "ft_sensor",
        "contact_learner",
        "impact_controller",
        "state_publisher",
    }


def test_comparison_sees_a_different_run(maximal_ff_mpc):
    """compare_with_runner is not blind: a run with another target force differs."""
    graph, _, _ = maximal_ff_mpc
    other = _runner("maximal", "ff_mpc", [*MAXIMAL, "target_force=50"])
    assert set(compare_with_runner(graph, other)) & {"final_force", "peak_force"}
    assert set(COMPARED) >= {"contact_time", "pre_impact_velocity", "peak_force"}


def _messages(bag: BagReader, topic: str) -> list:
    cls = message_class(bag.topics[topic].type)
    return [deserialize_message(m.data, cls) for m in bag.messages([topic])]


def test_the_bag_holds_the_planner_learner_controller_and_mpc(maximal_ff_mpc, capsys):
    graph, runner, path = maximal_ff_mpc
    steps = 350
    with BagReader(path) as bag:
        assert bag.recovery.complete
        for topic, type_name, _ in topics.IMPACT_GRAPH_TOPICS:
            assert bag.topics[topics.resolve(topic)].type == type_name, topic
        # the planner's pre-impact velocity (eq 14 bound) until the contact
        refs = [
            layouts.IMPACT_REFERENCE.unpack(m) for m in _messages(bag, "/impact_planner/reference")
        ]
        assert len(refs) == steps + 1
        bounds = [r["pre_impact_velocity"] for r in refs if r["bound_valid"] > 0]
        assert len(bounds) == 178 and max(bounds) > 0.4  # every cycle before the contact
        # the learner's stiffness and damping with their uncertainty
        est = [
            layouts.CONTACT_ESTIMATE.unpack(m) for m in _messages(bag, "/contact_learner/estimate")
        ]
        last = [e for e in est if e["t"] < steps * 1e-3][-1]
        assert last["stiffness"] == runner.learned_stiffness
        assert (last["stiffness_std"], last["damping_std"]) == runner.learned_std
        # the controller's commands, and the MPC's force after the hand-over
        torques = _messages(bag, "/impact_controller/torque")
        assert len(torques) == steps + 1 and isinstance(torques[0], JointState)
        status = [
            layouts.IMPACT_CONTROL.unpack(m, nv=7)
            for m in _messages(bag, "/impact_controller/status")
        ]
        assert np.array_equal(status[100]["torque"], np.asarray(torques[100].effort))
        after = [s for s in status if s["t"] >= runner.handover_time and s["t"] < steps * 1e-3]
        assert after and all(s["mpc_force"] > 0 for s in after[4:])
        assert max(s["mpc_weight"] for s in status) == 1.0
        summary = json.loads(_messages(bag, "/impact_graph/summary")[0].data)
        assert summary["peak_force"] == runner.peak_force and summary["safe"] is True
        assert set(bag.parameters) >= {"/impact_controller", "/impact_planner", "/dice_plant"}
    from ffmpc_ros.cli import main

    assert main(["bag", "info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "/impact_planner/reference" in out and "/contact_learner/estimate" in out


def test_the_graph_gives_the_planner_the_study_values_under_the_schema_names():
    from ffmpc_core.errors import ConfigError
    from ffmpc_core.impact.scenario import IMPACT_SCHEMA
    from ffmpc_ros.params import NODE_SPECS, impact_config_from_parameters, node_impact_names

    # the touch-first settings reach the planner node whole (a changed one too), under the
    # IMPACT_SCHEMA names, and rebuild the study's values there
    cfg, params = impact_node_parameters(
        "maximal", "admittance", overrides=["touch.touch_force=12", "planner.cost=lp"]
    )
    spec = NODE_SPECS["impact_planner"]
    planner = params["impact_planner"]
    assert planner["touch.touch_force"] == 12.0 and planner["planner.cost"] == "lp"
    built = IMPACT_SCHEMA.flatten(impact_config_from_parameters(spec, planner))
    wanted = IMPACT_SCHEMA.flatten(cfg)
    names = node_impact_names(spec)
    assert len(names) > 40 and all(built[n] == wanted[n] for n in names)
    assert params["contact_learner"]["planner_gate"] is True
    assert "contact_threshold" not in params["contact_learner"]  # the schema's default
    _, params = impact_node_parameters("maximal", "admittance", overrides=["contact_threshold=3"])
    assert params["contact_learner"]["contact_threshold"] == 3.0
    assert params["impact_controller"]["contact_threshold"] == 3.0
    _, params = impact_node_parameters("maximal", "admittance", overrides=["strategy=prior"])
    assert params["impact_planner"]["strategy"] == "prior"
    assert params["contact_learner"]["planner_gate"] is False
    with pytest.raises(ConfigError, match=r"^planner.horizon = 1: expected an integer"):
        impact_node_parameters("maximal", "admittance", overrides=["planner.horizon=1"])
    cfg, params = impact_node_parameters("baseline", "ff_mpc", overrides=["duration=1"])
    assert "impact_planner" not in params and cfg.duration == 1.0
    assert params["ft_sensor"]["measure_moments"] is True


def _reference(k: int, position, rotation, velocity=(0.0, 0.0, -0.1)) -> Float64MultiArray:
    return layouts.IMPACT_REFERENCE.pack(
        {
            "t": k * 1e-3,
            "safe_stop": 0.0,
            "phase": layouts.IMPACT_PHASES["approach"],
            "bound_valid": 1.0,
            "pre_impact_velocity": 0.5,
            "position": position,
            "velocity": velocity,
            "acceleration": np.zeros(3),
            "rotation": rotation,
            "force": 0.0,
            "target_force": 60.0,
            "strike": 1.0,
            "impact_force": 0.0,
            "handover_allowed": 1.0,
            "learner_samples": 0.0,
            "gate_phase": -1.0,
            "gate_learn": 0.0,
            "gate_surface_valid": 0.0,
            "gate_surface": np.zeros(3),
            "stopped_short_time": -1.0,
            "stopped_short_force": 0.0,
        }
    )


def test_controller_node_rejects_a_bad_reference_with_one_log_line_and_holds(ros):
    """A reference whose twist is NaN: one log line, a safe hold torque (finite, within the
    limits, safe_hold = 1) for that cycle; the next good reference is tracked again."""
    cfg, params = impact_node_parameters("maximal", "admittance", overrides=MAXIMAL)
    node = ros.add(
        ImpactControllerNode(
            context=ros.context,
            parameter_overrides=parameter_overrides(params["impact_controller"]),
        )
    )
    # the node declares every IMPACT_SCHEMA name (read-only, the schema's range) and rebuilt
    # the run's configuration from the changed ones the graph gave it
    assert node.config == cfg and set(IMPACT_SCHEMA.params) <= set(node.params)
    (desc,) = node.describe_parameters(["plant.dice_stiffness"])
    assert desc.read_only and desc.floating_point_range[0].from_value == 1.0
    robot = load_robot("panda")
    cfg = load_impact_config("impact", {"approach_height": 0.05})
    q = start_pose(cfg, robot)
    pose = robot.contact_placement(q)
    probe = ros.probe()
    out: list = []
    probe.create_subscription(
        Float64MultiArray,
        topics.IMPACT_CONTROL_STATUS,
        out.append,
        topics.graph_qos(topics.IMPACT_CONTROL_STATUS, "subscription"),
    )

    def qos(topic: str):  # the node runs with the graph's overrides: publish as the graph does
        return topics.graph_qos(topic, "publisher")

    pub_j = probe.create_publisher(
        JointState, topics.SENSED_JOINT_STATES, qos(topics.SENSED_JOINT_STATES)
    )
    from geometry_msgs.msg import WrenchStamped

    pub_w = probe.create_publisher(WrenchStamped, topics.SENSED_WRENCH, qos(topics.SENSED_WRENCH))
    pub_r = probe.create_publisher(
        Float64MultiArray, topics.IMPACT_REFERENCE, qos(topics.IMPACT_REFERENCE)
    )
    zeros = np.zeros(robot.nv)
    for k in range(3):
        ros.set_clock(node, k)
        velocity = (0.0, 0.0, float("nan")) if k == 1 else (0.0, 0.0, -0.1)
        pub_r.publish(_reference(k, pose.translation, pose.rotation.reshape(-1), velocity))
        pub_j.publish(joint_state(node, k, q, zeros, zeros))
        pub_w.publish(wrench(node, k, (0.0, 0.0, 0.0)))
        assert ros.spin_until(lambda k=k: len(out) == k + 1), f"no command for cycle {k}"
    status = [layouts.IMPACT_CONTROL.unpack(m, nv=7) for m in out]
    assert [s["safe_hold"] for s in status] == [0.0, 1.0, 0.0]
    kind = "/impact_planner/reference:value"
    assert node.rejected[kind] == 1 and node.log_lines[kind] == 1
    hold = status[1]["torque"]
    assert np.all(np.isfinite(hold)) and np.all(np.abs(hold) < robot.torque_limit)
    # the hold differs from the tracking commands (it does not track the reference's motion)
    assert not np.array_equal(hold, status[2]["torque"])


def test_the_launch_file_starts_the_nodes_ffmpc_run_impact_derives():
    """impact.launch.yaml's parameters are the ones run_impact_graph gives the same settings
    (but for what only a launch needs: no bring-up probe, exit at the end)."""
    from ffmpc_ros.launch import load_launch_file

    path = topics.__file__.replace("topics.py", "ros_layout/launch/impact.launch.yaml")
    settings = {"regulation": "ff_mpc", "duration": "0.5", "approach_height": "0.3"}
    description = load_launch_file(path, settings)
    launched = {n.name: dict(n.parameters) for n in description.nodes}
    items = ["duration=0.5", "approach_height=0.3"]  # the default strategy: strike first
    cfg, params = impact_node_parameters("maximal", "ff_mpc", overrides=items)
    assert cfg.strategy == "strike_first" and "strategy" not in params["impact_planner"]
    # only what differs from the schema's defaults is given, to the nodes that declare it
    assert (
        params["dice_plant"]["duration"] == 0.5 and params["dice_plant"]["approach_height"] == 0.3
    )
    assert params["impact_controller"]["duration"] == 0.5
    assert set(launched) == set(params)
    assert launched["dice_plant"].pop("exit_when_done") is True
    assert launched["dice_plant"].pop("start_subscribers") == 1  # no bring-up probe
    assert params["dice_plant"].pop("start_subscribers") == 2
    for name, values in params.items():
        # QoS: the launch names only the topics the node uses, each as the bring-up sets it
        qos = {k: v for k, v in launched[name].items() if k.startswith("qos_overrides.")}
        assert qos and all(values[k] == v for k, v in qos.items()), name
        plain = {k: v for k, v in values.items() if not k.startswith("qos_overrides.")}
        assert {k: v for k, v in launched[name].items() if k not in qos} == plain, name


def test_ffmpc_run_refuses_the_other_graphs_options(capsys):
    """Options of one graph given to the other: one line, exit 2, nothing started."""
    from ffmpc_ros.cli import main

    assert main(["run", "impact", "--single-process"]) == 2
    assert "--single-process: polishing-graph options" in capsys.readouterr().err
    assert main(["run", "polishing", "--approach", "baseline"]) == 2
    assert "--approach: options of ffmpc run impact only" in capsys.readouterr().err
    assert main(["run", "impact", "--set", "strategy=none"]) == 2
    assert "strategy" in capsys.readouterr().err
