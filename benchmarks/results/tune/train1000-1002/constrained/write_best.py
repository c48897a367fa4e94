"""Write a search's best weights among its first N completed trials (the same budget for the
three searches) as a tuned scenario file and a log, from the search's Optuna storage.

    python benchmarks/results/tune/train1000-1002/constrained/write_best.py FORMULATION DB N
"""

import sys
from pathlib import Path

import optuna

from studies.tune import best_trial_report, first_completed, write_tuned_scenario

form, db, budget = sys.argv[1], sys.argv[2], int(sys.argv[3])
here = Path(__file__).parent
study = optuna.load_study(study_name=f"polishing-{form}-constrained", storage=f"sqlite:///{db}")
_, best = first_completed(study, budget)
out = here / f"tuned_{form}.yaml"
write_tuned_scenario("polishing", form, dict(best.params), out, best.value, [1000, 1001, 1002])
lines = best_trial_report(study, db, form, budget, "the previous searches' weights")
(here / f"best_{form}.txt").write_text("\n".join(lines) + "\n")
print("\n".join(lines))
