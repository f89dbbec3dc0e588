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
Reference minimum-time trajectories of a URDF arm: CasADi transcriptions for IPOPT and FATROP.

The discrete problem (arm_problem.py) is the one toc_ros solves, written with the rigid-body
recursions of arm_casadi.py (independent of Pinocchio):

* state x = (q, qd), positions first; controls u = joint torques, constant on each of N
  intervals of h = t_f / N; explicit Euler or classic RK4; t_f free; minimise t_f;
* x(0) = start, x(N) = goal (goal velocity 0 unless given);
* at every node k: lower <= q <= upper (continuous joints: no bound), |qd| <= velocity;
  |u| <= effort on every interval, written as u = effort v, |v| <= 1 (O(1) for the solver);
* for every robot sphere s (centre p_s(q) on its link, radius r_s) and obstacle sphere o
  (centre c_o, radius R_o), with R = r_s + R_o + margin:
  (|p_s(q) - c_o|^2 - R^2) / (2 R) >= 0, the squared form (smooth everywhere, also at
  p_s = c_o) scaled so that it reads as the distance d - R near the boundary.

x(0) and x(N) are given: their limits and clearances are checked before solving (a start or
goal that violates one is refused with the reason), so the NLP carries the node constraints
at k = 1..N-1; the independent check (arm_check.py) measures all nodes 0..N.

Layouts as in benchmarks/reference_solvers.py: 'global' for IPOPT (w = [t_f, x0, v0, x1, v1,
..., xN]), 'stagewise' for FATROP (w = [x0, T0, v0, ..., xN, TN], t_f carried as a state T,
constraints ordered stage by stage and flagged in 'equality', structure_detection 'auto').

    spec = ArmSpec(urdf=path, joints=('panda_joint1', ...), start=q0, goal=q1,
                   obstacles=((0.5, 0.0, 0.5, 0.1),), robot_spheres={'panda_hand': [[...]]})
    best = solve_arm_ipopt(spec, N=100, integrator='euler')        # multi-started
    fat = solve_arm(spec, 100, 'euler', solver='fatrop')           # from the line start
"""

import math
import time

import numpy as np

from .arm_problem import ArmProblem, SpecError

SOLVERS = ('ipopt', 'fatrop')
INTEGRATORS = ('euler', 'rk4')
FORMULATIONS = ('lifted', 'explicit')
T_LOW = 1e-3
T_HIGH = 100.0
# The same tolerances as benchmarks/reference_solvers.py (close to fast mode's): scaled
# optimality 1e-8, constraint violation 1e-10, bounds not relaxed.
IPOPT_OPTIONS = {'tol': 1e-8, 'constr_viol_tol': 1e-10, 'bound_relax_factor': 0.0,
                 'max_iter': 3000, 'linear_solver': 'mumps', 'print_level': 0, 'sb': 'yes'}
FATROP_OPTIONS = {'tol': 1e-8, 'constr_viol_tol': 1e-10, 'max_iter': 3000, 'print_level': 0}


# ----------------------------------------------------------------------------------------
# transcription
# ----------------------------------------------------------------------------------------

def _stage_function(ca, problem, integrator, formulation):
    """
    Return the Function (x, v, a, h) -> (x_next, residual) of one interval, u = effort v.

    'explicit': x_next = Phi(x, u, h) with the ABA inside, no a, no residual.
    'lifted': the accelerations of the integrator's stages are variables a (n per stage:
    Euler 1, RK4 4) tied to u by inverse dynamics, residual = (RNEA(q_j, qd_j, a_j) - u) /
    effort = 0 at each stage's state j; since M(q) is positive definite this holds exactly
    when a_j = ABA(q_j, qd_j, u), so the discrete problem is the same.  Its derivatives are
    much cheaper than those of the ABA nested in the step (RK4: four nested ABAs).
    """
    n = problem.n
    effort = ca.DM(problem.effort)
    x, v, h = ca.SX.sym('x', 2 * n), ca.SX.sym('v', n), ca.SX.sym('h')
    u = effort * v
    stages = {'euler': 1, 'rk4': 4}
    if integrator not in stages:
        raise SpecError(f'integrator must be one of {INTEGRATORS}, got {integrator!r}')
    if formulation not in FORMULATIONS:
        raise SpecError(f'formulation must be one of {FORMULATIONS}, got {formulation!r}')
    if formulation == 'explicit':
        a = ca.SX.sym('a', 0)
        f = problem.f
        if integrator == 'euler':
            x_next = x + h * f(x, u)
        else:
            k1 = f(x, u)
            k2 = f(x + 0.5 * h * k1, u)
            k3 = f(x + 0.5 * h * k2, u)
            k4 = f(x + h * k3, u)
            x_next = x + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        return ca.Function('stage', [x, v, a, h], [x_next, ca.SX.zeros(0)]), 0
    m = stages[integrator]
    a = ca.SX.sym('a', n * m)
    rnea = problem.model.rnea
    residual, slopes, xj = [], [], x
    for j in range(m):
        aj = a[j * n:(j + 1) * n]
        residual.append((rnea(xj[:n], xj[n:], aj) - u) / effort)
        slopes.append(ca.vertcat(xj[n:], aj))
        if j < m - 1:
            xj = x + (0.5 if j < 2 else 1.0) * h * slopes[-1]
    if m == 1:
        x_next = x + h * slopes[0]
    else:
        x_next = x + h / 6.0 * (slopes[0] + 2.0 * slopes[1] + 2.0 * slopes[2] + slopes[3])
    return ca.Function('stage', [x, v, a, h], [x_next, ca.vertcat(*residual)]), n * m


class ArmTranscription:
    """
    One ArmProblem as an NLP on N intervals for one solver; built once, solved from any start.

    formulation 'lifted' (default) or 'explicit' (see _stage_function); the variables of
    interval k are x(k), v(k) (u = effort v) and, lifted, its stages' accelerations a(k).
    Construction (graph, derivatives, solver object) is timed apart: setup_time_s.
    """

    def __init__(self, problem, n_intervals, integrator='euler', solver='ipopt', options=None,
                 formulation='lifted', expand=False):
        self.ca = ca = problem.model.ca
        if solver not in SOLVERS:
            raise SpecError(f'solver must be one of {SOLVERS}, got {solver!r}')
        if solver == 'fatrop' and not ca.has_nlpsol('fatrop'):
            raise SpecError("this casadi has no 'fatrop' plugin")
        if isinstance(n_intervals, bool) or int(n_intervals) != n_intervals or n_intervals < 2:
            raise SpecError(f'N must be an integer >= 2, got {n_intervals!r}')
        started = time.perf_counter()
        self.problem = problem
        self.n_int = int(n_intervals)
        self.integrator = integrator
        self.formulation = formulation
        self.solver_name = solver
        self.layout = 'global' if solver == 'ipopt' else 'stagewise'
        self.extra_options = dict(options or {})
        self.expand = bool(expand)
        n = problem.n
        self.nx, self.nu = 2 * n, n
        self.stage, self.na = _stage_function(ca, problem, integrator, formulation)
        self.clear = None
        if problem.n_pairs:
            x = ca.SX.sym('x', self.nx)
            p = problem.points(x[:n])                          # (3, S) sphere centres
            n_obs = problem.obstacles.shape[0]
            rows = []
            for s in range(p.shape[1]):
                for o, (cx, cy, cz, _) in enumerate(problem.obstacles):
                    radius = problem.pair_radius[s * n_obs + o]
                    e = p[:, s] - ca.DM([cx, cy, cz])
                    rows.append((ca.dot(e, e) - radius * radius) / (2.0 * radius))
            self.clear = ca.Function('clear', [x], [ca.vertcat(*rows)])
        if self.layout == 'global':
            self._build_global()
        else:
            self._build_stagewise()
        self.setup_time_s = time.perf_counter() - started

    def _state_bounds(self):
        pr = self.problem
        lb = np.concatenate([pr.lower, -pr.velocity])
        ub = np.concatenate([pr.upper, pr.velocity])
        return lb, ub

    def _build_global(self):
        ca, pr, n = self.ca, self.problem, self.n_int
        nx, nu, na = self.nx, self.nu, self.na
        t_f = ca.MX.sym('t_f')
        col = ca.MX.sym('col', nx + nu + na, n)     # columns [x(k); v(k); a(k)], k = 0..N-1
        x_end = ca.MX.sym('xN', nx)
        xs = ca.horzcat(col[:nx, :], x_end)
        stages = self.stage.map(n)
        x_next, residual = stages(xs[:, :-1], col[nx:nx + nu, :], col[nx + nu:, :], t_f / n)
        parts = [ca.vec(xs[:, 1:] - x_next)]
        lbg, ubg = [np.zeros(nx * n)], [np.zeros(nx * n)]
        if na:
            parts.append(ca.vec(residual))
            lbg.append(np.zeros(na * n))
            ubg.append(np.zeros(na * n))
        if self.clear is not None:
            parts.append(ca.vec(self.clear.map(n - 1)(xs[:, 1:n])))
            lbg.append(np.zeros(pr.n_pairs * (n - 1)))
            ubg.append(np.full(pr.n_pairs * (n - 1), np.inf))
        w = ca.vertcat(t_f, ca.vec(col), x_end)
        slb, sub = self._state_bounds()
        body_lb = np.tile(np.concatenate([slb, -np.ones(nu), np.full(na, -np.inf)]), (n, 1))
        body_ub = np.tile(np.concatenate([sub, np.ones(nu), np.full(na, np.inf)]), (n, 1))
        body_lb[0, :nx], body_ub[0, :nx] = pr.x0, pr.x0
        self.lbw = np.concatenate([[T_LOW], body_lb.ravel(), pr.xg])
        self.ubw = np.concatenate([[T_HIGH], body_ub.ravel(), pr.xg])
        self.lbg, self.ubg = np.concatenate(lbg), np.concatenate(ubg)
        self._nlp = {'x': w, 'f': t_f, 'g': ca.vertcat(*parts)}
        self.solver = ca.nlpsol('arm_ipopt', 'ipopt', self._nlp, self._options())

    def _build_stagewise(self):
        ca, pr, n = self.ca, self.problem, self.n_int
        nx, nu, na = self.nx, self.nu, self.na
        z = ca.MX.sym('z', nx + 1 + nu + na, n)     # columns [x(k); T(k); v(k); a(k)]
        x_end, t_end = ca.MX.sym('xN', nx), ca.MX.sym('TN')
        xs = ca.horzcat(z[:nx, :], x_end)
        ts = ca.horzcat(z[nx, :], t_end)
        stages = self.stage.map(n)
        x_next, residual = stages(xs[:, :-1], z[nx + 1:nx + 1 + nu, :], z[nx + 1 + nu:, :],
                                  ts[:, :-1] / n)
        gap = xs[:, 1:] - x_next
        gap_t = ts[:, 1:] - ts[:, :-1]
        obs = self.clear.map(n)(xs[:, :-1]) if self.clear is not None else None
        g, lbg, ubg, equality = [], [], [], []

        def add(expr, low, high, eq):
            size = expr.shape[0]
            g.append(expr)
            lbg.append(np.broadcast_to(low, (size,)))
            ubg.append(np.broadcast_to(high, (size,)))
            equality.extend([eq] * size)

        # Stage by stage: the gap constraints first, then the stage's own constraints.
        for k in range(n):
            add(gap[:, k], 0.0, 0.0, True)
            add(gap_t[:, k], 0.0, 0.0, True)
            if k == 0:
                add(xs[:, 0] - pr.x0, 0.0, 0.0, True)
            if na:
                add(residual[:, k], 0.0, 0.0, True)
            if k > 0 and obs is not None:
                add(obs[:, k], 0.0, np.inf, False)
        add(x_end - pr.xg, 0.0, 0.0, True)
        w = ca.vertcat(ca.vec(z), x_end, t_end)
        slb, sub = self._state_bounds()
        body_lb = np.tile(np.concatenate([slb, [T_LOW], -np.ones(nu), np.full(na, -np.inf)]),
                          (n, 1))
        body_ub = np.tile(np.concatenate([sub, [T_HIGH], np.ones(nu), np.full(na, np.inf)]),
                          (n, 1))
        # x(0) is fixed by its equality constraint (FATROP's initial constraint), not bounds.
        body_lb[0, :nx], body_ub[0, :nx] = -np.inf, np.inf
        self.lbw = np.concatenate([body_lb.ravel(), np.full(nx, -np.inf), [T_LOW]])
        self.ubw = np.concatenate([body_ub.ravel(), np.full(nx, np.inf), [T_HIGH]])
        self.lbg, self.ubg = np.concatenate(lbg), np.concatenate(ubg)
        self._equality = equality
        self._nlp = {'x': w, 'f': z[nx, 0], 'g': ca.vertcat(*g)}
        self.solver = ca.nlpsol('arm_fatrop', 'fatrop', self._nlp, self._options())

    def _options(self):
        if self.solver_name == 'ipopt':
            inner = dict(IPOPT_OPTIONS, **self.extra_options)
            opts = {'print_time': False}
            opts.update({'ipopt.' + k: v for k, v in inner.items()})
            return opts
        inner = dict(FATROP_OPTIONS, **self.extra_options)
        return {'print_time': False, 'structure_detection': 'auto', 'expand': self.expand,
                'equality': self._equality, 'fatrop': inner}

    # Points ------------------------------------------------------------------------------
    def accelerations(self, states, controls, t_f):
        """(N, na) stage accelerations of the lifted formulation along a guess (ABA)."""
        if not self.na:
            return np.zeros((self.n_int, 0))
        pr, n, h = self.problem, self.problem.n, t_f / self.n_int
        fd = pr.model.forward_dynamics.map(self.n_int)
        x = np.asarray(states[:-1], dtype=float)
        u = np.asarray(controls, dtype=float)
        out, xj = [], x
        for j in range(self.na // n):
            aj = np.asarray(fd(xj[:, :n].T, xj[:, n:].T, u.T)).T
            out.append(aj)
            slope = np.hstack([xj[:, n:], aj])
            xj = x + (0.5 if j < 2 else 1.0) * h * slope
        return np.hstack(out)

    def pack(self, states, controls, t_f):
        """Flatten (states (N+1, 2n), controls (N, n) torques, t_f) into w, clipped to bounds."""
        n = self.n_int
        states = np.asarray(states, dtype=float)
        controls = np.asarray(controls, dtype=float)
        if states.shape != (n + 1, self.nx) or controls.shape != (n, self.nu):
            raise SpecError(f'guess needs states ({n + 1}, {self.nx}) and controls '
                            f'({n}, {self.nu}), got {states.shape} and {controls.shape}')
        vs = controls / self.problem.effort[None, :]
        acc = self.accelerations(states, controls, t_f)
        if self.layout == 'global':
            body = np.hstack([states[:-1], vs, acc]).ravel()
            w = np.concatenate([[t_f], body, states[-1]])
        else:
            body = np.hstack([states[:-1], np.full((n, 1), t_f), vs, acc]).ravel()
            w = np.concatenate([body, states[-1], [t_f]])
        return np.clip(w, self.lbw, self.ubw)

    def unpack(self, w):
        """(states (N+1, 2n), controls (N, n) torques, t_f) from w."""
        w = np.asarray(w, dtype=float).ravel()
        nx, nu, na, n = self.nx, self.nu, self.na, self.n_int
        effort = self.problem.effort[None, :]
        if self.layout == 'global':
            body = w[1:1 + n * (nx + nu + na)].reshape(n, nx + nu + na)
            return (np.vstack([body[:, :nx], w[-nx:]]), body[:, nx:nx + nu] * effort,
                    float(w[0]))
        body = w[:n * (nx + 1 + nu + na)].reshape(n, nx + 1 + nu + na)
        states = np.vstack([body[:, :nx], w[-nx - 1:-1]])
        return states, body[:, nx + 1:nx + 1 + nu] * effort, float(body[0, nx])

    def solve(self, guess):
        """
        Solve from guess (states, controls, t_f).

        Returns a dict: solver, status, success (the solver's own), t_f, states, controls
        (torques), iterations, solve_time_s, setup_time_s, max_violation (as the NLP sees it,
        before any independent check).
        """
        states, controls, t_f = guess
        w0 = self.pack(states, controls, t_f)
        started = time.perf_counter()
        sol = self.solver(x0=w0, lbx=self.lbw, ubx=self.ubw, lbg=self.lbg, ubg=self.ubg)
        elapsed = time.perf_counter() - started
        stats = self.solver.stats()
        w = np.asarray(sol['x']).ravel()
        g = np.asarray(sol['g']).ravel()
        viol = float(max(np.max(np.maximum(self.lbg - g, 0.0), initial=0.0),
                         np.max(np.maximum(g - self.ubg, 0.0), initial=0.0),
                         np.max(np.maximum(self.lbw - w, 0.0), initial=0.0),
                         np.max(np.maximum(w - self.ubw, 0.0), initial=0.0)))
        states, controls, t_f = self.unpack(w)
        status = stats.get('return_status', '')
        if not isinstance(status, str):      # FATROP: an integer code
            status = f'{stats.get("unified_return_status", "")} ({status})'
        success = bool(stats.get('success', False)) and bool(np.all(np.isfinite(w)))
        return {'solver': self.solver_name, 'status': status, 'success': success,
                't_f': t_f, 'states': states, 'controls': controls,
                'iterations': int(stats.get('iter_count', -1)), 'solve_time_s': elapsed,
                'setup_time_s': self.setup_time_s, 'max_violation': viol,
                'N': self.n_int, 'integrator': self.integrator,
                'formulation': self.formulation}


# ----------------------------------------------------------------------------------------
# solving
# ----------------------------------------------------------------------------------------

def default_starts(problem, n_starts=4, seed=0, spread=0.5):
    """
    Named starting recipes [(name, t_f factor, offsets or None)] for a multi-start.

    The cubic line at 1.0 and 1.5 times line_time, then perturbed cubics (each joint's
    midpoint shifted by spread times a standard normal draw, radians or metres) at 1.25 times,
    drawn from numpy's default_rng(seed): the same starts for the same seed.
    """
    rng = np.random.default_rng(seed)
    recipes = [('line', 1.0, None), ('line x1.5', 1.5, None)]
    k = 0
    while len(recipes) < n_starts:
        k += 1
        recipes.append((f'perturbed {k}', 1.25, spread * rng.standard_normal(problem.n)))
    return recipes[:max(int(n_starts), 1)]


def solve_arm(spec_or_problem, N, integrator='euler', solver='ipopt',  # noqa: N803
              guess=None, options=None):
    """Build and solve once from guess (default: the cubic line start at line_time)."""
    problem = _as_problem(spec_or_problem)
    nlp = ArmTranscription(problem, N, integrator, solver, options)
    if guess is None:
        guess = problem.path_guess(problem.line_time(), nlp.n_int)
    out = nlp.solve(guess)
    out['start'] = 'line'
    return out


def _as_problem(spec_or_problem):
    if isinstance(spec_or_problem, ArmProblem):
        return spec_or_problem
    return ArmProblem(spec_or_problem)


def solve_arm_ipopt(spec_or_problem, N, integrator='euler', starts=None,  # noqa: N803
                    n_starts=4, seed=0, options=None, budget_s=None):
    """
    Multi-started IPOPT: solve from several starts, keep the best converged t_f.

    starts: recipes as default_starts returns (default: default_starts(problem, n_starts,
    seed)); budget_s: stop starting new attempts once the IPOPT time spent exceeds it (the
    line start always runs).  Returns the best attempt's dict (solve's keys) plus attempts
    (per start: name, status, success, t_f, iterations, solve_time_s), t_spread (max - min
    t_f over the converged attempts), solve_time_s and iterations summed over all attempts.
    """
    problem = _as_problem(spec_or_problem)
    nlp = ArmTranscription(problem, N, integrator, 'ipopt', options)
    recipes = default_starts(problem, n_starts, seed) if starts is None else list(starts)
    base = problem.line_time()
    best, attempts, spent = None, [], 0.0
    for name, factor, offsets in recipes:
        if budget_s is not None and attempts and spent > budget_s:
            break
        out = nlp.solve(problem.path_guess(base * factor, nlp.n_int, offsets))
        spent += out['solve_time_s']
        ok = out['success'] and out['max_violation'] < 1e-6
        attempts.append({'start': name, 'status': out['status'], 'success': ok,
                         't_f': out['t_f'], 'iterations': out['iterations'],
                         'solve_time_s': out['solve_time_s']})
        out['start'] = name
        key = (not ok, out['t_f'] if ok else out['max_violation'])
        if best is None or key < best[0]:
            best = (key, out)
    result = dict(best[1])
    good = [a['t_f'] for a in attempts if a['success']]
    result.update({'attempts': attempts, 'solve_time_s': spent,
                   'iterations': sum(a['iterations'] for a in attempts),
                   'best_iterations': best[1]['iterations'],
                   'best_solve_time_s': best[1]['solve_time_s'],
                   't_spread': (max(good) - min(good)) if good else math.nan,
                   'line_time': base})
    return result


def solve_arm_fatrop(spec_or_problem, N, integrator='euler', guess=None,  # noqa: N803
                     options=None):
    """FATROP from the line start (or guess), the same discretisation as solve_arm_ipopt."""
    return solve_arm(spec_or_problem, N, integrator, 'fatrop', guess, options)
