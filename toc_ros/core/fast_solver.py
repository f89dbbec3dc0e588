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
(prefetch.py), with the same result as after all attempts.  With several circles they are
added lazily: first none, then the classes of the circles that solution hits (class_starts.py).
The run on one grid is ip_run.py's, its starting points and resampling start_points.py's,
how runs execute on the threads and are recorded run_execution.py's, the coarse optima's
climb to the N grid refinement.py's.
A warm start (initial_guess: a previous SolveResult, or controls and t_f, e.g. the remainder of
the plan being executed) skips the coarse grid.
"""

import dataclasses

import numpy as np

from . import homotopy, ipm
from .class_starts import ClassStarts
from .fast_tuning import COARSE_INTERVALS, COLD_ATTEMPTS, EXPLORE_INTERVALS, EXPLORE_NONCONVEX, \
    EXPLORE_TIME, FIT_BAND, FIT_FACTORS, FIT_FACTORS_FOLDING, FOLD_ATTEMPT, FOLD_SOURCES, \
    FOLD_STARTS, FOLDING_SEARCHES, MU_COLD_RETRIES, MU_DRIFT, MU_EXACT, MU_WARM, WARM_BUDGET, \
    WARM_EXACT, WARM_PUSH
from .ip_run import BOUND_PUSH, Stop
from .ipm_workspace import H_DELTA
from .refinement import Refinement, same_optimum
from .result import SolveResult, Status
from .run_execution import RunExecution
from .start_points import actuator_states, fitted_final_time, fold_starts, has_actuators, \
    interpolation_start, interpolation_states, start_along, warm_start_point

CODE_STATUS = {ipm.CONVERGED: Status.SOLVED, ipm.ITERATION_LIMIT: Status.MAX_ITERATIONS,
               ipm.LINE_SEARCH_FAILED: Status.STALLED, ipm.NUMERICAL_FAILURE: Status.STALLED}


def _guess_intervals(guess):
    if guess is None:
        return 0
    controls = guess.controls if isinstance(guess, SolveResult) else guess[0]
    return int(np.shape(controls)[0])


class FastSolve(Refinement, ClassStarts, RunExecution):
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
        self.offset = 0          # iterations of earlier cold searches (_cold_searches)
        self.history = []
        self.run = None
        self.best = None         # the shortest converged run on the N grid so far
        self.narrow = False      # climbs without the far circles (_narrowed; lazy solves)
        self.fit_mu = FOLDING_SEARCHES[0]    # first mu of the fitted attempts (None: none)
        self.attempts = {}       # _attempt's runs by their start, shared by the cold searches

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
            elif has_actuators(problem.robot_model):
                run, code = self._cold_actuated(n)
            else:
                run, code = self._cold_searches(n)
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
        are refined (_finish), and when none of them refines the others, shortest first
        (_refine_others); with three or more joints, the folds of the attempts' best ones and
        of the refined result are attempted too (_fold_attempts).  When nothing converges, the
        N grid from the cold start with each barrier parameter of MU_COLD_RETRIES in turn (the
        central path from another mu can lead into another basin), unless the refinements
        spent the iteration limit (then the last one's point).
        """
        problem = self.problem
        grid = COARSE_INTERVALS if n > 2 * COARSE_INTERVALS else n
        found = []
        states = interpolation_states(problem, grid)
        # Class starts on a coarser grid still (their candidates are carried up by _finish like
        # the others); not when the coarse grid is the N grid (short horizons, cheap already).
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
            for t_f in self._fitted_times():
                if self.done < self.limit // 2:
                    self._attempt(grid, n, interpolation_start(problem, grid, t_f),
                                  (COLD_ATTEMPTS[0][0], self.fit_mu), found)
            self._fold_attempts(grid, n, found)
        if grid == n and found:
            # Ties (the same optimum from several starts, within 1e-6): the first attempt.
            shortest = min(run.t_f for run in found)
            return next(run for run in found if run.t_f <= (1.0 + 1e-6) * shortest), \
                ipm.CONVERGED
        if found:
            self._finish(found, n, allowance, prefetched)
            if self.best is None and grid < n:
                self._refine_others(found, n)
        if self.best is not None and grid < n:
            self._fold_attempts(n, n, [self.best])
        if self.best is not None:
            return self.best, ipm.CONVERGED
        if self.done >= self.limit and self.run is not None and self.run.n == n:
            # The budget went to refinements on the N grid: the last one's point (not a cold
            # run of the N grid with the one iteration left).
            return self.run, ipm.ITERATION_LIMIT
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

    def _cold_searches(self, n):
        """
        Return (run, code) of the cold start: _cold, or with 3+ joints the best of searches.

        Three or more joints: one whole cold search per FOLDING_SEARCHES entry (the first
        barrier parameter of its fitted attempts), each with the iteration limit as its own
        budget, the next one only within EXPLORE_TIME of a timeout; the shortest converged on
        the N grid is the result (ties: the earlier search).  Attempts an earlier search ran
        are not run again (self.attempts); the iterations run add up (and the history); when
        a search is stopped, a timeout returns the shortest converged so far.
        """
        run, code = self._cold(n)
        if self.problem.robot_model.n_joints < 3:
            return run, code
        for fit_mu in FOLDING_SEARCHES[1:]:
            if not self._within_explore_time():
                break
            other = FastSolve(self.problem, self.options, self.clock)
            other.fit_mu, other.attempts = fit_mu, self.attempts
            other.offset, other.history = self.offset + self.done, self.history
            converged = code == ipm.CONVERGED and run.n == n
            try:
                other_run, other_code = other._cold(n)
            except Stop:
                kept = [r for r in (run if converged else None, other.best) if r is not None]
                self.best = min(kept, key=lambda r: r.t_f) if kept else None
                self.run = other.run or self.run     # (None: it ran only shared attempts)
                raise
            finally:
                self.done += other.done
            if other_code == ipm.CONVERGED and other_run.n == n and (
                    not converged or other_run.t_f < run.t_f):
                run, code = other_run, other_code
        return run, code

    def _fold_attempts(self, grid, n, found):
        """
        Attempt other folds of the shortest converged runs' distal links (3+ joints).

        Optima of a free or obstructed motion of three or more links differ by which way the
        distal links fold (issue 23: elbow down or up under gravity, 3.2 % apart) and by how
        far the wrist whips, and the other folds are narrow basins that none of the
        interpolation starts reaches.  The FOLD_SOURCES shortest distinct runs of found (the
        converged ones on grid, which the attempts join), each with its distal joints'
        deviations from the straight interpolation scaled (fold_starts, the same timing),
        start them: mirrored for all distal joints, then for the wrist alone, the wrist's
        doubled, then each other distal joint's mirrored from the wrist inwards; at most
        FOLD_STARTS per source, with FOLD_ATTEMPT (a small barrier parameter: the start is a
        trajectory, not a guess).  Within three quarters of the iteration budget and, with a
        timeout, within EXPLORE_TIME of it.
        """
        problem = self.problem
        joints = problem.robot_model.n_joints
        if joints < 3 or not found:
            return
        wrist = joints - 1
        variants = [(tuple(range(1, joints)), -1.0), ((wrist,), -1.0), ((wrist,), 2.0)] + \
            [((j,), -1.0) for j in range(wrist - 1, 0, -1)]
        sources = []
        for run in sorted(found, key=lambda run: run.t_f):
            if not any(same_optimum(run, other) for other in sources):
                sources.append(run)
        for source in sources[:FOLD_SOURCES]:
            for start in fold_starts(problem, source.ws.x, source.t_f,
                                     variants[:FOLD_STARTS]):
                if self.done >= 3 * self.limit // 4 or not self._within_explore_time():
                    return
                self._attempt(grid, n, start, FOLD_ATTEMPT, found)

    def _fitted_times(self):
        """
        Return the final times [s] of the cold starts that fit the problem (FIT_FACTORS).

        Those off the problem's t_f0 by more than FIT_BAND, in order; none when the fitted
        time cannot be formed (fitted_final_time) or t_f0 is within FIT_BAND of it.  A model
        of three or more joints: every one of FIT_FACTORS_FOLDING, whatever t_f0 (its optima
        differ by how the links fold, and starts of other timing reach other folds).
        """
        fitted = None if self.fit_mu is None else fitted_final_time(self.problem)
        if fitted is None:
            return []
        if self.problem.robot_model.n_joints >= 3:
            return [factor * fitted for factor in FIT_FACTORS_FOLDING]
        t_f0 = float(self.problem.t_f0)
        if max(fitted, t_f0) <= FIT_BAND * min(fitted, t_f0):
            return []
        return [factor * fitted for factor in FIT_FACTORS
                if max(factor * fitted, t_f0) > FIT_BAND * min(factor * fitted, t_f0)]

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
            inner_run, code = inner._cold_searches(n)
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

    def _attempt(self, grid, n, start, pair, found):
        """
        Run one cold attempt (elastic weight, mu) on grid; append it to found if converged.

        An attempt an earlier cold search ran (the same start, pair and budget: the first
        one, folds of the same optimum) is taken from self.attempts, not run again.
        """
        states, controls, t_f = start
        rho, mu = pair
        budget = min(max(1, self.limit // (8 if grid < n else 4)), max(1, self.limit - self.done))
        key = (grid, rho, mu, budget, float(t_f), np.asarray(states, dtype=float).tobytes(),
               np.asarray(controls, dtype=float).tobytes())
        if key not in self.attempts:
            self.attempts[key] = self._solve_on(grid, states, controls, t_f, mu, elastic=rho,
                                                budget=budget)
        run, code = self.attempts[key]
        if code == ipm.CONVERGED:
            found.append(run)
            if grid == n and (self.best is None or run.t_f < self.best.t_f):
                self.best = run     # what a timeout during the further attempts returns
        return run, code

    def _may_explore(self):
        """Return whether a further cold attempt may start (obstacles, budget and time)."""
        if not len(self.problem.obstacles) or self.done >= self.limit // 2:
            return False
        return self._within_explore_time()

    def _within_explore_time(self):
        """Return whether, with a timeout, less than EXPLORE_TIME of it has passed."""
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
        shifted = np.count_nonzero(run.ws.hist[:run.iterations, H_DELTA] > 0.0)
        return code != ipm.CONVERGED or shifted > EXPLORE_NONCONVEX

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
