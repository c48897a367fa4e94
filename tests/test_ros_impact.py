"""The impact nodes alone (Dehio & Kheddar 2020): the impact planner publishes the core
ImpactController's numbers, the contact learner the core RLS estimate and recovers a known
spring-damper, bad input is rejected with one log line and a safe output, and the MPC node takes a
learner estimate live only when it is confident."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from ffmpc_msgs.msg import MpcCommand
from geometry_msgs.msg import TwistStamped, WrenchStamped
from rcl_interfaces.msg import ParameterType
from ros_helpers import joint_state, overrides, publish_clock, recorder, wrench
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger

from ffmpc_core.errors import ConfigError
from ffmpc_core.impact import (
    ContactEstimate,
    ImpactController,
    ImpactControllerConfig,
    ImpactMeasurement,
    RecursiveContactLearner,
    SoftMaterial,
    joint_limits,
)
from ffmpc_core.impact.scenario import IMPACT_SCHEMA, ImpactStudyConfig
from ffmpc_core.mpc import ModelPredictiveController, MpcMeasurement
from ffmpc_core.polishing import build_task, mpc_config
from ffmpc_core.robots import load_robot
from ffmpc_core.scenario import load_scenario
from ffmpc_ros import layouts, topics
from ffmpc_ros.command_msg import command_fields
from ffmpc_ros.contact_learner_node import ContactLearnerNode
from ffmpc_ros.impact_common import estimate_message
from ffmpc_ros.impact_planner_node import ImpactPlannerNode
from ffmpc_ros.mpc_node import MpcNode

DOWN = np.array([0.0, 0.0, -1.0])
#: The paper's scheme with the learner's material (the study's default strategy is
#: strike_first).
PRIOR = {"strategy": "prior", "use_learned_material": True}
LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


@pytest.fixture(scope="module")
def panda():
    return load_robot("panda")


def _scenario(**changes):
    values = {"robot": "panda", **changes}
    return load_scenario("polishing").with_overrides(values)


def _estimate(stiffness, damping, rel_std, samples, t, direction=DOWN):
    est = ContactEstimate(
        stiffness=stiffness,
        damping=damping,
        stiffness_std=rel_std * stiffness,
        damping_std=rel_std * damping,
        noise_std=0.1,
        samples=samples,
        condition=10.0,
    )
    return estimate_message(est, t, (0.01, 0.0, 30.0), direction, np.zeros(3))


def _pubs(probe):
    qos = topics.publisher_qos()
    return (
        probe.create_publisher(JointState, topics.SENSED_JOINT_STATES, qos),
        probe.create_publisher(WrenchStamped, topics.SENSED_WRENCH, qos),
        probe.create_publisher(Float64MultiArray, topics.CONTACT_ESTIMATE, qos),
    )


def _approach(robot, n, speed=0.2):
    """Joint states moving the contact frame down at ``speed`` m/s (1 ms apart)."""
    data = robot.create_data()
    J = pin.computeFrameJacobian(robot.model, data, robot.q_nominal, robot.contact_frame_id, LWA)[
        :3
    ]
    qd = np.linalg.pinv(J) @ (speed * DOWN)
    return [robot.q_nominal + 1e-3 * k * qd for k in range(n)], qd


# -- impact planner ---------------------------------------------------------------------------
def test_planner_publishes_the_core_controller_numbers_and_takes_a_confident_estimate(ros, panda):
    node = ros.add(
        ImpactPlannerNode(
            context=ros.context,
            parameter_overrides=overrides("impact_planner", _scenario(), **PRIOR),
        )
    )
    probe = ros.probe()
    twists = recorder(probe, TwistStamped, topics.IMPACT_COMMAND)
    status = recorder(probe, Float64MultiArray, topics.IMPACT_STATUS)
    pub_j, pub_w, pub_e = _pubs(probe)
    # The paper's set-up, built here from the core classes (not from the node's parameters).
    core = ImpactController(
        panda,
        ImpactStudyConfig().control_limits(joint_limits(panda)),  # 0.9 × q̈_max, q̇_max
        ImpactControllerConfig(direction=DOWN, material=SoftMaterial(2400.0, 15.0, 0.03)),
    )
    qs, qd = _approach(panda, 12)
    forces = [0.0] * 8 + [1.0, 5.0, 20.0, 40.0]  # contact at cycle 9 (≥ 2 N)
    expected = []
    for k, (q, f) in enumerate(zip(qs, forces, strict=True)):
        ros.set_clock(node, k)
        if k == 2:  # not confident (20 % standard error): ignored
            pub_e.publish(_estimate(5000.0, 30.0, 0.2, 500, 0.001))
            assert ros.spin_until(
                lambda: node.gate.last_cycle(topics.resolve(topics.CONTACT_ESTIMATE)) >= 0
            )
        if k == 4:  # confident: the planner plans with it from this cycle on
            pub_e.publish(_estimate(5000.0, 30.0, 0.01, 500, 0.003))
            assert ros.spin_until(lambda: node.estimates_used == 1)
            core.material = SoftMaterial(5000.0, 30.0, 0.03)
        pub_w.publish(wrench(node, k, (0.0, 0.0, f)))
        pub_j.publish(joint_state(node, k, q, qd, np.zeros(7)))
        assert ros.spin_until(lambda k=k: len(status) == k + 1)
        expected.append(
            core.step(ImpactMeasurement(q=q, v=qd, force=np.array([0, 0, f])), k * 1e-3)
        )
    assert node.estimates_used == 1 and node.log_lines["learned_material"] == 1
    bounds = []
    for k, (cmd, tw, st) in enumerate(zip(expected, twists, status, strict=True)):
        got = layouts.IMPACT_STATUS.unpack(st)
        assert tw.header.stamp == node.grid.stamp_of(k)
        assert tw.header.frame_id == topics.COMMAND_FRAME
        lin = np.array([tw.twist.linear.x, tw.twist.linear.y, tw.twist.linear.z])
        np.testing.assert_array_equal(lin, cmd.velocity)
        np.testing.assert_array_equal(got["position"], cmd.position)
        assert got["t"] == k * 1e-3 and got["safe_stop"] == 0.0
        assert got["phase"] == (1.0 if k >= 9 else 0.0)
        assert got["velocity"] == DOWN @ cmd.velocity and got["force"] == forces[k]
        if k < 9:
            assert got["pre_impact_velocity"] == cmd.pre_impact_velocity > 0
            assert (got["stiffness"], got["learned"]) == ((5000.0, 1.0) if k >= 4 else (2400, 0))
            bounds.append(got["pre_impact_velocity"])
        else:
            assert got["pre_impact_velocity"] == 0.0 and np.isnan(cmd.pre_impact_velocity)
            assert got["contact_time"] == 9 * 1e-3 and got["target_force"] == 60.0
    # A stiffer, more damped material lowers the certified pre-impact velocity.
    assert bounds[4] < bounds[3]
    assert 0.0 < np.min(bounds) and np.max(bounds) < 2.0


def test_planner_rejects_bad_input_with_one_log_line_and_stops_safely(ros, panda):
    node = ros.add(
        ImpactPlannerNode(
            context=ros.context,
            parameter_overrides=overrides("impact_planner", _scenario(), **PRIOR),
        )
    )
    probe = ros.probe()
    status = recorder(probe, Float64MultiArray, topics.IMPACT_STATUS)
    twists = recorder(probe, TwistStamped, topics.IMPACT_COMMAND)
    pub_j, pub_w, pub_e = _pubs(probe)
    qs, qd = _approach(panda, 4)
    nan_q = [np.nan] * 7

    def last():
        tw = twists[-1].twist.linear
        return layouts.IMPACT_STATUS.unpack(status[-1]), np.array([tw.x, tw.y, tw.z])

    # Bad input before any command: rejected, nothing to stop, nothing published.
    ros.set_clock(node, 0)
    pub_j.publish(joint_state(node, 0, nan_q, qd, np.zeros(7)))
    assert ros.spin_until(lambda: node.rejected.total() == 1)
    ros.spin_for(0.05)
    assert not status
    for k in (1, 2):
        ros.set_clock(node, k)
        pub_w.publish(wrench(node, k, (0.0, 0.0, 0.0)))
        pub_j.publish(joint_state(node, k, qs[k], qd, np.zeros(7)))
    assert ros.spin_until(lambda: len(status) == 2)
    assert last()[0]["velocity"] > 0 and last()[0]["safe_stop"] == 0.0
    # Four NaN joint states: four rejections, ONE log line, a zero twist for each.
    for k in range(3, 7):
        ros.set_clock(node, k)
        pub_j.publish(joint_state(node, k, nan_q, qd, np.zeros(7)))
    assert ros.spin_until(lambda: len(status) == 6)
    kind = f"{topics.resolve(topics.SENSED_JOINT_STATES)}:value"
    assert node.rejected[kind] == 5 and node.log_lines[kind] == 1
    got, lin = last()
    assert got["safe_stop"] == 1.0 and got["velocity"] == 0.0 and not lin.any()
    assert got["t"] == 6e-3 and twists[-1].header.stamp == node.grid.stamp_of(6)
    # A wrench in another frame and unknown joint names: rejected and stopped as well.
    ros.set_clock(node, 8)
    pub_w.publish(wrench(node, 7, (0.0, 0.0, 0.0), frame="tool0"))
    pub_j.publish(joint_state(node, 8, qs[3], qd, np.zeros(7), [f"j{i}" for i in range(7)]))
    assert ros.spin_until(lambda: len(status) == 8)
    assert (
        node.rejected[f"{topics.resolve(topics.SENSED_WRENCH)}:value"] == 1
        and last()[0]["safe_stop"] == 1
    )
    # A duplicate is rejected without a stop; a complete good cycle resumes the command.
    ros.set_clock(node, 9)
    pub_w.publish(wrench(node, 2, (0.0, 0.0, 0.0)))
    pub_w.publish(wrench(node, 9, (0.0, 0.0, 0.0)))
    pub_j.publish(joint_state(node, 9, qs[3], qd, np.zeros(7)))
    assert ros.spin_until(lambda: len(status) == 9)
    assert node.rejected[f"{topics.resolve(topics.SENSED_WRENCH)}:order"] == 1
    assert last()[0]["safe_stop"] == 0.0 and last()[0]["velocity"] > 0
    # Missing input: the clock runs on (0.2 s) without a measurement → one watchdog stop.
    clock = probe.create_publisher(Clock, topics.CLOCK, topics.clock_qos())
    publish_clock(clock, node, 200)
    assert ros.spin_until(lambda: node.rejected["inputs:missing"] == 1)
    ros.spin_for(0.15)
    assert len(status) == 10 and node.rejected["inputs:missing"] == 1
    got, lin = last()
    assert got["safe_stop"] == 1.0 and got["t"] == 200 * 1e-3 and not lin.any()
    # Stale input (cycle 10 at t = 0.2 s): rejected as stale, stopped at the clock's cycle.
    pub_j.publish(joint_state(node, 10, qs[3], qd, np.zeros(7)))
    assert ros.spin_until(lambda: len(status) == 11)
    assert node.rejected[f"{topics.resolve(topics.SENSED_JOINT_STATES)}:stale"] == 1
    assert last()[0]["safe_stop"] == 1.0 and last()[0]["t"] == 200 * 1e-3
    # Estimates: NaN, another direction: rejected, the planner keeps the prior.
    bad = _estimate(5000.0, 30.0, 0.01, 500, 0.2)
    bad.data[1] = float("nan")
    for msg, kind in (
        (bad, "value"),
        (_estimate(5000.0, 30.0, 0.01, 500, 0.2, direction=np.array([1.0, 0, 0])), "direction"),
    ):  # one at a time: the estimate subscription keeps only the newest sample
        pub_e.publish(msg)
        assert ros.spin_until(
            lambda kind=kind: node.rejected[f"{topics.resolve(topics.CONTACT_ESTIMATE)}:{kind}"]
        )
    assert node.controller.material.stiffness == 2400.0 and node.estimates_used == 0


def test_planner_needs_acceleration_limits_for_a_robot_without_a_data_sheet(ros):
    with pytest.raises(ConfigError, match="acceleration_limit"):
        ImpactPlannerNode(context=ros.context, parameter_overrides=overrides("impact_planner"))
    iiwa = overrides("impact_planner", acceleration_limit=[10.0] * 7, **{"planner.horizon": 10})
    node = ros.add(ImpactPlannerNode(context=ros.context, parameter_overrides=iiwa))
    np.testing.assert_array_equal(node.limits.acceleration, np.full(7, 9.0))  # 0.9 × 10 rad/s²
    assert node.controller.planner.config.horizon == 10


def test_impact_parameters_are_described_read_only_and_ranged(ros):
    numeric = (ParameterType.PARAMETER_INTEGER, ParameterType.PARAMETER_DOUBLE)
    scenario = _scenario()
    for cls, name in (
        (ImpactPlannerNode, "impact_planner"),
        (ContactLearnerNode, "contact_learner"),
    ):
        node = ros.add(cls(context=ros.context, parameter_overrides=overrides(name, scenario)))
        for desc in node.describe_parameters(list(node.params)):
            assert desc.description and desc.read_only, desc.name
            if desc.type in numeric:
                assert desc.floating_point_range or desc.integer_range, desc.name
    with pytest.raises(ConfigError, match="solver"):
        bad = overrides("impact_planner", scenario, **{"planner.solver": "qpoases"})
        ImpactPlannerNode(context=ros.context, parameter_overrides=bad, node_name="bad_solver")
    with pytest.raises(ConfigError, match=r"^skip_onset_samples = -1: expected an integer"):
        bad = overrides("contact_learner", scenario, skip_onset_samples=-1)
        ContactLearnerNode(context=ros.context, parameter_overrides=bad, node_name="bad")
    with pytest.raises(ConfigError, match="direction"):
        bad = overrides("contact_learner", scenario, direction=[0.0, 0.0, -2.0])
        ContactLearnerNode(context=ros.context, parameter_overrides=bad, node_name="bad2")


# -- contact learner --------------------------------------------------------------------------
def _spring_damper_run(robot, stiffness, damping, noise_std, rng, dt):
    """A penetration z = A(1 − cos 2πντ)/2 after 5 samples at rest on the surface, seen as joint
    states (q, q̇) and the force of a spring-damper contact f = αz + βż (≥ 0) plus noise."""
    data = robot.create_data()
    fid, q0 = robot.contact_frame_id, robot.q_nominal
    J = pin.computeFrameJacobian(robot.model, data, q0, fid, LWA)[:3]
    u = np.linalg.pinv(J) @ DOWN
    p0 = robot.contact_placement(q0).translation.copy()
    amplitude, w = 0.01, 2 * np.pi * 4.0
    tau = np.maximum(np.arange(255) - 5, 0) * dt
    s, sd = 0.5 * amplitude * (1 - np.cos(w * tau)), 0.5 * amplitude * w * np.sin(w * tau)
    out = []
    for si, sdi in zip(s, sd, strict=True):
        q, v = q0 + si * u, sdi * u
        pin.forwardKinematics(robot.model, data, q, v)
        p = pin.updateFramePlacement(robot.model, data, fid).translation
        z = DOWN @ (p - p0)
        zd = DOWN @ pin.getFrameVelocity(robot.model, data, fid, LWA).linear
        f_true = max(stiffness * z + damping * zd, 0.0) if z > 0 else 0.0
        out.append((q, v, f_true + noise_std * rng.standard_normal()))
    return out


def _fed_samples(robot, run, threshold=2.0, skip=1):
    """The documented rule, written again: surface = last sample with f ≤ 0 before f ≥ threshold;
    feed in-contact (f > 0) samples but the first ``skip`` of each episode; z, ż by FK."""
    data, fid = robot.create_data(), robot.contact_frame_id
    surface = last_free = None
    run_length, fed = 0, []  # fed: (cycle, z m, ż m/s, f N)
    for k, (q, v, f) in enumerate(run):
        pin.forwardKinematics(robot.model, data, q, v)
        p = pin.updateFramePlacement(robot.model, data, fid).translation.copy()
        zd = float(DOWN @ pin.getFrameVelocity(robot.model, data, fid, LWA).linear)
        if surface is None:
            if f <= 0.0:
                last_free = p
            if f >= threshold:
                surface = last_free
        run_length = run_length + 1 if f > 0.0 else 0
        if surface is not None and run_length > skip:
            fed.append((k, float(DOWN @ (p - surface)), zd, f))
    return fed, surface


def test_learner_node_equals_the_core_rls_and_recovers_a_spring_damper(ros, panda):
    dt = 1e-3
    node = ros.add(
        ContactLearnerNode(
            context=ros.context, parameter_overrides=overrides("contact_learner", _scenario())
        )
    )
    probe = ros.probe()
    out = recorder(probe, Float64MultiArray, topics.CONTACT_ESTIMATE)
    pub_j, pub_w, _ = _pubs(probe)
    stiffness, damping = 3000.0, 20.0
    run = _spring_damper_run(panda, stiffness, damping, 0.05, np.random.default_rng(7), dt)
    for k, (q, v, f) in enumerate(run):
        ros.set_clock(node, k)
        pub_w.publish(wrench(node, k, -f * DOWN))
        pub_j.publish(joint_state(node, k, q, v, np.zeros(7)))
        if k % 50 == 49:  # stay within the subscription depth
            assert ros.spin_until(lambda k=k: node.processed == k + 1)
    assert ros.spin_until(lambda: node.processed == len(run))
    fed, surface = _fed_samples(panda, run)
    core = RecursiveContactLearner()
    for _, z, zd, f in fed:
        core.update(z, zd, f)
    expected = core.estimate()
    assert ros.spin_until(lambda: len(out) == len(fed) - 2)  # one per sample from the third
    got = layouts.CONTACT_ESTIMATE.unpack(out[-1])
    assert got["t"] == fed[-1][0] * dt and got["samples"] == len(fed) == node.learner.samples
    for name in ("stiffness", "damping", "stiffness_std", "damping_std", "noise_std"):
        np.testing.assert_allclose(got[name], getattr(expected, name), rtol=1e-9, err_msg=name)
    np.testing.assert_allclose(got["condition"], expected.condition, rtol=1e-6)
    np.testing.assert_array_equal(got["direction"], DOWN)
    np.testing.assert_allclose(got["surface"], surface, rtol=1e-12)
    assert (got["deformation"], got["deformation_rate"], got["force"]) == pytest.approx(fed[-1][1:])
    # The known material, within 4 standard errors and 2 % (noise σ = 0.05 N).
    assert abs(got["stiffness"] - stiffness) < min(4 * got["stiffness_std"], 0.02 * stiffness)
    assert abs(got["damping"] - damping) < min(4 * got["damping_std"], 0.02 * damping)
    assert got["noise_std"] == pytest.approx(0.05, rel=0.2)
    # Bad input: rejected with one log line; nothing fed, nothing published.
    published = node.published
    for k in range(len(run), len(run) + 3):
        ros.set_clock(node, k)
        pub_w.publish(wrench(node, k, (0.0, 0.0, np.nan)))
        pub_j.publish(joint_state(node, k, run[-1][0], run[-1][1], np.zeros(7)))
    kind = f"{topics.resolve(topics.SENSED_WRENCH)}:value"
    assert ros.spin_until(lambda: node.rejected[kind] == 3)
    ros.spin_for(0.05)
    assert node.log_lines[kind] == 1 and node.published == published
    assert node.learner.samples == len(fed)
    # Reset service: every sample and the surface are forgotten.
    client = probe.create_client(Trigger, topics.CONTACT_LEARNER_RESET_SERVICE)
    assert client.wait_for_service(timeout_sec=5.0)
    future = client.call_async(Trigger.Request())
    assert ros.spin_until(future.done)
    assert future.result().success and str(len(fed)) in future.result().message
    assert node.learner.samples == 0 and node.surface is None


def test_learner_node_recovers_the_material_exactly_without_noise(ros, panda):
    node = ros.add(
        ContactLearnerNode(
            context=ros.context,
            parameter_overrides=overrides("contact_learner", _scenario(), skip_onset_samples=0),
        )
    )
    probe = ros.probe()
    pub_j, pub_w, _ = _pubs(probe)
    run = _spring_damper_run(panda, 800.0, 35.0, 0.0, np.random.default_rng(0), 1e-3)[:130]
    for k, (q, v, f) in enumerate(run):
        ros.set_clock(node, k)
        pub_w.publish(wrench(node, k, -f * DOWN))
        pub_j.publish(joint_state(node, k, q, v, np.zeros(7)))
        if k % 50 == 49:
            assert ros.spin_until(lambda k=k: node.processed == k + 1)
    assert ros.spin_until(lambda: node.processed == len(run))
    est = node.estimate
    fed, surface = _fed_samples(panda, run, skip=0)
    assert est.samples == len(fed)
    np.testing.assert_array_equal(surface, panda.contact_placement(panda.q_nominal).translation)
    np.testing.assert_allclose(node.surface, surface, rtol=1e-12)
    assert est.stiffness == pytest.approx(800.0, rel=1e-6)
    assert est.damping == pytest.approx(35.0, rel=1e-6)
    assert est.noise_std < 1e-4  # N: only the ridge term λ = 1e-9 biases the fit


# -- the MPC node with the learned contact ----------------------------------------------------
def _contact_of(mpc: ModelPredictiveController) -> set[tuple[float, float]]:
    return {
        (float(n.model.nominal_stiffness[0]), float(n.model.nominal_damping[0]))
        for n in (*mpc.nodes, mpc.terminal_node)
    }


def test_mpc_node_applies_a_learner_estimate_live_only_when_confident(ros):
    scenario = load_scenario("polishing")
    robot = load_robot("iiwa")
    params = overrides("mpc", scenario, use_learned_contact=True, learner_min_samples=50)
    default = MpcNode(context=ros.context, parameter_overrides=overrides("mpc"))
    assert topics.resolve(topics.CONTACT_ESTIMATE) not in {
        s.topic_name for s in default.subscriptions
    }
    default.destroy_node()  # off by default: the polishing graph is unchanged
    node = ros.add(MpcNode(context=ros.context, parameter_overrides=params))
    assert topics.resolve(topics.CONTACT_ESTIMATE) in {s.topic_name for s in node.subscriptions}
    probe = ros.probe()
    out = recorder(probe, MpcCommand, topics.MPC_COMMAND)
    pub_j, pub_w, pub_e = _pubs(probe)
    assert _contact_of(node.mpc) == {(1000.0, 100.0)}

    def send(msg):
        before = node.gate.last_cycle(topics.resolve(topics.CONTACT_ESTIMATE))
        pub_e.publish(msg)
        assert ros.spin_until(
            lambda: node.gate.last_cycle(topics.resolve(topics.CONTACT_ESTIMATE)) > before
        )

    # Not confident: 10 % standard errors, then too few samples → the model is unchanged.
    send(_estimate(3000.0, 40.0, 0.10, 500, 0.001))
    send(_estimate(3000.0, 40.0, 0.01, 49, 0.002))
    assert node.learned.updates == 0 and _contact_of(node.mpc) == {(1000.0, 100.0)}
    # Confident: applied to every OCP node at once, logged once (throttled).
    send(_estimate(3000.0, 40.0, 0.01, 500, 0.003))
    assert node.learned.updates == 1 and _contact_of(node.mpc) == {(3000.0, 40.0)}
    send(_estimate(3100.0, 42.0, 0.02, 600, 0.004))
    assert node.learned.updates == 2 and _contact_of(node.mpc) == {(3100.0, 42.0)}
    assert node.log_lines["contact_update"] == 1
    assert node.rejected.total() == 0
    # Bad estimates: NaN, wrong direction (x, the contact is along z), out of order.
    bad = _estimate(5000.0, 40.0, 0.01, 500, 0.005)
    bad.data[2] = float("inf")
    wrong_axis = _estimate(5000.0, 40.0, 0.01, 500, 0.006, direction=np.array([1.0, 0, 0]))
    for i, msg in enumerate((bad, wrong_axis, _estimate(5000.0, 40.0, 0.01, 500, 0.002))):
        pub_e.publish(msg)  # one at a time: the subscription keeps only the newest sample
        assert ros.spin_until(lambda i=i: node.rejected.total() == i + 1)
    assert {k.rsplit(":", 1)[1] for k in node.rejected} == {"value", "direction", "order"}
    assert node.learned.updates == 2 and _contact_of(node.mpc) == {(3100.0, 42.0)}
    # The next solve uses the learned model: the command equals a core MPC with K, B set.
    rng = np.random.default_rng(3)
    q = robot.q_nominal + 0.01 * rng.standard_normal(7)
    v, tau = 0.05 * rng.standard_normal(7), robot.gravity(robot.q_nominal)
    pub_w.publish(wrench(node, 0, (0.0, 0.0, 5.0)))
    pub_j.publish(joint_state(node, 0, q, v, tau))
    assert ros.spin_until(lambda: len(out) == 1, timeout=30)
    mpc = ModelPredictiveController(robot, mpc_config(scenario), build_task(scenario, robot))
    mpc.set_contact_parameters(3100.0, 42.0)
    expected = mpc.step(MpcMeasurement(q=q, v=v, force=np.array([5.0]), torque=tau), 0.0)
    got = command_fields(out[0], 7)
    np.testing.assert_array_equal(got["torque"], expected.torque)
    np.testing.assert_array_equal(got["feedback_gain"].reshape(7, 15), expected.feedback_gain)


def test_mpc_node_refuses_the_learned_contact_without_force_feedback(ros):
    scenario = load_scenario("polishing").with_overrides({"mpc.formulation": "classical"})
    params = overrides("mpc", scenario, use_learned_contact=True)
    with pytest.raises(ConfigError, match="force_feedback"):
        MpcNode(context=ros.context, parameter_overrides=params)


# -- the impact study's parameters, declared once (IMPACT_SCHEMA) --------------------------------
#: Names the impact nodes had as hand-written copies of IMPACT_SCHEMA values (issue 14).
OLD_COPIES = {
    "preview_horizon",
    "preview_dt",
    "max_penetration",
    "solver",
    "admittance_max_velocity",
    "admittance_velocity_filter",
    "learner_min_samples",
    "learner_max_relative_std",
}


def test_impact_nodes_declare_the_impact_schema_with_its_descriptors(ros):
    """Every IMPACT_SCHEMA name an impact node declares has the schema's description, unit,
    type and range, and its default; the planner's configuration is the ROS-free run's
    (``task_config``) from those values; no graph parameter copies a schema value."""
    from ffmpc_core.impact.scenario import task_config
    from ffmpc_ros.impact_graph import _same
    from ffmpc_ros.params import NODE_SPECS, impact_flat, node_impact_names

    aliases = set(IMPACT_SCHEMA.paths.values())
    aliases |= {a.replace(".", "_") for a in aliases} | OLD_COPIES
    defaults = impact_flat()
    for cls, name in (
        (ImpactPlannerNode, "impact_planner"),
        (ContactLearnerNode, "contact_learner"),
    ):
        spec = NODE_SPECS[name]
        copies = {g.name for g in spec.graph_parameters} & (set(IMPACT_SCHEMA.params) | aliases)
        assert not copies, (name, copies)
        node = ros.add(cls(context=ros.context, parameter_overrides=overrides(name, _scenario())))
        declared = [n for n in node.params if n in IMPACT_SCHEMA.params]
        assert declared == node_impact_names(spec) and "plant.time_step" in declared
        assert "contact_threshold" in declared
        for desc in node.describe_parameters(declared):
            p = IMPACT_SCHEMA.params[desc.name]
            assert desc.read_only and desc.additional_constraints == p.expected(), desc.name
            assert desc.description == p.description + (f", {p.unit}" if p.unit else "")
            if p.kind == "int":
                r = desc.integer_range[0]
                assert (r.from_value, r.to_value) == p.range, desc.name
            elif p.range is not None:
                r = desc.floating_point_range[0]
                assert (r.from_value, min(r.to_value, 1e300)) == (
                    p.range[0],
                    min(p.range[1], 1e300),
                ), desc.name
            assert node.get_parameter(desc.name).value == defaults[desc.name] or (
                list(node.get_parameter(desc.name).value) == defaults[desc.name]
            ), desc.name
        if name == "impact_planner":
            declared_set = set(declared)
            for pattern in ("planner.", "admittance.", "touch.", "strike.", "learner."):
                assert {n for n in IMPACT_SCHEMA.params if n.startswith(pattern)} <= declared_set
            # defaults: the study's; the controller: the ROS-free run's
            assert node.study == ImpactStudyConfig() and node.strategy == "strike_first"
            wanted = task_config("maximal", "admittance", ImpactStudyConfig())
            assert _same(node.config, wanted.controller)
            assert node.controller.touch == ImpactStudyConfig().touch
            assert node.controller.strike == ImpactStudyConfig().strike
            assert np.array_equal(node.controller.surface, wanted.surface)


def test_impact_nodes_refuse_what_the_study_refuses_with_its_message(ros):
    """A value outside the schema's range (or of the wrong type) is refused at start with the
    message ``ffmpc study impact --set`` gives; through the parameter service it is refused
    (read-only) and the node keeps its value."""
    from rclpy.parameter import Parameter

    from ffmpc_core.errors import ConfigError as Err

    scenario = _scenario()
    for i, (name, value) in enumerate(
        (
            ("planner.horizon", 1),
            ("target_force", 1000.0),
            ("touch.touch_force", -1.0),
            ("strategy", "fastest"),
            ("admittance.max_velocity", "fast"),
        )
    ):
        with pytest.raises(Err) as study:
            IMPACT_SCHEMA.build({name: value})
        with pytest.raises(Err) as node:
            bad = overrides("impact_planner", scenario, **{name: value})
            ImpactPlannerNode(context=ros.context, parameter_overrides=bad, node_name=f"bad{i}")
        assert str(node.value) == str(study.value) and str(node.value).startswith(name), name
    with pytest.raises(Err, match=r"^contact_threshold = 0\.0: expected a number in \[0\.01"):
        bad = overrides("contact_learner", scenario, contact_threshold=0.0)
        ContactLearnerNode(context=ros.context, parameter_overrides=bad, node_name="bad_lr")
    # the cross-field checks of the study's configuration too
    with pytest.raises(Err, match="contact_threshold must be below target_force"):
        bad = overrides("impact_planner", scenario, target_force=5.0, contact_threshold=10.0)
        ImpactPlannerNode(context=ros.context, parameter_overrides=bad, node_name="bad_x")
    node = ros.add(
        ImpactPlannerNode(
            context=ros.context, parameter_overrides=overrides("impact_planner", scenario)
        )
    )
    result = node.set_parameters([Parameter("planner.horizon", value=1)])[0]
    assert not result.successful and node.get_parameter("planner.horizon").value == 20
