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
Model-generic discretisation kernels: one step of eq. (2), its Jacobians and second-order terms.

The step is x(i+1) = Phi(x(i), u(i), tau) with piecewise-constant controls (explicit Euler,
the paper's, or classic RK4); the second-order terms are those the Newton-type solver needs.

These functions take the model's pointwise kernels (models/base.py) as arguments and are not
cached themselves: each model module binds them in small @njit(cache=True) wrappers, so numba
compiles and caches the machine code per model.  Work buffers come from step_work() so that
nothing is allocated per step.
"""

from numba import njit
import numpy as np

EULER = 0
RK4 = 1
INTEGRATORS = {'euler': EULER, 'rk4': RK4}


@njit(inline='always')
def _rk4_offset(s):
    # Stage offsets c_s of classic RK4 (times tau).
    if s == 0:
        return 0.0
    return 0.5 if s < 3 else 1.0


def integrator_id(name):
    """Map an integrator name to its kernel id (ValueError for unknown names)."""
    try:
        return INTEGRATORS[name]
    except (KeyError, TypeError):
        raise ValueError(f'integrator must be one of {sorted(INTEGRATORS)}, got {name!r}')


@njit
def step_work(nx, nu):
    """Work buffers of step/step_jacobians: (k, y, f, fx, fu, kx, ku, kt)."""
    return (np.zeros((4, nx)), np.zeros(nx), np.zeros(nx), np.zeros((nx, nx)),
            np.zeros((nx, nu)), np.zeros((4, nx, nx)), np.zeros((4, nx, nu)), np.zeros((4, nx)))


@njit(inline='always')
def step(rhs, x, u, tau, p, method, out, work):
    """Compute out = Phi(x, u, tau): one Euler or RK4 step."""
    k, y, f = work[0], work[1], work[2]
    nx = x.shape[0]
    if method == EULER:
        rhs(x, u, p, f)
        for r in range(nx):
            out[r] = x[r] + tau * f[r]
        return
    for s in range(4):
        if s == 0:
            for r in range(nx):
                y[r] = x[r]
        else:
            c = _rk4_offset(s) * tau
            for r in range(nx):
                y[r] = x[r] + c * k[s - 1, r]
        rhs(y, u, p, f)
        for r in range(nx):
            k[s, r] = f[r]
    w = tau / 6.0
    for r in range(nx):
        out[r] = x[r] + w * (k[0, r] + 2.0 * k[1, r] + 2.0 * k[2, r] + k[3, r])


@njit
def rollout(rhs, x0, controls, tau, p, method, states):
    """states[0] = x0, states[i+1] = Phi(states[i], controls[i], tau)."""
    nx = x0.shape[0]
    work = step_work(nx, controls.shape[1])
    for r in range(nx):
        states[0, r] = x0[r]
    for i in range(controls.shape[0]):
        step(rhs, states[i], controls[i], tau, p, method, states[i + 1], work)


@njit(inline='always')
def step_jacobians(rhs_jac, x, u, tau, p, method, out, jac_x, jac_u, jac_tau, work):
    """
    Compute out = Phi(x, u, tau) with jac_x = dPhi/dx, jac_u = dPhi/du, jac_tau = dPhi/dtau.

    RK4: chain rule through the stages k_s = f(x + c_s tau k_{s-1}, u) (eqs. 21-22 for the
    one-step map); Euler: I + tau df/dx, tau df/du, f.
    """
    k, y, f, fx, fu, kx, ku, kt = work
    nx, nu = jac_u.shape
    if method == EULER:
        rhs_jac(x, u, p, f, fx, fu)
        for r in range(nx):
            out[r] = x[r] + tau * f[r]
            jac_tau[r] = f[r]
            for c in range(nx):
                jac_x[r, c] = tau * fx[r, c]
            jac_x[r, r] += 1.0
            for c in range(nu):
                jac_u[r, c] = tau * fu[r, c]
        return
    for s in range(4):
        cs = _rk4_offset(s)
        c = cs * tau
        if s == 0:
            for r in range(nx):
                y[r] = x[r]
        else:
            for r in range(nx):
                y[r] = x[r] + c * k[s - 1, r]
        rhs_jac(y, u, p, f, fx, fu)
        for r in range(nx):
            k[s, r] = f[r]
        # dk_s/dx = fx (I + c dk_{s-1}/dx); dk_s/du = fx c dk_{s-1}/du + fu;
        # dk_s/dtau = fx (c_s k_{s-1} + c dk_{s-1}/dtau).
        for r in range(nx):
            for col in range(nx):
                acc = fx[r, col]
                if s > 0:
                    for m in range(nx):
                        acc += fx[r, m] * c * kx[s - 1, m, col]
                kx[s, r, col] = acc
            for col in range(nu):
                acc = fu[r, col]
                if s > 0:
                    for m in range(nx):
                        acc += fx[r, m] * c * ku[s - 1, m, col]
                ku[s, r, col] = acc
            acc = 0.0
            if s > 0:
                for m in range(nx):
                    acc += fx[r, m] * (cs * k[s - 1, m] + c * kt[s - 1, m])
            kt[s, r] = acc
    w = tau / 6.0
    for r in range(nx):
        incr = (k[0, r] + 2.0 * k[1, r] + 2.0 * k[2, r] + k[3, r]) / 6.0
        out[r] = x[r] + tau * incr
        jac_tau[r] = incr + w * (2.0 * kt[1, r] + 2.0 * kt[2, r] + kt[3, r])
        for col in range(nx):
            jac_x[r, col] = w * (kx[0, r, col] + 2.0 * kx[1, r, col] + 2.0 * kx[2, r, col]
                                 + kx[3, r, col])
        jac_x[r, r] += 1.0
        for col in range(nu):
            jac_u[r, col] = w * (ku[0, r, col] + 2.0 * ku[1, r, col] + 2.0 * ku[2, r, col]
                                 + ku[3, r, col])


@njit(inline='always')
def step_lagrangian_hessian(rhs_jac, rhs_hess, x, u, tau, p, lam, hxx, hxu, huu, hxt, hut,
                            work, hwork):
    """
    Second derivatives of lam . Phi(x, u, tau) in (x, u, tau).

    Exact for Euler (Phi = x + tau f): tau lam . f'' and the cross terms f_x^T lam,
    f_u^T lam in tau.  For RK4 the same expression is used, which differs from the exact
    RK4 Hessian by O(tau) relative terms: the Newton-type method then converges linearly with
    a contraction factor of that order (~1e-3) instead of quadratically.
    """
    f, fx, fu = work[2], work[3], work[4]
    nx, nu = hxu.shape
    rhs_jac(x, u, p, f, fx, fu)
    rhs_hess(x, u, p, lam, hwork[0], hwork[1], hwork[2])
    hx, hxu_f, huu_f = hwork[0], hwork[1], hwork[2]
    for r in range(nx):
        for c in range(nx):
            hxx[r, c] = tau * hx[r, c]
        for c in range(nu):
            hxu[r, c] = tau * hxu_f[r, c]
        acc = 0.0
        for m in range(nx):
            acc += fx[m, r] * lam[m]
        hxt[r] = acc
    for r in range(nu):
        for c in range(nu):
            huu[r, c] = tau * huu_f[r, c]
        acc = 0.0
        for m in range(nx):
            acc += fu[m, r] * lam[m]
        hut[r] = acc


@njit
def hessian_work(nx, nu):
    """Work buffers of step_lagrangian_hessian: (hxx, hxu, huu) of lam . f."""
    return (np.zeros((nx, nx)), np.zeros((nx, nu)), np.zeros((nu, nu)))
