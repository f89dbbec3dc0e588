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

"""Fast mode: a feasible minimum-time solution built on the same BPTT gradient.

The discrete problem is the paper's (eqs. 1-5 with F-hat = 1, i.e. J0 = N tau = t_f) with the
constraints kept as constraints instead of fixed penalties:

    minimise t_f  over  u(0..N-1), t_f
    s.t.  x(N) = x_goal                               (eq. 3)
          |u_k(i)| <= u_k,max                         (eq. 47)
          dist(arm segment at node i, c_k) >= R_k     (eq. 41, whole arm, any quadrant)

solved by an augmented Lagrangian (Powell-Hestenes-Rockafellar) on the terminal and obstacle
constraints, whose sub-problems are bound-constrained (L-BFGS-B, scipy) in scaled controls
v = u / u_max in [-1, 1] and t_f.  The sub-problem gradient, including d/dt_f, comes from one
BPTT sweep (bptt.adjoint_sweep).  Bounds hold exactly at every iterate; the outer loop stops
when the terminal error and the clearance deficit are below tolerance and the multipliers
have settled.  The obstacle constraint uses the squared segment distance (C1), scaled as
(d^2 - R^2) / (2 R) ~ d - R, rather than the ray formula of eq. (41), whose derivative is
unbounded where the ray is tangent to the circle.
"""

import math
import time

from numba import njit
import numpy as np
from scipy.optimize import minimize

from .bptt import adjoint_sweep, Workspace
from .integrators import rollout_linearized
from .obstacles import segment_distance_sq


@njit(cache=True)
def alm_value_gradient(z, x0, x_goal, u_max, p, method, circles, lam, rho, mu, states,
                       jac_x, jac_u, jac_tau, grad_x, grad_u, out_grad_u, grad_z, cons):
    """Augmented Lagrangian L(v, t_f) and dL/dz for z = [v (2N, row-major), t_f].

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


class Stop(Exception):
    """Raised inside the sub-problem to unwind on cancel/timeout."""


class FastRun:
    """Augmented-Lagrangian minimum-time solve, driven by solver.py."""

    def __init__(self, problem, method, t_f_bounds=(1e-3, 1e3)):
        n = problem.n_intervals
        self.problem = problem
        self.n = n
        self.method = method
        self.p = problem.robot.packed()
        self.x0 = np.asarray(problem.x0, float)
        self.x_goal = np.asarray(problem.x_goal, float)
        self.u_max = problem.robot.u_max
        self.circles = np.ascontiguousarray(problem.circles())
        self.n_cons = 4 + n * self.circles.shape[0]
        self.ws = Workspace(n)
        self.grad_z = np.zeros(2 * n + 1)
        self.cons = np.zeros(self.n_cons)
        self.lam = np.zeros(4)
        self.mu = np.zeros(self.n_cons - 4)
        self.rho = 10.0
        self.z = np.zeros(2 * n + 1)
        self.z[2 * n] = problem.t_f0
        self.bounds = [(-1.0, 1.0)] * (2 * n) + [t_f_bounds]
        self.evaluations = 0
        self.iterations = 0

    def value_gradient(self, z):
        """Sub-problem objective and gradient (scipy callback)."""
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
        """Controls u (N x 2) of z (default: the current iterate)."""
        z = self.z if z is None else z
        return z[:2 * self.n].reshape(self.n, 2) * self.u_max[None, :]

    def solve_subproblem(self, max_iter, callback):
        """Minimise L for fixed multipliers from the current z; returns the scipy result."""
        res = minimize(self.value_gradient, self.z, jac=True, method='L-BFGS-B',
                       bounds=self.bounds, callback=callback,
                       options={'maxiter': max_iter, 'maxcor': 20, 'ftol': 1e-15,
                                'gtol': 1e-10, 'maxls': 40})
        self.z = res.x
        self.iterations += res.nit
        self.value_gradient(self.z)          # constraints at the accepted point
        return res

    def update_multipliers(self):
        """First-order PHR multiplier update."""
        self.lam += self.rho * self.cons[:4]
        self.mu = np.maximum(0.0, self.mu - self.rho * self.cons[4:])
