"""The guarded approach in the ROS-free closed loop (studies.polishing): the force-feedback MPC
descends in free space at the approach speed, switches to its contact model when the measured
force crosses the threshold, and holds in free space when the table is beyond the bound.

The table is tilted by a fixed 6° about the y axis through the circle's centre, so that under the
tool, 7 cm from that axis, it is 7.3 mm LOWER than the controller believes (no random tilt);
the reflexes are on (the scenario's default). Each run is ~1.2 s of simulated time.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from ffmpc_core.errors import InputError
from ffmpc_core.mpc import ModelPredictiveController, MpcMeasurement
from ffmpc_core.polishing import build_task, mpc_config, scenario_robot
from ffmpc_core.scenario import load_scenario
from ffmpc_core.tasks import GuardedTask
from studies.polishing import run_polishing

LOWER_TABLE = {"plant.random_tilt_deg": 0.0, "plant.table_tilt_deg": 6.0, "seed": 3}
DROP = 0.07 * math.sin(math.radians(6.0))  # m, the real table below the believed one


def _first_contact(result) -> int:
    """Cycle of the first true contact force above 0.01 N."""
    return int(np.argmax(result.log["force_true"] > 0.01))


def test_force_feedback_touches_a_lower_table_at_the_approach_speed() -> None:
    scenario = load_scenario("polishing", LOWER_TABLE)
    task_cfg = scenario.task
    assert scenario.mpc.ocp.formulation == "force_feedback" and scenario.plant.reflex
    speed = task_cfg.approach_speed
    assert speed > 0.0
    nominal = task_cfg.still + task_cfg.reach  # the reach's end: clearance above the belief
    expected = nominal + (task_cfg.approach_clearance + DROP) / speed  # reference at the table
    result = run_polishing(scenario, duration=expected + 0.4)
    assert not result.aborted, result.reflex
    assert result.contact_time is not None and not result.contact_missed
    # the contact was measured when the tool really met the lower table, not at a fixed time
    assert expected - 0.1 < result.contact_time < expected + 0.15, result.contact_time
    k = _first_contact(result)
    t, z = result.log["t"], result.log["ee_position"][:, 2]
    assert t[k] < result.contact_time + 0.02
    # the tool's speed along the normal over the 5 ms before the first contact
    velocity = np.diff(z[k - 6 : k]) / np.diff(t[k - 6 : k])
    assert -velocity.min() <= speed * 1.3 + 0.005, (velocity, speed)
    # and the impact stays light: well below the 25 N of the time-based touch
    after = result.log["force_true"][k : k + 20]
    assert after.max() < 10.0, after.max()
    # the phases moved with the detection: no force reference before it, touch force after
    f_ref = result.log["force_reference"]
    assert np.all(f_ref[t < result.contact_time - 1e-9] == 0.0)
    assert f_ref[np.searchsorted(t, result.contact_time + 0.1)] == pytest.approx(
        task_cfg.touch_force
    )
    assert max(result.max_velocity_ratio) < 1.0


def test_a_table_beyond_the_bound_is_never_touched_and_the_run_says_so() -> None:
    """approach_depth 0: the descent stops on the believed table, 7.3 mm above the real one."""
    scenario = load_scenario("polishing", {**LOWER_TABLE, "task.approach_depth": 0.0})
    task_cfg = scenario.task
    bound = task_cfg.still + task_cfg.reach + task_cfg.approach_clearance / task_cfg.approach_speed
    result = run_polishing(scenario, duration=bound + 0.3)
    assert result.contact_missed and result.contact_time is None
    assert not result.aborted
    assert result.log["force_true"].max() == 0.0
    assert np.all(result.log["force_reference"] == 0.0)
    # it holds at the bound: the believed table, within a millimetre
    t, z = result.log["t"], result.log["ee_position"][:, 2]
    held = z[t > bound + 0.15]
    believed = build_task(scenario, scenario_robot(scenario)).contact_position[2]
    assert np.all(np.abs(held - believed) < 1e-3), (held.min(), held.max(), believed)
    summary = result.summary()
    assert summary["contact_missed"] is True and summary["contact_time_s"] is None


def test_every_formulation_needs_the_measured_force_to_detect() -> None:
    scenario = load_scenario("polishing", {"mpc.formulation": "classical"})
    robot = scenario_robot(scenario)
    task = build_task(scenario, robot)
    assert isinstance(task, GuardedTask)
    mpc = ModelPredictiveController(robot, mpc_config(scenario), task)
    q, v = robot.q_nominal, np.zeros(robot.nv)
    t = task.contact_time + 0.1  # in the descent (the first step: no outage before it)
    with pytest.raises(InputError, match="guarded approach"):
        mpc.step(MpcMeasurement(q=q, v=v), t)
    # a detection switches the classical OCP's nodes to the contact model
    assert not mpc.nodes[0].in_contact
    mpc.step(MpcMeasurement(q=q, v=v, force=np.array([1.0])), t)
    assert task.detected_at is None and not mpc.nodes[0].in_contact  # below the threshold
    mpc.step(MpcMeasurement(q=q, v=v, force=np.array([3.0])), t + 0.002)
    assert task.detected_at == pytest.approx(t + 0.002)
    assert all(node.in_contact for node in mpc.nodes)
