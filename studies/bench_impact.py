"""``ffmpc bench impact``: the impact planner's control cycle on the impact study's problems.

The problems are the real ones: the study's maximal approach (:func:`studies.impact_study.
run_impact`, Panda above the soft dice in PyBullet, ``sim_duration`` s of it) is run once, and
its joint states before contact are replayed, ``cycles`` times in order (wrapping around), through
two planner pipelines built as in :class:`~ffmpc_core.impact.control.ImpactController` with the
study's control limits, prior material and planner parameters:

* ``daqp`` (the default, measured): eq 9 and eq 11 in closed form, the eq 10 LPs and eq 14 by
  warm-started DAQP;
* ``osqp`` (the reference, measured in the same run, the two alternating in blocks of 50
  cycles over the same states so that the machine's load hits both alike): OSQP for every LP
  and for eq 14, as before.

One cycle = the learner's update (eq 19–20, one contact sample of the same run: after contact
its (z, ż, f); if the run stopped before contact, its approach samples) + the bounds mapping
(eq 9–11) + the deformation dynamics (eq 3–8) + eq 14. Prints median, p90 and p99 per pipeline,
the ratio, solver failures and fallbacks, and the largest difference between the two pipelines'
pre-impact velocities where OSQP's solution is polished (an exact active-set solve); ``--json``
writes the same figures. Wall-clock figures include the time the process waits for a core on a
loaded machine; the per-cycle CPU time of the thread (``time.thread_time``) does not.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from ffmpc_core.errors import ConfigError
from ffmpc_core.impact.deformation import deformation_dynamics
from ffmpc_core.impact.learner import RecursiveContactLearner
from ffmpc_core.impact.limits import ContactSpaceMapper, joint_limits
from ffmpc_core.impact.planner import ImpactPlanner
from ffmpc_core.robots import RobotModel, load_robot

__all__ = ["ApproachProblems", "approach_problems", "bench_impact", "run_bench_impact"]

#: Pipelines: the measured one first, then the reference.
PIPELINES = ("daqp", "osqp")
#: Cycles each pipeline runs in a row before the other takes its turn.
BLOCK = 50


@dataclass(frozen=True)
class ApproachProblems:
    """Joint states of the study's maximal approach and learner samples of the same run.

    Attributes:
        q, v: joint positions (rad) and velocities (rad/s) before contact, K×7.
        samples: learner samples (z m, ż m/s, f N), L×3.
        contact: whether the run reached contact (then ``samples`` are contact samples).
        sim_duration: simulated time of the run, s.
    """

    q: np.ndarray
    v: np.ndarray
    samples: np.ndarray
    contact: bool
    sim_duration: float


def approach_problems(sim_duration: float, robot: RobotModel | None = None) -> ApproachProblems:
    """Run the impact study's maximal approach (admittance regulation) for ``sim_duration`` s
    and return its pre-contact joint states and its learner samples."""
    from ffmpc_core.impact.scenario import ImpactStudyConfig
    from studies.impact_study import run_impact

    if not (np.isfinite(sim_duration) and sim_duration > 0):
        raise ConfigError(f"sim_duration must be positive, got {sim_duration}")
    robot = robot if robot is not None else load_robot("panda")
    # the paper's scheme: the approach eq 14 is solved on every cycle until the contact
    cfg = ImpactStudyConfig(duration=float(sim_duration), strategy="prior")
    run = run_impact("maximal", "admittance", cfg, robot)
    log = run.log
    approach = ~log["in_contact_phase"]
    if not np.any(approach):
        raise ConfigError("the run has no approach phase")
    contact = log["in_contact_phase"] & (log["force"] > 0.0)
    rows = contact if np.any(contact) else approach
    # z: below the dice's top face (m); ż: speed along d (m/s); f: pressing force (N).
    samples = np.column_stack([log["penetration"][rows], log["speed"][rows], log["force"][rows]])
    return ApproachProblems(
        q=log["q"][approach],
        v=log["v"][approach],
        samples=samples,
        contact=bool(np.any(contact)),
        sim_duration=float(sim_duration),
    )


def _percentiles(samples: list[float]) -> dict[str, float]:
    a = np.asarray(samples) * 1e3
    return {
        "median_ms": float(np.median(a)),
        "p90_ms": float(np.percentile(a, 90)),
        "p99_ms": float(np.percentile(a, 99)),
        "max_ms": float(np.max(a)),
    }


def bench_impact(
    problems: ApproachProblems, cycles: int, warmup: int = 20, robot: RobotModel | None = None
) -> dict:
    """Time both pipelines on ``problems`` (see the module docstring); returns the figures."""
    from ffmpc_core.impact.scenario import DOWN, ImpactStudyConfig

    if cycles < 1 or warmup < 0:
        raise ConfigError("cycles must be ≥ 1 and warmup ≥ 0")
    robot = robot if robot is not None else load_robot("panda")
    study = ImpactStudyConfig()
    limits = study.control_limits(joint_limits(robot))
    material = study.prior
    # per pipeline: its mapper, planner and learner, and the lists of the measured samples
    pipes: dict[str, dict[str, Any]] = {}
    for solver in PIPELINES:
        pipes[solver] = {
            "mapper": ContactSpaceMapper(robot, limits, DOWN, solver=solver),
            "planner": ImpactPlanner(replace(study.planner, solver=solver)),
            "learner": RecursiveContactLearner(),
            "cycle": [],
            "cpu": [],
            "mapping": [],
            "eq14": [],
            "velocity": [],
            "solver": [],
            "failures": 0,
        }
    n_states, n_samples = problems.q.shape[0], problems.samples.shape[0]
    dt = study.planner.dt
    total = warmup + cycles
    # Blocks of BLOCK cycles: both pipelines run the same states, block by block, the order
    # alternating, so both see the same machine load; within a block each runs alone with warm
    # caches, as in a controller (alternating every cycle made each evict the other's data:
    # DAQP's CPU median was 0.58 ms that way, 0.37 ms in blocks, in two runs here).
    for start in range(0, total, BLOCK):
        first = PIPELINES if (start // BLOCK) % 2 == 0 else PIPELINES[::-1]
        for solver in first:
            p = pipes[solver]
            for k in range(start, min(start + BLOCK, total)):
                q, v = problems.q[k % n_states], problems.v[k % n_states]
                z, zd, f = problems.samples[k % n_samples]
                c0 = time.thread_time()
                t0 = time.perf_counter()
                p["learner"].update(z, zd, f)
                bounds = p["mapper"].update(q, v)
                t1 = time.perf_counter()
                dyn = deformation_dynamics(
                    material.stiffness, material.damping, bounds.effective_mass, dt
                )
                plan = p["planner"].max_pre_impact_velocity(dyn, bounds, material)
                t2 = time.perf_counter()
                c2 = time.thread_time()
                if k >= warmup:
                    p["cycle"].append(t2 - t0)
                    p["cpu"].append(c2 - c0)
                    p["mapping"].append(t1 - t0)
                    p["eq14"].append(t2 - t1)
                    p["velocity"].append(plan.pre_impact_velocity)
                    p["solver"].append(plan.solver)
    out: dict = {}
    for solver in PIPELINES:
        p = pipes[solver]
        planner, mapper = p["planner"], p["mapper"]
        cpu = np.asarray(p["cpu"]) * 1e3
        out[solver] = {
            **_percentiles(p["cycle"]),
            "cpu_median_ms": float(np.median(cpu)),
            "cpu_p99_ms": float(np.percentile(cpu, 99)),
            "mapping_median_ms": float(np.median(p["mapping"]) * 1e3),
            "eq14_median_ms": float(np.median(p["eq14"]) * 1e3),
            "eq14_failures": int(planner.stats["failures"]),
            "eq14_highs_fallbacks": int(planner.stats["highs_fallbacks"]),
            "mapping_lp_solves": int(mapper.stats["lp_solves"]),
            "mapping_highs_fallbacks": int(mapper.stats["highs_fallbacks"]),
            "mapping_qhull_fallbacks": int(mapper.stats["qhull_fallbacks"]),
            "pre_impact_velocity_min": float(np.min(p["velocity"])),
            "pre_impact_velocity_max": float(np.max(p["velocity"])),
        }
    new, ref = pipes["daqp"], pipes["osqp"]
    polished = np.array([s == "osqp" for s in ref["solver"]])
    diff = np.abs(np.array(new["velocity"]) - np.array(ref["velocity"]))
    new_out, ref_out = out["daqp"], out["osqp"]
    return {
        "median_ms": new_out["median_ms"],
        "p90_ms": new_out["p90_ms"],
        "p99_ms": new_out["p99_ms"],
        "max_ms": new_out["max_ms"],
        "solver": "daqp",
        "failures": new_out["eq14_failures"] + new_out["mapping_highs_fallbacks"],
        "daqp": new_out,
        "reference": {"solver": "osqp", **ref_out},
        "cpu_median_ms": new_out["cpu_median_ms"],
        "ratio_reference_over_new": ref_out["median_ms"] / new_out["median_ms"],
        "cpu_ratio_reference_over_new": ref_out["cpu_median_ms"] / new_out["cpu_median_ms"],
        "load_average_1min": float(os.getloadavg()[0]),
        "max_velocity_difference_polished": float(diff[polished].max()) if polished.any() else None,
        "polished_reference_cycles": int(polished.sum()),
        "cycles": int(cycles),
        "warmup": int(warmup),
        "states": int(n_states),
        "learner_samples_from_contact": problems.contact,
        "sim_duration": problems.sim_duration,
        "machine": platform.processor() or platform.machine(),
        "date": time.strftime("%Y-%m-%d %H:%M"),
    }


def _row(name: str, r: dict) -> str:
    return (
        f"  {name:10s} {r['median_ms']:9.3f} {r['p90_ms']:8.3f} {r['p99_ms']:8.3f} "
        f"{r['cpu_median_ms']:8.3f} {r['mapping_median_ms']:12.3f} {r['eq14_median_ms']:10.3f} "
        f"{r['eq14_failures']:9d} {r['eq14_highs_fallbacks'] + r['mapping_highs_fallbacks']:9d}"
    )


def run_bench_impact(args: argparse.Namespace) -> int:
    """The ``ffmpc bench impact`` command (``args.cycles``, ``args.warmup``,
    ``args.sim_duration``, ``args.json``)."""
    robot = load_robot("panda")
    problems = approach_problems(args.sim_duration, robot)
    result = bench_impact(problems, args.cycles, args.warmup, robot)
    print(
        f"ffmpc bench impact — Panda, impact study's maximal approach ({problems.sim_duration:g} s "
        f"simulated, {result['states']} pre-contact states), {args.cycles} planner cycles after "
        f"{args.warmup} warm-up, {result['machine']}, {result['date']}"
    )
    print(
        "  pipeline   median ms   p90 ms   p99 ms  cpu med  mapping med  eq14 med  failures "
        "fallbacks"
    )
    print(_row("daqp", result["daqp"]))
    print(_row("osqp (ref)", result["reference"]))
    diff = result["max_velocity_difference_polished"]
    print(
        f"  ratio osqp/daqp (median): {result['ratio_reference_over_new']:.1f}x wall, "
        f"{result['cpu_ratio_reference_over_new']:.1f}x cpu; "
        f"pre-impact velocity {result['daqp']['pre_impact_velocity_min']:.3f} … "
        f"{result['daqp']['pre_impact_velocity_max']:.3f} m/s; max |Δ| vs polished OSQP "
        f"{'n/a' if diff is None else f'{diff:.1e}'} m/s "
        f"({result['polished_reference_cycles']} cycles)"
    )
    print(
        "  cycle = learner update (eq 19-20) + bounds mapping (eq 9-11) + deformation dynamics "
        "(eq 3-8) + eq 14; cpu = this thread's CPU time per cycle (what the machine's load "
        "does not inflate); failures = failed eq 14 solves; fallbacks = solves redone by HiGHS; "
        f"load average {result['load_average_1min']:.1f}"
    )
    if args.json:
        path = Path(args.json)
        path.write_text(json.dumps(result, indent=2) + "\n")
        print(f"  wrote {path}")
    return 0
