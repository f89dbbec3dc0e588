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
Fast mode's engine: a primal-dual interior-point method.

Its Newton steps are solved by a Riccati recursion, the second-order form of the BPTT
recursion of eqs. (24)-(32).

The transcription is multiple shooting on the paper's grid: decision variables are the states
x(1..N), the scaled controls v(i) = u(i) / u_max (|v| < 1) and the final time T (tau = T / N);
constraints are the shooting defects Phi(x(i), u(i), tau) - x(i+1) = 0 (eq. 2), the terminal
state x(N) = x_goal, and c(x(i)) >= 0 for every link segment and inflated circle at the nodes
i = 1..N, with c = (d^2 - R^2) / (2 R) (d: segment-to-centre distance; ~ clearance in metres,
smooth where the distance is not).  The objective is T.

Each iteration (IPOPT's algorithm, Waechter & Biegler 2006, reduced to what this structure
needs):
* derivatives at the current point: step Jacobians A(i), B(i), dPhi/dT (the X(j), U(j) of
  eqs. 21-22), the Hessian of the Lagrangian (lam(i+1) . Phi'' and the obstacle curvature), the
  barrier terms of the bounds condensed into the stage blocks (slacks and bound duals are
  eliminated per constraint);
* the Newton step by one backward Riccati sweep over stages (xi(i) = (dx(i), dT): T enters as a
  constant state; eqs. 24-27 are this sweep's first-order part) plus a forward sweep.  The
  terminal condition is handled through its multipliers nu: the step is affine in nu, the sweeps
  run for nx + 1 right-hand sides and an nx-by-nx system gives nu.  Cost O(N (nx + nu)^3) per
  iteration, no dense (N nx)-sized matrix anywhere;
* inertia correction: when a reduced Hessian R + B^T P B is not positive definite, a multiple of
  the identity is added to the Hessian and the sweep repeated;
* a filter line search on (constraint violation, barrier objective) with the fraction-to-the-
  boundary rule, then the monotone barrier update mu <- max(mu_min, min(0.2 mu, mu^1.5)).
Exact Hessians make the local convergence quadratic for Euler; for RK4 the Hessian of the
one-step map is approximated by Euler's (horizon.step_lagrangian_hessian).

Everything lives in one Workspace (a namedtuple of arrays): scalars in fscal / iscal under the
F_* / I_* names below.  The kernels take the model's pointwise kernels as arguments and are bound
per model in the model modules (models/cylindrical.py).
"""

from collections import namedtuple
import math

from numba import njit
import numpy as np

from .horizon import EULER, hessian_work, step, step_jacobians, step_lagrangian_hessian, \
    step_work
from .ipm_obstacles import obstacle_terms, obstacle_values, obstacle_work

# fscal entries.
F_T = 0              # final time [s]
F_MU = 1             # barrier parameter
F_T_LOW = 2          # bounds on T [s]
F_T_HIGH = 3
F_ZT_LOW = 4         # duals of the T bounds
F_ZT_HIGH = 5
F_TOL = 6            # overall optimality tolerance (scaled, IPOPT's)
F_CONSTR_TOL = 7     # constraint violation tolerance (unscaled)
F_MU_MIN = 8
F_THETA = 9          # constraint violation at the current point (l1)
F_PHI = 10           # barrier objective at the current point
F_ERR = 11           # optimality error E_0 at the current point
F_DELTA = 12         # last inertia-correction shift
F_RHO = 13           # terminal augmentation weight (does not change the step)
F_THETA_MAX = 14
F_THETA_MIN = 15
F_ALPHA = 16         # last primal step length
F_DUAL_INF = 17
F_PRIMAL_INF = 18
F_COMPL = 19
F_DT = 20            # last step in T
F_ALPHA_DUAL = 21
F_T_REF = 22          # the objective is T^2 / (2 T_ref): same minimiser as T, with curvature
F_ELASTIC = 23       # l1 weight rho of the elastic variables of the obstacle constraints
F_ELASTIC_MAX = 24   # largest elastic variable at the current point
F_ERR_MU = 25        # optimality error of the barrier problem (E_mu)
N_FSCAL = 26

# iscal entries.
I_N = 0              # intervals
I_METHOD = 1         # integrator id (horizon.EULER / RK4)
I_ITER = 2           # iterations done
I_MAX_ITER = 3
I_N_FILTER = 4
I_LS_FAILS = 5       # consecutive line-search failures
I_STATUS = 6
I_REG_TRIES = 7      # factorizations of the last iteration
I_BACKTRACKS = 8     # line-search trials of the last iteration
I_STOP = 9           # set to 1 by another thread to stop the iterations (cancel, timeout)
I_ACCEPTABLE = 10    # consecutive iterations at an acceptable point (ACCEPT_TOL)
N_ISCAL = 11

# Return codes of iterate().
CONTINUE = 0
CONVERGED = 1
ITERATION_LIMIT = 2
LINE_SEARCH_FAILED = 3
NUMERICAL_FAILURE = 4
STOPPED = 5          # iscal[I_STOP] was set

# History columns (one row per iteration).
H_T, H_THETA, H_ERR, H_MU, H_ALPHA, H_DELTA = 0, 1, 2, 3, 4, 5
N_HIST = 6

MAX_FILTER = 200
MAX_BACKTRACKS = 40
MAX_LS_FAILS = 8
# Acceptable termination (IPOPT's acceptable_tol / acceptable_iter, with the full constraint
# tolerance): see iterate().
ACCEPT_TOL = 1e-6
ACCEPT_ITERATIONS = 10
KAPPA_SIGMA = 1e10
# Monotone barrier update mu <- min(KAPPA_MU mu, mu^THETA_MU) once E_mu <= KAPPA_EPS mu.
KAPPA_MU = 0.2
THETA_MU = 1.5
KAPPA_EPS = 10.0
# Upper limit of the elastic weight rho.
ELASTIC_MAX = 1e8

Workspace = namedtuple('Workspace', [
    # state and control sizes as tuples of that length: their lengths are part of the numba
    # type, so every kernel is compiled for its model's (nx, nu) with constant loop bounds
    # (factorize ~3x faster than with sizes read from array shapes; same arithmetic, same bits);
    # size_q: the joints, whose positions are the states 0, 2, ..., 2 (nq - 1)
    'size_x', 'size_u', 'size_q',
    # problem data
    'p', 'x0', 'x_goal', 'u_max', 'circles',
    # primal: states, scaled controls; duals: dynamics, terminal, obstacles, control bounds
    'x', 'v', 'lam', 'nu', 's', 'e', 'z', 'zl', 'zu',
    # derivatives at the current point
    'jac_x', 'jac_v', 'jac_t', 'defect', 'cons', 'cons_q',
    # stage blocks of the Newton system: Q (xi, xi), S (v, xi), R (v, v), q, r
    'qq', 'ss', 'rr', 'qv', 'rv',
    # Riccati sweep; term_m, term_c: the terminal system dx(N) = term_c + term_m nu
    'pp', 'pc', 'gain', 'ff', 'chol', 'term_m', 'term_c',
    # step
    'dx', 'dv', 'lam_new', 'nu_new', 'ds', 'de', 'dz', 'dzl', 'dzu',
    # trial point of the line search
    'xt', 'vt', 'st', 'et', 'ct',
    # filter, history, scalars
    'filt', 'hist', 'fscal', 'iscal',
])


def make_workspace(n, nx, nu, n_links, circles, p, x0, x_goal, u_max, max_iter, nq=None):
    """
    Allocate a Workspace for N = n intervals (scalars still to be set by the caller).

    nq: number of joints (default nx / 2; a model with actuator states has more states).
    """
    nq = nx // 2 if nq is None else int(nq)
    circles = np.ascontiguousarray(np.reshape(circles, (-1, 3)), dtype=float)
    nb = n_links * circles.shape[0]
    nxi = nx + 1
    ncol = nx + 1
    z = np.zeros
    return Workspace(
        size_x=(0,) * nx, size_u=(0,) * nu, size_q=(0,) * nq,
        p=np.ascontiguousarray(p, dtype=float), x0=np.array(x0, dtype=float),
        x_goal=np.array(x_goal, dtype=float), u_max=np.array(u_max, dtype=float),
        circles=circles,
        x=z((n + 1, nx)), v=z((n, nu)), lam=z((n + 1, nx)), nu=z(nx), s=z((n + 1, nb)),
        e=z((n + 1, nb)),
        z=z((n + 1, nb)), zl=z((n, nu)), zu=z((n, nu)),
        jac_x=z((n, nx, nx)), jac_v=z((n, nx, nu)), jac_t=z((n, nx)), defect=z((n, nx)),
        cons=z((n + 1, nb)), cons_q=z((n + 1, nb, nq)),
        qq=z((n + 1, nxi, nxi)), ss=z((n, nu, nxi)), rr=z((n, nu, nu)), qv=z((n + 1, nxi)),
        rv=z((n, nu)),
        pp=z((n + 1, nxi, nxi)), pc=z((n + 1, nxi, ncol)), gain=z((n, nu, nxi)),
        ff=z((n, nu, ncol)), chol=z((n, nu, nu)), term_m=z((nx, nx)), term_c=z(nx),
        dx=z((n + 1, nx)), dv=z((n, nu)), lam_new=z((n + 1, nx)), nu_new=z(nx),
        ds=z((n + 1, nb)), de=z((n + 1, nb)), dz=z((n + 1, nb)), dzl=z((n, nu)),
        dzu=z((n, nu)),
        xt=z((n + 1, nx)), vt=z((n, nu)), st=z((n + 1, nb)), et=z((n + 1, nb)),
        ct=z((n + 1, nb)),
        filt=z((MAX_FILTER, 2)), hist=np.full((max_iter, N_HIST), np.nan),
        fscal=z(N_FSCAL), iscal=np.zeros(N_ISCAL, dtype=np.int64))


# ---------------------------------------------------------------------------------------------
# Evaluation: derivatives, stage blocks and residuals at the current point.
# ---------------------------------------------------------------------------------------------

@njit(inline='always')
def _controls(v, u_max, u):
    for c in range(v.shape[0]):
        u[c] = v[c] * u_max[c]


@njit
def evaluate(rhs, rhs_jac, rhs_hess, segments, ws):
    """
    Compute the derivatives, Newton stage blocks and residuals at the current point.

    This is derivative_terms + barrier_terms.  Returns False when a value is not finite.
    """
    derivative_terms(rhs_jac, rhs_hess, segments, ws)
    return barrier_terms(ws)


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
        _controls(ws.v[i], u_max, u)
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


# ---------------------------------------------------------------------------------------------
# The Newton step: Riccati sweep with T as a constant state and the terminal multipliers nu.
# ---------------------------------------------------------------------------------------------

@njit(inline='always')
def _cholesky(a, out, m):
    """Cholesky factor of the m x m matrix a into out (lower); False when not positive definite."""
    for i in range(m):
        for j in range(i + 1):
            acc = a[i, j]
            for k in range(j):
                acc -= out[i, k] * out[j, k]
            if i == j:
                if not acc > 0.0:
                    return False
                out[i, i] = math.sqrt(acc)
            else:
                out[i, j] = acc / out[j, j]
        for j in range(i + 1, m):
            out[i, j] = 0.0
    return True


@njit(inline='always')
def _chol_solve(lower, b, m):
    """Solve (L L^T) y = b in place for one vector b of length m."""
    for i in range(m):
        acc = b[i]
        for k in range(i):
            acc -= lower[i, k] * b[k]
        b[i] = acc / lower[i, i]
    for i in range(m - 1, -1, -1):
        acc = b[i]
        for k in range(i + 1, m):
            acc -= lower[k, i] * b[k]
        b[i] = acc / lower[i, i]


@njit
def factorize(ws, delta):
    """
    Run the backward Riccati sweep for the current stage blocks.

    The shift delta is put on the primal diagonal.  Returns False when a reduced Hessian is
    not positive definite (the caller then raises delta).  pc holds nx + 1 right-hand sides:
    column 0 the Newton step's, column 1 + r the derivative with respect to the terminal
    multiplier nu_r (Gamma, propagated by the closed loop); term_m and term_c receive the
    terminal system.
    """
    n = ws.iscal[I_N]
    nx = len(ws.size_x)
    nu = len(ws.size_u)
    nxi = nx + 1
    ncol = nx + 1
    pp, pc = ws.pp, ws.pc
    pa = np.zeros((nxi, nxi))
    pb = np.zeros((nxi, nu))
    rhat = np.zeros((nu, nu))
    shat = np.zeros((nu, nxi))
    h = np.zeros(nxi)
    rcol = np.zeros(nu)
    lower = np.zeros((nu, nu))
    wcol = np.zeros((nu, nx))
    for r in range(nx):
        ws.term_c[r] = 0.0
        for c in range(nx):
            ws.term_m[r, c] = 0.0
    for a in range(nxi):
        for b in range(nxi):
            pp[n, a, b] = ws.qq[n, a, b]
        pp[n, a, a] += delta
        for c in range(ncol):
            pc[n, a, c] = 0.0
        pc[n, a, 0] = ws.qv[n, a]
    for r in range(nx):
        pc[n, r, 1 + r] = 1.0
    for i in range(n - 1, -1, -1):
        # pa = P Abar, pb = P Bbar with Abar = [[A, a_T], [0, 1]], Bbar = [B; 0].
        for a in range(nxi):
            for b in range(nx):
                acc = 0.0
                for m in range(nx):
                    acc += pp[i + 1, a, m] * ws.jac_x[i, m, b]
                pa[a, b] = acc
            acc = pp[i + 1, a, nx]
            for m in range(nx):
                acc += pp[i + 1, a, m] * ws.jac_t[i, m]
            pa[a, nx] = acc
            for c in range(nu):
                acc = 0.0
                for m in range(nx):
                    acc += pp[i + 1, a, m] * ws.jac_v[i, m, c]
                pb[a, c] = acc
        # rhat = R + B^T P B, shat = S + B^T P Abar.
        for c in range(nu):
            for d in range(nu):
                acc = ws.rr[i, c, d]
                for m in range(nx):
                    acc += ws.jac_v[i, m, c] * pb[m, d]
                rhat[c, d] = acc
            rhat[c, c] += delta
            for b in range(nxi):
                acc = ws.ss[i, c, b]
                for m in range(nx):
                    acc += ws.jac_v[i, m, c] * pa[m, b]
                shat[c, b] = acc
        if not _cholesky(rhat, lower, nu):
            return False
        for c in range(nu):
            for d in range(nu):
                ws.chol[i, c, d] = lower[c, d]
        # gain = -rhat^-1 shat.
        for b in range(nxi):
            for c in range(nu):
                rcol[c] = shat[c, b]
            _chol_solve(lower, rcol, nu)
            for c in range(nu):
                ws.gain[i, c, b] = -rcol[c]
        # P(i) = Q + Abar^T P Abar + shat^T gain (x part of xi(0) is fixed, T part is free).
        for a in range(nxi):
            for b in range(a, nxi):
                if a < nx:
                    acc = 0.0
                    for m in range(nx):
                        acc += ws.jac_x[i, m, a] * pa[m, b]
                else:
                    acc = pa[nx, b]
                    for m in range(nx):
                        acc += ws.jac_t[i, m] * pa[m, b]
                acc += ws.qq[i, a, b]
                for c in range(nu):
                    acc += shat[c, a] * ws.gain[i, c, b]
                pp[i, a, b] = acc
                pp[i, b, a] = acc
        if i > 0:
            for a in range(nx):
                pp[i, a, a] += delta
        # Right-hand sides: h = P b + p(i+1) (b: the defect, column 0 only); columns 1..nx
        # carry Gamma(i) = A_cl^T Gamma(i+1) (A_cl = Abar + Bbar gain) in the form
        # Abar^T h + shat^T ff, which is cheaper here than forming A_cl.
        for col in range(ncol):
            for a in range(nxi):
                acc = pc[i + 1, a, col]
                if col == 0:
                    for m in range(nx):
                        acc += pp[i + 1, a, m] * ws.defect[i, m]
                h[a] = acc
            for c in range(nu):
                acc = ws.rv[i, c] if col == 0 else 0.0
                for m in range(nx):
                    acc += ws.jac_v[i, m, c] * h[m]
                rcol[c] = acc
                if col > 0:
                    wcol[c, col - 1] = acc
            _chol_solve(lower, rcol, nu)
            for c in range(nu):
                ws.ff[i, c, col] = -rcol[c]
            for a in range(nxi):
                if a < nx:
                    acc = 0.0
                    for m in range(nx):
                        acc += ws.jac_x[i, m, a] * h[m]
                else:
                    acc = h[nx]
                    for m in range(nx):
                        acc += ws.jac_t[i, m] * h[m]
                if col == 0:
                    acc += ws.qv[i, a]
                for c in range(nu):
                    acc += shat[c, a] * ws.ff[i, c, col]
                pc[i, a, col] = acc
        # The terminal system [I 0] xi(N) = term_c + term_m nu (up to the dT(0) terms added in
        # newton_step): sum_i Gamma(i+1)^T (Bbar ff(i) + b(i)), with Gamma(i+1)^T Bbar ff_nu =
        # -W^T rhat^-1 W, W = Bbar^T Gamma(i+1).  The forward sweep then runs once instead of
        # nx + 2 times.
        for a in range(nx):
            acc = ws.defect[i, a]
            for c in range(nu):
                acc += ws.jac_v[i, a, c] * ws.ff[i, c, 0]
            h[a] = acc
        for r in range(nx):
            acc = 0.0
            for m in range(nx):
                acc += pc[i + 1, m, 1 + r] * h[m]
            ws.term_c[r] += acc
            for r2 in range(nx):
                acc = 0.0
                for c in range(nu):
                    acc += wcol[c, r] * ws.ff[i, c, 1 + r2]
                ws.term_m[r, r2] += acc
    # T is a free initial state component: its curvature must be positive too.
    return pp[0, nx, nx] > 0.0


@njit
def _forward(ws, col_weights, dt, xi, store):
    """
    Run the forward sweep with feed-forward sum_c w_c ff[:, :, c] from xi(0) = (0, dt).

    Returns xi(N) in xi.  With store, writes dx, dv and the new multipliers lam_new.
    """
    n = ws.iscal[I_N]
    nx = len(ws.size_x)
    nu = len(ws.size_u)
    nxi = nx + 1
    ncol = nx + 1
    nxt = np.zeros(nxi)
    dv = np.zeros(nu)
    for a in range(nx):
        xi[a] = 0.0
    xi[nx] = dt
    if store:
        for a in range(nx):
            ws.dx[0, a] = 0.0
    for i in range(n):
        for c in range(nu):
            acc = 0.0
            for col in range(ncol):
                acc += ws.ff[i, c, col] * col_weights[col]
            for b in range(nxi):
                acc += ws.gain[i, c, b] * xi[b]
            dv[c] = acc
        for r in range(nx):
            acc = ws.jac_t[i, r] * xi[nx] + ws.defect[i, r] * col_weights[0]
            for m in range(nx):
                acc += ws.jac_x[i, r, m] * xi[m]
            for c in range(nu):
                acc += ws.jac_v[i, r, c] * dv[c]
            nxt[r] = acc
        nxt[nx] = xi[nx]
        for a in range(nxi):
            xi[a] = nxt[a]
        if store:
            for c in range(nu):
                ws.dv[i, c] = dv[c]
            for a in range(nx):
                ws.dx[i + 1, a] = xi[a]
                acc = 0.0
                for b in range(nxi):
                    acc += ws.pp[i + 1, a, b] * xi[b]
                for col in range(ncol):
                    acc += ws.pc[i + 1, a, col] * col_weights[col]
                ws.lam_new[i + 1, a] = acc


@njit
def newton_step(ws, delta):
    """
    Solve for the Newton step after a successful factorize(ws, delta).

    First nu from the nx x nx terminal system, then dx, dv, dT and the new multipliers (one
    forward sweep).  Returns dT, or nan when the terminal system is singular.
    """
    n = ws.iscal[I_N]
    nx = len(ws.size_x)
    ncol = nx + 1
    p_tt = ws.pp[0, nx, nx]
    xi = np.zeros(nx + 1)
    weights = np.zeros(ncol)
    # dT per right-hand side (T is free at i = 0): dT_c = -pc[0, T, c] / P[T, T].
    dts = np.zeros(ncol)
    for c in range(ncol):
        dts[c] = -ws.pc[0, nx, c] / p_tt
    # dx(N) = rhs-free part + mat nu, from the sums factorize accumulated (see there).
    rhs = np.zeros(nx)
    mat = np.zeros((nx, nx))
    for r in range(nx):
        rhs[r] = -(ws.x[n, r] - ws.x_goal[r]) - ws.term_c[r] - ws.pc[0, nx, 1 + r] * dts[0]
        for c in range(nx):
            mat[r, c] = ws.term_m[r, c] + ws.pc[0, nx, 1 + r] * dts[1 + c]
    # mat is symmetric negative definite when the step is well defined.
    neg = np.zeros((nx, nx))
    lower = np.zeros((nx, nx))
    scale = 0.0
    for r in range(nx):
        scale = max(scale, abs(mat[r, r]))
        for c in range(nx):
            neg[r, c] = -0.5 * (mat[r, c] + mat[c, r])
    if not scale > 0.0:
        return np.nan
    for r in range(nx):
        neg[r, r] += 1e-14 * scale
    if not _cholesky(neg, lower, nx):
        return np.nan
    sol = -rhs
    _chol_solve(lower, sol, nx)
    weights[0] = 1.0
    dt = dts[0]
    for r in range(nx):
        weights[1 + r] = sol[r]
        ws.nu_new[r] = sol[r]
        dt += sol[r] * dts[1 + r]
    _forward(ws, weights, dt, xi, True)
    return dt


@njit
def recover_bound_steps(ws, dt):
    """Slack and bound-dual steps from the primal step (condensed per constraint)."""
    n = ws.iscal[I_N]
    nu = len(ws.size_u)
    nq = len(ws.size_q)
    nb = ws.s.shape[1]
    mu = ws.fscal[F_MU]
    for i in range(n):
        for c in range(nu):
            sl = 1.0 + ws.v[i, c]
            su = 1.0 - ws.v[i, c]
            dvc = ws.dv[i, c]
            ws.dzl[i, c] = mu / sl - ws.zl[i, c] - ws.zl[i, c] / sl * dvc
            ws.dzu[i, c] = mu / su - ws.zu[i, c] + ws.zu[i, c] / su * dvc
    rho_e = ws.fscal[F_ELASTIC]
    for i in range(1, n + 1):
        for j in range(nb):
            lin = ws.cons[i, j]
            for a in range(nq):
                lin += ws.cons_q[i, j, a] * ws.dx[i, 2 * a]
            sj, ej, zj = ws.s[i, j], ws.e[i, j], ws.z[i, j]
            ze = rho_e - zj
            dz = (mu / zj - mu / ze - lin) / (sj / zj + ej / ze)
            ws.dz[i, j] = dz
            ws.ds[i, j] = (mu - sj * zj - sj * dz) / zj
            ws.de[i, j] = (mu - ej * ze + ej * dz) / ze


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


# ---------------------------------------------------------------------------------------------
# Line search.
# ---------------------------------------------------------------------------------------------

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
        _controls(ws.vt[i], ws.u_max, u)
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
def _add_to_filter(ws, theta, phi):
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
def _t_bound_dual_limit(ws, dt, frac, ad):
    fs = ws.fscal
    mu = fs[F_MU]
    s_low = fs[F_T] - fs[F_T_LOW]
    s_high = fs[F_T_HIGH] - fs[F_T]
    dzl_t = mu / s_low - fs[F_ZT_LOW] - fs[F_ZT_LOW] / s_low * dt
    dzu_t = mu / s_high - fs[F_ZT_HIGH] + fs[F_ZT_HIGH] / s_high * dt
    ad = _max_step(fs[F_ZT_LOW], dzl_t, frac, ad)
    return _max_step(fs[F_ZT_HIGH], dzu_t, frac, ad)


# ---------------------------------------------------------------------------------------------
# The iteration loop.
# ---------------------------------------------------------------------------------------------

@njit
def _update_barrier(ws):
    """
    Update the barrier parameter monotonically.

    Applied while the barrier problem is solved to kappa_eps mu (IPOPT's rule); refreshes the
    mu-dependent terms.  Returns True when mu changed.
    """
    fs = ws.fscal
    changed = False
    while fs[F_MU] > fs[F_MU_MIN] and fs[F_ERR_MU] <= KAPPA_EPS * fs[F_MU]:
        mu = fs[F_MU]
        fs[F_MU] = max(fs[F_MU_MIN], min(KAPPA_MU * mu, mu ** THETA_MU))
        barrier_terms(ws)
        changed = True
    if changed:
        ws.iscal[I_N_FILTER] = 0
    return changed


@njit
def _regularized_step(ws):
    """
    Factorize with IPOPT's inertia correction (delta_w rules) and solve the Newton step.

    Returns dT (nan when no shift up to 1e40 works); fscal[F_DELTA] holds the shift used.
    """
    fs = ws.fscal
    delta = 0.0
    last = fs[F_DELTA]
    tries = 0
    while True:
        tries += 1
        if factorize(ws, delta):
            dt = newton_step(ws, delta)
            if math.isfinite(dt):
                break
        if delta == 0.0:
            delta = 1e-4 if last == 0.0 else max(1e-20, last / 3.0)
        else:
            delta *= 100.0 if last == 0.0 else 8.0
        if delta > 1e40:
            return np.nan
    fs[F_DELTA] = delta
    ws.iscal[I_REG_TRIES] = tries
    recover_bound_steps(ws, dt)
    return dt


@njit
def _raise_elastic_weight(ws):
    """
    Multiply rho by 10 when an obstacle multiplier nears it (z > 0.9 rho) at a solution.

    The l1 penalty is then binding and would accept a violated constraint.  Only once the
    barrier problem is solved (E_mu <= kappa_eps mu, when mu would be decreased): while the
    iterates still cross an obstacle, z near rho is the penalty doing its work, and raising rho
    there gives the Lagrangian the curvature -rho grad^2 c inside the obstacle (large inertia
    corrections, tiny steps, runaway rho up to ELASTIC_MAX).  Returns True when rho changed.
    """
    fs = ws.fscal
    rho_e = fs[F_ELASTIC]
    if fs[F_ERR_MU] > KAPPA_EPS * fs[F_MU]:
        return False
    z_max = 0.0
    for i in range(1, ws.iscal[I_N] + 1):
        for j in range(ws.s.shape[1]):
            z_max = max(z_max, ws.z[i, j])
    if z_max <= 0.9 * rho_e or rho_e >= ELASTIC_MAX:
        return False
    fs[F_ELASTIC] = 10.0 * rho_e
    ws.iscal[I_N_FILTER] = 0
    return True


@njit
def _line_search(rhs, segments, ws, dt, alpha_max):
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


@njit
def iterate(rhs, rhs_jac, rhs_hess, segments, ws, n_iter):
    """
    Run up to n_iter interior-point iterations from the current point.

    Returns CONTINUE, CONVERGED, ITERATION_LIMIT, LINE_SEARCH_FAILED, NUMERICAL_FAILURE or
    STOPPED (another thread set iscal[I_STOP]: checked between the phases of an iteration, so
    a stop request waits at most for one derivative evaluation or one factorization).
    """
    fs = ws.fscal
    it = ws.iscal
    for _ in range(n_iter):
        if it[I_STOP]:
            return STOPPED
        derivative_terms(rhs_jac, rhs_hess, segments, ws)
        if not barrier_terms(ws):
            return NUMERICAL_FAILURE
        k = it[I_ITER]
        if k < ws.hist.shape[0]:
            ws.hist[k, H_T] = fs[F_T]
            ws.hist[k, H_THETA] = fs[F_THETA]
            ws.hist[k, H_ERR] = fs[F_ERR]
            ws.hist[k, H_MU] = fs[F_MU]
        feasible = fs[F_PRIMAL_INF] <= fs[F_CONSTR_TOL] and \
            fs[F_ELASTIC_MAX] <= fs[F_CONSTR_TOL]
        if feasible and fs[F_ERR] <= fs[F_TOL]:
            return CONVERGED
        # IPOPT's acceptable termination: a feasible point whose optimality error stays below
        # ACCEPT_TOL for ACCEPT_ITERATIONS iterations.  Where the reduced Hessian is singular
        # (a joint that is not time-critical: its controls are not unique) the inertia
        # correction makes the last digits converge linearly, by ~0.1 % an iteration.
        it[I_ACCEPTABLE] = it[I_ACCEPTABLE] + 1 if feasible and fs[F_ERR] <= ACCEPT_TOL else 0
        if it[I_ACCEPTABLE] >= ACCEPT_ITERATIONS:
            return CONVERGED
        if it[I_ITER] >= it[I_MAX_ITER]:
            return ITERATION_LIMIT
        if it[I_ITER] == 0 or fs[F_THETA_MAX] <= 0.0:
            fs[F_THETA_MAX] = 1e4 * max(1.0, fs[F_THETA])
            fs[F_THETA_MIN] = 1e-4 * max(1.0, fs[F_THETA])
        if _raise_elastic_weight(ws):
            derivative_terms(rhs_jac, rhs_hess, segments, ws)
            barrier_terms(ws)
        _update_barrier(ws)
        if it[I_STOP]:
            return STOPPED
        dt = _regularized_step(ws)
        if it[I_STOP]:
            return STOPPED
        if not math.isfinite(dt):
            return NUMERICAL_FAILURE
        frac = max(0.99, 1.0 - fs[F_MU])
        alpha_max, alpha_dual = fraction_to_boundary(ws, dt, frac)
        alpha_dual = _t_bound_dual_limit(ws, dt, frac, alpha_dual)
        theta0 = fs[F_THETA]
        phi0 = fs[F_PHI]
        alpha, accepted, f_type = _line_search(rhs, segments, ws, dt, alpha_max)
        if it[I_STOP]:
            return STOPPED
        if not accepted:
            # No acceptable point: take the longest trial that does not blow theta up, reset
            # the filter and count the failure (IPOPT would enter feasibility restoration).
            it[I_LS_FAILS] += 1
            if it[I_LS_FAILS] > MAX_LS_FAILS:
                return LINE_SEARCH_FAILED
            alpha = alpha_max
            for _ls in range(MAX_BACKTRACKS):
                theta, phi = trial_merit(rhs, segments, ws, alpha, dt)
                if math.isfinite(theta) and math.isfinite(phi) and theta < 10.0 * theta0 + 1e-8:
                    break
                alpha *= 0.5
            it[I_N_FILTER] = 0
        else:
            it[I_LS_FAILS] = 0
            if not f_type:
                _add_to_filter(ws, (1.0 - 1e-5) * theta0, phi0 - 1e-8 * theta0)
        accept_trial(ws, alpha, alpha_dual, dt)
        fs[F_ALPHA] = alpha
        fs[F_ALPHA_DUAL] = alpha_dual
        fs[F_DT] = dt
        if k < ws.hist.shape[0]:
            ws.hist[k, H_ALPHA] = alpha
            ws.hist[k, H_DELTA] = fs[F_DELTA]
        it[I_ITER] += 1
    return CONTINUE


@njit(cache=True, nogil=True)
def newton_direction(ws, delta):
    """Compute the Newton step at the evaluated point with shift delta: return dT (nan if none)."""
    if not factorize(ws, delta):
        return np.nan
    dt = newton_step(ws, delta)
    if math.isfinite(dt):
        recover_bound_steps(ws, dt)
    return dt
