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
The published arm trajectory, interpolated as controllers do, keeps the velocity limits.

Each segment's cubic is rebuilt here from its two points (a 4 x 4 solve, not the package's
Hermite formula) and sampled; the limits are the URDF's, read by test/arm_oracle.py.
"""

from arm_oracle import ArmOracle, find_panda_urdf, PANDA_JOINTS
from builtin_interfaces.msg import Time
import numpy as np
import pytest
from toc_ros.arm_model import build_arm
from toc_ros.conversions import duration_seconds
from toc_ros.core import Problem, solve, Status
from toc_ros.core.executing_plan import plan_from_result
from toc_ros.core.plan_reference import reference_positions
from toc_ros.core.replan import predict
from toc_ros.core.replan_policy import cycle_start_state
from toc_ros.plant.jtc_trajectory import interpolate, Point

pytestmark = pytest.mark.slow

START = [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785]
GOALS = ([0.8, -0.3, 0.0, -2.0, 0.0, 1.8, 0.785], [-0.6, 0.2, 0.5, -1.6, 0.4, 1.5, 0.2])


def cubic_samples(times, positions, velocities, per_segment=25):
    """(position, velocity) rows of each segment's cubic through its end points, sampled."""
    out_q, out_v = [], []
    for k in range(len(times) - 1):
        h = times[k + 1] - times[k]
        basis = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0],
                          [1.0, h, h * h, h ** 3], [0.0, 1.0, 2 * h, 3 * h * h]])
        coef = np.linalg.solve(basis, np.vstack([positions[k], velocities[k],
                                                 positions[k + 1], velocities[k + 1]]))
        for s in np.linspace(0.0, h, per_segment):
            out_q.append(coef[0] + coef[1] * s + coef[2] * s * s + coef[3] * s ** 3)
            out_v.append(coef[1] + 2 * coef[2] * s + 3 * coef[3] * s * s)
    return np.array(out_q), np.array(out_v)


@pytest.fixture(scope='module')
def panda():
    model = build_arm('panda', '', PANDA_JOINTS, None, None, None)
    results = []
    for goal in GOALS:
        result = solve(Problem(model=model.robot, x0=tuple(model.state(np.array(START))),
                               x_goal=tuple(model.state(np.array(goal))), n_intervals=60))
        assert result.status is Status.SOLVED, result.message
        results.append(result)
    return model, results


def test_euler_points_are_the_motion_with_linear_velocity():
    rng = np.random.default_rng(3)
    times = np.linspace(0.0, 1.2, 31)
    h = times[1] - times[0]
    velocities = np.vstack([np.zeros(3), rng.uniform(-2.0, 2.0, (29, 3)), np.zeros(3)])
    q = np.vstack([np.zeros(3), np.cumsum(h * velocities[:-1], axis=0)])   # explicit Euler
    points = reference_positions(q, velocities, times, 'euler')
    np.testing.assert_array_equal(points[[0, -1]], q[[0, -1]])    # from rest to rest
    positions, speeds = cubic_samples(times, points, velocities)
    k = np.repeat(np.arange(30), 25)
    s = np.tile(np.linspace(0.0, 1.0, 25), 30)[:, None]
    np.testing.assert_allclose(speeds, (1 - s) * velocities[k] + s * velocities[k + 1],
                               rtol=0, atol=1e-9)
    # Half a step ahead of the Euler nodes: at the middle of step k, q_{k+1} + h dq'/8.
    middle = cubic_samples(times, points, velocities, per_segment=3)[0][1::3]
    np.testing.assert_allclose(middle, q[1:] + h / 8 * np.diff(velocities, axis=0),
                               rtol=0, atol=1e-12)
    assert reference_positions(q, velocities, times, 'rk4') is q


def test_published_panda_plans_keep_the_velocity_limits(panda):
    model, results = panda
    limits = ArmOracle(find_panda_urdf().read_text()).velocity
    for result in results:
        msg = model.trajectory_msg(result, PANDA_JOINTS, Time())
        times = np.array([duration_seconds(p.time_from_start) for p in msg.points])
        positions = np.array([p.positions for p in msg.points])
        velocities = np.array([p.velocities for p in msg.points])
        assert all(len(p.accelerations) == 0 for p in msg.points)
        np.testing.assert_allclose(positions[-1], result.states[-1][:7], atol=1e-12)
        np.testing.assert_allclose(positions[0], START, atol=1e-12)
        speeds = cubic_samples(times, positions, velocities)[1]
        assert np.max(np.abs(speeds) / limits) <= 1.0 + 1e-9
        # The Euler nodes as points (what was published before) go past the limits.
        raw = cubic_samples(times, result.states[:, :7], velocities)[1]
        assert np.max(np.abs(raw) / limits) > 1.1
        # JTC's interpolation of the message (cubic: no accelerations) keeps them too.
        worst = 0.0
        for k in range(len(times) - 1):
            a, b = (Point(positions[i], velocities[i]) for i in (k, k + 1))
            for s in np.linspace(0.0, times[k + 1] - times[k], 11):
                worst = max(worst, np.max(np.abs(interpolate(s, times[k + 1] - times[k],
                                                             a, b)[1]) / limits))
        assert worst <= 1.0 + 1e-9


def test_deviation_is_measured_from_the_published_motion(panda):
    model, results = panda
    result = results[0]
    plan = plan_from_result(result, 0.0, result.states[-1], 'goal_joints', model)
    msg = model.trajectory_msg(plan, PANDA_JOINTS, Time())
    times = np.array([duration_seconds(p.time_from_start) for p in msg.points])
    positions = np.array([p.positions for p in msg.points])
    velocities = np.array([p.velocities for p in msg.points])
    k = 20
    t = 0.5 * (times[k] + times[k + 1])
    on_motion = cubic_samples(times[k:k + 2], positions[k:k + 2], velocities[k:k + 2],
                              per_segment=3)[0][1]
    state = np.concatenate([on_motion, velocities[k]])
    assert plan.deviation(state, t) < 1e-8      # the points' times are whole nanoseconds
    # The Euler nodes' line is half a step behind it.
    assert np.max(np.abs(on_motion - 0.5 * (result.states[k, :7] + result.states[k + 1, :7]))) \
        > 1e-3


def test_a_cycle_from_a_prediction_publishes_from_the_prediction(panda):
    model, results = panda
    result = results[0]
    plan = plan_from_result(result, 0.0, result.states[-1], 'goal_joints', model)
    h = result.time_grid[1] - result.time_grid[0]
    measured = result.states[20] + np.concatenate([np.full(7, 0.05), np.zeros(7)])
    start_at = float(result.time_grid[24])
    start = cycle_start_state(plan, measured, float(result.time_grid[20]), start_at,
                              deviation=0.05, stitch=-1.0)
    predicted = predict(model, measured, plan.times, plan.controls,
                        float(result.time_grid[20]), start_at)
    np.testing.assert_allclose(start[7:], predicted[7:], rtol=0, atol=0)
    # Its first point (an Euler plan on the same step) is the prediction, not h dq / 2 ahead.
    nodes = np.vstack([start, start])
    first = reference_positions(nodes[:, :7], nodes[:, 7:], [0.0, h], 'euler')[0]
    np.testing.assert_allclose(first, predicted[:7], rtol=0, atol=1e-12)
    assert np.max(np.abs(start[:7] - predicted[:7])) > 1e-3
    # Within the stitch: the plan's own node, unchanged.
    np.testing.assert_array_equal(cycle_start_state(plan, measured, 0.0, start_at, 0.01, -1.0),
                                  result.states[24])
    # Never past a position limit: at panda_joint4's upper limit, leaving it.
    at_limit = np.array(result.states[20])
    at_limit[3], at_limit[7 + 3] = model.arm.upper[3], -2.0
    assert plan.start_for(at_limit)[3] == model.arm.upper[3]
