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

"""Message conversions of toc_ros.conversions, without a ROS graph."""

import math

from builtin_interfaces.msg import Time
from node_harness import eq37, pose
import numpy as np
import pytest
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension
from toc_ros import conversions
from toc_ros.conversions import ConversionError
from toc_ros.core import RobotParams, SolveResult, Status, Violations
from toc_ros.core.integrators import EULER, rollout
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
from visualization_msgs.msg import Marker

NAMES = ['rotation_joint', 'extension_joint']


@pytest.fixture(scope='module')
def result():
    """Build a SolveResult of an Euler rollout of varied controls (not an optimum)."""
    n, t_f = 40, 1.3
    rng = np.random.default_rng(3)
    controls = np.column_stack([rng.uniform(-600, 600, n), rng.uniform(-500, 500, n)])
    states = np.empty((n + 1, 4))
    rollout(np.array([0.3, 0.1, 1.0, -0.2]), controls, t_f / n, RobotParams().packed(), EULER,
            states)
    return SolveResult(status=Status.SOLVED, message='ok', mode='fast', integrator='euler',
                       n_intervals=n, final_time=t_f, time_grid=np.linspace(0, t_f, n + 1),
                       states=states, controls=controls, iterations=7, wall_time_s=0.5,
                       violations=Violations(0.0, 1e-9, 0.05))


def test_trajectory_msg_carries_states_controls_and_model_accelerations(result):
    msg = conversions.trajectory_msg(result, NAMES, RobotParams(), Time(sec=5))
    assert msg.joint_names == NAMES and msg.header.stamp.sec == 5
    assert len(msg.points) == result.n_intervals + 1
    times = [conversions.duration_seconds(p.time_from_start) for p in msg.points]
    np.testing.assert_allclose(times, result.time_grid, atol=1e-9)
    for i, point in enumerate(msg.points):
        x = result.states[i]
        u = result.controls[min(i, result.n_intervals - 1)]
        np.testing.assert_allclose(point.positions, [x[0], x[2]], rtol=0, atol=0)
        np.testing.assert_allclose(point.velocities, [x[1], x[3]], rtol=0, atol=0)
        np.testing.assert_allclose(point.effort, u, rtol=0, atol=0)
        f = eq37(x, u)
        np.testing.assert_allclose(point.accelerations, [f[1], f[3]], rtol=1e-12, atol=1e-9)


def test_trajectory_round_trip_and_reordering(result):
    msg = conversions.trajectory_msg(result, NAMES, RobotParams(), Time())
    arrays = conversions.trajectory_arrays(msg, NAMES)
    np.testing.assert_allclose(arrays.positions, result.states[:, [0, 2]])
    np.testing.assert_allclose(arrays.velocities, result.states[:, [1, 3]])
    np.testing.assert_allclose(arrays.efforts[:-1], result.controls)
    swapped = conversions.trajectory_arrays(msg, NAMES[::-1])
    np.testing.assert_allclose(swapped.positions, result.states[:, [2, 0]])


def _trajectory(times, positions, efforts=None, names=NAMES):
    msg = JointTrajectory(joint_names=list(names))
    for k, (t, p) in enumerate(zip(times, positions)):
        point = JointTrajectoryPoint(positions=list(p),
                                     time_from_start=conversions.duration_msg(t))
        if efforts is not None and efforts[k] is not None:
            point.effort = list(efforts[k])
        msg.points.append(point)
    return msg


@pytest.mark.parametrize('msg, reason', [
    (_trajectory([0.0, 0.1], [[0, 1], [0, 1]], names=['rotation_joint', 'x']), 'lacks joints'),
    (_trajectory([0.0, 0.1], [[0, 1], [0, 1]], names=NAMES + ['rotation_joint']),
     'duplicate'),
    (_trajectory([0.0, 0.0], [[0, 1], [0, 1]]), 'strictly increasing'),
    (_trajectory([0.2, 0.1], [[0, 1], [0, 1]]), 'strictly increasing'),
    (_trajectory([0.0, 0.1], [[0, 1], [0]]), 'positions'),
    (_trajectory([0.0, 0.1], [[0, math.nan], [0, 1]]), 'NaN'),
    (_trajectory([0.0, 0.1], [[0, 1], [0, 1]], efforts=[[1, 2], None]), 'effort'),
])
def test_trajectory_arrays_refuses_bad_messages(msg, reason):
    with pytest.raises(ConversionError, match=reason):
        conversions.trajectory_arrays(msg, NAMES)


def test_trajectory_arrays_defaults():
    arrays = conversions.trajectory_arrays(_trajectory([0.0, 0.5], [[0, 1], [1, 2]]), NAMES)
    assert arrays.efforts is None and arrays.accelerations is None
    np.testing.assert_array_equal(arrays.velocities, np.zeros((2, 2)))
    empty = conversions.trajectory_arrays(JointTrajectory(joint_names=NAMES), NAMES)
    assert empty.times.shape == (0,) and empty.positions.shape == (0, 2)


def test_hand_path_follows_the_forward_kinematics(result):
    path = conversions.hand_path_msg(result.states, 1.1, 'base_link', Time())
    assert path.header.frame_id == 'base_link' and len(path.poses) == len(result.states)
    for pose_msg, x in zip(path.poses, result.states):
        p = pose_msg.pose.position
        assert p.x == pytest.approx((1.1 + x[2]) * math.cos(x[0]), abs=1e-12)
        assert p.y == pytest.approx((1.1 + x[2]) * math.sin(x[0]), abs=1e-12)
        yaw = 2.0 * math.atan2(pose_msg.pose.orientation.z, pose_msg.pose.orientation.w)
        assert math.remainder(yaw - x[0], 2 * math.pi) == pytest.approx(0.0, abs=1e-12)


def test_markers_show_obstacles_inflated_circles_path_and_arm(result):
    msg = conversions.markers_msg([(1.0, 1.0, 0.2), (-1.0, 0.5, 0.3)], 0.01, 1.1, 'base_link',
                                  Time(), result.states, result.states[0])
    assert msg.markers[0].action == Marker.DELETEALL
    by_ns = {}
    for marker in msg.markers[1:]:
        assert marker.header.frame_id == 'base_link'
        by_ns.setdefault(marker.ns, []).append(marker)
    assert sorted(by_ns) == ['arm', 'inflated_obstacles', 'obstacles', 'planned_path']
    cylinders = by_ns['obstacles']
    assert [m.scale.x for m in cylinders] == pytest.approx([0.4, 0.6])
    (rings,) = by_ns['inflated_obstacles']     # one line list for all circles
    assert rings.type == Marker.LINE_LIST and len(rings.points) % 2 == 0
    per_circle = len(rings.points) // 2
    for k, (cx, cy, r) in enumerate([(1.0, 1.0, 0.2), (-1.0, 0.5, 0.3)]):
        points = rings.points[k * per_circle:(k + 1) * per_circle]
        radii = [math.hypot(p.x - cx, p.y - cy) for p in points]
        assert radii == pytest.approx([r + 0.01] * len(radii))
    arm = by_ns['arm'][0].points
    x0 = result.states[0]
    assert (arm[0].x, arm[0].y) == (0.0, 0.0)
    assert math.hypot(arm[1].x, arm[1].y) == pytest.approx(1.1 + x0[2])
    assert len(by_ns['planned_path'][0].points) == len(result.states)


def test_pose_inverse_kinematics():
    goal = conversions.pose_to_joint_goal(pose(0.0, 2.1), 'base_link', 1.1)
    np.testing.assert_allclose(goal, [math.pi / 2, 0.0, 1.0, 0.0], atol=1e-15)
    goal = conversions.pose_to_joint_goal(pose(-1.0, -1.0, '/base_link'), 'base_link', 1.1)
    np.testing.assert_allclose(goal, [-0.75 * math.pi, 0.0, math.sqrt(2) - 1.1, 0.0])


@pytest.mark.parametrize('msg, reason', [
    (pose(1.0, 1.0, 'map'), "frame 'map'"),
    (pose(1.0, 1.0, ''), "frame ''"),
    (pose(math.nan, 1.0), 'NaN'),
    (pose(1.0, math.inf), 'NaN or inf'),
    (pose(0.0, 0.0), 'base axis'),
    (pose(5.0, 0.0), 'out of reach'),
    (pose(0.05, 0.0), 'out of reach'),
])
def test_pose_refusals(msg, reason):
    with pytest.raises(ConversionError, match=reason):
        conversions.pose_to_joint_goal(msg, 'base_link', 1.1, (-1.0, 3.0))


def _joint_state(names, positions, velocities=()):
    return JointState(name=names, position=positions, velocity=velocities)


def test_joint_state_by_name():
    state = conversions.joint_state_to_state(
        _joint_state(['other', 'extension_joint', 'rotation_joint'], [9.0, 1.5, 0.25],
                     [9.0, -0.5, 0.125]), NAMES)
    np.testing.assert_array_equal(state, [0.25, 0.125, 1.5, -0.5])
    state = conversions.joint_state_to_state(_joint_state(NAMES, [0.25, 1.5]), NAMES)
    np.testing.assert_array_equal(state, [0.25, 0.0, 1.5, 0.0])


@pytest.mark.parametrize('msg, reason', [
    (_joint_state(['rotation_joint'], [0.1]), 'lacks joints'),
    (_joint_state(NAMES, [0.1]), '2 names but 1 positions'),
    (_joint_state(NAMES, [0.1, 1.0], [0.0]), 'velocities'),
    (_joint_state(NAMES, [0.1, math.nan]), 'NaN'),
    (_joint_state(NAMES, [0.1, 1.0], [math.inf, 0.0]), 'NaN or inf'),
    (_joint_state(NAMES + ['rotation_joint'], [0.1, 1.0, 0.2]), 'duplicate'),
])
def test_joint_state_refusals(msg, reason):
    with pytest.raises(ConversionError, match=reason):
        conversions.joint_state_to_state(msg, NAMES)


def _array(data, dims=(), offset=0):
    msg = Float64MultiArray(data=[float(v) for v in data])
    msg.layout.data_offset = offset
    msg.layout.dim = [MultiArrayDimension(label=label, size=size, stride=stride)
                      for label, size, stride in dims]
    return msg


def test_obstacle_rows():
    assert conversions.obstacle_rows_from_msg(_array([])) == ()
    rows = conversions.obstacle_rows_from_msg(_array([1, 1, 0.2, -1, 2, 0.5]))
    assert rows == ((1.0, 1.0, 0.2), (-1.0, 2.0, 0.5))
    laid_out = _array([7, 1, 1, 0.2], [('rows', 1, 3), ('xyr', 3, 3)], offset=1)
    assert conversions.obstacle_rows_from_msg(laid_out) == ((1.0, 1.0, 0.2),)


@pytest.mark.parametrize('msg, reason', [
    (_array([1, 1]), 'multiple of 3'),
    (_array([1, 1, -0.2]), 'radius must be > 0'),
    (_array([1, 1, 0.0]), 'radius must be > 0'),
    (_array([1, math.nan, 0.2]), 'non-finite'),
    (_array([0.1, 0.0, 0.5]), 'contains the robot base'),
    (_array([300.0, 0.0, 0.2]), 'beyond 100 m from the base'),
    (_array([1, 1, 0.2], [('rows', 1, 3), ('xy', 2, 2)]), 'layout'),
    (_array([1, 1, 0.2], [('rows', 2, 6), ('xyr', 3, 3)]), 'does not match'),
    (_array([1, 1, 0.2], [('a', 1, 3), ('b', 3, 3), ('c', 1, 1)]), 'layout'),
])
def test_obstacle_refusals(msg, reason):
    with pytest.raises(ConversionError, match=reason):
        conversions.obstacle_rows_from_msg(msg)


def test_time_and_duration_round_the_total_not_the_fraction():
    """15.9999999996 s is 16 s: rounding only the fraction would give 15 s + 0 ns."""
    for convert in (conversions.time_msg, conversions.duration_msg):
        msg = convert(15.9999999996)
        assert (msg.sec, msg.nanosec) == (16, 0)
        msg = convert(2.5)
        assert (msg.sec, msg.nanosec) == (2, 500_000_000)


def test_time_and_duration_of_nanoseconds_round_trip():
    for total in (0, 999_999_999, 1_000_000_000, 1_765_000_000_123_456_789):
        for convert in (conversions.time_of_ns, conversions.duration_of_ns):
            msg = convert(total)
            assert 0 <= msg.nanosec < 1_000_000_000
            assert conversions.nanoseconds(msg) == total
    assert type(conversions.time_of_ns(5)).__name__ == 'Time'
    assert type(conversions.duration_of_ns(5)).__name__ == 'Duration'
