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
End-effector pose goals: IK round trips, limits, collisions, determinism and refusals.

Goals are the poses of random in-limit configurations; the answers are checked with the
independent numpy forward kinematics of the URDF (urdf_oracle.py), not with Pinocchio.
"""

import numpy as np
import pytest

pin = pytest.importorskip('pinocchio')

from test_arm_model import toy  # noqa: E402
from toc_ros.core.arms import (ArmError, default_spheres, load_arm, solve_ik,  # noqa: E402
                               worst_collision)
import urdf_oracle  # noqa: E402

TIPS = {'panda': 'panda_hand_tcp', 'ur5': 'tool0'}


def oracle_pose(arm, q, link):
    values = dict(arm.locked)
    values.update(zip(arm.joint_names, q))
    return urdf_oracle.UrdfOracle(arm.urdf).link_poses(values)[link]


def quaternion_xyzw(rotation):
    quat = pin.Quaternion(rotation)
    return [quat.x, quat.y, quat.z, quat.w]


def rotation_error(r_a, r_b):
    cos = np.clip((np.trace(r_a.T @ r_b) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.arccos(cos))


def clear_configurations(arm, spheres, count, seed):
    """Random in-limit configurations free of self-collision."""
    rng = np.random.default_rng(seed)
    found = []
    while len(found) < count:
        q = rng.uniform(arm.lower, arm.upper)
        if worst_collision(arm, spheres, q) is None:
            found.append(q)
    return found


@pytest.mark.parametrize('name', ['panda', 'ur5'])
def test_pose_round_trips(name):
    arm = load_arm(name)
    spheres = default_spheres(arm)
    tip = TIPS[name]
    for q_goal in clear_configurations(arm, spheres, 4, seed=11):
        goal = oracle_pose(arm, q_goal, tip)
        q = solve_ik(arm, tip, goal[:3, 3], quaternion_xyzw(goal[:3, :3]),
                     q_start=np.clip(np.zeros(arm.n), arm.lower, arm.upper), spheres=spheres)
        assert np.all(q >= arm.lower) and np.all(q <= arm.upper)
        reached = oracle_pose(arm, q, tip)
        assert np.linalg.norm(reached[:3, 3] - goal[:3, 3]) < 1e-6
        assert rotation_error(reached[:3, :3], goal[:3, :3]) < 1e-6


def test_position_only_goal_and_start_seed_first():
    arm = load_arm('panda')
    home = np.array([0, -0.785398, 0, -2.35619, 0, 1.5707, 0.785398])
    target = oracle_pose(arm, home, 'panda_hand_tcp')[:3, 3] + [0.05, -0.03, 0.02]
    q = solve_ik(arm, 'panda_hand_tcp', target, q_start=home)
    assert np.linalg.norm(oracle_pose(arm, q, 'panda_hand_tcp')[:3, 3] - target) < 1e-6
    # Seeded at the start, a small move stays near it (the redundant arm is not flung away).
    assert np.abs(q - home).max() < 0.5


@pytest.mark.parametrize('orientation', [False, True])
def test_one_planned_joint_reaches_its_pose(orientation):
    # Pinocchio returns a one-joint model's 6 x 1 Jacobians as vectors (was an IndexError).
    arm = load_arm('panda', joints=['panda_joint1'])
    goal = oracle_pose(arm, np.array([0.7]), 'panda_hand_tcp')
    quaternion = quaternion_xyzw(goal[:3, :3]) if orientation else None
    q = solve_ik(arm, 'panda_hand_tcp', goal[:3, 3], quaternion, q_start=np.zeros(1))
    assert q.shape == (1,) and abs(q[0] - 0.7) < 1e-6
    assert arm.frame_jacobian(q, 'panda_hand_tcp').shape == (6, 1)


def test_answers_are_deterministic():
    arm = load_arm('ur5')
    goal = oracle_pose(arm, np.array([0.3, -1.2, 1.4, -0.5, 1.0, 0.2]), 'tool0')
    first = solve_ik(arm, 'tool0', goal[:3, 3], quaternion_xyzw(goal[:3, :3]))
    second = solve_ik(arm, 'tool0', goal[:3, 3], quaternion_xyzw(goal[:3, :3]))
    np.testing.assert_array_equal(first, second)


def test_limits_hold_when_the_goal_needs_a_joint_at_its_bound():
    # The toy arm's tool lies 0.35 m + slide from its elbow point (0, 0, 0.5): a goal at
    # 0.55 m needs the slide at its upper limit 0.2 exactly, one at 0.6 m is out of reach.
    arm = load_arm(toy())
    direction = np.array([0.6, -0.3, 0.5]) / np.linalg.norm([0.6, -0.3, 0.5])
    target = np.array([0.0, 0.0, 0.5]) + 0.55 * direction
    q = solve_ik(arm, 'tool', target, q_start=[0.0, 0.0, 0.0])
    assert q[2] == pytest.approx(0.2, abs=1e-9) and q[2] <= arm.upper[2] == 0.2
    assert np.all(q[1:] >= arm.lower[1:]) and np.all(q[1:] <= arm.upper[1:])
    assert np.linalg.norm(oracle_pose(arm, q, 'tool')[:3, 3] - target) < 1e-6
    with pytest.raises(ArmError, match='unreachable'):
        solve_ik(arm, 'tool', np.array([0.0, 0.0, 0.5]) + 0.6 * direction, seeds=4)


def test_obstacles_steer_the_answer_to_a_clear_solution():
    arm = load_arm('panda')
    spheres = default_spheres(arm)
    home = np.array([0, -0.785398, 0, -2.35619, 0, 1.5707, 0.785398])
    target = oracle_pose(arm, home, 'panda_hand_tcp')[:3, 3]
    free = solve_ik(arm, 'panda_hand_tcp', target, q_start=home, spheres=spheres)
    # An obstacle on the elbow of the unobstructed answer: another solution must avoid it.
    values = dict(arm.locked)
    values.update(zip(arm.joint_names, free))
    elbow = urdf_oracle.UrdfOracle(arm.urdf).link_poses(values)['panda_link4'][:3, 3]
    obstacle = [list(elbow) + [0.08]]
    margin = 0.01
    assert worst_collision(arm, spheres, free, obstacle, margin) is not None
    q = solve_ik(arm, 'panda_hand_tcp', target, q_start=home, spheres=spheres,
                 obstacles=obstacle, margin=margin)
    assert np.linalg.norm(oracle_pose(arm, q, 'panda_hand_tcp')[:3, 3] - target) < 1e-6
    centres = urdf_oracle.sphere_centres(urdf_oracle.UrdfOracle(arm.urdf),
                                         dict(zip(arm.joint_names, q)), spheres.links,
                                         spheres.offsets)
    for c, r in zip(centres, spheres.radii):
        assert urdf_oracle.pair_clearance(c, r, obstacle[0][:3], 0.08, margin) >= 0


def test_unreachable_and_colliding_goals_are_refused():
    arm = load_arm('panda')
    spheres = default_spheres(arm)
    with pytest.raises(ArmError, match='unreachable within the joint limits'):
        solve_ik(arm, 'panda_hand_tcp', [2.0, 0.0, 0.5], seeds=4)
    # The goal inside an obstacle: every solution collides.
    with pytest.raises(ArmError, match='every solution found is in collision'):
        solve_ik(arm, 'panda_hand_tcp', [0.5, 0.0, 0.4], spheres=spheres,
                 obstacles=[[0.5, 0.0, 0.4, 0.1]], seeds=4)


@pytest.mark.parametrize('kwargs, reason', [
    ({'link': 'nope'}, "unknown link 'nope'"),
    ({'position': [0.5, 0.0]}, 'goal position must be 3 finite numbers'),
    ({'position': [0.5, float('nan'), 0.4]}, 'goal position must be 3 finite numbers'),
    ({'orientation': [0, 0, 0, 0]}, 'has norm 0'),
    ({'orientation': [0, 0, float('inf'), 1]}, 'must be 4 finite numbers'),
    ({'orientation': [0, 0, 1]}, 'must be 4 finite numbers'),
    ({'obstacles': [[1, 1, 1, 0.1]]}, "needs the arm's collision spheres"),
    ({'q_start': [0.0] * 6}, 'IK start positions has 6 values'),
])
def test_bad_goals_are_refused_with_their_reason(kwargs, reason):
    arm = load_arm('panda')
    args = {'link': 'panda_hand_tcp', 'position': [0.5, 0.0, 0.4]}
    args.update(kwargs)
    with pytest.raises(ArmError) as error:
        solve_ik(arm, **args)
    assert reason in str(error.value)
