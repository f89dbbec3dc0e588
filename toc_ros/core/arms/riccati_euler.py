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
The Riccati step of riccati.py for Euler steps, with the goal state eliminated, not carried.

The same stage QP (riccati.py's docstring) when every step is an Euler step x + h f: the
positions' rows of B are zero and its velocities' rows B_v = h M^-1 diag(effort) are
invertible.  Then the goal condition dx_N = 0 fixes the last two intervals' controls: the
velocities' rows of the last step give u_{N-1} = K1 xi_{N-1} + k1; what remains of it, the
positions' rows E xi_{N-1} + e = 0 (E = [I, h I, dq/dT]), is met by u_{N-2}, as E B_{N-2} =
h B_v is invertible: u_{N-2} = K2 xi_{N-2} + k2.  Their costs fold into the value at stage
N - 2, and the recursion below it carries one right-hand side: riccati.py carries 1 + nx for
the goal's multipliers, and those columns were about half of its work.

Inertia: the constraints' null space is parametrised by u_0..u_{N-3} and dT, so the QP has
the right inertia exactly when every reduced Hessian R_k + B_k^T P B_k (k <= N - 3) is
positive definite and the final time's reduced curvature P_0(T, T) is positive; the codes
are riccati.py's (FINAL_TIME_CURVATURE for the last test: the same test as riccati.py's
(1 + nx) system's inertia, whose Schur complement this is).

Multipliers: lam_k = the value's derivative P_k xi_k + p_k for k <= N - 2; the goal's
multipliers lam_N from the stationarity in u_{N-1} (velocities' rows) and in u_{N-2}
(positions' rows); lam_{N-1} from the stationarity in x_{N-1}.
"""

from numba import njit
import numpy as np

from .riccati import (_add_transposed_product, _chol_solve_rows, _cholesky, FINAL_TIME_CURVATURE,
                      OK, padded, REDUCED_HESSIAN_INDEFINITE)

SINGULAR_STEP = 4


@njit(cache=True)
def work_arrays_euler(n_int, nx, nu):
    """Zeroed work arrays (pp, pv, gain, ff, xi) of riccati_solve_euler, rows padded."""
    nxp = padded(nx + 1)
    return (np.zeros((n_int + 1, nxp, nxp)), np.zeros((n_int + 1, nxp, 1)),
            np.zeros((n_int, nu, nxp)), np.zeros((n_int, nu, 1)), np.zeros((n_int + 1, nxp)))


@njit(cache=True)
def _lu(a, m):
    """LU factors of a (m x m, overwritten in place) with row pivots: (ok, pivots)."""
    piv = np.arange(m)
    for j in range(m):
        best = j
        for i in range(j + 1, m):
            if abs(a[i, j]) > abs(a[best, j]):
                best = i
        if not abs(a[best, j]) > 0.0:
            return False, piv
        if best != j:
            for c in range(m):
                a[j, c], a[best, c] = a[best, c], a[j, c]
            piv[j], piv[best] = piv[best], piv[j]
        for i in range(j + 1, m):
            a[i, j] /= a[j, j]
            f = a[i, j]
            for c in range(j + 1, m):
                a[i, c] -= f * a[j, c]
    return True, piv


@njit(cache=True)
def _lu_solve(lu, piv, b, m, ncol):
    """Solve A Y = B in place (B (m x ncol)) with _lu's factors of A."""
    y = np.empty((m, ncol))
    for i in range(m):
        for c in range(ncol):
            y[i, c] = b[piv[i], c]
    for i in range(m):
        for k in range(i):
            f = lu[i, k]
            for c in range(ncol):
                y[i, c] -= f * y[k, c]
    for i in range(m - 1, -1, -1):
        for k in range(i + 1, m):
            f = lu[i, k]
            for c in range(ncol):
                y[i, c] -= f * y[k, c]
        for c in range(ncol):
            y[i, c] /= lu[i, i]
    for i in range(m):
        for c in range(ncol):
            b[i, c] = y[i, c]


@njit(cache=True)
def _lu_solve_transposed(lu, piv, b, m):
    """Solve A^T y = b in place (b (m,)) with _lu's factors of A (P A = L U)."""
    z = b.copy()
    for i in range(m):              # U^T w = b
        for k in range(i):
            z[i] -= lu[k, i] * z[k]
        z[i] /= lu[i, i]
    for i in range(m - 1, -1, -1):  # L^T v = w
        for k in range(i + 1, m):
            z[i] -= lu[k, i] * z[k]
    for i in range(m):              # y = P^T v
        b[piv[i]] = z[i]


@njit(cache=True)
def _negated_split(solved, nu_, nxi):
    """(gain, shift) = -(solved[:, :nxi], solved[:, nxi]): u = gain xi + shift."""
    gain = np.empty((nu_, nxi))
    shift = np.empty(nu_)
    for i in range(nu_):
        for j in range(nxi):
            gain[i, j] = -solved[i, j]
        shift[i] = -solved[i, nxi]
    return gain, shift


@njit(cache=True)
def _control_gradient(k, hux, huu, gu, xi_k, du):
    """Interval k's cost gradient in its control at (xi_k, du[k]): Hux xi + Huu u + gu."""
    nu_ = gu.shape[1]
    out = np.empty(nu_)
    for i in range(nu_):
        acc = gu[k, i]
        for j in range(hux.shape[2]):          # (xi_k's rows may be padded)
            acc += hux[k, i, j] * xi_k[j]
        for j in range(nu_):
            acc += huu[k, i, j] * du[k, j]
        out[i] = acc
    return out


@njit(cache=True)
def _fold(cost, cross, curv, grad, grad_u, gain, shift, nxi, nu_):
    """
    Return (P, p): a stage cost with its control u = gain xi + shift substituted.

    The cost [xi; u]^T [[cost, cross^T], [cross, curv]] [xi; u] / 2 + grad . xi + grad_u . u
    becomes xi^T P xi / 2 + p . xi (+ a constant): P = cost + gain^T cross + cross^T gain +
    gain^T curv gain, p = grad + gain^T grad_u + (cross^T + gain^T curv) shift.
    """
    p_mat = np.empty((nxi, nxi))
    p_vec = np.empty(nxi)
    cg = np.zeros((nu_, nxi))          # curv gain
    for i in range(nu_):
        for j in range(nu_):
            s = curv[i, j]
            for c in range(nxi):
                cg[i, c] += s * gain[j, c]
    cs = np.zeros(nu_)                 # curv shift + grad_u
    for i in range(nu_):
        acc = grad_u[i]
        for j in range(nu_):
            acc += curv[i, j] * shift[j]
        cs[i] = acc
    for i in range(nxi):
        for j in range(nxi):
            acc = cost[i, j]
            for m in range(nu_):
                acc += gain[m, i] * (cross[m, j] + 0.5 * cg[m, j]) + cross[m, i] * gain[m, j] \
                    + 0.5 * cg[m, i] * gain[m, j]
            p_mat[i, j] = acc
        acc = grad[i]
        for m in range(nu_):
            acc += gain[m, i] * cs[m] + cross[m, i] * shift[m]
        p_vec[i] = acc
    for i in range(nxi):
        for j in range(i):
            s = 0.5 * (p_mat[i, j] + p_mat[j, i])
            p_mat[i, j] = s
            p_mat[j, i] = s
    return p_mat, p_vec


@njit(cache=True)
def riccati_solve_euler(a_mat, b_mat, c_vec, d_vec, hxx, hux, huu, gx, gu, pp, pv, gain, ff,
                        xi, dx, du, lam):
    """
    Solve riccati.py's stage QP for Euler steps (module docstring); return (code, dT).

    Arguments as riccati.riccati_solve's (no terminal curvature: the goal is eliminated);
    work: pp, pv, gain, ff, xi from work_arrays_euler(N, nx, nu).  N >= 2, nu = nx / 2.
    Out: dx (N + 1, nx), du (N, nu), lam (N + 1, nx).  SINGULAR_STEP when a B_v (or E B) has
    no LU factors.
    """
    n = a_mat.shape[0]
    nx = a_mat.shape[1]
    nq = nx // 2
    nu_ = b_mat.shape[2]
    nxi = nx + 1
    nxp = pp.shape[1]
    last = n - 1
    # Stage N - 1: its velocities' rows give u = K1 xi + k1.
    lu1 = np.empty((nq, nq))
    for i in range(nq):
        for j in range(nu_):
            lu1[i, j] = b_mat[last, nq + i, j]
    ok, piv1 = _lu(lu1, nq)
    if not ok:
        return SINGULAR_STEP, 0.0
    k1_mat = np.empty((nq, nxi + 1))          # [-K1 | -k1] before the solve
    for i in range(nq):
        for j in range(nx):
            k1_mat[i, j] = a_mat[last, nq + i, j]
        k1_mat[i, nx] = c_vec[last, nq + i]
        k1_mat[i, nxi] = d_vec[last, nq + i]
    _lu_solve(lu1, piv1, k1_mat, nq, nxi + 1)
    gain1, shift1 = _negated_split(k1_mat, nu_, nxi)
    p1, q1 = _fold(hxx[last], hux[last], huu[last], gx[last], gu[last], gain1, shift1, nxi, nu_)
    # Stage N - 2: the positions' rows of the last step, E xi_{N-1} + e = 0, give u_{N-2}.
    j2 = n - 2
    phi = np.zeros((nxi, nxi))                # [[A, c], [0, 1]]
    for i in range(nx):
        for j in range(nx):
            phi[i, j] = a_mat[j2, i, j]
        phi[i, nx] = c_vec[j2, i]
    phi[nx, nx] = 1.0
    e_mat = np.empty((nq, nxi))
    for i in range(nq):
        for j in range(nx):
            e_mat[i, j] = a_mat[last, i, j]
        e_mat[i, nx] = c_vec[last, i]
    lu2 = np.zeros((nq, nq))                  # E B_{N-2}
    for i in range(nq):
        for m in range(nx):
            s = e_mat[i, m]
            if s != 0.0:
                for j in range(nu_):
                    lu2[i, j] += s * b_mat[j2, m, j]
    ok, piv2 = _lu(lu2, nq)
    if not ok:
        return SINGULAR_STEP, 0.0
    k2_mat = np.zeros((nq, nxi + 1))          # [E Phi | E delta + e]
    for i in range(nq):
        for m in range(nxi):
            s = e_mat[i, m]
            if s != 0.0:
                for j in range(nxi):
                    k2_mat[i, j] += s * phi[m, j]
        acc = d_vec[last, i]
        for m in range(nx):
            acc += e_mat[i, m] * d_vec[j2, m]
        k2_mat[i, nxi] = acc
    _lu_solve(lu2, piv2, k2_mat, nq, nxi + 1)
    gain2, shift2 = _negated_split(k2_mat, nu_, nxi)
    # Q of stage N - 2 over the value (p1, q1) of xi_{N-1} = Phi xi + [B; 0] u + [d; 0].
    p1_phi = np.zeros((nxi, nxi))
    _add_transposed_product(p1_phi, p1, phi, nxi)      # (P1 symmetric: P1 Phi)
    qxx = np.empty((nxi, nxi))
    qux = np.empty((nu_, nxi))
    quu = np.empty((nu_, nu_))
    for i in range(nxi):
        for j in range(nxi):
            qxx[i, j] = hxx[j2, i, j]
    _add_transposed_product(qxx, phi, p1_phi, nxi)
    for i in range(nu_):
        for j in range(nxi):
            qux[i, j] = hux[j2, i, j]
        for j in range(nu_):
            quu[i, j] = huu[j2, i, j]
    bbar = np.zeros((nxi, nu_))
    for i in range(nx):
        for j in range(nu_):
            bbar[i, j] = b_mat[j2, i, j]
    _add_transposed_product(qux, bbar, p1_phi, nx)
    p1_b = np.zeros((nxi, nu_))
    _add_transposed_product(p1_b, p1, bbar, nxi)
    _add_transposed_product(quu, bbar, p1_b, nx)
    s_vec = q1.copy()                          # P1 delta + q1
    for i in range(nxi):
        for m in range(nx):
            s_vec[i] += p1[i, m] * d_vec[j2, m]
    qx = np.empty(nxi)
    qu = np.empty(nu_)
    for i in range(nxi):
        acc = gx[j2, i]
        for m in range(nxi):
            acc += phi[m, i] * s_vec[m]
        qx[i] = acc
    for i in range(nu_):
        acc = gu[j2, i]
        for m in range(nx):
            acc += b_mat[j2, m, i] * s_vec[m]
        qu[i] = acc
    p2, q2 = _fold(qxx, qux, quu, qx, qu, gain2, shift2, nxi, nu_)
    pp[j2] = 0.0
    pv[j2] = 0.0
    for i in range(nxi):
        for j in range(nxi):
            pp[j2, i, j] = p2[i, j]
        pv[j2, i, 0] = q2[i]
    # The recursion below stage N - 2, one right-hand side: riccati.py's stage written out
    # for one column (sharing riccati.py's stage function cost 10-20 % of this kernel's time).
    abar = np.zeros((nxp, nxp))                # [[A, c], [0, 1]]
    bb = np.zeros((nxp, nu_))                  # [B; 0]
    abar[nx, nx] = 1.0
    w = np.empty((nxp, nxp))
    pa = np.empty((nxp, nxp))
    v = np.empty((nu_, nxp))
    pb = np.empty((nxp, nu_))
    qxx_k = np.zeros((nxp, nxp))
    qux_k = np.zeros((nu_, nxp))
    quu_k = np.empty((nu_, nu_))
    low = np.zeros((nu_, nu_))
    r = np.empty((nxp, 1))
    qx_k = np.empty((nxp, 1))
    qu_k = np.empty((nu_, 1))
    for k in range(n - 3, -1, -1):
        p = pp[k + 1]
        for i in range(nx):
            for j in range(nx):
                abar[i, j] = a_mat[k, i, j]
            abar[i, nx] = c_vec[k, i]
            for j in range(nu_):
                bb[i, j] = b_mat[k, i, j]
        w[:] = 0.0
        _add_transposed_product(w, abar, p, nxi)
        v[:] = 0.0
        _add_transposed_product(v, bb, p, nx)
        for i in range(nxp):
            for j in range(nxp):
                pa[i, j] = w[j, i]
            for j in range(nu_):
                pb[i, j] = v[j, i]
        qxx_k[:nxi, :nxi] = hxx[k]
        _add_transposed_product(qxx_k, abar, pa, nxi)
        qux_k[:, :nxi] = hux[k]
        _add_transposed_product(qux_k, bb, pa, nx)
        quu_k[:] = huu[k]
        _add_transposed_product(quu_k, bb, pb, nx)
        for i in range(nxi):
            acc = pv[k + 1, i, 0]
            for m in range(nx):
                acc += p[i, m] * d_vec[k, m]
            r[i, 0] = acc
        qx_k[:] = 0.0
        _add_transposed_product(qx_k, abar, r, nxi)
        qu_k[:] = 0.0
        _add_transposed_product(qu_k, bb, r, nx)
        for i in range(nxi):
            qx_k[i, 0] += gx[k, i]
        for i in range(nu_):
            qu_k[i, 0] += gu[k, i]
        if not _cholesky(quu_k, low, nu_):
            return REDUCED_HESSIAN_INDEFINITE, 0.0
        gk = gain[k]
        fk = ff[k]
        for i in range(nu_):
            for j in range(nxp):
                gk[i, j] = -qux_k[i, j]
            fk[i, 0] = -qu_k[i, 0]
        _chol_solve_rows(low, gk, nu_, nxp)
        _chol_solve_rows(low, fk, nu_, 1)
        pk = pp[k]
        pk[:] = qxx_k
        _add_transposed_product(pk, qux_k, gk, nu_)
        ck = pv[k]
        ck[:] = qx_k
        _add_transposed_product(ck, qux_k, fk, nu_)
        for i in range(nxi):
            for j in range(i):
                s = 0.5 * (pk[i, j] + pk[j, i])
                pk[i, j] = s
                pk[j, i] = s
    ptt = pp[0, nx, nx]
    if not ptt > 0.0:
        return FINAL_TIME_CURVATURE, 0.0
    d_t = -pv[0, nx, 0] / ptt
    # Forward sweep from xi_0 = (0, dT).
    xi[0] = 0.0
    xi[0, nx] = d_t
    for k in range(n):
        xk = xi[k]
        if k < n - 2:
            for i in range(nu_):
                acc = ff[k, i, 0]
                for j in range(nxi):
                    acc += gain[k, i, j] * xk[j]
                du[k, i] = acc
        else:
            g_mat, sh = (gain2, shift2) if k == j2 else (gain1, shift1)
            for i in range(nu_):
                acc = sh[i]
                for j in range(nxi):
                    acc += g_mat[i, j] * xk[j]
                du[k, i] = acc
        xn = xi[k + 1]
        for i in range(nx):
            acc = c_vec[k, i] * d_t + d_vec[k, i]
            for j in range(nx):
                s = a_mat[k, i, j]
                if s != 0.0:
                    acc += s * xk[j]
            for j in range(nu_):
                s = b_mat[k, i, j]
                if s != 0.0:
                    acc += s * du[k, j]
            xn[i] = acc
        xn[nx] = d_t
    for k in range(n + 1):
        for i in range(nx):
            dx[k, i] = xi[k, i]
    for i in range(nx):
        dx[n, i] = 0.0
    # Multipliers (module docstring).
    for i in range(nx):
        lam[0, i] = 0.0
    for k in range(1, n - 1):
        for i in range(nx):
            acc = pv[k, i, 0]
            for j in range(nxi):
                acc += pp[k, i, j] * xi[k, j]
            lam[k, i] = acc
    x1 = xi[last]
    lam_v = -_control_gradient(last, hux, huu, gu, x1, du)  # B_v^T lam_v = -(that)
    _lu_solve_transposed(lu1, piv1, lam_v, nq)
    wx = np.empty(nx)                          # d(stage N - 1 cost)/dx at its point
    for i in range(nx):
        acc = gx[last, i]
        for j in range(nxi):
            acc += hxx[last, i, j] * x1[j]
        for m in range(nu_):
            acc += hux[last, m, i] * du[last, m]
        wx[i] = acc
    tail = wx.copy()                           # wx + A_v^T lam_v
    for m in range(nq):
        s = lam_v[m]
        for i in range(nx):
            tail[i] += a_mat[last, nq + m, i] * s
    x2 = xi[j2]
    lam_q = _control_gradient(j2, hux, huu, gu, x2, du)   # (E B)^T lam_q = -(that + B^T tail)
    for i in range(nu_):
        acc = lam_q[i]
        for m in range(nx):
            acc += b_mat[j2, m, i] * tail[m]
        lam_q[i] = -acc
    _lu_solve_transposed(lu2, piv2, lam_q, nq)
    for i in range(nq):
        lam[n, i] = lam_q[i]
        lam[n, nq + i] = lam_v[i]
    for i in range(nx):                        # lam_{N-1} = wx + A^T lam_N
        acc = wx[i]
        for m in range(nx):
            acc += a_mat[last, m, i] * lam[n, m]
        lam[last, i] = acc
    return OK, d_t
