"""``mpc/command`` as ``ffmpc_msgs/msg/MpcCommand`` (``msg/MpcCommand.msg``): the one place that
builds the message from an MPC solution and reads it back.

The message is modelled on ``linear_feedback_controller_msgs/Control``: the torque to send now
(``feedforward``, N·m), the Riccati feedback gain G (``feedback_gain``, nv × nx row-major) and the
state x0 the solve started from (``initial_state``: q, v and the formulation's augmented part,
τ̂ for torque feedback or λ̂ for force feedback), so that ``feedforward + G·(x − x0)`` is the
locally optimal torque at a nearby state x. The header's stamp is t_k, the time of the
measurement the solve started from; its frame is the frame of λ̂ (:data:`topics.WRENCH_FRAME`).

:func:`command_fields` returns the same named fields as the retired array layout
``ffmpc/mpc_command/1`` did (``t``, ``nv``, ``nx``, ``sequence``, ``iterations``, ``kkt``,
``solve_time``, ``converged``, ``torque``, ``state``, ``feedback_gain``), plus ``stamp`` and
``formulation``; every receiver (PID node, real-time loop, bag tools) reads the command
through it, and a message of another :data:`VERSION` is refused with a clear error.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time as TimeMsg
from ffmpc_msgs.msg import LinearizationState, Matrix, MpcCommand

from ffmpc_core.errors import InputError
from ffmpc_ros import topics

#: The ROS type of ``mpc/command``.
TYPE_NAME = "ffmpc_msgs/msg/MpcCommand"
#: The definition version this code writes and reads (``MpcCommand.VERSION``); version 1 was
#: the ``std_msgs/Float64MultiArray`` layout ``ffmpc/mpc_command/1``.
VERSION = int(MpcCommand.VERSION)
#: The formulations and the augmented part of their state after (q, v).
FORMULATIONS = ("classical", "torque_feedback", "force_feedback")
#: Fields that carry wall-clock time (never reproducible).
WALL_TIME_FIELDS = ("solve_time",)


def command_message(
    stamp: TimeMsg,
    formulation: str,
    joint_names: Sequence[str],
    sequence: int,
    command: Any,
) -> MpcCommand:
    """The message of one MPC solution (``ffmpc_core.mpc.MpcCommand``: torque, state,
    feedback_gain, iterations, kkt, solve_time, converged) solved from the measurement
    stamped ``stamp``, for the joints ``joint_names`` (empty: unnamed, in the receiver's
    order); InputError when the sizes do not fit the formulation."""
    if formulation not in FORMULATIONS:
        raise InputError(f"unknown formulation {formulation!r} (one of {FORMULATIONS})")
    torque = np.asarray(command.torque, dtype=float).reshape(-1)
    nv = torque.size
    state = np.asarray(command.state, dtype=float).reshape(-1)
    gain = np.asarray(command.feedback_gain, dtype=float)
    augmented = state.size - 2 * nv
    if (joint_names and len(joint_names) != nv) or augmented < 0 or gain.shape != (nv, state.size):
        raise InputError(
            f"an MPC command of {torque.size} torques, a state of {state.size} and a gain of "
            f"shape {gain.shape} for {nv} joints"
        )
    msg = MpcCommand()
    msg.header.stamp = stamp
    msg.header.frame_id = topics.WRENCH_FRAME
    msg.version = VERSION
    msg.formulation = formulation
    msg.joint_names = list(joint_names)
    msg.sequence = int(sequence)
    msg.iterations = int(command.iterations)
    msg.kkt = float(command.kkt)
    msg.solve_time = float(command.solve_time)
    msg.converged = bool(command.converged)
    msg.feedforward = torque
    msg.feedback_gain = Matrix(rows=nv, cols=state.size, data=gain.reshape(-1))
    extra = state[2 * nv :]
    msg.initial_state = LinearizationState(
        position=state[:nv],
        velocity=state[nv : 2 * nv],
        effort=extra if formulation == "torque_feedback" else np.empty(0),
        force=extra if formulation == "force_feedback" else np.empty(0),
    )
    return msg


def _augmented_size(formulation: str, nv: int, effort: int, force: int) -> str | None:
    """Why the augmented part (effort, force sizes) does not fit the formulation, or None."""
    expected = {
        "classical": effort == 0 and force == 0,
        "torque_feedback": effort == nv and force == 0,
        "force_feedback": effort == 0 and force in (1, 3),
    }[formulation]
    if expected:
        return None
    return f"{formulation} state with {effort} efforts and {force} forces"


def command_fields(msg: Any, nv: int, joint_names: Sequence[str] | None = None) -> dict[str, Any]:
    """The named fields of an ``mpc/command`` message for a robot of ``nv`` joints (and, when
    given and the message names its joints, those names in that order). InputError on another
    version, an unknown formulation, wrong sizes, a non-finite value or other joints."""
    if not isinstance(msg, MpcCommand):
        raise InputError(f"expected an {TYPE_NAME}, got {type(msg).__name__}")
    if msg.version != VERSION:
        raise InputError(f"{TYPE_NAME} version {msg.version}; this code reads version {VERSION}")
    if msg.formulation not in FORMULATIONS:
        raise InputError(f"unknown formulation {msg.formulation!r} (one of {FORMULATIONS})")
    names = list(msg.joint_names)
    if names and joint_names is not None and names != list(joint_names):
        raise InputError(f"command for joints {names}; this robot has {list(joint_names)}")
    state_msg = msg.initial_state
    torque = np.asarray(msg.feedforward, dtype=float)
    q = np.asarray(state_msg.position, dtype=float)
    v = np.asarray(state_msg.velocity, dtype=float)
    effort = np.asarray(state_msg.effort, dtype=float)
    force = np.asarray(state_msg.force, dtype=float)
    if torque.size != nv or q.size != nv or v.size != nv or (names and len(names) != nv):
        raise InputError(
            f"command for {torque.size} torques, {q.size} positions, {v.size} velocities, "
            f"{len(names)} names; this robot has nv={nv}"
        )
    problem = _augmented_size(msg.formulation, nv, effort.size, force.size)
    if problem is not None:
        raise InputError(f"{TYPE_NAME}: {problem}")
    state = np.concatenate((q, v, effort, force))
    gain = msg.feedback_gain
    data = np.asarray(gain.data, dtype=float)
    if gain.rows != nv or gain.cols != state.size or data.size != gain.rows * gain.cols:
        raise InputError(
            f"feedback gain {gain.rows}x{gain.cols} with {data.size} elements; expected "
            f"{nv}x{state.size}"
        )
    scalars = (msg.kkt, msg.solve_time)
    if not (np.all(np.isfinite(state)) and np.all(np.isfinite(torque))):
        raise InputError(f"{TYPE_NAME}: non-finite torque or state")
    if not (np.all(np.isfinite(data)) and np.all(np.isfinite(scalars))):
        raise InputError(f"{TYPE_NAME}: non-finite gain, kkt or solve time")
    stamp = msg.header.stamp
    return {
        "stamp": stamp,
        "t": (stamp.sec * 1_000_000_000 + stamp.nanosec) / 1e9,
        "formulation": msg.formulation,
        "nv": nv,
        "nx": state.size,
        "sequence": msg.sequence,
        "iterations": msg.iterations,
        "kkt": msg.kkt,
        "solve_time": msg.solve_time,
        "converged": msg.converged,
        "torque": torque,
        "state": state,
        "feedback_gain": data.reshape(nv, state.size),
    }
