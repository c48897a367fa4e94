"""Helpers of the OCP-formulation tests (classical and torque-feedback nodes): rich weights
and references so every cost term matters, seeded random states, a relative-tolerance check and
a small SQP solve."""

from __future__ import annotations

import crocoddyl  # noqa: F401  (loads boost before mim_solvers)
import mim_solvers
import numpy as np

from ffmpc_core.config import CostWeights, NodeReference


def rich_weights(
    rng: np.random.Generator,
    nc: int,
    isotropic_velocity: bool = False,
    lowpass_input=0.0,
    authors_terms: bool = False,
) -> CostWeights:
    """Non-trivial weights so that every term of eq 25 (and eq 28) matters. ``authors_terms``:
    the orientation and angular-velocity costs (all three formulations) and the low-pass
    terminal torque term (torque-feedback) too (else 0)."""
    return CostWeights(
        ee_rotation=2.5 if authors_terms else 0.0,
        ee_angular_velocity=0.7 if authors_terms else 0.0,
        lowpass_terminal_torque=0.05 if authors_terms else 0.0,
        posture=0.7,
        posture_diag=tuple(rng.uniform(0.5, 2.0, 7)),
        joint_velocity=0.3,
        joint_velocity_diag=tuple(rng.uniform(0.5, 2.0, 7)),
        torque=0.05,
        torque_diag=tuple(rng.uniform(0.5, 2.0, 7)),
        ee_position=20.0,
        ee_position_diag=(1.0, 2.0, 0.5),
        ee_velocity=3.0,
        ee_velocity_diag=1.5 if isotropic_velocity else (1.0, 2.0, 3.0),
        force=0.2,
        force_diag=(1.0, 0.5, 2.0)[:nc] if nc > 1 else 1.5,
        lowpass_input=lowpass_input,
        state_limit=4.0,
        state_limit_fraction=RICH_STATE_LIMIT_FRACTION,
    )


#: ``state_limit_fraction`` of :func:`rich_weights` (not the default 0.9: a fraction mix-up shows).
RICH_STATE_LIMIT_FRACTION = 0.8


def beyond_state_limits(
    rng: np.random.Generator, robot, x: np.ndarray, fraction: float = RICH_STATE_LIMIT_FRACTION
) -> np.ndarray:
    """A copy of the state ``x`` (q, v first) with one joint velocity 5–30 % beyond its bound of
    the joint-limit barrier (``robot.state_limit_bounds(fraction)``, random sign) and another
    joint's position 0.02–0.1 rad beyond its upper or lower bound: the barrier is active there
    (and far from its kink, for finite differences)."""
    lower, upper = robot.state_limit_bounds(fraction)
    nv = robot.nv
    out = np.array(x, dtype=float)
    jv, jq = rng.choice(nv, 2, replace=False)
    out[nv + jv] = rng.choice([-1.0, 1.0]) * upper[nv + jv] * rng.uniform(1.05, 1.3)
    if rng.random() < 0.5:
        out[jq] = upper[jq] + rng.uniform(0.02, 0.1)
    else:
        out[jq] = lower[jq] - rng.uniform(0.02, 0.1)
    return out


#: Q4 of :func:`random_reference`: differs from ``rich_weights``' (1, 2, 0.5), so the derivative
#: tests cover a per-node Q4.
RICH_EE_POSITION_DIAG = (1.5, 0.5, 0.25)


def random_reference(rng, robot, contact, in_contact: bool) -> NodeReference:
    p = robot.contact_placement(robot.q_nominal).translation + 0.05 * rng.standard_normal(3)
    return NodeReference(
        ee_position=p,
        force=10.0 * rng.standard_normal(contact.dimension),
        ee_position_weight=15.0,
        force_weight=0.4,
        in_contact=in_contact,
        posture=robot.q_nominal + 0.1 * rng.standard_normal(robot.nq),
        ee_position_diag=np.array(RICH_EE_POSITION_DIAG),
    )


def random_state(rng, robot, with_torque: bool = False) -> np.ndarray:
    """(q, v) near the nominal posture, or (q, v, τ) with τ around gravity (torque-feedback)."""
    q = robot.q_nominal + 0.3 * rng.standard_normal(robot.nq)
    x = [q, rng.standard_normal(robot.nv)]
    if with_torque:
        x.append(robot.gravity(q) + 10.0 * rng.standard_normal(robot.nv))
    return np.concatenate(x)


def assert_close_rel(actual, expected, rtol, what):
    scale = max(1.0, float(np.max(np.abs(expected))))
    err = float(np.max(np.abs(actual - expected)))
    assert err <= rtol * scale, f"{what}: max error {err:.2e} (scale {scale:.2e})"


def solve(problem, x0, u0, iters=20):
    """SQP solve (KKT tolerance 1e-10) from x0 repeated and controls u0; returns (xs, us)."""
    solver = mim_solvers.SolverSQP(problem)
    solver.termination_tolerance = 1e-10
    xs = [x0.copy() for _ in range(problem.T + 1)]
    us = [np.array(u0, dtype=float) for _ in range(problem.T)]
    solver.solve(xs, us, iters, False)
    return np.array(solver.xs), np.array(solver.us)
