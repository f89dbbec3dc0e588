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
Fast mode: a feasible minimum-time solution built on the same BPTT gradient.

The discrete problem is the paper's (eqs. 1-5 with F-hat = 1, i.e. J0 = N tau = t_f) with the
constraints kept as constraints instead of fixed penalties:

    minimise t_f  over  u(0..N-1), t_f
    s.t.  x(N) = x_goal                               (eq. 3)
          |u_k(i)| <= u_k,max                         (eq. 47)
          dist(arm segment at node i, c_k) >= R_k     (eq. 41, whole arm, any quadrant)

solved by an augmented Lagrangian (Powell-Hestenes-Rockafellar) on the terminal and obstacle
constraints.  Its sub-problems are bound-constrained in scaled controls v = u / u_max in
[-1, 1] and t_f, and solved by a projected L-BFGS (lbfgs_box, in numba: scipy's L-BFGS-B spends
~20x the cost of a function evaluation per iteration here).  The sub-problem gradient, including
d/dt_f, comes from one BPTT sweep (bptt.adjoint_sweep); bounds hold exactly at every iterate.
The obstacle constraint uses the squared segment distance (C1), scaled as (d^2 - R^2) / (2 R)
~ d - R, rather than the ray formula of eq. (41), whose derivative is unbounded where the ray
is tangent to the circle.  solver.py drives it over a coarse-to-fine ladder of grids and makes
each result exactly feasible with FeasibilityProjector (Gauss-Newton on BPTT sensitivity rows).
"""

from numba import njit
import numpy as np

from .bptt import adjoint_sweep, Workspace
from .integrators import rollout_linearized
from .obstacles import segment_distance_sq

LBFGS_MEMORY = 10


@njit(cache=True)
def alm_value_gradient(z, x0, x_goal, u_max, p, method, circles, lam, rho, mu, states,
                       jac_x, jac_u, jac_tau, grad_x, grad_u, out_grad_u, grad_z, cons):
    """
    Augmented Lagrangian L(v, t_f) and dL/dz for z = [v (2N, row-major), t_f].

    cons receives the terminal residuals (4) then the obstacle constraints (N x K, row-major).
    """
    n = jac_u.shape[0]
    t_f = z[2 * n]
    tau = t_f / n
    controls = grad_u  # reuse as scratch for u, overwritten below by the partials
    for i in range(n):
        controls[i, 0] = z[2 * i] * u_max[0]
        controls[i, 1] = z[2 * i + 1] * u_max[1]
    rollout_linearized(x0, controls, tau, p, method, states, jac_x, jac_u, jac_tau)
    grad_x[:, :] = 0.0
    grad_u[:, :] = 0.0
    value = t_f
    for r in range(4):
        h = states[n, r] - x_goal[r]
        cons[r] = h
        value += lam[r] * h + 0.5 * rho * h * h
        grad_x[n, r] += lam[r] + rho * h
    n_circles = circles.shape[0]
    a = p[3]
    for i in range(1, n + 1):
        for k in range(n_circles):
            radius = circles[k, 2]
            d2, d2_q1, d2_q2 = segment_distance_sq(states[i, 0], states[i, 2], a,
                                                   circles[k, 0], circles[k, 1])
            c = (d2 - radius * radius) / (2.0 * radius)
            idx = (i - 1) * n_circles + k
            cons[4 + idx] = c
            m = mu[idx]
            shifted = m - rho * c
            if shifted > 0.0:
                value += (shifted * shifted - m * m) / (2.0 * rho)
                g = -shifted / (2.0 * radius)
                grad_x[i, 0] += g * d2_q1
                grad_x[i, 2] += g * d2_q2
            else:
                value -= m * m / (2.0 * rho)
    d_tau, _ = adjoint_sweep(jac_x, jac_u, jac_tau, grad_x, grad_u, out_grad_u)
    for i in range(n):
        grad_z[2 * i] = out_grad_u[i, 0] * u_max[0]
        grad_z[2 * i + 1] = out_grad_u[i, 1] * u_max[1]
    grad_z[2 * n] = 1.0 + d_tau / n
    return value


@njit(cache=True)
def _masked_dot(a, b, free):
    acc = 0.0
    for i in range(a.shape[0]):
        if free[i]:
            acc += a[i] * b[i]
    return acc


@njit(cache=True)
def lbfgs_box(z, lower, upper, max_iter, gtol, mem_s, mem_y, mem_info, x0, x_goal, u_max, p,
              method, circles, lam, rho, mu, states, jac_x, jac_u, jac_tau, grad_x, grad_u,
              out_grad_u, grad_z, cons):
    """
    Minimise the augmented Lagrangian over the box by projected L-BFGS, in place on z.

    The variables at a bound whose gradient points outwards are held; the two-loop recursion
    (memory mem_s, mem_y; mem_info = [pairs stored, next slot]) acts on the others, and an
    Armijo backtracking search runs along the projection of that direction onto the box.
    Memory persists across calls, so the solve can run in chunks.  Returns (iterations,
    code, value) with code 1 = projected gradient below gtol, 2 = no further decrease,
    0 = max_iter reached.
    """
    n = z.shape[0]
    depth = mem_s.shape[0]
    value = alm_value_gradient(z, x0, x_goal, u_max, p, method, circles, lam, rho, mu, states,
                               jac_x, jac_u, jac_tau, grad_x, grad_u, out_grad_u, grad_z,
                               cons)
    g = grad_z.copy()
    free = np.empty(n, dtype=np.bool_)
    d = np.empty(n)
    trial = np.empty(n)
    alpha_hist = np.empty(depth)
    stalls = 0
    for it in range(max_iter):
        pg = 0.0
        for i in range(n):
            at_low = z[i] <= lower[i] and g[i] > 0.0
            at_high = z[i] >= upper[i] and g[i] < 0.0
            free[i] = not (at_low or at_high)
            if free[i]:
                pg = max(pg, abs(g[i]))
        if pg <= gtol:
            return it, 1, value
        # Two-loop recursion on the free variables.
        for i in range(n):
            d[i] = -g[i] if free[i] else 0.0
        count = int(mem_info[0])
        head = int(mem_info[1])
        for k in range(count):
            slot = (head - 1 - k) % depth
            sy = _masked_dot(mem_s[slot], mem_y[slot], free)
            if sy <= 0.0:
                alpha_hist[k] = 0.0
                continue
            a = _masked_dot(mem_s[slot], d, free) / sy
            alpha_hist[k] = a
            for i in range(n):
                if free[i]:
                    d[i] -= a * mem_y[slot, i]
        if count > 0:
            slot = (head - 1) % depth
            yy = _masked_dot(mem_y[slot], mem_y[slot], free)
            sy = _masked_dot(mem_s[slot], mem_y[slot], free)
            if yy > 0.0 and sy > 0.0:
                for i in range(n):
                    d[i] *= sy / yy
        for k in range(count - 1, -1, -1):
            slot = (head - 1 - k) % depth
            sy = _masked_dot(mem_s[slot], mem_y[slot], free)
            if sy <= 0.0:
                continue
            b = _masked_dot(mem_y[slot], d, free) / sy
            for i in range(n):
                if free[i]:
                    d[i] += mem_s[slot, i] * (alpha_hist[k] - b)
        slope = _masked_dot(g, d, free)
        if slope >= 0.0:       # not a descent direction: restart from steepest descent
            mem_info[0] = 0.0
            for i in range(n):
                d[i] = -g[i] if free[i] else 0.0
            slope = _masked_dot(g, d, free)
        step = 1.0
        if int(mem_info[0]) == 0:
            step = min(1.0, 1.0 / max(pg, 1e-300))
        accepted = False
        for _ in range(40):
            decrease = 0.0
            for i in range(n):
                t = z[i] + step * d[i]
                t = min(upper[i], max(lower[i], t))
                trial[i] = t
                decrease += g[i] * (t - z[i])
            new_value = alm_value_gradient(trial, x0, x_goal, u_max, p, method, circles, lam,
                                           rho, mu, states, jac_x, jac_u, jac_tau, grad_x,
                                           grad_u, out_grad_u, grad_z, cons)
            if new_value <= value + 1e-4 * decrease and decrease < 0.0:
                accepted = True
                break
            step *= 0.5
        if not accepted:
            # Leave cons/grad consistent with z before giving up.
            alm_value_gradient(z, x0, x_goal, u_max, p, method, circles, lam, rho, mu, states,
                               jac_x, jac_u, jac_tau, grad_x, grad_u, out_grad_u, grad_z,
                               cons)
            return it, 2, value
        slot = int(mem_info[1])
        sy = 0.0
        for i in range(n):
            mem_s[slot, i] = trial[i] - z[i]
            mem_y[slot, i] = grad_z[i] - g[i]
            sy += mem_s[slot, i] * mem_y[slot, i]
        if sy > 1e-16:
            mem_info[1] = (slot + 1) % depth
            mem_info[0] = min(mem_info[0] + 1.0, float(depth))
        for i in range(n):
            z[i] = trial[i]
            g[i] = grad_z[i]
        # Relative decrease at round-off level for several steps: nothing left to gain.
        if value - new_value <= 1e-15 * max(1.0, abs(value)):
            stalls += 1
            if stalls >= 5:
                return it + 1, 2, new_value
        else:
            stalls = 0
        value = new_value
    return max_iter, 0, value


class Stop(Exception):
    """Raised inside the sub-problem to unwind on cancel/timeout."""


class FastRun:
    """Augmented-Lagrangian minimum-time solve, driven by solver.py."""

    def __init__(self, problem, method, t_f_bounds=(1e-3, 1e3)):
        n = problem.n_intervals
        self.problem = problem
        self.n = n
        self.method = method
        self.p, self.x0, self.x_goal, self.u_max, self.circles = problem.kernel_arrays()
        self.n_cons = 4 + n * self.circles.shape[0]
        self.ws = Workspace(n)
        self.grad_z = np.zeros(2 * n + 1)
        self.cons = np.zeros(self.n_cons)
        self.lam = np.zeros(4)
        self.mu = np.zeros(self.n_cons - 4)
        self.rho = 10.0
        self.z = np.zeros(2 * n + 1)
        self.z[2 * n] = problem.t_f0
        self.lower = np.full(2 * n + 1, -1.0)
        self.upper = np.full(2 * n + 1, 1.0)
        self.lower[-1], self.upper[-1] = t_f_bounds
        self.mem_s = np.zeros((LBFGS_MEMORY, 2 * n + 1))
        self.mem_y = np.zeros((LBFGS_MEMORY, 2 * n + 1))
        self.mem_info = np.zeros(2)
        self.evaluations = 0
        self.iterations = 0

    def value_gradient(self, z):
        """Sub-problem objective and gradient at z (also refreshes cons)."""
        ws = self.ws
        self.evaluations += 1
        value = alm_value_gradient(z, self.x0, self.x_goal, self.u_max, self.p, self.method,
                                   self.circles, self.lam, self.rho, self.mu, ws.states,
                                   ws.jac_x, ws.jac_u, ws.jac_tau, ws.grad_x, ws.grad_u,
                                   ws.out_grad_u, self.grad_z, self.cons)
        return value, self.grad_z.copy()

    def violation(self):
        """(terminal error norm, worst obstacle deficit) at the last evaluation."""
        term = float(np.linalg.norm(self.cons[:4]))
        deficit = float(max(0.0, -np.min(self.cons[4:]))) if self.n_cons > 4 else 0.0
        return term, deficit

    def controls(self, z=None):
        """Return the controls u (N x 2) of z (default: the current iterate)."""
        z = self.z if z is None else z
        return z[:2 * self.n].reshape(self.n, 2) * self.u_max[None, :]

    def solve_subproblem(self, max_iter, callback, chunk=100, gtol=1e-10):
        """
        Minimise L for fixed multipliers from the current z (projected L-BFGS, in chunks).

        callback(iterations) runs between chunks (progress, cancel); returns the stop code.
        """
        ws = self.ws
        self.mem_info[:] = 0.0
        done = 0
        code = 0
        while done < max_iter:
            n_iter, code, _ = lbfgs_box(
                self.z, self.lower, self.upper, min(chunk, max_iter - done), gtol,
                self.mem_s, self.mem_y, self.mem_info, self.x0, self.x_goal, self.u_max, self.p,
                self.method, self.circles, self.lam, self.rho, self.mu, ws.states, ws.jac_x,
                ws.jac_u, ws.jac_tau, ws.grad_x, ws.grad_u, ws.out_grad_u, self.grad_z,
                self.cons)
            done += n_iter
            self.iterations += n_iter
            if callback is not None:
                callback(n_iter)
            if code != 0:
                break
        self.value_gradient(self.z)          # constraints at the accepted point
        return code

    def update_multipliers(self):
        """First-order PHR multiplier update."""
        self.lam += self.rho * self.cons[:4]
        self.mu = np.maximum(0.0, self.mu - self.rho * self.cons[4:])


@njit(cache=True)
def obstacle_constraints(states, a, circles, cons, d_q1, d_q2):
    """Fill cons = (d^2 - R^2) / (2 R) ~ clearance [m] at nodes 0..N (N+1 x K), dc/dq1, dc/dq2."""
    for i in range(states.shape[0]):
        for k in range(circles.shape[0]):
            radius = circles[k, 2]
            d2, d2_q1, d2_q2 = segment_distance_sq(states[i, 0], states[i, 2], a,
                                                   circles[k, 0], circles[k, 1])
            cons[i, k] = (d2 - radius * radius) / (2.0 * radius)
            d_q1[i, k] = d2_q1 / (2.0 * radius)
            d_q2[i, k] = d2_q2 / (2.0 * radius)


@njit(cache=True)
def sensitivity_rows(jac_x, jac_u, jac_tau, u_max, nodes, seeds, rows):
    """
    Row m of rows (M x 2N+1) = d(seed_m . x(nodes[m])) / d(v, t_f), v = u / u_max.

    One backward sweep of the BPTT recursion per row, started at its own node (eqs. 21-22);
    the last column is the derivative wrt t_f = N tau.
    """
    n = jac_u.shape[0]
    for m in range(nodes.shape[0]):
        node = nodes[m]
        l0, l1, l2, l3 = seeds[m, 0], seeds[m, 1], seeds[m, 2], seeds[m, 3]
        for j in range(2 * n + 1):
            rows[m, j] = 0.0
        d_tau = 0.0
        for j in range(node - 1, -1, -1):
            d_tau += l0 * jac_tau[j, 0] + l1 * jac_tau[j, 1] + l2 * jac_tau[j, 2] \
                + l3 * jac_tau[j, 3]
            for k in range(2):
                rows[m, 2 * j + k] = u_max[k] * (jac_u[j, 0, k] * l0 + jac_u[j, 1, k] * l1
                                                 + jac_u[j, 2, k] * l2 + jac_u[j, 3, k] * l3)
            n0 = jac_x[j, 0, 0] * l0 + jac_x[j, 1, 0] * l1 + jac_x[j, 2, 0] * l2 \
                + jac_x[j, 3, 0] * l3
            n1 = jac_x[j, 0, 1] * l0 + jac_x[j, 1, 1] * l1 + jac_x[j, 2, 1] * l2 \
                + jac_x[j, 3, 1] * l3
            n2 = jac_x[j, 0, 2] * l0 + jac_x[j, 1, 2] * l1 + jac_x[j, 2, 2] * l2 \
                + jac_x[j, 3, 2] * l3
            n3 = jac_x[j, 0, 3] * l0 + jac_x[j, 1, 3] * l1 + jac_x[j, 2, 3] * l2 \
                + jac_x[j, 3, 3] * l3
            l0, l1, l2, l3 = n0, n1, n2, n3
        rows[m, 2 * n] = d_tau / n


class FeasibilityProjector:
    """
    Gauss-Newton projection onto {x(N) = x_goal, clearance >= 0} at a fixed t_f.

    Levenberg-Marquardt minimum-norm steps in the controls that are inside the box or would
    leave their bound inwards; the rows are the terminal residuals and the violated obstacle
    constraints.  Used to carry a coarse-grid optimum to a finer grid and to bracket t_f.
    """

    def __init__(self, run):
        self.run = run
        n = run.n
        k = run.circles.shape[0]
        self.cons = np.zeros((n + 1, k))
        self.d_q1 = np.zeros((n + 1, k))
        self.d_q2 = np.zeros((n + 1, k))

    def residuals(self, v, t_f):
        """Rollout; returns (terminal residual (4), obstacle constraints (N+1 x K))."""
        run = self.run
        ws = run.ws
        controls = v.reshape(run.n, 2) * run.u_max[None, :]
        rollout_linearized(run.x0, controls, t_f / run.n, run.p, run.method, ws.states,
                           ws.jac_x, ws.jac_u, ws.jac_tau)
        if self.cons.shape[1]:
            obstacle_constraints(ws.states, run.p[3], run.circles, self.cons, self.d_q1,
                                 self.d_q2)
        return ws.states[run.n] - run.x_goal, self.cons

    def _merit(self, h, cons):
        viol = np.minimum(cons, 0.0)
        return float(h @ h + np.sum(viol * viol))

    def _worst(self, h, cons):
        return max(float(np.max(np.abs(h))), float(max(0.0, -cons.min())) if cons.size else 0.0)

    def project(self, v, t_f, tol=1e-11, max_iter=30, check=None):
        """Return (ok, v) with v feasible to tol at t_f, or ok False (Levenberg-Marquardt)."""
        run = self.run
        ws = run.ws
        v = v.copy()
        damping = 1e-6
        h, cons = self.residuals(v, t_f)
        merit = self._merit(h, cons)
        for _ in range(max_iter):
            if check is not None:
                check()
            if self._worst(h, cons) <= tol:
                return True, v
            violated = np.argwhere(cons[1:] < 0.0) if cons.size else np.zeros((0, 2), int)
            m = 4 + violated.shape[0]
            nodes = np.empty(m, dtype=np.int64)
            seeds = np.zeros((m, 4))
            target = np.empty(m)
            nodes[:4] = run.n
            seeds[:4, :4] = np.eye(4)
            target[:4] = -h
            for row, (i, k) in enumerate(violated, start=4):
                node = i + 1
                nodes[row] = node
                seeds[row, 0] = self.d_q1[node, k]
                seeds[row, 2] = self.d_q2[node, k]
                target[row] = -cons[node, k]
            rows = np.empty((m, 2 * run.n + 1))
            sensitivity_rows(ws.jac_x, ws.jac_u, ws.jac_tau, run.u_max, nodes, seeds, rows)
            # Free variables: inside the box, or at a bound that the unconstrained minimum-norm
            # step would leave inwards (so bang-bang arcs can give way where needed).
            jall = rows[:, :-1]
            gram = jall @ jall.T
            scale = max(float(np.trace(gram)) / m, 1e-300)
            try:
                probe = jall.T @ np.linalg.solve(gram + damping * scale * np.eye(m), target)
            except np.linalg.LinAlgError:
                probe = np.zeros_like(v)
            outward = (((v >= 1.0 - 1e-12) & (probe > 0.0))
                       | ((v <= -1.0 + 1e-12) & (probe < 0.0)))
            free = ~outward
            jf = jall[:, free]
            gram = jf @ jf.T
            scale = max(float(np.trace(gram)) / m, 1e-300)
            accepted = False
            for _ in range(10):
                try:
                    step = jf.T @ np.linalg.solve(gram + damping * scale * np.eye(m), target)
                except np.linalg.LinAlgError:
                    damping *= 10.0
                    continue
                trial = v.copy()
                trial[free] = np.clip(v[free] + step, -1.0, 1.0)
                th, tc = self.residuals(trial, t_f)
                t_merit = self._merit(th, tc)
                if t_merit < merit:
                    v, h, cons, merit = trial, th, tc, t_merit
                    damping = max(damping * 0.1, 1e-12)
                    accepted = True
                    break
                damping *= 10.0
            if not accepted:
                break
        h, cons = self.residuals(v, t_f)
        return self._worst(h, cons) <= tol, v
