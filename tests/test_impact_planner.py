"""Penetration QP and maximal pre-impact velocity (Dehio & Kheddar 2020, eq 12–14, app. B/C)."""

from __future__ import annotations

import numpy as np
import pytest

from ffmpc_core.errors import ConfigError, SolverError
from ffmpc_core.impact.deformation import SoftMaterial, deformation_dynamics, simulate_deformation
from ffmpc_core.impact.limits import DAQP_INF, ContactSpaceMapper, joint_limits
from ffmpc_core.impact.planner import (
    ImpactPlanner,
    PlannerConfig,
    _Eq14Workspace,
    _highs_max_velocity,
    penetration_constraints,
    penetration_cost,
    pre_impact_cost,
    prediction_matrices,
)
from ffmpc_core.robots import load_robot

DOWN = np.array([0.0, 0.0, -1.0])
SOLVERS = ("daqp", "osqp")


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


def _check_plan(plan, dyn, b, mat, tol):
    """Independent check: simulate eq 6 with the returned inputs from s_1 = [0, ż_imp] and test
    every bound of eq 12 on the arrays, each row to the tolerance its solver guarantees (``tol``:
    ImpactPlanner.feasibility_tolerance, in the rows' order: z_2..z_{h+1}, ż_1..ż_{h+1}, the
    half-planes step by step, ż_{h+1} = 0)."""
    states, acc, forces = simulate_deformation(
        dyn, np.array([0.0, plan.pre_impact_velocity]), plan.inputs
    )
    z, zd = states[:, 0], states[:, 1]
    h = plan.inputs.size
    n_p = b.halfplane_normals.shape[0]
    tol_z, tol_v = tol[:h], tol[h : 2 * h + 1]
    tol_hp = tol[2 * h + 1 : -1].reshape(h, -1)[:, :n_p]
    assert z[0] == 0.0
    assert np.all(z[1:] >= -tol_z) and np.all(z[1:] <= mat.max_penetration + tol_z)
    assert np.all(zd >= b.velocity_lower - tol_v) and np.all(zd <= b.velocity_upper + tol_v)
    assert abs(zd[-1]) <= tol[-1]
    lhs = np.column_stack([acc, forces[:-1]]) @ b.halfplane_normals.T
    assert np.all(lhs <= b.halfplane_offsets + tol_hp)
    # The polytope keeps f ≥ 0: its edge f = 0 is a half-plane −f/Λ ≤ 0, so f ≥ −Λ·(its row
    # tolerance), N.
    assert forces[:-1].min() >= -b.effective_mass * tol_hp.max()


def _highs_max(rows):
    """max ż_imp of eq 14's LP by HiGHS (scipy), m/s: the reference the solution must hit."""
    return _highs_max_velocity(rows)[0][0]


@pytest.mark.parametrize("cost", ["qp", "lp"])
@pytest.mark.parametrize("solver", SOLVERS)
def test_pre_impact_velocity_plans_respect_every_bound(bounds, solver, cost):
    planner = ImpactPlanner(PlannerConfig(cost=cost, solver=solver))
    for b in bounds:
        for mat in _materials(seed=1, n=3):
            dyn = deformation_dynamics(mat.stiffness, mat.damping, b.effective_mass, 0.025)
            plan = planner.max_pre_impact_velocity(dyn, b, mat)
            tol = planner.feasibility_tolerance(plan, dyn, b, mat)
            assert 0.0 < plan.pre_impact_velocity <= b.velocity_upper + tol[0]
            _check_plan(plan, dyn, b, mat, tol)
            rows, _ = planner.constraints(dyn, b, mat)
            best = _highs_max(rows)
            if cost == "lp":
                assert plan.pre_impact_velocity == pytest.approx(best, abs=1e-6)
            else:
                # eq 14's weighted null-space trick is exact only for r → −∞: with the finite
                # default weights the QP may stop short, never above (measured gap ≤ 1.2 %).
                assert 0.97 * best <= plan.pre_impact_velocity <= best + 1e-6
    if solver == "daqp":
        assert planner.stats["failures"] == 0 and planner.stats["highs_fallbacks"] == 0


def _random_problems(seed: int, n_states: int, n_materials: int, solver: str = "daqp"):
    """Bounds at seeded random Panda states (mapped by ``solver``) × seeded random materials."""
    robot = load_robot("panda")
    mapper = ContactSpaceMapper(robot, joint_limits(robot), DOWN, solver=solver)
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n_states):
        q = robot.q_nominal + rng.normal(scale=0.2, size=7)
        b = mapper.update(q, rng.normal(0.0, 0.3, 7))
        for _ in range(n_materials):
            mat = SoftMaterial(
                10 ** rng.uniform(2.5, 4.5), 10 ** rng.uniform(0.5, 2.5), rng.uniform(0.01, 0.06)
            )
            out.append(
                (deformation_dynamics(mat.stiffness, mat.damping, b.effective_mass, 0.025), b, mat)
            )
    return out


def test_daqp_gives_the_optimum_of_the_references_on_random_problems():
    """DAQP's eq 14 optimum equals the references' to 1e-6 m/s: the QP against OSQP (tight eps)
    where OSQP's polish succeeded (an exact active-set solve), the LP variant against HiGHS."""
    problems = _random_problems(seed=11, n_states=8, n_materials=6)
    new_qp, new_lp = ImpactPlanner(), ImpactPlanner(PlannerConfig(cost="lp"))
    ref_qp = ImpactPlanner(PlannerConfig(solver="osqp", eps=1e-8))
    compared = 0
    for dyn, b, mat in problems:
        plan = new_qp.max_pre_impact_velocity(dyn, b, mat)
        ref = ref_qp.max_pre_impact_velocity(dyn, b, mat)
        assert plan.solver == "daqp"
        if ref.solver == "osqp":
            assert plan.pre_impact_velocity == pytest.approx(ref.pre_impact_velocity, abs=1e-6)
            compared += 1
        tol = new_qp.feasibility_tolerance(plan, dyn, b, mat)
        _check_plan(plan, dyn, b, mat, tol)
        lp = new_lp.max_pre_impact_velocity(dyn, b, mat)
        rows, _ = new_lp.constraints(dyn, b, mat)
        assert lp.solver == "daqp"
        assert lp.pre_impact_velocity == pytest.approx(_highs_max(rows), abs=1e-6)
        _check_plan(lp, dyn, b, mat, new_lp.feasibility_tolerance(lp, dyn, b, mat))
    assert compared >= 0.9 * len(problems)
    for planner in (new_qp, new_lp):
        assert planner.stats["failures"] == 0 and planner.stats["highs_fallbacks"] == 0


def test_daqp_with_force_tracking_equals_osqp():
    """With ω_f > 0 W̃ changes with the dynamics every cycle (DAQP refactorises it): the
    optimum still equals OSQP's polished one, and the workspace's predictions are eq 6's."""
    cfg = dict(force_tracking_weight=1e-4, target_force=60.0)
    new = ImpactPlanner(PlannerConfig(**cfg))
    ref = ImpactPlanner(PlannerConfig(solver="osqp", eps=1e-8, **cfg))
    compared = 0
    for dyn, b, mat in _random_problems(seed=13, n_states=3, n_materials=4):
        plan = new.max_pre_impact_velocity(dyn, b, mat)
        S_imp, S_u = new._work.predictions()
        ref_imp, ref_u = prediction_matrices(dyn, 20)
        np.testing.assert_allclose(S_imp, ref_imp, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(S_u, ref_u, rtol=1e-12, atol=1e-15)
        other = ref.max_pre_impact_velocity(dyn, b, mat)
        if other.solver == "osqp":
            assert plan.pre_impact_velocity == pytest.approx(other.pre_impact_velocity, abs=1e-6)
            compared += 1
        _check_plan(plan, dyn, b, mat, new.feasibility_tolerance(plan, dyn, b, mat))
    assert compared >= 9 and new.stats["failures"] == 0


def test_daqp_warm_start_keeps_the_working_set():
    """The same problem solved again starts from the optimal working set: no active-set change."""
    dyn, b, mat = _random_problems(seed=3, n_states=1, n_materials=1)[0]
    planner = ImpactPlanner()
    first = planner.max_pre_impact_velocity(dyn, b, mat)
    again = planner.max_pre_impact_velocity(dyn, b, mat)
    assert first.iterations > 2
    assert again.iterations < first.iterations
    assert again.pre_impact_velocity == pytest.approx(first.pre_impact_velocity, abs=1e-12)


def test_workspace_rows_equal_the_reference_builder():
    """The in-place eq 14 rows (_Eq14Workspace) equal penetration_constraints'."""
    for dyn, b, mat in _random_problems(seed=5, n_states=2, n_materials=3):
        work = _Eq14Workspace(20, 8)
        work.update(dyn, b, mat)
        rows = penetration_constraints(dyn, b, mat, 20, 8)
        np.testing.assert_allclose(
            work.A, np.column_stack([rows.K, rows.X]), rtol=1e-12, atol=1e-12
        )
        finite = np.isfinite(rows.upper)
        np.testing.assert_allclose(work.upper[finite], rows.upper[finite], rtol=1e-15)
        assert np.all(work.upper[~finite] >= DAQP_INF)
        finite = np.isfinite(rows.lower)
        np.testing.assert_allclose(work.lower[finite], rows.lower[finite], rtol=1e-15)
        assert np.all(work.lower[~finite] <= -DAQP_INF)


@pytest.mark.parametrize("solver", SOLVERS)
def test_eq12_feasible_below_and_infeasible_above_the_maximum(bounds, solver):
    planner = ImpactPlanner(PlannerConfig(solver=solver))
    b = bounds[0]
    mat = SoftMaterial(2000.0, 50.0, 0.05)
    dyn = deformation_dynamics(mat.stiffness, mat.damping, b.effective_mass, 0.025)
    best = planner.max_pre_impact_velocity(dyn, b, mat).pre_impact_velocity
    plan = planner.plan_penetration(dyn, b, mat, 0.9 * best)
    assert plan.solver == solver
    _check_plan(plan, dyn, b, mat, planner.feasibility_tolerance(plan, dyn, b, mat, eq12=True))
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
    with pytest.raises(ConfigError):
        PlannerConfig(solver="qpoases")
    planner = ImpactPlanner(PlannerConfig(dt=0.01))
    dyn = deformation_dynamics(2000.0, 50.0, 4.0, 0.025)
    with pytest.raises(ConfigError):
        planner.max_pre_impact_velocity(dyn, None, SoftMaterial(2000.0, 50.0, 0.05))
