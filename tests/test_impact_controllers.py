"""The impact experiment's controller objects (ffmpc_core.impact.controllers, .exploration).

Plants: a spring along d for the admittance task; the Panda's rigid-body dynamics (pinocchio
ABA, semi-implicit Euler at 1 kHz) above a spring-damper surface for the whole task.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.impact.control import ImpactControllerConfig
from ffmpc_core.impact.controllers import (
    AdmittanceConfig,
    AdmittanceRegulator,
    BaselineApproach,
    BaselineApproachConfig,
    ContactMeasurement,
    ForceFeedbackHandover,
    HandoverConfig,
    ImpactTaskConfig,
    ImpactTaskController,
    contact_measurement,
)
from ffmpc_core.impact.deformation import SoftMaterial
from ffmpc_core.impact.exploration import (
    ExplorationController,
    ExplorationControllerConfig,
)
from ffmpc_core.impact.learner import RecursiveContactLearner, exploration_reference
from ffmpc_core.impact.limits import joint_limits
from ffmpc_core.impact.task_space import JointLimitGuard, JointLimitGuardConfig
from ffmpc_core.robots import load_robot

DOWN = np.array([0.0, 0.0, -1.0])
DT = 1e-3


@pytest.fixture(scope="module")
def robot():
    return load_robot("panda")


def _spring_measurement(position_along: float, stiffness: float) -> ContactMeasurement:
    """A contact frame at ``position_along`` (m) below a surface at 0 with a pure spring."""
    force = stiffness * max(position_along, 0.0)
    return ContactMeasurement(
        q=np.zeros(7),
        v=np.zeros(7),
        position=position_along * DOWN,
        rotation=np.eye(3),
        speed=0.0,
        force=force,
        wrench=np.concatenate([-force * DOWN, np.zeros(3)]),
    )


def _run_admittance(regulator: AdmittanceRegulator, stiffness: float, steps: int) -> np.ndarray:
    regulator.start(np.zeros(3), np.eye(3), 0.0)
    forces = []
    along = 0.0
    for k in range(steps):
        m = _spring_measurement(along, stiffness)
        forces.append(m.force)
        command = regulator.step(m, k * DT)
        along = float(DOWN @ command.position)  # the reference, tracked perfectly
    return np.array(forces)


def test_admittance_regulator_converges_to_the_target_force_on_a_spring():
    regulator = AdmittanceRegulator(AdmittanceConfig(direction=DOWN, target_force=60.0))
    forces = _run_admittance(regulator, 3000.0, 3000)
    assert forces[0] == 0.0
    assert abs(forces[-1] - 60.0) < 0.05
    assert np.max(forces) < 60.0 * 1.05  # no large overshoot with the filtered admittance
    regulator.reset()
    again = _run_admittance(regulator, 3000.0, 3000)
    np.testing.assert_array_equal(forces, again)  # reset gives the same run


def test_admittance_regulator_needs_a_start_and_monotonic_time():
    regulator = AdmittanceRegulator(AdmittanceConfig(direction=DOWN))
    m = _spring_measurement(0.0, 1000.0)
    with pytest.raises(InputError, match="start"):
        regulator.step(m, 0.0)
    regulator.start(np.zeros(3), np.eye(3), 0.0)
    regulator.step(m, 0.1)
    with pytest.raises(InputError, match="non-decreasing"):
        regulator.step(m, 0.05)
    with pytest.raises(ConfigError):
        AdmittanceConfig(direction=DOWN, target_force=-1.0)


def _static_measurement(robot, q: np.ndarray) -> ContactMeasurement:
    return contact_measurement(robot, robot.create_data(), q, np.zeros(robot.nv), np.zeros(6), DOWN)


def test_baseline_approach_stops_at_its_target_depth(robot):
    limits = joint_limits(robot)
    config = BaselineApproachConfig(direction=DOWN, distance=0.1, frequency=5.0, refresh=0.05)
    baseline = BaselineApproach(robot, limits, config)
    m = _static_measurement(robot, robot.q_nominal)
    start = m.position.copy()
    first = [baseline.step(m, k * DT) for k in range(50)]
    for k in range(50, 3000):
        command = baseline.step(m, k * DT)
    np.testing.assert_allclose(command.position, start + 0.1 * DOWN, atol=2e-4)
    assert np.linalg.norm(command.velocity) < 2e-3
    assert baseline.position <= 0.1 + 1e-9  # critically damped: no overshoot
    baseline.reset()
    again = [baseline.step(m, k * DT) for k in range(50)]
    for a, b in zip(first, again, strict=True):
        np.testing.assert_array_equal(a.position, b.position)
        np.testing.assert_array_equal(a.acceleration, b.acceleration)
    assert first[0].acceleration[2] < 0.0  # accelerates down, along d


def test_handover_engages_blends_and_takes_the_learned_model(robot):
    limits = joint_limits(robot)
    guard = JointLimitGuard(robot, limits, JointLimitGuardConfig(dt=DT))
    learner = RecursiveContactLearner()
    config = HandoverConfig(direction=DOWN, blend=0.01, mpc_period=0.004)
    handover = ForceFeedbackHandover(robot, guard, learner, config)
    assert not handover.ready(False, 0.0)
    assert not handover.ready(True, 0.2)
    assert handover.ready(True, -0.2)  # moving out fast is fine without symmetric_speed
    symmetric = ForceFeedbackHandover(
        robot, guard, learner, HandoverConfig(direction=DOWN, symmetric_speed=True)
    )
    assert not symmetric.ready(True, -0.2) and symmetric.ready(True, 0.05)

    data = robot.create_data()
    q = robot.q_nominal
    wrench = np.array([0.0, 0.0, 20.0, 0.0, 0.0, 0.0])
    m = contact_measurement(robot, data, q, np.zeros(7), wrench, DOWN)
    assert m.force == pytest.approx(20.0)
    first = [handover.step(m, k * DT) for k in range(12)]
    assert handover.engaged and handover.engage_time == 0.0
    np.testing.assert_allclose([c.weight for c in first[:10]], (np.arange(10) + 1) / 10)
    assert all(c.weight == 1.0 for c in first[10:])
    assert len(handover.solve_times) == 3  # every 4 steps
    assert not first[-1].learned and first[-1].stiffness == config.prior_stiffness
    for c in first:
        assert np.all(np.abs(c.torque) <= robot.torque_limit + 1e-9)

    handover.reset()
    again = [handover.step(m, k * DT) for k in range(12)]
    for a, b in zip(first, again, strict=True):
        np.testing.assert_allclose(a.torque, b.torque, rtol=0, atol=1e-9)

    # A confident learner replaces the prior at the next MPC solve.
    rng = np.random.default_rng(3)
    for z, zd in zip(rng.uniform(0, 0.01, 50), rng.uniform(-0.1, 0.1, 50), strict=True):
        learner.update(z, zd, 3000.0 * z + 20.0 * zd)
    handover.reset()
    command = handover.step(m, 0.0)
    assert command.learned
    assert command.stiffness == pytest.approx(3000.0, rel=1e-4)
    assert command.damping == pytest.approx(20.0, rel=1e-4)


def _task_run(controller: ImpactTaskController, robot, gap: float, material, steps: int):
    """The Panda (ABA, 1 kHz) starting ``gap`` m above a spring-damper surface."""
    model, data, fid = robot.model, robot.create_data(), robot.contact_frame_id
    q, v = robot.q_nominal.copy(), np.zeros(robot.nv)
    surface = robot.contact_placement(q).translation[2] - gap
    lwa = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    forces, torques = [], []
    for k in range(steps):
        pin.forwardKinematics(model, data, q, v)
        pin.updateFramePlacements(model, data)
        z = surface - data.oMf[fid].translation[2]
        zd = -pin.getFrameVelocity(model, data, fid, lwa).linear[2]
        f = max(0.0, material.stiffness * z + material.damping * zd) if z > 0 else 0.0
        wrench = np.concatenate([-f * DOWN, np.zeros(3)])
        m = contact_measurement(robot, data, q, v, wrench, DOWN)
        command = controller.step(m, k * DT)
        J = pin.computeFrameJacobian(model, data, q, fid, lwa)
        qdd = pin.aba(model, data, q, v, command.torque + J[:3].T @ wrench[:3])
        v = v + qdd * DT
        q = pin.integrate(model, q, v * DT)
        forces.append(f)
        torques.append(command.torque)
    return np.array(forces), np.array(torques)


def test_impact_task_baseline_touches_then_regulates_the_target(robot):
    limits = joint_limits(robot)
    material = SoftMaterial(3000.0, 20.0, 0.03)
    config = ImpactTaskConfig(
        approach="baseline",
        regulation="admittance",
        controller=ImpactControllerConfig(direction=DOWN, material=material, target_force=30.0),
        guard=JointLimitGuardConfig(dt=DT),
        baseline=BaselineApproachConfig(direction=DOWN, distance=0.025, refresh=0.01),
    )
    controller = ImpactTaskController(robot, limits, config)
    forces, torques = _task_run(controller, robot, 0.02, material, 2500)
    assert controller.contact_time is not None and controller.contact_time < 1.5
    assert controller.admittance.started
    assert controller.learner.samples > 100
    assert abs(forces[-1] - 30.0) < 1.5
    controller.reset()
    assert controller.contact_time is None and controller.learner.samples == 0
    again, torques_again = _task_run(controller, robot, 0.02, material, 300)
    np.testing.assert_array_equal(torques[:300], torques_again)


def test_impact_task_config_refuses_missing_parts():
    material = SoftMaterial(3000.0, 20.0, 0.03)
    ctrl = ImpactControllerConfig(direction=DOWN, material=material)
    guard = JointLimitGuardConfig(dt=DT)
    with pytest.raises(ConfigError, match="baseline"):
        ImpactTaskConfig("baseline", "admittance", ctrl, guard)
    with pytest.raises(ConfigError, match="handover"):
        ImpactTaskConfig("maximal", "ff_mpc", ctrl, guard)
    with pytest.raises(ConfigError, match="approach"):
        ImpactTaskConfig("fast", "admittance", ctrl, guard)
    with pytest.raises(InputError):
        ContactMeasurement(
            np.zeros(7), np.zeros(7), np.full(3, np.nan), np.eye(3), 0.0, 0.0, np.zeros(6)
        )


def _exploration_run(controller: ExplorationController, robot, gap: float, material):
    """The Panda (ABA, 1 kHz) ``gap`` m above a spring-damper surface until the motion ends."""
    model, data, fid = robot.model, robot.create_data(), robot.contact_frame_id
    q, v = robot.q_nominal.copy(), np.zeros(robot.nv)
    surface = robot.contact_placement(q).translation[2] - gap
    lwa = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    commands = []
    for k in range(20000):
        pin.forwardKinematics(model, data, q, v)
        pin.updateFramePlacements(model, data)
        z = surface - data.oMf[fid].translation[2]
        zd = -pin.getFrameVelocity(model, data, fid, lwa).linear[2]
        f = max(0.0, material.stiffness * z + material.damping * zd) if z > 0 else 0.0
        wrench = np.concatenate([-f * DOWN, np.zeros(3)])
        command = controller.step(contact_measurement(robot, data, q, v, wrench, DOWN), k * DT)
        commands.append(command)
        if command.done:
            return commands, surface
        J = pin.computeFrameJacobian(model, data, q, fid, lwa)
        qdd = pin.aba(model, data, q, v, command.torque + J[:3].T @ wrench[:3])
        v = v + qdd * DT
        q = pin.integrate(model, q, v * DT)
    raise AssertionError("the exploration never ended")


def test_exploration_controller_finds_the_surface_and_learns_the_material(robot):
    material = SoftMaterial(3000.0, 20.0, 0.03)
    gap = 0.002
    config = ExplorationControllerConfig(
        reference=exploration_reference(
            0.03, dt=DT, sine_cycles=1, impact_velocities=np.array([0.15]), dwell=0.1
        ),
        start_height=robot.contact_placement(robot.q_nominal).translation[2],
        guard=JointLimitGuardConfig(dt=DT, margin=0.9),
        start_clearance=gap,
        approach_speed=0.005,
        prior_stiffness=3000.0,
        prior_damping=20.0,
    )
    controller = ExplorationController(robot, joint_limits(robot), config)
    commands, surface = _exploration_run(controller, robot, gap, material)
    assert controller.surface is not None
    # the surface is the last force-free sample: at most one approach step above the truth
    assert 0.0 <= controller.surface[2] - surface <= 0.005 * DT + 1e-6
    phases = {c.phase for c in commands}
    assert phases == {-1, 0, 1}
    est = controller.learner.estimate()
    assert est.stiffness == pytest.approx(3000.0, rel=0.02)
    assert est.damping == pytest.approx(20.0, rel=0.1)
    # the impact's first in-contact sample is not fed (the force is partial in that step)
    onsets = [c for c in commands if c.onset]
    assert len(onsets) == 1 and onsets[0].phase == 1 and not onsets[0].fed
    controller.reset()
    assert controller.surface is None and controller.learner.samples == 0
    again, _ = _exploration_run(controller, robot, gap, material)
    assert len(again) == len(commands)
    for a, b in zip(commands[:500], again[:500], strict=True):
        np.testing.assert_array_equal(a.torque, b.torque)


def test_exploration_controller_refuses_a_start_in_contact(robot):
    config = ExplorationControllerConfig(
        reference=exploration_reference(0.03, dt=DT, sine_cycles=1),
        start_height=0.5,
        guard=JointLimitGuardConfig(dt=DT),
    )
    controller = ExplorationController(robot, joint_limits(robot), config)
    m = _static_measurement(robot, robot.q_nominal)
    pressed = ContactMeasurement(m.q, m.v, m.position, m.rotation, 0.0, 5.0, np.zeros(6))
    with pytest.raises(ConfigError, match="in contact at the start"):
        controller.step(pressed, 0.0)


@pytest.mark.parametrize("constraints", [False, True])
def test_the_handover_mpc_has_the_hard_constraints_the_study_says(robot, constraints):
    """``mpc.constraints`` of the impact study reaches the hand-over's MPC: off by default (the
    constrained MPC broke limits on model-error dice, ``HandoverConfig``), on when asked."""
    from ffmpc_core.impact.scenario import load_impact_config

    assert load_impact_config().mpc_constraints is False
    study = load_impact_config(overrides={"mpc.constraints": constraints})
    assert study.mpc_constraints is constraints
    limits = joint_limits(robot)
    guard = JointLimitGuard(robot, limits, JointLimitGuardConfig(dt=DT))
    config = HandoverConfig(direction=DOWN, mpc_constraints=study.mpc_constraints)
    handover = ForceFeedbackHandover(robot, guard, RecursiveContactLearner(), config)
    data = robot.create_data()
    wrench = np.array([0.0, 0.0, 20.0, 0.0, 0.0, 0.0])
    m = contact_measurement(robot, data, robot.q_nominal, np.zeros(7), wrench, DOWN)
    handover.step(m, 0.0)
    assert handover.mpc is not None
    assert handover.mpc.config.constraints.enabled is constraints
