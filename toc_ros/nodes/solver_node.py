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
space, by name) or the service ``~/plan`` (nav_msgs/GetPlan, answered when its solve ends).
Each plan starts from the latest ``joint_states`` (parameter ``initial_state`` until one
arrived) and avoids the current obstacles (parameters ``obstacles.*``, replaced by messages on
``obstacles``; at most ``obstacles.max_count`` circles).  ``~/plan`` always plans from that
measured state, never from the request's ``start`` (a state the node cannot vouch for): a
``start`` that is given (not the empty pose) and differs from the measured hand position by
more than 1 mm, or is not finite, or is in another frame, is ignored with a warning on
``~/progress`` (event ``start_ignored``) and in the log.  ``~/ready`` (std_srvs/Trigger)
answers success once the numba kernels are loaded.

One worker thread solves; only the newest goal is solved (a new goal preempts the running
solve, a queued one is answered as superseded).  The subscriptions and services exist from
the start; the numba kernels load in the background and goals that arrive meanwhile are
queued and solved once ready.  While it solves, ``~/progress`` reports at >= 5 Hz, and once at
the end with the status: level OK for SOLVED, WARN for SOLVED_INACCURATE (paper mode's
heuristic, trajectory published anyway), CANCELED and TIMEOUT, ERROR for failures and refused
input (message = the reason).  ``trajectory`` (transient local) is published for SOLVED and
SOLVED_INACCURATE results only, together with ``planned_path`` and ``markers``; the result on
``~/progress`` and the markers name the obstacle set it was planned for (``obstacles_hash``)
and the revision of the planning data (``data_revision``).

Goal lifecycle.  A goal is active from its acceptance until it is reached (its plan, and the
replan cycles' plans, ran out), replaced by a newer goal, or canceled:

- ``~/cancel`` (std_srvs/Trigger) cancels the running *solve* only (and a queued one): during
  an execution with replanning, the next cycles still drive the robot on to the goal.
- ``~/cancel_goal`` (std_srvs/Trigger) abandons the *goal*: the running and queued solves are
  canceled, no further replan cycle runs and no plan of the goal is published any more; a
  robot that executes a plan of it gets the braking trajectory (every joint decelerates at its
  control bound until it rests; an empty trajectory without a measured state), and
  ``~/progress`` reports CANCELED with event ``goal_canceled``.  success is false when no goal
  was active (nothing solving, queued or executing).
- A jump of the measured state, e.g. plant_node's ``~/reset`` while a goal executes, is a
  disturbance like any other: the goal stays active, and with replanning on the next cycle
  (due at once: the state deviates from the plan by more than replan.deviation) plans from the
  new state to the same goal while the executing plan lasts.  To stop instead, call
  ``~/cancel_goal`` before resetting the plant.

Replanning (fast mode, replan.rate > 0): while a plan executes, replan cycles solve to the
same goal from the latest joint_states, predicted forward to the new plan's start
(header.stamp = now + lead) along the executing plan, warm-started from that plan's rest; a
cycle's plan is published only when solved before its stamp, else the executing plan is kept
(~/progress event replan_kept).  Goals go first: a cycle never preempts a goal.  With
replan.estimate the cycles plan with model parameters estimated online from the joint_states
efforts (core/estimation.py).  The policy (when a cycle is due, its lead and grid, braking)
is core/replan_policy.py, the executing plan core/executing_plan.py and its bookkeeping
execution_state.py, the goals' checks and problems goal_requests.py, the worker
goal_worker.py: this node translates messages and wires them.

No plan for stale data: when the obstacles, the margin, the robot data or the extension
limits change during a goal's solve, the solve restarts from the same goal and the latest
state (a replan cycle's plan is published only if it satisfies the data current at its end);
when they change while a published trajectory is still executing and its remaining part
now cuts an (inflated) obstacle or exceeds u_max, a replan cycle plans around them at once
while braking can still wait for it (the plan stays out of the true circles until the cycle's
outcome is known, and the fastest stop started then still keeps out of them:
replan_policy.brake_can_wait); otherwise, or when that fails, a braking trajectory (an empty
one without a measured state) is published at once and the goal is planned again from the
measured state.

Run: ``ros2 run toc_ros solver_node --ros-args --params-file config/toc_ros.yaml``
"""

import dataclasses
import math
import sys
import threading
import time

from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path
from nav_msgs.srv import GetPlan
import numpy as np
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger
from toc_ros import conversions, goal_requests as goals, progress as schema
from toc_ros.config import problem_from_parameters
from toc_ros.core import ProblemError, Progress, solve, Status
from toc_ros.core import replan_policy as policy
from toc_ros.core.executing_plan import braking_plan, plan_from_result, true_conflict_time
from toc_ros.execution_state import ExecutionState
from toc_ros.goal_worker import GoalWorker, Request
from toc_ros.kernel_loader import KernelLoader
from toc_ros.nodes import parameters
from toc_ros.nodes.common import run_node
from toc_ros.nodes.solver_settings import checked, parameter_errors, SolverNodeConfig
from toc_ros.solve_progress import SolveProgress
from trajectory_msgs.msg import JointTrajectory
from visualization_msgs.msg import MarkerArray

PARAMETER_NAMES = parameters.SOLVER_NODE_NAMES
# ~/progress while solving: the heartbeat checks this often for a gap to fill.
HEARTBEAT_PERIOD_S = 0.05
CYCLE_SOURCE = 'replan_cycle'     # goal_source of the replan cycles' ~/progress reports
MARKER_PERIOD_S = 0.2
ARM_REDRAW = 1e-3     # [rad, m, rad/s, m/s] state change that redraws the arm marker
# Queue depth of the services: every request of a burst is kept and answered.
SERVICE_QOS = QoSProfile(depth=100)


def obstacle_count(msg):
    """Rows of an obstacles message, counted without reading the data (the limit check)."""
    dims = list(msg.layout.dim)
    if dims:
        return int(dims[0].size)
    return len(msg.data) // 3


def ignored_start(start, config, measured_state):
    """Return why a ~/plan request's start pose is ignored with a warning, or None."""
    p = start.pose.position
    return goals.ignored_start(start.header.frame_id.strip('/'), p.x, p.y,
                               config.frames.base_frame, config.model.joint_model,
                               measured_state)


class SolverNode(Node):
    """Plans minimum-time trajectories on goals; see the module docstring."""

    def __init__(self, **kwargs):
        super().__init__('solver_node', **kwargs)
        parameters.declare(self, PARAMETER_NAMES)
        flat = parameters.values(self, PARAMETER_NAMES)
        errors = parameter_errors(flat)
        if errors:
            raise parameters.ParameterError('; '.join(errors))
        self._config = SolverNodeConfig.from_flat(flat)
        self._accepted = None               # the config of the last accepted candidate
        self._name = self.get_fully_qualified_name()
        self._lock = threading.Lock()       # guards the fields below, shared with the worker
        self._measured = None               # latest joint state from joint_states
        self._measured_effort = None        # and its efforts (None: not given or not used)
        self._arm_dirty = True
        self._arm_drawn = None              # state drawn by the last markers
        self._progress = SolveProgress()    # of the running solve, for the heartbeat
        self._publish_lock = threading.Lock()
        # The plan in execution and its data revision (a trajectory is published only while
        # its data revision is still current: under self._plans.lock).
        self._plans = ExecutionState(self._config.planning_data())
        self._estimate = policy.OnlineEstimate()    # replan.estimate: fed by joint_states
        self._kernels = KernelLoader(self._config.model, self._on_kernels_loaded,
                                     self._on_kernels_failed)
        self._ready = self._kernels.ready
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._after_set_parameters)

        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                             reliability=ReliabilityPolicy.RELIABLE)
        self._trajectory_pub = self.create_publisher(JointTrajectory, 'trajectory', latched)
        self._path_pub = self.create_publisher(Path, 'planned_path', 10)
        self._marker_pub = self.create_publisher(MarkerArray, 'markers', latched)
        self._progress_pub = self.create_publisher(schema.DiagnosticStatus, '~/progress', 100)
        inputs = MutuallyExclusiveCallbackGroup()
        self.create_subscription(PoseStamped, 'goal_pose', self._on_goal_pose, 10,
                                 callback_group=inputs)
        self.create_subscription(JointState, 'goal_joints', self._on_goal_joints, 10,
                                 callback_group=inputs)
        self.create_subscription(Float64MultiArray, 'obstacles', self._on_obstacles, 10,
                                 callback_group=inputs)
        # Depth 1: only the newest state matters; a backlog would start replans from old ones.
        self.create_subscription(JointState, 'joint_states', self._on_joint_states,
                                 QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE),
                                 callback_group=MutuallyExclusiveCallbackGroup())
        # ~/plan is a coroutine that waits for its request without holding an executor
        # thread; reentrant so that any number of them wait at once.
        self.create_service(GetPlan, '~/plan', self._on_plan, qos_profile=SERVICE_QOS,
                            callback_group=ReentrantCallbackGroup())
        for name, callback in (('~/cancel', self._on_cancel), ('~/ready', self._on_ready),
                               ('~/cancel_goal', self._on_cancel_goal)):
            self.create_service(Trigger, name, callback, qos_profile=SERVICE_QOS,
                                callback_group=MutuallyExclusiveCallbackGroup())
        timers = MutuallyExclusiveCallbackGroup()
        self.create_timer(HEARTBEAT_PERIOD_S, self._heartbeat, callback_group=timers)
        self.create_timer(MARKER_PERIOD_S, self._publish_markers_if_dirty,
                          callback_group=timers)
        self._worker = GoalWorker(self._run, self._drop, self._ready, self.get_logger().error)
        self._publish_markers()
        # Compile or load the numba kernels in the background: the node already listens, and
        # goals that arrive meanwhile are queued.
        self._kernels.start()

    @property
    def _model(self):
        """The robot model planned for (its kernels loaded or loading)."""
        return self._kernels.model

    def _on_kernels_failed(self, exc):
        self.get_logger().error(f'loading the numba kernels failed: {exc!r}')

    def _on_kernels_loaded(self, elapsed):
        self.get_logger().info(f'numba kernels loaded in {elapsed:.2f} s')
        config = self._snapshot()[0]
        self._publish_progress(schema.ProgressReport(
            message=f'ready: numba kernels loaded in {elapsed:.2f} s', elapsed_s=elapsed,
            event=schema.EVENT_READY, **config.model_keys()))
        self.get_logger().info(
            f'ready: {len(config.problem.obstacles)} obstacle(s), mode '
            f'{config.options.mode}, N = {config.problem.n_intervals}')

    def ready(self):
        """Tell whether the kernels are loaded (goals before that are queued)."""
        return self._ready.is_set()

    def _on_ready(self, _request, response):
        response.success, response.message = self._kernels.status()
        return response

    # -- parameters ---------------------------------------------------------------------------

    def _on_set_parameters(self, changed):
        with self._lock:
            flat = parameters.candidate(self._config.flat, changed)
        errors, config = checked(flat)
        self._accepted = config       # built once: _after_set_parameters takes it
        result = parameters.result(errors)
        if not result.successful:
            self.get_logger().warning(f'refused parameter change: {result.reason}')
            if any(p.name.startswith('robot.model') for p in changed):
                self._publish_progress(schema.refusal_report(
                    f'parameters: refused robot model: {result.reason}'))
        return result

    def _after_set_parameters(self, changed):
        if any(p.name in ('replan.lead', 'robot.model', 'robot.actuator_lag') for p in changed):
            self._plans.clear_latencies()   # another lead or model: measured afresh
        if any(p.name.startswith('replan.estimate') for p in changed):
            self._estimate.reset()      # set (even to the same value): start afresh
        flat = parameters.candidate(self._config.flat, changed)
        config = self._accepted
        if config is None or config.flat != flat:
            config = SolverNodeConfig.from_flat(flat)
        with self._lock:
            self._config = config
            self._arm_dirty = True   # obstacles or frames may have changed
        if any(p.name.startswith('robot.') for p in changed) \
                and self._kernels.switch(config.model):
            self.get_logger().info(f'robot model changed: loading the kernels of {config.model!r}')
        revision = self._plans.new_data(config.planning_data())
        if revision is None:
            return
        reason = f'planning data changed (data revision {revision})'
        if self._worker.restart(reason):
            self.get_logger().warning(f'{reason}: restarting the running solve')
            self._publish_progress(schema.ProgressReport(
                message=f'{reason}: solving again from the latest state',
                event=schema.EVENT_RESTARTED, data_revision=revision))
        self._check_executing(config, revision)

    # -- the executing plan under new data ----------------------------------------------------

    def _check_executing(self, config, revision):
        """Replan around, or stop, an executing trajectory that violates the current data."""
        stale = self._plans.stale_plan(
            revision, self._now(), lambda plan, t: goals.plan_violation(plan, config, t))
        if stale is None:
            return
        plan, elapsed, problem = stale
        measured = self._snapshot()[1]
        if measured is not None and self._brake_can_wait(plan, config, measured, elapsed) \
                and self._maybe_replan(config, measured, self._now(), time.monotonic(),
                                       reason=policy.DATA_CHANGE):
            self.get_logger().warning(
                f'the executing trajectory {problem} under data revision {revision}: '
                'replanning from the current state')
            return
        self._stop(plan, config, revision, problem)

    def _publish_stop(self, plan, config, still_valid):
        """
        Replace plan by a stop at once; return (published, braking plan or None).

        With a measured state the stop is a braking trajectory (every joint decelerates at
        its control bound until it rests); without one an empty trajectory (the plant holds).
        still_valid() (under the plan lock) tells whether plan may still be replaced.
        """
        measured = self._snapshot()[1]
        names = config.frames.joint_names
        braking = braking_plan(plan, measured, self._now(), policy.BRAKE_STEP_S)
        if braking is None:
            stop = JointTrajectory(joint_names=list(names))
        else:
            stop = conversions.trajectory_msg(braking, names, braking.model,
                                              conversions.time_msg(0.0))
        with self._plans.lock:
            if not still_valid():
                return False, None
            self._trajectory_pub.publish(stop)
            if braking is not None:
                braking.start = self._now()
            self._plans.executing = braking
        return True, braking

    def _stop(self, plan, config, revision, problem):
        """Stop the executing plan at once and plan its goal again (unless a goal is queued)."""
        plans = self._plans
        published, braking = self._publish_stop(
            plan, config, lambda: revision == plans.revision and plans.executing is plan)
        if not published:
            return        # newer data or a newer plan took over meanwhile
        replan = plan.goal_active and not self._worker.goal_busy()
        how = 'braking to rest' if braking is not None else 'stopped'
        reason = (f'the executing trajectory {problem} under data revision {revision}: '
                  f'{how}' + (', planning the goal again' if replan else ''))
        self.get_logger().warning(reason)
        self._publish_progress(schema.ProgressReport(
            status=Status.CANCELED, message=reason, level=schema.DiagnosticStatus.WARN,
            goal_source=plan.source, data_revision=revision, event=schema.EVENT_STOPPED))
        if replan:
            request = self._submit(lambda _config: plan.goal, goals.REPLAN)
            if request is not None:
                request.event = schema.EVENT_REPLACED

    def _brake_can_wait(self, plan, config, measured, elapsed):
        """Tell whether plan may run on while a cycle plans around new data (the policy)."""
        rows = config.problem.obstacles
        conflict = true_conflict_time(plan, rows, elapsed)
        return policy.brake_can_wait(plan, rows, measured, elapsed,
                                     self._plans.cycle_lead(config.node.replan_lead), conflict)

    def _snapshot(self):
        """Return (settings, the measured state of their model or None)."""
        with self._lock:
            config, joints, effort = self._config, self._measured, self._measured_effort
        return config, (None if joints is None else self._model_state(joints, effort))

    # -- inputs -------------------------------------------------------------------------------

    def _on_joint_states(self, msg):
        with self._lock:
            config = self._config
        names = config.frames.joint_names
        try:
            state = conversions.joint_state_to_state(msg, names)
            # The applied efforts are the actuator states of a model with actuator lag.
            effort = (conversions.joint_state_efforts(msg, names)
                      if config.robot.actuator_lag > 0.0 else None)
        except conversions.ConversionError as exc:
            self.get_logger().warning(f'ignoring joint_states: {exc}', throttle_duration_sec=5.0)
            return
        received = time.monotonic()
        stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        with self._lock:
            self._measured = state
            self._measured_effort = effort
            # Redraw the arm when it moved visibly, not for every message of a resting robot.
            if self._arm_drawn is None or np.max(np.abs(state - self._arm_drawn)) > ARM_REDRAW:
                self._arm_dirty = True
        state_time = stamp if stamp > 0.0 else self._now()
        if config.node.replan_estimate:
            self._estimate_from(msg, config, state, state_time)
        self._maybe_replan(config, self._model_state(state, effort), state_time, received)

    def _model_state(self, joints, effort=None):
        """
        Return the current model's state from a measured joint state and its efforts.

        A model with actuator states (robot.actuator_lag) takes the efforts as the applied ones
        (without them: the torques that hold the joints' velocities); others the joint state.
        self._model follows the robot parameters (KernelLoader.switch): no model is built here,
        on the joint_states path.
        """
        try:
            return self._model.full_state(joints, effort)
        except ValueError:          # e.g. efforts for another joint count: the joint state
            return np.array(joints, dtype=float)

    def _estimate_from(self, msg, config, state, state_time):
        """Feed the online estimator (replan.estimate) with one joint_states sample."""
        try:
            effort = conversions.joint_state_efforts(msg, config.frames.joint_names)
        except conversions.ConversionError as exc:
            effort, why = None, str(exc)
        else:
            why = 'joint_states carry no effort'
        if effort is None:
            self.get_logger().warning(f'replan.estimate: {why}; nothing estimated',
                                      throttle_duration_sec=5.0)
            return
        # The joints' model; the efforts are the applied ones, after any actuator lag.
        self._estimate.add(self._model.joint_model, config.node.replan_estimate,
                           config.node.replan_estimate_window, state_time, state, effort)

    def _estimated_model(self, config):
        """Return (model with the online estimate or None, its text or why there is none)."""
        if not config.node.replan_estimate:
            return None, ''
        return self._estimate.model(self._model.joint_model, config.robot.actuator_lag)

    def _pose_goal(self, msg, config):
        """Joint goal of a hand pose by the model's IK, seeded by the start (ConversionError)."""
        start, _ = self._start_state(config, self._snapshot()[1])
        return conversions.pose_to_joint_goal(
            msg, config.frames.base_frame, config.model, tuple(config.node.extension_limits),
            config.node.ik_branch, seed=config.model.positions(start))

    def _on_goal_pose(self, msg):
        self._submit(lambda config: self._pose_goal(msg, config), 'goal_pose')

    def _on_goal_joints(self, msg):
        self._submit(lambda config: conversions.joint_state_to_state(
            msg, config.frames.joint_names), 'goal_joints')

    def _on_obstacles(self, msg):
        with self._lock:
            limit = self._config.node.max_count
        count = obstacle_count(msg)
        if count > limit:    # refused before any per-obstacle work
            self._refuse('obstacles', f'{count} obstacles exceed obstacles.max_count = {limit}')
            return
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

    async def _on_plan(self, request, response):
        config, measured = self._snapshot()
        response.plan.header.frame_id = config.frames.base_frame
        response.plan.header.stamp = self.get_clock().now().to_msg()
        start, start_source = self._start_state(config, measured)
        try:
            why = ignored_start(request.start, config, start)
        except (ValueError, IndexError) as exc:      # a model without a hand position
            why = f'cannot be compared with the measured state ({exc})'
        if why is not None:
            note = (f'~/plan: the request start {why}; planning from the {start_source} state '
                    'instead (the start is always the measured state)')
            self.get_logger().warning(note)
            self._publish_progress(schema.ProgressReport(
                message=note, level=schema.DiagnosticStatus.WARN, goal_source='~/plan',
                start_source=start_source, event=schema.EVENT_START_IGNORED))
        pending = self._submit(lambda cfg: self._pose_goal(request.goal, cfg), '~/plan')
        if pending is None:
            return response
        finished = Future()

        def wake():      # worker thread: resume this coroutine in the executor
            if not finished.done():
                finished.set_result(True)
            executor = self.executor
            if executor is not None:
                executor.wake()
        pending.on_done(wake)
        await finished
        if pending.path is not None:
            response.plan = pending.path
        return response

    def _on_cancel(self, _request, response):
        started = time.monotonic()
        response.success = self._worker.cancel('canceled by ~/cancel')
        response.message = (f'solve stopped in {time.monotonic() - started:.4f} s'
                            if response.success else 'no solve was running')
        return response

    def _on_cancel_goal(self, _request, response):
        """Abandon the goal: no more solves or cycles for it, the robot brakes to rest."""
        started = time.monotonic()
        reason = 'goal canceled by ~/cancel_goal'
        with self._plans.lock:      # first: no new cycle and no replan after a stop for it
            plan = self._plans.executing
            active = plan is not None and plan.goal_active and plan.executing(self._now())
            if plan is not None:
                plan.goal_active = False
        stopped, dropped = self._worker.cancel_goal(reason)
        config, measured = self._snapshot()
        how = None
        if policy.cancel_goal_action(plan, self._now(), measured) != policy.NOTHING:
            published, braking = self._publish_stop(
                plan, config, lambda: self._plans.executing is plan)
            if published and braking is None:
                how = 'stopped (no measured state)'
        current, revision = self._plans.current()
        if how is None and current is not None and current.braking \
                and current.executing(self._now()):
            how = 'braking to rest'
        response.success = bool(stopped or dropped or active)
        if not response.success:
            response.message = 'no active goal (nothing solving, queued or executing)'
            return response
        response.message = (f'{reason}: ' + (how or 'no plan was executing')
                            + f' ({time.monotonic() - started:.4f} s)')
        self.get_logger().warning(response.message)
        self._publish_progress(schema.ProgressReport(
            status=Status.CANCELED, message=response.message, level=schema.DiagnosticStatus.WARN,
            goal_source='' if plan is None else plan.source, data_revision=revision,
            event=schema.EVENT_GOAL_CANCELED))
        return response

    def _start_state(self, config, measured):
        if measured is not None:
            return measured, 'joint_states'
        return np.asarray(config.problem.x0, dtype=float), 'initial_state'

    def _submit(self, make_goal, source):
        """Check a goal against the current start state and obstacles, then queue it."""
        config, measured = self._snapshot()
        start, start_source = self._start_state(config, measured)
        try:
            goal = make_goal(config)
        except conversions.ConversionError as exc:
            self._refuse(source, str(exc))
            return None
        why = goals.goal_refusal(config, start, start_source, goal, source)
        if why is not None:
            self._refuse(source, why)
            return None
        request = Request(np.asarray(goal, dtype=float), source)
        self.get_logger().info(f'goal from {source}: {np.round(goal, 6).tolist()}')
        if not self._ready.is_set():
            note = (f'goal from {source} queued: the numba kernels are still loading; it is '
                    'solved once ready')
            self.get_logger().info(note)
            self._publish_progress(schema.ProgressReport(
                message=note, goal_source=source, goal=tuple(goal), event=schema.EVENT_QUEUED))
        self._worker.submit(request)
        return request

    def _refuse(self, source, reason):
        self.get_logger().error(f'refused {source}: {reason}')
        self._publish_progress(schema.refusal_report(f'{source}: {reason}'))

    # -- solving (worker thread) --------------------------------------------------------------

    def _publish_progress(self, report):
        msg = schema.progress_msg(self._name, report)
        with self._publish_lock:
            self._progress_pub.publish(msg)
            self._progress.sent()

    def _on_progress(self, progress):
        progress = self._progress.update(progress)
        if progress is not None:
            self._publish_progress(schema.running_report(progress))

    def _heartbeat(self):
        progress = self._progress.due()
        if progress is not None:
            self._publish_progress(schema.running_report(progress))

    def _drop(self, request, reason, event=None):
        event = schema.EVENT_SUPERSEDED if event is None else event
        self.get_logger().warning(f'goal from {request.source} {reason}')
        self._publish_progress(schema.ProgressReport(
            status=Status.CANCELED, message=f'goal from {request.source} {reason}',
            goal_source=request.source, event=event))
        request.finish()

    def _run(self, request, cancel):
        if request.cycle is not None:
            self._run_cycle(request, cancel)
            return
        config, measured = self._snapshot()
        start, start_source = self._start_state(config, measured)
        executing, revision = self._plans.current()
        try:
            problem, guess, margin = goals.goal_problem(
                config, start, request.goal, request.source,
                executing if start_source == 'joint_states' else None, self._now())
        except (ProblemError, TypeError, ValueError) as exc:   # parameters are validated
            self._refuse(request.source, str(exc))
            return
        if margin is not None:
            self.get_logger().warning(
                f'replanning from inside the obstacle margin with margin {margin:.4g} m')
        self._publish_progress(schema.running_report(self._progress.start(
            Progress(0, problem.t_f0, math.nan, math.nan, 0.0, 'start'))))
        try:
            result = solve(problem, config.options, progress=self._on_progress, cancel=cancel,
                           initial_guess=guess)
        except Exception as exc:  # noqa: B902 - a core bug must not kill the worker thread
            self.get_logger().error(f'solver failed: {exc!r}')
            self._publish_progress(schema.refusal_report(
                f'internal solver error: {exc!r}', status=Status.INVALID_INPUT, event=''))
            return
        finally:
            self._progress.end()
        if request.restart_reason is not None:
            return        # the worker runs it again with the current data
        request.result = result
        status, message = goals.goal_outcome(result, request.stop_reason, start_source)
        if status in schema.PUBLISHED and result.has_trajectory \
                and not self._publish_plan(request, result, problem, config, revision):
            if self._worker.current(request):
                request.restart_reason = 'planning data changed at the end of the solve'
                return
            status, message = Status.CANCELED, f'{request.stop_reason}: not published'
        report = schema.result_report(
            result, message, goal_source=request.source, start_source=start_source,
            goal=tuple(float(v) for v in np.round(request.goal, 9)),
            obstacles_hash=schema.obstacles_hash(problem.obstacles, problem.margin),
            data_revision=revision, event=request.event, **config.model_keys())
        if status is not result.status:
            report = dataclasses.replace(report, status=status, level=None)
        text = (f'{status.value} for goal from {request.source}: {message} '
                f'({result.iterations} iterations, {result.wall_time_s:.3f} s)')
        # One call site per severity: rclpy refuses to change it between calls of a site.
        level = schema.LEVELS[status]
        if level == schema.DiagnosticStatus.OK:
            self.get_logger().info(text)
        elif level == schema.DiagnosticStatus.WARN:
            self.get_logger().warning(text)
        else:
            self.get_logger().error(text)
        self._publish_progress(report)

    def _publish_plan(self, request, result, problem, config, revision, stamp_s=None):
        """
        Publish the plan unless its data revision is stale or its goal canceled (then False).

        stamp_s: the plan's header.stamp [s, node clock], when it starts to apply (replan
        cycles: ahead of now); None: start_lead after publication for a start at rest (the
        stamp is taken once the message is built), else now.  A replan cycle's plan whose data
        changed meanwhile is published when it also satisfies the current data (checked as
        executing plans are).
        """
        model = problem.robot_model
        rest = stamp_s is None and policy.at_rest(model, problem.x0)
        lead = config.node.start_lead if rest else 0.0
        names = config.frames.joint_names
        trajectory = conversions.trajectory_msg(result, names, model, conversions.time_msg(0.0))
        now = self._now()
        if request.cycle is not None and time.monotonic() > request.cycle.deadline:
            request.late = True         # over the cycle's budget (the lead): keep the old plan
            return False
        start = now + lead if stamp_s is None else float(stamp_s)
        stamp = trajectory.header.stamp = conversions.time_msg(start)
        plan = plan_from_result(result, start, request.goal, request.source, model)
        plans = self._plans
        with plans.lock:
            if not self._worker.current(request):
                return False            # its goal was canceled (~/cancel_goal)
            if revision != plans.revision:
                with self._lock:
                    current = self._config
                if request.cycle is None or goals.plan_violation(plan, current, 0.0):
                    return False
                problem = problem_from_parameters(current.flat, x0=problem.x0,
                                                  x_goal=problem.x_goal)
                revision = plans.revision
            self._trajectory_pub.publish(trajectory)
            request.published_at = time.monotonic()
            plans.executing = plan
            plans.plan_info = (schema.obstacles_hash(problem.obstacles, problem.margin),
                               revision)
        # The path and the markers only after the trajectory: they are not on its latency.
        path = conversions.hand_path_msg(result.states, model, config.frames.base_frame, stamp)
        request.path = path
        self._path_pub.publish(path)
        if request.cycle is None:
            self._publish_markers()   # cycles: the marker timer redraws (no solve delay)
        else:
            with self._lock:
                self._arm_dirty = True
        return True

    # -- replanning (receding horizon) ----------------------------------------------------------

    def _now(self):
        """Return the node clock's time [s] (simulated time under use_sim_time)."""
        return self.get_clock().now().nanoseconds * 1e-9

    def _maybe_replan(self, config, state, state_time, received, reason=None):
        """
        Start a replan cycle from a measured state when one is due; True when it was queued.

        Due (policy.cycle_reason): at replan.rate, at once when the state deviates from the
        executing plan by more than replan.deviation, or for a reason (new data).  The cycle's
        plan starts on the executing plan's node at or after now + lead (policy.cycle_start)
        from the state predicted along the executing plan; the worker takes it only when no
        goal is queued or solving.
        """
        plan, revision = self._plans.current()
        if not policy.cycle_allowed(plan, config.replanning, self._ready.is_set()) \
                or state.shape[0] != plan.model.nx:
            return False
        cycle = policy.next_cycle(plan, state, state_time, self._now(), received,
                                  self._plans.cycle_lead(config.node.replan_lead), config.node,
                                  self._plans.next_cycle, revision, reason)
        if cycle is None:
            return False
        request = Request(plan.goal, CYCLE_SOURCE, cycle)
        if not self._worker.offer(request, behind_cycle=cycle.reason == policy.DATA_CHANGE):
            return False
        self._plans.cycle_taken(received, config.node.replan_rate)
        return True

    def _run_cycle(self, request, cancel):
        """Solve one replan cycle (worker thread); publish it or keep the executing plan."""
        cycle, plan = request.cycle, request.cycle.plan
        config = self._snapshot()[0]
        taken = self._plans.cycle_source(plan)
        if taken is None:
            return          # a newer plan was published meanwhile: nothing to replace
        revision, source = taken
        result, problem, why = None, None, ''
        estimated, estimate = self._estimated_model(config)
        try:
            problem = problem_from_parameters(config.flat, x0=cycle.start, x_goal=plan.goal)
            if estimated is not None:
                problem = problem.with_model(estimated)
            # Published only by its deadline (its lead after its joint_states arrived): the
            # lead bounds the latency; a late solve seeds the next cycle's warm start.
            planned, options, guess = policy.cycle_problem(
                source, cycle, problem, config.node.replan_max_nodes, config.options,
                time.monotonic())
            if planned is None:
                why = guess
            else:
                problem = planned
                result = solve(problem, options, cancel=cancel, initial_guess=guess)
        except (ProblemError, TypeError, ValueError) as exc:
            why = f'no plan from the predicted state: {exc}'
        except Exception as exc:  # noqa: B902 - a core bug must not kill the worker thread
            self.get_logger().error(f'replan cycle failed: {exc!r}')
            why = f'internal solver error: {exc!r}'
        published = False
        if result is not None:
            late_by = None
            if result.status is Status.SOLVED and result.has_trajectory:
                # Published only when its message is ready by the deadline (else late).
                request.late = time.monotonic() > cycle.deadline
                published = not request.late and self._publish_plan(
                    request, result, problem, config, revision, stamp_s=cycle.stamp_s)
                if request.late:
                    late_by = time.monotonic() - cycle.deadline
                    self._plans.seed_next(plan, result, problem)
            why = goals.cycle_failure(result, request.stop_reason, late_by,
                                      cycle.deadline - cycle.received, published,
                                      published or self._worker.current(request)) or why
        # joint_states received -> trajectory published (the path and markers come after).
        latency = (request.published_at if published else time.monotonic()) - cycle.received
        if result is not None and result.status is Status.SOLVED:
            # Solved cycles, published or late: the median follows cycles that are slow most
            # of the time, not the rare one that seeds the next.  Not timed-out ones: those
            # are the final braking's overshoot problems, hundreds of iterations whatever the
            # lead (they would stretch every later cycle's lead to the cap).
            self._plans.record_latency(latency)
        values = dict(goal_source=CYCLE_SOURCE, start_source='predicted joint_states',
                      goal=tuple(float(v) for v in np.round(plan.goal, 9)),
                      data_revision=revision, latency_s=latency, deviation=cycle.deviation,
                      plan_stamp=cycle.stamp_s, state_stamp=cycle.state_stamp,
                      estimate=estimate if estimated is not None else
                      (f'none: {estimate}' if estimate else ''), **config.model_keys())
        if problem is not None:
            values['obstacles_hash'] = schema.obstacles_hash(problem.obstacles, problem.margin)
        if published:       # the data it was checked against
            with self._plans.lock:
                values['obstacles_hash'], values['data_revision'] = self._plans.plan_info
            self._publish_progress(schema.result_report(
                result, f'replanned ({cycle.reason}): {result.message}',
                event=schema.EVENT_REPLANNED, **values))
            return
        message = f'replan cycle ({cycle.reason}) kept the executing plan: {why}'
        self.get_logger().warning(message, throttle_duration_sec=1.0)
        report = (schema.result_report(result, message, **values) if result is not None
                  else schema.ProgressReport(status=Status.INVALID_INPUT, message=message,
                                             **values))
        self._publish_progress(dataclasses.replace(
            report, level=schema.DiagnosticStatus.WARN, event=schema.EVENT_REPLAN_KEPT))
        self._stop_if_violating(plan, self._snapshot()[0], cycle, request.late)

    def _stop_if_violating(self, plan, config, cycle, late=False):
        """
        After a failed cycle: act on the plan it kept if that violates the current data.

        Another data-change cycle is tried when policy.retry_after_failed_cycle says so and
        braking can wait for it (_brake_can_wait); else the plan is stopped.
        """
        plan_now, revision = self._plans.current()
        if plan_now is not plan:
            return
        elapsed = plan.elapsed(self._now())
        problem = goals.plan_violation(plan, config, elapsed)
        if problem is None:
            return
        measured = self._snapshot()[1]
        again = policy.retry_after_failed_cycle(cycle.reason, cycle.revision, revision, late)
        if again and measured is not None \
                and self._brake_can_wait(plan, config, measured, elapsed) \
                and self._maybe_replan(config, measured, self._now(), time.monotonic(),
                                       reason=policy.DATA_CHANGE):
            return
        self._stop(plan, config, revision, problem)

    # -- markers ------------------------------------------------------------------------------

    def _publish_markers_if_dirty(self):
        with self._lock:
            dirty = self._arm_dirty
        if dirty:
            self._publish_markers()

    def _publish_markers(self):
        with self._lock:
            config = self._config
            arm = self._measured
            self._arm_dirty = False
            self._arm_drawn = arm
        path_states, plan_info, revision = self._plans.drawing()
        if arm is None:
            arm = np.asarray(config.problem.x0, dtype=float)
        rows, margin = config.problem.obstacles, config.problem.margin
        model = config.model.joint_model     # joint states drawn
        if path_states is not None and np.shape(path_states)[-1] != np.shape(arm)[-1]:
            path_states = None      # planned for another robot model
        self._marker_pub.publish(conversions.markers_msg(
            rows, margin, model, config.frames.base_frame,
            self.get_clock().now().to_msg(), path_states, arm,
            obstacles_info=(schema.obstacles_hash(rows, margin), revision),
            plan_info=plan_info))

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
    return run_node('solver_node', SolverNode, SingleThreadedExecutor,
                    args=args, errors=(parameters.ParameterError, InvalidParameterValueException,
                                       InvalidParameterTypeException),
                    error_prefix='invalid parameters: ')


if __name__ == '__main__':
    sys.exit(main())
