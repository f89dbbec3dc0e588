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
plant_node's command_interface position, ROS-free: a position-controlled arm's controller.

JointTrajectoryController without an effort command interface refuses goals with efforts
(ros2_controllers, jazzy: validate_trajectory_msg); the drives of a position-controlled arm
track the commanded position on their own, with gravity compensation, and take no torque
from the trajectory.
"""

import numpy as np
from plant_oracle import Expected
import pytest
from test_follow_joint_trajectory import _msg, _point, JOINTS as FJT_JOINTS
from test_plant_simulator import advance, KD, KP, reference, simulator
from toc_ros.plant import jtc_trajectory as jtc


def test_efforts_are_refused_without_an_effort_interface():
    msg = _msg([_point(1, [0.1, 0.2], velocities=[0, 0], effort=[1.0, 2.0])])
    with pytest.raises(jtc.GoalError) as info:
        jtc.validate(msg, FJT_JOINTS, now_ns=0, effort_interface=False)
    assert info.value.code == jtc.INVALID_GOAL and info.value.text == jtc.EFFORT_REFUSED
    assert jtc.validate(msg, FJT_JOINTS, now_ns=0).points[0].effort.tolist() == [1.0, 2.0]
    plain = _msg([_point(1, [0.1, 0.2], velocities=[0, 0])])
    assert jtc.validate(plain, FJT_JOINTS, now_ns=0, effort_interface=False).points[0].effort \
        is None


def _run(interface, efforts):
    """Follow a motion that carries the given efforts with the cylindrical robot."""
    sim = simulator()
    sim.configure(sim.model, KP, KD, 1000.0, 0.0, 0.0, interface)
    q0 = sim.x[0::2].copy()
    expected = Expected([0.0, 0.5, 1.0], [q0, q0 + [0.2, 0.1], q0 + [0.3, 0.1]],
                        [[0.0, 0.0], [0.5, 0.1], [0.0, 0.0]], efforts)
    sim.schedule(reference(expected), 0)
    samples = advance(sim, 1200 * 1_000_000, [])
    return sim, samples


def test_a_position_interface_takes_no_torque_from_the_trajectory():
    efforts = [[50.0, 20.0], [-80.0, 10.0], [0.0, 0.0]]
    moved, samples = _run('position', efforts)
    without, _ = _run('position', None)
    # The trajectory's efforts change nothing: the same states, bit for bit.
    np.testing.assert_array_equal(moved.x, without.x)
    # The command is the PD on the reference alone (this robot has no gravity to hold).
    q_ref, dq_ref = (np.asarray(v) for v in moved.target(moved.sim_ns)[:2])
    pd = np.asarray(KP) * (q_ref - moved.x[0::2]) + np.asarray(KD) * (dq_ref - moved.x[1::2])
    np.testing.assert_allclose(moved.command(), np.clip(pd, -moved.u_max, moved.u_max),
                               rtol=0, atol=1e-9)
    fed, _ = _run('effort', efforts)
    assert np.max(np.abs(fed.x - moved.x)) > 1e-6
    assert len(samples) == 1200


@pytest.mark.slow
def test_the_panda_on_mujoco_tracks_a_goal_without_efforts_and_holds_it_against_gravity():
    pytest.importorskip('mujoco')
    from arm_oracle import find_panda_urdf, PANDA_JOINTS
    import pinocchio as pin
    from test_plan_reference import START
    from toc_ros.arm_model import build_arm
    from toc_ros.conversions import time_msg
    from toc_ros.core import Problem, solve, Status
    from toc_ros.execution import without_effort
    from toc_ros.plant import follow_joint_trajectory as fjt
    from toc_ros.plant.model import MujocoEngine
    from toc_ros.plant.reference import NS
    from toc_ros.plant.simulator import PlantSimulator

    urdf = find_panda_urdf().read_text()
    model = build_arm('panda', '', PANDA_JOINTS, None, None, None)
    goal = np.array([1.6, -0.4, 0.3, -2.0, 0.2, 1.8, 0.6])
    result = solve(Problem(model=model.robot, x0=tuple(model.state(np.array(START))),
                           x_goal=tuple(model.state(goal)), n_intervals=60))
    assert result.status is Status.SOLVED, result.message
    engine = MujocoEngine({'robot_description': urdf, 'joint_names': PANDA_JOINTS,
                           'robot.tip_link': '', 'payload_mass_offset': 0.0,
                           'inertia_scale': 1.0, 'integration_rate': 1000.0})
    sim = PlantSimulator(PANDA_JOINTS)
    # config/panda.yaml's gains.
    sim.configure(engine, [600.0] * 4 + [250.0, 150.0, 50.0], [20.0] * 4 + [8.0, 6.0, 2.0],
                  1000.0, 0.0, 0.0, 'position')
    sim.reset(np.ravel(np.column_stack([START, np.zeros(7)])), PANDA_JOINTS)
    msg = model.trajectory_msg(result, PANDA_JOINTS, time_msg((sim.sim_ns + 0.03 * NS) / NS))
    with pytest.raises(jtc.GoalError, match='effort'):
        jtc.validate(msg, PANDA_JOINTS, sim.sim_ns, effort_interface=False)
    sim.follow(jtc.validate(without_effort(msg), PANDA_JOINTS, sim.sim_ns,
                            effort_interface=False), fjt.Tolerances.defaults(7), object())
    worst = 0.0
    for _ in range(round((result.final_time + 2.0) * 1000)):
        sim.run(1)
        worst = max(worst, np.max(np.abs(sim.follower.reference(sim.sim_ns).positions
                                         - sim.x[0::2])))
    assert [o.code for o in sim.follower.take_outcomes()] == [fjt.SUCCESSFUL]
    # Without the feed-forward the PD carries the torques: it lags (0.045 rad here, 0.019
    # with the efforts fed forward) but arrives, and rests on the gravity torque.
    assert worst < 0.1
    np.testing.assert_allclose(sim.x[0::2], goal, rtol=0, atol=1e-4)
    oracle = pin.buildModelFromXML(urdf)
    q_full = np.zeros(oracle.nq)
    q_full[[oracle.getJointId(name) - 1 for name in PANDA_JOINTS]] = goal
    gravity = pin.computeGeneralizedGravity(oracle, oracle.createData(), q_full)
    np.testing.assert_allclose(sim.command(), gravity[:7], rtol=0, atol=0.05)
