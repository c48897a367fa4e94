"""``linear_feedback_controller_msgs`` (Control, Sensor) ↔ ffmpc's MPC data: the one place that
builds and reads them.

Upstream's conventions (linear-feedback-controller-msgs 1.2.2, ``eigen_conversions.hpp`` and
``numpy_conversions.py``; linear-feedback-controller 4.0.3, ``lf_controller.cpp``), kept here:

* a matrix in a ``std_msgs/Float64MultiArray``: ``layout.dim = [rows, cols]`` with
  ``dim[0] = ("rows", size r, stride r·c)``, ``dim[1] = ("cols", size c, stride c)``,
  ``data_offset`` 0, row-major (element (i, j) is ``data[c·i + j]``); a vector is an r × 1 matrix
  (two dims too: upstream's reader asserts exactly two);
* ``Control.feedforward``: τ_ff, N·m, one row per actuated joint; ``Control.feedback_gain``: K,
  nu × 2·nv, columns (dq, dv) in the model's tangent order; ``Control.initial_state``: the
  ``Sensor`` x₀ = (q₀, v₀) the MPC solved from (``joint_state`` with the joint names — the
  controller ignores a Control whose ``initial_state.joint_state.name`` is empty);
* the law τ = τ_ff + K·(x₀ ⊖ x) (``ffmpc_core.linear_feedback``). ffmpc's MPC command carries
  G with ``torque + G·(x − x0)``, so K = −G on the (q, v) columns;
* ``Sensor``: ``joint_state`` (names, q rad, v rad/s, τ̂ N·m, in the controller's joint order)
  stamped with the state's time; ``base_pose``/``base_twist`` unused on a fixed base (left at
  their defaults); ``contacts`` unused by the controller.

What ``Control`` cannot carry: the MPC's augmented state columns. For the torque-feedback (τ) and
force-feedback (λ) formulations, K holds the (q, v) columns of the gain only; x₀'s augmented part
travels for the record (τ₀ in ``initial_state.joint_state.effort``, λ₀ as the force of
``initial_state.contacts[0]``, frame :data:`topics.WRENCH_FRAME`, the header's frame_id) and a
receiver of ffmpc's (the PID node) reads it back with zero gain columns.

Joint order: K's columns and the feed-forward follow the robot model's joint order; a Control
must name exactly those joints in that order (upstream maps the joint_state arrays through its
``moving_joint_names``; on a serial arm they are the same). A Sensor's joints may come in any
order (like a JointState).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time as TimeMsg
from linear_feedback_controller_msgs.msg import Contact, Control, Sensor
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from ffmpc_core.errors import InputError
from ffmpc_ros import topics
from ffmpc_ros.command_msg import FORMULATIONS

#: The ROS types.
CONTROL_TYPE = "linear_feedback_controller_msgs/msg/Control"
SENSOR_TYPE = "linear_feedback_controller_msgs/msg/Sensor"
#: The name of the contact that carries λ₀ in ``Control.initial_state.contacts``.
CONTACT_NAME = "contact"


def matrix_message(matrix: np.ndarray) -> Float64MultiArray:
    """A matrix (2-D) or a vector (1-D: r × 1) in upstream's Float64MultiArray layout."""
    arr = np.asarray(matrix, dtype=float)
    if arr.ndim == 1:
        arr = arr.reshape(-1, 1)
    if arr.ndim != 2:
        raise InputError(f"a matrix message needs a 1-D or 2-D array, got {arr.ndim}-D")
    rows, cols = arr.shape
    msg = Float64MultiArray()
    msg.layout.data_offset = 0
    msg.layout.dim = [
        MultiArrayDimension(label="rows", size=rows, stride=rows * cols),
        MultiArrayDimension(label="cols", size=cols, stride=cols),
    ]
    msg.data = arr.reshape(-1)
    return msg


def matrix_from_message(msg: Float64MultiArray, name: str, shape: tuple[int, int]) -> np.ndarray:
    """The ``shape`` matrix of an upstream-layout Float64MultiArray; InputError naming ``name``
    for another layout, size or a non-finite value."""
    dims = list(msg.layout.dim)
    if len(dims) != 2:
        raise InputError(f"{name}: {len(dims)} layout dims, expected 2 (rows, cols)")
    rows, cols = int(dims[0].size), int(dims[1].size)
    if (rows, cols) != shape:
        raise InputError(f"{name} is {rows}×{cols}, expected {shape[0]}×{shape[1]}")
    row_stride, offset = int(dims[1].stride), int(msg.layout.data_offset)
    data = np.asarray(msg.data, dtype=float)
    if row_stride < cols or offset < 0 or data.size < offset + row_stride * (rows - 1) + cols:
        raise InputError(
            f"{name}: {data.size} values for {rows}×{cols} (offset {offset}, row stride "
            f"{row_stride})"
        )
    index = offset + row_stride * np.arange(rows)[:, None] + np.arange(cols)[None, :]
    out = data[index]
    if not np.all(np.isfinite(out)):
        raise InputError(f"{name} is not finite")
    return out


def sensor_message(
    stamp: TimeMsg,
    joint_names: Sequence[str],
    q: np.ndarray,
    v: np.ndarray,
    effort: np.ndarray | None,
) -> Sensor:
    """A ``Sensor`` of one cycle (fixed base): q rad, v rad/s, effort N·m (None: empty)."""
    msg = Sensor()
    msg.header.stamp = stamp
    js = msg.joint_state
    js.header.stamp = stamp
    js.name = list(joint_names)
    js.position = np.asarray(q, dtype=float).tolist()
    js.velocity = np.asarray(v, dtype=float).tolist()
    js.effort = [] if effort is None else np.asarray(effort, dtype=float).tolist()
    return msg


def effort_message(effort: np.ndarray) -> Float64MultiArray:
    """A forward_command_controller command (``<controller>/commands``): one effort per
    configured joint, N·m, in the controller's joint order; no layout (the controller reads only
    ``data``, as ``ros2 topic pub`` sends it)."""
    msg = Float64MultiArray()
    msg.data = np.asarray(effort, dtype=float)
    return msg


def control_message(
    stamp: TimeMsg,
    formulation: str,
    joint_names: Sequence[str],
    command: Any,
    force_axes: Sequence[int] = (2,),
) -> Control:
    """The ``Control`` of one MPC solution (``ffmpc_core.mpc.MpcCommand``: torque, state x0,
    feedback_gain G) solved from the state stamped ``stamp``: τ_ff = torque, K = −G[:, :2nv],
    initial_state = x0 (augmented part for the record, module docstring; ``force_axes``: the
    world axes of a force-feedback λ₀). InputError when the sizes do not fit."""
    if formulation not in FORMULATIONS:
        raise InputError(f"unknown formulation {formulation!r} (one of {FORMULATIONS})")
    torque = np.asarray(command.torque, dtype=float).reshape(-1)
    nv = torque.size
    state = np.asarray(command.state, dtype=float).reshape(-1)
    gain = np.asarray(command.feedback_gain, dtype=float)
    if len(joint_names) != nv or state.size < 2 * nv or gain.shape != (nv, state.size):
        raise InputError(
            f"an MPC command of {nv} torques, a state of {state.size} and a gain of shape "
            f"{gain.shape} for {len(joint_names)} joints"
        )
    extra = state[2 * nv :]
    effort = extra if formulation == "torque_feedback" else None
    msg = Control()
    msg.header.stamp = stamp
    msg.header.frame_id = topics.WRENCH_FRAME
    msg.feedforward = matrix_message(torque)
    msg.feedback_gain = matrix_message(-gain[:, : 2 * nv])
    msg.initial_state = sensor_message(stamp, joint_names, state[:nv], state[nv : 2 * nv], effort)
    if formulation == "force_feedback":
        if len(force_axes) != extra.size:
            raise InputError(f"λ₀ has {extra.size} entries for the axes {list(force_axes)}")
        contact = Contact(active=True, name=CONTACT_NAME)
        force = [0.0, 0.0, 0.0]
        for axis, value in zip(force_axes, extra, strict=True):
            force[axis] = float(value)
        contact.wrench.force.x, contact.wrench.force.y, contact.wrench.force.z = force
        msg.initial_state.contacts = [contact]
    return msg


def control_fields(
    msg: Any,
    joint_names: Sequence[str],
    nq: int | None = None,
    force_axes: Sequence[int] = (2,),
) -> dict[str, Any]:
    """The arrays of a ``Control`` for a robot with ``joint_names`` (nv joints, nq configuration
    entries; default nv): ``stamp``, ``t`` (s), ``feedforward`` (nv), ``feedback_gain`` K
    (nv × 2nv), ``q0`` (nq), ``v0`` (nv), and what x₀ carries beyond (q, v): ``effort0`` (τ₀,
    N·m, or empty) and ``force0`` (λ₀ on ``force_axes``, N, or empty). InputError on another
    type, other joints or order, wrong sizes or layout, non-finite values."""
    if not isinstance(msg, Control):
        raise InputError(f"expected a {CONTROL_TYPE}, got {type(msg).__name__}")
    nv = len(joint_names)
    nq = nv if nq is None else nq
    js = msg.initial_state.joint_state
    names = list(js.name)
    if names != list(joint_names):
        raise InputError(
            f"Control.initial_state names joints {names}; this robot's are {list(joint_names)} "
            "in that order (K's columns follow it)"
        )
    q0 = np.asarray(js.position, dtype=float)
    v0 = np.asarray(js.velocity, dtype=float)
    effort0 = np.asarray(js.effort, dtype=float)
    if q0.shape != (nq,) or v0.shape != (nv,) or effort0.size not in (0, nv):
        raise InputError(
            f"initial_state has {q0.size} positions, {v0.size} velocities, {effort0.size} "
            f"efforts; this robot has nq={nq}, nv={nv}"
        )
    if not (np.all(np.isfinite(q0)) and np.all(np.isfinite(v0)) and np.all(np.isfinite(effort0))):
        raise InputError("Control.initial_state is not finite")
    force0 = np.empty(0)
    contacts = [c for c in msg.initial_state.contacts if c.name == CONTACT_NAME]
    if contacts:
        f = contacts[0].wrench.force
        force0 = np.array([f.x, f.y, f.z], dtype=float)[list(force_axes)]
        if not np.all(np.isfinite(force0)):
            raise InputError("Control.initial_state contact force is not finite")
    stamp = msg.header.stamp
    return {
        "stamp": stamp,
        "t": (stamp.sec * 1_000_000_000 + stamp.nanosec) / 1e9,
        "feedforward": matrix_from_message(msg.feedforward, "feedforward", (nv, 1)).reshape(-1),
        "feedback_gain": matrix_from_message(msg.feedback_gain, "feedback_gain", (nv, 2 * nv)),
        "q0": q0,
        "v0": v0,
        "effort0": effort0,
        "force0": force0,
    }


def low_level_command(fields: dict[str, Any], formulation: str, nx: int) -> dict[str, Any]:
    """``torque``, ``state`` and ``feedback_gain`` G (nv × nx) of ffmpc's low level from the
    fields of a Control (:func:`control_fields`): G = −K on the (q, v) columns, zero on the
    augmented ones (Control has none), x₀'s augmented part from τ₀ or λ₀ when the Control
    carries it, else zeros (multiplied by zero columns). InputError when it does not fit nx."""
    nv = fields["v0"].size
    extra = nx - 2 * nv
    carried = {"torque_feedback": fields["effort0"], "force_feedback": fields["force0"]}
    augmented = carried.get(formulation, np.empty(0))
    if extra < 0 or augmented.size not in (0, extra):
        raise InputError(f"a Control for nv={nv} does not fit a state of {nx}")
    if augmented.size == 0:
        augmented = np.zeros(extra)
    gain = np.zeros((nv, nx))
    gain[:, : 2 * nv] = -fields["feedback_gain"]
    return {
        "torque": fields["feedforward"],
        "state": np.concatenate((fields["q0"], fields["v0"], augmented)),
        "feedback_gain": gain,
    }


def sensor_fields(msg: Any) -> Any:
    """The ``sensor_msgs/JointState`` of a ``Sensor`` (its joint_state, stamped with the
    Sensor's header: upstream stamps the header) for the JointState parsers of the nodes;
    InputError for another type."""
    if not isinstance(msg, Sensor):
        raise InputError(f"expected a {SENSOR_TYPE}, got {type(msg).__name__}")
    js = msg.joint_state
    js.header.stamp = msg.header.stamp
    return js
