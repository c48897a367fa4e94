"""The simulated plant in MuJoCo: the same robot, tool, table and soft boxes as the PyBullet plant.

:class:`MujocoPlant` has the :class:`ffmpc_core.plant.Plant` shape, takes the same
:class:`~sim_bridge.plant.PlantConfig` and reports the same :class:`~sim_bridge.plant.PlantState`
as :class:`sim_bridge.plant.Plant`, with the same units, frames and signs (rad, rad/s, N·m, m,
N; world frame; the wrench the environment exerts on the tool, reduced to the contact frame
origin). A closed loop, a sensing model or a reflex wrapper written against the protocol runs on
either; :func:`sim_bridge.scenes.make_plant` (``plant.engine``) picks one.

The model. MuJoCo compiles the URDF the PyBullet plant loads
(:func:`sim_bridge.plant.tool_urdf_text`: the robot's own description, mesh paths resolved, the
tool link added at the contact frame, the Panda's fingers fixed at 0 and their collision shapes
removed), with every link kept as a body (``fusestatic="false"``) and the inertias of the file.
Like the PyBullet plant: no joint damping or friction (the URDF's ``<dynamics>`` are zeroed;
joint friction belongs to the actuation model, eq 31), no motors (the torque is a generalized
force), torques saturated to the data-sheet limits, semi-implicit Euler at the configuration's
time step; mass matrix, bias forces and accelerations equal pinocchio's to round-off
(tests/test_mujoco_plant.py). Robot links never touch each other (no self-collision, as in
PyBullet). The URDF's position limits are enforced by each engine its own way (Bullet's limit
constraint, MuJoCo's soft limit with its default ``solref``): a motion that reaches a limit
differs between the two, none other does.

The contact (:mod:`sim_bridge.contact_forces`). MuJoCo's constraint solver never sees a contact:
the dynamics run with contacts disabled, a second ``MjData`` runs MuJoCo's collision detection
on the same configuration, and the plant applies, for each penetrating pair of a robot body and
the table or a soft box (or a free box and the table), the spring–damper normal force
``max(0, K·δ + B·δ̇)`` with the scenario's K (N/m) and B (N·s/m), and Coulomb friction solved at
the end of the step, through ``qfrc_applied``. The parameters of two surfaces combine as Bullet
combines them (stiffness in series, damping summed, friction multiplied), with the tool and the
other robot links given the PyBullet plant's values, so a table of K = 1e4 N/m, B = 1e2 N·s/m,
μ = 0.5 is the same contact in both engines. Differences that remain: MuJoCo's box edges are
sharp (Bullet's ``collision_margin`` rounds them; MuJoCo ignores it: its sphere–box contact
is one point at any depth, the double point that margin avoids in Bullet does not exist here),
and the spring is explicit (at the step's start) where Bullet's is implicit, so a static press
settles at exactly λ/K here and 0.2 % deeper in Bullet.

Step size. The explicit spring–damper is stable and accurate when ``ω·h`` (ω = √(K·a), a the
inverse inertia along the contact normal, 1/kg) and ``B·a·h`` are small: each step is split into
the fewest sub-steps of equal length that keep them at most :data:`MAX_PHASE_PER_SUBSTEP` and
:data:`MAX_DAMPING_PER_SUBSTEP` for every contact within :data:`SPECULATIVE_MARGIN` of
touching (the torque is held over the sub-steps). The paper's table (1e4 N/m, 1e2 N·s/m) needs
none at 1 kHz.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import mujoco
import numpy as np
import numpy.typing as npt
import pinocchio as pin

from ffmpc_core.errors import ConfigError, InputError, ModelError
from ffmpc_core.plant import Plant as PlantProtocol
from ffmpc_core.robots import RobotModel, load_robot
from sim_bridge.contact_forces import (
    BULLET_DEFAULT_MATERIAL,
    ContactMaterial,
    combine_materials,
    coulomb_friction,
    normal_force,
)
from sim_bridge.plant import (
    TOOL_LINK,
    PlantConfig,
    PlantState,
    SoftBoxConfig,
    TableConfig,
    checked_push,
    tool_urdf_text,
)

__all__ = [
    "MAX_DAMPING_PER_SUBSTEP",
    "MAX_PHASE_PER_SUBSTEP",
    "MAX_SUBSTEPS",
    "SPECULATIVE_MARGIN",
    "MujocoPlant",
    "mujoco_model",
]

#: Largest ω·h (rad) of a contact's spring per sub-step (module docstring).
MAX_PHASE_PER_SUBSTEP = 0.25
#: Largest B·a·h of a contact's damper per sub-step.
MAX_DAMPING_PER_SUBSTEP = 0.5
#: Most sub-steps per step; a contact that needs more is a ModelError (K or B out of reach).
MAX_SUBSTEPS = 1000
#: Contacts closer than this (m) size the sub-steps before they touch.
SPECULATIVE_MARGIN = 0.02

_ROBOT_CONTYPE, _ROBOT_CONAFFINITY = 1, 0  # robot links touch the scene, never each other
_SCENE_CONTYPE, _SCENE_CONAFFINITY = 1, 1
_NO_CONTACT = int(mujoco.mjtDisableBit.mjDSBL_CONTACT)


def mujoco_model(robot: RobotModel, config: PlantConfig) -> tuple[mujoco.MjModel, dict[int, str]]:
    """Compile the MuJoCo model of the plant (module docstring); returns it and the name of
    each scene geom (``"table"`` or ``"box<i>"``, i the index in ``config.soft_boxes``)."""
    root = ET.fromstring(tool_urdf_text(robot, config.tool, visuals=False))
    extension = ET.SubElement(root, "mujoco")
    ET.SubElement(
        extension, "compiler", strippath="false", fusestatic="false", discardvisual="true"
    )
    try:
        spec = mujoco.MjSpec.from_string(ET.tostring(root, encoding="unicode"))
    except ValueError as exc:
        raise ModelError(f"MuJoCo could not load {robot.name}: {exc}") from exc
    for geom in spec.geoms:
        geom.contype, geom.conaffinity = _ROBOT_CONTYPE, _ROBOT_CONAFFINITY
    names: dict[str, str] = {}
    if config.table is not None:
        names["ffmpc_table"] = "table"
        _add_table(spec, config.table)
    for i, box in enumerate(config.soft_boxes):
        names[f"ffmpc_box{i}"] = f"box{i}"
        _add_box(spec, box, f"ffmpc_box{i}")
    for geom in spec.geoms:
        if geom.name in names:
            geom.contype, geom.conaffinity = _SCENE_CONTYPE, _SCENE_CONAFFINITY
            geom.margin = SPECULATIVE_MARGIN
    try:
        model = spec.compile()
    except ValueError as exc:
        raise ModelError(f"MuJoCo could not compile {robot.name}: {exc}") from exc
    model.opt.timestep = config.time_step
    model.opt.gravity[:] = config.gravity
    model.opt.integrator = mujoco.mjtIntegrator.mjINT_EULER
    model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_AUTORESET)  # divergence: an error
    model.opt.disableflags |= _NO_CONTACT  # the dynamics never solve a contact
    model.dof_damping[:] = 0.0
    model.dof_frictionloss[:] = 0.0
    model.dof_armature[:] = 0.0
    model.jnt_stiffness[:] = 0.0
    scene = {model.geom(name).id: label for name, label in names.items()}
    return model, scene


def _quaternion_wxyz(rotation: np.ndarray) -> list[float]:
    x, y, z, w = (float(c) for c in pin.Quaternion(rotation).coeffs())
    return [w, x, y, z]


def _add_table(spec: mujoco.MjSpec, table: TableConfig) -> None:
    geom = spec.worldbody.add_geom()
    geom.name = "ffmpc_table"
    geom.type = mujoco.mjtGeom.mjGEOM_BOX
    geom.size = [float(x) for x in table.half_extents]
    geom.pos = [float(x) for x in table.center]
    geom.quat = _quaternion_wxyz(table.rotation)


def _add_box(spec: mujoco.MjSpec, box: SoftBoxConfig, name: str) -> None:
    """A static box (mass 0) is a world geom; a box with mass a free body of that mass and the
    inertia of a solid box, as PyBullet builds it."""
    x, y, z, w = box.orientation
    parent = spec.worldbody
    if box.mass > 0.0:
        parent = spec.worldbody.add_body()
        parent.name = name
        parent.pos = [float(c) for c in box.position]
        parent.quat = [w, x, y, z]
        parent.add_freejoint()
    geom = parent.add_geom()
    geom.name = name
    geom.type = mujoco.mjtGeom.mjGEOM_BOX
    geom.size = [0.5 * float(c) for c in box.size]
    if box.mass > 0.0:
        geom.mass = float(box.mass)
    else:
        geom.pos = [float(c) for c in box.position]
        geom.quat = [w, x, y, z]


@dataclass
class _Contacts:
    """The contacts of one sub-step: per contact i, the two bodies, the contact frame
    ``frame[i]`` = rows [n; t1; t2] (world; n unit, pointing from body1 to body2: the force on
    body2 is ``frame[i].T @ [λ, f_t1, f_t2]``, its opposite acts on body1), the points on
    body1's and body2's surfaces (m, world), the penetration δ (m, < 0 when apart), the
    combined material, and ``jacobian[i]`` = frame[i]·(J_body2(point2) − J_body1(point1))
    (3×nv: separation speed and slip per q̇), and the geom pair of each."""

    geoms: np.ndarray
    body1: np.ndarray
    body2: np.ndarray
    frame: np.ndarray
    point1: np.ndarray
    point2: np.ndarray
    depth: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray
    friction: np.ndarray
    jacobian: np.ndarray
    scene_label: list[str]

    def penetrating(self) -> _Contacts | None:
        """The contacts with δ > 0, or None."""
        keep = self.depth > 0.0
        if not keep.any():
            return None
        if keep.all():
            return self
        index = np.flatnonzero(keep)
        return _Contacts(
            self.geoms[index],
            self.body1[index],
            self.body2[index],
            self.frame[index],
            self.point1[index],
            self.point2[index],
            self.depth[index],
            self.stiffness[index],
            self.damping[index],
            self.friction[index],
            self.jacobian[index],
            [self.scene_label[i] for i in index],
        )


class MujocoPlant:
    """A MuJoCo simulation of one torque-controlled arm with a spherical tool, a table and soft
    boxes (module docstring); the same constructor, methods and state as
    :class:`sim_bridge.plant.Plant`. Use as a context manager or call :meth:`close`.

    Attributes:
        friction_sweep_limit_hits: sub-steps since the reset whose multi-contact friction
            stopped at the sweep limit (:func:`~sim_bridge.contact_forces.coulomb_friction`:
            admissible forces, not the optimum); 0 whenever at most one contact touches.
    """

    friction_sweep_limit_hits: int

    def __init__(self, robot: RobotModel | str = "iiwa", config: PlantConfig | None = None) -> None:
        self.robot = load_robot(robot) if isinstance(robot, str) else robot
        self.config = config if config is not None else PlantConfig()
        self.dt = float(self.config.time_step)
        self._model, scene = mujoco_model(self.robot, self.config)
        self._data = mujoco.MjData(self._model)
        self._geometry = mujoco.MjData(self._model)  # collision detection only
        self._index(scene)
        nv = self.robot.nv
        self._t = 0.0
        self._tau = np.zeros(nv)
        self._push_force = np.zeros(3)
        self._push_body = self._tool_body
        self._push_steps = 0
        self._closed = False
        # per geom pair of the last sub-step's contacts: (friction on body2, N, world; λ, N; μ)
        self._last_friction: dict[tuple[int, int], tuple[np.ndarray, float, float]] = {}
        self.reset(self.robot.q_nominal)

    # ------------------------------------------------------------------ construction
    def _index(self, scene: dict[int, str]) -> None:
        m, robot = self._model, self.robot
        try:
            joints = [m.joint(name) for name in robot.joint_names]
        except KeyError as exc:
            raise ModelError(f"joint {exc} of {robot.name} is not in the MuJoCo model") from None
        self._qadr = np.array([int(j.qposadr[0]) for j in joints])
        self._vadr = np.array([int(j.dofadr[0]) for j in joints])
        free = mujoco.mjtJoint.mjJNT_FREE
        robot_joints = {m.joint(i).name for i in range(m.njnt) if m.jnt_type[i] != free}
        if robot_joints != set(robot.joint_names):
            raise ModelError("MuJoCo model has movable joints the robot model does not have")
        self._tool_body = m.body(TOOL_LINK).id
        self._scene_geoms = scene
        self._robot_bodies = {
            b for b in range(1, m.nbody) if m.body_rootid[b] == m.body_rootid[self._tool_body]
        }
        self.link_indices: dict[str, int] = {m.body(b).name: b for b in self._robot_bodies}
        self._materials: dict[int, ContactMaterial] = {}
        self._pair_materials: dict[tuple[int, int], ContactMaterial] = {}
        tool = self.config.tool
        for g in range(m.ngeom):
            if g in scene:
                self._materials[g] = self._scene_material(scene[g])
            elif m.geom_bodyid[g] == self._tool_body:
                self._materials[g] = ContactMaterial(
                    tool.stiffness, tool.damping, tool.lateral_friction
                )
            else:
                self._materials[g] = BULLET_DEFAULT_MATERIAL
        self._free_boxes = [
            (m.body(f"ffmpc_box{i}").id, box)
            for i, box in enumerate(self.config.soft_boxes)
            if box.mass > 0.0
        ]
        self._table_normal = self.config.table.normal if self.config.table is not None else None

    def _scene_material(self, label: str) -> ContactMaterial:
        if label == "table":
            table = self.config.table
            assert table is not None
            return ContactMaterial(table.stiffness, table.damping, table.lateral_friction)
        box = self.config.soft_boxes[int(label[3:])]
        return ContactMaterial(box.stiffness, box.damping, box.lateral_friction)

    # ------------------------------------------------------------------ properties
    @property
    def t(self) -> float:
        """Simulation time since the last reset, s."""
        return self._t

    @property
    def table_normal(self) -> np.ndarray:
        """Unit normal of the table's top surface (world frame); ConfigError without a table."""
        if self._table_normal is None:
            raise ConfigError("this plant has no table")
        return self._table_normal.copy()

    @property
    def model(self) -> mujoco.MjModel:
        """The MuJoCo model (read it; changing it changes the plant)."""
        return self._model

    # ------------------------------------------------------------------ simulation
    def _check_vector(self, value: npt.ArrayLike, name: str) -> np.ndarray:
        arr = np.asarray(value, dtype=float)
        if arr.shape != (self.robot.nv,) or not np.all(np.isfinite(arr)):
            raise InputError(f"{name} must be {self.robot.nv} finite numbers, got {value!r}")
        return arr

    def reset(self, q: np.ndarray, v: np.ndarray | None = None) -> None:
        """Put the robot at (q, v) (rad, rad/s), t = 0, free boxes back to their initial pose."""
        self._ensure_open()
        q = self._check_vector(q, "q")
        v = np.zeros(self.robot.nv) if v is None else self._check_vector(v, "v")
        m, d = self._model, self._data
        mujoco.mj_resetData(m, d)
        d.qpos[self._qadr] = q
        d.qvel[self._vadr] = v
        for body, box in self._free_boxes:
            joint = m.body_jntadr[body]
            adr, vadr = m.jnt_qposadr[joint], m.jnt_dofadr[joint]
            x, y, z, w = box.orientation
            d.qpos[adr : adr + 7] = [*box.position, w, x, y, z]
            d.qvel[vadr : vadr + 6] = 0.0
        mujoco.mj_forward(m, d)
        self._t = 0.0
        self._tau[:] = 0.0
        self._push_steps = 0
        self._last_friction = {}
        self.friction_sweep_limit_hits = 0

    def apply_external_push(
        self, force_world: np.ndarray, steps: int, link: str | None = None
    ) -> None:
        """Apply ``force_world`` (N, world frame) at the centre of mass of ``link`` (a URDF link
        name; default the tool link) during the next ``steps`` steps (Experiment 3.3). A new
        push replaces a pending one."""
        self._push_force, self._push_body, self._push_steps = checked_push(
            force_world, steps, link, self.link_indices
        )

    def step(self, tau: np.ndarray) -> None:
        """Apply the joint torque ``tau`` (N·m, saturated to the torque limits) for one step."""
        self._ensure_open()
        tau = np.clip(
            self._check_vector(tau, "tau"), -self.robot.torque_limit, self.robot.torque_limit
        )
        push = self._push_force if self._push_steps > 0 else None
        m, d = self._model, self._data
        self._prepare(tau, push)
        nearby = self._detect(within=SPECULATIVE_MARGIN)
        substeps = self._substeps(nearby)
        m.opt.timestep = self.dt / substeps
        for j in range(substeps):
            if j > 0:
                self._prepare(tau, push)
                nearby = self._detect(within=0.0)
            self._apply_contacts(nearby)
            mujoco.mj_step2(m, d)
        if push is not None:
            self._push_steps -= 1
        if not (np.isfinite(d.qpos).all() and np.isfinite(d.qvel).all()):
            raise ModelError(f"MuJoCo plant diverged at t = {self._t + self.dt:.4f} s")
        self._tau[:] = tau
        self._t += self.dt

    def _prepare(self, tau: np.ndarray, push: np.ndarray | None) -> None:
        """mj_step1 (kinematics, M and its factorization, bias forces; no contacts) and the
        applied forces other than the contacts' in ``qfrc_applied``."""
        m, d = self._model, self._data
        d.qfrc_applied[:] = 0.0
        d.qfrc_applied[self._vadr] = tau
        mujoco.mj_step1(m, d)
        if push is not None:
            point = d.xipos[self._push_body]
            mujoco.mj_applyFT(m, d, push, np.zeros(3), point, self._push_body, d.qfrc_applied)

    def _substeps(self, contacts: _Contacts | None) -> int:
        """Sub-steps of the coming step (module docstring) from the contacts near touching."""
        if contacts is None:
            return 1
        normal_rows = np.ascontiguousarray(contacts.jacobian[:, 0, :])
        solved = np.empty_like(normal_rows)
        mujoco.mj_solveM(self._model, self._data, solved, normal_rows)
        inverse_inertia = np.einsum("ij,ij->i", normal_rows, solved)  # 1/kg along n
        with np.errstate(invalid="ignore"):
            omega = np.sqrt(contacts.stiffness * inverse_inertia)
        needed = max(
            float(np.max(omega)) * self.dt / MAX_PHASE_PER_SUBSTEP,
            float(np.max(contacts.damping * inverse_inertia)) * self.dt / MAX_DAMPING_PER_SUBSTEP,
            1.0,
        )
        if not math.isfinite(needed) or needed > MAX_SUBSTEPS:
            raise ModelError(
                f"a contact needs {needed:.0f} sub-steps of the {self.dt:g} s step (at most "
                f"{MAX_SUBSTEPS}): stiffness or damping too high for the MuJoCo plant"
            )
        return math.ceil(needed)

    def _apply_contacts(self, nearby: _Contacts | None) -> None:
        """Add the forces of the penetrating contacts among ``nearby`` to ``qfrc_applied``."""
        contacts = None if nearby is None else nearby.penetrating()
        self._last_friction = {}
        if contacts is None:
            return
        forces = self._contact_forces(contacts, self._model.opt.timestep)
        self._data.qfrc_applied += np.einsum("ikv,ik->v", contacts.jacobian, forces)
        friction = np.einsum("ikj,ik->ij", contacts.frame[:, 1:, :], forces[:, 1:])
        for i, (g1, g2) in enumerate(contacts.geoms.tolist()):
            self._last_friction[(g1, g2)] = (friction[i], forces[i, 0], contacts.friction[i])

    def _detect(self, within: float, jacobians: mujoco.MjData | None = None) -> _Contacts | None:
        """MuJoCo's collision detection at the plant's configuration, on the geometry data: the
        contacts of a scene geom closer than ``within`` (m; 0: penetrating), with the Jacobians
        of ``jacobians`` (default: the dynamics data after mj_step1; the geometry data, brought
        to that configuration here, otherwise)."""
        m, g = self._model, self._geometry
        g.qpos[:] = self._data.qpos
        mujoco.mj_kinematics(m, g)
        if jacobians is g:
            mujoco.mj_comPos(m, g)
        m.opt.disableflags &= ~_NO_CONTACT
        try:
            mujoco.mj_collision(m, g)
        finally:
            m.opt.disableflags |= _NO_CONTACT
        if g.ncon == 0:
            return None
        contact = g.contact
        rows = np.flatnonzero(contact.dist < within)
        if len(rows) == 0:
            return None
        return self._contact_rows(
            contact.geom[rows],
            contact.dist[rows],
            contact.pos[rows],
            contact.frame[rows, :3],
            self._data if jacobians is None else jacobians,
        )

    def _contact_rows(
        self,
        geoms: np.ndarray,
        dist: np.ndarray,
        pos: np.ndarray,
        normal: np.ndarray,
        d: mujoco.MjData,
    ) -> _Contacts:
        """The contact rows of MuJoCo's contacts (geom pairs, signed distances m, midpoints m
        and normals from geom1 to geom2, world), with the Jacobians of ``d``."""
        m, nv, k = self._model, self._model.nv, len(dist)
        body1, body2 = m.geom_bodyid[geoms[:, 0]], m.geom_bodyid[geoms[:, 1]]
        point1 = pos - 0.5 * dist[:, None] * normal  # each surface point lies inside the other
        point2 = pos + 0.5 * dist[:, None] * normal
        frame = np.array([_frame(*n) for n in normal.tolist()])
        jacobian = np.empty((k, 3, nv))
        jac1, jac2 = np.zeros((3, nv)), np.zeros((3, nv))
        stiffness, damping, friction = np.empty(k), np.empty(k), np.empty(k)
        labels = []
        for i in range(k):
            mujoco.mj_jac(m, d, jac2, None, point2[i], body2[i])
            if body1[i] == 0:  # the world (table, static boxes) does not move
                jacobian[i] = frame[i] @ jac2
            else:
                mujoco.mj_jac(m, d, jac1, None, point1[i], body1[i])
                jacobian[i] = frame[i] @ (jac2 - jac1)
            g1, g2 = int(geoms[i, 0]), int(geoms[i, 1])
            material = self._pair_materials.get((g1, g2))
            if material is None:
                material = combine_materials(self._materials[g1], self._materials[g2])
                self._pair_materials[(g1, g2)] = material
            stiffness[i], damping[i] = material.stiffness, material.damping
            friction[i] = material.friction
            labels.append(self._scene_geoms.get(g1, self._scene_geoms.get(g2, "")))
        return _Contacts(
            geoms,
            body1,
            body2,
            frame,
            point1,
            point2,
            -dist,
            stiffness,
            damping,
            friction,
            jacobian,
            labels,
        )

    def _contact_forces(self, contacts: _Contacts, h: float) -> np.ndarray:
        """Per contact [λ, f_t1, f_t2] (N) in its frame (the force on body2), for a sub-step
        of h s; d holds mj_step1's results and the applied forces other than the contacts'."""
        m, d = self._model, self._data
        velocity = contacts.jacobian @ d.qvel  # k×3: separation speed and slip, m/s
        k = len(contacts.depth)
        forces = np.zeros((k, 3))
        for i in range(k):
            forces[i, 0] = normal_force(
                contacts.stiffness[i], contacts.damping[i], contacts.depth[i], -velocity[i, 0]
            )
        bounds = contacts.friction * forces[:, 0]
        if not np.any(bounds > 0.0):
            return forces
        # The slip at the end of the sub-step without friction, and the tangential inverse
        # inertia, from the mass matrix mj_step1 factorized.
        tangential = np.ascontiguousarray(contacts.jacobian[:, 1:, :].reshape(2 * k, m.nv))
        free_force = (
            d.qfrc_applied + contacts.jacobian[:, 0, :].T @ forces[:, 0] + d.qfrc_passive
        ) - d.qfrc_bias
        free_acceleration = np.empty((1, m.nv))
        mujoco.mj_solveM(m, d, free_acceleration, free_force[None, :])
        slip = tangential @ (d.qvel + h * free_acceleration[0])
        solved = np.empty_like(tangential)
        mujoco.mj_solveM(m, d, solved, tangential)
        inverse_inertia = tangential @ solved.T
        friction, converged = coulomb_friction(inverse_inertia, slip, bounds, h)
        if not converged:
            self.friction_sweep_limit_hits += 1
        forces[:, 1:] = friction.reshape(k, 2)
        return forces

    def state(self) -> PlantState:
        """The true state after the last step (see :class:`~sim_bridge.plant.PlantState`).

        The wrench is the contact's at this state, as a sensor sampling with the encoders
        measures it: the normal force ``K·δ + B·δ̇`` of the current penetration and its rate
        (the force the next step starts from), and the friction of the step just taken (at
        its end), rescaled to that normal force where the contact slid (μ·λ).
        """
        self._ensure_open()
        g = self._geometry
        contacts = self._detect(within=0.0, jacobians=g)  # leaves g at this configuration
        origin = g.xpos[self._tool_body].copy()
        rotation = g.xmat[self._tool_body].reshape(3, 3).copy()
        force, moment = np.zeros(3), np.zeros(3)
        normal_force_table, weight = 0.0, 0.0
        contact_point = origin.copy()
        robot_collision = False
        if contacts is not None:
            forces, normal = self._forces_at_state(contacts)
            weighted = np.zeros(3)
            for i in range(len(contacts.depth)):
                b1, b2 = int(contacts.body1[i]), int(contacts.body2[i])
                if self._tool_body not in (b1, b2):
                    robot_collision = robot_collision or bool({b1, b2} & self._robot_bodies)
                    continue
                on_body2 = b2 == self._tool_body
                f = forces[i] if on_body2 else -forces[i]  # on the tool
                point = contacts.point2[i] if on_body2 else contacts.point1[i]
                force += f
                lever = point - origin
                moment += (
                    lever[1] * f[2] - lever[2] * f[1],
                    lever[2] * f[0] - lever[0] * f[2],
                    lever[0] * f[1] - lever[1] * f[0],
                )
                if contacts.scene_label[i] == "table" and self._table_normal is not None:
                    normal_force_table += float(f @ self._table_normal)
                if normal[i] > 0.0:
                    weighted += normal[i] * point
                    weight += normal[i]
            if weight > 0.0:
                contact_point = weighted / weight
        return PlantState(
            t=self._t,
            q=self._data.qpos[self._qadr].copy(),
            v=self._data.qvel[self._vadr].copy(),
            tau=self._tau.copy(),
            wrench_world=np.concatenate([force, moment]),
            wrench_sensor=np.concatenate([force @ rotation, moment @ rotation]),
            normal_force=normal_force_table,
            contact_point=contact_point,
            contact_frame_position=origin,
            contact_frame_rotation=rotation,
            in_contact=weight > 0.0,
            robot_collision=robot_collision,
        )

    def _forces_at_state(self, contacts: _Contacts) -> tuple[np.ndarray, np.ndarray]:
        """The contact forces on body2 at the current state (:meth:`state`), N, world (k×3),
        and their normal parts λ (k)."""
        velocity = contacts.jacobian[:, 0, :] @ self._data.qvel  # separation speeds, m/s
        k = len(contacts.depth)
        forces, normal = np.zeros((k, 3)), np.zeros(k)
        for i in range(k):
            lam = normal_force(
                contacts.stiffness[i], contacts.damping[i], contacts.depth[i], -velocity[i]
            )
            n = contacts.frame[i, 0]
            forces[i] = lam * n
            normal[i] = lam
            last = self._last_friction.get((int(contacts.geoms[i, 0]), int(contacts.geoms[i, 1])))
            if last is None or lam <= 0.0:
                continue
            friction, last_lam, mu = last
            friction = friction - (friction @ n) * n  # onto this state's tangent plane
            size = float(np.linalg.norm(friction))
            if last_lam > 0.0 and size >= mu * last_lam * (1.0 - 1e-9):  # it slid
                friction = friction * (lam / last_lam)
            elif size > mu * lam:  # it stuck: at most the disc of this normal force
                friction = friction * (mu * lam / size)
            forces[i] += friction
        return forces, normal

    # ------------------------------------------------------------------ lifetime
    def _ensure_open(self) -> None:
        if self._closed:
            raise ModelError("this plant is closed")

    def close(self) -> None:
        """Release the simulation (idempotent)."""
        self._closed = True

    def __enter__(self) -> MujocoPlant:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _frame(nx: float, ny: float, nz: float) -> list[list[float]]:
    """Rows [n; t1; t2] of a right-handed orthonormal frame around the unit normal n (scalar
    arithmetic: numpy costs tens of µs on 3-vectors)."""
    if abs(nx) < 0.9:  # t1 = n × x̂ / |n × x̂|
        tx, ty, tz, norm = 0.0, nz, -ny, math.hypot(ny, nz)
    else:  # t1 = n × ŷ / |n × ŷ|
        tx, ty, tz, norm = -nz, 0.0, nx, math.hypot(nx, nz)
    tx, ty, tz = tx / norm, ty / norm, tz / norm
    return [[nx, ny, nz], [tx, ty, tz], [ny * tz - nz * ty, nz * tx - nx * tz, nx * ty - ny * tx]]


def _conforms(plant: MujocoPlant) -> PlantProtocol[PlantState]:
    """Static check (mypy): the MuJoCo plant is a :class:`ffmpc_core.plant.Plant`."""
    return plant
