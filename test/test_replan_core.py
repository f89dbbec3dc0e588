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

"""The ROS-free receding-horizon helpers: prediction along a plan, braking, arrival."""

import math

import numpy as np
import numpy_model as nm
import pytest
from toc_ros.analysis.closed_loop import arrival_time, execution_metrics, PlanSpan
from toc_ros.core import Problem, solve, SolverOptions
from toc_ros.core.models import CylindricalRobot
from toc_ros.core.replan import (brake, BRAKE_REST_SPEED, BRAKE_SMOOTHING_SPEED, control_at,
                                 controls_at, predict, stop_later_is_clear)

MODEL = CylindricalRobot()
U_MAX = np.array([600.0, 500.0])


@pytest.fixture(scope='module')
def plan():
    result = solve(Problem.paper(n_intervals=100), SolverOptions(timeout=120.0))
    assert result.success, result.message
    return result


def test_control_at_holds_each_control_and_is_zero_outside(plan):
    times, controls = plan.time_grid, plan.controls
    assert np.array_equal(control_at(times, controls, 0.0), controls[0])
    mid = 0.5 * (times[10] + times[11])
    assert np.array_equal(control_at(times, controls, mid), controls[10])
    assert not np.any(control_at(times, controls, times[-1]))
    assert not np.any(control_at(times, controls, -1e-3))


def test_prediction_integrates_the_plan_controls(plan):
    """From a node to a later time: an independent RK4 of eq. (37) under the held controls."""
    times, controls = plan.time_grid, plan.controls
    x = plan.states[20] + np.array([0.01, -0.02, 0.005, 0.03])   # off the plan: the measured
    t0, t1 = times[20], times[20] + 0.03
    got = predict(MODEL, x, times, controls, t0, t1)
    expected, t = x.copy(), t0
    for i in range(20, 100):          # interval by interval, fine RK4 steps inside each
        end = min(times[i + 1], t1)
        if end <= t:
            break
        expected = nm.rk4(expected, controls[i], (end - t) / 50, 50)
        t = end
    assert np.max(np.abs(got - expected)) < 1e-7
    assert np.array_equal(predict(MODEL, x, times, controls, t1, t0), x)   # no time: no motion


def test_brake_stops_every_joint_at_its_bounds():
    x0 = np.array([0.3, 1.2, 1.0, -0.8])
    times, states, controls = brake(MODEL, x0, 0.002)
    assert states.shape == (len(times), 4) and controls.shape == (len(times) - 1, 2)
    assert np.all(np.abs(controls) <= U_MAX + 1e-12)
    # Away from rest the control opposes each joint's velocity at the full bound.
    fast = np.abs(states[:-1, 1::2]) > 0.05
    assert np.all(np.abs(controls[fast]) == np.broadcast_to(U_MAX, controls.shape)[fast])
    assert np.all(np.sign(controls[fast]) == -np.sign(states[:-1, 1::2][fast]))
    # It ends at rest (the last state's velocities zero, the one before below the threshold).
    assert np.all(states[-1, 1::2] == 0.0)
    assert np.max(np.abs(states[-2, 1::2])) < 10 * BRAKE_REST_SPEED
    # The states follow the model under those controls (independent RK4).
    for k in (0, len(controls) // 2, len(controls) - 2):
        step = nm.rk4(states[k], controls[k], 0.002 / 20, 20)
        assert np.max(np.abs(step - states[k + 1])) < 1e-9


def test_arrival_is_the_first_time_after_which_the_goal_holds():
    times = np.arange(6) * 0.1
    goal = np.array([1.0, 2.0])
    positions = np.array([[0.0, 0.0], [0.995, 2.0], [1.2, 2.0], [1.005, 2.0],
                          [1.0, 2.0], [1.0, 2.001]])
    assert arrival_time(times, positions, goal) == pytest.approx(0.3)
    assert math.isnan(arrival_time(times[:3], positions[[0, 0, 0]], goal))
    metrics = execution_metrics(MODEL, goal, [PlanSpan(0.0, 0.25), PlanSpan(0.1, 0.2)], times,
                                positions)
    assert metrics['arrival_s'] == pytest.approx(0.3) and metrics['plans'] == 2
    assert metrics['last_plan_end_s'] == pytest.approx(0.3)
    # 0.2 s after the last plan's end (0.3 s): the sample at 0.5 s.
    assert metrics['final_error'] == pytest.approx(0.001)


def test_vectorised_and_pointwise_control_lookup():
    rng = np.random.default_rng(3)
    times = np.linspace(0.0, 2.0, 301)
    controls = rng.normal(size=(300, 2))
    # Outside the plan, on every node, and between them.
    t = np.concatenate([rng.uniform(-0.5, 2.5, 2000), times])
    # The lookup written out here: interval i holds on [times[i], times[i + 1]), zero outside.
    expected = np.array([controls[min(int(np.searchsorted(times, v, side='right')) - 1, 299)]
                         if times[0] <= v < times[-1] else np.zeros(2) for v in t])
    np.testing.assert_array_equal(controls_at(times, controls, t), expected)
    np.testing.assert_array_equal(np.array([control_at(times, controls, v) for v in t]),
                                  expected)


def _follow_then_brake(plan, k, wait):
    """Independently: plan controls from node k for wait [s], then the bang-bang stop."""
    return nm.follow_then_brake(plan.time_grid, plan.controls, plan.states[k],
                                plan.time_grid[k], wait, U_MAX, BRAKE_REST_SPEED,
                                BRAKE_SMOOTHING_SPEED)


def test_a_stop_may_wait_only_while_it_still_ends_clear(plan):
    k = int(np.searchsorted(plan.time_grid, 0.6))     # mid-motion, joint 1 fast
    short, late = 0.05, 0.4
    stop_short = _follow_then_brake(plan, k, short)
    stop_late = _follow_then_brake(plan, k, late)
    # A circle where the later stop ends, out of the sooner stop's reach.
    q1, q2 = stop_late[-1, 0], stop_late[-1, 2]
    hand = (nm.PAPER['a'] + q2) * np.array([math.cos(q1), math.sin(q1)])
    circle = (hand[0], hand[1], 0.05)
    assert np.min(nm.clearance(stop_short, [circle])) > 0.0
    assert np.min(nm.clearance(stop_late, [circle])) < 0.0
    args = (MODEL, plan.states[k], plan.time_grid, plan.controls, plan.time_grid[k])
    assert stop_later_is_clear(*args, short, [circle], 0.002)
    assert not stop_later_is_clear(*args, late, [circle], 0.002)
    assert stop_later_is_clear(*args, late, [(5.0, 5.0, 0.1)], 0.002)
    assert stop_later_is_clear(*args, late, [], 0.002)
