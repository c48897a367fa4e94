"""Deformation dynamics (Dehio & Kheddar 2020, eq 3–8, appendix A, footnote 1)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from scipy.integrate import quad, solve_ivp

from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.impact.deformation import (
    SoftMaterial,
    continuous_deformation_dynamics,
    deformation_dynamics,
    deformation_force,
    discretize_deformation_closed_form,
    discretize_deformation_dynamics,
    effective_mass,
    simulate_deformation,
)
from ffmpc_core.robots import load_robot

CASES = [  # stiffness N/m, damping N·s/m, effective mass kg
    (2000.0, 50.0, 4.0),
    (300.0, 5.0, 2.5),
    (1.0e4, 200.0, 6.0),
    (5.0e4, 10.0, 3.0),  # lightly damped, fast oscillation (period ~50 ms vs Δt = 25 ms)
]


def _continuous_rhs(alpha: float, beta: float, lam: float, u: float):
    def rhs(_t, s):
        return [s[1], u - (alpha * s[0] + beta * s[1]) / lam]

    return rhs


@pytest.mark.parametrize(("alpha", "beta", "lam"), CASES)
def test_expm_discretisation_matches_fine_integration(alpha, beta, lam):
    rng = np.random.default_rng(7)
    dt = 0.025
    dyn = deformation_dynamics(alpha, beta, lam, dt)
    for _ in range(5):
        s = rng.normal(size=2) * np.array([0.01, 0.5])
        u = float(rng.normal() * 10.0)
        sol = solve_ivp(
            _continuous_rhs(alpha, beta, lam, u),
            (0.0, dt),
            s,
            method="DOP853",
            rtol=1e-12,
            atol=1e-14,
        )
        expected = sol.y[:, -1]
        got = dyn.A_d @ s + dyn.B_d[:, 0] * u
        np.testing.assert_allclose(got, expected, rtol=1e-8, atol=1e-11)


@pytest.mark.parametrize(("alpha", "beta", "lam"), CASES)
def test_acceleration_map_is_the_mean_acceleration_over_the_step(alpha, beta, lam):
    """Eq 8: z̈_i = C s_i + D u_i equals (1/Δt)∫ z̈(t) dt of the continuous model (eq 4–5),
    integrated by quadrature over a fine ODE solution, independently of A_d, B_d."""
    rng = np.random.default_rng(11)
    dt = 0.025
    dyn = deformation_dynamics(alpha, beta, lam, dt)
    for _ in range(3):
        s = rng.normal(size=2) * np.array([0.01, 0.5])
        u = float(rng.normal() * 10.0)
        sol = solve_ivp(
            _continuous_rhs(alpha, beta, lam, u),
            (0.0, dt),
            s,
            method="DOP853",
            rtol=1e-12,
            atol=1e-14,
            dense_output=True,
        )

        def acc(t, sol=sol, u=u):
            z, zd = sol.sol(t)
            return u - (alpha * z + beta * zd) / lam

        mean_acc = quad(acc, 0.0, dt, epsabs=1e-12, epsrel=1e-12, limit=200)[0] / dt
        got = float(dyn.C[0] @ s + dyn.D[0, 0] * u)
        assert got == pytest.approx(mean_acc, rel=1e-7, abs=1e-9)
        # and the appendix-A definition: finite difference of the exact velocities
        assert got == pytest.approx((sol.y[1, -1] - s[1]) / dt, rel=1e-7, abs=1e-9)


def test_force_and_simulation_are_consistent():
    dyn = deformation_dynamics(2000.0, 50.0, 4.0, 0.025)
    u = np.linspace(-20.0, 5.0, 10)
    states, acc, forces = simulate_deformation(dyn, np.array([0.0, 0.8]), u)
    assert states.shape == (11, 2) and acc.shape == (10,) and forces.shape == (11,)
    np.testing.assert_allclose(forces, deformation_force(2000.0, 50.0, states[:, 0], states[:, 1]))
    np.testing.assert_allclose(acc, np.diff(states[:, 1]) / 0.025, rtol=1e-12, atol=1e-12)
    # contact reaction decelerates: with u = 0 a penetrating state slows down
    s_next, _, _ = simulate_deformation(dyn, np.array([0.01, 0.5]), np.zeros(1))
    assert s_next[1, 1] < 0.5


def test_effective_mass_matches_the_response_to_a_force():
    """Footnote 1 against physics: push the contact frame with 1 N along d (ABA, v = 0, gravity
    compensated); the acceleration along d is 1/Λ."""
    robot = load_robot("panda")
    model, data = robot.model, robot.create_data()
    rng = np.random.default_rng(3)
    for _ in range(4):
        q = robot.q_nominal + rng.normal(scale=0.2, size=7)
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        lam = effective_mass(robot, q, d)
        J = pin.computeFrameJacobian(
            model, data, q, robot.contact_frame_id, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
        )
        tau = pin.computeGeneralizedGravity(model, data, q) + J[:3].T @ d
        qdd = pin.aba(model, data, q, np.zeros(7), tau)
        assert 1.0 / float(d @ J[:3] @ qdd) == pytest.approx(lam, rel=1e-9)
        assert 0.1 < lam < 50.0


def test_bad_input_is_rejected():
    with pytest.raises(ConfigError):
        deformation_dynamics(-1.0, 1.0, 1.0, 0.01)
    with pytest.raises(ConfigError):
        deformation_dynamics(1.0, 1.0, 0.0, 0.01)
    with pytest.raises(ConfigError):
        SoftMaterial(1000.0, 10.0, -0.01)
    robot = load_robot("panda")
    with pytest.raises(InputError):
        effective_mass(robot, robot.q_nominal, [0.0, 0.0, 2.0])
    with pytest.raises(InputError):
        effective_mass(robot, robot.q_nominal, [np.nan, 0.0, 1.0])
    dyn = deformation_dynamics(2000.0, 50.0, 4.0, 0.025)
    with pytest.raises(InputError):
        simulate_deformation(dyn, np.array([0.0, np.inf]), np.zeros(3))


def test_closed_form_discretisation_equals_expm():
    """Eq 6–7 in closed form (Cayley–Hamilton) against scipy's expm on seeded random materials
    and effective masses: under-, over- and critically damped, undamped, tiny and large Δt."""
    rng = np.random.default_rng(7)
    cases = [(2000.0, 2.0 * np.sqrt(2000.0 * 4.0), 4.0, 0.025), (3000.0, 0.0, 5.0, 0.025)]
    for _ in range(500):
        cases.append(
            (
                10 ** rng.uniform(1.0, 5.5),
                10 ** rng.uniform(-1.0, 3.5),
                10 ** rng.uniform(-0.5, 1.5),
                10 ** rng.uniform(-3.5, -1.0),
            )
        )
    for alpha, beta, lam, dt in cases:
        A_c, B_c = continuous_deformation_dynamics(alpha, beta, lam)
        A_ref, B_ref = discretize_deformation_dynamics(A_c, B_c, dt)
        A_d, B_d = discretize_deformation_closed_form(alpha, beta, lam, dt)
        np.testing.assert_allclose(A_d, A_ref, rtol=0, atol=1e-11 * np.abs(A_ref).max())
        np.testing.assert_allclose(B_d, B_ref, rtol=0, atol=1e-11 * np.abs(B_ref).max())
    with pytest.raises(ConfigError):
        discretize_deformation_closed_form(-1.0, 1.0, 1.0, 0.01)
