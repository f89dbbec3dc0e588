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
How a plan starts and ends for a JointTrajectoryController: at rest, held, on time.

A plan from rest is stamped start_lead ahead; JTC interpolates from the state it commanded
last to the first point from the goal's arrival on, the effort too.  Without the hold point the
plan's first torque fades in while the positions rest; with it (execution.held_start) the
controller holds until the plan starts.  Checked on the JTC emulation's samples and, closing
the loop on MuJoCo, on how far the Panda moves before its plan starts.
"""

import math

from builtin_interfaces.msg import Duration, Time
import numpy as np
import pytest
from std_msgs.msg import Header
from toc_ros.core.plan_reference import END_REST_SPEED, rest_at_end
from toc_ros.execution import continued, goal_trajectory, held_start, HOLD_LEAD_S
from toc_ros.plant import jtc_trajectory as jtc
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

NS = 1_000_000_000
LEAD_S = 0.03           # solver_node's start_lead default


def ns(stamp):
    return stamp.sec * NS + stamp.nanosec


def plan_msg(stamp_ns, u0):
    """Return a 2-joint plan from rest at [0.1, 0.2]: 3 points 0.1 s apart, efforts u0, u0, 0."""
    times = [0, NS // 10, 2 * NS // 10]
    points = [JointTrajectoryPoint(positions=q, velocities=v, effort=u,
                                   time_from_start=Duration(sec=t // NS, nanosec=t % NS))
              for q, v, u, t in zip([[0.1, 0.2], [0.15, 0.25], [0.2, 0.3]],
                                    [[0.0, 0.0], [1.0, 1.0], [0.0, 0.0]],
                                    [u0, u0, [0.0, 0.0]], times)]
    return JointTrajectory(header=Header(stamp=Time(sec=stamp_ns // NS, nanosec=stamp_ns % NS)),
                           joint_names=['a', 'b'], points=points)


def test_rest_at_end_zeroes_only_a_residual():
    v = np.array([[1.0, -2.0], [0.5, 0.1], [5e-7, -9e-7]])
    zeroed, at_rest = rest_at_end(v)
    assert at_rest and np.all(zeroed[-1] == 0.0) and np.array_equal(zeroed[:-1], v[:-1])
    assert v[-1, 0] == 5e-7                      # the caller's array is not changed
    moving, at_rest = rest_at_end(np.array([[0.0, 0.0], [2 * END_REST_SPEED, 0.0]]))
    assert not at_rest and moving[-1, 0] == 2 * END_REST_SPEED
    # JTC's bound on the last point's velocities (float32 epsilon) is below END_REST_SPEED:
    # what the solver leaves there must be published as zero.
    assert END_REST_SPEED > jtc.FLOAT32_EPSILON


def test_held_start_keeps_every_point_at_its_time():
    stamp_ns = 12 * NS + 345_000_000
    msg = plan_msg(stamp_ns, [3.0, -4.0])
    held = held_start(msg, [0.5, -0.25])
    hold_ns = round(HOLD_LEAD_S * NS)
    assert ns(held.header.stamp) == stamp_ns - hold_ns
    assert list(held.joint_names) == ['a', 'b'] and len(held.points) == 4
    first = held.points[0]
    assert list(first.positions) == [0.1, 0.2] and list(first.velocities) == [0.0, 0.0]
    assert list(first.effort) == [0.5, -0.25] and ns(first.time_from_start) == 0
    assert len(first.accelerations) == 0          # the points have none
    for original, copy in zip(msg.points, held.points[1:]):
        assert ns(copy.time_from_start) - hold_ns == ns(original.time_from_start)
        assert list(copy.positions) == list(original.positions)
        assert list(copy.effort) == list(original.effort)
    assert ns(msg.points[1].time_from_start) == NS // 10      # the plan message is unchanged
    assert ns(msg.header.stamp) == stamp_ns
    # A zero stamp ("start on arrival") stays zero.
    assert ns(held_start(plan_msg(0, [3.0, -4.0]), [0.0, 0.0]).header.stamp) == 0


def test_goals_carry_efforts_only_when_told():
    msg = plan_msg(12 * NS, [3.0, -4.0])
    # By default (execute.effort false) no point has efforts: JTC without an effort command
    # interface rejects goals that carry them.  Nor is there a hold point.
    plain = goal_trajectory(msg, False, [0.5, -0.25])
    assert len(plain.points) == 3 and all(len(p.effort) == 0 for p in plain.points)
    assert [list(p.positions) for p in plain.points] == [list(p.positions) for p in msg.points]
    assert [ns(p.time_from_start) for p in plain.points] == [0, NS // 10, 2 * NS // 10]
    assert ns(plain.header.stamp) == 12 * NS
    assert all(len(p.effort) == 2 for p in msg.points)       # the published plan keeps them
    held = goal_trajectory(msg, True, [0.5, -0.25])
    assert len(held.points) == 4 and list(held.points[0].effort) == [0.5, -0.25]
    assert goal_trajectory(msg, True, None) is msg            # a moving start: as published


def motion_msg(stamp_ns, t0, count, dt=0.1):
    """
    Return a 2-joint motion sampled every dt from t0, stamped.

    Joint a accelerates at 5 rad/s^2 up to 2 rad/s at t = 0.4 s, then holds it (effort 5,
    then 0); joint b moves as sin t.
    """
    points = []
    for k in range(count):
        t = t0 + k * dt
        ns_k = round(k * dt * NS)
        a = 2.5 * t * t if t <= 0.4 else 0.4 + 2.0 * (t - 0.4)
        points.append(JointTrajectoryPoint(
            positions=[a, math.sin(t)], velocities=[min(5.0 * t, 2.0), math.cos(t)],
            effort=[5.0 if t < 0.4 - 1e-9 else 0.0, -math.sin(t)],
            time_from_start=Duration(sec=ns_k // NS, nanosec=ns_k % NS)))
    return JointTrajectory(header=Header(stamp=Time(sec=stamp_ns // NS, nanosec=stamp_ns % NS)),
                           joint_names=['a', 'b'], points=points)


def samples(msg, arrival_ns, until_ns, state):
    """Return JTC's desired (positions, velocities, efforts) every ms from arrival to until."""
    # The test motions end moving (they stand for parts of longer plans).
    trajectory = jtc.validate(msg, ['a', 'b'], 0, allow_nonzero_velocity_at_end=True)
    trajectory.begin(arrival_ns, state)
    out = [trajectory.sample(t) for t in range(arrival_ns, until_ns, NS // 1000)]
    return np.array([np.concatenate([s.positions, s.velocities, s.effort]) for s in out])


def test_a_goal_ahead_of_now_continues_the_previous_motion_until_it_starts():
    previous = motion_msg(10 * NS, 0.0, 11)           # 10.0 .. 11.0 s
    # The new plan starts on the previous one's node at 10.5 s, where it is (a cycle's start).
    new = motion_msg(10 * NS + NS // 2, 0.5, 8)
    now = 10 * NS + 320_000_000
    goal = continued(previous, new, now)
    # Stamped at the previous point at or before now; every point keeps its absolute time.
    assert ns(goal.header.stamp) == 10 * NS + 300_000_000
    absolute = [ns(goal.header.stamp) + ns(p.time_from_start) for p in goal.points]
    assert absolute[:2] == [10 * NS + 300_000_000, 10 * NS + 400_000_000]
    assert absolute[2:] == [10 * NS + NS // 2 + ns(p.time_from_start) for p in new.points]
    # The controller, taking it at now from the reference it followed, goes on exactly as the
    # previous goal would have until the new plan starts, and follows the plan after.
    before = jtc.validate(previous, ['a', 'b'], 0, allow_nonzero_velocity_at_end=True)
    before.begin(10 * NS, jtc.Point(np.array([0.0, 0.0]), np.array([1.0, 0.0]), None,
                                    np.zeros(2)))
    state = before.sample(now)
    state = jtc.Point(state.positions, state.velocities, None, state.effort)
    expected = samples(previous, now, 10 * NS + NS // 2, state)
    np.testing.assert_allclose(samples(goal, now, 10 * NS + NS // 2, state), expected,
                               rtol=0, atol=1e-12)
    # Without it, JTC bridges the 180 ms to the plan with one cubic and an effort ramp.
    assert np.max(np.abs(samples(new, now, 10 * NS + NS // 2, state) - expected)) > 0.05
    # Nothing to continue: no previous goal, one that is over, a plan that starts now.
    assert continued(None, new, now) is new
    assert continued(previous, new, 11 * NS + 1) is new
    assert continued(previous, new, 10 * NS + NS // 2) is new
    assert continued(JointTrajectory(joint_names=['a', 'b']), new, now) is new


def efforts_before_the_plan(msg, holding, plan_ns):
    """Return JTC's desired (positions, efforts) every ms from the goal's arrival to plan_ns."""
    trajectory = jtc.validate(msg, ['a', 'b'], 0)
    arrival = plan_ns - round(LEAD_S * NS)        # sent when its stamp was start_lead ahead
    # The state the controller commanded last: holding the start, with the holding torque.
    trajectory.begin(arrival, jtc.Point(np.array([0.1, 0.2]), np.zeros(2), None,
                                        np.array(holding)))
    samples = [trajectory.sample(t) for t in range(arrival, plan_ns, NS // 1000)]
    return (np.array([s.positions for s in samples]), np.array([s.effort for s in samples]))


def test_the_controller_holds_until_the_plan_starts():
    holding, u0 = [0.5, -0.25], [3.0, -4.0]
    stamp_ns = 20 * NS
    positions, efforts = efforts_before_the_plan(plan_msg(stamp_ns, u0), holding, stamp_ns)
    assert np.all(positions == [0.1, 0.2])
    # Without the hold point the first torque fades in over the lead, positions at rest.
    assert np.max(np.abs(efforts[-1] - u0)) < 0.05 * np.max(np.abs(np.subtract(u0, holding)))
    positions, efforts = efforts_before_the_plan(
        held_start(plan_msg(stamp_ns, u0), holding), holding, stamp_ns)
    assert np.all(positions == [0.1, 0.2])
    # With it: the holding torque until HOLD_LEAD_S before the plan, then the first torque.
    hold_ms = round(HOLD_LEAD_S * 1000)
    np.testing.assert_allclose(efforts[:-hold_ms], np.tile(holding, (len(efforts) - hold_ms, 1)),
                               rtol=0, atol=1e-12)


@pytest.mark.slow
def test_a_held_goal_from_rest_starts_with_its_reference_on_mujoco():
    """The Panda on MuJoCo, through the JTC emulation: how far it moves before the stamp."""
    # Measured from where the arm is when the goal is sent (the PD may still be settling).
    pytest.importorskip('mujoco')
    from arm_oracle import ArmOracle, find_panda_urdf, PANDA_JOINTS
    from test_plan_reference import START
    from toc_ros.arm_model import build_arm
    from toc_ros.conversions import time_msg
    from toc_ros.core import Problem, solve, Status
    from toc_ros.plant import follow_joint_trajectory as fjt
    from toc_ros.plant.model import MujocoEngine
    from toc_ros.plant.simulator import PlantSimulator
    import pinocchio as pin

    urdf = find_panda_urdf().read_text()
    model = build_arm('panda', '', PANDA_JOINTS, None, None, None)
    oracle = ArmOracle(urdf)
    goals = [np.array([1.6, -0.4, 0.3, -2.0, 0.2, 1.8, 0.6]), np.array(START)]
    plans, q = [], np.array(START)
    for goal in goals:
        result = solve(Problem(model=model.robot, x0=tuple(model.state(q)),
                               x_goal=tuple(model.state(goal)), n_intervals=60))
        assert result.status is Status.SOLVED, result.message
        plans.append((q, goal, result))
        q = goal
    # The last point ends at rest with the torque that holds the arm there (gravity).
    msg = model.trajectory_msg(plans[0][2], PANDA_JOINTS, Time())
    assert all(v == 0.0 for v in msg.points[-1].velocities)
    np.testing.assert_allclose(
        msg.points[-1].effort, pin.computeGeneralizedGravity(
            oracle.model, oracle.model.createData(), np.array(msg.points[-1].positions)),
        rtol=0, atol=1e-9)

    def run(held):
        engine = MujocoEngine({'robot_description': urdf, 'joint_names': PANDA_JOINTS,
                               'robot.tip_link': '', 'payload_mass_offset': 0.0,
                               'inertia_scale': 1.0, 'integration_rate': 1000.0})
        sim = PlantSimulator(PANDA_JOINTS)
        sim.configure(engine, [600.0] * 4 + [250.0, 150.0, 50.0],
                      [20.0] * 4 + [8.0, 6.0, 2.0], 1000.0, 0.0, 0.0)
        sim.reset(np.ravel(np.column_stack([START, np.zeros(7)])), PANDA_JOINTS)
        moved = []
        for start, _, result in plans:
            stamp = sim.sim_ns + round(LEAD_S * NS)      # sent now, stamped start_lead ahead
            msg = model.trajectory_msg(result, PANDA_JOINTS, time_msg(stamp / NS))
            if held:
                msg = held_start(msg, model.holding_torque(start))
            sim.follow(jtc.validate(msg, PANDA_JOINTS, sim.sim_ns),
                       fjt.Tolerances.defaults(7), object())
            before, sent = 0.0, sim.x[0::2].copy()
            while sim.sim_ns < stamp + round((result.final_time + 0.5) * NS):
                sim.run(1)
                if sim.sim_ns <= stamp:
                    before = max(before, np.max(np.abs(sim.x[0::2] - sent)))
            moved.append(before)
        return moved

    plain, held = run(False), run(True)
    # Measured: 0.014 and 0.008 rad without the hold point (0.019 for the second goal when the
    # last point repeated the last torque), 4e-19 and 1.6e-4 rad with it.
    assert min(plain) > 5e-3, plain
    assert max(held) < 1e-3, held
