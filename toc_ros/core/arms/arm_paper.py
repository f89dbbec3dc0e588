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
Paper mode for URDF arms: the section-3 heuristic (eqs. 6-34) on an arm, in joint accelerations.

The method is the paper's: gradient descent with a constant learning rate on the controls
(eq. 15) with the BPTT gradient (eqs. 16-31) of J_T = J1 + J2 + J3, and tau(l+1) = tau(l) -
d_tau H-(J_T - J_eps) after every iteration (eq. 34); t_min is N tau of the last iteration
with J_T < J_eps, whose controls are returned.  What differs from the planar paper mode:

* The controls of the descent are the joint accelerations a_k (piecewise constant), and the
  torques are RNEA(q_k, v_k, a_k).  Under explicit Euler the step x_{k+1} = (q_k + tau v_k,
  v_k + tau a_k) is the arm's own Euler step under those torques (ABA(q, v, RNEA(q, v, a)) = a),
  so the returned torques reproduce the plan.  Why not the torques themselves: through an arm
  that gravity makes unstable in open loop the single-shooting gradient grows like
  exp(lambda t_f) (norms of 1e6-1e53 measured, benchmarks/arm_paper_sensitivity.py) and the
  descent diverges at any learning rate; in accelerations the rollout is a double integrator.
  RK4 steps have no such identity (the torques would vary within a step): refused.
* J1 is eq. (7) (K_B); J2 eq. (8) on the torque bounds |RNEA| <= effort with K_V-hat = tau0 K_V
  (the paper's control bounds); J3 the state constraints as the paper's obstacle penalty
  (eq. 42, K_p-hat = tau0 K_p): joint positions within their limits (nodes 0..N), velocities
  within theirs (nodes 1..N), and every sphere row of the fast mode (ArmEvaluator's clearance
  rows, obstacles and, when constrained, self-collision) at nodes 1..N.
* The learning rate: the planar eta = 1000 is its robot's (torques through a large inertia);
  here it is paper.arm_step / L, L the largest curvature of J1 in the accelerations at tau0
  (2 K_B times the largest eigenvalue of the Gram matrix of dq_N/da_k, dv_N/da_k), which falls
  with tau: the descent is stable for arm_step < 2 as far as J1 dominates the curvature.

The result's speed is the method's: thousands of iterations of about a millisecond, and a t_f
the heuristic reaches only slowly (benchmarks/RESULTS.md, "Paper mode for arms").
"""

import math
import time

import numpy as np
import pinocchio as pin

from ..paper_solver import next_chunk
from ..result import Progress, SolveResult, Status


def terminal_curvature(n_int, tau, k_b):
    """Return L, the largest eigenvalue of J1's Hessian in the accelerations at step tau."""
    k = np.arange(n_int)
    dq = tau * tau * (n_int - 1 - k)      # d q_N / d a_k of one joint
    dv = np.full(n_int, tau)              # d v_N / d a_k
    gram = np.array([[dq @ dq, dq @ dv], [dq @ dv, dv @ dv]])
    return 2.0 * k_b * float(np.linalg.eigvalsh(gram)[-1])


class ArmPaperRun:
    """State of a paper-mode arm solve: the accelerations, tau, the last accepted iterate."""

    def __init__(self, robot, evaluator, x0, x_goal, n_int, t_f0, paper):
        arm = robot.arm
        self.arm = arm
        self.evaluator = evaluator
        self.n = arm.n
        self.n_int = n_int
        self.x0 = np.asarray(x0, dtype=float)
        self.x_goal = np.asarray(x_goal, dtype=float)
        self.paper = paper
        self.tau0 = t_f0 / n_int
        self.k_v_hat = self.tau0 * paper.k_v
        self.k_p_hat = self.tau0 * paper.k_p
        self.eta = paper.arm_step / terminal_curvature(n_int, self.tau0, paper.k_b)
        self.data = arm.model.createData()
        # Joints without a position limit (continuous) have infinite bounds: no row.
        self.has_lower = np.isfinite(arm.lower)
        self.has_upper = np.isfinite(arm.upper)
        self.lower = np.where(self.has_lower, arm.lower, 0.0)
        self.upper = np.where(self.has_upper, arm.upper, 0.0)
        self.accelerations = np.zeros((n_int, self.n))     # u(0) = 0, as section 4
        self.tau = self.tau0
        self.best = None                  # (accelerations, tau, J_T) of the last accepted
        self.accepted = 0
        self.done = 0
        self.last_j = math.inf
        self.hist_tf = []     # (grown per iteration: an iteration limit may be huge)
        self.hist_j = []

    # The model ------------------------------------------------------------------------------
    def rollout(self, accelerations, tau):
        """Return q, v (N + 1, n): the Euler double integrator from x0."""
        n = self.n
        q0, v0 = self.x0[:n], self.x0[n:]
        v = np.vstack([v0, v0 + tau * np.cumsum(accelerations, axis=0)])
        q = np.vstack([q0, q0 + tau * np.cumsum(v[:-1], axis=0)])
        return q, v

    def torques(self, q, v, accelerations):
        """Return RNEA(q_k, v_k, a_k) for k = 0..N-1, (N, n)."""
        model, data = self.arm.model, self.data
        return np.array([pin.rnea(model, data, q[k], v[k], accelerations[k])
                         for k in range(self.n_int)])

    def cost_gradient(self, accelerations, tau):
        """Return (J1, J2, J3, dJ_T/da (N, n)) by the backward recursion of eqs. (24)-(31)."""
        n, n_int, p = self.n, self.n_int, self.paper
        q, v = self.rollout(accelerations, tau)
        g_q = np.zeros((n_int + 1, n))    # partial derivatives of J_T in each node's state
        g_v = np.zeros((n_int + 1, n))
        g_a = np.zeros((n_int, n))
        # J2: torque bounds (derivatives only where a bound is exceeded: elsewhere zero).
        model, data, effort = self.arm.model, self.data, self.arm.effort
        j2 = 0.0
        for k in range(n_int):
            torque = pin.rnea(model, data, q[k], v[k], accelerations[k])
            excess = np.abs(torque) - effort
            if np.any(excess > 0.0):
                excess = np.maximum(excess, 0.0)
                j2 += self.k_v_hat * float(excess @ excess)
                weight = 2.0 * self.k_v_hat * excess * np.sign(torque)
                d_q, d_v, d_a = pin.computeRNEADerivatives(model, data, q[k], v[k],
                                                           accelerations[k])
                # Pinocchio fills the mass matrix (d tau / d a) in its upper triangle only.
                d_a = np.triu(d_a) + np.triu(d_a, 1).T
                g_q[k] += weight @ d_q
                g_v[k] += weight @ d_v
                g_a[k] += weight @ d_a
        # J3: positions (every node), velocities and sphere rows (nodes 1..N).
        kp = self.k_p_hat
        above = np.where(self.has_upper, np.maximum(q - self.upper, 0.0), 0.0)
        below = np.where(self.has_lower, np.maximum(self.lower - q, 0.0), 0.0)
        j3 = kp * float(np.sum(above ** 2) + np.sum(below ** 2))
        g_q += 2.0 * kp * (above - below)
        fast = np.maximum(np.abs(v[1:]) - self.arm.velocity, 0.0)
        j3 += kp * float(np.sum(fast ** 2))
        g_v[1:] += 2.0 * kp * fast * np.sign(v[1:])
        if self.evaluator.n_pairs:
            rows, d_rows, _ = self.evaluator.clearance_terms(q[1:])
            inside = np.minimum(rows, 0.0)
            j3 += kp * float(np.sum(inside ** 2))
            g_q[1:] += 2.0 * kp * np.einsum('kp,kpn->kn', inside, d_rows)
        # J1, eq. (7).
        miss_q, miss_v = q[-1] - self.x_goal[:n], v[-1] - self.x_goal[n:]
        j1 = p.k_b * float(miss_q @ miss_q + miss_v @ miss_v)
        g_q[-1] += 2.0 * p.k_b * miss_q
        g_v[-1] += 2.0 * p.k_b * miss_v
        # Adjoints of q_{k+1} = q_k + tau v_k, v_{k+1} = v_k + tau a_k, from node N back.
        lam_q = np.cumsum(g_q[::-1], axis=0)[::-1]
        lam_q_next = np.vstack([lam_q[1:], np.zeros((1, n))])
        lam_v = np.cumsum((g_v + tau * lam_q_next)[::-1], axis=0)[::-1]
        return j1, j2, j3, g_a + tau * lam_v[1:]

    # The heuristic --------------------------------------------------------------------------
    def advance(self, n_iter):
        """Run n_iter more iterations of eqs. (15) and (34); stop early when J_T is not finite."""
        p = self.paper
        for _ in range(n_iter):
            with np.errstate(over='ignore', invalid='ignore'):     # (divergence: reported)
                j1, j2, j3, grad = self.cost_gradient(self.accelerations, self.tau)
            j_total = j1 + j2 + j3
            self.last_j = j_total
            if not math.isfinite(j_total):
                return
            self.hist_tf.append(self.n_int * self.tau)
            self.hist_j.append(j_total)
            self.done += 1
            if j_total < p.j_eps:
                self.best = (self.accelerations.copy(), self.tau, j_total)
                self.accepted += 1
                if self.tau - p.d_tau > 0.0:
                    self.tau -= p.d_tau
            self.accelerations -= self.eta * grad

    @property
    def t_f(self):
        """Return the current final time N tau [s]."""
        return self.n_int * self.tau

    @property
    def best_t_f(self):
        """Return t_f of the last accepted iteration (nan before the first)."""
        return math.nan if self.best is None else self.n_int * self.best[1]

    def plan(self):
        """(torques (N, n), t_f) of the last accepted iterate, else of the current one."""
        accelerations, tau = ((self.accelerations, self.tau) if self.best is None
                              else self.best[:2])
        q, v = self.rollout(accelerations, tau)
        return self.torques(q, v, accelerations), self.n_int * tau

    def history(self):
        """Rows of result.HISTORY_COLUMNS: iteration, t_f, J_T, nan (no separate measure)."""
        done = self.done
        return np.column_stack([np.arange(done, dtype=float), np.array(self.hist_tf),
                                np.array(self.hist_j), np.full(done, np.nan)])


def solve_arm_paper(problem, options, robot, evaluator, x0, x_goal, should_stop, stop_reason,
                    progress, measure):
    """
    Run the heuristic to its iteration limit (or a stop); return the SolveResult.

    measure(torques, t_f) -> (states, ArmViolations) re-integrates with pinocchio.aba;
    stop_reason() names the Status of a stop that should_stop() reported.
    """
    limit = options.iteration_limit()
    run = ArmPaperRun(robot, evaluator, x0, x_goal, problem.n_intervals, problem.t_f0,
                      options.paper)
    started = time.monotonic()
    last_report = -math.inf
    chunk = 1
    stopped = None
    while run.done < limit:
        if should_stop():
            stopped = stop_reason()
            break
        t0 = time.monotonic()
        before = run.done
        run.advance(min(chunk, limit - run.done))
        if not math.isfinite(run.last_j):
            break
        chunk = next_chunk((time.monotonic() - t0) / max(run.done - before, 1))
        now = time.monotonic()
        if progress is not None and now - last_report >= 0.5 * options.progress_period:
            last_report = now
            progress(Progress(run.done, run.t_f, run.last_j, run.best_t_f, now - started,
                              'paper'))
    history = run.history()
    common = {'mode': 'paper', 'integrator': problem.integrator,
              'n_intervals': problem.n_intervals, 'iterations': run.done, 'history': history,
              'solver_state': {'learning_rate': run.eta, 'accepted': run.accepted}}
    if run.best is None and not math.isfinite(run.last_j):
        return SolveResult(status=Status.STALLED, message=(
            f'diverged (J_T not finite) after {run.done} iterations from t_f0 = '
            f'{problem.t_f0} s: the penalties outgrew the terminal curvature that sets the '
            f'learning rate; a smaller paper.arm_step (now {options.paper.arm_step}) or a t_f0 '
            "nearer the motion's time may help"), **common)
    torques, t_f = run.plan()
    with np.errstate(all='ignore'):
        states, violations = measure(torques, t_f)
    if not (np.all(np.isfinite(torques)) and np.all(np.isfinite(states))):
        return SolveResult(status=Status.STALLED, message=(
            f'the plan of {run.done} iterations (t_f = {t_f:.6g} s) does not integrate: its '
            "torques, integrated again with the arm's dynamics, leave the numbers (an "
            'open-loop unstable arm over a long horizon)'), **common)
    if stopped is not None:
        status, message = stopped, f'{stopped.value.lower()} after {run.done} iterations'
    elif run.best is None:
        status = Status.MAX_ITERATIONS
        message = (f'J_T never fell below J_eps = {options.paper.j_eps} in {run.done} '
                   f'iterations (t_f0 = {problem.t_f0} s may be below what the arm can do, '
                   'or the iterations too few to reach the goal)')
    elif violations.feasible():
        status = Status.SOLVED
        message = f't_min = {t_f:.6f} s, feasible within tolerances'
    else:
        status = Status.SOLVED_INACCURATE
        message = (f'paper heuristic t_min = {t_f:.6f} s with residual violations (penalties, '
                   'not constraints): ' + ', '.join(violations.exceeded()))
    result = SolveResult(status=status, message=message, final_time=float(t_f),
                         states=states, controls=torques, violations=violations,
                         cost=float(run.last_j if run.best is None else run.best[2]), **common)
    result.time_grid = np.linspace(0.0, t_f, problem.n_intervals + 1)
    return result
