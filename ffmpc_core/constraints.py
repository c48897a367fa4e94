"""Hard constraints of the three OCP formulations (issue 23), solved by ``mim_solvers.SolverCSQP``.

Every node of every formulation carries the same kinds of constraint rows g(x, u) with bounds
g_lb ≤ g ≤ g_ub (crocoddyl's convention; CSQP's ADMM keeps them), all linear in (x, u):

* **state rows**, one per state entry, in the order of x: joint positions, as the braking
  look-ahead q + T_b·v (rad; T_b = ``position_braking_time``) inside ``1 − position_margin`` of
  each joint's range about its middle, joint velocities v (rad/s) inside
  ``±(1 − velocity_margin)·velocity_limit``; then the formulation's third block:
  torque-feedback τ (N·m) inside ``±(1 − torque_margin)·torque_limit``, force-feedback λ (N):
  the normal entry in ``[0, max_force]`` (no pulling), the tangential ones (3-D) unbounded;
* **friction-cone rows** (force-feedback, 3-D contact only): the inscribed four-sided pyramid of
  the cone ‖λ_t‖ ≤ μ·λ_n, i.e. μ'·λ_n ∓ λ_a ≥ 0 and μ'·λ_n ∓ λ_b ≥ 0 with μ' = μ/√2 and a, b the
  two tangential axes of the force frame (crocoddyl's ``FrictionCone`` with four facets and its
  inner approximation; the authors' library uses the round cone μλ_n − ‖λ_t‖ ≥ 0, whose
  derivative is undefined at λ_t = 0, where a 1-D-like push starts);
* **control rows** (running nodes only): the joint torque u = τ (classical, force-feedback) in
  ``±(1 − torque_margin)·torque_limit``; the torque-feedback control w (the unfiltered torque
  command the filter tracks, eq 9) in ``±torque_limit``, the drives' full range: the margin is
  kept on τ, the torque the robot feels.

Why q + T_b·v and not q: kept for all t, q + T_b·q̇ ≤ q̄ makes the distance to the bound q̄ − q
shrink at most like exp(−t/T_b), so a joint brakes smoothly as it nears its limit and never
crosses it. A bound on q alone is a wall the 15 ms horizon sees too late: measured, the
classical MPC without the PID drifted joint 4 to 95 % of its range at t = 1.79 s (seed 0), then
hit the wall with the torque bound (bang-bang), and the run ended at 2.4× joint 6's velocity
limit with 22 refused solves.

The state rows and the cone rows ("state-only rows", :attr:`OcpBounds.state_matrix`) depend on
x alone. Which nodes carry them (:meth:`OcpBounds.node_bounds`): not the initial node, whose
state is x̂ (fixed by the problem: its state-only rows get infinite bounds), nor a node whose
row the controls cannot move yet (the torque-feedback node 1's q and v follow from x̂ alone:
those rows start at node 2). And where the state a row starts from (x̂, or the predicted x₁
for those rows) lies beyond a bound (a measured velocity above the margin, a measured force
below 0) the bound of that row is relaxed for this solve: it starts at that value and comes
back to the margin's bound exponentially, b + (s − b)·exp(−t_k/T_r) at node k (s the row's
value now, t_k the node's time after the state it starts from, T_r = ``recovery_time``), so
that a measured state beyond a margin never makes the problem infeasible by construction, and
the plan always asks the row back inside. Holding the row where it is ("not further out than
now") has no restoring term: whatever the model does not see (actuation gain error, the
command delay, the table's friction) pushes the robot a little beyond each plan, the bound
follows it from solve to solve, and the excess ratchets outward (measured: the classical MPC
on the 6 rad/s circle, seed 100, the elbow's velocity 0.81 → 1.009 of its limit in 70 ms with
every plan holding it). A solve
whose solution still breaks a bound by more than ``violation_tolerance`` of the limit raises
:class:`ConstraintViolationError` (the caller's fallback is the safe hold,
:mod:`ffmpc_core.polishing_loop`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ffmpc_core.config import FORMULATIONS, ContactConfig
from ffmpc_core.declaration import param
from ffmpc_core.errors import ConfigError, SolverError
from ffmpc_core.robots import RobotModel

#: Row groups of a node's constraint vector g, in this order (a group may be absent).
ROW_GROUPS = ("state", "friction_cone", "control")
#: Rows of the friction-cone pyramid (3-D force-feedback).
CONE_ROWS = 4


class ConstraintViolationError(SolverError):
    """The MPC's solution breaks a hard constraint by more than the stated tolerance: nothing
    may be sent; the caller engages the safe hold. ``violation`` is the largest excess as a
    fraction of its limit, ``where`` says which row (``"v[3] at node 2"``)."""

    def __init__(self, message: str, violation: float, where: str) -> None:
        super().__init__(message)
        self.violation = violation
        self.where = where


@dataclass(frozen=True)
class ConstraintConfig:
    """The hard constraints of the MPC and the settings of their solver (``mpc.constraints.*``).

    Attributes:
        enabled: constraints on (``SolverCSQP``); off: the unconstrained problem solved by
            ``SolverSQP`` as before issue 23 (for comparison).
        position_margin: fraction of each joint's half range kept free at both ends (0.05: the
            bound is 95 % of the way from the middle to the limit). A 15 ms horizon sees only
            Δt·N·v ≈ 0.03 rad ahead at the velocity bound, so the margin, not the horizon, is
            what leaves room to brake; 5 % is 0.10–0.15 rad on the iiwa and the Panda.
        position_braking_time: T_b of the joint-position rows q + T_b·v, s (module docstring):
            a joint that reaches its position row at its velocity bound must decelerate at
            v/T_b, 15–28 rad/s² for velocity bounds of 0.9 × 1.71–3.14 rad/s; a
            shorter T_b asks more of the torques, a longer one slows joints earlier.
        velocity_margin: fraction of the velocity limits kept free (0.10: |v| ≤ 0.9·limit, the
            bound the quadratic barrier had). The MPC bounds its predicted velocities, but the
            robot moves with what the prediction does not see (δo, sensing delay, actuation
            bias, contact transients): the margin is the room for that. The polishing
            scenarios set 0.35: with 0.10 the elbow (joint 3) overshot its bound by ~13 % at
            the circle's start and the robot's velocity reflex stopped it (1.015×, seed 101);
            0.20 left it at 0.90× there, but on the paper study's 20 seeds the reflex still
            stopped 22 of its 420 runs with the PID (mostly the torque-feedback MPC after the
            push, on A6), and 0.30 stops 2; at the searched weights 0.30 let the push drive A3
            to 1.003× (force-feedback, seed 119), 0.35 to 0.976× (docs: tuning results, "The
            defaults from the searches"). The impact's force-feedback MPC keeps 0.10 (with
            0.20 it brakes harder at the handover and breaks the Panda's acceleration limits).
        recovery_time: T_r, s: a row whose value at the state it starts from lies beyond its
            bound is asked back inside with this time constant, its bound at node k
            b + (s − b)·exp(−t_k/T_r) (module docstring). 0.01 s: beyond a velocity bound by
            10 % of the limit, a planned deceleration of 10 limits/s (15 rad/s² on the iiwa's
            base joint), 22 % of the excess left at the end of the 15 ms horizon. Measured on
            the 6 rad/s circle and the push (classical, seeds 100–101, reflex off): the largest
            |q̇|/limit 1.013–1.081 with the hold ("not further out than now", which lets model
            errors ratchet a joint outward), 0.920–1.001 with 0.02 s, 0.951–0.965 with 0.01 s;
            no solve refused.
        torque_margin: fraction of the torque limits kept free on the MPC's torque (u for
            classical and force-feedback, the filtered τ of the torque-feedback state); 0.05
            leaves room for the low level's PID and feedback corrections before its saturation.
        max_force: the largest normal force the force-feedback MPC may plan, N (λ_n ≤ this);
            150 N is three times the polishing reference (50 N) and the study's bound on λmax.
        friction_coefficient: μ of the friction cone on the 3-D force state (the table's μ of
            the paper's simulation, VI-B: 0.5); the pyramid is inscribed (μ/√2 per axis).
        max_qp_iterations: ADMM iterations per SQP iteration at most (``max_qp_iters``): 100
            is four convergence checks at ``rho_update_interval`` 25 and bounds the work of a
            QP that does not converge (the median is the first check, 25).
        eps_abs, eps_rel: ADMM termination tolerances on the primal and dual residuals, in the
            rows' units (fractions of the limits): 1e-3 is a tenth of ``violation_tolerance``.
            Tighter ones cost more ADMM iterations for the same closed loop (README).
        rho_update_interval: ADMM iterations between two convergence checks (and updates of
            the penalty ρ with a new factorisation): mim_solvers' default, 25. With 5 the
            force-capped force-feedback MPC (``ffmpc bench mpc``'s ``force_feedback_capped``)
            used all 8 SQP iterations in 74 % of its solves, with 25 in 2.5 % (README).
        kkt_tolerance: termination tolerance of ``SolverCSQP`` on its KKT residual, which
            contains the ADMM's multipliers: at ``eps_abs`` 1e-3 they keep it near 1e-3; with
            the unconstrained 1e-4 (``MpcConfig.ocp.kkt_tolerance``) more solves with an active
            bound use all 8 SQP iterations (README: 7.0 % against 2.5 % of the force-capped
            bench case's).
        unconstrained_first: solve with ``SolverSQP`` first and call ``SolverCSQP`` only when
            that solution breaks a bound, or when the last constrained solution had one
            active. An unconstrained solution inside every bound is the constrained optimum (a
            KKT point with zero multipliers), and the Riccati solve is exact where the ADMM is
            approximate and costs several passes per SQP iteration (README: the bench's cost).
        max_solve_time: wall-clock cap of one solve, s (0: none). Applied in real-time runs
            only (the MPC node with ``lockstep`` false): a lockstep run must give the same
            numbers whatever the CPU speed, so it never uses a wall-clock cap. 0 by default in
            real time too: on a shared machine a late solve is mostly preemption, which a cap
            cannot shorten, and a cut ADMM solution breaks its bounds more often (then refused);
            the low level already holds when a command is late (``pid.stale_timeout``).
        violation_tolerance: largest excess over a bound allowed in a solution, as a fraction
            of that row's limit (velocity limit, torque limit, half range, max_force); beyond
            it the solve raises :class:`ConstraintViolationError`. 0.01 keeps a tolerated
            excess well inside every margin.
    """

    enabled: bool = param(
        True, "", None, "hard constraints on (mim_solvers SolverCSQP); off: unconstrained SolverSQP"
    )
    position_margin: float = param(
        0.05,
        "",
        (0.0, 0.99),
        "fraction of each joint's half range kept free by the joint-position box",
    )
    position_braking_time: float = param(
        0.1,
        "s",
        (0.0, 10.0),
        "T_b of the joint-position rows q + T_b·q̇ (a joint brakes smoothly near its bound)",
    )
    velocity_margin: float = param(
        0.10, "", (0.0, 0.99), "fraction of the joint velocity limits kept free by the velocity box"
    )
    recovery_time: float = param(
        0.01,
        "s",
        (1e-4, 10.0),
        "T_r: a row that starts beyond its bound is planned back inside, exp(−t/T_r)",
    )
    torque_margin: float = param(
        0.05,
        "",
        (0.0, 0.99),
        "fraction of the joint torque limits kept free by the torque box (u; τ state)",
    )
    max_force: float = param(
        150.0,
        "N",
        (1e-3, 1e5),
        "largest normal force of the force-feedback state (its box is [0, this])",
    )
    friction_coefficient: float = param(
        0.5,
        "",
        (0.0, 10.0),
        "μ of the friction cone on the 3-D force state (inscribed pyramid, μ/√2 per axis)",
    )
    max_qp_iterations: int = param(100, "", (1, 100000), "ADMM iterations per SQP iteration")
    eps_abs: float = param(1e-3, "", (1e-12, 1.0), "ADMM absolute tolerance")
    eps_rel: float = param(1e-3, "", (1e-12, 1.0), "ADMM relative tolerance")
    rho_update_interval: int = param(
        25, "", (1, 100000), "ADMM iterations between convergence checks and penalty updates"
    )
    kkt_tolerance: float = param(1e-3, "", (1e-12, 1.0), "KKT tolerance of the constrained SQP")
    unconstrained_first: bool = param(
        True,
        "",
        None,
        "solve unconstrained (SolverSQP) first; SolverCSQP only when that breaks a bound",
    )
    max_solve_time: float = param(
        0.0,
        "s",
        (0.0, 10.0),
        "wall-clock cap of a solve in real-time runs only (lockstep runs ignore it); 0: none",
    )
    violation_tolerance: float = param(
        0.01,
        "",
        (1e-9, 1.0),
        "largest excess over a bound (fraction of its limit) before a solve is refused",
    )

    def __post_init__(self) -> None:
        for name in ("position_margin", "velocity_margin", "torque_margin"):
            value = float(getattr(self, name))
            if not 0.0 <= value < 1.0:  # also rejects NaN
                raise ConfigError(f"constraints {name} must be in [0, 1), got {value}")
        t_b = float(self.position_braking_time)
        if not (math.isfinite(t_b) and t_b >= 0.0):
            raise ConfigError(f"constraints position_braking_time must be >= 0 s, got {t_b}")
        t_r = float(self.recovery_time)
        if not (math.isfinite(t_r) and t_r > 0.0):
            raise ConfigError(f"constraints recovery_time must be > 0 s, got {t_r}")
        if not (math.isfinite(self.max_force) and self.max_force > 0.0):
            raise ConfigError(f"constraints max_force must be > 0 N, got {self.max_force}")
        mu = float(self.friction_coefficient)
        if not (math.isfinite(mu) and mu >= 0.0):
            raise ConfigError(f"constraints friction_coefficient must be >= 0, got {mu}")
        if self.max_qp_iterations < 1 or self.rho_update_interval < 1:
            raise ConfigError("constraints max_qp_iterations and rho_update_interval must be >= 1")
        for name in ("eps_abs", "eps_rel", "kkt_tolerance", "violation_tolerance"):
            value = float(getattr(self, name))
            if not (math.isfinite(value) and value > 0.0):
                raise ConfigError(f"constraints {name} must be > 0, got {value}")
        t = float(self.max_solve_time)
        if not (math.isfinite(t) and t >= 0.0):
            raise ConfigError(f"constraints max_solve_time must be >= 0 s, got {t}")


@dataclass(frozen=True)
class OcpBounds:
    """The constraint rows of one formulation's nodes (module docstring) and their bounds.

    Every row is **normalised by its limit** (a velocity row is v/v_max, a torque row τ/τ_max,
    a position row q/h with h the joint's half range, a force or cone row λ/λ_max): its bounds
    and its values are fractions of the limit (0.9 = 90 % of it), so that the ADMM of
    ``SolverCSQP`` sees rows of one scale whatever their units (with raw N·m rows beside the
    tiny torque weights, its penalty ρ grew to ~500 and the SQP never met the KKT tolerance:
    measured), and an excess reads directly as a fraction of the limit.

    Attributes:
        formulation: the formulation.
        nv: joints; nx: state size; nu: control size.
        state_matrix: S (n_state_rows × nx): the state-only rows are S·x (the state box, then
            the friction-cone rows, if any; each divided by its limit).
        state_lower, state_upper: their bounds at nodes 1..N (fractions of the limits).
        state_limit: the limit each state-only row was divided by (rad, rad/s, N·m, N).
        control_scale: c (nu), the control rows are c ∘ u (c = 1 / the control limit, 1/N·m).
        control_lower, control_upper: their bounds (fractions of the limits).
        friction_coefficient: μ of the cone rows; None when there are none.
        names: a readable name per state-only row then per control row (``"v[3]"``; a joint
            position row ``q[j]`` is q + T_b·v).
        first_node: per state-only row, the first node whose value the controls move (1; the
            torque-feedback joint positions and velocities: 2, since node 1's (q, v) follow
            from x̂ alone, whatever w₀): the row is free at the nodes before.
        recovery_time: T_r of a relaxed row's return to its bound, s
            (:attr:`ConstraintConfig.recovery_time`, :meth:`node_bounds`).
    """

    formulation: str
    nv: int
    nx: int
    nu: int
    state_matrix: np.ndarray
    state_lower: np.ndarray
    state_upper: np.ndarray
    state_limit: np.ndarray
    control_scale: np.ndarray
    control_lower: np.ndarray
    control_upper: np.ndarray
    friction_coefficient: float | None
    names: tuple[str, ...]
    first_node: np.ndarray
    recovery_time: float = 0.01

    @property
    def n_state_rows(self) -> int:
        """Rows of the state constraint matrix (position, velocity and force-state boxes)."""
        return int(self.state_matrix.shape[0])

    @property
    def has_cone(self) -> bool:
        """Whether the friction-cone rows on the 3-D force state are present."""
        return self.friction_coefficient is not None

    def ng(self, terminal: bool) -> int:
        """Constraint rows of a running (state-only + control) or terminal (state-only) node."""
        return self.n_state_rows + (0 if terminal else self.nu)

    def bounds(
        self,
        terminal: bool,
        state_lower: np.ndarray | None = None,
        state_upper: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """(g_lb, g_ub) of a node: its state-only rows' bounds (default the margins'), then the
        control rows' (running nodes)."""
        lo = self.state_lower if state_lower is None else state_lower
        hi = self.state_upper if state_upper is None else state_upper
        if terminal:
            return np.array(lo, dtype=float), np.array(hi, dtype=float)
        return np.concatenate([lo, self.control_lower]), np.concatenate([hi, self.control_upper])

    def state_rows(self, x: np.ndarray) -> np.ndarray:
        """The state-only rows' values S·x of a state (or of each row of a stack of states)."""
        return np.asarray(x) @ self.state_matrix.T

    def node_bounds(
        self,
        horizon: int,
        x0: np.ndarray | None = None,
        x1: np.ndarray | None = None,
        dt: float | None = None,
    ) -> tuple[np.ndarray, bool]:
        """The state-only rows' bounds at nodes k = 1..N (nodes ``dt`` s apart), an array
        (N, 2, n_state_rows) of (lower, upper), and whether any was relaxed.

        A row is free (±inf) before its :attr:`first_node` (where the controls start to move
        it). From there, the margins' bounds, relaxed so that the measured state does not make
        the problem infeasible by construction: a row whose value s at the state it starts from
        (x̂ = ``x0`` for rows first constrained at node 1, the predicted ``x1`` for those at node
        2) is beyond its bound b gets at node k the bound b + (s − b)·exp(−t_k/T_r), t_k =
        (k − first_node + 1)·dt the time since that state and T_r = :attr:`recovery_time`: the
        plan asks the row back inside at a stated rate (for a joint position row q + T_b·v, a
        deceleration beyond v/T_b). Holding the bound at s instead ("not further out than now")
        let what the model does not see push the joint a little further at every solve, the
        bound following it (module docstring). Without ``x0``: the margins' bounds (nothing
        relaxed); ``dt`` is needed when a row is relaxed (ConfigError)."""
        out = np.empty((horizon, 2, self.n_state_rows))
        out[:, 0] = self.state_lower
        out[:, 1] = self.state_upper
        k = np.arange(1, horizon + 1)[:, None]
        early = k < self.first_node  # (N, rows): before the row's first node
        out[:, 0][early] = -np.inf
        out[:, 1][early] = np.inf
        if x0 is None:
            return out, False
        start = self.state_rows(x0)
        second = self.first_node == 2
        if second.any():
            if x1 is None:
                raise ConfigError("rows first constrained at node 2 need the predicted x1")
            start = np.where(second, self.state_rows(x1), start)
        below = start < self.state_lower
        above = start > self.state_upper
        if not (below.any() or above.any()):
            return out, False
        if dt is None or not (math.isfinite(dt) and dt > 0.0):
            raise ConfigError(f"relaxed bounds need the node duration dt > 0 s, got {dt}")
        decay = np.exp(-(k - self.first_node + 1) * dt / self.recovery_time)  # (N, rows)
        lower = self.state_lower + (start - self.state_lower) * decay
        upper = self.state_upper + (start - self.state_upper) * decay
        out[:, 0] = np.where(below & ~early, lower, out[:, 0])
        out[:, 1] = np.where(above & ~early, upper, out[:, 1])
        return out, True

    def excess(self, xs: np.ndarray, us: np.ndarray, node_bounds: np.ndarray) -> float:
        """The largest signed excess of a solution's rows over their bounds (fractions of the
        limits; > 0: a bound is broken, < 0: the smallest slack), with the state-only rows'
        bounds ``node_bounds`` of :meth:`node_bounds` at nodes 1..N (node 0's state is x̂: its
        rows do not count) and the control rows at nodes 0..N−1. Written for the MPC's hot
        path (a few vector operations)."""
        values = xs[1:] @ self.state_matrix.T
        u = us * self.control_scale
        return float(
            max(
                (node_bounds[:, 0] - values).max(),
                (values - node_bounds[:, 1]).max(),
                (self.control_lower - u).max(),
                (u - self.control_upper).max(),
            )
        )

    def violation(
        self,
        xs: np.ndarray,
        us: np.ndarray,
        node_bounds: np.ndarray | None = None,
    ) -> tuple[float, str]:
        """The largest excess over a bound of a solution (states xs at nodes 0..N, controls us
        at 0..N−1), as a fraction of its row's limit, and where it is (``"v[3] at node 2"``;
        0 and "" when none). Node 0's state is x̂ (fixed): only its control rows count.
        ``node_bounds``: the state-only rows' bounds at nodes 1..N (:meth:`node_bounds`; default
        the margins' at every node)."""
        if node_bounds is None:
            node_bounds = self.node_bounds(xs.shape[0] - 1)[0]
        worst = self.excess(xs, us, node_bounds)
        if worst <= 0.0:
            return 0.0, ""
        values = self.state_rows(xs[1:])
        lo, hi = node_bounds[:, 0], node_bounds[:, 1]
        state_excess = np.maximum(lo - values, values - hi)
        u = us * self.control_scale
        control_excess = np.maximum(self.control_lower - u, u - self.control_upper)
        if state_excess.max() >= control_excess.max():
            node, row = np.unravel_index(int(np.argmax(state_excess)), state_excess.shape)
            return worst, f"{self.names[row]} at node {node + 1}"
        node, row = np.unravel_index(int(np.argmax(control_excess)), control_excess.shape)
        return worst, f"{self.names[self.n_state_rows + row]} at node {node}"

    def beyond(self, x0: np.ndarray, x1: np.ndarray | None = None) -> bool:
        """Whether the state a row starts from (x̂, or x₁ for rows first constrained at node
        2) lies beyond a bound: then :meth:`node_bounds` relaxes it."""
        values = self.state_matrix @ x0
        if x1 is not None:
            values = np.where(self.first_node == 2, self.state_matrix @ x1, values)
        return bool((values < self.state_lower).any() or (values > self.state_upper).any())


def _position_bounds(robot: RobotModel, margin: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """q bounds (rad) at ``1 − margin`` of each half range, and the half ranges (the limit a
    position row is divided by; 1 rad for a joint without position limits)."""
    lower, upper = robot.state_limit_bounds(1.0 - margin)
    nv = robot.nv
    full_lo, full_hi = robot.state_limit_bounds(1.0)
    half = 0.5 * (full_hi[:nv] - full_lo[:nv])
    half = np.where(np.isfinite(half), half, 1.0)
    return lower[:nv], upper[:nv], half


def _cone_matrix(nx: int, first: int, normal: int, mu: float) -> np.ndarray:
    """The four rows μ'·λ_n ∓ λ_a, μ'·λ_n ∓ λ_b (μ' = μ/√2) on a state whose force block starts
    at index ``first``, ``normal`` the normal axis of the 3 force entries."""
    tangential = [a for a in range(3) if a != normal]
    rows = np.zeros((CONE_ROWS, nx))
    for i, axis in enumerate(tangential):
        for j, sign in enumerate((-1.0, 1.0)):
            row = rows[2 * i + j]
            row[first + normal] = mu / math.sqrt(2.0)
            row[first + axis] = sign
    return rows


def ocp_bounds(
    robot: RobotModel, formulation: str, contact: ContactConfig, config: ConstraintConfig
) -> OcpBounds:
    """The constraint rows and bounds of ``formulation`` on ``robot`` (module docstring)."""
    if formulation not in FORMULATIONS:
        raise ConfigError(f"formulation must be one of {FORMULATIONS}, got {formulation!r}")
    nv = robot.nv
    q_lo, q_hi, half_range = _position_bounds(robot, config.position_margin)
    v_lo, v_hi = robot.state_limit_bounds(1.0 - config.velocity_margin)
    v_limit = np.where(np.isfinite(robot.velocity_limit), np.abs(robot.velocity_limit), 1.0)
    tau_limit = np.abs(np.asarray(robot.torque_limit, dtype=float))
    tau_fraction = np.full(nv, 1.0 - config.torque_margin)
    lower = [q_lo, v_lo[nv:]]
    upper = [q_hi, v_hi[nv:]]
    limit = [half_range, v_limit]
    names = [f"q[{j}]" for j in range(nv)] + [f"v[{j}]" for j in range(nv)]
    control_fraction = tau_fraction
    cone: float | None = None
    if formulation == "torque_feedback":
        lower.append(-tau_fraction * tau_limit)
        upper.append(tau_fraction * tau_limit)
        limit.append(tau_limit)
        names += [f"tau[{j}]" for j in range(nv)]
        control_fraction = np.ones(nv)  # w: the drives' full range (module docstring)
    elif formulation == "force_feedback":
        nc = contact.dimension
        normal = 0 if nc == 1 else contact.normal_axis
        f_lo = np.full(nc, -np.inf)
        f_hi = np.full(nc, np.inf)
        f_lo[normal], f_hi[normal] = 0.0, config.max_force
        lower.append(f_lo)
        upper.append(f_hi)
        limit.append(np.full(nc, config.max_force))
        names += [f"force[{j}]" for j in range(nc)]
        if nc == 3:
            cone = float(config.friction_coefficient)
    state_limit = np.concatenate(limit)
    nx = state_limit.size
    matrix = np.diag(1.0 / state_limit)
    # joint positions as the braking look-ahead q + T_b·v (module docstring)
    matrix[np.arange(nv), nv + np.arange(nv)] = config.position_braking_time / half_range
    state_lower = np.concatenate(lower) / state_limit
    state_upper = np.concatenate(upper) / state_limit
    if cone is not None:
        rows = _cone_matrix(nx, 2 * nv, contact.normal_axis, cone) / config.max_force
        matrix = np.vstack([matrix, rows])
        state_lower = np.concatenate([state_lower, np.zeros(CONE_ROWS)])
        state_upper = np.concatenate([state_upper, np.full(CONE_ROWS, np.inf)])
        state_limit = np.concatenate([state_limit, np.full(CONE_ROWS, config.max_force)])
        names += [f"friction_cone[{i}]" for i in range(CONE_ROWS)]
    names += [f"u[{j}]" for j in range(nv)]
    first_node = np.ones(matrix.shape[0], dtype=int)
    if formulation == "torque_feedback":
        first_node[: 2 * nv] = 2  # q₁, v₁ = f(q₀, v₀, τ₀): w₀ only moves τ₁
    return OcpBounds(
        formulation=formulation,
        nv=nv,
        nx=nx,
        nu=nv,
        state_matrix=matrix,
        state_lower=state_lower,
        state_upper=state_upper,
        state_limit=state_limit,
        control_scale=1.0 / tau_limit,
        control_lower=-control_fraction,
        control_upper=control_fraction.copy(),
        friction_coefficient=cone,
        names=tuple(names),
        first_node=first_node,
        recovery_time=float(config.recovery_time),
    )


class ConstraintRows:
    """The constraint rows g = [S·x; c ∘ u] of the Python action models (the reference of
    ``cpp/constraint_rows.hpp``): S (n_s × nx) the state-only rows, c ∘ u (c: ``control_scale``,
    nu entries) in a running node only (``control``). Jacobians Gx = [S; 0], Gu = [0; diag(c)].
    No rows when S has none."""

    def __init__(
        self,
        state_matrix: np.ndarray | None,
        control_scale: np.ndarray | None,
        nx: int,
        nu: int,
        control: bool,
    ) -> None:
        matrix = np.zeros((0, nx)) if state_matrix is None else np.asarray(state_matrix, float)
        if matrix.ndim != 2 or (matrix.shape[0] > 0 and matrix.shape[1] != nx):
            raise ConfigError(f"constraint matrix has shape {matrix.shape}, expected (rows, {nx})")
        if not np.isfinite(matrix).all():
            raise ConfigError("constraint matrix must be finite")
        self.state_matrix = matrix.copy()
        self.nx, self.nu = nx, nu
        self.n_state = int(matrix.shape[0])
        self.control = bool(control) and self.n_state > 0
        scale = np.ones(nu) if control_scale is None else np.asarray(control_scale, float)
        if self.control and (scale.shape != (nu,) or not np.isfinite(scale).all()):
            raise ConfigError(f"constraint control scale must have {nu} finite entries")
        self.control_scale = scale.copy()

    @property
    def ng(self) -> int:
        """Rows of a call with a control (a running node)."""
        return self.n_state + (self.nu if self.control else 0)

    @property
    def ng_T(self) -> int:  # noqa: N802 (crocoddyl's name)
        """Rows of a call without a control (a terminal node): the state-only rows."""
        return self.n_state

    def calc(self, g: np.ndarray, x: np.ndarray, u: np.ndarray | None = None) -> None:
        """g = [S·x; c ∘ u] (u's rows when given and the node has them)."""
        ns = self.n_state
        if ns == 0:
            return
        g[:ns] = self.state_matrix @ x
        if self.control and u is not None:
            g[ns : ns + self.nu] = self.control_scale * u

    def calc_diff(self, Gx: np.ndarray, Gu: np.ndarray) -> None:  # noqa: N803 (crocoddyl's)
        """Gx = [S; 0], Gu = [0; diag(c)]."""
        ns = self.n_state
        if ns == 0:
            return
        Gx[:ns] = self.state_matrix
        if self.control:
            Gx[ns : ns + self.nu] = 0.0
            Gu[:ns] = 0.0
            Gu[ns : ns + self.nu] = np.diag(self.control_scale)
