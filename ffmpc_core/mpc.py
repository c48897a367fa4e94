"""Model-predictive controllers for the three formulations (paper III-C, IV, V).

One class, :class:`ModelPredictiveController`, runs any formulation: the formulation only decides
the state x, the nodes of the shooting problem and the torque to send. The controller has the shape
``reset()`` / ``step(measurement, t) -> MpcCommand`` and never reads a clock: t is given.

Every ``step``:

1. builds x̂ from the measurement: (q, v) classical, (q, v, τ̂) torque-feedback, (q, v, λ̂)
   force-feedback (eq 5, 10, 19);
2. has the task schedule write the references of every node at t + kΔt into preallocated
   references and updates the nodes in place (phase switches replace a node's model only when
   its contact status changes);
3. warm-starts from the previous solution shifted by the elapsed time (linear interpolation
   along the horizon, first state replaced by x̂);
4. solves with ``mim_solvers.SolverCSQP`` under the hard constraints of
   :mod:`ffmpc_core.constraints` (joint position, velocity and torque boxes in every
   formulation, the torque-feedback τ box, the force-feedback force box and 3-D friction cone;
   ADMM QPs warm-started with the previous duals), or, with ``constraints.enabled`` false, the
   unconstrained problem with ``mim_solvers.SolverSQP``; filter line search, ≤ 8 SQP
   iterations, KKT tolerance 1e-4 (paper VII-A4). A solution that breaks a bound by more than
   ``constraints.violation_tolerance`` raises :class:`ConstraintViolationError` (the caller's
   safe hold): a violated limit is never sent silently;
5. returns the torque to send (u₀* for classical and force-feedback; eq 15's interpolation for
   torque-feedback), the local feedback gain, the prediction and solver statistics.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any, Protocol, cast

import crocoddyl  # noqa: F401  (must be imported before mim_solvers: it loads boost)
import mim_solvers
import numpy as np
import numpy.typing as npt

from ffmpc_core.config import (
    BACKENDS,
    LIVE_COST_WEIGHTS,
    TORQUE_STATES,
    ContactConfig,
    CostWeights,
    NodeReference,
    OcpConfig,
)
from ffmpc_core.constraints import (
    ConstraintConfig,
    ConstraintViolationError,
    OcpBounds,
    ocp_bounds,
)
from ffmpc_core.contact_friction import (
    SlidingDirectionEstimator,
    coulomb_friction_torque,
    normal_force_without_friction,
)
from ffmpc_core.errors import ConfigError, InputError, SolverError
from ffmpc_core.joint_observer import JointPositionObserver, check_time_constant
from ffmpc_core.lowpass import (
    interpolate_torque,
    interpolation_epsilon,
    lowpass_alpha,
    lowpass_filter_step,
)
from ffmpc_core.plausibility import (
    MEASURED_TORQUE_FACTOR,
    JointStateRange,
    check_force,
    check_torque,
)
from ffmpc_core.robots import RobotModel

#: A step more than this many MPC periods after the previous one is a resumption after an outage
#: (a dropout, a killed and restarted MPC): see :meth:`ModelPredictiveController.step`.
RESUME_GAP_PERIODS = 10
#: After an outage, the schedule's clock comes back to speed over this time, s (its rate follows
#: a minimum-jerk ramp from 0 to 1: :func:`resume_lag`).
RESUME_RAMP = 0.3
#: A constrained solution with a row this close to a bound (a fraction of its limit) has an
#: active constraint: the next solve goes to ``SolverCSQP`` directly (``unconstrained_first``).
ACTIVE_MARGIN = 1e-3


def resume_lag(elapsed: float, ramp: float = RESUME_RAMP) -> float:
    """How far the task's clock lags behind the controller's, s, ``elapsed`` s after it resumed
    from an outage: the task time advances at the rate w(s) = 10s³ − 15s⁴ + 6s⁵ (s = elapsed /
    ramp, the minimum-jerk profile), so the reference starts AT REST where the task stood (the
    robot was held still meanwhile) and is back to full speed after ``ramp``; the lag is
    elapsed − ramp·(2.5s⁴ − 3s⁵ + s⁶) during the ramp and ramp/2 after it."""
    if ramp <= 0.0:
        return 0.0
    x = min(max(elapsed / ramp, 0.0), 1.0)
    return max(elapsed, 0.0) - ramp * x**4 * (2.5 - 3.0 * x + x * x) if x < 1.0 else 0.5 * ramp


def resume_force_reference(
    reference: np.ndarray, resumed_force: np.ndarray, elapsed: float, ramp: float = RESUME_RAMP
) -> np.ndarray:
    """The force reference λ̄ (N, written in place and returned) ``elapsed`` s after the MPC
    resumed from an outage with the measured force ``resumed_force`` (N, same entries): a
    minimum-jerk blend from the measured force to the schedule's over ``ramp`` s, so the MPC
    does not press back to the schedule's force at once. During the outage the low level held
    the robot and the contact force relaxed (50 → 1 N in a 0.5 s dropout mid-circle); the step
    back to 50 N drove the wrist to 1.003× its speed limit and the robot's reflex stopped it."""
    if ramp <= 0.0 or elapsed >= ramp:
        return reference
    x = max(elapsed / ramp, 0.0)
    s = x**3 * (10.0 - 15.0 * x + 6.0 * x * x)
    reference *= s
    reference += (1.0 - s) * resumed_force
    return reference


class OcpNode(Protocol):
    """What the MPC needs of one node of any formulation."""

    model: crocoddyl.ActionModelAbstract

    def set_reference(self, ref: NodeReference) -> bool:
        """Update the node in place; True when ``model`` is now a different object."""

    def set_state_bounds(self, lower: np.ndarray, upper: np.ndarray) -> None:
        """Bounds of the node's state-only constraint rows (:mod:`ffmpc_core.constraints`)."""


class SoftContactOcpNode(OcpNode, Protocol):
    """A node of the force-feedback formulation: its visco-elastic contact can change."""

    def set_contact_parameters(self, stiffness: npt.ArrayLike, damping: npt.ArrayLike) -> None:
        """Stiffness K (N/m) and damping B (N·s/m), scalar or per force axis, in place."""


class RigidContactOcpNode(OcpNode, Protocol):
    """A node of the classical or torque-feedback formulation: its rigid-contact force."""

    def contact_force(self, data: crocoddyl.ActionDataAbstract) -> np.ndarray:
        """λ^r of the node (N) from ``data`` after calc."""


class Schedule(Protocol):
    """A task schedule (:mod:`ffmpc_core.tasks`): the reference of a node at time t (s).

    ``reference_into`` writes into a preallocated reference (no allocation on the MPC's hot
    path); a schedule without it is asked for a new ``reference`` per node instead.
    """

    def reference(self, t: float, dimension: int = 1) -> NodeReference:
        """A new reference of a node at time t (s); ``dimension``: force entries."""
        ...

    def reference_into(self, t: float, ref: NodeReference) -> NodeReference:
        """Write the reference of a node at time t (s) into ``ref``; returns it."""
        ...


@dataclass(frozen=True)
class MpcConfig:
    """Parameters of one MPC.

    Attributes:
        ocp: the problem and its solver: formulation, horizon N, Δt, re-planning period, SQP
            iterations and tolerance, low-pass cut-off f_c
            (:class:`~ffmpc_core.config.OcpConfig`; the scenario's ``mpc`` section holds it).
        contact: the contact model the OCP assumes (K, B used by force-feedback only).
        weights: cost weights (eq 25, 28, 29).
        q_reference: posture q̄ of eq 25.1, rad (None: the robot's nominal posture).
        command_delay: known delay between the measurement and the moment the command acts,
            s (the paper's δo = 5 ms). With a delay, the MPC predicts the state at t + δo by
            integrating its own model with the commands already sent (a Smith predictor) and
            solves from there; 0 = the plain scheme (solve from the measured state).
        prediction_step: integration step of that prediction, s.
        torque_state: the τ entry of the torque-feedback state x̂ = (q, v, τ) the solve starts
            from: ``"measured"`` = the measured joint torque τ̂ (eq 10/15: τ₀* = τ̂, the
            paper's and the authors' code's choice) or ``"commanded"`` = the last torque τ̃ sent
            (eq 15), which is what acts at t + δo when the low level tracks it perfectly. With
            ``"measured"``, eq 15 interpolates from τ̂ too. Other formulations ignore it.
        backend: implementation of the project's own action models: ``"native"`` (C++,
            :mod:`ffmpc_core.native`, the default) or ``"python"`` (the readable reference,
            e.g. :mod:`ffmpc_core.soft_contact`). Both give the same numbers (tests hold them
            equal); formulations without a native model use the Python one.
        constraints: the hard constraints and their solver's settings
            (:class:`~ffmpc_core.constraints.ConstraintConfig`; on by default). Its
            ``max_solve_time`` is applied as given: :func:`ffmpc_core.polishing.mpc_config`
            passes it for real-time runs only.
        position_observer_time: T of the joint-position observer, s
            (:mod:`ffmpc_core.joint_observer`): the solve starts from q̂, the measured q with
            its noise filtered by the measured q̇; 0 = the measured q as it is.
        constrained_iterations: SQP iterations of ``SolverCSQP`` per solve, at most (0:
            ``ocp.max_iterations``, as every lockstep run). The real-time MPC node sets 1 (its
            graph parameter ``real_time_iterations``, :mod:`ffmpc_ros.mpc_node`): one SQP
            iteration per tick, the real-time iteration scheme (Diehl et al. 2005), whose QP is
            still solved to the ADMM's tolerances, so that its plan keeps the linear bounds. The
            unconstrained ``SolverSQP`` (the screen of ``unconstrained_first``, or the solve
            with the constraints off) keeps ``ocp.max_iterations``.
    """

    ocp: OcpConfig = field(default_factory=OcpConfig)
    contact: ContactConfig = field(default_factory=ContactConfig)
    weights: CostWeights = field(default_factory=CostWeights)
    q_reference: tuple[float, ...] | None = None
    command_delay: float = 0.0
    prediction_step: float = 0.001
    torque_state: str = "measured"
    backend: str = "native"
    constraints: ConstraintConfig = field(default_factory=ConstraintConfig)
    constrained_iterations: int = 0
    position_observer_time: float = 0.0

    def __post_init__(self) -> None:
        if self.torque_state not in TORQUE_STATES:
            raise ConfigError(
                f"torque_state must be one of {TORQUE_STATES}, got {self.torque_state!r}"
            )
        if self.backend not in BACKENDS:
            raise ConfigError(f"backend must be one of {BACKENDS}, got {self.backend!r}")
        horizon = self.ocp.horizon * self.ocp.dt
        if not 0.0 <= self.command_delay < horizon or self.prediction_step <= 0:
            raise ConfigError("command_delay must be in [0, horizon·dt), prediction_step > 0")
        check_time_constant(self.position_observer_time)
        if self.constrained_iterations < 0:
            raise ConfigError(
                f"constrained_iterations must be >= 0 (0: max_iterations), "
                f"got {self.constrained_iterations}"
            )


@dataclass
class MpcMeasurement:
    """What the MPC reads. q rad, v rad/s (joint order of the robot model); force N, in the
    contact configuration's frame and dimension (force-feedback); torque N·m, the measured joint
    torque τ̂ (torque-feedback)."""

    q: np.ndarray
    v: np.ndarray
    force: np.ndarray | None = None
    torque: np.ndarray | None = None


@dataclass
class MpcCommand:
    """The MPC's output.

    Attributes:
        torque: joint torque to send now, N·m (saturated to the robot's limits).
        state: the state x̂ the solve started from (and ``feedback_gain`` refers to).
        feedback_gain: G (nv × ndx) such that ``torque + G @ (x − state)`` is the locally optimal
            torque at a nearby state x (from the first Riccati gain; crocoddyl's u = u* − K·Δx,
            so G = −K, chained through eq 15 for torque-feedback).
        xs, us: predicted states and controls over the horizon.
        iterations, kkt: SQP iterations of the solver that gave the solution and its final KKT
            residual.
        solve_time: wall time of the solve, s (statistics only; never used for control).
        converged: whether the KKT tolerance was reached within ``max_iterations``.
        qp_iterations: ADMM iterations of the last SQP iteration (0 without constraints).
        constraint_violation: the solution's largest excess over a bound, as a fraction of
            its limit (0 without constraints; at most ``violation_tolerance``, else the step
            raised).
        relaxed: whether x̂ lay beyond a bound, so that the bounds were relaxed for this solve
            (:meth:`~ffmpc_core.constraints.OcpBounds.node_bounds`).
        screen_iterations: SQP iterations of the unconstrained screen whose solution broke a
            bound, so that ``SolverCSQP`` solved again (``constraints.unconstrained_first``);
            0 when the screen's solution was the answer or there was none.
    """

    torque: np.ndarray
    state: np.ndarray
    feedback_gain: np.ndarray
    xs: np.ndarray
    us: np.ndarray
    iterations: int
    kkt: float
    solve_time: float
    converged: bool
    qp_iterations: int = 0
    constraint_violation: float = 0.0
    relaxed: bool = False
    screen_iterations: int = 0


def problem_bounds(robot: RobotModel, config: MpcConfig) -> OcpBounds | None:
    """The hard constraints of ``config``'s formulation (None when they are off)."""
    if not config.constraints.enabled:
        return None
    return ocp_bounds(robot, config.ocp.formulation, config.contact, config.constraints)


def _node_factory(
    robot: RobotModel, config: MpcConfig, q_ref: np.ndarray | None
) -> Callable[[bool], OcpNode]:
    """A function terminal -> node for the configured formulation (with its constraints)."""
    args = (robot, config.contact, config.weights, config.ocp.dt)
    bounds = problem_bounds(robot, config)
    if config.ocp.formulation == "classical":
        from ffmpc_core.rigid_contact import make_rigid_contact_node

        return lambda terminal: make_rigid_contact_node(
            *args, terminal, q_reference=q_ref, backend=config.backend, bounds=bounds
        )
    if config.ocp.formulation == "torque_feedback":
        from ffmpc_core.lowpass import make_lowpass_node

        return lambda terminal: make_lowpass_node(
            *args,
            terminal,
            config.ocp.cutoff_frequency,
            q_reference=q_ref,
            backend=config.backend,
            bounds=bounds,
            torque_integration=config.ocp.torque_integration,
        )
    if config.backend == "native":
        from ffmpc_core.native import make_native_soft_contact_node as make_soft_contact_node
    else:
        from ffmpc_core.soft_contact import make_soft_contact_node

    return lambda terminal: make_soft_contact_node(
        *args, terminal, q_reference=q_ref, bounds=bounds
    )


class ModelPredictiveController:
    """Receding-horizon controller around one of the three OCP formulations.

    Args:
        robot: robot model (its contact frame carries the contact).
        config: MPC parameters.
        schedule: task schedule giving each node's reference at a time t.
        node_factory: ``terminal -> node`` replacing the formulation's own nodes (benchmarks
            use it for a reference problem); the state layout must stay the formulation's, and
            its nodes must carry the constraints of ``config`` (:func:`problem_bounds`) when
            they are on.
    """

    def __init__(
        self,
        robot: RobotModel,
        config: MpcConfig,
        schedule: Schedule,
        node_factory: Callable[[bool], OcpNode] | None = None,
    ) -> None:
        self.robot = robot
        self.config = config
        self.schedule = schedule
        nv = robot.nv
        self.nc = config.contact.dimension
        q_ref = robot.q_nominal if config.q_reference is None else np.asarray(config.q_reference)
        make = node_factory or _node_factory(robot, config, q_ref)
        self.bounds = problem_bounds(robot, config)
        #: the plausible measured (q, q̇) (:meth:`state_from`), computed once
        self._joint_range = JointStateRange.of(
            robot.position_lower, robot.position_upper, robot.velocity_limit
        )
        self.nodes: list[OcpNode] = [make(False) for _ in range(config.ocp.horizon)]
        self.terminal_node: OcpNode = make(True)
        # bounds of the state-only rows at nodes 1..N as written in the nodes (constraints.py)
        self._node_bounds: np.ndarray | None = None
        if self.bounds is not None:
            if any(getattr(n, "bounds", None) is None for n in (*self.nodes, self.terminal_node)):
                raise ConfigError(
                    "the nodes lack the hard constraints of config.constraints (enabled): build "
                    "them with bounds=problem_bounds(robot, config), or disable the constraints"
                )
            # x₀ = x̂ is fixed: node 0's state-only rows are constants, never constraints.
            free = np.full(self.bounds.n_state_rows, np.inf)
            self.nodes[0].set_state_bounds(-free, free)
            self._margin_bounds = self.bounds.node_bounds(config.ocp.horizon)[0]
            self._write_node_bounds(self._margin_bounds)
        self.nx = {
            "classical": 2 * nv,
            "torque_feedback": 3 * nv,
            "force_feedback": 2 * nv + self.nc,
        }[config.ocp.formulation]
        self._x0 = np.zeros(self.nx)
        self._x0[:nv] = q_ref
        self._make_problem()
        # One preallocated reference per node (+ terminal, + predictor), filled in place.
        self._refs = [NodeReference.empty(self.nc) for _ in range(config.ocp.horizon + 1)]
        self._predictor_ref = NodeReference.empty(self.nc)
        self._reference_into = getattr(schedule, "reference_into", None)
        #: a guarded approach's contact detection (tasks.GuardedTask.observe_force), or None
        self._observe_force: Callable[[float, float], bool] | None = getattr(
            schedule, "observe_force", None
        )
        self._predictor = None
        if config.command_delay > 0.0:
            # Torque-feedback: what acts during the delay is the torque τ̃ already sent, so (q, v)
            # are predicted with the rigid-contact dynamics driven by τ̃; τ is the measured τ̂
            # (torque_state "measured", eq 10/15) or the last τ̃ ("commanded").
            pred_form = "classical" if config.ocp.formulation == "torque_feedback" else None
            pred_ocp = replace(
                config.ocp,
                dt=config.prediction_step,
                formulation=pred_form or config.ocp.formulation,
            )
            pred_cfg = replace(
                config,
                ocp=pred_ocp,
                command_delay=0.0,
                constraints=replace(config.constraints, enabled=False),  # only integrated
            )
            self._predictor = _node_factory(robot, pred_cfg, q_ref)(False)
            self._predictor_data = self._predictor.model.createData()
            self._friction_data = robot.create_data()  # the predictor's table friction
        #: the sliding direction for the force-feedback MPC's friction correction of λ̂
        #: (ContactConfig.friction_in_measured_force), else None
        self._sliding: SlidingDirectionEstimator | None = None
        if config.ocp.formulation == "force_feedback" and config.contact.friction_in_measured_force:
            self._sliding = SlidingDirectionEstimator(
                robot,
                config.contact,
                config.contact.sliding_filter_time,
                config.contact.sliding_min_speed,
            )
        #: the joint-position observer of x̂'s q (MpcConfig.position_observer_time), else None;
        #: it starts again after an outage (the same gap as the controller's resumption)
        self._observer: JointPositionObserver | None = None
        if config.position_observer_time > 0.0:
            self._observer = JointPositionObserver(
                robot,
                config.position_observer_time,
                max_gap=RESUME_GAP_PERIODS * config.ocp.period,
            )
        # eq 15; τ₁* as it is (ε = 1) when q̈ is at τ⁺: the plan applies τ₁* from node 0 on
        self._epsilon = (
            1.0
            if config.ocp.torque_integration == "next"
            else interpolation_epsilon(config.ocp.period, config.ocp.dt)
        )
        self._alpha = lowpass_alpha(config.ocp.cutoff_frequency, config.ocp.dt)  # eq 13
        self.reset()

    def _make_problem(self) -> None:
        """(Re)build the shooting problem and its SQP solver from the nodes' current models.

        Called at construction and when a node's model object changes (a contact switch, a few
        times per task). ``problem.updateModel`` + a solver kept across it crashes with
        mim_solvers 0.3.0 (the solver caches node data), so both are rebuilt; the warm start is
        passed explicitly to every solve and survives.
        """
        self.problem = crocoddyl.ShootingProblem(
            self._x0, [n.model for n in self.nodes], self.terminal_node.model
        )
        if self.problem.nthreads != 1:
            # An all-C++ problem defaults to one thread per core; on a loaded 2-core machine that
            # made problem.calc 7.6 ms instead of 0.05 ms (N=5, measured). Python models get 1.
            self.problem.nthreads = 1
        c = self.config.constraints
        self.unconstrained_solver = mim_solvers.SolverSQP(self.problem)
        self.constrained_solver: Any = None
        if self.bounds is not None:
            csqp = mim_solvers.SolverCSQP(self.problem)
            csqp.max_qp_iters = c.max_qp_iterations
            csqp.eps_abs = c.eps_abs
            csqp.eps_rel = c.eps_rel
            csqp.rho_update_interval = c.rho_update_interval
            csqp.max_solve_time = c.max_solve_time if c.max_solve_time > 0 else np.inf
            csqp.termination_tolerance = c.kkt_tolerance
            self.constrained_solver = csqp
        for solver in (self.unconstrained_solver, self.constrained_solver):
            if solver is not None:
                solver.use_filter_line_search = True
                solver.with_callbacks = False
        self.unconstrained_solver.termination_tolerance = self.config.ocp.kkt_tolerance
        #: the solver that gave the last solution (its K, iter, KKT are the command's)
        self.solver: Any = self.constrained_solver or self.unconstrained_solver

    # -- controller shape -------------------------------------------------------------------
    def reset(self) -> None:
        """Forget the warm start and any task pause; the next step starts from a static guess."""
        self.task_pause = 0.0  # s the task's clock stood still for outages (see step)
        self._resumed_at: float | None = None  # controller time of the last resumption, s
        self._resumed_force: np.ndarray | None = None  # measured λ at that resumption, N
        self._prev_t: float | None = None
        self._prev_xs: np.ndarray | None = None
        self._prev_us: np.ndarray | None = None
        self._sent: list[tuple[float, np.ndarray]] = []  # (time, model control) in flight
        self._active = False  # the last constrained solution had a bound active
        self._first_step_data: dict[int, crocoddyl.ActionDataAbstract] = {}
        self._excess = 0.0  # the last solution's largest signed excess over a bound
        if self._sliding is not None:
            self._sliding.reset()
        if self._observer is not None:
            self._observer.reset()

    def set_contact_parameters(self, stiffness: npt.ArrayLike, damping: npt.ArrayLike) -> None:
        """Change the force-feedback model's K (N/m) and B (N·s/m) in place, for every node and
        the δo predictor, from the next solve (no rebuild of the problem). ``config.contact``
        reads the new values back. ConfigError (nothing changed) for a bad value."""
        if self.config.ocp.formulation != "force_feedback":
            raise ConfigError("only the force-feedback formulation has a visco-elastic contact")
        contact = replace(
            self.config.contact,
            stiffness=_as_setting(stiffness),
            damping=_as_setting(damping),
        )  # validates both (ConfigError) before any node changes
        nodes = (*self.nodes, self.terminal_node)
        if self._predictor is not None:
            nodes += (self._predictor,)
        for node in nodes:
            # the force-feedback formulation builds soft-contact nodes
            cast(SoftContactOcpNode, node).set_contact_parameters(
                contact.stiffness_vector(), contact.damping_vector()
            )
        self.config = replace(self.config, contact=contact)

    def set_cost_weight(self, name: str, value: float) -> None:
        """Set the scalar weight c of cost term ``name`` (a :class:`CostWeights` field among
        :data:`LIVE_COST_WEIGHTS`) in every node, in place, from the next solve; ``config.weights``
        reads it back. ConfigError (nothing changed) for another name, a term the formulation
        lacks, or a value that is not finite and >= 0.

        c4 (``ee_position``) and c6 (``force``) are not here: the task sets them per node
        (its phase weights); ``lowpass_input`` (c_w) is built into the low-pass integrator."""
        if name not in LIVE_COST_WEIGHTS:
            raise ConfigError(
                f"cost weight {name!r} cannot change in place; these can: {LIVE_COST_WEIGHTS}"
            )
        if name == "force_rate" and self.config.ocp.formulation != "force_feedback":
            raise ConfigError("only the force-feedback formulation has the force-rate cost")
        value = float(value)
        if not (np.isfinite(value) and value >= 0.0):
            raise ConfigError(f"cost weight {name} must be finite and >= 0, got {value}")
        for node in (*self.nodes, self.terminal_node):
            _set_node_weight(node, name, value)
        self.config = replace(self.config, weights=replace(self.config.weights, **{name: value}))

    def task_time(self, t: float) -> float:
        """The schedule's time at controller time t, s: t minus the outages' pause and, after the
        last one, the lag of the task clock's ramp back to speed (:func:`resume_lag`)."""
        if self._resumed_at is None:
            return t - self.task_pause
        return t - self.task_pause - resume_lag(t - self._resumed_at)

    def state_from(self, meas: MpcMeasurement) -> np.ndarray:
        """The OCP state x̂ of a measurement (eq 5, 10, 19), validated: finite and plausible
        (:mod:`ffmpc_core.plausibility`: joint positions and velocities, the measured torque, the
        force), InputError otherwise."""
        nv, robot = self.robot.nv, self.robot
        parts = [self._vector(meas.q, nv, "q"), self._vector(meas.v, nv, "v")]
        self._joint_range.check(parts[0], parts[1])
        if self.config.ocp.formulation == "torque_feedback":
            tau = self._vector(meas.torque, nv, "torque")
            parts.append(check_torque(tau, robot.torque_limit, "torque", MEASURED_TORQUE_FACTOR))
        elif self.config.ocp.formulation == "force_feedback":
            parts.append(check_force(self._vector(meas.force, self.nc, "force")))
        return np.concatenate(parts)

    def step(self, meas: MpcMeasurement, t: float) -> MpcCommand:
        """Solve the OCP from the measured state at time t (s) and return the command.

        After an outage (no step for more than ``RESUME_GAP_PERIODS`` periods) the controller
        starts cold and the task resumes where it was left: the schedule's clock is paused for
        the outage (:attr:`task_pause`, s), because meanwhile the low level held the robot still
        and a reference that ran on would make the MPC race to catch up (measured: the iiwa's
        wrist at 5.2× its velocity limit after a 0.5 s dropout, without the pause). Its clock
        then comes back to speed over :data:`RESUME_RAMP` (:func:`resume_lag`): a reference
        resuming at full speed from a robot at rest took joint 3 to 1.14× its velocity limit
        after a 50 ms stall of the MPC process mid-circle (real time, ``mpc-stall@1.0+0.05``).
        """
        if (
            self._prev_t is not None
            and t - self._prev_t > RESUME_GAP_PERIODS * self.config.ocp.period
        ):
            lag = self._prev_t - self.task_time(self._prev_t)  # the outages' lag so far
            pause = lag + (t - self._prev_t) - self.config.ocp.period
            self.reset()
            self.task_pause = pause
            self._resumed_at = t
            if meas.force is not None and len(meas.force) == self.nc:
                force = np.asarray(meas.force, dtype=float)
                self._resumed_force = force.copy() if np.all(np.isfinite(force)) else None
        self._observe_contact(meas, t)
        x_hat = self.state_from(meas)
        if self._observer is not None:
            nq = self.robot.nq
            x_hat[:nq] = self._observer.update(x_hat[:nq], x_hat[nq : nq + self.robot.nv], t)
        if self._sliding is not None:
            self._remove_friction_share(x_hat, t)
        x0 = self.predict(x_hat, t)
        if not np.all(np.isfinite(x0)):
            self._sent.clear()  # the next solve starts from the measured state itself
            raise SolverError(f"the δo prediction from t = {t} s is not finite")
        self._update_references(t + self.config.command_delay)
        relaxed = self._relax_bounds(x0)
        self.problem.x0 = x0
        xs, us = self._warm_start(x0, t)
        start = time.perf_counter()
        converged, xs_opt, us_opt, screened = self._solve(xs, us)
        solve_time = time.perf_counter() - start
        violation = self._check_constraints(xs_opt, us_opt, t)
        self._prev_t, self._prev_xs, self._prev_us = t, xs_opt, us_opt
        torque, gain = self._command(x0, xs_opt, us_opt)
        try:
            clipped = self.robot.clip_torque(torque)
        except InputError:
            # A diverged solve (non-finite or absurd torque): nothing is sent, so nothing enters
            # the δo prediction, and the next solve starts cold rather than from this solution.
            self._prev_xs = self._prev_us = None
            raise
        if self._predictor is not None:
            sent = torque if self.config.ocp.formulation == "torque_feedback" else us_opt[0]
            self._sent.append((t, sent.copy()))
        return MpcCommand(
            torque=clipped,
            state=x0,
            feedback_gain=gain,
            xs=xs_opt,
            us=us_opt,
            iterations=int(self.solver.iter),
            kkt=float(self.solver.KKT),
            solve_time=solve_time,
            converged=bool(converged),
            qp_iterations=int(self.solver.qp_iters)
            if self.solver is self.constrained_solver
            else 0,
            screen_iterations=screened,
            constraint_violation=violation,
            relaxed=relaxed,
        )

    def prediction(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The last solve's horizon, for display (not used for control), at its N + 1 nodes:
        contact-frame origins (N+1 × 3, m, world frame) by forward kinematics of the predicted
        q, contact forces λ (N+1 × nc, N: the force-feedback state's λ, else each node's
        rigid-contact force, 0 out of contact) and the references λ̄ (N+1 × nc, N). Nodes are
        Δt apart from t + command_delay (t: the solve's time). InputError before any solve."""
        if self._prev_xs is None or self._prev_t is None:
            raise InputError("no solve yet: nothing predicted")
        import pinocchio as pin

        robot, nc, nv = self.robot, self.nc, self.robot.nv
        xs = self._prev_xs
        data = robot.create_data()
        positions = np.empty((xs.shape[0], 3))
        for k, x in enumerate(xs):
            pin.framesForwardKinematics(robot.model, data, x[: robot.nq])
            positions[k] = data.oMf[robot.contact_frame_id].translation
        if self.config.ocp.formulation == "force_feedback":
            forces = xs[:, 2 * nv : 2 * nv + nc].copy()
        else:
            datas = [*self.problem.runningDatas, self.problem.terminalData]
            nodes = [*self.nodes, self.terminal_node]
            forces = np.array(
                [
                    cast(RigidContactOcpNode, n).contact_force(d)
                    for n, d in zip(nodes, datas, strict=True)
                ]
            ).reshape(-1, nc)
        start = self._prev_t + self.config.command_delay
        references = np.array(
            [
                self._reference(start + k * self.config.ocp.dt, NodeReference.empty(nc)).force
                for k in range(xs.shape[0])
            ]
        )
        return positions, forces, references

    def predict(self, x: np.ndarray, t: float) -> np.ndarray:
        """The state at t + command_delay: x (measured at t) integrated with the model controls
        sent during [t − δo, t), which act on the robot during [t, t + δo). Identity without
        a command delay or before any command was sent. Torque-feedback: (q, v) are predicted
        so, τ is the measured τ̂ of x (``torque_state`` "measured") or the last τ̃ sent
        ("commanded")."""
        if self._predictor is None or not self._sent:
            return x
        delay, h = self.config.command_delay, self.config.prediction_step
        # The commands acting during [t, t + δo): those sent after t − δo, and the newest one sent
        # at or before t − δo (acting at t). Not "sent within one period before t − δo": after a
        # tick without a solve (dropped, or skipped in real time), the command acting at t is
        # older than that, and the prediction would apply a newer one too early.
        cut = t - delay + 1e-12
        acting = [c for c in self._sent if c[0] <= cut][-1:]
        self._sent = acting + [c for c in self._sent if c[0] > cut]
        steps = int(round(delay / h))
        nv = self.robot.nv
        torque_feedback = self.config.ocp.formulation == "torque_feedback"
        x_full, x = x, (x[: 2 * nv].copy() if torque_feedback else x.copy())
        friction = self.config.contact.friction_coefficient > 0.0
        rigid_force: float | None = None  # the rigid model's normal force of the last step, N
        for i in range(steps):
            s = t - delay + i * h  # the command acting at t + i·h was sent at s
            u = self._sent[0][1]
            for ts, us in self._sent:
                if ts <= s + 1e-12:
                    u = us
            ref = self._reference(t + i * h, self._predictor_ref)
            if self._predictor.set_reference(ref):
                self._predictor_data = self._predictor.model.createData()
            if friction:
                if self.config.ocp.formulation == "force_feedback":
                    normal_force = self._normal_component(x[2 * nv : 2 * nv + self.nc])
                else:
                    if rigid_force is None:  # the first step: the force without the drag
                        self._predictor.model.calc(self._predictor_data, x, u)
                        rigid_force = self._predicted_rigid_normal_force()
                    normal_force = rigid_force
                u = u + coulomb_friction_torque(
                    self.robot,
                    self._friction_data,
                    x[: self.robot.nq],
                    x[self.robot.nq : self.robot.nq + nv],
                    normal_force,
                    self.config.contact,
                )
            self._predictor.model.calc(self._predictor_data, x, u)
            if friction and self.config.ocp.formulation != "force_feedback":
                rigid_force = self._predicted_rigid_normal_force()
            x = np.array(self._predictor_data.xnext)
        if torque_feedback:
            commanded = self.config.torque_state == "commanded" and self._sent
            return np.concatenate([x, self._sent[-1][1] if commanded else x_full[2 * nv :]])
        return x

    # -- internals ---------------------------------------------------------------------------
    def _solve(self, xs: list, us: list) -> tuple[bool, np.ndarray, np.ndarray, int]:
        """Solve from the guess (xs, us): (converged, xs*, us*, SQP iterations of an
        unconstrained screen that was not the answer).

        Without constraints: ``SolverSQP``. With them, ``SolverCSQP`` from the guess, unless
        ``constraints.unconstrained_first`` and the last solution had no bound active (within
        :data:`ACTIVE_MARGIN`): then ``SolverSQP`` first, whose solution is the constrained
        optimum when it is inside every bound (a KKT point with zero multipliers); else
        ``SolverCSQP`` from the same guess (not from that solution: measured, its torques far
        beyond the bounds made the ADMM fail to converge), with at most
        ``config.constrained_iterations`` SQP iterations when set (the real-time budget).
        ``self.solver`` is the solver that gave the solution."""
        maxiter = self.config.ocp.max_iterations
        csqp = self.constrained_solver
        screened = 0
        if csqp is None or (self.config.constraints.unconstrained_first and not self._active):
            sqp = self.unconstrained_solver
            converged = sqp.solve(xs, us, maxiter, False)
            self.solver = sqp
            xs_opt, us_opt = np.array(sqp.xs), np.array(sqp.us)
            if csqp is None:
                return bool(converged), xs_opt, us_opt, 0
            assert self.bounds is not None and self._node_bounds is not None
            self._excess = self.bounds.excess(xs_opt, us_opt, self._node_bounds)
            if self._excess <= 0.0:
                return bool(converged), xs_opt, us_opt, 0
            screened = int(sqp.iter)
        converged = csqp.solve(xs, us, self.config.constrained_iterations or maxiter, False)
        self.solver = csqp
        xs_opt, us_opt = np.array(csqp.xs), np.array(csqp.us)
        assert self.bounds is not None and self._node_bounds is not None
        self._excess = self.bounds.excess(xs_opt, us_opt, self._node_bounds)
        self._active = self._excess >= -ACTIVE_MARGIN
        return bool(converged), xs_opt, us_opt, screened

    def _relax_bounds(self, x0: np.ndarray) -> bool:
        """Set nodes 1..N's state-only bounds for a solve from x̂ = ``x0``: the margins', or
        relaxed where the state a row starts from lies beyond them, coming back to them with
        ``constraints.recovery_time`` (:meth:`OcpBounds.node_bounds`; the torque-feedback q, v
        rows start from x₁, predicted here with node 0's model). True when relaxed. Nodes are
        written only on a change."""
        bounds = self.bounds
        if bounds is None:
            return False
        x1 = None
        if self.config.ocp.formulation == "torque_feedback":
            x1 = self._first_step(x0)
        if not bounds.beyond(x0, x1):
            if self._node_bounds is not self._margin_bounds:
                self._write_node_bounds(self._margin_bounds)
            return False
        node_bounds, relaxed = bounds.node_bounds(
            self.config.ocp.horizon, x0, x1, self.config.ocp.dt
        )
        self._write_node_bounds(node_bounds)
        return relaxed

    def _first_step(self, x0: np.ndarray) -> np.ndarray:
        """x₁ = f(x̂, u) of node 0's model; its (q, v) do not depend on u in the torque-feedback
        formulation (the filtered τ₀ of x̂ drives them), u = τ₀ is any control."""
        model = self.nodes[0].model
        data = self._first_step_data.get(id(model))
        if data is None:
            data = self._first_step_data[id(model)] = model.createData()
        model.calc(data, x0, x0[2 * self.robot.nv :])
        return np.array(data.xnext)

    def _write_node_bounds(self, bounds: np.ndarray) -> None:
        """Write the state-only bounds (N, 2, rows) of nodes 1..N where they changed."""
        previous = self._node_bounds
        nodes = [*self.nodes[1:], self.terminal_node]
        for k, node in enumerate(nodes):
            if previous is None or not np.array_equal(previous[k], bounds[k]):
                node.set_state_bounds(bounds[k, 0], bounds[k, 1])
        self._node_bounds = bounds

    def _check_constraints(self, xs: np.ndarray, us: np.ndarray, t: float) -> float:
        """The solution's largest excess over a bound (a fraction of its limit); beyond
        ``violation_tolerance`` nothing may be sent: the next solve starts cold (its guess,
        x̂ at every node, meets every state bound) and ConstraintViolationError is raised."""
        if self.bounds is None or self._node_bounds is None:
            return 0.0
        tolerance = self.config.constraints.violation_tolerance
        excess = self._excess  # of this solution (_solve)
        if excess <= tolerance:
            return max(excess, 0.0)
        violation, where = self.bounds.violation(xs, us, self._node_bounds)
        if violation > tolerance:
            self._prev_xs = self._prev_us = None
            raise ConstraintViolationError(
                f"MPC solution at t = {t:.4f} s breaks {where} by {violation:.3g} of its limit "
                f"(tolerance {tolerance:g}): not sent",
                violation,
                where,
            )
        return violation

    def _remove_friction_share(self, x_hat: np.ndarray, t: float) -> None:
        """Filter the contact point's sliding velocity of x̂'s (q, v) at t (s) in, and replace the
        normal entry of x̂'s measured force by the normal force without the friction drag's
        share along the assumed normal, in place
        (:func:`~ffmpc_core.contact_friction.normal_force_without_friction`). Unchanged while
        the sliding direction is unknown (slow or at rest)."""
        assert self._sliding is not None
        nv = self.robot.nv
        self._sliding.update(x_hat[:nv], x_hat[nv : 2 * nv], t)
        direction = self._sliding.direction()
        if direction is None:
            return
        index = 2 * nv + (0 if self.nc == 1 else self.config.contact.normal_axis)
        x_hat[index] = normal_force_without_friction(
            x_hat[index], direction, self._sliding.normal, self.config.contact.friction_coefficient
        )

    def _observe_contact(self, meas: MpcMeasurement, t: float) -> None:
        """Feed a guarded approach (:class:`~ffmpc_core.tasks.GuardedTask`) the measured normal
        force of ``meas`` at the task time of t (s), before the references are written: its
        detection switches the nodes to the contact model. A non-finite λ̂ (a faulty reading)
        is not fed (the detection stays as it is); InputError without a force or with the
        wrong number of entries: every formulation needs λ̂ to detect the contact."""
        if self._observe_force is None:
            return
        if meas.force is None:
            raise InputError("measurement has no force (the guarded approach detects with it)")
        force = np.asarray(meas.force, dtype=float).reshape(-1)
        if force.shape != (self.nc,):
            raise InputError(f"measurement force has {force.size} entries, expected {self.nc}")
        self._observe_force(self._normal_component(force), self.task_time(t))

    def _normal_component(self, force: np.ndarray) -> float:
        """The normal entry of a contact force in the contact configuration's layout, N."""
        return float(force[0] if self.nc == 1 else force[self.config.contact.normal_axis])

    def _predicted_rigid_normal_force(self) -> float:
        """Normal force λ^r of the rigid-contact predictor's last calc, N (0 out of contact)."""
        node = cast(RigidContactOcpNode, self._predictor)
        return self._normal_component(node.contact_force(self._predictor_data))

    @staticmethod
    def _vector(value: npt.ArrayLike | None, n: int, name: str) -> np.ndarray:
        if value is None:
            raise InputError(f"measurement has no {name}")
        arr = np.asarray(value, dtype=float).reshape(-1)
        if arr.shape != (n,):
            raise InputError(f"measurement {name} has {arr.size} entries, expected {n}")
        if not np.all(np.isfinite(arr)):
            raise InputError(f"measurement {name} is not finite: {arr}")
        return arr

    def _reference(self, t: float, ref: NodeReference) -> NodeReference:
        """The schedule's reference at controller time t (at :meth:`task_time`), written into
        ``ref`` when the schedule can; after a resumption its force blends in from the measured
        one (:func:`resume_force_reference`)."""
        task_t = self.task_time(t)
        if self._reference_into is not None:
            ref = self._reference_into(task_t, ref)
        else:
            ref = self.schedule.reference(task_t, self.nc)
        if self._resumed_force is not None and self._resumed_at is not None and ref.in_contact:
            resume_force_reference(ref.force, self._resumed_force, t - self._resumed_at)
        return ref

    def _update_references(self, t: float) -> None:
        """Node k gets the reference at t + kΔt, the terminal node the one at t + NΔt."""
        dt = self.config.ocp.dt
        changed = False
        refs = self._refs
        for k, node in enumerate(self.nodes):
            changed |= node.set_reference(self._reference(t + k * dt, refs[k]))
        horizon_end = t + len(self.nodes) * dt
        changed |= self.terminal_node.set_reference(self._reference(horizon_end, refs[-1]))
        if changed:
            self._make_problem()

    def _warm_start(self, x0: np.ndarray, t: float) -> tuple[list, list]:
        """Previous solution shifted by the elapsed time (in node units), x₀ replaced by x̂."""
        n = self.config.ocp.horizon
        if self._prev_xs is None:
            gravity = self.robot.gravity(x0[: self.robot.nq])
            xs = [x0.copy() for _ in range(n + 1)]
            u0 = (
                gravity
                if self.config.ocp.formulation != "torque_feedback"
                else x0[-self.robot.nv :]
            )
            return xs, [u0.copy() for _ in range(n)]
        assert self._prev_t is not None and self._prev_us is not None  # set with _prev_xs
        shift = (t - self._prev_t) / self.config.ocp.dt
        grid = np.arange(n + 1) + shift
        xs_arr = _interp_rows(self._prev_xs, grid)
        us_arr = _interp_rows(self._prev_us, grid[:n])
        xs_arr[0] = x0
        return list(xs_arr), list(us_arr)

    def _command(
        self, x0: np.ndarray, xs: np.ndarray, us: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        nv = self.robot.nv
        K0 = np.array(self.solver.K[0])
        u0 = us[0]
        if self.config.ocp.formulation != "torque_feedback":
            return u0, -K0
        tau0 = x0[2 * nv :]
        tau1 = lowpass_filter_step(tau0, u0, self._alpha)  # eq 13: τ₁* = ατ₀ + (1 − α)w₀*
        torque = interpolate_torque(tau0, tau1, self._epsilon)  # eq 15: τ₀ + ε(τ₁* − τ₀)
        # ∂τ̃/∂x through both, with ∂w₀*/∂x = −K₀ (Riccati gain)
        gain_w = self._epsilon * (1.0 - self._alpha)
        gain = -gain_w * K0
        gain[:, 2 * nv :] += (1.0 - gain_w) * np.eye(nv)
        return torque, gain


def _as_setting(value: npt.ArrayLike) -> float | tuple[float, ...]:
    """A scalar or per-axis ContactConfig setting from a number or a sequence."""
    arr = np.asarray(value, dtype=float)
    return float(arr) if arr.ndim == 0 else tuple(float(v) for v in arr.reshape(-1))


def _set_node_weight(node: OcpNode, name: str, value: float) -> None:
    """c of cost ``name`` in one node of any formulation (the soft-contact models' own setter;
    the crocoddyl cost sums of the classical and torque-feedback nodes, both contact models)."""
    model = node.model
    if hasattr(model, "set_weight"):
        model.set_weight(name, value)
        return
    models = getattr(node, "_models", {None: model}).values()
    for m in models:
        differential = m.differential
        costs = differential.costs.costs
        if name in costs:
            costs[name].weight = value


def _interp_rows(rows: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Rows of ``rows`` linearly interpolated at fractional indices ``grid`` (held at the ends)."""
    idx = np.clip(grid, 0.0, rows.shape[0] - 1.0)
    lo = np.floor(idx).astype(int)
    hi = np.minimum(lo + 1, rows.shape[0] - 1)
    frac = (idx - lo)[:, None]
    return (1.0 - frac) * rows[lo] + frac * rows[hi]
