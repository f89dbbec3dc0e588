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
The interior-point method's evaluation at the current point of a Workspace.

derivative_terms computes what does not depend on the barrier parameter mu (step Jacobians,
defects, the Hessian blocks of the Newton system with the condensed bound and obstacle terms,
the dual infeasibility); barrier_terms what does (the linear terms of the Newton system, the
constraint violation, the barrier objective and the scaled optimality errors).  A change of mu
then costs one barrier_terms, not a new derivative evaluation.
"""

import math

from numba import njit
import numpy as np

from .horizon import EULER, hessian_work, step_jacobians, step_lagrangian_hessian, step_work
from .ipm_obstacles import obstacle_terms, obstacle_work
from .ipm_workspace import F_COMPL, F_DUAL_INF, F_ELASTIC, F_ELASTIC_MAX, F_ERR, F_ERR_MU, F_MU, \
    F_PHI, F_PRIMAL_INF, F_RHO, F_T, F_T_HIGH, F_T_LOW, F_T_REF, F_THETA, F_ZT_HIGH, F_ZT_LOW, \
    I_METHOD, I_N


@njit(inline='always')
def unscaled_controls(v, u_max, u):
    """Write the controls u = u_max v of the scaled controls v (|v| < 1) into u."""
    for c in range(v.shape[0]):
        u[c] = v[c] * u_max[c]


@njit
def derivative_terms(rhs_jac, rhs_hess, segments, ws):
    """
    Compute the parts that do not depend on mu.

    These are: step Jacobians, defects, the Hessian blocks qq, ss, rr (Lagrangian curvature
    plus the condensed bound and obstacle terms), obstacle constraints and their gradients,
    and the dual infeasibility fscal[F_DUAL_INF].
    """
    n = ws.iscal[I_N]
    method = ws.iscal[I_METHOD]
    nx = len(ws.size_x)
    nu = len(ws.size_u)
    nq = len(ws.size_q)
    nb = ws.s.shape[1]
    fs = ws.fscal
    t_f = fs[F_T]
    tau = t_f / n
    p = ws.p
    u_max = ws.u_max
    work = step_work(nx, nu)
    hwork = hessian_work(nx, nu)
    owork = obstacle_work(max(1, nb // max(1, ws.circles.shape[0])), nq)
    u = np.zeros(nu)
    nxt = np.zeros(nx)
    jac_u = np.zeros((nx, nu))
    hxx = np.zeros((nx, nx))
    hxu = np.zeros((nx, nu))
    huu = np.zeros((nu, nu))
    hxt = np.zeros(nx)
    hut = np.zeros(nu)
    q = np.zeros(nq)
    hq = np.zeros((nq, nq))
    sigma = np.zeros(max(nb, 1))
    nxi = nx + 1
    qq, ss, rr = ws.qq, ws.ss, ws.rr
    rho_e = fs[F_ELASTIC]
    dual = 0.0
    for i in range(n + 1):
        for a in range(nxi):
            for b in range(nxi):
                qq[i, a, b] = 0.0
    f, fx, fu = work[2], work[3], work[4]
    hx_f, hxu_f, huu_f = hwork
    for i in range(n):
        unscaled_controls(ws.v[i], u_max, u)
        if method == EULER:
            # Written out for Euler (Phi = x + tau f): no output views in the hot loop, which
            # costs numba several times the arithmetic.
            rhs_jac(ws.x[i], u, p, f, fx, fu)
            rhs_hess(ws.x[i], u, p, ws.lam[i + 1], hx_f, hxu_f, huu_f)
            for r in range(nx):
                ws.defect[i, r] = ws.x[i, r] + tau * f[r] - ws.x[i + 1, r]
                ws.jac_t[i, r] = f[r] / n
                for c in range(nx):
                    ws.jac_x[i, r, c] = tau * fx[r, c]
                ws.jac_x[i, r, r] += 1.0
                for c in range(nu):
                    ws.jac_v[i, r, c] = tau * fu[r, c] * u_max[c]
            for r in range(nx):
                acc = 0.0
                for m in range(nx):
                    acc += fx[m, r] * ws.lam[i + 1, m]
                hxt[r] = acc
                for c in range(nx):
                    hxx[r, c] = tau * hx_f[r, c]
                for c in range(nu):
                    hxu[r, c] = tau * hxu_f[r, c]
            for r in range(nu):
                acc = 0.0
                for m in range(nx):
                    acc += fu[m, r] * ws.lam[i + 1, m]
                hut[r] = acc
                for c in range(nu):
                    huu[r, c] = tau * huu_f[r, c]
        else:
            step_jacobians(rhs_jac, ws.x[i], u, tau, p, method, nxt, ws.jac_x[i], jac_u,
                           ws.jac_t[i], work)
            for r in range(nx):
                ws.defect[i, r] = nxt[r] - ws.x[i + 1, r]
                ws.jac_t[i, r] /= n
                for c in range(nu):
                    ws.jac_v[i, r, c] = jac_u[r, c] * u_max[c]
            step_lagrangian_hessian(rhs_jac, rhs_hess, ws.x[i], u, tau, p, ws.lam[i + 1],
                                    hxx, hxu, huu, hxt, hut, work, hwork)
        # Stage blocks in (xi, v) with xi = (x, T): tau-derivatives divided by N, u = u_max v.
        for a in range(nx):
            for b in range(nx):
                qq[i, a, b] += hxx[a, b]
            qq[i, a, nx] += hxt[a] / n
            qq[i, nx, a] += hxt[a] / n
        for c in range(nu):
            for a in range(nx):
                ss[i, c, a] = hxu[a, c] * u_max[c]
            ss[i, c, nx] = hut[c] * u_max[c] / n
            for d2 in range(nu):
                rr[i, c, d2] = huu[c, d2] * u_max[c] * u_max[d2]
            rr[i, c, c] += ws.zl[i, c] / (1.0 + ws.v[i, c]) + ws.zu[i, c] / (1.0 - ws.v[i, c])
            # Dual residual in v(i): B^T lam(i+1) - zl + zu.
            acc = -ws.zl[i, c] + ws.zu[i, c]
            for r in range(nx):
                acc += ws.jac_v[i, r, c] * ws.lam[i + 1, r]
            dual = max(dual, abs(acc))
    # Obstacle constraints at the nodes 1..N, elastic form c + e - s = 0, s, e >= 0, with the
    # l1 penalty rho e: the dual z of c lies in (0, rho) and the dual of e is rho - z, so the
    # multipliers stay bounded while the start is inside an obstacle.  Per constraint, s, e and
    # their duals are eliminated: D = s / z + e / (rho - z) and grad c grad c^T / D enters the
    # Hessian.
    for i in range(1, n + 1):
        if nb == 0:
            break
        for a in range(nq):
            q[a] = ws.x[i, 2 * a]
        for j in range(nb):
            zj = ws.z[i, j]
            sigma[j] = 1.0 / (ws.s[i, j] / zj + ws.e[i, j] / (rho_e - zj))
        obstacle_terms(segments, q, p, ws.circles, ws.cons[i], ws.cons_q[i], ws.z[i], sigma,
                       hq, owork)
        for a in range(nq):
            for b in range(nq):
                qq[i, 2 * a, 2 * b] += hq[a, b]
    # Terminal augmentation, the objective's and the T bounds' curvature.
    for r in range(nx):
        qq[n, r, r] += fs[F_RHO]
    qq[n, nx, nx] += 1.0 / fs[F_T_REF] + fs[F_ZT_LOW] / (t_f - fs[F_T_LOW]) \
        + fs[F_ZT_HIGH] / (fs[F_T_HIGH] - t_f)
    # Dual residuals in x(i) (i = 1..N) and T.
    grad_t = t_f / fs[F_T_REF] - fs[F_ZT_LOW] + fs[F_ZT_HIGH]
    for i in range(1, n + 1):
        for a in range(nx):
            acc = -ws.lam[i, a]
            if i < n:
                for r in range(nx):
                    acc += ws.jac_x[i, r, a] * ws.lam[i + 1, r]
            else:
                acc += ws.nu[a]
            if a % 2 == 0 and a < 2 * nq:
                for j in range(nb):
                    acc -= ws.cons_q[i, j, a // 2] * ws.z[i, j]
            dual = max(dual, abs(acc))
    for i in range(n):
        for r in range(nx):
            grad_t += ws.jac_t[i, r] * ws.lam[i + 1, r]
    fs[F_DUAL_INF] = max(dual, abs(grad_t))


@njit
def barrier_terms(ws):
    """
    Compute the parts that depend on mu, from the stored derivatives.

    These are: the linear terms qv, rv, the constraint violation theta, the barrier objective
    phi, complementarity, the scaled optimality errors E_0 (fscal[F_ERR]) and the elastic
    maximum.
    """
    n = ws.iscal[I_N]
    nx = len(ws.size_x)
    nu = len(ws.size_u)
    nq = len(ws.size_q)
    nb = ws.s.shape[1]
    fs = ws.fscal
    t_f = fs[F_T]
    mu = fs[F_MU]
    rho_e = fs[F_ELASTIC]
    qv, rv = ws.qv, ws.rv
    theta = 0.0
    primal = 0.0
    compl = 0.0
    compl0 = 0.0
    barrier = 0.0
    elastic_cost = 0.0
    elastic_max = 0.0
    mult_sum = 0.0
    bound_sum = 0.0
    mult_cnt = n * nx + nx
    bound_cnt = 2 * n * nu + 2 * n * nb + 2
    for i in range(n + 1):
        for a in range(nx + 1):
            qv[i, a] = 0.0
    for i in range(n):
        for r in range(nx):
            d = abs(ws.defect[i, r])
            theta += d
            primal = max(primal, d)
            mult_sum += abs(ws.lam[i + 1, r])
        for c in range(nu):
            sl = 1.0 + ws.v[i, c]
            su = 1.0 - ws.v[i, c]
            zl = ws.zl[i, c]
            zu = ws.zu[i, c]
            rv[i, c] = mu / su - mu / sl
            barrier -= math.log(sl) + math.log(su)
            compl = max(compl, abs(sl * zl - mu), abs(su * zu - mu))
            compl0 = max(compl0, sl * zl, su * zu)
            bound_sum += zl + zu
    for i in range(1, n + 1):
        for j in range(nb):
            c = ws.cons[i, j]
            sj = ws.s[i, j]
            ej = ws.e[i, j]
            zj = ws.z[i, j]
            ze = rho_e - zj
            res = c + ej - sj
            theta += abs(res)
            primal = max(primal, abs(res))
            coef = zj + (mu / zj - mu / ze - c) / (sj / zj + ej / ze)
            for a in range(nq):
                qv[i, 2 * a] -= ws.cons_q[i, j, a] * coef
            barrier -= math.log(sj) + math.log(ej)
            elastic_cost += rho_e * ej
            elastic_max = max(elastic_max, ej)
            compl = max(compl, abs(sj * zj - mu), abs(ej * ze - mu))
            compl0 = max(compl0, sj * zj, ej * ze)
            bound_sum += rho_e
    # Terminal condition (with its augmentation) and the T row.
    for r in range(nx):
        res = ws.x[n, r] - ws.x_goal[r]
        theta += abs(res)
        primal = max(primal, abs(res))
        qv[n, r] += fs[F_RHO] * res
        mult_sum += abs(ws.nu[r])
    s_low = t_f - fs[F_T_LOW]
    s_high = fs[F_T_HIGH] - t_f
    z_low = fs[F_ZT_LOW]
    z_high = fs[F_ZT_HIGH]
    qv[n, nx] += t_f / fs[F_T_REF] - mu / s_low + mu / s_high
    barrier -= math.log(s_low) + math.log(s_high)
    compl = max(compl, abs(s_low * z_low - mu), abs(s_high * z_high - mu))
    compl0 = max(compl0, s_low * z_low, s_high * z_high)
    bound_sum += z_low + z_high
    # IPOPT's scaled optimality error (s_max = 100).
    s_max = 100.0
    s_d = max(s_max, (mult_sum + bound_sum) / max(1, mult_cnt + bound_cnt)) / s_max
    s_c = max(s_max, bound_sum / max(1, bound_cnt)) / s_max
    fs[F_THETA] = theta
    fs[F_PHI] = 0.5 * t_f * t_f / fs[F_T_REF] + mu * barrier + elastic_cost
    fs[F_PRIMAL_INF] = primal
    fs[F_COMPL] = compl
    fs[F_ELASTIC_MAX] = elastic_max
    fs[F_ERR] = max(fs[F_DUAL_INF] / s_d, primal, compl0 / s_c)
    fs[F_ERR_MU] = max(fs[F_DUAL_INF] / s_d, primal, compl / s_c)
    return math.isfinite(theta) and math.isfinite(fs[F_DUAL_INF]) and math.isfinite(fs[F_PHI])
