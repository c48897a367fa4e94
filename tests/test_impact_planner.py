"""Penetration QP and maximal pre-impact velocity (Dehio & Kheddar 2020, eq 12–14, app. B/C)."""

from __future__ import annotations

import numpy as np
import pytest

from ffmpc_core.errors import ConfigError, SolverError
from ffmpc_core.impact.deformation import SoftMaterial, deformation_dynamics, simulate_deformation
from ffmpc_core.impact.limits import ContactSpaceMapper, joint_limits
from ffmpc_core.impact.planner import (
    ImpactPlanner,
    PlannerConfig,
    _highs_max_velocity,
    penetration_constraints,
    penetration_cost,
    pre_impact_cost,
    prediction_matrices,
)
from ffmpc_core.robots import load_robot

DOWN = np.array([0.0, 0.0, -1.0])
TOL = 1e-6  # m, m/s, m/s²: feasibility tolerance of the returned plans


@pytest.fixture(scope="module")
def bounds():
    robot = load_robot("panda")
    mapper = ContactSpaceMapper(robot, joint_limits(robot), DOWN, n_directions=8)
    rng = np.random.default_rng(0)
    return [
        mapper.update(robot.q_nominal + rng.normal(scale=0.1, size=7), rng.normal(0, 0.2, 7))
        for _ in range(3)
    ]


def _materials(seed: int, n: int):
    rng = np.random.default_rng(seed)
    fixed = [(2000.0, 50.0, 0.05), (300.0, 5.0, 0.05), (1.0e4, 200.0, 0.03), (3.0e4, 100.0, 0.02)]
    rand = [
        (10 ** rng.uniform(2.5, 4.5), 10 ** rng.uniform(0.5, 2.5), rng.uniform(0.01, 0.06))
        for _ in range(n)
    ]
    return [SoftMaterial(*m) for m in fixed + rand]


def _check_plan(plan, dyn, b, mat):
    """Independent check: simulate eq 6 with the returned inputs from s_1 = [0, ż_imp] and test
    every bound of eq 12 on the arrays."""
    states, acc, forces = simulate_deformation(
        dyn, np.array([0.0, plan.pre_impact_velocity]), plan.inputs
    )
    z, zd = states[:, 0], states[:, 1]
    assert z.min() >= -TOL and z.max() <= mat.max_penetration + TOL
    assert zd.min() >= b.velocity_lower - TOL and zd.max() <= b.velocity_upper + TOL
    assert abs(zd[-1]) <= TOL
    lhs = np.column_stack([acc, forces[:-1]]) @ b.halfplane_normals.T
    assert np.all(lhs <= b.halfplane_offsets + TOL)
    assert forces[:-1].min() >= -1e-3  # the polytope keeps f ≥ 0 (up to its scaling, N)
    assert plan.max_violation <= TOL


def _highs_max(rows):
    """max ż_imp of eq 14's LP by HiGHS (scipy), m/s: the reference the osqp solution must hit."""
    return _highs_max_velocity(rows)[0][0]


@pytest.mark.parametrize("cost", ["qp", "lp"])
def test_pre_impact_velocity_plans_respect_every_bound(bounds, cost):
    planner = ImpactPlanner(PlannerConfig(cost=cost))
    for b in bounds:
        for mat in _materials(seed=1, n=3):
            dyn = deformation_dynamics(mat.stiffness, mat.damping, b.effective_mass, 0.025)
            plan = planner.max_pre_impact_velocity(dyn, b, mat)
            assert 0.0 < plan.pre_impact_velocity <= b.velocity_upper + TOL
            _check_plan(plan, dyn, b, mat)
            rows, _ = planner.constraints(dyn, b, mat)
            best = _highs_max(rows)
            if cost == "lp":
                assert plan.pre_impact_velocity == pytest.approx(best, abs=1e-6)
            else:
                # eq 14's weighted null-space trick is exact only for r → −∞: with the finite
                # default weights the QP may stop short, never above (measured gap ≤ 1.2 %).
                assert 0.97 * best <= plan.pre_impact_velocity <= best + 1e-6


def test_eq12_feasible_below_and_infeasible_above_the_maximum(bounds):
    planner = ImpactPlanner()
    b = bounds[0]
    mat = SoftMaterial(2000.0, 50.0, 0.05)
    dyn = deformation_dynamics(mat.stiffness, mat.damping, b.effective_mass, 0.025)
    best = planner.max_pre_impact_velocity(dyn, b, mat).pre_impact_velocity
    plan = planner.plan_penetration(dyn, b, mat, 0.9 * best)
    _check_plan(plan, dyn, b, mat)
    with pytest.raises(SolverError):
        planner.plan_penetration(dyn, b, mat, 1.02 * best)


def test_softer_or_deeper_material_allows_faster_impacts(bounds):
    b = bounds[0]
    planner = ImpactPlanner()

    def vmax(alpha, beta, zbar):
        mat = SoftMaterial(alpha, beta, zbar)
        dyn = deformation_dynamics(alpha, beta, b.effective_mass, 0.025)
        return planner.max_pre_impact_velocity(dyn, b, mat).pre_impact_velocity

    assert vmax(1.0e4, 100.0, 0.01) < vmax(1.0e4, 100.0, 0.03)
    assert vmax(3.0e4, 100.0, 0.05) < vmax(3.0e3, 100.0, 0.05)


def test_prediction_matrices_match_simulation():
    dyn = deformation_dynamics(2000.0, 50.0, 4.0, 0.025)
    rng = np.random.default_rng(4)
    u = rng.normal(scale=10.0, size=20)
    S_imp, S_u = prediction_matrices(dyn, 20)
    states, _, _ = simulate_deformation(dyn, np.array([0.0, 0.7]), u)
    np.testing.assert_allclose(S_imp * 0.7 + S_u @ u, states.reshape(-1), atol=1e-12)


def test_constraint_count_matches_the_paper(bounds):
    """h = 20 with 6 half-planes gives 204 one-sided inequality constraints (Sec. VI)."""
    b = bounds[0]
    mat = SoftMaterial(2000.0, 50.0, 0.05)
    dyn = deformation_dynamics(2000.0, 50.0, b.effective_mass, 0.025)
    rows = penetration_constraints(dyn, b, mat, 20, 8)
    ineq = rows.lower != rows.upper
    one_sided = np.isfinite(rows.lower[ineq]).sum() + np.isfinite(rows.upper[ineq]).sum()
    n_hp = b.halfplane_normals.shape[0]
    # z_1 = 0 is not a row here (it holds by construction), the paper counts its two bounds.
    assert one_sided + 2 == 4 * 21 + n_hp * 20
    if n_hp == 6:
        assert one_sided + 2 == 204


def test_eq14_hessian_is_positive_definite_and_has_the_appendix_c_factor():
    dyn = deformation_dynamics(2000.0, 50.0, 4.0, 0.025)
    cfg = PlannerConfig(force_tracking_weight=1e-3, target_force=60.0)
    cost = penetration_cost(dyn, cfg)
    Wt, wt = pre_impact_cost(cost, cfg)
    assert np.all(np.linalg.eigvalsh(Wt) > 0)
    L = np.linalg.cholesky(cost.W)
    R = cfg.velocity_regularization
    # Appendix C writes the factor as [[R, Y L⁻ᵀ], [0, L]] so that W̃ = F Fᵀ (with Y a row).
    F = np.zeros((21, 21))
    F[0, 0] = R
    F[0, 1:] = cost.Y @ np.linalg.inv(L.T)
    F[1:, 1:] = L
    np.testing.assert_allclose(F @ F.T, Wt, rtol=1e-10, atol=1e-12)
    assert wt[0] == -cfg.velocity_weight


def test_planner_configuration_is_validated():
    with pytest.raises(ConfigError):
        PlannerConfig(horizon=1)
    with pytest.raises(ConfigError):
        PlannerConfig(cost="milp")
    with pytest.raises(ConfigError):
        PlannerConfig(control_effort_weight=0.0)
    planner = ImpactPlanner(PlannerConfig(dt=0.01))
    dyn = deformation_dynamics(2000.0, 50.0, 4.0, 0.025)
    with pytest.raises(ConfigError):
        planner.max_pre_impact_velocity(dyn, None, SoftMaterial(2000.0, 50.0, 0.05))
