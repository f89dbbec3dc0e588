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
Fast mode: the discrete minimum-time problem solved by the interior-point method of ipm.py.

This is the problem of eqs. (1)-(5) (J0 = N tau = t_f) with the constraints kept as
constraints:

    minimise t_f  over  x(1..N), u(0..N-1), t_f
    s.t.  x(i+1) = Phi(x(i), u(i), t_f / N)          (eq. 2, multiple shooting)
          x(N) = x_goal                               (eq. 3)
          |u_k(i)| <= u_k,max                         (eq. 47)
          dist(link segment at node i, c_k) >= R_k    (eq. 41 for every link, any quadrant)

A cold solve first runs on a coarse grid (COARSE_INTERVALS), whose solution (primal and dual)
is carried to the requested grid through intermediate grids (ladder), where a few Newton-type
iterations finish.  When the straight start crosses an obstacle of a two-joint model, one start
per homotopy class (homotopy.py) is solved instead, on EXPLORE_INTERVALS, side by side on two
threads (workers.py); a candidate's climb up the ladder starts as soon as its attempt converges
(_Prefetch), with the same result as after all attempts.  With several circles they are
added lazily (_lazy_classes): first none, then the classes of the circles that solution hits.
A warm start (initial_guess: a previous SolveResult, or controls and t_f, e.g. the remainder of
the plan being executed) skips the coarse grid.
"""

import dataclasses
import math
import os
import threading
import time

import numpy as np

from . import homotopy, ipm, workers
from .result import SolveResult, Status

# Grids: a cold solve on N > 2 COARSE_INTERVALS starts on COARSE_INTERVALS intervals.
COARSE_INTERVALS = 100
# Barrier parameter of the first cold attempt (IPOPT's default 0.1 led into poorer local optima
# more often: planar_2r with circles, the demo scenario), and of a warm start on N intervals:
# MU_WARM / N, since the bound multipliers of the discrete problem scale with tau = t_f / N.
MU_COLD = 0.01
# Further cold starts of the N grid after a failure, with these barrier parameters.
MU_COLD_RETRIES = (0.01, 1.0)
MU_WARM = 1e-5
# ... and of a warm start whose first state the robot has drifted from (a replan cycle):
# MU_DRIFT / N, re-centred more than a refinement's.  Over 38 perturbed cycle starts of the
# paper scenario (150 intervals) 1e-4 needed no cold fallback where 1e-5 needed 2-9, and on
# the actuated model 26 instead of 35 iterations (median).
MU_DRIFT = 1e-4
# Tolerances: IPOPT's scaled optimality error, and the unscaled constraint violation (well
# inside the SOLVED tolerances of result.py, so the re-integrated trajectory passes them).
TOL = 1e-8
CONSTR_TOL = 1e-10
MU_MIN = 1e-11
# Interior push of the initial controls and slacks (IPOPT's bound_push); a warm start keeps
# the controls of the guess on their bounds (within WARM_PUSH).
BOUND_PUSH = 1e-2
WARM_PUSH = 1e-6
# A warm start whose first state lies within WARM_EXACT of the start uses MU_EXACT.
WARM_EXACT = 1e-6
MU_EXACT = 1e-10
# Iterations a warm start may take before fast mode solves from scratch instead.
WARM_BUDGET = 60
# Weight of the terminal augmentation 1/2 rho |dx(N) + x(N) - x_goal|^2 (see ipm.py).
RHO_TERMINAL = 1e2
# Initial l1 weight of the obstacle constraints' elastic variables.  The kernel raises it
# (x10) when a multiplier nears it at a solution of the barrier problem, so it ends above every
# obstacle multiplier and the elastic variables vanish; a small start keeps the Lagrangian's
# curvature -rho grad^2 c moderate while the iterates still cross an obstacle.  A warm start
# with multipliers uses the weight its solution ended with.
ELASTIC_WEIGHT = 1.0
# Cold-start attempts (elastic weight, initial barrier parameter), all from the same cold
# start: the first always; the others when the problem has obstacles and the first did not
# converge on the coarse grid or needed the inertia correction on more than EXPLORE_NONCONVEX
# of its iterations there (other weights and barrier parameters lead around the obstacles
# other ways, into other local optima; see FastSolve._explore).
COLD_ATTEMPTS = ((ELASTIC_WEIGHT, MU_COLD), (0.3, 1.0), (1.0, 0.1), (10.0, 0.01), (0.1, 0.1),
                 (1.0, 1e-3), (100.0, 1.0), (0.03, 0.1))
EXPLORE_NONCONVEX = 20
# (Elastic weight, initial barrier parameter) of the attempt from each class start of
# homotopy.py (near collision-free starts, one per homotopy class of a two-joint configuration
# space), tried instead of the interpolation start when that crosses an obstacle.  The first
# cold attempt's pair: on the 12 planar_2r scenarios of bench_planar_2r.py it reached the best
# known optimum from some class start in every one (so did mu0 = 1.0, at more iterations).
CLASS_ATTEMPT = (ELASTIC_WEIGHT, MU_COLD)
# Fraction of a solve's timeout after which no further cold attempt starts.
EXPLORE_TIME = 0.25
# Converged coarse optima within REFINE_BAND of the shortest (scaled by COARSE_INTERVALS / their
# grid: the discretisation error ~ 1 / intervals) are refined (at most MAX_REFINE distinct
# ones); the shortest refined one is the result (_finish).
REFINE_BAND = 0.02
MAX_REFINE = 3
# Grid of the cold attempts from the class starts (when the coarse grid is not the N grid):
# half the cost per iteration and fewer iterations than on COARSE_INTERVALS, the same optima
# after refinement on planar_2r (with mu0 = 0.01 on 100 intervals two of them were missed).
EXPLORE_INTERVALS = 50
# A lazy solve's candidates (_lazy_classes) climb without the circles they stay this far [m]
# from (segment clearance, at every node of the coarse run): fewer constraints per node on the
# ladder and the N grid; a climb that comes closer is checked and redone as a relaxed one.
NARROW_MARGIN = 0.05
# Refinement from the coarse grid to N intervals in steps of at most LADDER_RATIO (ladder()).
LADDER_RATIO = 4.0
# [s] period at which the stop watcher polls cancel and the deadline during a kernel call.
STOP_POLL = 0.005
# Box on t_f [s].
T_LOW = 1e-3
T_HIGH_FACTOR = 100.0
CODE_STATUS = {ipm.CONVERGED: Status.SOLVED, ipm.ITERATION_LIMIT: Status.MAX_ITERATIONS,
               ipm.LINE_SEARCH_FAILED: Status.STALLED, ipm.NUMERICAL_FAILURE: Status.STALLED}


class Stop(Exception):
    """Raised between iteration chunks to stop a solve (argument: the Status)."""


class _Cancelled(Exception):
    """Raised in a prefetched task that is no longer wanted (_Prefetch)."""


def _in_band(run, shortest):
    """Return whether a converged coarse run is within REFINE_BAND of the shortest t_f."""
    # The band scales with the discretisation error, ~ 1 / intervals.
    band = REFINE_BAND * COARSE_INTERVALS / min(run.n, COARSE_INTERVALS)
    return run.t_f <= (1.0 + band) * shortest


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
        self.ws = ipm.make_workspace(n, model.nx, model.nu, model.n_links, self.circles,
                                     model.packed(), problem.x0, problem.x_goal, self.u_max,
                                     max_iter, nq=model.n_joints)
        fs, it = self.ws.fscal, self.ws.iscal
        it[ipm.I_N] = n
        it[ipm.I_METHOD] = problem.integrator_id
        it[ipm.I_MAX_ITER] = max_iter
        fs[ipm.F_TOL] = TOL
        fs[ipm.F_CONSTR_TOL] = CONSTR_TOL
        fs[ipm.F_MU_MIN] = MU_MIN
        fs[ipm.F_RHO] = RHO_TERMINAL
        fs[ipm.F_T_LOW] = T_LOW
        fs[ipm.F_T_REF] = max(problem.t_f0, 1e-3)
        fs[ipm.F_ELASTIC] = ELASTIC_WEIGHT if elastic is None else elastic
        fs[ipm.F_T_HIGH] = T_HIGH_FACTOR * max(problem.t_f0, 1.0)

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
        t_f = float(np.clip(t_f, fs[ipm.F_T_LOW] * 10.0, fs[ipm.F_T_HIGH] / 10.0))
        ws.x[:] = states
        ws.x[0] = ws.x0
        ws.v[:] = np.clip(np.asarray(controls) / self.u_max, -1.0 + push, 1.0 - push)
        fs[ipm.F_T] = t_f
        fs[ipm.F_MU] = mu
        cons = self.constraint_values(ws.x)
        rho = fs[ipm.F_ELASTIC]
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
        fs[ipm.F_ZT_LOW] = mu / (t_f - fs[ipm.F_T_LOW])
        fs[ipm.F_ZT_HIGH] = mu / (fs[ipm.F_T_HIGH] - t_f)
        fs[ipm.F_DELTA] = 0.0
        fs[ipm.F_THETA_MAX] = 0.0
        ws.iscal[ipm.I_N_FILTER] = 0
        ws.iscal[ipm.I_LS_FAILS] = 0
        ws.iscal[ipm.I_ACCEPTABLE] = 0
        ws.iscal[ipm.I_ITER] = 0

    def constraint_values(self, states):
        """Obstacle constraints c = (d^2 - R^2) / (2 R) at nodes 1..N, (N, L K)."""
        if self.circles.shape[0] == 0:
            return np.zeros((states.shape[0] - 1, 0))
        seg = self.model.link_segments(self.model.positions(states[1:]))
        return homotopy.clearance(seg, self.circles, squared=True)

    def duals(self):
        """Copy of the multipliers (for a warm start of another run)."""
        ws = self.ws
        return {'lam': ws.lam.copy(), 'nu': ws.nu.copy(), 'z': ws.z[1:].copy(),
                'zl': ws.zl.copy(), 'zu': ws.zu.copy(),
                'rho': float(ws.fscal[ipm.F_ELASTIC])}

    # Results -----------------------------------------------------------------------------
    @property
    def t_f(self):
        """Return the current final time [s]."""
        return float(self.ws.fscal[ipm.F_T])

    @property
    def iterations(self):
        """Return the number of iterations done on this grid."""
        return int(self.ws.iscal[ipm.I_ITER])

    def controls(self):
        """Return the controls u (N, nu) of the current point."""
        return self.ws.v * self.u_max[None, :]

    def history(self):
        """Rows (t_f, constraint violation) per iteration."""
        k = min(self.iterations + 1, self.ws.hist.shape[0])
        return self.ws.hist[:k, [ipm.H_T, ipm.H_THETA]]

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
                        ws.iscal[ipm.I_STOP] = 1
                        del self._active[key]
                self._cond.wait(STOP_POLL)


_WATCHER = _StopWatcher()


class _Prefetch:
    """
    The class attempts of one FastSolve, with the climbs of their candidates started early.

    The calling thread and the workers.share helpers each take the next task when theirs ends
    (no hand-over through a waiting thread: a wake-up cost milliseconds on a loaded machine):
    first the climb of an attempt that is a candidate among the converged ones so far, then
    the refinement to N (refine) of the shortest climbed one so far, else the next attempt.  A
    task that later results put out (a shorter attempt, a shorter climb) is cancelled.
    """

    def __init__(self, solver, tasks, climb, refine, usable=None):
        self.solver = solver
        self.tasks = tasks
        self.climb = climb
        self.refine = refine
        # usable(run): whether a candidate can stand (a relaxation's: clear of the other
        # circles); while one cannot, _finish will not run (_lazy_classes): no climbs.
        self.usable = usable or (lambda run: True)
        self.verdicts = {}                       # id(attempt run) -> usable(run)
        self.finals = {}                         # id(climbed run) -> [runs, value, wanted]
        self.logs = [[] for _ in tasks]          # runs of the attempts, in task order
        self.all_logs = list(self.logs)          # and of the climbs (progress reports)
        self.results = {}                        # attempt index -> (run, code)
        self.climbs = {}                         # attempt index -> [runs, value or None, wanted]
        self.waiting = list(range(len(tasks)))   # attempts not started
        self.busy = 0                            # tasks running
        self.failure = None
        self.cond = threading.Condition()
        self.poll = solver._poller(self.all_logs)
        self.caller = threading.current_thread()       # reports progress

    def run(self):
        """
        Return (converged attempt runs in task order, prefetched).

        prefetched: {'climbs': {id(attempt run): (climb value, runs)}, 'finals': {id(climbed
        run): (refinement value, runs)}} for the final candidates and the best climbed one.
        """
        solver = self.solver
        try:
            workers.share(self._work)
        finally:
            logs = self.logs
            if self.failure is not None:    # stopped: keep the wanted runs for best-so-far
                logs = logs + [c[0] for c in self.climbs.values() if c[2]] + \
                    [f[0] for f in self.finals.values() if f[2]]
            for run in (run for log in logs for run in log):
                solver._record(run)
                solver.run = run
        if self.failure is not None:
            raise self.failure
        found = [self.results[k][0] for k in sorted(self.results)
                 if self.results[k][1] == ipm.CONVERGED]
        wanted = {id(run) for run in self._candidates()}
        climbs = {id(self.results[k][0]): (c[1], c[0]) for k, c in self.climbs.items()
                  if c[1] is not None and id(self.results[k][0]) in wanted}
        best = self._best_climbed()
        finals = {key: (f[1], f[0]) for key, f in self.finals.items()
                  if f[1] is not None and best is not None and key == id(best)}
        return found, {'climbs': climbs, 'finals': finals}

    def _work(self):
        """Run tasks until none is left and none can come (a thread's loop)."""
        caller = threading.current_thread() is self.caller
        while True:
            with self.cond:
                job = self._next()
                while job is None and self.busy and self.failure is None:
                    self.cond.wait(workers.POLL)
                    if caller:
                        self.poll()
                    job = self._next()
                if job is None:
                    return
                self.busy += 1
            key, task = job
            value, error = None, None
            try:
                value = task()
            except _Cancelled:
                key = None
            except BaseException as exc:        # Stop, or a bug: raised by run()
                error = exc
            with self.cond:
                self.busy -= 1
                if error is not None:
                    self.failure = self.failure or error
                elif key is not None:
                    self._finished(key, value)
                self.cond.notify_all()

    def _candidates(self):
        """_finish's candidates among the attempts converged so far."""
        return self.solver._candidates([self.results[k][0] for k in sorted(self.results)
                                        if self.results[k][1] == ipm.CONVERGED])

    def _next(self):
        """Return the next (key, task): a candidate's climb before an attempt; None if none."""
        if self.failure is not None:
            return None
        index = {id(self.results[k][0]): k for k in self.results}
        candidates = self._candidates()
        usable = all(self._usable(run) for run in candidates)
        for run in candidates if usable else []:
            k = index[id(run)]
            if k not in self.climbs:
                log = []
                self.all_logs.append(log)
                self.climbs[k] = [log, None, True]
                return ('climb', k), self.solver._bind(
                    lambda solve, run=run: self.climb(solve, run), log, self.poll,
                    cancelled=lambda c=self.climbs[k]: not c[2], caller=self.caller)
        best = self._best_climbed() if usable else None
        if best is not None and id(best) not in self.finals:
            log = []
            self.all_logs.append(log)
            self.finals[id(best)] = [log, None, True]
            return ('final', id(best)), self.solver._bind(
                lambda solve: self.refine(solve, best), log, self.poll,
                cancelled=lambda f=self.finals[id(best)]: not f[2], caller=self.caller)
        if self.waiting:
            k = self.waiting.pop(0)
            return ('attempt', k), self.solver._bind(self.tasks[k], self.logs[k], self.poll,
                                                     caller=self.caller)
        return None

    def _usable(self, run):
        if id(run) not in self.verdicts:
            self.verdicts[id(run)] = self.usable(run)
        return self.verdicts[id(run)]

    def _best_climbed(self):
        """Return the shortest converged climb of a candidate so far (None if none)."""
        climbs = [self.climbs.get(self._index(run)) for run in self._candidates()]
        ranked = [c[1][0] for c in climbs
                  if c is not None and c[1] is not None and c[1][1] == ipm.CONVERGED]
        return min(ranked, key=lambda r: r.t_f) if ranked else None

    def _index(self, run):
        return next(k for k in self.results if self.results[k][0] is run)

    def _finished(self, key, value):
        kind, k = key
        if kind == 'final':
            self.finals[k][1] = value
            return
        if kind == 'climb':
            self.climbs[k][1] = value
        else:
            self.results[k] = value
        # A later, shorter attempt may put earlier candidates out, a later climb the best one:
        # cancel their climbs and refinements.
        wanted = {id(run) for run in self._candidates()}
        for j, climb in self.climbs.items():
            if id(self.results[j][0]) not in wanted:
                climb[2] = False
        best = self._best_climbed()
        for key, final in self.finals.items():
            if best is None or key != id(best):
                final[2] = False


def interpolation_start(problem, n):
    """
    Return the cold starting point for n intervals over t_f0.

    Each joint moves from x0 to x_goal along a cubic in time (positions and velocities match
    both ends), and the controls are that motion's inverse dynamics clipped to the bounds
    (least squares through df/du; exact for models affine in u).  The same point is handed to
    the reference solvers in benchmarks/ so that all start alike.
    """
    t_f = float(problem.t_f0)
    return start_along(problem, interpolation_states(problem, n), t_f) + (t_f,)


def interpolation_states(problem, n):
    """Return the joint states (n + 1, 2 n) of interpolation_start (its controls cost more)."""
    model = problem.robot_model
    t_f = float(problem.t_f0)
    x0 = np.asarray(problem.x0, dtype=float)
    xg = np.asarray(problem.x_goal, dtype=float)
    q0, qg = model.positions(x0), model.positions(xg)
    v0, vg = model.velocities(x0) * t_f, model.velocities(xg) * t_f
    n_q = model.n_joints
    s = np.linspace(0.0, 1.0, n + 1)[:, None]
    # Cubic Hermite basis on s in [0, 1] (positions, and velocities scaled by t_f).
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, \
        s**3 - s**2
    d00, d10, d01, d11 = 6 * s**2 - 6 * s, 3 * s**2 - 4 * s + 1, -6 * s**2 + 6 * s, \
        3 * s**2 - 2 * s
    q = h00 * q0 + h10 * v0 + h01 * qg + h11 * vg
    dq = (d00 * q0 + d10 * v0 + d01 * qg + d11 * vg) / t_f
    states = np.empty((n + 1, 2 * n_q))
    states[:, 0::2] = q
    states[:, 1::2] = dq
    return states


def start_along(problem, joint_states, t_f):
    """
    Return (states, controls) of a start that moves the joints along joint_states over t_f.

    joint_states (n + 1, 2 n) from the start's to the goal's joints; the controls by
    controls_for the joints.  A model with actuator states (models/actuated.py) gets those
    controls as its applied torques (actuator_states) and as commands.
    """
    model = problem.robot_model
    joint = model.joint_model
    controls = controls_for(joint, joint_states, t_f)
    if not _has_actuators(model):
        return joint_states, controls
    return np.hstack([joint_states, actuator_states(problem, controls)]), controls


def actuator_states(problem, controls):
    """
    Actuator states (N + 1, n) that apply controls (N, n) (models/actuated.py).

    Each node's applied control is the command of the interval it starts (the lag as if
    instant); the first and last nodes keep the start's and the goal's.
    """
    model = problem.robot_model
    joints = model.joint_model.nx
    states = np.vstack([model.actuator_states(controls),
                        np.asarray(problem.x_goal, dtype=float)[None, joints:]])
    states[0] = np.asarray(problem.x0, dtype=float)[joints:]
    return states


def controls_for(model, states, t_f):
    """
    Return controls (n, nu) whose Euler steps follow states (n + 1, nx) over t_f, clipped.

    Least squares through df/du at u = 0 (exact for models affine in u).
    """
    n = states.shape[0] - 1
    tau = t_f / n
    k = model.kernels
    p = model.packed()
    f = np.zeros((n, model.nx))
    fx = np.zeros((model.nx, model.nx))
    fu = np.zeros((n, model.nx, model.nu))
    zero = np.zeros(model.nu)
    u_max = np.asarray(model.u_max, dtype=float)
    for i in range(n):
        k.rhs_jac(states[i], zero, p, f[i], fx, fu[i])
    # One stacked pseudo-inverse instead of n lstsq calls (that loop was ~3 ms at n = 100).
    target = (states[1:] - states[:-1]) / tau - f
    u = np.matmul(np.linalg.pinv(fu), target[:, :, None])[:, :, 0]
    return np.clip(u, -u_max, u_max)


def ladder(coarse, n):
    """
    Intermediate grids between coarse and n intervals, a geometric sequence (ratio <= 4).

    A refinement that jumps by 10 needs ~45 iterations on the N grid (planar_2r, N = 1000),
    one via 316 intervals ~20 there plus ~20 on the cheaper grid.
    """
    if n <= coarse:
        return []
    steps = int(math.ceil(math.log(n / coarse) / math.log(LADDER_RATIO) - 1e-12))
    return [int(round(coarse * (n / coarse) ** (k / steps))) for k in range(1, steps)]


def resample(states, controls, n):
    """
    Carry a trajectory to n intervals.

    States are interpolated linearly in time, controls piecewise constant (the control of the
    old interval that contains the new interval's midpoint).
    """
    m = controls.shape[0]
    old = np.linspace(0.0, 1.0, m + 1)
    new = np.linspace(0.0, 1.0, n + 1)
    out_states = np.column_stack([np.interp(new, old, states[:, r])
                                  for r in range(states.shape[1])])
    mid = (np.arange(n) + 0.5) / n
    idx = np.minimum((mid * m).astype(np.int64), m - 1)
    return out_states, controls[idx].copy()


def resample_duals(duals, m, n):
    """Multipliers carried from m to n intervals (obstacle duals scale with tau)."""
    old = np.linspace(0.0, 1.0, m + 1)
    new = np.linspace(0.0, 1.0, n + 1)
    lam = np.column_stack([np.interp(new, old, duals['lam'][:, r])
                           for r in range(duals['lam'].shape[1])])
    nodes_old = old[1:]
    nodes_new = new[1:]
    z = np.column_stack([np.interp(nodes_new, nodes_old, duals['z'][:, j])
                         for j in range(duals['z'].shape[1])]) * (m / n) \
        if duals['z'].shape[1] else np.zeros((n, 0))
    out = {'lam': lam, 'nu': duals['nu'].copy(), 'z': z}
    if 'rho' in duals:
        out['rho'] = duals['rho']
    if 'zl' in duals:
        mid = (np.arange(n) + 0.5) / n
        idx = np.minimum((mid * m).astype(np.int64), m - 1)
        out['zl'] = duals['zl'][idx] * (m / n)
        out['zu'] = duals['zu'][idx] * (m / n)
    return out


def widen_duals(duals, kept, n_circles, n_links):
    """
    Multipliers of a run on the circles kept (indices) for all n_circles of the problem.

    The obstacle duals z of the circles it did not have are 0: InteriorPointRun.start makes
    them mu / slack, an inactive constraint's start.
    """
    z = duals['z']
    wide = np.zeros((z.shape[0], n_links * n_circles))
    for link in range(n_links):
        for r, k in enumerate(kept):
            wide[:, link * n_circles + k] = z[:, link * len(kept) + r]
    return dict(duals, z=wide)


def warm_start_point(problem, guess, n):
    """
    Return (states, controls, t_f, duals or None, drift) from an initial guess for n intervals.

    drift: how far [max norm] the problem's start lies from the guess's first state.
    """
    if isinstance(guess, SolveResult):
        controls = np.asarray(guess.controls, dtype=float)
        t_f = float(guess.final_time)
        states = np.asarray(guess.states, dtype=float)
        duals = guess.solver_state.get('duals') if guess.solver_state else None
    else:
        controls, t_f = guess
        controls = np.asarray(controls, dtype=float)
        t_f = float(t_f)
        states = None
        duals = None
    model = problem.robot_model
    if controls.ndim != 2 or controls.shape[1] != model.nu or controls.shape[0] < 1:
        raise ValueError(f'initial guess controls must be an M x {model.nu} array, got shape '
                         f'{controls.shape}')
    if not (np.all(np.isfinite(controls)) and math.isfinite(t_f) and t_f > 0.0):
        raise ValueError('initial guess must have finite controls and a positive final time')
    m = controls.shape[0]
    drift = 0.0
    if states is not None and states.shape == (m + 1, model.nx) \
            and np.all(np.isfinite(states)):
        # A trajectory (e.g. the remainder of the plan being executed): its states and
        # multipliers, starting from the problem's start (the robot may have drifted off it;
        # the first shooting defect absorbs that).
        drift = float(np.max(np.abs(states[0] - np.asarray(problem.x0, dtype=float))))
        states = states.copy()
        states[0] = problem.x0
    else:
        # Roll the controls out from the problem's start: consistent states (zero defects).
        states = np.empty((m + 1, model.nx))
        model.kernels.rollout(np.asarray(problem.x0, dtype=float),
                              np.ascontiguousarray(np.clip(controls, -model.u_max,
                                                           model.u_max)),
                              t_f / m, model.packed(), problem.integrator_id, states)
        duals = None
    if not np.all(np.isfinite(states)):
        raise ValueError('initial guess controls make the state diverge')
    if m != n:
        if duals is not None and duals['z'].shape[1] == model.n_links * len(problem.obstacles):
            duals = resample_duals(duals, m, n)
        else:
            duals = None
        states, controls = resample(states, controls, n)
    elif duals is not None and duals['z'].shape[1] != model.n_links * len(problem.obstacles):
        duals = None
    return states, controls, t_f, duals, drift


def _relaxation(run):
    """Return (problem, kept) of a relaxation's run (_lazy_classes), None for the problem's."""
    return None if run.kept is None else (run.problem, run.kept)


def _has_actuators(model):
    return model.joint_model is not model


def _guess_intervals(guess):
    if guess is None:
        return 0
    controls = guess.controls if isinstance(guess, SolveResult) else guess[0]
    return int(np.shape(controls)[0])


class FastSolve:
    """Fast mode on one problem: coarse-to-fine cold start or warm start, then the result."""

    def __init__(self, problem, options, clock, initial_guess=None, start_point=None):
        self.problem = problem
        self.options = options
        self.clock = clock
        self.initial_guess = initial_guess
        # warm_start_point(problem, initial_guess, N) when the caller has it already.
        self.start_point = start_point
        self.initial_guess_intervals = _guess_intervals(initial_guess)
        self.limit = options.iteration_limit()
        self.done = 0            # iterations on finished grids
        self.history = []
        self.run = None
        self.best = None         # the shortest converged run on the N grid so far
        self.narrow = False      # climbs without the far circles (_narrowed; lazy solves)

    def _check(self, run):
        reason = self.clock.stop_reason()
        if reason is not None:
            raise Stop(reason)
        from .result import Progress
        fs = run.ws.fscal
        self.clock.report(lambda: Progress(
            self.done + run.iterations, run.t_f, run.t_f, math.nan, self.clock.elapsed(),
            f'fast N={run.n}', None, float(fs[ipm.F_THETA])))

    def _solve_on(self, n, states, controls, t_f, mu, duals=None, budget=None,
                  push=BOUND_PUSH, elastic=None, relaxed=None):
        left = max(1, self.limit - self.done)
        problem, kept = relaxed or (self.problem, None)
        run = InteriorPointRun(problem, n, left if budget is None else min(budget, left),
                               elastic, kept)
        run.start(states, controls, t_f, mu, duals, push)
        self.run = run
        try:
            code = run.run(self._check, lambda: self.clock.stop_reason() is not None)
        finally:
            self._record(run)
        if code == ipm.STOPPED:
            raise Stop(self.clock.stop_reason() or Status.CANCELED)
        return run, code

    def _record(self, run):
        rows = run.history()
        if rows.shape[0]:
            first = sum(block.shape[0] for block in self.history)
            self.history.append(np.column_stack([np.arange(first, first + rows.shape[0]),
                                                 rows[:, 0], rows[:, 0], rows[:, 1]]))
        self.done += run.iterations

    def solve(self):
        problem = self.problem
        n = problem.n_intervals
        try:
            if self.initial_guess is not None:
                states, controls, t_f, duals, drift = self.start_point or warm_start_point(
                    problem, self.initial_guess, n)
                # A guess that starts where the robot is (within ~1e-6) is kept tight against
                # its bounds and barely re-centred; one the robot has drifted from gets room
                # (an interior method cannot move along the bounds it is pinned to).
                exact = self.initial_guess_intervals == n
                if duals is None:
                    mu, push = MU_WARM / n, BOUND_PUSH
                elif exact and drift <= WARM_EXACT:
                    mu, push = MU_EXACT, WARM_PUSH
                else:
                    mu, push = min(MU_DRIFT / n, max(MU_EXACT, 1e-4 * drift)), BOUND_PUSH
                rho = None if duals is None else duals.get('rho')
                run, code = self._solve_on(n, states, controls, t_f, mu, duals,
                                           budget=WARM_BUDGET, push=push, elastic=rho)
                if code != ipm.CONVERGED and self.done < self.limit:
                    # A poor guess: solve from scratch rather than report the failure.
                    self.initial_guess = None
                    return self.solve()
            elif _has_actuators(problem.robot_model):
                run, code = self._cold_actuated(n)
            else:
                run, code = self._cold(n)
        except Stop as stop:
            reason = stop.args[0]
            if reason is Status.TIMEOUT and self.best is not None:
                # A converged optimum on the N grid is in hand; only the search for a shorter
                # one (further attempts, candidates) was cut short: a real-time caller wants it.
                result = self._result(self.best, Status.SOLVED, '')
                if result.status is Status.SOLVED:
                    result.message += ' (the timeout stopped the search for a shorter optimum)'
                return result
            run = self.best or self.run
            if run is None or run.n != n:
                return SolveResult(status=reason, iterations=self.done,
                                   message=f'{reason.value.lower()} after {self.done} '
                                   'iterations', history=self._history())
            return self._result(run, reason, f'{reason.value.lower()} after {self.done} '
                                'iterations')
        status = CODE_STATUS[code]
        messages = {ipm.ITERATION_LIMIT: f'iteration limit {self.limit} reached',
                    ipm.LINE_SEARCH_FAILED: 'no acceptable step (line search failed '
                                            'repeatedly): the problem may be infeasible',
                    ipm.NUMERICAL_FAILURE: 'numerical failure (non-finite values or a '
                                           'singular Newton system)'}
        return self._result(run, status, messages.get(code, ''))

    def _cold(self, n):
        """
        Solve from the cold start and return (run, code).

        Attempts (start, elastic weight, barrier parameter) run on the coarse grid (on the N
        grid itself when N <= 2 COARSE_INTERVALS).  When N > 2 COARSE_INTERVALS and the
        interpolation start crosses an obstacle of a two-joint model: the class starts of
        homotopy.py with CLASS_ATTEMPT, on EXPLORE_INTERVALS, side by side (with several
        circles those of a relaxation first: _lazy_classes, _bounded_classes).  When there are
        none (another number of joints, no hole inside the grid) or none of them converges: the
        interpolation start with the first pair of COLD_ATTEMPTS and, when _explore says so,
        with the other pairs.  The distinct converged ones within REFINE_BAND of the shortest
        are refined (_finish).  When nothing converges, the N grid from the cold start with each
        barrier parameter of MU_COLD_RETRIES in turn (the central path from another mu can
        lead into another basin).
        """
        problem = self.problem
        grid = COARSE_INTERVALS if n > 2 * COARSE_INTERVALS else n
        found = []
        states = interpolation_states(problem, grid)
        # Class starts on a coarser grid still (their candidates are carried up by _finish like
        # the others); not when the coarse grid is the N grid (short horizons, a few ms).
        explore = min(grid, EXPLORE_INTERVALS)
        crosses = grid < n and self._crosses(states)
        allowance, prefetched = None, None
        bounds = None
        if crosses and len(problem.obstacles) > 1 and self._may_explore() and \
                homotopy.has_holes(problem):
            self.narrow = True
            found, prefetched, allowance, bounds = self._lazy_classes(explore, n)
        paths, feet = homotopy.classes(problem) if crosses and not found else ([], None)
        if paths and self._may_explore():
            found, prefetched, allowance = self._bounded_classes(paths, feet, explore, n,
                                                                 bounds)
        first = None
        if not found:
            allowance, prefetched = None, None      # today's shares for these attempts
            t_f0 = float(problem.t_f0)
            start = start_along(problem, states, t_f0) + (t_f0,)
            first = self._attempt(grid, n, start, COLD_ATTEMPTS[0], found)
            if self._explore(first):
                for pair in COLD_ATTEMPTS[1:]:
                    if self._may_explore():
                        self._attempt(grid, n, start, pair, found)
        if grid == n and found:
            return min(found, key=lambda r: r.t_f), ipm.CONVERGED   # ties: the first attempt
        if found:
            self._finish(found, n, allowance, prefetched)
        if self.best is not None:
            return self.best, ipm.CONVERGED
        for mu in MU_COLD_RETRIES:
            if self.done >= self.limit and first is not None and first[0].n == n:
                break
            states, controls, t_f = interpolation_start(problem, n)
            run, code = self._solve_on(n, states, controls, t_f, mu)
            if first is None or first[0].n != n:
                first = (run, code)
            if code == ipm.CONVERGED:
                return run, code
        return first

    def _cold_actuated(self, n):
        """
        Solve a model with actuator states (models/actuated.py) from a cold start.

        The joints are solved first without the lag (the whole cold start: coarse grids,
        class starts), then that solution on the N grid, its controls also as the applied
        torques, is the start of the actuated problem.  The actuators' time constant is
        usually far below the coarse grids' steps, where their (stiff) states would make the
        explicit discretisation unstable; on the N grid the lag moves the optimum little.
        Returns (run, code); the plain cold start of the actuated problem when that fails.
        """
        problem = self.problem
        model = problem.robot_model
        joint = model.joint_model
        joints = dataclasses.replace(problem, x0=tuple(model.joint_states(problem.x0)),
                                     x_goal=tuple(model.joint_states(problem.x_goal)))
        inner = FastSolve(joints.with_model(joint), self.options, self.clock)
        inner.limit = self.limit - self.done
        try:
            inner_run, code = inner._cold(n)
        finally:
            self.history += inner.history
            self.done += inner.done
        if code == ipm.CONVERGED and inner_run.n == n and self.done < self.limit:
            controls = inner_run.controls()
            states = np.hstack([inner_run.ws.x, actuator_states(problem, controls)])
            duals = inner._duals(inner_run)      # all circles (a relaxed run: widened)
            duals['lam'] = np.hstack([duals['lam'], np.zeros((n + 1, joint.nu))])
            duals['nu'] = np.concatenate([duals['nu'], np.zeros(joint.nu)])
            run, code = self._solve_on(n, states, controls, inner_run.t_f, MU_WARM / n, duals,
                                       budget=max(1, self.limit // 4), elastic=duals['rho'])
            if code == ipm.CONVERGED:
                return run, code
        return self._cold(n)

    def _crosses(self, states):
        """
        Return whether the interpolation start's states (coarse grid) cross an obstacle.

        Only then are the class starts of homotopy.py solved (a two-joint model): the side of
        each obstacle that start ends on is arbitrary, while a start already on one side of
        each keeps its iterates out of the obstacles (fewer, convex iterations).
        """
        model = self.problem.robot_model
        if not len(self.problem.obstacles) or model.n_joints != 2:
            return False
        seg = model.link_segments(model.positions(states))
        return bool(np.min(homotopy.clearance(seg, self.problem.circles())) < 0.0)

    def _explore_classes(self, paths, explore, n, relaxed=None, budget=None, allowance=None,
                         warm=()):
        """
        Run the class attempts of paths (of relaxed, default the problem) on explore intervals.

        Returns (converged runs, prefetched, allowance) as _class_attempts, with the climbs'
        allowance; ([], None, None) when the iteration budget has no room for them.  budget
        and allowance: given when the classes are solved in parts (_bounded_classes).
        """
        if budget is None:
            budget, allowance = self._class_budget(len(paths))
        if budget < 1:
            return [], None, None
        found, prefetched = self._class_attempts(paths, explore, budget, n, allowance, relaxed,
                                                 warm)
        return found, prefetched, allowance

    def _class_budget(self, count):
        """Return (budget of each of count class attempts, the climbs' allowance)."""
        # Each limit // 8, all within the iteration limit.
        budget = min(self.limit // 8, (self.limit - self.done) // max(count, 1))
        # The candidates' climbs get a share fixed now, and limit // 4 is left for the N grid
        # (_refine), so that both can start before the last attempt ends (_class_attempts).
        return budget, max(1, (self.limit - self.done - count * budget
                               - self.limit // 4) // MAX_REFINE)

    def _bounded_classes(self, paths, feet, explore, n, bounds):
        """
        Run the class attempts of paths, skipping those a relaxation bounds out of the band.

        feet: of the problem's holes (homotopy.classes).  bounds (from _lazy_classes, or
        None): (feet of the relaxation's holes, its converged attempts).  An attempt that ended
        in its start's class (homotopy.same_class around the relaxation's holes) is, under the
        class starts' premise, the best of that class; the problem's classes inside it (more
        circles) end no shorter.  So the paths with the smallest such lower bounds (within the
        band; no bound: 0) are solved first, and the others only if their bound is within the
        band of the shortest found.  A relaxation's candidate that hits the circles it did not
        have starts the problem warm first (_warm_classes): a problem's class next to it,
        whose attempt is then not run.  Returns (found, prefetched, allowance) as
        _explore_classes; the same budget and allowance for both parts (the prefetched climbs
        must be _finish's).
        """
        if bounds is None:
            return self._explore_classes(paths, explore, n)
        relaxed_feet, relaxed_runs = bounds
        model = self.problem.robot_model
        solutions = [(model.positions(run.ws.x), run.t_f) for run in relaxed_runs
                     if homotopy.same_class(run.path, model.positions(run.ws.x), relaxed_feet)]
        low = [min([t for q, t in solutions if homotopy.same_class(path, q, relaxed_feet)],
                   default=0.0) for path in paths]
        band = 1.0 + REFINE_BAND * COARSE_INTERVALS / min(explore, COARSE_INTERVALS)
        order = [k for k in range(len(paths)) if low[k] <= band * min(low)]
        budget, allowance = self._class_budget(len(paths))
        if budget < 1:
            return [], None, None
        warm, covered = self._warm_classes(relaxed_runs, paths, feet, explore, budget)
        first = [k for k in order if k not in covered]
        found, prefetched, allowance = self._explore_classes(
            [paths[k] for k in first], explore, n, None, budget, allowance, warm)
        shortest = min([run.t_f for run in found], default=math.inf)
        rest = [k for k in range(len(paths)) if k not in order and k not in covered and
                low[k] <= band * shortest]
        if not rest or not self._may_explore():
            return found, prefetched, allowance
        more, later, _ = self._explore_classes([paths[k] for k in rest], explore, n, None,
                                               budget, allowance)
        merged = {key: {**(prefetched or {}).get(key, {}), **(later or {}).get(key, {})}
                  for key in ('climbs', 'finals')}
        return found + more, merged, allowance

    def _warm_classes(self, relaxed_runs, paths, feet, explore, budget):
        """
        Return (converged runs, indices of their classes in paths): the problem from hits.

        Each candidate of the relaxation (_candidates) that hits a circle it did not have
        starts the problem on explore intervals (its primal-dual point, the widened duals):
        its optimum grazes that circle, so the problem's optimum on the near side of it is
        close (planar_2r '2 circles, g = 0, moving start': 12 iterations instead of the class
        start's 41, the same optimum).  The class (homotopy.same_class around feet) a run ends
        in is covered by it.  Serial, before the class attempts: the same runs with one or two
        workers.
        """
        model = self.problem.robot_model
        found, covered = [], set()
        for source in self._candidates(relaxed_runs):
            if not self._violated(source) or not self._may_explore():
                continue
            duals = self._duals(source)
            run, code = self._solve_on(explore, source.ws.x, source.controls(), source.t_f,
                                       MU_WARM / explore, duals, budget=budget,
                                       elastic=duals['rho'])
            if code != ipm.CONVERGED:
                continue
            q = model.positions(run.ws.x)
            same = [k for k, path in enumerate(paths) if homotopy.same_class(path, q, feet)]
            run.path = paths[same[0]] if same else None
            covered.update(same[:1])
            found.append(run)
        return found, covered

    def _lazy_classes(self, explore, n):
        """
        Class attempts on the circles that matter only: (found, prefetched, allowance, bounds).

        Lazy constraints over the circles: a local optimum of a relaxation (some circles
        dropped) that is clear of the dropped ones is one of the problem.  And under the
        premise of the class starts (the attempt from each class start reaches its class's
        best optimum), the relaxation's best is no longer than the problem's best of the same
        classes, so when the relaxation's candidates (_candidates) are all clear of the dropped
        circles they are the problem's candidates: fewer classes solved (two-circle planar_2r:
        2 attempts instead of 4, where circle B is not in the way).  First without circles
        (one attempt from the interpolation start), then with the circles its candidates hit,
        and so on.  The candidates climb on the relaxation too (fewer constraints per node);
        _finish keeps its solutions only where they are clear of the dropped circles.
        found is [] (the caller solves the classes of all circles) when they hit every circle,
        an attempt does not converge, a relaxation has no class starts or the budget is spent;
        bounds: (feet of the last relaxation's holes, its converged attempts) for
        _bounded_classes, or None.
        """
        problem = self.problem
        kept = ()
        relaxed = (dataclasses.replace(problem, obstacles=()), kept)
        budget = max(1, min(self.limit // 8, self.limit - self.done))
        run, code = self._solve_on(explore, *interpolation_start(relaxed[0], explore),
                                   CLASS_ATTEMPT[1], budget=budget, elastic=CLASS_ATTEMPT[0],
                                   relaxed=relaxed)
        found = [run] if code == ipm.CONVERGED else []
        prefetched = allowance = bounds = None
        while found:
            hit = set()
            for run in self._candidates(found):
                hit.update(self._violated(run))
            if not hit:
                return found, prefetched, allowance, None
            kept = tuple(sorted(set(kept) | hit))
            if len(kept) == len(problem.obstacles) or not self._may_explore():
                break
            relaxed = (dataclasses.replace(
                problem, obstacles=tuple(problem.obstacles[k] for k in kept)), kept)
            paths, feet = homotopy.classes(relaxed[0])
            if not paths:
                return [], None, None, None
            found, prefetched, allowance = self._explore_classes(paths, explore, n, relaxed)
            bounds = (feet, found)
        return [], None, None, bounds

    def _violated(self, run):
        """Return the indices of the circles run did not have that its nodes hit (a set)."""
        if run.kept is None:
            return set()
        dropped = [k for k in range(len(self.problem.obstacles)) if k not in run.kept]
        hit = self._clearances(run, dropped) < 0.0
        return {dropped[r] for r in np.flatnonzero(hit)}

    def _clearances(self, run, indices):
        """Return the least clearance of run's nodes 1..N to each circle of indices (array)."""
        model = self.problem.robot_model
        seg = model.link_segments(model.positions(run.ws.x[1:]))
        clear = homotopy.clearance(seg, self.problem.circles()[list(indices)])
        return np.min(clear.reshape(-1, model.n_links, len(indices)), axis=(0, 1))

    def _duals(self, run, relaxed=None):
        """
        Return the multipliers of run for a run on relaxed (problem, kept), default the problem.

        A relaxed run's are widened (widen_duals), then the circles of kept selected.
        """
        duals = run.duals()
        if run.kept is not None:
            if relaxed is not None and tuple(relaxed[1]) == tuple(run.kept):
                return duals
            duals = widen_duals(duals, run.kept, len(self.problem.obstacles),
                                self.problem.robot_model.n_links)
        if relaxed is None:
            return duals
        n_circles, kept = len(self.problem.obstacles), relaxed[1]
        columns = [link * n_circles + k for link in range(self.problem.robot_model.n_links)
                   for k in kept]
        return dict(duals, z=duals['z'][:, columns])

    def _narrowed(self, run):
        """
        Return the (problem, kept) run's candidate climbs on (None: the problem).

        Its own relaxation (_relaxation), without the circles it stays NARROW_MARGIN clear of
        at every node in a lazy solve (self.narrow): their constraints are inactive there and
        likely on the finer grids, where a climb that hits them is redone with all circles
        (_clear_climbs, _complete).
        """
        relaxed = _relaxation(run)
        if not self.narrow:
            return relaxed
        obstacles = self.problem.obstacles
        have = range(len(obstacles)) if run.kept is None else run.kept
        if not len(have):
            return relaxed
        kept = tuple(k for k, c in zip(have, self._clearances(run, have)) if c < NARROW_MARGIN)
        if len(kept) == len(have):
            return relaxed
        return dataclasses.replace(self.problem, obstacles=tuple(obstacles[k] for k in kept)), \
            kept

    def _class_attempts(self, paths, explore, budget, n, allowance, relaxed=None, warm=()):
        """
        Solve the class starts on explore intervals; return (converged runs, prefetched).

        The attempts (CLASS_ATTEMPT, budget each) run two at a time.  With two workers and an
        Euler ladder, a converged attempt that is a candidate among those converged so far
        (_candidates) starts its climb at once, ahead of the attempts still waiting, and the
        best climbed one its refinement to N (_Prefetch): the chain to the N grid then overlaps
        the other attempts instead of following them.  These are _finish's climb and _refine's
        solve, with the same allowance and budget, so their results are the ones _finish would
        get (a prefetch); one that later results put out is cancelled.  Only the attempts' runs
        are recorded here (in task order), the climbs and the refinement by _finish.
        relaxed: (problem, kept) of a relaxation (_lazy_classes) the attempts are solved on;
        its candidates climb on the problem, and only while all are clear of the other circles.
        """
        rho, mu = CLASS_ATTEMPT
        problem = self.problem

        def attempt(solve, path, point=None):
            # The start is built on the worker: its numpy overlaps the other's kernel.
            point = point or homotopy.path_start(problem, path, explore)
            run, code = solve(explore, *point, mu, None, budget, rho, relaxed)
            run.path = path                 # its class (_bounded_classes)
            return run, code

        # The first one here, before a helper thread starts building its own (the GIL).
        first = homotopy.path_start(problem, paths[0], explore) if paths else None
        # warm: converged runs already (_warm_classes), first in task order.
        tasks = [lambda solve, run=run: (run, ipm.CONVERGED) for run in warm] + \
            [lambda solve, path=path, point=point: attempt(solve, path, point)
             for path, point in zip(paths, [first] + [None] * (len(paths) - 1))]
        rank = self._rank_grid(explore, n, MAX_REFINE)
        if workers.WORKERS < 2 or problem.integrator != 'euler' or rank == n:
            return [run for run, code in self._parallel(tasks) if code == ipm.CONVERGED], {}

        def refine(solve, run):
            # _refine's solve on a worker (the budget is limit // 4 there too: see _cold).
            states, controls = resample(run.ws.x, run.controls(), n)
            duals = resample_duals(run.duals(), run.n, n)
            return solve(n, states, controls, run.t_f, MU_WARM / n, duals,
                         max(1, self.limit // 4), duals['rho'], _relaxation(run))

        return _Prefetch(self, tasks, self._climber(rank, allowance), refine,
                         lambda run: not self._violated(run)).run()

    def _attempt(self, grid, n, start, pair, found):
        """Run one cold attempt (elastic weight, mu) on grid; append it to found if converged."""
        states, controls, t_f = start
        rho, mu = pair
        run, code = self._solve_on(grid, states, controls, t_f, mu, elastic=rho,
                                   budget=max(1, self.limit // (8 if grid < n else 4)))
        if code == ipm.CONVERGED:
            found.append(run)
            if grid == n and (self.best is None or run.t_f < self.best.t_f):
                self.best = run     # what a timeout during the further attempts returns
        return run, code

    def _finish(self, found, n, allowance=None, prefetched=None):
        """
        Refine the distinct coarse optima close to the best one; set self.best.

        The coarse grid's ranking of nearby optima is not the N grid's, so the distinct
        converged ones within REFINE_BAND of the shortest (at most MAX_REFINE) are carried up.
        Through the intermediate grids of ladder() when there are any (each step a few cheap
        iterations, fewer in all than one jump to N): every candidate to the last intermediate
        grid, then the shortest converged there to N (the next one if it fails).  Without
        intermediate grids each candidate goes to N and the shortest converged one is kept.
        The candidates climb the ladder side by side (_parallel), each within allowance
        iterations (default: an equal share of the iterations left); prefetched: climbs and a
        refinement to N already run (_Prefetch.run), with the same allowance and budget.
        """
        candidates = self._candidates(found)
        if not candidates:
            return
        rank = self._rank_grid(min(run.n for run in candidates), n, len(candidates))
        if rank == n:
            for coarse in candidates:
                if self.done >= self.limit:
                    break
                run, code = self._complete(self._refine(coarse, n), coarse, n)
                if code == ipm.CONVERGED and (self.best is None or run.t_f < self.best.t_f):
                    self.best = run
            return
        # The candidates side by side (_parallel), each up its own ladder within its share.
        left = self.limit - self.done
        if left < 1:
            return
        candidates = candidates[:left]
        climb = self._climber(rank, allowance or left // len(candidates))
        climbs = (prefetched or {}).get('climbs', {})
        finals = (prefetched or {}).get('finals', {})
        climbed = self._parallel(
            [lambda solve, run=run: climb(solve, run) for run in candidates],
            {k: climbs[id(run)] for k, run in enumerate(candidates) if id(run) in climbs})
        ranked = self._clear_climbs(climbed, candidates, climb)
        for source in sorted(ranked, key=lambda r: r.t_f) + candidates:
            if self.done >= self.limit:
                break
            if id(source) in finals:           # its refinement to N, run already
                (run, code), runs = finals.pop(id(source))
                for done in runs:
                    self._record(done)
                    self.run = done
            else:
                run, code = self._refine(source, n)
            run, code = self._complete((run, code), source, n)
            if code == ipm.CONVERGED:
                self.best = run
                return

    def _clear_climbs(self, climbed, candidates, climb):
        """
        Return the converged climbs of candidates whose solutions are the problem's.

        climbed: (run, code) per candidate.  A relaxation's climb (_lazy_classes) clear of the
        dropped circles is a local optimum of the problem; one that hits them bounds its
        candidate's climb with all circles from below (under the class starts' premise), so
        that climb is done (from the clear coarse candidate) only when the bound is shorter
        than the shortest clear climb.
        """
        hit = {k for k, (run, code) in enumerate(climbed)
               if code == ipm.CONVERGED and self._violated(run)}
        shortest = min([run.t_f for k, (run, code) in enumerate(climbed)
                        if code == ipm.CONVERGED and k not in hit], default=math.inf)
        redo = [k for k in sorted(hit) if climbed[k][0].t_f < shortest]
        again = self._parallel([lambda solve, run=candidates[k]: climb(solve, run, True)
                                for k in redo])
        climbed = list(climbed)
        for k, value in zip(redo, again):
            climbed[k] = value
        return [run for k, (run, code) in enumerate(climbed)
                if code == ipm.CONVERGED and (k not in hit or k in redo)]

    def _candidates(self, found):
        """
        Return the distinct runs of found (in attempt order) within the band of the shortest.

        Shortest first, at most MAX_REFINE.  Of runs that end at the same t_f (within 1e-6: the
        same optimum reached from two starts) the first attempt's stands for them: it usually
        converges first, so its climb may have started already (_class_attempts).
        """
        order = sorted(range(len(found)), key=lambda k: found[k].t_f)   # stable
        chosen = []
        for k in order:
            if self.done >= self.limit or len(chosen) >= MAX_REFINE:
                break
            if not _in_band(found[k], found[order[0]].t_f):
                continue
            same = [i for i, c in enumerate(chosen)
                    if abs(found[k].t_f - found[c].t_f) <= 1e-6 * found[c].t_f]
            if not same:
                chosen.append(k)
            elif k < chosen[same[0]]:
                chosen[same[0]] = k
        return [found[k] for k in chosen]

    def _rank_grid(self, coarse, n, count):
        """
        Return the grid count candidates from coarse intervals are ranked on.

        The last grid of the ladder from coarse to N (N if none): from the class attempts' 50
        intervals 136, 368 (the last step to N 2.7, 15-20 iterations there on planar_2r; via
        126 and 316 it was 17-25).  Never coarser than from COARSE_INTERVALS: nearby optima
        swap places on coarse grids (planar_2r: on 126 intervals, not on 316).  An RK4 coarse
        solution is already close to the N grid's (error O(tau^4), not O(tau)): there the
        intermediate grid saves no N-grid iterations (paper scenario: 17 there after 25 on
        316, 19 straight), so a single candidate goes straight to N.
        """
        if self.problem.integrator != 'euler' and count == 1:
            return n
        return max((ladder(coarse, n) or [n])[-1], (ladder(COARSE_INTERVALS, n) or [n])[-1])

    def _climber(self, rank, allowance):
        """
        Return climb(solve, run, full=False): run's solution up the ladder to rank.

        Within allowance iterations; a relaxation's run (_lazy_classes) climbs on its
        relaxation, or with full on the problem.
        """
        def climb(solve, run, full=False):
            used, code = 0, ipm.CONVERGED
            relaxed = None if full else self._narrowed(run)
            for m in ladder(run.n, rank) + [rank]:
                if used >= allowance:
                    return run, ipm.ITERATION_LIMIT
                states, controls = resample(run.ws.x, run.controls(), m)
                duals = resample_duals(self._duals(run, relaxed), run.n, m)
                run, code = solve(m, states, controls, run.t_f, MU_WARM / m, duals,
                                  min(self.limit // 4, allowance - used), duals['rho'],
                                  relaxed)
                used += run.iterations
                if code != ipm.CONVERGED:
                    break
            return run, code
        return climb

    def _parallel(self, tasks, done=None):
        """
        Run tasks (callables solve -> value) on the worker threads; return their values.

        solve(n, states, controls, t_f, mu, duals, budget, elastic[, relaxed]) is a worker's
        _solve_on:
        it neither records its run nor reports progress (this thread does, meanwhile and, in
        task order, afterwards), and only the fixed budget caps it, so a task's result does not
        depend on the others' timing (workers.py).  done: {index: (value, runs)} of tasks
        already run (_class_attempts); their runs are recorded in their place.
        """
        done = done or {}
        logs = [list(done[k][1]) if k in done else [] for k in range(len(tasks))]
        todo = [k for k in range(len(tasks)) if k not in done]
        poll = self._poller(logs)
        values = {k: value for k, (value, _) in done.items()}
        try:
            out = workers.run_tasks([self._bind(tasks[k], logs[k], poll) for k in todo], poll)
            values.update(zip(todo, out))
            return [values[k] for k in range(len(tasks))]
        finally:
            for run in (run for log in logs for run in log):
                self._record(run)
                self.run = run

    def _bind(self, task, log, poll, cancelled=None, caller=None):
        """
        Return a worker's callable: task(solve), its runs appended to log.

        poll() runs between iteration chunks when this is the caller's thread (default: the
        current one).  cancelled(): a prefetch no longer wanted; its kernel stops within one
        phase and _Cancelled is raised.
        """
        caller = caller or threading.current_thread()

        def stop_requested():
            return self.clock.stop_reason() is not None or (cancelled is not None and
                                                            cancelled())

        def check(run):
            if cancelled is not None and cancelled():
                raise _Cancelled()
            reason = self.clock.stop_reason()
            if reason is not None:
                raise Stop(reason)
            if threading.current_thread() is caller:
                poll()

        def solve(n, states, controls, t_f, mu, duals, budget, elastic, relaxed=None):
            problem, kept = relaxed or (self.problem, None)
            run = InteriorPointRun(problem, n, budget, elastic, kept)
            run.start(states, controls, t_f, mu, duals)
            log.append(run)
            code = run.run(check, stop_requested)
            if code == ipm.STOPPED:
                if cancelled is not None and cancelled():
                    raise _Cancelled()
                raise Stop(self.clock.stop_reason() or Status.CANCELED)
            return run, code
        return lambda: task(solve)

    def _poller(self, logs):
        """Return poll(): a progress report on the newest run of logs (lists of runs)."""
        def poll():
            runs = [run for log in logs for run in log]
            if runs:
                from .result import Progress
                its = self.done + sum(run.iterations for run in runs)
                self.clock.report(lambda: Progress(
                    its, runs[-1].t_f, runs[-1].t_f, math.nan, self.clock.elapsed(),
                    f'fast N={runs[-1].n}', None, float(runs[-1].ws.fscal[ipm.F_THETA])))
        return poll

    def _refine(self, run, n, full=False):
        """
        Carry a converged run's primal-dual solution to n intervals and solve there.

        A relaxation's run (_lazy_classes) on its relaxation, or with full on the problem.
        """
        relaxed = None if full else _relaxation(run)
        states, controls = resample(run.ws.x, run.controls(), n)
        duals = resample_duals(run.duals() if relaxed else self._duals(run), run.n, n)
        return self._solve_on(n, states, controls, run.t_f, MU_WARM / n, duals,
                              budget=max(1, self.limit // 4), elastic=duals['rho'],
                              relaxed=relaxed)

    def _complete(self, refined, source, n):
        """
        Return refined (run, code) on the N grid, solved on the problem if need be.

        A relaxation's run (_lazy_classes) clear of the circles it does not have at every
        node is a local optimum of the problem too (those constraints inactive, multipliers
        0); one that hits them is refined again from source (clear of them, _finish) with
        all circles.
        """
        run, code = refined
        if code != ipm.CONVERGED or not self._violated(run):
            return run, code
        return self._refine(source, n, full=True)

    def _may_explore(self):
        """Return whether a further cold attempt may start (obstacles, budget and time)."""
        if not len(self.problem.obstacles) or self.done >= self.limit // 2:
            return False
        timeout = self.options.timeout
        return timeout is None or self.clock.elapsed() < EXPLORE_TIME * timeout

    def _explore(self, first):
        """
        Return whether to run the cold attempts after the first one (first: its run, code).

        Only when _may_explore (with obstacles, within half the iteration budget and, with a
        timeout, within EXPLORE_TIME of it, leaving the rest for the N grid), and only when the
        first attempt failed or needed the inertia correction (negative curvature) on more
        than EXPLORE_NONCONVEX iterations: its path crossed a nonconvex region, where other
        local optima are likely.  A start that leads straight into its basin (the paper
        scenario: 5 such iterations of 35) is not re-solved.
        """
        if not self._may_explore():
            return False
        run, code = first
        shifted = np.count_nonzero(run.ws.hist[:run.iterations, ipm.H_DELTA] > 0.0)
        return code != ipm.CONVERGED or shifted > EXPLORE_NONCONVEX

    def _history(self):
        return np.concatenate(self.history) if self.history else np.zeros((0, 4))

    def _result(self, run, status, message):
        from .problem import measure_violations
        controls = run.controls()
        states, violations = measure_violations(self.problem, controls, run.t_f)
        result = SolveResult(status=status, message=message, final_time=run.t_f,
                             states=states, controls=controls, iterations=self.done,
                             history=self._history(), violations=violations, cost=run.t_f,
                             solver_state={'duals': self._duals(run)})
        if status is Status.SOLVED:
            if violations.feasible():
                result.message = f't_min = {run.t_f:.6f} s'
            else:
                result.status = Status.STALLED
                result.message = ('converged, but the re-integrated trajectory misses the '
                                  'tolerances')
        return result
