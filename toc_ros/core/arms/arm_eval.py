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
Model evaluations of the arm interior point: Euler steps, their derivatives, sphere clearances.

Every interval's dynamics derivatives are one pinocchio.computeABADerivatives call: all
intervals in one call of the C++ loop of pin_batch.py when it is built, else from Python (its
outputs copied from views of the data's buffers), the same bits either way; the Euler blocks
are then assembled in one compiled call (ipm_kernels.py); a
line search's first trial point takes its accelerations from these calls and keeps the
derivatives for the next iteration (the trial is usually taken: the Panda past a sphere -8 %
time, the same bits), later trials one batched pinocchio.abaInParallel call on one thread; the
sphere kinematics, rows, gradients and curvature of all nodes are one compiled call
(kernels.sphere_rows, with the centres' exact second derivatives).

With hessian='cross' the curvature between the final time and (x, tau) is exact: the step is
x + (T / N) f(x, tau), so d2 (lam . step) / dT dz = lam . df/dz / N, from the same call.
With hessian='exact' also the dynamics' curvature is exact up to a forward difference of
Pinocchio's analytical derivatives: the Hessian of lam_v . ABA(q, v, tau) is the forward
difference, along each coordinate of q and v, of its gradient (lam_v . da/dq, lam_v . da/dv,
M^-1 lam_v); ABA is affine in tau, so no tau direction is needed (2 n extra derivative calls
per node).  The Hessian only shapes the Newton steps: the convergence test uses the exact
first derivatives, so the accuracy of this difference cannot make a non-optimal point look
optimal.

Constraint of robot sphere s and obstacle o, R = r_s + R_o + margin:
    g = (|p_s(q) - c_o|^2 - R^2) / (2 R) >= 0
(smooth everywhere, reads as the distance d - R near the boundary; the same form as the
CasADi reference transcription).
"""

import time

import numpy as np
import pinocchio as pin

from . import kernels, pin_batch
from .clearances import reachable_obstacles
from .ipm_kernels import euler_terms
from .rk4_steps import rk4_curvature, rk4_defects, rk4_second_derivatives, rk4_terms

FD_STEP = 1e-6
# The second derivatives of ABA (2 n derivative calls per interval) are recomputed every
# TENSOR_REUSE evaluations and contracted with the current multipliers in between: the
# curvature lags the iterate by at most TENSOR_REUSE - 1 steps.  The exact phase starts near
# the optimum (cold_runs.run_ipm), where the iterate moves little: 12 against 3 cut the
# time of random arm suites by 4 % alone, by 13-16 % with the earlier switch to it, the same
# final times (benchmarks/RESULTS.md, "Arms: the final time's curvature").
TENSOR_REUSE = 12


class ArmEvaluator:
    """Euler step values/derivatives and sphere constraints for one arm problem."""

    def __init__(self, arm, spheres, obstacles, margin, n_intervals, self_collision=False,
                 integrator='euler'):
        self.arm = arm
        self.integrator = integrator
        self.model = arm.model
        self.data = arm.model.createData()
        self._pool = None           # (pin.ModelPool: made when first used, accelerations)
        self.batch = pin_batch.workspace(arm.model)
        self.n = arm.n
        self.n_int = n_intervals
        self.effort = arm.effort.copy()
        self.spheres = spheres
        obstacles = np.asarray(obstacles, dtype=float).reshape(-1, 4)
        # Obstacles out of every sphere's reach get no rows (clearances.reachable_obstacles).
        obstacles = np.ascontiguousarray(
            obstacles[reachable_obstacles(spheres, arm, obstacles, margin)])
        self.obstacles = obstacles
        if spheres is not None:
            self.radius = spheres.radii[:, None] + obstacles[None, :, 3] + margin   # (S, O)
        else:
            self.radius = np.zeros((0, 0))
        self.n_obstacle_rows = self.radius.size
        if spheres is not None and self_collision and len(spheres.self_pairs):
            # Self-collision rows: sphere pairs of non-adjacent links, no margin.
            self.pairs = np.asarray(spheres.self_pairs, dtype=np.int64)
            self.pair_radius = spheres.radii[self.pairs[:, 0]] + spheres.radii[self.pairs[:, 1]]
        else:
            self.pairs = np.zeros((0, 2), dtype=np.int64)
            self.pair_radius = np.zeros(0)
        self.n_pairs = self.n_obstacle_rows + len(self.pairs)
        self.pin_time = 0.0
        self.pin_calls = 0
        self._tensor = None
        self._tensor_age = 0
        self._kept = None

    # Dynamics ------------------------------------------------------------------------------
    def accelerations(self, states, controls):
        """Return the ABA joint accelerations, (K, n), at states (K, 2n) and scaled controls."""
        n = self.n
        # One batched call (one thread: deterministic, and no waiting for a busy core):
        # Pinocchio's abaInParallel is ABA in the WORLD convention, bit for bit the ddq that
        # computeABADerivatives leaves in data, so the line search sees the same dynamics as
        # the Newton steps.
        q = np.asfortranarray(states[:, :n].T)
        dq = np.asfortranarray(states[:, n:].T)
        tau = np.asfortranarray((self.effort * controls).T)
        out = np.empty((n, states.shape[0]), order='F')
        if self._pool is None:
            self._pool = pin.ModelPool(self.model, 1)
        started = time.perf_counter()
        pin.abaInParallel(1, self._pool, q, dq, tau, out)
        self.pin_time += time.perf_counter() - started
        self.pin_calls += states.shape[0]
        return out.T

    def defects(self, x, v, t_f, keep_derivatives=False):
        """
        Defects step_k - x_{k+1}, (N, 2n): Euler x_k + h f(x_k, u_k), or RK4.

        keep_derivatives (Euler): the accelerations come from the derivative call and its
        results are kept for stage_terms at the same (x, v): a line search's first trial is
        usually the next iterate, whose derivatives would otherwise cost a second pass.
        """
        if self.integrator == 'rk4':
            return rk4_defects(self, x, v, t_f)
        n, h = self.n, t_f / self.n_int
        if keep_derivatives:
            acc = self._kept_derivatives(x, v)[0]
        else:
            acc = self.accelerations(x[:-1], v)
        step = np.hstack([x[:-1, n:], acc])
        return x[:-1] + h * step - x[1:]

    def _kept_derivatives(self, x, v):
        """derivatives_at the intervals of (x, v), reused while (x, v) stay the same."""
        kept = self._kept
        if kept is not None and np.array_equal(kept[0], x) and np.array_equal(kept[1], v):
            return kept[2]
        found = self.derivatives_at(x[:-1], v * self.effort[None, :])
        self._kept = (x.copy(), v.copy(), found)
        return found

    def derivatives_at(self, states, tau):
        """(acc, d acc/dq, d acc/dv, M^-1) at states (K, 2n) under torques (K, n)."""
        n, count = self.n, states.shape[0]
        acc = np.empty((count, n))
        d_q = np.empty((count, n, n))
        d_v = np.empty((count, n, n))
        minv = np.empty((count, n, n))
        started = time.perf_counter()
        if self.batch is not None:
            self.batch.aba_derivatives(states, tau, acc, d_q, d_v, minv)
        else:
            model, data, derivatives = self.model, self.data, pin.computeABADerivatives
            # data's ddq, ddq_dq, ddq_dv and Minv are numpy views of Pinocchio's own buffers:
            # copying them from the views skips the tuple of fresh arrays each call returns.
            out_a, out_q, out_v, out_m = data.ddq, data.ddq_dq, data.ddq_dv, data.Minv
            for k in range(count):
                derivatives(model, data, states[k, :n], states[k, n:], tau[k])
                acc[k] = out_a
                d_q[k] = out_q
                d_v[k] = out_v
                minv[k] = out_m
        self.pin_time += time.perf_counter() - started
        self.pin_calls += count
        return acc, d_q, d_v, minv

    def stage_terms(self, x, v, t_f, lam, hessian='exact'):
        """
        Step derivatives and Lagrangian curvature at every interval (rk4_steps.py for RK4).

        Returns a dict: defect (N, 2n), a (N, 2n, 2n), b (N, 2n, n) (scaled controls),
        c (N, 2n) (d step / d T), and the blocks hxx (N, 2n + 1, 2n + 1), hux (N, n, 2n + 1)
        of lam_{k+1} . step_k's curvature over (x_k, T, v_k) (huu = 0: ABA is affine in the
        torques): zero with hessian 'none', the final time's rows and columns with 'cross',
        all of it with 'exact' (module docstring).  RK4 steps with 'exact' also have huu
        (N, n, n) (rk4_steps.py); their 'cross' is 'none'.
        """
        n, nx, n_int = self.n, 2 * self.n, self.n_int
        if self.integrator == 'rk4':
            out = rk4_terms(self, x, v, t_f)
            if hessian == 'exact':      # ('cross' has no cheap form here: like 'none')
                rk4_curvature(self._kept_tensor(
                    lambda: rk4_second_derivatives(self, x, v, t_f, FD_STEP)), lam, out)
            return out
        h = t_f / n_int
        tau = v * self.effort[None, :]
        acc, d_q, d_v, minv = self._kept_derivatives(x, v)
        out = {'defect': np.empty((n_int, nx)), 'c': np.empty((n_int, nx)),
               'a': np.empty((n_int, nx, nx)), 'b': np.empty((n_int, nx, n)),
               'hxx': np.zeros((n_int, nx + 1, nx + 1)), 'hux': np.zeros((n_int, n, nx + 1))}
        euler_terms(x, v, t_f, acc, d_q, d_v, minv, self.effort, out['defect'], out['a'],
                    out['b'], out['c'])
        if hessian in ('cross', 'exact'):
            lam_q, lam_v = lam[1:, :n], lam[1:, n:]
            # d2 (lam . step) / dT d(x, v) = lam . df/d(x, v) / N.
            hxx, hux = out['hxx'], out['hux']
            hxx[:, :n, nx] = np.einsum('ki,kij->kj', lam_v, d_q) / n_int
            hxx[:, n:nx, nx] = (lam_q + np.einsum('ki,kij->kj', lam_v, d_v)) / n_int
            hxx[:, nx, :nx] = hxx[:, :nx, nx]
            hux[:, :, nx] = self.effort * np.einsum('kji,kj->ki', minv, lam_v) / n_int
        if hessian == 'exact':
            self._exact_curvature(x, tau, lam, d_q, d_v, minv, h, out)
        return out

    def forget_curvature(self):
        """Drop the kept second derivatives (a run from another start point begins)."""
        self._tensor = None

    def _kept_tensor(self, second_derivatives):
        """Return the kept second derivatives, made again by the call every TENSOR_REUSE uses."""
        if self._tensor is None or self._tensor_age >= TENSOR_REUSE:
            self._tensor = second_derivatives()
            self._tensor_age = 0
        self._tensor_age += 1
        return self._tensor

    def _exact_curvature(self, x, tau, lam, d_q, d_v, minv, h, out):
        """Fill out's hxx/hux (x, tau blocks) with h times the Hessian of lam_v . ABA."""
        n, nx = self.n, 2 * self.n
        tensor = self._kept_tensor(lambda: self._second_derivatives(x, tau, d_q, d_v, minv))
        # Rows i of the Hessian over (q, v, tau): lam_v . d/dz_i of (da/dq, da/dv, M^-1).
        hess = np.einsum('kj,kijl->kil', lam[1:, n:], tensor)
        square = hess[:, :, :nx]
        out['hxx'][:, :nx, :nx] = 0.5 * h * (square + square.transpose(0, 2, 1))
        # The tau rows by symmetry: d2 a / dtau dq from the q rows, d2 a / dtau dv = 0 and
        # d2 a / dtau2 = 0 (ABA is affine in tau).
        out['hux'][:, :, :n] = h * self.effort[None, :, None] * hess[:, :n, nx:].transpose(
            0, 2, 1)
        out['hux'][:, :, n:nx] = 0.0

    def _second_derivatives(self, x, tau, d_q, d_v, minv):
        """(N, 2n, n, 3n): d/dz_i of (da/dq, da/dv, M^-1) at every interval, z = (q, v)."""
        n, nx, n_int = self.n, 2 * self.n, self.n_int
        # Every interval's state shifted by FD_STEP along each of its 2n coordinates: one
        # derivatives_at call for all of them, differenced in one call.
        shifted = np.repeat(x[:-1, None, :], nx, axis=1)
        shifted[:, np.arange(nx), np.arange(nx)] += FD_STEP
        _, s_q, s_v, s_m = self.derivatives_at(
            shifted.reshape(n_int * nx, nx), np.repeat(tau, nx, axis=0))
        shifted_derivatives = np.concatenate([s_q, s_v, s_m], axis=2).reshape(
            n_int, nx, n, 3 * n)
        base = np.concatenate([d_q, d_v, minv], axis=2)[:, None]
        return (shifted_derivatives - base) / FD_STEP

    # Spheres -------------------------------------------------------------------------------
    def clearances(self, qs):
        """Constraints g (K, S * O + P) at configurations qs (K, n)."""
        return self.clearance_terms(qs, gradients=False)[0]

    def clearance_terms(self, qs, weights=None, gradients=True):
        """
        (g (K, S * O + P), dg/dq, curvature (K, n, n) of sum_p weights_p g_p or None).

        Rows: sphere-obstacle pairs (sphere-major), then self-collision pairs; each row is
        (d^2 - R^2) / (2 R).  One compiled call (kernels.sphere_rows): kinematics, rows,
        gradients and the exact curvature (J^T J terms and the centres' second derivatives).
        """
        count, n = qs.shape
        if not self.n_pairs:
            return np.zeros((count, 0)), np.zeros((count, 0, n)), None
        qs = np.ascontiguousarray(qs, dtype=float)
        level = 0 if not gradients else (1 if weights is None else 2)
        values = np.empty((count, self.n_pairs))
        grads = np.empty((count, self.n_pairs, n) if level else (0, 0, 0))
        curvature = np.empty((count, n, n) if level == 2 else (0, 0, 0))
        w = (np.ascontiguousarray(weights, dtype=float) if level == 2
             else np.zeros((0, 0)))
        spheres = self.spheres
        kernels.sphere_rows(qs, *spheres.chain, spheres.joint_ids, spheres.joint_offsets,
                            spheres.support, self.obstacles, self.radius, self.pairs,
                            self.pair_radius, w, level, values, grads, curvature)
        return values, (grads if level else None), (curvature if level == 2 else None)
