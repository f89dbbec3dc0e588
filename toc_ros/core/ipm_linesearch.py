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
The interior-point method's step length: fraction to the boundary, filter line search, update.

IPOPT's rules (Waechter & Biegler 2006): the primal and dual step lengths are capped so that
every slack and bound dual keeps a fraction of its distance to zero; the primal length is then
halved until the trial point is acceptable to the filter of (constraint violation, barrier
objective) pairs, with the Armijo condition on the barrier objective when the step is an
f-type step.  accept_trial moves to the accepted point and keeps the duals within a factor
KAPPA_SIGMA of their primal-dual values mu / s.
"""

import math

from numba import njit
import numpy as np

from .horizon import step, step_work
from .ipm_evaluation import unscaled_controls
from .ipm_obstacles import obstacle_values, obstacle_work
from .ipm_workspace import F_ELASTIC, F_MU, F_PHI, F_T, F_T_HIGH, F_T_LOW, F_T_REF, F_THETA, \
    F_THETA_MAX, F_THETA_MIN, F_ZT_HIGH, F_ZT_LOW, I_BACKTRACKS, I_METHOD, I_N, I_N_FILTER, \
    I_STOP, MAX_FILTER

MAX_BACKTRACKS = 40
# Safeguard of the bound duals: within a factor KAPPA_SIGMA of mu / slack.
KAPPA_SIGMA = 1e10


@njit
def _max_step(value, step, frac, alpha):
    # Largest alpha' <= alpha with value + alpha' step >= (1 - frac) value (value > 0).
    if step < 0.0:
        limit = -frac * value / step
        if limit < alpha:
            return limit
    return alpha


@njit
def fraction_to_boundary(ws, dt, frac):
    """(alpha_primal, alpha_dual) of the fraction-to-the-boundary rule."""
    n = ws.iscal[I_N]
    nu = len(ws.size_u)
    nb = ws.s.shape[1]
    fs = ws.fscal
    ap = 1.0
    ad = 1.0
    for i in range(n):
        for c in range(nu):
            ap = _max_step(1.0 + ws.v[i, c], ws.dv[i, c], frac, ap)
            ap = _max_step(1.0 - ws.v[i, c], -ws.dv[i, c], frac, ap)
            ad = _max_step(ws.zl[i, c], ws.dzl[i, c], frac, ad)
            ad = _max_step(ws.zu[i, c], ws.dzu[i, c], frac, ad)
    rho_e = fs[F_ELASTIC]
    for i in range(1, n + 1):
        for j in range(nb):
            ap = _max_step(ws.s[i, j], ws.ds[i, j], frac, ap)
            ap = _max_step(ws.e[i, j], ws.de[i, j], frac, ap)
            ad = _max_step(ws.z[i, j], ws.dz[i, j], frac, ad)
            ad = _max_step(rho_e - ws.z[i, j], -ws.dz[i, j], frac, ad)
    ap = _max_step(fs[F_T] - fs[F_T_LOW], dt, frac, ap)
    ap = _max_step(fs[F_T_HIGH] - fs[F_T], -dt, frac, ap)
    return ap, ad


@njit
def t_bound_dual_limit(ws, dt, frac, ad):
    """Cap the dual step length ad so that the duals of the bounds on T stay positive."""
    fs = ws.fscal
    mu = fs[F_MU]
    s_low = fs[F_T] - fs[F_T_LOW]
    s_high = fs[F_T_HIGH] - fs[F_T]
    dzl_t = mu / s_low - fs[F_ZT_LOW] - fs[F_ZT_LOW] / s_low * dt
    dzu_t = mu / s_high - fs[F_ZT_HIGH] + fs[F_ZT_HIGH] / s_high * dt
    ad = _max_step(fs[F_ZT_LOW], dzl_t, frac, ad)
    return _max_step(fs[F_ZT_HIGH], dzu_t, frac, ad)


@njit
def trial_merit(rhs, segments, ws, alpha, dt):
    """(theta, phi) at the trial point x + alpha dx, v + alpha dv, s + alpha ds, T + alpha dT."""
    n = ws.iscal[I_N]
    method = ws.iscal[I_METHOD]
    nx = len(ws.size_x)
    nu = len(ws.size_u)
    nq = len(ws.size_q)
    nb = ws.s.shape[1]
    fs = ws.fscal
    mu = fs[F_MU]
    t_f = fs[F_T] + alpha * dt
    tau = t_f / n
    work = step_work(nx, nu)
    owork = obstacle_work(max(1, nb // max(1, ws.circles.shape[0])), nq)
    u = np.zeros(nu)
    nxt = np.zeros(nx)
    q = np.zeros(nq)
    for i in range(n + 1):
        for r in range(nx):
            ws.xt[i, r] = ws.x[i, r] + alpha * ws.dx[i, r]
    theta = 0.0
    barrier = 0.0
    elastic_cost = 0.0
    for i in range(n):
        for c in range(nu):
            vc = ws.v[i, c] + alpha * ws.dv[i, c]
            ws.vt[i, c] = vc
            barrier -= math.log(1.0 + vc) + math.log(1.0 - vc)
        unscaled_controls(ws.vt[i], ws.u_max, u)
        step(rhs, ws.xt[i], u, tau, ws.p, method, nxt, work)
        for r in range(nx):
            theta += abs(nxt[r] - ws.xt[i + 1, r])
    for r in range(nx):
        theta += abs(ws.xt[n, r] - ws.x_goal[r])
    for i in range(1, n + 1):
        if nb == 0:
            break
        for a in range(nq):
            q[a] = ws.xt[i, 2 * a]
        obstacle_values(segments, q, ws.p, ws.circles, ws.ct[i], owork)
        for j in range(nb):
            sj = ws.s[i, j] + alpha * ws.ds[i, j]
            ej = ws.e[i, j] + alpha * ws.de[i, j]
            ws.st[i, j] = sj
            ws.et[i, j] = ej
            theta += abs(ws.ct[i, j] + ej - sj)
            barrier -= math.log(sj) + math.log(ej)
            elastic_cost += fs[F_ELASTIC] * ej
    barrier -= math.log(t_f - fs[F_T_LOW]) + math.log(fs[F_T_HIGH] - t_f)
    return theta, 0.5 * t_f * t_f / fs[F_T_REF] + mu * barrier + elastic_cost


@njit
def barrier_slope(ws, dt):
    """Directional derivative of the barrier objective along the step."""
    n = ws.iscal[I_N]
    nu = len(ws.size_u)
    nb = ws.s.shape[1]
    fs = ws.fscal
    mu = fs[F_MU]
    acc = 0.0
    for i in range(n):
        for c in range(nu):
            acc += ws.dv[i, c] * (1.0 / (1.0 - ws.v[i, c]) - 1.0 / (1.0 + ws.v[i, c]))
    elastic = 0.0
    for i in range(1, n + 1):
        for j in range(nb):
            acc -= ws.ds[i, j] / ws.s[i, j] + ws.de[i, j] / ws.e[i, j]
            elastic += ws.de[i, j]
    acc -= dt / (fs[F_T] - fs[F_T_LOW]) - dt / (fs[F_T_HIGH] - fs[F_T])
    return fs[F_T] / fs[F_T_REF] * dt + mu * acc + fs[F_ELASTIC] * elastic


@njit
def _in_filter(ws, theta, phi):
    for k in range(ws.iscal[I_N_FILTER]):
        if theta >= ws.filt[k, 0] and phi >= ws.filt[k, 1]:
            return True
    return False


@njit
def add_to_filter(ws, theta, phi):
    """Add the pair (theta, phi) to the filter, which then rejects points it dominates."""
    k = ws.iscal[I_N_FILTER]
    if k < MAX_FILTER:
        ws.filt[k, 0] = theta
        ws.filt[k, 1] = phi
        ws.iscal[I_N_FILTER] = k + 1
    else:
        # Full: replace the entry with the largest theta (keeps the recent, tighter ones).
        worst = 0
        for j in range(k):
            if ws.filt[j, 0] > ws.filt[worst, 0]:
                worst = j
        ws.filt[worst, 0] = theta
        ws.filt[worst, 1] = phi


@njit
def accept_trial(ws, alpha, alpha_dual, dt):
    """Move to the trial point (primal from the trial buffers, duals by alpha / alpha_dual)."""
    n = ws.iscal[I_N]
    nx = len(ws.size_x)
    nu = len(ws.size_u)
    nb = ws.s.shape[1]
    fs = ws.fscal
    mu = fs[F_MU]
    for i in range(n + 1):
        for r in range(nx):
            ws.x[i, r] = ws.xt[i, r]
            if i > 0:
                ws.lam[i, r] += alpha * (ws.lam_new[i, r] - ws.lam[i, r])
    for r in range(nx):
        ws.nu[r] += alpha * (ws.nu_new[r] - ws.nu[r])
    for i in range(n):
        for c in range(nu):
            ws.v[i, c] = ws.vt[i, c]
            zl = ws.zl[i, c] + alpha_dual * ws.dzl[i, c]
            zu = ws.zu[i, c] + alpha_dual * ws.dzu[i, c]
            # IPOPT's safeguard keeps the duals within a factor KAPPA_SIGMA of mu / s.
            sl = 1.0 + ws.v[i, c]
            su = 1.0 - ws.v[i, c]
            ws.zl[i, c] = min(max(zl, mu / (KAPPA_SIGMA * sl)), KAPPA_SIGMA * mu / sl)
            ws.zu[i, c] = min(max(zu, mu / (KAPPA_SIGMA * su)), KAPPA_SIGMA * mu / su)
    rho_e = fs[F_ELASTIC]
    for i in range(1, n + 1):
        for j in range(nb):
            sj = ws.st[i, j]
            ej = ws.et[i, j]
            ws.s[i, j] = sj
            ws.e[i, j] = ej
            zj = ws.z[i, j] + alpha_dual * ws.dz[i, j]
            zj = min(max(zj, mu / (KAPPA_SIGMA * sj)), KAPPA_SIGMA * mu / sj)
            # ... and the elastic dual rho - z likewise (within (0, rho)).
            ze = rho_e - zj
            ze = min(max(ze, mu / (KAPPA_SIGMA * ej)), KAPPA_SIGMA * mu / ej)
            ws.z[i, j] = min(max(rho_e - ze, 1e-300), rho_e * (1.0 - 1e-15))
    # T-bound duals: Newton step of (T - T_low) z = mu (and the upper one) from the old slack.
    s_low = fs[F_T] - fs[F_T_LOW]
    s_high = fs[F_T_HIGH] - fs[F_T]
    zl = fs[F_ZT_LOW] + alpha_dual * (mu / s_low - fs[F_ZT_LOW] - fs[F_ZT_LOW] / s_low * dt)
    zu = fs[F_ZT_HIGH] + alpha_dual * (mu / s_high - fs[F_ZT_HIGH]
                                       + fs[F_ZT_HIGH] / s_high * dt)
    fs[F_T] += alpha * dt
    s_low = fs[F_T] - fs[F_T_LOW]
    s_high = fs[F_T_HIGH] - fs[F_T]
    fs[F_ZT_LOW] = min(max(zl, mu / (KAPPA_SIGMA * s_low)), KAPPA_SIGMA * mu / s_low)
    fs[F_ZT_HIGH] = min(max(zu, mu / (KAPPA_SIGMA * s_high)), KAPPA_SIGMA * mu / s_high)


@njit
def filter_line_search(rhs, segments, ws, dt, alpha_max):
    """
    Run IPOPT's filter line search from alpha_max (backtracking by halves).

    Returns (alpha, accepted, f_type).
    """
    fs = ws.fscal
    theta0 = fs[F_THETA]
    phi0 = fs[F_PHI]
    slope = barrier_slope(ws, dt)
    alpha = alpha_max
    backtracks = 0
    for _ls in range(MAX_BACKTRACKS):
        if ws.iscal[I_STOP]:
            break
        backtracks += 1
        theta, phi = trial_merit(rhs, segments, ws, alpha, dt)
        ws.iscal[I_BACKTRACKS] = backtracks
        if not (math.isfinite(theta) and math.isfinite(phi)) or theta > fs[F_THETA_MAX] \
                or _in_filter(ws, theta, phi):
            alpha *= 0.5
            continue
        switching = slope < 0.0 and alpha * (-slope) ** 2.3 > theta0 ** 1.1
        if theta0 <= fs[F_THETA_MIN] and switching:
            if phi <= phi0 + 1e-4 * alpha * slope:
                return alpha, True, True
        elif theta <= (1.0 - 1e-5) * theta0 or phi <= phi0 - 1e-8 * theta0:
            return alpha, True, False
        alpha *= 0.5
    return alpha, False, False
