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
Compiled per-iteration arithmetic of the arm interior point (arm_ipm.py).

The formulas are those of arm_ipm.py's docstring; they sit here because one iteration touches
every stage a dozen times (errors, barrier terms, steps to the boundary, merit), and each of
those as numpy expressions costs a few microseconds of call overhead per operation.

Bounds: x_k in [lx, ux] at the free nodes k = 1..N-1 (has_l / has_u mark the finite ones),
scaled controls v_k in [-1, 1], T in [t_low, t_high], sphere slacks s >= 0.  Arrays of the
free nodes (x_inner, zlx, zux, s, z, values, grads) have N - 1 rows.
"""

import math

from numba import njit
import numpy as np


@njit(cache=True)
def euler_terms(x, v, t_f, acc, d_q, d_v, minv, effort, defect, a_mat, b_mat, c_vec):
    """
    Fill the Euler steps' defects and derivatives from Pinocchio's ABA derivatives.

    step_k = x_k + h f(x_k, effort v_k), f = (dq, ddq), h = t_f / N: defect (N, 2n) =
    step_k - x_{k+1}, a_mat = d step / dx (N, 2n, 2n), b_mat = d step / dv (N, 2n, n),
    c_vec = d step / dT = f / N (N, 2n).
    """
    n_int, n = acc.shape
    h = t_f / n_int
    for k in range(n_int):
        for i in range(n):
            f_q = x[k, n + i]
            f_v = acc[k, i]
            defect[k, i] = x[k, i] + h * f_q - x[k + 1, i]
            defect[k, n + i] = x[k, n + i] + h * f_v - x[k + 1, n + i]
            c_vec[k, i] = f_q / n_int
            c_vec[k, n + i] = f_v / n_int
            for j in range(n):
                a_mat[k, i, j] = 1.0 if i == j else 0.0
                a_mat[k, i, n + j] = h if i == j else 0.0
                a_mat[k, n + i, j] = h * d_q[k, i, j]
                a_mat[k, n + i, n + j] = (1.0 if i == j else 0.0) + h * d_v[k, i, j]
                b_mat[k, i, j] = 0.0
                b_mat[k, n + i, j] = h * minv[k, i, j] * effort[j]


@njit(cache=True)
def _lower_slack(x_inner, lx, has_l, k, i):
    return x_inner[k, i] - lx[i] if has_l[i] else math.inf


@njit(cache=True)
def _upper_slack(x_inner, ux, has_u, k, i):
    return ux[i] - x_inner[k, i] if has_u[i] else math.inf


@njit(cache=True)
def kkt_errors(lam, a_mat, b_mat, c_vec, defect, grads, values, s, z, x_inner, v, t,
               zlx, zux, zlv, zuv, zlt, zut, lx, ux, has_l, has_u, t_low, t_high, s_max):
    """
    (dual infeasibility, primal infeasibility, complementarity, s_d, s_c): IPOPT's measures.

    Dual infeasibility: the largest entry of the Lagrangian's gradient in x_1..x_{N-1}, v and
    T; primal: the largest defect or sphere-row residual g - s; s_d and s_c: IPOPT's
    scalings of the dual and complementarity errors (s_max: IPOPT's s_max, 100).
    """
    n_int, nx = defect.shape
    n = nx // 2
    n_rows = s.shape[1]
    dual = 0.0
    for k in range(1, n_int):
        for j in range(nx):
            acc = -lam[k, j]
            for i in range(nx):
                acc += a_mat[k, i, j] * lam[k + 1, i]
            acc += -zlx[k - 1, j] + zux[k - 1, j]
            if j < n:
                for p in range(n_rows):
                    acc -= grads[k - 1, p, j] * z[k - 1, p]
            dual = max(dual, abs(acc))
    for k in range(n_int):
        for j in range(n):
            acc = 0.0
            for i in range(nx):
                acc += b_mat[k, i, j] * lam[k + 1, i]
            acc += -zlv[k, j] + zuv[k, j]
            dual = max(dual, abs(acc))
    acc = 1.0
    for k in range(n_int):
        for i in range(nx):
            acc += c_vec[k, i] * lam[k + 1, i]
    dual = max(dual, abs(acc - zlt + zut))
    primal = 0.0
    for k in range(n_int):
        for i in range(nx):
            primal = max(primal, abs(defect[k, i]))
    for k in range(n_int - 1):
        for p in range(n_rows):
            primal = max(primal, abs(values[k, p] - s[k, p]))
    compl = complementarity(x_inner, v, t, s, z, zlx, zux, zlv, zuv, zlt, zut, lx, ux, has_l,
                            has_u, t_low, t_high, 0.0)
    bound_duals = 0.0
    count = 0
    for k in range(n_int - 1):
        for i in range(nx):
            bound_duals += abs(zlx[k, i]) + abs(zux[k, i])
            if zlx[k, i] != 0.0:
                count += 1
            if zux[k, i] != 0.0:
                count += 1
        for p in range(n_rows):
            bound_duals += z[k, p]
    for k in range(n_int):
        for i in range(n):
            bound_duals += zlv[k, i] + zuv[k, i]
    bound_duals += zlt + zut
    count += 2 * v.size + 2 + z.size
    lam_sum = 0.0
    for k in range(lam.shape[0]):
        for i in range(nx):
            lam_sum += abs(lam[k, i])
    s_d = max(s_max, (lam_sum + bound_duals) / max(count + lam.size, 1)) / s_max
    s_c = max(s_max, bound_duals / max(count, 1)) / s_max
    return dual, primal, compl, s_d, s_c


@njit(cache=True)
def complementarity(x_inner, v, t, s, z, zlx, zux, zlv, zuv, zlt, zut, lx, ux, has_l, has_u,
                    t_low, t_high, mu):
    """Return the largest |slack * dual - mu| over every bound and sphere slack."""
    worst = 0.0
    for k in range(x_inner.shape[0]):
        for i in range(x_inner.shape[1]):
            if has_l[i]:
                worst = max(worst, abs((x_inner[k, i] - lx[i]) * zlx[k, i] - mu))
            if has_u[i]:
                worst = max(worst, abs((ux[i] - x_inner[k, i]) * zux[k, i] - mu))
        for p in range(s.shape[1]):
            worst = max(worst, abs(s[k, p] * z[k, p] - mu))
    for k in range(v.shape[0]):
        for i in range(v.shape[1]):
            worst = max(worst, abs((v[k, i] + 1.0) * zlv[k, i] - mu),
                        abs((1.0 - v[k, i]) * zuv[k, i] - mu))
    return max(worst, abs((t - t_low) * zlt - mu), abs((t_high - t) * zut - mu))


@njit(cache=True)
def qp_blocks(model_hxx, grads, values, curvature, s, z, x_inner, v, t, zlx, zux, zlv, zuv,
              zlt, zut, lx, ux, has_l, has_u, t_low, t_high, mu, hxx, gx, huu_diag, gu):
    """
    Fill the condensed barrier QP's blocks hxx, gx, huu_diag and gu.

    Shapes: hxx (N, nx + 1, nx + 1), gx (N, nx + 1), huu_diag (N, n), gu (N, n).
    hxx = the model's curvature + the bound duals' Sigma = z / slack on x and T + the sphere
    rows' Gauss-Newton term J^T (z / s) J minus the rows' own curvature (curvature: of
    sum_p z_p g_p); gradients of the barrier problem (cost T) with the sphere residuals
    g - s folded in through Sigma_s.
    """
    n_int = hxx.shape[0]
    nx = hxx.shape[1] - 1
    n = nx // 2
    n_rows = s.shape[1]
    hxx[:] = model_hxx
    gx[:] = 0.0
    for k in range(1, n_int):
        for i in range(nx):
            sig = 0.0
            g = 0.0
            if has_l[i]:
                lo = x_inner[k - 1, i] - lx[i]
                sig += zlx[k - 1, i] / lo
                g += -mu / lo
            if has_u[i]:
                hi = ux[i] - x_inner[k - 1, i]
                sig += zux[k - 1, i] / hi
                g += mu / hi
            hxx[k, i, i] += sig
            gx[k, i] = g
        # Sphere rows: J^T Sigma_s J - curvature, gradient J^T (Sigma_s (g - s) - mu / s).
        for p in range(n_rows):
            sig_s = z[k - 1, p] / s[k - 1, p]
            weight = sig_s * (values[k - 1, p] - s[k - 1, p]) - mu / s[k - 1, p]
            for i in range(n):
                gi = grads[k - 1, p, i]
                if gi == 0.0:
                    continue
                gx[k, i] += gi * weight
                scaled = gi * sig_s
                for j in range(n):
                    hxx[k, i, j] += scaled * grads[k - 1, p, j]
        if n_rows:
            for i in range(n):
                for j in range(n):
                    hxx[k, i, j] -= curvature[k - 1, i, j]
    lo_t = t - t_low
    hi_t = t_high - t
    hxx[0, nx, nx] += zlt / lo_t + zut / hi_t
    gx[0, nx] = 1.0 - mu / lo_t + mu / hi_t
    for k in range(n_int):
        for i in range(n):
            lo = v[k, i] + 1.0
            hi = 1.0 - v[k, i]
            huu_diag[k, i] = zlv[k, i] / lo + zuv[k, i] / hi
            gu[k, i] = -mu / lo + mu / hi


@njit(cache=True)
def regularised(hxx, huu_diag, prox, delta, hxx_out, huu_out):
    """hxx_out = hxx + (prox + delta) I, huu_out = diag(huu_diag + prox + delta)."""
    n_int, nxi, _ = hxx.shape
    n = huu_diag.shape[1]
    hxx_out[:] = hxx
    huu_out[:] = 0.0
    for k in range(n_int):
        for i in range(nxi):
            hxx_out[k, i, i] = hxx_out[k, i, i] + prox + delta
        for i in range(n):
            huu_out[k, i, i] = huu_diag[k, i] + prox + delta


@njit(cache=True)
def _ratio(value, step, frac, best):
    """min(best, -frac value / step) for a negative step."""
    if step < 0.0:
        return min(best, -frac * value / step)
    return best


@njit(cache=True)
def step_to_boundary(dx_inner, dv, d_t, grads, values, s, z, x_inner, v, t, zlx, zux, zlv,
                     zuv, zlt, zut, lx, ux, has_l, has_u, t_low, t_high, mu, frac,
                     ds, dzlx, dzux, dzlv, dzuv, dz):
    """
    Fill the slack and bound-dual steps; return (alpha_max, alpha_dual, dzlt, dzut, slope).

    ds = g + J dq - s (the linearised sphere rows), the duals' steps of the condensed system,
    the fraction-to-the-boundary step lengths (primal, dual) and the directional derivative of
    the barrier objective along the step (the filter line search's switching rule).
    """
    n_rows = s.shape[1]
    n = v.shape[1]
    alpha = 1.0
    alpha_dual = 1.0
    slope = 0.0
    for k in range(x_inner.shape[0]):
        for i in range(x_inner.shape[1]):
            step = dx_inner[k, i]
            if has_l[i]:
                lo = x_inner[k, i] - lx[i]
                alpha = _ratio(lo, step, frac, alpha)
                dzlx[k, i] = mu / lo - zlx[k, i] - zlx[k, i] / lo * step
                alpha_dual = _ratio(zlx[k, i], dzlx[k, i], frac, alpha_dual)
                slope += -mu / lo * step
            else:
                dzlx[k, i] = 0.0
            if has_u[i]:
                hi = ux[i] - x_inner[k, i]
                alpha = _ratio(hi, -step, frac, alpha)
                dzux[k, i] = mu / hi - zux[k, i] + zux[k, i] / hi * step
                alpha_dual = _ratio(zux[k, i], dzux[k, i], frac, alpha_dual)
                slope += mu / hi * step
            else:
                dzux[k, i] = 0.0
        for p in range(n_rows):
            acc = values[k, p] - s[k, p]
            for j in range(n):
                acc += grads[k, p, j] * dx_inner[k, j]
            ds[k, p] = acc
            alpha = _ratio(s[k, p], acc, frac, alpha)
            dz[k, p] = mu / s[k, p] - z[k, p] - z[k, p] / s[k, p] * acc
            alpha_dual = _ratio(z[k, p], dz[k, p], frac, alpha_dual)
            slope -= mu / s[k, p] * acc
    for k in range(v.shape[0]):
        for i in range(n):
            lo = v[k, i] + 1.0
            hi = 1.0 - v[k, i]
            step = dv[k, i]
            alpha = _ratio(lo, step, frac, alpha)
            alpha = _ratio(hi, -step, frac, alpha)
            dzlv[k, i] = mu / lo - zlv[k, i] - zlv[k, i] / lo * step
            dzuv[k, i] = mu / hi - zuv[k, i] + zuv[k, i] / hi * step
            alpha_dual = _ratio(zlv[k, i], dzlv[k, i], frac, alpha_dual)
            alpha_dual = _ratio(zuv[k, i], dzuv[k, i], frac, alpha_dual)
            slope += (-mu / lo + mu / hi) * step
    lo_t = t - t_low
    hi_t = t_high - t
    alpha = _ratio(lo_t, d_t, frac, alpha)
    alpha = _ratio(hi_t, -d_t, frac, alpha)
    dzlt = mu / lo_t - zlt - zlt / lo_t * d_t
    dzut = mu / hi_t - zut + zut / hi_t * d_t
    alpha_dual = _ratio(zlt, dzlt, frac, alpha_dual)
    alpha_dual = _ratio(zut, dzut, frac, alpha_dual)
    slope += d_t * (1.0 - mu / lo_t + mu / hi_t)
    return alpha, alpha_dual, dzlt, dzut, slope


@njit(cache=True)
def merit(x_inner, v, t, s, defect, values, lx, ux, has_l, has_u, t_low, t_high, mu):
    """(phi, theta): barrier objective and l1 constraint violation; (inf, inf) outside."""
    log_sum = 0.0
    for k in range(x_inner.shape[0]):
        for i in range(x_inner.shape[1]):
            if has_l[i]:
                lo = x_inner[k, i] - lx[i]
                if not lo > 0.0:
                    return math.inf, math.inf
                log_sum += math.log(lo)
            if has_u[i]:
                hi = ux[i] - x_inner[k, i]
                if not hi > 0.0:
                    return math.inf, math.inf
                log_sum += math.log(hi)
        for p in range(s.shape[1]):
            if not s[k, p] > 0.0:
                return math.inf, math.inf
            log_sum += math.log(s[k, p])
    for k in range(v.shape[0]):
        for i in range(v.shape[1]):
            lo = v[k, i] + 1.0
            hi = 1.0 - v[k, i]
            if not (lo > 0.0 and hi > 0.0):
                return math.inf, math.inf
            log_sum += math.log(lo) + math.log(hi)
    lo_t = t - t_low
    hi_t = t_high - t
    if not (lo_t > 0.0 and hi_t > 0.0):
        return math.inf, math.inf
    log_sum += math.log(lo_t) + math.log(hi_t)
    theta = 0.0
    for k in range(defect.shape[0]):
        for i in range(defect.shape[1]):
            theta += abs(defect[k, i])
    for k in range(values.shape[0]):
        for p in range(values.shape[1]):
            theta += abs(values[k, p] - s[k, p])
    return t - mu * log_sum, theta


@njit(cache=True)
def _clip_dual(value, slack, mu, kappa):
    return min(max(value, mu / (kappa * slack)), kappa * mu / slack)


@njit(cache=True)
def safeguard_duals(x_inner, v, s, z, zlx, zux, zlv, zuv, lx, ux, has_l, has_u, mu, kappa):
    """Clip every bound dual into [mu / (kappa slack), kappa mu / slack] (IPOPT), in place."""
    for k in range(x_inner.shape[0]):
        for i in range(x_inner.shape[1]):
            zlx[k, i] = (_clip_dual(zlx[k, i], x_inner[k, i] - lx[i], mu, kappa) if has_l[i]
                         else 0.0)
            zux[k, i] = (_clip_dual(zux[k, i], ux[i] - x_inner[k, i], mu, kappa) if has_u[i]
                         else 0.0)
        for p in range(s.shape[1]):
            z[k, p] = _clip_dual(z[k, p], s[k, p], mu, kappa)
    for k in range(v.shape[0]):
        for i in range(v.shape[1]):
            zlv[k, i] = _clip_dual(zlv[k, i], v[k, i] + 1.0, mu, kappa)
            zuv[k, i] = _clip_dual(zuv[k, i], 1.0 - v[k, i], mu, kappa)


def empty_rows(count, n):
    """Zero-row placeholders (values, grads, curvature) for a problem without sphere rows."""
    return np.zeros((count, 0)), np.zeros((count, 0, n)), np.zeros((count, n, n))
