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

"""Second-order BPTT: an augmented-Lagrangian iLQR (box-DDP) step for the free-t_f problem.

The backward sweep is the BPTT recursion of eqs. (24)-(31) carried to second order (a Riccati
recursion, Gauss-Newton curvature): alongside the adjoint V_x it propagates V_xx, which gives
per-step feedback gains and a Newton-like step in the controls and in tau.  The state is
augmented with tau (x5, constant along the horizon: x5(i+1) = x5(i)), so its coupling to every
step is handled exactly, and tau is optimised as a free initial state.  Controls are scaled,
v = u / u_max, and each step's 2-D box QP over v in [-1, 1] is solved exactly (bang-bang arcs
are where it is active).  Costs are those of fast_solver.alm_value_gradient: N tau + PHR terms
of the terminal and obstacle constraints.
"""

import math

from numba import njit
import numpy as np

from .integrators import step_scalar
from .obstacles import segment_distance_sq

NA = 5   # augmented state: q1, dq1, q2, dq2, tau


@njit(cache=True)
def al_cost(states, tau, x_goal, lam, rho, mu, circles, a, cons):
    """N tau + PHR terms (terminal, obstacles at nodes 1..N); fills cons like alm_value."""
    n = states.shape[0] - 1
    value = n * tau
    for r in range(4):
        h = states[n, r] - x_goal[r]
        cons[r] = h
        value += lam[r] * h + 0.5 * rho * h * h
    n_circles = circles.shape[0]
    for i in range(1, n + 1):
        for k in range(n_circles):
            radius = circles[k, 2]
            d2, _, _ = segment_distance_sq(states[i, 0], states[i, 2], a, circles[k, 0],
                                           circles[k, 1])
            c = (d2 - radius * radius) / (2.0 * radius)
            idx = (i - 1) * n_circles + k
            cons[4 + idx] = c
            shifted = mu[idx] - rho * c
            if shifted > 0.0:
                value += (shifted * shifted - mu[idx] * mu[idx]) / (2.0 * rho)
            else:
                value -= mu[idx] * mu[idx] / (2.0 * rho)
    return value


@njit(cache=True)
def _obstacle_terms(q1, q2, a, circles, mu, rho, i, lx, lxx):
    """Add gradient and Gauss-Newton Hessian of node i's PHR obstacle terms to lx, lxx."""
    n_circles = circles.shape[0]
    for k in range(n_circles):
        radius = circles[k, 2]
        d2, d2_q1, d2_q2 = segment_distance_sq(q1, q2, a, circles[k, 0], circles[k, 1])
        c = (d2 - radius * radius) / (2.0 * radius)
        idx = (i - 1) * n_circles + k
        shifted = mu[idx] - rho * c
        if shifted > 0.0:
            g1 = d2_q1 / (2.0 * radius)
            g2 = d2_q2 / (2.0 * radius)
            lx[0] -= shifted * g1
            lx[2] -= shifted * g2
            lxx[0, 0] += rho * g1 * g1
            lxx[0, 2] += rho * g1 * g2
            lxx[2, 0] += rho * g1 * g2
            lxx[2, 2] += rho * g2 * g2


@njit(cache=True)
def _box_qp2(h, g, lo, hi):
    """min 0.5 k'Hk + g'k over lo <= k <= hi in 2-D (H positive definite): k, free mask."""
    best = np.zeros(2)
    best_val = np.inf
    det = h[0, 0] * h[1, 1] - h[0, 1] * h[1, 0]
    cand = np.zeros(2)
    for mode0 in range(3):          # 0 free, 1 at lo, 2 at hi
        for mode1 in range(3):
            if mode0 == 0 and mode1 == 0:
                cand[0] = -(h[1, 1] * g[0] - h[0, 1] * g[1]) / det
                cand[1] = -(-h[1, 0] * g[0] + h[0, 0] * g[1]) / det
                if cand[0] < lo[0] or cand[0] > hi[0] or cand[1] < lo[1] or cand[1] > hi[1]:
                    continue
            elif mode0 == 0:
                cand[1] = lo[1] if mode1 == 1 else hi[1]
                cand[0] = min(hi[0], max(lo[0], -(g[0] + h[0, 1] * cand[1]) / h[0, 0]))
            elif mode1 == 0:
                cand[0] = lo[0] if mode0 == 1 else hi[0]
                cand[1] = min(hi[1], max(lo[1], -(g[1] + h[1, 0] * cand[0]) / h[1, 1]))
            else:
                cand[0] = lo[0] if mode0 == 1 else hi[0]
                cand[1] = lo[1] if mode1 == 1 else hi[1]
            val = 0.5 * (h[0, 0] * cand[0] * cand[0] + 2.0 * h[0, 1] * cand[0] * cand[1]
                         + h[1, 1] * cand[1] * cand[1]) + g[0] * cand[0] + g[1] * cand[1]
            if val < best_val:
                best_val = val
                best[0] = cand[0]
                best[1] = cand[1]
    free = np.zeros(2, dtype=np.bool_)
    for j in range(2):
        free[j] = lo[j] + 1e-12 < best[j] < hi[j] - 1e-12
    return best, free


@njit(cache=True)
def backward_pass(states, v, tau, jac_x, jac_u, jac_tau, u_max, x_goal, lam, rho, mu,
                  circles, a, reg, k_ff, k_fb):
    """Riccati sweep; fills k_ff (N x 2), k_fb (N x 2 x 5); returns (d_tau, dv1, dv2, ok).

    dv1, dv2 are the linear and quadratic terms of the predicted cost change for step alpha:
    dV(alpha) = alpha dv1 + alpha^2 dv2.
    """
    n = v.shape[0]
    vx = np.zeros(NA)
    vxx = np.zeros((NA, NA))
    # Terminal: N tau + lam'h + rho/2 |h|^2 (+ obstacle terms at node N).
    for r in range(4):
        h = states[n, r] - x_goal[r]
        vx[r] = lam[r] + rho * h
        vxx[r, r] = rho
    vx[4] = n
    _obstacle_terms(states[n, 0], states[n, 2], a, circles, mu, rho, n, vx, vxx)
    fa = np.zeros((NA, NA))
    fb = np.zeros((NA, 2))
    qx = np.zeros(NA)
    qu = np.zeros(2)
    qxx = np.zeros((NA, NA))
    quu = np.zeros((2, 2))
    qux = np.zeros((2, NA))
    lo = np.zeros(2)
    hi = np.zeros(2)
    dv1 = 0.0
    dv2 = 0.0
    for i in range(n - 1, -1, -1):
        # Augmented Jacobians [[X, dx/dtau], [0, 1]] and [[U diag(u_max)], [0]].
        for r in range(4):
            for c in range(4):
                fa[r, c] = jac_x[i, r, c]
            fa[r, 4] = jac_tau[i, r]
            fb[r, 0] = jac_u[i, r, 0] * u_max[0]
            fb[r, 1] = jac_u[i, r, 1] * u_max[1]
        for c in range(4):
            fa[4, c] = 0.0
        fa[4, 4] = 1.0
        fb[4, 0] = 0.0
        fb[4, 1] = 0.0
        qx[:] = fa.T @ vx
        qu[:] = fb.T @ vx
        vxx_fa = vxx @ fa
        qxx[:, :] = fa.T @ vxx_fa
        quu[:, :] = fb.T @ (vxx @ fb)
        qux[:, :] = fb.T @ vxx_fa
        if i > 0:
            _obstacle_terms(states[i, 0], states[i, 2], a, circles, mu, rho, i, qx, qxx)
        scale = max(quu[0, 0], quu[1, 1], 1e-300)
        quu[0, 0] += reg * scale
        quu[1, 1] += reg * scale
        if quu[0, 0] <= 0.0 or quu[1, 1] <= 0.0 or \
                quu[0, 0] * quu[1, 1] - quu[0, 1] * quu[1, 0] <= 0.0:
            return 0.0, 0.0, 0.0, False
        for j in range(2):
            lo[j] = -1.0 - v[i, j]
            hi[j] = 1.0 - v[i, j]
        kk, free = _box_qp2(quu, qu, lo, hi)
        k_ff[i, 0] = kk[0]
        k_ff[i, 1] = kk[1]
        # Feedback only in the free directions (box-DDP).
        k_fb[i, :, :] = 0.0
        if free[0] and free[1]:
            det = quu[0, 0] * quu[1, 1] - quu[0, 1] * quu[1, 0]
            for c in range(NA):
                k_fb[i, 0, c] = -(quu[1, 1] * qux[0, c] - quu[0, 1] * qux[1, c]) / det
                k_fb[i, 1, c] = -(-quu[1, 0] * qux[0, c] + quu[0, 0] * qux[1, c]) / det
        elif free[0]:
            for c in range(NA):
                k_fb[i, 0, c] = -qux[0, c] / quu[0, 0]
        elif free[1]:
            for c in range(NA):
                k_fb[i, 1, c] = -qux[1, c] / quu[1, 1]
        kmat = k_fb[i]
        # V_x = Q_x + K'Q_uu k + K'Q_u + Q_ux'k ; V_xx = Q_xx + K'Q_uu K + K'Q_ux + Q_ux'K
        quu_k = quu @ kk
        vx[:] = qx + kmat.T @ quu_k + kmat.T @ qu + qux.T @ kk
        t1 = kmat.T @ (quu @ kmat)
        t2 = kmat.T @ qux
        vxx[:, :] = qxx + t1 + t2 + t2.T
        for r in range(NA):
            for c in range(r + 1, NA):
                s = 0.5 * (vxx[r, c] + vxx[c, r])
                vxx[r, c] = s
                vxx[c, r] = s
        dv1 += kk[0] * qu[0] + kk[1] * qu[1]
        dv2 += 0.5 * (kk[0] * quu_k[0] + kk[1] * quu_k[1])
    # Free initial tau: Newton step on the value function's tau component.
    if vxx[4, 4] > 0.0:
        d_tau = -vx[4] / (vxx[4, 4] * (1.0 + reg))
    else:
        d_tau = -vx[4] * 1e-12
    dv1 += vx[4] * d_tau
    dv2 += 0.5 * vxx[4, 4] * d_tau * d_tau
    return d_tau, dv1, dv2, True


@njit(cache=True)
def forward_pass(x0, states, v, tau, k_ff, k_fb, d_tau, alpha, u_max, p, method,
                 new_states, new_v):
    """Roll out the policy v + alpha k + K dx (clamped to [-1, 1]); returns the new tau."""
    new_tau = tau + alpha * d_tau
    if new_tau <= 0.0:
        new_tau = 0.5 * tau
    dx = np.zeros(NA)
    for r in range(4):
        new_states[0, r] = x0[r]
    dx[4] = new_tau - tau
    n = v.shape[0]
    for i in range(n):
        for r in range(4):
            dx[r] = new_states[i, r] - states[i, r]
        for j in range(2):
            val = v[i, j] + alpha * k_ff[i, j]
            for c in range(NA):
                val += k_fb[i, j, c] * dx[c]
            new_v[i, j] = min(1.0, max(-1.0, val))
        nxt = step_scalar(new_states[i, 0], new_states[i, 1], new_states[i, 2],
                          new_states[i, 3], new_v[i, 0] * u_max[0], new_v[i, 1] * u_max[1],
                          new_tau, p, method)
        new_states[i + 1, 0], new_states[i + 1, 1], new_states[i + 1, 2], \
            new_states[i + 1, 3] = nxt
        if not (math.isfinite(nxt[0]) and math.isfinite(nxt[1]) and math.isfinite(nxt[2])
                and math.isfinite(nxt[3])):
            return math.nan
    return new_tau
