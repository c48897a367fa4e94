"""Joint limits mapped to the contact space (Dehio & Kheddar 2020, eq 2, 9–11)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import null_space

from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.impact.limits import (
    PANDA_ACCELERATION_LIMIT,
    ContactSpaceMapper,
    acceleration_force_vertices,
    deformation_velocity_bounds,
    deformation_velocity_bounds_closed_form,
    halfplanes_from_support_points,
    halfplanes_from_vertices,
    joint_limits,
    motion_basis,
    position_aware_velocity_limits,
    velocity_lp_data,
    vertex_directions,
    vertex_lp_data,
)
from ffmpc_core.robots import load_robot

DOWN = np.array([0.0, 0.0, -1.0])
SOLVERS = ("daqp", "osqp")


@pytest.fixture(scope="module")
def panda():
    robot = load_robot("panda")
    return robot, joint_limits(robot)


def _states(robot, n, seed):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        q = robot.q_nominal + rng.normal(scale=0.15, size=7)
        v = rng.normal(scale=0.3, size=7)
        yield q, v


def test_motion_basis_is_orthonormal_with_d_first():
    rng = np.random.default_rng(0)
    for d in [DOWN, np.array([1.0, 0.0, 0.0]), *rng.normal(size=(3, 3))]:
        d = d / np.linalg.norm(d)
        basis = motion_basis(d)
        np.testing.assert_allclose(basis.T @ basis, np.eye(6), atol=1e-12)
        np.testing.assert_allclose(basis[:3, 0], d, atol=1e-12)
        np.testing.assert_allclose(basis[3:, 0], 0.0)


@pytest.mark.parametrize("solver", SOLVERS)
def test_velocity_lp_against_brute_force_grid(panda, solver):
    """Eq 9: the LP's extremes bound every sampled feasible joint velocity and are attained up to
    the grid resolution. Samples: q̇ = N a on a grid of a, N an orthonormal basis of ker J_B."""
    robot, limits = panda
    mapper = ContactSpaceMapper(robot, limits, DOWN, solver=solver)
    for q, v in _states(robot, 3, seed=1):
        bounds = mapper.update(q, v)
        kin = mapper.kinematics(q, v)
        lower, upper = position_aware_velocity_limits(q, limits)
        ref = deformation_velocity_bounds(velocity_lp_data(kin["J_A"], kin["J_B"], lower, upper))
        assert bounds.velocity_lower == pytest.approx(ref[0], abs=1e-7)
        assert bounds.velocity_upper == pytest.approx(ref[1], abs=1e-7)

        N = null_space(kin["J_B"])  # 7×2
        reach = float(np.linalg.norm(np.maximum(-lower, upper)))
        grid = np.linspace(-reach, reach, 801)
        step = grid[1] - grid[0]
        a = np.stack(np.meshgrid(grid, grid), axis=-1).reshape(-1, 2)
        qd = a @ N.T
        ok = np.all((qd >= lower) & (qd <= upper), axis=1)
        zd = qd[ok] @ kin["J_A"]
        gain = float(np.linalg.norm(kin["J_A"] @ N))
        assert zd.max() <= bounds.velocity_upper + 1e-9
        assert zd.min() >= bounds.velocity_lower - 1e-9
        assert zd.max() >= bounds.velocity_upper - 2 * gain * step
        assert zd.min() <= bounds.velocity_lower + 2 * gain * step


@pytest.mark.parametrize("solver", SOLVERS)
def test_vertex_lps_against_sampling_and_highs(panda, solver):
    """Eq 10/11: DAQP's and OSQP's vertices equal HiGHS's; no sampled feasible (q̈, f) beats a
    vertex in its weight direction; every vertex satisfies the eq 11 half-planes."""
    robot, limits = panda
    mapper = ContactSpaceMapper(robot, limits, DOWN, n_directions=8, solver=solver)
    rng = np.random.default_rng(5)
    for q, v in _states(robot, 3, seed=2):
        bounds = mapper.update(q, v)
        kin = mapper.kinematics(q, v)
        lp = vertex_lp_data(
            kin["J_A"], kin["J_B"], kin["drift_A"], kin["drift_B"], kin["M"], kin["h"], limits
        )
        weights = vertex_directions(8, bounds.effective_mass)
        np.testing.assert_allclose(
            bounds.vertices, acceleration_force_vertices(lp, weights), atol=1e-6
        )
        P, p = bounds.halfplane_normals, bounds.halfplane_offsets
        assert np.all(bounds.vertices @ P.T <= p + 1e-6)  # the closed-form eq 11 merges ≤ 1e-7

        # Brute force: q̈ = q̈_p + N a satisfies the equality rows; sample a and f, keep feasible.
        n = 7
        A_eq = lp.A_eq[:, :n]
        qdd_p = np.linalg.lstsq(A_eq[:5], lp.b_eq[:5], rcond=None)[0]
        N = null_space(A_eq[:5])
        m = 200_000
        a = rng.uniform(-30.0, 30.0, size=(m, N.shape[1]))
        f = rng.uniform(0.0, 400.0, size=m)
        qdd = qdd_p + a @ N.T
        zdd = qdd @ kin["J_A"] + kin["drift_A"]
        torque = qdd @ kin["M"].T + f[:, None] * kin["J_A"]
        ok = np.all(np.abs(qdd) <= limits.acceleration, axis=1)
        ok &= np.all((torque >= lp.lower[n : 2 * n]) & (torque <= lp.upper[n : 2 * n]), axis=1)
        assert ok.sum() > 100
        pts = np.column_stack([zdd[ok], f[ok]])
        support = pts @ weights.T  # samples × directions
        best = np.einsum("kj,kj->k", bounds.vertices, weights)
        assert np.all(support.max(axis=0) <= best + 1e-9)
        # sampled points lie in the hull up to the inner-approximation gap (small)
        gap = (pts @ P.T - p).max()
        assert gap < 0.5  # m/s² in the scaled plane


def test_position_limits_shrink_the_velocity_bounds(panda):
    robot, limits = panda
    q = robot.q_nominal.copy()
    lo, up = position_aware_velocity_limits(q, limits)
    np.testing.assert_allclose(up, limits.velocity)  # far from the limits: data-sheet values
    q[3] = limits.position_upper[3] - 1e-3
    lo, up = position_aware_velocity_limits(q, limits)
    assert up[3] == pytest.approx(np.sqrt(2 * limits.acceleration[3] * 1e-3))
    assert lo[3] == -limits.velocity[3]


def test_limits_configuration_and_inputs():
    iiwa = load_robot("iiwa")
    with pytest.raises(ConfigError):
        joint_limits(iiwa)
    lim = joint_limits(iiwa, acceleration_limit=np.full(7, 10.0))
    assert lim.acceleration.shape == (7,)
    panda = load_robot("panda")
    np.testing.assert_allclose(joint_limits(panda).acceleration, PANDA_ACCELERATION_LIMIT)
    mapper = ContactSpaceMapper(panda, joint_limits(panda), DOWN)
    with pytest.raises(InputError):
        mapper.update(np.full(7, np.nan), np.zeros(7))
    with pytest.raises(InputError):
        mapper.update(panda.q_nominal, np.zeros(6))
    with pytest.raises(InputError):
        ContactSpaceMapper(panda, joint_limits(panda), [0.0, 0.0, 0.5])
    with pytest.raises(ConfigError):
        ContactSpaceMapper(panda, joint_limits(panda), DOWN, solver="highs")


def _random_states(robot, limits, n, seed):
    """Seeded random states, a third of them with a joint within 1e-3 rad of a position limit
    (its velocity bound towards the limit then nearly 0)."""
    rng = np.random.default_rng(seed)
    for k in range(n):
        q = robot.q_nominal + rng.normal(scale=0.3, size=7)
        q = np.clip(q, limits.position_lower + 1e-3, limits.position_upper - 1e-3)
        if k % 3 == 0:
            j = rng.integers(7)
            q[j] = limits.position_upper[j] - 1e-4 if k % 2 else limits.position_lower[j] + 1e-4
        yield q, rng.normal(scale=0.4, size=7)


def test_closed_form_eq9_equals_highs_on_random_states(panda):
    """Eq 9 in closed form (Fourier–Motzkin on the task null space) against the HiGHS LPs, to
    HiGHS's primal feasibility tolerance (1e-7), on 60 Panda states; and a 6-joint case."""
    robot, limits = panda
    mapper = ContactSpaceMapper(robot, limits, DOWN)
    for q, v in _random_states(robot, limits, 60, seed=21):
        kin = mapper.kinematics(q, v)
        lower, upper = position_aware_velocity_limits(q, limits)
        got = deformation_velocity_bounds_closed_form(kin["J_A"], kin["J_B"], lower, upper)
        ref = deformation_velocity_bounds(velocity_lp_data(kin["J_A"], kin["J_B"], lower, upper))
        assert got is not None
        np.testing.assert_allclose(got, ref, atol=1e-7)
    rng = np.random.default_rng(22)
    for _ in range(20):  # 6 joints: no null space, q̇ = c ż
        J = rng.normal(size=(6, 6))
        lower, upper = -rng.uniform(0.5, 2.0, 6), rng.uniform(0.5, 2.0, 6)
        got = deformation_velocity_bounds_closed_form(J[0], J[1:], lower, upper)
        ref = deformation_velocity_bounds(velocity_lp_data(J[0], J[1:], lower, upper))
        np.testing.assert_allclose(got, ref, atol=1e-7)
    # Rank-deficient J: no closed form, the caller falls back to the LP.
    J = rng.normal(size=(6, 7))
    J[5] = J[4]
    assert (
        deformation_velocity_bounds_closed_form(J[0], J[1:], lower[:1].repeat(7), 1.0 + 0 * J[0])
        is None
    )


@pytest.mark.parametrize("solver", SOLVERS)
def test_mappers_equal_the_highs_references_on_random_states(panda, solver):
    """Both mappers give HiGHS's eq 9 bounds (1e-7) and eq 10 optima ``ω·(z̈, f)`` (1e-6
    relative; the vertex itself is not unique when ω is normal to an edge), with no fallback
    for DAQP, on seeded random states including near-position-limit ones."""
    robot, limits = panda
    mapper = ContactSpaceMapper(robot, limits, DOWN, n_directions=8, solver=solver)
    for q, v in _random_states(robot, limits, 30, seed=23):
        bounds = mapper.update(q, v)
        kin = mapper.kinematics(q, v)
        lower, upper = position_aware_velocity_limits(q, limits)
        ref = deformation_velocity_bounds(velocity_lp_data(kin["J_A"], kin["J_B"], lower, upper))
        np.testing.assert_allclose([bounds.velocity_lower, bounds.velocity_upper], ref, atol=1e-7)
        lp = vertex_lp_data(
            kin["J_A"], kin["J_B"], kin["drift_A"], kin["drift_B"], kin["M"], kin["h"], limits
        )
        weights = vertex_directions(8, bounds.effective_mass)
        ref_vertices = acceleration_force_vertices(lp, weights)
        got = np.einsum("kj,kj->k", bounds.vertices, weights)
        want = np.einsum("kj,kj->k", ref_vertices, weights)
        np.testing.assert_allclose(got, want, atol=1e-6 * (1.0 + np.abs(want).max()))
    if solver == "daqp":
        assert mapper.stats["highs_fallbacks"] == 0 and mapper.stats["qhull_fallbacks"] == 0


def test_closed_form_eq11_equals_qhull(panda):
    """The half-planes from the ordered support points are Qhull's: every one of them is a Qhull
    row, and both sets contain every vertex. (Qhull may keep an extra edge between two points
    closer than the closed form's merge tolerance, 1e-7 of the scale.)"""
    robot, limits = panda
    mapper = ContactSpaceMapper(robot, limits, DOWN, n_directions=8)
    for q, v in _random_states(robot, limits, 30, seed=24):
        b = mapper.update(q, v)
        got = halfplanes_from_support_points(b.vertices, b.effective_mass)
        ref = halfplanes_from_vertices(b.vertices, b.effective_mass)
        assert got is not None
        mine, qhull = np.column_stack(got), np.column_stack(ref)
        scale = np.abs(qhull).max(axis=0)
        for row in mine:
            assert np.min(np.max(np.abs(qhull - row) / scale, axis=1)) < 1e-6
        assert len(mine) >= len(qhull) - 2
        for P, p in (got, ref):
            assert np.all(b.vertices @ P.T <= p + 1e-6 * (1.0 + np.abs(p)))
    # Not a convex counter-clockwise sequence: None (the mapper then uses Qhull).
    clockwise = np.array([[1.0, 0.0], [0.0, -1.0], [-1.0, 0.0], [0.0, 1.0]])
    assert halfplanes_from_support_points(clockwise, 1.0) is None
    assert halfplanes_from_support_points(np.ones((8, 2)), 1.0) is None
