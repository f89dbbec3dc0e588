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
solver_node: minimum-time trajectories of the 2-DOF cylindrical robot on request.

Goals arrive on ``goal_pose`` (hand position, inverse kinematics), ``goal_joints`` (joint
space, by name) or the blocking service ``~/plan`` (nav_msgs/GetPlan).  Each plan starts from
the latest ``joint_states`` (parameter ``initial_state`` until one arrived) and avoids the
current obstacles (parameters ``obstacles.*``, replaced by messages on ``obstacles``).

One worker thread solves; a new goal preempts the running solve (cancel, then start the new
one), ``~/cancel`` stops it.  While it solves, ``~/progress`` reports at >= 5 Hz, and once at
the end with the status: level OK for SOLVED, WARN for SOLVED_INACCURATE (paper mode's
heuristic, trajectory published anyway), CANCELED and TIMEOUT, ERROR for failures and refused
input (message = the reason).  ``trajectory`` (transient local) is published for SOLVED and
SOLVED_INACCURATE results only, together with ``planned_path`` and ``markers``.

Run: ``ros2 run toc_ros solver_node --ros-args --params-file config/toc_ros.yaml``
"""

import dataclasses
import math
import sys
import threading
import time

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path
from nav_msgs.srv import GetPlan
import numpy as np
import rclpy
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger
from toc_ros import conversions
from toc_ros.config import obstacle_rows, options_from_parameters, problem_from_parameters
from toc_ros.core import ProblemError, Progress, solve, Status, warm_up
from toc_ros.nodes import parameters
from toc_ros.nodes.common import run_node
from trajectory_msgs.msg import JointTrajectory
from visualization_msgs.msg import MarkerArray

PARAMETER_NAMES = parameters.SOLVER_NODE_NAMES
PUBLISHED = (Status.SOLVED, Status.SOLVED_INACCURATE)
# ~/progress while solving: the core reports every 0.1 s; the heartbeat fills gaps (set-up,
# slow iterations) so that no gap exceeds MAX_PROGRESS_GAP_S.
HEARTBEAT_PERIOD_S = 0.05
MAX_PROGRESS_GAP_S = 0.15
MARKER_PERIOD_S = 0.2
ARM_REDRAW = 1e-3     # [rad, m, rad/s, m/s] state change that redraws the arm marker
# How long ~/cancel waits for the solve to stop (the core stops within ~0.1 s).
CANCEL_WAIT_S = 2.0


class ParameterError(ValueError):
    """Invalid parameters at start-up (before the on-set callback guards changes)."""


def parameter_errors(params):
    """
    Everything wrong with a candidate set of solver_node parameters (empty: valid).

    Whether start and goal states clear the obstacles is checked per request, against the
    measured start state, not here.
    """
    errors = parameters.joint_name_errors(params['joint_names'])
    if not str(params['base_frame']).strip('/'):
        errors.append('base_frame must not be empty')
    limit_errors = parameters.vector_errors('extension_limits', params['extension_limits'], 2)
    if not limit_errors and not params['extension_limits'][0] < params['extension_limits'][1]:
        limit_errors = [f'extension_limits must be [q2_min, q2_max] with q2_min < q2_max, got '
                        f'{params["extension_limits"]}']
    errors += limit_errors
    state_errors = (parameters.vector_errors('initial_state', params['initial_state'], 4)
                    + parameters.vector_errors('goal_state', params['goal_state'], 4))
    errors += state_errors
    try:
        options_from_parameters(params).validate()
    except (ProblemError, TypeError, ValueError) as exc:
        errors.append(str(exc))
    if not state_errors:    # else the Problem would repeat them as x0 / x_goal errors
        try:
            # The one check of the problem data, obstacles included (start and goal against
            # the obstacles are checked per request, against the measured start).
            problem_from_parameters(params).validate(states=False)
        except (ProblemError, TypeError, ValueError) as exc:
            errors.append(str(exc))
    return errors


class _Request:
    """One goal on its way through the worker."""

    def __init__(self, goal, source):
        self.goal = np.asarray(goal, dtype=float)
        self.source = source
        self.stop_reason = None          # set when preempted or canceled
        self.result = None               # SolveResult once solved (None when dropped)
        self.path = None                 # nav_msgs/Path when a trajectory was published
        self.done = threading.Event()


class _Worker:
    """A thread solving one request at a time; the newest request preempts older ones."""

    def __init__(self, run, drop, logger):
        self._run = run          # run(request, cancel_event): solve and publish
        self._drop = drop        # drop(request, reason): report a request never started
        self._logger = logger
        self._cond = threading.Condition()
        self._pending = None
        self._active = None
        self._cancel = None
        self._stopping = False
        self._thread = threading.Thread(target=self._loop, name='solver', daemon=True)
        self._thread.start()

    def submit(self, request):
        """Queue request, dropping a queued one and canceling the running one."""
        with self._cond:
            dropped, self._pending = self._pending, request
            if self._active is not None:
                self._active.stop_reason = 'preempted by a newer goal'
                self._cancel.set()
            self._cond.notify()
        if dropped is not None:
            self._drop(dropped, 'superseded by a newer goal before its solve started')

    def cancel(self):
        """Stop the running solve and drop a queued one; True when a solve was stopped."""
        with self._cond:
            dropped, self._pending = self._pending, None
            active = self._active
            if active is not None:
                active.stop_reason = 'canceled by ~/cancel'
                self._cancel.set()
        if dropped is not None:
            self._drop(dropped, 'canceled by ~/cancel before its solve started')
        return active is not None and active.done.wait(CANCEL_WAIT_S)

    def busy(self):
        """Tell whether a request is queued or solving."""
        with self._cond:
            return self._active is not None or self._pending is not None

    def stop(self):
        """Cancel everything and end the thread."""
        with self._cond:
            self._stopping = True
            if self._cancel is not None:
                self._cancel.set()
            dropped, self._pending = self._pending, None
            self._cond.notify()
        if dropped is not None:
            dropped.done.set()
        self._thread.join(timeout=CANCEL_WAIT_S)

    def _loop(self):
        while True:
            with self._cond:
                while self._pending is None and not self._stopping:
                    self._cond.wait()
                if self._stopping:
                    return
                request, self._pending = self._pending, None
                self._active, self._cancel = request, threading.Event()
                cancel = self._cancel
            try:
                self._run(request, cancel)
            except Exception as exc:  # noqa: B902 - a bug must not end the worker thread
                self._logger.error(f'solve of goal from {request.source} failed: {exc!r}')
            finally:
                with self._cond:
                    self._active = None
                request.done.set()


class SolverNode(Node):
    """Plans minimum-time trajectories on goals; see the module docstring."""

    def __init__(self, **kwargs):
        super().__init__('solver_node', **kwargs)
        parameters.declare(self, PARAMETER_NAMES)
        self._params = parameters.values(self, PARAMETER_NAMES)
        errors = parameter_errors(self._params)
        if errors:
            raise ParameterError('; '.join(errors))
        self._lock = threading.Lock()       # guards the fields below, shared with the worker
        self._measured = None               # latest state from joint_states
        self._arm_dirty = True
        self._arm_drawn = None              # state drawn by the last markers
        self._path_states = None            # states of the last published plan
        self._progress = None               # (Progress, solve start) of the running solve
        self._progress_sent = 0.0
        self._publish_lock = threading.Lock()
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._after_set_parameters)

        started = time.monotonic()
        warm_up()  # compile or load the numba kernels before the first goal can arrive
        self.get_logger().info(f'numba kernels loaded in {time.monotonic() - started:.2f} s')

        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                             reliability=ReliabilityPolicy.RELIABLE)
        self._trajectory_pub = self.create_publisher(JointTrajectory, 'trajectory', latched)
        self._path_pub = self.create_publisher(Path, 'planned_path', 10)
        self._marker_pub = self.create_publisher(MarkerArray, 'markers', latched)
        self._progress_pub = self.create_publisher(DiagnosticStatus, '~/progress', 50)
        self.create_subscription(PoseStamped, 'goal_pose', self._on_goal_pose, 10)
        self.create_subscription(JointState, 'goal_joints', self._on_goal_joints, 10)
        self.create_subscription(Float64MultiArray, 'obstacles', self._on_obstacles, 10)
        self.create_subscription(JointState, 'joint_states', self._on_joint_states, 10)
        # ~/plan blocks until its solve ends, so it must not share a group with anything that
        # has to run meanwhile; reentrant so that a second plan can preempt the first.
        self.create_service(GetPlan, '~/plan', self._on_plan,
                            callback_group=ReentrantCallbackGroup())
        self.create_service(Trigger, '~/cancel', self._on_cancel,
                            callback_group=MutuallyExclusiveCallbackGroup())
        timers = MutuallyExclusiveCallbackGroup()
        self.create_timer(HEARTBEAT_PERIOD_S, self._heartbeat, callback_group=timers)
        self.create_timer(MARKER_PERIOD_S, self._publish_markers_if_dirty,
                          callback_group=timers)
        self._worker = _Worker(self._run, self._drop, self.get_logger())
        self._publish_markers()
        self.get_logger().info(
            f"ready: {len(self._params['obstacles.x'])} obstacle(s), mode "
            f"{self._params['solver.mode']}, N = {self._params['solver.N']}")

    # -- parameters ---------------------------------------------------------------------------

    def _on_set_parameters(self, changed):
        with self._lock:
            params = parameters.candidate(self._params, changed)
        result = parameters.result(parameter_errors(params))
        if not result.successful:
            self.get_logger().warning(f'refused parameter change: {result.reason}')
        return result

    def _after_set_parameters(self, changed):
        with self._lock:
            self._params = parameters.candidate(self._params, changed)
            self._arm_dirty = True   # obstacles or frames may have changed

    def _snapshot(self):
        with self._lock:
            return dict(self._params), (None if self._measured is None
                                        else self._measured.copy())

    # -- inputs -------------------------------------------------------------------------------

    def _on_joint_states(self, msg):
        with self._lock:
            names = self._params['joint_names']
        try:
            state = conversions.joint_state_to_state(msg, names)
        except conversions.ConversionError as exc:
            self.get_logger().warning(f'ignoring joint_states: {exc}', throttle_duration_sec=5.0)
            return
        with self._lock:
            self._measured = state
            # Redraw the arm when it moved visibly, not for every message of a resting robot.
            if self._arm_drawn is None or np.max(np.abs(state - self._arm_drawn)) > ARM_REDRAW:
                self._arm_dirty = True

    def _on_goal_pose(self, msg):
        self._submit(lambda params: conversions.pose_to_joint_goal(
            msg, params['base_frame'], float(params['robot.a']),
            tuple(params['extension_limits'])), 'goal_pose')

    def _on_goal_joints(self, msg):
        self._submit(lambda params: conversions.joint_state_to_state(
            msg, params['joint_names']), 'goal_joints')

    def _on_obstacles(self, msg):
        try:
            rows = conversions.obstacle_rows_from_msg(msg)
        except conversions.ConversionError as exc:
            self._refuse('obstacles', str(exc))
            return
        outcome = self.set_parameters_atomically([
            Parameter(f'obstacles.{key}', Parameter.Type.DOUBLE_ARRAY, [row[i] for row in rows])
            for i, key in enumerate(('x', 'y', 'radius'))])
        if not outcome.successful:
            self._refuse('obstacles', outcome.reason)
        else:
            self.get_logger().info(f'obstacles replaced: {len(rows)} circle(s)')

    def _on_plan(self, request, response):
        response.plan.header.frame_id = self._snapshot()[0]['base_frame']
        response.plan.header.stamp = self.get_clock().now().to_msg()
        pending = self._submit(lambda params: conversions.pose_to_joint_goal(
            request.goal, params['base_frame'], float(params['robot.a']),
            tuple(params['extension_limits'])), '~/plan')
        if pending is None:
            return response
        while not pending.done.wait(0.5):
            if not rclpy.ok(context=self.context):
                return response
        if pending.path is not None:
            response.plan = pending.path
        return response

    def _on_cancel(self, _request, response):
        started = time.monotonic()
        response.success = self._worker.cancel()
        response.message = (f'solve stopped in {time.monotonic() - started:.4f} s'
                            if response.success else 'no solve was running')
        return response

    def _start_state(self, params, measured):
        if measured is not None:
            return measured, 'joint_states'
        return np.asarray(params['initial_state'], dtype=float), 'initial_state'

    def _submit(self, make_goal, source):
        """Check a goal against the current start state and obstacles, then queue it."""
        params, measured = self._snapshot()
        start, start_source = self._start_state(params, measured)
        try:
            goal = make_goal(params)
            low, high = params['extension_limits']
            if not low <= goal[2] <= high:
                raise conversions.ConversionError(
                    f'goal extension q2 = {goal[2]:.6g} m is outside extension_limits '
                    f'[{low:.6g}, {high:.6g}] m')
            problem_from_parameters(params, x0=start, x_goal=goal).validate()
        except conversions.ConversionError as exc:
            self._refuse(source, str(exc))
            return None
        except ProblemError as exc:
            self._refuse(source, f'{exc} (start state from {start_source}: '
                                 f'{np.round(start, 6).tolist()})')
            return None
        request = _Request(goal, source)
        self.get_logger().info(f'goal from {source}: {np.round(goal, 6).tolist()}')
        self._worker.submit(request)
        return request

    def _refuse(self, source, reason):
        self.get_logger().error(f'refused {source}: {reason}')
        self._publish_progress(conversions.error_msg(self.get_fully_qualified_name(),
                                                     f'{source}: {reason}'))

    # -- solving (worker thread) --------------------------------------------------------------

    def _publish_progress(self, msg):
        with self._publish_lock:
            self._progress_pub.publish(msg)
            self._progress_sent = time.monotonic()

    def _on_progress(self, progress):
        if progress.phase == 'done':   # the result message follows
            return
        with self._lock:
            if self._progress is None:
                return
            self._progress = (progress, self._progress[1])
        self._publish_progress(conversions.progress_msg(self.get_fully_qualified_name(),
                                                        progress))

    def _heartbeat(self):
        with self._lock:
            current = self._progress
        if current is None or time.monotonic() - self._progress_sent < MAX_PROGRESS_GAP_S:
            return
        progress, started = current
        progress = dataclasses.replace(progress, elapsed_s=time.monotonic() - started)
        self._publish_progress(conversions.progress_msg(self.get_fully_qualified_name(),
                                                        progress))

    def _drop(self, request, reason):
        self.get_logger().warning(f'goal from {request.source} {reason}')
        self._publish_progress(conversions.diagnostic_msg(
            self.get_fully_qualified_name(), DiagnosticStatus.WARN,
            f'goal from {request.source} {reason}', {'status': Status.CANCELED.value}))
        request.done.set()

    def _run(self, request, cancel):
        params, measured = self._snapshot()
        start, start_source = self._start_state(params, measured)
        name = self.get_fully_qualified_name()
        try:
            problem = problem_from_parameters(params, x0=start, x_goal=request.goal)
            options = options_from_parameters(params)
        except (ProblemError, TypeError, ValueError) as exc:   # parameters are validated
            self._refuse(request.source, str(exc))
            return
        with self._lock:
            self._progress = (Progress(0, problem.t_f0, math.nan, math.nan, 0.0, 'start'),
                              time.monotonic())
            progress = self._progress[0]
        self._publish_progress(conversions.progress_msg(name, progress))
        try:
            result = solve(problem, options, progress=self._on_progress, cancel=cancel)
        except Exception as exc:  # noqa: B902 - a core bug must not kill the worker thread
            self.get_logger().error(f'solver failed: {exc!r}')
            self._publish_progress(conversions.error_msg(name, f'internal solver error: {exc!r}',
                                                         'ERROR'))
            return
        finally:
            with self._lock:
                self._progress = None
        request.result = result
        message = result.message
        if result.status is Status.CANCELED and request.stop_reason:
            message = f'{request.stop_reason} ({result.message})'
        if result.status is Status.INVALID_INPUT:
            message = f'{message} (start state from {start_source})'
        extra = {'goal_source': request.source, 'start_source': start_source,
                 'goal': str(np.round(request.goal, 9).tolist())}
        if result.status in PUBLISHED and result.has_trajectory:
            self._publish_plan(request, result, problem, params)
        report = (f'{result.status.value} for goal from {request.source}: {message} '
                  f'({result.iterations} iterations, {result.wall_time_s:.3f} s)')
        # One call site per severity: rclpy refuses to change it between calls of a site.
        level = conversions.LEVELS[result.status]
        if level == DiagnosticStatus.OK:
            self.get_logger().info(report)
        elif level == DiagnosticStatus.WARN:
            self.get_logger().warning(report)
        else:
            self.get_logger().error(report)
        self._publish_progress(conversions.result_msg(name, result, message, extra))

    def _publish_plan(self, request, result, problem, params):
        stamp = self.get_clock().now().to_msg()
        self._trajectory_pub.publish(conversions.trajectory_msg(
            result, params['joint_names'], problem.robot, stamp))
        request.path = conversions.hand_path_msg(result.states, problem.robot.a,
                                                 params['base_frame'], stamp)
        self._path_pub.publish(request.path)
        with self._lock:
            self._path_states = result.states
        self._publish_markers()

    # -- markers ------------------------------------------------------------------------------

    def _publish_markers_if_dirty(self):
        with self._lock:
            dirty = self._arm_dirty
        if dirty:
            self._publish_markers()

    def _publish_markers(self):
        with self._lock:
            params = dict(self._params)
            path_states = self._path_states
            arm = self._measured
            self._arm_dirty = False
            self._arm_drawn = arm
        if arm is None:
            arm = np.asarray(params['initial_state'], dtype=float)
        try:
            rows = obstacle_rows(params)
        except ProblemError:
            rows = ()
        self._marker_pub.publish(conversions.markers_msg(
            rows, float(params['obstacles.margin']), float(params['robot.a']),
            params['base_frame'], self.get_clock().now().to_msg(), path_states, arm))

    def busy(self):
        """Tell whether a goal is queued or being solved."""
        return self._worker.busy()

    def destroy_node(self):
        """Stop the worker (canceling its solve) before the node goes away."""
        if hasattr(self, '_worker'):
            self._worker.stop()
        return super().destroy_node()


def main(args=None):
    """Run solver_node until shutdown; exit code 2 for invalid parameters."""
    return run_node('solver_node', SolverNode, lambda: MultiThreadedExecutor(num_threads=4),
                    args=args, errors=(ParameterError, InvalidParameterValueException,
                                       InvalidParameterTypeException),
                    error_prefix='invalid parameters: ')


if __name__ == '__main__':
    sys.exit(main())
