"""Time-based task schedules: what each OCP node should track at a given time (paper VI-A3).

A schedule maps a time t (s, simulated) to a :class:`~ffmpc_core.config.NodeReference`. The MPC
asks it for every node of its horizon (t, t + Δt, …), so references and phase switches are
previewed. Schedules are pure functions of t: no clock, no state. ``reference(t, dimension)``
returns a new reference; ``reference_into(t, ref)`` writes the same values into a preallocated
one (:meth:`NodeReference.empty`), which is what the MPC does every step for every node.

Two tasks of the force-feedback paper:

* :class:`PolishingTask` (VI-A, VII-C): stand still, reach the table, ramp the normal force to
  50 N, draw a 14 cm-diameter circle at 3 rad/s (or 6 rad/s) while pushing, stop.
* :class:`ForceSquareTask` (VII-B, Experiment 1): press on the table and track a square-wave normal
  force reference. The paper's Fig. 4 is not in our copy of the text, so the levels and period are
  parameters (defaults: 20 N / 50 N, 2 s period); the figure's exact values are not claimed.

And one for the impact study (Dehio & Kheddar 2020, Sec. VI, after the contact):

* :class:`PressTask`: hold the tool where it touched and press with a constant force.

:class:`LiveTask` wraps any of them for the MPC: a position offset and a force set-point that
change while the task runs (live parameters, reference topics), blended in with a minimum jerk.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from ffmpc_core.config import NodeReference
from ffmpc_core.errors import ConfigError, InputError


def min_jerk(s: float) -> float:
    """Minimum-jerk blend 10s³ − 15s⁴ + 6s⁵ of a phase s clipped to [0, 1]."""
    s = min(max(s, 0.0), 1.0)
    return s * s * s * (10.0 + s * (-15.0 + 6.0 * s))


def min_jerk_integral(x: float) -> float:
    """∫₀ˣ of :func:`min_jerk`, 2.5x⁴ − 3x⁵ + x⁶, for x in [0, 1] (½ at 1)."""
    return x**4 * (2.5 - 3.0 * x + x * x)


@dataclass(frozen=True)
class PhaseWeights:
    """Per-phase scalars of the time-varying cost terms: c4 (end-effector position), c6 (force)."""

    free_ee_position: float = 1e3
    contact_ee_position: float = 1e3
    force: float = 1e-2


def _diag_of(ref: NodeReference) -> np.ndarray:
    """``ref.ee_position_diag``, which the tasks write in place; InputError when it is None."""
    if ref.ee_position_diag is None:
        raise InputError("the reference has no ee_position_diag: make it with NodeReference.empty")
    return ref.ee_position_diag


class _ApproachThenContact:
    """What the approach-then-contact tasks share: the tool stands still, reaches a point
    ``clearance`` above ``contact_position`` with a minimum-jerk path, touches the table under
    a light force (the touch phase), then the contact phases begin.

    The touch phase is the guarded move of the approach:
    the nodes are in contact from the end of the reach on, with the force reference
    ``touch_force`` for ``touch`` s, so the tool comes down onto the table under force control
    wherever the table is within ``clearance`` of the belief (a tilt unknown to the controller
    moves it), and the force ramp starts from a light contact, not from a free tool or from a
    tool already pressed into the table by the position cost. ``clearance`` = ``touch`` = 0
    is the paper's schedule (reach the believed table, switch, ramp from 0 N).

    A subclass provides ``start_position``, ``contact_position``, ``still``, ``reach``,
    ``clearance``, ``touch``, ``touch_force``, ``weights``, ``force(t)``, ``ee_position(t)``
    and ``_ee_z_weight_in_contact``.
    """

    _ee_z_weight_in_contact: float = 0.0

    if TYPE_CHECKING:  # declared for the type checker only: each subclass provides them
        start_position: np.ndarray
        contact_position: np.ndarray
        still: float
        reach: float
        clearance: float
        touch: float
        touch_force: float
        weights: PhaseWeights

        def force(self, t: float) -> float: ...

        def ee_position(self, t: float) -> np.ndarray: ...

    def _check_approach(self) -> None:
        """ConfigError for a negative duration, clearance or touch force."""
        for name in ("still", "reach", "touch", "clearance", "touch_force"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ConfigError(f"{name} must be finite and >= 0, got {value}")

    @property
    def contact_time(self) -> float:
        """Time at which the OCP switches to the contact model (the touch phase starts), s."""
        return self.still + self.reach

    @property
    def force_start(self) -> float:
        """Time at which the force ramp starts (the touch phase ends), s."""
        return self.contact_time + self.touch

    def approach_target(self) -> np.ndarray:
        """Where the reach ends: ``clearance`` above ``contact_position`` (world z), m."""
        target = np.array(self.contact_position, dtype=float)
        target[2] += self.clearance
        return target

    def approach_position(self, t: float) -> np.ndarray:
        """p̄(t) up to the contact time: at rest, then a minimum-jerk reach, m, world frame."""
        return self._approach_position_into(t, np.empty(3))

    def _approach_position_into(self, t: float, out: np.ndarray) -> np.ndarray:
        start = np.asarray(self.start_position, float)
        if t < self.still:
            out[:] = start
            return out
        if t >= self.contact_time:  # touch and contact: the believed table point
            out[:] = self.contact_position
            return out
        s = min_jerk((t - self.still) / max(self.reach, 1e-9))
        np.subtract(self.approach_target(), start, out=out)
        out *= s
        out += start
        return out

    def _ramped_force(self, t: float, level: float, ramp: float) -> float:
        """The force reference up to the force ramp's end, N: 0 before the contact time,
        ``touch_force`` during the touch phase, then a minimum-jerk ramp of ``ramp`` s from
        ``touch_force`` to ``level``."""
        if t < self.contact_time:
            return 0.0
        if t < self.force_start:
            return self.touch_force
        s = min_jerk((t - self.force_start) / max(ramp, 1e-9))
        return self.touch_force + (level - self.touch_force) * s

    def _ee_position_into(self, t: float, out: np.ndarray) -> np.ndarray:
        """p̄(t) written into ``out`` (3 entries), m, world frame; subclasses may override."""
        out[:] = self.ee_position(t)
        return out

    def in_contact(self, t: float) -> bool:
        return t >= self.contact_time

    def reference(self, t: float, dimension: int = 1) -> NodeReference:
        """The node reference at time t for a contact model with ``dimension`` force entries
        (1-D: the normal; 3-D (x, y, z): the z entry carries the normal force)."""
        return self.reference_into(t, NodeReference.empty(dimension))

    def reference_into(self, t: float, ref: NodeReference) -> NodeReference:
        """Write the node reference at time t into ``ref`` (from :meth:`NodeReference.empty`;
        its force size is the dimension) without allocating; returns ``ref``. ``posture`` is
        left as it is (these tasks do not set it)."""
        contact = self.in_contact(t)
        self._ee_position_into(t, ref.ee_position)
        ref.force[:] = 0.0
        ref.force[-1] = self.force(t)
        w = self.weights
        ref.ee_position_weight = w.contact_ee_position if contact else w.free_ee_position
        ref.force_weight = w.force if contact else 0.0
        ref.in_contact = contact
        diag = _diag_of(ref)
        diag[0] = diag[1] = 1.0
        diag[2] = self._ee_z_weight_in_contact if contact else 1.0
        return ref


@dataclass(frozen=True)
class PolishingTask(_ApproachThenContact):
    """The polishing task of the paper (VI-A, VII-C), phases with fixed durations (s).

    Attributes:
        start_position: contact-frame position at t = 0, m, world frame.
        contact_position: where the controller believes the table surface is under the tool, m,
            world frame (the table's real tilt is unknown to it); the circle starts here.
        normal_force: target normal force λ̄ during polishing, N (paper: 50 N).
        circle_radius: m (paper: 0.07 m, i.e. 14 cm diameter).
        angular_velocity: rad/s along the circle (paper: 3 rad/s; fast variant 6 rad/s).
        still, reach, touch, force_ramp, circle, stop: phase durations, s. ``circle`` defaults
            to two turns at the nominal angular velocity.
        clearance: the reach ends this far above ``contact_position``, m (world z).
        touch_force: the force reference of the touch phase, N (the ramp starts from it).
        circle_ramp: s over which the angular velocity rises from 0 to ``angular_velocity`` at
            the circle's start and falls back to 0 at its end (minimum jerk,
            :meth:`circle_angle`); 0, the paper's circle, steps it (the reference's tangential
            speed jumps 0 → ω·r at the start and back at the end).
        weights: per-phase c4 and c6.
        ee_z_weight_in_contact: activation of the z (normal) axis of the position cost while in
            contact; 0 leaves the normal direction to the force task (the paper's pure sliding).
    """

    start_position: np.ndarray
    contact_position: np.ndarray
    normal_force: float = 50.0
    circle_radius: float = 0.07
    angular_velocity: float = 3.0
    still: float = 0.1
    reach: float = 0.4
    force_ramp: float = 0.5
    circle: float = 4.0 * np.pi / 3.0
    stop: float = 0.3
    weights: PhaseWeights = PhaseWeights()
    ee_z_weight_in_contact: float = 0.0
    circle_ramp: float = 0.0
    clearance: float = 0.0
    touch: float = 0.0
    touch_force: float = 0.0

    @property
    def _ee_z_weight_in_contact(self) -> float:  # type: ignore[override]
        return self.ee_z_weight_in_contact

    def __post_init__(self) -> None:
        self._check_approach()
        for name in ("force_ramp", "circle", "stop"):
            if getattr(self, name) < 0:
                raise ConfigError(f"phase duration {name} must be >= 0")
        if self.circle_radius < 0 or self.normal_force < 0:
            raise ConfigError("circle_radius and normal_force must be >= 0")
        if not 0.0 <= 2.0 * self.circle_ramp <= self.circle:
            raise ConfigError(
                f"circle_ramp ({self.circle_ramp} s) must be >= 0 and fit twice in the circle "
                f"({self.circle} s)"
            )

    @property
    def circle_start(self) -> float:
        """Time the circle starts, s."""
        return self.force_start + self.force_ramp

    @property
    def circle_end(self) -> float:
        """Time the circle ends, s."""
        return self.circle_start + self.circle

    @property
    def duration(self) -> float:
        """Length of the whole task, s."""
        return self.circle_end + self.stop

    @classmethod
    def pressing(
        cls,
        position: np.ndarray,
        force_ramp: float = 0.3,
        circle: float = 0.0,
        stop: float = 0.5,
        force_weight: float = 3.0,
    ) -> PolishingTask:
        """Contact from t = 0 where the tool is (``position``, m, world): ramp the normal force
        in ``force_ramp`` s, circle for ``circle`` s, hold ``stop`` s. The closed loops on a
        formulation's own dynamics (tests, demo, benchmark) use it."""
        p = np.asarray(position, dtype=float)
        return cls(
            p,
            p,
            still=0.0,
            reach=0.0,
            force_ramp=force_ramp,
            circle=circle,
            stop=stop,
            weights=PhaseWeights(force=force_weight),
        )

    def circle_center(self) -> np.ndarray:
        """Centre of the circle, m, world frame: the circle starts at ``contact_position``."""
        return np.asarray(self.contact_position, float) - np.array([self.circle_radius, 0, 0])

    def ee_position(self, t: float) -> np.ndarray:
        """Desired contact-frame position p̄(t), m, world frame."""
        return self._ee_position_into(t, np.empty(3))

    def _ee_position_into(self, t: float, out: np.ndarray) -> np.ndarray:
        circle_start = self.circle_start
        if t < circle_start:
            return self._approach_position_into(t, out)
        angle = self.circle_angle(t - circle_start)
        r = self.circle_radius
        start = self.contact_position  # the circle starts here; its centre is r along −x
        out[0] = start[0] - r + r * math.cos(angle)
        out[1] = start[1] + r * math.sin(angle)
        out[2] = start[2]
        return out

    def circle_angle(self, elapsed: float) -> float:
        """Angle θ travelled along the circle ``elapsed`` s after its start, rad.

        Without ramp, θ = ω·τ (τ = elapsed, clipped to the circle). With ``circle_ramp`` T, the
        angular velocity is ω·s(τ/T) over the first T s and ω·s((C − τ)/T) over the last
        (s: the minimum jerk 10x³ − 15x⁴ + 6x⁵, C the circle's duration), so θ is its integral:
        ω·T·S(τ/T) at the start, ω·(τ − T/2) in between, ω·(C − T) − ω·T·S((C − τ)/T) at the
        end, with S = :func:`min_jerk_integral`; the whole circle is ω·(C − T)."""
        omega, duration, ramp = self.angular_velocity, self.circle, self.circle_ramp
        tau = min(max(elapsed, 0.0), duration)
        if ramp <= 0.0:
            return omega * tau
        if tau < ramp:
            return omega * ramp * min_jerk_integral(tau / ramp)
        if tau > duration - ramp:
            rest = min_jerk_integral((duration - tau) / ramp)
            return omega * (duration - ramp) - omega * ramp * rest
        return omega * (tau - 0.5 * ramp)

    def force(self, t: float) -> float:
        """Desired normal force λ̄(t), N (positive: the table pushes the tool up)."""
        return self._ramped_force(t, self.normal_force, self.force_ramp)

    def in_circle(self, t: np.ndarray) -> np.ndarray:
        """Mask of times inside the circle phase (where the paper's metrics are computed)."""
        t = np.asarray(t)
        return (t >= self.circle_start) & (t <= self.circle_end)


@dataclass(frozen=True)
class ForceSquareTask(_ApproachThenContact):
    """Experiment 1 (VII-B): hold the tool on the table and track a square normal-force signal.

    The tool reaches ``contact_position``, the force ramps to ``low_force``, then alternates
    between ``high_force`` and ``low_force`` every half ``period`` for ``cycles`` periods.
    """

    start_position: np.ndarray
    contact_position: np.ndarray
    low_force: float = 20.0
    high_force: float = 50.0
    period: float = 2.0
    cycles: int = 2
    still: float = 0.1
    reach: float = 0.4
    force_ramp: float = 0.5
    weights: PhaseWeights = PhaseWeights()
    clearance: float = 0.0
    touch: float = 0.0
    touch_force: float = 0.0

    def __post_init__(self) -> None:
        self._check_approach()

    @property
    def square_start(self) -> float:
        """Time the square signal starts, s."""
        return self.force_start + self.force_ramp

    @property
    def duration(self) -> float:
        """Length of the whole task, s."""
        return self.square_start + self.period * self.cycles

    def ee_position(self, t: float) -> np.ndarray:
        """Contact-frame position reference at t (s), m, world frame."""
        return self.approach_position(t)

    def _ee_position_into(self, t: float, out: np.ndarray) -> np.ndarray:
        return self._approach_position_into(t, out)

    def force(self, t: float) -> float:
        """Normal force reference at t (s), N: the ramp, then the square signal."""
        if t < self.square_start:
            return self._ramped_force(t, self.low_force, self.force_ramp)
        phase = ((t - self.square_start) % self.period) / self.period
        return self.high_force if phase < 0.5 else self.low_force

    def in_circle(self, t: np.ndarray) -> np.ndarray:
        """Mask of the evaluation window (the square signal), for the shared metrics code."""
        t = np.asarray(t)
        return (t >= self.square_start) & (t <= self.duration)


@dataclass(frozen=True)
class PressTask:
    """Press with a constant target force where the tool is (the impact study's handover).

    From the moment of contact on, every node is in contact, the end-effector position is held
    in the two directions tangent to the world z axis (``ee_position_diag`` = (1, 1, 0): the
    normal direction belongs to the force task) and the force reference is ``force``.

    Attributes:
        position: contact-frame position to hold, m, world frame (its z is not tracked).
        force: λ̄, N: the world-z component of the force on the tool (pressing down: > 0).
        weights: c4 (``contact_ee_position``) and c6 (``force``) of the nodes.
    """

    position: np.ndarray
    force: float = 60.0
    weights: PhaseWeights = PhaseWeights()

    def __post_init__(self) -> None:
        p = np.asarray(self.position, dtype=float)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise ConfigError("PressTask.position must be 3 finite numbers (m)")
        if not (np.isfinite(self.force) and self.force >= 0):
            raise ConfigError("PressTask.force must be finite and >= 0 (N)")

    def ee_position(self, t: float) -> np.ndarray:
        """The fixed contact-frame position, m, world frame."""
        return np.asarray(self.position, dtype=float).copy()

    def in_contact(self, t: float) -> bool:
        """Always in contact."""
        return True

    def reference(self, t: float, dimension: int = 1) -> NodeReference:
        """A new reference of a node at t (s); ``dimension``: force entries."""
        return self.reference_into(t, NodeReference.empty(dimension))

    def reference_into(self, t: float, ref: NodeReference) -> NodeReference:
        """Write the reference at t into ``ref`` (see :meth:`NodeReference.empty`); returns it."""
        ref.ee_position[:] = self.position
        ref.force[:] = 0.0
        ref.force[-1] = self.force
        ref.ee_position_weight = self.weights.contact_ee_position
        ref.force_weight = self.weights.force
        ref.in_contact = True
        _diag_of(ref)[:] = (1.0, 1.0, 0.0)
        return ref


@dataclass(frozen=True)
class GuardedApproach:
    """The guarded approach of a real cell: descend slowly until the force sensor feels the
    table, then start the contact phases (:class:`GuardedTask`).

    Attributes:
        speed: approach speed of the reference along the world −z after the reach, m/s.
        depth: the reference descends at most this far below the believed table, m (then it
            holds there: the contact never came, :meth:`GuardedTask.contact_missed`).
        contact_force: measured normal force λ̂ above which the contact is detected, N.
    """

    speed: float
    depth: float
    contact_force: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.speed) and self.speed > 0.0):
            raise ConfigError(f"the approach speed must be finite and > 0 m/s, got {self.speed}")
        if not (math.isfinite(self.depth) and self.depth >= 0.0):
            raise ConfigError(f"the approach depth must be finite and >= 0 m, got {self.depth}")
        if not (math.isfinite(self.contact_force) and self.contact_force > 0.0):
            raise ConfigError(
                f"the contact force threshold must be finite and > 0 N, got {self.contact_force}"
            )


class GuardedTask:
    """An approach-then-contact task (:class:`PolishingTask`, :class:`ForceSquareTask`) whose
    contact phases start when the contact is MEASURED, not at a fixed time.

    Until the contact is detected every node is out of contact (the OCP's free-space model):
    the wrapped task's stand-still and reach, then, from its ``contact_time`` on, a descent of
    the reference along the world −z at ``approach.speed`` from the reach's end
    (``clearance`` above the believed table) down to ``approach.depth`` below it, where it
    holds. The MPC feeds every measured normal force λ̂ to :meth:`observe_force`; the first
    one above ``contact_force`` is the detection, at t_d, and it is final: the wrapped task's
    schedule resumes with its contact time moved to t_d, so every later phase (touch, force
    ramp, circle or square signal, stop), its references and its evaluation window
    (:meth:`in_circle`) are shifted by t_d − ``contact_time``. (A release level that re-armed
    the descent when λ̂ fell back in the touch phase was measured and not kept: the MPC then
    alternated between its free and contact models for seconds; seed 110 at δo = 0 started
    its contact phases at 6.65 s instead of 1.05 s.) Phase
    times read through the wrapper (``circle_start``, …) are the wrapped task's, unshifted.

    A contact that never comes (the table lower than ``depth`` below the belief) leaves the
    reference holding at that depth in free space, the force reference 0: no contact phase
    starts, and :meth:`contact_missed` says so from the time the descent has reached the bound.

    State: the detection time and the descent's origin, set by :meth:`observe_force` (the
    only schedule with a state; :meth:`reset` forgets it). Every reader of the task (the
    MPC through :class:`LiveTask`, the run's log, the metrics) must share the one object.

    Args:
        task: the wrapped task (its phases are those of the time-based schedule).
        approach: the guarded approach's parameters.
    """

    def __init__(self, task: PolishingTask | ForceSquareTask, approach: GuardedApproach) -> None:
        self.task = task
        self.approach = approach
        self.reset()

    def reset(self) -> None:
        """Forget the detection: the descent starts again at the reach's end."""
        self.detected_at: float | None = None  # task time of the detection, s

    def __getattr__(self, name: str) -> Any:
        if name == "task":  # (not set yet: copy and pickle look attributes up before __init__)
            raise AttributeError(name)
        return getattr(self.task, name)

    # -- detection ------------------------------------------------------------------------------
    def restore_detection(self, detected_at: float | None) -> None:
        """Set the detection time of a finished run (its result's ``contact_time``, task time,
        s; None: none) on a new task, to read that run's references and window afterwards."""
        self.reset()
        if detected_at is not None:
            if not (math.isfinite(detected_at) and detected_at >= self.task.contact_time):
                raise InputError(
                    f"a detection time must be finite and >= {self.task.contact_time} s, "
                    f"got {detected_at}"
                )
            self.detected_at = float(detected_at)

    @property
    def shift(self) -> float:
        """How far the contact phases moved, s: t_d − ``contact_time`` (0 before a detection)."""
        return 0.0 if self.detected_at is None else self.detected_at - self.task.contact_time

    def observe_force(self, normal_force: float, t: float) -> bool:
        """Feed the measured normal force λ̂ (N, the table pushing the tool: > 0) read at task
        time t (s); returns whether the task is in its contact phases. Before the reach's end
        and for a non-finite λ̂ nothing changes; after a detection neither."""
        if self.detected_at is None and t >= self.task.contact_time:
            if math.isfinite(normal_force) and normal_force > self.approach.contact_force:
                self.detected_at = float(t)
        return self.detected_at is not None

    def replay(self, t: npt.ArrayLike, normal_force: npt.ArrayLike, every: int) -> float | None:
        """Detect the contact again from a run's log: reset, then :meth:`observe_force` the
        measured normal force (N) of every ``every``-th sample (the MPC's ticks) at its time t
        (s). Returns the detection time (s; None: none). A process that did not run the MPC
        (the graph's metrics node, the real-time loop) reads the run's phases so; it is the
        MPC's own detection when the MPC read those samples (no fault hid one from it)."""
        times = np.asarray(t, dtype=float)
        forces = np.asarray(normal_force, dtype=float)
        if times.shape != forces.shape or every < 1:
            raise InputError("replay needs times and forces of one shape and every >= 1")
        self.reset()
        for k in range(0, times.size, every):
            self.observe_force(float(forces[k]), float(times[k]))
        return self.detected_at

    def descent_height(self, t: float) -> float:
        """z of the descending reference at task time t (s), m, world frame (without contact)."""
        start = float(self.task.contact_position[2]) + self.task.clearance
        height = start - self.approach.speed * max(t - self.task.contact_time, 0.0)
        return max(height, float(self.task.contact_position[2]) - self.approach.depth)

    @property
    def max_descent_time(self) -> float:
        """Time of the longest descent, from the reach's end to the bound, s."""
        return (self.task.clearance + self.approach.depth) / self.approach.speed

    def contact_missed(self, t: float) -> bool:
        """Whether the descent reached its bound by task time t (s) without a contact."""
        floor = float(self.task.contact_position[2]) - self.approach.depth
        return (
            self.detected_at is None
            and t >= self.task.contact_time
            and self.descent_height(t) <= floor
        )

    # -- schedule ---------------------------------------------------------------------------
    def _inner_time(self, t: float) -> float:
        """The wrapped task's time at t (s): shifted from the detection on, t itself before
        (the stand-still and the reach are never shifted)."""
        if self.detected_at is not None and t >= self.detected_at:
            return t - self.shift
        return t

    def _guarding(self, t: float) -> bool:
        """Whether t (s) is in the descent: after the reach, without a detection before t."""
        if t < self.task.contact_time:
            return False
        return self.detected_at is None or t < self.detected_at

    @property
    def duration(self) -> float:
        """The run's length, s: the wrapped task's plus the longest descent (the contact
        phases end that late when the table is at the bound)."""
        return self.task.duration + self.max_descent_time

    def in_contact(self, t: float) -> bool:
        """Whether the nodes at t (s) use the contact model."""
        return not self._guarding(t) and self.task.in_contact(self._inner_time(t))

    def ee_position(self, t: float) -> np.ndarray:
        """p̄(t), m, world frame."""
        if self._guarding(t):
            out = np.array(self.task.contact_position, dtype=float)
            out[2] = self.descent_height(t)
            return out
        return self.task.ee_position(self._inner_time(t))

    def force(self, t: float) -> float:
        """λ̄(t), N: 0 during the descent."""
        return 0.0 if self._guarding(t) else self.task.force(self._inner_time(t))

    def in_circle(self, t: np.ndarray) -> np.ndarray:
        """The evaluation window, shifted with the contact phases (empty without a contact)."""
        t = np.asarray(t, dtype=float)
        if self.detected_at is None:
            return np.zeros(t.shape, dtype=bool)
        return np.asarray(self.task.in_circle(t - self.shift))

    def set_phase_weights(self, weights: PhaseWeights) -> None:
        """Replace the wrapped task's per-phase c4 and c6 (the detection is kept)."""
        self.task = replace(self.task, weights=weights)

    def reference(self, t: float, dimension: int = 1) -> NodeReference:
        """A new reference of a node at t (s); ``dimension``: force entries."""
        return self.reference_into(t, NodeReference.empty(dimension))

    def reference_into(self, t: float, ref: NodeReference) -> NodeReference:
        """The node reference at t (s) written into ``ref``; returns it. During the descent:
        free space, p̄ on the descending line, all three axes of the position cost active."""
        if not self._guarding(t):
            return self.task.reference_into(self._inner_time(t), ref)
        self.task.reference_into(self.task.contact_time - 1e-9, ref)  # a free node's weights
        ref.ee_position[:] = self.task.contact_position
        ref.ee_position[2] = self.descent_height(t)
        return ref


#: Time over which a live retarget (:class:`LiveTask`) blends from the old to the new target, s
#: (minimum jerk). A 0.1 m offset change then moves p̄ at most 0.375 m/s, below twice the
#: polishing circle's own speed (0.07 m × 6 rad/s on the fast variant).
RETARGET_BLEND = 0.5


class _Blend:
    """A value that moves from ``start`` to ``target`` with a minimum-jerk blend of ``duration``
    s from time ``t0`` (s, the schedule's time); before any change it is ``target``."""

    def __init__(self, value: np.ndarray, duration: float) -> None:
        self.start = np.array(value, dtype=float)
        self.target = self.start.copy()
        self.t0 = -math.inf
        self.duration = float(duration)

    def at(self, t: float) -> np.ndarray:
        s = min_jerk((t - self.t0) / self.duration) if self.duration > 0 else 1.0
        return self.start + s * (self.target - self.start)

    def settled(self, t: float) -> bool:
        return t >= self.t0 + self.duration

    def retarget(self, value: np.ndarray, t: float) -> None:
        self.start = self.at(t)
        self.target = np.array(value, dtype=float)
        self.t0 = float(t)


class LiveTask:
    """A task schedule whose position offset and force set-point change while it runs (the MPC
    node's live parameters ``position_offset`` and ``task.normal_force`` and its reference
    topics).

    ``reference_into(t, ref)`` is the wrapped task's, then:

    * p̄(t) ← p̄(t) + o(t): o is the position offset (m, world frame);
    * λ̄(t) ← λ̄(t)·f(t)/f₀ (the normal entry): f is the force set-point (N), f₀ the wrapped
      task's own (``normal_force`` of :class:`PolishingTask`, ``force`` of :class:`PressTask`),
      so the task's profile (zero before contact, the ramp) keeps its shape and reaches f.

    A change at time t₀ (s, the schedule's time) blends o and f from their values at t₀ to the
    new ones with a minimum jerk over ``blend`` s (:data:`RETARGET_BLEND`). Until the first
    change the references are the wrapped task's, bit for bit. Everything else (``duration``,
    ``in_circle``, …) is the wrapped task's.

    Args:
        task: the task schedule (any with ``reference_into``).
        position_offset: initial o, m, world frame (``mpc.position_offset``).
        blend: blend time of a change, s.
    """

    def __init__(
        self,
        task: Any,
        position_offset: npt.ArrayLike = (0.0, 0.0, 0.0),
        blend: float = RETARGET_BLEND,
    ) -> None:
        offset = np.asarray(position_offset, dtype=float)
        if offset.shape != (3,) or not np.all(np.isfinite(offset)):
            raise ConfigError(
                f"position_offset must be 3 finite numbers (m), got {position_offset!r}"
            )
        if not (math.isfinite(blend) and blend >= 0.0):
            raise ConfigError(f"blend must be a finite time >= 0 s, got {blend}")
        self.task = task
        self.nominal_force = _task_force(task)
        self._offset = _Blend(offset, blend)
        self._force = _Blend(np.array([self.nominal_force or 0.0]), blend)
        self._shifted = bool(np.any(offset != 0.0))
        self._scaled = False

    def __getattr__(self, name: str) -> Any:
        if name == "task":  # (not set yet: copy and pickle look attributes up before __init__)
            raise AttributeError(name)
        return getattr(self.task, name)

    # -- what changes ---------------------------------------------------------------------------
    @property
    def position_offset(self) -> np.ndarray:
        """The offset o the blend ends at, m, world frame (a copy)."""
        return self._offset.target.copy()

    @property
    def force_setpoint(self) -> float | None:
        """The set-point f the blend ends at, N (None: the task has no single force)."""
        return None if self.nominal_force is None else float(self._force.target[0])

    def set_position_offset(self, offset: npt.ArrayLike, t: float) -> None:
        """Move o to ``offset`` (3 entries, m, world) from time t (s, schedule time)."""
        value = np.asarray(offset, dtype=float)
        if value.shape != (3,) or not np.all(np.isfinite(value)):
            raise InputError(f"position offset must be 3 finite numbers (m), got {offset!r}")
        self._offset.retarget(value, t)
        self._shifted = True

    def set_force(self, force: float, t: float) -> None:
        """Move the force set-point to ``force`` (N, >= 0) from time t (s, schedule time)."""
        if self.nominal_force is None or self.nominal_force <= 0.0:
            raise InputError(
                f"{type(self.task).__name__} has no single positive force set-point to change"
            )
        if not (math.isfinite(force) and force >= 0.0):
            raise InputError(f"force set-point must be finite and >= 0 N, got {force}")
        self._force.retarget(np.array([float(force)]), t)
        self._scaled = True

    def set_phase_weights(self, weights: PhaseWeights) -> None:
        """Replace the wrapped task's per-phase c4 and c6 (applies to every later reference)."""
        if isinstance(self.task, GuardedTask):  # in place: the log and metrics share it
            self.task.set_phase_weights(weights)
            return
        if not hasattr(self.task, "weights"):
            raise InputError(f"{type(self.task).__name__} has no phase weights")
        self.task = replace(self.task, weights=weights)

    # -- schedule ---------------------------------------------------------------------------
    def reference(self, t: float, dimension: int = 1) -> NodeReference:
        """A new reference of a node at t (s); ``dimension``: force entries."""
        return self.reference_into(t, NodeReference.empty(dimension))

    def reference_into(self, t: float, ref: NodeReference) -> NodeReference:
        """The wrapped task's reference at t (s) with the live offset and force scale, written
        into ``ref``; returns it."""
        self.task.reference_into(t, ref)
        if self._shifted:
            ref.ee_position += self._offset.at(t)
        if self._scaled:
            assert self.nominal_force is not None  # set_force refuses a task without one
            ref.force[-1] *= float(self._force.at(t)[0]) / self.nominal_force
        return ref


def _task_force(task: Any) -> float | None:
    """The single force set-point of a task, N (None for a task without one)."""
    if isinstance(task, GuardedTask):
        task = task.task
    if isinstance(task, PolishingTask):
        return float(task.normal_force)
    if isinstance(task, PressTask):
        return float(task.force)
    return None
