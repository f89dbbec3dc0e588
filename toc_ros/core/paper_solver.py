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
Paper mode: the section-3 minimum-time heuristic exactly as the paper states it.

Gradient descent with constant learning rate eta on u (eq. 32) with the BPTT gradient of
J_T = J1 + J2 + J3 (eq. 33; J2 uses the constant K_V-hat = tau0 K_V), and after every
iteration tau(l+1) = tau(l) - d_tau H-(J_T(tau(l)) - J_eps) (eq. 34).  The paper's obstacle
gradient is the shortcut eq. (46) by default.  t_min is read off as N tau at the last iteration
that met J_T < J_eps ("tau_min ~ tau(l-1)"), and the controls of that iteration are returned with
their measured (re-integrated) violations.  No step size adaptation, no projection: this is the
reference behaviour to compare the fast mode with, not a feasibility guarantee.
"""

from numba import njit
import numpy as np

from .bptt import paper_cost_gradient, Workspace

# Iterations run between the driver's checks for cancel, timeout and progress: ~25 ms of them.
CHUNK_SECONDS = 0.025
MAX_CHUNK = 5000


def next_chunk(per_iteration):
    """Return how many iterations take about CHUNK_SECONDS at per_iteration seconds each."""
    return max(1, min(MAX_CHUNK, int(CHUNK_SECONDS / max(per_iteration, 1e-7))))


# nogil: a chunk runs for ~CHUNK_SECONDS of CPU (longer in wall time on a loaded machine);
# without the GIL the node's executor thread (progress heartbeat, parameters, ~/cancel) runs
# beside it instead of waiting for the chunk's end.
@njit(cache=True, nogil=True)
def paper_iterations(n_iter, x0, x_goal, controls, tau, p, method, u_max, circles, k_b,
                     k_v_hat, k_p_hat, grad_mode, eta, d_tau, j_eps, best_controls, best_tau,
                     best_cost, accepted, hist_tf, hist_j, hist_start, states, jac_x, jac_u,
                     jac_tau, grad_x, grad_u, out_grad_u):
    """
    Run n_iter iterations of eqs. (28)-(34) in place; returns the last J_T.

    One-element arrays updated in place: tau[0] the current tau; best_tau[0], best_cost[0] the
    tau and J_T of the last accepted iteration (J_T < J_eps), whose controls are copied to
    best_controls; accepted[0] (integer) how many iterations were accepted.  hist_* receive t_f
    and J_T per iteration.
    """
    n = controls.shape[0]
    j_total = np.inf
    for it in range(n_iter):
        tau_now = tau[0]
        j1, j2, j3, _ = paper_cost_gradient(x0, x_goal, controls, tau_now, p, method, u_max,
                                            circles, k_b, k_v_hat, k_p_hat, grad_mode, states,
                                            jac_x, jac_u, jac_tau, grad_x, grad_u, out_grad_u)
        j_total = j1 + j2 + j3
        if not np.isfinite(j_total):
            return j_total, it   # diverged (eta too large for this N): the driver reports it
        hist_tf[hist_start + it] = n * tau_now
        hist_j[hist_start + it] = j_total
        if j_total < j_eps:
            best_controls[:, :] = controls
            best_tau[0] = tau_now
            best_cost[0] = j_total
            accepted[0] += 1
            if tau_now - d_tau > 0.0:
                tau[0] = tau_now - d_tau
        for i in range(n):
            controls[i, 0] -= eta * out_grad_u[i, 0]
            controls[i, 1] -= eta * out_grad_u[i, 1]
    return j_total, n_iter


class PaperRun:
    """State of a paper-mode solve, advanced in chunks by the driver (solver.py)."""

    def __init__(self, problem, options, method):
        n = problem.n_intervals
        po = options.paper
        self.problem = problem
        self.po = po
        self.method = method
        self.p, self.x0, self.x_goal, self.u_max, self.circles = problem.kernel_arrays()
        self.tau0 = problem.t_f0 / n
        self.k_v_hat = self.tau0 * po.k_v
        self.k_p_hat = self.tau0 * po.k_p
        self.controls = np.zeros((n, 2))            # u(0) = 0, section 4
        self.tau = np.array([self.tau0])
        self.best_controls = np.zeros((n, 2))
        self.best_tau = np.array([np.nan])
        self.best_cost = np.array([np.inf])
        self.accepted = np.zeros(1, dtype=np.int64)
        self.hist_tf = np.zeros(options.iteration_limit())
        self.hist_j = np.zeros(options.iteration_limit())
        self.ws = Workspace(n)
        self.done = 0
        self.last_j = np.inf

    def advance(self, n_iter):
        """Run n_iter more iterations."""
        ws = self.ws
        po = self.po
        self.last_j, ran = paper_iterations(
            n_iter, self.x0, self.x_goal, self.controls, self.tau, self.p, self.method,
            self.u_max, self.circles, po.k_b, self.k_v_hat, self.k_p_hat, po.grad_mode(), po.eta,
            po.d_tau, po.j_eps, self.best_controls, self.best_tau, self.best_cost, self.accepted,
            self.hist_tf, self.hist_j,
            self.done, ws.states, ws.jac_x, ws.jac_u, ws.jac_tau, ws.grad_x, ws.grad_u,
            ws.out_grad_u)
        self.done += ran

    @property
    def t_f(self):
        """Return the current final time N tau [s]."""
        return self.problem.n_intervals * self.tau[0]

    @property
    def best_t_f(self):
        """Return t_f of the last accepted iteration (nan before the first)."""
        return self.problem.n_intervals * self.best_tau[0]

    def history(self):
        """Rows of result.HISTORY_COLUMNS: iteration, t_f, J_T, nan (no separate measure)."""
        it = np.arange(self.done, dtype=float)
        return np.column_stack([it, self.hist_tf[:self.done], self.hist_j[:self.done],
                                np.full(self.done, np.nan)])
