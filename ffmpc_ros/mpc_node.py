"""The MPC node: one of the three OCP formulations (parameter ``formulation``) in receding horizon.

Subscribes ``/joint_sensor/joint_states`` (q̂, q̇̂, τ̂) and, for force-feedback,
``/ft_sensor/wrench`` (λ̂); publishes ``/mpc/command`` (layout ``mpc_command``, ffmpc_ros.layouts)
and, after the command and only while something subscribes, ``/mpc/prediction`` (layout
``mpc_prediction``: the horizon's contact positions and normal forces, for the live view).

It solves at the ticks k = j·``period / time_step`` (as the ROS-free runner does), once it has
the measurements OF cycle k (joint state, and the wrench with the same stamp for force-
feedback). In real time (``lockstep: false``) it solves the newest complete tick (a tick that
arrives while a solve runs is skipped): the node warms up (``WARM_UP_SOLVES`` solves, then
``reset``) before it subscribes, and runs without an executor (``spin_realtime``: a wait set
over its inputs, newest sample taken). The command carries the measurement's time t_k; the
solver's wall time is reported but never used for control.

Learned contact (force-feedback only; parameter ``use_learned_contact``, default off, so the
polishing graph is unchanged): the node also subscribes ``/contact_learner/estimate`` (layout
``contact_estimate``) and, for every estimate that is confident (``learner_min_samples``,
``learner_max_relative_std``: both standard errors at most that fraction of the value), sets the
OCP's contact stiffness K (N/m) and damping B (N·s/m) live (``set_contact_parameters``) for the
next solve. The estimate is along the learner's motion direction: it replaces the normal-axis
entry of K and B (``contact.normal_axis``; the only one of a 1-D contact), and with a
LOCAL_WORLD_ALIGNED contact an estimate whose direction is not ±that axis is rejected. Each
accepted update is logged (at most one line per 2 s). Estimates are not synchronised with the
lockstep cycle: one applies from the first solve after its arrival.
"""

from __future__ import annotations

import contextlib
import gc

import numpy as np
from geometry_msgs.msg import WrenchStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from ffmpc_core.errors import ConfigError, FfmpcError
from ffmpc_core.impact.learner import confident
from ffmpc_core.mpc import ModelPredictiveController, MpcMeasurement
from ffmpc_core.robots import load_robot
from ffmpc_core.study import build_task, measured_force, mpc_config, steps_per_mpc_period
from ffmpc_ros import layouts, topics
from ffmpc_ros.base import StudyNode, drop_stale_cycles, run_node
from ffmpc_ros.impact_common import DIRECTION_TOLERANCE, receive_estimate

_KEEP = 20  # cycles of unmatched measurements kept
WARM_UP_SOLVES = 20  # real time: solves before the node subscribes to its inputs


class MpcNode(StudyNode):
    """ModelPredictiveController on topics (see the module docstring)."""

    def __init__(self, **kwargs) -> None:
        super().__init__("mpc", **kwargs)
        s = self.scenario
        self.robot = load_robot(s.robot)
        self.joint_names = list(self.robot.joint_names)
        self.config = mpc_config(s)
        self.mpc = ModelPredictiveController(self.robot, self.config, build_task(s, self.robot))
        self.every = steps_per_mpc_period(s)
        self.needs_force = self.config.formulation == "force_feedback"
        self._joints: dict[int, tuple] = {}
        self._forces: dict[int, object] = {}
        self._last_solve: int | None = None
        self.sequence = 0
        self.solve_times: list[float] = []
        self._diagnosed_solves = (0, 0)  # (solves, failed solves) at the last report
        self.lockstep = bool(self.params["lockstep"])
        if not self.lockstep:
            self.warm_up()
        self.publisher = self.create_publisher(
            Float64MultiArray, topics.MPC_COMMAND, topics.publisher_qos()
        )
        self.prediction_publisher = self.create_publisher(
            Float64MultiArray, topics.MPC_PREDICTION, topics.publisher_qos()
        )
        qos = topics.subscriber_qos(self.lockstep)
        self.inputs = [
            self.create_subscription(JointState, topics.SENSED_JOINT_STATES, self.on_joints, qos)
        ]
        if self.needs_force:
            self.inputs.append(
                self.create_subscription(WrenchStamped, topics.SENSED_WRENCH, self.on_wrench, qos)
            )
        self.use_learned_contact = bool(self.params["use_learned_contact"])
        self.learner_min_samples = int(self.params["learner_min_samples"])
        self.learner_max_relative_std = float(self.params["learner_max_relative_std"])
        self.contact_updates = 0
        if self.use_learned_contact:
            if not self.needs_force:
                raise ConfigError("use_learned_contact needs the force_feedback formulation")
            contact = self.config.contact
            self.contact_stiffness = contact.stiffness_vector().copy()  # N/m, per force entry
            self.contact_damping = contact.damping_vector().copy()  # N·s/m
            self._learned_entry = 0 if contact.dimension == 1 else contact.normal_axis
            self.estimates = self.create_subscription(
                Float64MultiArray,
                topics.CONTACT_ESTIMATE,
                self.on_estimate,
                topics.subscriber_qos(False),
            )

    def on_joints(self, msg: JointState) -> None:
        topic = self.name_of(topics.SENSED_JOINT_STATES)
        got = self.receive(topic, msg, self.joint_fields("position", "velocity", "effort"))
        if got is None:
            return
        k, arrays = got
        self._joints[k] = tuple(arrays)
        self._try_solve(k)

    def on_wrench(self, msg: WrenchStamped) -> None:
        topic = self.name_of(topics.SENSED_WRENCH)
        got = self.receive(
            topic, msg, lambda m: measured_force(self.wrench_array(m), self.config.contact)
        )
        if got is None:
            return
        k, force = got
        self._forces[k] = force
        self._try_solve(k)

    def on_estimate(self, msg: Float64MultiArray) -> None:
        """A learner estimate: applied to the OCP's contact model when confident."""
        topic = self.name_of(topics.CONTACT_ESTIMATE)
        got = receive_estimate(self, msg)
        if got is None:
            return
        k, estimate, direction = got
        contact = self.config.contact
        if contact.frame_type == "LOCAL_WORLD_ALIGNED":
            along = abs(float(direction[contact.normal_axis]))
            if along < 1.0 - DIRECTION_TOLERANCE:
                self.reject(
                    f"{topic}:direction",
                    f"estimate along {direction}, the contact model's axis is "
                    f"{contact.normal_axis}",
                )
                return
        self.accept_cycle(topic, k)
        if not confident(estimate, self.learner_min_samples, self.learner_max_relative_std):
            return
        stiffness, damping = self.contact_stiffness.copy(), self.contact_damping.copy()
        stiffness[self._learned_entry] = estimate.stiffness
        damping[self._learned_entry] = estimate.damping
        try:
            self.mpc.set_contact_parameters(stiffness, damping)
        except FfmpcError as exc:
            self.reject(f"{topic}:value", str(exc))
            return
        self.contact_stiffness, self.contact_damping = stiffness, damping
        self.contact_updates += 1
        self.inform(
            "contact_update",
            f"contact model from the learner: stiffness {estimate.stiffness:.1f} N/m, damping "
            f"{estimate.damping:.2f} N·s/m ({estimate.samples} samples, update "
            f"{self.contact_updates})",
        )

    def _due(self, k: int) -> bool:
        """Whether cycle k is an MPC tick to solve: k = j·every (the runner's grid, and the
        cycles the PID waits on in lockstep), after the last solve. Never off the grid: after
        an outage (a process frozen and resumed) a solve on the first cycle that completes
        would shift every later command by a cycle from the ticks the PID waits for (measured:
        each PID tick then timed out, the commands acted a cycle late, and the wrist went to
        8× its velocity limit)."""
        return k % self.every == 0 and (self._last_solve is None or k > self._last_solve)

    def _behind_clock(self, k: int) -> bool:
        """Lockstep: whether tick k is already more than one MPC period behind this node's
        clock (the plant's newest cycle), and is skipped (counted as ``solve:late``).

        In a lockstep run the plant never passes a tick before the PID has its command, so an
        on-time tick is never behind; a tick that is behind comes from a backlog (a process
        frozen and resumed finds the sensor messages queued meanwhile). Its command would reach
        the PID after the PID went on without it, and solving it would hide the outage from the
        controller: the task's clock pauses for the time between two solves
        (``ModelPredictiveController.step``), so the next solve must be the first live tick."""
        if not self.lockstep:
            return False
        behind = self.get_clock().now().nanoseconds - k * self.step_ns
        if behind > self.every * self.step_ns:
            self.reject("solve:late", f"tick {k} is {behind * 1e-9:.4f} s behind the clock")
            return True
        return False

    # -- real time ----------------------------------------------------------------------------
    def warm_up(self, solves: int = WARM_UP_SOLVES) -> None:
        """Real time: solve a few times from the start posture (t = 0), then forget it all
        (``reset``): the first real solve then runs warm code, not a cold start."""
        nv = self.robot.nv
        q = self.robot.q_nominal
        meas = MpcMeasurement(
            q=q.copy(),
            v=np.zeros(nv),
            force=np.zeros(self.config.contact.dimension) if self.needs_force else None,
            torque=self.robot.gravity(q),
        )
        for _ in range(solves):
            self.mpc.reset()
            self.mpc.step(meas, 0.0)
        self.mpc.reset()

    def _is_tick(self, stamp) -> bool:
        """Real time: whether a stamp is an MPC tick (other cycles are not parsed at all)."""
        k = self.cycle_of(stamp)
        return k is None or k % self.every == 0  # (off-grid stamps: rejected by the handler)

    def spin_realtime(self) -> None:
        """Real time, instead of an executor: block on a wait set over the inputs, take the
        newest sample of each topic (older ones are worthless) and solve when it completes a
        tick; until the context shuts down (SIGINT). The collector is frozen and disabled.
        /clock is taken first at every wake-up (the newest sample): the node judges its inputs'
        stamps against it like every node (stale, or from the future and never adopted)."""
        from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

        gc.collect()
        gc.freeze()
        gc.disable()
        # (subscription, handler, only on MPC ticks): measurements, then the learner's estimate
        clock_topic = self.resolve_topic_name(topics.CLOCK)  # remapped: /arm1/clock
        clock = [s for s in self.subscriptions if s.topic_name == clock_topic]
        inputs = [(sub, sub.callback, False) for sub in clock]
        inputs += [
            (sub, handler, True)
            for sub, handler in zip(self.inputs, (self.on_joints, self.on_wrench), strict=False)
        ]
        if self.use_learned_contact:
            inputs.append((self.estimates, self.on_estimate, False))
        with contextlib.ExitStack() as stack:
            for sub, _, _ in inputs:
                stack.enter_context(sub.handle)
            stack.enter_context(self.context.handle)
            wait_set = _rclpy.WaitSet(len(inputs), 0, 0, 0, 0, 0, self.context.handle)
            while self.context.ok():
                wait_set.clear_entities()
                for sub, _, _ in inputs:
                    wait_set.add_subscription(sub.handle)
                try:
                    wait_set.wait(100_000_000)  # ns
                except Exception:  # noqa: BLE001  (the context shut down while waiting)
                    break
                for sub, handler, ticks_only in inputs:
                    newest = None
                    while (taken := sub.handle.take_message(sub.msg_type, sub.raw)) is not None:
                        newest = taken[0]
                    if newest is None or (ticks_only and not self._is_tick(newest.header.stamp)):
                        continue
                    handler(newest)
        gc.enable()

    def _try_solve(self, k: int) -> None:
        drop_stale_cycles((self._joints, self._forces), k, _KEEP)
        if not self._due(k) or k not in self._joints:
            return
        if self.needs_force and k not in self._forces:
            return
        q, v, tau = self._joints.pop(k)
        force = self._forces.pop(k, None)
        if self._behind_clock(k):
            return
        t = self.t_of(k)
        try:
            command = self.mpc.step(MpcMeasurement(q=q, v=v, force=force, torque=tau), t)
        except FfmpcError as exc:
            self.reject("solve", f"cycle {k}: {exc}")
            return
        self._last_solve = k
        self.solve_times.append(command.solve_time)
        nv = self.robot.nv
        self.publisher.publish(
            layouts.MPC_COMMAND.pack(
                {
                    "t": t,
                    "nv": nv,
                    "nx": self.mpc.nx,
                    "sequence": self.sequence,
                    "iterations": command.iterations,
                    "kkt": command.kkt,
                    "solve_time": command.solve_time,
                    "converged": float(command.converged),
                    "torque": command.torque,
                    "state": command.state,
                    "feedback_gain": command.feedback_gain,
                },
                nv,
                self.mpc.nx,
            )
        )
        self.sequence += 1
        if self.prediction_publisher.get_subscription_count() > 0:
            self.publish_prediction(t)

    def publish_prediction(self, t: float) -> None:
        """``/mpc/prediction`` of the last solve (t: its time, s), after the command."""
        positions, forces, references = self.mpc.prediction()
        contact = self.config.contact
        column = 0 if contact.dimension == 1 else contact.normal_axis
        self.prediction_publisher.publish(
            layouts.MPC_PREDICTION.pack(
                {
                    "t": t,
                    "nodes": positions.shape[0],
                    "dt": self.config.dt,
                    "normal_axis": contact.normal_axis,
                    "normal_force": forces[:, column],
                    "reference_force": references[:, column],
                    "positions": positions,
                },
                nodes=positions.shape[0],
            )
        )

    def diagnostic_values(self, period: float) -> dict[str, str]:
        """Solves over the period: rate (Hz, wall), median and max solve time (ms, wall)."""
        new = self.solve_times[self._diagnosed_solves[0] :]
        values = {"solves": str(len(self.solve_times)), "solve_rate_hz": f"{len(new) / period:.1f}"}
        if new:
            values["solve_time_p50_ms"] = f"{1e3 * float(np.median(new)):.3f}"
            values["solve_time_max_ms"] = f"{1e3 * max(new):.3f}"
        return values

    def diagnostic_problems(self) -> list[str]:
        """Solves that failed since the previous report (their ticks got no command)."""
        failed = self.rejected["solve"] - self._diagnosed_solves[1]
        self._diagnosed_solves = (len(self.solve_times), self.rejected["solve"])
        return [f"{failed} solves failed"] if failed else []


def main(argv=None) -> int:
    return run_node(MpcNode, __doc__.splitlines()[0], argv)


if __name__ == "__main__":
    raise SystemExit(main())
