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
Cold solves of many intervals: the search on a coarser grid, then one refining run.

The cold search (cold_runs.py: the free optimum, its bends around the obstacles, the bent
lines) costs iterations per start, and each iteration costs in proportion to N.  On N / 4
intervals the search finds the same way around the obstacles at a quarter of the cost per
iteration; its optimum, carried to the N grid with its multipliers (resample_arm_duals),
converges there in a few iterations of one run from a small barrier parameter.  Euler steps
with N >= COARSE_FROM and obstacle spheres only (a free motion has no search to save: its one
run refined took as long as on the N grid); when the refining run does not converge, the cold
search runs on the N grid itself with the iterations left.  (60 random Panda and UR5 motions
past a sphere at N = 200 and 400: the same optima within 0.03 % or lower, 2.1-2.6x faster in
the median; benchmarks/RESULTS.md, "Arms: the cold search on a coarser grid".)
"""

import numpy as np

from .arm_ipm import ArmInteriorPoint
from .cold_runs import cold_runs, run_ipm, run_summary
from ..start_points import resample

# Grids of at least COARSE_FROM intervals are searched on N // COARSE_FACTOR first (>= 50).
COARSE_FROM = 200
COARSE_FACTOR = 4
# The refining run: its first barrier parameter, how far its start is pushed inside the
# bounds (the coarse optimum's active bounds stay nearly active), and its iteration budget.
REFINE_MU = 1e-7
REFINE_PUSH = 1e-4
REFINE_BUDGET = 200


def coarse_intervals(n_int, integrator, obstacles):
    """Return the coarse grid's intervals for a cold solve on n_int, or None (no coarse grid)."""
    if integrator != 'euler' or n_int < COARSE_FROM or not obstacles:
        return None
    return n_int // COARSE_FACTOR


def resample_arm_duals(duals, m, n_int):
    """
    Carry an arm run's multipliers (ArmInteriorPoint.duals) from m to n_int intervals.

    The defects' multipliers (costates, at the nodes) are interpolated in time; the bounds'
    and spheres' multipliers (inner nodes, intervals) too, scaled by m / n_int: each stands for
    a constraint at one node, and a node's share of the time is 1 / N.
    """
    def interpolate(values, old, new, scale):
        values = np.asarray(values, dtype=float)
        if values.shape[1] == 0:
            return np.zeros((len(new), 0))
        columns = [np.interp(new, old, values[:, j]) for j in range(values.shape[1])]
        return scale * np.column_stack(columns)
    nodes_m, nodes_n = np.linspace(0.0, 1.0, m + 1), np.linspace(0.0, 1.0, n_int + 1)
    mids_m, mids_n = (np.arange(m) + 0.5) / m, (np.arange(n_int) + 0.5) / n_int
    share = m / n_int
    # lam[k] belongs to the defect reaching node k: lam[0] is unused (zero) and is left out
    # (interpolated towards it, the first nodes' costates came out up to (1 - m / N) short).
    out = {'lam': interpolate(np.asarray(duals['lam'])[1:], nodes_m[1:], nodes_n, 1.0)}
    out['lam'][0] = 0.0
    for name in ('z', 'zlx', 'zux'):
        out[name] = interpolate(duals[name], nodes_m[1:-1], nodes_n[1:-1], share)
    for name in ('zlv', 'zuv'):
        out[name] = interpolate(duals[name], mids_m, mids_n, share)
    out['zlt'], out['zut'] = float(duals['zlt']), float(duals['zut'])
    out['prox'] = float(duals['prox'])
    return out


def cold_solve(robot, evaluator, coarse_evaluator, x0, xg, hessian, budget, should_stop,
               runs):
    """
    (best run, iterations, Riccati time) of a cold solve on evaluator's grid.

    coarse_evaluator: the same problem on coarse_intervals() (None: the cold search on the N
    grid, cold_runs).  runs gets a line per run.  The run returned is always on the N grid (a
    search stopped or out of iterations on the coarse one: its point carried over, unsolved).
    """
    n_int = evaluator.n_int
    if coarse_evaluator is None:
        return cold_runs(robot, evaluator, x0, xg, n_int, hessian, budget, should_stop, runs)
    m = coarse_evaluator.n_int
    searched = []
    coarse, iterations, linalg_time = cold_runs(robot, coarse_evaluator, x0, xg, m, hessian,
                                                budget, should_stop, searched)
    runs.extend(f'{line} ({m} intervals)' for line in searched)
    if coarse.status == 'stopped' or iterations >= budget:
        return _carried(robot, evaluator, x0, xg, coarse, m), iterations, linalg_time
    if coarse.status in ('converged', 'acceptable'):
        ipm = _refining_ipm(robot, evaluator, x0, xg, coarse, m)
        run = run_ipm(ipm, min(REFINE_BUDGET, budget - iterations), should_stop, hessian)
        run.start_name = f'refined from {m} intervals'
        iterations += run.iterations
        linalg_time += ipm.linalg_time
        runs.append(f'{run.start_name}: {run_summary(run)}')
        if run.status in ('converged', 'acceptable', 'stopped') or iterations >= budget:
            return run, iterations, linalg_time
    run, more, more_linalg = cold_runs(robot, evaluator, x0, xg, n_int, hessian,
                                       budget - iterations, should_stop, runs)
    return run, iterations + more, linalg_time + more_linalg


def _refining_ipm(robot, evaluator, x0, xg, coarse, m):
    """Return an interior point on evaluator's grid at the coarse run's point and multipliers."""
    n_int = evaluator.n_int
    states, controls = resample(coarse.x, coarse.v * robot.arm.effort[None, :], n_int)
    ipm = ArmInteriorPoint(evaluator, x0, xg, mu_init=REFINE_MU)
    ipm.start(states, controls, coarse.t, duals=resample_arm_duals(coarse.duals, m, n_int),
              push=REFINE_PUSH)
    return ipm


def _carried(robot, evaluator, x0, xg, coarse, m):
    """Return the coarse run's point on evaluator's grid, evaluated there (no iteration)."""
    run = _refining_ipm(robot, evaluator, x0, xg, coarse, m).run(0)
    if run.status not in ('converged', 'acceptable'):
        run.status = 'stopped' if coarse.status == 'stopped' else 'max_iterations'
    run.start_name = f'carried from {m} intervals'
    return run
