"""The impact control scheme (Dehio & Kheddar 2020, Sec. IV-C) in a closed loop.

The plant is the Panda's rigid-body dynamics (pinocchio ABA, semi-implicit Euler at 1 kHz) with
a linear spring-damper surface below the tool (eq 3 with the same α, β the controller plans with).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.impact.control import (
    APPROACH,
    CONTACT,
    AdmittanceForceController,
    ImpactController,
    ImpactControllerConfig,
    ImpactMeasurement,
)
from ffmpc_core.impact.deformation import SoftMaterial
from ffmpc_core.impact.limits import joint_limits
from ffmpc_core.impact.task_space import TaskSpaceInverseDynamics
from ffmpc_core.robots import load_robot

DOWN = np.array([0.0, 0.0, -1.0])
LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


def _run(steps: int, gap: float, material: SoftMaterial, dt: float = 1e-3):
    robot = load_robot("panda")
    limits = joint_limits(robot)
    controller = ImpactController(
        robot, limits, ImpactControllerConfig(direction=DOWN, material=material)
    )
    law = TaskSpaceInverseDynamics(robot)
    model, data, fid = robot.model, robot.create_data(), robot.contact_frame_id
    q, v = robot.q_nominal.copy(), np.zeros(7)
    surface = robot.contact_placement(q).translation[2] - gap
    log = []
    for k in range(steps):
        pin.forwardKinematics(model, data, q, v)
        pin.updateFramePlacements(model, data)
        z = surface - data.oMf[fid].translation[2]  # penetration along DOWN, m
        zd = -pin.getFrameVelocity(model, data, fid, LWA).linear[2]
        f = max(0.0, material.stiffness * z + material.damping * zd) if z > 0 else 0.0
        f_ext = -f * DOWN  # on the robot, world frame
        cmd = controller.step(ImpactMeasurement(q, v, f_ext), k * dt)
        tau = law.torque(cmd, q, v, f_ext)
        J = pin.computeFrameJacobian(model, data, q, fid, LWA)
        qdd = pin.aba(model, data, q, v, tau + J[:3].T @ f_ext)
        v = v + qdd * dt
        q = pin.integrate(model, q, v * dt)
        log.append(
            (
                k * dt,
                z,
                zd,
                f,
                cmd.pre_impact_velocity,
                cmd.phase,
                np.abs(v / limits.velocity).max(),
            )
        )
    return controller, log


def test_closed_loop_impacts_at_the_planned_speed_then_regulates_60_newton():
    material = SoftMaterial(2000.0, 50.0, 0.05)
    controller, log = _run(steps=2000, gap=0.15, material=material)
    phases = [row[5] for row in log]
    assert phases[0] == APPROACH and phases[-1] == CONTACT
    k_contact = phases.index(CONTACT)
    bound_before = log[k_contact - 1][4]
    # the impact happens near the maximal safe pre-impact velocity of the last approach cycle
    assert controller.contact_velocity == pytest.approx(bound_before, rel=0.05)
    assert controller.contact_velocity > 0.3  # a real impact, not a slow touch (m/s)
    # safety: elastic domain and joint velocity limits respected over the whole run
    assert max(row[1] for row in log) <= material.max_penetration
    assert max(row[6] for row in log) <= 1.0
    # force regulation to the paper's 60 N
    assert log[-1][3] == pytest.approx(60.0, abs=1.5)
    assert controller.solver_failures == 0
    # online learning during contact recovers the surface model (detection offset ≈ 1 step)
    est = controller.learner.estimate()
    assert est.stiffness == pytest.approx(material.stiffness, rel=0.05)
    assert est.damping == pytest.approx(material.damping, rel=0.15)


def test_admittance_converges_on_a_spring():
    """Robot-independent: a position-controlled point on a 2000 N/m spring, force → target."""
    adm = AdmittanceForceController()
    stiffness, dt, x, vref = 2000.0, 1e-3, 0.0, 0.0
    for _ in range(3000):
        vref = adm.velocity(vref, stiffness * max(x, 0.0), 60.0, dt)
        x += vref * dt
    assert stiffness * x == pytest.approx(60.0, rel=1e-3)
    with pytest.raises(ConfigError):
        AdmittanceForceController(velocity_filter=1.0)


def test_controller_rejects_bad_measurements():
    robot = load_robot("panda")
    controller = ImpactController(
        robot,
        joint_limits(robot),
        ImpactControllerConfig(direction=DOWN, material=SoftMaterial(2000.0, 50.0, 0.05)),
    )
    good = ImpactMeasurement(robot.q_nominal, np.zeros(7), np.zeros(3))
    controller.step(good, 1.0)
    with pytest.raises(InputError):
        controller.step(good, 0.5)  # time goes backwards
    with pytest.raises(InputError):
        controller.step(ImpactMeasurement(robot.q_nominal, np.zeros(7), np.full(3, np.nan)), 2.0)
    with pytest.raises(InputError):
        controller.step(ImpactMeasurement(robot.q_nominal[:6], np.zeros(7), np.zeros(3)), 2.0)
    with pytest.raises(ConfigError):
        ImpactControllerConfig(
            direction=DOWN, material=SoftMaterial(2000.0, 50.0, 0.05), contact_threshold=100.0
        )
    controller.reset()
    assert controller.phase == APPROACH
