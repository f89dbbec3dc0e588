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
The Newton step of the interior-point method by a Riccati recursion over the stages.

xi(i) = (dx(i), dT): the final time enters as a constant state that is free at i = 0, so the
sweep is the second-order form of the BPTT recursion of eqs. (24)-(32).  The terminal condition
x(N) = x_goal is handled through its multipliers nu: the step is affine in nu, the backward
sweep (factorize) runs for nx + 1 right-hand sides and accumulates an nx-by-nx system for nu,
and one forward sweep (newton_step) gives dx, dv, dT and the new multipliers.  Cost
O(N (nx + nu)^3), no dense (N nx)-sized matrix anywhere.  recover_bound_steps then recovers the
steps of the slacks and bound duals that were condensed into the stage blocks.
"""

import math

from numba import njit
import numpy as np

from .ipm_workspace import F_ELASTIC, F_MU, I_N


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


@njit(cache=True, nogil=True)
def newton_direction(ws, delta):
    """Compute the Newton step at the evaluated point with shift delta: return dT (nan if none)."""
    if not factorize(ws, delta):
        return np.nan
    dt = newton_step(ws, delta)
    if math.isfinite(dt):
        recover_bound_steps(ws, dt)
    return dt
