"""Write each search's best weights among its first N completed trials (the same budget for the
three searches) as ``best_<formulation>.txt`` and, for the three together, ``tuned_weights.yaml``
(a ``--set-file`` mapping, 4 significant digits), from the searches' Optuna storage, into the
directory of DB. PREFIX is the searches' name before the formulation (default
``three-scenarios``; ``observer`` for ../observer).

    python benchmarks/results/tune/train1000-1002/three_scenarios/write_best.py DB N [PREFIX]
"""

import sys
from pathlib import Path

import optuna

from studies.tune import best_trial_report, first_completed

FORMULATIONS = ("classical", "torque_feedback", "force_feedback")

db, budget = sys.argv[1], int(sys.argv[2])
prefix = sys.argv[3] if len(sys.argv) > 3 else "three-scenarios"
here = Path(db).parent
optuna.logging.set_verbosity(optuna.logging.WARNING)
weights: list[str] = []
for form in FORMULATIONS:
    study = optuna.load_study(study_name=f"{prefix}-{form}", storage=f"sqlite:///{db}")
    lines = best_trial_report(study, Path(db).name, form, budget, "the scenario files' weights")
    (here / f"best_{form}.txt").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    _, best = first_completed(study, budget)
    weights += [f"mpc.weights.{form}.{k}: {float(f'{v:.4g}')!r}" for k, v in best.params.items()]
header = (
    "# The cost weights of the three MPCs tuned alike by `ffmpc tune` on the slow circle, the\n"
    "# fast circle and the push at once (tune.sh here: training seeds 1000-1002, sampler seed 0,\n"
    "# the"
    " hard constraints and the robot's reflexes on): the best of each search's first "
    f"{budget}\n# completed trials, 4 significant digits, as `--set-file` overrides.\n\n"
)
(here / "tuned_weights.yaml").write_text(header + "\n".join(weights) + "\n")
