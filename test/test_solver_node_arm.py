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
solver_node planning for the Panda (robot.model panda) as a process, checked independently.

Every published plan is re-checked by test/arm_oracle.py (Pinocchio from the URDF file, the
sphere file read here): limits at every node, Euler dynamics, the goal (joints or the tip
pose by forward kinematics), clearance of every robot sphere from every obstacle sphere.
No joint_states are published: every plan starts at initial_state.
"""

import math
import time
from types import SimpleNamespace

from arm_oracle import ArmOracle, find_panda_urdf, PANDA_JOINTS
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from nav_msgs.srv import GetPlan
from node_harness import handshake, LATCHED, NodeProcess, reports, RosClient
import numpy as np
import pinocchio as pin
import pytest
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger
from toc_ros.core import Status
from toc_ros.progress import EVENT_REFUSED, EVENT_RESTARTED, EVENT_STOPPED
from trajectory_msgs.msg import JointTrajectory
from visualization_msgs.msg import Marker, MarkerArray

pytestmark = pytest.mark.slow

Q0 = [0.0, -0.5, 0.0, -2.0, 0.0, 1.6, 0.8]
Q1 = [0.5, -0.3, 0.2, -1.8, 0.0, 1.5, 0.8]
# Far enough from Q0 that a sphere half-way along the straight joint path clears both ends.
Q2 = [1.0, -0.3, 0.2, -1.8, 0.0, 1.5, 0.8]
# A long motion (joint 1 over 2.4 rad): executing long enough to change obstacles meanwhile.
Q_FAR = [2.4, -0.5, 0.0, -2.0, 0.0, 1.6, 0.8]
MARGIN = 0.01
# (max_state_age: the tests publish a few joint_states, then send goals: node_harness.py)
PARAMS = {'robot.model': 'panda', 'joint_names': PANDA_JOINTS, 'initial_state': Q0,
          'solver.N': 40, 'solver.timeout': 300.0, 'obstacles.margin': MARGIN,
          'max_state_age': 3600.0}
TIMEOUT = 300.0


@pytest.fixture(scope='module')
def panda(tmp_path_factory):
    yield from _panda_node(tmp_path_factory)


@pytest.fixture()
def own_panda(tmp_path_factory):
    """Start a node of its own: for a test that leaves a measured state (others plan from Q0)."""
    yield from _panda_node(tmp_path_factory)


def _panda_node(tmp_path_factory):
    client = RosClient()
    node = NodeProcess('solver_node', client.namespace, tmp_path_factory.mktemp('arm'),
                       PARAMS)
    try:
        node.wait_for_log('ready:')
        client.collect(DiagnosticStatus, 'solver_node/progress', 100)
        client.collect(JointTrajectory, 'trajectory', LATCHED)
        client.collect(MarkerArray, 'markers', LATCHED)
        create = client.node.create_publisher
        ctx = SimpleNamespace(
            client=client, node=node, oracle=ArmOracle(find_panda_urdf().read_text()),
            goal_pose=create(PoseStamped, client.name('goal_pose'), 10),
            goal_joints=create(JointState, client.name('goal_joints'), 10),
            obstacles=create(Float64MultiArray, client.name('obstacles'), 10),
            markers=create(MarkerArray, client.name('obstacle_markers'), 10),
            plan=client.node.create_client(GetPlan, client.name('solver_node/plan')),
            ready=client.node.create_client(Trigger, client.name('solver_node/ready')))
        for publisher, msg, text in (
                (ctx.goal_joints, JointState(name=['handshake'], position=[0.0]),
                 "'handshake'"),
                (ctx.goal_pose, pose((0.4, 0.0, 0.4), frame='handshake'), "'handshake'"),
                (ctx.obstacles, Float64MultiArray(data=[1.0]), 'multiple of 4'),
                (ctx.markers, marker_array(sphere_marker(0, (0.5, 0, 0.5), 0.1,
                                                         frame='handshake')), "'handshake'")):
            since = time.monotonic()
            handshake(client, publisher, msg, lambda text=text, since=since: [
                r for r in reports(ctx, since) if text in r.message])
        yield ctx
        assert node.stop() == 0, node.log()
    finally:
        node.stop()
        client.close()


def pose(position, quaternion=(0.0, 0.0, 0.0, 0.0), frame='base_link'):
    msg = PoseStamped()
    msg.header.frame_id = frame
    p, o = msg.pose.position, msg.pose.orientation
    p.x, p.y, p.z = (float(v) for v in position)
    o.x, o.y, o.z, o.w = (float(v) for v in quaternion)
    return msg


def sphere_marker(marker_id, centre, radius, frame='base_link', ns='test', action=Marker.ADD,
                  kind=Marker.SPHERE, scale=None):
    marker = Marker(ns=ns, id=marker_id, type=kind, action=action)
    marker.header.frame_id = frame
    marker.pose.position.x, marker.pose.position.y, marker.pose.position.z = centre
    marker.pose.orientation.w = 1.0
    marker.scale.x, marker.scale.y, marker.scale.z = scale or (2 * radius,) * 3
    return marker


def marker_array(*markers):
    return MarkerArray(markers=list(markers))


def final(ctx, since, source):
    """Return the first final report of a goal source since a time (refusals included)."""
    return ctx.client.wait_for(lambda: [r for r in reports(ctx, since)
                                        if r.final and r.goal_source == source], TIMEOUT,
                               f'the result of {source}')[0]


def refusal(ctx, since, text):
    """Return the first refusal report since a time that contains text."""
    return ctx.client.wait_for(lambda: [r for r in reports(ctx, since)
                                        if r.event == EVENT_REFUSED and text in r.message],
                               30.0, f'a refusal with {text!r}')[0]


def plan_after(ctx, since, goal):
    """Return the first trajectory since a time that ends at the goal positions."""
    def found():
        return [m for m in ctx.client.messages('trajectory', since)
                if m.points and np.max(np.abs(np.array(m.points[-1].positions) - goal)) < 1e-4]
    return ctx.client.wait_for(found, TIMEOUT, 'the plan')[0]


def obstacle_markers(ctx, since, count):
    """Return the node's 'obstacles' markers of the first MarkerArray since with count of them."""
    def found():
        for msg in ctx.client.messages('markers', since):
            spheres = [m for m in msg.markers if m.ns == 'obstacles']
            if len(spheres) == count:
                return spheres or [None]
        return None
    spheres = ctx.client.wait_for(found, 30.0, f'markers with {count} obstacle(s)')
    return [] if spheres == [None] else spheres


def settle(ctx):
    """Wait until no plan executes any more (duration + the node's 0.5 s slack)."""
    messages = ctx.client.stamped('trajectory')
    if messages:
        received, msg = messages[-1]
        end = received + (msg.points[-1].time_from_start.sec
                          + 1e-9 * msg.points[-1].time_from_start.nanosec if msg.points else 0)
        time.sleep(max(0.0, end + 0.7 - time.monotonic()))


def test_the_arm_node_is_ready(panda):
    answer = panda.client.call(panda.ready, Trigger.Request())
    assert answer.success, answer.message


def test_goal_joints_plan_checked_independently(panda):
    since = time.monotonic()
    panda.goal_joints.publish(JointState(name=PANDA_JOINTS, position=Q1))
    result = final(panda, since, 'goal_joints')
    assert result.status is Status.SOLVED, result.message
    assert result.robot_model == 'panda'
    msg = plan_after(panda, since, Q1)
    _, t_f = panda.oracle.check(msg, Q0, Q1)
    assert abs(t_f - result.t_f) < 1e-6


def test_goal_joints_outside_the_limits_is_refused(panda):
    settle(panda)
    since = time.monotonic()
    goal = list(Q1)
    goal[3] = 0.5       # panda_joint4's upper limit is -0.0698 rad
    panda.goal_joints.publish(JointState(name=PANDA_JOINTS, position=goal))
    report = refusal(panda, since, 'panda_joint4')
    assert 'outside its limits' in report.message and report.level == DiagnosticStatus.ERROR
    missing = JointState(name=PANDA_JOINTS[:6], position=Q1[:6])
    panda.goal_joints.publish(missing)
    assert 'panda_joint7' in refusal(panda, since, 'lacks joints').message


def test_goal_pose_position_only(panda):
    settle(panda)
    target = panda.oracle.tip(Q1).translation + np.array([0.0, 0.02, -0.03])
    since = time.monotonic()
    panda.goal_pose.publish(pose(target))        # orientation all zero: position only
    result = final(panda, since, 'goal_pose')
    assert result.status is Status.SOLVED, result.message
    goal = np.array(result.goal[:7])
    msg = plan_after(panda, since, goal)
    panda.oracle.check(msg, Q0, goal)
    reached = panda.oracle.tip(msg.points[-1].positions).translation
    assert np.linalg.norm(reached - target) < 1e-6


def test_goal_pose_with_orientation(panda):
    settle(panda)
    wanted = panda.oracle.tip([0.4, -0.3, 0.2, -1.8, 0.1, 1.6, 0.9])
    quat = pin.Quaternion(wanted.rotation).coeffs()     # x, y, z, w
    since = time.monotonic()
    panda.goal_pose.publish(pose(wanted.translation, quat))
    result = final(panda, since, 'goal_pose')
    assert result.status is Status.SOLVED, result.message
    goal = np.array(result.goal[:7])
    msg = plan_after(panda, since, goal)
    panda.oracle.check(msg, Q0, goal)
    reached = panda.oracle.tip(msg.points[-1].positions)
    assert np.linalg.norm(reached.translation - wanted.translation) < 1e-6
    assert np.linalg.norm(pin.log3(reached.rotation.T @ wanted.rotation)) < 1e-6


def test_goal_pose_refusals(panda):
    since = time.monotonic()
    panda.goal_pose.publish(pose((3.0, 0.0, 0.5)))
    assert 'unreachable' in refusal(panda, since, 'goal_pose').message
    panda.goal_pose.publish(pose((0.4, 0.0, 0.4), frame='world'))
    refusal(panda, since, "'world'")
    panda.goal_pose.publish(pose((0.4, 0.0, 0.4), quaternion=(0.0, 0.0, 0.0, 2.0)))
    refusal(panda, since, 'norm')


def test_plan_service_answers_with_the_tip_path(panda):
    settle(panda)
    target = panda.oracle.tip(Q1).translation
    request = GetPlan.Request()
    request.goal = pose(target)
    response = panda.client.call(panda.plan, request, timeout=TIMEOUT)
    poses = response.plan.poses
    assert len(poses) == PARAMS['solver.N'] + 1
    end = poses[-1].pose.position
    assert np.linalg.norm(np.array([end.x, end.y, end.z]) - target) < 1e-6
    start = poses[0].pose.position
    expected = panda.oracle.tip(Q0).translation
    assert np.linalg.norm(np.array([start.x, start.y, start.z]) - expected) < 1e-9


@pytest.mark.parametrize('marker, reason', [
    (sphere_marker(1, (0.5, 0.0, 0.5), 0.1, kind=Marker.CUBE), 'is not SPHERE'),
    (sphere_marker(1, (0.5, 0.0, 0.5), 0.1, scale=(0.2, 0.2, 0.3)), 'non-uniform scale'),
    (sphere_marker(1, (0.5, 0.0, 0.5), 0.1, frame='world'), 'is not the base frame'),
    (sphere_marker(1, (math.nan, 0.0, 0.5), 0.1), 'NaN'),
])
def test_obstacle_marker_refusals(panda, marker, reason):
    settle(panda)
    clear_obstacles(panda)
    since = time.monotonic()
    good = sphere_marker(0, (0.6, 0.3, 0.9), 0.05)
    panda.markers.publish(marker_array(good, marker))
    report = refusal(panda, since, reason)
    assert report.message.startswith('obstacle_markers:')
    # The whole array is refused: the obstacle set stays as it was (empty).
    time.sleep(0.5)
    latest = panda.client.messages('markers')[-1]
    assert not [m for m in latest.markers if m.ns == 'obstacles']


def test_obstacle_markers_add_delete_deleteall(panda):
    settle(panda)
    since = time.monotonic()
    panda.markers.publish(marker_array(sphere_marker(0, (0.6, 0.3, 0.9), 0.05),
                                       sphere_marker(1, (0.6, -0.3, 0.9), 0.07)))
    drawn = obstacle_markers(panda, since, 2)
    assert sorted(round(m.scale.x, 9) for m in drawn) == [0.1, 0.14]
    since = time.monotonic()
    panda.markers.publish(marker_array(sphere_marker(0, (0.6, 0.35, 0.95), 0.06)))  # replaces
    drawn = obstacle_markers(panda, since, 2)
    moved = [m for m in drawn if abs(m.scale.x - 0.12) < 1e-9]
    assert len(moved) == 1 and abs(moved[0].pose.position.y - 0.35) < 1e-12
    since = time.monotonic()
    panda.markers.publish(marker_array(sphere_marker(1, (0, 0, 0), 0.1, action=Marker.DELETE)))
    drawn = obstacle_markers(panda, since, 1)
    assert abs(drawn[0].scale.x - 0.12) < 1e-9
    since = time.monotonic()
    panda.markers.publish(marker_array(
        Marker(action=Marker.DELETEALL), sphere_marker(5, (0.5, 0.5, 1.0), 0.04)))
    drawn = obstacle_markers(panda, since, 1)
    assert abs(drawn[0].scale.x - 0.08) < 1e-9 and abs(drawn[0].pose.position.z - 1.0) < 1e-12
    since = time.monotonic()
    panda.markers.publish(marker_array(Marker(action=Marker.DELETEALL)))
    assert obstacle_markers(panda, since, 0) == []


def clear_obstacles(ctx):
    """Empty the obstacle set (whatever an earlier test left) and wait until it is drawn."""
    since = time.monotonic()
    ctx.obstacles.publish(Float64MultiArray())
    obstacle_markers(ctx, since, 0)


def test_obstacle_rows_are_avoided(panda):
    settle(panda)
    clear_obstacles(panda)
    since = time.monotonic()
    panda.obstacles.publish(Float64MultiArray(data=[1.0, 2.0, 3.0, 0.1, 5.0]))
    refusal(panda, since, 'multiple of 4')
    # A sphere where the tip passes half-way along the unobstructed plan from Q0 to Q1.
    middle = panda.oracle.tip(0.5 * (np.array(Q0) + np.array(Q2))).translation
    sphere = (*middle, 0.05)
    since = time.monotonic()
    panda.obstacles.publish(Float64MultiArray(data=list(sphere)))
    obstacle_markers(panda, since, 1)
    # The straight joint path collides; start and goal are clear.
    assert panda.oracle.clearance(0.5 * (np.array(Q0) + np.array(Q2)), [sphere], MARGIN) < 0
    assert min(panda.oracle.clearance(q, [sphere], MARGIN) for q in (Q0, Q2)) > 0
    since = time.monotonic()
    panda.goal_joints.publish(JointState(name=PANDA_JOINTS, position=Q2))
    result = final(panda, since, 'goal_joints')
    assert result.status is Status.SOLVED, result.message
    worst, _ = panda.oracle.check(plan_after(panda, since, Q2), Q0, Q2, [sphere], MARGIN)
    assert worst >= -1e-6, worst
    clear_obstacles(panda)


def test_obstacle_on_the_executing_plan_stops_and_replans(panda):
    settle(panda)
    clear_obstacles(panda)
    since = time.monotonic()
    panda.goal_joints.publish(JointState(name=PANDA_JOINTS, position=Q_FAR))
    first = plan_after(panda, since, Q_FAR)
    received = time.monotonic()
    final(panda, since, 'goal_joints')     # the worker is done with the goal's solve
    times, q, _, _ = panda.oracle.arrays(first)
    # On the rest of the plan: where the tip is at 80 % of its duration.
    k = int(np.searchsorted(times, 0.8 * times[-1]))
    centre = panda.oracle.tip(q[k]).translation
    sphere = (*centre, 0.03)
    stopped_since = time.monotonic()
    panda.obstacles.publish(Float64MultiArray(data=list(sphere)))
    assert time.monotonic() - received < 0.8 * times[-1], 'too slow to test on this machine'
    stop = panda.client.wait_for(lambda: [r for r in reports(panda, stopped_since)
                                          if r.event == EVENT_STOPPED], 30.0, 'the stop')[0]
    assert 'cuts obstacle 0' in stop.message, stop.message
    # The stop is sent at once: the empty trajectory (no measured state: the robot holds).
    sent = panda.client.wait_for(lambda: panda.client.messages('trajectory', stopped_since),
                                 30.0, 'the stop trajectory')[0]
    assert not sent.points and list(sent.joint_names) == PANDA_JOINTS
    # The goal is planned again around the new obstacle (source 'replan'; when the obstacle
    # came while the worker still finished the goal's request, that request restarts).
    result = panda.client.wait_for(lambda: [
        r for r in reports(panda, stopped_since)
        if r.final and r.goal_source in ('replan', 'goal_joints')], TIMEOUT, 'the replan')[0]
    if result.status is Status.SOLVED:
        again = plan_after(panda, stopped_since, Q_FAR)
        worst, _ = panda.oracle.check(again, Q0, Q_FAR, [sphere], MARGIN)
        assert worst >= -1e-6
    else:
        assert result.message, result
    clear_obstacles(panda)


def test_obstacle_change_during_a_solve_restarts_it(panda):
    settle(panda)
    clear_obstacles(panda)
    middle = panda.oracle.tip(0.5 * (np.array(Q0) + np.array(Q2))).translation
    first = (*middle, 0.05)
    moved = (middle[0], middle[1] + 0.02, middle[2], 0.06)
    since = time.monotonic()
    panda.obstacles.publish(Float64MultiArray(data=list(first)))
    obstacle_markers(panda, since, 1)
    since = time.monotonic()
    panda.goal_joints.publish(JointState(name=PANDA_JOINTS, position=Q2))
    # Once the solve runs (a detour around the sphere takes seconds), move the sphere.
    panda.client.wait_for(lambda: [r for r in reports(panda, since) if r.solving], 60.0,
                          'the solve')
    panda.obstacles.publish(Float64MultiArray(data=list(moved)))
    result = final(panda, since, 'goal_joints')
    events = [r.event for r in reports(panda, since)]
    if EVENT_RESTARTED not in events:
        pytest.skip('the solve ended before the obstacle change arrived (fast machine)')
    assert result.status is Status.SOLVED, result.message
    plans = [m for m in panda.client.messages('trajectory', since) if m.points]
    assert len(plans) == 1      # only the plan for the current data was published
    worst, _ = panda.oracle.check(plans[0], Q0, Q2, [moved], MARGIN)
    assert worst >= -1e-6, worst
    clear_obstacles(panda)


def _moving_half_way(panda):
    """Plan to Q_FAR; return (q, dq, k, publish(count)): joint_states of node k, half-way."""
    since = time.monotonic()
    panda.goal_joints.publish(JointState(name=PANDA_JOINTS, position=Q_FAR))
    plan = plan_after(panda, since, Q_FAR)
    _, q, dq, _ = panda.oracle.arrays(plan)
    k = len(q) // 2     # the robot is half-way, moving
    states = panda.client.node.create_publisher(JointState, panda.client.name('joint_states'), 10)
    panda.client.wait_for(lambda: states.get_subscription_count() > 0, 30.0, 'joint_states')

    def publish(count=5):
        for _ in range(count):
            states.publish(JointState(name=PANDA_JOINTS, position=q[k].tolist(),
                                      velocity=dq[k].tolist()))
            time.sleep(0.05)
    return q, dq, k, publish


def test_cancel_goal_brakes_from_the_measured_state(own_panda):
    panda = own_panda
    q, dq, k, measured = _moving_half_way(panda)
    measured()
    cancel = panda.client.node.create_client(Trigger, panda.client.name('solver_node/cancel_goal'))
    since = time.monotonic()
    answer = panda.client.call(cancel, Trigger.Request())
    assert answer.success and 'braking to rest' in answer.message, answer.message
    stop = panda.client.wait_for(lambda: panda.client.messages('trajectory', since), 30.0,
                                 'the braking trajectory')[0]
    times, bq, bdq, effort = panda.oracle.arrays(stop)
    assert np.allclose(bq[0], q[k], atol=1e-12) and np.allclose(bdq[0], dq[k], atol=1e-12)
    assert np.allclose(bdq[-1], 0.0, atol=1e-12)
    deceleration = -dq[k] / times[-1]
    for qj, vj, uj in zip(bq[:-1], bdq[:-1], effort[:-1]):    # the last repeats the torque
        tau = pin.rnea(panda.oracle.model, panda.oracle.data, qj, vj, deceleration)
        assert np.allclose(uj, tau, atol=1e-6)
    assert np.all(np.abs(effort) <= panda.oracle.effort + 1e-9)
    assert np.all(bq >= panda.oracle.lower) and np.all(bq <= panda.oracle.upper)


def test_a_new_joint_set_under_an_executing_plan_stops_it_on_its_own_joints(own_panda):
    # joint_names changed to six of the Panda's joints while a plan of seven executes: the
    # stop addresses the plan's seven joints (it had the new six names and seven positions),
    # and joint_states keep coming without crashing the node (a ValueError in the callback
    # ended the process).
    panda = own_panda
    _, _, _, measured = _moving_half_way(panda)
    measured(6)         # the arm is drawn at this state; the plan (1.1 s) still executes
    since = time.monotonic()
    results = panda.client.set_parameters('solver_node', {'joint_names': PANDA_JOINTS[:6]})
    assert all(r.successful for r in results), [r.reason for r in results]
    stop = panda.client.wait_for(lambda: panda.client.messages('trajectory', since), 30.0,
                                 'the stop')[0]
    assert list(stop.joint_names) == PANDA_JOINTS
    assert all(len(p.positions) == len(PANDA_JOINTS) for p in stop.points)
    measured(10)
    assert panda.node.alive(), panda.node.log()
    assert panda.client.call(panda.ready, Trigger.Request()).success
    # Goals for the six joints start from the newest joint_states, read with the new names.
    since = time.monotonic()
    panda.goal_joints.publish(JointState(name=PANDA_JOINTS[:6], position=Q_FAR[:6]))
    result = final(panda, since, 'goal_joints')
    assert result.status is Status.SOLVED, result.message
