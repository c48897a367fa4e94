"""Robot models: kinematics/dynamics, the contact (tool) frame and the limits, in one place.

Two 7-DoF torque-controlled arms are supported:

* ``"iiwa"`` — the KUKA LBR iiwa URDF shipped with ``pybullet_data`` (``kuka_iiwa/model.urdf``).
  Its URDF carries placeholder limits (300 N·m, 10 rad/s on every joint); the limits are the
  LBR iiwa 14 R820's data sheet (the paper's hardware robot, :data:`ffmpc_core.datasheet.
  IIWA14_R820`; the URDF's link masses are lighter than the 14's: see that module).
  The URDF ends at the flange (``lbr_iiwa_link_7``); we add a ``contact`` frame for the polishing
  tool: 0.10 m along the flange z axis, rotated by -45° about z (the F/T sensor's mounting).
* ``"panda"`` — the Franka Emika Panda of ``example-robot-data``; the two finger joints are locked
  (closed) to get a 7-DoF arm, and the ``contact`` frame is ``panda_hand_tcp``. Its limits are
  Franka's data sheet (:data:`ffmpc_core.datasheet.PANDA`; the URDF carries the same q, q̇, τ).

Every limit of a :class:`RobotModel` (and of its pinocchio model) comes from
:mod:`ffmpc_core.datasheet`, the one place the data sheets are written down.

Both contact frames have non-identity placements on purpose: derivatives are tested with them.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace

import numpy as np
import pinocchio as pin

from ffmpc_core.datasheet import DataSheet, datasheet
from ffmpc_core.errors import ConfigError, ModelError
from ffmpc_core.plausibility import check_torque

#: The contact frame of every robot model is called so.
CONTACT_FRAME = "contact"
#: A joint limit at or beyond this magnitude (rad, rad/s) means "no limit" (pinocchio fills
#: unlimited joints with the largest double).
_NO_LIMIT = 1e10


@dataclass(frozen=True)
class RobotModel:
    """An immutable robot description; create pinocchio data with :meth:`create_data`.

    Attributes:
        name: ``"iiwa"`` or ``"panda"``.
        model: pinocchio model (fixed base, ``nq == nv == 7``; its effort, velocity and
            position limits are the data sheet's).
        contact_frame_id: id in ``model.frames`` of the contact/tool frame (``"contact"``).
        joint_names: actuated joint names, in the order of q, v and τ.
        torque_limit: maximum absolute joint torque, N·m (the data sheet's).
        velocity_limit: maximum absolute joint velocity, rad/s (the data sheet's).
        position_lower, position_upper: joint position limits, rad (the data sheet's).
        q_nominal: a posture with the tool pointing down above a table, rad.
        urdf_path: URDF file the model was built from (the simulator loads the same file).
        flange_frame: name of the parent link of the contact frame (where PyBullet attaches tools).
        tool_placement: placement of the contact frame in the flange frame.
    """

    name: str
    model: pin.Model
    contact_frame_id: int
    joint_names: tuple[str, ...]
    torque_limit: np.ndarray
    velocity_limit: np.ndarray
    position_lower: np.ndarray
    position_upper: np.ndarray
    q_nominal: np.ndarray
    urdf_path: str
    flange_frame: str
    tool_placement: pin.SE3 = field(repr=False)

    @property
    def nq(self) -> int:
        """Size of the configuration q."""
        return self.model.nq

    @property
    def datasheet(self) -> DataSheet:
        """Every data-sheet limit of this robot (q̈, q⃛, τ̇ too, where published) and what its
        controller stops on (:mod:`ffmpc_core.datasheet`)."""
        return datasheet(self.name)

    @property
    def nv(self) -> int:
        """Size of the velocity q̇ (the number of joints)."""
        return self.model.nv

    def create_data(self) -> pin.Data:
        """A fresh pinocchio workspace for this model."""
        return self.model.createData()

    def contact_placement(self, q: np.ndarray, data: pin.Data | None = None) -> pin.SE3:
        """World placement of the contact frame at configuration ``q`` (m, world frame)."""
        data = data if data is not None else self.create_data()
        pin.framesForwardKinematics(self.model, data, q)
        return data.oMf[self.contact_frame_id].copy()

    def gravity(self, q: np.ndarray, data: pin.Data | None = None) -> np.ndarray:
        """Gravity torque g(q), N·m."""
        data = data if data is not None else self.create_data()
        return pin.computeGeneralizedGravity(self.model, data, q).copy()

    def state_limit_bounds(self, fraction: float) -> tuple[np.ndarray, np.ndarray]:
        """Bounds (lower, upper) on the state x = (q, v) of the joint-limit barrier cost, each of
        2·nv entries: q (rad) within ``fraction`` of the position range about its middle, for
        joints with finite position limits (±inf otherwise), and v (rad/s) within
        ±``fraction``·``velocity_limit`` (±inf for a joint without a finite velocity limit).

        ``fraction`` in (0, 1] (ConfigError otherwise): 0.9 leaves 10 % of each limit as margin.
        """
        fraction = float(fraction)
        if not (0.0 < fraction <= 1.0):  # also rejects NaN
            raise ConfigError(f"state_limit_fraction must be in (0, 1], got {fraction}")
        lower_q, upper_q = self.position_lower, self.position_upper
        finite_q = (
            np.isfinite(lower_q)
            & np.isfinite(upper_q)
            & (upper_q > lower_q)
            & (np.abs(lower_q) < _NO_LIMIT)
            & (np.abs(upper_q) < _NO_LIMIT)
        )
        middle = np.where(finite_q, 0.5 * (lower_q + upper_q), 0.0)
        half_range = np.where(finite_q, 0.5 * fraction * (upper_q - lower_q), np.inf)
        finite_v = np.isfinite(self.velocity_limit) & (self.velocity_limit < _NO_LIMIT)
        v_bound = np.where(finite_v, fraction * np.abs(self.velocity_limit), np.inf)
        lower = np.concatenate([middle - half_range, -v_bound])
        upper = np.concatenate([middle + half_range, v_bound])
        return lower, upper

    def clip_torque(self, tau: np.ndarray) -> np.ndarray:
        """Saturate a torque to the joint torque limits (N·m).

        A non-finite entry, or one beyond ``plausibility.COMMAND_TORQUE_FACTOR`` × its limit, raises
        InputError: such a torque is a fault (a diverged solver), never a command to saturate
        or to replace by 0 — the caller must stop the robot safely (``ffmpc_core.lowlevel``).
        """
        tau = check_torque(tau, self.torque_limit)
        return np.clip(tau, -self.torque_limit, self.torque_limit)


@dataclass(frozen=True)
class ToolLoad:
    """A rigid tool fixed to the flange, behind the wrist force/torque sensor (the robot's load
    data, as a robot controller is configured with it).

    Attributes:
        mass: kg (0: no tool).
        center_of_mass: m, in the flange (= sensor) frame.
        radius: m, the tool's rotational inertia is a solid sphere's of this radius about the
            centre of mass, 2/5·m·r² (the PyBullet plant's spherical tool).
    """

    mass: float = 0.0
    center_of_mass: tuple[float, float, float] = (0.0, 0.0, 0.0)
    radius: float = 0.01

    def __post_init__(self) -> None:
        com = np.asarray(self.center_of_mass, dtype=float)
        if not (np.isfinite(self.mass) and self.mass >= 0.0):
            raise ConfigError(f"tool mass must be finite and >= 0 kg, got {self.mass!r}")
        if com.shape != (3,) or not np.all(np.isfinite(com)):
            raise ConfigError(f"tool centre of mass must be 3 finite numbers (m), got {com}")
        if not (np.isfinite(self.radius) and self.radius > 0.0):
            raise ConfigError(f"tool radius must be > 0 m, got {self.radius!r}")

    def inertia(self) -> pin.Inertia:
        """The tool's spatial inertia about the flange frame origin, flange axes."""
        rotational = 0.4 * self.mass * self.radius**2 * np.eye(3)
        return pin.Inertia(self.mass, np.asarray(self.center_of_mass, float), rotational)


def with_tool_load(robot: RobotModel, load: ToolLoad) -> RobotModel:
    """``robot`` carrying ``load`` on its flange: a copy whose pinocchio model has the tool's
    inertia added to the flange's body (the model the controllers use when the cell is
    configured with this load; ``sim_bridge.plant.model_with_tool`` is the one PyBullet
    simulates). A massless load returns ``robot`` itself (the same model, bit for bit)."""
    if load.mass == 0.0:
        return robot
    model = pin.Model(robot.model)
    flange = model.frames[model.getFrameId(robot.flange_frame)]
    model.appendBodyToJoint(
        flange.parentJoint, flange.placement.act(load.inertia()), pin.SE3.Identity()
    )
    return replace(robot, model=model)


def _iiwa_urdf_path() -> str:
    import pybullet_data  # data-only package: no simulator is imported

    return os.path.join(pybullet_data.getDataPath(), "kuka_iiwa", "model.urdf")


def _add_contact_frame(model: pin.Model, parent_frame: str, placement: pin.SE3) -> int:
    parent_id = model.getFrameId(parent_frame)
    parent = model.frames[parent_id]
    frame = pin.Frame(
        CONTACT_FRAME,
        parent.parentJoint,
        parent_id,
        parent.placement * placement,
        pin.FrameType.OP_FRAME,
    )
    return model.addFrame(frame)


def _set_datasheet_limits(model: pin.Model, sheet: DataSheet) -> None:
    """The pinocchio model's effort, velocity and position limits from the data sheet."""
    model.effortLimit = sheet.torque.copy()
    model.velocityLimit = sheet.velocity.copy()
    model.lowerPositionLimit = sheet.position_lower.copy()
    model.upperPositionLimit = sheet.position_upper.copy()


def _load_iiwa() -> RobotModel:
    urdf = _iiwa_urdf_path()
    model = pin.buildModelFromUrdf(urdf)
    tool = pin.SE3(pin.utils.rotate("z", -np.pi / 4), np.array([0.0, 0.0, 0.10]))
    fid = _add_contact_frame(model, "lbr_iiwa_link_7", tool)
    sheet = datasheet("iiwa")
    _set_datasheet_limits(model, sheet)
    names = tuple(model.names[1:])
    return RobotModel(
        name="iiwa",
        model=model,
        contact_frame_id=fid,
        joint_names=names,
        torque_limit=sheet.torque.copy(),
        velocity_limit=sheet.velocity.copy(),
        position_lower=sheet.position_lower.copy(),
        position_upper=sheet.position_upper.copy(),
        q_nominal=np.array([0.0, 0.6, 0.0, -1.5, 0.0, 1.04, 0.0]),
        urdf_path=urdf,
        flange_frame="lbr_iiwa_link_7",
        tool_placement=tool,
    )


def _load_panda() -> RobotModel:
    import example_robot_data as erd

    robot = erd.load("panda")
    full = robot.model
    finger_ids = [full.getJointId(n) for n in ("panda_finger_joint1", "panda_finger_joint2")]
    q_full = robot.q0.copy()
    q_full[-2:] = 0.0
    model = pin.buildReducedModel(full, finger_ids, q_full)
    hand_tcp = model.getFrameId("panda_hand_tcp")
    parent = model.frames[hand_tcp]
    # The TCP frame is the contact frame; register it under the common name too.
    fid = model.addFrame(
        pin.Frame(
            CONTACT_FRAME,
            parent.parentJoint,
            hand_tcp,
            parent.placement,
            pin.FrameType.OP_FRAME,
        )
    )
    flange_id = model.getFrameId("panda_link8")
    tool = model.frames[flange_id].placement.inverse() * parent.placement
    sheet = datasheet("panda")
    _set_datasheet_limits(model, sheet)
    return RobotModel(
        name="panda",
        model=model,
        contact_frame_id=fid,
        joint_names=tuple(model.names[1:]),
        torque_limit=sheet.torque.copy(),
        velocity_limit=sheet.velocity.copy(),
        position_lower=sheet.position_lower.copy(),
        position_upper=sheet.position_upper.copy(),
        q_nominal=np.array([0.0, -0.785398, 0.0, -2.356194, 0.0, 1.570796, 0.785398]),
        urdf_path=robot.urdf,
        flange_frame="panda_link8",
        tool_placement=tool,
    )


_LOADERS = {"iiwa": _load_iiwa, "panda": _load_panda}
ROBOT_NAMES = tuple(_LOADERS)


def mass_matrix(model: pin.Model, data: pin.Data, q: np.ndarray) -> np.ndarray:
    """The joint-space mass matrix M(q) (kg·m², kg), symmetric, as a new array.

    ``pin.crba`` fills the upper triangle (the strict lower one is left as it was in
    ``data.M``); the upper triangle is mirrored here, so the result does not depend on that
    convention. Also computes what ``pin.crba`` computes into ``data``.
    """
    M = pin.crba(model, data, q)
    return np.triu(M) + np.triu(M, 1).T


def load_robot(name: str) -> RobotModel:
    """Load a robot model by name (``"iiwa"`` or ``"panda"``)."""
    try:
        loader = _LOADERS[name]
    except KeyError:
        raise ConfigError(f"unknown robot {name!r}; choose one of {ROBOT_NAMES}") from None
    robot = loader()
    if robot.nq != robot.nv or robot.nv != 7:
        raise ModelError(f"{name}: expected a 7-DoF fixed-base arm, got nq={robot.nq}")
    return robot
