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
The backpropagation-through-time gradient, eqs. (16)-(32), in one place.

The paper propagates two quantities backwards: P(j) for the running cost (eqs. 24-25) and
D(j) = d x(N)/d x(j+1) for the terminal penalty (eq. 27), and combines them in eq. (31):
    J_u(j) = F_u(j) + U(j)^T P(j) + (G_x(N) D(j) U(j))^T.
Both are the same linear recursion, so they are carried as one adjoint vector
    lam(j+1) = dJ/dx(j+1) = P(j) + D(j)^T G_x(N),
    lam(N) = dJ/dx(N),  lam(j) = l_x(j) + X(j)^T lam(j+1),  J_u(j) = l_u(j) + U(j)^T lam(j+1),
which needs 4-vectors instead of the 4x4 matrices D(j) (O(N n^2) instead of O(N n^3)) and gives
the same numbers.  Here l_x, l_u are the partial derivatives of every cost term at a node
(tau-scaled running terms included), X(j), U(j) the step Jacobians of integrators.py.  The same
sweep also accumulates dJ/dtau = sum_j lam(j+1) . d x(j+1)/d tau for the free final time.
"""

from numba import njit
import numpy as np

from .integrators import rollout_linearized
from .obstacles import GRAD_EXACT
from .penalties import paper_penalties


@njit(cache=True)
def adjoint_sweep(jac_x, jac_u, jac_tau, grad_x, grad_u, out_grad_u):
    """
    Backward recursion (eqs. 24-27, 30-31): total dJ/du (N x 2) and dJ/dtau.

    grad_x (N+1 x 4) and grad_u (N x 2) hold the explicit partials of the cost; out_grad_u
    receives the total derivatives.  Returns (dJ/dtau, dJ/dx(0) as a 4-tuple).
    """
    n = jac_u.shape[0]
    l0, l1, l2, l3 = grad_x[n, 0], grad_x[n, 1], grad_x[n, 2], grad_x[n, 3]
    d_tau = 0.0
    for j in range(n - 1, -1, -1):
        for k in range(2):
            out_grad_u[j, k] = (grad_u[j, k] + jac_u[j, 0, k] * l0 + jac_u[j, 1, k] * l1
                                + jac_u[j, 2, k] * l2 + jac_u[j, 3, k] * l3)
        d_tau += l0 * jac_tau[j, 0] + l1 * jac_tau[j, 1] + l2 * jac_tau[j, 2] \
            + l3 * jac_tau[j, 3]
        n0 = grad_x[j, 0] + jac_x[j, 0, 0] * l0 + jac_x[j, 1, 0] * l1 + jac_x[j, 2, 0] * l2 \
            + jac_x[j, 3, 0] * l3
        n1 = grad_x[j, 1] + jac_x[j, 0, 1] * l0 + jac_x[j, 1, 1] * l1 + jac_x[j, 2, 1] * l2 \
            + jac_x[j, 3, 1] * l3
        n2 = grad_x[j, 2] + jac_x[j, 0, 2] * l0 + jac_x[j, 1, 2] * l1 + jac_x[j, 2, 2] * l2 \
            + jac_x[j, 3, 2] * l3
        n3 = grad_x[j, 3] + jac_x[j, 0, 3] * l0 + jac_x[j, 1, 3] * l1 + jac_x[j, 2, 3] * l2 \
            + jac_x[j, 3, 3] * l3
        l0, l1, l2, l3 = n0, n1, n2, n3
    return d_tau, (l0, l1, l2, l3)


class Workspace:
    """Preallocated buffers for one horizon length N (reused across iterations)."""

    def __init__(self, n):
        self.states = np.zeros((n + 1, 4))
        self.jac_x = np.zeros((n, 4, 4))
        self.jac_u = np.zeros((n, 4, 2))
        self.jac_tau = np.zeros((n, 4))
        self.grad_x = np.zeros((n + 1, 4))
        self.grad_u = np.zeros((n, 2))
        self.out_grad_u = np.zeros((n, 2))


@njit(cache=True)
def paper_cost_gradient(x0, x_goal, controls, tau, p, method, u_max, circles, k_b, k_v_hat,
                        k_p_hat, grad_mode, states, jac_x, jac_u, jac_tau, grad_x, grad_u,
                        out_grad_u):
    """
    J_T = J1 + J2 + J3 (eq. 33) and its BPTT gradient dJ_T/du (eq. 29) for fixed tau.

    With grad_mode GRAD_EXACT this is the true gradient; GRAD_SHORTCUT substitutes eq. (46).
    Returns (J1, J2, J3, dJ/dtau); the gradient is left in out_grad_u.
    """
    rollout_linearized(x0, controls, tau, p, method, states, jac_x, jac_u, jac_tau)
    j1, j2, j3 = paper_penalties(states, controls, x_goal, u_max, p[3], circles, k_b,
                                 k_v_hat, k_p_hat, grad_mode, grad_x, grad_u)
    d_tau, _ = adjoint_sweep(jac_x, jac_u, jac_tau, grad_x, grad_u, out_grad_u)
    return j1, j2, j3, d_tau


def paper_cost(x0, x_goal, controls, tau, p, method, u_max, circles, k_b, k_v_hat, k_p_hat,
               grad_mode=GRAD_EXACT):
    """Return (J_T, dJ_T/du) with fresh buffers (for tests and one-off calls)."""
    ws = Workspace(controls.shape[0])
    j1, j2, j3, _ = paper_cost_gradient(
        np.asarray(x0, float), np.asarray(x_goal, float), np.ascontiguousarray(controls, float),
        float(tau), p, method, np.asarray(u_max, float), np.reshape(circles, (-1, 3)),
        k_b, k_v_hat, k_p_hat, grad_mode, ws.states, ws.jac_x, ws.jac_u, ws.jac_tau, ws.grad_x,
        ws.grad_u, ws.out_grad_u)
    return j1 + j2 + j3, ws.out_grad_u.copy()
