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
compiled Riccati recursion (riccati.py) with an inertia correction (a multiple of the identity
added to the Hessian until every reduced Hessian is positive definite), the step length from
the fraction-to-the-boundary rule and IPOPT's filter line search (with its switching rule and
one filter reset), and the barrier parameter falls monotonically
(mu <- max(mu_min, min(0.2 mu, mu^1.5)) once the barrier problem is solved to 10 mu).

Second-order information (hessian=): 'none' (default) keeps the sphere rows' exact curvature
and the bound/slack barrier terms but no curvature of the dynamics (a Gauss-Newton-like model:
one Pinocchio derivative call per interval); 'exact' adds the dynamics' curvature by forward
differences of Pinocchio's analytical derivatives (2 n + 1 calls per interval, see
arm_eval.py).  On the Panda and UR5 scenarios (N = 20, 50) both took similar iteration counts
and failed on the same cases, so the cheap model is the default.  A proximal term rho I (a
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

from . import riccati

T_LOW = 1e-3
T_HIGH = 100.0
MU_INIT = 0.1
KAPPA_EPS = 10.0
KAPPA_SIGMA = 1e10
S_MAX = 100.0
ARMIJO = 1e-4
MIN_ALPHA = 1e-12
DELTA_FIRST = 1e-4
DELTA_MAX = 1e40
ACCEPT_TOL = 1e-6
PROX_INIT = 1.0
PROX_MAX = 1e8
ACCEPT_ITERATIONS = 10
ROUNDING = 10.0 * np.finfo(float).eps


class ArmIpmResult:
    """Outcome of ArmInteriorPoint.run (see its docstring)."""

    def __init__(self, **fields):
        self.__dict__.update(fields)


class ArmInteriorPoint:
    """One minimum-time problem for an ArmEvaluator; run() iterates from a start point."""

    def __init__(self, evaluator, x0, x_goal, tol=1e-8, constr_tol=1e-9, hessian='none'):
        self.ev = evaluator
        n = evaluator.n
        arm = evaluator.arm
        self.n, self.nx, self.n_int = n, 2 * n, evaluator.n_int
        self.x0 = np.asarray(x0, dtype=float)
        self.x_goal = np.asarray(x_goal, dtype=float)
        self.lx = np.concatenate([arm.lower, -arm.velocity])
        self.ux = np.concatenate([arm.upper, arm.velocity])
        self.has_l = np.isfinite(self.lx)
        self.has_u = np.isfinite(self.ux)
        self.tol = tol
        self.hessian = hessian
        self.constr_tol = constr_tol
        self.mu_min = tol / 10.0
        n_int, nx = self.n_int, self.nx
        self.work = (np.zeros((n_int + 1, nx + 1, nx + 1)), np.zeros((n_int + 1, nx + 1, 1 + nx)),
                     np.zeros((n_int, n, nx + 1)), np.zeros((n_int, n, 1 + nx)),
                     np.zeros((n_int + 1, nx + 1, 1 + nx)), np.zeros((n_int, n, 1 + nx)))
        self.linalg_time = 0.0
        self.factorizations = 0

    # Start point ---------------------------------------------------------------------------
    def start(self, states, controls, t_f):
        """Set the primal point, pushed strictly inside the bounds, and the duals."""
        x = np.array(states, dtype=float)
        x[0], x[-1] = self.x0, self.x_goal
        push = 1e-2 * np.maximum(1.0, np.abs(np.where(self.has_l, self.lx, 0.0)))
        low = np.where(self.has_l, self.lx + np.minimum(push, 0.25 * (self.ux - self.lx)),
                       -np.inf)
        push = 1e-2 * np.maximum(1.0, np.abs(np.where(self.has_u, self.ux, 0.0)))
        high = np.where(self.has_u, self.ux - np.minimum(push, 0.25 * (self.ux - self.lx)),
                        np.inf)
        x[1:-1] = np.clip(x[1:-1], low, high)
        self.x = x
        self.v = np.clip(np.asarray(controls, dtype=float) / self.ev.effort, -0.99, 0.99)
        self.t = float(min(max(t_f, 10 * T_LOW), 0.5 * T_HIGH))
        self.mu = MU_INIT
        g = self.ev.clearances(self.x[1:-1, :self.n])
        self.s = np.maximum(g, 1e-2)
        self.z = self.mu / self.s
        self.lam = np.zeros((self.n_int + 1, self.nx))
        lo, hi = self._slacks(self.x, self.v, self.t)
        self.zlx = np.where(self.has_l, self.mu / lo[0], 0.0)
        self.zux = np.where(self.has_u, self.mu / hi[0], 0.0)
        self.zlv, self.zuv = self.mu / lo[1], self.mu / hi[1]
        self.zlt, self.zut = self.mu / lo[2], self.mu / hi[2]
        self.penalty = 1.0
        self.delta_last = 0.0
        self.prox = PROX_INIT
        self.filter = []
        self.theta_max = None
        self.theta_min = None

    def _slacks(self, x, v, t):
        """((x - lx, v + 1, T - T_LOW), (ux - x, 1 - v, T_HIGH - T)); inf where unbounded."""
        inner = x[1:-1]
        lo = np.where(self.has_l, inner - np.where(self.has_l, self.lx, 0.0), np.inf)
        hi = np.where(self.has_u, np.where(self.has_u, self.ux, 0.0) - inner, np.inf)
        return (lo, v + 1.0, t - T_LOW), (hi, 1.0 - v, T_HIGH - t)

    # Residuals -----------------------------------------------------------------------------
    def _errors(self, terms, grads, g):
        """(E_0 scaled, primal infeasibility, complementarity at mu = 0, dual infeasibility)."""
        n = self.n
        lam = self.lam
        dual_x = (-lam[1:-1] + np.einsum('kij,ki->kj', terms['a'][1:], lam[2:])
                  - self.zlx + self.zux)
        if grads.shape[1]:
            dual_x[:, :n] -= np.einsum('kpn,kp->kn', grads, self.z)
        dual_v = np.einsum('kij,ki->kj', terms['b'], lam[1:]) - self.zlv + self.zuv
        dual_t = 1.0 + np.sum(terms['c'] * lam[1:]) - self.zlt + self.zut
        dual = max(np.max(np.abs(dual_x), initial=0.0), np.max(np.abs(dual_v)), abs(dual_t))
        primal = max(np.max(np.abs(terms['defect'])),
                     np.max(np.abs(g - self.s), initial=0.0))
        lo, hi = self._slacks(self.x, self.v, self.t)
        compl = max(np.max(np.where(self.has_l, lo[0] * self.zlx, 0.0), initial=0.0),
                    np.max(np.where(self.has_u, hi[0] * self.zux, 0.0), initial=0.0),
                    np.max(lo[1] * self.zlv), np.max(hi[1] * self.zuv),
                    lo[2] * self.zlt, hi[2] * self.zut,
                    np.max(self.s * self.z, initial=0.0))
        bound_duals = (np.sum(np.abs(self.zlx)) + np.sum(np.abs(self.zux))
                       + np.sum(self.zlv) + np.sum(self.zuv) + self.zlt + self.zut
                       + np.sum(self.z))
        count = (np.count_nonzero(self.zlx) + np.count_nonzero(self.zux) + 2 * self.v.size
                 + 2 + self.z.size)
        s_d = max(S_MAX, (np.sum(np.abs(lam)) + bound_duals) / max(count + lam.size, 1)) / S_MAX
        s_c = max(S_MAX, bound_duals / max(count, 1)) / S_MAX
        return dual, primal, compl, s_d, s_c

    def _barrier_error(self, dual, primal, s_d, s_c):
        lo, hi = self._slacks(self.x, self.v, self.t)
        mu = self.mu
        compl = max(np.max(np.where(self.has_l, np.abs(lo[0] * self.zlx - mu), 0.0),
                           initial=0.0),
                    np.max(np.where(self.has_u, np.abs(hi[0] * self.zux - mu), 0.0),
                           initial=0.0),
                    np.max(np.abs(lo[1] * self.zlv - mu)), np.max(np.abs(hi[1] * self.zuv - mu)),
                    abs(lo[2] * self.zlt - mu), abs(hi[2] * self.zut - mu),
                    np.max(np.abs(self.s * self.z - mu), initial=0.0))
        return max(dual / s_d, primal, compl / s_c)

    # One iteration -------------------------------------------------------------------------
    def _qp_blocks(self, terms, values, grads, curvature):
        """Hessian and gradient blocks of the condensed barrier QP at the current point."""
        n, nx, mu = self.n, self.nx, self.mu
        hxx = terms['hxx'].copy()
        hux = terms['hux'].copy()
        lo, hi = self._slacks(self.x, self.v, self.t)
        inner = hxx[1:, :nx, :nx]
        sig_x = (np.where(self.has_l, self.zlx / lo[0], 0.0)
                 + np.where(self.has_u, self.zux / hi[0], 0.0))
        idx = np.arange(nx)
        inner[:, idx, idx] += sig_x
        gx = np.zeros((self.n_int, nx + 1))
        gx[1:, :nx] = (np.where(self.has_l, -mu / lo[0], 0.0)
                       + np.where(self.has_u, mu / hi[0], 0.0))
        if grads.shape[1]:
            sig_s = self.z / self.s
            r = values - self.s
            inner[:, :n, :n] += np.einsum('kpi,kp,kpj->kij', grads, sig_s, grads) - curvature
            gx[1:, :n] += np.einsum('kpn,kp->kn', grads, sig_s * r - mu / self.s)
        hxx[0, nx, nx] += self.zlt / lo[2] + self.zut / hi[2]
        gx[0, nx] = 1.0 - mu / lo[2] + mu / hi[2]
        huu_diag = self.zlv / lo[1] + self.zuv / hi[1]
        gu = -mu / lo[1] + mu / hi[1]
        return hxx, hux, huu_diag, gx, gu

    def _newton_step(self, terms, hxx, hux, huu_diag, gx, gu):
        """Riccati step with inertia correction: (dx, dv, dT, lam_qp) or None."""
        n_int, n, nx = self.n_int, self.n, self.nx
        eye_x = np.eye(nx + 1)
        eye_u = np.eye(n)
        # The proximal term (a trust region in Levenberg-Marquardt form) bounds the steps
        # where the model has little curvature; it vanishes as full steps are accepted.
        hxx = hxx + self.prox * eye_x
        huu0 = (huu_diag + self.prox)[:, :, None] * eye_u[None]
        delta = 0.0
        dx = np.zeros((n_int + 1, nx))
        dv = np.zeros((n_int, n))
        lam = np.zeros((n_int + 1, nx))
        nu = np.zeros(nx)
        started = time.perf_counter()
        while True:
            code, d_t = riccati.riccati_solve(
                terms['a'], terms['b'], terms['c'], terms['defect'],
                hxx + delta * eye_x if delta else hxx, hux, huu0 + delta * eye_u,
                gx, gu, 1.0, *self.work, dx, dv, lam, nu)
            self.factorizations += 1
            if code == riccati.OK and np.isfinite(d_t) and np.all(np.isfinite(dx)):
                break
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

    def _merit(self, x, v, t, s, defect, values):
        lo, hi = self._slacks(x, v, t)
        if (np.any(lo[0] <= 0) or np.any(hi[0] <= 0) or np.any(lo[1] <= 0)
                or np.any(hi[1] <= 0) or lo[2] <= 0 or hi[2] <= 0 or np.any(s <= 0)):
            return math.inf, math.inf
        phi = t - self.mu * (np.sum(np.log(lo[0][np.broadcast_to(self.has_l, lo[0].shape)]))
                             + np.sum(np.log(hi[0][np.broadcast_to(self.has_u, hi[0].shape)]))
                             + np.sum(np.log(lo[1])) + np.sum(np.log(hi[1]))
                             + math.log(lo[2]) + math.log(hi[2]) + np.sum(np.log(s)))
        theta = np.sum(np.abs(defect)) + np.sum(np.abs(values - s))
        return phi, theta

    def _in_filter(self, theta, phi):
        return any(theta >= f_theta and phi >= f_phi for f_theta, f_phi in self.filter)

    @staticmethod
    def _max_step(value, step, frac):
        neg = step < 0
        if not np.any(neg):
            return 1.0
        return float(min(1.0, np.min(-frac * value[neg] / step[neg])))

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
        acceptable = 0
        while True:
            terms = self.ev.stage_terms(self.x, self.v, self.t, self.lam, self.hessian)
            values, grads, curvature = self.ev.clearance_terms(
                self.x[1:-1, :n], self.z)
            dual, primal, compl, s_d, s_c = self._errors(terms, grads, values)
            e0 = max(dual / s_d, compl / s_c)
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
            if acceptable >= ACCEPT_ITERATIONS:
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
                            dual=dual, primal=primal, compl=compl, lam=self.lam.copy(),
                            z=self.z.copy())

    def _line_search(self, terms, values, grads, dx, dv, d_t, lam_qp):
        """Backtracking on the l1 merit; updates the iterate and duals; returns alpha."""
        n, mu = self.n, self.mu
        frac = max(0.99, 1.0 - mu)
        lo, hi = self._slacks(self.x, self.v, self.t)
        inner = dx[1:-1]
        ds = values - self.s + (np.einsum('kpn,kn->kp', grads, inner[:, :n])
                                if grads.shape[1] else np.zeros_like(self.s))
        alpha_max = min(
            self._max_step(lo[0][:, self.has_l], inner[:, self.has_l], frac),
            self._max_step(hi[0][:, self.has_u], -inner[:, self.has_u], frac),
            self._max_step(lo[1], dv, frac), self._max_step(hi[1], -dv, frac),
            self._max_step(np.array([lo[2]]), np.array([d_t]), frac),
            self._max_step(np.array([hi[2]]), np.array([-d_t]), frac),
            self._max_step(self.s, ds, frac) if self.s.size else 1.0)
        # Bound-dual steps of the condensed system.
        sig = (lambda zv, sv: zv / sv)
        dzlx = np.where(self.has_l, mu / lo[0] - self.zlx - sig(self.zlx, lo[0]) * inner, 0.0)
        dzux = np.where(self.has_u, mu / hi[0] - self.zux + sig(self.zux, hi[0]) * inner, 0.0)
        dzlv = mu / lo[1] - self.zlv - self.zlv / lo[1] * dv
        dzuv = mu / hi[1] - self.zuv + self.zuv / hi[1] * dv
        dzlt = mu / lo[2] - self.zlt - self.zlt / lo[2] * d_t
        dzut = mu / hi[2] - self.zut + self.zut / hi[2] * d_t
        dz = mu / self.s - self.z - self.z / self.s * ds if self.s.size else self.z * 0.0
        alpha_dual = min(
            self._max_step(self.zlx[:, self.has_l], dzlx[:, self.has_l], frac),
            self._max_step(self.zux[:, self.has_u], dzux[:, self.has_u], frac),
            self._max_step(self.zlv, dzlv, frac), self._max_step(self.zuv, dzuv, frac),
            self._max_step(np.array([self.zlt]), np.array([dzlt]), frac),
            self._max_step(np.array([self.zut]), np.array([dzut]), frac),
            self._max_step(self.z, dz, frac) if self.z.size else 1.0)
        # IPOPT's filter line search on (theta = l1 constraint violation, phi = barrier
        # objective), with its switching rule and constants.
        phi0, theta0 = self._merit(self.x, self.v, self.t, self.s, terms['defect'], values)
        slope = (d_t * (1.0 - mu / lo[2] + mu / hi[2])
                 + np.sum(np.where(self.has_l, -mu / lo[0], 0.0) * inner)
                 + np.sum(np.where(self.has_u, mu / hi[0], 0.0) * inner)
                 + np.sum((-mu / lo[1] + mu / hi[1]) * dv)
                 - np.sum(mu / self.s * ds))
        if self.theta_max is None:
            self.theta_max = 1e4 * max(1.0, theta0)
            self.theta_min = 1e-4 * max(1.0, theta0)
        alpha = alpha_max
        self.alpha_max = alpha_max
        accepted = False
        while alpha >= MIN_ALPHA:
            xt = self.x + alpha * dx
            vt = self.v + alpha * dv
            tt = self.t + alpha * d_t
            st = self.s + alpha * ds
            defect = self.ev.defects(xt, vt, tt)
            vals = self.ev.clearances(xt[1:-1, :n])
            phi, theta = self._merit(xt, vt, tt, st, defect, vals)
            if np.isfinite(phi) and theta <= self.theta_max and not self._in_filter(theta, phi):
                rounding = ROUNDING * abs(phi0)
                switching = slope < 0.0 and alpha * (-slope) ** 2.3 > theta0 ** 1.1
                if theta0 <= self.theta_min and switching:
                    if phi <= phi0 + ARMIJO * alpha * slope + rounding:
                        accepted = True         # f-type: the filter is not augmented
                        break
                elif theta <= (1.0 - 1e-5) * theta0 or phi <= phi0 - 1e-8 * theta0 + rounding:
                    self.filter.append(((1.0 - 1e-5) * theta0, phi0 - 1e-8 * theta0))
                    accepted = True
                    break
            alpha *= 0.5
        if not accepted:
            if self.filter:
                # IPOPT's filter reset heuristic, once: forget the filter and search again.
                self.filter = []
                return self._line_search(terms, values, grads, dx, dv, d_t, lam_qp)
            return None
        self.x, self.v, self.t, self.s = xt, vt, tt, st
        ad = alpha_dual
        self.zlx = self.zlx + ad * dzlx
        self.zux = self.zux + ad * dzux
        self.zlv, self.zuv = self.zlv + ad * dzlv, self.zuv + ad * dzuv
        self.zlt, self.zut = self.zlt + ad * dzlt, self.zut + ad * dzut
        if self.z.size:
            self.z = self.z + ad * dz
        self.lam = self.lam + alpha * (lam_qp - self.lam)
        self._safeguard_duals()
        return alpha

    def _safeguard_duals(self):
        """Keep every bound dual within [mu / (k slack), k mu / slack] (IPOPT's kappa_sigma)."""
        mu = self.mu
        lo, hi = self._slacks(self.x, self.v, self.t)

        def clip(zv, sv):
            return np.clip(zv, mu / (KAPPA_SIGMA * sv), KAPPA_SIGMA * mu / sv)

        self.zlx = np.where(self.has_l, clip(self.zlx, lo[0]), 0.0)
        self.zux = np.where(self.has_u, clip(self.zux, hi[0]), 0.0)
        self.zlv, self.zuv = clip(self.zlv, lo[1]), clip(self.zuv, hi[1])
        self.zlt, self.zut = float(clip(self.zlt, lo[2])), float(clip(self.zut, hi[2]))
        if self.z.size:
            self.z = clip(self.z, self.s)
