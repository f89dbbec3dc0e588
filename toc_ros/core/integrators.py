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
Discretisation of eq. (37): x(i+1) = f(x(i), u(i)) of eq. (2), piecewise-constant controls.

Two one-step maps on the interval tau = t_f / N: explicit Euler (the paper's) and classic RK4
with u held over the step.  rollout_linearized also returns the Jacobians X(j) = dx(j+1)/dx(j)
and U(j) = dx(j+1)/du(j) used by the BPTT recursion (eqs. 21-22, 25, 27), and dx(j+1)/dtau,
which the free-final-time solver needs.  Outputs go into caller-owned buffers, indexed rather
than sliced, so that the hot loops allocate nothing.
"""

from numba import njit
import numpy as np

from .model import NX, rhs, rhs_partials

EULER = 0
RK4 = 1
INTEGRATORS = {'euler': EULER, 'rk4': RK4}


def integrator_id(name):
    """Map an integrator name to its kernel id (ValueError for unknown names)."""
    try:
        return INTEGRATORS[name]
    except (KeyError, TypeError):
        raise ValueError(f'integrator must be one of {sorted(INTEGRATORS)}, got {name!r}')


@njit(cache=True, inline='always')
def step_scalar(x1, x2, x3, x4, u1, u2, tau, p, method):
    """One step of eq. (2) on scalars: the next state as a tuple."""
    k1 = rhs(x1, x2, x3, x4, u1, u2, p)
    if method == EULER:
        return (x1 + tau * k1[0], x2 + tau * k1[1], x3 + tau * k1[2], x4 + tau * k1[3])
    h = 0.5 * tau
    k2 = rhs(x1 + h * k1[0], x2 + h * k1[1], x3 + h * k1[2], x4 + h * k1[3], u1, u2, p)
    k3 = rhs(x1 + h * k2[0], x2 + h * k2[1], x3 + h * k2[2], x4 + h * k2[3], u1, u2, p)
    k4 = rhs(x1 + tau * k3[0], x2 + tau * k3[1], x3 + tau * k3[2], x4 + tau * k3[3],
             u1, u2, p)
    w = tau / 6.0
    return (x1 + w * (k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0]),
            x2 + w * (k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1]),
            x3 + w * (k1[2] + 2.0 * k2[2] + 2.0 * k3[2] + k4[2]),
            x4 + w * (k1[3] + 2.0 * k2[3] + 2.0 * k3[3] + k4[3]))


@njit(cache=True)
def step(x, u, tau, p, method):
    """One step x(i+1) = f(x(i), u(i)) of eq. (2) as a new array."""
    out = np.empty(NX)
    out[0], out[1], out[2], out[3] = step_scalar(x[0], x[1], x[2], x[3], u[0], u[1], tau, p,
                                                 method)
    return out


@njit(cache=True)
def rollout(x0, controls, tau, p, method, states):
    """Fill states (N+1 x 4) with the trajectory of eq. (28) from x0 under controls (N x 2)."""
    for r in range(NX):
        states[0, r] = x0[r]
    for i in range(controls.shape[0]):
        states[i + 1, 0], states[i + 1, 1], states[i + 1, 2], states[i + 1, 3] = step_scalar(
            states[i, 0], states[i, 1], states[i, 2], states[i, 3],
            controls[i, 0], controls[i, 1], tau, p, method)


@njit(cache=True, inline='always')
def _stage_jacobians(d, jx, ju):
    """Write df/dx, df/du of eq. (37) from the rhs_partials tuple into jx (4x4), ju (4x2)."""
    f1_x2, f1_x3, f1_x4, f3_x2, f3_x3, f1_u1, f3_u2 = d
    for r in range(NX):
        for c in range(NX):
            jx[r, c] = 0.0
        ju[r, 0] = 0.0
        ju[r, 1] = 0.0
    jx[0, 1] = 1.0
    jx[1, 1], jx[1, 2], jx[1, 3] = f1_x2, f1_x3, f1_x4
    jx[2, 3] = 1.0
    jx[3, 1], jx[3, 2] = f3_x2, f3_x3
    ju[1, 0], ju[3, 1] = f1_u1, f3_u2


@njit(cache=True, inline='always')
def _rk4_linearized(i, states, controls, tau, p, jac_x, jac_u, jac_tau, scratch):
    # Chain rule through the stages k_s = f(x + c_s tau k_{s-1}, u); scratch holds the stage
    # Jacobians a_s (4x4), b_s (4x2) and the running dk/dx, dk/du, dk/dtau, so nothing is
    # allocated per step.
    x1, x2, x3, x4 = states[i, 0], states[i, 1], states[i, 2], states[i, 3]
    u1, u2 = controls[i, 0], controls[i, 1]
    h = 0.5 * tau
    k = scratch[5]
    coef = (0.0, h, h, tau)
    dkx, dku, dkt = scratch[0], scratch[1], scratch[2]   # (4, 4, 4), (4, 4, 2), (4, 4)
    ax, bu = scratch[3], scratch[4]
    for s in range(4):
        c = coef[s]
        if s == 0:
            y1, y2, y3, y4 = x1, x2, x3, x4
        else:
            y1 = x1 + c * k[s - 1, 0]
            y2 = x2 + c * k[s - 1, 1]
            y3 = x3 + c * k[s - 1, 2]
            y4 = x4 + c * k[s - 1, 3]
        f = rhs(y1, y2, y3, y4, u1, u2, p)
        k[s, 0], k[s, 1], k[s, 2], k[s, 3] = f
        _stage_jacobians(rhs_partials(y1, y2, y3, y4, u1, u2, p), ax[0], bu[0])
        a = ax[0]
        b = bu[0]
        # dk_s/dx = a (I + c dk_{s-1}/dx); dk_s/du = a c dk_{s-1}/du + b;
        # dk_s/dtau = a (c' k_{s-1} + c dk_{s-1}/dtau) with c' = dc/dtau.
        for r in range(NX):
            for col in range(NX):
                acc = a[r, col]
                if s > 0:
                    for m in range(NX):
                        acc += a[r, m] * c * dkx[s - 1, m, col]
                dkx[s, r, col] = acc
            for col in range(2):
                acc = b[r, col]
                if s > 0:
                    for m in range(NX):
                        acc += a[r, m] * c * dku[s - 1, m, col]
                dku[s, r, col] = acc
            acc = 0.0
            if s > 0:
                dc = c / tau
                for m in range(NX):
                    acc += a[r, m] * (dc * k[s - 1, m] + c * dkt[s - 1, m])
            dkt[s, r] = acc
    w = tau / 6.0
    for r in range(NX):
        incr = (k[0, r] + 2.0 * k[1, r] + 2.0 * k[2, r] + k[3, r]) / 6.0
        states[i + 1, r] = states[i, r] + tau * incr
        jac_tau[i, r] = incr + w * (2.0 * dkt[1, r] + 2.0 * dkt[2, r] + dkt[3, r])
        for col in range(NX):
            jac_x[i, r, col] = (1.0 if r == col else 0.0) + w * (
                dkx[0, r, col] + 2.0 * dkx[1, r, col] + 2.0 * dkx[2, r, col] + dkx[3, r, col])
        for col in range(2):
            jac_u[i, r, col] = w * (dku[0, r, col] + 2.0 * dku[1, r, col]
                                    + 2.0 * dku[2, r, col] + dku[3, r, col])


@njit(cache=True)
def rollout_linearized(x0, controls, tau, p, method, states, jac_x, jac_u, jac_tau):
    """Trajectory (eq. 28) plus per-step Jacobians X(j), U(j), dx(j+1)/dtau, in place."""
    for r in range(NX):
        states[0, r] = x0[r]
    if method == EULER:
        # Written out inline: a helper call per step costs twice the step itself.
        for i in range(controls.shape[0]):
            x1, x2, x3, x4 = states[i, 0], states[i, 1], states[i, 2], states[i, 3]
            u1, u2 = controls[i, 0], controls[i, 1]
            f = rhs(x1, x2, x3, x4, u1, u2, p)
            f1_x2, f1_x3, f1_x4, f3_x2, f3_x3, f1_u1, f3_u2 = rhs_partials(
                x1, x2, x3, x4, u1, u2, p)
            states[i + 1, 0] = x1 + tau * f[0]
            states[i + 1, 1] = x2 + tau * f[1]
            states[i + 1, 2] = x3 + tau * f[2]
            states[i + 1, 3] = x4 + tau * f[3]
            jac_tau[i, 0], jac_tau[i, 1], jac_tau[i, 2], jac_tau[i, 3] = f
            # I + tau df/dx and tau df/du, every entry written once (sparsity of eq. 37).
            jac_x[i, 0, 0], jac_x[i, 0, 1], jac_x[i, 0, 2], jac_x[i, 0, 3] = 1.0, tau, 0.0, 0.0
            jac_x[i, 1, 0] = 0.0
            jac_x[i, 1, 1] = 1.0 + tau * f1_x2
            jac_x[i, 1, 2] = tau * f1_x3
            jac_x[i, 1, 3] = tau * f1_x4
            jac_x[i, 2, 0], jac_x[i, 2, 1], jac_x[i, 2, 2], jac_x[i, 2, 3] = 0.0, 0.0, 1.0, tau
            jac_x[i, 3, 0] = 0.0
            jac_x[i, 3, 1] = tau * f3_x2
            jac_x[i, 3, 2] = tau * f3_x3
            jac_x[i, 3, 3] = 1.0
            jac_u[i, 0, 0], jac_u[i, 0, 1] = 0.0, 0.0
            jac_u[i, 1, 0], jac_u[i, 1, 1] = tau * f1_u1, 0.0
            jac_u[i, 2, 0], jac_u[i, 2, 1] = 0.0, 0.0
            jac_u[i, 3, 0], jac_u[i, 3, 1] = 0.0, tau * f3_u2
    else:
        scratch = (np.zeros((4, NX, NX)), np.zeros((4, NX, 2)), np.zeros((4, NX)),
                   np.zeros((1, NX, NX)), np.zeros((1, NX, 2)), np.zeros((4, NX)))
        for i in range(controls.shape[0]):
            _rk4_linearized(i, states, controls, tau, p, jac_x, jac_u, jac_tau, scratch)
