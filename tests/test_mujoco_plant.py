"""The MuJoCo plant (sim_bridge.mujoco_plant) against pinocchio, the statics, a spring–damper
reference and the PyBullet plant: the same model, the same contact parameters meaning the same
N/m, N·s/m and friction coefficient, the same state."""

from __future__ import annotations

import functools
from dataclasses import replace

import numpy as np
import pinocchio as pin
import pytest
from scipy.integrate import solve_ivp
from test_plant import ForceController, penetration, random_state, settle

from ffmpc_core.errors import ConfigError, InputError, ModelError
from ffmpc_core.impact.scenario import ImpactStudyConfig, start_pose
from ffmpc_core.plant import Plant as PlantProtocol
from ffmpc_core.robots import load_robot
from sim_bridge.mujoco_plant import MujocoPlant
from sim_bridge.plant import (
    Plant,
    PlantConfig,
    SoftBoxConfig,
    TableConfig,
    ToolConfig,
    model_with_tool,
)
from sim_bridge.scenes import impact_plant_config, make_plant

FORCE = 50.0  # N
robot_named = functools.cache(load_robot)


@pytest.fixture(scope="module", params=["iiwa", "panda"])
def robot(request):
    return robot_named(request.param)


def table_at_tip(robot, tilt=0.0, **table):
    """A plant configuration whose table surface passes through the tool tip at q_nominal."""
    tip = robot.contact_placement(robot.q_nominal).translation
    half = (0.3, 0.3, 0.05) if robot.name == "iiwa" else (0.12, 0.12, 0.05)
    config = PlantConfig(
        table=TableConfig(
            surface_point=tuple(tip),
            tilt_angle=tilt,
            tilt_axis=(1.0, 1.0, 0.0),
            half_extents=half,
            **table,
        )
    )
    return config, tip


# -- the model --------------------------------------------------------------------------------
@pytest.mark.parametrize("time_step", [1e-3, 5e-4])
def test_free_acceleration_matches_aba(robot, time_step):
    """Mass matrix, bias forces and integrator are pinocchio's: one semi-implicit Euler step
    gives v1 = v0 + dt·aba(q0, v0, τ) to round-off (no joint damping, friction or armature)."""
    rng = np.random.default_rng(3)
    with MujocoPlant(robot, PlantConfig(table=None, time_step=time_step)) as plant:
        assert np.all(plant.model.dof_damping == 0.0) and np.all(plant.model.dof_armature == 0.0)
        for _ in range(3):
            q, v, tau = random_state(robot, rng)
            plant.reset(q, v)
            plant.step(tau)
            a_mj = (plant.state().v - v) / plant.dt
            a_pin = pin.aba(robot.model, robot.create_data(), q, v, tau)
            assert np.allclose(a_mj, a_pin, rtol=1e-9, atol=1e-9 * np.abs(a_pin).max())


def test_massive_tool_is_accounted_for(robot):
    tool = ToolConfig(mass=0.2, radius=0.015)
    q, v, tau = random_state(robot, np.random.default_rng(5))
    with MujocoPlant(robot, PlantConfig(table=None, tool=tool)) as plant:
        plant.reset(q, v)
        plant.step(tau)
        a_mj = (plant.state().v - v) / plant.dt
    augmented = model_with_tool(robot, tool)
    a_tool = pin.aba(augmented, augmented.createData(), q, v, tau)
    a_rigid = pin.aba(robot.model, robot.create_data(), q, v, tau)
    scale = np.abs(a_tool).max()
    assert np.abs(a_mj - a_rigid).max() > 1e-4 * scale
    assert np.allclose(a_mj, a_tool, rtol=1e-9, atol=1e-9 * scale)


def test_the_robot_description_is_the_urdf_with_its_meshes(robot):
    """The links of the URDF (the Panda's fingers fixed, no finger collision) with their
    collision meshes, and the contact frame is pinocchio's."""
    import mujoco

    with MujocoPlant(robot, PlantConfig(table=None)) as plant:
        model = plant.model
        meshes = [g for g in range(model.ngeom) if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH]
        assert len(meshes) >= 8 and model.nmesh == len(meshes)
        assert model.njnt == 7 and model.nv == 7
        if robot.name == "panda":
            finger = model.body("panda_leftfinger").id
            assert finger in plant.link_indices.values()
            assert not np.any(model.geom_bodyid == finger)
        rng, data = np.random.default_rng(7), robot.create_data()
        for _ in range(3):
            q, _, _ = random_state(robot, rng)
            plant.reset(q)
            state = plant.state()
            placement = robot.contact_placement(q, data)
            assert np.allclose(state.contact_frame_position, placement.translation, atol=1e-12)
            assert np.allclose(state.contact_frame_rotation, placement.rotation, atol=1e-12)
            assert not state.in_contact and not state.robot_collision


def test_free_motion_follows_the_pybullet_trajectory(robot):
    """The same torque sequence (gravity compensation, sines, a damping term) for 1 s gives
    the same joint trajectory in both engines: both integrate the same rigid-body model with
    semi-implicit Euler; measured 1.9e-10 rad (iiwa) and 2.3e-11 rad (Panda), 1e-6 allowed."""
    rng = np.random.default_rng(1)
    amplitude = 0.03 * robot.torque_limit * rng.uniform(0.5, 1.0, robot.nv)
    frequency, phase = rng.uniform(0.5, 2.0, robot.nv), rng.uniform(0.0, 2 * np.pi, robot.nv)
    trajectories = []
    for engine in ("pybullet", "mujoco"):
        with make_plant(robot, PlantConfig(table=None), engine) as plant:
            qs = []
            for k in range(1000):
                state = plant.state()
                wave = amplitude * np.sin(2 * np.pi * frequency * k * plant.dt + phase)
                plant.step(robot.gravity(state.q) + wave - 2.0 * state.v)
                qs.append(plant.state().q)
            trajectories.append(np.array(qs))
    bullet, mujoco_q = trajectories
    assert np.ptp(bullet, axis=0).max() > 0.2  # the arm moved
    assert np.abs(bullet - mujoco_q).max() < 1e-6


# -- the contact: the scenario's parameters mean the same in both engines ---------------------
@pytest.mark.parametrize(
    ("tilt", "tangential", "stiffness"),
    [(0.0, 0.0, 1e4), (np.deg2rad(6.0), 0.0, 1e4), (np.deg2rad(-6.0), 0.3, 1e4), (0.0, 0.0, 4e4)],
)
def test_static_press_gives_the_same_deflection_in_both_engines(robot, tilt, tangential, stiffness):
    """Pressing the tool with f_des (normal 50 N, plus a tangential part inside the friction
    cone) until rest: both engines hold exactly f_des, and the penetration is λ/K — exactly in
    MuJoCo (the explicit spring-damper; 1e-4 relative), 0.2 % deeper in Bullet (its implicit
    spring; 1 %): the table's K means the same N/m in both."""
    depths = {}
    for engine in ("pybullet", "mujoco"):
        config, tip = table_at_tip(robot, tilt, stiffness=stiffness)
        with make_plant(robot, config, engine) as plant:
            n = plant.table_normal
            along = np.cross(n, [1.0, -1.0, 0.0])
            along /= np.linalg.norm(along)
            f_des = FORCE * n + tangential * FORCE * along
            state = settle(plant, ForceController(plant, f_des, n))
            assert np.abs(state.v).max() < 1e-4
            assert state.in_contact and not state.robot_collision
            assert state.normal_force == pytest.approx(FORCE, abs=1e-2)
            assert np.allclose(state.wrench_world[:3], f_des, atol=1e-2)
            moment = np.cross(state.contact_point - state.contact_frame_position, f_des)
            assert np.allclose(state.wrench_world[3:], moment, atol=1e-3)
            rot = state.contact_frame_rotation
            assert np.allclose(state.wrench_sensor[:3], rot.T @ state.wrench_world[:3])
            assert np.allclose(state.wrench_sensor[3:], rot.T @ state.wrench_world[3:])
            depths[engine] = penetration(plant, state, tip, n)
            assert (state.contact_point - tip) @ n == pytest.approx(-depths[engine], abs=1e-4)
    assert depths["mujoco"] == pytest.approx(FORCE / stiffness, rel=1e-4)
    assert depths["pybullet"] == pytest.approx(FORCE / stiffness, rel=1e-2)
    assert depths["mujoco"] == pytest.approx(depths["pybullet"], rel=1e-2)


def test_sliding_friction_is_coulomb_against_the_slip():
    """Pushed outside the friction cone, the tool slides with |f_t| = μ·λ exactly (μ = 0.5:
    tool 1 × table 0.5, Bullet's product) and f_t anti-parallel to the slip at the end of the
    step (maximal dissipation; Bullet's is 16° off with this contact mass, test_plant.py)."""
    robot = robot_named("iiwa")
    config, _ = table_at_tip(robot, np.deg2rad(4.0))
    with MujocoPlant(robot, config) as plant:
        n = plant.table_normal
        along = np.cross(n, [1.0, 1.0, 0.0])
        along /= np.linalg.norm(along)
        settle(plant, ForceController(plant, FORCE * n, n), seconds=0.4)
        push = ForceController(plant, FORCE * n + 0.8 * FORCE * along, n)
        data = robot.create_data()
        for _ in range(3):
            state = plant.state()
            plant.step(push(state.q, state.v))
            state = plant.state()
            f = state.wrench_world[:3]
            tangential = f - (f @ n) * n
            assert np.linalg.norm(tangential) == pytest.approx(0.5 * (f @ n), rel=1e-9)
            pin.computeJointJacobians(robot.model, data, state.q)
            pin.framesForwardKinematics(robot.model, data, state.q)
            jac = pin.getFrameJacobian(
                robot.model, data, robot.contact_frame_id, pin.LOCAL_WORLD_ALIGNED
            )
            lever = state.contact_point - state.contact_frame_position
            slip = jac[:3] @ state.v - pin.skew(lever) @ jac[3:] @ state.v
            slip -= (slip @ n) * n
            cosine = slip @ tangential / (np.linalg.norm(slip) * np.linalg.norm(tangential))
            assert cosine < -0.9999


def _impact_reference(robot, cfg, q0, v0, duration):
    """The continuous model the MPC and the planner assume: the arm's rigid-body dynamics with
    the spring-damper λ = max(0, K·δ + B·δ̇) at the tool's lowest point, frictionless,
    integrated accurately (RK45, steps ≤ 20 µs). Returns t ↦ (penetration m, force N)."""
    model, data, fid = robot.model, robot.create_data(), robot.contact_frame_id
    radius, top = cfg.tool_radius, cfg.dice.top_height
    stiffness, damping = cfg.dice.stiffness, cfg.dice.damping

    def contact(q, v):
        pin.computeJointJacobians(model, data, q)
        pin.framesForwardKinematics(model, data, q)
        frame = data.oMf[fid]
        lowest = frame.act(np.array([0.0, 0.0, -radius])) - np.array([0.0, 0.0, radius])
        jac = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)
        jac_point = jac[:3] - pin.skew(lowest - frame.translation) @ jac[3:]
        depth = top - lowest[2]
        force = max(0.0, stiffness * depth - damping * (jac_point @ v)[2]) if depth > 0 else 0.0
        return depth, force, jac_point

    def rhs(_t, y):
        q, v = y[:7], y[7:]
        _, force, jac_point = contact(q, v)
        tau = robot.gravity(q) + jac_point.T @ np.array([0.0, 0.0, force])
        return np.concatenate([v, pin.aba(model, data, q, v, tau)])

    y0 = np.concatenate([q0, v0])
    sol = solve_ivp(
        rhs, (0.0, duration), y0, max_step=2e-5, rtol=1e-9, atol=1e-12, dense_output=True
    )
    return lambda t: contact(sol.sol(t)[:7], sol.sol(t)[7:])[:2]


def test_dice_impact_follows_the_spring_damper_model():
    """The Panda's tool hits the impact study's dice (K = 3000 N/m, B = 20 N·s/m, frictionless
    here) at 0.3 m/s, the arm coasting under gravity compensation: the peak penetration and
    force of each engine against the continuous model (measured: MuJoCo −0.20 % and +0.01 %,
    PyBullet −1.8 % and −1.6 %, its implicit spring adding h·K of damping), and the force the
    state reports at each step against the model's at that instant (RMS: MuJoCo 0.04 N,
    PyBullet 0.50 N): the wrench is the one at the reported q, q̇, as a sensor reads it."""
    robot = robot_named("panda")
    base = ImpactStudyConfig()
    cfg = replace(base, approach_height=0.005, dice=replace(base.dice, lateral_friction=0.0))
    q0 = start_pose(cfg, robot)
    data = robot.create_data()
    pin.computeJointJacobians(robot.model, data, q0)
    pin.framesForwardKinematics(robot.model, data, q0)
    jac = pin.getFrameJacobian(robot.model, data, robot.contact_frame_id, pin.LOCAL_WORLD_ALIGNED)
    v0 = np.linalg.pinv(jac) @ np.array([0.0, 0.0, -0.3, 0.0, 0.0, 0.0])  # m/s down, no turn
    steps = 100
    reference = _impact_reference(robot, cfg, q0, v0, steps * cfg.time_step)
    times = cfg.time_step * np.arange(1, steps + 1)
    ref = np.array([reference(t) for t in times])
    peaks, rms = {}, {}
    for engine in ("pybullet", "mujoco"):
        with make_plant(robot, impact_plant_config(cfg), engine) as plant:
            plant.reset(q0, v0)
            depth, force = [], []
            for _ in range(steps):
                plant.step(robot.gravity(plant.state().q))
                s = plant.state()
                lowest = s.contact_frame_position + s.contact_frame_rotation @ [
                    0,
                    0,
                    -cfg.tool_radius,
                ]
                depth.append(cfg.dice.top_height - (lowest[2] - cfg.tool_radius))
                force.append(s.wrench_world[2])
            peaks[engine] = (max(depth), max(force), times[int(np.argmax(depth))])
            rms[engine] = float(np.sqrt(np.mean((np.array(force) - ref[:, 1]) ** 2)))
    ref_depth, ref_force = ref[:, 0].max(), ref[:, 1].max()
    assert 0.008 < ref_depth < cfg.dice.max_penetration  # a real impact, inside z̄
    assert peaks["mujoco"][0] == pytest.approx(ref_depth, rel=0.01)
    assert peaks["mujoco"][1] == pytest.approx(ref_force, rel=0.01)
    assert peaks["pybullet"][0] == pytest.approx(ref_depth, rel=0.03)
    assert peaks["pybullet"][1] == pytest.approx(ref_force, rel=0.03)
    t_peak = times[int(np.argmax(ref[:, 0]))]
    assert peaks["mujoco"][2] == pytest.approx(t_peak, abs=2e-3)
    assert rms["mujoco"] < 0.2 and rms["pybullet"] < 1.0


def test_soft_box_contact_uses_its_stiffness():
    """Pressing the tool into a static soft box (k = 2000 N/m) under a stiff table: the box's
    stiffness sets the penetration, the contact is in the wrench, not in the table force."""
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
    with MujocoPlant(robot, PlantConfig(table=table, soft_boxes=(box,))) as plant:
        state = settle(plant, ForceController(plant, [0.0, 0.0, 20.0], [0.0, 0.0, 1.0]))
        assert state.in_contact and state.normal_force == 0.0
        assert state.wrench_world[2] == pytest.approx(20.0, abs=1e-2)
        depth = penetration(plant, state, tip, np.array([0.0, 0.0, 1.0]))
        assert depth == pytest.approx(20.0 / 2e3, rel=1e-4)


def test_a_free_box_rests_on_its_four_corners_and_reset_restores_it():
    """A 0.1 kg box (k = 1e3 N/m, in series with the table's 1e4) falls and rests on 4 contact
    points, each a spring as in Bullet: it sinks m·g/(4·k_series) (overdamped: 4 dampers of
    20 + 100 N·s/m, a 0.13 s creep; 1 s); reset puts it back."""
    robot = robot_named("iiwa")
    box = SoftBoxConfig(position=(0.5, 0.3, 0.4), stiffness=1e3, damping=20.0)
    config = PlantConfig(table=TableConfig(surface_point=(0.5, 0.3, 0.1)), soft_boxes=(box,))
    with MujocoPlant(robot, config) as plant:
        body = plant.model.body("ffmpc_box0").id
        for _ in range(1000):
            plant.step(robot.gravity(plant.state().q))
        assert plant.t == pytest.approx(1.0)
        series = 1.0 / (1.0 / 1e3 + 1.0 / 1e4)
        sink = 0.1 * 9.81 / (4 * series)
        height = plant._data.xpos[body][2]
        assert height == pytest.approx(0.1 + 0.08 - sink, abs=2e-6)
        assert not plant.state().in_contact  # the box touches the table, not the tool
        plant.reset(robot.q_nominal)
        assert plant.t == 0.0
        import mujoco

        mujoco.mj_kinematics(plant.model, plant._data)
        assert np.allclose(plant._data.xpos[body], box.position)


def test_a_stiff_contact_is_substepped_and_an_impossible_one_refused():
    """A table 100× stiffer than the paper's still settles at exactly λ/K (the step is split
    so that the explicit spring stays stable); a damping no sub-step can integrate is a
    ModelError before the robot moves, not a divergence."""
    robot = robot_named("iiwa")
    config, tip = table_at_tip(robot, stiffness=1e6)
    with MujocoPlant(robot, config) as plant:
        n = plant.table_normal
        state = settle(plant, ForceController(plant, FORCE * n, n), seconds=0.5)
        assert state.normal_force == pytest.approx(FORCE, abs=1e-2)
        assert penetration(plant, state, tip, n) == pytest.approx(FORCE / 1e6, rel=1e-3)
    config, _ = table_at_tip(robot, damping=1e7)
    with MujocoPlant(robot, config) as plant:
        with pytest.raises(ModelError, match="sub-steps"):
            plant.step(robot.gravity(robot.q_nominal))


def test_a_link_in_the_table_is_a_robot_collision():
    """The table 6 cm above the tool tip: the flange link is in it too — as in PyBullet, a
    robot collision."""
    robot = robot_named("iiwa")
    tip = robot.contact_placement(robot.q_nominal).translation
    table = TableConfig(surface_point=tuple(tip + [0.0, 0.0, 0.06]))
    for engine in ("pybullet", "mujoco"):
        with make_plant(robot, PlantConfig(table=table), engine) as plant:
            plant.step(robot.gravity(robot.q_nominal))
            state = plant.state()
            assert state.robot_collision and state.in_contact, engine


def test_external_push_acts_for_exactly_the_given_steps():
    """A push of F for k steps adds the generalized impulse J_comᵀ·F·k·dt and nothing after."""
    robot = robot_named("iiwa")
    tool = ToolConfig(mass=0.5)
    config = PlantConfig(table=None, gravity=(0.0, 0.0, 0.0), tool=tool)
    model = model_with_tool(robot, tool)
    data = model.createData()
    force = np.array([20.0, -10.0, 5.0])
    with MujocoPlant(robot, config) as plant:
        q0, k = robot.q_nominal, 5
        plant.reset(q0)
        plant.apply_external_push(force, steps=k)
        momenta = []
        for _ in range(2 * k):
            plant.step(np.zeros(robot.nv))
            state = plant.state()
            mass = pin.crba(model, data, state.q)
            momenta.append((np.triu(mass) + np.triu(mass, 1).T) @ state.v)
        pin.computeJointJacobians(model, data, q0)
        pin.framesForwardKinematics(model, data, q0)
        frame = data.oMf[robot.contact_frame_id]
        jac = pin.getFrameJacobian(model, data, robot.contact_frame_id, pin.LOCAL_WORLD_ALIGNED)
        com = frame.act(np.array([0.0, 0.0, -tool.radius]))
        jac_com = jac[:3] - pin.skew(com - frame.translation) @ jac[3:]
        impulse = jac_com.T @ force * k * plant.dt
        scale = np.abs(impulse).max()
        assert np.allclose(momenta[k - 1], impulse, atol=0.02 * scale)
        assert np.allclose(momenta[-1], momenta[k - 1], atol=0.02 * scale)
        with pytest.raises(InputError):
            plant.apply_external_push(force, steps=2, link="no_such_link")
        plant.apply_external_push(force, steps=1, link="lbr_iiwa_link_4")


# -- the protocol, inputs and lifetime --------------------------------------------------------
def test_it_is_a_plant_and_runs_the_same_loop(robot):
    """The ffmpc_core Plant protocol (reset/step/state, dt) and make_plant's engines."""
    with make_plant(robot, PlantConfig(table=None), "mujoco") as plant:
        assert isinstance(plant, MujocoPlant) and isinstance(plant, PlantProtocol)
        q0 = robot.q_nominal
        plant.reset(q0)
        for _ in range(50):
            plant.step(robot.gravity(plant.state().q))
        assert np.allclose(plant.state().q, q0, atol=1e-4)
        assert plant.t == pytest.approx(0.05)
    with make_plant(robot, PlantConfig(table=None), "pybullet") as bullet:
        assert isinstance(bullet, Plant)
    with pytest.raises(ConfigError, match="engine"):
        make_plant(robot, PlantConfig(table=None), "gazebo")


def test_torque_is_saturated_and_inputs_checked():
    robot = robot_named("iiwa")
    plant = MujocoPlant(robot, PlantConfig(table=None))
    plant.step(10.0 * robot.torque_limit)
    assert np.allclose(plant.state().tau, robot.torque_limit)
    for bad in (np.zeros(6), np.full(robot.nv, np.nan)):
        with pytest.raises(InputError):
            plant.step(bad)
        with pytest.raises(InputError):
            plant.reset(bad)
    with pytest.raises(ConfigError):
        plant.table_normal  # noqa: B018 - no table
    plant.close()
    plant.close()
    with pytest.raises(ModelError):
        plant.step(np.zeros(robot.nv))
