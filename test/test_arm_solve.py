# Copyright 2026 toc_ros developers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.

"""
Fast mode for URDF arms: Riccati step, derivatives, bad input, and solves against IPOPT.

The solves are re-checked independently (toc_ros/bench/arm_check.py: Pinocchio's own URDF
parser, controls re-integrated, every limit and clearance at every node) and compared with
CasADi + IPOPT on the same transcription (toc_ros/bench/arm_reference.py).
"""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

pin = pytest.importorskip('pinocchio')

from toc_ros.core import Problem, solve, SolverOptions, Status  # noqa: E402
from toc_ros.core.arms import load_arm, load_spheres  # noqa: E402
from toc_ros.core.arms import riccati  # noqa: E402
from toc_ros.core.arms.arm_eval import ArmEvaluator  # noqa: E402
from toc_ros.core.arms.arm_solve import ArmRobot  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / 'benchmarks' / 'data'
SCENARIOS = {
    'panda': ((-1.2, 0.2, 0.0, -2.0, 0.0, 2.2, 0.8), (1.2, 0.1, 0.3, -1.8, 0.2, 2.0, 0.3),
              ((0.60, 0.0, 0.42, 0.08),)),
    'ur5': ((0.0, -0.4, 0.4, -1.57, -1.57, 0.0), (0.0, -2.0, 0.9, -1.57, -1.57, 0.0),
            ((0.60, 0.0, 0.55, 0.2),)),
}
MARGIN = 0.02


def _robot(name):
    arm = load_arm(name)
    spheres = load_spheres(DATA / f'arm_spheres_{name}.yaml', arm, self_collision=False)
    return ArmRobot(arm, spheres)


def _problem(name, n_int=50, with_obstacles=True, **changes):
    start, goal, obs = SCENARIOS[name]
    fields = {'x0': start, 'x_goal': goal, 'model': _robot(name),
              'obstacles': obs if with_obstacles else (), 'margin': MARGIN,
              'n_intervals': n_int}
    fields.update(changes)
    return Problem(**fields)


# Riccati step against a dense KKT solve ---------------------------------------------------

def _dense_step(a, b, c, d, hxx, hux, huu, gx, gu, convex=None):
    """
    Solve the stage QP of riccati.py with one dense KKT system (numpy.linalg.solve).

    convex: a list to which True is appended when the Hessian is positive definite on the
    constraints' null space (the QP has a unique minimum), else False.
    """
    n_int, nx, nu = b.shape
    # Variables: dT, dx_1..dx_{N-1}, du_0..du_{N-1}; dx_0 = dx_N = 0.
    nvar = 1 + (n_int - 1) * nx + n_int * nu

    def xi(k):
        return (list(range(1 + (k - 1) * nx, 1 + k * nx)) if 0 < k < n_int else None)

    def ui(k):
        return list(range(1 + (n_int - 1) * nx + k * nu, 1 + (n_int - 1) * nx + (k + 1) * nu))

    hess = np.zeros((nvar, nvar))
    grad = np.zeros(nvar)
    for k in range(n_int):
        idx = (xi(k) or []) + [0]
        sel = ([True] * nx if xi(k) else [False] * nx) + [True]
        hk = hxx[k][np.ix_(sel, sel)]
        hess[np.ix_(idx, idx)] += hk
        grad[idx] += gx[k][sel]
        hess[np.ix_(ui(k), idx)] += hux[k][:, sel]
        hess[np.ix_(idx, ui(k))] += hux[k][:, sel].T
        hess[np.ix_(ui(k), ui(k))] += huu[k]
        grad[ui(k)] += gu[k]
    rows = []
    rhs = []
    for k in range(n_int):
        row = np.zeros((nx, nvar))
        if xi(k):
            row[:, xi(k)] += a[k]
        row[:, ui(k)] += b[k]
        row[:, 0] += c[k]
        if xi(k + 1):
            row[:, xi(k + 1)] -= np.eye(nx)
        rows.append(row)
        rhs.append(-d[k])
    jac = np.vstack(rows)
    if convex is not None:
        _, sing, vt = np.linalg.svd(jac)
        null = vt[np.sum(sing > 1e-12 * sing[0]):].T
        convex.append(bool(np.min(np.linalg.eigvalsh(null.T @ hess @ null)) > 0.0))
    kkt = np.block([[hess, jac.T], [jac, np.zeros((jac.shape[0], jac.shape[0]))]])
    sol = np.linalg.solve(kkt, np.concatenate([-grad, np.concatenate(rhs)]))
    step = sol[:nvar]
    dx = np.zeros((n_int + 1, nx))
    for k in range(1, n_int):
        dx[k] = step[xi(k)]
    du = np.array([step[ui(k)] for k in range(n_int)])
    # KKT multipliers y of "A dx + B du + c dT + d - dx_{k+1} = 0" with L = f + y . g:
    # the sign convention of riccati's lam is lam_{k+1} = -y_k... solve's sign is +: check both.
    return step[0], dx, du, sol[nvar:].reshape(n_int, nx)


def _random_stage_qp():
    """Return (a, b, c, d, hxx, hux, huu, gx, gu) of a random stage QP (6 intervals, nx 4)."""
    rng = np.random.default_rng(3)
    n_int, nx, nu = 6, 4, 2
    a = np.eye(nx)[None] + 0.1 * rng.normal(size=(n_int, nx, nx))
    b = rng.normal(size=(n_int, nx, nu))
    c = 0.3 * rng.normal(size=(n_int, nx))
    d = 0.1 * rng.normal(size=(n_int, nx))
    hxx = np.zeros((n_int, nx + 1, nx + 1))
    for k in range(n_int):
        m = rng.normal(size=(nx + 1, nx + 1))
        hxx[k] = m @ m.T + np.eye(nx + 1)
    hux = 0.1 * rng.normal(size=(n_int, nu, nx + 1))
    huu = np.array([np.eye(nu) * 2.0 for _ in range(n_int)])
    gx = rng.normal(size=(n_int, nx + 1))
    gu = rng.normal(size=(n_int, nu))
    return a, b, c, d, hxx, hux, huu, gx, gu


def test_riccati_step_matches_a_dense_kkt_solve():
    a, b, c, d, hxx, hux, huu, gx, gu = _random_stage_qp()
    n_int, nx, nu = b.shape
    work = (np.zeros((n_int + 1, nx + 1, nx + 1)), np.zeros((n_int + 1, nx + 1, 1 + nx)),
            np.zeros((n_int, nu, nx + 1)), np.zeros((n_int, nu, 1 + nx)),
            np.zeros((n_int + 1, nx + 1, 1 + nx)), np.zeros((n_int, nu, 1 + nx)))
    dx, du = np.zeros((n_int + 1, nx)), np.zeros((n_int, nu))
    lam, nu_out = np.zeros((n_int + 1, nx)), np.zeros(nx)
    code, d_t = riccati.riccati_solve(a, b, c, d, hxx, hux, huu, gx, gu, 1.0, *work, dx, du,
                                      lam, nu_out)
    assert code == riccati.OK
    d_t_ref, dx_ref, du_ref, y = _dense_step(a, b, c, d, hxx, hux, huu, gx, gu)
    assert d_t == pytest.approx(d_t_ref, abs=1e-10)
    np.testing.assert_allclose(dx[1:-1], dx_ref[1:-1], atol=1e-10)
    np.testing.assert_allclose(du, du_ref, atol=1e-10)
    assert np.max(np.abs(dx[-1])) < 1e-10
    # The multipliers of the steps into x_1..x_N (the dense system's y, same sign).
    np.testing.assert_allclose(lam[1:], y, atol=1e-8)
    np.testing.assert_allclose(nu_out, y[-1], atol=1e-8)


def test_riccati_step_with_a_negative_final_time_curvature_is_solved_when_convex():
    # P_0(T, T) <= 0 at a point of a convex QP (velocity-limited arm motions): dT is solved
    # with the terminal multipliers, not refused; refused only when the QP is not convex.
    a, b, c, d, hxx, hux, huu, gx, gu = _random_stage_qp()
    n_int, nx, nu = b.shape
    seen = set()
    for lowered in (0.0, 2.0, 5.0, 7.0, 10.0, 40.0):
        h = hxx.copy()
        h[:, nx, nx] -= lowered        # less curvature in T at every stage
        work = riccati.work_arrays(n_int, nx, nu)
        dx, du = np.zeros((n_int + 1, nx)), np.zeros((n_int, nu))
        lam, nu_out = np.zeros((n_int + 1, nx)), np.zeros(nx)
        code, d_t = riccati.riccati_solve(a, b, c, d, h, hux, huu, gx, gu, 1.0, *work, dx, du,
                                          lam, nu_out)
        convex = []
        d_t_ref, dx_ref, du_ref, y = _dense_step(a, b, c, d, h, hux, huu, gx, gu, convex)
        final_time_curvature = work[0][0, nx, nx]
        seen.add((final_time_curvature > 0.0, convex[0]))
        if not convex[0]:
            assert code == riccati.FINAL_TIME_CURVATURE
            continue
        assert code == riccati.OK
        assert d_t == pytest.approx(d_t_ref, rel=1e-9, abs=1e-12)
        np.testing.assert_allclose(dx[1:-1], dx_ref[1:-1], atol=1e-9)
        np.testing.assert_allclose(du, du_ref, atol=1e-9)
        assert np.max(np.abs(dx[-1])) < 1e-9
        np.testing.assert_allclose(lam[1:], y, atol=1e-8)
    # Every case: P_0(T, T) > 0 and convex, <= 0 and convex, <= 0 and not convex.
    assert seen == {(True, True), (False, True), (False, False)}


def test_line_search_takes_a_step_that_lowers_both_the_violation_and_the_barrier():
    # Near the solution: the switching rule asks for Armijo on phi; a step whose slope
    # promised far more than the barrier can give still lowers phi and theta: it is taken as
    # an h-type step (the filter grows); one that raises phi is not.
    from toc_ros.core.arms.arm_ipm import ArmInteriorPoint
    ipm = ArmInteriorPoint.__new__(ArmInteriorPoint)
    ipm.theta_max, ipm.theta_min, ipm.filter = 1e4, 1e-4, []
    phi0, theta0, slope = 0.5389882208788, 4.818e-05, -0.53
    small_gain = {'phi': phi0 - 2.5e-8, 'theta': 1.25e-5}
    assert ipm._acceptable(small_gain, 1.0, phi0, theta0, slope)
    assert ipm.filter == [((1.0 - 1e-5) * theta0, phi0 - 1e-8 * theta0)]
    ipm.filter = []
    assert not ipm._acceptable({'phi': phi0 + 1e-9, 'theta': 1.25e-5}, 1.0, phi0, theta0,
                               slope)
    assert not ipm._acceptable({'phi': phi0 - 2.5e-8, 'theta': theta0}, 1.0, phi0, theta0,
                               slope)
    # Armijo met: an f-type step, the filter unchanged.
    assert ipm._acceptable({'phi': phi0 - 1e-4, 'theta': theta0}, 1.0, phi0, theta0, slope)
    assert ipm.filter == []


def test_riccati_reports_an_indefinite_reduced_hessian():
    n_int, nx, nu = 3, 2, 1
    a = np.tile(np.eye(nx), (n_int, 1, 1))
    b = np.ones((n_int, nx, nu))
    zeros = (np.zeros((n_int, nx)), np.zeros((n_int, nx)))
    hxx = np.tile(np.eye(nx + 1), (n_int, 1, 1))
    huu = -np.ones((n_int, nu, nu)) * 100.0
    work = (np.zeros((n_int + 1, nx + 1, nx + 1)), np.zeros((n_int + 1, nx + 1, 1 + nx)),
            np.zeros((n_int, nu, nx + 1)), np.zeros((n_int, nu, 1 + nx)),
            np.zeros((n_int + 1, nx + 1, 1 + nx)), np.zeros((n_int, nu, 1 + nx)))
    code, _ = riccati.riccati_solve(a, b, *zeros, hxx, np.zeros((n_int, nu, nx + 1)), huu,
                                    np.zeros((n_int, nx + 1)), np.zeros((n_int, nu)), 1.0,
                                    *work, np.zeros((n_int + 1, nx)), np.zeros((n_int, nu)),
                                    np.zeros((n_int + 1, nx)), np.zeros(nx))
    assert code == riccati.REDUCED_HESSIAN_INDEFINITE


# Derivatives the solver uses, against finite differences ----------------------------------

@pytest.mark.parametrize('name', ['panda', 'ur5'])
def test_step_derivatives_and_curvature_match_finite_differences(name):
    robot = _robot(name)
    arm = robot.arm
    n, nx = arm.n, 2 * arm.n
    rng = np.random.default_rng(7)
    ev = ArmEvaluator(arm, robot.spheres, SCENARIOS[name][2], MARGIN, 1)
    q = np.clip(rng.uniform(-1.0, 1.0, n), arm.lower, arm.upper)
    x = np.vstack([np.concatenate([q, rng.uniform(-1, 1, n)]), rng.uniform(-1, 1, nx)])
    v = rng.uniform(-0.8, 0.8, (1, n))
    t_f = 0.7
    lam = rng.normal(size=(2, nx))
    terms = ev.stage_terms(x, v, t_f, lam, hessian='exact')
    z0 = np.concatenate([x[0], v[0], [t_f]])

    def step(z):
        return ev.defects(np.vstack([z[:nx], x[1]]), z[nx:nx + n][None], z[-1])[0] + x[1]

    eps = 1e-6
    jac = np.stack([(step(z0 + eps * e) - step(z0 - eps * e)) / (2 * eps)
                    for e in np.eye(z0.size)], axis=1)
    np.testing.assert_allclose(terms['a'][0], jac[:, :nx], atol=2e-6 * max(1, abs(jac).max()))
    np.testing.assert_allclose(terms['b'][0], jac[:, nx:nx + n], atol=1e-7)
    np.testing.assert_allclose(terms['c'][0], jac[:, -1], atol=1e-7)
    assert np.allclose(terms['defect'][0], step(z0) - x[1], atol=1e-12)

    def lagrangian_gradient(z):
        t = ev.stage_terms(np.vstack([z[:nx], x[1]]), z[nx:nx + n][None], z[-1], lam,
                           hessian='none')
        return np.concatenate([t['a'][0].T @ lam[1], [t['c'][0] @ lam[1]],
                               t['b'][0].T @ lam[1]])

    order = list(range(nx)) + [z0.size - 1] + list(range(nx, nx + n))
    zs = z0[order]

    def in_z(w):
        out = np.empty_like(w)
        out[order] = w
        return out

    hess = np.stack([(lagrangian_gradient(in_z(zs + eps * e)) - lagrangian_gradient(
        in_z(zs - eps * e))) / (2 * eps) for e in np.eye(z0.size)], axis=1)
    scale = max(1.0, np.abs(hess).max())
    np.testing.assert_allclose(terms['hxx'][0], hess[:nx + 1, :nx + 1], atol=1e-4 * scale)
    np.testing.assert_allclose(terms['hux'][0], hess[nx + 1:, :nx + 1], atol=1e-4 * scale)
    assert np.abs(hess[nx + 1:, nx + 1:]).max() < 1e-6 * scale      # ABA affine in tau
    # The cheap model 'cross': the final time's row and column of the same Hessian, no more.
    cross = ev.stage_terms(x, v, t_f, lam, hessian='cross')
    np.testing.assert_allclose(cross['hxx'][0, :, nx], hess[:nx + 1, nx], atol=1e-6 * scale)
    np.testing.assert_allclose(cross['hxx'][0, nx, :], hess[nx, :nx + 1], atol=1e-6 * scale)
    np.testing.assert_allclose(cross['hux'][0, :, nx], hess[nx + 1:, nx], atol=1e-6 * scale)
    assert not cross['hxx'][0, :nx, :nx].any() and not cross['hux'][0, :, :nx].any()

    # Sphere rows (obstacles and, with the shipped spheres, self-collision pairs): values
    # against the spheres module, gradients and curvature by differences.
    from toc_ros.core.arms import default_spheres, obstacle_clearance, self_clearance
    from toc_ros.core.arms import sphere_centres
    shipped = default_spheres(arm, self_collision=True)
    ev = ArmEvaluator(arm, shipped, SCENARIOS[name][2], MARGIN, 1, self_collision=True)
    assert len(ev.pairs) > 0
    qs = np.clip(rng.uniform(-1.0, 1.0, (3, n)), arm.lower, arm.upper)
    # The rows are (d^2 - R^2) / (2 R): zero and sign exactly where the distances say.
    centres = sphere_centres(arm, shipped, qs[0])
    distance_rows = np.concatenate([
        obstacle_clearance(centres, shipped.radii, SCENARIOS[name][2], MARGIN).ravel(),
        self_clearance(centres, shipped.radii, shipped.self_pairs)])
    rows = ev.clearances(qs[:1])[0]
    radius = np.concatenate([ev.radius.ravel(), ev.pair_radius])
    np.testing.assert_allclose(rows, distance_rows * (distance_rows + 2 * radius)
                               / (2 * radius), atol=1e-12)
    weights = rng.uniform(0.0, 1.0, (3, ev.n_pairs))
    values, grads, curvature = ev.clearance_terms(qs, weights)
    fd = np.stack([(ev.clearances(qs + eps * e) - ev.clearances(qs - eps * e)) / (2 * eps)
                   for e in np.eye(n)], axis=-1)
    np.testing.assert_allclose(grads, fd, atol=1e-7)

    def weighted_gradient(points):
        return np.einsum('kp,kpn->kn', weights, ev.clearance_terms(points)[1])

    fd2 = np.stack([(weighted_gradient(qs + eps * e) - weighted_gradient(qs - eps * e))
                    / (2 * eps) for e in np.eye(n)], axis=-1)
    np.testing.assert_allclose(curvature, fd2, atol=1e-4 * max(1.0, np.abs(fd2).max()))


def test_derivatives_kept_from_a_trial_are_reused_only_at_the_same_point():
    robot = _robot('panda')
    arm = robot.arm
    rng = np.random.default_rng(3)
    ev = ArmEvaluator(arm, robot.spheres, SCENARIOS['panda'][2], MARGIN, 4)
    q = np.clip(rng.uniform(-1.0, 1.0, (5, arm.n)), arm.lower, arm.upper)
    x = np.hstack([q, rng.uniform(-1, 1, (5, arm.n))])
    v = rng.uniform(-0.8, 0.8, (4, arm.n))
    lam = rng.normal(size=(5, 2 * arm.n))
    fresh = ArmEvaluator(arm, robot.spheres, SCENARIOS['panda'][2], MARGIN, 4)
    expected = fresh.stage_terms(x, v, 0.7, lam, hessian='cross')
    # A line-search trial that keeps its derivatives: the same defects as the ABA pass ...
    kept = ev.defects(x, v, 0.7, keep_derivatives=True)
    assert np.array_equal(kept, fresh.defects(x, v, 0.7))
    calls = ev.pin_calls
    # ... and the next iteration at that point makes no Pinocchio call and gets the same bits.
    terms = ev.stage_terms(x.copy(), v.copy(), 0.7, lam, hessian='cross')
    assert ev.pin_calls == calls
    for key, value in expected.items():
        assert np.array_equal(terms[key], value), key
    # Another point (one control changed) is evaluated afresh.
    v2 = v.copy()
    v2[2, 1] += 1e-3
    moved = ev.stage_terms(x, v2, 0.7, lam, hessian='cross')
    assert ev.pin_calls == calls + 4
    assert np.array_equal(moved['a'], fresh.stage_terms(x, v2, 0.7, lam, 'cross')['a'])
    assert not np.array_equal(moved['a'][2], terms['a'][2])


# Bad input --------------------------------------------------------------------------------

@pytest.mark.parametrize('changes, reason', [
    ({'x0': (9.0, 0.2, 0.0, -2.0, 0.0, 2.2, 0.8)}, 'outside its limits'),
    ({'x0': (float('nan'), 0.2, 0.0, -2.0, 0.0, 2.2, 0.8)}, 'NaN'),
    ({'x_goal': (1.2, 0.1)}, 'the arm has 7 joints'),
    ({'x_goal': (1.2, 0.1, 0.3, -1.8, 0.2, 2.0, 0.3) + (9.0,) * 7}, 'velocity'),
    ({'integrator': 'midpoint'}, "use 'euler' or 'rk4'"),
    ({'obstacles': ((0.214, -0.551, 0.35, 0.05),)}, 'in collision'),
    ({'obstacles': ((0.5, 0.0, 0.5, float('inf')),)}, 'NaN or infinite'),
    ({'margin': -1.0}, 'margin'),
    ({'n_intervals': 1}, 'N must be'),
])
def test_bad_arm_input_is_invalid_input_with_the_reason(changes, reason):
    result = solve(_problem('panda', **changes))
    assert result.status is Status.INVALID_INPUT
    assert reason in result.message


def test_a_goal_on_a_position_limit_moving_out_of_it_is_refused():
    upper = float(load_arm('panda').upper[0])
    q = (upper, 0.2, 0.0, -2.0, 0.0, 2.2, 0.8)
    out = q + (1.0,) + (0.0,) * 6
    result = solve(_problem('panda', x_goal=out))
    assert result.status is Status.INVALID_INPUT
    assert 'on its upper limit' in result.message and 'velocity 1 out of it' in result.message
    # Into the limits (or at rest there) is a goal like any other: not refused for it.
    for velocity in (-1.0, 0.0):
        result = solve(_problem('panda', x_goal=q + (velocity,) + (0.0,) * 6, n_intervals=20),
                       SolverOptions(max_iterations=1))
        assert result.status is not Status.INVALID_INPUT, result.message


def test_a_goal_checked_before_is_checked_again_when_anything_it_depends_on_changed():
    quick = SolverOptions(max_iterations=1)
    problem = _problem('panda', n_int=20)
    assert solve(problem, quick).status is not Status.INVALID_INPUT
    assert solve(problem, quick).status is not Status.INVALID_INPUT    # (the checked goal)
    arm = problem.model.arm
    goal = np.asarray(problem.x_goal, dtype=float)[:arm.n]
    tip = arm.frame_position(goal, problem.model.spheres.links[-1])
    at_goal = problem.obstacles + ((*tip, 0.05),)
    result = solve(dataclasses.replace(problem, obstacles=at_goal), quick)
    assert result.status is Status.INVALID_INPUT and 'goal in collision' in result.message
    # An obstacle 5 cm clear of the goal's spheres: the goal passes with the margin 0.02 m, and
    # is refused with 0.06 m (the start, turned away, clears both).
    from toc_ros.core.arms.clearances import obstacle_clearance, sphere_kinematics_batch
    spheres = problem.model.spheres
    centres = sphere_kinematics_batch(spheres, goal[None, :])[0][0]
    above = tip + np.array([0.0, 0.0, 0.3])
    gap = obstacle_clearance(centres, spheres.radii, np.array([[*above, 0.05]]), 0.0).min()
    near = problem.obstacles + ((*above, 0.05 + gap - 0.05),)
    assert solve(dataclasses.replace(problem, obstacles=near), quick).status \
        is not Status.INVALID_INPUT
    result = solve(dataclasses.replace(problem, obstacles=near, margin=0.06), quick)
    assert result.status is Status.INVALID_INPUT and 'goal in collision' in result.message
    upper = arm.upper.copy()
    try:
        arm.upper[0] = goal[0] - 0.01          # a limit changed in place
        result = solve(problem, quick)
        assert result.status is Status.INVALID_INPUT and 'outside its limits' in result.message
    finally:
        arm.upper[:] = upper


def test_paper_mode_with_rk4_and_spheres_missing_are_refused():
    result = solve(_problem('panda', integrator='rk4'), SolverOptions(mode='paper'))
    assert result.status is Status.INVALID_INPUT and 'explicit Euler' in result.message
    start, goal, obs = SCENARIOS['panda']
    bare = Problem(x0=start, x_goal=goal, model=ArmRobot(load_arm('panda')), obstacles=obs)
    result = solve(bare)
    assert result.status is Status.INVALID_INPUT and 'spheres' in result.message


_SIGNATURES = """
import dataclasses
import sys
from numba.core.registry import CPUDispatcher
sys.path.insert(0, sys.argv[1])
from test_arm_solve import _problem, MARGIN
from toc_ros.core import SolverOptions, solve, Status, warm_up_for
from toc_ros.core.arms import arm_eval, ipm_kernels, kernels, riccati, riccati_euler, rk4_steps


def signatures():
    return {(module.__name__, name): len(value.signatures)
            for module in (arm_eval, ipm_kernels, kernels, riccati, riccati_euler, rk4_steps)
            for name, value in vars(module).items() if isinstance(value, CPUDispatcher)}
"""

_COMPILES_NOTHING = _SIGNATURES + """
from toc_ros.core.arms.arm_eval import ArmEvaluator
from toc_ros.core.arms.polish import polish

problem = _problem('panda', 30)
warm_up_for(problem, SolverOptions())
before = signatures()
assert before[(riccati_euler.__name__, 'riccati_solve_euler')] >= 1
assert before[(kernels.__name__, 'sphere_rows')] >= 1
result = solve(problem)
assert result.status is Status.SOLVED
robot = problem.model
evaluator = ArmEvaluator(robot.arm, robot.spheres, problem.obstacles, MARGIN, 30)
polish(evaluator, result.states, result.controls / robot.arm.effort, result.final_time)
after = signatures()
print({key: (before[key], after[key]) for key in after if after[key] != before.get(key)})
assert after == before
"""

_NODE_WARM_UP_COMPILES_ALL = _SIGNATURES + """
from toc_ros.arm_model import build_arm

model = build_arm('panda', '', ['panda_joint%d' % i for i in range(1, 8)], None, None, None)
model.warm_up()
before = signatures()
problem = dataclasses.replace(_problem('panda', 30), model=model.robot)
assert solve(problem).status is Status.SOLVED
solve(dataclasses.replace(problem, integrator='rk4'), SolverOptions(max_iterations=3))
after = signatures()
print({key: (before[key], after[key]) for key in after if after[key] != before.get(key)})
assert after == before
"""


def _run_apart(script):
    import subprocess
    import sys
    here = str(Path(__file__).resolve().parent)
    done = subprocess.run([sys.executable, '-c', script, here], capture_output=True, text=True,
                          timeout=600, cwd=str(Path(here).parent))
    assert done.returncode == 0, done.stdout + done.stderr


@pytest.mark.slow
def test_a_solve_after_the_warm_up_compiles_nothing():
    # The CLI's and the sweep's start-up solve (warm_up_for) compiles every kernel an arm
    # solve uses: a solve past a sphere afterwards (free optimum, bends) and the polish of its
    # result add no compiled signature, so no user request waits for numba.  In a process of
    # its own (in this one other tests have compiled kernels already).
    _run_apart(_COMPILES_NOTHING)


@pytest.mark.slow
def test_the_nodes_warm_up_compiles_every_kernel_of_later_solves():
    # solver_node warms an arm before it knows any obstacle (ArmPlanModel.warm_up): a solve
    # past a sphere afterwards and an RK4 one add no compiled signature.  (Its tiny solve with
    # an obstacle out of reach never ran the sphere rows' kernel: the first plan past a sphere
    # of a fresh install compiled it, 1.5-2.9 s.)
    _run_apart(_NODE_WARM_UP_COMPILES_ALL)


def test_timeout_and_cancel_stop_an_arm_solve():
    import threading
    result = solve(_problem('ur5', 20), SolverOptions(timeout=1e-6))
    assert result.status is Status.TIMEOUT and result.has_trajectory
    cancel = threading.Event()
    cancel.set()
    result = solve(_problem('ur5', 20), cancel=cancel)
    assert result.status is Status.CANCELED
    result = solve(_problem('ur5', 20), SolverOptions(max_iterations=0))
    assert result.status is Status.INVALID_INPUT and 'max_iterations' in result.message


def test_cli_routes_the_named_arms_and_urdf_paths_only():
    from toc_ros.arm_cli import ARM_NAMES, is_arm_model_name, requested_model
    from toc_ros.core.arms import NAMED_ARMS
    assert set(ARM_NAMES) == set(NAMED_ARMS)
    assert is_arm_model_name(requested_model(['--model', 'urdf:/x.urdf']))
    assert is_arm_model_name(requested_model(['--model=panda']))
    assert not is_arm_model_name(requested_model(['--model', 'planar_2r']))
    assert not is_arm_model_name(requested_model(['--N', '10']))


def test_cli_refuses_a_goal_outside_the_limits(tmp_path, capsys):
    from toc_ros.solve import main
    out = tmp_path / 'r.json'
    code = main(['--model', 'panda', '--start', '0', '0', '0', '-2', '0', '2', '0.8',
                 '--goal', '9', '0', '0', '-2', '0', '2', '0.8', '--N', '20', '--json',
                 str(out)])
    assert code == 4
    data = json.loads(out.read_text())
    assert data['status'] == 'INVALID_INPUT' and 'outside its limits' in data['message']


# Solves against IPOPT, re-checked independently -------------------------------------------

def _independent_check(name, result, obstacles, start=None, goal=None, integrator='euler'):
    """Re-check result from start (default: the scenario's) to goal with arm_check.py."""
    from toc_ros.bench.arm_check import check_trajectory, example_robot_urdf
    from toc_ros.bench.arm_problem import ArmSpec
    start = SCENARIOS[name][0] if start is None else start
    goal = SCENARIOS[name][1] if goal is None else goal
    arm = load_arm(name)
    spec = ArmSpec(urdf=example_robot_urdf(name), joints=arm.joint_names, start=start,
                   goal=goal, obstacles=obstacles,
                   robot_spheres=str(DATA / f'arm_spheres_{name}.yaml'), margin=MARGIN)
    check = check_trajectory(spec, result.final_time, result.controls, integrator,
                             result.states)
    assert check['terminal_error'] < 1e-6
    assert check['defect'] < 1e-9
    assert check['max_position_excess'] <= 1e-9
    assert check['max_velocity_excess'] <= 1e-9
    assert check['max_effort_excess'] == 0.0
    # The solver constrains (d^2 - R^2) / (2 R) >= 0, the same set as d - R >= 0.
    assert check['min_clearance'] >= -1e-6
    return spec


def test_small_ur5_solve_is_solved_and_feasible_on_the_independent_check():
    result = solve(_problem('ur5', 20, True))
    assert result.status is Status.SOLVED, result.message
    assert result.states.shape == (21, 12) and result.controls.shape == (20, 6)
    _independent_check('ur5', result, SCENARIOS['ur5'][2])


def test_self_collision_rows_hold_at_every_node():
    from toc_ros.core.arms import self_clearance, sphere_centres
    start, goal, _ = SCENARIOS['ur5']
    robot = ArmRobot.shipped(load_arm('ur5'), self_collision=True)
    result = solve(Problem(model=robot, x0=start, x_goal=goal, n_intervals=20))
    assert result.status is Status.SOLVED, result.message
    assert result.violations.self_constrained
    worst = min(np.min(self_clearance(sphere_centres(robot.arm, robot.spheres, q),
                                      robot.spheres.radii, robot.spheres.self_pairs))
                for q in result.states[:, :6])
    assert worst >= -1e-6
    assert worst == pytest.approx(result.violations.self_clearance, abs=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize('name, obstacles', [('panda', False), ('panda', True),
                                             ('ur5', False), ('ur5', True)])
def test_fast_arm_solve_matches_ipopt_and_is_feasible(name, obstacles):
    pytest.importorskip('casadi')
    from toc_ros.bench.arm_problem import ArmProblem
    from toc_ros.bench.arm_reference import solve_arm
    problem = _problem(name, 50, obstacles)
    result = solve(problem)
    assert result.status is Status.SOLVED, result.message
    assert result.violations.feasible()
    obs = SCENARIOS[name][2] if obstacles else ()
    spec = _independent_check(name, result, obs)
    reference = ArmProblem(spec)
    best = solve_arm(reference, 50, 'euler', 'ipopt')
    assert best['success'], best['status']
    assert result.final_time == pytest.approx(best['t_f'], rel=1e-3)


@pytest.mark.slow
def test_a_motion_the_cheap_curvature_model_cannot_finish_is_solved_with_exact_curvature():
    # The Panda lifting joint 2 by 1 rad from its ready pose: without the dynamics' curvature
    # the interior point wanders (line-search failure, then the iteration limit); 'auto'
    # switches to exact curvature once the cheap model stalls (cold_runs._stall_watch: here
    # before CHEAP_ITERATIONS) and converges to IPOPT's optimum.
    pytest.importorskip('casadi')
    from toc_ros.bench.arm_problem import ArmProblem
    from toc_ros.bench.arm_reference import ArmTranscription
    from toc_ros.core.arms.arm_solve import solve_arm
    from toc_ros.core.arms.cold_runs import CHEAP_ITERATIONS, slowed
    start, goal = (0, -0.785, 0, -2.356, 0, 1.571, 0.785), (0.9, 0.25, 0, -2.0, 0, 2.25, 1.6)
    robot = _robot('panda')
    problem = Problem(model=robot, x0=start, x_goal=goal, n_intervals=20)
    cheap = solve_arm(problem, SolverOptions(max_iterations=300), hessian='none')
    assert cheap.status is not Status.SOLVED
    result = solve(problem)
    assert result.status is Status.SOLVED, result.message
    assert 'exact curvature' in result.message and result.iterations < CHEAP_ITERATIONS
    spec = _independent_check('panda', result, (), start=start, goal=goal)
    nlp = ArmTranscription(ArmProblem(spec), 20, 'euler', 'ipopt')
    best = min(out['t_f'] for out in (
        nlp.solve((result.states, result.controls, result.final_time)),
        nlp.solve(slowed(robot.arm, np.r_[start, np.zeros(7)], np.r_[goal, np.zeros(7)], 20,
                         0.8)[:2] + (0.8,))) if out['success'])
    assert result.final_time <= best * (1 + 1e-6)


def test_starts_that_repeat_an_earlier_run_are_abandoned_without_changing_the_optimum(
        monkeypatch):
    # The UR5 benchmark motion past one sphere (bench_arm_fast.py): several of its starts
    # are, once their first barrier problem is solved, where an earlier start's run was
    # (cold_runs.REPEAT_PATH); the search abandons them there and ends at the same optimum
    # as when every start is run to its end, in fewer iterations.
    from benchmarks.bench_arm_fast import SCENARIOS as BENCH
    from toc_ros.core.arms import cold_runs
    start, goal, sets = BENCH['ur5']
    problem = _problem('ur5', 50, x0=start, x_goal=goal, obstacles=sets['1 sphere'])
    result = solve(problem)
    assert result.status is Status.SOLVED, result.message
    assert "repeats an earlier start's run" in result.message
    monkeypatch.setattr(cold_runs, 'REPEAT_PATH', -1.0)
    every = solve(problem)
    assert every.status is Status.SOLVED, every.message
    assert 'repeats' not in every.message
    assert result.final_time == pytest.approx(every.final_time, rel=1e-12, abs=0.0)
    assert result.iterations < every.iterations
    _independent_check('ur5', result, sets['1 sphere'], start, goal)


def test_detours_keep_the_joint_limits_and_clear_the_sphere():
    # A goal 0.05 rad inside joint 4's lower limit with a sphere where the hand passes halfway:
    # bending the line towards that limit is not allowed, the detours bend the other joints.
    from toc_ros.core.arms import sphere_centres
    from toc_ros.core.arms.arm_start import line_detours
    robot = _robot('panda')
    arm = robot.arm
    start = np.array((0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785))
    goal = np.array((-0.814, 0.343, 0.039, -3.022, 0.296, 2.235, 1.056))
    middle = arm.frame_position(0.5 * (start + goal), robot.spheres.links[-1])
    ev = ArmEvaluator(arm, robot.spheres, ((*middle, 0.08),), MARGIN, 30)
    x0, xg = np.r_[start, np.zeros(7)], np.r_[goal, np.zeros(7)]
    assert ev.clearances(np.linspace(start, goal, 31)).min() < -0.05     # the line collides
    detours = line_detours(arm, ev, x0, xg, 30, count=2)
    assert len(detours) == 2
    for states, torques, t_f in detours:
        # Positions from start to goal (the interior point pins the end states themselves).
        assert np.allclose(states[0, :7], start) and np.allclose(states[-1, :7], goal)
        assert np.all(states[:, :7] >= arm.lower) and np.all(states[:, :7] <= arm.upper)
        assert np.all(np.abs(states[:, 7:]) <= arm.velocity + 1e-12)
        assert np.all(np.abs(torques) <= arm.effort)
        # Clearance recomputed from the sphere centres, not through the evaluator's rows.
        for q in states[1:-1, :7]:
            centres = sphere_centres(arm, robot.spheres, q)
            gap = (np.linalg.norm(centres - middle, axis=1) - robot.spheres.radii - 0.08
                   - MARGIN)
            assert gap.min() > 0.0
    assert np.linalg.norm(detours[0][0] - detours[1][0]) > 0.1        # two distinct ways


def _panda_sphere_halfway(goal, n_int):
    """(robot, start, obstacles, problem): from the ready pose, a sphere where the hand passes."""
    robot = _robot('panda')
    start = (0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785)
    middle = robot.arm.frame_position(0.5 * (np.array(start) + goal), robot.spheres.links[-1])
    obstacles = ((*middle, 0.08),)
    return robot, start, obstacles, Problem(model=robot, x0=start, x_goal=goal,
                                            obstacles=obstacles, margin=MARGIN,
                                            n_intervals=n_int)


@pytest.mark.slow
def test_a_sphere_on_the_line_near_a_joint_limit_is_passed_as_well_as_ipopt_does():
    # The same motion solved: the old single detour gave up at the joint limit and the solve
    # started inside the sphere (STALLED at N = 60); the free optimum and the bent lines are
    # tried now.
    pytest.importorskip('casadi')
    from toc_ros.bench.arm_problem import ArmProblem
    from toc_ros.bench.arm_reference import ArmTranscription
    from toc_ros.core.arms.cold_runs import start_point
    goal = (-0.814, 0.343, 0.039, -3.022, 0.296, 2.235, 1.056)
    robot, start, obstacles, problem = _panda_sphere_halfway(goal, 60)
    result = solve(problem)
    assert result.status is Status.SOLVED, result.message
    spec = _independent_check('panda', result, obstacles, start=start, goal=goal)
    x0, xg = np.r_[start, np.zeros(7)], np.r_[goal, np.zeros(7)]
    ev = ArmEvaluator(robot.arm, robot.spheres, obstacles, MARGIN, 60)
    nlp = ArmTranscription(ArmProblem(spec), 60, 'euler', 'ipopt')
    runs = [nlp.solve(start_point(robot, ev, x0, xg, 60)[:3]),
            nlp.solve((result.states, result.controls, result.final_time))]
    best = min(out['t_f'] for out in runs if out['success'])
    assert result.final_time <= best * (1 + 1e-3)


@pytest.mark.slow
def test_a_sphere_passed_the_better_way_found_by_the_free_optimums_other_bends(monkeypatch):
    # A Panda goal of the random one-sphere suite: the free optimum bent the nearest way
    # (and the bent lines) pass the sphere on a side that costs 10 % more time; another bend
    # of the free optimum finds the better way, which IPOPT confirms.
    pytest.importorskip('casadi')
    from toc_ros.bench.arm_problem import ArmProblem
    from toc_ros.bench.arm_reference import ArmTranscription
    from toc_ros.core.arms import cold_runs
    goal = (0.223, -1.361, 0.816, -2.333, 0.026, 2.178, -0.06)
    _, start, obstacles, problem = _panda_sphere_halfway(goal, 30)
    result = solve(problem)
    assert result.status is Status.SOLVED, result.message
    spec = _independent_check('panda', result, obstacles, start=start, goal=goal)
    # One bend and one bent line, without the colliding line (the mirror image of the first
    # bent line and the colliding line find the better way too).
    monkeypatch.setattr(cold_runs, 'FREE_BENDS', 1)
    monkeypatch.setattr(cold_runs, 'LINE_DETOURS', 1)
    points = cold_runs.start_points
    monkeypatch.setattr(cold_runs, 'start_points', lambda *args: [
        (name, make, last) for name, make, last in points(*args) if name != 'line'])
    one_bend = solve(problem)
    assert one_bend.status is Status.SOLVED, one_bend.message
    assert one_bend.final_time > 1.05 * result.final_time
    nlp = ArmTranscription(ArmProblem(spec), 30, 'euler', 'ipopt')
    from_one_bend = nlp.solve((one_bend.states, one_bend.controls, one_bend.final_time))
    from_result = nlp.solve((result.states, result.controls, result.final_time))
    assert from_result['success'], from_result['status']
    assert result.final_time <= from_result['t_f'] * (1 + 1e-4)
    if from_one_bend['success']:
        assert result.final_time <= from_one_bend['t_f'] * (1 + 1e-3)


@pytest.mark.slow
def test_the_colliding_line_start_finds_its_way_out_of_the_sphere(monkeypatch):
    # An xArm7 motion past one sphere (bench_arm_robots.py's "xarm7 past a sphere #1", rough
    # robot spheres along each link).  The straight line passes through the sphere; the sphere
    # rows' slacks let the interior point start there, and from there it finds a way around
    # (0.359658 s; IPOPT's best from two starts 0.358978 s).  The full cold solve keeps the
    # best of its starts: a bent line's 0.358705 s.
    from toc_ros.bench.arm_check import check_trajectory
    from toc_ros.bench.arm_problem import ArmSpec
    from toc_ros.core.arms import cold_runs
    from toc_ros.core.arms.model import example_robot_data_dir
    urdf = str(Path(example_robot_data_dir()) / 'xarm_description/urdf/xarm7.urdf')
    joints = tuple(f'joint{i}' for i in range(1, 8))
    start = (0.3282, -0.1827, -1.082, 2.7306, 1.4942, 0.4955, -2.751)
    goal = (-0.3653, -1.0583, -0.4102, 2.5706, 2.0183, 0.4499, -2.9517)
    sphere = (-0.3203, -0.1512, 0.945, 0.08)
    spheres = str(DATA / 'arm_spheres_xarm7_rough.yaml')
    arm = load_arm(f'urdf:{urdf}', joints=list(joints))
    problem = Problem(x0=start, x_goal=goal, model=ArmRobot(arm, load_spheres(
        spheres, arm, self_collision=False)), obstacles=(sphere,), margin=MARGIN,
        n_intervals=60)
    best = solve(problem)
    assert best.status is Status.SOLVED, best.message
    points = cold_runs.start_points
    monkeypatch.setattr(cold_runs, 'start_points', lambda *args: [
        (name, make, last) for name, make, last in points(*args) if name == 'line'])
    line = solve(problem)
    assert line.status is Status.SOLVED, line.message
    assert line.solver_state['start'] == 'line', line.message
    assert line.final_time <= 0.358978 * (1 + 3e-3), line.final_time
    for result in (line, best):
        check = check_trajectory(ArmSpec(urdf=urdf, joints=joints, start=start, goal=goal,
                                         obstacles=(sphere,), robot_spheres=spheres,
                                         margin=MARGIN),
                                 result.final_time, result.controls, 'euler', result.states)
        assert check['terminal_error'] < 1e-6 and check['min_clearance'] > -1e-6
        assert max(check['max_position_excess'], check['max_velocity_excess'],
                   check['max_effort_excess']) < 1e-6
    assert best.final_time <= line.final_time
    assert best.final_time <= 0.358978 * (1 + 1e-3), best.final_time


def _rk4_evaluator(name, n_int, seed):
    """(arm, n, 2n, a random generator, an RK4 ArmEvaluator of n_int intervals) of an arm."""
    robot = _robot(name)
    arm = robot.arm
    return (arm, arm.n, 2 * arm.n, np.random.default_rng(seed),
            ArmEvaluator(arm, robot.spheres, (), MARGIN, n_int, integrator='rk4'))


@pytest.mark.parametrize('name', ['panda', 'ur5'])
def test_rk4_step_derivatives_match_finite_differences(name):
    arm, n, nx, rng, ev = _rk4_evaluator(name, 1, 11)
    q = np.clip(rng.uniform(-1.0, 1.0, n), arm.lower, arm.upper)
    x = np.vstack([np.concatenate([q, rng.uniform(-1, 1, n)]), rng.uniform(-1, 1, nx)])
    v = rng.uniform(-0.8, 0.8, (1, n))
    t_f = 0.05          # one interval of 50 ms: a step the size of a plan's
    terms = ev.stage_terms(x, v, t_f, np.zeros((2, nx)), hessian='none')
    z0 = np.concatenate([x[0], v[0], [t_f]])

    def step(z):
        return ev.defects(np.vstack([z[:nx], x[1]]), z[nx:nx + n][None], z[-1])[0] + x[1]

    # RK4 by hand, with pinocchio.aba: the step the defects must describe.
    def f(state):
        return np.concatenate([state[n:], pin.aba(arm.model, arm.model.createData(),
                                                  state[:n], state[n:],
                                                  arm.effort * v[0])])
    k1 = f(x[0])
    k2 = f(x[0] + 0.5 * t_f * k1)
    k3 = f(x[0] + 0.5 * t_f * k2)
    k4 = f(x[0] + t_f * k3)
    assert np.allclose(step(z0), x[0] + t_f / 6 * (k1 + 2 * k2 + 2 * k3 + k4), atol=1e-12)
    eps = 1e-6
    jac = np.stack([(step(z0 + eps * e) - step(z0 - eps * e)) / (2 * eps)
                    for e in np.eye(z0.size)], axis=1)
    scale = max(1.0, np.abs(jac).max())
    np.testing.assert_allclose(terms['a'][0], jac[:, :nx], atol=1e-7 * scale)
    np.testing.assert_allclose(terms['b'][0], jac[:, nx:nx + n], atol=1e-7 * scale)
    np.testing.assert_allclose(terms['c'][0], jac[:, -1], atol=1e-7 * scale)


@pytest.mark.parametrize('name', ['panda', 'ur5'])
def test_rk4_step_curvature_matches_second_differences_of_the_steps(name):
    # hessian='exact' on RK4 steps: the Hessian of lam . step over (x_k, T, v_k), against
    # central second differences of that scalar (the steps' values only), two intervals.
    arm, n, nx, rng, ev = _rk4_evaluator(name, 2, 12)
    q = np.clip(rng.uniform(-1.0, 1.0, (3, n)), arm.lower, arm.upper)
    x = np.hstack([q, rng.uniform(-1, 1, (3, n))])
    v = rng.uniform(-0.8, 0.8, (2, n))
    t_f = 0.1
    lam = rng.uniform(-1, 1, (3, nx))
    terms = ev.stage_terms(x, v, t_f, lam, hessian='exact')

    def weighted(k, z):
        xs, vs = x.copy(), v.copy()
        xs[k], vs[k] = z[:nx], z[nx + 1:]
        return float(lam[k + 1] @ (ev.defects(xs, vs, z[nx]) + xs[1:])[k])

    eps = 1e-4
    for k in range(2):
        z0 = np.concatenate([x[k], [t_f], v[k]])
        basis = np.eye(z0.size) * eps
        hess = np.array([[(weighted(k, z0 + a + b) - weighted(k, z0 + a - b)
                           - weighted(k, z0 - a + b) + weighted(k, z0 - a - b)) / (4 * eps ** 2)
                          for b in basis] for a in basis])
        # (forward differences of the derivatives: ~1e-4 relative on the largest entries)
        scale = max(1.0, np.abs(hess).max())
        for got, want in ((terms['hxx'][k], hess[:nx + 1, :nx + 1]),
                          (terms['hux'][k], hess[nx + 1:, :nx + 1]),
                          (terms['huu'][k], hess[nx + 1:, nx + 1:])):
            np.testing.assert_allclose(got, want, rtol=1e-3, atol=1e-5 * scale)
        # Not affine in the torques: the control block is there to be checked.
        assert np.abs(hess[nx + 1:, nx + 1:]).max() > 1e-3 * scale


@pytest.mark.slow
def test_rk4_arm_solve_matches_ipopt_on_the_rk4_transcription():
    # N = 10: IPOPT on the RK4 transcription takes seconds; it is started from fast mode's
    # solution (a better optimum nearby would show).
    pytest.importorskip('casadi')
    from toc_ros.bench.arm_problem import ArmProblem
    from toc_ros.bench.arm_reference import ArmTranscription
    problem = _problem('ur5', 10, False, integrator='rk4')
    result = solve(problem)
    assert result.status is Status.SOLVED, result.message
    assert result.integrator == 'rk4'
    spec = _independent_check('ur5', result, (), integrator='rk4')
    euler = solve(_problem('ur5', 10, False))
    assert abs(euler.final_time - result.final_time) > 1e-4      # another discretisation
    nlp = ArmTranscription(ArmProblem(spec), 10, 'rk4', 'ipopt')
    out = nlp.solve((result.states, result.controls, result.final_time))
    assert out['success'], out['status']
    assert result.final_time <= out['t_f'] * (1 + 1e-6)


@pytest.mark.slow
def test_cli_solves_an_arm_and_writes_the_contract(tmp_path):
    from toc_ros.solve import main
    start, goal, obs = SCENARIOS['ur5']
    out = tmp_path / 'r.json'
    code = main(['--model', 'ur5', '--collision-spheres', str(DATA / 'arm_spheres_ur5.yaml'),
                 '--start', *map(str, start), '--goal', *map(str, goal),
                 '--sphere', *map(str, obs[0]), '--margin', str(MARGIN), '--N', '50',
                 '--json', str(out), '--quiet'])
    data = json.loads(out.read_text())
    assert code == 0 and data['status'] == 'SOLVED'
    states, controls = np.array(data['states']), np.array(data['controls'])
    assert states.shape == (51, 12) and controls.shape == (50, 6)
    np.testing.assert_allclose(states[0], list(start) + [0.0] * 6, atol=0)
    assert np.linalg.norm(states[-1] - np.array(list(goal) + [0.0] * 6)) < 1e-6
    assert data['violations']['min_clearance'] >= -1e-6
    assert data['joint_names'][0] == 'shoulder_pan_joint'


@pytest.mark.parametrize('args, reason', [
    (['--model', 'urdf:/nonexistent/robot.urdf'], 'cannot read URDF'),
    (['--model', 'panda', '--joints', 'panda_joint1,no_such_joint'], 'unknown joint'),
    (['--model', 'panda', '--locked', 'panda_finger_joint1=abc'], 'not a number'),
    # --mode is an option of its own, not an abbreviation of --model (it was read as
    # "--model paper": unknown arm 'paper').
    (['--model', 'panda', '--mode', 'paper', '--integrator', 'rk4'], 'explicit Euler'),
])
def test_cli_refuses_bad_models_with_the_reason(args, reason, capsys):
    from toc_ros.solve import main
    code = main(args + ['--start', '0', '0', '0', '-2', '0', '2', '0.8',
                        '--goal', '0.1', '0', '0', '-2', '0', '2', '0.8'])
    assert code == 4
    assert reason in capsys.readouterr().err


def test_cli_refuses_a_sphere_file_naming_unknown_links(tmp_path, capsys):
    from toc_ros.solve import main
    spheres = tmp_path / 'spheres.yaml'
    spheres.write_text('no_such_link: [[0.0, 0.0, 0.0, 0.1]]\n')
    code = main(['--model', 'panda', '--collision-spheres', str(spheres),
                 '--start', '0', '0', '0', '-2', '0', '2', '0.8',
                 '--goal', '0.1', '0', '0', '-2', '0', '2', '0.8'])
    assert code == 4
    assert 'unknown link' in capsys.readouterr().err


def test_toy_arms_with_a_continuous_or_a_clashing_joint_pass_the_independent_check():
    # arm_check.py builds the URDF with Pinocchio's own parser, where the continuous joint is
    # (cos, sin); the solver's model makes it an unbounded angle (model.py).
    from test_arm_model import toy
    from toc_ros.bench.arm_check import check_trajectory
    from toc_ros.bench.arm_problem import ArmSpec
    from toc_ros.core.arms.arm_solve import ArmViolations
    arm = load_arm(toy())
    assert arm.continuous.tolist() == [True, False, False]
    start, goal = (2.5, 0.0, 0.05), (-2.9, 0.5, 0.1)       # the spin joint passes +-pi
    result = solve(Problem(x0=start, x_goal=goal, model=arm, n_intervals=40))
    assert result.status is Status.SOLVED, result.message
    check = check_trajectory(ArmSpec(urdf=toy(), joints=arm.joint_names, start=start,
                                     goal=goal), result.final_time, result.controls,
                             'euler', result.states)
    assert check['defect'] < 1e-9 and check['terminal_error'] < 1e-6
    assert check['max_position_excess'] == 0.0 and check['max_velocity_excess'] <= 1e-9
    assert ArmViolations(0.0, 2e-6, np.inf, 0.0, 0.0).exceeded() == [
        'terminal error 2e-06 > 1e-06']
    # A locked joint named like a link (test_arm_model.py), in both implementations.
    clash = toy().replace('link name="c"', 'link name="slide"').replace(
        '<child link="c"/>', '<child link="slide"/>').replace(
        '<parent link="c"/>', '<parent link="slide"/>')
    arm = load_arm(clash, joints=['spin', 'elbow'], locked={'slide': 0.15})
    result = solve(Problem(x0=start[:2], x_goal=goal[:2], model=arm, n_intervals=40))
    assert result.status is Status.SOLVED, result.message
    check = check_trajectory(ArmSpec(urdf=clash, joints=arm.joint_names, start=start[:2],
                                     goal=goal[:2], locked={'slide': 0.15}),
                             result.final_time, result.controls, 'euler', result.states)
    assert check['defect'] < 1e-9 and check['terminal_error'] < 1e-6


def test_an_unstable_open_loop_motion_is_solved_inaccurately_with_the_reason():
    # The Kinova j2s6s200's light wrist: its Euler motion amplifies the solver's 1e-13 defects
    # to ~1e-4 at the goal when the controls are integrated again from the start.
    from toc_ros.bench.arm_check import check_trajectory
    from toc_ros.bench.arm_problem import ArmSpec
    from toc_ros.core.arms.model import example_robot_data_dir
    urdf = Path(example_robot_data_dir()) / 'kinova_description' / 'robots' / 'kinova.urdf'
    joints = tuple(f'j2s6s200_joint_{i}' for i in range(1, 7))
    start = (2.0572, 1.1777, 1.3141, -2.0763, 2.826, 2.9174)
    goal = (1.8432, 0.8703, 2.0061, -1.1038, 3.0916, 3.0916)
    arm = load_arm(f'urdf:{urdf}', joints=joints)
    result = solve(Problem(x0=start, x_goal=goal, model=arm, n_intervals=60))
    assert result.status is Status.SOLVED_INACCURATE and result.status.exit_code() == 1
    # The interior point ends by its tolerances or IPOPT's acceptable level (which of the two
    # depends on the last bits of the floating-point arithmetic: both happen across machines).
    assert 'converged' in result.message or 'acceptable after' in result.message
    assert 'SOLVED_INACCURATE: re-integrated from the start, terminal error' in result.message
    check = check_trajectory(ArmSpec(urdf=str(urdf), joints=joints, start=start, goal=goal),
                             result.final_time, result.controls, 'euler', result.states)
    # The independent integration (pin.aba in the LOCAL convention, ~3e-11 from the solver's
    # WORLD one per call) parts from the returned states by far more than that and misses the
    # goal too: the open loop is unstable, whichever arithmetic integrates it.
    assert check['defect'] > 1e-7
    assert check['terminal_error'] > 1e-6


def test_polish_takes_the_defects_of_a_trajectory_down_to_rounding():
    from toc_ros.core.arms.polish import polish
    problem = _problem('panda', 40, with_obstacles=False)
    result = solve(problem)
    assert result.status is Status.SOLVED, result.message
    robot = problem.model
    evaluator = ArmEvaluator(robot.arm, robot.spheres, np.zeros((0, 4)), MARGIN, 40)
    v = result.controls / robot.arm.effort
    noisy = result.states + 1e-8 * np.random.default_rng(5).normal(size=result.states.shape)
    noisy[0], noisy[-1] = result.states[0], result.states[-1]
    x, v2, t_f, before, after = polish(evaluator, noisy, v, result.final_time)
    assert before > 1e-7 and after < 1e-13
    # Recomputed here: the defects of the returned point, and how little it moved.
    assert np.max(np.abs(evaluator.defects(x, v2, t_f))) == after
    assert np.max(np.abs(v2)) <= 1.0
    assert abs(t_f - result.final_time) < 1e-7 and np.max(np.abs(x - noisy)) < 1e-6
    assert np.array_equal(x[0], noisy[0]) and np.array_equal(x[-1], noisy[-1])


def test_a_long_horizon_whose_rollout_amplifies_the_defects_is_polished_to_solved(monkeypatch):
    # A long horizon (N = 400) amplifies the defects a run converges with in the open-loop
    # integration of the SOLVED test (the Panda turned 7.5e-11 into a terminal error of
    # 1.4e-6).  Whether a given run needs the polish depends on its last digits, so the runs
    # here converge with a looser constraint tolerance (1e-7): without the polish the result
    # would be SOLVED_INACCURATE.
    from benchmarks.bench_arm_fast import SCENARIOS as BENCH
    from toc_ros.core.arms import arm_ipm
    start, goal, sets = BENCH['panda']
    plain_init = arm_ipm.ArmInteriorPoint.__init__

    def loose(self, *args, **kwargs):
        plain_init(self, *args, **kwargs)
        self.constr_tol = 1e-7
    monkeypatch.setattr(arm_ipm.ArmInteriorPoint, '__init__', loose)
    result = solve(_problem('panda', 400, x0=start, x_goal=goal, obstacles=sets['1 sphere']))
    assert result.status is Status.SOLVED, result.message
    assert 'defects polished' in result.message
    _independent_check('panda', result, sets['1 sphere'], start, goal)


def test_ur10_past_a_sphere_does_not_stall_and_passes_on_the_faster_side(monkeypatch):
    # The Riccati step refused P_0(T, T) <= 0 as an inertia failure; the correction's damped
    # steps then stalled every start next to its optimum (0.617280 s after 701 iterations).
    # Then every bend of the free optimum passed the sphere on the slower side (0.455011 s);
    # the mirror images of the bends find the side of IPOPT's best (0.441460 s,
    # benchmarks/bench_arm_robots.py).
    from benchmarks.bench_arm_robots import MARGIN as UR10_MARGIN, ROBOTS, UR10_SPHERE, \
        UR10_SPHERES
    from toc_ros.bench.arm_check import check_trajectory
    from toc_ros.bench.arm_problem import ArmSpec
    from toc_ros.core.arms import arm_start
    from toc_ros.core.arms.model import example_robot_data_dir
    rel, joints, _ = ROBOTS['ur10']
    urdf = Path(example_robot_data_dir()) / rel
    arm = load_arm(f'urdf:{urdf}', joints=list(joints))
    start, goal, sphere = UR10_SPHERE
    problem = Problem(x0=start, x_goal=goal, model=ArmRobot(arm, load_spheres(
        UR10_SPHERES, arm, self_collision=False)), obstacles=(sphere,), margin=UR10_MARGIN,
        n_intervals=60)
    result = solve(problem)
    assert result.status is Status.SOLVED, result.message
    assert result.final_time < 0.44147 and result.iterations < 400
    check = check_trajectory(ArmSpec(urdf=str(urdf), joints=tuple(joints), start=start,
                                     goal=goal, obstacles=(sphere,),
                                     robot_spheres=UR10_SPHERES, margin=UR10_MARGIN),
                             result.final_time, result.controls, 'euler', result.states)
    assert check['terminal_error'] < 1e-6 and check['min_clearance'] > -1e-6
    assert max(check['max_position_excess'], check['max_velocity_excess'],
               check['max_effort_excess']) < 1e-6

    # Without the mirror images (each replaced by a zero seed, which finds the first bend
    # again) the bends pass on the slower side.
    corrected = arm_start._corrected
    calls = []

    def without_mirrors(evaluator, path, bend, low, high, target, first, *rest):
        mirror = any(np.array_equal(first, np.clip(-found, low, high))
                     for found in calls if found is not None and found.any())
        out = corrected(evaluator, path, bend, low, high, target, 0.0 * first if mirror
                        else first, *rest)
        calls.append(out)
        return out
    monkeypatch.setattr(arm_start, '_corrected', without_mirrors)
    slower = solve(problem)
    assert slower.status is Status.SOLVED, slower.message
    assert slower.final_time > 1.02 * result.final_time, (slower.final_time, result.final_time)


def test_many_obstacles_off_the_motion_cost_few_iterations_and_far_ones_none():
    # A wall of 50 small spheres behind the Panda never touches its free optimum: with the
    # first barrier parameter scaled to the rows (ArmInteriorPoint.crowding_share) it is
    # solved at the free optimum's time in 18 iterations (73 unscaled; the free motion 11);
    # spheres out of the arm's reach get no rows at all.
    robot = ArmRobot.shipped(load_arm('panda'))
    start, goal = (0, -0.785, 0, -2.356, 0, 1.571, 0.785), (0.5, -0.5, 0.3, -2.0, 0.2, 1.8, 0.5)
    free = solve(Problem(model=robot, x0=start, x_goal=goal, n_intervals=40))
    assert free.status is Status.SOLVED, free.message
    rng = np.random.default_rng(0)
    wall = [(-0.5, y, z, 0.02) for y, z in zip(rng.uniform(-0.5, 0.5, 50), rng.uniform(0, 1, 50))]
    far = [(3.0 + 0.1 * k, 0.0, 0.0, 0.1) for k in range(200)]
    for obstacles, most in ((wall, 2 * free.iterations), (far, free.iterations)):
        result = solve(Problem(model=robot, x0=start, x_goal=goal, n_intervals=40,
                               obstacles=obstacles))
        assert result.status is Status.SOLVED, result.message
        assert result.final_time == pytest.approx(free.final_time, rel=1e-9)
        assert result.iterations <= most
        assert result.violations.min_clearance > 0.0


def test_controls_whose_integration_diverges_are_not_reported_solved():
    # A continuous joint turned 100 rad at 2 rad/s in the vertical plane: the velocity-bound
    # optimum is 50 s long, 0.5 s per Euler step, and the pendulum's open loop at that step
    # amplifies the solver's 1e-11 defects to overflow.
    urdf = """<robot name="r"><link name="base"/>
      <link name="l1"><inertial><origin xyz="0 0 0.25"/><mass value="1.0"/>
        <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
      <link name="l2"><inertial><origin xyz="0 0 0.25"/><mass value="1.0"/>
        <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
      <joint name="j1" type="continuous"><parent link="base"/><child link="l1"/>
        <origin xyz="0 0 0.5"/><axis xyz="0 1 0"/><limit effort="50" velocity="2"/></joint>
      <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/>
        <origin xyz="0 0 0.5"/><axis xyz="0 1 0"/>
        <limit effort="50" velocity="2" lower="-3" upper="3"/></joint></robot>"""
    result = solve(Problem(model=load_arm(urdf), x0=(0, 0), x_goal=(100, 0.5),
                           n_intervals=100))
    assert result.status is Status.STALLED, result.message
    assert 'diverge' in result.message
    assert np.all(np.isfinite(result.states))


@pytest.mark.parametrize('side', ['upper', 'lower'])
def test_a_start_at_rest_on_a_position_limit_is_solved_within_the_limits(side):
    # At rest on a limit, an Euler step's first node is the start itself: that bound has no
    # interior until arm_ipm.relaxed_bounds moves it out by 1e-12 (before: MAX_ITERATIONS).
    arm = load_arm('panda')
    start = np.array(SCENARIOS['panda'][0], dtype=float)
    start[3] = arm.upper[3] if side == 'upper' else arm.lower[3]
    goal = start.copy()
    goal[0] += 1.0
    goal[3] += -0.5 if side == 'upper' else 0.5
    problem = _problem('panda', 30, with_obstacles=False, x0=tuple(start), x_goal=tuple(goal))
    result = solve(problem)
    assert result.status is Status.SOLVED, result.message
    assert result.states[0, 3] == start[3] and result.states[1, 3] == start[3]
    _independent_check('panda', result, (), tuple(start), tuple(goal))


def test_only_the_bounds_a_start_sits_on_are_relaxed():
    from toc_ros.core.arms.arm_ipm import BOUND_RELAX, relaxed_bounds
    lower, upper = np.array([-2.0, -0.5, -np.inf]), np.array([2.0, 0.5, np.inf])
    low, high = relaxed_bounds(lower, upper, np.array([-2.0, 0.5 - 1e-14, 0.3]))
    assert low[0] == -2.0 - 2.0 * BOUND_RELAX and high[1] == 0.5 + BOUND_RELAX
    assert (low[1], low[2], high[0], high[2]) == (-0.5, -np.inf, 2.0, np.inf)
    assert lower[0] == -2.0         # the arm's own limits are not changed
