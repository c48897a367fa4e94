"""The MuJoCo plant's contact forces (sim_bridge.contact_forces): Bullet's combination rules,
the spring–damper normal force, and Coulomb friction at the end of the step against the
maximal-dissipation optimum."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import minimize

from sim_bridge.contact_forces import (
    BULLET_DEFAULT_MATERIAL,
    ContactMaterial,
    combine_materials,
    coulomb_friction,
    friction_disc,
    normal_force,
)

STEP = 1e-3  # s


def test_materials_combine_as_bullet_combines_them():
    table = ContactMaterial(1e4, 1e2, 0.5)
    tool = ContactMaterial(1e9, 0.0, 1.0)
    both = combine_materials(tool, table)
    assert both.stiffness == pytest.approx(1.0 / (1e-4 + 1e-9), rel=1e-15)  # series
    assert both.damping == 1e2 and both.friction == 0.5  # summed, multiplied
    link = combine_materials(BULLET_DEFAULT_MATERIAL, table)  # a rigid link passes K through
    assert link.stiffness == 1e4 and link.damping == pytest.approx(100.1)
    assert link.friction == 0.25
    rigid = combine_materials(BULLET_DEFAULT_MATERIAL, BULLET_DEFAULT_MATERIAL)
    assert math.isinf(rigid.stiffness)


def test_normal_force_is_the_spring_damper_and_never_pulls():
    assert normal_force(1e4, 1e2, 5e-3, 0.0) == pytest.approx(50.0)
    assert normal_force(1e4, 1e2, 5e-3, 0.1) == pytest.approx(60.0)
    assert normal_force(1e4, 1e2, 1e-3, -0.5) == 0.0  # separating fast: no adhesion
    assert normal_force(1e4, 1e2, -1e-3, 0.0) == 0.0


def _random_problem(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A tangential inverse inertia 2n×2n (1/kg), slips (m/s) and bounds (N)."""
    jac = rng.normal(size=(2 * n, 7))
    inverse_mass = np.linalg.inv(np.diag(rng.uniform(0.2, 3.0, 7)))
    return jac @ inverse_mass @ jac.T, rng.normal(0.0, 0.05, 2 * n), rng.uniform(1.0, 30.0, n)


def _objective(inverse_inertia, slip):
    return lambda f: 0.5 * STEP * f @ inverse_inertia @ f + f @ slip


@pytest.mark.parametrize("seed", range(6))
def test_one_contact_sticks_or_slides_against_the_final_slip(seed):
    rng = np.random.default_rng(seed)
    inverse_inertia, slip, bounds = _random_problem(rng, 1)
    for scale in (1e-3, 1.0, 30.0):  # from sticking to sliding
        u = scale * slip
        f = friction_disc(inverse_inertia, u, float(bounds[0]), STEP)
        final = u + STEP * inverse_inertia @ f
        if np.linalg.norm(f) < bounds[0] * (1 - 1e-9):  # inside the disc: the slip stops
            assert np.allclose(final, 0.0, atol=1e-12)
        else:  # on the disc: |f| = μλ, anti-parallel to the slip at the end of the step
            assert np.linalg.norm(f) == pytest.approx(bounds[0], rel=1e-9)
            cosine = f @ final / (np.linalg.norm(f) * np.linalg.norm(final))
            assert cosine == pytest.approx(-1.0, abs=1e-9)
        # and it is the maximal-dissipation optimum (a general solver agrees to its tolerance)
        objective = _objective(inverse_inertia, u)
        constraint = {"type": "ineq", "fun": lambda x, b=bounds[0]: b**2 - x @ x}
        ref = minimize(objective, np.zeros(2), constraints=[constraint])
        assert objective(f) <= objective(ref.x) + 1e-8 * abs(objective(ref.x)) + 1e-12


def test_sticking_needs_the_force_that_stops_the_slip_and_none_without_slip():
    inverse_inertia = np.array([[2.0, 0.3], [0.3, 0.5]])
    slip = np.array([0.01, -0.02])
    stop = -np.linalg.solve(STEP * inverse_inertia, slip)
    assert np.allclose(friction_disc(inverse_inertia, slip, 1e3, STEP), stop)
    assert np.allclose(friction_disc(inverse_inertia, np.zeros(2), 10.0, STEP), 0.0)
    assert np.allclose(friction_disc(inverse_inertia, slip, 0.0, STEP), 0.0)


def test_a_direction_no_force_can_move_does_not_break_the_solve():
    """A singular inverse inertia (the slip along its null direction cannot be stopped): the
    force stays on the disc and finite."""
    inverse_inertia = np.array([[1.0, 0.0], [0.0, 0.0]])
    f = friction_disc(inverse_inertia, np.array([0.0, 0.3]), 5.0, STEP)
    assert np.all(np.isfinite(f)) and np.linalg.norm(f) == pytest.approx(5.0, rel=1e-9)
    assert f[1] < 0.0  # opposes the slip


@pytest.mark.parametrize("seed", range(4))
def test_several_contacts_reach_the_joint_optimum(seed):
    """Block Gauss–Seidel over 3 coupled contacts: each block satisfies its own conditions at
    the end and the total dissipation equals a general solver's optimum."""
    rng = np.random.default_rng(100 + seed)
    inverse_inertia, slip, bounds = _random_problem(rng, 3)
    slip *= 5.0  # some contacts slide
    f, converged = coulomb_friction(inverse_inertia, slip, bounds, STEP)
    assert converged
    final = slip + STEP * inverse_inertia @ f
    for i, bound in enumerate(bounds):
        fi, ui = f[2 * i : 2 * i + 2], final[2 * i : 2 * i + 2]
        assert np.linalg.norm(fi) <= bound * (1 + 1e-9)
        if np.linalg.norm(fi) < bound * (1 - 1e-6):
            assert np.linalg.norm(ui) < 1e-6
        else:
            assert fi @ ui <= 0.0
    constraints = [
        {
            "type": "ineq",
            "fun": lambda x, i=i, b=b: b**2 - x[2 * i : 2 * i + 2] @ x[2 * i : 2 * i + 2],
        }
        for i, b in enumerate(bounds)
    ]
    objective = _objective(inverse_inertia, slip)
    ref = minimize(objective, np.zeros(6), constraints=constraints, options={"ftol": 1e-14})
    assert objective(f) <= objective(ref.x) + 1e-6 * abs(objective(ref.x))


def test_no_contact_and_no_bound_give_no_friction():
    forces, converged = coulomb_friction(np.zeros((0, 0)), np.zeros(0), np.zeros(0), STEP)
    assert forces.shape == (0,) and converged
    inverse_inertia, slip, _ = _random_problem(np.random.default_rng(0), 2)
    forces, converged = coulomb_friction(inverse_inertia, slip, np.zeros(2), STEP)
    assert np.allclose(forces, 0.0) and converged


def test_unconverged_sweeps_still_give_admissible_forces():
    """One sweep on 4 coupled contacts does not converge; the forces stay in their discs and
    dissipate (lower objective than no friction)."""
    inverse_inertia, slip, bounds = _random_problem(np.random.default_rng(7), 4)
    forces, converged = coulomb_friction(inverse_inertia, slip, bounds, STEP, max_sweeps=1)
    assert not converged
    for i, bound in enumerate(bounds):
        assert np.linalg.norm(forces[2 * i : 2 * i + 2]) <= bound * (1 + 1e-12)
    assert _objective(inverse_inertia, slip)(forces) < 0.0
