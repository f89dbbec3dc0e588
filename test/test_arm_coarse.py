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
Arm cold solves of many intervals searched on a coarser grid (core/arms/coarse_grid.py).

The refined result against the search on the N grid itself (the same optimum) and against
the independent check of toc_ros/bench/arm_check.py; the multipliers carried between grids;
a cancel during the coarse search; the fallback when the refining run does not converge.
"""

import threading

import numpy as np
import pytest

pytest.importorskip('pinocchio')

from test_arm_solve import _independent_check, _problem, SCENARIOS  # noqa: E402

from toc_ros.core import solve, Status  # noqa: E402
from toc_ros.core.arms import coarse_grid  # noqa: E402
from toc_ros.core.arms.coarse_grid import coarse_intervals, resample_arm_duals  # noqa: E402


def test_coarse_grid_only_for_long_euler_grids_with_obstacles():
    assert coarse_intervals(200, 'euler', 1) == 50
    assert coarse_intervals(401, 'euler', 3) == 100
    assert coarse_intervals(199, 'euler', 1) is None
    assert coarse_intervals(400, 'rk4', 1) is None
    assert coarse_intervals(400, 'euler', 0) is None


def test_multipliers_carried_to_another_grid():
    m, n_int, nx, n, rows = 4, 8, 2, 1, 3
    nodes = np.linspace(0.0, 1.0, m + 1)
    # lam[k] belongs to the defect reaching node k: lam[0] is unused and zero.
    lam = np.column_stack([nodes, 2.0 * nodes])
    lam[0] = 0.0
    duals = {'lam': lam,
             'z': np.tile(nodes[1:-1, None], (1, rows)),
             'zlx': np.ones((m - 1, nx)), 'zux': np.full((m - 1, nx), 2.0),
             'zlv': np.full((m, n), 3.0), 'zuv': np.full((m, n), 4.0),
             'zlt': 0.5, 'zut': 0.25, 'prox': 1e-3}
    out = resample_arm_duals(duals, m, n_int)
    fine = np.linspace(0.0, 1.0, n_int + 1)
    # Costates: interpolated (linear data: exact), not scaled; before the first coarse node
    # they hold its value, not one interpolated towards the unused lam[0].
    held = np.maximum(fine, 1.0 / m)
    held[0] = 0.0
    np.testing.assert_allclose(out['lam'], np.column_stack([held, 2.0 * held]), atol=1e-15)
    # A node's constraint multiplier scales with its share of the time, m / n_int.
    assert out['z'].shape == (n_int - 1, rows) and out['zlx'].shape == (n_int - 1, nx)
    np.testing.assert_allclose(out['z'][:, 0], 0.5 * np.clip(fine[1:-1], 0.25, 0.75))
    np.testing.assert_allclose(out['zux'], 1.0)
    assert out['zlv'].shape == (n_int, n)
    np.testing.assert_allclose(out['zuv'], 2.0)
    assert (out['zlt'], out['zut'], out['prox']) == (0.5, 0.25, 1e-3)
    # No sphere rows: an empty block of the right length.
    assert resample_arm_duals(dict(duals, z=np.zeros((m - 1, 0))), m, n_int)['z'].shape == \
        (n_int - 1, 0)


def test_refined_result_is_the_optimum_of_the_n_grid_search(monkeypatch):
    problem = _problem('panda', 200)
    result = solve(problem)
    assert result.status is Status.SOLVED, result.message
    assert 'refined from 50 intervals: converged' in result.message, result.message
    _independent_check('panda', result, SCENARIOS['panda'][2])
    assert np.shape(result.controls) == (200, 7) and np.shape(result.states) == (201, 14)
    monkeypatch.setattr(coarse_grid, 'COARSE_FROM', 10 ** 9)
    searched = solve(problem)
    assert searched.status is Status.SOLVED and 'intervals' not in searched.message
    assert abs(result.final_time / searched.final_time - 1.0) < 1e-9, (
        result.final_time, searched.final_time)


def test_free_motion_is_searched_on_its_own_grid():
    result = solve(_problem('panda', 200, with_obstacles=False))
    assert result.status is Status.SOLVED and 'intervals' not in result.message, result.message


def test_refinement_that_does_not_converge_falls_back_to_the_n_grid(monkeypatch):
    monkeypatch.setattr(coarse_grid, 'REFINE_BUDGET', 1)
    result = solve(_problem('panda', 200))
    assert result.status is Status.SOLVED, result.message
    assert 'refined from 50 intervals: max_iterations after 1 iterations' in result.message
    _independent_check('panda', result, SCENARIOS['panda'][2])


def test_cancel_during_the_coarse_search_returns_the_n_grid(monkeypatch):
    # The cancel arrives after the coarse search's first iterations: CANCELED, with the coarse
    # point carried to the problem's grid (the shapes a caller expects), not the coarse grid.
    cancel = threading.Event()
    cold = coarse_grid.cold_runs

    def cancelled_on_the_way(robot, evaluator, x0, xg, n_int, hessian, budget, should_stop,
                             runs):
        assert n_int == 50

        def stop():
            calls.append(1)
            if len(calls) == 5:
                cancel.set()
            return should_stop()
        calls = []
        return cold(robot, evaluator, x0, xg, n_int, hessian, budget, stop, runs)
    monkeypatch.setattr(coarse_grid, 'cold_runs', cancelled_on_the_way)
    result = solve(_problem('panda', 200), cancel=cancel)
    assert result.status is Status.CANCELED, result.message
    assert np.shape(result.controls) == (200, 7) and np.shape(result.states) == (201, 14)
    assert result.solver_state['start'] == 'carried from 50 intervals'
