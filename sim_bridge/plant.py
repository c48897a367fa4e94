"""The simulated plant ("RBDS" of the paper's Fig. 2): a torque-controlled arm in PyBullet.

One :class:`Plant` owns one PyBullet physics client in DIRECT mode; every PyBullet call passes
that ``physicsClientId``, so several plants can live in one process. Everything goes in and out
as numpy arrays in the joint order of :attr:`RobotModel.joint_names` (rad, rad/s, N·m) and in
the world frame (m, N). The plant never sees a controller's model of the table.

Modelling choices (each makes PyBullet's dynamics those of the pinocchio model):

* The URDF is loaded with ``URDF_USE_INERTIA_FROM_FILE`` (otherwise PyBullet recomputes link
  inertias from the collision meshes), fixed base at the world origin.
* PyBullet's default velocity motors are disabled (zero maximum force), and the joint damping
  read from the URDF and PyBullet's default linear/angular damping (0.04) are set to zero.
* Joints of the URDF that the robot model locks (the Panda's fingers) become ``fixed`` joints at
  0 in the generated URDF, as pinocchio's reduced model locks them at 0; their collision shapes
  are removed: the tool below replaces the gripper.

The tool. PyBullet loads URDFs only, so a copy of the robot URDF is generated in a temporary
directory (deleted right after loading; mesh paths are made absolute, ``package://`` URIs
resolved) with an extra link ``ffmpc_tool`` fixed to :attr:`RobotModel.flange_frame`. The
tool link's frame IS the robot's ``contact`` frame (joint origin =
:attr:`RobotModel.tool_placement`), and it carries a sphere of radius ``r`` (default 1 cm)
centred at ``(0, 0, -r)`` in that frame: the sphere's extreme point along the tool axis (+z of
the contact frame, pointing out of the flange) is the contact frame origin. A sphere gives a
single, well-defined contact point; when the tool axis is tilted by an angle α from the
surface normal, the touching point lies ``r·sin α`` (1.7 mm for r = 1 cm, α = 10°) away from
the contact frame origin, which is why the radius is small. The tool mass defaults to 0 (a
massless fixed link is exact in Bullet's Featherstone solver, so dynamics equal pinocchio's);
a non-zero mass is added as a solid sphere, see :func:`tool_spatial_inertia` and
:func:`model_with_tool`.

Contact parameters. Bullet combines the contact parameters of two bodies: stiffness in series,
``k = 1/(1/k_A + 1/k_B)``; damping summed, ``d = d_A + d_B``; friction multiplied,
``μ = μ_A · μ_B``. A body whose stiffness was never set is rigid (k = BT_LARGE_FLOAT) with
damping 0.1, and its lateral friction defaults to 0.5. To get exactly the paper's table
contact (k = 1e4 N/m, d = 1e2 N·s/m, μ = 0.5, VI-B2) the tool is given k = 1e9 N/m, d = 0,
μ = 1 (so the table parameters pass through unchanged, k = 1e4·(1 − 1e-5)), and the table
k = 1e4, d = 1e2, μ = 0.5.
Friction uses Bullet's cone (not pyramid) model. Measured (tests/test_plant.py): a static push
of 50 N gives exactly 50 N and a penetration of 5.01 mm (the implicit spring-damper settles
0.2 % deeper than λ/k); sliding friction is exactly μ·λ.

Signs. The contact wrench is the one the environment exerts ON the tool (the force convention
of ffmpc_core.config: pushing down on a horizontal table gives a positive normal force),
reduced to the contact frame origin: ``[f; m]`` with ``m = Σ (p_i − o) × f_i``.
"""

from __future__ import annotations

import math
import os
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
import pinocchio as pin
import pybullet as pb

from ffmpc_core.errors import ConfigError, InputError, ModelError
from ffmpc_core.plant import Plant as PlantProtocol
from ffmpc_core.robots import RobotModel, load_robot

#: Name of the link (and frame) PyBullet gets for the tool; its frame is the contact frame.
TOOL_LINK = "ffmpc_tool"
TOOL_JOINT = "ffmpc_tool_joint"

_MOVABLE_URDF_TYPES = ("revolute", "continuous", "prismatic")


def _vector3(value: npt.ArrayLike, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name} must be 3 finite numbers, got {value!r}")
    return arr


def _positive(value: float, name: str, allow_zero: bool = False) -> None:
    ok = math.isfinite(value) and (value >= 0.0 if allow_zero else value > 0.0)
    if not ok:
        raise ConfigError(f"{name} must be {'>= 0' if allow_zero else '> 0'}, got {value!r}")


def _quaternion_xyzw(rotation: np.ndarray) -> tuple[float, float, float, float]:
    x, y, z, w = (float(c) for c in pin.Quaternion(rotation).coeffs())
    return x, y, z, w


@dataclass(frozen=True)
class TableConfig:
    """A static box whose top face is the polishing surface, tilted by θ about a horizontal axis.

    Attributes:
        surface_point: a point of the top surface, m, world frame (the box is centred below it).
        tilt_angle: θ, rad, rotation of the box about ``tilt_axis`` (paper VI-B2: ±6°).
        tilt_axis: horizontal rotation axis of the tilt, world frame (normalised here).
        half_extents: half sizes of the box along its own x, y, z (z: half thickness), m.
        stiffness: contact stiffness, N/m (paper: 1e4).
        damping: contact damping, N·s/m (paper: 1e2).
        lateral_friction: Coulomb friction coefficient (paper: 0.5).
    """

    surface_point: tuple[float, float, float] = (0.55, 0.0, 0.2)
    tilt_angle: float = 0.0
    tilt_axis: tuple[float, float, float] = (1.0, 0.0, 0.0)
    half_extents: tuple[float, float, float] = (0.3, 0.3, 0.05)
    stiffness: float = 1e4
    damping: float = 1e2
    lateral_friction: float = 0.5

    def __post_init__(self) -> None:
        _vector3(self.surface_point, "surface_point")
        axis = _vector3(self.tilt_axis, "tilt_axis")
        norm = float(np.linalg.norm(axis))
        if norm == 0.0 or abs(axis[2]) > 1e-9 * norm:
            raise ConfigError(f"tilt_axis must be a non-zero horizontal vector, got {axis}")
        if not math.isfinite(self.tilt_angle) or abs(self.tilt_angle) >= math.pi / 2:
            raise ConfigError(f"tilt_angle must be in (-π/2, π/2) rad, got {self.tilt_angle}")
        if np.any(_vector3(self.half_extents, "half_extents") <= 0.0):
            raise ConfigError("half_extents must be positive")
        _positive(self.stiffness, "stiffness")
        _positive(self.damping, "damping", allow_zero=True)
        _positive(self.lateral_friction, "lateral_friction", allow_zero=True)

    @property
    def rotation(self) -> np.ndarray:
        """Orientation of the box in the world (rotation by θ about the tilt axis)."""
        axis = np.asarray(self.tilt_axis, dtype=float)
        return pin.exp3(axis / np.linalg.norm(axis) * self.tilt_angle)

    @property
    def normal(self) -> np.ndarray:
        """Unit normal of the top surface, pointing up (out of the table), world frame."""
        return self.rotation[:, 2].copy()

    @property
    def center(self) -> np.ndarray:
        """Centre of the box, m, world frame."""
        return np.asarray(self.surface_point, float) - self.half_extents[2] * self.normal


@dataclass(frozen=True)
class SoftBoxConfig:
    """A free (or static) box with its own contact stiffness and damping, e.g. a soft dice.

    Bullet applies stiffness and damping PER CONTACT POINT: the spherical tool makes one point,
    so pressing it into the box gives λ = k·depth; a box lying on a face of another box makes
    4 points, i.e. a support 4× stiffer (measured: a 0.1 kg dice of k = 1e3 N/m on the table
    sinks m·g/(4·k_series)).

    Attributes:
        position: initial centre, m, world frame.
        stiffness: contact stiffness, N/m (in series with the other body's, see module doc).
        damping: contact damping, N·s/m (summed with the other body's).
        size: full edge lengths along the box axes, m (the paper's dice: 0.16 m).
        mass: kg (the paper's dice: 0.1 kg); 0 makes the box static.
        orientation: initial orientation as a quaternion (x, y, z, w), world frame.
        lateral_friction: friction coefficient (multiplied with the other body's).
        collision_margin: Bullet's collision margin of the box, m (None: PyBullet's 1 mm). The
            outer faces stay where ``size`` puts them; the margin rounds the edges with this
            radius. Bullet's sphere–box contact switches branch once the sphere's centre passes
            the inner (margin-less) face, at a depth of radius + margin, and the manifold then
            keeps a SECOND point at the same depth: the force doubles in one step (measured with
            the 1 cm tool at 11.0 mm: 52.8 → 105.6 N on a 4800 N/m box). A margin larger than
            the deepest planned penetration minus the tool radius keeps the single contact.
    """

    position: tuple[float, float, float]
    stiffness: float
    damping: float
    size: tuple[float, float, float] = (0.16, 0.16, 0.16)
    mass: float = 0.1
    orientation: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    lateral_friction: float = 0.5
    collision_margin: float | None = None

    def __post_init__(self) -> None:
        _vector3(self.position, "position")
        if np.any(_vector3(self.size, "size") <= 0.0):
            raise ConfigError("size must be positive")
        quat = np.asarray(self.orientation, dtype=float)
        if quat.shape != (4,) or not np.isclose(np.linalg.norm(quat), 1.0, atol=1e-6):
            raise ConfigError(f"orientation must be a unit quaternion (x, y, z, w), got {quat}")
        _positive(self.stiffness, "stiffness")
        _positive(self.damping, "damping", allow_zero=True)
        _positive(self.mass, "mass", allow_zero=True)
        _positive(self.lateral_friction, "lateral_friction", allow_zero=True)
        if self.collision_margin is not None:
            _positive(self.collision_margin, "collision_margin")
            if 2.0 * self.collision_margin >= float(np.min(self.size)):
                raise ConfigError("collision_margin must be below half the smallest edge (m)")


@dataclass(frozen=True)
class ToolConfig:
    """The spherical tool at the contact frame (see the module docstring for the choices).

    Attributes:
        radius: sphere radius, m.
        mass: kg; 0 keeps PyBullet's dynamics identical to the pinocchio model's.
        lateral_friction: multiplied with the other body's (1 passes the table's through).
        stiffness: contact stiffness of the tool surface, N/m (1e9: rigid next to the table).
        damping: contact damping of the tool surface, N·s/m (0: the table's passes through).
        center_of_mass: the tool's centre of mass, m, in the FLANGE frame (where the wrist
            force/torque sensor is); None: the sphere's centre. Its rotational inertia is the
            solid sphere's (2/5·m·r²) about this point, as ``ffmpc_core.robots.ToolLoad``'s.
    """

    radius: float = 0.01
    mass: float = 0.0
    lateral_friction: float = 1.0
    stiffness: float = 1e9
    damping: float = 0.0
    center_of_mass: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        _positive(self.radius, "radius")
        _positive(self.mass, "mass", allow_zero=True)
        _positive(self.lateral_friction, "lateral_friction", allow_zero=True)
        _positive(self.stiffness, "stiffness")
        _positive(self.damping, "damping", allow_zero=True)
        if self.center_of_mass is not None:
            _vector3(self.center_of_mass, "center_of_mass")

    def sphere_center(self, robot: RobotModel) -> np.ndarray:
        """Centre of the tool sphere in the flange frame, m."""
        return robot.tool_placement.act(np.array([0.0, 0.0, -self.radius]))

    def mass_center(self, robot: RobotModel) -> np.ndarray:
        """The tool's centre of mass in the flange frame, m."""
        if self.center_of_mass is None:
            return self.sphere_center(robot)
        return np.asarray(self.center_of_mass, dtype=float)


@dataclass(frozen=True)
class PlantConfig:
    """Everything the plant is built from.

    Attributes:
        time_step: physics step, s (1 kHz default; 2 kHz works).
        gravity: m/s², world frame.
        table: the tilted table, or None for no table.
        soft_boxes: extra soft boxes (beside or instead of the table).
        tool: the spherical tool.
        solver_iterations: Bullet's constraint solver iterations per step.
        visuals: keep the URDF's visual shapes (only useful for rendering).
    """

    time_step: float = 1e-3
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)
    table: TableConfig | None = field(default_factory=TableConfig)
    soft_boxes: tuple[SoftBoxConfig, ...] = ()
    tool: ToolConfig = field(default_factory=ToolConfig)
    solver_iterations: int = 50
    visuals: bool = False

    def __post_init__(self) -> None:
        if not (math.isfinite(self.time_step) and 0.0 < self.time_step <= 0.01):
            raise ConfigError(f"time_step must be in (0, 0.01] s, got {self.time_step}")
        _vector3(self.gravity, "gravity")
        if self.solver_iterations < 1:
            raise ConfigError("solver_iterations must be >= 1")


@dataclass(frozen=True)
class PlantState:
    """What the simulator knows after a step (the truth, before any sensing model).

    Attributes:
        t: simulation time, s (0 at reset).
        q: joint positions, rad.  v: joint velocities, rad/s.
        tau: joint torque applied during the last step (after saturation), N·m.
        wrench_world: ``[f; m]`` exerted by the environment on the tool, reduced to the contact
            frame origin, world axes (pinocchio LOCAL_WORLD_ALIGNED), N and N·m.
        wrench_sensor: the same wrench in the contact (sensor) frame axes (LOCAL).
        normal_force: component along the true (tilted) table normal of the force the table
            exerts on the tool, N (> 0 when pressing; 0 without a table).
        contact_point: normal-force-weighted mean of the contact points on the tool's surface,
            m, world frame; the contact frame origin when not in contact.
        contact_frame_position: origin of the contact frame, m, world frame.
        contact_frame_rotation: orientation of the contact frame in the world (3×3).
        in_contact: whether any tool contact point carries a positive normal force.
        robot_collision: whether a robot link other than the tool touches something.
    """

    t: float
    q: np.ndarray
    v: np.ndarray
    tau: np.ndarray
    wrench_world: np.ndarray
    wrench_sensor: np.ndarray
    normal_force: float
    contact_point: np.ndarray
    contact_frame_position: np.ndarray
    contact_frame_rotation: np.ndarray
    in_contact: bool
    robot_collision: bool


def tool_spatial_inertia(robot: RobotModel, tool: ToolConfig) -> pin.Inertia:
    """Spatial inertia of the tool (solid sphere of ``tool.mass``) in the flange frame."""
    sphere = pin.Inertia.FromSphere(tool.mass, tool.radius)
    return pin.SE3(np.eye(3), tool.mass_center(robot)).act(sphere)


def model_with_tool(robot: RobotModel, tool: ToolConfig) -> pin.Model:
    """A copy of the robot's pinocchio model with the tool's inertia added to the flange body.

    With ``tool.mass == 0`` it equals the robot model; with a massive tool it is the model
    PyBullet simulates.
    """
    model = pin.Model(robot.model)
    flange = model.frames[model.getFrameId(robot.flange_frame)]
    inertia = flange.placement.act(tool_spatial_inertia(robot, tool))
    model.appendBodyToJoint(flange.parentJoint, inertia, pin.SE3.Identity())
    return model


def _sum_of_moments(lever: np.ndarray, force: np.ndarray) -> np.ndarray:
    """Σ_i lever_i × force_i for k×3 arrays (np.cross costs ~30 µs on these tiny arrays)."""
    (x, y, z), (fx, fy, fz) = lever.T, force.T
    return np.array([y @ fz - z @ fy, z @ fx - x @ fz, x @ fy - y @ fx])


def _resolve_mesh(filename: str, urdf_dir: str) -> str:
    if filename.startswith("package://"):
        package, _, rest = filename[len("package://") :].partition("/")
        directory = urdf_dir
        while True:
            if os.path.basename(directory) == package:
                return os.path.join(directory, rest)
            if os.path.isdir(os.path.join(directory, package)):
                return os.path.join(directory, package, rest)
            parent = os.path.dirname(directory)
            if parent == directory:
                raise ModelError(f"cannot resolve {filename!r} from {urdf_dir}")
            directory = parent
    if filename.startswith("file://"):
        filename = filename[len("file://") :]
    return filename if os.path.isabs(filename) else os.path.join(urdf_dir, filename)


def _fmt(values: Iterable[float]) -> str:
    return " ".join(f"{float(x):.17g}" for x in values)


def _joint_link(joint: ET.Element, tag: str, urdf_path: str) -> str:
    """The ``link`` attribute of a URDF joint's ``parent`` or ``child``; ModelError if absent."""
    element = joint.find(tag)
    link = None if element is None else element.get("link")
    if link is None:
        raise ModelError(f"joint {joint.get('name')!r} of {urdf_path} has no {tag} link")
    return link


def tool_urdf_text(robot: RobotModel, tool: ToolConfig, visuals: bool = False) -> str:
    """The robot URDF with the tool link added and the locked joints fixed (see module doc);
    without ``visuals`` the visual elements are dropped (DIRECT mode never draws them, and the
    Panda's COLLADA meshes take ~0.4 s to parse)."""
    urdf_path = os.path.realpath(robot.urdf_path)
    urdf_dir = os.path.dirname(urdf_path)
    root = ET.parse(urdf_path).getroot()
    if not visuals:
        for link in root.findall("link"):
            for visual in link.findall("visual"):
                link.remove(visual)
    for mesh in root.iter("mesh"):
        mesh.set("filename", _resolve_mesh(mesh.get("filename", ""), urdf_dir))

    links = {link.get("name"): link for link in root.findall("link")}
    if robot.flange_frame not in links:
        raise ModelError(f"flange link {robot.flange_frame!r} is not in {urdf_path}")
    children: dict[str, list[str]] = {}
    locked: list[str] = []
    for joint in root.findall("joint"):
        parent = _joint_link(joint, "parent", urdf_path)
        child = _joint_link(joint, "child", urdf_path)
        children.setdefault(parent, []).append(child)
        if joint.get("type") in _MOVABLE_URDF_TYPES and joint.get("name") not in robot.joint_names:
            joint.set("type", "fixed")  # locked at 0, as pinocchio's reduced model
            for tag in ("limit", "mimic", "dynamics", "safety_controller", "axis"):
                for element in joint.findall(tag):
                    joint.remove(element)
            locked.append(child)
    stack = list(locked)
    while stack:  # the locked sub-trees (the gripper) lose their collision shapes
        name = stack.pop()
        for collision in links[name].findall("collision"):
            links[name].remove(collision)
        stack.extend(children.get(name, []))
    if TOOL_LINK in links:
        raise ModelError(f"{urdf_path} already has a link named {TOOL_LINK!r}")

    center = np.array([0.0, 0.0, -tool.radius])
    # the inertial origin in the tool link's frame (= the contact frame)
    mass_center = (
        center
        if tool.center_of_mass is None
        else robot.tool_placement.actInv(np.asarray(tool.center_of_mass, dtype=float))
    )
    sphere_inertia = 0.4 * tool.mass * tool.radius**2
    link = ET.SubElement(root, "link", name=TOOL_LINK)
    inertial = ET.SubElement(link, "inertial")
    ET.SubElement(inertial, "origin", xyz=_fmt(mass_center), rpy="0 0 0")
    ET.SubElement(inertial, "mass", value=f"{tool.mass:.17g}")
    ET.SubElement(
        inertial,
        "inertia",
        ixx=f"{sphere_inertia:.17g}",
        iyy=f"{sphere_inertia:.17g}",
        izz=f"{sphere_inertia:.17g}",
        ixy="0",
        ixz="0",
        iyz="0",
    )
    for tag in ("collision", "visual") if visuals else ("collision",):
        element = ET.SubElement(link, tag)
        ET.SubElement(element, "origin", xyz=_fmt(center), rpy="0 0 0")
        geometry = ET.SubElement(element, "geometry")
        ET.SubElement(geometry, "sphere", radius=f"{tool.radius:.17g}")
    joint = ET.SubElement(root, "joint", name=TOOL_JOINT, type="fixed")
    placement = robot.tool_placement
    ET.SubElement(
        joint,
        "origin",
        xyz=_fmt(placement.translation),
        rpy=_fmt(pin.rpy.matrixToRpy(placement.rotation)),
    )
    ET.SubElement(joint, "parent", link=robot.flange_frame)
    ET.SubElement(joint, "child", link=TOOL_LINK)
    return ET.tostring(root, encoding="unicode")


def checked_push(
    force_world: object, steps: object, link: str | None, link_indices: dict[str, int]
) -> tuple[np.ndarray, int, int]:
    """A push request checked for either plant: the force (N, world frame; a copy), the index
    of ``link`` (default the tool link) in ``link_indices`` and the number of steps. Raises
    InputError on a force that is not 3 finite numbers, a negative or fractional step count,
    or an unknown link."""
    force = np.asarray(force_world, dtype=float)
    if force.shape != (3,) or not np.all(np.isfinite(force)):
        raise InputError(f"force_world must be 3 finite numbers, got {force_world!r}")
    if int(steps) != steps or steps < 0:  # type: ignore[call-overload, operator]
        raise InputError(f"steps must be a non-negative integer, got {steps!r}")
    name = TOOL_LINK if link is None else link
    if name not in link_indices:
        raise InputError(f"unknown link {name!r}; links: {sorted(link_indices)}")
    return force.copy(), link_indices[name], int(steps)  # type: ignore[call-overload]


class Plant:
    """A PyBullet simulation of one torque-controlled arm with a spherical tool, a table and
    soft boxes (the :class:`ffmpc_core.plant.Plant` shape, state :class:`PlantState`). Use as a
    context manager or call :meth:`close`.

    Typical loop: ``plant.reset(q0)``, then per physics step ``plant.step(tau)`` and, when a
    measurement is due, ``plant.state()``.
    """

    def __init__(self, robot: RobotModel | str = "iiwa", config: PlantConfig | None = None) -> None:
        self.robot = load_robot(robot) if isinstance(robot, str) else robot
        self.config = config if config is not None else PlantConfig()
        self.dt = float(self.config.time_step)
        self._box_configs: dict[int, SoftBoxConfig] = {}
        self._client = pb.connect(pb.DIRECT)
        if self._client < 0:
            raise ModelError("could not start a PyBullet physics client")
        try:
            self._build()
        except BaseException:
            pb.disconnect(physicsClientId=self._client)
            self._client = -1
            raise
        nv = self.robot.nv
        self._t = 0.0
        self._tau = np.zeros(nv)
        self._push_force = np.zeros(3)
        self._push_link = self.tool_link
        self._push_steps = 0
        self._forces_valid = False
        self.reset(self.robot.q_nominal)

    # ------------------------------------------------------------------ construction
    def _build(self) -> None:
        c = self._client
        cfg = self.config
        pb.setGravity(*cfg.gravity, physicsClientId=c)
        pb.setPhysicsEngineParameter(
            fixedTimeStep=self.dt,
            numSubSteps=0,
            numSolverIterations=cfg.solver_iterations,
            enableConeFriction=1,
            deterministicOverlappingPairs=1,
            physicsClientId=c,
        )
        text = tool_urdf_text(self.robot, cfg.tool, cfg.visuals)
        with tempfile.TemporaryDirectory(prefix="ffmpc_plant_") as tmp:
            path = os.path.join(tmp, f"{self.robot.name}_with_tool.urdf")
            with open(path, "w", encoding="utf-8") as stream:
                stream.write(text)
            try:
                self.body = pb.loadURDF(
                    path,
                    basePosition=(0.0, 0.0, 0.0),
                    baseOrientation=(0.0, 0.0, 0.0, 1.0),
                    useFixedBase=True,
                    flags=pb.URDF_USE_INERTIA_FROM_FILE,
                    physicsClientId=c,
                )
            except pb.error as exc:
                raise ModelError(f"PyBullet could not load {self.robot.name}: {exc}") from exc
        self._index_joints()
        # No velocity motors, no damping: the dynamics are pinocchio's.
        pb.setJointMotorControlArray(
            self.body,
            self.joint_indices,
            pb.VELOCITY_CONTROL,
            targetVelocities=[0.0] * len(self.joint_indices),
            forces=[0.0] * len(self.joint_indices),
            physicsClientId=c,
        )
        for link in range(-1, pb.getNumJoints(self.body, physicsClientId=c)):
            pb.changeDynamics(
                self.body,
                link,
                linearDamping=0.0,
                angularDamping=0.0,
                jointDamping=0.0,
                physicsClientId=c,
            )
        tool = cfg.tool
        pb.changeDynamics(
            self.body,
            self.tool_link,
            lateralFriction=tool.lateral_friction,
            contactStiffness=tool.stiffness,
            contactDamping=tool.damping,
            physicsClientId=c,
        )
        self.table = self._add_table(cfg.table) if cfg.table is not None else None
        self.soft_boxes: list[int] = [self.add_soft_box(box) for box in cfg.soft_boxes]

    def _index_joints(self) -> None:
        c = self._client
        by_joint: dict[str, tuple[int, int]] = {}
        self.link_indices: dict[str, int] = {
            pb.getBodyInfo(self.body, physicsClientId=c)[0].decode(): -1
        }
        for j in range(pb.getNumJoints(self.body, physicsClientId=c)):
            info = pb.getJointInfo(self.body, j, physicsClientId=c)
            by_joint[info[1].decode()] = (j, info[2])
            self.link_indices[info[12].decode()] = j
        indices = []
        for name in self.robot.joint_names:
            if name not in by_joint or by_joint[name][1] not in (
                pb.JOINT_REVOLUTE,
                pb.JOINT_PRISMATIC,
            ):
                raise ModelError(f"joint {name!r} is not a movable joint of the PyBullet model")
            indices.append(by_joint[name][0])
        movable = {j for j, kind in by_joint.values() if kind != pb.JOINT_FIXED}
        if movable != set(indices):
            raise ModelError("PyBullet model has movable joints the robot model does not have")
        self.joint_indices: list[int] = indices
        self.tool_link: int = self.link_indices[TOOL_LINK]

    def _add_table(self, table: TableConfig) -> int:
        c = self._client
        half = [float(x) for x in table.half_extents]
        shape = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=c)
        visual = pb.createVisualShape(
            pb.GEOM_BOX, halfExtents=half, rgbaColor=(0.6, 0.45, 0.3, 1.0), physicsClientId=c
        )
        body = pb.createMultiBody(
            baseMass=0.0,
            baseCollisionShapeIndex=shape,
            baseVisualShapeIndex=visual,
            basePosition=[float(x) for x in table.center],
            baseOrientation=_quaternion_xyzw(table.rotation),
            physicsClientId=c,
        )
        pb.changeDynamics(
            body,
            -1,
            lateralFriction=table.lateral_friction,
            contactStiffness=table.stiffness,
            contactDamping=table.damping,
            restitution=0.0,
            physicsClientId=c,
        )
        self._table_normal = table.normal
        return body

    def add_soft_box(self, box: SoftBoxConfig) -> int:
        """Add a soft box to the world; returns its PyBullet body id (reset restores its pose)."""
        c = self._client
        half = [0.5 * float(x) for x in box.size]
        shape = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=c)
        visual = pb.createVisualShape(
            pb.GEOM_BOX, halfExtents=half, rgbaColor=(0.9, 0.9, 0.2, 1.0), physicsClientId=c
        )
        body = pb.createMultiBody(
            baseMass=float(box.mass),
            baseCollisionShapeIndex=shape,
            baseVisualShapeIndex=visual,
            basePosition=[float(x) for x in box.position],
            baseOrientation=[float(x) for x in box.orientation],
            physicsClientId=c,
        )
        pb.changeDynamics(
            body,
            -1,
            lateralFriction=box.lateral_friction,
            contactStiffness=box.stiffness,
            contactDamping=box.damping,
            linearDamping=0.0,
            angularDamping=0.0,
            restitution=0.0,
            physicsClientId=c,
        )
        if box.collision_margin is not None:
            pb.changeDynamics(body, -1, collisionMargin=box.collision_margin, physicsClientId=c)
        self._box_configs[body] = box
        return body

    # ------------------------------------------------------------------ properties
    @property
    def client_id(self) -> int:
        """The PyBullet physics client id of this plant."""
        return self._client

    @property
    def t(self) -> float:
        """Simulation time since the last reset, s."""
        return self._t

    @property
    def table_normal(self) -> np.ndarray:
        """Unit normal of the table's top surface (world frame); ConfigError without a table."""
        if self.table is None:
            raise ConfigError("this plant has no table")
        return self._table_normal.copy()

    # ------------------------------------------------------------------ simulation
    def _check_vector(self, value: npt.ArrayLike, name: str) -> np.ndarray:
        arr = np.asarray(value, dtype=float)
        if arr.shape != (self.robot.nv,) or not np.all(np.isfinite(arr)):
            raise InputError(f"{name} must be {self.robot.nv} finite numbers, got {value!r}")
        return arr

    def reset(self, q: np.ndarray, v: np.ndarray | None = None) -> None:
        """Put the robot at (q, v) (rad, rad/s), t = 0, soft boxes back to their initial pose."""
        self._ensure_open()
        q = self._check_vector(q, "q")
        v = np.zeros(self.robot.nv) if v is None else self._check_vector(v, "v")
        c = self._client
        for j, qj, vj in zip(self.joint_indices, q, v, strict=True):
            pb.resetJointState(self.body, j, float(qj), float(vj), physicsClientId=c)
        for body, box in self._box_configs.items():
            pb.resetBasePositionAndOrientation(
                body, box.position, box.orientation, physicsClientId=c
            )
            pb.resetBaseVelocity(body, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), physicsClientId=c)
        self._t = 0.0
        self._tau[:] = 0.0
        self._push_steps = 0
        self._forces_valid = False  # PyBullet's contact forces are those of the last step

    def apply_external_push(
        self, force_world: np.ndarray, steps: int, link: str | None = None
    ) -> None:
        """Apply ``force_world`` (N, world frame) at the centre of mass of ``link`` (a URDF link
        name; default the tool link) during the next ``steps`` physics steps (Experiment 3.3).
        A new push replaces a pending one."""
        self._push_force, self._push_link, self._push_steps = checked_push(
            force_world, steps, link, self.link_indices
        )

    def step(self, tau: np.ndarray) -> None:
        """Apply the joint torque ``tau`` (N·m, saturated to the torque limits) for one step."""
        self._ensure_open()
        tau = np.clip(
            self._check_vector(tau, "tau"), -self.robot.torque_limit, self.robot.torque_limit
        )
        c = self._client
        pb.setJointMotorControlArray(
            self.body, self.joint_indices, pb.TORQUE_CONTROL, forces=tau.tolist(), physicsClientId=c
        )
        if self._push_steps > 0:
            com = (
                pb.getLinkState(
                    self.body, self._push_link, computeForwardKinematics=1, physicsClientId=c
                )[0]
                if self._push_link >= 0
                else pb.getBasePositionAndOrientation(self.body, physicsClientId=c)[0]
            )
            pb.applyExternalForce(
                self.body,
                self._push_link,
                self._push_force.tolist(),
                com,
                pb.WORLD_FRAME,
                physicsClientId=c,
            )
            self._push_steps -= 1
        pb.stepSimulation(physicsClientId=c)
        self._tau[:] = tau
        self._t += self.dt
        self._forces_valid = True

    def state(self) -> PlantState:
        """The true state after the last step (see :class:`PlantState`)."""
        self._ensure_open()
        c = self._client
        joints = pb.getJointStates(self.body, self.joint_indices, physicsClientId=c)
        q = np.array([s[0] for s in joints])
        v = np.array([s[1] for s in joints])
        link = pb.getLinkState(
            self.body, self.tool_link, computeForwardKinematics=1, physicsClientId=c
        )
        origin = np.array(link[4])
        rotation = np.array(pb.getMatrixFromQuaternion(link[5])).reshape(3, 3)
        rows = []  # per tool contact: point on the tool, normal, friction dirs, 3 magnitudes
        robot_collision = False
        if self._forces_valid:
            for pt in pb.getContactPoints(bodyA=self.body, physicsClientId=c):
                if pt[1] != self.body:  # PyBullet reports the filtered body as A
                    raise ModelError("PyBullet returned a contact with the robot as body B")
                if pt[2] == self.body:
                    continue  # self-collision is disabled; ignore if ever reported
                if pt[3] != self.tool_link:
                    robot_collision = robot_collision or pt[9] > 0.0 or pt[8] < 0.0
                    continue
                on_table = 1.0 if pt[2] == self.table else 0.0
                rows.append((*pt[5], *pt[7], *pt[11], *pt[13], pt[9], pt[10], pt[12], on_table))
        if rows:
            data = np.array(rows)
            points, normal_force_i = data[:, 0:3], data[:, 12]
            forces = (
                normal_force_i[:, None] * data[:, 3:6]
                + data[:, 13:14] * data[:, 6:9]
                + data[:, 14:15] * data[:, 9:12]
            )
            force = forces.sum(axis=0)
            moment = _sum_of_moments(points - origin, forces)
            table_force = data[:, 15] @ forces
            normal_force = (
                float(table_force @ self._table_normal) if self.table is not None else 0.0
            )
            weight = float(np.sum(np.maximum(normal_force_i, 0.0)))
        else:
            force = moment = np.zeros(3)
            normal_force = weight = 0.0
        in_contact = weight > 0.0
        contact_point = (
            np.maximum(normal_force_i, 0.0) @ points / weight if in_contact else origin.copy()
        )
        return PlantState(
            t=self._t,
            q=q,
            v=v,
            tau=self._tau.copy(),
            wrench_world=np.concatenate([force, moment]),
            wrench_sensor=np.concatenate([force @ rotation, moment @ rotation]),
            normal_force=normal_force,
            contact_point=contact_point,
            contact_frame_position=origin,
            contact_frame_rotation=rotation,
            in_contact=in_contact,
            robot_collision=robot_collision,
        )

    # ------------------------------------------------------------------ lifetime
    def _ensure_open(self) -> None:
        if self._client < 0:
            raise ModelError("this plant is closed")

    def close(self) -> None:
        """Disconnect the physics client (idempotent)."""
        if self._client >= 0:
            pb.disconnect(physicsClientId=self._client)
            self._client = -1

    def __enter__(self) -> Plant:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # interpreter shutdown: pybullet may already be gone
            pass


def _conforms(plant: Plant) -> PlantProtocol[PlantState]:
    """Static check (mypy): the PyBullet plant is a :class:`ffmpc_core.plant.Plant`."""
    return plant
