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
``obstacles``; at most ``obstacles.max_count`` circles).  ``~/ready`` (std_srvs/Trigger)
answers success once the numba kernels are loaded.

One worker thread solves; only the newest goal is solved (a new goal preempts the running
solve, a queued one is answered as superseded), ``~/cancel`` stops it.  The subscriptions and
services exist from the start; the numba kernels load in the background and goals that
arrive meanwhile are queued and solved once ready.  While it solves, ``~/progress`` reports at
>= 5 Hz, and once at the end with the status: level OK for SOLVED, WARN for SOLVED_INACCURATE
(paper mode's heuristic, trajectory published anyway), CANCELED and TIMEOUT, ERROR for
failures and refused input (message = the reason).  ``trajectory`` (transient local) is
published for SOLVED and SOLVED_INACCURATE results only, together with ``planned_path`` and
``markers``; the result on ``~/progress`` and the markers name the obstacle set it was planned
for (``obstacles_hash``) and the revision of the planning data (``data_revision``).

Replanning (fast mode, replan.rate > 0): while a plan executes, replan cycles solve to the
same goal from the latest joint_states, predicted forward to the new plan's start
(header.stamp = now + lead) along the executing plan, warm-started from that plan's rest; a
cycle's plan is published only when solved before its stamp, else the executing plan is kept
(~/progress event replan_kept).  Goals go first: a cycle never preempts a goal.  With
replan.estimate the cycles plan with model parameters estimated online from the joint_states
efforts (core/estimation.py).

No plan for stale data: when the obstacles, the margin, the robot data or the extension
limits change during a goal's solve, the solve restarts from the same goal and the latest
state (a replan cycle's plan is published only if it satisfies the data current at its end);
when they change while a published trajectory is still executing and its remaining part
now cuts an (inflated) obstacle or exceeds u_max, a replan cycle plans around them at once
while braking can still wait for it (the plan stays out of the true circles until the cycle's
outcome is known, and the fastest stop started then still keeps out of them:
_brake_can_wait); otherwise, or when that fails, a braking trajectory (an empty one without a
measured state) is published at once and the goal is planned again from the measured state.

Run: ``ros2 run toc_ros solver_node --ros-args --params-file config/toc_ros.yaml``
"""

import collections
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
from toc_ros import conversions, progress as schema
from toc_ros.config import (model_from_parameters, obstacle_rows, options_from_parameters,
                            problem_from_parameters)
from toc_ros.core import ModelError, ProblemError, Progress, solve, Status, warm_up
from toc_ros.core.estimation import estimate_text, ParameterEstimator
from toc_ros.core.models import CylindricalRobot, with_actuator_lag
from toc_ros.core.obstacles import model_clearance
from toc_ros.core.replan import brake, predict, stop_later_is_clear
from toc_ros.core.result import CLEARANCE_TOL
from toc_ros.nodes import parameters
from toc_ros.nodes.common import run_node
from trajectory_msgs.msg import JointTrajectory
from visualization_msgs.msg import MarkerArray

PARAMETER_NAMES = parameters.SOLVER_NODE_NAMES
# Parameters a plan depends on beyond its goal: a change restarts the running solve and
# re-checks the executing trajectory.
PLANNING_PREFIXES = ('obstacles.', 'robot.', 'extension_limits')
# ~/progress while solving: the core reports every 0.1 s; the heartbeat fills gaps (set-up,
# slow iterations) so that no gap exceeds MAX_PROGRESS_GAP_S.
HEARTBEAT_PERIOD_S = 0.05
MAX_PROGRESS_GAP_S = 0.15
# Fewest remaining plan nodes for which a replan warm-starts from the executing plan.
MIN_WARM_NODES = 20
# A replan cycle needs at least this many nodes of the executing plan left (a cycle keeps its
# plan's grid, so near the end of a plan cut to replan.max_nodes few are left).
MIN_CYCLE_GUESS_NODES = 5
# A joint_states stamp further than this from the node clock is from another time base
# (publish_clock without use_sim_time, say): its age is then taken as zero.
MAX_STATE_AGE_S = 1.0
# [rad/s, m/s] joint speeds up to which a goal's start is at rest (its plan starts start_lead
# after it is published).
REST_SPEED = 1e-3
MIN_CYCLE_TIMEOUT_S = 0.002
# The lead grows with the measured cycle latency (the median of the last LATENCY_WINDOW cycles,
# x LEAD_PER_MEDIAN) up to MAX_LEAD_S.
LATENCY_WINDOW = 20
MAX_LEAD_S = 0.2
# The lead is at least this many times the median of recent cycle latencies (_cycle_lead).
LEAD_PER_MEDIAN = 2.0
# [s] a cycle's solve may run this long past its deadline: not published, its plan warm-starts
# the next cycle (a new switching structure takes one slow solve, then the next is fast).  Not
# longer: the solves that need more (an overshoot in the final braking: 700-2000 iterations)
# would take a core from the plant for 0.1-0.2 s and delay the next cycles.
SEED_EXTRA_S = 0.05
CYCLE_SOURCE = 'replan_cycle'     # goal_source of the replan cycles' ~/progress reports
MARKER_PERIOD_S = 0.2
ARM_REDRAW = 1e-3     # [rad, m, rad/s, m/s] state change that redraws the arm marker
# How long ~/cancel waits for the solve to stop (the core stops within ~0.1 s).
CANCEL_WAIT_S = 2.0
# Before a solve starts, the worker waits until no goal arrived for QUIET_S (at most
# SETTLE_MAX_S): after a burst the executor takes the newer goals first, so only the newest
# is solved.  A goal with no other goal within QUIET_S before it waits only QUIET_FIRST_S (the
# goals of a burst follow each other within a fraction of a millisecond; a goal arriving in
# that window turns the wait into the burst's QUIET_S), so a single goal starts at once.
QUIET_S = 0.05
QUIET_FIRST_S = 0.005
SETTLE_MAX_S = 0.5
# Queue depth of the services: every request of a burst is kept and answered.
SERVICE_QOS = QoSProfile(depth=100)
# The cycles' model follows the online estimate when a parameter moved by more than this
# (relative) from the one planned with.
ESTIMATE_CHANGE = 0.01
# A published trajectory is "executing" until its duration plus this has passed.
EXECUTION_SLACK_S = 0.5
# New data that puts a true (uninflated) obstacle on the executing plan brakes at once unless
# braking can wait for a replan: the plan stays out of the true obstacles until the replan's
# outcome is known (its lead + SEED_EXTRA_S + BRAKE_HORIZON_S from now), and the fastest stop
# started then still keeps every link out of them (_brake_can_wait).  So the lead, which grows
# with the measured cycle latency on a loaded machine, moves the braking decision earlier.
BRAKE_HORIZON_S = 0.1
BRAKE_STEP_S = 0.002
# Step of the stop simulated to decide whether braking can wait (_brake_can_wait): its path
# stays within 3e-4 (rad, m) of the BRAKE_STEP_S one, at a sixth of the time (~0.8 ms).
BRAKE_CHECK_STEP_S = 0.01


def parameter_errors(params):
    """
    Everything wrong with a candidate set of solver_node parameters (empty: valid).

    Whether start and goal states clear the obstacles is checked per request, against the
    measured start state, not here.
    """
    try:
        model = model_from_parameters(params)
    except ProblemError as exc:
        return [str(exc)]
    errors = parameters.joint_name_errors(params['joint_names'], model.n_joints, model.name)
    if params['replan.estimate']:
        try:
            ParameterEstimator(model.joint_model, params['replan.estimate'],
                               float(params['replan.estimate_window']))
        except ModelError as exc:
            errors.append(f'replan.estimate: {exc}')
    if not str(params['base_frame']).strip('/'):
        errors.append('base_frame must not be empty')
    limit_errors = parameters.vector_errors('extension_limits', params['extension_limits'], 2)
    if not limit_errors and not params['extension_limits'][0] < params['extension_limits'][1]:
        limit_errors = [f'extension_limits must be [q2_min, q2_max] with q2_min < q2_max, got '
                        f'{params["extension_limits"]}']
    errors += limit_errors
    count, limit = len(params['obstacles.x']), int(params['obstacles.max_count'])
    if count > limit:
        errors.append(f'{count} obstacles exceed obstacles.max_count = {limit}')
        return errors      # no per-obstacle work on a refused set
    state_errors = (
        parameters.vector_errors('initial_state', params['initial_state'], 2 * model.n_joints)
        + parameters.vector_errors('goal_state', params['goal_state'], 2 * model.n_joints))
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


def model_keys(params):
    """Return the robot-model values of ~/progress: the recording says what was planned for."""
    return {'robot_model': str(params['robot.model']),
            'model_parameters': ', '.join(params['robot.model_parameters'])}


def planning_data(params):
    """Return the parameter values a plan depends on beyond its goal (one revision's data)."""
    return {k: v for k, v in params.items()
            if k.startswith(PLANNING_PREFIXES) and k != 'obstacles.max_count'}


def obstacle_count(msg):
    """Rows of an obstacles message, counted without reading the data (the limit check)."""
    dims = list(msg.layout.dim)
    if dims:
        return int(dims[0].size)
    return len(msg.data) // 3


def recovery_params(params, start):
    """
    Return params with obstacles.margin reduced so that start clears the inflated circles.

    For the replan after a stop: braking may end inside the margin (never inside a true
    circle, which the plans keep out of), and the plan out of there may use half the start's
    true clearance as its margin.  None when start clears the margin or is inside a circle.
    """
    try:
        model = model_from_parameters(params)
        rows = np.asarray(obstacle_rows(params), dtype=float).reshape(-1, 3)
    except ProblemError:
        return None
    if not len(rows) or np.shape(start) != (model.nx,):
        return None
    gap = float(np.min(model_clearance(model, np.asarray(start)[None, :], rows)))
    margin = float(params['obstacles.margin'])
    if gap >= margin or gap <= 0.0:
        return None
    return dict(params, **{'obstacles.margin': 0.5 * gap})


def nearest_node(model, states, x):
    """
    Return the index of the plan node nearest to state x in the joints' states.

    The plant lags or leads the plan's clock (mismatch, tracking error), so a warm start from
    the node nearest in state, scaled by each coordinate's spread along the plan, fits better
    than the node at the elapsed time.
    """
    states, x = model.joint_states(states), model.joint_states(np.asarray(x))
    scale = np.maximum(np.ptp(states, axis=0), 1e-6)
    return int(np.argmin(np.sum(((states - x) / scale) ** 2, axis=1)))


class _Request:
    """One goal on its way through the worker (a restart keeps the same request)."""

    def __init__(self, goal, source):
        self.goal = np.asarray(goal, dtype=float)
        self.source = source
        self.stop_reason = None          # set when preempted or canceled
        self.restart_reason = None       # set when the planning data changed during the solve
        self.event = ''                  # schema event of its result (e.g. a replacement)
        self.result = None               # SolveResult once solved (None when dropped)
        self.cycle = None                # a replan cycle's data (_Cycle), None for goals
        self.published_at = None         # time.monotonic() when its trajectory was published
        self.late = False                # a cycle's plan was ready only after its deadline
        self.path = None                 # nav_msgs/Path when a trajectory was published
        self.done = threading.Event()
        self._lock = threading.Lock()
        self._callbacks = []

    def on_done(self, callback):
        """Call callback() once the request is done (at once if it is)."""
        with self._lock:
            if not self.done.is_set():
                self._callbacks.append(callback)
                return
        callback()

    def finish(self):
        """Mark the request done and run the on_done callbacks."""
        with self._lock:
            self.done.set()
            callbacks, self._callbacks = self._callbacks, []
        for callback in callbacks:
            callback()


@dataclasses.dataclass
class _Cycle:
    """One replan cycle: the plan it replaces and the state it starts from."""

    plan: dict              # the executing plan (_executing) when the cycle started
    start: np.ndarray       # state predicted at stamp_s
    stamp_s: float          # the new plan's header.stamp [s, node clock]
    received: float         # time.monotonic() when its joint_states arrived
    state_stamp: float      # that joint_states' header.stamp [s]
    deviation: float        # max |q - q_ref| of the measured state [rad or m]
    reason: str             # 'rate', 'deviation' or 'data change'
    revision: int = -1      # the data revision when it started
    deadline: float = math.inf      # publish by then: received + lead [s, time.monotonic()]


@dataclasses.dataclass
class _Braking:
    """A braking stop as conversions.trajectory_msg takes it (time grid, states, controls)."""

    time_grid: np.ndarray
    states: np.ndarray
    controls: np.ndarray


class _Worker:
    """A thread solving one request at a time; the newest request preempts older ones."""

    def __init__(self, run, drop, ready, logger):
        self._run = run          # run(request, cancel_event): solve and publish
        self._drop = drop        # drop(request, reason, event): report a request never started
        self._ready = ready      # threading.Event: the kernels are loaded
        self._logger = logger
        self._cond = threading.Condition()
        self._pending = None
        self._active = None
        self._cancel = None
        self._stopping = False
        self._last_submit = -math.inf
        self._gap = math.inf     # [s] between the last two submits
        self._thread = threading.Thread(target=self._loop, name='solver', daemon=True)
        self._thread.start()

    def submit(self, request):
        """Queue request, dropping a queued one and canceling the running one."""
        with self._cond:
            dropped, self._pending = self._pending, request
            now = time.monotonic()
            self._gap, self._last_submit = now - self._last_submit, now
            if self._active is not None:
                self._active.stop_reason = 'preempted by a newer goal'
                self._cancel.set()
            self._cond.notify_all()
        if dropped is not None:
            self._drop(dropped, 'superseded by a newer goal before its solve started')

    def offer(self, request, behind_cycle=False):
        """
        Queue a replan cycle when idle (goals go first); True when taken.

        behind_cycle: also queue it behind a running cycle (new data cannot wait for the
        next regular cycle).
        """
        with self._cond:
            active = self._active
            waits = active is not None and active.cycle is not None and (
                behind_cycle or self._cancel.is_set())
            pending_goal = self._pending is not None and self._pending.cycle is None
            if (active is not None and not waits) or pending_goal or self._stopping:
                return False
            self._pending = request      # a newer cycle replaces a queued one
            self._cond.notify_all()
        return True

    def restart(self, reason):
        """Stop the running solve and solve its goal again (unless a newer goal is queued)."""
        with self._cond:
            active = self._active
            # A replan cycle runs on: its plan is checked against the data current when it
            # ends (obstacles may change faster than a cycle solves).
            if active is not None and active.stop_reason is None and active.cycle is None:
                active.restart_reason = reason
                self._cancel.set()
                return True
        return False

    def cancel(self):
        """Stop the running solve and drop a queued one; True when a solve was stopped."""
        with self._cond:
            dropped, self._pending = self._pending, None
            active = self._active
            if active is not None:
                active.stop_reason = 'canceled by ~/cancel'
                active.restart_reason = None
                self._cancel.set()
        if dropped is not None:
            self._drop(dropped, 'canceled by ~/cancel before its solve started', '')
        return active is not None and active.done.wait(CANCEL_WAIT_S)

    def busy(self):
        """Tell whether a request is queued or solving."""
        with self._cond:
            return self._active is not None or self._pending is not None

    def goal_busy(self):
        """Tell whether a goal (not a replan cycle) is queued or solving."""
        with self._cond:
            return any(r is not None and r.cycle is None for r in (self._active, self._pending))

    def stop(self):
        """Cancel everything and end the thread."""
        with self._cond:
            self._stopping = True
            if self._cancel is not None:
                self._cancel.set()
            dropped, self._pending = self._pending, None
            self._cond.notify_all()
        if dropped is not None:
            dropped.finish()
        self._thread.join(timeout=CANCEL_WAIT_S)

    def _next(self):
        """Wait for the kernels and a request, let a burst settle; None when stopping."""
        while not self._ready.wait(0.1):
            with self._cond:
                if self._stopping:
                    return None
        with self._cond:
            while self._pending is None and not self._stopping:
                self._cond.wait()
            settle_end = time.monotonic() + SETTLE_MAX_S
            while (not self._stopping and self._pending is not None
                   and self._pending.cycle is None):
                wait_s = QUIET_S if self._gap < QUIET_S else QUIET_FIRST_S
                quiet = self._last_submit + wait_s - time.monotonic()
                if quiet <= 0.0 or time.monotonic() >= settle_end:
                    break
                self._cond.wait(min(quiet, settle_end - time.monotonic()))
            if self._stopping or self._pending is None:
                return None
            request, self._pending = self._pending, None
            self._active, self._cancel = request, threading.Event()
            return request, self._cancel

    def _loop(self):
        while True:
            taken = self._next()
            if taken is None:
                with self._cond:
                    if self._stopping:
                        return
                continue
            request, cancel = taken
            try:
                self._run(request, cancel)
            except Exception as exc:  # noqa: B902 - a bug must not end the worker thread
                self._logger.error(f'solve of goal from {request.source} failed: {exc!r}')
                request.restart_reason = None
            with self._cond:
                self._active = None
                again = (request.restart_reason is not None and self._pending is None
                         and not self._stopping)
                if again:
                    self._pending = request
                superseded = request.restart_reason is not None and not again
                request.restart_reason = None
            if superseded:
                self._drop(request, 'superseded by a newer goal while restarting')
            elif not again:
                request.finish()


class SolverNode(Node):
    """Plans minimum-time trajectories on goals; see the module docstring."""

    def __init__(self, **kwargs):
        super().__init__('solver_node', **kwargs)
        parameters.declare(self, PARAMETER_NAMES)
        self._params = parameters.values(self, PARAMETER_NAMES)
        errors = parameter_errors(self._params)
        if errors:
            raise parameters.ParameterError('; '.join(errors))
        self._name = self.get_fully_qualified_name()
        self._lock = threading.Lock()       # guards the fields below, shared with the worker
        self._measured = None               # latest joint state from joint_states
        self._measured_effort = None        # and its efforts (None: not given or not used)
        self._arm_dirty = True
        self._arm_drawn = None              # state drawn by the last markers
        self._progress = None               # (Progress, solve start) of the running solve
        self._progress_sent = 0.0
        self._publish_lock = threading.Lock()
        # Planning data: revision counter and the plan in execution, guarded by _plan_lock
        # (a trajectory is published only while its data revision is still current).
        self._plan_lock = threading.Lock()
        self._revision = 0
        self._planning = planning_data(self._params)
        self._executing = None              # dict of the last published plan
        self._seed = None                   # a late cycle's plan: the next cycle's warm start
        self._plan_info = None              # (hash, revision) of the last published plan
        self._next_cycle = 0.0              # time.monotonic() of the next replan.rate cycle
        self._latencies = collections.deque(maxlen=LATENCY_WINDOW)   # of recent cycles [s]
        # Online estimation (replan.estimate): fed by joint_states, read by the cycles.
        self._estimation_lock = threading.Lock()
        self._estimator = None
        self._estimator_key = None
        self._planning_estimate = None      # (values, model) the cycles plan with
        self._ready = threading.Event()
        self._started = time.monotonic()
        self._kernel_load_s = None
        self._model = model_from_parameters(self._params)
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
        self.create_service(Trigger, '~/cancel', self._on_cancel, qos_profile=SERVICE_QOS,
                            callback_group=MutuallyExclusiveCallbackGroup())
        self.create_service(Trigger, '~/ready', self._on_ready, qos_profile=SERVICE_QOS,
                            callback_group=MutuallyExclusiveCallbackGroup())
        timers = MutuallyExclusiveCallbackGroup()
        self.create_timer(HEARTBEAT_PERIOD_S, self._heartbeat, callback_group=timers)
        self.create_timer(MARKER_PERIOD_S, self._publish_markers_if_dirty,
                          callback_group=timers)
        self._worker = _Worker(self._run, self._drop, self._ready, self.get_logger())
        self._publish_markers()
        # Compile or load the numba kernels in the background: the node already listens, and
        # goals that arrive meanwhile are queued.
        threading.Thread(target=self._warm_up, name='warm_up', daemon=True).start()

    def _warm_up(self):
        started = time.monotonic()
        try:
            warm_up(None if isinstance(self._model, CylindricalRobot) else [self._model])
        except Exception as exc:  # noqa: B902 - reported; solves then compile on demand
            self.get_logger().error(f'loading the numba kernels failed: {exc!r}')
        elapsed = time.monotonic() - started
        self.get_logger().info(f'numba kernels loaded in {elapsed:.2f} s')
        self._kernel_load_s = elapsed
        self._ready.set()
        self._publish_progress(schema.ProgressReport(
            message=f'ready: numba kernels loaded in {elapsed:.2f} s', elapsed_s=elapsed,
            event=schema.EVENT_READY, **model_keys(self._params)))
        with self._lock:
            params = dict(self._params)
        self.get_logger().info(
            f"ready: {len(params['obstacles.x'])} obstacle(s), mode "
            f"{params['solver.mode']}, N = {params['solver.N']}")

    def _load_kernels_of(self, params):
        """
        Load the kernels of a new robot model in the background (goals wait for them).

        E.g. robot.actuator_lag or robot.model set at run time: the new model's kernels are
        compiled (or loaded from the cache) before any goal is solved with it, as at start-up.
        """
        try:
            model = model_from_parameters(params)
        except ProblemError:
            return              # refused by the parameter check before it gets here
        previous, self._model = self._model, model
        if model.kernels is previous.kernels:
            return
        self._ready.clear()
        self.get_logger().info(f'robot model changed: loading the kernels of {model!r}')
        threading.Thread(target=self._warm_up, name='warm_up', daemon=True).start()

    def ready(self):
        """Tell whether the kernels are loaded (goals before that are queued)."""
        return self._ready.is_set()

    def _on_ready(self, _request, response):
        response.success = self._ready.is_set()
        response.message = (
            f'ready: numba kernels loaded in {self._kernel_load_s:.2f} s' if response.success
            else f'loading the numba kernels ({time.monotonic() - self._started:.1f} s so '
                 'far); goals are queued until then')
        return response

    # -- parameters ---------------------------------------------------------------------------

    def _on_set_parameters(self, changed):
        with self._lock:
            params = parameters.candidate(self._params, changed)
        result = parameters.result(parameter_errors(params))
        if not result.successful:
            self.get_logger().warning(f'refused parameter change: {result.reason}')
            if any(p.name.startswith('robot.model') for p in changed):
                self._publish_progress(schema.refusal_report(
                    f'parameters: refused robot model: {result.reason}'))
        return result

    def _after_set_parameters(self, changed):
        if any(p.name in ('replan.lead', 'robot.model', 'robot.actuator_lag') for p in changed):
            with self._lock:    # another lead or model: cycle latencies measured afresh
                self._latencies.clear()
        if any(p.name.startswith('replan.estimate') for p in changed):
            with self._estimation_lock:     # set (even to the same value): start afresh
                self._estimator, self._estimator_key = None, None
                self._planning_estimate = None
        with self._lock:
            self._params = parameters.candidate(self._params, changed)
            self._arm_dirty = True   # obstacles or frames may have changed
            params = dict(self._params)
        if any(p.name.startswith('robot.') for p in changed):
            self._load_kernels_of(params)
        planning = planning_data(params)
        with self._plan_lock:
            if planning == self._planning:
                return
            self._planning = planning
            self._revision += 1
            revision = self._revision
        reason = f'planning data changed (data revision {revision})'
        if self._worker.restart(reason):
            self.get_logger().warning(f'{reason}: restarting the running solve')
            self._publish_progress(schema.ProgressReport(
                message=f'{reason}: solving again from the latest state',
                event=schema.EVENT_RESTARTED, data_revision=revision))
        self._check_executing(params, revision)

    def _check_executing(self, params, revision):
        """Replan around, or stop, an executing trajectory that violates the current data."""
        with self._plan_lock:
            plan = self._executing
            if plan is None or revision != self._revision:
                return
            elapsed = self._now() - plan['start']
            if elapsed > plan['duration'] + EXECUTION_SLACK_S:
                self._executing = None
                return
            violation = self._violation(plan, params, elapsed)
            if violation is None:
                return
        measured = self._snapshot()[1]
        if measured is not None and self._brake_can_wait(plan, params, measured, elapsed) \
                and self._maybe_replan(params, measured, self._now(), time.monotonic(),
                                       reason='data change'):
            self.get_logger().warning(
                f'the executing trajectory {violation} under data revision {revision}: '
                'replanning from the current state')
            return
        self._stop(plan, params, revision, violation)

    def _stop(self, plan, params, revision, violation):
        """
        Stop the executing plan at once and plan its goal again (unless a goal is queued).

        With a measured state the stop is a braking trajectory (every joint decelerates at
        its control bound until it rests); without one an empty trajectory (the plant holds).
        """
        measured = self._snapshot()[1]
        stop = JointTrajectory()
        stop.joint_names = list(params['joint_names'])
        braking = None
        model = plan.get('model')
        if measured is not None and model is not None and measured.shape[0] == model.nx:
            times, states, controls = brake(model, measured, BRAKE_STEP_S)
            braking = _Braking(times, states, controls)
            stop = conversions.trajectory_msg(braking, params['joint_names'], model,
                                              conversions.time_msg(0.0))
        with self._plan_lock:
            if revision != self._revision or self._executing is not plan:
                return        # newer data or a newer plan took over meanwhile
            self._trajectory_pub.publish(stop)
            self._executing = None if braking is None else {
                'start': self._now(), 'duration': float(braking.time_grid[-1]),
                'times': braking.time_grid, 'states': braking.states,
                'controls': braking.controls, 'goal': plan['goal'], 'source': 'brake',
                'path_states': plan['path_states'], 'result': None, 'model': model}
        replan = not self._worker.goal_busy()
        how = 'braking to rest' if braking is not None else 'stopped'
        reason = (f'the executing trajectory {violation} under data revision {revision}: '
                  f'{how}' + (', planning the goal again' if replan else ''))
        self.get_logger().warning(reason)
        self._publish_progress(schema.ProgressReport(
            status=Status.CANCELED, message=reason, level=schema.DiagnosticStatus.WARN,
            goal_source=plan['source'], data_revision=revision, event=schema.EVENT_STOPPED))
        if replan:
            request = self._submit(lambda _params: plan['goal'], 'replan')
            if request is not None:
                request.event = schema.EVENT_REPLACED

    @staticmethod
    def _true_conflict_time(plan, params, elapsed):
        """Return the time [s] until the plan's rest enters a true obstacle (None: never)."""
        model = plan.get('model')
        try:
            rows = obstacle_rows(params)
        except ProblemError:
            return None
        if model is None or not rows or model.nx != plan['states'].shape[1]:
            return None
        rest = plan['times'] >= elapsed
        if not rest.any():
            return None
        gaps = model_clearance(model, plan['states'][rest], np.asarray(rows, dtype=float))
        inside = np.min(gaps, axis=1) < 0.0
        if not inside.any():
            return None
        return float(plan['times'][rest][int(np.argmax(inside))] - elapsed)

    def _brake_can_wait(self, plan, params, measured, elapsed):
        """
        Return whether a plan that violates new data may run on while a replan is tried.

        Yes when it never enters a true (uninflated) obstacle, or when it stays out of them
        for the wait (the cycle lead, as _maybe_replan will set it, + SEED_EXTRA_S +
        BRAKE_HORIZON_S) and the fastest stop (replan.brake) from the state predicted at the
        wait's end (measured: the latest joint state, at plan time elapsed) keeps every link
        out of them: braking later than that could no longer stop clear.
        """
        conflict = self._true_conflict_time(plan, params, elapsed)
        if conflict is None:
            return True
        wait = self._cycle_lead(params) + SEED_EXTRA_S + BRAKE_HORIZON_S
        model = plan.get('model')
        if conflict <= wait or model is None or np.shape(measured) != (model.nx,):
            return False
        try:
            return stop_later_is_clear(model, measured, plan['times'], plan['controls'],
                                       elapsed, wait, obstacle_rows(params), BRAKE_CHECK_STEP_S)
        except (ProblemError, ValueError, FloatingPointError):
            return False

    @staticmethod
    def _violation(plan, params, elapsed):
        """Return what the rest of a published plan violates under params, or None."""
        try:
            problem = problem_from_parameters(params, x0=plan['states'][0],
                                              x_goal=plan['goal'])
        except ProblemError as exc:
            return f'cannot be checked ({exc})'
        model = problem.robot_model
        if model.nx != plan['states'].shape[1]:
            return f'was planned for another robot model (now {model.name!r})'
        rest = plan['times'] >= elapsed
        if rest.any():
            rest[max(int(np.argmax(rest)) - 1, 0)] = True     # the segment being executed
        else:
            rest[-1] = True                                   # at rest at the goal
        states = plan['states'][rest]
        circles = problem.circles()
        if len(circles):
            gaps = model_clearance(model, states, circles)
            worst = float(np.min(gaps))
            if worst < -CLEARANCE_TOL:
                k = int(np.argmin(np.min(gaps, axis=0))) % len(circles)
                return f'cuts obstacle {k} by {-worst:.3g} m'
        controls = plan['controls'][rest[:len(plan['controls'])]]
        if len(controls):
            excess = float(np.max(np.abs(controls) - np.asarray(model.u_max)[None, :]))
            if excess > 0.0:
                return f'exceeds u_max by {excess:.3g}'
        return None

    def _snapshot(self):
        """Return (parameters, the measured state of their model or None)."""
        with self._lock:
            params, joints, effort = dict(self._params), self._measured, self._measured_effort
        return params, (None if joints is None else self._model_state(joints, effort))

    # -- inputs -------------------------------------------------------------------------------

    def _on_joint_states(self, msg):
        with self._lock:
            names = self._params['joint_names']
        try:
            state = conversions.joint_state_to_state(msg, names)
            # The applied efforts are the actuator states of a model with actuator lag.
            effort = (conversions.joint_state_efforts(msg, names)
                      if self._params['robot.actuator_lag'] > 0.0 else None)
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
            params = self._params
        state_time = stamp if stamp > 0.0 else self._now()
        if params['replan.estimate']:
            self._estimate_from(msg, params, state, state_time)
        self._maybe_replan(params, self._model_state(state, effort), state_time, received)

    def _model_state(self, joints, effort=None):
        """
        Return the current model's state from a measured joint state and its efforts.

        A model with actuator states (robot.actuator_lag) takes the efforts as the applied ones
        (without them: the torques that hold the joints' velocities); others the joint state.
        self._model follows the robot parameters (_load_kernels_of): no model is built here,
        on the joint_states path.
        """
        try:
            return self._model.full_state(joints, effort)
        except ValueError:          # e.g. efforts for another joint count: the joint state
            return np.array(joints, dtype=float)

    def _estimate_from(self, msg, params, state, state_time):
        """Feed the online estimator (replan.estimate) with one joint_states sample."""
        try:
            effort = conversions.joint_state_efforts(msg, params['joint_names'])
        except conversions.ConversionError as exc:
            effort, why = None, str(exc)
        else:
            why = 'joint_states carry no effort'
        if effort is None:
            self.get_logger().warning(f'replan.estimate: {why}; nothing estimated',
                                      throttle_duration_sec=5.0)
            return
        # The joints' model (self._model follows the robot parameters: none is built on the
        # joint_states path); the efforts are the applied ones, after any actuator lag.
        key = (self._model.joint_model, tuple(params['replan.estimate']),
               float(params['replan.estimate_window']))
        with self._estimation_lock:
            if key != self._estimator_key:      # new robot data or estimation settings
                self._estimator = ParameterEstimator(*key)
                self._estimator_key = key
                self._planning_estimate = None
            self._estimator.add(state_time, state[0::2], state[1::2], effort)

    def _estimated_model(self, params):
        """
        Return (model with the online estimate or None, its text or the reason for none).

        The model planned with changes only when the estimate moved by more than
        ESTIMATE_CHANGE from it: successive cycles then solve the same problem, and each
        warm start (the previous cycle's optimum) stays nearly optimal.
        """
        if not params['replan.estimate']:
            return None, ''
        with self._estimation_lock:
            estimator = self._estimator
            if estimator is None or estimator.model_ != self._model.joint_model:
                return None, 'no samples yet'
            values = estimator.estimate()
            if values is None:
                self._planning_estimate = None
                return None, estimator.status
            held = self._planning_estimate
            if held is None or held[0].keys() != values.keys() or any(
                    abs(values[k] - held[0][k]) > ESTIMATE_CHANGE * abs(held[0][k])
                    for k in values):
                model = estimator.model(values)
                if model is None:
                    return None, estimator.status
                model = with_actuator_lag(model, params['robot.actuator_lag'])
                held = self._planning_estimate = (values, model)
            return held[1], estimate_text(held[0])

    # -- replanning (receding horizon) ----------------------------------------------------------

    def _now(self):
        """Return the node clock's time [s] (simulated time under use_sim_time)."""
        return self.get_clock().now().nanoseconds * 1e-9

    def _maybe_replan(self, params, state, state_time, received, reason=None):
        """
        Start a replan cycle from a measured state when one is due; True when it was queued.

        Due: at replan.rate, at once when the state deviates from the executing plan by more
        than replan.deviation, or for a reason (new data).  The cycle's plan starts at
        stamp = now + lead (replan.lead, or more when recent cycles took longer) from the state
        predicted along the executing plan, and only while more than replan.min_remaining of it
        is left; the worker takes it only when no goal is queued or solving.
        """
        rate = float(params['replan.rate'])
        if rate <= 0.0 or params['solver.mode'] != 'fast' or not self._ready.is_set():
            return False
        with self._plan_lock:
            plan, revision = self._executing, self._revision
        if plan is None or plan.get('result') is None or state.shape[0] != plan['model'].nx:
            return False
        now = self._now()
        if abs(now - state_time) > MAX_STATE_AGE_S:
            state_time = now
        measured_at = state_time - plan['start']
        if measured_at < 0.0:
            # The plan starts replan.lead after the state of the cycle that made it, and the
            # state is from before that: wait for it to apply, unless new data cannot wait;
            # then start from the plan's own start (that cycle's prediction).
            if reason is None:
                return False
            state, measured_at = plan['states'][0], 0.0
        times = plan['times']
        model = plan['model']
        q_plan = model.positions(plan['states'])
        q_ref = np.array([np.interp(measured_at, times, q_plan[:, j])
                          for j in range(q_plan.shape[1])])
        deviation = float(np.max(np.abs(model.positions(state) - q_ref)))
        limit = float(params['replan.deviation'])
        if reason is None:
            if limit > 0.0 and deviation > limit:
                reason = 'deviation'
            elif received >= self._next_cycle:
                reason = 'rate'
            else:
                return False
        # The lead covers the solve: replan.lead, or more when recent cycles took longer (a
        # loaded machine, a slower model).  New data gets the same: its first cycle usually
        # needs a new switching structure, runs late and seeds the next (_run_cycle).
        lead = self._cycle_lead(params)
        # The new plan starts on a node of the executing one (the first at or after now +
        # lead): its warm start, that plan's remainder from the node, then starts where the
        # predicted state is, not up to half an interval away (which costs iterations).
        start_at = now + lead - plan['start']
        node = int(np.searchsorted(times, start_at))
        if node < times.shape[0]:
            start_at = float(times[node])
        stamp = plan['start'] + start_at
        if plan['duration'] - start_at < float(params['replan.min_remaining']):
            return False
        start = predict(plan['model'], state, times, plan['controls'], measured_at, start_at)
        request = _Request(plan['goal'], CYCLE_SOURCE)
        request.cycle = _Cycle(plan, start, stamp, received, state_time, deviation, reason,
                               revision, received + lead)
        if not self._worker.offer(request, behind_cycle=reason == 'data change'):
            return False
        self._next_cycle = received + 1.0 / rate
        return True

    def _cycle_lead(self, params):
        """
        Return a cycle's lead [s]: replan.lead, or more when recent cycles took longer.

        More: LEAD_PER_MEDIAN x the median of the recent cycle latencies (with at least five).
        The median, not a high percentile: the rare cycle whose warm start needs a new
        switching structure (a new estimate, the final braking) runs late and seeds the next
        one (_run_cycle) instead of stretching every cycle's lead, and with it the prediction.
        """
        with self._lock:
            recent = list(self._latencies)
        latency = LEAD_PER_MEDIAN * float(np.median(recent)) if len(recent) >= 5 else 0.0
        return max(float(params['replan.lead']), latency)

    def _run_cycle(self, request, cancel):
        """Solve one replan cycle (worker thread); publish it or keep the executing plan."""
        cycle, plan = request.cycle, request.cycle.plan
        params = self._snapshot()[0]
        with self._plan_lock:
            revision = self._revision
            if self._executing is not plan:
                return          # a newer plan was published meanwhile: nothing to replace
            seed = self._seed
        # The warm start: the executing plan, or a late cycle's plan for it (when the data
        # changed since, still closer to the new optimum than the executing plan).
        source = plan if seed is None or seed['plan'] is not plan else seed
        result, problem, why = None, None, ''
        estimated, estimate = self._estimated_model(params)
        try:
            guess = source['result'].remainder(source['times'][nearest_node(
                source['model'], source['states'], cycle.start)])
            problem = problem_from_parameters(params, x0=cycle.start, x_goal=plan['goal'])
            if estimated is not None:
                problem = problem.with_model(estimated)
            # The remainder's own grid (same tau: the warm start is then nearly optimal), cut
            # to replan.max_nodes intervals (resampling to another grid each cycle would move
            # the control switches off it and cost many more iterations), but with steps no
            # longer than the model's max_step (actuator lags; 2 % to spare: the plan's t_f
            # may grow a little, and its remainders keep its grid).
            nodes = max(min(guess.controls.shape[0], int(params['replan.max_nodes'])),
                        math.ceil(1.02 * guess.final_time / problem.robot_model.max_step))
            problem = dataclasses.replace(problem, n_intervals=nodes)
            # A cycle's plan is published only by its deadline (its lead after its joint_states
            # arrived; the stamp, on the next plan node, may be later): the lead bounds the
            # latency.  A solve that runs late goes on for up to SEED_EXTRA_S, and its plan
            # seeds the next cycle's warm start.
            options = options_from_parameters(params)
            options = dataclasses.replace(options, timeout=max(min(
                cycle.deadline - time.monotonic() + SEED_EXTRA_S, options.timeout or math.inf),
                MIN_CYCLE_TIMEOUT_S))
            if guess.controls.shape[0] < MIN_CYCLE_GUESS_NODES:
                why = f'only {guess.controls.shape[0]} plan nodes left'
            else:
                result = solve(problem, options, cancel=cancel, initial_guess=guess)
        except (ProblemError, TypeError, ValueError) as exc:
            why = f'no plan from the predicted state: {exc}'
        except Exception as exc:  # noqa: B902 - a core bug must not kill the worker thread
            self.get_logger().error(f'replan cycle failed: {exc!r}')
            why = f'internal solver error: {exc!r}'
        published = False
        if result is not None:
            if result.status is not Status.SOLVED or not result.has_trajectory:
                why = f'{result.status.value}: {request.stop_reason or result.message}'
            else:
                # Published only when its message is ready by the deadline (else late).
                request.late = time.monotonic() > cycle.deadline
                published = not request.late and self._publish_plan(
                    request, result, problem, params, revision, stamp_s=cycle.stamp_s)
                if request.late:
                    why = (f'late: ready {1e3 * (time.monotonic() - cycle.deadline):.1f} ms after '
                           f'its deadline ({1e3 * (cycle.deadline - cycle.received):.0f} ms '
                           'after its joint_states); it seeds the next cycle')
                    self._seed_next(plan, result, problem)
                elif not published:
                    why = 'the planning data changed during the cycle and the plan ' \
                          'violates the new data'
        # joint_states received -> trajectory published (the path and markers come after).
        latency = (request.published_at if published else time.monotonic()) - cycle.received
        if result is not None and result.status is Status.SOLVED:
            # Solved cycles, published or late: the median follows cycles that are slow most
            # of the time, not the rare one that seeds the next.  Not timed-out ones: those
            # are the final braking's overshoot problems, hundreds of iterations whatever the
            # lead (they would stretch every later cycle's lead to the cap).
            with self._lock:
                self._latencies.append(min(latency, MAX_LEAD_S / LEAD_PER_MEDIAN))
        values = dict(goal_source=CYCLE_SOURCE, start_source='predicted joint_states',
                      goal=tuple(float(v) for v in np.round(plan['goal'], 9)),
                      data_revision=revision, latency_s=latency, deviation=cycle.deviation,
                      plan_stamp=cycle.stamp_s, state_stamp=cycle.state_stamp,
                      estimate=estimate if estimated is not None else
                      (f'none: {estimate}' if estimate else ''), **model_keys(params))
        if problem is not None:
            values['obstacles_hash'] = schema.obstacles_hash(problem.obstacles, problem.margin)
        if published:       # the data it was checked against
            with self._plan_lock:
                values['obstacles_hash'], values['data_revision'] = self._plan_info
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

    def _seed_next(self, plan, result, problem):
        """Keep a late cycle's plan: the next cycle for the same executing plan starts there."""
        with self._plan_lock:
            if self._executing is plan:
                self._seed = {'plan': plan, 'result': result,
                              'times': np.asarray(result.time_grid),
                              'states': np.asarray(result.states), 'model': problem.robot_model}

    def _stop_if_violating(self, plan, params, cycle, late=False):
        """
        After a failed cycle: act on the plan it kept if that violates the current data.

        A data-change cycle is tried first unless this cycle was one (on the same data, not
        late) or braking cannot wait for it (_brake_can_wait); else the plan is stopped.
        """
        with self._plan_lock:
            revision = self._revision
            if self._executing is not plan:
                return
        elapsed = self._now() - plan['start']
        violation = self._violation(plan, params, elapsed)
        if violation is None:
            return
        measured = self._snapshot()[1]
        # Try again unless this was a data-change cycle on the same data that failed (it would
        # fail alike); a late one seeded the next, which starts where it ended.
        again = cycle.reason != 'data change' or cycle.revision != revision or late
        if again and measured is not None \
                and self._brake_can_wait(plan, params, measured, elapsed) \
                and self._maybe_replan(params, measured, self._now(), time.monotonic(),
                                       reason='data change'):
            return
        self._stop(plan, params, revision, violation)

    def _pose_goal(self, msg, params):
        """Joint goal of a hand pose by the model's IK, seeded by the start (ConversionError)."""
        try:
            model = model_from_parameters(params)
        except ProblemError as exc:
            raise conversions.ConversionError(str(exc))
        start, _ = self._start_state(params, self._snapshot()[1])
        return conversions.pose_to_joint_goal(
            msg, params['base_frame'], model, tuple(params['extension_limits']),
            params['robot.ik_branch'], seed=model.positions(start))

    def _on_goal_pose(self, msg):
        self._submit(lambda params: self._pose_goal(msg, params), 'goal_pose')

    def _on_goal_joints(self, msg):
        self._submit(lambda params: conversions.joint_state_to_state(
            msg, params['joint_names']), 'goal_joints')

    def _on_obstacles(self, msg):
        with self._lock:
            limit = int(self._params['obstacles.max_count'])
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
        response.plan.header.frame_id = self._snapshot()[0]['base_frame']
        response.plan.header.stamp = self.get_clock().now().to_msg()
        pending = self._submit(lambda params: self._pose_goal(request.goal, params), '~/plan')
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
            cylindrical = params['robot.model'] == 'cylindrical'
            if cylindrical and len(goal) == 4 and not low <= goal[2] <= high:
                raise conversions.ConversionError(
                    f'goal extension q2 = {goal[2]:.6g} m is outside extension_limits '
                    f'[{low:.6g}, {high:.6g}] m')
            if source == 'replan':
                params = recovery_params(params, start) or params
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
            self._progress_sent = time.monotonic()

    def _on_progress(self, progress):
        if progress.phase == 'done':   # the result message follows
            return
        with self._lock:
            if self._progress is None:
                return
            self._progress = (progress, self._progress[1])
        self._publish_progress(schema.running_report(progress))

    def _heartbeat(self):
        with self._lock:
            current = self._progress
        if current is None or time.monotonic() - self._progress_sent < MAX_PROGRESS_GAP_S:
            return
        progress, started = current
        progress = dataclasses.replace(progress, elapsed_s=time.monotonic() - started)
        self._publish_progress(schema.running_report(progress))

    def _drop(self, request, reason, event=schema.EVENT_SUPERSEDED):
        self.get_logger().warning(f'goal from {request.source} {reason}')
        self._publish_progress(schema.ProgressReport(
            status=Status.CANCELED, message=f'goal from {request.source} {reason}',
            goal_source=request.source, event=event))
        request.finish()

    def _run(self, request, cancel):
        if request.cycle is not None:
            self._run_cycle(request, cancel)
            return
        params, measured = self._snapshot()
        with self._plan_lock:
            revision = self._revision
        start, start_source = self._start_state(params, measured)
        if request.source == 'replan':
            recovery = recovery_params(params, start)
            if recovery is not None:
                self.get_logger().warning(
                    'replanning from inside the obstacle margin with margin '
                    f"{recovery['obstacles.margin']:.4g} m")
                params = recovery
        try:
            problem = problem_from_parameters(params, x0=start, x_goal=request.goal)
            options = options_from_parameters(params)
        except (ProblemError, TypeError, ValueError) as exc:   # parameters are validated
            self._refuse(request.source, str(exc))
            return
        problem, guess = self._warm_start(problem, options, start_source)
        with self._lock:
            self._progress = (Progress(0, problem.t_f0, math.nan, math.nan, 0.0, 'start'),
                              time.monotonic())
            progress = self._progress[0]
        self._publish_progress(schema.running_report(progress))
        try:
            result = solve(problem, options, progress=self._on_progress, cancel=cancel,
                           initial_guess=guess)
        except Exception as exc:  # noqa: B902 - a core bug must not kill the worker thread
            self.get_logger().error(f'solver failed: {exc!r}')
            self._publish_progress(schema.refusal_report(
                f'internal solver error: {exc!r}', status=Status.INVALID_INPUT, event=''))
            return
        finally:
            with self._lock:
                self._progress = None
        if request.restart_reason is not None:
            return        # the worker runs it again with the current data
        request.result = result
        message = result.message
        if result.status is Status.CANCELED and request.stop_reason:
            message = f'{request.stop_reason} ({result.message})'
        if result.status is Status.INVALID_INPUT:
            message = f'{message} (start state from {start_source})'
        if result.status in schema.PUBLISHED and result.has_trajectory:
            if not self._publish_plan(request, result, problem, params, revision):
                request.restart_reason = 'planning data changed at the end of the solve'
                return
        rows = problem.obstacles
        report = schema.result_report(
            result, message, goal_source=request.source, start_source=start_source,
            goal=tuple(float(v) for v in np.round(request.goal, 9)),
            obstacles_hash=schema.obstacles_hash(rows, problem.margin),
            data_revision=revision, event=request.event, **model_keys(params))
        text = (f'{result.status.value} for goal from {request.source}: {message} '
                f'({result.iterations} iterations, {result.wall_time_s:.3f} s)')
        # One call site per severity: rclpy refuses to change it between calls of a site.
        level = schema.LEVELS[result.status]
        if level == schema.DiagnosticStatus.OK:
            self.get_logger().info(text)
        elif level == schema.DiagnosticStatus.WARN:
            self.get_logger().warning(text)
        else:
            self.get_logger().error(text)
        self._publish_progress(report)

    def _warm_start(self, problem, options, start_source):
        """
        Return (problem, initial guess) for replanning while a plan executes.

        When the robot moves along a published plan to the same goal (a replan after an
        obstacle or data change, or a repeated goal), fast mode starts from the remainder of that
        plan (states, controls, multipliers from the plan node nearest to the measured state), on
        the plan's remaining nodes (same tau: the remainder is then nearly optimal already).
        Otherwise, or with fewer than MIN_WARM_NODES left, a cold solve with solver.N.
        """
        with self._plan_lock:
            plan = self._executing
        model = problem.robot_model
        if options.mode != 'fast' or plan is None or start_source != 'joint_states' \
                or plan.get('result') is None or plan['model'] != model \
                or not np.allclose(model.joint_states(plan['goal']),
                                   model.joint_states(problem.x_goal), rtol=0.0, atol=1e-9):
            return problem, None
        elapsed = self._now() - plan['start']
        k = nearest_node(model, plan['states'], problem.x0)
        remainder = plan['result'].remainder(plan['times'][k])
        nodes = remainder.controls.shape[0]
        if elapsed >= plan['duration'] or nodes < MIN_WARM_NODES \
                or remainder.controls.shape[1] != problem.robot_model.nu:
            return problem, None
        return dataclasses.replace(problem, n_intervals=nodes), remainder

    def _publish_plan(self, request, result, problem, params, revision, stamp_s=None):
        """
        Publish the plan unless its data revision is stale (then return False).

        stamp_s: the plan's header.stamp [s, node clock], when it starts to apply (replan
        cycles: ahead of now); None: start_lead after publication for a start at rest (the
        stamp is taken once the message is built), else now.  A replan cycle's plan whose data
        changed meanwhile is published when it also satisfies the current data (checked as
        executing plans are).
        """
        model = problem.robot_model
        at_rest = np.max(np.abs(model.velocities(np.asarray(problem.x0)))) <= REST_SPEED
        lead = float(params['start_lead']) if stamp_s is None and at_rest else 0.0
        trajectory = conversions.trajectory_msg(result, params['joint_names'], model,
                                                conversions.time_msg(0.0))
        now = self._now()
        if request.cycle is not None and time.monotonic() > request.cycle.deadline:
            request.late = True         # over the cycle's budget (the lead): keep the old plan
            return False
        start = now + lead if stamp_s is None else float(stamp_s)
        stamp = trajectory.header.stamp = conversions.time_msg(start)
        with self._plan_lock:
            if revision != self._revision:
                with self._lock:
                    current = dict(self._params)
                candidate = {'states': np.asarray(result.states), 'goal': request.goal,
                             'times': np.asarray(result.time_grid),
                             'controls': np.asarray(result.controls)}
                if request.cycle is None or self._violation(candidate, current, 0.0):
                    return False
                problem = problem_from_parameters(current, x0=problem.x0,
                                                  x_goal=problem.x_goal)
                revision = self._revision
            self._trajectory_pub.publish(trajectory)
            request.published_at = time.monotonic()
            self._executing = {
                'start': start, 'duration': float(result.time_grid[-1]),
                'times': np.asarray(result.time_grid, dtype=float),
                'states': np.asarray(result.states, dtype=float),
                'controls': np.asarray(result.controls, dtype=float),
                'goal': request.goal.copy(), 'source': request.source,
                'path_states': result.states, 'result': result, 'model': model}
            self._plan_info = (schema.obstacles_hash(problem.obstacles, problem.margin),
                               revision)
        # The path and the markers only after the trajectory: they are not on its latency.
        path = conversions.hand_path_msg(result.states, model, params['base_frame'], stamp)
        request.path = path
        self._path_pub.publish(path)
        if request.cycle is None:
            self._publish_markers()   # cycles: the marker timer redraws (no solve delay)
        else:
            with self._lock:
                self._arm_dirty = True
        return True

    # -- markers ------------------------------------------------------------------------------

    def _publish_markers_if_dirty(self):
        with self._lock:
            dirty = self._arm_dirty
        if dirty:
            self._publish_markers()

    def _publish_markers(self):
        with self._lock:
            params = dict(self._params)
            arm = self._measured
            self._arm_dirty = False
            self._arm_drawn = arm
        with self._plan_lock:
            plan = self._executing
            path_states = None if plan is None else plan['path_states']
            if path_states is not None and plan.get('model') is not None:
                path_states = plan['model'].joint_states(path_states)
            plan_info, revision = self._plan_info, self._revision
        if arm is None:
            arm = np.asarray(params['initial_state'], dtype=float)
        try:
            rows = obstacle_rows(params)
        except ProblemError:
            rows = ()
        margin = float(params['obstacles.margin'])
        try:
            model = model_from_parameters(params).joint_model     # joint states drawn
        except ProblemError:
            model = float(params['robot.a'])
        if path_states is not None and np.shape(path_states)[-1] != np.shape(arm)[-1]:
            path_states = None      # planned for another robot model
        self._marker_pub.publish(conversions.markers_msg(
            rows, margin, model, params['base_frame'],
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
