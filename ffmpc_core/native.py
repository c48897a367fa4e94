"""Native (C++) force-feedback OCP node: the interface of :mod:`ffmpc_core.soft_contact`.

:class:`IntegratedActionModelSoftContactNative` derives from the C++ class
``ffmpc_core._native.IntegratedActionModelSoftContact`` (``cpp/soft_contact.cpp``, a port of
:class:`ffmpc_core.soft_contact.IntegratedActionModelSoftContact`, which stays the readable
reference and is held equal to it by ``tests/test_native_soft_contact.py``). The solver calls the
C++ ``calc``/``calcDiff`` directly: no Python runs on the hot path. This class only converts the
arguments of the setters (scalars broadcast like the Python model's) and lets the C++ setters
validate them; bad values raise :class:`~ffmpc_core.errors.ConfigError` (configuration) or
:class:`~ffmpc_core.errors.InputError` (run-time references) and change nothing.

Same state, control, costs, frames and units as the Python model (see its docstrings): x =
[q (rad), v (rad/s), λ (N)], u = τ (N·m), residual layout :data:`RESIDUAL_TERMS`.
"""

from __future__ import annotations

from typing import Any

import crocoddyl  # noqa: F401  (registers the base classes the native module derives from)
import numpy as np
import numpy.typing as npt

import ffmpc_core._native as _native  # (this form lets mypy skip the compiled module)
from ffmpc_core.config import ContactConfig, CostWeights
from ffmpc_core.constraints import OcpBounds
from ffmpc_core.errors import ConfigError, FfmpcError, InputError
from ffmpc_core.robots import RobotModel
from ffmpc_core.soft_contact import (
    LOCAL_WORLD_ALIGNED,
    RESIDUAL_TERMS,
    SoftContactNode,
    check_soft_contact_robot,
    residual_slices,
)

__all__ = [
    "IntegratedActionModelSoftContactNative",
    "make_native_soft_contact_node",
]

_EMPTY = np.zeros(0)


def _vector(
    value: npt.ArrayLike, n: int, name: str, error: type[FfmpcError] = InputError
) -> np.ndarray:
    """``value`` as a float64 vector for the C++ setters; a scalar broadcasts to n entries.

    Sizes and finiteness are checked in C++ (same messages as the Python model)."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise error(f"{name} must be numeric, got {value!r}") from None
    if arr.ndim == 0:
        return np.full(n, float(arr))
    if arr.ndim != 1:
        raise error(f"{name} must have {n} entries, got shape {arr.shape}")
    return arr


def _scalar(value: Any, name: str, error: type[FfmpcError] = InputError) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        raise error(f"{name} must be a number, got {value!r}") from None


class IntegratedActionModelSoftContactNative(_native.IntegratedActionModelSoftContact):
    """One node of the force-feedback OCP in C++ (eq 24, costs eq 25 and 29).

    Same constructor and interface as the Python reference
    :class:`ffmpc_core.soft_contact.IntegratedActionModelSoftContact`
    (``set_reference_values``, ``set_contact_parameters``, ``set_in_contact``, ``set_weight``,
    ``weight``, ``residual_slice``, ``set_state_limit_bounds``, ``state_limit_lower``,
    ``state_limit_upper``, ``terminal``, ``dt``, ``nv``, ``nc``, ``ndx``,
    ``q_reference``, ``ee_position_reference``, ``force_reference``, ``rotation_reference``,
    ``in_contact``, control limits ``u_lb``/``u_ub``). References and parameters read back as
    copies; change them with the setters. ``data.dynamics`` exposes the dynamics workspace
    (``ddq``, ``force_rate``, ...). ``constraint_matrix``: the hard-constraint rows as the
    Python model's (:class:`ffmpc_core.constraints.ConstraintRows`: g = [S·x; u], bounds in
    ``g_lb``/``g_ub``).
    """

    def __init__(
        self,
        robot: RobotModel,
        contact: ContactConfig,
        weights: CostWeights,
        dt: float,
        terminal: bool = False,
        q_reference: np.ndarray | None = None,
        constraint_matrix: np.ndarray | None = None,
        control_scale: np.ndarray | None = None,
    ) -> None:
        dt = _scalar(dt, "dt", ConfigError)
        check_soft_contact_robot(robot)
        nx = 2 * robot.nv + int(contact.dimension)
        matrix = np.zeros((0, nx)) if constraint_matrix is None else constraint_matrix
        super().__init__(
            robot.model,
            int(robot.contact_frame_id),
            int(contact.dimension),
            contact.frame_type == LOCAL_WORLD_ALIGNED,
            int(contact.normal_axis),
            dt,
            bool(terminal),
            np.asarray(matrix, dtype=np.float64),
            np.ones(robot.nv) if control_scale is None else np.asarray(control_scale, np.float64),
        )
        nv, nc = self.nv, self.nc
        self._slices = residual_slices(nv, nc)
        self.robot = robot
        self.contact = contact
        self.weights = weights
        self.u_lb = -robot.torque_limit
        self.u_ub = robot.torque_limit.copy()
        for name in RESIDUAL_TERMS:
            # No activation diagonal in CostWeights (identity activations in C++).
            if name not in ("force_rate", "state_limit", "ee_rotation", "ee_angular_velocity"):
                rows = self._slices[name]
                self.set_activation(name, weights.diag(name, rows.stop - rows.start))
            self.set_weight(name, getattr(weights, name))
        self.set_state_limit_bounds(*robot.state_limit_bounds(weights.state_limit_fraction))
        q_ref = robot.q_nominal if q_reference is None else q_reference
        self._set_q_reference(_vector(q_ref, nv, "q_reference", ConfigError))
        # R̄ of the orientation cost: the contact frame's orientation at the construction-time q̄.
        self._set_rotation_reference(robot.contact_placement(self.q_reference).rotation.copy())
        self._set_reference_values(
            robot.contact_placement(self.q_reference).translation.copy(),
            np.zeros(nc),
            weights.ee_position,
            weights.force,
            True,
            _EMPTY,
            _EMPTY,
        )
        self.set_contact_parameters(contact.stiffness_vector(), contact.damping_vector())

    # ------------------------------------------------------------ parameters
    def residual_slice(self, name: str) -> slice:
        """Rows of term ``name`` (see :data:`RESIDUAL_TERMS`) in ``data.r``."""
        return self._slices[name]

    def set_reference_values(
        self,
        ee_position: np.ndarray,
        force: np.ndarray,
        ee_position_weight: float,
        force_weight: float,
        in_contact: bool,
        posture: np.ndarray | None = None,
        ee_position_diag: np.ndarray | None = None,
    ) -> None:
        """Update p̄ (m, world), λ̄ (N, force frame), c4, c6, the contact flag, q̄ (rad) and Q4.

        ``ee_position_diag``: the activation Q4 of the end-effector position cost (3 entries,
        world axes, ≥ 0); None restores ``CostWeights.ee_position_diag``. ``posture`` None keeps
        q̄. Out of contact K = B = 0 and c6 = 0 for this node. Nothing changes when any value is
        invalid (InputError).
        """
        q4 = None if ee_position_diag is None else _vector(ee_position_diag, 3, "ee_position_diag")
        self._set_reference_values(
            _vector(ee_position, 3, "ee_position"),
            _vector(force, 1, "force"),  # like np.atleast_1d: a scalar is one entry
            _scalar(ee_position_weight, "ee_position_weight"),
            _scalar(force_weight, "force_weight"),
            bool(in_contact),
            _EMPTY if posture is None else _vector(posture, self.nv, "posture"),
            _EMPTY if q4 is None else q4,
        )

    def set_contact_parameters(self, stiffness: npt.ArrayLike, damping: npt.ArrayLike) -> None:
        """Nominal K (N/m) and B (N·s/m), scalar or per force axis; applied in place."""
        self._set_contact_parameters(
            _vector(stiffness, self.nc, "stiffness", ConfigError),
            _vector(damping, self.nc, "damping", ConfigError),
        )

    def set_weight(self, name: str, value: float) -> None:
        """Set the scalar weight c of term ``name`` (in place)."""
        super().set_weight(str(name), _scalar(value, f"weight {name}", ConfigError))

    def set_state_limit_bounds(self, lower: npt.ArrayLike, upper: npt.ArrayLike) -> None:
        """Bounds of the joint-limit barrier on (q, v): 2·nv entries each (rad, then rad/s),
        lower ≤ upper, no NaN (±inf: no bound); ConfigError changes nothing."""
        n = 2 * self.nv
        self._set_state_limit_bounds(
            _vector(lower, n, "state-limit lower bounds", ConfigError),
            _vector(upper, n, "state-limit upper bounds", ConfigError),
        )


def make_native_soft_contact_node(
    robot: RobotModel,
    contact: ContactConfig,
    weights: CostWeights,
    dt: float,
    terminal: bool,
    q_reference: np.ndarray | None = None,
    bounds: OcpBounds | None = None,
) -> SoftContactNode:
    """Build a native force-feedback node (running or terminal) with Δt in s.

    Same initial references and constraints (``bounds``) as
    :func:`ffmpc_core.soft_contact.make_soft_contact_node`.
    """
    matrix = None if bounds is None else bounds.state_matrix
    scale = None if bounds is None else bounds.control_scale
    model = IntegratedActionModelSoftContactNative(
        robot, contact, weights, dt, terminal, q_reference, matrix, scale
    )
    return SoftContactNode(model, bounds)
