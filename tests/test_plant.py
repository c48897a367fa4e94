"""The PyBullet plant: dynamics equal pinocchio's, contact forces equal the statics, the tool,
the table, soft boxes, pushes, saturation and input checks."""

from __future__ import annotations

import functools

import numpy as np
import pinocchio as pin
import pytest

from ffmpc_core.actuation import ActuationModel, ActuationParams
from ffmpc_core.errors import ConfigError, InputError, ModelError
from ffmpc_core.robots import ToolLoad, load_robot, with_tool_load
from sim_bridge.plant import (
    TOOL_LINK,
    Plant,
    PlantConfig,
    SoftBoxConfig,
    TableConfig,
    ToolConfig,
    model_with_tool,
)

FORCE = 50.0  # N, the paper's force reference

robot_named = functools.cache(load_robot)


@pytest.fixture(scope="module", params=["iiwa", "panda"])
def robot(request):
    return robot_named(request.param)


def random_state(robot, rng):
    """A state away from the joint limits, moderate velocity and torque."""
    mid = 0.5 * (robot.position_lower + robot.position_upper)
    half = 0.5 * (robot.position_upper - robot.position_lower)
    q = mid + 0.6 * half * rng.uniform(-1.0, 1.0, robot.nv)
    v = rng.uniform(-0.5, 0.5, robot.nv)
    tau = 0.2 * robot.torque_limit * rng.uniform(-1.0, 1.0, robot.nv)
    return q, v, tau


def one_step_acceleration(plant, q, v, tau):
    """PyBullet's acceleration over one step: semi-implicit Euler gives v1 = v0 + dt·a(q0, v0)."""
    plant.reset(q, v)
    plant.step(tau)
    return (plant.state().v - v) / plant.dt


@pytest.mark.parametrize("time_step", [1e-3, 5e-4])
def test_free_acceleration_matches_aba(robot, time_step):
    rng = np.random.default_rng(3)
    with Plant(robot, PlantConfig(table=None, time_step=time_step)) as plant:
        for _ in range(3):
            q, v, tau = random_state(robot, rng)
            a_pin = pin.aba(robot.model, robot.create_data(), q, v, tau)
            a_pb = one_step_acceleration(plant, q, v, tau)
            # Same articulated-body algorithm, double precision: agreement to round-off.
            assert np.allclose(a_pb, a_pin, rtol=1e-8, atol=1e-8 * np.abs(a_pin).max())


def test_massive_tool_is_accounted_for(robot):
    """A tool with mass changes the dynamics; model_with_tool is then the simulated model."""
    tool = ToolConfig(mass=0.2, radius=0.015)
    q, v, tau = random_state(robot, np.random.default_rng(5))
    with Plant(robot, PlantConfig(table=None, tool=tool)) as plant:
        a_pb = one_step_acceleration(plant, q, v, tau)
    a_rigid = pin.aba(robot.model, robot.create_data(), q, v, tau)
    augmented = model_with_tool(robot, tool)
    a_tool = pin.aba(augmented, augmented.createData(), q, v, tau)
    scale = np.abs(a_tool).max()
    assert np.abs(a_pb - a_rigid).max() > 1e-4 * scale  # the tool mass is visible ...
    assert np.allclose(a_pb, a_tool, rtol=1e-8, atol=1e-8 * scale)  # ... and accounted for


def test_tool_with_an_offset_centre_of_mass_is_the_controllers_load(robot):
    """A 1 kg tool whose centre of mass is off the tool axis (flange frame): PyBullet's dynamics
    equal pinocchio's with ``ffmpc_core.robots.with_tool_load`` of the same numbers (the load the
    controllers carry) and ``model_with_tool``."""
    com = (0.03, -0.02, 0.08)
    tool = ToolConfig(mass=1.0, center_of_mass=com)
    q, v, tau = random_state(robot, np.random.default_rng(8))
    with Plant(robot, PlantConfig(table=None, tool=tool)) as plant:
        a_pb = one_step_acceleration(plant, q, v, tau)
    loaded = with_tool_load(robot, ToolLoad(1.0, com, radius=tool.radius)).model
    a_load = pin.aba(loaded, loaded.createData(), q, v, tau)
    augmented = model_with_tool(robot, tool)
    a_tool = pin.aba(augmented, augmented.createData(), q, v, tau)
    scale = np.abs(a_load).max()
    np.testing.assert_allclose(a_tool, a_load, rtol=1e-12, atol=1e-12 * scale)
    assert np.allclose(a_pb, a_load, rtol=1e-8, atol=1e-8 * scale)
    centred = with_tool_load(robot, ToolLoad(1.0, (0.0, 0.0, 0.08))).model
    a_centred = pin.aba(centred, centred.createData(), q, v, tau)
    assert np.abs(a_centred - a_load).max() > 1e-4 * scale  # the offset is visible


def test_contact_frame_is_pinocchio_contact_frame(robot):
    rng = np.random.default_rng(7)
    data = robot.create_data()
    with Plant(robot, PlantConfig(table=None)) as plant:
        for _ in range(3):
            q, _, _ = random_state(robot, rng)
            plant.reset(q)
            state = plant.state()
            placement = robot.contact_placement(q, data)
            assert np.allclose(state.contact_frame_position, placement.translation, atol=1e-6)
            assert np.allclose(state.contact_frame_rotation, placement.rotation, atol=1e-6)
            assert np.allclose(state.q, q) and np.allclose(state.v, 0.0)
            assert not state.in_contact


class ForceController:
    """τ = g(q) − J_pᵀ f_des − M(q)·(ζ q̇): press the tool with the force f_des (world frame).

    J_p is the Jacobian of the tool point that touches the table (sphere centre − r·n), so at
    rest the contact force must equal f_des exactly (J_p has full row rank). ζ = 20 s⁻¹ damps all
    motion, null space included, and vanishes at rest.
    """

    def __init__(self, plant, force, normal):
        self.robot = plant.robot
        self.data = self.robot.create_data()
        self.radius = plant.config.tool.radius
        self.force = np.asarray(force, dtype=float)
        self.normal = np.asarray(normal, dtype=float)

    def __call__(self, q, v):
        model, data, fid = self.robot.model, self.data, self.robot.contact_frame_id
        pin.computeJointJacobians(model, data, q)
        pin.framesForwardKinematics(model, data, q)
        jac = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)
        frame = data.oMf[fid]
        touching = frame.act(np.array([0.0, 0.0, -self.radius])) - self.radius * self.normal
        jac_point = jac[:3] - pin.skew(touching - frame.translation) @ jac[3:]
        mass = pin.crba(model, data, q)
        mass = np.triu(mass) + np.triu(mass, 1).T
        gravity = pin.computeGeneralizedGravity(model, data, q)
        return gravity - jac_point.T @ self.force - mass @ (20.0 * v)


def pressed_plant(robot, tilt=0.0, time_step=1e-3, half_extents=None, boxes=(), table=True):
    """A plant whose table surface passes through the tool tip at q_nominal."""
    tip = robot.contact_placement(robot.q_nominal).translation
    if half_extents is None:  # keep the table away from the Panda's base
        half_extents = (0.3, 0.3, 0.05) if robot.name == "iiwa" else (0.12, 0.12, 0.05)
    config = PlantConfig(
        time_step=time_step,
        table=TableConfig(
            surface_point=tuple(tip),
            tilt_angle=tilt,
            tilt_axis=(1.0, 1.0, 0.0),
            half_extents=half_extents,
        )
        if table
        else None,
        soft_boxes=boxes,
    )
    return Plant(robot, config), tip


def settle(plant, controller, seconds=1.0):
    plant.reset(plant.robot.q_nominal)
    for _ in range(round(seconds / plant.dt)):
        state = plant.state()
        plant.step(controller(state.q, state.v))
    return plant.state()


def penetration(plant, state, surface_point, normal):
    """Depth of the tool sphere below the plane (m, > 0 when penetrating)."""
    r = plant.config.tool.radius
    center = state.contact_frame_position + state.contact_frame_rotation @ np.array([0, 0, -r])
    return r - (center - surface_point) @ normal


@pytest.mark.parametrize(
    ("tilt", "tangential", "time_step"),
    [
        (0.0, 0.0, 1e-3),
        (np.deg2rad(6.0), 0.0, 1e-3),
        (np.deg2rad(-6.0), 0.3, 1e-3),
        (np.deg2rad(6.0), 0.3, 5e-4),
    ],
)
def test_static_push_gives_commanded_force(robot, tilt, tangential, time_step):
    plant, tip = pressed_plant(robot, tilt, time_step)
    with plant:
        n = plant.table_normal
        assert np.isclose(n @ [0, 0, 1], np.cos(tilt))
        along = np.cross(n, [1.0, -1.0, 0.0])  # a tangent direction of the tilted table
        along /= np.linalg.norm(along)
        f_des = FORCE * n + tangential * FORCE * along  # inside the friction cone (μ = 0.5)
        state = settle(plant, ForceController(plant, f_des, n))
        # At rest the contact force balances the commanded joint torque exactly (J_p has full
        # row rank): only the residual motion, ~1e-7 rad/s after 1 s of damping, perturbs it.
        assert np.abs(state.v).max() < 1e-4
        assert state.in_contact and not state.robot_collision
        assert state.normal_force == pytest.approx(FORCE, abs=1e-2)
        assert np.allclose(state.wrench_world[:3], f_des, atol=1e-2)  # friction sign included
        # The table is a spring: penetration = λ/K with K = 1e4 N/m (Bullet's implicit
        # spring-damper settles 0.2 % deeper; 1 % tolerance).
        depth = penetration(plant, state, tip, n)
        assert depth == pytest.approx(FORCE / 1e4, rel=1e-2)
        # The wrench is reduced to the contact frame origin and rotated into the sensor frame.
        moment = np.cross(state.contact_point - state.contact_frame_position, f_des)
        assert np.allclose(state.wrench_world[3:], moment, atol=1e-3)
        rot = state.contact_frame_rotation
        assert np.allclose(state.wrench_sensor[:3], rot.T @ state.wrench_world[:3])
        assert np.allclose(state.wrench_sensor[3:], rot.T @ state.wrench_world[3:])
        # The touching point is the sphere's, on the table plane up to the penetration.
        assert (state.contact_point - tip) @ n == pytest.approx(-depth, abs=1e-4)


def test_sliding_friction_is_coulomb_and_opposes_motion():
    robot = robot_named("iiwa")
    plant, _ = pressed_plant(robot, tilt=np.deg2rad(4.0))
    with plant:
        n = plant.table_normal
        along = np.cross(n, [1.0, 1.0, 0.0])
        along /= np.linalg.norm(along)
        settle(plant, ForceController(plant, FORCE * n, n), seconds=0.4)
        push = ForceController(plant, FORCE * n + 0.8 * FORCE * along, n)  # outside the cone
        data = robot.create_data()
        for _ in range(3):
            state = plant.state()
            plant.step(push(state.q, state.v))
            state = plant.state()
            f = state.wrench_world[:3]
            normal_part = f @ n
            tangential = f - normal_part * n
            # Coulomb: |f_t| = μ·λ with μ = 0.5 (tool μ 1 × table μ 0.5, Bullet multiplies).
            assert np.linalg.norm(tangential) == pytest.approx(0.5 * normal_part, rel=1e-3)
            pin.computeJointJacobians(robot.model, data, state.q)
            pin.framesForwardKinematics(robot.model, data, state.q)
            jac = pin.getFrameJacobian(
                robot.model, data, robot.contact_frame_id, pin.LOCAL_WORLD_ALIGNED
            )
            lever = state.contact_point - state.contact_frame_position
            slip = jac[:3] @ state.v - pin.skew(lever) @ jac[3:] @ state.v
            slip -= (slip @ n) * n
            # Friction opposes the slip. Bullet scales the impulse that would stop the slip onto
            # the cone, and with an anisotropic contact mass that impulse is not exactly
            # anti-parallel to the slip: 16° here, hence cos < −0.9 rather than −1.
            cosine = slip @ tangential / (np.linalg.norm(slip) * np.linalg.norm(tangential))
            assert cosine < -0.9


def test_soft_box_contact_uses_its_stiffness():
    """Pressing the tool into a static soft box: the box's stiffness sets the penetration, the
    contact is in the wrench but not in the table normal force."""
    robot = robot_named("iiwa")
    tip = robot.contact_placement(robot.q_nominal).translation
    size = 0.1
    box = SoftBoxConfig(
        position=tuple(tip - [0.0, 0.0, 0.5 * size]),
        stiffness=2e3,
        damping=50.0,
        mass=0.0,
        size=(size, size, size),
    )
    table = TableConfig(surface_point=tuple(tip - [0.0, 0.0, 0.3]))
    with Plant(robot, PlantConfig(table=table, soft_boxes=(box,))) as plant:
        force = 20.0
        state = settle(plant, ForceController(plant, [0.0, 0.0, force], [0.0, 0.0, 1.0]))
        assert state.in_contact and state.normal_force == 0.0
        assert state.wrench_world[2] == pytest.approx(force, abs=1e-2)
        depth = penetration(plant, state, tip, np.array([0.0, 0.0, 1.0]))
        assert depth == pytest.approx(force / 2e3, rel=1e-2)


def test_reset_restores_soft_boxes_and_time():
    robot = robot_named("iiwa")
    box = SoftBoxConfig(position=(0.5, 0.3, 0.4), stiffness=1e3, damping=20.0)
    config = PlantConfig(table=TableConfig(surface_point=(0.5, 0.3, 0.1)), soft_boxes=(box,))
    with Plant(robot, config) as plant:
        (body,) = plant.soft_boxes
        for _ in range(200):  # the dice falls onto the table
            plant.step(robot.gravity(plant.state().q))
        assert plant.t == pytest.approx(0.2)
        import pybullet as pb

        fallen = pb.getBasePositionAndOrientation(body, physicsClientId=plant.client_id)[0]
        assert fallen[2] < 0.4 - 0.05
        plant.reset(robot.q_nominal)
        assert plant.t == 0.0
        pos = pb.getBasePositionAndOrientation(body, physicsClientId=plant.client_id)[0]
        assert np.allclose(pos, box.position)


def test_external_push_acts_for_exactly_the_given_steps():
    """A push of F for k steps adds the generalized impulse J_comᵀ·F·k·dt (no gravity, q ≈ const
    over a few ms), and nothing afterwards."""
    robot = robot_named("iiwa")
    tool = ToolConfig(mass=0.5)  # a push at the tool's centre of mass needs a body with mass
    config = PlantConfig(table=None, gravity=(0.0, 0.0, 0.0), tool=tool)
    model = model_with_tool(robot, tool)
    data = model.createData()
    force = np.array([20.0, -10.0, 5.0])
    with Plant(robot, config) as plant:
        q0 = robot.q_nominal
        k = 5
        plant.reset(q0)
        plant.apply_external_push(force, steps=k)
        momenta = []
        for _ in range(2 * k):
            plant.step(np.zeros(robot.nv))
            state = plant.state()
            mass = pin.crba(model, data, state.q)
            mass = np.triu(mass) + np.triu(mass, 1).T
            momenta.append(mass @ state.v)
        pin.computeJointJacobians(model, data, q0)
        pin.framesForwardKinematics(model, data, q0)
        jac = pin.getFrameJacobian(model, data, robot.contact_frame_id, pin.LOCAL_WORLD_ALIGNED)
        com = data.oMf[robot.contact_frame_id].act(np.array([0.0, 0.0, -tool.radius]))
        jac_com = jac[:3] - pin.skew(com - data.oMf[robot.contact_frame_id].translation) @ jac[3:]
        impulse = jac_com.T @ force * k * plant.dt
        scale = np.abs(impulse).max()
        assert np.allclose(momenta[k - 1], impulse, atol=0.02 * scale)
        # after the push the momentum only changes by the Coriolis terms of the slow motion
        assert np.allclose(momenta[-1], momenta[k - 1], atol=0.02 * scale)
        with pytest.raises(InputError):
            plant.apply_external_push(force, steps=2, link="no_such_link")
        plant.apply_external_push(force, steps=1, link="lbr_iiwa_link_4")  # a named link works


@pytest.mark.parametrize("friction_velocity", [0.1, None])
def test_default_friction_smoothing_is_stable_on_the_wrist(friction_velocity):
    """The explicit tanh friction of eq 31 chatters on the iiwa's light wrist unless v_s is large
    enough: the default (1 rad/s) is stable at 1 kHz, 0.1 rad/s is not (ffmpc_core.actuation)."""
    robot = robot_named("iiwa")
    kwargs = {} if friction_velocity is None else {"friction_velocity": friction_velocity}
    params = ActuationParams(
        gain=np.ones(robot.nv), offset=np.zeros(robot.nv), torque_noise_std=0.0, **kwargs
    )
    actuation = ActuationModel(params, np.random.default_rng(0))
    with Plant(robot, PlantConfig(table=None)) as plant:
        velocities = []
        for k in range(400):
            state = plant.state()
            command = robot.gravity(state.q) + 0.3 * np.sin(2.0 * np.pi * k * plant.dt)
            plant.step(actuation.step(command, state.v))
            velocities.append(plant.state().v[6])
    wobble = np.abs(np.diff(velocities[200:], 2)).mean()  # rad/s, ~0 when smooth
    if friction_velocity is None:
        assert wobble < 1e-3
    else:
        assert wobble > 1.0


def test_torque_is_saturated_and_inputs_checked():
    robot = robot_named("iiwa")
    with Plant(robot, PlantConfig(table=None)) as plant:
        tau = 10.0 * robot.torque_limit * np.array([1, -1, 1, -1, 1, -1, 1])
        plant.step(tau)
        assert np.array_equal(plant.state().tau, np.sign(tau) * robot.torque_limit)
        for bad in (np.full(robot.nv, np.nan), np.zeros(robot.nv - 1)):
            with pytest.raises(InputError):
                plant.step(bad)
            with pytest.raises(InputError):
                plant.reset(bad)
        with pytest.raises(ConfigError):
            _ = plant.table_normal
    with pytest.raises(ModelError):
        plant.step(np.zeros(robot.nv))  # closed


def test_bad_configurations_are_rejected():
    with pytest.raises(ConfigError):
        TableConfig(tilt_axis=(0.0, 0.0, 1.0))  # not horizontal
    with pytest.raises(ConfigError):
        TableConfig(stiffness=-1.0)
    with pytest.raises(ConfigError):
        ToolConfig(radius=0.0)
    with pytest.raises(ConfigError):
        PlantConfig(time_step=0.0)
    with pytest.raises(ConfigError):
        SoftBoxConfig(position=(0, 0, 0), stiffness=1e3, damping=1.0, orientation=(0, 0, 0, 2))


def test_generated_urdf_has_tool_and_no_gripper_collisions():
    import xml.etree.ElementTree as ET

    from sim_bridge.plant import tool_urdf_text

    panda = robot_named("panda")
    root = ET.fromstring(tool_urdf_text(panda, ToolConfig()))
    joints = {j.get("name"): j for j in root.findall("joint")}
    links = {link.get("name"): link for link in root.findall("link")}
    assert joints["panda_finger_joint1"].get("type") == "fixed"
    assert not links["panda_leftfinger"].findall("collision")
    assert links["panda_link7"].findall("collision")
    assert joints["ffmpc_tool_joint"].find("parent").get("link") == panda.flange_frame
    assert TOOL_LINK in links
    for mesh in root.iter("mesh"):
        assert mesh.get("filename").startswith("/")


def test_urdf_joint_without_child_link_is_a_model_error():
    import xml.etree.ElementTree as ET

    from sim_bridge.plant import _joint_link

    joint = ET.fromstring('<joint name="j" type="fixed"><parent link="a"/></joint>')
    assert _joint_link(joint, "parent", "x.urdf") == "a"
    with pytest.raises(ModelError, match="'j' of x.urdf has no child link"):
        _joint_link(joint, "child", "x.urdf")
