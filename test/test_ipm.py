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
Tests of the interior-point engine of fast mode (toc_ros/core/ipm.py and the modules it drives).

The engine is checked against derivatives and residuals computed here independently.

* The Newton step: the full primal-dual KKT residual F (stationarity, shooting defects,
  terminal condition, elastic obstacle constraints, complementarity) is written out here in
  numpy from the problem's definition; the step solved by the Riccati sweep must satisfy
  F(w + eps dw) = (1 - eps) F(w) + O(eps^2), i.e. J_F dw = -F, for Euler (exact Hessian) on
  both robot models with obstacles active and random multipliers.
* The stage Hessian of lam . Phi and the obstacle constraint's gradient and Hessian against
  central differences.
* Warm starts: the same optimum as a cold solve, in fewer iterations; replanning from a moving
  state with the remainder of a plan; bad guesses refused.
"""

from dataclasses import replace

from numba import njit
import numpy as np
import numpy_model as nm
import pytest

from toc_ros.core import CylindricalRobot, horizon, ip_run, ipm_obstacles, Problem, riccati, \
    RobotParams, solve, SolverOptions, start_points, Status
from toc_ros.core.ipm_workspace import F_ELASTIC, F_MU, F_T, F_T_HIGH, F_T_LOW, F_T_REF, \
    F_ZT_HIGH, F_ZT_LOW, I_N
from toc_ros.core.models import cylindrical, load_model, planar_2r


def _residual(run, ws):
    """Compute the KKT residual vector of the barrier problem at the point held in ws."""
    run.kernels.ipm_evaluate(ws)
    n = ws.iscal[I_N]
    fs = ws.fscal
    mu = fs[F_MU]
    rho = fs[F_ELASTIC]
    parts = [np.einsum('irc,ir->ic', ws.jac_v, ws.lam[1:]) - ws.zl + ws.zu]
    rx = -ws.lam[1:].copy()
    rx[:-1] += np.einsum('irc,ir->ic', ws.jac_x[1:], ws.lam[2:])
    rx[-1] += ws.nu
    if ws.s.shape[1]:
        rx[:, 0::2] -= np.einsum('ija,ij->ia', ws.cons_q[1:], ws.z[1:])
    parts += [rx, [fs[F_T] / fs[F_T_REF] + np.sum(ws.jac_t * ws.lam[1:])
                   - fs[F_ZT_LOW] + fs[F_ZT_HIGH]],
              ws.defect, ws.x[n] - ws.x_goal, ws.cons[1:] + ws.e[1:] - ws.s[1:],
              ws.s[1:] * ws.z[1:] - mu, ws.e[1:] * (rho - ws.z[1:]) - mu,
              (1.0 + ws.v) * ws.zl - mu, (1.0 - ws.v) * ws.zu - mu,
              [(fs[F_T] - fs[F_T_LOW]) * fs[F_ZT_LOW] - mu,
               (fs[F_T_HIGH] - fs[F_T]) * fs[F_ZT_HIGH] - mu]]
    return np.concatenate([np.ravel(np.asarray(p, dtype=float)) for p in parts])


def _moved(ws, eps, dt, dzt):
    # Copies of the arrays (the size tuples are immutable).
    w = ws._replace(**{k: getattr(ws, k).copy() for k in ws._fields
                       if isinstance(getattr(ws, k), np.ndarray)})
    w.x[:] += eps * ws.dx
    w.v[:] += eps * ws.dv
    w.lam[1:] += eps * (ws.lam_new[1:] - ws.lam[1:])
    w.nu[:] += eps * (ws.nu_new - ws.nu)
    w.s[1:] += eps * ws.ds[1:]
    w.e[1:] += eps * ws.de[1:]
    w.z[1:] += eps * ws.dz[1:]
    w.zl[:] += eps * ws.dzl
    w.zu[:] += eps * ws.dzu
    w.fscal[F_T] += eps * dt
    w.fscal[F_ZT_LOW] += eps * dzt[0]
    w.fscal[F_ZT_HIGH] += eps * dzt[1]
    return w


PLANAR = load_model('planar_2r', g=9.81)
CASES = {
    'cylindrical': Problem.paper(n_intervals=24),
    'cylindrical_eq36_two_circles': Problem.paper(
        n_intervals=24, obstacles=((1.0, 1.0, 0.2), (0.6, 1.1, 0.15)),
        model=CylindricalRobot(RobotParams(model_variant='eq36'))),
    'planar_2r_gravity': Problem(model=PLANAR, x0=tuple(PLANAR.state([0.0, 0.5])),
                                 x_goal=tuple(PLANAR.state([1.4, 0.3])), n_intervals=24,
                                 t_f0=1.0, obstacles=((1.0, 0.9, 0.2),)),
}


@pytest.mark.parametrize('name', sorted(CASES))
def test_newton_step_solves_the_linearised_kkt_system(name):
    problem = CASES[name]
    n = problem.n_intervals
    run = ip_run.InteriorPointRun(problem, n, 10)
    states, controls, t_f = start_points.interpolation_start(problem, n)
    run.start(states, controls, t_f, 0.05)
    ws = run.ws
    rng = np.random.default_rng(7)
    # Multipliers small enough that the Hessian stays positive definite on the dynamics'
    # null space, so the step is computed without an inertia shift (the exact Newton step).
    ws.lam[1:] = rng.normal(scale=0.3 if isinstance(problem.model, CylindricalRobot) else 1e-3,
                            size=ws.lam[1:].shape)
    ws.nu[:] = rng.normal(size=ws.nu.shape)
    ws.z[1:] = rng.uniform(1e-5, 1e-4, size=ws.z[1:].shape)
    ws.v[:] = rng.uniform(-0.9, 0.9, size=ws.v.shape)
    assert ws.s.shape[1] > 0
    f0 = _residual(run, ws)
    dt = riccati.newton_direction(ws, 0.0)
    assert np.isfinite(dt)
    fs = ws.fscal
    mu = fs[F_MU]
    s_low, s_high = fs[F_T] - fs[F_T_LOW], fs[F_T_HIGH] - fs[F_T]
    dzt = (mu / s_low - fs[F_ZT_LOW] - fs[F_ZT_LOW] / s_low * dt,
           mu / s_high - fs[F_ZT_HIGH] + fs[F_ZT_HIGH] / s_high * dt)
    errors = []
    for eps in (1e-3, 1e-4):
        f = _residual(run, _moved(ws, eps, dt, dzt))
        errors.append(np.max(np.abs(f - (1.0 - eps) * f0)) / eps)
    # The first-order error vanishes linearly with eps: J_F dw = -F holds to rounding.
    assert errors[1] <= 0.2 * errors[0] + 1e-9 * np.max(np.abs(f0)), errors
    assert errors[1] <= 1e-3 * np.max(np.abs(f0)), errors


@njit(cache=True)
def _hessian(x, u, tau, p, lam, out):
    nx, nu = x.shape[0], u.shape[0]
    work = horizon.step_work(nx, nu)
    hw = horizon.hessian_work(nx, nu)
    horizon.step_lagrangian_hessian(cylindrical.rhs_jac, cylindrical.rhs_hess, x, u, tau, p,
                                    lam, out[0][:nx, :nx], out[1], out[2], out[3], out[4],
                                    work, hw)


@njit(cache=True)
def _jacobians(x, u, tau, p, a, b, t):
    nx, nu = x.shape[0], u.shape[0]
    work = horizon.step_work(nx, nu)
    nxt = np.zeros(nx)
    horizon.step_jacobians(cylindrical.rhs_jac, x, u, tau, p, horizon.EULER, nxt, a, b, t,
                           work)


def test_euler_stage_hessian_matches_finite_differences_of_the_jacobians():
    model = cylindrical.CylindricalRobot()
    p = model.packed()
    rng = np.random.default_rng(3)
    x = np.array([0.4, 0.7, 0.9, -0.3])
    u = np.array([150.0, -80.0])
    tau = 0.01
    lam = rng.normal(size=4)
    out = (np.zeros((4, 4)), np.zeros((4, 2)), np.zeros((2, 2)), np.zeros(4), np.zeros(2))
    _hessian(x, u, tau, p, lam, out)

    def grad(x, u, tau):
        a, b, t = np.zeros((4, 4)), np.zeros((4, 2)), np.zeros(4)
        _jacobians(x, u, tau, p, a, b, t)
        return lam @ a, lam @ b, lam @ t

    h = 1e-6
    for k in range(4):
        e = np.zeros(4)
        e[k] = h
        gxp, gup, _ = grad(x + e, u, tau)
        gxm, gum, _ = grad(x - e, u, tau)
        np.testing.assert_allclose(out[0][k], (gxp - gxm) / (2 * h), rtol=1e-6, atol=1e-8)
        np.testing.assert_allclose(out[1][k], (gup - gum) / (2 * h), rtol=1e-6, atol=1e-8)
    for k in range(2):
        e = np.zeros(2)
        e[k] = 1e-3
        _, gup, _ = grad(x, u + e, tau)
        _, gum, _ = grad(x, u - e, tau)
        np.testing.assert_allclose(out[2][k], (gup - gum) / 2e-3, rtol=1e-6, atol=1e-10)
    gxp, gup, _ = grad(x, u, tau + 1e-7)
    gxm, gum, _ = grad(x, u, tau - 1e-7)
    np.testing.assert_allclose(out[3], (gxp - gxm) / 2e-7, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(out[4], (gup - gum) / 2e-7, rtol=1e-6, atol=1e-8)


# One wrapper per model, each binding its segments kernel as a module attribute: numba caches
# these, whereas a kernel passed as an argument makes every test run compile anew.
@njit(cache=True)
def _obstacle_cylindrical(q, p, circles, z, sigma, cons, cons_q, hess):
    work = ipm_obstacles.obstacle_work(cons.shape[0] // circles.shape[0], q.shape[0])
    ipm_obstacles.obstacle_terms(cylindrical.segments, q, p, circles, cons, cons_q, z, sigma,
                                 hess, work)


@njit(cache=True)
def _obstacle_planar_2r(q, p, circles, z, sigma, cons, cons_q, hess):
    work = ipm_obstacles.obstacle_work(cons.shape[0] // circles.shape[0], q.shape[0])
    ipm_obstacles.obstacle_terms(planar_2r.segments, q, p, circles, cons, cons_q, z, sigma,
                                 hess, work)


OBSTACLE_TERMS = {cylindrical: _obstacle_cylindrical, planar_2r: _obstacle_planar_2r}


@pytest.mark.parametrize('model', [cylindrical.CylindricalRobot(), PLANAR],
                         ids=['cylindrical', 'planar_2r'])
def test_obstacle_constraint_derivatives_match_finite_differences(model):
    circles = np.array([[0.9, 0.8, 0.3], [-0.4, 1.0, 0.2], [1.2, -0.3, 0.25]])
    n_con = model.n_links * circles.shape[0]
    rng = np.random.default_rng(11)
    p = model.packed()
    obstacle = OBSTACLE_TERMS[model.kernels]
    for _ in range(20):
        q = rng.uniform([-1.0, 0.2], [2.0, 1.2])
        z = np.zeros(n_con)
        cons, grad, hess = np.zeros(n_con), np.zeros((n_con, 2)), np.zeros((2, 2))
        obstacle(q, p, circles, z, np.zeros(n_con), cons, grad, hess)
        # Against the numpy geometry (independent of the kernels).
        seg = model.link_segments(q)
        ref = nm.segment_clearance(seg, circles)
        d = ref + np.tile(circles[:, 2], model.n_links)
        radius = np.tile(circles[:, 2], model.n_links)
        np.testing.assert_allclose(cons, (d ** 2 - radius ** 2) / (2 * radius), atol=1e-12)
        assert seg.shape == (model.n_links, 4)
        for j in range(n_con):
            # Hessian of constraint j alone: z = e_j, sigma = 0 gives -grad^2 c_j.
            zj = np.zeros(n_con)
            zj[j] = 1.0
            obstacle(q, p, circles, zj, np.zeros(n_con), cons, grad, hess)
            h = 1e-6
            for a in range(2):
                e = np.zeros(2)
                e[a] = h
                cp, gp = np.zeros(n_con), np.zeros((n_con, 2))
                cm, gm = np.zeros(n_con), np.zeros((n_con, 2))
                obstacle(q + e, p, circles, z, z, cp, gp, np.zeros((2, 2)))
                obstacle(q - e, p, circles, z, z, cm, gm, np.zeros((2, 2)))
                assert grad[j, a] == pytest.approx((cp[j] - cm[j]) / (2 * h), abs=1e-6)
                np.testing.assert_allclose(-hess[a], (gp[j] - gm[j]) / (2 * h), atol=1e-5)


def test_warm_start_from_a_solution_gives_the_same_optimum_in_fewer_iterations():
    problem = Problem.paper(n_intervals=300)
    cold = solve(problem)
    assert cold.status is Status.SOLVED, cold.message
    warm = solve(problem, initial_guess=cold)
    assert warm.status is Status.SOLVED, warm.message
    assert warm.final_time == pytest.approx(cold.final_time, rel=1e-6)
    assert warm.iterations < cold.iterations
    nm.assert_feasible(problem, warm)
    # A pair (controls, t_f) on another grid is resampled to N.
    resampled = solve(problem, initial_guess=(cold.controls[::3], cold.final_time))
    assert resampled.status is Status.SOLVED, resampled.message
    assert resampled.final_time == pytest.approx(cold.final_time, rel=1e-6)


def test_replanning_from_a_moving_state_with_the_plan_remainder():
    problem = Problem.paper(n_intervals=1000)
    plan = solve(problem)
    assert plan.status is Status.SOLVED, plan.message
    k = 300
    # The robot at 30 % of the plan, moving; the same goal; N = the plan's remaining nodes.
    moved = replace(problem, x0=tuple(plan.states[k]), n_intervals=problem.n_intervals - k)
    remainder = plan.remainder(plan.time_grid[k])
    assert remainder.controls.shape == (700, 2)
    np.testing.assert_array_equal(remainder.states[0], plan.states[k])
    warm = solve(moved, initial_guess=remainder)
    cold = solve(moved)
    assert warm.status is Status.SOLVED and cold.status is Status.SOLVED
    assert warm.final_time == pytest.approx(cold.final_time, rel=1e-6)
    # Bellman: the rest of an optimal plan is optimal from its state on the same grid.
    assert warm.final_time == pytest.approx(remainder.final_time, rel=1e-6)
    assert warm.iterations <= 0.2 * cold.iterations, (warm.iterations, cold.iterations)
    nm.assert_feasible(moved, warm)
    # The bare pair (controls, remaining time), resampled to another N, and from a state the
    # robot drifted to: still the same optimum.
    drifted = replace(problem, x0=tuple(plan.states[k] + np.array([0.002, -0.01, 0.003, 0.0])))
    pair = solve(drifted, initial_guess=(plan.controls[k:], remainder.final_time))
    assert pair.status is Status.SOLVED, pair.message
    assert pair.final_time == pytest.approx(solve(drifted).final_time, rel=1e-5)
    nm.assert_feasible(drifted, pair)


@pytest.mark.parametrize('guess, words', [
    ((np.zeros((10, 3)), 2.0), 'M x 2'),
    ((np.zeros((10, 2)), -1.0), 'positive final time'),
    ((np.full((10, 2), np.nan), 2.0), 'finite'),
    ('not a guess', 'bad initial guess'),
])
def test_bad_initial_guesses_are_refused(guess, words):
    result = solve(Problem.paper(n_intervals=100), initial_guess=guess)
    assert result.status is Status.INVALID_INPUT
    assert words in result.message


def test_paper_mode_refuses_other_models_and_initial_guesses():
    planar = CASES['planar_2r_gravity']
    result = solve(planar, SolverOptions(mode='paper'))
    assert result.status is Status.INVALID_INPUT and 'cylindrical' in result.message
    result = solve(Problem.paper(n_intervals=50), SolverOptions(mode='paper'),
                   initial_guess=(np.zeros((50, 2)), 2.0))
    assert result.status is Status.INVALID_INPUT and 'fast mode only' in result.message


def test_planar_2r_is_solved_and_feasible_for_both_links():
    model = load_model('planar_2r')
    problem = Problem(model=model, x0=tuple(model.state([0.0, 0.5])),
                      x_goal=tuple(model.state([1.4, 0.3])), n_intervals=200, t_f0=1.0,
                      obstacles=((1.3, 1.1, 0.15), (-0.5, 0.4, 0.2)))
    result = solve(problem)
    assert result.status is Status.SOLVED, result.message
    assert np.all(np.abs(result.controls) <= np.asarray(model.u_max))
    # The reported states reach the goal, and every link clears every inflated circle,
    # measured by the numpy geometry (independent of the kernels).
    states = result.states
    assert np.linalg.norm(states[-1] - np.asarray(problem.x_goal)) <= 1e-6
    prm = model.params
    clearance = nm.segment_clearance(nm.chain_segments(states[:, 0::2], (prm.l1, prm.l2)),
                                     problem.circles())
    assert clearance.shape == (201, 4)
    assert clearance.min() >= -1e-6
