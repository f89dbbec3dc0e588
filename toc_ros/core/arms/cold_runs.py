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
The cold start of an arm solve: its starts, tried in turn, and the best converged run kept.

The line start when it clears the obstacles; around them the free optimum (solved first)
bent clear in up to FREE_BENDS ways, LINE_DETOURS bent lines and the colliding line itself
(start_points), each run within its budget, a settled run above the best abandoned, the search
ended at the free optimum's time (cold_runs).  run_ipm: one run with the curvature model 'auto'
(cheap, then exact where the cheap one stalls), also for solve_arm's warm starts.
"""

import numpy as np

from .arm_eval import ArmEvaluator
from .arm_ipm import ArmInteriorPoint, MU_INIT_RETRY
from .arm_start import (bent_states, cold_start, cubic_path, detour_offsets,
                        line_detour_makers, line_detours, line_time, path_torques, timed_start)

# When no start converges after a failure: one more run from the line slowed down this much.
RETRY_SLOWDOWN = 1.5
# Curvature of the dynamics (arm_ipm.py's hessian) with hessian='auto': CHEAP_MODEL first
# (one Pinocchio derivative call per interval, enough for most problems), then exact (2n + 1
# calls) from the same iterate, multipliers and barrier parameter once the run has not
# converged after CHEAP_ITERATIONS or its line search failed: where the dynamics' curvature
# matters the cheap model wanders without converging (benchmarks/RESULTS.md, "Arms: exact
# curvature when the cheap model stalls").  The cheap model keeps the final time's exact
# curvature with the states and controls ('cross', free from the same call): against none,
# the same final times on 126 random arm motions, iterations -1 to -5 %, the Panda past a
# sphere at N = 100 23 -> 19 (benchmarks/RESULTS.md, "Arms: the final time's curvature").
CHEAP_MODEL = 'cross'
CHEAP_ITERATIONS = 60
# ... or sooner, once the cheap model stops making progress: STALL_STEPS steps in a row
# shorter than STALL_ALPHA at the last barrier parameter (the steps it lacks the curvature
# for run into the bounds: UR5 past a sphere, 30 such steps at the final t_f to 7 digits
# before the 60th iteration), or, with the barrier parameter at 1e-6 or below (STALL_MU:
# room for mu^1.5's rounding), STALL_WINDOW iterations at one barrier parameter that did
# not halve the larger of the KKT error and the constraint violation (runs around a sphere
# wandering 50 iterations at t_f to 5 digits; a refining run's full steps at a rate of 0.97
# per iteration).  With the exact phase's tensor reused (arm_eval.TENSOR_REUSE) and the
# progress rule: random arm suites past a sphere 9-13 % less time, the same final times
# (benchmarks/RESULTS.md, "Arms: the cheap model's stalls by progress").
STALL_STEPS = 6
STALL_ALPHA = 0.5
STALL_MU = 2e-6
STALL_WINDOW = 15
# Around obstacles (arm_start.py, cold_runs): the free optimum (solved within FREE_BUDGET
# iterations) bent clear of them in up to FREE_BENDS distinct ways, then up to LINE_DETOURS
# bent lines.  Each start finds the optimum of its own way around the obstacles; with one
# bend 3 of 20 random one-sphere cases ended 0.7-10 % above the best of three
# (benchmarks/RESULTS.md, "Arms: more ways around a sphere").
LINE_DETOURS = 2
FREE_BENDS = 3
FREE_BUDGET = 300
# A start whose run has settled (barrier parameter at most 1e-6, SETTLED_MU leaving room for
# mu^1.5's rounding, and constraint violation <= SETTLED_PRIMAL: its t_f then moves by less
# than 0.1 %) more than ABANDON_GAP above the best converged start's t_f is abandoned: it is
# converging to a worse way around.
SETTLED_MU = 2e-6
SETTLED_PRIMAL = 1e-5
ABANDON_GAP = 2e-3
# ... and so is a start settled at or above the best t_f whose joint path lies within
# DUPLICATE_PATH [rad] of the best's at every node: it is converging to the same way around
# (runs settled at 1e-6 on the best's optimum: 0.1 rad off its path; on another way around:
# more than 1 rad).  It cannot end more than 0.1 % below the best; on 60 random motions past
# a sphere every final time stayed the same to 6 digits.
DUPLICATE_PATH = 0.2
# ... and so is a start whose run, once its first barrier problem is solved (the first iteration
# after the barrier parameter falls), lies within REPEAT_PATH [rad] of an earlier start's run at
# that point at every node, its t_f within REPEAT_TIME (relative): from there it follows the same
# barrier path to the same end, and the earlier run has ended (converged, or abandoned itself).
# Searches around a sphere often reach one optimum from several starts (benchmarks/RESULTS.md,
# "Arms: starts that repeat an earlier run").
REPEAT_PATH = 1e-2
REPEAT_TIME = 1e-3
# Every start but the last gets at most START_BUDGET iterations; the last one the rest of the
# budget only when no start converged (a UR5 case spent 1727 iterations there, 11 s, after a
# start had converged in 86).
START_BUDGET = 150
# A run within this (relative) of the free optimum's time ends the search of the starts.
FREE_REACHED = 1e-7
# The free optimum is a start and a bound, not a result: its run ends at IPOPT's acceptable
# tolerances, its barrier parameter still falling to a converged run's last (the Panda past a
# sphere: its final time 4.7e-9 from the converged one, well inside FREE_REACHED, one
# iteration fewer; with the barrier parameter's floor raised as well, 8.8e-6 and none).
FREE_TOL = 1e-6
FREE_CONSTR_TOL = 1e-7
FREE_MU_MIN = 1e-9          # (the last barrier parameter of a run at the default tolerance)


def slowed(arm, x0, x_goal, n_int, t_f):
    """(states, torques) of the cubic line start over the final time t_f."""
    states = cubic_path(x0, x_goal, t_f, n_int)
    return states, np.clip(path_torques(arm, states, t_f), -arm.effort, arm.effort)


def start_point(robot, evaluator, x0, x_goal, n_int):
    """(states, torques, t_f, name): the line start, or a detour when the line collides."""
    states, torques, t_f = cold_start(robot.arm, x0, x_goal, n_int)
    if evaluator.n_pairs and evaluator.clearances(states[:, :robot.arm.n]).min() < 0.0:
        detours = line_detours(robot.arm, evaluator, x0, x_goal, n_int)
        if detours:
            return (*detours[0], 'detour')
    return states, torques, t_f, 'line'


def start_points(robot, evaluator, x0, x_goal, n_int, line, free=None):
    """
    Yield (name, make, last): the starts a cold solve tries, in order.

    make() -> (states, torques, t_f); last is True for the last start (the line).

    line: cold_start's (states, torques, t_f).  The line start when it clears every sphere
    row; otherwise the free optimum (free: its (states, torques, t_f), solved without the
    obstacles) as it is when it clears them, else bent clear of them in up to FREE_BENDS
    distinct ways, then LINE_DETOURS distinct bent lines, then the colliding line (last: True).
    Each bend is found when it is asked for and each start timed by its make(): the search
    often ends at the first (the Panda past a sphere: finding all five bends took 2-4 ms).
    """
    arm, n = robot.arm, robot.arm.n
    if not evaluator.n_pairs or evaluator.clearances(line[0][:, :n]).min() >= 0.0:
        yield 'line', lambda: line, True
        return
    if free is not None:
        states, torques, t_f = free
        if evaluator.clearances(states[:, :n]).min() >= 0.0:
            yield 'free optimum', lambda: free, False
        else:
            rate = states[:, n:] * t_f
            for offsets in detour_offsets(arm, evaluator, states[:, :n], FREE_BENDS):
                yield 'free optimum bent', lambda o=offsets: timed_start(
                    arm, lambda t: bent_states(states[:, :n], rate, o, t), t_f), False
    for make in line_detour_makers(arm, evaluator, x0, x_goal, n_int, LINE_DETOURS):
        yield 'detour', make, False
    # Last the colliding line itself: the sphere rows' slacks let the interior point start
    # inside an obstacle, and from there it sometimes reaches a way around that no bend
    # takes (xArm7: 0.3 % faster on two of four motions), or fails within a few iterations.
    yield 'line', lambda: line, True


def run_ipm(ipm, budget, should_stop, hessian, cheap=CHEAP_ITERATIONS):
    """Run ipm within budget iterations with the curvature hessian ('auto': see above)."""
    if hessian != 'auto':
        ipm.hessian = hessian
        return ipm.run(budget, should_stop)
    # (RK4 steps have no cheap cross curvature: rk4_steps.py)
    ipm.hessian = CHEAP_MODEL if ipm.ev.integrator == 'euler' else 'none'
    watch = _stall_watch(ipm, should_stop)
    run = ipm.run(min(budget, cheap), watch)
    if (not (watch.stalled or run.status in ('max_iterations', 'line_search_failed'))
            or run.iterations >= budget):
        return run
    ipm.hessian = 'exact'
    rest = ipm.run(budget - run.iterations, should_stop)
    rest.iterations += run.iterations
    rest.history = np.vstack([run.history, rest.history])
    rest.exact_from = run.iterations
    return rest


def _stall_watch(ipm, should_stop):
    """should_stop for the cheap phase that also fires (.stalled) once it stalls (above)."""
    def stop():
        if should_stop is not None and should_stop():
            return True
        short = (ipm.at_last_barrier() and ipm.last_alpha is not None
                 and ipm.last_alpha < STALL_ALPHA)
        stop.count = stop.count + 1 if short else 0
        if ipm.mu > STALL_MU or ipm.mu != stop.mu:
            stop.errors, stop.mu = [], ipm.mu
        stop.errors.append(max(ipm.e0, ipm.primal))
        slow = (len(stop.errors) > STALL_WINDOW
                and stop.errors[-1] > 0.5 * stop.errors[-1 - STALL_WINDOW])
        stop.stalled = stop.count >= STALL_STEPS or slow
        return stop.stalled
    stop.count, stop.stalled, stop.errors, stop.mu = 0, False, [], None
    return stop


def _free_optimum(robot, evaluator, x0, xg, line, hessian, budget, should_stop):
    """
    ((states, torques, t_f) or None, iterations, Riccati time): solved without obstacles.

    From line; its Pinocchio calls and time are added to evaluator's counters (the solve's
    time split covers every run).
    """
    states, torques, t_f = line
    free = ArmEvaluator(robot.arm, robot.spheres, np.zeros((0, 4)), 0.0, len(torques),
                        len(evaluator.pairs) > 0, evaluator.integrator)
    ipm = ArmInteriorPoint(free, x0, xg, tol=FREE_TOL, constr_tol=FREE_CONSTR_TOL,
                           mu_min=FREE_MU_MIN)
    ipm.start(states, torques, t_f)
    run = run_ipm(ipm, budget, should_stop, hessian)
    evaluator.pin_calls += free.pin_calls
    evaluator.pin_time += free.pin_time
    if run.status not in ('converged', 'acceptable'):
        return None, run.iterations, ipm.linalg_time
    return (run.x, run.v * robot.arm.effort, run.t), run.iterations, ipm.linalg_time


def cold_runs(robot, evaluator, x0, xg, n_int, hessian, budget, should_stop, runs):
    """(best run, iterations, Riccati time) from the cold starts; runs gets a line per run."""
    # Around obstacles a cold solve finds the local optimum of its start's way around them:
    # every start of start_points is solved and the best converged run kept (the search
    # ends early at the free optimum's time: the obstacles then cost nothing).  When none
    # converges after a failure (line search, numerics), one more run from the line slowed
    # down by RETRY_SLOWDOWN (IPOPT's second recipe in the reference multi-start: further
    # inside the torque limits) with IPOPT's default first barrier parameter (0.1).
    iterations, linalg_time = 0, 0.0
    free = None
    line = cold_start(robot.arm, x0, xg, n_int)
    if evaluator.n_obstacle_rows and evaluator.clearances(line[0][:, :robot.arm.n]).min() < 0.0:
        free, used, free_linalg = _free_optimum(robot, evaluator, x0, xg, line, hessian,
                                                min(budget, FREE_BUDGET), should_stop)
        iterations += used
        linalg_time += free_linalg
        runs.append(f'without the obstacles: {"converged" if free else "no optimum"} after '
                    f'{used} iterations')
    best = run = None
    ends = []           # (t_f, joint path) of the ended runs after their first barrier problem
    for start_name, make, last in start_points(robot, evaluator, x0, xg, n_int, line, free):
        if run is not None and iterations >= budget:
            break
        ipm = ArmInteriorPoint(evaluator, x0, xg)
        ipm.start(*make())
        allowed = budget - iterations
        if not last or best is not None:
            allowed = min(allowed, START_BUDGET)      # (a converged run exists: no long tail)
        abandon = _abandon_above(ipm, best, should_stop, ends)
        run = run_ipm(ipm, allowed, abandon, hessian)
        run.start_name = start_name
        iterations += run.iterations
        linalg_time += ipm.linalg_time
        if abandon.fired:
            why = ("repeats an earlier start's run after the first barrier problem"
                   if abandon.repeat else "settled on the best start's way around"
                   if abandon.duplicate else 'settled above the best start')
            runs.append(f'{start_name}: abandoned after {run.iterations} iterations at t_f = '
                        f'{run.t:.6f} s ({why})')
            if abandon.first is not None and not abandon.repeat:
                ends.append(abandon.first)
            continue
        runs.append(f'{start_name}: {run_summary(run)}')
        if run.status in ('converged', 'acceptable') and abandon.first is not None:
            ends.append(abandon.first)
        if run.status in ('converged', 'acceptable') and (best is None or run.t < best.t):
            best = run
        free_reached = (best is not None and free is not None
                        and best.t <= free[2] * (1.0 + FREE_REACHED))
        if run.status == 'stopped' or free_reached:
            break       # (free_reached: the obstacles cost no time, no start can do better)
    if best is not None:
        return best, iterations, linalg_time
    if run is not None and run.status in ('line_search_failed', 'numerical_failure') \
            and iterations < budget:
        t_f = RETRY_SLOWDOWN * line_time(robot.arm, x0, xg)
        states, torques = slowed(robot.arm, x0, xg, n_int, t_f)
        ipm = ArmInteriorPoint(evaluator, x0, xg, mu_init=MU_INIT_RETRY)
        ipm.start(states, torques, t_f)
        run = run_ipm(ipm, budget - iterations, should_stop, hessian)
        run.start_name = f'line x{RETRY_SLOWDOWN:g}'
        iterations += run.iterations
        linalg_time += ipm.linalg_time
        runs.append(f'{run.start_name}: {run_summary(run)}')
    return run, iterations, linalg_time


def _abandon_above(ipm, best, should_stop, ends=()):
    """
    should_stop for ipm's run that also fires (.fired) once it settles above best.

    .duplicate: it fired because the run settled on best's way around (above); .repeat: because
    after its first barrier problem it was where a run of ends was (above); .first: (t_f, joint
    path) there, None before.
    """
    def stop():
        if should_stop() or stop.repeat:
            return True
        if stop.mu_start is None:
            stop.mu_start = ipm.mu
        elif stop.first is None and ipm.mu < stop.mu_start:
            stop.first = (ipm.t, ipm.x[:, :ipm.n].copy())
            stop.fired = stop.repeat = any(_repeats(stop.first, end) for end in ends)
            if stop.fired:
                return True
        settled = (best is not None and ipm.mu <= SETTLED_MU
                   and ipm.primal <= SETTLED_PRIMAL)
        stop.fired = settled and ipm.t > best.t * (1.0 + ABANDON_GAP)
        if settled and not stop.fired and ipm.t >= best.t:
            n = ipm.n
            stop.fired = stop.duplicate = bool(
                np.abs(ipm.x[:, :n] - best.x[:, :n]).max() <= DUPLICATE_PATH)
        return stop.fired
    stop.fired = stop.duplicate = stop.repeat = False
    stop.mu_start = stop.first = None
    return stop


def _repeats(first, end):
    """Return True when first (t_f, joint path) lies within REPEAT_TIME/REPEAT_PATH of end."""
    (t_f, path), (t_end, path_end) = first, end
    return bool(abs(t_f - t_end) <= REPEAT_TIME * t_end
                and np.abs(path - path_end).max() <= REPEAT_PATH)


def run_summary(run):
    exact = getattr(run, 'exact_from', None)
    return (f'{run.status} after {run.iterations} iterations'
            + ('' if exact is None else f' (exact curvature from iteration {exact + 1})'))
