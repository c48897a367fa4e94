"""Runs on the MuJoCo plant (``plant.engine: mujoco``, ``--plant mujoco``): a short polishing run
and a short impact run through the ROS-free runner and through the node graph (bit-identical,
as on PyBullet: tests/test_ros_graph.py, tests/test_impact_graph.py), the study command and its
document, and the flag's checks."""

from __future__ import annotations

import json

import numpy as np
import pytest
from ros_helpers import assert_same_run

from ffmpc_core.errors import ConfigError
from ffmpc_core.impact.scenario import load_impact_config
from ffmpc_core.scenario import PLANT_ENGINES, load_scenario
from ffmpc_ros import cli_args
from ffmpc_ros.bringup import GraphOptions, run_graph
from ffmpc_ros.cli import main
from ffmpc_ros.impact_graph import compare_with_runner, run_impact_graph
from sim_bridge.mujoco_plant import MujocoPlant
from studies.impact_study import run_impact
from studies.polishing import run_polishing

#: The impact graph's short maximal run (tests/test_impact_graph.py): 5 cm above the dice.
MAXIMAL = ["strategy=prior", "approach_height=0.05", "duration=0.35"]


def test_polishing_on_mujoco_graph_equals_the_runner():
    """1 s of the force-feedback polishing run (seed 2) on MuJoCo: the single-process node
    graph's plant node builds the same MuJoCo plant as the runner, every logged signal equal;
    the run reaches the table, and it is not the PyBullet run."""
    overrides = {
        "seed": 2,
        "mpc.formulation": "force_feedback",
        "plant.engine": "mujoco",
        "task.approach_speed": 0.0,  # the time-based switch: the table within the second
    }
    scenario = load_scenario("polishing", overrides)
    graph = run_graph(scenario, GraphOptions(duration=1.0, single_process=True, timeout=180))
    runner = run_polishing(scenario, duration=1.0)
    assert_same_run(graph, runner)
    assert graph.summary()["plant_engine"] == "mujoco"
    force = runner.log["force_true"]
    assert force.max() > 5.0 and np.all(np.isfinite(force))
    bullet = run_polishing(scenario.with_overrides({"plant.engine": "pybullet"}), duration=1.0)
    assert not np.array_equal(bullet.log["force_true"], force)
    # the same experiment in either engine: first contact within 10 ms
    first = [float(r.log["t"][np.argmax(r.log["force_true"] > 1.0)]) for r in (runner, bullet)]
    assert first[0] == pytest.approx(first[1], abs=0.01)


def test_impact_on_mujoco_graph_equals_the_runner():
    """The maximal approach with the admittance regulation, 5 cm above the dice, on MuJoCo:
    the impact graph's dice plant equals the ROS-free study's run; no limit violated, and the
    contact, the pre-impact velocity and the peak penetration are PyBullet's (measured: contact
    at 0.178 s with 0.456 m/s in both, 31.2 vs 30.2 mm: Bullet's implicit spring damps more;
    the ``prior`` strategy plans with a prior softer than the dice, past z̄ = 30 mm in both)."""
    items = [*MAXIMAL, "plant.engine=mujoco"]
    graph = run_impact_graph("maximal", "admittance", overrides=items, timeout=180)
    values = {"strategy": "prior", "approach_height": 0.05, "duration": 0.35}
    config = load_impact_config("impact", {**values, "plant.engine": "mujoco"})
    runner = run_impact("maximal", "admittance", config)
    assert compare_with_runner(graph, runner) == {}
    assert graph.summary()["plant_engine"] == "mujoco"
    assert runner.violations.total == 0
    bullet = run_impact("maximal", "admittance", load_impact_config("impact", values))
    assert runner.contact_time == pytest.approx(bullet.contact_time, abs=5e-3)
    assert runner.pre_impact_velocity == pytest.approx(bullet.pre_impact_velocity, rel=0.01)
    assert runner.peak_penetration == pytest.approx(bullet.peak_penetration, rel=0.05)


def test_study_records_the_engine(tmp_path, capsys):
    """``ffmpc study polishing --plant mujoco``: the runs use MuJoCo and the document and the
    tables say so."""
    out = tmp_path / "study"
    argv = ["study", "polishing", "--seeds", "1", "--workers", "1", "--duration", "0.2"]
    argv += ["--formulations", "classical", "--pid", "on", "--plant", "mujoco"]
    argv += ["--out", str(out), "--no-progress", "--no-cache"]
    assert main(argv) == 0
    capsys.readouterr()
    doc = json.loads((out / "results.json").read_text())
    assert doc["plant_engine"] == "mujoco" and doc["overrides"]["plant.engine"] == "mujoco"
    assert doc["scenario_parameters"]["plant"]["engine"] == "mujoco"
    assert doc["versions"]["mujoco"] == "3.17.0"
    assert "Plant simulator (`plant.engine`): mujoco" in (out / "tables.md").read_text()


def test_plant_flag_and_set_must_agree(capsys):
    assert cli_args.PLANT_ENGINES == PLANT_ENGINES
    assert cli_args.with_plant_engine({"seed": 1}, "mujoco") == {
        "seed": 1,
        "plant.engine": "mujoco",
    }
    assert cli_args.with_plant_engine({"plant.engine": "mujoco"}, None) == {
        "plant.engine": "mujoco"
    }
    with pytest.raises(ConfigError, match="give one"):
        cli_args.with_plant_engine({"plant.engine": "pybullet"}, "mujoco")
    argv = ["run", "polishing", "--plant", "mujoco", "--set", "plant.engine=pybullet"]
    assert main(argv) == 2
    assert "give one" in capsys.readouterr().err
    argv = ["run", "impact", "--plant", "mujoco", "--set", "plant.engine=pybullet"]
    assert main(argv) == 2
    assert "give one" in capsys.readouterr().err
    argv = ["study", "impact", "--plant", "mujoco", "--set", "plant.engine=pybullet"]
    assert main(argv) == 2
    assert "--plant" in capsys.readouterr().err
    with pytest.raises(ConfigError, match="plant.engine"):
        load_scenario("polishing", {"plant.engine": "gazebo"})
    with pytest.raises(ConfigError, match="engine"):
        load_impact_config("impact", {"plant.engine": "gazebo"})


def test_a_scenario_builds_the_plant_of_its_engine():
    from ffmpc_core.polishing import device_generator
    from ffmpc_core.robots import load_robot
    from sim_bridge.scenes import simulated_robot

    scenario = load_scenario("polishing", {"plant.engine": "mujoco"})
    robot = load_robot(scenario.robot)
    draws, actuation = (device_generator(scenario.seed, d) for d in ("draws", "actuation"))
    sim = simulated_robot(scenario, robot, draws, actuation)
    with sim.plant as plant:
        assert isinstance(plant, MujocoPlant)
        assert plant.config.table is not None
        assert plant.config.table.stiffness == scenario.plant.table_stiffness
