"""Write a search's best weights among its first N completed trials (the same budget for the
three searches) as a tuned scenario file and a log, from the search's Optuna storage.

    python benchmarks/results/tune/train1000-1002/constrained/write_best.py FORMULATION DB N
"""

import sys
from pathlib import Path

import optuna

from studies.tune import write_tuned_scenario

form, db, budget = sys.argv[1], sys.argv[2], int(sys.argv[3])
here = Path(__file__).parent
study = optuna.load_study(study_name=f"polishing-{form}-constrained", storage=f"sqlite:///{db}")
done = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
done = sorted(done, key=lambda t: t.number)[:budget]
best = min(done, key=lambda t: t.value)
out = here / f"tuned_{form}.yaml"
write_tuned_scenario("polishing", form, dict(best.params), out, best.value, [1000, 1001, 1002])
lines = [
    f"search polishing-{form}-constrained ({db}): the first {len(done)} completed trials",
    f"  trial 0 (the previous searches' weights): J = {done[0].value:.4f}",
    f"  best: trial {best.number}, J = {best.value:.4f}",
    *(f"    mpc.weights.{form}.{k} = {v:.6g}" for k, v in best.params.items()),
    f"  J per trial: {', '.join(f'{t.value:.3f}' for t in done)}",
]
(here / f"best_{form}.txt").write_text("\n".join(lines) + "\n")
print("\n".join(lines))
