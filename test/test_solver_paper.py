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
Paper mode (section 3 heuristic, paper's constants) on a reduced number of iterations M.

The full M = 30000 run is in benchmarks/bench_solvers.py.  Here: the tau rule of eq. (34) as
seen in the history, the returned t_min and its violations re-measured in numpy, and the first
gradient step of eq. (32) against a finite-difference gradient of a numpy cost.
"""

from dataclasses import replace
import math

import numpy as np
import numpy_model as nm
import pytest

from toc_ros.core import PaperOptions, Problem, solve, SolverOptions, Status
from toc_ros.core.result import HISTORY_COLUMNS

PAPER = Problem.paper()
CONSTANTS = PaperOptions()       # K_B 600, K_V 0.01, K_p 1000, eta 1000, d_tau 1e-5, J_eps 0.01
M = 4000


def _numpy_cost(controls, tau, tau0, circles, constants=CONSTANTS, x_goal=nm.XG):
    """
    J_T = J1 + J2 + J3 (eqs. 7, 8, 42) by plain numpy.

    The running penalties carry the constant tau0 (K_V-hat = tau0 K_V, K_p-hat = tau0 K_p, the
    section-2 scaling K-hat = tau K with tau frozen at its initial value).
    """
    states = nm.simulate(nm.X0, controls, tau * controls.shape[0])
    j1 = constants.k_b * np.sum((states[-1] - np.asarray(x_goal)) ** 2)
    excess = np.maximum(np.abs(controls) - nm.U_MAX[None, :], 0.0)
    j2 = tau0 * constants.k_v * np.sum(excess ** 2)
    j3 = 0.0
    for x in states:
        for cx, cy, radius in circles:
            hit = nm.ray_first_hit(x[0], cx, cy, radius)
            if hit is not None and hit < nm.PAPER['a'] + x[2]:
                j3 += tau0 * constants.k_p * (hit - nm.PAPER['a'] - x[2]) ** 2
    return j1 + j2 + j3


@pytest.fixture(scope='module')
def reduced():
    return solve(PAPER, SolverOptions(mode='paper', max_iterations=M))


def test_t_f_decreases_by_the_tau_rule(reduced):
    hist = reduced.history
    assert hist.shape == (M, len(HISTORY_COLUMNS))
    assert np.all(np.isnan(hist[:, 3]))     # paper mode: its penalties are the cost
    np.testing.assert_array_equal(hist[:, 0], np.arange(M))
    t_f, cost = hist[:, 1], hist[:, 2]
    assert t_f[0] == pytest.approx(PAPER.t_f0, abs=1e-12)
    # Eq. (34): tau drops by d_tau (t_f by N d_tau) exactly after the iterations with
    # J_T < J_eps, and stays put otherwise.
    step = -PAPER.n_intervals * CONSTANTS.d_tau
    expected = np.where(cost[:-1] < CONSTANTS.j_eps, step, 0.0)
    np.testing.assert_allclose(np.diff(t_f), expected, rtol=0, atol=1e-9)
    assert t_f[-1] < PAPER.t_f0 - 0.1
    assert np.sum(cost < CONSTANTS.j_eps) > 10


def test_reduced_run_result_and_violations_are_independently_confirmed(reduced):
    result = reduced
    assert result.status in (Status.SOLVED, Status.SOLVED_INACCURATE), result.message
    assert result.mode == 'paper' and result.iterations == M
    assert result.final_time < 2.5
    # t_min is N tau of the last iteration that met J_T < J_eps, with that iteration's controls.
    cost = result.history[:, 2]
    last = int(np.flatnonzero(cost < CONSTANTS.j_eps)[-1])
    assert result.final_time == pytest.approx(result.history[last, 1], abs=1e-12)
    tau = result.final_time / PAPER.n_intervals
    tau0 = PAPER.t_f0 / PAPER.n_intervals
    assert _numpy_cost(result.controls, tau, tau0, nm.PAPER_CIRCLES) == pytest.approx(
        cost[last], rel=1e-8)

    measured = nm.violations(nm.X0, nm.XG, result.controls, result.final_time,
                             nm.PAPER_CIRCLES)
    np.testing.assert_allclose(result.states, measured['states'], rtol=0, atol=1e-9)
    v = result.violations
    assert v.max_control_excess == pytest.approx(measured['max_control_excess'], abs=1e-9)
    assert v.terminal_error == pytest.approx(measured['terminal_error'], abs=1e-9)
    assert v.min_clearance == pytest.approx(measured['min_clearance'], abs=1e-9)
    feasible = (measured['max_control_excess'] == 0.0 and measured['terminal_error'] <= 1e-6
                and measured['min_clearance'] >= -1e-6)
    assert result.status is (Status.SOLVED if feasible else Status.SOLVED_INACCURATE)
    if not feasible:       # the message reports the residual violations
        assert 'violations' in result.message


@pytest.mark.parametrize('gradient', ['exact', 'shortcut'])
def test_first_iteration_is_one_gradient_step_from_zero(gradient):
    """u(1) = u(0) - eta dJ_T/du with u(0) = 0 (eq. 32), gradient by FD of the numpy cost."""
    n = 40
    goal = (PAPER.x_goal[0], 0.0, 0.8, 0.0)      # q2 moves too, so dJ/du2 != 0
    problem = replace(PAPER, n_intervals=n, x_goal=goal)
    options = SolverOptions(mode='paper', max_iterations=1,
                            paper=replace(CONSTANTS, obstacle_gradient=gradient))
    result = solve(problem, options)
    # J_T(u = 0) = K_B |x0 - x_goal|^2 >> J_eps: not accepted, t_f unchanged.
    assert result.status is Status.MAX_ITERATIONS
    assert result.final_time == pytest.approx(PAPER.t_f0, abs=1e-12)
    tau = PAPER.t_f0 / n
    zero = np.zeros((n, 2))
    fd = np.zeros((n, 2))
    h = 1e-3
    for i in range(n):
        for k in range(2):
            up, um = zero.copy(), zero.copy()
            up[i, k], um[i, k] = h, -h
            fd[i, k] = (_numpy_cost(up, tau, tau, nm.PAPER_CIRCLES, x_goal=goal)
                        - _numpy_cost(um, tau, tau, nm.PAPER_CIRCLES, x_goal=goal)) / (2.0 * h)
    # At rest at the start the arm is clear of the circle, so both obstacle gradients agree.
    np.testing.assert_allclose(result.controls, -CONSTANTS.eta * fd, rtol=1e-6,
                               atol=1e-6 * CONSTANTS.eta * np.max(np.abs(fd)))
    assert np.min(np.max(np.abs(result.controls), axis=0)) > 1.0     # both joints move


def test_initial_time_below_t_min_is_never_accepted():
    problem = replace(PAPER, t_f0=1.0)        # below the unconstrained optimum (1.61 s)
    result = solve(problem, SolverOptions(mode='paper', max_iterations=300))
    assert result.status is Status.MAX_ITERATIONS
    assert 'J_eps' in result.message
    assert np.all(result.history[:, 1] == pytest.approx(1.0, abs=1e-12))
    assert result.has_trajectory and math.isfinite(result.violations.terminal_error)


def test_a_chunk_of_iterations_lets_other_threads_run():
    # The node's executor thread (progress heartbeat, parameters, ~/cancel) runs beside a
    # chunk instead of waiting for its end: the kernel releases the GIL.
    import threading
    import time
    from toc_ros.core.paper_solver import PaperRun
    problem = Problem.paper(n_intervals=1000)
    run = PaperRun(problem, SolverOptions(mode='paper', max_iterations=10 ** 6),
                   problem.integrator_id)
    run.advance(1)                                  # (compiled or loaded from the cache)
    started = time.perf_counter()
    run.advance(1)
    per_iteration = time.perf_counter() - started
    stamps, done = [], threading.Event()

    def stamp():
        while not done.is_set():
            stamps.append(time.perf_counter())
            time.sleep(0.001)
    other = threading.Thread(target=stamp)
    other.start()
    count = max(2, int(0.3 / max(per_iteration, 1e-6)))
    for _ in range(4):          # (a chunk long enough to have a middle, on a loaded machine)
        time.sleep(0.02)
        started = time.perf_counter()
        run.advance(count)
        ended = time.perf_counter()
        if ended - started > 0.1:
            break
        count *= 3
    done.set()
    other.join()
    # The middle half of the chunk: the other thread ran there (with the GIL held: never).
    low, high = started + 0.25 * (ended - started), started + 0.75 * (ended - started)
    inside = sum(low < t < high for t in stamps)
    assert ended - started > 0.1
    assert inside >= 10, f'{inside} stamps in the middle of a {ended - started:.2f} s chunk'
