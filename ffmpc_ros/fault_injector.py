"""Fault injection in the node graph (``ffmpc run --fault KIND@T[+DURATION]``).

The bring-up itself injects the faults, at the simulated time it sees on ``/plant/joint_states``
(the plant's state of cycle k, stamped t_k): nothing is added to the nodes' normal path. Because
the bring-up hears t_k a little after the plant published it, a fault starts at the first cycle
the bring-up sees at or after its start time; the cycle actually seen is reported
(``injected_at``, ``ended_at``). Where each kind acts:

* ``mpc-dropout`` — SIGSTOP of the MPC process at the start, SIGCONT at the end (multi-process
  only). The PID goes on without the command after ``lockstep_timeout`` (lowered to
  :data:`FAULT_LOCKSTEP_TIMEOUT` wall s in runs with a process fault, so a long dropout does not
  take minutes) and falls back to the safe hold.
* ``sensor-dropout`` — SIGSTOP/SIGCONT of the F/T-sensor process (multi-process only): no new
  measured wrench reaches the MPC and the PID. The joint sensor cannot drop out in lockstep: the
  plant steps on the torque computed from its measurement, so simulated time would stop.
* ``future-stamp`` — every cycle seen in the window, one JointState on
  ``/joint_sensor/joint_states`` and one WrenchStamped on ``/ft_sensor/wrench`` stamped
  ``FUTURE_STAMP_AHEAD`` s ahead, with the last genuine values: every node must reject them
  (``rejected_messages``: ``…:future``); one adopted would make every later genuine message look
  old (``…:order``) and stop the graph.
* ``nan-wrench`` — every cycle seen in the window, a WrenchStamped full of NaN stamped with the
  cycle seen (rejected as ``…:value``, or ``…:order`` when the genuine one came first).
* ``torque-spike`` — every cycle seen in the window, the last genuine joint measurement with
  every effort set to ``value`` (1e9 N·m), stamped with the cycle seen: when it arrives before
  the genuine one, the controllers read τ̂ = 1e9; the motor torque stays saturated to the limits.
* ``node-kill`` — SIGKILL of the named node's process (multi-process only); the run goes on, the
  PID holds the robot, and the node is reported as killed on purpose.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from builtin_interfaces.msg import Time as TimeMsg
from geometry_msgs.msg import WrenchStamped
from rclpy.node import Node
from sensor_msgs.msg import JointState

from ffmpc_core.faults import FUTURE_STAMP_AHEAD, REALTIME_KINDS, Fault, require_kinds
from ffmpc_ros import topics
from ffmpc_ros.base import stamp_at

#: Kinds injected by acting on a node's process (multi-process lockstep only).
PROCESS_KINDS = ("mpc-dropout", "sensor-dropout", "node-kill")
#: Kinds injected as messages on sensor topics.
MESSAGE_KINDS = ("future-stamp", "nan-wrench", "torque-spike")
#: lockstep_timeout of the PID in runs with a process fault, wall s. It applies to the whole
#: run (the parameter is fixed at start): an MPC solve slower than this outside a fault window
#: also lets the PID go on without its command (counted in rejected_messages pid "lockstep").
#: 0.05 s was measured too short on the loaded 2-core machine (1366 skips for 250 dropped
#: ticks, a non-deterministic run); 0.2 s costs 0.2 s wall per dropped MPC tick.
FAULT_LOCKSTEP_TIMEOUT = 0.2
#: The process SIGSTOPped by each dropout kind.
_STOPPED = {"mpc-dropout": "mpc", "sensor-dropout": "ft_sensor"}


def check_supported(faults: Sequence[Fault], single_process: bool, lockstep: bool) -> None:
    """ConfigError (one line) for a fault the mode cannot inject."""
    if not faults:
        return
    if not lockstep:
        require_kinds(faults, REALTIME_KINDS, "real time (--fault-window marks external faults)")
    elif single_process:
        require_kinds(faults, MESSAGE_KINDS, "--single-process (no process to stop or kill)")
    else:
        require_kinds(faults, (*PROCESS_KINDS, *MESSAGE_KINDS), "lockstep")


@dataclass
class _Applied:
    fault: Fault
    injected_at: float | None = None
    ended_at: float | None = None
    messages: int = 0
    detail: str = ""


@dataclass
class FaultInjector:
    """Applies ``faults`` as the plant's cycles are seen (module docstring).

    Args:
        node: the bring-up's node (publishers are created on it).
        faults: what to inject.
        processes: node name → child process (multi-process; empty in single process).
        time_step: plant cycle, s.
    """

    node: Node
    faults: Sequence[Fault]
    processes: Mapping[str, subprocess.Popen]
    time_step: float
    killed: set[str] = field(default_factory=set)

    def __post_init__(self) -> None:
        self.applied = [_Applied(f) for f in self.faults]
        kinds = {f.kind for f in self.faults}
        # it stands in for the sensor nodes: their QoS in the graph (reliable, lockstep)
        self._pub_joints = (
            self.node.create_publisher(
                JointState,
                topics.SENSED_JOINT_STATES,
                topics.graph_qos(topics.SENSED_JOINT_STATES, "publisher"),
            )
            if kinds & {"future-stamp", "torque-spike"}
            else None
        )
        self._pub_wrench = (
            self.node.create_publisher(
                WrenchStamped,
                topics.SENSED_WRENCH,
                topics.graph_qos(topics.SENSED_WRENCH, "publisher"),
            )
            if kinds & {"future-stamp", "nan-wrench"}
            else None
        )
        self.last_joints: JointState | None = None
        self.last_wrench: WrenchStamped | None = None
        self._stopped: set[str] = set()

    @property
    def wants_sensors(self) -> bool:
        """Whether the genuine sensor messages must be fed (:meth:`on_sensed_joints`...)."""
        return self._pub_joints is not None

    # -- the genuine messages the injected ones copy ------------------------------------------
    def on_sensed_joints(self, msg: JointState) -> None:
        self.last_joints = msg

    def on_sensed_wrench(self, msg: WrenchStamped) -> None:
        self.last_wrench = msg

    def _stamp(self, k: int) -> TimeMsg:
        """The stamp of cycle k on the nodes' grid (``TimeGrid.stamp_of``: k·step_ns)."""
        return stamp_at(k, int(round(self.time_step * 1e9)))

    # -- the clock ------------------------------------------------------------------------------
    def on_cycle(self, k: int) -> None:
        """Cycle k of the plant was seen: start, continue or end every fault."""
        t = k * self.time_step
        for a in self.applied:
            f = a.fault
            if a.ended_at is not None or t < f.start - 1e-9:
                continue
            if a.injected_at is None:
                a.injected_at = t
                self._start(a)
            if t >= f.end - 1e-9:
                a.ended_at = t
                self._end(a)
                continue
            self._during(a, k)

    def _signal(self, name: str, sig: int) -> bool:
        proc = self.processes.get(name)
        if proc is None or proc.poll() is not None:
            return False
        os.kill(proc.pid, sig)
        return True

    def _start(self, a: _Applied) -> None:
        f = a.fault
        if f.kind in _STOPPED:
            name = _STOPPED[f.kind]
            if self._signal(name, signal.SIGSTOP):
                self._stopped.add(name)
                a.detail = f"SIGSTOP {name} (pid {self.processes[name].pid})"
        elif f.kind == "node-kill":
            node = f.node
            assert node is not None  # Fault names the default node of a node-kill
            self.killed.add(node)
            if self._signal(node, signal.SIGKILL):
                a.detail = f"SIGKILL {node} (pid {self.processes[node].pid})"
            a.ended_at = a.injected_at

    def _end(self, a: _Applied) -> None:
        name = _STOPPED.get(a.fault.kind)
        if name is not None and name in self._stopped:
            self._signal(name, signal.SIGCONT)
            self._stopped.discard(name)
            a.detail += f", SIGCONT at {a.ended_at:.3f} s"

    def _during(self, a: _Applied, k: int) -> None:
        kind = a.fault.kind
        # (__post_init__ made the publishers these kinds use)
        pub_joints, pub_wrench = self._pub_joints, self._pub_wrench
        if kind == "future-stamp":
            ahead = k + int(round(FUTURE_STAMP_AHEAD / self.time_step))
            if self.last_joints is not None and pub_joints is not None:
                msg = self.last_joints
                msg.header.stamp = self._stamp(ahead)
                pub_joints.publish(msg)
                a.messages += 1
            if self.last_wrench is not None and pub_wrench is not None:
                msg = self.last_wrench
                msg.header.stamp = self._stamp(ahead)
                pub_wrench.publish(msg)
                a.messages += 1
        elif kind == "nan-wrench" and pub_wrench is not None:
            msg = WrenchStamped()
            msg.header.stamp = self._stamp(k)
            msg.header.frame_id = topics.WRENCH_FRAME
            w = msg.wrench
            w.force.x = w.force.y = w.force.z = math.nan
            w.torque.x = w.torque.y = w.torque.z = math.nan
            pub_wrench.publish(msg)
            a.messages += 1
        elif kind == "torque-spike" and self.last_joints is not None and pub_joints is not None:
            msg = self.last_joints
            msg.header.stamp = self._stamp(k)
            msg.effort = [float(a.fault.value)] * len(msg.name)
            pub_joints.publish(msg)
            a.messages += 1

    def release(self) -> None:
        """SIGCONT every process still stopped (the run is ending)."""
        for name in list(self._stopped):
            self._signal(name, signal.SIGCONT)
        self._stopped.clear()

    def report(self) -> list[dict]:
        """What was injected and when (``faults`` of the run's summary)."""
        return [
            {
                "fault": str(a.fault),
                "kind": a.fault.kind,
                "node": a.fault.node,
                "start_s": a.fault.start,
                "end_s": None if math.isinf(a.fault.end) else a.fault.end,
                "injected_at_s": a.injected_at,
                "ended_at_s": a.ended_at,
                "messages_injected": a.messages,
                "action": a.detail,
            }
            for a in self.applied
        ]
