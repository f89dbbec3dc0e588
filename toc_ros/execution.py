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
Executing plans through ros2_control: a control_msgs/action/FollowJointTrajectory client.

What MoveIt does to execute: every plan (and every replan cycle's plan) is sent as a goal to a
JointTrajectoryController's action, with the trajectory's header.stamp as its start time.  A
newer goal preempts the older one at the controller (which aborts it with "Current goal
preempted by new incoming action."): that is the normal course of replanning, reported as
``preempted``, not as a failure.  Every other end of the newest goal is an Outcome that the
node reports on ``~/progress``; a rejected or aborted goal is a failed execution, which the node
treats like a failed plan.

Goals carry the planned torques as efforts only with ``effort`` (execute.effort): JTC rejects
goals with efforts unless it commands an effort interface, and then feeds them forward.  A plan
from rest is stamped start_lead ahead, and a JointTrajectoryController interpolates from
the state it commanded last to the first point from the goal's arrival on, the effort too: the
plan's first torque would fade in while its positions still rest, and a controller that feeds
the effort forward would move the arm ahead of its reference.  Such a goal is led in by a point
that holds the start with the holding torque until HOLD_LEAD_S before the plan (``held_start``).
A goal stamped ahead of now (a replan cycle's lead, a goal's goal_lead) also carries the
previous goal's points from now to its start (``continued``): JTC would otherwise bridge that
time with one cubic from the state it commanded to the new first point.  A stop without a
braking plan (an empty trajectory) cancels our goals: JTC rejects an empty goal and would go
on with the running one.

control_msgs is not a wheel: it is imported lazily (``follow_joint_trajectory_action``), and
without it execution through the action is refused with that reason.
"""

from dataclasses import dataclass
import threading
from typing import Callable, Optional

from toc_ros.conversions import duration_of_ns, nanoseconds, time_of_ns

# control_msgs/action/FollowJointTrajectory result codes (control_msgs 5.8.0).
ERROR_NAMES = {0: 'SUCCESSFUL', -1: 'INVALID_GOAL', -2: 'INVALID_JOINTS',
               -3: 'OLD_HEADER_TIMESTAMP', -4: 'PATH_TOLERANCE_VIOLATED',
               -5: 'GOAL_TOLERANCE_VIOLATED'}
PREEMPTED_TEXT = 'Current goal preempted by new incoming action.'
# The hold point of a goal from rest comes this long [s] before the plan's first point: the
# first torque takes over within about one control period.
HOLD_LEAD_S = 0.001

# Outcome kinds.
ACCEPTED = 'accepted'
SUCCEEDED = 'succeeded'
PREEMPTED = 'preempted'          # replaced by a newer goal of ours: the normal replan course
CANCELED = 'canceled'
REJECTED = 'rejected'            # the server refused the goal (JTC: invalid joints, old stamp)
ABORTED = 'aborted'              # the server ended it with an error code
UNAVAILABLE = 'unavailable'      # no server answered in time
FAILED = (REJECTED, ABORTED, UNAVAILABLE)
# action_msgs/msg/GoalStatus values of a finished goal.
GOAL_SUCCEEDED = 4
GOAL_CANCELED = 5
GOAL_ABORTED = 6


def follow_joint_trajectory_action():
    """Return (the FollowJointTrajectory action type, None), or (None, why it is missing)."""
    try:
        from control_msgs.action import FollowJointTrajectory
    except ImportError as exc:
        return None, (f'control_msgs is not installed ({exc}); a ROS install has it '
                      '(ros-jazzy-control-msgs)')
    # The Python package can be there while its C type support does not load (e.g. a library
    # path of another ROS environment): say so instead of failing when the action is created.
    from rclpy.type_support import check_for_type_support
    try:
        check_for_type_support(FollowJointTrajectory)
    except Exception as exc:   # noqa: B902 - UnsupportedTypeSupport, ImportError, ...
        return None, (f'control_msgs is installed but its type support does not load '
                      f'({type(exc).__name__}: {exc}); source the ROS environment it was built in')
    return FollowJointTrajectory, None


@dataclass(frozen=True)
class Tolerances:
    """Goal tolerances sent with every goal (0: the controller's own default)."""

    path_position: float = 0.0     # [rad or m] per joint, while the trajectory runs
    goal_position: float = 0.0     # [rad or m] per joint, at the end
    goal_time: float = 0.0         # [s] allowed after the end to get within goal_position


@dataclass(frozen=True)
class Outcome:
    """What became of one goal."""

    kind: str
    goal_id: int                   # our counter of sent goals (1, 2, ...)
    code: Optional[int] = None     # FollowJointTrajectory result error_code, when there is one
    text: str = ''

    @property
    def failed(self):
        """Tell whether the execution failed: the node then stops or replans."""
        return self.kind in FAILED

    def describe(self):
        """Return a one-line description for logs and ~/progress."""
        code = '' if self.code is None else \
            f' error_code {self.code} {ERROR_NAMES.get(self.code, "UNKNOWN")}'
        return f'FollowJointTrajectory goal {self.goal_id} {self.kind}{code}' + \
            (f': {self.text}' if self.text else '')


def classify_result(goal_id, newest_id, goal_status, code, text):
    """
    Return the Outcome of a goal's result.

    goal_status: the action_msgs GoalStatus of the finished goal (GOAL_*).  A goal that is not
    the newest and was aborted as preempted (or for any reason after a newer one was sent) is
    PREEMPTED: a newer plan took over.
    """
    if goal_status == GOAL_SUCCEEDED and code in (0, None):
        return Outcome(SUCCEEDED, goal_id, 0, text)
    if goal_status == GOAL_CANCELED:
        return Outcome(CANCELED, goal_id, code, text)
    if goal_id != newest_id or text == PREEMPTED_TEXT:
        return Outcome(PREEMPTED, goal_id, code, text)
    return Outcome(ABORTED, goal_id, code, text)


def _retimed(point, ns, effort=True):
    """Return a copy of a JointTrajectoryPoint at time_from_start ns (without its efforts)."""
    from trajectory_msgs.msg import JointTrajectoryPoint
    return JointTrajectoryPoint(
        positions=point.positions, velocities=point.velocities,
        accelerations=point.accelerations, effort=point.effort if effort else [],
        time_from_start=duration_of_ns(ns))


def _trajectory(like, stamp_ns, points):
    """Return a JointTrajectory with the joints and frame of like, stamped stamp_ns."""
    from trajectory_msgs.msg import JointTrajectory
    msg = JointTrajectory(joint_names=list(like.joint_names), points=points)
    msg.header.frame_id = like.header.frame_id
    msg.header.stamp = time_of_ns(stamp_ns)
    return msg


def held_start(trajectory, effort, hold_s=HOLD_LEAD_S):
    """
    Return a trajectory that holds its first positions, at rest with effort, until it starts.

    The copy has a point (the first positions, zero velocities and accelerations where the
    points have them, effort) at time_from_start 0, and the trajectory's points hold_s later;
    its stamp is hold_s earlier, so that every point of the plan keeps its time (a zero
    stamp, "on arrival", stays zero).
    """
    from trajectory_msgs.msg import JointTrajectoryPoint
    hold_ns = int(round(hold_s * 1e9))
    first = trajectory.points[0]
    n = len(first.positions)
    hold = JointTrajectoryPoint(
        positions=list(first.positions), velocities=[0.0] * n if len(first.velocities) else [],
        accelerations=[0.0] * n if len(first.accelerations) else [],
        effort=[float(e) for e in effort])
    start_ns = nanoseconds(trajectory.header.stamp)
    return _trajectory(trajectory, max(start_ns - hold_ns, 1) if start_ns else 0, [hold] + [
        _retimed(p, nanoseconds(p.time_from_start) + hold_ns) for p in trajectory.points])


def without_effort(trajectory):
    """Return a copy of a JointTrajectory whose points have no efforts."""
    return _trajectory(trajectory, nanoseconds(trajectory.header.stamp), [
        _retimed(p, nanoseconds(p.time_from_start), effort=False) for p in trajectory.points])


def continued(previous, trajectory, now_ns):
    """
    Return trajectory preceded by the points of previous still to come before it starts.

    A JointTrajectoryController takes a goal at once and, until its first point, interpolates
    from the state it commanded to that point (one cubic, the effort a ramp): a plan stamped
    ahead of now (a cycle's lead, a goal's goal_lead) would replace the motion still to be made
    on the previous goal by that bridge.  So the goal also carries the previous goal's points
    from the one at or before now_ns up to its start, and is stamped at that point: the
    controller goes on along the previous motion and reaches the plan at its stamp.  previous
    and trajectory are goal trajectories (stamped, same joints and fields); trajectory as it
    is when nothing of previous is left before its start.
    """
    if previous is None or not previous.points or not trajectory.points \
            or list(previous.joint_names) != list(trajectory.joint_names):
        return trajectory
    old_ns, new_ns = nanoseconds(previous.header.stamp), nanoseconds(trajectory.header.stamp)
    if old_ns == 0 or new_ns <= now_ns:
        return trajectory
    times = [old_ns + nanoseconds(p.time_from_start) for p in previous.points]
    first = max((k for k, t in enumerate(times) if t <= now_ns), default=0)
    kept = [k for k in range(first, len(times)) if times[k] < new_ns]
    if not kept or times[kept[-1]] <= now_ns:
        return trajectory       # previous is over by now (or starts after trajectory)
    start = times[kept[0]]
    return _trajectory(trajectory, start, [
        _retimed(previous.points[k], times[k] - start) for k in kept] + [
        _retimed(p, new_ns + nanoseconds(p.time_from_start) - start) for p in trajectory.points])


def goal_trajectory(trajectory, effort, hold_effort=None):
    """
    Return the trajectory a goal carries for a published one.

    effort: whether goals carry efforts (else a copy without them); hold_effort: the holding
    torques of a plan from rest (then, with efforts, ``held_start``), or None.
    """
    if not effort:
        return without_effort(trajectory)
    if hold_effort is not None:
        return held_start(trajectory, hold_effort)
    return trajectory


def build_goal(action_type, trajectory, tolerances: Tolerances):
    """Return the FollowJointTrajectory goal of a trajectory_msgs/JointTrajectory message."""
    from control_msgs.msg import JointTolerance
    joint_names = list(trajectory.joint_names)
    goal = action_type.Goal()
    goal.trajectory = trajectory
    if tolerances.path_position > 0.0:
        goal.path_tolerance = [JointTolerance(name=name, position=tolerances.path_position)
                               for name in joint_names]
    if tolerances.goal_position > 0.0:
        goal.goal_tolerance = [JointTolerance(name=name, position=tolerances.goal_position)
                               for name in joint_names]
    ns = int(round(tolerances.goal_time * 1e9))
    goal.goal_time_tolerance = duration_of_ns(ns)
    return goal


class TrajectoryExecutor:
    """
    Send plans as FollowJointTrajectory goals; report every goal's Outcome through a callback.

    on_outcome(Outcome) is called from the node's executor thread (or a waiting thread).
    send() never blocks: when the server is not (yet) discovered, the goal waits for it in the
    background for SERVER_WAIT_S, then its outcome is UNAVAILABLE.
    """

    SERVER_WAIT_S = 2.0

    def __init__(self, node, action_name, tolerances: Tolerances,
                 on_outcome: Callable[[Outcome], None], action_type=None, effort=False):
        from rclpy.action import ActionClient
        if action_type is None:
            action_type, reason = follow_joint_trajectory_action()
            if action_type is None:
                raise RuntimeError(reason)
        self._action_type = action_type
        self._node = node
        self._client = ActionClient(node, action_type, action_name)
        self._action_name = action_name
        self._tolerances = tolerances
        self._effort = bool(effort)     # goals carry the efforts (else their fields are empty)
        self._on_outcome = on_outcome
        self._lock = threading.Lock()
        self._sent = 0
        self._previous = None       # the newest goal's trajectory (None: none runs)
        self._cancel_below = 0      # goals older than the last stop are canceled on acceptance
        self._handles = {}          # goal id -> accepted goal handle, until its result
        self._destroyed = False

    @property
    def action_name(self):
        """Return the action's name as resolved by the client."""
        return self._action_name

    @property
    def newest(self):
        """Return the id of the newest goal sent (0: none)."""
        return self._sent

    def wait_for_server(self, timeout):
        """Wait up to timeout [s] for the action server; tell whether it is there."""
        return self._client.wait_for_server(timeout_sec=timeout)

    def send(self, trajectory, hold_effort=None):
        """
        Send a trajectory as the newest goal; return its goal id (never blocks).

        hold_effort: for a trajectory from rest, the torques that hold its start (sent
        ``held_start`` when the goals carry efforts), or None.  An empty trajectory (a stop
        without a braking plan) is no goal: JTC rejects it and goes on with the running goal.
        It cancels our goals instead, running or still on their way (JTC then holds the robot
        where it is).
        """
        sent = goal_trajectory(trajectory, self._effort, hold_effort)
        now_ns = self._node.get_clock().now().nanoseconds
        with self._lock:
            self._sent += 1
            goal_id = self._sent
            if not trajectory.points:
                self._cancel_below = goal_id
                self._previous = None
            else:
                sent = continued(self._previous, sent, now_ns)
                self._previous = sent
        if not trajectory.points:
            self.cancel()
            return goal_id
        goal = build_goal(self._action_type, sent, self._tolerances)
        if self._client.server_is_ready():
            self._send(goal_id, goal)
        else:
            # Discovery may still be under way (a node just started): wait for the server in
            # the background; a newer goal meanwhile takes this one's place.
            threading.Thread(target=self._send_when_ready, args=(goal_id, goal),
                             name='fjt_wait', daemon=True).start()
        return goal_id

    def _send(self, goal_id, goal):
        future = self._client.send_goal_async(goal)
        future.add_done_callback(lambda done: self._on_response(goal_id, done))

    def _send_when_ready(self, goal_id, goal):
        ready = self._client.wait_for_server(timeout_sec=self.SERVER_WAIT_S)
        if goal_id != self.newest:
            self._deliver(Outcome(PREEMPTED, goal_id, text='a newer goal was sent first'))
        elif ready:
            self._send(goal_id, goal)
        else:
            self._deliver(Outcome(UNAVAILABLE, goal_id, text=f'no action server '
                                  f'{self.action_name} within {self.SERVER_WAIT_S:g} s'))

    def cancel(self):
        """Ask the server to cancel every goal of ours that is still running."""
        with self._lock:
            handles = list(self._handles.values())
        for handle in handles:
            handle.cancel_goal_async()

    def watch_server(self, on_found):
        """Call on_found() once the action server is discovered (from a background thread)."""
        def watch():
            while not self._destroyed:
                if self._client.wait_for_server(timeout_sec=1.0):
                    if not self._destroyed:
                        on_found()
                    return
        threading.Thread(target=watch, name='fjt_watch', daemon=True).start()

    def destroy(self):
        """Destroy the action client."""
        self._destroyed = True
        self._client.destroy()

    def _deliver(self, outcome):
        """Pass an outcome on; the newest goal's failure or cancel leaves nothing running."""
        if outcome.failed or outcome.kind == CANCELED:
            with self._lock:
                if outcome.goal_id == self._sent:
                    self._previous = None       # the controller holds the robot
        self._on_outcome(outcome)

    def _on_response(self, goal_id, future):
        try:
            handle = future.result()
        except Exception as exc:   # noqa: B902 - a transport error is an outcome, not a crash
            self._deliver(Outcome(REJECTED, goal_id, text=f'no goal response: {exc}'))
            return
        if not handle.accepted:
            self._deliver(Outcome(REJECTED, goal_id, text='the server rejected the goal'))
            return
        with self._lock:
            self._handles[goal_id] = handle
            stopped = goal_id < self._cancel_below
        self._deliver(Outcome(ACCEPTED, goal_id))
        if stopped:
            handle.cancel_goal_async()
        handle.get_result_async().add_done_callback(
            lambda done: self._on_result(goal_id, done))

    def _on_result(self, goal_id, future):
        with self._lock:
            self._handles.pop(goal_id, None)
        try:
            response = future.result()
        except Exception as exc:   # noqa: B902
            self._deliver(Outcome(ABORTED, goal_id, text=f'no result: {exc}'))
            return
        result = response.result
        self._deliver(classify_result(goal_id, self.newest, response.status,
                                      result.error_code, result.error_string))
