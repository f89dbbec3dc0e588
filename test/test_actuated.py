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
Robots with first-order actuators (toc_ros.core.models.actuated, robot.actuator_lag).

Plans re-integrated by an independent numpy model of eq. (37) plus the lag, the optimum
against the lag-free one and against IPOPT on the same discretisation, warm starts of replan
cycles, and the problem's joint-state conveniences.
"""

from dataclasses import replace
import math

import numpy as np
import numpy_model as nm
import pytest
from toc_ros import config
from toc_ros.core import ProblemError, solve
from toc_ros.core.models import load_model, with_actuator_lag

LAG = 0.01


def _params(lag, integrator='rk4', n=700, **extra):
    # No time limit: the first solve compiles the actuated kernels (cached afterwards).
    return dict(config.load_parameters(), **{'robot.actuator_lag': lag, 'solver.N': n,
                                             'solver.timeout': 0.0,
                                             'solver.integrator': integrator}, **extra)


def _solve(params, **overrides):
    problem = config.problem_from_parameters(params, **overrides)
    return problem, solve(problem, config.options_from_parameters(params))


def _simulate_with_lag(x0, applied0, commands, t_f, lag, integrator):
    """Independent re-integration: eq. (37) driven by a, da/dt = (u - a) / lag."""
    def g(z, u):
        return np.concatenate([nm.f(z[:4], z[4:]), (u - z[4:]) / lag])
    z = np.concatenate([x0, applied0])
    tau = t_f / len(commands)
    out = [z]
    for u in commands:
        if integrator == 'euler':
            z = z + tau * g(z, u)
        else:
            k1 = g(z, u)
            k2 = g(z + 0.5 * tau * k1, u)
            k3 = g(z + 0.5 * tau * k2, u)
            k4 = g(z + tau * k3, u)
            z = z + tau / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        out.append(z)
    return np.array(out)


@pytest.mark.parametrize('integrator', ['euler', 'rk4'])
def test_plan_is_feasible_when_re_integrated_independently(integrator):
    problem, result = _solve(_params(LAG, integrator))
    assert result.status.value == 'SOLVED', result.message
    model = problem.robot_model
    assert model.nx == 6 and result.states.shape == (701, 6)
    # Start and goal at rest, the actuators at the hold torque (zero: no gravity).
    np.testing.assert_array_equal(problem.x0, tuple(nm.X0) + (0.0, 0.0))
    np.testing.assert_array_equal(problem.x_goal, tuple(nm.XG) + (0.0, 0.0))
    commands = np.asarray(result.controls)
    assert np.all(np.abs(commands) <= nm.U_MAX)
    z = _simulate_with_lag(nm.X0, np.zeros(2), commands, result.final_time, LAG, integrator)
    assert np.max(np.abs(z[-1] - np.concatenate([nm.XG, [0.0, 0.0]]))) < 1e-6
    # The applied torques lag the commands and stay within the bounds.
    assert np.all(np.abs(z[:, 4:]) <= nm.U_MAX * (1.0 + 1e-12))
    assert np.max(np.abs(z[1:, 4:] - commands)) > 100.0
    np.testing.assert_allclose(model.actuators(result.states), z[:, 4:], atol=1e-6)
    assert np.min(nm.clearance(z[:, :4], nm.PAPER_CIRCLES)) > -1e-6


def test_the_lag_costs_time_and_vanishes_with_it():
    times = {}
    for lag in (0.0, 0.007, 0.015, 0.03):
        _, result = _solve(_params(lag, n=1000))
        assert result.status.value == 'SOLVED', (lag, result.message)
        times[lag] = result.final_time
    # Each switch of the bang-bang command waits for the drive: t_min grows with the lag,
    # by less than a few time constants per switch, and tends to the lag-free one.
    assert times[0.0] < times[0.007] < times[0.015] < times[0.03]
    assert times[0.03] - times[0.0] < 10 * 0.03
    assert times[0.007] - times[0.0] < 0.6 * (times[0.015] - times[0.0])


def test_a_grid_too_coarse_for_the_lag_is_refused():
    # Steps t_f / N beyond lag / 2.5 do not resolve the drives (module actuated.py): refused
    # with the N needed, for the initial guess of t_f (2.5 s).
    problem, result = _solve(_params(0.002, n=1000))
    assert result.status.value == 'INVALID_INPUT'
    assert 'too coarse' in result.message and 'N >= 3125' in result.message


def test_replan_cycle_warm_start_from_a_plan_node():
    # A replan cycle: the remainder of the plan from a node on, from the (slightly perturbed)
    # state there, on the remainder's own grid.
    params = _params(LAG)
    problem, plan = _solve(params)
    k = 280
    guess = plan.remainder(plan.time_grid[k])
    start = np.array(plan.states[k])
    start[1] += 1e-4
    cycle = replace(config.problem_from_parameters(params, x0=start, x_goal=problem.x_goal),
                    n_intervals=guess.controls.shape[0])
    result = solve(cycle, config.options_from_parameters(params), initial_guess=guess)
    assert result.status.value == 'SOLVED', result.message
    assert result.iterations <= 60
    assert abs(result.final_time - (plan.final_time - plan.time_grid[k])) < 0.01


def test_joint_states_become_model_states():
    # Joint states (2 n entries) get the actuator torques that hold them; full states pass.
    params = _params(LAG, **{'robot.model': 'planar_2r', 'joint_names': ['a', 'b'],
                             'robot.model_parameters': ['g=9.81'], 'obstacles.x': [],
                             'obstacles.y': [], 'obstacles.radius': []})
    problem = config.problem_from_parameters(params, x0=[0.3, 0.0, -0.5, 0.0],
                                             x_goal=[0.8, 0.0, -0.2, 0.0])
    model = problem.robot_model
    base = load_model('planar_2r', g=9.81)
    assert model == with_actuator_lag(base, LAG)
    for x in (problem.x0, problem.x_goal):
        f = np.empty(6)
        model.kernels.rhs(np.asarray(x), model.actuators(np.asarray(x)), model.packed(), f)
        np.testing.assert_allclose(f, 0.0, atol=1e-10)         # at rest, held by gravity torques
        assert np.all(np.abs(model.actuators(np.asarray(x))) > 1.0)
    full = tuple(problem.x0)
    assert config.problem_from_parameters(params, x0=full).x0 == full
    with pytest.raises(ProblemError, match='6 entries'):
        config.problem_from_parameters(params, x0=[0.3, 0.0, -0.5, 0.0, 1.0]).validate()


def test_bad_actuator_lag_is_refused():
    with pytest.raises(ProblemError, match='actuator'):
        config.model_from_parameters(_params(math.inf))


@pytest.mark.slow
def test_agrees_with_ipopt_on_the_same_discretisation():
    # The cylindrical robot (its actuated kernels are compiled for the tests above already; a
    # second base model's would cost a minute of CI on a cold cache: test_models checks the
    # generated actuated kernels of planar_2r and of a 3-link model file by finite
    # differences).
    pytest.importorskip('casadi')
    from benchmarks import reference_solvers as rs
    params = _params(0.02, n=320)
    problem, result = _solve(params)
    assert result.status.value == 'SOLVED', result.message
    reference = rs.Reference(problem, 'ipopt')
    runs = [reference.solve(), reference.solve(guess=(result.states, result.controls,
                                                      result.final_time))]
    best = min(r['t_f'] for r in runs if r['feasible'])
    assert abs(result.final_time / best - 1.0) < 1e-5, (result.final_time, best)
