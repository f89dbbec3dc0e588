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

from .model import dynamics_jacobians, NX, rhs, rhs_partials

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


@njit(cache=True)
def _rk4_linearized(i, states, controls, tau, p, jac_x, jac_u, jac_tau):
    # Chain rule through the stages k_s = f(x + c_s tau k_{s-1}, u) (not a hot path).
    x = states[i].copy()
    u = controls[i].copy()
    eye = np.eye(NX)
    k1, a1, b1 = dynamics_jacobians(x, u, p)
    k2, a2, b2 = dynamics_jacobians(x + 0.5 * tau * k1, u, p)
    k3, a3, b3 = dynamics_jacobians(x + 0.5 * tau * k2, u, p)
    k4, a4, b4 = dynamics_jacobians(x + tau * k3, u, p)
    dk2x = a2 @ (eye + 0.5 * tau * a1)
    dk2u = a2 @ (0.5 * tau * b1) + b2
    dk3x = a3 @ (eye + 0.5 * tau * dk2x)
    dk3u = a3 @ (0.5 * tau * dk2u) + b3
    dk4x = a4 @ (eye + tau * dk3x)
    dk4u = a4 @ (tau * dk3u) + b4
    dk2t = a2 @ (0.5 * k1)
    dk3t = a3 @ (0.5 * k2 + 0.5 * tau * dk2t)
    dk4t = a4 @ (k3 + tau * dk3t)
    incr = (k1 + 2.0 * k2 + 2.0 * k3 + k4) / 6.0
    states[i + 1, :] = x + tau * incr
    jac_x[i, :, :] = eye + tau / 6.0 * (a1 + 2.0 * dk2x + 2.0 * dk3x + dk4x)
    jac_u[i, :, :] = tau / 6.0 * (b1 + 2.0 * dk2u + 2.0 * dk3u + dk4u)
    jac_tau[i, :] = incr + tau / 6.0 * (2.0 * dk2t + 2.0 * dk3t + dk4t)


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
            d = rhs_partials(x1, x2, x3, x4, u1, u2, p)
            states[i + 1, 0] = x1 + tau * f[0]
            states[i + 1, 1] = x2 + tau * f[1]
            states[i + 1, 2] = x3 + tau * f[2]
            states[i + 1, 3] = x4 + tau * f[3]
            jac_tau[i, 0], jac_tau[i, 1], jac_tau[i, 2], jac_tau[i, 3] = f
            for r in range(NX):
                for c in range(NX):
                    jac_x[i, r, c] = 0.0
                jac_x[i, r, r] = 1.0
                jac_u[i, r, 0] = 0.0
                jac_u[i, r, 1] = 0.0
            jac_x[i, 0, 1] = tau
            jac_x[i, 1, 1] = 1.0 + tau * d[0]
            jac_x[i, 1, 2] = tau * d[1]
            jac_x[i, 1, 3] = tau * d[2]
            jac_x[i, 2, 3] = tau
            jac_x[i, 3, 1] = tau * d[3]
            jac_x[i, 3, 2] = tau * d[4]
            jac_u[i, 1, 0] = tau * d[5]
            jac_u[i, 3, 1] = tau * d[6]
    else:
        for i in range(controls.shape[0]):
            _rk4_linearized(i, states, controls, tau, p, jac_x, jac_u, jac_tau)
