"""Start-up self-check: installed versions, and crocoddyl's dynamics against ``pin.aba``.

DESIGN.md records that pin 4.1.0 with crocoddyl 3.2.1 gives free-dynamics accelerations 29 rad/s²
off with ``pip check`` clean. :func:`check_crocoddyl_dynamics` catches that class of breakage: it
builds crocoddyl's free forward-dynamics model and compares its acceleration with ``pin.aba`` on
random states. The controllers call it once at start-up.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import metadata

import crocoddyl
import numpy as np
import pinocchio as pin

from ffmpc_core.errors import SelfCheckError
from ffmpc_core.robots import RobotModel

#: Exact versions DESIGN.md requires (other combinations are known to compute wrong dynamics).
REQUIRED_VERSIONS = {
    "pin": "4.0.0",
    "crocoddyl": "3.2.1",
    "mim-solvers": "0.3.0",
    "example-robot-data": "5.0.0",
}
REPORTED_PACKAGES = (
    *REQUIRED_VERSIONS,
    "numpy",
    "scipy",
    "osqp",
    "daqp",
    "pybullet",
    "mujoco",
    "mcap",
    "mcap-ros2-support",
    "rosbags",
    "ros-jazzy-rclpy",
)


def installed_versions() -> dict[str, str | None]:
    """Installed distribution versions of the packages ffmpc relies on (None if missing)."""
    out: dict[str, str | None] = {}
    for name in REPORTED_PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


def version_mismatches() -> dict[str, tuple[str | None, str]]:
    """Packages whose installed version differs from the required pin: name -> (found, wanted)."""
    found = installed_versions()
    return {k: (found[k], v) for k, v in REQUIRED_VERSIONS.items() if found[k] != v}


@dataclass(frozen=True)
class DynamicsCheck:
    """Result of a check: worst error (:func:`check_crocoddyl_dynamics`: acceleration error,
    rad/s²; :func:`check_native_soft_contact`: relative difference, dimensionless)."""

    robot: str
    max_error: float
    tolerance: float
    samples: int

    @property
    def ok(self) -> bool:
        """Whether the largest error is within the tolerance."""
        return bool(self.max_error <= self.tolerance)


def check_crocoddyl_dynamics(
    robot: RobotModel,
    rng: np.random.Generator,
    samples: int = 10,
    tolerance: float = 1e-6,
    crocoddyl_model: pin.Model | None = None,
) -> DynamicsCheck:
    """Compare crocoddyl's free forward dynamics with ``pin.aba`` on random states.

    Args:
        robot: the reference model; ``pin.aba`` runs on ``robot.model``.
        rng: source of the random states (q within the joint limits, |v| ≤ 1 rad/s,
            |τ| ≤ 20 % of the torque limits).
        samples: number of random states.
        tolerance: largest acceptable |q̈_crocoddyl − q̈_aba|, rad/s².
        crocoddyl_model: the pinocchio model crocoddyl is built on (default: ``robot.model``).
            Tests pass a deliberately wrong one to prove the check can fail.
    """
    croc_pin = robot.model if crocoddyl_model is None else crocoddyl_model
    state = crocoddyl.StateMultibody(croc_pin)
    actuation = crocoddyl.ActuationModelFull(state)
    costs = crocoddyl.CostModelSum(state, actuation.nu)
    dam = crocoddyl.DifferentialActionModelFreeFwdDynamics(state, actuation, costs)
    dad = dam.createData()
    ref_data = robot.create_data()
    worst = 0.0
    for _ in range(samples):
        q = rng.uniform(robot.position_lower, robot.position_upper)
        v = rng.uniform(-1.0, 1.0, robot.nv)
        tau = rng.uniform(-0.2, 0.2) * robot.torque_limit
        dam.calc(dad, np.concatenate([q, v]), tau)
        ref = pin.aba(robot.model, ref_data, q, v, tau)
        worst = max(worst, float(np.max(np.abs(dad.xout - ref))))
    return DynamicsCheck(robot.name, worst, tolerance, samples)


def check_native_soft_contact(
    robot: RobotModel,
    rng: np.random.Generator,
    samples: int = 10,
    tolerance: float = 1e-9,
) -> DynamicsCheck:
    """Compare the native (C++) force-feedback node with the Python reference on random states.

    Worst relative difference of x⁺ and Fx (1-D and 3-D contact, LOCAL_WORLD_ALIGNED), which
    catches a C++ module built against other pinocchio/crocoddyl binaries than the ones loaded.
    States: q within the joint limits, |v| ≤ 1 rad/s, |λ| ≤ 20 N, |τ| ≤ 20 % of the limits.
    """
    from ffmpc_core.config import ContactConfig, CostWeights
    from ffmpc_core.native import IntegratedActionModelSoftContactNative
    from ffmpc_core.soft_contact import IntegratedActionModelSoftContact

    worst = 0.0
    for dim in (1, 3):
        contact = ContactConfig(dimension=dim)
        pair = [
            cls(robot, contact, CostWeights(), 0.003)
            for cls in (IntegratedActionModelSoftContact, IntegratedActionModelSoftContactNative)
        ]
        datas = [m.createData() for m in pair]
        for _ in range(samples):
            x = np.concatenate(
                [
                    rng.uniform(robot.position_lower, robot.position_upper),
                    rng.uniform(-1.0, 1.0, robot.nv),
                    rng.uniform(-20.0, 20.0, dim),
                ]
            )
            u = rng.uniform(-0.2, 0.2) * robot.torque_limit
            for model, data in zip(pair, datas, strict=True):
                model.calc(data, x, u)
                model.calcDiff(data, x, u)
            for name in ("xnext", "Fx"):
                ref, nat = np.asarray(getattr(datas[0], name)), np.asarray(getattr(datas[1], name))
                scale = max(1.0, float(np.max(np.abs(ref))))
                worst = max(worst, float(np.max(np.abs(nat - ref))) / scale)
    return DynamicsCheck(robot.name, worst, tolerance, 2 * samples)


def require_sound_dynamics(robot: RobotModel, rng: np.random.Generator | None = None) -> None:
    """Raise :class:`SelfCheckError` unless crocoddyl agrees with ``pin.aba`` for ``robot``."""
    result = check_crocoddyl_dynamics(robot, rng or np.random.default_rng(0))
    if not result.ok:
        raise SelfCheckError(
            f"crocoddyl free dynamics disagree with pin.aba on {robot.name}: "
            f"{result.max_error:.3g} rad/s² > {result.tolerance:g}. Check the pins in "
            f"pyproject.toml (pin==4.0.0 with crocoddyl==3.2.1); found {installed_versions()}"
        )
