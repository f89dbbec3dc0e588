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
Fast mode: feasible minimum-time solutions, checked independently; cancel/timeout/progress.

Every returned trajectory is re-integrated here in plain numpy (numpy_model) and its clearance
re-measured; t_min is compared with the independent IPOPT transcription
(benchmarks/reference_ipopt.py) when casadi is importable, else with the recorded optimum of
the paper scenario only.
"""

from dataclasses import replace
import importlib.util
import math
import threading
import time

import numpy as np
import numpy_model as nm
import pytest

from toc_ros.core import Problem, solve, SolverOptions, Status, warm_up
from toc_ros.core.result import HISTORY_COLUMNS

HAVE_CASADI = importlib.util.find_spec('casadi') is not None
GAP = 1e-3              # 0.1 % of the reference optimum
STOP_LATENCY = 0.1      # [s] cancel/timeout honoured within 100 ms

PAPER = Problem.paper()       # the paper's scenario, Euler, N = 1000
# N = 300 runs the coarse-to-fine ladder like N = 1000, at a fraction of the cost; the
# obstacle-free case at N = 200 takes the single-grid path.
SCENARIOS = {
    'paper_n300': replace(PAPER, n_intervals=300),
    # The paper's circle plus an active one near the start and an idle one in quadrant II.
    'several_circles': replace(PAPER, n_intervals=300, obstacles=(
        (1.0, 1.0, 0.2), (1.4, 0.6, 0.1), (-0.8, 0.9, 0.2))),
    'second_quadrant': replace(PAPER, n_intervals=300, obstacles=((-0.6, 1.2, 0.25),),
                               x0=(1.0, 0.0, 1.0, 0.0), x_goal=(2.6, 0.0, 1.0, 0.0)),
    'start_velocity': replace(PAPER, n_intervals=300, x0=(0.3, 0.5, 0.8, -0.2),
                              x_goal=(1.4, 0.0, 1.2, 0.0)),
    'rk4': replace(PAPER, n_intervals=300, integrator='rk4'),
    'no_obstacles': replace(PAPER, n_intervals=200, obstacles=()),
}


def _reference():
    from benchmarks import reference_ipopt
    return reference_ipopt


def _reference_t_f(problem):
    res = _reference().solve_reference(
        problem.x0, problem.x_goal, problem.obstacles, problem.margin, N=problem.n_intervals,
        integrator=problem.integrator, model_variant=problem.model.params.model_variant,
        u_max=tuple(problem.model.u_max))
    assert res['success'], res['attempts']
    return res['t_f']


@pytest.fixture(scope='module', autouse=True)
def _compiled():
    warm_up()       # numba kernels compiled/loaded once, outside every measurement


@pytest.fixture(scope='module')
def paper_result():
    return solve(PAPER, SolverOptions(mode='fast'))


@pytest.mark.slow
def test_paper_scenario_is_solved_feasible_and_optimal(paper_result):
    result = paper_result
    assert result.status is Status.SOLVED, result.message
    assert result.mode == 'fast' and result.integrator == 'euler' and result.n_intervals == 1000
    nm.assert_feasible(PAPER, result)
    assert abs(result.final_time - nm.T_STAR_PAPER) <= GAP * nm.T_STAR_PAPER, result.final_time
    assert result.iterations > 0 and result.history.shape[1] == len(HISTORY_COLUMNS)
    assert result.cost == result.final_time


@pytest.mark.slow
@pytest.mark.parametrize('name', sorted(SCENARIOS))
def test_other_scenarios_are_solved_feasible_and_near_ipopt(name):
    problem = SCENARIOS[name]
    result = solve(problem, SolverOptions(mode='fast'))
    assert result.status is Status.SOLVED, result.message
    measured = nm.assert_feasible(problem, result)
    if problem.obstacles:
        assert measured['min_clearance'] < 1e-3, 'expected the obstacle to be active'
    if HAVE_CASADI:
        t_ref = _reference_t_f(problem)
        assert abs(result.final_time - t_ref) <= GAP * t_ref, (result.final_time, t_ref)


def test_same_inputs_give_bit_identical_results():
    problem = SCENARIOS['several_circles']
    first = solve(problem, SolverOptions(mode='fast'))
    second = solve(problem, SolverOptions(mode='fast'))
    assert first.status is second.status and first.has_trajectory
    assert first.final_time == second.final_time
    assert first.iterations == second.iterations
    assert np.array_equal(first.states, second.states)
    assert np.array_equal(first.controls, second.controls)
    assert np.array_equal(first.history, second.history, equal_nan=True)


def _solve_with_cancel(problem, options, delay):
    """Set a threading.Event from a timer thread; return (result, seconds from set to return)."""
    cancel = threading.Event()
    stamp = {}

    def fire():
        stamp['set'] = time.monotonic()
        cancel.set()

    timer = threading.Timer(delay, fire)
    timer.start()
    try:
        result = solve(problem, options, cancel=cancel)
        returned = time.monotonic()
    finally:
        timer.cancel()
    assert 'set' in stamp, 'the solve finished before the cancel fired: make it longer'
    return result, returned - stamp['set']


def _check_best_so_far(problem, result):
    n = problem.n_intervals
    if not result.has_trajectory:      # fast mode stopped before reaching the fine level
        assert result.states.shape[0] == 0 and math.isnan(result.final_time)
        return
    assert result.states.shape == (n + 1, 4) and result.controls.shape == (n, 2)
    assert math.isfinite(result.final_time) and result.final_time > 0.0
    circles = problem.circles()
    measured = nm.violations(problem.x0, problem.x_goal, result.controls, result.final_time,
                             circles)
    np.testing.assert_allclose(result.states, measured['states'], rtol=0, atol=1e-9)
    assert result.violations.terminal_error == pytest.approx(measured['terminal_error'],
                                                             abs=1e-9)


# Long solves: paper mode with a million iterations; fast mode (milliseconds at N = 1000) on a
# long horizon with several circles, whose single iterations take tens of milliseconds.
LONG = {'paper': PAPER, 'fast': replace(SCENARIOS['several_circles'], n_intervals=40000)}


@pytest.mark.parametrize('mode', ['fast', 'paper'])
def test_cancel_is_honoured_within_100_ms(mode):
    options = SolverOptions(mode=mode, max_iterations=10 ** 6 if mode == 'paper' else None)
    result, latency = _solve_with_cancel(LONG[mode], options, delay=0.4)
    assert result.status is Status.CANCELED, result.message
    assert latency <= STOP_LATENCY, latency
    if mode == 'paper':
        assert result.has_trajectory
    _check_best_so_far(LONG[mode], result)


@pytest.mark.parametrize('mode', ['fast', 'paper'])
def test_timeout_is_honoured_within_100_ms(mode):
    timeout = 0.4
    options = SolverOptions(mode=mode, timeout=timeout,
                            max_iterations=10 ** 6 if mode == 'paper' else None)
    start = time.monotonic()
    result = solve(LONG[mode], options)
    elapsed = time.monotonic() - start
    assert result.status is Status.TIMEOUT, result.message
    assert timeout <= elapsed <= timeout + STOP_LATENCY, elapsed
    _check_best_so_far(LONG[mode], result)


@pytest.mark.parametrize('mode', ['fast', 'paper'])
def test_progress_is_reported_at_least_every_100_ms(mode):
    calls = []
    options = SolverOptions(mode=mode, timeout=1.5)
    problem = LONG[mode]
    start = time.monotonic()
    result = solve(problem, options, progress=lambda p: calls.append((time.monotonic(), p)))
    stamps = np.array([start] + [t for t, _ in calls])
    gaps = np.diff(stamps)
    assert len(calls) >= 10
    # The typical gap must meet 100 ms; slack for the first call, a garbage collection or a
    # busy machine, but no long silence.
    assert np.median(gaps) <= 0.1, gaps
    assert gaps[0] <= 0.15 and np.percentile(gaps, 90) <= 0.15, gaps
    assert np.max(gaps) <= 0.3, gaps
    its = [p.iteration for _, p in calls]
    assert its == sorted(its) and its[-1] == result.iterations
    assert calls[-1][1].phase == 'done'
    assert all(math.isfinite(p.t_f) and p.t_f > 0.0 for _, p in calls[:-1])


# Near the goal, overshooting (a replan cycle's start): the first cold attempt converges on
# the N grid (32 <= 2 x COARSE_INTERVALS), then its inertia-corrected iterations make fast
# mode try the other COLD_ATTEMPTS, which crawl for hundreds of iterations.
OVERSHOOT = replace(PAPER, x0=(1.3058269, 0.0755279, 0.99260788, 0.24495655), n_intervals=32,
                    integrator='rk4')


@pytest.mark.parametrize('reason', [Status.TIMEOUT, Status.CANCELED])
def test_a_timeout_during_further_attempts_returns_the_converged_one(monkeypatch, reason):
    from toc_ros.core import fast_solver, ip_run
    reference = solve(OVERSHOOT, SolverOptions())
    assert reference.status is Status.SOLVED, reference.message
    attempts = []
    original = fast_solver.FastSolve._attempt

    def attempt(self, *args):
        if attempts:                  # the stop lands during the second attempt
            raise ip_run.Stop(reason)
        attempts.append(original(self, *args))
        return attempts[-1]

    monkeypatch.setattr(fast_solver.FastSolve, '_attempt', attempt)
    result = solve(OVERSHOOT, SolverOptions())
    first_run, first_code = attempts[0]
    assert first_code == fast_solver.ipm.CONVERGED
    if reason is Status.CANCELED:     # a cancel is not a deadline: nothing is published
        assert result.status is Status.CANCELED
        return
    assert result.status is Status.SOLVED, result.message
    assert 'timeout' in result.message
    assert result.final_time == first_run.t_f
    # The first attempt's optimum, feasible by an independent re-integration, and no more
    # than the tolerance away from the full search's.
    measured = nm.violations(OVERSHOOT.x0, OVERSHOOT.x_goal, result.controls,
                             result.final_time, OVERSHOOT.circles(), integrator='rk4')
    assert measured['terminal_error'] <= 1e-6 and measured['max_control_excess'] <= 1e-9
    assert measured['min_clearance'] >= -1e-9      # circles() are the inflated ones
    assert result.final_time == pytest.approx(reference.final_time, rel=1e-3)
