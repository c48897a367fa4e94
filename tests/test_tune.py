"""``ffmpc tune`` (studies/tune.py): a few trials on one seed improve the objective over the
scenario's own weights (the first trial), the search resumes from its SQLite database, and the
best weights are written into a scenario file that loads."""

from __future__ import annotations

import math

import pytest

from ffmpc_core.errors import ConfigError
from ffmpc_core.scenario import load_scenario
from ffmpc_ros.cli import main
from studies.tune import (
    SEARCH_SPACE,
    Objective,
    current_weights,
    searched_names,
    start_weights,
    tune,
)

#: 0.6 s of the circle (it starts 1.0 s in): short runs, the objective still sees the circle.
DURATION = 1.6
#: The search starts from the classical MPC's untuned weights (the authors' orientation and
#: joint-velocity terms, the code's c4 and c5), not from the shipped ones, which are tuned.
UNTUNED = {
    "mpc.weights.classical.force_phase": 1.0,
    "mpc.weights.classical.ee_position_phase": 1e3,
    "mpc.weights.classical.joint_velocity": 0.04,
    "mpc.weights.classical.ee_velocity": 1.0,
    "mpc.weights.classical.ee_rotation": 20.0,
}


def _two_trials(db) -> list[str]:
    """``ffmpc tune classical``: 2 trials on training seed 1000, stored in ``db``."""
    return ["tune", "classical", "--seeds", "1", "--first-seed", "1000", "--trials", "2",
            "--storage", str(db)]  # fmt: skip


def test_objective_is_the_stated_sum():
    j = Objective(position_weight=0.5, break_penalty=10.0, force_limit=150.0, force_penalty=1.0)
    assert j.of(4.0, 6.0, 0.0, 100.0) == pytest.approx(4.0 + 3.0)
    assert j.of(4.0, 6.0, 2.0, 170.0) == pytest.approx(4.0 + 3.0 + 20.0 + 20.0)
    # Joint speed over its limit: 50 N per unit of max |q̇|/limit above 1 (default).
    assert j.of(4.0, 6.0, 0.0, 100.0, 0.99) == pytest.approx(4.0 + 3.0)
    assert j.of(4.0, 6.0, 0.0, 100.0, 1.2) == pytest.approx(4.0 + 3.0 + 50.0 * 0.2)
    with pytest.raises(ConfigError):
        Objective(position_weight=-1.0)
    with pytest.raises(ConfigError):
        Objective(velocity_penalty=math.nan)


def test_search_space_is_the_same_but_for_the_terms_a_formulation_lacks():
    common = {"force_phase", "ee_position_phase", "joint_velocity", "ee_velocity", "ee_rotation"}
    assert set(searched_names("classical")) == common
    assert set(searched_names("torque_feedback")) == common | {"lowpass_input"}
    assert set(searched_names("force_feedback")) == common | {"force_rate"}
    w = current_weights(load_scenario("polishing"), "torque_feedback")
    assert set(w) == set(searched_names("torque_feedback"))
    assert (
        w["ee_rotation"] == load_scenario("polishing").mpc.weights["torque_feedback"]["ee_rotation"]
    )
    # A weight the file leaves out starts at its default; a 0 (term off) at the lower bound.
    untuned = load_scenario("polishing", {**UNTUNED, "mpc.weights.classical.ee_rotation": 0.0})
    start = current_weights(untuned, "classical")
    assert start["joint_velocity"] == 0.04 and start["ee_rotation"] == 0.1


def test_a_few_trials_improve_the_objective_and_the_search_resumes(tmp_path, capsys):
    db = tmp_path / "tune.db"
    out = tmp_path / "tuned.yaml"
    first = tune(
        "polishing",
        "classical",
        seeds=[1000],
        trials=4,
        storage=str(db),
        duration=DURATION,
        sampler_seed=3,
        workers=1,
        cache_dir=tmp_path / "cache",
        overrides=UNTUNED,
    )
    assert len(first.values) == 4 and first.trials_run == 4
    assert len(list((tmp_path / "cache").glob("*.json"))) == 4  # one run per trial
    assert first.best_value < first.values[0]  # better than the scenario's own weights
    assert db.is_file()
    # Resumed through the command line: the 4 trials are loaded, 2 more are added.
    code = main(
        [
            *_two_trials(db),
            "--sampler-seed",
            "3",
            "--duration",
            str(DURATION),
            "--out",
            str(out),
            "--workers",
            "2",
            "--cache-dir",
            str(tmp_path / "cache"),
            *(f"--set={name}={value}" for name, value in UNTUNED.items()),
        ]
    )
    assert code == 0
    assert len(list((tmp_path / "cache").glob("*.json"))) == 6  # the 2 new trials ran on Dask
    printed = capsys.readouterr().out
    assert "6 trials" in printed and "(4 resumed)" in printed
    tuned = load_scenario(out)
    written = tuned.mpc.weights["classical"]
    assert set(searched_names("classical")) <= set(written)
    import optuna

    study = optuna.load_study(study_name="polishing-classical", storage=f"sqlite:///{db}")
    assert len(study.trials) == 6
    old = [t.params for t in study.trials[:4]]
    assert all(t.params not in old for t in study.trials[4:])  # the resumed search goes on
    assert study.best_value <= first.best_value
    for name in searched_names("classical"):  # the file holds the best trial's weights
        assert written[name] == pytest.approx(study.best_params[name])
    with pytest.raises(ConfigError):  # never overwritten
        tune("polishing", "classical", [1000], 1, str(db), duration=DURATION, out=out, workers=1)
    # The search remembers its objective and training seeds: another is refused before any run.
    runs = len(list((tmp_path / "cache").glob("*.json")))
    for other in ({"objective": Objective(velocity_penalty=0.0)}, {"seeds": [1000, 1001]}):
        args = {"seeds": [1000], "objective": Objective(), **other}
        with pytest.raises(ConfigError, match="objective"):
            tune("polishing", "classical", trials=1, storage=str(db), workers=1, **args)
    assert len(list((tmp_path / "cache").glob("*.json"))) == runs


def test_start_weights_take_the_formulations_keys_clipped_to_the_search_bounds():
    base = current_weights(load_scenario("polishing"), "classical")
    doc = {
        "mpc.weights.classical.ee_rotation": 5e4,  # above the bound 1e3
        "mpc.weights.classical.joint_velocity": 0.5,
        "mpc.weights.force_feedback.ee_rotation": 43.0,  # another formulation's: ignored
    }
    start = start_weights(doc, "classical", base)
    assert start["ee_rotation"] == SEARCH_SPACE["ee_rotation"][1]
    assert start["joint_velocity"] == 0.5
    assert start["force_phase"] == base["force_phase"]  # not in the file: the scenario's
    with pytest.raises(ConfigError, match="no searched"):
        start_weights({"mpc.weights.force_feedback.ee_rotation": 43.0}, "classical", base)
    for bad in (math.nan, "big", True):
        with pytest.raises(ConfigError, match="finite"):
            start_weights({"mpc.weights.classical.ee_rotation": bad}, "classical", base)


def test_a_search_over_two_scenarios_averages_both_and_tries_the_start_points(tmp_path):
    """J over two scenarios is the mean of each scenario's J (runs read back from the cache);
    a ``--start-from`` file's weights are the second trial, right after the scenario's own."""
    from studies.execute import RunCache
    from studies.tune import evaluate

    db, cache = tmp_path / "tune.db", tmp_path / "cache"
    start = tmp_path / "start.yaml"
    start.write_text("mpc.weights.classical.ee_rotation: 200.0\n", encoding="utf-8")
    code = main(
        [
            *_two_trials(db),
            "--scenario",
            "polishing",
            "--scenario",
            "tilt",
            "--start-from",
            str(start),
            "--duration",
            str(DURATION),
            "--workers",
            "1",
            "--cache-dir",
            str(cache),
            *(f"--set={name}={value}" for name, value in UNTUNED.items()),
        ]
    )
    assert code == 0
    assert len(list(cache.glob("*.json"))) == 4  # 2 trials x 2 scenarios x 1 seed
    import optuna

    study = optuna.load_study(study_name="polishing+tilt-classical", storage=f"sqlite:///{db}")
    own = current_weights(load_scenario("polishing", UNTUNED), "classical")
    assert study.trials[0].params == pytest.approx(own)
    assert study.trials[1].params == pytest.approx({**own, "ee_rotation": 200.0})
    args = ([1000], Objective(), DURATION, UNTUNED)
    run_cache = RunCache(cache)
    both = evaluate(["polishing", "tilt"], "classical", own, *args, cache=run_cache)
    each = [evaluate(n, "classical", own, *args, cache=run_cache) for n in ("polishing", "tilt")]
    assert len(list(cache.glob("*.json"))) == 4  # all read back
    assert both == pytest.approx(study.trials[0].value)
    assert both == pytest.approx(sum(each) / 2) and each[0] != pytest.approx(each[1])
    with pytest.raises(ConfigError, match="twice"):
        evaluate(["polishing", "polishing"], "classical", own, *args, cache=run_cache)


def test_the_best_of_the_first_completed_trials_and_its_report():
    """first_completed: the budget counts completed trials in trial order (a failed one is
    skipped); best_trial_report names the best of them and lists J of each."""
    import optuna

    from studies.tune import best_trial_report, first_completed

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(study_name="demo")
    values = [3.0, None, 2.0, 2.5, 1.0]  # None: a failed trial; 1.0 is past the budget of 3
    for value in values:
        trial = study.ask()
        trial.suggest_float("force_phase", 0.1, 10.0)
        if value is None:
            study.tell(trial, state=optuna.trial.TrialState.FAIL)
        else:
            study.tell(trial, value)
    done, best = first_completed(study, 3)
    assert [t.number for t in done] == [0, 2, 3] and best.number == 2
    lines = best_trial_report(study, "demo.db", "classical", 3, "the scenario's weights")
    assert lines[0] == "search demo (demo.db): the first 3 completed trials"
    assert lines[1] == "  trial 0 (the scenario's weights): J = 3.0000"
    assert lines[2] == "  best: trial 2, J = 2.0000"
    assert lines[3].startswith("    mpc.weights.classical.force_phase = ")
    assert lines[-1] == "  J per trial: 3.000, 2.000, 2.500"
    with pytest.raises(ConfigError, match="no completed trial"):
        first_completed(optuna.create_study(study_name="empty"), 3)
