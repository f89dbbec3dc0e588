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
Primal-dual interior point for minimum-time arm trajectories (Euler, free final time).

Variables: the final time T, the states x_1..x_{N-1} (x_0 = start and x_N = goal are fixed),
the scaled controls v_k = u_k / effort in [-1, 1].  Constraints: the Euler defects
x_k + (T/N) f(x_k, u_k) - x_{k+1} = 0 (k = 0..N-1, the last one reaching the goal), position
and velocity boxes at the free nodes (the fixed end nodes are checked before solving),
the sphere constraints g(q_k) - s = 0 with slacks s >= 0, and T in [T_LOW, T_HIGH].

Each iteration follows IPOPT's primal-dual scheme (Waechter & Biegler 2006) in a reduced form:
bound and slack duals are condensed into the stage blocks, the Newton step comes from the
compiled Riccati recursion (riccati_euler.py for Euler steps, the goal state eliminated;
riccati.py for RK4 steps) with an inertia correction (a multiple of the identity added to
the Hessian until every reduced Hessian is positive definite), the step length from
the fraction-to-the-boundary rule and IPOPT's filter line search (arm_line_search.py), and the
barrier parameter falls monotonically (mu <- max(mu_min, min(0.2 mu, mu^1.5)) once the barrier
problem is solved to 10 mu).  The
per-stage arithmetic of an iteration (errors, barrier blocks, steps to the boundary, merit,
dual safeguard) is compiled (ipm_kernels.py); this class keeps the logic.

The first barrier parameter is MU_INIT = 1e-4, not IPOPT's 0.1: the objective is T (order
1 s) against thousands of bound terms (about 30 per interval), so at mu = 0.1 the barrier
dominates and the first barrier problems' solutions lie far from the optimum (T rose to 8 s
on the Panda scenario before coming back).  Measured on 16 Panda/UR5 scenarios (free, 1 and 3
spheres, N = 50..200): 1e-4 solved all 16 with 1.7 times fewer iterations in total (one
scenario took one more), 0.1 stopped at the iteration limit on two (UR5, 3 spheres), which
its total counts; neighbouring values (1e-3, 3e-5) failed on some, so the iteration count
depends erratically on this value.  solve_arm's restart after a failure starts with
MU_INIT_RETRY = 0.1.

Second-order information (hessian=): 'none' (default) keeps the sphere rows' exact curvature
and the bound/slack barrier terms but no curvature of the dynamics (a Gauss-Newton-like model:
one Pinocchio derivative call per interval); 'cross' adds the exact curvature between the
final time and the states and controls (the steps are h f, h = T / N: lam . df / N, from the
same call); 'exact' adds the dynamics' curvature by forward differences of Pinocchio's
analytical derivatives (2 n + 1 calls per interval, see arm_eval.py; RK4 steps:
rk4_steps.py, which have no 'cross' and start with 'none').  The cheap models
converge on most problems in 10-30 iterations at a fraction of the cost; where the
dynamics' curvature matters they wander without converging, and solve_arm then switches the
same run to 'exact' (cold_runs.run_ipm, which starts with 'cross'; the attribute hessian is
read every iteration).  A proximal term rho I (a
trust region in Levenberg-Marquardt form: raised when the line search backtracks, lowered
after full steps) bounds the steps where the model has little curvature; it changes the
steps, never the convergence test.

Convergence is IPOPT's test on the original problem: scaled dual infeasibility and
complementarity <= tol and the constraint violation (defects, sphere rows) <= constr_tol,
all measured with exact first derivatives; or IPOPT's acceptable level (<= ACCEPT_TOL for
ACCEPT_ITERATIONS iterations in a row, constraints still <= constr_tol), the rule of the
planar fast mode.  The minimum-time arm problems are degenerate (controls of the joints that
do not set the time are not unique), and the last digits of the dual infeasibility are then
limited by the conditioning of the regularised Newton system.
"""

import math
import time

import numpy as np

from . import ipm_kernels, riccati, riccati_euler
from .arm_line_search import FilterLineSearch
from ..barrier_start import crowding_share

T_LOW = 1e-3
T_HIGH = 100.0
MU_INIT = 1e-4
MU_INIT_RETRY = 0.1
KAPPA_EPS = 10.0
KAPPA_SIGMA = 1e10
S_MAX = 100.0
DELTA_FIRST = 1e-4
DELTA_MAX = 1e40
ACCEPT_TOL = 1e-6
# The first proximal weight: small from a cold start, whose first steps from the line start
# are mostly full ones (1.0 cost every Euler cold solve the iterations that lowered it;
# benchmarks/RESULTS.md, "Arms: a smaller first proximal weight") ... but PROX_GUARDED on
# RK4 steps, whose cheap model has no curvature of the dynamics (rk4_steps.py: the proximal
# term is all the curvature their first steps have; from 1e-4 a UR5 RK4 solve failed its
# line search),
# and from a primal guess without multipliers (start(prox=...)), which it keeps from
# wandering off while the multipliers form (6 iterations on the plan, 14 from 1e-4).
PROX_INIT = 1e-4
PROX_GUARDED = 1.0
PROX_MAX = 1e8
# The Newton step of Euler steps eliminates the goal state through the last two intervals'
# controls (riccati_euler.py): its inertia test is the one on the constraints' null space.
# RK4 steps (riccati.py) carry the goal's multipliers and put the curvature
# TERMINAL_CURVATURE_RK4 |dx_N|^2 / 2 on the goal, which never changes a step (dx_N = 0 is
# imposed) but enters the stage-by-stage inertia test of the last intervals; a large value
# makes that the null space's test (Euler steps ran with 1e4 until they eliminated the goal:
# benchmarks/RESULTS.md, "The goal's curvature"), but RK4 steps (measured while they had no
# curvature of the dynamics) keep 1: the UR5 at N = 10 stalled with 10-1e4 (its line start
# fails with 1 too; the slowed line then converges).
TERMINAL_CURVATURE_RK4 = 1.0
ACCEPT_ITERATIONS = 10
# How far (relative to the bound, at least absolute) a start point is pushed inside its bounds:
# a cold start needs room to move; a warm start keeps its active bounds nearly active.
COLD_PUSH = 1e-2
# The multipliers a warm start takes over; every array's first axis is the plan's node or
# interval (sliced alike by SolveResult.remainder).
DUAL_NAMES = ('lam', 'z', 'zlx', 'zux', 'zlv', 'zuv', 'zlt', 'zut')
# A start on a position limit pins the first node there (an Euler step's positions are
# q0 + h v0: at rest, q0), which leaves that bound no interior: the barrier cannot start (the
# Z1 from its home pose, joint 2 on its limit: 2000 iterations, MAX_ITERATIONS). Such a bound
# is moved out by BOUND_RELAX (relative to max(1, |bound|)), as IPOPT's bound_relax_factor
# moves every bound: far below arm_solve.BOUND_TOL, which still judges the result against the
# URDF's limit.
BOUND_RELAX = 1e-12


def relaxed_bounds(lower, upper, start):
    """(lower, upper) with the bounds that start sits on (within BOUND_RELAX) moved out."""
    lower, upper = np.array(lower, dtype=float), np.array(upper, dtype=float)
    with np.errstate(invalid='ignore'):
        low_relax = BOUND_RELAX * np.maximum(1.0, np.abs(lower))
        high_relax = BOUND_RELAX * np.maximum(1.0, np.abs(upper))
        on_lower = start - lower < low_relax
        on_upper = upper - start < high_relax
    lower[on_lower] -= low_relax[on_lower]
    upper[on_upper] += high_relax[on_upper]
    return lower, upper


class ArmIpmResult:
    """Outcome of ArmInteriorPoint.run (see its docstring)."""

    def __init__(self, **fields):
        self.__dict__.update(fields)


class ArmInteriorPoint(FilterLineSearch):
    """One minimum-time problem for an ArmEvaluator; run() iterates from a start point."""

    def __init__(self, evaluator, x0, x_goal, tol=1e-8, constr_tol=1e-9, hessian='none',
                 mu_init=MU_INIT, mu_min=None):
        self.ev = evaluator
        n = evaluator.n
        arm = evaluator.arm
        self.n, self.nx, self.n_int = n, 2 * n, evaluator.n_int
        self.x0 = np.asarray(x0, dtype=float)
        self.x_goal = np.asarray(x_goal, dtype=float)
        lower, upper = relaxed_bounds(arm.lower, arm.upper, self.x0[:n])
        self.lx = np.concatenate([lower, -arm.velocity])
        self.ux = np.concatenate([upper, arm.velocity])
        self.has_l = np.isfinite(self.lx)
        self.has_u = np.isfinite(self.ux)
        self.tol = tol
        self.hessian = hessian
        self.constr_tol = constr_tol
        self.mu_min = tol / 10.0 if mu_min is None else mu_min
        self.mu_init = mu_init
        self.accept_iterations = ACCEPT_ITERATIONS
        # A warm start at the solution of the same problem (a remainder of a plan, the robot on
        # it) is taken as it is when already acceptable: its solve met the acceptable level.
        self.accept_at_start = False
        n_int, nx = self.n_int, self.nx
        # Euler steps: the Riccati step with the goal state eliminated (riccati_euler.py).
        self.euler_step = evaluator.integrator == 'euler' and n_int >= 2
        self.work = (riccati_euler.work_arrays_euler(n_int, nx, n) if self.euler_step
                     else riccati.work_arrays(n_int, nx, n))
        self.linalg_time = 0.0
        self.factorizations = 0
        self.primal = self.e0 = math.inf
        self._no_curvature = np.zeros((0, 0, 0))

    # Start point ---------------------------------------------------------------------------
    def start(self, states, controls, t_f, duals=None, push=COLD_PUSH, prox=None):
        """
        Set the primal point, pushed strictly inside the bounds by push (relative), and duals.

        duals (warm start: ArmIpmResult.duals() of a run on the same grid, e.g. the remainder
        of a plan): its multipliers, re-centred for mu_init by IPOPT's kappa_sigma safeguard;
        without them, every bound and sphere dual is mu / slack (a cold start).  prox: the
        first proximal weight (None: PROX_INIT, PROX_GUARDED on RK4 steps); duals bring theirs.
        """
        self.ev.forget_curvature()
        x = np.array(states, dtype=float)
        x[0], x[-1] = self.x0, self.x_goal
        room = 0.25 * (self.ux - self.lx)
        step = push * np.maximum(1.0, np.abs(np.where(self.has_l, self.lx, 0.0)))
        low = np.where(self.has_l, self.lx + np.minimum(step, room), -np.inf)
        step = push * np.maximum(1.0, np.abs(np.where(self.has_u, self.ux, 0.0)))
        high = np.where(self.has_u, self.ux - np.minimum(step, room), np.inf)
        x[1:-1] = np.clip(x[1:-1], low, high)
        self.x = x
        self.v = np.clip(np.asarray(controls, dtype=float) / self.ev.effort,
                         -1.0 + push, 1.0 - push)
        self.t = float(min(max(t_f, 10 * T_LOW), 0.5 * T_HIGH))
        self.mu = self.mu_init if duals is not None else max(
            self.mu_min, self.mu_init * self.crowding_share())
        g = self.ev.clearances(self.x[1:-1, :self.n])
        self.s = np.maximum(g, push)
        self.z = self.mu / self.s
        self.lam = np.zeros((self.n_int + 1, self.nx))
        lo, hi = self._slacks(self.x, self.v, self.t)
        self.zlx = np.where(self.has_l, self.mu / lo[0], 0.0)
        self.zux = np.where(self.has_u, self.mu / hi[0], 0.0)
        self.zlv, self.zuv = self.mu / lo[1], self.mu / hi[1]
        self.zlt, self.zut = self.mu / lo[2], self.mu / hi[2]
        if prox is None:
            prox = PROX_GUARDED if self.ev.integrator == 'rk4' else PROX_INIT
        self.prox = prox
        if duals is not None:
            for name in DUAL_NAMES:
                if name not in duals:
                    continue        # e.g. the sphere duals after the obstacles changed
                value = duals[name]
                setattr(self, name, np.array(value, dtype=float) if np.ndim(value) else
                        float(value))
            self.prox = float(duals['prox'])
            self._safeguard_duals()
        self.rescale_duals = duals is not None
        self.penalty = 1.0
        self.delta_last = 0.0
        self.new_filter()

    def crowding_share(self):
        """Return the factor on the barrier parameter of a start without multipliers."""
        # Barrier terms: the controls' and states' bounds, one slack per sphere row
        # (barrier_start.py: a wall of 25 spheres off the Panda's motion took 125 iterations).
        n_int = self.n_int
        bounds = 2 * self.n * n_int + (np.count_nonzero(self.has_l)
                                       + np.count_nonzero(self.has_u)) * (n_int - 1)
        return crowding_share(bounds, self.ev.n_pairs * (n_int - 1))

    def duals(self):
        """Return the multipliers and the proximal weight (start(duals=...) of another run)."""
        out = {name: np.copy(getattr(self, name)) for name in DUAL_NAMES}
        out['prox'] = self.prox
        return out

    def _slacks(self, x, v, t):
        """((x - lx, v + 1, T - T_LOW), (ux - x, 1 - v, T_HIGH - T)); inf where unbounded."""
        inner = x[1:-1]
        lo = np.where(self.has_l, inner - np.where(self.has_l, self.lx, 0.0), np.inf)
        hi = np.where(self.has_u, np.where(self.has_u, self.ux, 0.0) - inner, np.inf)
        return (lo, v + 1.0, t - T_LOW), (hi, 1.0 - v, T_HIGH - t)

    # Residuals -----------------------------------------------------------------------------
    def _bounds(self):
        """Return the bound arguments shared by the compiled kernels."""
        return self.lx, self.ux, self.has_l, self.has_u, T_LOW, T_HIGH

    def _errors(self, terms, grads, g):
        """(dual infeasibility, primal infeasibility, complementarity at mu = 0, s_d, s_c)."""
        return ipm_kernels.kkt_errors(
            self.lam, terms['a'], terms['b'], terms['c'], terms['defect'], grads, g, self.s,
            self.z, self.x[1:-1], self.v, self.t, self.zlx, self.zux, self.zlv, self.zuv,
            self.zlt, self.zut, *self._bounds(), S_MAX)

    def _barrier_error(self, dual, primal, s_d, s_c):
        compl = ipm_kernels.complementarity(
            self.x[1:-1], self.v, self.t, self.s, self.z, self.zlx, self.zux, self.zlv,
            self.zuv, self.zlt, self.zut, *self._bounds(), self.mu)
        return max(dual / s_d, primal, compl / s_c)

    # One iteration -------------------------------------------------------------------------
    def _qp_blocks(self, terms, values, grads, curvature):
        """Hessian and gradient blocks of the condensed barrier QP at the current point."""
        n_int, n, nx = self.n_int, self.n, self.nx
        hxx = np.empty((n_int, nx + 1, nx + 1))
        gx = np.empty((n_int, nx + 1))
        huu_diag = np.empty((n_int, n))
        gu = np.empty((n_int, n))
        ipm_kernels.qp_blocks(
            terms['hxx'], grads, values, self._no_curvature if curvature is None else curvature,
            self.s, self.z, self.x[1:-1], self.v, self.t, self.zlx, self.zux, self.zlv,
            self.zuv, self.zlt, self.zut, *self._bounds(), self.mu, hxx, gx, huu_diag, gu)
        return hxx, terms['hux'], huu_diag, gx, gu

    def _newton_step(self, terms, hxx, hux, huu_diag, gx, gu):
        """Riccati step with inertia correction: (dx, dv, dT, lam_qp) or None."""
        n_int, n, nx = self.n_int, self.n, self.nx
        hxx_reg = np.empty_like(hxx)
        huu = np.empty((n_int, n, n))
        delta = 0.0
        dx = np.zeros((n_int + 1, nx))
        dv = np.zeros((n_int, n))
        lam = np.zeros((n_int + 1, nx))
        nu = np.zeros(nx)
        started = time.perf_counter()
        while True:
            # The proximal term (a trust region in Levenberg-Marquardt form) bounds the steps
            # where the model has little curvature; it vanishes as full steps are accepted.
            ipm_kernels.regularised(hxx, huu_diag, self.prox, delta, hxx_reg, huu)
            if 'huu' in terms:
                huu += terms['huu']     # (RK4 steps' exact curvature: not affine in torques)
            if self.euler_step:
                code, d_t = riccati_euler.riccati_solve_euler(
                    terms['a'], terms['b'], terms['c'], terms['defect'], hxx_reg, hux, huu,
                    gx, gu, *self.work, dx, dv, lam)
            else:
                code, d_t = riccati.riccati_solve(
                    terms['a'], terms['b'], terms['c'], terms['defect'], hxx_reg, hux, huu,
                    gx, gu, TERMINAL_CURVATURE_RK4, *self.work, dx, dv, lam, nu)
            self.factorizations += 1
            if code == riccati.OK and np.isfinite(d_t) and np.all(np.isfinite(dx)):
                break
            if code == riccati_euler.SINGULAR_STEP:
                self.linalg_time += time.perf_counter() - started
                return None         # (no multiple of the identity on H mends the steps' B)
            if delta == 0.0:
                delta = DELTA_FIRST if self.delta_last == 0.0 else max(
                    DELTA_FIRST * 1e-4, self.delta_last / 3.0)
            else:
                delta *= 8.0
            if delta > DELTA_MAX:
                self.linalg_time += time.perf_counter() - started
                return None
        self.delta_last = delta
        self.linalg_time += time.perf_counter() - started
        dx[0] = 0.0
        dx[-1] = 0.0
        return dx, dv, d_t, lam, delta

    def _rescale_duals(self, terms):
        """
        Scale a warm start's multipliers so that its stationarity in T holds; True if scaled.

        Stationarity in the states and controls is homogeneous in the multipliers (the
        objective is T alone), so one factor fixes the T row without disturbing them.  A
        remainder's multipliers miss that row by the change of the discrete Hamiltonian over
        the part cut off (constant in continuous time, O(h) here), which otherwise costs
        iterations.
        """
        lam_part = float(np.einsum('ki,ki->', terms['c'], self.lam[1:]))
        total = lam_part - self.zlt + self.zut
        if not (math.isfinite(total) and total < 0.0):
            return False
        scale = -1.0 / total
        if not 0.5 <= scale <= 2.0:
            return False
        for name in DUAL_NAMES:
            setattr(self, name, getattr(self, name) * scale)
        return True

    def at_last_barrier(self):
        """Return True once the barrier parameter is at its last value (mu_min)."""
        return self.mu <= 1.5 * self.mu_min     # (mu^1.5 rounds a little above mu_min)

    def run(self, max_iterations=200, should_stop=None):
        """
        Iterate until convergence; return an ArmIpmResult.

        status: 'converged', 'acceptable' (IPOPT's acceptable level, module docstring),
        'max_iterations', 'line_search_failed', 'numerical_failure' or 'stopped'
        (should_stop() returned True); x, v, t, iterations, history (rows: T,
        primal infeasibility, E_0, mu, alpha, delta), dual, primal, compl.
        """
        n = self.n
        history = []
        status = 'max_iterations'
        dual = primal = compl = math.inf
        iteration = 0
        self.last_alpha = None
        acceptable = 0
        while True:
            terms = self.ev.stage_terms(self.x, self.v, self.t, self.lam, self.hessian)
            if self.rescale_duals:
                # (before the sphere rows: their curvature is weighted by the rescaled duals)
                self.rescale_duals = False
                self._rescale_duals(terms)
            values, grads, curvature = self.ev.clearance_terms(self.x[1:-1, :n], self.z)
            dual, primal, compl, s_d, s_c = self._errors(terms, grads, values)
            e0 = max(dual / s_d, compl / s_c)
            self.primal, self.e0 = primal, e0    # (read by should_stop callbacks: cold_runs.py)
            if not np.isfinite(e0 + primal):
                status = 'numerical_failure'
                break
            if e0 <= self.tol and primal <= self.constr_tol:
                status = 'converged'
                break
            # IPOPT's acceptable termination (as fast mode's ipm.py): E_0 <= ACCEPT_TOL for
            # ACCEPT_ITERATIONS iterations in a row with the full constraint tolerance.
            acceptable = acceptable + 1 if (e0 <= ACCEPT_TOL
                                            and primal <= self.constr_tol) else 0
            if acceptable >= self.accept_iterations or (
                    acceptable and iteration == 0 and self.accept_at_start):
                status = 'acceptable'
                break
            if iteration >= max_iterations:
                break
            if should_stop is not None and should_stop():
                status = 'stopped'
                break
            while (self.mu > self.mu_min
                   and self._barrier_error(dual, primal, s_d, s_c) <= KAPPA_EPS * self.mu):
                self.mu = max(self.mu_min, min(0.2 * self.mu, self.mu ** 1.5))
                self.filter = []
            blocks = self._qp_blocks(terms, values, grads, curvature)
            step = self._newton_step(terms, *blocks)
            if step is None:
                status = 'numerical_failure'
                break
            dx, dv, d_t, lam_qp, delta = step
            alpha = self._line_search(terms, values, grads, dx, dv, d_t, lam_qp)
            self.last_alpha = alpha
            iteration += 1
            history.append((self.t, primal, e0, self.mu, alpha, delta + self.prox))
            if alpha is not None:
                # Backtracking (not the fraction to the boundary) means the model was trusted
                # too far: raise the proximal weight; full steps lower it.
                ratio = alpha / self.alpha_max
                if ratio >= 0.5:
                    self.prox = self.prox / 4.0 if self.prox > 1e-10 else 0.0
                elif ratio < 0.1:
                    self.prox = min(PROX_MAX, max(self.prox, 1e-4) * 4.0)
            if alpha is None:
                status = 'line_search_failed'
                break
        return ArmIpmResult(status=status, x=self.x.copy(), v=self.v.copy(), t=self.t,
                            iterations=iteration, history=np.array(history).reshape(-1, 6),
                            dual=dual, primal=primal, compl=compl, duals=self.duals(),
                            mu=self.mu)

    def _safeguard_duals(self):
        """Keep every bound dual within [mu / (k slack), k mu / slack] (IPOPT's kappa_sigma)."""
        mu = self.mu
        ipm_kernels.safeguard_duals(self.x[1:-1], self.v, self.s, self.z, self.zlx, self.zux,
                                    self.zlv, self.zuv, self.lx, self.ux, self.has_l,
                                    self.has_u, mu, KAPPA_SIGMA)
        self.zlt = min(max(self.zlt, mu / (KAPPA_SIGMA * (self.t - T_LOW))),
                       KAPPA_SIGMA * mu / (self.t - T_LOW))
        self.zut = min(max(self.zut, mu / (KAPPA_SIGMA * (T_HIGH - self.t))),
                       KAPPA_SIGMA * mu / (T_HIGH - self.t))
