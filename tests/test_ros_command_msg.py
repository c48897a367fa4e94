"""``mpc/command`` as ``ffmpc_msgs/msg/MpcCommand`` (generated with rosidl by the project's own
build): round trips, the fields every receiver reads, refusals, and the PID's torque from the
typed command equal to the one from the retired array layout on the same numbers."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from ffmpc_msgs.msg import LinearizationState, Matrix, MpcCommand
from rclpy.serialization import deserialize_message, serialize_message
from ros_helpers import joint_state, mpc_command, overrides, recorder
from sensor_msgs.msg import JointState

from ffmpc_core.errors import InputError
from ffmpc_core.lowlevel import LowLevelCommand, LowLevelMeasurement
from ffmpc_core.polishing import lowlevel_controller
from ffmpc_core.scenario import load_scenario
from ffmpc_ros import topics
from ffmpc_ros.bag.schema import MessageDefinitions
from ffmpc_ros.command_msg import TYPE_NAME, VERSION, command_fields, command_message
from ffmpc_ros.pid_node import PidNode

ROOT = Path(__file__).resolve().parents[1]


def _solution(rng: np.random.Generator, nv: int, nx: int) -> SimpleNamespace:
    """An MPC solution (ffmpc_core.mpc.MpcCommand's fields) drawn from rng."""
    return SimpleNamespace(
        torque=rng.normal(size=nv),
        state=rng.normal(size=nx),
        feedback_gain=rng.normal(size=(nv, nx)),
        iterations=3,
        kkt=1.5e-7,
        solve_time=4.2e-4,
        converged=True,
    )


@pytest.mark.parametrize(
    ("formulation", "nx"), [("classical", 14), ("torque_feedback", 21), ("force_feedback", 15)]
)
def test_command_fields_give_back_the_solution(robot, formulation, nx):
    rng = np.random.default_rng(nx)
    solution = _solution(rng, 7, nx)
    stamp = Time(sec=3, nanosec=4_000_000)
    msg = command_message(stamp, formulation, robot.joint_names, 11, solution)
    assert msg.version == MpcCommand.VERSION == VERSION == 2
    assert msg.header.frame_id == topics.WRENCH_FRAME and msg.formulation == formulation
    state = msg.initial_state
    augmented = {"classical": 0, "torque_feedback": 7, "force_feedback": 1}[formulation]
    assert (len(state.effort), len(state.force)) == (
        (augmented, 0) if formulation == "torque_feedback" else (0, augmented)
    )
    assert (msg.feedback_gain.rows, msg.feedback_gain.cols) == (7, nx)
    fields = command_fields(deserialize_message(serialize_message(msg), MpcCommand), 7)
    assert fields["t"] == 3.004 and fields["stamp"] == stamp
    assert (fields["nv"], fields["nx"], fields["sequence"], fields["iterations"]) == (7, nx, 11, 3)
    assert (fields["kkt"], fields["solve_time"], fields["converged"]) == (1.5e-7, 4.2e-4, True)
    np.testing.assert_array_equal(fields["torque"], solution.torque)
    np.testing.assert_array_equal(fields["state"], solution.state)
    np.testing.assert_array_equal(fields["feedback_gain"], solution.feedback_gain)


def test_bad_commands_are_refused_with_the_reason(robot):
    names = list(robot.joint_names)
    solution = _solution(np.random.default_rng(0), 7, 14)

    def message(**changes) -> MpcCommand:
        msg = command_message(Time(), "classical", names, 0, solution)
        for name, value in changes.items():
            setattr(msg, name, value)
        return msg

    command_fields(message(), 7, names)  # the valid one
    cases = {
        "version 1": message(version=1),
        "unknown formulation": message(formulation="lqr"),
        "this robot has": message(joint_names=names[::-1]),
        "6 torques": message(feedforward=solution.torque[:6]),
        "feedback gain 7x13": message(feedback_gain=Matrix(rows=7, cols=13, data=np.zeros(7 * 13))),
        "classical state with 0 efforts and 1 forces": message(
            initial_state=LinearizationState(
                position=solution.state[:7], velocity=solution.state[7:], force=[1.0]
            )
        ),
        "non-finite torque": message(feedforward=np.full(7, np.inf)),
        "non-finite gain": message(kkt=float("nan")),
    }
    for reason, msg in cases.items():
        with pytest.raises(InputError, match=reason):
            command_fields(msg, 7, names)
    with pytest.raises(InputError, match=f"expected an {TYPE_NAME}"):
        command_fields(JointState(), 7)
    with pytest.raises(InputError, match="for 6 joints|7 torques"):
        command_message(Time(), "classical", names[:6], 0, solution)


def test_the_message_travels_equal_through_a_topic(ros, robot):
    probe = ros.probe()
    got = recorder(probe, MpcCommand, topics.MPC_COMMAND)
    pub = probe.create_publisher(MpcCommand, topics.MPC_COMMAND, topics.publisher_qos())
    assert ros.spin_until(lambda: pub.get_subscription_count() > 0)
    rng = np.random.default_rng(5)
    sent = [
        command_message(Time(nanosec=2_000_000 * i), "force_feedback", robot.joint_names, i, s)
        for i, s in enumerate(_solution(rng, 7, 15) for _ in range(3))
    ]
    for msg in sent:
        pub.publish(msg)
    assert ros.spin_until(lambda: len(got) == 3)
    assert got == sent


def test_the_installed_definitions_are_msg_s():
    """The .msg files installed with the package (what the recorder writes into a bag's schema)
    are msg/'s, and the complete definition names every dependency rosbag2-style."""
    for name in ("MpcCommand", "LinearizationState", "Matrix"):
        installed = MessageDefinitions().text(f"ffmpc_msgs/msg/{name}")
        assert installed == (ROOT / "msg" / f"{name}.msg").read_text(encoding="utf-8")
    full = MessageDefinitions().full_text(TYPE_NAME)
    for dependency in ("ffmpc_msgs/Matrix", "ffmpc_msgs/LinearizationState", "std_msgs/Header"):
        assert f"MSG: {dependency}\n" in full


# -- the PID node: the typed command against the retired array layout ------------------------
#: ``ffmpc/mpc_command/1`` (retired): 8 scalars (t, nv, nx, sequence, iterations, kkt,
#: solve_time, converged), then torque (nv), state (nx), feedback_gain (nv × nx row-major).
def _legacy_array(t: float, solution: SimpleNamespace) -> np.ndarray:
    nv, nx = solution.feedback_gain.shape
    head = [t, nv, nx, 0, solution.iterations, solution.kkt, solution.solve_time, 1.0]
    return np.concatenate((head, solution.torque, solution.state, solution.feedback_gain.ravel()))


def _legacy_command(data: np.ndarray) -> LowLevelCommand:
    """The LowLevelCommand the PID node made of a version-1 array (its former unpacking)."""
    nv, nx = int(data[1]), int(data[2])
    torque, state = data[8 : 8 + nv], data[8 + nv : 8 + nv + nx]
    return LowLevelCommand(torque, state, data[8 + nv + nx :].reshape(nv, nx))


def test_pid_torque_from_the_typed_command_equals_the_array_layouts(ros, robot):
    """Torque feedback with the Riccati gain (τ* + G·(x̂ − x̂_solve), every entry of the state
    and the gain used): the PID node fed typed commands outputs, bit for bit, what the low-level
    controller outputs from the same numbers decoded from the old array layout."""
    scenario = load_scenario(
        "polishing", {"mpc.formulation": "torque_feedback", "mpc.riccati_feedback": True}
    )
    node = ros.add(PidNode(context=ros.context, parameter_overrides=overrides("pid", scenario)))
    probe = ros.probe()
    pub_j = probe.create_publisher(JointState, topics.SENSED_JOINT_STATES, topics.publisher_qos())
    pub_c = probe.create_publisher(MpcCommand, topics.MPC_COMMAND, topics.publisher_qos())
    desired = recorder(probe, JointState, topics.DESIRED_TORQUE)
    rng = np.random.default_rng(7)
    reference = lowlevel_controller(scenario, robot)
    gravity = robot.gravity(robot.q_nominal)
    for k in range(8):
        q = robot.q_nominal + 0.01 * rng.standard_normal(7)
        v, tau = 0.05 * rng.standard_normal(7), gravity + rng.standard_normal(7)
        if k % 2 == 0:
            solution = _solution(rng, 7, 21)
            solution.torque = gravity + rng.normal(0.0, 2.0, 7)
            solution.state = np.concatenate((q, v, tau)) + 0.01 * rng.standard_normal(21)
            solution.feedback_gain *= 0.5
            stamp = node.grid.stamp_of(k)
            pub_c.publish(command_message(stamp, "torque_feedback", [], k // 2, solution))
            reference.set_command(_legacy_command(_legacy_array(k * 1e-3, solution)), k * 1e-3)
        pub_j.publish(joint_state(node, k, q, v, tau))
        assert ros.spin_until(lambda k=k: len(desired) == k + 1)
        out = reference.step(LowLevelMeasurement(q, v, tau), k * 1e-3)
        np.testing.assert_array_equal(desired[k].effort, out.desired_torque)
    assert node.rejected.total() == 0


def test_a_typed_command_of_another_robot_is_refused_by_the_pid(ros, robot):
    scenario = load_scenario("polishing", {"mpc.formulation": "classical"})
    node = ros.add(PidNode(context=ros.context, parameter_overrides=overrides("pid", scenario)))
    probe = ros.probe()
    pub_c = probe.create_publisher(MpcCommand, topics.MPC_COMMAND, topics.publisher_qos())
    assert ros.spin_until(lambda: pub_c.get_subscription_count() > 0)
    pub_c.publish(mpc_command(0, np.zeros(7), names=list(robot.joint_names)))
    pub_c.publish(mpc_command(2, np.zeros(7), names=[f"panda_joint{i}" for i in range(1, 8)]))
    topic = topics.resolve(topics.MPC_COMMAND)
    assert ros.spin_until(lambda: node.rejected.total() == 1)
    assert node.rejected[f"{topic}:value"] == 1


def test_rerun_refuses_a_bag_recorded_with_the_array_layout(ros):
    """A bag from before the typed command (mpc/command as std_msgs/Float64MultiArray, version
    1) is refused by ``ffmpc bag rerun`` with the reason, never fed to a node that cannot take
    it (the real version-1 bag gives the same line: docs/explanation/ros.md, "Typed messages")."""
    from dataclasses import replace

    from ffmpc_ros.bag.reader import BagReader
    from ffmpc_ros.bag.rerun import RerunError, _check_types

    node = ros.add(PidNode(context=ros.context, parameter_overrides=overrides("pid")))
    name = topics.resolve(topics.MPC_COMMAND)
    with BagReader(ROOT / "bags" / "polishing_short.mcap") as bag:
        _check_types(bag, "pid", node, "", [name])  # the committed bag: version 2
        bag.topics[name] = replace(bag.topics[name], type="std_msgs/msg/Float64MultiArray")
        reason = "recorded as std_msgs/msg/Float64MultiArray; this pid node uses " + TYPE_NAME
        with pytest.raises(RerunError, match=reason):
            _check_types(bag, "pid", node, "", [name])
