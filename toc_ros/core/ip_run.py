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
One interior-point solve on one grid (ipm_workspace.py, ipm.py's kernels) and how it is driven.

InteriorPointRun holds a Workspace, sets its primal-dual starting point and runs the kernel
in chunks between which the caller checks progress, cancel and timeout; a shared watcher
thread stops a running kernel within one phase of an iteration.  The strategy that decides
which runs to make is fast_solver.py's.
"""

import os
import threading
import time

import numpy as np

from . import ipm
from .barrier_start import crowding_share
from .ipm_workspace import F_CONSTR_TOL, F_DELTA, F_ELASTIC, F_MU, F_MU_MIN, F_RHO, F_T, \
    F_T_HIGH, F_T_LOW, F_T_REF, F_THETA_MAX, F_TOL, F_ZT_HIGH, F_ZT_LOW, H_T, H_THETA, \
    I_ACCEPTABLE, I_ITER, I_LS_FAILS, I_MAX_ITER, I_METHOD, I_N, I_N_FILTER, I_STOP, \
    make_workspace
from .obstacles import segment_clearance

# Tolerances: IPOPT's scaled optimality error, and the unscaled constraint violation (well
# inside the SOLVED tolerances of result.py, so the re-integrated trajectory passes them).
TOL = 1e-8
CONSTR_TOL = 1e-10
MU_MIN = 1e-11
# Interior push of the initial controls and slacks (IPOPT's bound_push).
BOUND_PUSH = 1e-2
# Weight of the terminal augmentation 1/2 rho |dx(N) + x(N) - x_goal|^2 (ipm_evaluation.py).
RHO_TERMINAL = 1e2
# Initial l1 weight of the obstacle constraints' elastic variables.  The kernel raises it
# (x10) when a multiplier nears it at a solution of the barrier problem, so it ends above every
# obstacle multiplier and the elastic variables vanish; a small start keeps the Lagrangian's
# curvature -rho grad^2 c moderate while the iterates still cross an obstacle.  A warm start
# with multipliers uses the weight its solution ended with.
ELASTIC_WEIGHT = 1.0
# [s] period at which the stop watcher polls cancel and the deadline during a kernel call.
STOP_POLL = 0.005
# Box on t_f [s].
T_LOW = 1e-3
T_HIGH_FACTOR = 100.0


class Stop(Exception):
    """Raised between iteration chunks to stop a solve (argument: the Status)."""


class Cancelled(Exception):
    """Raised in a prefetched task that is no longer wanted (prefetch.Prefetch)."""


class InteriorPointRun:
    """One interior-point solve on one grid (the Workspace plus the driver state)."""

    def __init__(self, problem, n, max_iter, elastic=None, kept=None):
        model = problem.robot_model
        self.problem = problem
        # Indices of the solve's circles this run has (a relaxation, _lazy_classes); None: all.
        self.kept = kept
        self.path = None         # the class path it started from (_class_attempts)
        self.model = model
        self.kernels = model.kernels
        self.n = n
        self.u_max = np.asarray(model.u_max, dtype=float)
        self.circles = np.ascontiguousarray(problem.circles())
        self.ws = make_workspace(n, model.nx, model.nu, model.n_links, self.circles,
                                 model.packed(), problem.x0, problem.x_goal, self.u_max,
                                 max_iter, nq=model.n_joints)
        fs, it = self.ws.fscal, self.ws.iscal
        it[I_N] = n
        it[I_METHOD] = problem.integrator_id
        it[I_MAX_ITER] = max_iter
        fs[F_TOL] = TOL
        fs[F_CONSTR_TOL] = CONSTR_TOL
        fs[F_MU_MIN] = MU_MIN
        fs[F_RHO] = RHO_TERMINAL
        fs[F_T_LOW] = T_LOW
        fs[F_T_REF] = max(problem.t_f0, 1e-3)
        fs[F_ELASTIC] = ELASTIC_WEIGHT if elastic is None else elastic
        fs[F_T_HIGH] = T_HIGH_FACTOR * max(problem.t_f0, 1.0)

    # Starting points ---------------------------------------------------------------------
    def start(self, states, controls, t_f, mu, duals=None, push=BOUND_PUSH):
        """
        Set the primal point and the duals.

        The primal point (states (N+1, nx), controls (N, nu), t_f) is pushed inside the
        bounds by push; the duals are given ones (a dict as from duals(), resampled) or
        mu / slack.  With duals, each slack is at least mu / z (complementarity mu).
        """
        ws = self.ws
        fs = ws.fscal
        t_f = float(np.clip(t_f, fs[F_T_LOW] * 10.0, fs[F_T_HIGH] / 10.0))
        if duals is None:
            # Barrier terms: the controls' bounds, a slack and an elastic per circle row
            # (barrier_start.py: 50 circles off the paper robot's motion stalled).
            mu *= crowding_share(2 * ws.v.size, 2 * ws.s[1:].size)
        ws.x[:] = states
        ws.x[0] = ws.x0
        ws.v[:] = np.clip(np.asarray(controls) / self.u_max, -1.0 + push, 1.0 - push)
        fs[F_T] = t_f
        fs[F_MU] = mu
        cons = self.constraint_values(ws.x)
        rho = fs[F_ELASTIC]
        # Obstacle constraints in elastic form c + e - s = 0: e absorbs what the start lacks.
        ws.s[0] = ws.e[0] = 1.0
        ws.z[0] = 0.5 * rho
        e_push = push if duals is None else max(mu, 1e-8)
        ws.e[1:] = np.maximum(e_push, e_push - cons)
        if duals is None:
            ws.s[1:] = np.maximum(cons + ws.e[1:], push)
            ws.lam[:] = 0.0
            ws.nu[:] = 0.0
            ws.z[1:] = np.clip(mu / ws.s[1:], 1e-6 * rho, 0.5 * rho)
        else:
            # Active constraints of the guess (z > 0) get slack mu / z; the others keep c.
            z = np.clip(duals['z'], mu, 0.5 * rho)
            ws.s[1:] = np.maximum(cons + ws.e[1:], np.minimum(mu / z, push))
            ws.z[1:] = np.clip(mu / ws.s[1:], 1e-6 * rho, 0.5 * rho)
            ws.lam[:] = duals['lam']
            ws.nu[:] = duals['nu']
        ws.zl[:] = mu / (1.0 + ws.v)
        ws.zu[:] = mu / (1.0 - ws.v)
        if duals is not None and 'zl' in duals:
            # Bound duals of the guess: they carry which controls sit on a bound.
            ws.zl[:] = np.maximum(duals['zl'], ws.zl)
            ws.zu[:] = np.maximum(duals['zu'], ws.zu)
        fs[F_ZT_LOW] = mu / (t_f - fs[F_T_LOW])
        fs[F_ZT_HIGH] = mu / (fs[F_T_HIGH] - t_f)
        fs[F_DELTA] = 0.0
        fs[F_THETA_MAX] = 0.0
        ws.iscal[I_N_FILTER] = 0
        ws.iscal[I_LS_FAILS] = 0
        ws.iscal[I_ACCEPTABLE] = 0
        ws.iscal[I_ITER] = 0

    def constraint_values(self, states):
        """Obstacle constraints c = (d^2 - R^2) / (2 R) at nodes 1..N, (N, L K)."""
        if self.circles.shape[0] == 0:
            return np.zeros((states.shape[0] - 1, 0))
        seg = self.model.link_segments(self.model.positions(states[1:]))
        return segment_clearance(seg, self.circles, squared=True)

    def duals(self):
        """Copy of the multipliers (for a warm start of another run)."""
        ws = self.ws
        return {'lam': ws.lam.copy(), 'nu': ws.nu.copy(), 'z': ws.z[1:].copy(),
                'zl': ws.zl.copy(), 'zu': ws.zu.copy(),
                'rho': float(ws.fscal[F_ELASTIC])}

    # Results -----------------------------------------------------------------------------
    @property
    def t_f(self):
        """Return the current final time [s]."""
        return float(self.ws.fscal[F_T])

    @property
    def iterations(self):
        """Return the number of iterations done on this grid."""
        return int(self.ws.iscal[I_ITER])

    def controls(self):
        """Return the controls u (N, nu) of the current point."""
        return self.ws.v * self.u_max[None, :]

    def history(self):
        """Rows (t_f, constraint violation) per iteration."""
        k = min(self.iterations + 1, self.ws.hist.shape[0])
        return self.ws.hist[:k, [H_T, H_THETA]]

    # Driving -----------------------------------------------------------------------------
    def run(self, check, stop_requested=None):
        """
        Iterate until a stop code.

        check() runs between chunks of ~20 ms (progress, cancel, timeout: it raises Stop).
        While a chunk runs (the kernel releases the GIL), a watcher thread sets the kernel's
        stop flag as soon as stop_requested() is true, so a stop is honoured within one phase
        of an iteration even on long horizons.  Returns the ipm code.
        """
        chunk = 1
        if stop_requested is not None:
            _WATCHER.add(self.ws, stop_requested)
        try:
            while True:
                check(self)
                started = time.monotonic()
                code = self.kernels.ipm_iterate(self.ws, chunk)
                per_iteration = (time.monotonic() - started) / chunk
                chunk = int(max(1, min(50, 0.02 / max(per_iteration, 1e-6))))
                if code != ipm.CONTINUE:
                    check(self)
                    return code
        finally:
            if stop_requested is not None:
                _WATCHER.remove(self.ws)


class _StopWatcher:
    """
    One daemon thread that polls the stop requests of the running kernels every STOP_POLL.

    Shared by all solves: a thread per solve cost its start and join, several ms on a loaded
    machine (both wait until the scheduler runs the new thread).  It sleeps while no kernel
    runs.
    """

    def __init__(self):
        self._reset()
        # A forked child (e.g. a sweep worker) has neither the thread nor a usable lock.
        if hasattr(os, 'register_at_fork'):
            os.register_at_fork(after_in_child=self._reset)

    def _reset(self):
        self._cond = threading.Condition()
        self._active = {}
        self._thread = None

    def add(self, ws, stop_requested):
        with self._cond:
            self._active[id(ws)] = (ws, stop_requested)
            if self._thread is None or not self._thread.is_alive():
                self._thread = threading.Thread(target=self._watch, name='toc_ros-stop-watch',
                                                daemon=True)
                self._thread.start()
            self._cond.notify()

    def remove(self, ws):
        with self._cond:
            self._active.pop(id(ws), None)

    def _watch(self):
        with self._cond:
            while True:
                if not self._active:
                    self._cond.wait()
                    continue
                for key, (ws, stop_requested) in list(self._active.items()):
                    if stop_requested():
                        ws.iscal[I_STOP] = 1
                        del self._active[key]
                self._cond.wait(STOP_POLL)


_WATCHER = _StopWatcher()
