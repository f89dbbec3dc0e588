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
solver_node: minimum-time trajectories of the robot model (robot.model) on request.

Goals arrive on ``goal_pose``, ``goal_joints`` or ``~/plan``; each plan starts from the latest
``joint_states`` (``initial_state`` until one arrived; while a plan moves the robot, on that
plan ``goal_lead`` ahead), avoids the current obstacles and is
published on ``trajectory``; ``~/progress`` reports every solve, cycle and stop, ``~/cancel``
stops a solve, ``~/cancel_goal`` abandons a goal, ``~/ready`` tells when the kernels are loaded.
The interface and its rules (goal lifecycle, newest goal wins, no plan for stale data, replan
cycles, braking) are documented in docs/ros_interface.md.

This module only translates messages and wires them: the topic inputs are solver_inputs.py,
the execute.* action client solver_execution.py; the solves, cycles and stops are planner.py
(free of rclpy), the worker goal_worker.py, the goals' checks and problems goal_requests.py,
the executing plan's bookkeeping execution_state.py, the policy (when a cycle is due, its lead
and grid, braking) core/replan_policy.py, where goals start core/goal_starts.py; URDF arms are
translated by the arm_* modules (arm_config, arm_model, arm_goals, arm_inputs, arm_markers).

Run: ``ros2 run toc_ros solver_node --ros-args --params-file config/toc_ros.yaml``
"""

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
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import Trigger
from toc_ros import arm_config, arm_goals, conversions, goal_requests as goals
from toc_ros import progress as schema
from toc_ros.arm_inputs import ArmInputs
from toc_ros.arm_markers import arm_markers
from toc_ros.core.online_estimate import OnlineEstimate
from toc_ros.kernel_loader import KernelLoader
from toc_ros.nodes import parameters
from toc_ros.nodes.common import run_node
from toc_ros.nodes.solver_execution import ExecutionLink, refused
from toc_ros.nodes.solver_inputs import SolverInputs
from toc_ros.nodes.solver_settings import checked, parameter_errors, SolverNodeConfig
from toc_ros.planner import Planner
from trajectory_msgs.msg import JointTrajectory
from visualization_msgs.msg import MarkerArray

PARAMETER_NAMES = parameters.SOLVER_NODE_NAMES
# ~/progress while solving: the heartbeat checks this often for a gap to fill.
HEARTBEAT_PERIOD_S = 0.05
MARKER_PERIOD_S = 0.2
# Queue depth of the services: every request of a burst is kept and answered.
SERVICE_QOS = QoSProfile(depth=100)


def ignored_start(start, config, measured_state):
    """Return why a ~/plan request's start pose is ignored with a warning, or None."""
    p = start.pose.position
    return goals.ignored_start(start.header.frame_id.strip('/'), p.x, p.y,
                               config.frames.base_frame, config.model.joint_model,
                               measured_state)


class SolverNode(SolverInputs, Node):
    """Plans minimum-time trajectories on goals; see the module docstring."""

    def __init__(self, **kwargs):
        super().__init__('solver_node', **kwargs)
        parameters.declare(self, PARAMETER_NAMES)
        # With the values that topics fill (an arm's obstacle spheres, URDF): none yet.
        flat = dict(parameters.values(self, PARAMETER_NAMES), **arm_config.TOPIC_DEFAULTS)
        errors = parameter_errors(flat)
        if errors:
            raise parameters.ParameterError('; '.join(errors))
        self._config = SolverNodeConfig.from_flat(flat)
        self._accepted = None               # the config of the last accepted candidate
        self._name = self.get_fully_qualified_name()
        self.logger = self.get_logger()
        self._lock = threading.Lock()       # guards the fields below, shared with the worker
        self._measured = None               # latest joint state from joint_states
        self._measured_effort = None        # and its efforts (None: not given or not used)
        self._measured_time = None          # and its time [s, node clock]
        self._measured_received = None      # and when it arrived [s, node clock]
        self._arm_dirty = True
        self._arm_drawn = None              # state drawn by the last markers
        self._publish_lock = threading.Lock()
        self._estimate = OnlineEstimate()    # replan.estimate: fed by joint_states
        self._arm_inputs = ArmInputs()      # URDF arms: obstacle markers, robot_description
        self._kernels = KernelLoader(self._config.model, self._on_kernels_loaded,
                                     self._on_kernels_failed)
        self._planner = Planner(self, self._config.planning_data(), self._kernels.ready)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._after_set_parameters)

        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                             reliability=ReliabilityPolicy.RELIABLE)
        self._trajectory_pub = self.create_publisher(JointTrajectory, 'trajectory', latched)
        self._path_pub = self.create_publisher(Path, 'planned_path', 10)
        self._marker_pub = self.create_publisher(MarkerArray, 'markers', latched)
        self._progress_pub = self.create_publisher(schema.DiagnosticStatus, '~/progress', 100)
        self._execution = ExecutionLink(self)      # execute.*
        self._execution.configure(self._config.node)
        inputs = MutuallyExclusiveCallbackGroup()
        self.create_subscription(PoseStamped, 'goal_pose', self._on_goal_pose, 10,
                                 callback_group=inputs)
        self.create_subscription(JointState, 'goal_joints', self._on_goal_joints, 10,
                                 callback_group=inputs)
        self.create_subscription(Float64MultiArray, 'obstacles', self._on_obstacles, 10,
                                 callback_group=inputs)
        self.create_subscription(MarkerArray, 'obstacle_markers', self._on_obstacle_markers,
                                 10, callback_group=inputs)
        # As robot_state_publisher publishes it: the latest URDF, kept for late joiners.
        self.create_subscription(String, 'robot_description', self._on_robot_description,
                                 latched, callback_group=inputs)
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
        self._worker = self._planner.worker
        self.publish_markers()
        # Compile or load the numba kernels in the background: the node already listens, and
        # goals that arrive meanwhile are queued.
        self._kernels.start()

    @property
    def _model(self):
        """Return the robot model planned for (its kernels loaded or loading)."""
        return self._kernels.model

    def _on_kernels_failed(self, exc):
        self.get_logger().error(f'loading the numba kernels failed: {exc!r}')

    def _on_kernels_loaded(self, elapsed):
        self.get_logger().info(f'numba kernels loaded in {elapsed:.2f} s')
        config = self.settings()
        self.report(schema.ProgressReport(
            message=f'ready: numba kernels loaded in {elapsed:.2f} s', elapsed_s=elapsed,
            event=schema.EVENT_READY, **config.model_keys(texts=True)))
        self.get_logger().info(
            f'ready: {len(config.problem.obstacles)} obstacle(s), mode '
            f'{config.options.mode}, N = {config.problem.n_intervals}')
        if config.is_arm:
            from toc_ros.core.arms import pin_batch     # imports Pinocchio: arms only
            self.get_logger().info(pin_batch.status())

    def ready(self):
        """Tell whether the kernels are loaded (goals before that are queued)."""
        return self._kernels.ready.is_set()

    def _on_ready(self, _request, response):
        response.success, response.message = self._kernels.status()
        return response

    # -- the planner's port -------------------------------------------------------------------

    def settings(self):
        """Return the current SolverNodeConfig."""
        with self._lock:
            return self._config

    def snapshot(self):
        """Return (settings, the measured state of their model or None)."""
        with self._lock:
            config, joints, effort = self._config, self._measured, self._measured_effort
        return config, (None if joints is None else self._model_state(joints, effort))

    def measured_time(self):
        """Return the node-clock time [s] of the measured state (None: none yet)."""
        with self._lock:
            return self._measured_time

    def measured_received(self):
        """Return the node-clock time [s] when the measured state arrived (None: none yet)."""
        with self._lock:
            return self._measured_received

    def now(self):
        """Return the node clock's time [s] (simulated time under use_sim_time)."""
        return self.get_clock().now().nanoseconds * 1e-9

    def publish_trajectory(self, msg, hold_effort=None):
        """Send a trajectory (the planner holds its plan lock meanwhile)."""
        self._trajectory_pub.publish(msg)
        self._execution.send(msg, hold_effort)

    def publish_path(self, msg):
        """Send a planned path."""
        self._path_pub.publish(msg)

    def arm_moved(self):
        """Have the marker timer redraw."""
        with self._lock:
            self._arm_dirty = True

    def report(self, report):
        """Send a ~/progress report."""
        msg = schema.progress_msg(self._name, report)
        with self._publish_lock:
            self._progress_pub.publish(msg)
            self._planner.progress.sent()

    def estimated_model(self, config):
        """Return (model with the online estimate or None, its text or why there is none)."""
        if not config.node.replan_estimate:
            return None, ''
        return self._estimate.model(self._model.joint_model, config.robot.actuator_lag)

    # -- parameters ---------------------------------------------------------------------------

    def _on_set_parameters(self, changed):
        with self._lock:
            flat = parameters.candidate(self._config.flat, changed)
        errors, config = checked(flat)
        refusal = refused(flat, changed)
        if refusal:
            errors.append(refusal)
        self._accepted = config       # built once: _after_set_parameters takes it
        result = parameters.result(errors)
        if not result.successful:
            self.get_logger().warning(f'refused parameter change: {result.reason}')
            if any(p.name.startswith('robot.model') for p in changed):
                self.report(schema.refusal_report(
                    f'parameters: refused robot model: {result.reason}'))
        return result

    def _after_set_parameters(self, changed):
        if any(p.name in ('replan.lead', 'robot.model', 'robot.actuator_lag') for p in changed):
            self._planner.plans.clear_latencies()   # another lead or model: measured afresh
        if any(p.name.startswith('replan.estimate') for p in changed):
            self._estimate.reset()      # set (even to the same value): start afresh
        flat = parameters.candidate(self._config.flat, changed)
        config = self._accepted
        if config is None or config.flat != flat:
            config = SolverNodeConfig.from_flat(flat)
        with self._lock:
            if tuple(config.frames.joint_names) != tuple(self._config.frames.joint_names):
                # A state of other joints is no start of this robot: goals wait for the next
                # joint_states (read with the new joint_names).
                self._measured = self._measured_effort = self._measured_time = None
                self._measured_received = None
            self._config = config
            self._arm_dirty = True   # obstacles or frames may have changed
        if any(p.name.startswith('execute.') for p in changed):
            self._execution.configure(config.node)
        if any(p.name.startswith('robot.') or p.name in ('robot_description', 'joint_names')
               for p in changed) \
                and self._kernels.switch(config.model):
            self.get_logger().info('robot model changed: loading the kernels of '
                                   f'{getattr(config.model, "name", config.model)!r}')
        self._planner.data_changed(config)

    async def _on_plan(self, request, response):
        config, measured = self.snapshot()
        response.plan.header.frame_id = config.frames.base_frame
        response.plan.header.stamp = self.get_clock().now().to_msg()
        start, start_source, _ = goals.goal_start(
            config, measured, self._planner.plans.current()[0], self.now(), self.measured_time())
        try:
            why = (arm_goals.ignored_start(request.start, config, measured) if config.is_arm
                   else ignored_start(request.start, config, start))
        except (ValueError, IndexError) as exc:      # a model without a hand position
            why = f'cannot be compared with the measured state ({exc})'
        if why is not None:
            note = (f'~/plan: the request start {why}; planning from the {start_source} state '
                    'instead (the start is the measured state, the rest of a braking stop, or '
                    'the executing plan ahead)')
            self.get_logger().warning(note)
            self.report(schema.ProgressReport(
                message=note, level=schema.DiagnosticStatus.WARN, goal_source='~/plan',
                start_source=start_source, event=schema.EVENT_START_IGNORED))
        pending = self._planner.submit(lambda cfg: self._pose_goal(request.goal, cfg),
                                       '~/plan')
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
        response.success, response.message = self._planner.cancel_goal(
            'goal canceled by ~/cancel_goal')
        return response

    def _heartbeat(self):
        self._planner.brake_if_overdue(self.settings())    # also when joint_states stop
        progress = self._planner.progress.due()
        if progress is not None:
            self.report(schema.running_report(progress))

    # -- markers ------------------------------------------------------------------------------

    def _publish_markers_if_dirty(self):
        with self._lock:
            dirty = self._arm_dirty
        if dirty:
            self.publish_markers()

    def publish_markers(self):
        """Draw the obstacles, the arm and the executing plan's path."""
        with self._lock:
            config = self._config
            arm = self._measured
            self._arm_dirty = False
            self._arm_drawn = arm
        path_states, plan_info, revision = self._planner.plans.drawing()
        if config.is_arm:
            self._marker_pub.publish(arm_markers(config, self.get_clock().now().to_msg(),
                                                 path_states, arm, plan_info, revision))
            return
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
