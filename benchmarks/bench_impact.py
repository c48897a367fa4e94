"""Timing of the impact planner and the contact learner (Dehio & Kheddar 2020 ran at 1 kHz).

Per control cycle before contact the planner maps the joint limits to the contact space (eq 9–11,
10 LPs) and solves eq 14. The robot follows a straight downward motion at 0.2 m/s sampled at
1 kHz, so consecutive problems differ as they would in the control loop (warm starts).
Prints medians and p90 after a warm-up, plus references measured in the same run (a cold
solve, and HiGHS on the same LP) and the ratio. Usage:

    python benchmarks/bench_impact.py [--cycles 1000]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import pinocchio as pin

from ffmpc_core.impact.deformation import SoftMaterial, deformation_dynamics
from ffmpc_core.impact.learner import RecursiveContactLearner
from ffmpc_core.impact.limits import ContactSpaceMapper, joint_limits
from ffmpc_core.impact.planner import ImpactPlanner, PlannerConfig, _highs_max_velocity
from ffmpc_core.robots import load_robot

DOWN = np.array([0.0, 0.0, -1.0])


def trajectory(robot, n: int, dt: float = 1e-3, speed: float = 0.2):
    """Joint states of the contact frame moving down at ``speed`` m/s (1 kHz samples)."""
    model, data, fid = robot.model, robot.create_data(), robot.contact_frame_id
    q = robot.q_nominal.copy()
    out = []
    for _ in range(n):
        J = pin.computeFrameJacobian(model, data, q, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        v = np.linalg.pinv(J) @ np.concatenate([speed * DOWN, np.zeros(3)])
        out.append((q.copy(), v))
        q = pin.integrate(model, q, v * dt)
    return out


def stats(samples: list[float]) -> str:
    a = np.asarray(samples) * 1e6
    return f"median {np.median(a):8.1f} µs   p90 {np.percentile(a, 90):8.1f} µs"


def run_planner(robot, states, material, cost: str, warmup: int):
    limits = joint_limits(robot)
    mapper = ContactSpaceMapper(robot, limits, DOWN, n_directions=8)
    planner = ImpactPlanner(PlannerConfig(cost=cost))
    t_map, t_qp, t_all, v_imp, iters = [], [], [], [], []
    for k, (q, v) in enumerate(states):
        t0 = time.perf_counter()
        bounds = mapper.update(q, v)
        t1 = time.perf_counter()
        dyn = deformation_dynamics(
            material.stiffness, material.damping, bounds.effective_mass, planner.config.dt
        )
        plan = planner.max_pre_impact_velocity(dyn, bounds, material)
        t2 = time.perf_counter()
        if k >= warmup:
            t_map.append(t1 - t0)
            t_qp.append(t2 - t1)
            t_all.append(t2 - t0)
            v_imp.append(plan.pre_impact_velocity)
            if plan.solver == "osqp":
                iters.append(plan.iterations)
    planner.iterations = iters
    return mapper, planner, bounds, dyn, t_map, t_qp, t_all, v_imp


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--cycles", type=int, default=1000)
    parser.add_argument("--warmup", type=int, default=50)
    args = parser.parse_args()

    robot = load_robot("panda")
    material = SoftMaterial(stiffness=2000.0, damping=50.0, max_penetration=0.05)
    states = trajectory(robot, args.cycles + args.warmup)
    print(
        f"Panda, h=20, Δt=25 ms, 8 vertex directions, {args.cycles} cycles after "
        f"{args.warmup} warm-up cycles (1 kHz motion, 0.2 m/s down)"
    )

    mapper, planner, bounds, dyn, t_map, t_qp, t_all, v_imp = run_planner(
        robot, states, material, "qp", args.warmup
    )
    print("\n[eq 14 QP, OSQP warm-started]")
    print(f"  bounds mapping (eq 9–11)   {stats(t_map)}")
    print(f"  QP (eq 12–14 build+solve)  {stats(t_qp)}")
    print(f"  planner cycle (total)      {stats(t_all)}")
    print(f"  pre-impact velocity        {min(v_imp):.3f} … {max(v_imp):.3f} m/s")
    it = np.percentile(planner.iterations, [10, 50, 90])
    print(f"  OSQP iterations (eq 14)    p10 {it[0]:.0f}, median {it[1]:.0f}, p90 {it[2]:.0f}")
    print(
        f"  fallbacks to HiGHS: mapper {mapper.stats['highs_fallbacks']}/"
        f"{mapper.stats['lp_solves']} LPs, planner {planner.stats['highs_fallbacks']}/"
        f"{planner.stats['solves']} solves"
    )

    # References measured now: a cold planner (setup + first solve) and HiGHS on the same LP.
    cold, highs, cold_map = [], [], []
    for _ in range(20):
        t0 = time.perf_counter()
        fresh = ImpactPlanner(PlannerConfig())
        fresh.max_pre_impact_velocity(dyn, bounds, material)
        cold.append(time.perf_counter() - t0)
        rows, _ = planner.constraints(dyn, bounds, material)
        t0 = time.perf_counter()
        _highs_max_velocity(rows)
        highs.append(time.perf_counter() - t0)
        q, v = states[-1]
        fresh_mapper = ContactSpaceMapper(robot, joint_limits(robot), DOWN, n_directions=8)
        t0 = time.perf_counter()
        fresh_mapper.update(q, v)
        cold_map.append(time.perf_counter() - t0)
    print("\n[references, same run]")
    print(
        f"  cold QP (setup + 1st solve) {stats(cold)}   ratio cold/warm QP "
        f"{np.median(cold) / np.median(t_qp):.1f}×"
    )
    print(
        f"  HiGHS LP of eq 14 (linprog) {stats(highs)}   ratio HiGHS/warm QP "
        f"{np.median(highs) / np.median(t_qp):.1f}×"
    )
    print(
        f"  cold bounds mapping         {stats(cold_map)}   ratio cold/warm mapping "
        f"{np.median(cold_map) / np.median(t_map):.1f}×"
    )
    rate = 1.0 / np.median(t_all)
    print(f"  planner rate at the median: {rate:.0f} Hz (paper: 1000 Hz, C++)")

    n_lp = min(args.cycles, 200) + args.warmup
    mapper, planner, _, _, t_map, t_qp, t_all, _ = run_planner(
        robot, states[:n_lp], material, "lp", args.warmup
    )
    print("\n[LP variant of eq 14]")
    print(
        f"  LP (build+solve)           {stats(t_qp)}   HiGHS fallbacks "
        f"{planner.stats['highs_fallbacks']}/{planner.stats['solves']}"
    )

    rng = np.random.default_rng(0)
    data = rng.normal(size=(20000, 3))
    learner = RecursiveContactLearner()
    t_upd, t_est = [], []
    for z, zd, f in data:
        t0 = time.perf_counter()
        learner.update(z, zd, f)
        t1 = time.perf_counter()
        learner.coefficients()
        t2 = time.perf_counter()
        t_upd.append(t1 - t0)
        t_est.append(t2 - t1)
    t0 = time.perf_counter()
    for _ in range(200):
        learner.estimate()
    t_conf = (time.perf_counter() - t0) / 200
    print("\n[learner, eq 19–21]")
    print(f"  update (eq 19–20)          {stats(t_upd[1000:])}")
    print(f"  estimate (eq 21, 2×2 solve){stats(t_est[1000:])}")
    print(f"  estimate with confidence   {t_conf * 1e6:8.1f} µs")


if __name__ == "__main__":
    main()
