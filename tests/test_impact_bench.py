"""The DAQP planner path on the project's real problems (the impact study's approach in PyBullet)
and ``ffmpc bench impact``."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from ffmpc_core.impact.deformation import deformation_dynamics, simulate_deformation
from ffmpc_core.impact.limits import (
    ContactSpaceMapper,
    acceleration_force_vertices,
    deformation_velocity_bounds,
    joint_limits,
    position_aware_velocity_limits,
    velocity_lp_data,
    vertex_directions,
    vertex_lp_data,
)
from ffmpc_core.impact.planner import ImpactPlanner, PlannerConfig, _highs_max_velocity
from ffmpc_core.impact.scenario import DOWN, ImpactStudyConfig
from ffmpc_core.robots import load_robot
from studies.bench_impact import approach_problems


@pytest.fixture(scope="module")
def study():
    robot = load_robot("panda")
    return robot, approach_problems(0.3, robot)


def test_daqp_path_equals_the_references_on_the_study_approach(study):
    """Every 10th pre-contact state of the study's maximal approach: the DAQP mapper gives
    HiGHS's eq 9 bounds and eq 10 optima; eq 14 by DAQP gives OSQP's polished optimum (QP) and
    HiGHS's (LP variant) to 1e-6 m/s, feasible to DAQP's own tolerance."""
    robot, problems = study
    cfg = ImpactStudyConfig()
    limits = cfg.control_limits(joint_limits(robot))
    material = cfg.prior
    mapper = ContactSpaceMapper(robot, limits, DOWN)
    new_qp = ImpactPlanner(cfg.planner)
    new_lp = ImpactPlanner(replace(cfg.planner, cost="lp"))
    ref_qp = ImpactPlanner(replace(cfg.planner, solver="osqp", eps=1e-8))
    states = list(zip(problems.q, problems.v, strict=True))[::10]
    assert len(states) >= 25
    compared = 0
    for q, v in states:
        b = mapper.update(q, v)
        kin = mapper.kinematics(q, v)
        lower, upper = position_aware_velocity_limits(q, limits)
        ref = deformation_velocity_bounds(velocity_lp_data(kin["J_A"], kin["J_B"], lower, upper))
        np.testing.assert_allclose([b.velocity_lower, b.velocity_upper], ref, atol=1e-7)
        lp = vertex_lp_data(
            kin["J_A"], kin["J_B"], kin["drift_A"], kin["drift_B"], kin["M"], kin["h"], limits
        )
        w = vertex_directions(8, b.effective_mass)
        want = np.einsum("kj,kj->k", acceleration_force_vertices(lp, w), w)
        got = np.einsum("kj,kj->k", b.vertices, w)
        np.testing.assert_allclose(got, want, atol=1e-6 * (1.0 + np.abs(want).max()))

        dyn = deformation_dynamics(
            material.stiffness, material.damping, b.effective_mass, cfg.planner.dt
        )
        plan = new_qp.max_pre_impact_velocity(dyn, b, material)
        ref = ref_qp.max_pre_impact_velocity(dyn, b, material)
        if ref.solver == "osqp":
            assert plan.pre_impact_velocity == pytest.approx(ref.pre_impact_velocity, abs=1e-6)
            compared += 1
        rows, _ = new_lp.constraints(dyn, b, material)
        best = _highs_max_velocity(rows)[0][0]
        lp_plan = new_lp.max_pre_impact_velocity(dyn, b, material)
        assert lp_plan.pre_impact_velocity == pytest.approx(best, abs=1e-6)
        for planner, p in ((new_qp, plan), (new_lp, lp_plan)):
            assert p.solver == "daqp"
            tol = planner.feasibility_tolerance(p, dyn, b, material)
            s, acc, f = simulate_deformation(dyn, np.array([0.0, p.pre_impact_velocity]), p.inputs)
            Ax = np.concatenate(
                [
                    s[1:, 0],
                    s[:, 1],
                    (np.column_stack([acc, f[:-1]]) @ b.halfplane_normals.T).reshape(-1),
                    s[-1:, 1],
                ]
            )
            n_p = b.halfplane_normals.shape[0]
            keep = np.ones(rows.lower.size, dtype=bool)  # drop the zero padding rows
            keep[2 * 20 + 1 : -1] = (np.arange(20 * 8) % 8) < n_p
            assert np.all(Ax <= rows.upper[keep] + tol[keep])
            assert np.all(Ax >= rows.lower[keep] - tol[keep])
    assert compared >= 0.9 * len(states)
    assert mapper.stats["highs_fallbacks"] == 0
    assert new_qp.stats["failures"] == 0 and new_lp.stats["failures"] == 0


def test_bench_impact_writes_sane_json(tmp_path, capsys):
    from ffmpc_ros.cli import main

    out = tmp_path / "bench.json"
    argv = ["bench", "impact", "--cycles", "30", "--warmup", "3", "--sim-duration", "0.05"]
    assert main([*argv, "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "daqp" in printed and "osqp (ref)" in printed
    result = json.loads(out.read_text())
    for key in ("median_ms", "p90_ms", "p99_ms"):
        assert math.isfinite(result[key]) and result[key] > 0.0
        assert math.isfinite(result["reference"][key]) and result["reference"][key] > 0.0
    assert result["median_ms"] <= result["p90_ms"] <= result["p99_ms"] <= result["max_ms"]
    assert 0.0 < result["cpu_median_ms"] and result["reference"]["cpu_median_ms"] > 0.0
    assert result["reference"]["solver"] == "osqp" and result["solver"] == "daqp"
    ratio = result["reference"]["median_ms"] / result["median_ms"]
    assert result["ratio_reference_over_new"] == pytest.approx(ratio)
    assert result["cycles"] == 30 and result["failures"] == 0
    assert result["daqp"]["mapping_lp_solves"] == 33 * 8  # eq 10: one DAQP LP per direction
    assert result["reference"]["mapping_lp_solves"] == 33 * 10  # 2 eq 9 + 8 eq 10 OSQP LPs
    assert (
        0.0
        <= result["daqp"]["pre_impact_velocity_min"]
        <= result["daqp"]["pre_impact_velocity_max"]
    )
    diff = result["max_velocity_difference_polished"]
    assert diff is None or diff <= 1e-4  # the reference runs at the planner's eps (1e-4)
    assert main(["bench", "impact", "--cycles", "x"]) == 2  # argparse's exit status, returned


def test_planner_option_selects_the_solver(study):
    """The solver option is not silent: each choice runs its own solver (plans say which)."""
    robot, problems = study
    cfg = ImpactStudyConfig()
    limits = cfg.control_limits(joint_limits(robot))
    q, v = problems.q[-1], problems.v[-1]
    seen = {}
    for solver in ("daqp", "osqp"):
        mapper = ContactSpaceMapper(robot, limits, DOWN, solver=solver)
        planner = ImpactPlanner(PlannerConfig(solver=solver))
        b = mapper.update(q, v)
        dyn = deformation_dynamics(2400.0, 15.0, b.effective_mass, 0.025)
        seen[solver] = (planner.max_pre_impact_velocity(dyn, b, cfg.prior).solver, mapper.stats)
    assert seen["daqp"][0] == "daqp" and seen["osqp"][0] in ("osqp", "highs")
    assert seen["daqp"][1]["lp_solves"] == 8 and seen["osqp"][1]["lp_solves"] == 10
