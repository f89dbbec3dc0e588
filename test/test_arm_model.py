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
URDF arms: loading, joint subsets and locked joints, limits and their refusals, dynamics.

The reduced model's dynamics are checked against the full (unreduced) URDF model with the
locked joints still and at their values; the derivatives against central differences of ABA;
frame poses against an independent numpy forward kinematics of the URDF (urdf_oracle.py).
"""

import hashlib
import json

import numpy as np
import pytest

pin = pytest.importorskip('pinocchio')

from toc_ros.core.arms import ArmError, load_arm  # noqa: E402
from toc_ros.core.arms.model import named_arm_path  # noqa: E402
from urdf_oracle import UrdfOracle  # noqa: E402

PANDA_JOINTS = tuple(f'panda_joint{i}' for i in range(1, 8))
UR5_JOINTS = ('shoulder_pan_joint', 'shoulder_lift_joint', 'elbow_joint', 'wrist_1_joint',
              'wrist_2_joint', 'wrist_3_joint')

# A small arm with a continuous, a revolute and a prismatic joint and a fixed tool; the
# placeholders make the invalid variants below.
TOY = """<?xml version="1.0"?>
<robot name="toy">
  <link name="base"/>
  <link name="a"><inertial><mass value="2"/><origin xyz="0 0 0.2"/>
    <inertia ixx="0.02" iyy="0.02" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="b"><inertial><mass value="1"/><origin xyz="0.15 0 0"/>
    <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="c"><inertial><mass value="0.5"/><origin xyz="0 0 0"/>
    <inertia ixx="0.001" iyy="0.001" izz="0.001" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="tool"/>
  <joint name="spin" type="{spin_type}"><parent link="base"/><child link="a"/>
    <origin xyz="0 0 0.1"/><axis xyz="0 0 1"/>{spin_limit}</joint>
  <joint name="elbow" type="revolute"><parent link="a"/><child link="b"/>
    <origin xyz="0 0 0.4" rpy="0.3 0 0"/><axis xyz="0 1 0"/>
    <limit effort="{elbow_effort}" velocity="2" lower="-2" upper="2"/></joint>
  <joint name="slide" type="prismatic"><parent link="b"/><child link="c"/>
    <origin xyz="0.3 0 0"/><axis xyz="1 0 0"/>
    <limit effort="50" velocity="0.5" lower="0" upper="0.2"/></joint>
  <joint name="tool_joint" type="fixed"><parent link="c"/><child link="tool"/>
    <origin xyz="0.05 0 0" rpy="0 0 0.5"/></joint>
</robot>
"""


def toy(spin_type='continuous', spin_limit='<limit effort="10" velocity="3"/>',
        elbow_effort='20'):
    return TOY.format(spin_type=spin_type, spin_limit=spin_limit, elbow_effort=elbow_effort)


def random_states(arm, count, seed):
    rng = np.random.default_rng(seed)
    low = np.where(arm.continuous, -np.pi, arm.lower)
    high = np.where(arm.continuous, np.pi, arm.upper)
    for _ in range(count):
        yield (rng.uniform(low, high), rng.uniform(-arm.velocity, arm.velocity),
               rng.uniform(-arm.effort, arm.effort))


def test_panda_and_ur5_load_with_their_urdf_limits():
    panda = load_arm('panda')
    assert panda.joint_names == PANDA_JOINTS
    assert panda.n == panda.nq == panda.nv == 7
    assert panda.effort.tolist() == [87.0] * 4 + [12.0] * 3
    assert panda.velocity.tolist() == [2.175] * 4 + [2.61] * 3
    assert panda.lower[3] == -3.0718 and panda.upper[3] == -0.0698
    assert panda.lower[5] == -0.0175 and panda.upper[5] == 3.7525
    assert panda.locked == {'panda_finger_joint1': 0.0, 'panda_finger_joint2': 0.0}
    assert not panda.continuous.any()
    np.testing.assert_array_equal(panda.gravity, [0.0, 0.0, -9.81])
    with open(named_arm_path('panda')) as stream:
        assert panda.source == {'model': 'panda', 'path': named_arm_path('panda'),
                                'sha256': hashlib.sha256(stream.read().encode()).hexdigest()}
    ur5 = load_arm('ur5')
    assert ur5.joint_names == UR5_JOINTS and ur5.n == 6
    assert ur5.effort.tolist() == [150.0] * 3 + [28.0] * 3
    assert ur5.velocity.tolist() == [3.15] * 3 + [3.2] * 3
    assert ur5.locked == {}


def test_path_and_string_sources_give_the_same_model():
    path = named_arm_path('ur5')
    by_name, by_path = load_arm('ur5'), load_arm('urdf:' + path)
    with open(path) as stream:
        text = stream.read()
    by_string = load_arm(text)
    assert by_path.source['path'] == path and 'model' not in by_path.source
    assert by_string.source == {'string': True,
                                'sha256': hashlib.sha256(text.encode()).hexdigest()}
    assert by_path.joint_names == by_string.joint_names == UR5_JOINTS
    for q, v, tau in random_states(by_name, 3, seed=1):
        expected = by_name.forward_dynamics(q, v, tau)
        np.testing.assert_array_equal(by_path.forward_dynamics(q, v, tau), expected)
        np.testing.assert_array_equal(by_string.forward_dynamics(q, v, tau), expected)


def test_continuous_and_prismatic_joints():
    arm = load_arm(toy())
    assert arm.joint_names == ('spin', 'elbow', 'slide')
    assert arm.nq == arm.nv == 3     # the continuous joint is an angle, not (cos, sin)
    assert arm.continuous.tolist() == [True, False, False]
    assert arm.lower.tolist() == [-np.inf, -2.0, 0.0]
    assert arm.upper.tolist() == [np.inf, 2.0, 0.2]
    assert arm.effort.tolist() == [10.0, 20.0, 50.0]
    # Frame poses against the independent numpy forward kinematics, angles beyond pi too.
    oracle = UrdfOracle(arm.urdf)
    for q in ([4.0, 0.7, 0.1], [-7.5, -1.9, 0.2], [0.0, 0.0, 0.0]):
        pose = arm.frame_pose(np.array(q), 'tool')
        expected = oracle.link_poses(dict(zip(arm.joint_names, q)))['tool']
        np.testing.assert_allclose(pose.homogeneous, expected, atol=1e-12)
    # An angle and the same angle + 2 pi give the same pose (it is a revolute angle).
    np.testing.assert_allclose(arm.frame_position(np.array([0.4, 0.3, 0.1]), 'tool'),
                               arm.frame_position(np.array([0.4 + 2 * np.pi, 0.3, 0.1]),
                                                  'tool'), atol=1e-12)
    bounded = load_arm(toy(), limits={'spin': {'lower': -1.0, 'upper': 1.5}})
    assert bounded.continuous.tolist() == [False, False, False]
    assert bounded.lower[0] == -1.0 and bounded.upper[0] == 1.5


def test_reduced_dynamics_equal_the_full_model_with_locked_joints_still():
    locked = {'panda_joint3': 0.4, 'panda_joint5': -1.1, 'panda_finger_joint1': 0.02,
              'panda_finger_joint2': 0.03}
    planned = ('panda_joint1', 'panda_joint2', 'panda_joint4', 'panda_joint6', 'panda_joint7')
    arm = load_arm('panda', joints=planned, locked=locked)
    assert arm.joint_names == planned and arm.n == 5
    assert arm.locked == locked
    full = arm.full_model
    full_data = full.createData()
    planned_idx = [full.idx_vs[full.getJointId(name)] for name in planned]
    oracle = UrdfOracle(arm.urdf)
    for q, v, tau in random_states(arm, 5, seed=2):
        ddq = arm.forward_dynamics(q, v, tau)
        # The full model at the locked values, locked joints at rest and not accelerating,
        # needs exactly tau at the planned joints (the locked ones take what holds them).
        q_full = arm.full_configuration(q)
        v_full, a_full = np.zeros(full.nv), np.zeros(full.nv)
        v_full[planned_idx], a_full[planned_idx] = v, ddq
        tau_full = pin.rnea(full, full_data, q_full, v_full, a_full)
        np.testing.assert_allclose(tau_full[planned_idx], tau, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(arm.inverse_dynamics(q, v, ddq), tau, rtol=1e-9, atol=1e-9)
        values = dict(locked)
        values.update(zip(planned, q))
        poses = oracle.link_poses(values)
        for link in ('panda_link4', 'panda_hand_tcp', 'panda_leftfinger'):
            np.testing.assert_allclose(arm.frame_pose(q, link).homogeneous, poses[link],
                                       atol=1e-12)


def test_a_locked_mimic_joint_follows_its_joint():
    # panda_finger_joint2 <mimic joint="panda_finger_joint1"/>: given finger 1 only, finger 2
    # follows (it stayed at 0 before); a mimic of a planned joint is refused.
    arm = load_arm('panda', locked={'panda_finger_joint1': 0.03})
    assert arm.locked == {'panda_finger_joint1': 0.03, 'panda_finger_joint2': 0.03}
    values = dict(arm.locked, **dict(zip(arm.joint_names, np.zeros(7))))
    poses = UrdfOracle(arm.urdf).link_poses(values)
    for link in ('panda_leftfinger', 'panda_rightfinger'):
        np.testing.assert_allclose(arm.frame_pose(np.zeros(7), link).homogeneous, poses[link],
                                   atol=1e-12)
    with pytest.raises(ArmError, match='mimics the planned joint'):
        load_arm('panda', joints=PANDA_JOINTS + ('panda_finger_joint1',))


def test_default_lock_is_zero_clamped_into_the_limits():
    arm = load_arm('panda', joints=PANDA_JOINTS[:3] + PANDA_JOINTS[4:])
    # panda_joint4 lies in [-3.0718, -0.0698]: 0 clamps to its upper limit.
    assert arm.locked['panda_joint4'] == -0.0698
    assert arm.locked['panda_finger_joint1'] == 0.0


@pytest.mark.parametrize('name', ['panda', 'ur5'])
def test_dynamics_derivatives_match_central_differences(name):
    arm = load_arm(name)
    eps = 1e-6
    for q, v, tau in random_states(arm, 3, seed=3):
        ddq_dq, ddq_dv, ddq_dtau = arm.dynamics_derivatives(q, v, tau)
        for wrt, analytic in ((0, ddq_dq), (1, ddq_dv), (2, ddq_dtau)):
            numeric = np.zeros((arm.n, arm.n))
            for k in range(arm.n):
                plus, minus = [q.copy(), v.copy(), tau.copy()], [q.copy(), v.copy(), tau.copy()]
                plus[wrt][k] += eps
                minus[wrt][k] -= eps
                numeric[:, k] = (pin.aba(arm.model, arm.model.createData(), *plus)
                                 - pin.aba(arm.model, arm.model.createData(), *minus)) / (2 * eps)
            scale = max(1.0, np.abs(numeric).max())
            assert np.abs(analytic - numeric).max() < 1e-6 * scale, (name, wrt)
        ddq, *together = arm.dynamics_and_derivatives(q, v, tau)
        np.testing.assert_allclose(ddq, arm.forward_dynamics(q, v, tau), rtol=1e-12,
                                   atol=1e-10)
        for one, other in zip(together, (ddq_dq, ddq_dv, ddq_dtau)):
            np.testing.assert_array_equal(one, other)
        # M^-1 is the inverse of the mass matrix (not just its upper triangle).
        mass = pin.crba(arm.model, arm.model.createData(), q)
        mass = np.triu(mass) + np.triu(mass, 1).T
        np.testing.assert_allclose(ddq_dtau @ mass, np.eye(arm.n), atol=1e-9)


def test_limit_overrides():
    arm = load_arm('panda', limits={'panda_joint1': {'effort': 50, 'velocity': 1.0},
                                    'panda_joint2': {'lower': -1.0, 'upper': 1.2}})
    assert arm.effort[0] == 50.0 and arm.velocity[0] == 1.0
    assert arm.lower[1] == -1.0 and arm.upper[1] == 1.2
    assert arm.effort[1] == 87.0
    assert arm.model.effortLimit[0] == 50.0     # the Pinocchio model agrees
    # A joint without an effort limit is accepted once one is given.
    fixed = load_arm(toy(elbow_effort='0'), limits={'elbow': {'effort': 15}})
    assert fixed.effort[1] == 15.0


@pytest.mark.parametrize('source, kwargs, reason', [
    ('kuka', {}, "unknown arm 'kuka'"),
    ('urdf:/nonexistent/arm.urdf', {}, 'cannot read URDF'),
    ('<robot name="x"><link name="a"></robot>', {}, 'does not parse as XML'),
    ('<sdf version="1.6"/>', {}, 'root element is <sdf>'),
    (42, {}, 'arm source must be'),
    ('panda', {'joints': ['panda_joint1', 'panda_jointX']}, "unknown joint 'panda_jointX'"),
    ('panda', {'joints': ['panda_joint2', 'panda_joint1']}, 'kinematic order'),
    ('panda', {'joints': ['panda_joint1', 'panda_joint1']}, 'twice'),
    ('panda', {'joints': []}, 'joints is empty'),
    ('panda', {'joints': ['panda_joint8']}, 'is fixed'),
    ('panda', {'joints': PANDA_JOINTS + ('panda_finger_joint2',)}, 'mimics'),
    ('panda', {'locked': {'panda_finger_joint1': 0.5}}, 'outside its limits'),
    ('panda', {'locked': {'panda_finger_joint1': float('nan')}}, 'is NaN'),
    ('panda', {'locked': {'panda_joint1': 0.1}}, 'both planned and locked'),
    ('panda', {'locked': {'nope': 0.1}}, "unknown or fixed joint 'nope'"),
    ('panda', {'limits': {'nope': {'effort': 1}}}, "unknown joint 'nope'"),
    ('panda', {'limits': {'panda_joint1': {'torque': 1}}}, 'unknown key(s) torque'),
    ('panda', {'limits': {'panda_joint1': {'effort': -1}}}, 'effort must be positive'),
    ('panda', {'limits': {'panda_joint1': {'velocity': float('nan')}}}, 'is NaN'),
    ('panda', {'limits': {'panda_joint1': {'effort': float('inf')}}}, 'must be finite'),
    ('panda', {'limits': {'panda_joint1': {'lower': 1.0, 'upper': 0.5}}}, 'not below'),
    ('panda', {'limits': {'panda_finger_joint1': {'lower': 5.0}}}, 'is above the upper'),
    (toy(elbow_effort='0'), {}, "joint 'elbow' has no effort limit"),
    (toy(spin_limit='<limit effort="10"/>'), {}, "joint 'spin' has no velocity limit"),
    (toy(spin_type='revolute', spin_limit='<limit effort="1" velocity="1"/>'), {},
     "joint 'spin' has no lower/upper"),
    (toy(spin_type='floating', spin_limit=''), {}, "of type 'floating'"),
    ('panda', {'limits': {'panda_joint1': {'effort': 1e308}}}, 'outside [1e-06, 1e+06]'),
    ('panda', {'limits': {'panda_joint1': {'velocity': 1e-300}}}, 'outside [1e-06, 10000]'),
    (toy().replace('<mass value="1"/>', '<mass value="nan"/>'), {}, "link 'b' <mass> is NaN"),
    (toy().replace('<mass value="1"/>', '<mass value="-1"/>'), {}, 'finite and >= 0'),
    (toy().replace('ixx="0.01" iyy', 'ixx="inf" iyy', 1), {}, '<inertia ixx> must be finite'),
    (toy().replace('<axis xyz="0 1 0"/>', '<axis xyz="0 0 0"/>'), {}, 'is zero'),
    (toy().replace('<origin xyz="0.3 0 0"/>', '<origin xyz="0.3 0 1e300"/>'), {},
     'beyond 1000 m'),
    (toy().replace('<origin xyz="0.3 0 0"/>', '<origin xyz="0.3 0"/>'), {}, 'three numbers'),
    (toy().replace('velocity="0.5"', 'velocity="inf"'), {}, '<limit velocity> must be finite'),
    (toy().replace('<child link="tool"/>', '<child link="b"/>'), {}, 'child of two joints'),
])
def test_bad_input_is_refused_with_its_reason(source, kwargs, reason):
    with pytest.raises(ArmError) as error:
        load_arm(source, **kwargs)
    assert reason in str(error.value)


def test_a_singular_mass_matrix_is_refused_with_the_joints_that_move_no_mass():
    from toc_ros.core.arms.validate import check_mass_matrix, check_state
    massless = load_arm(toy().replace('<mass value="0.5"/>', '<mass value="0"/>').replace(
        'ixx="0.001" iyy="0.001" izz="0.001"', 'ixx="0" iyy="0" izz="0"'))
    q = np.zeros(massless.n)
    with pytest.raises(ArmError, match=r'singular there \(slide moves no mass'):
        check_state(massless, q)
    check_mass_matrix(load_arm(toy()), q)           # the toy itself is fine
    check_mass_matrix(load_arm('panda'), [0, -0.785, 0, -2.356, 0, 1.571, 0.785])


def test_unknown_link_is_refused():
    arm = load_arm('ur5')
    with pytest.raises(ArmError, match="unknown link 'hand'"):
        arm.frame_position(np.zeros(6), 'hand')


def test_a_missing_limit_is_given_on_the_command_line(tmp_path):
    """toc-solve --limit JOINT.KEY=VALUE: the override the refusal names, as load_arm's."""
    from toc_ros.solve import main
    urdf = tmp_path / 'toy.urdf'
    urdf.write_text(toy(elbow_effort='0'))
    args = ['--model', f'urdf:{urdf}', '--start', '0', '0', '0.05', '--goal', '1', '0.5',
            '0.1', '--N', '20', '--quiet']
    refused = tmp_path / 'refused.json'
    assert main(args + ['--json', str(refused)]) == 4
    assert '--limit elbow.effort=VALUE' in json.loads(refused.read_text())['message']
    given = tmp_path / 'given.json'
    assert main(args + ['--limit', 'elbow.effort=20', '--json', str(given)]) == 0
    # The same solve as the original URDF's (elbow effort 20).
    original = tmp_path / 'original.urdf'
    original.write_text(toy())
    same = tmp_path / 'same.json'
    assert main(['--model', f'urdf:{original}'] + args[2:] + ['--json', str(same)]) == 0
    assert json.loads(given.read_text())['final_time'] == json.loads(
        same.read_text())['final_time']
    bad = tmp_path / 'bad.json'
    assert main(args + ['--limit', 'elbow.torque=20', '--json', str(bad)]) == 4
    assert "--limit entry 'elbow.torque'" in json.loads(bad.read_text())['message']


def test_a_joint_named_like_a_link_is_locked():
    # Pinocchio's buildReducedModel looks the locked joint up among all frames by name; a link
    # of the same name makes that ambiguous (example-robot-data's so100 'gripper').
    clash = toy().replace('link name="c"', 'link name="slide"').replace(
        '<child link="c"/>', '<child link="slide"/>').replace(
        '<parent link="c"/>', '<parent link="slide"/>')
    arm = load_arm(clash, joints=['spin', 'elbow'], locked={'slide': 0.15})
    same = load_arm(toy(), joints=['spin', 'elbow'], locked={'slide': 0.15})
    assert arm.n == 2 and arm.locked == {'slide': 0.15}
    for q, dq, tau in random_states(same, 5, seed=3):
        assert np.array_equal(arm.forward_dynamics(q, dq, tau), same.forward_dynamics(q, dq, tau))
        assert np.array_equal(arm.frame_position(q, 'slide'), same.frame_position(q, 'c'))
        assert np.array_equal(arm.frame_position(q, 'tool'), same.frame_position(q, 'tool'))
    assert [f.name for f in arm.full_model.frames] == [
        f.name for f in load_arm(clash).full_model.frames]


def test_the_settings_limit_keys_are_the_models():
    from toc_ros import arm_config
    from toc_ros.core.arms import urdf
    assert arm_config.LIMIT_KEYS == urdf.LIMIT_KEYS
