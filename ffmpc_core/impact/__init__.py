"""Safe maximal impacts on soft contacts (Dehio & Kheddar 2020): the math core.

Modules:
    deformation: eq 3–8 (deformation dynamics, effective mass, discretisation, acceleration map).
    limits: eq 1, 2, 9–11 (joint limits mapped to the contact space).
    planner: eq 12–14 (penetration QP, maximal pre-impact velocity; DAQP, OSQP reference).
    learner: eq 15–21 (batch and recursive least squares, exploration reference).
    control: Sec. IV-C (the controller: approach at the maximal safe speed, then admittance).
    controllers: Sec. VI's experiment as controller objects (admittance regulator, baseline
        approach, hand-over to the force-feedback MPC, the whole run's control).
    exploration: Sec. V–VI's exploration (guarded approach, exploration motion, learning).
    robust: eq 14 over an interval of materials (the prior's plausible range, or the learner's
        confidence interval) and the infeasible-force-target check.
    touch_first: learn before striking hard: a touch safe for every plausible material, the
        learner's interval, then the maximal strike (or a refusal of the target).
    strike_first: the first contact is the task's impact, at the bound safe for every material
        still plausible; the target decided in contact from the learned interval.
    memory: what a run learned about an object, kept for the next run on it.
    task_space: a task-space inverse-dynamics law from the Cartesian command to joint torques.

Sign convention of the package: the deformation ``z`` and the pressing force ``f`` are positive
along the unit motion direction ``d`` (world frame); see :mod:`.deformation`.
"""

from ffmpc_core.impact.control import (
    AdmittanceForceController,
    CartesianCommand,
    ImpactController,
    ImpactControllerConfig,
    ImpactMeasurement,
)
from ffmpc_core.impact.deformation import (
    DeformationDynamics,
    SoftMaterial,
    acceleration_map,
    continuous_deformation_dynamics,
    deformation_dynamics,
    deformation_force,
    discretize_deformation_closed_form,
    discretize_deformation_dynamics,
    effective_mass,
    simulate_deformation,
)
from ffmpc_core.impact.learner import (
    ContactEstimate,
    RecursiveContactLearner,
    exploration_reference,
    fit_stiffness_damping,
)
from ffmpc_core.impact.limits import (
    PANDA_ACCELERATION_LIMIT,
    ContactSpaceBounds,
    ContactSpaceMapper,
    JointLimits,
    joint_limits,
)
from ffmpc_core.impact.planner import ImpactPlanner, PenetrationPlan, PlannerConfig
from ffmpc_core.impact.robust import (
    MaterialInterval,
    RobustImpactPlanner,
    check_force_target,
    steady_penetration,
)
from ffmpc_core.impact.strike_first import StrikeFirstConfig, StrikeFirstImpactController
from ffmpc_core.impact.task_space import TaskSpaceGains, TaskSpaceInverseDynamics
from ffmpc_core.impact.touch_first import TouchFirstConfig, TouchFirstImpactController

__all__ = [
    "PANDA_ACCELERATION_LIMIT",
    "AdmittanceForceController",
    "CartesianCommand",
    "ContactEstimate",
    "ContactSpaceBounds",
    "ContactSpaceMapper",
    "DeformationDynamics",
    "ImpactController",
    "ImpactControllerConfig",
    "ImpactMeasurement",
    "ImpactPlanner",
    "JointLimits",
    "MaterialInterval",
    "PenetrationPlan",
    "PlannerConfig",
    "RecursiveContactLearner",
    "RobustImpactPlanner",
    "SoftMaterial",
    "StrikeFirstConfig",
    "StrikeFirstImpactController",
    "TaskSpaceGains",
    "TaskSpaceInverseDynamics",
    "TouchFirstConfig",
    "TouchFirstImpactController",
    "acceleration_map",
    "check_force_target",
    "continuous_deformation_dynamics",
    "deformation_dynamics",
    "deformation_force",
    "discretize_deformation_closed_form",
    "discretize_deformation_dynamics",
    "effective_mass",
    "exploration_reference",
    "fit_stiffness_damping",
    "joint_limits",
    "simulate_deformation",
    "steady_penetration",
]
