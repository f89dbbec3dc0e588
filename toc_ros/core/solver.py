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
Solver driver: validation, paper/fast mode, progress, cancel, timeout, result assembly.

solve() runs in the caller's thread in chunks, calls progress at least every
options.progress_period seconds and checks cancel (a threading.Event or any object with
is_set()) and the wall-clock timeout between chunks (well under 100 ms apart), returning the
best solution found so far with status CANCELED or TIMEOUT.
"""

from dataclasses import replace
import math
import time

import numpy as np

from .fast_solver import FastRun, FeasibilityProjector, Stop
from .integrators import integrator_id
from .paper_solver import PaperRun
from .problem import measure_violations, Problem, ProblemError, SolverOptions
from .result import Progress, SolveResult, Status

# Fast mode.  ALM_TOL: constraint tolerance of the augmented Lagrangian (tighter than the SOLVED
# tolerances of result.py, so the re-integrated trajectory passes them with margin).
ALM_TOL = 1e-9
# Grids of the coarse-to-fine ladder (those below N / 2 are used): the coarse solve finds the
# structure of the solution cheaply, each finer grid only moves it by the discretisation error.
LADDER = (100, 300)
PROLONG_RHO = 100.0          # penalty parameter a finer grid starts with (multipliers carried)
FINE_ALM_ROUNDS = 3          # warm-started ALM rounds on each finer grid ...
FINE_ALM_INNER = 1000        # ... of at most this many L-BFGS iterations each
# Feasibility bracketing on each grid: relative steps above the previous t_f tried until the
# projection succeeds, the assumed lower end of the bracket, the bisection steps (0.1 % / 2^8).
BRACKET_STEPS = (0.0, 2e-4, 1e-3, 5e-3, 2e-2, 0.1)
BRACKET_BELOW = 1e-3
BISECTION_STEPS = 8
# On the coarse grid the bracket reaches further down (the ALM stops once feasible).
COARSE_BRACKET_BELOW = 1e-2
COARSE_BISECTION_STEPS = 10


class _Clock:
    """Deadline, cancel flag and progress throttling shared by both modes."""

    def __init__(self, options, progress, cancel):
        self.start = time.monotonic()
        self.deadline = None if options.timeout is None else self.start + options.timeout
        self.progress = progress
        self.cancel = cancel
        self.period = options.progress_period
        self.last_report = -math.inf

    def elapsed(self):
        return time.monotonic() - self.start

    def stop_reason(self):
        if self.cancel is not None and self.cancel.is_set():
            return Status.CANCELED
        if self.deadline is not None and time.monotonic() >= self.deadline:
            return Status.TIMEOUT
        return None

    def report(self, make_progress, force=False):
        now = time.monotonic()
        # Half the period: the check runs between chunks, so gaps stay below the period.
        if self.progress is not None and (force or now - self.last_report >= 0.5 * self.period):
            self.last_report = now
            self.progress(make_progress())


def solve(problem, options=None, progress=None, cancel=None):
    """Solve a minimum-time problem; never raises for bad input (status INVALID_INPUT)."""
    options = SolverOptions() if options is None else options
    try:
        if not isinstance(problem, Problem):
            raise ProblemError('problem must be a toc_ros.core.Problem')
        if not isinstance(options, SolverOptions):
            raise ProblemError('options must be a toc_ros.core.SolverOptions')
        problem.validate()
        options.validate()
    except ProblemError as exc:
        return SolveResult(status=Status.INVALID_INPUT, message=str(exc),
                           mode=str(getattr(options, 'mode', '')),
                           integrator=str(getattr(problem, 'integrator', '')))
    clock = _Clock(options, progress, cancel)
    method = integrator_id(problem.integrator)
    if options.mode == 'paper':
        result = _solve_paper(problem, options, method, clock)
    else:
        result = _solve_fast(problem, options, method, clock)
    result.mode = options.mode
    result.integrator = problem.integrator
    result.n_intervals = problem.n_intervals
    result.wall_time_s = clock.elapsed()
    if result.has_trajectory:
        result.time_grid = np.linspace(0.0, result.final_time, problem.n_intervals + 1)
    clock.report(lambda: Progress(result.iterations, result.final_time, math.nan,
                                  result.final_time if result.success else math.nan,
                                  result.wall_time_s, 'done', result.violations), force=True)
    return result


def _finish(problem, controls, final_time, iterations, history, status, message):
    states, violations = measure_violations(problem, controls, final_time)
    return SolveResult(status=status, message=message, final_time=float(final_time),
                       states=states, controls=np.array(controls, dtype=float),
                       iterations=iterations, history=history, violations=violations)


def _solve_paper(problem, options, method, clock):
    run = PaperRun(problem, options, method)
    chunk = 1
    stopped = None
    diverged = False
    while run.done < options.iteration_limit():
        stopped = clock.stop_reason()
        if stopped is not None:
            break
        n_iter = min(chunk, options.iteration_limit() - run.done)
        t0 = time.monotonic()
        run.advance(n_iter)
        if not math.isfinite(run.last_j):
            diverged = True
            break
        per_iter = (time.monotonic() - t0) / n_iter
        # Chunks of ~25 ms keep progress, cancel and timeout responsive.
        chunk = max(1, min(5000, int(0.025 / max(per_iter, 1e-7))))
        clock.report(lambda: Progress(run.done, run.t_f, run.last_j, run.best_t_f,
                                      clock.elapsed(), 'paper'))
    accepted = run.best_box[2] > 0
    controls = run.best_controls if accepted else run.controls
    final_time = run.best_t_f if accepted else run.t_f
    history = run.history()
    if stopped is not None:
        return _finish(problem, controls, final_time, run.done, history, stopped,
                       f'{stopped.value.lower()} after {run.done} iterations')
    if diverged and not accepted:
        return SolveResult(status=Status.STALLED, iterations=run.done, history=history,
                           message=f'diverged (J_T not finite) after {run.done} iterations: the '
                           f'learning rate eta = {options.paper.eta} is too large for N = '
                           f'{problem.n_intervals}')
    if not accepted:
        return _finish(problem, controls, final_time, run.done, history,
                       Status.MAX_ITERATIONS,
                       f'J_T never fell below J_eps = {options.paper.j_eps} in '
                       f'{run.done} iterations (t_f0 = {problem.t_f0} s may be below t_min)')
    result = _finish(problem, controls, final_time, run.done, history, Status.SOLVED,
                     '')
    v = result.violations
    if v.feasible():
        result.message = f't_min = {final_time:.6f} s, feasible within tolerances'
    else:
        result.status = Status.SOLVED_INACCURATE
        result.message = (f'paper heuristic t_min = {final_time:.6f} s with residual '
                          f'violations: control excess {v.max_control_excess:.3g}, terminal '
                          f'error {v.terminal_error:.3g}, clearance {v.min_clearance:.3g} m')
    return result


class _FastDriver:
    """Augmented-Lagrangian outer loop over a coarse-to-fine ladder of horizons."""

    def __init__(self, problem, options, method, clock):
        self.problem = problem
        self.options = options
        self.method = method
        self.clock = clock
        self.iterations = 0
        self.history = []
        self.best_t_f = math.nan
        self.run = None
        self.last_value = math.nan

    def _callback(self, n_iter):
        self.iterations += n_iter
        run = self.run
        reason = self.clock.stop_reason()
        if reason is not None:
            raise Stop(reason)
        if self.iterations >= self.options.iteration_limit():
            raise Stop(Status.MAX_ITERATIONS)
        self.clock.report(lambda: Progress(self.iterations, float(run.z[-1]),
                                           self.last_value, self.best_t_f,
                                           self.clock.elapsed(), f'fast N={run.n}'))

    def _alm(self, run, final, feasibility_first=False, max_outer=60, max_inner=2000):
        """
        ALM outer loop on run; returns True when the constraints meet ALM_TOL.

        feasibility_first: first solve the penalty problem at the fixed t_f0 (a feasible
        starting trajectory) and start with a stiffer penalty; the default starts from rest
        with a soft one.  The two reach different local optima on some problems.
        """
        self.run = run
        prev = math.inf
        if feasibility_first:
            free_bounds = run.lower[-1], run.upper[-1]
            run.lower[-1] = run.upper[-1] = run.z[-1]
            run.rho = 1e3
            run.value_gradient(run.z)
            run.solve_subproblem(2000, self._callback)
            run.lower[-1], run.upper[-1] = free_bounds
        run.value_gradient(run.z)
        for _ in range(max_outer):
            # Inexact inner solves while far from feasible (augmented-Lagrangian practice).
            run.solve_subproblem(max_inner, self._callback,
                                 gtol=max(1e-10, min(1e-3, 0.1 * prev)))
            term, deficit = run.violation()
            viol = max(term, deficit)
            self.last_value = float(run.z[-1])
            self.history.append((self.iterations, float(run.z[-1]), viol))
            if viol < ALM_TOL:
                if final:
                    self.best_t_f = float(run.z[-1])
                return True
            run.update_multipliers()
            if viol > 0.25 * prev:
                run.rho = min(run.rho * 10.0, 1e12)
            prev = viol
        return False

    def _best_start(self, problem):
        """ALM from both starting strategies on problem; the feasible run with least t_f."""
        best = None
        for feasibility_first in (False, True):
            run = FastRun(problem, self.method)
            if self._alm(run, final=False, feasibility_first=feasibility_first):
                if best is None or run.z[-1] < best.z[-1]:
                    best = run
        return best

    def _check(self):
        reason = self.clock.stop_reason()
        if reason is not None:
            raise Stop(reason)
        run = self.run
        self.clock.report(lambda: Progress(self.iterations, float(run.z[-1]), self.last_value,
                                           self.best_t_f, self.clock.elapsed(),
                                           f'refine N={run.n}'))

    def _refine(self, fine, below=None, steps=None):
        """
        Carry the coarse optimum to the fine grid: feasibility projection + bisection on t_f.

        The coarse and fine discrete optima differ by the discretisation error (O(1/N)), so
        the fine minimum time is bracketed near the coarse one: step up until the projection
        finds a feasible trajectory, then bisect down between the last failure and it.
        """
        self.run = fine
        proj = FeasibilityProjector(fine)
        v0 = fine.z[:-1].copy()
        t0 = float(fine.z[-1])
        low = t0 * (1.0 - (BRACKET_BELOW if below is None else below))
        best = None
        for eps in BRACKET_STEPS:
            ok, v = proj.project(v0, t0 * (1.0 + eps), check=self._check)
            self.iterations += 1
            if ok:
                best, high = v, t0 * (1.0 + eps)
                break
            low = t0 * (1.0 + eps)
        if best is None:
            return False
        self.best_t_f = high
        for _ in range(BISECTION_STEPS if steps is None else steps):
            mid = 0.5 * (low + high)
            ok, v = proj.project(best, mid, check=self._check)
            self.iterations += 1
            if ok:
                best, high = v, mid
                self.best_t_f = high
            else:
                low = mid
            self.history.append((self.iterations, mid, 0.0 if ok else math.nan))
        fine.z[:-1] = best
        fine.z[-1] = high
        return True

    def solve(self):
        problem = self.problem
        n = problem.n_intervals
        fine = FastRun(problem, self.method)
        self.run = fine
        try:
            ladder = [m for m in LADDER if 2 * m < n] + [n]
            start = self._best_start(_with_intervals(problem, ladder[0]))
            if start is not None:
                # The ALM stops once feasible; a cheap bisection on the coarse grid recovers
                # what its inexact sub-problems left of the minimum time.
                self._refine(start, below=COARSE_BRACKET_BELOW, steps=COARSE_BISECTION_STEPS)
            if start is None:
                converged = False
            elif len(ladder) == 1:
                fine = start
                converged = True
                self.best_t_f = float(fine.z[-1])
            else:
                prev = start
                converged = True
                for m in ladder[1:]:
                    run = fine if m == n else FastRun(_with_intervals(problem, m), self.method)
                    _prolong(prev, run)
                    prolonged = run.z.copy()
                    # A few warm-started ALM rounds re-optimise on this grid (the optimum moves
                    # by the discretisation error); the projection then makes it exactly feasible.
                    self._alm(run, final=False, max_outer=FINE_ALM_ROUNDS,
                              max_inner=FINE_ALM_INNER)
                    refined = self._refine(run)
                    if not refined:
                        # The rounds can wander off on hard problems: bracket from the
                        # prolonged coarse solution instead.
                        run.z[:] = prolonged
                        refined = self._refine(run)
                    if not refined:
                        # The bracket failed: plain ALM on this grid from the warm start.
                        if not self._alm(run, final=m == n):
                            converged = False
                            break
                    prev = run
        except Stop as stop:
            reason = stop.args[0]
            return self._result(fine if self.run is fine else None, reason,
                                f'{reason.value.lower()} after {self.iterations} iterations')
        if not converged:
            return self._result(fine, Status.STALLED,
                                'augmented Lagrangian did not reach the tolerances')
        return self._result(fine, Status.SOLVED, '')

    def _result(self, run, status, message):
        history = np.array(self.history, dtype=float).reshape(-1, 3)
        if run is None:       # stopped on the coarse level: no fine trajectory yet
            return SolveResult(status=status, message=message, iterations=self.iterations,
                               history=history)
        result = _finish(self.problem, run.controls(), float(run.z[-1]), self.iterations,
                         history, status, message)
        if status is Status.SOLVED:
            if result.violations.feasible():
                result.message = f't_min = {result.final_time:.6f} s'
            else:
                result.status = Status.STALLED
                result.message = ('converged, but the re-integrated trajectory misses the '
                                  'tolerances')
        return result


def _solve_fast(problem, options, method, clock):
    return _FastDriver(problem, options, method, clock).solve()


def _with_intervals(problem, n):
    return replace(problem, n_intervals=n)


def _prolong(coarse, fine):
    """Warm start the fine level from the coarse one (piecewise-constant in time)."""
    idx = (np.arange(fine.n) * coarse.n) // fine.n
    v = coarse.z[:-1].reshape(coarse.n, 2)
    fine.z[:-1] = v[idx].ravel()
    fine.z[-1] = coarse.z[-1]
    fine.lam[:] = coarse.lam
    k = coarse.circles.shape[0]
    if k:
        mu = coarse.mu.reshape(coarse.n, k)
        fine.mu[:] = (mu[idx] * coarse.n / fine.n).ravel()
    fine.rho = PROLONG_RHO


def warm_up():
    """Compile (or load from cache) every numba kernel, so no user request pays for it."""
    for integrator in ('euler', 'rk4'):
        tiny = replace(Problem(), n_intervals=20, integrator=integrator)
        solve(tiny, SolverOptions(mode='paper', max_iterations=2))
        solve(tiny, SolverOptions(mode='fast', max_iterations=3))
        run = FastRun(tiny, integrator_id(integrator))
        FeasibilityProjector(run).project(run.z[:-1], tiny.t_f0, max_iter=1)
