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
plant_node's ~/follow_joint_trajectory action as a process (needs control_msgs).

Where this interpreter has no control_msgs but <repo>/.ros2env (the Jazzy environment that
.ci/setup builds with TOC_ROS2_ENV=1) is ready, one test runs this file again in that
environment, so that the action tests run there too; without either they skip.
"""

import os
import subprocess
import sys
import threading
import time
from types import SimpleNamespace

from builtin_interfaces.msg import Duration, Time
from node_harness import CONFIG, JOINTS, NodeProcess, RosClient
import numpy as np
import pytest
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

try:
    from control_msgs.action import FollowJointTrajectory
    from control_msgs.msg import JointTolerance
    from rclpy.action import ActionClient
except ImportError as exc:
    FollowJointTrajectory = None
    MISSING = str(exc)

pytestmark = pytest.mark.slow
needs_control_msgs = pytest.mark.skipif(
    FollowJointTrajectory is None,
    reason='control_msgs is not installed (a ROS install has ros-jazzy-control-msgs; '
           '.ci/setup with TOC_ROS2_ENV=1 builds it into .ros2env)')
RESULT_TIMEOUT = 60.0
REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ROS2ENV = os.path.join(REPO, '.ros2env')
ROS2ENV_READY = os.path.isfile(os.path.join(ROS2ENV, '.toc_ros_env_ready'))


@pytest.mark.skipif(FollowJointTrajectory is not None or not ROS2ENV_READY,
                    reason='control_msgs is importable here (the tests below run), or there '
                           'is no .ros2env to run them in')
def test_action_tests_pass_in_the_ros2_environment(tmp_path):
    env = {k: v for k, v in os.environ.items()
           if k not in ('PYTHONPATH', 'AMENT_PREFIX_PATH', 'VIRTUAL_ENV', 'PYTHONHOME')}
    venv_bin = os.path.join(sys.prefix, 'bin')
    env['PATH'] = os.pathsep.join(p for p in env.get('PATH', '').split(os.pathsep)
                                  if p and p != venv_bin)
    # The ROS wheels of this venv put their libraries on LD_LIBRARY_PATH and mark that done:
    # the environment's wheels must set up their own (else its control_msgs type support or
    # rclpy itself does not load).
    env.pop('_ROS_WHEELS_BOOTSTRAP_COMPLETE', None)
    libraries = [p for p in env.pop('LD_LIBRARY_PATH', '').split(os.pathsep)
                 if p and not p.startswith(sys.prefix)]
    if libraries:
        env['LD_LIBRARY_PATH'] = os.pathsep.join(libraries)
    script = (f'source "{ROS2ENV}/setup.bash" && export PYTHONPATH="{REPO}:${{PYTHONPATH:-}}" '
              f'&& cd "{REPO}" && exec python -m pytest {os.path.relpath(__file__, REPO)} -q '
              f'-p no:randomly -p no:cacheprovider -rs')
    run = subprocess.run(['bash', '-c', script], env=env, stdin=subprocess.DEVNULL,
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                         timeout=900)
    assert run.returncode == 0, run.stdout[-6000:]
    assert ' passed' in run.stdout and 'control_msgs is not installed' not in run.stdout, \
        run.stdout[-3000:]


@pytest.fixture(scope='module')
def plant(tmp_path_factory):
    client = RosClient()
    node = NodeProcess('plant_node', client.namespace, tmp_path_factory.mktemp('plant_fjt'))
    try:
        node.wait_for_log('ready:')
        client.collect(JointState, 'joint_states', keep=3000)
        client.collect(JointState, 'plant_node/reference', keep=3000)
        ctx = SimpleNamespace(client=client, node=node, action=None, feedback=[])
        if FollowJointTrajectory is not None:
            ctx.action = ActionClient(client.node, FollowJointTrajectory,
                                      client.name('plant_node/follow_joint_trajectory'))
            assert ctx.action.wait_for_server(timeout_sec=30.0), node.tail()
        ctx.trajectory = client.node.create_publisher(JointTrajectory,
                                                      client.name('trajectory'), 10)
        client.wait_for(lambda: client.count('joint_states') > 5, what='joint_states')
        yield ctx
    finally:
        node.stop()
        client.close()


def _current(plant):
    return np.array(plant.client.messages('joint_states')[-1].position)


def _trajectory(points, names=JOINTS):
    """Build the JointTrajectory of (t, positions, velocities) rows, stamp zero (now)."""
    msg = JointTrajectory()
    msg.joint_names = list(names)
    for t, q, dq in points:
        ns = int(round(t * 1e9))
        msg.points.append(JointTrajectoryPoint(
            positions=[float(v) for v in q], velocities=[float(v) for v in dq],
            time_from_start=Duration(sec=ns // 10 ** 9, nanosec=ns % 10 ** 9)))
    return msg


def _time(seconds):
    ns = int(round(seconds * 1e9))
    return Time(sec=ns // 10 ** 9, nanosec=ns % 10 ** 9)


def _send(plant, trajectory, goal_tolerance=0.01, goal_time=3.0):
    """Send a goal; return (accepted-event, holder) with holder.result set when it ends."""
    goal = FollowJointTrajectory.Goal()
    goal.trajectory = trajectory
    goal.goal_tolerance = [JointTolerance(name=n, position=goal_tolerance) for n in JOINTS]
    goal.goal_time_tolerance = Duration(sec=int(goal_time),
                                        nanosec=int(goal_time % 1 * 1e9))
    holder = SimpleNamespace(result=None, status=None, feedback=[], done=threading.Event())

    def on_result(future):
        response = future.result()
        holder.status, holder.result = response.status, response.result
        holder.done.set()

    def on_goal(future):
        handle = future.result()
        if not handle.accepted:
            holder.done.set()
            return
        handle.get_result_async().add_done_callback(on_result)

    plant.action.send_goal_async(
        goal, feedback_callback=lambda msg: holder.feedback.append(msg.feedback)
    ).add_done_callback(on_goal)
    return holder


def _wait(plant, holder, timeout=RESULT_TIMEOUT):
    assert holder.done.wait(timeout), f'no result in {timeout} s:\n{plant.node.tail(30)}'
    assert holder.result is not None, 'the goal was rejected'
    return holder.result


@pytest.mark.skipif(FollowJointTrajectory is not None, reason='control_msgs is installed')
def test_without_control_msgs_the_node_says_why(plant):
    plant.client.wait_for(lambda: 'follow_joint_trajectory is not served' in plant.node.log(),
                          what='the log line')
    assert 'control_msgs is not installed' in plant.node.log()


@needs_control_msgs
def test_goal_executes_and_succeeds_with_feedback(plant):
    q0 = _current(plant)
    target = q0 + np.array([0.2, 0.1])
    holder = _send(plant, _trajectory([(0.8, 0.5 * (q0 + target), [0.25, 0.125]),
                                       (1.6, target, [0.0, 0.0])]))
    result = _wait(plant, holder)
    assert result.error_code == FollowJointTrajectory.Result.SUCCESSFUL, result.error_string
    np.testing.assert_allclose(_current(plant), target, atol=0.01, err_msg=plant.node.tail(20))
    assert len(holder.feedback) >= 10, 'feedback at 20 Hz over ~1.6 s'
    for feedback in holder.feedback:
        assert list(feedback.joint_names) == JOINTS
        np.testing.assert_allclose(np.subtract(feedback.desired.positions,
                                               feedback.actual.positions),
                                   feedback.error.positions, atol=1e-12)


@needs_control_msgs
@pytest.mark.parametrize('names', [['rotation_joint', 'elbow_joint'], ['rotation_joint']])
def test_wrong_joint_names_give_invalid_joints(plant, names):
    q0 = _current(plant)
    holder = _send(plant, _trajectory([(0.5, q0[:len(names)], [0.0] * len(names))], names))
    result = _wait(plant, holder)
    assert result.error_code == FollowJointTrajectory.Result.INVALID_JOINTS
    assert 'elbow_joint' in result.error_string or 'missing' in result.error_string


def _steps(messages, since_stamp):
    """Stamps [s], positions and velocities of reference messages from a stamp on."""
    rows = [(m.header.stamp.sec + m.header.stamp.nanosec * 1e-9, m.position, m.velocity,
             m.effort) for m in messages]
    rows = [r for r in rows if r[0] >= since_stamp]
    return (np.array([r[0] for r in rows]), np.array([r[1] for r in rows]),
            np.array([r[2] for r in rows]), np.array([r[3] for r in rows]))


def _smooth(q0, amplitude, t0, t1, times):
    """Rows (t, q, dq) of q0 + amplitude (1 - cos(pi (t - t0) / (t1 - t0))) / 2 on [t0, t1]."""
    rows = []
    for t in times:
        s = np.clip((t - t0) / (t1 - t0), 0.0, 1.0)
        q = q0 + amplitude * (1.0 - np.cos(np.pi * s)) / 2.0
        dq = amplitude * np.pi / (2.0 * (t1 - t0)) * np.sin(np.pi * s) * (0.0 < s < 1.0)
        rows.append((t, q, dq))
    return rows


@needs_control_msgs
def test_new_goal_preempts_without_a_jump_in_the_reference(plant):
    q0 = _current(plant)
    stamp = plant.client.messages('joint_states')[-1].header.stamp
    start = stamp.sec + stamp.nanosec * 1e-9 + 0.3
    first_rows = _smooth(q0, np.array([0.3, 0.15]), 0.0, 3.0, np.arange(31) * 0.1)
    first = _trajectory(first_rows)
    first.header.stamp = _time(start)
    sent_first = time.monotonic()
    first_goal = _send(plant, first)
    time.sleep(1.2)
    # A replan of the same start: the first motion up to 1.8 s, then a changed target; it
    # arrives about 1 s into the first and begins at its own first point (1.8 s).
    times = 1.8 + np.arange(13) * 0.1
    bend = _smooth(np.zeros(2), np.array([-0.1, 0.05]), 1.8, 3.0, times)
    rows = [(t, q + dq_, v + dv) for (t, q, v), (_, dq_, dv) in
            zip(_smooth(q0, np.array([0.3, 0.15]), 0.0, 3.0, times), bend)]
    second = _trajectory(rows)
    second.header.stamp = _time(start)
    sent_second = time.monotonic()
    second_goal = _send(plant, second)
    result = _wait(plant, first_goal)
    assert result.error_code == FollowJointTrajectory.Result.INVALID_GOAL, plant.node.tail(30)
    assert 'preempted' in result.error_string
    result = _wait(plant, second_goal)
    assert result.error_code == FollowJointTrajectory.Result.SUCCESSFUL, result.error_string
    stamps, q_ref, dq_ref, _ = _steps(plant.client.messages('plant_node/reference'), start)
    dt = np.diff(stamps)[:, None]
    # Position: every step of the reference is covered by its velocity (no jump anywhere,
    # the switch included); velocity: continuous (a bounded acceleration: the motion's own
    # is at most 0.3 pi^2 / 18 = 0.16 rad/s^2).
    speed = np.maximum(np.abs(dq_ref[:-1]), np.abs(dq_ref[1:]))
    assert np.all(np.abs(np.diff(q_ref, axis=0)) <= 1.2 * speed * dt + 1e-6)
    acceleration = np.abs(np.diff(dq_ref, axis=0)) / dt
    assert np.max(acceleration) < 1.0, f'max |d dq_ref / dt| = {np.max(acceleration):.3g}'
    np.testing.assert_allclose(q_ref[-1], rows[-1][1], atol=1e-9)
    # The commanded effort (joint_states.effort, PD on the reference): its largest change
    # between samples around the switch against the largest while the first goal ran alone.
    # Joining from the measured state instead would add kp times the tracking error at once.
    states = plant.client.stamped('joint_states', sent_first)
    efforts = np.array([m.effort for _, m in states])
    received = np.array([t for t, _ in states])[1:]
    jumps = np.abs(np.diff(efforts, axis=0))
    alone = np.max(jumps[(received > sent_first + 0.5) & (received < sent_second - 0.05)],
                   axis=0)
    switch = np.max(jumps[(received > sent_second - 0.05) & (received < sent_second + 0.3)],
                    axis=0)
    print(f'max |delta u| between joint_states samples: first goal alone {alone}, around '
          f'the switch {switch}')
    assert np.all(switch <= 2.0 * alone + 1.0)


@needs_control_msgs
def test_topic_trajectory_aborts_the_active_goal(plant):
    q0 = _current(plant)
    holder = _send(plant, _trajectory([(2.0, q0 + [0.2, 0.0], [0.0, 0.0])]))
    time.sleep(0.5)
    plant.trajectory.publish(_trajectory([(0.5, q0, [0.0, 0.0])]))
    result = _wait(plant, holder)
    assert result.error_code == FollowJointTrajectory.Result.INVALID_GOAL, plant.node.tail(30)
    assert 'trajectory topic' in result.error_string


def _outcomes_of(plant, action_name):
    from toc_ros.execution import Tolerances, TrajectoryExecutor
    outcomes, arrived = [], threading.Condition()

    def record(outcome):
        with arrived:
            outcomes.append(outcome)
            arrived.notify_all()

    executor = TrajectoryExecutor(plant.client.node, plant.client.name(action_name),
                                  Tolerances(goal_position=0.01, goal_time=3.0), record)

    def wait(kinds, timeout=RESULT_TIMEOUT):
        """Wait until the outcomes' (goal id, kind) pairs include every one of kinds."""
        with arrived:
            arrived.wait_for(lambda: set(kinds) <= {(o.goal_id, o.kind) for o in outcomes},
                             timeout)
            return list(outcomes)
    return executor, outcomes, wait


@needs_control_msgs
def test_executor_reports_preemption_success_and_invalid_joints(plant):
    from toc_ros import execution as ex
    executor, outcomes, wait = _outcomes_of(plant, 'plant_node/follow_joint_trajectory')
    try:
        assert executor.wait_for_server(30.0)
        q0 = _current(plant)
        first = _trajectory(_smooth(q0, np.array([0.2, 0.1]), 0.0, 2.0, np.arange(21) * 0.1))
        assert executor.send(first) == 1
        time.sleep(0.5)
        second = _trajectory(_smooth(_current(plant), np.array([-0.1, 0.05]), 0.0, 1.0,
                                     np.arange(11) * 0.1))
        assert executor.send(second) == 2
        seen = wait({(1, ex.PREEMPTED), (2, ex.SUCCEEDED)})
        kinds = [(o.goal_id, o.kind) for o in seen]
        assert (1, ex.PREEMPTED) in kinds and (2, ex.SUCCEEDED) in kinds, \
            f'{[o.describe() for o in seen]}\n{plant.node.tail(20)}'
        assert not any(o.failed for o in seen)
        np.testing.assert_allclose(_current(plant), second.points[-1].positions, atol=0.01)
        wrong = _trajectory([(0.5, _current(plant), [0.0, 0.0])], ['rotation_joint', 'x'])
        assert executor.send(wrong) == 3
        seen = wait({(3, ex.ABORTED)})
        last = [o for o in seen if o.goal_id == 3][-1]
        assert last.failed and last.code == FollowJointTrajectory.Result.INVALID_JOINTS, \
            last.describe()
    finally:
        executor.destroy()


@needs_control_msgs
def test_an_empty_trajectory_cancels_the_running_goal(plant):
    """A stop without a braking plan: JTC rejects an empty goal, so the executor cancels."""
    from toc_ros import execution as ex
    executor, outcomes, wait = _outcomes_of(plant, 'plant_node/follow_joint_trajectory')
    try:
        assert executor.wait_for_server(30.0)
        q0 = _current(plant)
        target = q0 + np.array([0.6, 0.3])
        long = _trajectory(_smooth(q0, target - q0, 0.0, 4.0, np.arange(41) * 0.1))
        assert executor.send(long) == 1
        time.sleep(0.8)
        assert executor.send(JointTrajectory(joint_names=JOINTS)) == 2
        seen = wait({(1, ex.CANCELED)})
        assert (1, ex.CANCELED) in [(o.goal_id, o.kind) for o in seen], \
            f'{[o.describe() for o in seen]}\n{plant.node.tail(20)}'
        time.sleep(1.0)
        held = _current(plant)
        time.sleep(1.0)
        # The plant holds where it stopped, far from the goal the trajectory went to.
        np.testing.assert_allclose(_current(plant), held, atol=2e-3)
        assert np.max(np.abs(held - target)) > 0.1
    finally:
        executor.destroy()


@needs_control_msgs
def test_executor_without_a_server_reports_unavailable(plant):
    from toc_ros import execution as ex
    executor, outcomes, _ = _outcomes_of(plant, 'no_such_controller/follow_joint_trajectory')
    try:
        executor.send(_trajectory([(0.5, _current(plant), [0.0, 0.0])]))
        plant.client.wait_for(lambda: outcomes, timeout=3 * executor.SERVER_WAIT_S,
                              what='the outcome')
        assert [(o.goal_id, o.kind) for o in outcomes] == [(1, ex.UNAVAILABLE)]
        assert outcomes[0].failed and 'no action server' in outcomes[0].text
    finally:
        executor.destroy()


@needs_control_msgs
def test_solver_node_executes_its_plan_through_the_action(plant, tmp_path):
    """execute.follow_joint_trajectory: the plan goes to the plant as a goal and succeeds."""
    from diagnostic_msgs.msg import DiagnosticStatus
    from node_harness import report
    from toc_ros import progress as schema
    from toc_ros.harness import node_command
    client = plant.client
    # The solver's trajectory topic is remapped away: the plant hears the plan only as a goal.
    argv = node_command('solver_node', CONFIG, {
        'solver.N': 100, 'replan.rate': 0.0,
        'execute.follow_joint_trajectory': client.name('plant_node/follow_joint_trajectory'),
        'execute.goal_tolerance': 0.01, 'execute.goal_time_tolerance': 3.0},
        client.namespace, extra=['-r', 'trajectory:=planned_only'])
    solver = NodeProcess('solver_node', client.namespace, tmp_path, argv=argv)
    try:
        solver.wait_for_log('ready:')
        assert 'executing plans through' in solver.log(), solver.tail()
        # A goal sent before discovery waits for the server and may arrive after its plan.
        solver.wait_for_log('found', timeout=30.0)
        client.collect(DiagnosticStatus, 'solver_node/progress', keep=1000)
        goals = client.node.create_publisher(JointState, client.name('goal_joints'), 10)
        client.wait_for(lambda: goals.get_subscription_count() > 0, what='goal_joints')
        # From the plant's initial state (the tests run in any order: another may have left
        # it anywhere, even inside the circle's margin), a turn away from the scenario's circle.
        reset = client.node.create_client(Trigger, client.name('plant_node/reset'))
        assert reset.wait_for_service(timeout_sec=30.0)
        assert client.call(reset, Trigger.Request(), 30.0).success
        home = np.array([0.261799, 1.0])
        client.wait_for(lambda: np.max(np.abs(_current(plant) - home)) < 1e-3, what='reset')
        time.sleep(0.2)     # the solver's latest joint_states is the reset one
        target = home - [0.3, 0.0]
        goals.publish(JointState(name=list(JOINTS), position=[float(v) for v in target]))

        def executed():
            return [r for r in map(report, client.messages('solver_node/progress'))
                    if r.event == schema.EVENT_EXECUTION]
        try:
            client.wait_for(lambda: executed(), what='an execution report', timeout=120.0)
        except Exception:
            texts = [r.message for r in map(report, client.messages('solver_node/progress'))]
            raise AssertionError(f'{texts[-10:]}\n{solver.tail(30)}\n{plant.node.tail(20)}')
        outcome = executed()[-1]
        assert 'succeeded' in outcome.message, outcome.message
        assert outcome.level == DiagnosticStatus.OK
        np.testing.assert_allclose(_current(plant), target, atol=0.01,
                                   err_msg=solver.tail(20))
    finally:
        solver.stop()


@needs_control_msgs
def test_a_position_interface_refuses_goals_with_efforts(plant):
    """command_interface position: JTC's refusal of efforts; a goal without them succeeds."""
    from toc_ros.plant.jtc_trajectory import EFFORT_REFUSED
    results = plant.client.set_parameters('plant_node', {'command_interface': 'position'})
    assert all(r.successful for r in results), [r.reason for r in results]
    try:
        q0 = _current(plant)
        target = q0 + np.array([0.1, 0.05])
        with_effort = _trajectory([(1.0, target, [0.0, 0.0])])
        with_effort.points[0].effort = [0.0, 0.0]
        result = _wait(plant, _send(plant, with_effort))
        assert result.error_code == FollowJointTrajectory.Result.INVALID_GOAL
        assert result.error_string == EFFORT_REFUSED
        result = _wait(plant, _send(plant, _trajectory([(1.0, target, [0.0, 0.0])])))
        assert result.error_code == FollowJointTrajectory.Result.SUCCESSFUL, result.error_string
        np.testing.assert_allclose(_current(plant), target, atol=0.01,
                                   err_msg=plant.node.tail(20))
    finally:
        results = plant.client.set_parameters('plant_node', {'command_interface': 'effort'})
        assert all(r.successful for r in results), [r.reason for r in results]
