"""Every subscriber callback of every node, fed arbitrary messages (hypothesis, derandomized):
no exception escapes, and nothing the node publishes is unsafe — every number finite, every
torque within the robot's limits.

Each example is a run of a few cycles one simulated second after the previous example (the
node's /clock callback is driven directly, as the plant's /clock would). In every cycle each
subscription gets a valid message of that cycle (so the node really computes and publishes), a
valid message with one field corrupted, a message drawn at random over its whole type (NaN,
±inf, 1e300, wrong lengths, unknown names and frames, stamps anywhere in time), or nothing; now
and then the clock jumps. The test also asserts that the fuzz reached the nodes' outputs.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from builtin_interfaces.msg import Time as TimeMsg
from ffmpc_msgs.msg import MpcCommand
from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from ros_helpers import RosHarness, overrides
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64, Float64MultiArray, MultiArrayDimension

from ffmpc_core.robots import load_robot
from ffmpc_core.scenario import load_scenario
from ffmpc_ros import layouts, topics
from ffmpc_ros.command_msg import command_fields, command_message

#: Layout of each Float64MultiArray topic a node subscribes to.
TOPIC_LAYOUTS = {
    topics.resolve(topics.PLANT_TRUTH): layouts.PLANT_TRUTH,
    topics.resolve(topics.CONTACT_ESTIMATE): layouts.CONTACT_ESTIMATE,
}
#: Topics carrying joint torques to the motors (checked against the torque limits).
TORQUE_TOPICS = (topics.resolve(topics.MOTOR_TORQUE), topics.resolve(topics.DESIRED_TORQUE))
EXAMPLES = 25
#: How each subscription is fed in a cycle (drawn uniformly from this list).
HOW = ("valid",) * 6 + ("corrupt", "corrupt", "random", "skip")
#: Topics each node must have published at least once during its fuzz (the fuzz got deep).
OUTPUTS = {
    "plant": (topics.resolve(topics.PLANT_JOINT_STATES),),
    "joint_sensor": (topics.resolve(topics.SENSED_JOINT_STATES),),
    "ft_sensor": (topics.resolve(topics.SENSED_WRENCH),),
    "mpc": (topics.resolve(topics.MPC_COMMAND),),
    "pid": (topics.resolve(topics.MOTOR_TORQUE), topics.resolve(topics.DESIRED_TORQUE)),
    "metrics": (),
    "impact_planner": (topics.resolve(topics.IMPACT_COMMAND),),
    "contact_learner": (topics.resolve(topics.CONTACT_ESTIMATE),),
}


def _nodes():
    from ffmpc_ros.contact_learner_node import ContactLearnerNode
    from ffmpc_ros.ft_sensor_node import FtSensorNode
    from ffmpc_ros.impact_planner_node import ImpactPlannerNode
    from ffmpc_ros.joint_sensor_node import JointSensorNode
    from ffmpc_ros.metrics_node import MetricsNode
    from ffmpc_ros.mpc_node import MpcNode
    from ffmpc_ros.pid_node import PidNode
    from ffmpc_ros.plant_node import PlantNode

    ff_riccati = load_scenario(
        "polishing", {"mpc.formulation": "force_feedback", "mpc.riccati_feedback": True}
    )
    panda = load_scenario("polishing").with_overrides({"robot": "panda"})
    return {
        "plant": (PlantNode, "plant", ff_riccati, {}),
        "joint_sensor": (JointSensorNode, "joint_sensor", ff_riccati, {}),
        "ft_sensor": (FtSensorNode, "ft_sensor", ff_riccati, {}),
        "mpc": (MpcNode, "mpc", ff_riccati, {"use_learned_contact": True}),
        "pid": (PidNode, "pid", ff_riccati, {"lockstep_timeout": 0.01}),
        "metrics": (MetricsNode, "metrics", ff_riccati, {}),
        # the paper's scheme with the learner's material (the study's default is touch_first)
        "impact_planner": (
            ImpactPlannerNode,
            "impact_planner",
            panda,
            {"strategy": "prior", "use_learned_material": True},
        ),
        "contact_learner": (ContactLearnerNode, "contact_learner", panda, {}),
    }


@pytest.fixture(scope="module")
def ros():
    harness = RosHarness()
    yield harness
    harness.close()


# -- strategies -------------------------------------------------------------------------------
ADVERSARIAL = st.sampled_from(
    [math.nan, math.inf, -math.inf, 1e9, -1e9, 1e300, -1e300, 5e-324, 0.0, -0.0]
)
FLOATS = st.one_of(st.floats(-3.0, 3.0), ADVERSARIAL, st.floats(allow_nan=True))


def _stamp(step_ns: int, base_k: int):
    near = st.integers(-3, 12).map(lambda d: (base_k + d) * step_ns)
    anywhere = st.integers(0, 2**31 - 1).map(lambda s: s * 1_000_000_000)
    off_grid = st.integers(1, step_ns - 1).map(lambda d: base_k * step_ns + d)
    return st.one_of(near, near, near, anywhere, off_grid).map(
        lambda ns: TimeMsg(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))
    )


def _vector(n: int):
    return st.one_of(
        st.lists(st.floats(-3.0, 3.0), min_size=n, max_size=n),
        st.lists(FLOATS, min_size=n, max_size=n),
        st.lists(FLOATS, min_size=0, max_size=n + 3),
    )


def _joint_state(node, names: list[str], stamp):
    nv = len(names)
    name_lists = st.one_of(
        st.just(names),
        st.permutations(names),
        st.lists(st.sampled_from([*names, "elbow", ""]), max_size=nv + 2),
    )

    def build(stamp, names_, position, velocity, effort) -> JointState:
        msg = JointState()
        msg.header.stamp = stamp
        msg.name = list(names_)
        msg.position, msg.velocity, msg.effort = position, velocity, effort
        return msg

    return st.builds(build, stamp, name_lists, _vector(nv), _vector(nv), _vector(nv))


def _wrench(stamp):
    def build(stamp, frame, values) -> WrenchStamped:
        msg = WrenchStamped()
        msg.header.stamp = stamp
        msg.header.frame_id = frame
        w = msg.wrench
        w.force.x, w.force.y, w.force.z, w.torque.x, w.torque.y, w.torque.z = values
        return msg

    frames = st.sampled_from([topics.WRENCH_FRAME, topics.WRENCH_FRAME, "world", ""])
    values = st.tuples(*[st.one_of(st.floats(-80.0, 80.0), FLOATS)] * 6)
    return st.builds(build, stamp, frames, values)


def _array(layout, node, stamp_ns):
    nv = getattr(getattr(node, "robot", None), "nv", 7)
    nx = getattr(getattr(node, "lowlevel", None), "nx", None) or getattr(
        getattr(node, "mpc", None), "nx", 2 * nv
    )

    def valid(t, body) -> list[float]:
        data = list(body[: layout.length(nv, nx)])
        data += [0.5] * (layout.length(nv, nx) - len(data))
        slices = layout.slices(nv, nx)
        data[slices["t"].start] = t
        for name, size in (("nv", nv), ("nx", nx)):
            if name in slices:
                data[slices[name].start] = float(size)
        return data

    def build(label, data, mutations) -> Float64MultiArray:
        msg = Float64MultiArray(data=[0.0])
        msg.layout.dim = [MultiArrayDimension(label=label, size=len(data), stride=len(data))]
        for i, value in mutations:
            if data:
                data[i % len(data)] = value
        msg.data = data
        return msg

    t = st.sampled_from([1e-9 * stamp_ns]) | st.floats(0.0, 1e4) | ADVERSARIAL
    bodies = st.lists(st.floats(-2.0, 2.0), min_size=0, max_size=layout.length(nv, nx))
    data = st.one_of(st.builds(valid, t, bodies), st.lists(FLOATS, max_size=400))
    labels = st.sampled_from([layout.label, layout.label, "ffmpc/other/1", ""])
    mutations = st.lists(st.tuples(st.integers(0, 10_000), FLOATS), max_size=3)
    return st.builds(build, labels, data, mutations)


def _command(node, stamp):
    """An MpcCommand drawn over its whole type: any version, formulation, names, sizes."""
    nv, nx = _robot(node).nv, _nx(node)
    names = node_joint_names(node)

    def build(stamp, version, formulation, names_, ff, q, v, effort, force, shape, gain):
        msg = MpcCommand()
        msg.header.stamp = stamp
        msg.version, msg.formulation, msg.joint_names = version, formulation, list(names_)
        msg.feedforward, msg.feedback_gain.data = ff, gain
        msg.feedback_gain.rows, msg.feedback_gain.cols = shape
        state = msg.initial_state
        state.position, state.velocity, state.effort, state.force = q, v, effort, force
        return msg

    return st.builds(
        build,
        stamp,
        st.sampled_from([MpcCommand.VERSION, MpcCommand.VERSION, 1, 255]),
        st.sampled_from(["classical", "torque_feedback", "force_feedback", "", "lqr"]),
        st.one_of(st.just([]), st.just(names), st.permutations(names), st.just(["j"] * nv)),
        _vector(nv),
        _vector(nv),
        _vector(nv),
        st.one_of(st.just([]), _vector(nv)),
        st.one_of(st.just([]), _vector(nx - 2 * nv if nx > 2 * nv else 1)),
        st.tuples(st.sampled_from([nv, nv - 1, 0, 2**32 - 1]), st.sampled_from([nx, nx + 1, 0])),
        st.one_of(_vector(nv * nx), st.lists(FLOATS, max_size=3)),
    )


def _message(sub, node, base_k: int):
    step_ns = node.step_ns
    stamp = _stamp(step_ns, base_k)
    if sub.msg_type is JointState:
        return _joint_state(node, list(node_joint_names(node)), stamp)
    if sub.msg_type is WrenchStamped:
        return _wrench(stamp)
    if sub.msg_type is Clock:
        return stamp.map(lambda s: Clock(clock=s))
    if sub.msg_type is Bool:
        return st.builds(Bool, data=st.booleans())
    if sub.msg_type is Float64MultiArray:
        return _array(TOPIC_LAYOUTS[sub.topic_name], node, base_k * step_ns)
    if sub.msg_type is MpcCommand:
        return _command(node, stamp)
    if sub.msg_type is PoseStamped:
        frames = st.sampled_from([topics.WORLD_FRAME, topics.WORLD_FRAME, "", "base_link"])
        return st.builds(_pose, stamp, frames, st.tuples(*[FLOATS] * 3))
    if sub.msg_type is Float64:
        return st.builds(Float64, data=st.one_of(st.floats(0.0, 100.0), FLOATS))
    raise AssertionError(f"no strategy for {sub.msg_type} on {sub.topic_name}")


def _pose(stamp, frame: str, position) -> PoseStamped:
    msg = PoseStamped()
    msg.header.stamp = stamp
    msg.header.frame_id = frame
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = map(float, position)
    msg.pose.orientation.w = 1.0
    return msg


def node_joint_names(node) -> list[str]:
    if hasattr(node, "joint_names"):
        return list(node.joint_names)
    return list(load_robot(node.scenario.robot).joint_names)


# -- checks -----------------------------------------------------------------------------------
def _numbers(msg) -> list[float]:
    if isinstance(msg, JointState):
        return [*msg.position, *msg.velocity, *msg.effort]
    if isinstance(msg, WrenchStamped):
        f, m = msg.wrench.force, msg.wrench.torque
        return [f.x, f.y, f.z, m.x, m.y, m.z]
    if isinstance(msg, TwistStamped):
        lin, ang = msg.twist.linear, msg.twist.angular
        return [lin.x, lin.y, lin.z, ang.x, ang.y, ang.z]
    if isinstance(msg, Float64MultiArray):
        return list(msg.data)
    if isinstance(msg, MpcCommand):
        state = msg.initial_state
        arrays = (msg.feedforward, msg.feedback_gain.data, state.position, state.velocity)
        return [msg.kkt, *[x for a in (*arrays, state.effort, state.force) for x in a]]
    return []


def _check(published: list, limits: np.ndarray) -> None:
    for topic, msg in published:
        values = np.asarray(_numbers(msg), dtype=float)
        assert np.all(np.isfinite(values)), f"{topic} published a non-finite value: {msg}"
        if topic in TORQUE_TOPICS:
            assert np.all(np.abs(values[-len(limits) :]) <= limits), f"{topic}: {msg.effort}"
        if topic == topics.resolve(topics.MPC_COMMAND):
            torque = command_fields(msg, len(limits))["torque"]
            assert np.all(np.abs(torque) <= limits), f"{topic}: {torque}"


def _valid(sub, node, k: int, data) -> object:
    """A plausible message of cycle k for ``sub`` (values drawn small and finite)."""
    stamp = node.grid.stamp_of(k)
    small = st.floats(-0.05, 0.05)
    if sub.msg_type is JointState:
        names = node_joint_names(node)
        robot = _robot(node)
        msg = JointState()
        msg.header.stamp = stamp
        msg.name = names
        noise = np.array(data.draw(st.lists(small, min_size=len(names), max_size=len(names))))
        msg.position = (robot.q_nominal + noise).tolist()
        msg.velocity = (10 * noise).tolist()
        msg.effort = (robot.gravity(robot.q_nominal) + 100 * noise).tolist()
        return msg
    if sub.msg_type is WrenchStamped:
        msg = WrenchStamped()
        msg.header.stamp = stamp
        msg.header.frame_id = topics.WRENCH_FRAME
        msg.wrench.force.x, msg.wrench.force.y = data.draw(small), data.draw(small)
        msg.wrench.force.z = data.draw(st.floats(0.0, 60.0))  # pressing (λ_z > 0)
        return msg
    if sub.msg_type is Bool:
        return Bool(data=data.draw(st.booleans()))
    if sub.msg_type is PoseStamped:  # the MPC's target, within 5 cm of the task's
        target = node.nominal_target + [data.draw(small) for _ in range(3)]
        return _pose(stamp, topics.WORLD_FRAME, target)
    if sub.msg_type is Float64:  # the MPC's force set-point, N
        return Float64(data=data.draw(st.floats(0.0, 60.0)))
    if sub.msg_type is MpcCommand:
        robot, nx = _robot(node), _nx(node)
        state = np.full(nx, data.draw(small))
        state[: robot.nv] = robot.q_nominal
        solution = SimpleNamespace(
            torque=robot.gravity(robot.q_nominal) + data.draw(small),
            state=state,
            feedback_gain=np.full((robot.nv, nx), data.draw(small)),
            iterations=1,
            kkt=0.0,
            solve_time=0.0,
            converged=True,
        )
        formulation = node.scenario.mpc.ocp.formulation
        return command_message(stamp, formulation, robot.joint_names, k // 2, solution)
    layout = TOPIC_LAYOUTS[sub.topic_name]
    nv = _robot(node).nv
    nx = _nx(node)
    values = {f.name: np.full(f.length(nv, nx), data.draw(small)) for f in layout.fields}
    values["t"] = k * node.time_step
    for name, value in (("nv", nv), ("nx", nx), ("samples", 100.0), ("stiffness", 3000.0)):
        if name in values:
            values[name] = value
    if "direction" in values:
        values["direction"] = np.array([0.0, 0.0, -1.0])
    if "damping" in values:
        values["damping"] = 20.0
    for name in ("stiffness_std", "damping_std", "noise_std"):
        if name in values:
            values[name] = abs(values[name]) + 1e-3
    if "state" in values:
        values["state"][:nv] = _robot(node).q_nominal
    return layout.pack(values, nv, nx)


def _corrupt(msg, data):
    """``msg`` with one number replaced by an adversarial value (or its stamp moved)."""
    if isinstance(msg, Float64MultiArray) and msg.data:
        values = list(msg.data)
        values[data.draw(st.integers(0, len(values) - 1))] = data.draw(ADVERSARIAL)
        msg.data = values
    elif isinstance(msg, JointState):
        field = data.draw(st.sampled_from(["position", "velocity", "effort"]))
        values = list(getattr(msg, field))
        values[data.draw(st.integers(0, len(values) - 1))] = data.draw(ADVERSARIAL)
        setattr(msg, field, values)
    elif isinstance(msg, WrenchStamped):
        setattr(msg.wrench.force, data.draw(st.sampled_from("xyz")), data.draw(ADVERSARIAL))
    elif isinstance(msg, PoseStamped):
        setattr(msg.pose.position, data.draw(st.sampled_from("xyz")), data.draw(ADVERSARIAL))
    elif isinstance(msg, Float64):
        msg.data = data.draw(ADVERSARIAL)
    elif isinstance(msg, MpcCommand):
        owner, field = data.draw(
            st.sampled_from(
                [
                    (msg, "feedforward"),
                    (msg.feedback_gain, "data"),
                    (msg.initial_state, "position"),
                    (msg.initial_state, "velocity"),
                ]
            )
        )
        values = list(getattr(owner, field))
        values[data.draw(st.integers(0, len(values) - 1))] = data.draw(ADVERSARIAL)
        setattr(owner, field, values)
    if hasattr(msg, "header") and data.draw(st.booleans()):
        msg.header.stamp = data.draw(_stamp(1_000_000, 0))
    return msg


def _robot(node):
    robot = getattr(node, "robot", None)
    return robot if robot is not None else load_robot(node.scenario.robot)


def _nx(node) -> int:
    lowlevel = getattr(node, "lowlevel", None)
    if lowlevel is not None:
        return lowlevel.nx
    mpc = getattr(node, "mpc", None)
    return mpc.nx if mpc is not None else 2 * _robot(node).nv


@pytest.mark.parametrize("case", list(_nodes()))
def test_no_message_crashes_a_node_or_makes_it_unsafe(case, ros):
    cls, spec, scenario, graph = _nodes()[case]
    node = ros.add(cls(context=ros.context, parameter_overrides=overrides(spec, scenario, **graph)))
    limits = load_robot(scenario.robot).torque_limit * (1 + 1e-12)
    published: list = []
    counts: dict[str, int] = {}
    for pub in node.publishers:
        topic = pub.topic_name

        def record(msg, topic=topic, original=pub.publish):
            published.append((topic, msg))
            counts[topic] = counts.get(topic, 0) + 1
            original(msg)

        pub.publish = record
    if hasattr(node, "_try_start"):
        node._try_start()  # the plant publishes its first state
    subs = [s for s in node.subscriptions if s.topic_name != topics.CLOCK]
    clock = next(s for s in node.subscriptions if s.topic_name == topics.CLOCK)
    assert subs, case
    base = {"k": 0}

    @settings(
        max_examples=EXAMPLES,
        derandomize=True,
        deadline=None,
        database=None,
        suppress_health_check=list(HealthCheck),
    )
    @given(data=st.data())
    def feed(data):
        base["k"] += 1000  # one second later: earlier inputs are now stale, not newer
        for i in range(data.draw(st.integers(1, 10), label="cycles")):
            # the plant checks torques against its own cycle; the others follow /clock
            k = getattr(node, "k", None) if case == "plant" else base["k"] + i
            clock.callback(Clock(clock=node.grid.stamp_of(k)))
            for sub in subs:
                how = data.draw(st.sampled_from(HOW), label="how")
                if how == "skip":
                    continue
                if how == "random":
                    msg = data.draw(_message(sub, node, k), label=sub.topic_name)
                else:
                    msg = _valid(sub, node, k, data)
                    if how == "corrupt":
                        msg = _corrupt(msg, data)
                sub.callback(msg)  # no exception may escape
            if data.draw(st.integers(0, 19), label="jump") == 0:
                clock.callback(data.draw(_message(clock, node, k), label="clock"))
        _check(published, limits)
        published.clear()

    feed()
    assert node.rejected.total() > 0  # the fuzz did reach the input checks
    assert counts.keys() >= set(OUTPUTS[case]), counts  # ... and the nodes' outputs
