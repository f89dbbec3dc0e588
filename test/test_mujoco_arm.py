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

"""MujocoArm against Pinocchio (an independent implementation of the same URDF's dynamics)."""

import os
import sys

import numpy as np
import pytest

pin = pytest.importorskip('pinocchio')
pytest.importorskip('mujoco')

from toc_ros.plant.mujoco_arm import ArmModelError, dynamics_urdf, MujocoArm  # noqa: E402

GRAVITY = 9.81
PANDA_ARM = [f'panda_joint{i}' for i in range(1, 8)]
UR5_JOINTS = ['shoulder_pan_joint', 'shoulder_lift_joint', 'elbow_joint', 'wrist_1_joint',
              'wrist_2_joint', 'wrist_3_joint']


def _robots_dir():
    """example-robot-data's robots folder under any site-packages (cmeel.prefix)."""
    for entry in sys.path + [sys.prefix]:
        for base in (entry, os.path.join(entry, 'lib', 'python3.11', 'site-packages')):
            path = os.path.join(base, 'cmeel.prefix', 'share', 'example-robot-data', 'robots')
            if os.path.isdir(path):
                return path
    return None


ROBOTS = _robots_dir()
pytestmark = pytest.mark.skipif(ROBOTS is None, reason='example-robot-data is not installed')
ARMS = {
    'panda': ('panda_description/urdf/panda.urdf', PANDA_ARM, 'panda_hand'),
    'ur5': ('ur_description/urdf/ur5_robot.urdf', UR5_JOINTS, 'tool0'),
}


def _urdf(arm):
    with open(os.path.join(ROBOTS, ARMS[arm][0])) as f:
        return f.read()


def _reduced_pinocchio(urdf, joint_names):
    """Pinocchio model of the URDF with every other joint locked at 0 (as MujocoArm does)."""
    full = pin.buildModelFromXML(dynamics_urdf(urdf))
    locked = [full.getJointId(name) for name in full.names[1:] if name not in joint_names]
    model = pin.buildReducedModel(full, locked, pin.neutral(full))
    assert list(model.names[1:]) == list(joint_names)
    return model


def _random_states(model, rng, count):
    """Positions within the limits, velocities and torques within theirs."""
    for _ in range(count):
        q = rng.uniform(model.lowerPositionLimit, model.upperPositionLimit)
        v = rng.uniform(-model.velocityLimit, model.velocityLimit)
        tau = rng.uniform(-model.effortLimit, model.effortLimit)
        yield q, v, tau


@pytest.mark.parametrize('arm', sorted(ARMS))
def test_forward_dynamics_equal_pinocchio_aba(arm):
    urdf = _urdf(arm)
    _, joints, tip = ARMS[arm]
    plant = MujocoArm(urdf, joints, tip_link=tip)
    model = _reduced_pinocchio(urdf, joints)
    data = model.createData()
    np.testing.assert_array_equal(plant.effort_limits, model.effortLimit)
    worst = 0.0
    for q, v, tau in _random_states(model, np.random.default_rng(1), 300):
        plant.set_state(q, v)
        expected = pin.aba(model, data, q, v, tau)
        error = np.max(np.abs(plant.acceleration(tau) - expected)) / max(
            1.0, np.max(np.abs(expected)))
        worst = max(worst, error)
    assert worst < 1e-9, f'{arm}: max relative |qacc - aba| = {worst:.3g}'


def test_torques_are_clamped_to_the_effort_limits():
    urdf = _urdf('panda')
    plant = MujocoArm(urdf, PANDA_ARM)
    model = _reduced_pinocchio(urdf, PANDA_ARM)
    q = 0.5 * (model.lowerPositionLimit + model.upperPositionLimit)
    v = np.zeros(7)
    tau = 3.0 * np.array([87, -87, 87, -87, 12, -12, 12.0])
    plant.set_state(q, v)
    clamped = np.clip(tau, -model.effortLimit, model.effortLimit)
    np.testing.assert_allclose(plant.acceleration(tau),
                               pin.aba(model, model.createData(), q, v, clamped),
                               rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(plant.step(tau), clamped)


def _with_point_mass(model, frame, mass):
    """Copy of the Pinocchio model with a point mass at the frame's origin (no rotation)."""
    model = model.copy()
    placement = model.frames[model.getFrameId(frame)].placement
    joint = model.frames[model.getFrameId(frame)].parentJoint
    model.inertias[joint] = model.inertias[joint] + placement.act(
        pin.Inertia(mass, np.zeros(3), np.zeros((3, 3))))
    return model


def _lever_torques(model, q, frame, mass):
    """tau_j = axis_j . ((p_tip - o_j) x F), F = m g downwards: a point mass's gravity load."""
    data = model.createData()
    pin.forwardKinematics(model, data, q)
    pin.updateFramePlacements(model, data)
    tip = data.oMf[model.getFrameId(frame)].translation
    force = np.array([0.0, 0.0, -mass * GRAVITY])
    pin.computeJointJacobians(model, data, q)
    torques = []
    for j in range(1, model.njoints):
        # The joint's rotation axis in the world frame: the angular part of its column.
        column = pin.getJointJacobian(model, data, j, pin.LOCAL_WORLD_ALIGNED)[
            3:, model.joints[j].idx_v]
        torques.append(column @ np.cross(tip - data.oMi[j].translation, force))
    return np.array(torques)


@pytest.mark.parametrize('arm', sorted(ARMS))
def test_payload_changes_gravity_torque_by_m_g_lever(arm):
    urdf = _urdf(arm)
    _, joints, tip = ARMS[arm]
    mass = 1.5
    plain = MujocoArm(urdf, joints, tip_link=tip)
    loaded = MujocoArm(urdf, joints, tip_link=tip, payload_mass_offset=mass)
    model = _reduced_pinocchio(urdf, joints)
    heavy = _with_point_mass(model, tip, mass)
    heavy_data = heavy.createData()
    model.gravity.linear[:] = heavy.gravity.linear[:] = [0.0, 0.0, -GRAVITY]
    for q, _, _ in _random_states(model, np.random.default_rng(2), 50):
        plain.set_state(q, np.zeros(len(q)))
        loaded.set_state(q, np.zeros(len(q)))
        difference = loaded.gravity_torque() - plain.gravity_torque()
        # Joint torque that holds a weight m g at the tip: m g times the lever about each axis
        # (the sign: the holding torque opposes the weight's moment).
        np.testing.assert_allclose(difference, -_lever_torques(model, q, tip, mass),
                                   atol=1e-8)
        np.testing.assert_allclose(loaded.gravity_torque(),
                                   pin.computeGeneralizedGravity(heavy, heavy_data, q),
                                   atol=1e-8)
    # The lever check is not vacuous: the payload loads the shoulder substantially.
    assert np.max(np.abs(difference)) > 0.5 * mass * GRAVITY * 0.1


def test_inertia_scale_scales_every_link():
    urdf = _urdf('ur5')
    scale = 1.3
    plant = MujocoArm(urdf, UR5_JOINTS, inertia_scale=scale)
    model = _reduced_pinocchio(urdf, UR5_JOINTS)
    for j in range(1, model.njoints):
        inertia = model.inertias[j]
        model.inertias[j] = pin.Inertia(inertia.mass * scale, inertia.lever,
                                        inertia.inertia * scale)
    data = model.createData()
    for q, v, tau in _random_states(model, np.random.default_rng(3), 50):
        plant.set_state(q, v)
        np.testing.assert_allclose(plant.acceleration(tau), pin.aba(model, data, q, v, tau),
                                   rtol=1e-9, atol=1e-9)


def _pinocchio_rk4(model, q, v, torques, dt, substeps):
    """Classical RK4 of (q, v) with pin.aba, torque held over each dt, dt / substeps steps."""
    data = model.createData()
    h = dt / substeps

    def f(q, v, tau):
        return v, pin.aba(model, data, q, v, tau)

    for tau in torques:
        for _ in range(substeps):
            k1q, k1v = f(q, v, tau)
            k2q, k2v = f(q + 0.5 * h * k1q, v + 0.5 * h * k1v, tau)
            k3q, k3v = f(q + 0.5 * h * k2q, v + 0.5 * h * k2v, tau)
            k4q, k4v = f(q + h * k3q, v + h * k3v, tau)
            q = q + h / 6.0 * (k1q + 2 * k2q + 2 * k3q + k4q)
            v = v + h / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v)
    return q, v


def open_loop_drift(arm, timestep=1e-3, duration=1.0, substeps=10):
    """
    Compare MuJoCo's RK4 with an independent Pinocchio RK4 over an open-loop torque sequence.

    Returns (max |q| difference against Pinocchio at the same step, the same against
    Pinocchio at timestep / substeps) after `duration` seconds from rest at mid-range.
    """
    urdf = _urdf(arm)
    _, joints, _ = ARMS[arm]
    # No joint-limit constraints here: this compares integration, not the end stops.
    plant = MujocoArm(urdf, joints, joint_limits=False, timestep=timestep)
    model = _reduced_pinocchio(urdf, joints)
    q0 = 0.5 * (model.lowerPositionLimit + model.upperPositionLimit)
    rng = np.random.default_rng(4)
    gravity = pin.computeGeneralizedGravity(model, model.createData(), q0)
    steps = int(round(duration / timestep))
    # Gravity of the start plus a random torque held for 10 steps at a time: a motion of a
    # few tenths of a radian, not a fall.
    wiggle = rng.uniform(-0.2, 0.2, (steps // 10 + 1, len(joints))) * model.effortLimit
    torques = [np.clip(gravity + wiggle[k // 10], -model.effortLimit, model.effortLimit)
               for k in range(steps)]
    plant.set_state(q0, np.zeros(len(joints)))
    for tau in torques:
        plant.step(tau)
    q_mujoco, _ = plant.state()
    q_same, _ = _pinocchio_rk4(model, q0, np.zeros(len(joints)), torques, timestep, 1)
    q_fine, _ = _pinocchio_rk4(model, q0, np.zeros(len(joints)), torques, timestep, substeps)
    assert np.max(np.abs(q_mujoco - q0)) > 0.05, 'the sequence barely moved the arm'
    return np.max(np.abs(q_mujoco - q_same)), np.max(np.abs(q_mujoco - q_fine))


@pytest.mark.parametrize('arm', sorted(ARMS))
def test_open_loop_integration_matches_pinocchio_rk4(arm):
    same, fine = open_loop_drift(arm, timestep=1e-3)
    coarse_same, coarse = open_loop_drift(arm, timestep=2e-3)
    # Same scheme and step: the engines agree to round-off.
    assert max(same, coarse_same) < 1e-9, (arm, same, coarse_same)
    # Against a 10x finer step: RK4's own truncation error, small at 1 ms and shrinking as a
    # 4th-order method's does (2^4 = 16 for half the step; > 8 allows for the leading term
    # not yet dominating).
    assert fine < 5e-5, f'{arm}: MuJoCo (1 ms) vs Pinocchio RK4 (0.1 ms) after 1 s: {fine:.3g}'
    assert coarse / fine > 8.0, (arm, coarse, fine)


def test_state_step_and_time():
    plant = MujocoArm(_urdf('ur5'), UR5_JOINTS, timestep=2e-3)
    plant.set_state(np.full(6, 0.1), np.zeros(6))
    q, v = plant.state()
    np.testing.assert_array_equal(q, np.full(6, 0.1))
    plant.step(np.zeros(6), steps=5)
    assert plant.time == pytest.approx(0.01)
    q1, v1 = plant.state()
    assert np.any(v1 != 0.0), 'gravity moves an unpowered arm'


def test_damping_is_opt_in():
    urdf = _urdf('panda')
    plain = MujocoArm(urdf, PANDA_ARM)
    damped = MujocoArm(urdf, PANDA_ARM, damping=True)
    assert np.all(plain.model.dof_damping == 0.0)
    np.testing.assert_allclose(damped.model.dof_damping, 0.003)


def test_locked_joint_at_a_position_matches_reduced_model():
    urdf = _urdf('ur5')
    planned = UR5_JOINTS[:3]
    locked = {'wrist_1_joint': 0.4, 'wrist_2_joint': -1.1, 'wrist_3_joint': 2.0}
    plant = MujocoArm(urdf, planned, locked_positions=locked)
    full = pin.buildModelFromXML(dynamics_urdf(urdf))
    reference = pin.neutral(full)
    for name, value in locked.items():
        reference[full.joints[full.getJointId(name)].idx_q] = value
    model = pin.buildReducedModel(full, [full.getJointId(n) for n in locked], reference)
    data = model.createData()
    for q, v, tau in _random_states(model, np.random.default_rng(5), 50):
        plant.set_state(q, v)
        np.testing.assert_allclose(plant.acceleration(tau), pin.aba(model, data, q, v, tau),
                                   rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize('kwargs, match', [
    ({'joint_names': ['nope']}, 'not joints of the URDF'),
    ({'joint_names': UR5_JOINTS, 'payload_mass_offset': 1.0}, 'needs tip_link'),
    ({'joint_names': UR5_JOINTS, 'tip_link': 'nope', 'payload_mass_offset': 1.0},
     'not a link'),
    ({'joint_names': UR5_JOINTS, 'inertia_scale': 0.0}, 'inertia_scale'),
    ({'joint_names': UR5_JOINTS, 'integrator': 'rk5'}, 'integrator'),
])
def test_bad_settings_are_refused_with_the_reason(kwargs, match):
    with pytest.raises(ArmModelError, match=match):
        MujocoArm(_urdf('ur5'), **kwargs)


def test_bad_urdf_is_refused():
    with pytest.raises(ArmModelError, match='not valid XML'):
        MujocoArm('<robot', UR5_JOINTS)
    plant = MujocoArm(_urdf('ur5'), UR5_JOINTS)
    with pytest.raises(ArmModelError, match='finite'):
        plant.step(np.full(6, np.nan))
