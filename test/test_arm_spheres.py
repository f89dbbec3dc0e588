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
Collision spheres: file checks, centres and Jacobians, obstacle and self clearances, state checks.

Centres and every clearance are recomputed with the independent numpy forward kinematics of
the URDF (urdf_oracle.py) and plain loops; which pairs are checked for self-collision is
recomputed from the URDF tree there too.  Jacobians are checked against central differences.
"""

import os

import numpy as np
import pytest

pytest.importorskip('pinocchio')

from test_arm_model import toy  # noqa: E402
from toc_ros.core.arms import (ArmError, check_obstacles, check_state, default_spheres,  # noqa
                               load_arm, load_spheres, obstacle_clearance,
                               obstacle_clearance_jacobian, obstacle_clearances_batch,
                               self_clearance, self_clearance_jacobian, self_clearances_batch,
                               shipped_spheres_path, sphere_centres, sphere_jacobians,
                               sphere_kinematics_batch, worst_collision)
import urdf_oracle  # noqa: E402

ARMS = {
    'panda': {'source': 'panda'},
    'ur5': {'source': 'ur5'},
    # Joints 3 and 5 locked: links 3 and 5 ride on their parents' bodies.
    'panda_locked': {'source': 'panda',
                     'joints': ('panda_joint1', 'panda_joint2', 'panda_joint4', 'panda_joint6',
                                'panda_joint7'),
                     'locked': {'panda_joint3': 0.4, 'panda_joint5': -1.1,
                                'panda_finger_joint1': 0.03, 'panda_finger_joint2': 0.01}},
    # One planned joint: Pinocchio returns its 6 x 1 Jacobians as vectors.
    'panda_one_joint': {'source': 'panda', 'joints': ('panda_joint1',),
                        'locked': {'panda_joint4': -1.5, 'panda_joint6': 1.5}},
}


def arm_and_spheres(key):
    spec = dict(ARMS[key])
    arm = load_arm(spec.pop('source'), **spec)
    return arm, load_spheres(shipped_spheres_path(arm.source['model']), arm)


def joint_values(arm, q):
    values = dict(arm.locked)
    values.update(zip(arm.joint_names, q))
    return values


def random_q(arm, count, seed):
    rng = np.random.default_rng(seed)
    return [rng.uniform(arm.lower, arm.upper) for _ in range(count)]


def test_shipped_sets_load_with_modest_counts():
    for name, count, pairs in (('panda', 20, 61), ('ur5', 14, 37)):
        arm = load_arm(name)
        spheres = default_spheres(arm)
        assert len(spheres) == count
        assert len(spheres.self_pairs) == pairs
        assert spheres.source == shipped_spheres_path(name)
        assert np.all(spheres.radii > 0)
        # The usual home poses are collision-free with these spheres.
        home = {'panda': [0, -0.785398, 0, -2.35619, 0, 1.5707, 0.785398],
                'ur5': [0, -1.5708, 1.5708, -1.5708, -1.5708, 0]}[name]
        assert worst_collision(arm, spheres, np.array(home)) is None
    assert default_spheres(load_arm(load_arm('ur5').urdf)) is None     # no named arm


@pytest.mark.parametrize('key', sorted(ARMS))
def test_centres_and_every_clearance_match_the_independent_oracle(key):
    arm, spheres = arm_and_spheres(key)
    oracle = urdf_oracle.UrdfOracle(arm.urdf)
    obstacles = np.array([[0.4, 0.1, 0.5, 0.1], [-0.2, 0.3, 0.2, 0.05], [0.1, -0.4, 0.8, 0.2]])
    margin = 0.02
    for q in random_q(arm, 4, seed=5):
        centres = sphere_centres(arm, spheres, q)
        expected = urdf_oracle.sphere_centres(oracle, joint_values(arm, q), spheres.links,
                                              spheres.offsets)
        np.testing.assert_allclose(centres, expected, atol=1e-12)
        clearance = obstacle_clearance(centres, spheres.radii, obstacles, margin)
        assert clearance.shape == (len(spheres), len(obstacles))
        for s in range(len(spheres)):
            for o, obstacle in enumerate(obstacles):
                assert clearance[s, o] == pytest.approx(urdf_oracle.pair_clearance(
                    expected[s], spheres.radii[s], obstacle[:3], obstacle[3], margin), abs=1e-12)
        own = self_clearance(centres, spheres.radii, spheres.self_pairs)
        for p, (a, b) in enumerate(spheres.self_pairs):
            assert own[p] == pytest.approx(urdf_oracle.pair_clearance(
                expected[a], spheres.radii[a], expected[b], spheres.radii[b]), abs=1e-12)


@pytest.mark.parametrize('key', sorted(ARMS))
def test_self_pairs_are_the_non_adjacent_non_ignored_moving_pairs(key):
    arm, spheres = arm_and_spheres(key)
    oracle = urdf_oracle.UrdfOracle(arm.urdf)
    q0, q1 = random_q(arm, 2, seed=6)
    moving_0 = sphere_centres(arm, spheres, q0)
    moving_1 = sphere_centres(arm, spheres, q1)
    expected = set()
    for a in range(len(spheres)):
        for b in range(a + 1, len(spheres)):
            la, lb = spheres.links[a], spheres.links[b]
            if la == lb or oracle.adjacent(la, lb) or frozenset((la, lb)) in spheres.ignore_pairs:
                continue
            # Pairs held rigidly together keep their distance: not checked.
            d0 = np.linalg.norm(moving_0[a] - moving_0[b])
            d1 = np.linalg.norm(moving_1[a] - moving_1[b])
            if abs(d0 - d1) < 1e-12 and spheres.joint_ids[a] == spheres.joint_ids[b]:
                continue
            expected.add((a, b))
    assert {tuple(p) for p in spheres.self_pairs.tolist()} == expected
    if key == 'panda_locked':
        # link4 and link5 are fused by the lock; link3 sits on joint 2's body with link2.
        assert spheres.joint_ids[spheres.links.index('panda_link5')] == \
            spheres.joint_ids[spheres.links.index('panda_link4')]


@pytest.mark.parametrize('key', sorted(ARMS))
def test_jacobians_match_central_differences(key):
    arm, spheres = arm_and_spheres(key)
    obstacles = np.array([[0.4, 0.1, 0.5, 0.1], [-0.2, 0.3, 0.2, 0.05]])
    eps = 1e-6
    for q in random_q(arm, 3, seed=7):
        centres, jac = sphere_jacobians(arm, spheres, q)
        np.testing.assert_allclose(centres, sphere_centres(arm, spheres, q), atol=1e-14)
        obstacle_jac = obstacle_clearance_jacobian(centres, jac, obstacles)
        self_jac = self_clearance_jacobian(centres, jac, spheres.self_pairs)
        for k in range(arm.n):
            step = np.zeros(arm.n)
            step[k] = eps
            plus = sphere_centres(arm, spheres, q + step)
            minus = sphere_centres(arm, spheres, q - step)
            np.testing.assert_allclose(jac[:, :, k], (plus - minus) / (2 * eps), atol=1e-8)
            np.testing.assert_allclose(
                obstacle_jac[:, :, k],
                (obstacle_clearance(plus, spheres.radii, obstacles)
                 - obstacle_clearance(minus, spheres.radii, obstacles)) / (2 * eps), atol=1e-8)
            np.testing.assert_allclose(
                self_jac[:, k],
                (self_clearance(plus, spheres.radii, spheres.self_pairs)
                 - self_clearance(minus, spheres.radii, spheres.self_pairs)) / (2 * eps),
                atol=1e-8)


@pytest.mark.parametrize('key', sorted(ARMS))
def test_centres_match_pinocchio_frame_placements(key):
    arm, spheres = arm_and_spheres(key)
    for q in random_q(arm, 3, seed=8):
        expected = np.array([arm.frame_pose(q, link).act(offset)
                             for link, offset in zip(spheres.links, spheres.offsets)])
        np.testing.assert_allclose(sphere_centres(arm, spheres, q), expected, atol=1e-12)


def test_prismatic_and_continuous_joints_in_the_sphere_kinematics():
    arm = load_arm(toy())
    spheres = load_spheres({'a': [[0.02, 0.0, 0.3, 0.05]], 'c': [[0.01, 0.02, 0.0, 0.03]],
                            'tool': [[0.03, 0.0, 0.01, 0.02]]}, arm)
    oracle = urdf_oracle.UrdfOracle(arm.urdf)
    for q in ([0.3, 0.5, 0.1], [5.0, -1.5, 0.2], [-4.0, 1.9, 0.0]):
        q = np.array(q)
        centres, jac = sphere_jacobians(arm, spheres, q)
        np.testing.assert_allclose(centres, urdf_oracle.sphere_centres(
            oracle, dict(zip(arm.joint_names, q)), spheres.links, spheres.offsets), atol=1e-12)
        for k in range(arm.n):
            step = np.zeros(arm.n)
            step[k] = 1e-6
            np.testing.assert_allclose(jac[:, :, k], (sphere_centres(arm, spheres, q + step)
                                                      - sphere_centres(arm, spheres, q - step))
                                       / 2e-6, atol=1e-8)
    # The sphere on link a moves only with the first joint.
    assert spheres.support.tolist() == [[True, False, False], [True, True, True],
                                        [True, True, True]]


def test_batches_equal_single_configurations():
    arm, spheres = arm_and_spheres('panda')
    qs = np.array(random_q(arm, 5, seed=9))
    obstacles = np.array([[0.4, 0.1, 0.5, 0.1], [-0.2, 0.3, 0.2, 0.05]])
    centres, jac = sphere_kinematics_batch(spheres, qs)
    values, gradients = obstacle_clearances_batch(centres, jac, spheres.radii, obstacles, 0.03)
    own, own_gradients = self_clearances_batch(centres, jac, spheres.radii, spheres.self_pairs,
                                               0.01)
    for i, q in enumerate(qs):
        c, j = sphere_jacobians(arm, spheres, q)
        np.testing.assert_array_equal(centres[i], c)
        np.testing.assert_array_equal(jac[i], j)
        np.testing.assert_allclose(values[i], obstacle_clearance(c, spheres.radii, obstacles,
                                                                 0.03), atol=1e-14)
        np.testing.assert_allclose(gradients[i], obstacle_clearance_jacobian(c, j, obstacles),
                                   atol=1e-14)
        np.testing.assert_allclose(own[i], self_clearance(c, spheres.radii, spheres.self_pairs,
                                                          0.01), atol=1e-14)
        np.testing.assert_allclose(own_gradients[i],
                                   self_clearance_jacobian(c, j, spheres.self_pairs), atol=1e-14)


def test_worst_collision_names_the_pair_and_depth():
    arm, spheres = arm_and_spheres('panda')
    q = np.array([0, -0.785398, 0, -2.35619, 0, 1.5707, 0.785398])
    centres = sphere_centres(arm, spheres, q)
    s = spheres.links.index('panda_link4') + 1          # panda_link4 sphere 1
    far = [3.0, 3.0, 3.0, 0.1]
    obstacle = list(centres[s] + [0.0, 0.0, spheres.radii[s] + 0.05 - 0.013]) + [0.05]
    hit = worst_collision(arm, spheres, q, [far, obstacle], margin=0.0)
    # The depth is the deepest over every sphere, recomputed here by brute force.
    depth = max(-(np.linalg.norm(c - obstacle[:3]) - r - 0.05)
                for c, r in zip(centres, spheres.radii))
    assert hit.depth == pytest.approx(depth, abs=1e-12)
    assert depth >= 0.013 - 1e-12
    label = spheres.label(int(np.argmax([-(np.linalg.norm(c - obstacle[:3]) - r)
                                         for c, r in zip(centres, spheres.radii)])))
    assert hit.text == f'{label} vs obstacle 1, depth {depth:.3f} m'
    assert worst_collision(arm, spheres, q, [far]) is None
    # A margin turns a near miss into a collision: an obstacle 10 mm from sphere s, on the
    # side (of the six axis directions) where every other sphere is farther.
    candidates = [list(centres[s] + d * (spheres.radii[s] + 0.05 + 0.01)) + [0.05]
                  for d in np.vstack([np.eye(3), -np.eye(3)])]
    near = max(candidates, key=lambda o: min(np.linalg.norm(c - o[:3]) - r - 0.05
                                             for c, r in zip(centres, spheres.radii)))
    assert min(np.linalg.norm(c - near[:3]) - r - 0.05
               for c, r in zip(centres, spheres.radii)) == pytest.approx(0.01, abs=1e-9)
    assert worst_collision(arm, spheres, q, [near], margin=0.0) is None
    assert worst_collision(arm, spheres, q, [near], margin=0.02) is not None
    # Self-collision: the hand folded onto the base.
    folded = np.array([0.0, 1.7, 0.0, -3.0, 0.0, 0.0, 0.0])
    own = worst_collision(arm, spheres, folded)
    centres = sphere_centres(arm, spheres, folded)
    clear = self_clearance(centres, spheres.radii, spheres.self_pairs)
    assert own is not None and '(self-collision)' in own.text
    assert own.depth == pytest.approx(-clear.min(), abs=1e-12)
    assert worst_collision(arm, spheres, folded, self_collision=False) is None


def test_check_state_refuses_bad_states_with_reasons():
    arm, spheres = arm_and_spheres('panda')
    home = [0, -0.785398, 0, -2.35619, 0, 1.5707, 0.785398]
    q, v = check_state(arm, home, [0.1] * 7, spheres=spheres)
    assert q.tolist() == home and v.tolist() == [0.1] * 7
    hand = arm.frame_position(np.array(home), 'panda_hand')
    cases = [
        ({'q': home[:6]}, 'start positions has 6 values; the arm has 7 joints'),
        ({'q': home[:3] + [float('nan')] + home[4:]}, 'panda_joint4 is nan (NaN or infinite)'),
        ({'q': home, 'v': [0, 0, float('inf'), 0, 0, 0, 0]}, 'panda_joint3 is inf'),
        ({'q': home[:3] + [0.1] + home[4:]}, 'panda_joint4 = 0.1 is outside its limits'),
        ({'q': home, 'v': [0, 3.0, 0, 0, 0, 0, 0]}, 'panda_joint2 velocity 3 exceeds its limit'),
        ({'q': home, 'obstacles': [list(hand) + [0.05]]}, 'start in collision: panda_'),
        ({'q': [0.0, 1.7, 0.0, -3.0, 0.0, 0.0, 0.0]}, '(self-collision)'),
        ({'q': home, 'obstacles': [[0, 0, 0, -1]]}, 'obstacle 0: negative radius'),
    ]
    for kwargs, reason in cases:
        with pytest.raises(ArmError) as error:
            check_state(arm, spheres=spheres, **kwargs)
        assert reason in str(error.value), (kwargs, str(error.value))
    with pytest.raises(ArmError, match='goal: obstacles need'):
        check_state(arm, home, what='goal', obstacles=[[1, 1, 1, 0.1]])


def test_curobo_layout_and_mappings_are_read():
    arm = load_arm('ur5')
    mine = load_spheres({'wrist_3_link': [[0.0, 0.06, 0.0, 0.04]],
                         'base_link': [[0, 0, 0, 0.1]]}, arm)
    curobo = load_spheres({'collision_spheres': {
        'wrist_3_link': [{'center': [0.0, 0.06, 0.0], 'radius': 0.04}],
        'base_link': [{'center': [0, 0, 0], 'radius': 0.1}]}}, arm)
    np.testing.assert_array_equal(mine.offsets, curobo.offsets)
    np.testing.assert_array_equal(mine.radii, curobo.radii)
    assert mine.self_pairs.tolist() == [[0, 1]]
    assert load_spheres({'wrist_3_link': [[0.0, 0.06, 0.0, 0.04]], 'base_link': [[0, 0, 0, 0.1]]},
                        arm, self_collision=False).self_pairs.shape == (0, 2)
    assert load_spheres({'wrist_3_link': [[0.0, 0.06, 0.0, 0.04]], 'base_link': [[0, 0, 0, 0.1]]},
                        arm, ignore_pairs=[['base_link', 'wrist_3_link']]).self_pairs.size == 0


@pytest.mark.parametrize('doc, reason', [
    ({'nope_link': [[0, 0, 0, 0.1]]}, 'unknown link(s) nope_link'),
    ({'shoulder_pan_joint': [[0, 0, 0, 0.1]]}, 'unknown link(s) shoulder_pan_joint'),
    ({'base_link': [[0, 0, 0, -0.1]]}, 'base_link sphere 0: negative radius'),
    ({'base_link': [[0, 0, 0, 0.1], [0, 0, 0, float('nan')]]}, 'base_link sphere 1: NaN'),
    ({'base_link': [[0, 0, float('inf'), 0.1]]}, 'NaN or infinite'),
    ({'base_link': [[0, 0, 0.1]]}, 'expected [x, y, z, r]'),
    ({'base_link': [[0, 0, 'a', 0.1]]}, 'entries must be numbers'),
    ({'base_link': 0.1}, 'must be a list of [x, y, z, r]'),
    ({'base_link': [{'center': [0, 0, 0]}]}, 'expected {center: [x, y, z], radius: r}'),
    ({}, 'no spheres'),
    ({'base_link': [[0, 0, 0, 0.1]], 'ignore_pairs': [['base_link', 'hand']]},
     "ignore_pairs: unknown link 'hand'"),
    ({'base_link': [[0, 0, 0, 0.1]], 'ignore_pairs': [['base_link']]}, 'pair of link names'),
    ({'base_link': [[0, 0, 0, 0.1]], 'ignore_pairs': 'base_link'}, 'ignore_pairs must be'),
])
def test_bad_sphere_files_are_refused_with_their_reason(doc, reason):
    with pytest.raises(ArmError) as error:
        load_spheres(doc, load_arm('ur5'))
    assert reason in str(error.value)


def test_bad_sphere_files_on_disk(tmp_path):
    arm = load_arm('ur5')
    broken = tmp_path / 'broken.yaml'
    broken.write_text('base_link: [[0, 0, 0, 0.1]\n')
    listed = tmp_path / 'listed.yaml'
    listed.write_text('- [0, 0, 0, 0.1]\n')
    for path, reason in ((broken, 'is not valid YAML'), (listed, 'must map link names'),
                         (tmp_path / 'missing.yaml', 'cannot read collision spheres')):
        with pytest.raises(ArmError) as error:
            load_spheres(os.fspath(path), arm)
        assert reason in str(error.value)
    with pytest.raises(ArmError, match='no shipped collision spheres'):
        shipped_spheres_path('kuka')


def test_spheres_held_together_in_collision_by_locks_are_refused():
    # Joints 4 and 5 locked: links 3, 4 and 5 form one body; link3 and link5 are not adjacent.
    arm = load_arm('panda', joints=('panda_joint1', 'panda_joint2', 'panda_joint3',
                                    'panda_joint6', 'panda_joint7'))
    doc = {'panda_link3': [[0, 0, 0, 0.3]], 'panda_link5': [[0, 0, 0, 0.3]]}
    with pytest.raises(ArmError, match='held together in collision'):
        load_spheres(doc, arm)
    ok = load_spheres(dict(doc, ignore_pairs=[['panda_link3', 'panda_link5']]), arm)
    assert ok.self_pairs.size == 0
    # Without self-collision the overlap is no concern: only obstacles are checked.
    assert len(load_spheres(doc, arm, self_collision=False).radii) == 2


def test_one_planned_joint_with_the_shipped_spheres_plans_past_an_obstacle():
    # The Panda's others locked at 0 (joint 4 clamped to -0.0698) hold link5 and a finger
    # 0.023 m into each other: refused before, whatever self-collision was.
    from toc_ros.core import Problem, solve, Status
    from toc_ros.core.arms.arm_solve import ArmRobot
    arm = load_arm('panda', joints=('panda_joint1',))
    robot = ArmRobot(arm, load_spheres(shipped_spheres_path('panda'), arm,
                                       self_collision=False))
    obstacle = (0.5, 0.3, 0.5, 0.05)
    result = solve(Problem(x0=(0.0, 0.0), x_goal=(1.0, 0.0), model=robot,
                           obstacles=(obstacle,), n_intervals=20))
    assert result.status is Status.SOLVED, result.message
    centres = np.array([sphere_centres(arm, robot.spheres, q) for q in result.states[:, :1]])
    gaps = np.linalg.norm(centres - np.array(obstacle[:3]), axis=-1) - robot.spheres.radii
    assert gaps.min() >= obstacle[3] - 1e-6


@pytest.mark.parametrize('obstacles, reason', [
    ([[0, 0, 0]], 'rows (cx, cy, cz, R)'),
    ([[0, 0, float('nan'), 1]], 'obstacle 0: NaN'),
    ([[0, 0, 0, 1], [0, 0, 0, -1]], 'obstacle 1: negative radius'),
    ('abc', 'rows (cx, cy, cz, R)'),
])
def test_bad_obstacles_are_refused(obstacles, reason):
    with pytest.raises(ArmError) as error:
        check_obstacles(obstacles)
    assert reason in str(error.value)


def test_spheres_of_another_arm_or_joint_set_are_refused():
    from toc_ros.core.arms.arm_solve import ArmRobot
    panda = load_arm('panda')
    spheres = load_spheres(shipped_spheres_path('panda'), panda)
    part = load_arm('panda', joints=('panda_joint1', 'panda_joint2'),
                    locked={'panda_joint4': -1.5, 'panda_joint6': 1.5})
    ur5 = load_arm('ur5')
    for arm in (part, ur5, load_arm('panda', locked={'panda_finger_joint1': 0.03})):
        with pytest.raises(ArmError, match='loaded for another arm'):
            ArmRobot(arm, spheres)
    ArmRobot(load_arm('panda'), spheres)        # the same arm loaded again fits
    with pytest.raises(ArmError, match='must come from load_spheres'):
        ArmRobot(panda, 'spheres.yaml')
    with pytest.raises(ArmError, match='needs an ArmModel'):
        ArmRobot(None)
    with pytest.raises(ArmError, match='self-collision needs'):
        ArmRobot(panda, None, True)
    with pytest.raises(ArmError, match='move with 7 joints'):
        sphere_centres(part, spheres, np.zeros(2))


def test_sphere_reach_bounds_every_centre_and_far_obstacles_get_no_rows():
    from toc_ros.core.arms.arm_eval import ArmEvaluator
    from toc_ros.core.arms.clearances import reachable_obstacles, sphere_reach
    for key in sorted(ARMS):
        arm, spheres = arm_and_spheres(key)
        reach = sphere_reach(spheres, arm)
        oracle = urdf_oracle.UrdfOracle(arm.urdf)
        for q in random_q(arm, 50, seed=3):
            centres = urdf_oracle.sphere_centres(oracle, joint_values(arm, q), spheres.links,
                                                 spheres.offsets)
            assert np.all(np.linalg.norm(centres, axis=1) <= reach + 1e-12)
        far = reach.max() + spheres.radii.max() + 0.5
        obstacles = np.array([[far, 0.0, 0.0, 0.4], [0.0, far, 0.0, 0.6], [0.0, 0.0, -far, 0.1]])
        assert reachable_obstacles(spheres, arm, obstacles, 0.0).tolist() == [False, True, False]
        assert reachable_obstacles(spheres, arm, obstacles, 0.2).tolist() == [True, True, False]
        evaluator = ArmEvaluator(arm, spheres, obstacles, 0.0, 10)
        assert evaluator.obstacles.tolist() == [obstacles[1].tolist()]
        assert evaluator.n_pairs == len(spheres)


def test_obstacles_beyond_the_workspace_extent_are_refused():
    check_obstacles([[9e4, 0, 0, 1e4]])
    for row in ([1e5 + 1, 0, 0, 0.1], [0, 0, 1e200, 2e200], [0, 0, 0, 2e5]):
        with pytest.raises(ArmError, match='reaches beyond 100000 m'):
            check_obstacles([row])
