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
solve(Problem(model=ArmRobot(arm, spheres), ...)) for URDF arms: checks, fast mode, result.

For an arm the Problem's fields mean: x0 / x_goal the states (q_1..q_n, dq_1..dq_n), positions
first (n values: velocities 0); obstacles rows (cx, cy, cz, R) [m] in the base frame; margin
[m] added to every sphere pair's radii; n_intervals N; integrator 'euler' or 'rk4' (RK4
steps cost 4 derivative calls an interval, their curvature 4 (3n + 1): rk4_steps.py); t_f0
only for paper mode, which starts from it as the paper does (fast mode's cold start times its
own path).  Paper mode runs the section-3 heuristic in joint accelerations (arm_paper.py),
explicit Euler only (PAPER_RK4_REFUSAL).

Self-collision between the spheres' self_pairs (non-adjacent links, no margin) is
constrained at every node when ArmRobot.self_collision is True (start and goal are then
checked for it too); otherwise it is only reported (self_clearance), outside the SOLVED test.

The returned states are the controls re-integrated with pinocchio.aba (in the solver's
arithmetic, arm_warm.rollout; the problem's integrator, the same h = t_f / N) from x0; every
limit and clearance is measured on them at every node k = 0..N (ArmViolations), the
velocities from node 1 on (the start's are given, and may exceed their limits by
START_VELOCITY_SLACK).
"""

import collections
import dataclasses
import math
import threading
import time
from typing import Optional

import numpy as np

from .arm_eval import ArmEvaluator
from .arm_ipm import ArmInteriorPoint, MU_INIT, PROX_GUARDED, T_HIGH, T_LOW
from .arm_paper import solve_arm_paper
from .arm_warm import rollout, UnusableGuess, warm_point
from .clearances import (check_obstacles, obstacle_clearance, self_clearance,
                         sphere_kinematics_batch)
from .coarse_grid import coarse_intervals, cold_solve
from .cold_runs import CHEAP_ITERATIONS, run_ipm, run_summary
from .model import ArmError, ArmModel
from .polish import polish
from .spheres import check_spheres_fit, default_spheres, Spheres
from .validate import check_holdable, check_not_leaving, check_state
from ..problem import finite_number
from ..result import CLEARANCE_TOL, Progress, SolveResult, Status, TERMINAL_TOL, Violations

# Positions and velocities of the re-integrated states may exceed a bound by rounding only.
BOUND_TOL = 1e-9
MAX_INTERVALS = 100000
# Why paper mode for an arm takes explicit Euler only (also solver_node's parameter check).
PAPER_RK4_REFUSAL = ('is not offered for URDF arms in paper mode: its controls are the joint '
                     'accelerations, whose torques RNEA(q, v, a) reproduce the plan under '
                     "explicit Euler steps only; use 'euler' (or fast mode for RK4)")
# A start may exceed a velocity limit by this fraction: a measured state that the tracking
# carried past a limit the plan rides (replanning from it must be possible); the plan keeps
# every limit from node 1 on when the efforts can slow the joint down that fast (else the
# solve fails).  A goal keeps the limits exactly.
START_VELOCITY_SLACK = 0.1
# Warm starts (arm_warm.py): at most WARM_BUDGET iterations before the cold start takes over;
# every guess is pushed WARM_PUSH inside its bounds.  With its multipliers, a guess from
# within WARM_EXACT [rad, rad/s] of the start begins at the last barrier parameter of a solve
# (MU_WARM_EXACT = tol / 10), one the robot drifted from at MU_WARM_DRIFT (at 1e-9 or 1e-8
# drifts of 0.01-0.03 rad failed on the Panda at N = 50 and fell back to the cold start; at
# 1e-7 none did, RESULTS "Arms: warm replanning"); without them at the cold start's MU_INIT.
WARM_BUDGET = 60
WARM_EXACT = 1e-6
MU_WARM_EXACT = 1e-9
MU_WARM_DRIFT = 1e-7
# A guess with multipliers within WARM_NEAR of the start is tried at MU_WARM_EXACT first, for
# at most WARM_NEAR_BUDGET iterations, then at MU_WARM_DRIFT: on 1,046 replans of the
# benchmark and random Panda/UR5 motions (N = 50-200, drifts 1e-4 to 5e-3 rad with velocity
# errors up to 3x that) MU_WARM_EXACT alone took 3 iterations in the median against 6, and
# fell back to the cold start on 9 where MU_WARM_DRIFT did on 6 (benchmarks/RESULTS.md, "Warm
# starts near the plan").
WARM_NEAR = 1e-2
WARM_NEAR_BUDGET = 30
WARM_PUSH = 1e-6
# ... but a guess at the solution itself (within WARM_EXACT, with multipliers) only as far as
# strictly inside: its bounds' slacks are ~ mu / z, and a push of WARM_PUSH on a joint at its
# velocity limit would open Euler defects of 2e-6 that cost two iterations to close.
WARM_PUSH_EXACT = 1e-12
# A warm start with multipliers begins at the optimum of a neighbouring problem: its acceptable
# level (arm_ipm.py) needs this many iterations in a row, not the cold start's 10.  Where the
# last digits of the dual infeasibility are out of reach (arm_ipm's docstring: degenerate
# problems), the cold count cost Panda replans at N = 60 eight more iterations at the same
# t_f (benchmarks/RESULTS.md, "Arms: a payload ...").
WARM_ACCEPT_ITERATIONS = 3
# ... and it switches to the exact curvature (hessian='auto', cold_runs.py) after WARM_CHEAP cheap
# iterations, within its WARM_BUDGET (with the cold CHEAP_ITERATIONS it never did: a UR5 replan
# 1e-3 off its plan at N = 60 spent the 60 warm iterations, then 63 cold ones).
WARM_CHEAP = 15


@dataclasses.dataclass(frozen=True, eq=False)
class ArmRobot:
    """A URDF arm (ArmModel) with its collision spheres: the model of an arm Problem."""

    arm: ArmModel
    spheres: Optional[Spheres] = None
    self_collision: bool = False    # constrain the spheres' self_pairs (no margin) too

    def __post_init__(self):
        if not isinstance(self.arm, ArmModel):
            raise ArmError(f'ArmRobot needs an ArmModel (load_arm), got {type(self.arm).__name__}')
        if self.spheres is not None:
            check_spheres_fit(self.spheres, self.arm)
        if not isinstance(self.self_collision, (bool, np.bool_)):
            raise ArmError(f'self_collision must be True or False, got {self.self_collision!r}')
        if self.self_collision and self.spheres is None:
            raise ArmError("self-collision needs the arm's collision spheres (give a sphere "
                           'file)')

    @classmethod
    def shipped(cls, arm, self_collision=False):
        """
        Return the arm with its shipped spheres (Panda, UR5), or without spheres.

        Their self-collision pairs are constrained with self_collision, else only reported.
        """
        return cls(arm, default_spheres(arm, self_collision=True), self_collision)


def is_arm_model(model):
    """Return True for an ArmRobot or a bare ArmModel."""
    return isinstance(model, (ArmRobot, ArmModel))


@dataclasses.dataclass
class ArmViolations(Violations):
    """Violations of an arm trajectory (every node k = 0..N of the re-integrated states)."""

    max_position_excess: float = math.inf   # max(q - upper, lower - q, 0)
    max_velocity_excess: float = math.inf   # max(|dq| - velocity, 0), nodes 1..N
    self_clearance: float = math.inf        # worst self-collision clearance
    self_constrained: bool = False          # self_clearance is part of the SOLVED test

    def feasible(self):
        """Return True when within the SOLVED tolerances."""
        return not self.exceeded()

    def exceeded(self):
        """Return 'name value > tolerance' of every measure outside its SOLVED tolerance."""
        # (name, value, tolerance, a lower bound): NaN is outside every tolerance.
        checks = (('control excess', self.max_control_excess, 0.0, False),
                  ('terminal error', self.terminal_error, TERMINAL_TOL, False),
                  ('clearance', self.min_clearance, -CLEARANCE_TOL, True),
                  ('position excess', self.max_position_excess, BOUND_TOL, False),
                  ('velocity excess', self.max_velocity_excess, BOUND_TOL, False),
                  ('self clearance', self.self_clearance if self.self_constrained
                   else math.inf, -CLEARANCE_TOL, True))
        return [f'{name} {value:.3g} {"<" if below else ">"} {tol:.3g}'
                for name, value, tol, below in checks
                if not (value >= tol if below else value <= tol)]

    def as_dict(self):
        """Plain-float dict (JSON)."""
        out = super().as_dict()
        out.update({'max_position_excess': float(self.max_position_excess),
                    'max_velocity_excess': float(self.max_velocity_excess),
                    'self_clearance': float(self.self_clearance)})
        return out


def _robot(problem):
    model = problem.model
    if isinstance(model, ArmModel):
        return ArmRobot.shipped(model)
    return model


def _state(arm, values, what):
    try:
        x = np.array(values, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ArmError(f'{what} must be {arm.n} or {2 * arm.n} numbers, got {values!r}') from None
    if x.size == arm.n:
        x = np.concatenate([x, np.zeros(arm.n)])
    if x.size != 2 * arm.n:
        raise ArmError(f'{what} has {x.size} values; the arm has {arm.n} joints '
                       f'({", ".join(arm.joint_names)}): give Q1..Q{arm.n} [DQ1..DQ{arm.n}]')
    return x


# Goals that passed their checks (limits, mass matrix, collisions), most recent last: a
# replanning node sends the same goal again and again, and the checks cost about as much as a
# warm replan's iteration.  Keyed by everything they read; the entry holds the model and the
# spheres it was checked with (ids are reused once an object is gone).
_CHECKED_GOALS = collections.OrderedDict()
_CHECKED_GOALS_LOCK = threading.Lock()
CHECKED_GOALS = 32


def _check_goal(robot, spheres, xg, obstacles, margin):
    arm = robot.arm
    key = (id(arm.model), id(spheres), robot.self_collision, xg.tobytes(),
           np.asarray(obstacles, dtype=float).tobytes(), float(margin), arm.lower.tobytes(),
           arm.upper.tobytes(), arm.velocity.tobytes())
    with _CHECKED_GOALS_LOCK:
        held = _CHECKED_GOALS.get(key)
        if held is not None and held[0] is arm.model and held[1] is spheres:
            _CHECKED_GOALS.move_to_end(key)
            return
    check_state(arm, xg[:arm.n], xg[arm.n:], 'goal', spheres, obstacles, margin,
                self_collision=robot.self_collision)
    check_not_leaving(arm, xg[:arm.n], xg[arm.n:])
    with _CHECKED_GOALS_LOCK:
        _CHECKED_GOALS[key] = (arm.model, spheres)
        while len(_CHECKED_GOALS) > CHECKED_GOALS:
            _CHECKED_GOALS.popitem(last=False)


def check_arm_problem(problem, options):
    """(robot, x0, x_goal, obstacles) after every check; ArmError with the reason otherwise."""
    options.validate()
    robot = _robot(problem)
    arm = robot.arm
    if problem.integrator not in ('euler', 'rk4'):
        raise ArmError(f"integrator {problem.integrator!r}: use 'euler' or 'rk4'")
    if options.mode == 'paper' and problem.integrator != 'euler':
        raise ArmError(f'integrator {problem.integrator!r} {PAPER_RK4_REFUSAL}')
    if options.mode == 'paper' and not (finite_number(problem.t_f0)
                                        and T_LOW <= problem.t_f0 <= T_HIGH):
        raise ArmError(f't_f0 (paper mode starts from it) must be a number of seconds in '
                       f"[{T_LOW:g}, {T_HIGH:g}] (the arm solver's range of final times), got "
                       f'{problem.t_f0!r}')
    n_int = problem.n_intervals
    if (not isinstance(n_int, (int, np.integer)) or isinstance(n_int, bool)
            or not 2 <= n_int <= MAX_INTERVALS):
        raise ArmError(f'N must be an integer in [2, {MAX_INTERVALS}], got {n_int!r}')
    margin = problem.margin
    if not finite_number(margin) or margin < 0:
        raise ArmError(f'margin must be finite and >= 0 [m], got {margin!r}')
    obstacles = check_obstacles(problem.obstacles)
    if (len(obstacles) or robot.self_collision) and robot.spheres is None:
        raise ArmError("obstacles need the arm's collision spheres (give a sphere file)")
    x0 = _state(arm, problem.x0, 'start')
    xg = _state(arm, problem.x_goal, 'goal')
    spheres = robot.spheres if len(obstacles) or robot.self_collision else None
    check_state(arm, x0[:arm.n], x0[arm.n:], 'start', spheres, obstacles, margin,
                self_collision=robot.self_collision, velocity_slack=START_VELOCITY_SLACK)
    _check_goal(robot, spheres, xg, obstacles, margin)
    return robot, x0, xg, obstacles


def measure_arm(robot, x0, x_goal, controls, t_f, obstacles, margin, integrator='euler'):
    """(states (N + 1, 2n) re-integrated with pinocchio.aba, ArmViolations)."""
    # A diverged rollout (an open-loop unstable motion) is measured as what it is: inf / NaN
    # violations, without numpy's overflow warnings on the way.
    with np.errstate(over='ignore', invalid='ignore'):
        return _measure(robot, x0, x_goal, controls, t_f, obstacles, margin, integrator)


def _measure(robot, x0, x_goal, controls, t_f, obstacles, margin, integrator):
    arm = robot.arm
    n = arm.n
    controls = np.asarray(controls, dtype=float)
    states = rollout(arm, x0, controls, t_f, integrator)
    q, dq = states[:, :n], states[:, n:]
    clearance = self_clear = math.inf
    if robot.spheres is not None:
        centres, _ = sphere_kinematics_batch(robot.spheres, q)
        # Every node's spheres at once: the nodes' spheres stacked as one sphere set.
        count, n_spheres = centres.shape[:2]
        stacked = centres.reshape(-1, 3)
        radii = np.tile(robot.spheres.radii, count)
        if len(obstacles):
            clearance = float(np.min(obstacle_clearance(stacked, radii, obstacles, margin)))
        pairs = robot.spheres.self_pairs
        if len(pairs):
            node_pairs = (pairs[None] + n_spheres * np.arange(count)[:, None, None])
            self_clear = float(np.min(self_clearance(stacked, radii, node_pairs.reshape(-1, 2))))
    pos = max(float(np.max(q - arm.upper)), float(np.max(arm.lower - q)), 0.0)
    return states, ArmViolations(
        max_control_excess=max(float(np.max(np.abs(controls) - arm.effort)), 0.0),
        terminal_error=float(np.linalg.norm(states[-1] - x_goal)),
        min_clearance=clearance, max_position_excess=pos,
        max_velocity_excess=max(float(np.max(np.abs(dq[1:]) - arm.velocity)), 0.0),
        self_clearance=self_clear, self_constrained=robot.self_collision)


def _warm_runs(evaluator, x0, xg, warm, budget, should_stop, hessian, runs):
    """
    Run the interior point from a warm start; return (run, iterations, linalg time).

    A guess on this grid with its multipliers continues near the end of the barrier path (at
    the last barrier parameter when the start is within WARM_NEAR of it, else a little before
    it, and there again when the first try fails); any other guess restarts the path with the
    cold start's parameter but keeps its active bounds nearly active.  runs: the summaries.
    """
    states, torques, t_f, duals, drift = warm
    if duals is None:
        tries = ((MU_INIT, WARM_BUDGET),)
    elif drift <= WARM_EXACT:
        tries = ((MU_WARM_EXACT, WARM_BUDGET),)
    elif drift <= WARM_NEAR:
        tries = ((MU_WARM_EXACT, WARM_NEAR_BUDGET), (MU_WARM_DRIFT, WARM_BUDGET))
    else:
        tries = ((MU_WARM_DRIFT, WARM_BUDGET),)
    exact = duals is not None and drift <= WARM_EXACT
    run, iterations, linalg_time = None, 0, 0.0
    for mu, limit in tries:
        if run is not None and (run.status in ('converged', 'acceptable', 'stopped')
                                or iterations >= budget):
            break
        ipm = ArmInteriorPoint(evaluator, x0, xg, mu_init=mu)
        if duals is not None:
            ipm.accept_iterations = WARM_ACCEPT_ITERATIONS
            ipm.accept_at_start = exact
        ipm.start(states, torques, t_f, duals=duals, push=WARM_PUSH_EXACT if exact else WARM_PUSH,
                  prox=PROX_GUARDED if duals is None else None)
        run = run_ipm(ipm, min(budget - iterations, limit), should_stop, hessian,
                      CHEAP_ITERATIONS if duals is None else WARM_CHEAP)
        iterations += run.iterations
        linalg_time += ipm.linalg_time
        runs.append(f'warm start{" with multipliers" if duals else ""}'
                    f'{f" at mu = {mu:g}" if len(tries) > 1 else ""}: {run_summary(run)}')
    return run, iterations, linalg_time


def solve_arm(problem, options, progress=None, cancel=None, initial_guess=None,
              hessian='auto'):
    """Solve an arm Problem (fast or paper mode); never raises for bad input (INVALID_INPUT)."""
    started = time.monotonic()
    unusable = ''
    try:
        robot, x0, xg, obstacles = check_arm_problem(problem, options)
        n_int = problem.n_intervals
        evaluator = ArmEvaluator(robot.arm, robot.spheres, obstacles, problem.margin, n_int,
                                 robot.self_collision, problem.integrator)
        if options.mode == 'paper' and initial_guess is not None:
            raise ArmError('an initial guess is used by fast mode only')
        warm = None if initial_guess is None else warm_point(
            robot.arm, x0, initial_guess, n_int, evaluator.n_pairs, problem.integrator)
    except UnusableGuess as exc:
        warm, unusable = None, f'initial guess not used: {exc}'
    except (ArmError, ValueError, TypeError) as exc:
        return SolveResult(status=Status.INVALID_INPUT, message=str(exc),
                           mode=str(getattr(options, 'mode', '')),
                           integrator=str(getattr(problem, 'integrator', '')))
    deadline = None if options.timeout is None else started + options.timeout
    stop = {'why': None}

    def should_stop():
        if cancel is not None and cancel.is_set():
            stop['why'] = Status.CANCELED
        elif deadline is not None and time.monotonic() >= deadline:
            stop['why'] = Status.TIMEOUT
        return stop['why'] is not None

    if options.mode == 'paper':
        return _solve_paper(problem, options, robot, evaluator, x0, xg, obstacles, should_stop,
                            lambda: stop['why'], progress, started)
    budget = options.iteration_limit()
    iterations, linalg_time = 0, 0.0
    runs = [unusable] if unusable else []
    run = None
    if warm is not None:
        run, iterations, linalg_time = _warm_runs(evaluator, x0, xg, warm, budget, should_stop,
                                                  hessian, runs)
    if run is None or (run.status not in ('converged', 'acceptable', 'stopped')
                       and iterations < budget):
        # A poor guess is solved from scratch rather than reported as a failure.
        coarse = coarse_intervals(n_int, problem.integrator, evaluator.n_obstacle_rows)
        coarse_evaluator = None if coarse is None else ArmEvaluator(
            robot.arm, robot.spheres, obstacles, problem.margin, coarse, robot.self_collision,
            problem.integrator)
        run, cold_iterations, cold_linalg = cold_solve(
            robot, evaluator, coarse_evaluator, x0, xg, hessian, budget - iterations,
            should_stop, runs)
        iterations += cold_iterations
        linalg_time += cold_linalg
    controls = run.v * robot.arm.effort[None, :]
    states, violations = measure_arm(robot, x0, xg, controls, run.t, obstacles,
                                     problem.margin, problem.integrator)
    converged = run.status in ('converged', 'acceptable')
    polished = ''
    if converged and not violations.feasible():
        # The open-loop integration amplified the defects left at convergence: take them down
        # to rounding (polish.py), and keep that when it meets every tolerance.
        x, v, t_f, before, after = polish(evaluator, run.x, run.v, run.t)
        torques = v * robot.arm.effort[None, :]
        again = measure_arm(robot, x0, xg, torques, t_f, obstacles, problem.margin,
                            problem.integrator)
        if after < before and again[1].feasible():
            run.x, run.v, run.t = x, v, t_f
            controls = torques
            states, violations = again
            polished = f'; defects polished from {before:.1e} to {after:.1e}'
    diverged = not np.all(np.isfinite(states))
    if diverged:
        # Not "solved inaccurately": no finite motion comes out of these controls.  The
        # solver's own states (its dynamics' defects within tolerance) are returned instead.
        states = run.x.copy()
    if converged and violations.feasible():
        status = Status.SOLVED
    elif diverged:
        status = Status.STALLED
    elif converged:
        status = Status.SOLVED_INACCURATE
    elif run.status == 'stopped':
        status = stop['why']
    elif run.status == 'max_iterations':
        status = Status.MAX_ITERATIONS
    else:
        status = Status.STALLED
    message = (f'{"; ".join(runs)} (interior-point iterations, by start): t_f = {run.t:.6f} '
               f's, dual infeasibility {run.dual:.2e}, constraint violation {run.primal:.2e}'
               + polished)
    if diverged:
        message += (f'; the controls re-integrated from the start diverge (the '
                    f'{problem.integrator} steps of {run.t / n_int:.3g} s amplify the '
                    "solver's residual defects to overflow): more intervals shorten the steps; "
                    "the states are the solver's own")
    if status is Status.SOLVED_INACCURATE:
        # Converged, but the measures re-taken on the controls integrated again from the start
        # (open loop) miss a tolerance: say which, and why that can happen after convergence.
        why = (f" (open loop: the discretised motion amplifies the solver's residual defects, "
               f'{run.primal:.1e}, over the horizon; it is unstable)'
               if not violations.terminal_error <= TERMINAL_TOL else '')
        message += ('; SOLVED_INACCURATE: re-integrated from the start, '
                    + ', '.join(violations.exceeded()) + why)
    if status in (Status.STALLED, Status.MAX_ITERATIONS) and not np.any(xg[robot.arm.n:]):
        # A likely cause worth naming (not refused: a goal reached at rest for an instant is
        # a valid problem even when the efforts cannot hold it there).
        try:
            check_holdable(robot.arm, xg[:robot.arm.n])
        except ArmError as exc:
            message += f'; note: {exc}'
    history = np.zeros((run.history.shape[0], 4))
    if run.history.shape[0]:
        history[:, 0] = np.arange(1, run.history.shape[0] + 1)
        history[:, 1] = run.history[:, 0]
        history[:, 2] = run.history[:, 0]
        history[:, 3] = run.history[:, 1]
    result = SolveResult(status=status, message=message, mode='fast',
                         integrator=problem.integrator,
                         n_intervals=n_int, final_time=float(run.t), states=states,
                         controls=controls, iterations=iterations, history=history,
                         violations=violations, cost=float(run.t),
                         solver_state={'start': getattr(run, 'start_name',
                                                        runs[-1].split(':')[0]),
                                       'ipm_status': run.status, 'arm_duals': run.duals,
                                       # (the returned run's, one per iteration)
                                       'barrier_parameters': run.history[:, 3].copy(),
                                       'pin_calls': evaluator.pin_calls,
                                       'pin_time_s': evaluator.pin_time,
                                       'linalg_time_s': linalg_time})
    result.time_grid = np.linspace(0.0, run.t, n_int + 1)
    result.wall_time_s = time.monotonic() - started
    _report_done(progress, result)
    return result


def _solve_paper(problem, options, robot, evaluator, x0, xg, obstacles, should_stop,
                 stop_reason, progress, started):
    def measure(torques, t_f):
        return measure_arm(robot, x0, xg, torques, t_f, obstacles, problem.margin)

    result = solve_arm_paper(problem, options, robot, evaluator, x0, xg, should_stop,
                             stop_reason, progress, measure)
    result.wall_time_s = time.monotonic() - started
    _report_done(progress, result)
    return result


def _report_done(progress, result):
    """Send the last progress report of a solve ('done': its result's numbers)."""
    if progress is not None:
        progress(Progress(result.iterations, result.final_time, result.cost,
                          result.final_time if result.success else math.nan,
                          result.wall_time_s, 'done', result.violations))


__all__ = ['ArmRobot', 'ArmViolations', 'check_arm_problem', 'is_arm_model', 'measure_arm',
           'PAPER_RK4_REFUSAL',
           'solve_arm', 'CLEARANCE_TOL', 'TERMINAL_TOL']
