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
Hand inverse kinematics of model files (issue 13): the inverse_kinematics section and Newton.

The forward kinematics the answers are checked with is recomputed here with numpy from the
link lengths, independent of the generated code.
"""

import math
import os
import re

from geometry_msgs.msg import PoseStamped
import numpy as np
import pytest

from toc_ros import conversions
from toc_ros.core.models import load_model, ModelError

pytest.importorskip('sympy')

from toc_ros.core.models import symbolic  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PLANAR_FILE = os.path.join(ROOT, 'config', 'models', 'planar_2r.yaml')
CYLINDRICAL_FILE = os.path.join(ROOT, 'config', 'models', 'cylindrical_eq37.yaml')
BRANCHES = (('elbow_up', -1.0), ('elbow_down', 1.0))

# A planar 2R arm with trivial dynamics (no mass matrix: nothing is compiled at load) and a
# correct IK section; the bad sections below are edits of it.
SIMPLE_2R = """
name: simple_2r
joints: [{name: j1, kind: revolute}, {name: j2, kind: revolute}]
parameters: {l1: 1.0, l2: 0.5}
positive: [l1, l2]
u_max: [1, 1]
definitions:
  ex: l1*cos(q1)
  ey: l1*sin(q1)
links: [[0, 0, ex, ey], [ex, ey, ex + l2*cos(q1 + q2), ey + l2*sin(q1 + q2)]]
dynamics: [dq1, u1, dq2, u2]
inverse_kinematics:
  definitions:
    c2: (x^2 + y^2 - l1^2 - l2^2)/(2*l1*l2)
  reach: [x^2 + y^2 <= (l1 + l2)^2]
  branches:
    up:
      q1: atan2(y, x) + atan2(l2*sqrt(1 - c2^2), l1 + l2*c2)
      q2: -acos(c2)
"""
GOOD_Q1 = 'q1: atan2(y, x) + atan2(l2*sqrt(1 - c2^2), l1 + l2*c2)'


def planar_fk(q, l1, l2):
    """Hand of a planar 2R arm (numpy, from the link lengths)."""
    q = np.asarray(q, dtype=float)
    return np.array([l1 * np.cos(q[0]) + l2 * np.cos(q[0] + q[1]),
                     l1 * np.sin(q[0]) + l2 * np.sin(q[0] + q[1])])


def annulus_points(l1, l2, count, seed):
    rng = np.random.default_rng(seed)
    r = rng.uniform(abs(l1 - l2) + 1e-6, l1 + l2 - 1e-6, count)
    phi = rng.uniform(-math.pi, math.pi, count)
    return np.column_stack([r * np.cos(phi), r * np.sin(phi)])


def from_text(text, tmp_path):
    return symbolic.model_from_text(text, '<test>', str(tmp_path))


# -- the inverse_kinematics section ------------------------------------------------------------

@pytest.mark.parametrize('params', [{}, {'l1': 0.7, 'l2': 1.1}])
@pytest.mark.parametrize('branch,sign', BRANCHES)
def test_file_ik_round_trip(branch, sign, params):
    model = load_model(PLANAR_FILE, **params)
    values = model.params.as_dict()
    assert model.ik_branches == ('elbow_up', 'elbow_down')
    for goal in annulus_points(values['l1'], values['l2'], 200, 3):
        q = model.inverse_kinematics(goal[0], goal[1], branch)
        assert sign * q[1] >= 0.0 and -math.pi <= q[0] <= math.pi
        np.testing.assert_allclose(planar_fk(q, values['l1'], values['l2']), goal, atol=1e-12)


@pytest.mark.parametrize('params', [{}, {'l1': 0.7, 'l2': 1.1}])
@pytest.mark.parametrize('branch', [b for b, _ in BRANCHES])
def test_file_ik_agrees_with_the_builtin(branch, params):
    model = load_model(PLANAR_FILE, **params)
    builtin = load_model('planar_2r', **params)
    l1, l2 = builtin.params.l1, builtin.params.l2
    goals = list(annulus_points(l1, l2, 300, 4))
    # The boundary of the workspace: fully stretched and fully folded, both are reachable.
    goals += [(l1 + l2, 0.0), (0.0, -(l1 + l2)), (abs(l1 - l2), 0.0), (-0.5, 1e-300)]
    for x, y in goals:
        np.testing.assert_allclose(model.inverse_kinematics(x, y, branch),
                                   builtin.inverse_kinematics(x, y, branch), rtol=0, atol=1e-12)


@pytest.mark.parametrize('goal,branch,message', [
    ((1.0, 0.5), None, 'ambiguous: choose the IK branch'),
    ((1.0, 0.5), 'elbow_left', 'ambiguous'),
    ((1.5, 1.5), 'elbow_up', "out of reach: reach condition 'x^2 + y^2 <= (l1 + l2)^2' fails"),
    ((0.1, 0.05), 'elbow_down', "reach condition 'x^2 + y^2 >= (l1 - l2)^2' fails"),
    ((float('nan'), 0.0), 'elbow_up', 'not finite'),
])
def test_file_ik_refusals(goal, branch, message):
    with pytest.raises(ModelError, match=re.escape(message)):
        load_model(PLANAR_FILE).inverse_kinematics(goal[0], goal[1], branch)


def test_without_reach_conditions_the_domain_error_and_the_round_trip_refuse(tmp_path):
    no_reach = SIMPLE_2R.replace('  reach: [x^2 + y^2 <= (l1 + l2)^2]\n', '')
    model = from_text(no_reach, tmp_path)
    np.testing.assert_allclose(planar_fk(model.inverse_kinematics(1.2, 0.3), 1.0, 0.5),
                               [1.2, 0.3], atol=1e-12)
    with pytest.raises(ModelError, match=r"out of reach: branch 'up' has no value there "
                                         r'\(math domain error\)'):
        model.inverse_kinematics(2.0, 0.0)
    # A clamp without reach conditions answers off the goal: the round trip refuses it.
    clamped = no_reach.replace('acos(c2)', 'acos(min(1, c2))').replace(
        'sqrt(1 - c2^2)', 'sqrt(max(0, 1 - c2^2))')
    model = from_text(clamped, tmp_path)
    with pytest.raises(ModelError, match=r'whose hand is 0\.5 m from the goal'):
        model.inverse_kinematics(2.0, 0.0)


def test_one_branch_ignores_the_branch_setting(tmp_path):
    model = from_text(SIMPLE_2R, tmp_path)
    for branch in (None, 'elbow_up', 'up'):
        q = model.inverse_kinematics(0.6, 0.9, branch)
        assert q[1] <= 0.0
        np.testing.assert_allclose(planar_fk(q, 1.0, 0.5), [0.6, 0.9], atol=1e-12)


BAD_SECTIONS = {
    'missing joint': ('    q2: -acos(c2)\n', '', 'expected one expression per joint, q1, q2'),
    'extra joint': ('      q2: -acos(c2)\n', '      q2: -acos(c2)\n      q3: 0\n',
                    "expected one expression per joint, q1, q2; got ['q1', 'q2', 'q3']"),
    'unknown symbol': ('-acos(c2)', '-acos(c2) + z', "unknown symbol(s) z in '-acos(c2) + z'"),
    'joint symbol': ('-acos(c2)', '-acos(c2) + q1', 'may not depend on q1'),
    'model definition': ('-acos(c2)', '-acos(c2) + ex', 'may not depend on q1'),
    'does not parse': ('-acos(c2)', '-acos(c2', 'inverse_kinematics.branches.up.q2: cannot '
                                                'parse'),
    'unknown function': ('-acos(c2)', '-arccos(c2)', 'unknown function(s) arccos'),
    'reach without comparison': ('[x^2 + y^2 <= (l1 + l2)^2]', '[x^2 + y^2]',
                                 'inverse_kinematics.reach[0]: expected one comparison'),
    'reach of the joints': ('[x^2 + y^2 <= (l1 + l2)^2]', '[q1 <= 1]', 'may not depend on q1'),
    'no branches': ('  branches:\n    up:\n', '  other:\n    up:\n',
                    'inverse_kinematics: expected {definitions'),
    'bad branch': ('    up:\n', '    up: [1, 2]\n    down:\n',
                   'inverse_kinematics.branches.up: expected one expression per joint'),
    'definition shadows a parameter': ('    c2: ', '    l1: 1\n    c2: ',
                                       'inverse_kinematics.definitions.l1: a definition name'),
    'x is a parameter': ('{l1: 1.0, l2: 0.5}', '{l1: 1.0, l2: 0.5, x: 2.0}',
                         'x name the hand goal here: rename the parameter or definition x'),
    'not an inverse': ('-acos(c2)', 'acos(c2)', 'inverse_kinematics.branches.up: not an '
                                                'inverse of the links'),
    'never answers': ('-acos(c2)', '-acos(c2 + 3)', 'inverse_kinematics.branches.up: no answer '
                                                    'at any of 8 hand points'),
}


@pytest.mark.parametrize('case', sorted(BAD_SECTIONS))
def test_bad_ik_sections_are_refused_with_the_reason(case, tmp_path):
    old, new, reason = BAD_SECTIONS[case]
    assert old in SIMPLE_2R
    with pytest.raises(ModelError) as info:
        from_text(SIMPLE_2R.replace(old, new, 1), tmp_path)
    assert str(info.value).startswith('model file <test>: ') and reason in str(info.value), \
        str(info.value)


def test_the_correct_section_loads(tmp_path):
    assert GOOD_Q1 in SIMPLE_2R
    assert from_text(SIMPLE_2R, tmp_path).ik_branches == ('up',)


def test_strict_reach_condition_refuses_the_boundary(tmp_path):
    text = SIMPLE_2R.replace('[x^2 + y^2 <= (l1 + l2)^2]',
                             '[x^2 + y^2 <= (l1 + l2)^2, x^2 + y^2 > (l1 - l2)^2]')
    model = from_text(text, tmp_path)
    model.inverse_kinematics(0.5 + 1e-9, 0.0)
    with pytest.raises(ModelError, match='fails'):
        model.inverse_kinematics(0.5, 0.0)


# -- numeric IK (no inverse_kinematics section) ------------------------------------------------

def test_numeric_ik_of_the_cylindrical_file_agrees_with_the_builtin():
    model = load_model(CYLINDRICAL_FILE)
    builtin = load_model('cylindrical')
    assert model.ik_branches == ()
    a = model.params.as_dict()['a']
    rng = np.random.default_rng(5)
    for _ in range(50):
        r, phi = rng.uniform(0.6, 3.0), rng.uniform(-3.0, 3.0)
        x, y = r * math.cos(phi), r * math.sin(phi)
        seed = np.array([phi + rng.uniform(-0.5, 0.5), rng.uniform(-0.4, 1.0)])
        q = model.inverse_kinematics(x, y, 'elbow_up', seed=seed)
        hand = (a + q[1]) * np.array([math.cos(q[0]), math.sin(q[0])])
        np.testing.assert_allclose(hand, [x, y], rtol=0, atol=1e-12 * max(1.0, r))
        np.testing.assert_allclose(q, builtin.inverse_kinematics(x, y), rtol=0, atol=1e-12)


def planar_without_ik():
    # Generated into the user's model cache (keyed by the text's hash), as load_model does: a
    # fresh directory would derive the Lagrangian and compile its kernels on every run.
    text = open(PLANAR_FILE).read()
    text = text[:text.index('inverse_kinematics:')]
    return symbolic.model_from_text(text, '<test>')


@pytest.mark.parametrize('branch,sign', BRANCHES)
def test_numeric_ik_finds_the_solution_near_the_seed(branch, sign):
    model = planar_without_ik()
    builtin = load_model('planar_2r')
    assert model.ik_branches == ()
    for x, y in annulus_points(1.0, 0.8, 40, 6):
        expected = builtin.inverse_kinematics(x, y, branch)
        seed = expected + np.array([0.3, -0.2 * sign])
        q = model.inverse_kinematics(x, y, seed=seed)
        np.testing.assert_allclose(planar_fk(q, 1.0, 0.8), [x, y], rtol=0, atol=1e-12)
        np.testing.assert_allclose(q, expected, rtol=0, atol=1e-9)
    # Revolute joints come back within pi of the seed, not wrapped into (-pi, pi].
    q = model.inverse_kinematics(1.0, 0.5, seed=builtin.inverse_kinematics(1.0, 0.5, branch)
                                 + 2.0 * math.pi)
    assert q[0] > math.pi
    np.testing.assert_allclose(planar_fk(q, 1.0, 0.8), [1.0, 0.5], rtol=0, atol=1e-12)


@pytest.mark.parametrize('goal,seed,message', [
    ((2.5, 0.0), None, r'out of reach or not found by numeric IK from q = \[0. 0.\]: the '
                       r'nearest hand position found is 0.7 m from it'),
    ((1.8, 0.0), None, 'at a singular pose'),
    ((1.0, 0.5), [1.0, 2.0, 3.0], 'the IK seed must be 2 finite joint positions'),
])
def test_numeric_ik_refusals(goal, seed, message):
    with pytest.raises(ModelError, match=message):
        planar_without_ik().inverse_kinematics(goal[0], goal[1], seed=seed)


def test_numeric_ik_refuses_a_redundant_arm(tmp_path):
    text = """
name: planar_3r_kinematic
joints: [{name: j1}, {name: j2}, {name: j3}]
parameters: {}
u_max: [1, 1, 1]
links: [[0, 0, cos(q1) + cos(q1 + q2) + cos(q1 + q2 + q3),
         sin(q1) + sin(q1 + q2) + sin(q1 + q2 + q3)]]
dynamics: [dq1, u1, dq2, u2, dq3, u3]
"""
    with pytest.raises(ModelError, match=r'ambiguous: a redundant arm \(3 joints'):
        from_text(text, tmp_path).inverse_kinematics(1.0, 1.0)


# -- goal_pose conversion ----------------------------------------------------------------------

def pose(x, y, frame='base_link'):
    msg = PoseStamped()
    msg.header.frame_id = frame
    msg.pose.position.x, msg.pose.position.y = x, y
    return msg


def test_goal_pose_of_a_model_file():
    model = load_model(PLANAR_FILE)
    goal = conversions.pose_to_joint_goal(pose(1.0, 0.5), 'base_link', model,
                                          branch='elbow_down')
    assert goal[2] >= 0.0 and goal[1] == goal[3] == 0.0
    np.testing.assert_allclose(planar_fk(goal[0::2], 1.0, 0.8), [1.0, 0.5], atol=1e-12)
    with pytest.raises(conversions.ConversionError, match='out of reach'):
        conversions.pose_to_joint_goal(pose(3.0, 0.0), 'base_link', model, branch='elbow_up')
    with pytest.raises(conversions.ConversionError, match='ambiguous'):
        conversions.pose_to_joint_goal(pose(1.0, 0.5), 'base_link', model, branch='other')


def test_goal_pose_numeric_ik_uses_the_seed():
    model = load_model(CYLINDRICAL_FILE)
    goal = conversions.pose_to_joint_goal(pose(0.0, 2.0), 'base_link', model,
                                          seed=[1.5, 0.5])
    np.testing.assert_allclose(goal, [math.pi / 2, 0.0, 0.9, 0.0], atol=1e-12)
