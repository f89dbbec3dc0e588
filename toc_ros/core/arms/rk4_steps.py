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
RK4 steps of the arm dynamics and their derivatives (the arm interior point's 'rk4').

One step over h = t_f / N with the torques constant on the interval:
    k1 = f(x), k2 = f(x + h/2 k1), k3 = f(x + h/2 k2), k4 = f(x + h k3),
    step = x + h/6 (k1 + 2 k2 + 2 k3 + k4),    f(x) = (dq, ABA(q, dq, effort v)).
Its derivatives by the chain rule through the stages, each stage's Jacobian from one
pinocchio.computeABADerivatives call per interval (4 N calls), the matrix products batched
over the intervals.

The curvature (hessian 'exact'): forward differences of these derivatives along each
coordinate of z_k = (x_k, T, v_k), every interval shifted at once (a step depends on its own
x_k, v_k and on T only): 3 n + 1 evaluations of rk4_terms, 4 N (3 n + 1) derivative calls,
kept (arm_eval.TENSOR_REUSE) and contracted with the current multipliers.  Unlike an Euler
step, an RK4 step is not affine in the torques (the later stages' states move with them): the
control block huu is part of it.
"""

import numpy as np


def rk4_defects(evaluator, x, v, t_f):
    """RK4 defects step_k - x_{k+1}, (N, 2n): four batched ABA calls."""
    n, h = evaluator.n, t_f / evaluator.n_int
    xs = x[:-1]

    def f(states):
        return np.hstack([states[:, n:], evaluator.accelerations(states, v)])
    k1 = f(xs)
    k2 = f(xs + 0.5 * h * k1)
    k3 = f(xs + 0.5 * h * k2)
    k4 = f(xs + h * k3)
    return xs + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4) - x[1:]


def _stage(evaluator, states, tau):
    """(f (N, 2n), df/dx (N, 2n, 2n), df/dv (N, 2n, n)) at states under torques tau."""
    n = evaluator.n
    acc, d_q, d_v, minv = evaluator.derivatives_at(states, tau)
    count = states.shape[0]
    jac_x = np.zeros((count, 2 * n, 2 * n))
    jac_x[:, :n, n:] = np.eye(n)
    jac_x[:, n:, :n] = d_q
    jac_x[:, n:, n:] = d_v
    jac_v = np.zeros((count, 2 * n, n))
    jac_v[:, n:, :] = minv * evaluator.effort[None, None, :]
    return np.hstack([states[:, n:], acc]), jac_x, jac_v


def rk4_terms(evaluator, x, v, t_f):
    """Return the RK4 steps' defect (N, 2n), a = d/dx, b = d/dv and c = d/dT of the step."""
    n_int = evaluator.n_int
    h = t_f / n_int
    tau = v * evaluator.effort[None, :]
    xs = x[:-1]

    def apply(jac, vec):
        return np.einsum('kij,kj->ki', jac, vec)
    k1, j1, g1 = _stage(evaluator, xs, tau)
    k2, j2, g2 = _stage(evaluator, xs + 0.5 * h * k1, tau)
    k3, j3, g3 = _stage(evaluator, xs + 0.5 * h * k2, tau)
    k4, j4, g4 = _stage(evaluator, xs + h * k3, tau)
    # d k_i / dx, d k_i / dv and d k_i / dT (h = T / N) through the stage points.
    d1x, d1v = j1, g1
    d2x, d2v = j2 + 0.5 * h * j2 @ d1x, g2 + 0.5 * h * j2 @ d1v
    d3x, d3v = j3 + 0.5 * h * j3 @ d2x, g3 + 0.5 * h * j3 @ d2v
    d4x, d4v = j4 + h * j4 @ d3x, g4 + h * j4 @ d3v
    d2t = apply(j2, 0.5 * k1 / n_int)
    d3t = apply(j3, 0.5 * k2 / n_int + 0.5 * h * d2t)
    d4t = apply(j4, k3 / n_int + h * d3t)
    slope = k1 + 2.0 * k2 + 2.0 * k3 + k4
    nx = x.shape[1]
    return {'defect': xs + (h / 6.0) * slope - x[1:],
            'a': np.eye(nx)[None] + (h / 6.0) * (d1x + 2.0 * d2x + 2.0 * d3x + d4x),
            'b': (h / 6.0) * (d1v + 2.0 * d2v + 2.0 * d3v + d4v),
            'c': slope / (6.0 * n_int) + (h / 6.0) * (2.0 * d2t + 2.0 * d3t + d4t),
            'hxx': np.zeros((n_int, nx + 1, nx + 1)),
            'hux': np.zeros((n_int, v.shape[1], nx + 1))}


def rk4_jacobian(evaluator, x, v, t_f):
    """Return [a | c | b] of the RK4 steps, (N, 2n, 3n + 1): columns over (x_k, T, v_k)."""
    terms = rk4_terms(evaluator, x, v, t_f)
    return np.concatenate([terms['a'], terms['c'][:, :, None], terms['b']], axis=2)


def rk4_second_derivatives(evaluator, x, v, t_f, step):
    """
    (N, 3n + 1, 2n, 3n + 1): d/dz_i of rk4_jacobian, z = (x_k, T, v_k), forward differences.

    Each direction shifts every interval at once (its step depends on its own x_k and v_k,
    and on T): one rk4_jacobian per direction.
    """
    base = rk4_jacobian(evaluator, x, v, t_f)
    nx, n = x.shape[1], v.shape[1]
    out = np.empty((base.shape[0], nx + 1 + n, nx, nx + 1 + n))
    for i in range(nx):
        shifted = x.copy()
        shifted[:-1, i] += step
        out[:, i] = (rk4_jacobian(evaluator, shifted, v, t_f) - base) / step
    out[:, nx] = (rk4_jacobian(evaluator, x, v, t_f + step) - base) / step
    for j in range(n):
        shifted = v.copy()
        shifted[:, j] += step
        out[:, nx + 1 + j] = (rk4_jacobian(evaluator, x, shifted, t_f) - base) / step
    return out


def rk4_curvature(tensor, lam, out):
    """
    Fill out's hxx, hux and huu with the Hessian of lam_{k+1} . step_k over (x_k, T, v_k).

    tensor: rk4_second_derivatives (possibly of an earlier iterate); the rows' difference
    quotients are contracted with the multipliers, then symmetrised.
    """
    nx = tensor.shape[2]
    hess = np.einsum('kr,kirj->kij', lam[1:], tensor)
    hess = 0.5 * (hess + hess.transpose(0, 2, 1))
    out['hxx'][:] = hess[:, :nx + 1, :nx + 1]
    out['hux'][:] = hess[:, nx + 1:, :nx + 1]
    out['huu'] = np.ascontiguousarray(hess[:, nx + 1:, nx + 1:])
