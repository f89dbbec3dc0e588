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
Reference solvers for fast mode: the same discrete problem as CasADi NLPs, IPOPT and FATROP.

For a toc_ros Problem (any robot model: cylindrical eq37 / eq36, planar_2r, model files) this
builds fast mode's discretisation (toc_ros/core/fast_solver.py) from the model's CasADi
expressions (benchmarks/casadi_models.py, written independently of the numba kernels):

* N intervals of tau = t_f / N, t_f free (T_LOW <= t_f <= T_HIGH), controls constant on each
  interval and scaled, u = u_max v with |v| <= 1; explicit Euler or classic RK4
  (problem.integrator), multiple shooting: x(k+1) = Phi(x(k), u(k), tau), x(0) = x0,
  x(N) = x_goal;
* every link segment [a, b] of the model keeps its distance d from every circle (inflated
  radius R = R' + margin) at nodes 1..N, written as (d^2 - R^2) / (2 R) >= 0 with the
  closest point of the segment clamped (C1), the form fast mode uses;
* minimise t_f.

Two layouts of the same problem:

* 'global' (IPOPT): w = [t_f, x0, v0, x1, v1, ..., xN], one t_f column in the Jacobian;
* 'stagewise' (FATROP, structure_detection 'auto'): w = [x0, T0, v0, x1, T1, v1, ..., xN, TN]
  with t_f carried as a state T (T(k+1) = T(k)); the constraints ordered stage by stage (gap
  constraints x(k+1) - Phi(x(k), u(k), T(k) / N) first, then the stage's initial and path
  constraints, the terminal constraint last) and flagged in the 'equality' option.

Both start from the same point: fast mode's cold start (fast_solver.interpolation_start), or a
given guess (states, controls, t_f) such as the remainder of a previous plan.  Construction
(graph, derivatives, solver object) is timed apart from the solve.  Every returned solution is
re-measured independently of the NLP: its controls are re-integrated by toc_ros'
measure_violations (control excess, terminal error, minimum whole-arm clearance).

    ref = Reference(problem, 'fatrop')          # construction (timed: ref.setup_time_s)
    out = ref.solve()                           # or ref.solve((states, controls, t_f))
    out['t_f'], out['status'], out['solve_time_s'], out['iterations'], out['violations']

casadi is optional (setup.py extra 'bench'); the module imports without it.
"""

import dataclasses
import importlib.util
import math
import os
import time

import numpy as np

try:  # optional dependency: only the solvers need it
    import casadi as ca
except ImportError:  # pragma: no cover - exercised only where casadi is absent
    ca = None

from benchmarks.casadi_models import casadi_model, with_actuators  # noqa: I100
from toc_ros.core import measure_violations  # noqa: E402
from toc_ros.core.ip_run import T_HIGH_FACTOR, T_LOW  # noqa: E402
from toc_ros.core.models.actuated import ActuatedModel  # noqa: E402
from toc_ros.core.models.cylindrical import CylindricalRobot  # noqa: E402
from toc_ros.core.models.planar_2r import Planar2R  # noqa: E402
from toc_ros.core.start_points import interpolation_start  # noqa: E402

SOLVERS = ('ipopt', 'fatrop')
LAYOUTS = {'ipopt': 'global', 'fatrop': 'stagewise'}
# Tolerances close to fast mode's (scaled optimality 1e-8, constraint violation 1e-10); the
# control bounds are kept exact (IPOPT would relax them by 1e-8 relative by default).
IPOPT_OPTIONS = {'tol': 1e-8, 'constr_viol_tol': 1e-10, 'bound_relax_factor': 0.0,
                 'max_iter': 3000, 'linear_solver': 'mumps', 'print_level': 0, 'sb': 'yes'}
FATROP_OPTIONS = {'tol': 1e-8, 'constr_viol_tol': 1e-10, 'max_iter': 3000, 'print_level': 0}
# Options for a warm start (a point near the solution): small barrier, small bound push.
IPOPT_WARM = {'mu_init': 1e-5, 'warm_start_init_point': 'yes', 'warm_start_bound_push': 1e-6,
              'warm_start_mult_bound_push': 1e-6}
FATROP_WARM = {'mu_init': 1e-5, 'bound_push': 1e-6}


def have_solver(name):
    """Return True when casadi is importable and has the nlpsol plugin `name`."""
    if ca is None:
        return False
    try:
        return bool(ca.has_nlpsol(name))
    except RuntimeError:  # pragma: no cover
        return False


def model_spec(problem):
    """(casadi_models name or file, parameter dict) of the problem's robot model's joints."""
    model = problem.robot_model.joint_model
    if isinstance(model, (CylindricalRobot, Planar2R)):
        return model.name, dataclasses.asdict(model.params)
    source = getattr(model, '_source', None)
    if source is None or not os.path.exists(source):
        raise ValueError(f'model {model.name!r}: no model file to build CasADi expressions from')
    return source, model.params.as_dict()


def _segment_constraint(segments, circles, nq):
    """Return q -> (d^2 - R^2) / (2 R) per (link, circle), link-major like fast mode."""
    q = ca.SX.sym('q', nq)
    seg = segments(q)
    rows = []
    for link in range(seg.shape[0]):
        ax, ay, bx, by = seg[link, 0], seg[link, 1], seg[link, 2], seg[link, 3]
        dx, dy = bx - ax, by - ay
        dd = dx * dx + dy * dy
        for cx, cy, radius in circles:
            wx, wy = cx - ax, cy - ay
            # Closest point a + s d, s = clip(w.d / d.d, 0, 1), without dividing by d.d = 0.
            s = ca.fmin(ca.fmax(wx * dx + wy * dy, 0.0), dd) / ca.fmax(dd, 1e-12)
            ex, ey = ax + s * dx - cx, ay + s * dy - cy
            rows.append((ex * ex + ey * ey - radius * radius) / (2.0 * radius))
    return ca.Function('clearance', [q], [ca.vertcat(*rows)])


def _step_function(f, nx, nu, integrator):
    """Phi(x, v, tau) with u = u_max v applied inside."""
    x, u, tau = ca.SX.sym('x', nx), ca.SX.sym('u', nu), ca.SX.sym('tau')
    if integrator == 'euler':
        x_next = x + tau * f(x, u)
    elif integrator == 'rk4':
        k1 = f(x, u)
        k2 = f(x + 0.5 * tau * k1, u)
        k3 = f(x + 0.5 * tau * k2, u)
        k4 = f(x + tau * k3, u)
        x_next = x + tau / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    else:
        raise ValueError(f'unknown integrator {integrator!r}')
    return ca.Function('step', [x, u, tau], [x_next])


class Reference:
    """
    One problem as an NLP for one solver; build once (timed), solve from any starting point.

    solver: 'ipopt' or 'fatrop'; layout: 'global' or 'stagewise' (default: IPOPT global,
    FATROP stagewise, which FATROP needs); options: extra options of the solver itself.
    """

    def __init__(self, problem, solver='ipopt', layout=None, options=None):
        if ca is None:
            raise RuntimeError('benchmarks/reference_solvers.py needs casadi: pip install casadi '
                               '(or the package extra .[bench])')
        if solver not in SOLVERS:
            raise ValueError(f'solver must be one of {SOLVERS}, got {solver!r}')
        self.problem = problem
        self.solver_name = solver
        self.layout = layout or LAYOUTS[solver]
        if self.layout not in ('global', 'stagewise'):
            raise ValueError(f"layout must be 'global' or 'stagewise', got {self.layout!r}")
        if solver == 'fatrop' and self.layout != 'stagewise':
            raise ValueError('FATROP needs the stagewise layout')
        self.extra_options = dict(options or {})
        started = time.perf_counter()
        self._build()
        self.setup_time_s = time.perf_counter() - started

    # Construction ------------------------------------------------------------------------
    def _build(self):
        problem = self.problem
        model = problem.robot_model
        name, params = model_spec(problem)
        f, segments, u_max = casadi_model(name, params)
        if isinstance(model, ActuatedModel):
            f = with_actuators(f, u_max, model.lag)
        if not np.allclose(u_max, model.u_max, rtol=1e-12, atol=0.0):
            raise ValueError(f'CasADi u_max {u_max} differs from the model u_max {model.u_max}')
        self.u_max = np.asarray(model.u_max, dtype=float)
        nx, nu, n = model.nx, model.nu, int(problem.n_intervals)
        self.nx, self.nu, self.n = nx, nu, n
        circles = problem.circles()
        self.n_obs = model.n_links * circles.shape[0]
        step = _step_function(f, nx, nu, problem.integrator)
        x, v, tau = ca.SX.sym('x', nx), ca.SX.sym('v', nu), ca.SX.sym('tau')
        scaled = ca.Function('phi', [x, v, tau], [step(x, ca.DM(self.u_max) * v, tau)])
        x0 = np.asarray(problem.x0, dtype=float)
        xg = np.asarray(problem.x_goal, dtype=float)
        self.t_bounds = (T_LOW, T_HIGH_FACTOR * max(problem.t_f0, 1.0))
        if self.n_obs:
            qx = ca.SX.sym('x', nx)
            nq = model.n_joints
            clear = _segment_constraint(segments, circles, nq)
            clear_x = ca.Function('clear_x', [qx], [clear(qx[0:2 * nq:2])])
        if self.layout == 'global':
            self._build_global(scaled, clear_x if self.n_obs else None, x0, xg)
        else:
            self._build_stagewise(scaled, clear_x if self.n_obs else None, x0, xg)

    def _build_global(self, phi, clear, x0, xg):
        nx, nu, n = self.nx, self.nu, self.n
        t_f = ca.SX.sym('t_f')
        xv = ca.SX.sym('xv', nx + nu, n)            # columns [x(k); v(k)], k = 0..N-1
        x_end = ca.SX.sym('xN', nx)
        xs = ca.horzcat(xv[:nx, :], x_end)
        vs = xv[nx:, :]
        gap = xs[:, 1:] - phi.map(n)(xs[:, :-1], vs, t_f / n)
        parts, lbg, ubg = [ca.vec(gap)], [np.zeros(nx * n)], [np.zeros(nx * n)]
        if clear is not None:
            parts.append(ca.vec(clear.map(n)(xs[:, 1:])))
            lbg.append(np.zeros(self.n_obs * n))
            ubg.append(np.full(self.n_obs * n, np.inf))
        w = ca.vertcat(t_f, ca.vec(xv), x_end)
        nw = w.shape[0]
        lbw, ubw = np.full(nw, -np.inf), np.full(nw, np.inf)
        lbw[0], ubw[0] = self.t_bounds
        body_lb = np.full((n, nx + nu), -np.inf)
        body_ub = np.full((n, nx + nu), np.inf)
        body_lb[:, nx:], body_ub[:, nx:] = -1.0, 1.0
        body_lb[0, :nx], body_ub[0, :nx] = x0, x0
        lbw[1:1 + n * (nx + nu)], ubw[1:1 + n * (nx + nu)] = body_lb.ravel(), body_ub.ravel()
        lbw[-nx:], ubw[-nx:] = xg, xg
        self.lbw, self.ubw = lbw, ubw
        self.lbg, self.ubg = np.concatenate(lbg), np.concatenate(ubg)
        opts = {'print_time': False}
        opts.update({'ipopt.' + k: v for k, v in IPOPT_OPTIONS.items()})
        self._solver_opts = opts
        self._nlp = {'x': w, 'f': t_f, 'g': ca.vertcat(*parts)}
        self.solver = ca.nlpsol('reference_ipopt', 'ipopt', self._nlp, self._options())

    def _build_stagewise(self, phi, clear, x0, xg):
        nx, nu, n = self.nx, self.nu, self.n
        z = ca.SX.sym('z', nx + 1 + nu, n)          # columns [x(k); T(k); v(k)]
        x_end, t_end = ca.SX.sym('xN', nx), ca.SX.sym('TN')
        xs = ca.horzcat(z[:nx, :], x_end)
        ts = ca.horzcat(z[nx, :], t_end)
        vs = z[nx + 1:, :]
        gap = xs[:, 1:] - phi.map(n)(xs[:, :-1], vs, ts[:, :-1] / n)
        gap_t = ts[:, 1:] - ts[:, :-1]
        obs = clear.map(n)(xs[:, 1:]) if clear is not None else None
        g, lbg, ubg, equality = [], [], [], []

        def add(expr, low, high, eq):
            size = expr.shape[0]
            g.append(expr)
            lbg.append(np.broadcast_to(low, (size,)))
            ubg.append(np.broadcast_to(high, (size,)))
            equality.extend([eq] * size)

        for k in range(n):
            add(gap[:, k], 0.0, 0.0, True)
            add(gap_t[:, k], 0.0, 0.0, True)
            if k == 0:
                add(xs[:, 0] - x0, 0.0, 0.0, True)
            else:
                if obs is not None:
                    add(obs[:, k - 1], 0.0, np.inf, False)
        if obs is not None:
            add(obs[:, n - 1], 0.0, np.inf, False)
        add(x_end - xg, 0.0, 0.0, True)
        w = ca.vertcat(ca.vec(z), x_end, t_end)
        nw = w.shape[0]
        body_lb = np.full((n, nx + 1 + nu), -np.inf)
        body_ub = np.full((n, nx + 1 + nu), np.inf)
        body_lb[:, nx + 1:], body_ub[:, nx + 1:] = -1.0, 1.0
        body_lb[:, nx], body_ub[:, nx] = self.t_bounds
        lbw, ubw = np.full(nw, -np.inf), np.full(nw, np.inf)
        lbw[:n * (nx + 1 + nu)], ubw[:n * (nx + 1 + nu)] = body_lb.ravel(), body_ub.ravel()
        lbw[-1], ubw[-1] = self.t_bounds
        self.lbw, self.ubw = lbw, ubw
        self.lbg, self.ubg = np.concatenate(lbg), np.concatenate(ubg)
        self._equality = equality
        self._nlp = {'x': w, 'f': z[nx, 0], 'g': ca.vertcat(*g)}
        self.solver = ca.nlpsol(f'reference_{self.solver_name}', self.solver_name, self._nlp,
                                self._options())

    def _options(self, warm=False):
        if self.solver_name == 'ipopt':
            inner = dict(IPOPT_OPTIONS, **(IPOPT_WARM if warm else {}))
            inner.update(self.extra_options)
            opts = {'print_time': False}
            opts.update({'ipopt.' + k: v for k, v in inner.items()})
            return opts
        inner = dict(FATROP_OPTIONS, **(FATROP_WARM if warm else {}))
        inner.update(self.extra_options)
        return {'print_time': False, 'structure_detection': 'auto', 'expand': True,
                'equality': self._equality, 'fatrop': inner}

    # Points ------------------------------------------------------------------------------
    def pack(self, states, controls, t_f):
        """Flatten (states (N+1, nx), controls (N, nu), t_f) into w, clipped to the bounds."""
        states = np.asarray(states, dtype=float)
        vs = np.asarray(controls, dtype=float) / self.u_max[None, :]
        n = self.n
        if states.shape != (n + 1, self.nx) or vs.shape != (n, self.nu):
            raise ValueError(f'guess needs states ({n + 1}, {self.nx}) and controls '
                             f'({n}, {self.nu}), got {states.shape} and {vs.shape}')
        if self.layout == 'global':
            body = np.hstack([states[:-1], vs]).ravel()
            w = np.concatenate([[t_f], body, states[-1]])
        else:
            body = np.hstack([states[:-1], np.full((n, 1), t_f), vs]).ravel()
            w = np.concatenate([body, states[-1], [t_f]])
        return np.clip(w, self.lbw, self.ubw)

    def unpack(self, w):
        """(states (N+1, nx), controls (N, nu), t_f) from w."""
        w = np.asarray(w, dtype=float).ravel()
        nx, nu, n = self.nx, self.nu, self.n
        if self.layout == 'global':
            body = w[1:1 + n * (nx + nu)].reshape(n, nx + nu)
            states = np.vstack([body[:, :nx], w[-nx:]])
            return states, body[:, nx:] * self.u_max[None, :], float(w[0])
        body = w[:n * (nx + 1 + nu)].reshape(n, nx + 1 + nu)
        states = np.vstack([body[:, :nx], w[-nx - 1:-1]])
        return states, body[:, nx + 1:] * self.u_max[None, :], float(body[0, nx])

    # Solving -----------------------------------------------------------------------------
    def solve(self, guess=None, warm=False):
        """
        Solve from guess (states, controls, t_f), default fast mode's interpolation_start.

        warm=True switches to the warm-start options (IPOPT_WARM / FATROP_WARM), which needs
        a solver object of its own: built (and timed as warm_setup_time_s) on first use.
        Returns a dict: solver, layout, status, success (the solver's own), feasible
        (re-measured within toc_ros' SOLVED tolerances), t_f, states, controls, iterations,
        solve_time_s, setup_time_s, max_violation (as the NLP sees it) and violations.
        """
        if guess is None:
            guess = interpolation_start(self.problem, self.n)
        states, controls, t_f = guess
        solver = self.solver
        if warm:
            if getattr(self, '_warm_solver', None) is None:
                started = time.perf_counter()
                self._warm_solver = ca.nlpsol(f'reference_{self.solver_name}_warm',
                                              self.solver_name, self._nlp, self._options(True))
                self.warm_setup_time_s = time.perf_counter() - started
            solver = self._warm_solver
        w0 = self.pack(states, controls, t_f)
        started = time.perf_counter()
        sol = solver(x0=w0, lbx=self.lbw, ubx=self.ubw, lbg=self.lbg, ubg=self.ubg)
        elapsed = time.perf_counter() - started
        stats = solver.stats()
        w = np.asarray(sol['x']).ravel()
        g = np.asarray(sol['g']).ravel()
        viol = float(max(np.max(np.maximum(self.lbg - g, 0.0), initial=0.0),
                         np.max(np.maximum(g - self.ubg, 0.0), initial=0.0),
                         np.max(np.maximum(self.lbw - w, 0.0), initial=0.0),
                         np.max(np.maximum(w - self.ubw, 0.0), initial=0.0)))
        states, controls, t_f = self.unpack(w)
        finite = bool(np.all(np.isfinite(w)))
        if finite:
            _, violations = measure_violations(self.problem, controls, t_f)
            feasible = violations.feasible()
            vdict = violations.as_dict()
        else:
            feasible, vdict = False, {}
        status = stats.get('return_status', '')
        if not isinstance(status, str):      # FATROP: an integer code
            status = f'{stats.get("unified_return_status", "")} ({status})'
        return {'solver': self.solver_name, 'layout': self.layout, 'status': status,
                'success': bool(stats.get('success', False)), 'feasible': bool(feasible),
                't_f': t_f, 'states': states, 'controls': controls,
                'iterations': int(stats.get('iter_count', -1)), 'solve_time_s': elapsed,
                'setup_time_s': self.setup_time_s, 'max_violation': viol,
                'violations': vdict}


def solve_problem(problem, solver='ipopt', guess=None, warm=False, options=None):
    """Build and solve in one call (see Reference); returns Reference.solve's dict."""
    return Reference(problem, solver, options=options).solve(guess, warm=warm)


def rollout_guess(problem, controls, t_f):
    """Return a starting point (states, controls, t_f) from controls: states rolled out."""
    states, _ = measure_violations(problem, controls, t_f)
    return states, np.asarray(controls, dtype=float), float(t_f)


def casadi_available():
    """Return True when casadi is importable (the solvers need it)."""
    return importlib.util.find_spec('casadi') is not None and ca is not None


def gap_percent(t_f, t_ref):
    """100 (t_f - t_ref) / t_ref, nan when either is missing."""
    if t_f is None or t_ref is None or not (math.isfinite(t_f) and math.isfinite(t_ref)):
        return math.nan
    return 100.0 * (t_f - t_ref) / t_ref
