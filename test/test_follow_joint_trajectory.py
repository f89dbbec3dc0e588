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

"""JointTrajectoryController semantics of plant/follow_joint_trajectory (pure Python)."""

import glob
import os
import re
from types import SimpleNamespace as NS

import numpy as np
import pytest
from toc_ros.plant import follow_joint_trajectory as fjt

JOINTS = ['a', 'b']
SEC = 1_000_000_000
REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _duration(seconds):
    total = int(round(seconds * SEC))
    return NS(sec=total // SEC, nanosec=total % SEC)


def _point(t, positions, velocities=(), accelerations=(), effort=()):
    return NS(time_from_start=_duration(t), positions=list(positions),
              velocities=list(velocities), accelerations=list(accelerations),
              effort=list(effort))


def _msg(points, names=JOINTS, stamp=0.0):
    return NS(joint_names=list(names), header=NS(stamp=_duration(stamp)), points=points)


def _goal(path=(), goal=(), goal_time=0.0):
    return NS(path_tolerance=[NS(name=n, position=p, velocity=v, acceleration=a)
                              for n, p, v, a in path],
              goal_tolerance=[NS(name=n, position=p, velocity=v, acceleration=a)
                              for n, p, v, a in goal],
              goal_time_tolerance=_duration(goal_time))


def test_error_codes_mirror_control_msgs():
    candidates = (glob.glob(os.path.join(REPO, '.ros2env', 'src', 'control_msgs', '**',
                                         'FollowJointTrajectory.action'), recursive=True)
                  + glob.glob('/work/main/.ros2env/src/control_msgs/**/'
                              'FollowJointTrajectory.action', recursive=True))
    if not candidates:
        pytest.skip('control_msgs sources not present')
    with open(candidates[0]) as f:
        text = f.read()
    codes = dict(re.findall(r'int32 (\w+) = (-?\d+)', text))
    assert {k: int(v) for k, v in codes.items()} == {
        'SUCCESSFUL': fjt.SUCCESSFUL, 'INVALID_GOAL': fjt.INVALID_GOAL,
        'INVALID_JOINTS': fjt.INVALID_JOINTS, 'OLD_HEADER_TIMESTAMP': fjt.OLD_HEADER_TIMESTAMP,
        'PATH_TOLERANCE_VIOLATED': fjt.PATH_TOLERANCE_VIOLATED,
        'GOAL_TOLERANCE_VIOLATED': fjt.GOAL_TOLERANCE_VIOLATED}


def test_joints_in_any_order_are_mapped_by_name():
    traj = fjt.validate(_msg([_point(0.0, [1.0, 2.0], effort=[3.0, 4.0])], names=['b', 'a']),
                        JOINTS, 0)
    np.testing.assert_array_equal(traj.points[0].positions, [2.0, 1.0])
    np.testing.assert_array_equal(traj.points[0].effort, [4.0, 3.0])


@pytest.mark.parametrize('msg, code, match', [
    (_msg([_point(1, [0, 0])], names=['a']), fjt.INVALID_JOINTS, 'missing'),
    (_msg([_point(1, [0, 0, 0])], names=['a', 'b', 'c']), fjt.INVALID_JOINTS, 'unknown'),
    (_msg([_point(1, [0, 0])], names=['a', 'x']), fjt.INVALID_JOINTS, 'unknown'),
    (_msg([_point(1, [0, 0])], names=['a', 'a']), fjt.INVALID_JOINTS, 'exactly once'),
    (_msg([], names=[]), fjt.INVALID_JOINTS, 'empty joint names'),
    (_msg([]), fjt.INVALID_GOAL, 'empty trajectory'),
    (_msg([_point(1, [0, 0]), _point(1, [1, 1])]), fjt.INVALID_GOAL, 'strictly'),
    (_msg([_point(2, [0, 0]), _point(1, [1, 1])]), fjt.INVALID_GOAL, 'strictly'),
    (_msg([_point(1, [0])]), fjt.INVALID_GOAL, 'positions'),
    (_msg([_point(1, [0, 0], velocities=[0])]), fjt.INVALID_GOAL, 'velocities'),
    (_msg([_point(1, [0, 0], accelerations=[0, 0, 0])]), fjt.INVALID_GOAL, 'accelerations'),
    (_msg([_point(1, [0, 0], effort=[1])]), fjt.INVALID_GOAL, 'effort'),
    (_msg([_point(1, [0, float('nan')])]), fjt.INVALID_GOAL, 'non-finite'),
    (_msg([_point(1, [0, 0], velocities=[0, 0.1])]), fjt.INVALID_GOAL, 'not zero'),
    (_msg([_point(1, [0, 0])], stamp=5.0), fjt.OLD_HEADER_TIMESTAMP, 'in the past'),
])
def test_invalid_goals_get_their_code(msg, code, match):
    with pytest.raises(fjt.GoalError, match=match) as info:
        fjt.validate(msg, JOINTS, now_ns=7 * SEC)
    assert info.value.code == code


def test_zero_stamp_is_never_old_and_a_future_stamp_is_kept():
    assert fjt.validate(_msg([_point(1, [0, 0])]), JOINTS, 100 * SEC).start_ns is None
    assert fjt.validate(_msg([_point(1, [0, 0])], stamp=6.5), JOINTS, 7 * SEC).start_ns == \
        int(6.5 * SEC)


def _sampled(msg, times, state=None, begin=0.0):
    traj = fjt.validate(msg, JOINTS, 0)
    traj.begin(int(begin * SEC), state or traj.points[0])
    return [traj.sample(int(round(t * SEC))) for t in times]


def test_positions_only_is_linear():
    msg = _msg([_point(0.0, [0, 0]), _point(2.0, [2, -4])])
    mid, = _sampled(msg, [0.5])
    np.testing.assert_allclose(mid.positions, [0.5, -1.0])
    np.testing.assert_allclose(mid.velocities, [1.0, -2.0])


def _poly(coefficients, t):
    """Value and first two derivatives of a polynomial (lowest order first)."""
    c = np.polynomial.Polynomial(coefficients)
    return c(t), c.deriv(1)(t), c.deriv(2)(t)


@pytest.mark.parametrize('degree', [3, 5])
def test_cubic_and_quintic_reproduce_polynomials(degree):
    rng = np.random.default_rng(degree)
    coefficients = [rng.normal(size=degree + 1) for _ in JOINTS]
    times = [0.0, 0.4, 1.1, 1.5]

    def at(t):
        return [np.array(v) for v in zip(*(_poly(c, t) for c in coefficients))]

    points = []
    for t in times:
        q, dq, ddq = at(t)
        if t == times[-1]:
            dq = np.zeros(2)        # a goal ends at rest: compare before the last segment
        points.append(_point(t, q, dq, ddq if degree == 5 else ()))
    samples = np.linspace(0.0, 1.09, 23)
    for t, sample in zip(samples, _sampled(_msg(points), samples)):
        q, dq, ddq = at(t)
        np.testing.assert_allclose(sample.positions, q, atol=1e-9)
        np.testing.assert_allclose(sample.velocities, dq, atol=1e-9)
        np.testing.assert_allclose(sample.accelerations, ddq, atol=1e-8)


def test_velocity_is_the_derivative_of_position_and_effort_is_linear():
    msg = _msg([_point(0.0, [0, 1], [1, 0], effort=[0, 2]),
                _point(1.0, [1, 3], [2, -1], effort=[4, 6]),
                _point(2.0, [0, 0], [0, 0], effort=[1, 1])])
    h = 1e-6
    for t in (0.2, 0.7, 1.3):
        lo, mid, hi = _sampled(msg, [t - h, t, t + h])
        np.testing.assert_allclose(mid.velocities, (hi.positions - lo.positions) / (2 * h),
                                   atol=1e-6)
    a, = _sampled(msg, [0.25])
    np.testing.assert_allclose(a.effort, [1.0, 3.0])


def test_before_the_first_point_interpolates_from_the_state_and_after_the_end_holds():
    msg = _msg([_point(1.0, [1, 1], [0, 0]), _point(2.0, [2, 3], [0, 0], effort=[])])
    state = fjt.Point(np.array([0.0, -1.0]), np.array([0.5, 0.0]))
    start, half, after = _sampled(msg, [0.0, 0.5, 5.0], state=state)
    np.testing.assert_allclose(start.positions, [0.0, -1.0])
    np.testing.assert_allclose(start.velocities, [0.5, 0.0])
    assert start.segment == -1 and half.segment == -1
    np.testing.assert_allclose(after.positions, [2.0, 3.0])
    np.testing.assert_allclose(after.velocities, [0.0, 0.0])
    assert after.segment == 1


def test_zero_stamp_starts_at_the_first_update_and_a_future_stamp_waits():
    msg = _msg([_point(0.0, [0, 0]), _point(1.0, [1, 1])])
    follower = fjt.TrajectoryFollower(JOINTS)
    follower.follow(fjt.validate(msg, JOINTS, 0), fjt.Tolerances.defaults(2), 'g')
    follower.update(3 * SEC, [0, 0], [0, 0])
    assert follower.reference(int(3.5 * SEC)).positions == pytest.approx([0.5, 0.5])
    late = fjt.validate(_msg([_point(0.0, [1, 1]), _point(1.0, [2, 2])], stamp=10.0),
                        JOINTS, 4 * SEC)
    follower.follow(late, fjt.Tolerances.defaults(2), 'h')
    follower.update(4 * SEC, [0, 0], [0, 0], ([0.5, 0.5], [0.0, 0.0], None, None))
    # Until the stamp: from the state at the switch towards the first point.
    assert follower.reference(7 * SEC).segment == -1
    assert follower.reference(int(10.5 * SEC)).positions == pytest.approx([1.5, 1.5])


def _run(follower, track, t0, t1, dt=0.01):
    """Update from t0 to t1; track(t, desired) -> actual (q, v); return the outcomes."""
    outcomes = []
    desired = None
    t = t0
    while t <= t1 + 1e-12:
        t_ns = int(round(t * SEC))
        q, v = track(t, desired)
        desired = follower.update(t_ns, q, v)
        outcomes += follower.take_outcomes()
        t += dt
    return outcomes


def _perfect(t, desired):
    if desired is None:
        return np.zeros(2), np.zeros(2)
    return desired.positions, desired.velocities


MOVE = _msg([_point(0.0, [0, 0], [0, 0]), _point(1.0, [1, -1], [0, 0])])


def test_tracked_trajectory_succeeds_at_the_end():
    follower = fjt.TrajectoryFollower(JOINTS)
    tolerances, warning = fjt.goal_tolerances(
        fjt.Tolerances.defaults(2), _goal(path=[('a', 0.1, 0, 0)], goal=[('b', 0.01, 0, 0)]),
        JOINTS)
    assert warning is None
    follower.follow(fjt.validate(MOVE, JOINTS, 0), tolerances, 'g')
    outcomes = _run(follower, _perfect, 0.0, 1.5)
    assert [(o.goal, o.code) for o in outcomes] == [('g', fjt.SUCCESSFUL)]
    assert not follower.active


def test_path_tolerance_violation_aborts_and_holds_the_current_position():
    follower = fjt.TrajectoryFollower(JOINTS)
    tolerances, _ = fjt.goal_tolerances(fjt.Tolerances.defaults(2),
                                        _goal(path=[('b', 0.05, 0, 0)]), JOINTS)
    follower.follow(fjt.validate(MOVE, JOINTS, 0), tolerances, 'g')

    def stuck_b(t, desired):
        q, v = _perfect(t, desired)
        return np.array([q[0], 0.0]), np.array([v[0], 0.0])

    outcomes = _run(follower, stuck_b, 0.0, 1.5)
    assert [o.code for o in outcomes] == [fjt.PATH_TOLERANCE_VIOLATED]
    assert 'b position error' in outcomes[0].text
    # Held where it was when the violation was seen (b stuck at 0), with zero velocity.
    held = follower.reference(5 * SEC)
    assert held.positions[1] == 0.0 and np.all(held.velocities == 0.0)
    assert 0.0 < held.positions[0] < 0.5


def test_goal_tolerance_violated_after_goal_time():
    follower = fjt.TrajectoryFollower(JOINTS)
    tolerances, _ = fjt.goal_tolerances(
        fjt.Tolerances.defaults(2), _goal(goal=[('a', 0.01, 0, 0)], goal_time=0.2), JOINTS)
    follower.follow(fjt.validate(MOVE, JOINTS, 0), tolerances, 'g')

    def short(t, desired):
        q, v = _perfect(t, desired)
        return np.minimum(q, 0.9), v

    outcomes = _run(follower, short, 0.0, 1.5)
    assert [o.code for o in outcomes] == [fjt.GOAL_TOLERANCE_VIOLATED]
    # Not before the end + goal_time: the reference at 1.15 s was still being waited for.
    assert 'exceeding by 0.2' in outcomes[0].text


def test_goal_time_zero_waits_until_the_goal_is_reached():
    follower = fjt.TrajectoryFollower(JOINTS)
    tolerances, _ = fjt.goal_tolerances(fjt.Tolerances.defaults(2),
                                        _goal(goal=[('a', 0.01, 0, 0)]), JOINTS)
    follower.follow(fjt.validate(MOVE, JOINTS, 0), tolerances, 'g')

    def slow(t, desired):
        q, v = _perfect(t, desired)
        return np.array([min(q[0], 0.5 * t), q[1]]), np.zeros(2)

    outcomes = _run(follower, slow, 0.0, 1.9)
    assert outcomes == []
    outcomes = _run(follower, slow, 1.9, 2.1)
    assert [o.code for o in outcomes] == [fjt.SUCCESSFUL]


def test_stopped_velocity_tolerance_is_a_default_goal_tolerance():
    follower = fjt.TrajectoryFollower(JOINTS)
    tolerances = fjt.Tolerances.defaults(2, goal_time=0.1)
    follower.follow(fjt.validate(MOVE, JOINTS, 0), tolerances, 'g')

    def moving(t, desired):
        q, _ = _perfect(t, desired)
        return q, np.array([0.02, 0.0])

    outcomes = _run(follower, moving, 0.0, 1.5)
    assert [o.code for o in outcomes] == [fjt.GOAL_TOLERANCE_VIOLATED]
    assert 'a velocity error' in outcomes[0].text


def test_new_goal_preempts_and_joins_the_reference_without_a_jump():
    follower = fjt.TrajectoryFollower(JOINTS, interpolate_from_desired_state=True)
    follower.follow(fjt.validate(MOVE, JOINTS, 0), fjt.Tolerances.defaults(2), 'first')
    offset = np.array([0.05, -0.05])

    def lagging(t, desired):
        q, v = _perfect(t, desired)
        return q - offset, v
    _run(follower, lagging, 0.0, 0.5)
    switch = int(0.51 * SEC)
    before = follower.reference(switch)
    assert before.segment == 0
    replan = fjt.validate(_msg([_point(0.2, [0.8, -0.2], [0, 0]),
                                _point(0.6, [0.0, 0.0], [0, 0])]), JOINTS, switch)
    follower.follow(replan, fjt.Tolerances.defaults(2), 'second')
    assert [(o.goal, o.code, o.text) for o in follower.take_outcomes()] == [
        ('first', fjt.INVALID_GOAL, fjt.PREEMPTED)]
    after = follower.update(switch, before.positions - offset, before.velocities,
                            (before.positions, before.velocities, before.accelerations,
                             before.effort))
    np.testing.assert_allclose(after.positions, before.positions, atol=1e-12)
    np.testing.assert_allclose(after.velocities, before.velocities, atol=1e-12)
    step = follower.reference(switch + SEC // 1000)
    assert np.max(np.abs(step.positions - before.positions)) < 2e-3
    # JTC's default instead starts from the measured state: the reference jumps by the
    # tracking error.
    measured = fjt.TrajectoryFollower(JOINTS, interpolate_from_desired_state=False)
    measured.follow(fjt.validate(_msg([_point(0.2, [0.8, -0.2], [0, 0])]), JOINTS,
                                 switch), fjt.Tolerances.defaults(2), 'x')
    jumped = measured.update(switch, before.positions - offset, before.velocities,
                             (before.positions, before.velocities, None, None))
    np.testing.assert_allclose(jumped.positions, before.positions - offset)


def test_invalid_goal_leaves_the_active_one_alone():
    follower = fjt.TrajectoryFollower(JOINTS)
    follower.follow(fjt.validate(MOVE, JOINTS, 0), fjt.Tolerances.defaults(2), 'g')
    _run(follower, _perfect, 0.0, 0.3)
    with pytest.raises(fjt.GoalError):
        fjt.validate(_msg([_point(1, [0, 0])], names=['a', 'x']), JOINTS, 0)
    assert follower.goal == 'g' and follower.take_outcomes() == []


def test_cancel_holds_the_current_position():
    follower = fjt.TrajectoryFollower(JOINTS)
    follower.follow(fjt.validate(MOVE, JOINTS, 0), fjt.Tolerances.defaults(2), 'g')
    _run(follower, _perfect, 0.0, 0.3)
    assert follower.cancel('g', [0.25, -0.25])
    assert [(o.goal, o.code) for o in follower.take_outcomes()] == [('g', fjt.CANCELED)]
    np.testing.assert_allclose(follower.reference(9 * SEC).positions, [0.25, -0.25])
    assert not follower.cancel('g', [0, 0])


@pytest.mark.parametrize('goal, expected, warns', [
    (_goal(path=[('a', 0.3, 0, 0)]), [0.3, 0.1], False),
    (_goal(path=[('b', -1.0, 0, 0)]), [0.1, 0.0], False),
    (_goal(path=[('b', 0.0, 0, 0)]), [0.1, 0.1], False),
    (_goal(path=[('a', 0.3, 0, 0), ('b', -2.0, 0, 0)]), [0.1, 0.1], True),
    (_goal(path=[('x', 0.3, 0, 0)]), [0.1, 0.1], True),
    (_goal(goal_time=0.0), [0.1, 0.1], False),
])
def test_goal_tolerances_follow_jtc_rules(goal, expected, warns):
    defaults = fjt.Tolerances.defaults(2, path_position=0.1, goal_time=0.5)
    tolerances, warning = fjt.goal_tolerances(defaults, goal, JOINTS)
    np.testing.assert_array_equal(tolerances.path_position, expected)
    assert (warning is not None) == warns
    assert tolerances.goal_time == 0.5
