"""linear_feedback_controller_msgs: the generated package's type hashes equal upstream's, and the
conversions between ffmpc's MPC output and Control/Sensor (data, gains, state order, layout)
hold upstream's conventions, so that the agimus linear_feedback_controller's law applied to a
Control gives ffmpc's own τ* + G·(x − x0).

The expected hashes were computed from UPSTREAM's files, not from this project's copies: the
three .msg files of linear-feedback-controller-msgs at tag v1.2.2 (commit ef4bd47b,
github.com/loco-3d/linear-feedback-controller-msgs; ``main`` serves Humble to Rolling, and no
field changed since the ROS 2 port 1.0.0) were converted with Jazzy's rosidl (the wheels'
rosidl_adapter 4.6.6 ``convert_msg_to_idl``, then rosidl_generator_type_description 4.6.6
``generate_type_hash`` with the dependencies' descriptions from the ros-jazzy common_interfaces
5.3.6 wheels' share/). The same procedure, run on upstream geometry2 0.36.4's TFMessage and
TF2Error, gives the Jazzy golden hashes test_state_publisher.py holds, and on std_msgs' Header
and Float64MultiArray the hashes of the Jazzy wheels' own share/std_msgs JSON: so these are the
hashes a Jazzy build of upstream's package has. No buildfarm binary of the package was at hand
to read them from.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pinocchio as pin
import pytest
from builtin_interfaces.msg import Time
from linear_feedback_controller_msgs.msg import Contact, Control, Sensor
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from ffmpc_core.errors import InputError
from ffmpc_core.linear_feedback import (
    LinearFeedbackCommand,
    linear_feedback_torque,
    state_difference,
)
from ffmpc_core.robots import load_robot
from ffmpc_ros import lfc_msgs, topics

#: RIHS01 hashes of linear_feedback_controller_msgs 1.2.2 in ROS 2 Jazzy (module docstring).
UPSTREAM_HASHES = {
    "msg/Contact": "RIHS01_a63418bb7eb83a425287e44cf82fc0c2cf5d117b1bc02666c054e13dfb7f04cc",
    "msg/Control": "RIHS01_0eb28542a3e916cafc368183c6dc1a743dbd01bf72eb4dff901a723d2c7fed1f",
    "msg/Sensor": "RIHS01_7469b3066c03e0520c5a2e930ee9e4a181c017502bb041f3cda1a12917b53448",
}
NV = 7


def test_generated_package_has_upstream_type_hashes():
    share = Path(sys.prefix) / "share" / "linear_feedback_controller_msgs"
    for name, expected in UPSTREAM_HASHES.items():
        found = json.loads((share / f"{name}.json").read_text())["type_hashes"][0]["hash_string"]
        assert found == expected, name
    # the package's name, as a ROS type name and as the Python package
    assert Control.__module__.startswith("linear_feedback_controller_msgs.msg")
    assert Sensor().joint_state.name == [] and Contact().active is False


def test_publishers_advertise_the_upstream_hash(ros):
    """What another ROS 2 node sees on the wire: the type hash in the graph's discovery data."""
    probe = ros.probe("hash_probe")
    probe.create_publisher(Control, "lfc_hash/control", 1)
    probe.create_publisher(Sensor, "lfc_hash/sensor", 1)
    for topic, name in (("/lfc_hash/control", "msg/Control"), ("/lfc_hash/sensor", "msg/Sensor")):
        assert ros.spin_until(lambda t=topic: probe.get_publishers_info_by_topic(t), 5.0)
        (info,) = probe.get_publishers_info_by_topic(topic)
        assert info.topic_type == f"linear_feedback_controller_msgs/{name}"
        assert str(info.topic_type_hash) == UPSTREAM_HASHES[name]


# -- the matrix layout -----------------------------------------------------------------------
def test_matrix_message_has_upstream_layout_and_reads_back():
    m = np.arange(6.0).reshape(2, 3)
    msg = lfc_msgs.matrix_message(m)
    dims = [(d.label, d.size, d.stride) for d in msg.layout.dim]
    assert dims == [("rows", 2, 6), ("cols", 3, 3)] and msg.layout.data_offset == 0
    assert list(msg.data) == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]  # row-major
    np.testing.assert_array_equal(lfc_msgs.matrix_from_message(msg, "m", (2, 3)), m)
    vec = lfc_msgs.matrix_message(np.array([1.0, 2.0, 3.0]))  # a vector is r × 1
    assert [(d.size, d.stride) for d in vec.layout.dim] == [(3, 3), (1, 1)]


def test_matrix_reader_follows_offset_and_row_stride():
    """A general layout (offset 1, rows padded to 4): element (i, j) is data[1 + 4i + j]."""
    msg = Float64MultiArray()
    msg.layout.data_offset = 1
    msg.layout.dim = [
        MultiArrayDimension(label="rows", size=2, stride=8),
        MultiArrayDimension(label="cols", size=3, stride=4),
    ]
    msg.data = [9.0, 1.0, 2.0, 3.0, 9.0, 4.0, 5.0, 6.0, 9.0]
    np.testing.assert_array_equal(
        lfc_msgs.matrix_from_message(msg, "m", (2, 3)), [[1, 2, 3], [4, 5, 6]]
    )


@pytest.mark.parametrize(
    "mutate, match",
    [
        (lambda m: m.layout.dim.pop(), "1 layout dims"),
        (lambda m: setattr(m.layout.dim[0], "size", 3), r"3×3, expected 2×3"),
        (lambda m: setattr(m, "data", [0.0] * 5), "5 values"),
        (lambda m: m.data.__setitem__(4, float("nan")), "not finite"),
    ],
)
def test_matrix_reader_refuses_bad_layouts(mutate, match):
    msg = lfc_msgs.matrix_message(np.ones((2, 3)))
    mutate(msg)
    with pytest.raises(InputError, match=match):
        lfc_msgs.matrix_from_message(msg, "m", (2, 3))


# -- Control ↔ the MPC's command ---------------------------------------------------------------
def _solution(formulation: str, rng: np.random.Generator):
    extra = {"classical": 0, "torque_feedback": NV, "force_feedback": 1}[formulation]
    nx = 2 * NV + extra
    return SimpleNamespace(
        torque=rng.normal(0.0, 10.0, NV),
        state=rng.normal(0.0, 0.5, nx),
        feedback_gain=rng.normal(0.0, 30.0, (NV, nx)),
    )


@pytest.mark.parametrize("formulation", ["classical", "torque_feedback", "force_feedback"])
def test_control_carries_feedforward_gain_and_initial_state(formulation):
    rng = np.random.default_rng(3)
    names = [f"j{i}" for i in range(1, NV + 1)]
    sol = _solution(formulation, rng)
    stamp = Time(sec=1, nanosec=234_000_000)
    msg = lfc_msgs.control_message(stamp, formulation, names, sol, force_axes=[2])
    assert isinstance(msg, Control) and msg.header.stamp == stamp
    assert msg.initial_state.header.stamp == stamp
    assert list(msg.initial_state.joint_state.name) == names  # never empty (upstream ignores it)
    fields = lfc_msgs.control_fields(msg, names)
    np.testing.assert_array_equal(fields["feedforward"], sol.torque)
    # K = −G on the (q, v) columns, in that order
    np.testing.assert_array_equal(fields["feedback_gain"], -sol.feedback_gain[:, : 2 * NV])
    np.testing.assert_array_equal(fields["q0"], sol.state[:NV])
    np.testing.assert_array_equal(fields["v0"], sol.state[NV : 2 * NV])
    if formulation == "torque_feedback":
        np.testing.assert_array_equal(fields["effort0"], sol.state[2 * NV :])
    else:
        assert fields["effort0"].size == 0
    if formulation == "force_feedback":
        (contact,) = msg.initial_state.contacts
        assert contact.active and contact.name == lfc_msgs.CONTACT_NAME
        assert contact.wrench.force.z == sol.state[-1] and contact.wrench.force.x == 0.0
        np.testing.assert_array_equal(fields["force0"], sol.state[2 * NV :])
    # back to ffmpc's low level: the same x0 in the same order, G with zero augmented columns
    nx = sol.state.size
    cmd = lfc_msgs.low_level_command(fields, formulation, nx)
    np.testing.assert_array_equal(cmd["state"], sol.state)
    np.testing.assert_array_equal(cmd["feedback_gain"][:, : 2 * NV], sol.feedback_gain[:, : 2 * NV])
    assert not cmd["feedback_gain"][:, 2 * NV :].any()
    np.testing.assert_array_equal(cmd["torque"], sol.torque)


def test_the_upstream_law_on_a_control_is_ffmpc_riccati_torque():
    """τ_ff + K·(x₀ ⊖ x) of the Control equals ffmpc's τ* + G·(x − x0) on the iiwa (a vector
    space: pin.difference(q, q₀) = q₀ − q), and pin.difference is what the law uses."""
    robot = load_robot("iiwa")
    rng = np.random.default_rng(7)
    sol = _solution("classical", rng)
    sol.state[:NV] = robot.q_nominal + rng.normal(0.0, 0.1, NV)
    names = list(robot.joint_names)
    fields = lfc_msgs.control_fields(
        lfc_msgs.control_message(Time(), "classical", names, sol), names
    )
    command = LinearFeedbackCommand(
        fields["feedforward"], fields["feedback_gain"], fields["q0"], fields["v0"]
    )
    q = sol.state[:NV] + rng.normal(0.0, 0.05, NV)
    v = sol.state[NV:] + rng.normal(0.0, 0.2, NV)
    tau = linear_feedback_torque(robot.model, command, q, v)
    expected = sol.torque + sol.feedback_gain @ (np.concatenate((q, v)) - sol.state)
    np.testing.assert_allclose(tau, expected, rtol=1e-12, atol=1e-9)
    dx = state_difference(robot.model, q, v, command.q0, command.v0)
    np.testing.assert_allclose(dx[:NV], pin.difference(robot.model, q, command.q0))
    np.testing.assert_allclose(
        linear_feedback_torque(robot.model, command, *np.split(sol.state, 2)), sol.torque
    )


@pytest.mark.parametrize(
    "mutate, match",
    [
        (lambda m: m.initial_state.joint_state.name.reverse(), "in that order"),
        (lambda m: m.initial_state.joint_state.name.clear(), "names joints"),
        (lambda m: setattr(m.initial_state.joint_state, "velocity", [0.0] * 6), "6 velocities"),
        (lambda m: m.feedback_gain.layout.dim.pop(), "feedback_gain: 1 layout dims"),
        (lambda m: setattr(m, "feedforward", lfc_msgs.matrix_message(np.ones(6))), "6×1"),
        (lambda m: m.initial_state.joint_state.position.__setitem__(0, float("inf")), "finite"),
    ],
)
def test_control_reader_refuses_what_it_cannot_use(mutate, match):
    rng = np.random.default_rng(1)
    names = [f"j{i}" for i in range(NV)]
    msg = lfc_msgs.control_message(Time(), "classical", names, _solution("classical", rng))
    mutate(msg)
    with pytest.raises(InputError, match=match):
        lfc_msgs.control_fields(msg, names)


def test_sensor_carries_the_measured_state_stamped():
    names = [f"j{i}" for i in range(NV)]
    q, v, tau = np.arange(7.0), -np.arange(7.0), np.full(7, 2.5)
    stamp = Time(sec=0, nanosec=5_000_000)
    msg = lfc_msgs.sensor_message(stamp, names, q, v, tau)
    js = lfc_msgs.sensor_fields(msg)
    assert js.header.stamp == stamp and list(js.name) == names
    np.testing.assert_array_equal(js.position, q)
    np.testing.assert_array_equal(js.velocity, v)
    np.testing.assert_array_equal(js.effort, tau)
    assert msg.contacts == [] and topics.qos_class(topics.LFC_SENSOR) == topics.SENSOR
