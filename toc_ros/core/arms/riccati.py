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
Compiled Riccati recursion for the arm interior point's Newton steps (any stage sizes).

The interior point uses it for RK4 steps and the polish; Euler steps, whose structure lets
the goal state be eliminated, have riccati_euler.py (same QP, same codes, ~40 % less work).

The step solves the equality-constrained QP over stages k = 0..N-1

    min  sum_k 1/2 [xi_k; u_k]^T H_k [xi_k; u_k] + g_k^T [xi_k; u_k]
    s.t. dx_{k+1} = A_k dx_k + B_k du_k + c_k dT + d_k,   dx_0 = 0,   dx_N = 0,

with xi_k = (dx_k, dT): the final time is carried as a constant state, so its coupling with
every stage stays banded.  The terminal condition dx_N = 0 enters through its multipliers nu:
the backward sweep carries 1 + nx right-hand sides (the step is affine in nu), the forward
sweep gives dx_N as an affine function of nu and an nx-by-nx system gives nu.

Inertia: the QP has the right inertia (a minimum of a convex-on-the-constraints problem) when
every reduced Hessian R_k + B_k^T P B_k is positive definite and the (1 + nx) system of dT and
nu that remains, K = [[P_0(T, T), d(dT row)/d nu], [d dx_N / d dT, d dx_N / d nu]], has one
positive and nx negative eigenvalues; otherwise the kernel returns the failing test's code and
the caller adds a multiple of the identity to H.  When P_0(T, T) > 0, dT is eliminated first
and K's inertia is that of the terminal Schur complement (negative definite: a Cholesky
factor).  P_0(T, T) <= 0 is no reason to correct: at points of velocity-limited motions it is
often <= 0 while K's inertia is right, and the correction's damped steps then never removed
the last dual infeasibility (a UR10 around a sphere stalled next to its optimum for hundreds
of iterations); then dT is kept as a direction of the forward sweep and K is solved whole,
its inertia from its eigenvalues (jacobi_eigen: no LAPACK here).

No numpy linear algebra inside the kernels: numba's np.dot and np.linalg call SciPy's BLAS and
LAPACK, and SciPy is not a dependency of toc_ros; the loops below run along contiguous rows
(they vectorise) and skip the structural zeros of the Euler steps' A and B.
"""

import math

from numba import njit
import numpy as np

OK = 0
REDUCED_HESSIAN_INDEFINITE = 1
FINAL_TIME_CURVATURE = 2
TERMINAL_SCHUR_INDEFINITE = 3


@njit(cache=True)
def _cholesky(a, out, m):
    """Lower Cholesky factor of a (m x m) into out; False when a is not positive definite."""
    for j in range(m):
        acc = a[j, j]
        for k in range(j):
            acc -= out[j, k] * out[j, k]
        if not acc > 0.0:
            return False
        djj = math.sqrt(acc)
        out[j, j] = djj
        for i in range(j + 1, m):
            acc = a[i, j]
            for k in range(j):
                acc -= out[i, k] * out[j, k]
            out[i, j] = acc / djj
        for i in range(j):
            out[i, j] = 0.0
    return True


@njit(cache=True)
def _chol_solve_rows(lower, b, m, ncol):
    """
    Solve (L L^T) Y = B in place for every column of B (m x ncol).

    Row operations (the inner loops run along B's contiguous rows, so they vectorise); each
    column sees the same operations in the same order as a column-by-column substitution.
    """
    for i in range(m):
        for k in range(i):
            lik = lower[i, k]
            for c in range(ncol):
                b[i, c] -= lik * b[k, c]
        lii = lower[i, i]
        for c in range(ncol):
            b[i, c] /= lii
    for i in range(m - 1, -1, -1):
        for k in range(i + 1, m):
            lki = lower[k, i]
            for c in range(ncol):
                b[i, c] -= lki * b[k, c]
        lii = lower[i, i]
        for c in range(ncol):
            b[i, c] /= lii


@njit(cache=True)
def _add_transposed_product(out, left, right, rows):
    """
    Add left[:rows]^T right[:rows] to out (left (rows, p), right (rows, q), out (p, q)).

    Terms with a zero factor of left are skipped (an Euler step's A and B are about half
    zeros); adding an exact zero product would not change any finite sum.
    """
    for m in range(rows):
        for i in range(left.shape[1]):
            s = left[m, i]
            if s != 0.0:
                for j in range(right.shape[1]):
                    out[i, j] += s * right[m, j]


@njit(cache=True)
def padded(size):
    """Return size rounded up to a multiple of 8."""
    return (size + 7) // 8 * 8


@njit(cache=True)
def work_arrays(n_int, nx, nu):
    """Zeroed work arrays (pp, pc, gain, ff, xi, uu) of riccati_solve, rows padded."""
    nxp = padded(nx + 1)
    ncp = padded(1 + nx)
    return (np.zeros((n_int + 1, nxp, nxp)), np.zeros((n_int + 1, nxp, ncp)),
            np.zeros((n_int, nu, nxp)), np.zeros((n_int, nu, ncp)),
            np.zeros((n_int + 1, nxp, ncp)), np.zeros((n_int, nu, ncp)))


@njit(cache=True)
def jacobi_eigen(a, m, sweeps=60):
    """
    Eigen-decomposition of the symmetric a[:m, :m] (overwritten): (values (m,), vectors (m, m)).

    Cyclic Jacobi rotations in a fixed order (deterministic), until the off-diagonal part is
    below 1e-15 of the norm, at most sweeps sweeps; vectors' columns are the eigenvectors.
    """
    vec = np.zeros((m, m))
    for i in range(m):
        vec[i, i] = 1.0
    norm = 0.0
    for i in range(m):
        for j in range(m):
            norm += a[i, j] * a[i, j]
    for _ in range(sweeps):
        off = 0.0
        for i in range(m):
            for j in range(i + 1, m):
                off += a[i, j] * a[i, j]
        if not off > 1e-30 * norm:
            break
        for p in range(m - 1):
            for q in range(p + 1, m):
                apq = a[p, q]
                if apq == 0.0:
                    continue
                theta = (a[q, q] - a[p, p]) / (2.0 * apq)
                root = math.sqrt(theta * theta + 1.0)
                t = (1.0 if theta >= 0.0 else -1.0) / (abs(theta) + root)
                c = 1.0 / math.sqrt(t * t + 1.0)
                sn = t * c
                for k in range(m):
                    akp, akq = a[k, p], a[k, q]
                    a[k, p] = c * akp - sn * akq
                    a[k, q] = sn * akp + c * akq
                for k in range(m):
                    apk, aqk = a[p, k], a[q, k]
                    a[p, k] = c * apk - sn * aqk
                    a[q, k] = sn * apk + c * aqk
                for k in range(m):
                    vkp, vkq = vec[k, p], vec[k, q]
                    vec[k, p] = c * vkp - sn * vkq
                    vec[k, q] = sn * vkp + c * vkq
    values = np.empty(m)
    for i in range(m):
        values[i] = a[i, i]
    return values, vec


@njit(cache=True)
def _forward(a_mat, b_mat, c_vec, d_vec, gain, ff, xi, uu, n, nx, nu_, nxi, ncp):
    """Forward sweep from xi[0]: xi_k, u_k affine in the columns [1; nu; (dT)]."""
    for k in range(n):
        uk = uu[k]
        uk[:] = ff[k]
        gk = gain[k]
        xk = xi[k]
        for i in range(nu_):
            for j in range(nxi):
                s = gk[i, j]
                for c in range(ncp):
                    uk[i, c] += s * xk[j, c]
        xn = xi[k + 1]
        for i in range(nx):
            for c in range(ncp):
                xn[i, c] = c_vec[k, i] * xk[nx, c]
            for j in range(nx):
                s = a_mat[k, i, j]
                if s != 0.0:
                    for c in range(ncp):
                        xn[i, c] += s * xk[j, c]
            for j in range(nu_):
                s = b_mat[k, i, j]
                if s != 0.0:
                    for c in range(ncp):
                        xn[i, c] += s * uk[j, c]
            xn[i, 0] += d_vec[k, i]
        for i in range(nx, xi.shape[1]):
            for c in range(ncp):
                xn[i, c] = xk[i, c]


@njit(cache=True)
def _final_time_and_nu(pp, pc, xi, n, nx, nu):
    """
    Solve K [dT; nu] = -[p_0(T); dx_N(0)] (module docstring) when P_0(T, T) <= 0: (code, dT).

    xi's column 1 + nx is the dT direction.  K's inertia must be (1, nx); the symmetric part
    is solved through its eigen-decomposition and refined against K itself (its two
    off-diagonal blocks agree up to rounding).
    """
    m = nx + 1
    dcol = nx + 1
    k_mat = np.empty((m, m))
    k_mat[0, 0] = pp[0, nx, nx]
    for j in range(nx):
        k_mat[0, 1 + j] = pc[0, nx, 1 + j]
        k_mat[1 + j, 0] = xi[n, j, dcol]
        for i in range(nx):
            k_mat[1 + i, 1 + j] = xi[n, i, 1 + j]
    sym = np.empty((m, m))
    for i in range(m):
        for j in range(m):
            sym[i, j] = 0.5 * (k_mat[i, j] + k_mat[j, i])
    values, vec = jacobi_eigen(sym, m)
    positive = 0
    negative = 0
    for i in range(m):
        if values[i] > 0.0:
            positive += 1
        elif values[i] < 0.0:
            negative += 1
    if positive != 1 or negative != nx:
        return FINAL_TIME_CURVATURE, 0.0
    rhs = np.empty(m)
    rhs[0] = -pc[0, nx, 0]
    for i in range(nx):
        rhs[1 + i] = -xi[n, i, 0]
    sol = np.zeros(m)
    res = rhs.copy()
    for step in range(4):   # the solve, then three refinements against K
        if step:
            for i in range(m):
                acc = rhs[i]
                for j in range(m):
                    acc -= k_mat[i, j] * sol[j]
                res[i] = acc
        for i in range(m):
            acc = 0.0
            for j in range(m):
                acc += vec[j, i] * res[j]
            acc /= values[i]
            for j in range(m):
                sol[j] += vec[j, i] * acc
    for i in range(nx):
        nu[i] = sol[1 + i]
    return OK, sol[0]


@njit(cache=True)
def riccati_solve(a_mat, b_mat, c_vec, d_vec, hxx, hux, huu, gx, gu, rho,
                  pp, pc, gain, ff, xi, uu, dx, du, lam, nu):
    """
    Solve the stage QP of the module docstring; return (code, dT).

    a_mat (N, nx, nx), b_mat (N, nx, nu), c_vec, d_vec (N, nx): the linearised steps;
    hxx (N, nx + 1, nx + 1), hux (N, nu, nx + 1), huu (N, nu, nu), gx (N, nx + 1), gu (N, nu):
    Hessian and gradient blocks over (xi_k, u_k); rho > 0: curvature put on dx_N (dx_N = 0 is
    imposed, so it changes only the multipliers' intermediate values, not the step).
    Work: pp, pc, gain, ff, xi, uu from work_arrays(N, nx, nu) (rows padded to a multiple of
    8); work arrays of other shapes (e.g. the unpadded (N + 1, nx + 1, nx + 1), ...) are
    replaced by fresh ones.
    Out: dx (N + 1, nx), du (N, nu), lam (N + 1, nx) (multiplier of the step into x_k, the
    derivative of the cost-to-go), nu (nx,) terminal multipliers.
    """
    n = a_mat.shape[0]
    nx = a_mat.shape[1]
    nu_ = b_mat.shape[2]
    nxi = nx + 1
    ncol = 1 + nx
    # Rows padded with zeros to a multiple of 8: loops of a fixed multiple of the vector width
    # run vectorised, where 15 would fall to the scalar remainder loop.
    nxp = padded(nxi)
    ncp = padded(ncol)
    if (pp.shape[1] != nxp or pc.shape[2] != ncp or gain.shape[2] != nxp
            or ff.shape[2] != ncp or xi.shape[1] != nxp or uu.shape[2] != ncp):
        pp, pc, gain, ff, xi, uu = work_arrays(n, nx, nu_)
    abar = np.zeros((nxp, nxp))         # [[A, c], [0, 1]]
    bbar = np.zeros((nxp, nu_))         # [B; 0]
    abar[nx, nx] = 1.0
    w = np.empty((nxp, nxp))            # Abar^T P
    pa = np.empty((nxp, nxp))           # P Abar
    v = np.empty((nu_, nxp))            # Bbar^T P
    pb = np.empty((nxp, nu_))           # P Bbar
    qxx = np.zeros((nxp, nxp))
    qux = np.zeros((nu_, nxp))
    quu = np.empty((nu_, nu_))
    low = np.zeros((nu_, nu_))
    r = np.empty((nxp, ncp))
    qx = np.empty((nxp, ncp))
    qu = np.empty((nu_, ncp))
    # Terminal value: rho |dx_N|^2 / 2 + nu . dx_N (columns 1.. are the nu directions).
    pp[n] = 0.0
    pc[n] = 0.0
    for i in range(nx):
        pp[n, i, i] = rho
        pc[n, i, 1 + i] = 1.0
    for k in range(n - 1, -1, -1):
        p = pp[k + 1]
        for i in range(nx):
            for j in range(nx):
                abar[i, j] = a_mat[k, i, j]
            abar[i, nx] = c_vec[k, i]
            for j in range(nu_):
                bbar[i, j] = b_mat[k, i, j]
        # P is symmetric: P Abar = (Abar^T P)^T, P Bbar = (Bbar^T P)^T.
        w[:] = 0.0
        _add_transposed_product(w, abar, p, nxi)
        v[:] = 0.0
        _add_transposed_product(v, bbar, p, nx)
        for i in range(nxp):
            for j in range(nxp):
                pa[i, j] = w[j, i]
            for j in range(nu_):
                pb[i, j] = v[j, i]
        # Qxx = H + Abar^T P Abar, Qux = Hux + Bbar^T P Abar, Quu = Huu + Bbar^T P Bbar.
        qxx[:nxi, :nxi] = hxx[k]
        _add_transposed_product(qxx, abar, pa, nxi)
        qux[:, :nxi] = hux[k]
        _add_transposed_product(qux, bbar, pa, nx)
        quu[:] = huu[k]
        _add_transposed_product(quu, bbar, pb, nx)
        # r = p + P dbar (first column only); qx = g + Abar^T r, qu = g + Bbar^T r.
        r[:] = pc[k + 1]
        for i in range(nxi):
            acc = 0.0
            for m in range(nx):
                acc += p[i, m] * d_vec[k, m]
            r[i, 0] += acc
        qx[:] = 0.0
        _add_transposed_product(qx, abar, r, nxi)
        qu[:] = 0.0
        _add_transposed_product(qu, bbar, r, nx)
        for i in range(nxi):
            qx[i, 0] += gx[k, i]
        for i in range(nu_):
            qu[i, 0] += gu[k, i]
        if not _cholesky(quu, low, nu_):
            return REDUCED_HESSIAN_INDEFINITE, 0.0
        # gain = -Quu^-1 Qux, ff = -Quu^-1 qu.
        gk = gain[k]
        fk = ff[k]
        for i in range(nu_):
            for j in range(nxp):
                gk[i, j] = -qux[i, j]
            for c in range(ncp):
                fk[i, c] = -qu[i, c]
        _chol_solve_rows(low, gk, nu_, nxp)
        _chol_solve_rows(low, fk, nu_, ncp)
        # P_k = Qxx + Qux^T gain, p_k = qx + Qux^T ff.
        pk = pp[k]
        pk[:] = qxx
        _add_transposed_product(pk, qux, gk, nu_)
        ck = pc[k]
        ck[:] = qx
        _add_transposed_product(ck, qux, fk, nu_)
        for i in range(nxi):
            for j in range(i):
                s = 0.5 * (pk[i, j] + pk[j, i])
                pk[i, j] = s
                pk[j, i] = s
    ptt = pp[0, nx, nx]
    # Forward sweep, affine in nu: xi_k = Xi_k [1; nu], u_k = U_k [1; nu]; with dT eliminated
    # when P_0(T, T) > 0, else with dT as one more direction (column 1 + nx).
    eliminated = ptt > 0.0
    xi[0] = 0.0
    if eliminated:
        for c in range(ncol):
            xi[0, nx, c] = -pc[0, nx, c] / ptt
    else:
        xi[0, nx, ncol] = 1.0
    _forward(a_mat, b_mat, c_vec, d_vec, gain, ff, xi, uu, n, nx, nu_, nxi, ncp)
    if not eliminated:
        code, d_t = _final_time_and_nu(pp, pc, xi, n, nx, nu)
        if code != OK:
            return code, 0.0
        coef = np.zeros(ncol + 1)
        coef[0] = 1.0
        for i in range(nx):
            coef[1 + i] = nu[i]
        coef[ncol] = d_t
        _step_from(xi, uu, pp, pc, coef, ncol + 1, n, nx, nu_, d_t, dx, du, lam)
        return OK, d_t
    # dx_N = Xi_N[:nx, 0] + M nu = 0, M = -(terminal Schur complement): negative definite.
    m_mat = np.empty((nx, nx))
    neg = np.empty((nx, nx))
    low_t = np.zeros((nx, nx))
    rhs = np.empty((nx, 1))
    for i in range(nx):
        for j in range(nx):
            m_mat[i, j] = xi[n, i, 1 + j]
    for i in range(nx):
        for j in range(nx):
            neg[i, j] = -0.5 * (m_mat[i, j] + m_mat[j, i])
        rhs[i, 0] = xi[n, i, 0]
    if not _cholesky(neg, low_t, nx):
        return TERMINAL_SCHUR_INDEFINITE, 0.0
    # M is symmetric up to rounding: solve with its symmetric part (-neg).
    _chol_solve_rows(low_t, rhs, nx, 1)
    for i in range(nx):
        nu[i] = rhs[i, 0]       # (-M) nu = dx_N(nu = 0)  =>  dx_N = 0
    coef = np.empty(ncol)
    coef[0] = 1.0
    for i in range(nx):
        coef[1 + i] = nu[i]
    # Iterative refinement: M is ill-conditioned when the problem is degenerate (e.g. every
    # control interior on a velocity-limited arc); the affine map dx_N(nu) itself is accurate.
    for _ in range(3):
        for i in range(nx):
            acc = 0.0
            for c in range(ncol):
                acc += xi[n, i, c] * coef[c]
            rhs[i, 0] = acc
        _chol_solve_rows(low_t, rhs, nx, 1)
        for i in range(nx):
            nu[i] += rhs[i, 0]
            coef[1 + i] = nu[i]
    d_t = 0.0
    for c in range(ncol):
        d_t += xi[0, nx, c] * coef[c]
    _step_from(xi, uu, pp, pc, coef, ncol, n, nx, nu_, d_t, dx, du, lam)
    return OK, d_t


@njit(cache=True)
def _step_from(xi, uu, pp, pc, coef, ncol, n, nx, nu_, d_t, dx, du, lam):
    """dx, du and lam of the step: the forward sweep's columns [:ncol] combined by coef."""
    for k in range(n + 1):
        for i in range(nx):
            acc = 0.0
            for c in range(ncol):
                acc += xi[k, i, c] * coef[c]
            dx[k, i] = acc
        if k < n:
            for i in range(nu_):
                acc = 0.0
                for c in range(ncol):
                    acc += uu[k, i, c] * coef[c]
                du[k, i] = acc
    # lam_k = P_k xi_k + p_k [1; nu] (x rows), k = 1..N.
    for k in range(1, n + 1):
        for i in range(nx):
            acc = pp[k, i, nx] * d_t
            for j in range(nx):
                acc += pp[k, i, j] * dx[k, j]
            for c in range(ncol):
                acc += pc[k, i, c] * coef[c]
            lam[k, i] = acc
    for i in range(nx):
        lam[0, i] = 0.0
