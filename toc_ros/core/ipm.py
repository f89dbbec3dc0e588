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

The parts, each a module of numba kernels on one Workspace (ipm_workspace.py): the evaluation
of derivatives, stage blocks and residuals (ipm_evaluation.py), the Newton step (riccati.py),
the step length (ipm_linesearch.py).  This module is the iteration driver: inertia correction,
barrier and elastic-weight updates, termination.  The kernels take the model's pointwise kernels
as arguments and are bound per model in the model modules (models/cylindrical.py).
"""

import math

from numba import njit
import numpy as np

from .ipm_evaluation import barrier_terms, derivative_terms
from .ipm_linesearch import accept_trial, add_to_filter, filter_line_search, \
    fraction_to_boundary, MAX_BACKTRACKS, t_bound_dual_limit, trial_merit
from .ipm_workspace import F_ALPHA, F_ALPHA_DUAL, F_CONSTR_TOL, F_DELTA, F_DT, F_ELASTIC, \
    F_ELASTIC_MAX, F_ERR, F_ERR_MU, F_MU, F_MU_MIN, F_PHI, F_PRIMAL_INF, F_T, F_THETA, \
    F_THETA_MAX, F_THETA_MIN, F_TOL, H_ALPHA, H_DELTA, H_ERR, H_MU, H_T, H_THETA, I_ACCEPTABLE, \
    I_ITER, I_LS_FAILS, I_MAX_ITER, I_N, I_N_FILTER, I_REG_TRIES, I_STOP
from .riccati import factorize, newton_step, recover_bound_steps

# Return codes of iterate().
CONTINUE = 0
CONVERGED = 1
ITERATION_LIMIT = 2
LINE_SEARCH_FAILED = 3
NUMERICAL_FAILURE = 4
STOPPED = 5          # iscal[I_STOP] was set

# Consecutive line-search failures before iterate() gives up.
MAX_LS_FAILS = 8
# Acceptable termination (IPOPT's acceptable_tol / acceptable_iter, with the full constraint
# tolerance): see iterate().
ACCEPT_TOL = 1e-6
ACCEPT_ITERATIONS = 10
# Monotone barrier update mu <- min(KAPPA_MU mu, mu^THETA_MU) once E_mu <= KAPPA_EPS mu.
KAPPA_MU = 0.2
THETA_MU = 1.5
KAPPA_EPS = 10.0
# Upper limit of the elastic weight rho.
ELASTIC_MAX = 1e8


@njit
def evaluate(rhs, rhs_jac, rhs_hess, segments, ws):
    """
    Compute the derivatives, Newton stage blocks and residuals at the current point.

    This is derivative_terms + barrier_terms.  Returns False when a value is not finite.
    """
    derivative_terms(rhs_jac, rhs_hess, segments, ws)
    return barrier_terms(ws)


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
        alpha_dual = t_bound_dual_limit(ws, dt, frac, alpha_dual)
        theta0 = fs[F_THETA]
        phi0 = fs[F_PHI]
        alpha, accepted, f_type = filter_line_search(rhs, segments, ws, dt, alpha_max)
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
                add_to_filter(ws, (1.0 - 1e-5) * theta0, phi0 - 1e-8 * theta0)
        accept_trial(ws, alpha, alpha_dual, dt)
        fs[F_ALPHA] = alpha
        fs[F_ALPHA_DUAL] = alpha_dual
        fs[F_DT] = dt
        if k < ws.hist.shape[0]:
            ws.hist[k, H_ALPHA] = alpha
            ws.hist[k, H_DELTA] = fs[F_DELTA]
        it[I_ITER] += 1
    return CONTINUE
