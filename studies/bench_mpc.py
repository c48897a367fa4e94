"""``ffmpc bench mpc``: MPC step and solve times of each formulation, against crocoddyl's all-C++
classical model.

For every configuration (N = 5, Δt = 3 ms and N = 20, Δt = 10 ms, on the iiwa) each controller
runs in closed loop against its own dynamics (:mod:`ffmpc_core.model_plant`) through the same
pressing task — contact from t = 0, normal force ramped to 50 N and held, the tool drawing the
polishing circle — so every formulation solves the same sequence of problems from states it
really visits. The reference is the classical problem built from crocoddyl's C++ residuals only
(``builtin_residuals``), measured in the same run; ratios are medians over that median.

Two times per MPC step: the **step** (wall time of the whole ``ModelPredictiveController.step``:
measured state, the nodes' reference updates, the warm start, the solve, the command) and the
**solve** alone (mim_solvers' SQP). The step time is the headline figure (``median_ms``,
``p90_ms``, ``ratio_to_reference``): it is what delays a command. A solve "hits the cap" when
it used all ``max_iterations`` (8) SQP iterations. Figures are wall-clock on a shared machine:
compare ratios, not absolute times, across runs.

The formulations run with their hard constraints (issue 23, :mod:`ffmpc_core.constraints`; the
default, ``constraints: true`` in the JSON); ``*_unconstrained`` cases run the same problem
without them (``SolverSQP`` alone, as before issue 23), and each constrained row states its
``constraint_cost_ratio``, its step median over its unconstrained twin's in the same run. The
task keeps every bound inactive (the constrained MPC then solves like the unconstrained one plus
a check, :meth:`~ffmpc_core.mpc.ModelPredictiveController.step`), so ``force_feedback_capped``
caps the force at 40 N below the task's 50 N (``mpc.constraints.max_force``): the force bound
is active at every node of the hold and every solve is ``SolverCSQP``'s (``csqp_fraction``).
The reference stays crocoddyl's unconstrained classical problem.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ffmpc_core.config import FORMULATIONS, OcpConfig
from ffmpc_core.constraints import ConstraintConfig
from ffmpc_core.errors import ConfigError
from ffmpc_core.model_plant import run_model_closed_loop
from ffmpc_core.mpc import MpcConfig
from ffmpc_core.robots import RobotModel, load_robot
from ffmpc_core.tasks import PolishingTask

if TYPE_CHECKING:
    from ffmpc_core.rigid_contact import RigidContactNode

#: (N, Δt in s) of the benchmark.
CONFIGURATIONS = ((5, 0.003), (20, 0.010))
REFERENCE = "reference"
#: ``*_python``: the formulation with the Python reference action models (MpcConfig.backend);
#: the plain names use the default backend (native C++).
PYTHON_CASES = tuple(f"{f}_python" for f in FORMULATIONS)
#: ``*_unconstrained``: the formulation without its hard constraints (``SolverSQP`` alone).
UNCONSTRAINED_CASES = tuple(f"{f}_unconstrained" for f in FORMULATIONS)
#: The force-feedback MPC with its force bound active (max_force below the task's force).
CAPPED = "force_feedback_capped"
#: ``mpc.constraints.max_force`` of :data:`CAPPED`, N (the task holds 50 N).
CAPPED_FORCE = 40.0
CASES = (REFERENCE, *FORMULATIONS, *UNCONSTRAINED_CASES, CAPPED, *PYTHON_CASES)
#: What runs without ``--cases``: the three formulations with and without constraints, the
#: capped force-feedback case, and the Python force-feedback model as the before-figure of the
#: native port measured in the same run.
DEFAULT_CASES = (*FORMULATIONS, *UNCONSTRAINED_CASES, CAPPED, "force_feedback_python")


def case_config(case: str, horizon: int, dt: float) -> MpcConfig:
    """The MpcConfig of a bench case (module docstring)."""
    backend = "python" if case.endswith("_python") else "native"
    formulation = "classical" if case == REFERENCE else case
    for suffix in ("_python", "_unconstrained", "_capped"):
        formulation = formulation.removesuffix(suffix)
    constraints = ConstraintConfig(
        enabled=case != REFERENCE and not case.endswith("_unconstrained"),
        max_force=CAPPED_FORCE if case == CAPPED else ConstraintConfig.max_force,
    )
    return MpcConfig(
        ocp=OcpConfig(formulation=formulation, horizon=horizon, dt=dt),
        backend=backend,
        constraints=constraints,
    )


def _task(robot: RobotModel) -> PolishingTask:
    p0 = robot.contact_placement(robot.q_nominal).translation
    return PolishingTask.pressing(p0, force_ramp=0.1, circle=10.0, stop=0.0)


def bench_case(case: str, horizon: int, dt: float, solves: int) -> dict:
    """Closed-loop MPC steps of one case (``reference`` or a formulation); returns step-time,
    solve-time (ms) and iteration statistics over every step but the first (cold start)."""
    if case not in CASES:
        raise ConfigError(f"unknown bench case {case!r}; choose among {CASES}")
    if solves < 2:
        raise ConfigError(f"the benchmark needs at least 2 solves per case, got {solves}")
    robot = load_robot("iiwa")
    config = case_config(case, horizon, dt)
    factory: Callable[[bool], RigidContactNode] | None = None
    if case == REFERENCE:
        from ffmpc_core.rigid_contact import make_rigid_contact_node

        def factory(terminal: bool) -> RigidContactNode:
            return make_rigid_contact_node(
                robot, config.contact, config.weights, dt, terminal, builtin_residuals=True
            )

    task = _task(robot)
    log = run_model_closed_loop(
        robot, config, task, duration=solves * config.ocp.period, node_factory=factory
    )
    steps = np.asarray(log.step_time[1:]) * 1e3  # the first step starts cold
    solve = np.asarray(log.solve_time[1:]) * 1e3
    iters = np.asarray(log.iterations[1:])
    qp = np.asarray(log.qp_iterations[1:])
    return {
        "formulation": case,
        "backend": "builtin" if case == REFERENCE else config.backend,
        "constraints": config.constraints.enabled,
        "nodes": horizon,
        "dt": dt,
        "solves": int(steps.size),
        "median_ms": float(np.median(steps)),
        "p90_ms": float(np.percentile(steps, 90)),
        "step_median_ms": float(np.median(steps)),
        "solve_median_ms": float(np.median(solve)),
        "solve_p90_ms": float(np.percentile(solve, 90)),
        "iterations_median": float(np.median(iters)),
        "iterations_max": int(iters.max()),
        "cap_hit_fraction": float(np.mean(iters >= config.ocp.max_iterations)),
        "max_iterations": config.ocp.max_iterations,
        "final_force_N": float(log.force[-1][-1]),
        "csqp_fraction": float(np.mean(qp > 0)),
        "qp_iterations_median": float(np.median(qp[qp > 0])) if np.any(qp > 0) else 0.0,
        "screen_iterations_median": float(np.median(log.screen_iterations[1:])),
        "constraint_violation_max": float(np.max(log.constraint_violation[1:])),
    }


def parse_cases(items: list[str] | None) -> list[tuple[int, float, list[str]]]:
    """``--cases`` → [(N, Δt, formulations)] per configuration, the reference always first.

    An item is a formulation (every configuration) or ``formulation:N`` (the configuration with
    N nodes only); no item: every formulation in every configuration.
    """
    by_nodes = {n: dt for n, dt in CONFIGURATIONS}
    wanted: dict[int, list[str]] = {n: [] for n, _ in CONFIGURATIONS}
    choices = CASES[1:]
    for item in items or list(DEFAULT_CASES):
        name, _, nodes = item.partition(":")
        if name not in choices:
            raise ConfigError(f"--cases: unknown case {name!r}; choose among {choices}")
        if nodes:
            try:
                n = int(nodes)
            except ValueError:
                raise ConfigError(f"--cases: bad node count in {item!r}") from None
            if n not in by_nodes:
                raise ConfigError(f"--cases: N must be one of {sorted(by_nodes)}, got {n}")
            targets = [n]
        else:
            targets = list(by_nodes)
        for n in targets:
            if name not in wanted[n]:
                wanted[n].append(name)
    return [
        (n, by_nodes[n], [REFERENCE] + [f for f in choices if f in wanted[n]])
        for n, _ in CONFIGURATIONS
        if wanted[n]
    ]


def run_cases(
    plan: list[tuple[int, float, list[str]]],
    solves: int,
    on_row: Callable[[dict], object] | None = None,
) -> list[dict]:
    """Run the planned cases; every row gets ``ratio_to_reference`` (step medians) and
    ``solve_ratio_to_reference`` (solve medians) against its configuration's reference, and a
    constrained case whose ``*_unconstrained`` twin runs in the same configuration its
    ``constraint_cost_ratio`` (step medians: constrained over unconstrained)."""
    rows: list[dict] = []
    for horizon, dt, cases in plan:
        ref: dict | None = None
        done: dict[str, dict] = {}
        for case in sorted(cases, key=_run_order):
            row = bench_case(case, horizon, dt, solves)
            if case == REFERENCE:
                ref = row
            assert ref is not None  # the reference runs first in every configuration
            row["ratio_to_reference"] = row["median_ms"] / ref["median_ms"]
            row["solve_ratio_to_reference"] = row["solve_median_ms"] / ref["solve_median_ms"]
            name = _unconstrained_twin(case)
            twin = None if name is None else done.get(name)
            if row["constraints"] and twin is not None:
                row["constraint_cost_ratio"] = row["median_ms"] / twin["median_ms"]
            done[case] = row
            rows.append(row)
            if on_row is not None:
                on_row(row)
    return rows


def _unconstrained_twin(case: str) -> str | None:
    """The unconstrained case a constrained one's cost is stated against (the capped case's:
    the same formulation's; none for the Python models, which have no unconstrained case)."""
    if case.endswith("_python"):
        return None
    return f"{case.removesuffix('_capped')}_unconstrained"


def _run_order(case: str) -> int:
    """Reference first, then the unconstrained cases (the twins), then the rest in order."""
    if case == REFERENCE:
        return 0
    return 1 if case.endswith("_unconstrained") else 2


def run_bench_mpc(args: argparse.Namespace) -> int:
    """Print the table (and write ``--json``) of the cases chosen by ``--cases``."""
    plan = parse_cases(getattr(args, "cases", None))
    json_path = getattr(args, "json", None)
    stamp = time.strftime("%Y-%m-%d %H:%M")
    machine = platform.processor() or platform.machine()
    print(
        f"ffmpc bench mpc — iiwa, {args.solves} closed-loop MPC steps per case, {machine}, {stamp}"
    )
    header = (
        f"{'N':>3} {'dt ms':>5}  {'case':29} {'constr':>6} {'step med':>8} {'step p90':>8} "
        f"{'solve med':>9} {'iters med':>9} {'iters max':>9} {'cap hit':>7} {'ratio':>6} "
        f"{'vs unc':>6} {'CSQP':>6} {'QP it':>5} {'force N':>8}"
    )
    last_nodes: list[int] = []

    def show(r: dict) -> None:
        if not last_nodes or last_nodes[-1] != r["nodes"]:
            if last_nodes:
                print()
            print(header)
            last_nodes.append(r["nodes"])
        cost = r.get("constraint_cost_ratio")
        print(
            f"{r['nodes']:>3} {r['dt'] * 1e3:>5.0f}  {r['formulation']:29} "
            f"{'on' if r['constraints'] else 'off':>6} {r['median_ms']:>8.3f} "
            f"{r['p90_ms']:>8.3f} {r['solve_median_ms']:>9.3f} {r['iterations_median']:>9.1f} "
            f"{r['iterations_max']:>9d} {100 * r['cap_hit_fraction']:>6.1f}% "
            f"{r['ratio_to_reference']:>6.2f} {'' if cost is None else f'{cost:.2f}':>6} "
            f"{100 * r['csqp_fraction']:>5.1f}% {r['qp_iterations_median']:>5.0f} "
            f"{r['final_force_N']:>8.2f}",
            flush=True,
        )

    rows = run_cases(plan, args.solves, show)
    print()
    print(
        "times in ms; step = the whole MPC step (references, warm start, solve), solve = the SQP "
        "alone; constr = hard constraints on (SolverCSQP) or off (SolverSQP alone); ratio = "
        "median step time / median of 'reference' (crocoddyl's all-C++ classical model without "
        "constraints, same task, same run); vs unc = median step time / that of the same "
        "formulation without constraints; CSQP = solves SolverCSQP gave (the others: the "
        "unconstrained screen's solution met every bound); QP it = median ADMM iterations of "
        "those; cap hit = solves that used all 8 iterations; 'force N' = normal force at the "
        "end of the run (force_feedback_capped: max_force 40 N, the task asks 50 N)."
    )
    if json_path:
        doc = {
            "command": "ffmpc bench mpc",
            "created": stamp,
            "machine": machine,
            "solves_per_case": args.solves,
            "notes": (
                "median_ms, p90_ms, step_median_ms: wall time of the whole MPC step (reference "
                "updates, warm start, solve), ms; solve_*: the SQP solve alone, ms; "
                "ratio_to_reference: median step time over that of 'reference' (crocoddyl's "
                "all-C++ classical model, unconstrained) in the same configuration and run; "
                "cap_hit_fraction: fraction of solves that used max_iterations; constraints: "
                "hard constraints on (SolverCSQP; *_unconstrained: off, SolverSQP alone); "
                "constraint_cost_ratio: median step time over that of the same formulation's "
                "*_unconstrained case in the same run; csqp_fraction: solves whose solution "
                "SolverCSQP gave (the others: the unconstrained screen's met every bound); "
                "qp_iterations_median: median ADMM iterations of those; "
                "screen_iterations_median: SQP iterations of an unconstrained screen that broke "
                "a bound; constraint_violation_max: largest excess over a bound (fraction of "
                "its limit); force_feedback_capped: max_force 40 N below the task's 50 N."
            ),
            "cases": rows,
        }
        path = Path(json_path)
        path.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
        print(f"wrote {path}")
    return 0
