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

from . import homotopy
from .fast_solver import FastSolve
from .models.cylindrical import CylindricalRobot
from .paper_solver import next_chunk, PaperRun
from .problem import measure_violations, Problem, ProblemError, SolverOptions
from .result import Progress, SolveResult, Status
from .start_points import warm_start_point


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


def solve(problem, options=None, progress=None, cancel=None, initial_guess=None):
    """
    Solve a minimum-time problem; never raises for bad input (status INVALID_INPUT).

    initial_guess (fast mode): a previous SolveResult, or a pair (controls (M x nu), t_f) such
    as the remainder of a plan from the node the robot has reached; resampled to the problem's
    N.  A guess that does not lead to convergence falls back to a cold start.
    """
    options = SolverOptions() if options is None else options
    if _is_arm_problem(problem) and isinstance(options, SolverOptions):
        # URDF arms (Pinocchio): their own checks and interior point (core/arms/arm_solve.py).
        from .arms.arm_solve import solve_arm
        return solve_arm(problem, options, progress, cancel, initial_guess)
    start_point = None
    try:
        if not isinstance(problem, Problem):
            raise ProblemError('problem must be a toc_ros.core.Problem')
        if not isinstance(options, SolverOptions):
            raise ProblemError('options must be a toc_ros.core.SolverOptions')
        problem.validate()
        options.validate()
        if options.mode == 'paper' and not isinstance(problem.model, CylindricalRobot):
            raise ProblemError("paper mode is the paper's heuristic for the cylindrical robot "
                               'of eq. (37) only; use mode fast for other models')
        if initial_guess is not None:
            if options.mode != 'fast':
                raise ProblemError('an initial guess is used by fast mode only')
            try:
                # Checked here, used by fast mode (not computed twice: a rollout and resampling).
                start_point = warm_start_point(problem, initial_guess, problem.n_intervals)
            except (TypeError, ValueError) as exc:
                raise ProblemError(f'bad initial guess: {exc}')
        _check_resolution(problem, problem.t_f0 if start_point is None else start_point[2])
    except ProblemError as exc:
        return SolveResult(status=Status.INVALID_INPUT, message=str(exc),
                           mode=str(getattr(options, 'mode', '')),
                           integrator=str(getattr(problem, 'integrator', '')))
    clock = _Clock(options, progress, cancel)
    if options.mode == 'paper':
        result = _solve_paper(problem, options, problem.integrator_id, clock)
    else:
        result = _solve_fast(problem, options, clock, initial_guess, start_point)
    result.mode = options.mode
    result.integrator = problem.integrator
    result.n_intervals = problem.n_intervals
    result.wall_time_s = clock.elapsed()
    if result.has_trajectory:
        result.time_grid = np.linspace(0.0, result.final_time, problem.n_intervals + 1)
    clock.report(lambda: Progress(result.iterations, result.final_time, result.cost,
                                  result.final_time if result.success else math.nan,
                                  result.wall_time_s, 'done', result.violations), force=True)
    return result


def _is_arm_problem(problem):
    """Return True for a Problem whose model is a URDF arm (imported only when used)."""
    model = getattr(problem, 'model', None)
    return isinstance(problem, Problem) and type(model).__module__.startswith(
        'toc_ros.core.arms')


def _check_resolution(problem, t_f):
    """Refuse a grid too coarse for the model's fast states (actuator lags: max_step)."""
    step = problem.robot_model.max_step
    n = problem.n_intervals
    if t_f / n > step * (1.0 + 1e-9):
        raise ProblemError(
            f'N = {n} intervals is too coarse for the model: steps t_f / N up to {step:.4g} s '
            f'resolve its actuators (robot.actuator_lag / 2.5), the final time (guess) '
            f'{t_f:.4g} s needs N >= {math.ceil(t_f / step)}')


def _finish(problem, controls, final_time, iterations, history, status, message):
    states, violations = measure_violations(problem, controls, final_time)
    cost = float(history[-1, 2]) if history.shape[0] else math.nan
    return SolveResult(status=status, message=message, final_time=float(final_time),
                       states=states, controls=np.array(controls, dtype=float),
                       iterations=iterations, history=history, violations=violations,
                       cost=cost)


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
        chunk = next_chunk((time.monotonic() - t0) / n_iter)
        clock.report(lambda: Progress(run.done, run.t_f, run.last_j, run.best_t_f,
                                      clock.elapsed(), 'paper'))
    accepted = run.accepted[0] > 0
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
    result.cost = float(run.best_cost[0])      # J_T of the returned (last accepted) iteration
    v = result.violations
    if v.feasible():
        result.message = f't_min = {final_time:.6f} s, feasible within tolerances'
    else:
        result.status = Status.SOLVED_INACCURATE
        result.message = (f'paper heuristic t_min = {final_time:.6f} s with residual '
                          f'violations: control excess {v.max_control_excess:.3g}, terminal '
                          f'error {v.terminal_error:.3g}, clearance {v.min_clearance:.3g} m')
    return result


def _solve_fast(problem, options, clock, initial_guess, start_point=None):
    return FastSolve(problem, options, clock, initial_guess, start_point).solve()


def warm_up_for(problem, options):
    """
    Compile (or load from the cache) the kernels that solving this problem uses.

    A model file's kernels compile on their first solve; calling this first keeps that compile
    out of the solve's time limit (a cold cache costs minutes of CPU on a busy machine).
    """
    tiny = replace(problem, n_intervals=min(problem.n_intervals, 20))
    budget = 2 if options.mode == 'paper' else 3
    solve(tiny, replace(options, max_iterations=budget, timeout=None))


def warm_up(models=None):
    """Compile (or load from cache) every numba kernel, so no user request pays for it."""
    homotopy.warm_up()
    for integrator in ('euler', 'rk4'):
        tiny = Problem.paper(n_intervals=20, integrator=integrator)
        solve(tiny, SolverOptions(mode='paper', max_iterations=2))
        solve(tiny, SolverOptions(mode='fast', max_iterations=3))
        for model in models or ():
            solve(replace(tiny, obstacles=(), x0=tuple(model.state(np.zeros(model.n_joints))),
                          x_goal=tuple(model.state(np.full(model.n_joints, 0.1))),
                          ).with_model(model), SolverOptions(mode='fast', max_iterations=3))
