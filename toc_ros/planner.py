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
solver_node's planning without rclpy: goals, solves, replan cycles and stops.

A ``Planner`` takes the goals a node translated (``submit``), solves the newest on its
``GoalWorker`` thread, publishes each plan only while its planning data are current
(``ExecutionState``), runs the replan cycles of the executing plan (``maybe_replan``,
replan_cycles.py), and replans around or stops a plan that new data make unsafe
(``data_changed``).  It builds the
messages (toc_ros.conversions) and ~/progress reports (toc_ros.progress) but sends nothing
itself: the node gives it a *port*, an object with

- ``snapshot()``: (settings, measured state of their model or None); ``settings()``: the
  settings only (cheap, called under the plan lock); ``measured_time()``: the node-clock time
  [s] of that measured state (None: none); ``measured_received()``: the node-clock time [s]
  when it arrived (None: none; a goal is refused while it is stale, starts.stale_state);
- ``now()``: the node clock [s]; ``estimated_model(settings)``: (model, text) of the online
  estimate (replan.estimate);
- ``publish_trajectory(msg, hold_effort=None)`` (hold_effort: an arm plan from rest's
  holding torque, for a controller's goal: execution.held_start), ``publish_path(msg)``,
  ``publish_markers()``, ``arm_moved()`` (the markers are due), ``report(progress_report)``;
  ``logger`` (info, warning, error).

The settings are a ``nodes.solver_settings.SolverNodeConfig``.  The policy it applies is
core/replan_policy.py and core/goal_starts.py; see solver_node's docstring for the behaviour on
the topics.
"""

import dataclasses
import math
import time

import numpy as np

from toc_ros import arm_config, arm_goals, conversions, goal_requests as goals
from toc_ros import progress as schema
from toc_ros.config import problem_from_parameters
from toc_ros.core import goal_starts as starts, replan_policy as policy
from toc_ros.core import ProblemError, Progress, solve, Status
from toc_ros.core.executing_plan import braking_plan, plan_from_result, true_conflict_time
from toc_ros.execution_state import ExecutionState
from toc_ros.goal_worker import GoalWorker, Request
from toc_ros.replan_cycles import overdue, ReplanCycles
from toc_ros.solve_progress import SolveProgress
from trajectory_msgs.msg import JointTrajectory

# [rad] an arm goal's start on the executing plan is set again for its own Euler step when
# that moves it by more than this, at most REBASE_ROUNDS times (Planner._rebased).
REBASE_TOL = 1e-5
REBASE_ROUNDS = 3


class Planner(ReplanCycles):
    """Solves goals and replan cycles for a node's port; see the module docstring."""

    def __init__(self, port, planning, ready):
        """planning: the planning data of the initial settings; ready: the kernels' Event."""
        self._port = port
        self._log = port.logger
        self.ready = ready
        self.plans = ExecutionState(planning)
        self.progress = SolveProgress()
        self.worker = GoalWorker(self._run, self.drop, ready, self._log.error)

    # -- goals --------------------------------------------------------------------------------

    def submit(self, make_goal, source):
        """Check a goal against the current start state and obstacles, then queue it."""
        config, measured = self._port.snapshot()
        start, start_source, _ = goals.goal_start(
            config, measured, self.plans.current()[0], self._port.now(),
            self._port.measured_time())
        why = self._stale_start(config, measured)
        if why is not None:
            self.refuse(source, why)
            return None
        try:
            goal = make_goal(config)
        except conversions.ConversionError as exc:
            self.refuse(source, str(exc))
            return None
        why = goals.goal_refusal(config, start, start_source, goal, source)
        if why is not None:
            self.refuse(source, why)
            return None
        request = Request(np.asarray(goal, dtype=float), source)
        self._log.info(f'goal from {source}: {np.round(goal, 6).tolist()}')
        if not self.ready.is_set():
            note = (f'goal from {source} queued: the numba kernels are still loading; it is '
                    'solved once ready')
            self._log.info(note)
            self._port.report(schema.ProgressReport(
                message=note, goal_source=source, goal=tuple(goal), event=schema.EVENT_QUEUED))
        self.worker.submit(request)
        return request

    def _stale_start(self, config, measured):
        """Return why the measured state may not start a goal (too old), or None."""
        if measured is None:
            return None
        return starts.stale_state(self._port.measured_received(), self._port.now(),
                                  config.node.max_state_age)

    def refuse(self, source, reason):
        """Report refused input (log and ~/progress)."""
        self._log.error(f'refused {source}: {reason}')
        self._port.report(schema.refusal_report(f'{source}: {reason}'))

    def drop(self, request, reason, event=None):
        """Report a request that will not be solved (the worker's drop callback)."""
        event = schema.EVENT_SUPERSEDED if event is None else event
        self._log.warning(f'goal from {request.source} {reason}')
        self._port.report(schema.ProgressReport(
            status=Status.CANCELED, message=f'goal from {request.source} {reason}',
            goal_source=request.source, event=event))
        request.finish()

    def cancel_goal(self, reason):
        """
        Abandon the goal: no more solves or cycles for it, the robot brakes to rest.

        Return (success, message): success false when no goal was active (nothing solving,
        queued or executing).
        """
        started = time.monotonic()
        port, plans = self._port, self.plans
        with plans.lock:            # first: no new cycle and no replan after a stop for it
            plan = plans.executing
            active = plan is not None and plan.goal_active and plan.executing(port.now())
            if plan is not None:
                plan.goal_active = False
        stopped, dropped = self.worker.cancel_goal(reason)
        config, measured = port.snapshot()
        how = None
        if policy.cancel_goal_action(plan, port.now(), measured) != policy.NOTHING:
            published, braking = self._publish_stop(plan, config,
                                                    lambda: plans.executing is plan)
            if published and braking is None:
                how = 'stopped (no measured state)'
        current, revision = plans.current()
        if how is None and current is not None and current.braking \
                and current.executing(port.now()):
            how = 'braking to rest'
        if not (stopped or dropped or active):
            return False, 'no active goal (nothing solving, queued or executing)'
        message = (f'{reason}: ' + (how or 'no plan was executing')
                   + f' ({time.monotonic() - started:.4f} s)')
        self._log.warning(message)
        port.report(schema.ProgressReport(
            status=Status.CANCELED, message=message, level=schema.DiagnosticStatus.WARN,
            goal_source='' if plan is None else plan.source, data_revision=revision,
            event=schema.EVENT_GOAL_CANCELED))
        return True, message

    # -- new data -----------------------------------------------------------------------------

    def data_changed(self, config):
        """Take new settings: a new data revision restarts the solve, re-checks the plan."""
        revision = self.plans.new_data(config.planning_data())
        if revision is None:
            return
        reason = f'planning data changed (data revision {revision})'
        if self.worker.restart(reason):
            self._log.warning(f'{reason}: restarting the running solve')
            self._port.report(schema.ProgressReport(
                message=f'{reason}: solving again from the latest state',
                event=schema.EVENT_RESTARTED, data_revision=revision))
        self._check_executing(config, revision)

    def _check_executing(self, config, revision):
        """Replan around, or stop, an executing trajectory that violates the current data."""
        port = self._port
        stale = self.plans.stale_plan(
            revision, port.now(), lambda plan, t: goals.plan_violation(plan, config, t))
        if stale is None:
            return
        plan, _, problem = stale
        # URDF arms have no replan cycles (config.replanning): they stop and plan again.
        if not config.is_arm and self._replan_before_braking(plan, config):
            self._log.warning(
                f'the executing trajectory {problem} under data revision {revision}: '
                'replanning from the current state')
            return
        self._stop(plan, config, revision, problem)

    def _replan_before_braking(self, plan, config):
        """
        Queue a data-change cycle for plan, unsafe under new data, when braking can wait.

        True when queued; the plan then brakes at policy.brake_deadline unless a plan replaced
        it by then (brake_if_overdue).
        """
        port = self._port
        measured, measured_time = port.snapshot()[1], port.measured_time()
        now = port.now()
        if measured is None or not self._brake_can_wait(
                plan, config, policy.state_now(plan, measured, measured_time, now),
                plan.elapsed(now)):
            return False
        if not self.maybe_replan(config, measured, measured_time, time.monotonic(),
                                 reason=policy.DATA_CHANGE):
            return False
        self.plans.defer_brake(plan, policy.brake_deadline(
            now, self.plans.cycle_lead(config.node.replan_lead)))
        return True

    def brake_if_overdue(self, config):
        """Brake a plan whose deferred braking is due and that no replan replaced (any thread)."""
        plan = self.plans.overdue_brake(self._port.now())
        if plan is None:
            return
        problem = goals.plan_violation(plan, config, plan.elapsed(self._port.now()))
        if problem is not None:
            self._stop(plan, config, self.plans.current()[1],
                       f'{problem} (no replan around it in time)')

    def _publish_stop(self, plan, config, still_valid):
        """
        Replace plan by a stop at once; return (published, braking plan or None).

        With a measured state the stop is a braking trajectory (every joint decelerates at
        its control bound until it rests); without one an empty trajectory (the plant holds).
        still_valid() (under the plan lock) tells whether plan may still be replaced.
        """
        port = self._port
        now = port.now()
        # From where the robot is now: it follows plan until the stop reaches it.
        measured = policy.state_now(plan, port.snapshot()[1], port.measured_time(), now)
        # The stop addresses the joints of the plan it stops, which may not be the settings'
        # any more (joint_names or robot.model changed under it).
        names = plan.joint_names or config.frames.joint_names
        if getattr(plan.model, 'is_arm', False):
            braking = arm_goals.braking_plan(plan, measured, now, policy.BRAKE_STEP_S)
        else:
            braking = braking_plan(plan, measured, now, policy.BRAKE_STEP_S)
        if braking is None:
            stop = JointTrajectory(joint_names=list(names))
        elif getattr(braking.model, 'is_arm', False):
            stop = braking.model.trajectory_msg(braking, names, conversions.time_msg(0.0))
        else:
            stop = conversions.trajectory_msg(braking, names, braking.model,
                                              conversions.time_msg(0.0))
        with self.plans.lock:
            if not still_valid():
                return False, None
            port.publish_trajectory(stop)
            if braking is not None:
                braking.start = port.now()
            self.plans.executing = braking
        return True, braking

    def _stop(self, plan, config, revision, problem):
        """Stop the executing plan at once and plan its goal again (unless a goal is queued)."""
        plans = self.plans
        published, braking = self._publish_stop(
            plan, config, lambda: revision == plans.revision and plans.executing is plan)
        if not published:
            return        # newer data or a newer plan took over meanwhile
        replan = plan.goal_active and not self.worker.goal_busy()
        how = 'braking to rest' if braking is not None else 'stopped'
        reason = (f'the executing trajectory {problem} under data revision {revision}: '
                  f'{how}' + (', planning the goal again' if replan else ''))
        self._log.warning(reason)
        self._port.report(schema.ProgressReport(
            status=Status.CANCELED, message=reason, level=schema.DiagnosticStatus.WARN,
            goal_source=plan.source, data_revision=revision, event=schema.EVENT_STOPPED))
        if replan:
            request = self.submit(lambda _config: plan.goal, goals.REPLAN)
            if request is not None:
                request.event = schema.EVENT_REPLACED

    def _brake_can_wait(self, plan, config, measured, elapsed):
        """Tell whether plan may run on while a cycle plans around new data (the policy)."""
        rows = config.problem.obstacles
        conflict = true_conflict_time(plan, rows, elapsed)
        return policy.brake_can_wait(plan, rows, measured, elapsed,
                                     self.plans.cycle_lead(config.node.replan_lead), conflict)

    # -- solving (worker thread) --------------------------------------------------------------

    def _on_progress(self, progress):
        progress = self.progress.update(progress)
        if progress is not None:
            self._port.report(schema.running_report(progress))

    def _run(self, request, cancel):
        if request.cycle is not None:
            self._run_cycle(request, cancel)
            return
        port = self._port
        config, measured = port.snapshot()
        why = self._stale_start(config, measured)
        if why is not None:         # (e.g. queued while the kernels loaded, the plant gone)
            self.refuse(request.source, why)
            return
        executing, revision = self.plans.current()
        start, start_source, not_before = goals.goal_start(
            config, measured, executing, port.now(), port.measured_time(), request.lead_scale)
        # A start on the executing plan applies at that node's time (published before it).
        stamp_s = not_before if start_source == goals.ON_PLAN else None
        try:
            problem, guess, margin = goals.goal_problem(
                config, start, request.goal, request.source,
                executing if start_source in ('joint_states', goals.ON_PLAN) else None,
                port.now(), start_source)
        except (ProblemError, TypeError, ValueError) as exc:   # parameters are validated
            self.refuse(request.source, str(exc))
            return
        # With an online estimate in use, a goal is planned with the model its replan cycles
        # use: the robot.* values are known to be off, and a first cycle on another model
        # cannot warm-start from the goal's plan (a slow first cycle, then a jump).
        estimated, estimate = port.estimated_model(config)
        if estimated is not None:
            problem = problem.with_model(estimated)
        if margin is not None:
            self._log.warning(
                f'replanning from inside the obstacle margin with margin {margin:.4g} m')
        port.report(schema.running_report(self.progress.start(
            Progress(0, problem.t_f0, math.nan, math.nan, 0.0, 'start'))))
        try:
            result = solve(problem, config.options, progress=self._on_progress, cancel=cancel,
                           initial_guess=guess)
            if start_source == goals.ON_PLAN and config.is_arm:
                result, problem = self._rebased(executing, problem, result, config.options,
                                                cancel)
            elif start_source == goals.ON_PLAN and result.status in starts.RETRIED:
                result, problem = self._with_less_margin(problem, result, guess, config,
                                                         cancel)
        except Exception as exc:  # noqa: B902 - a core bug must not kill the worker thread
            self._log.error(f'solver failed: {exc!r}')
            port.report(schema.refusal_report(
                f'internal solver error: {exc!r}', status=Status.INVALID_INPUT, event=''))
            return
        finally:
            self.progress.end()
        if request.restart_reason is not None:
            return        # the worker runs it again with the current data
        request.result = result
        status, message = goals.goal_outcome(result, request.stop_reason, start_source)
        if status in schema.PUBLISHED and result.has_trajectory \
                and not self._publish_plan(
                    request, result, problem, config, revision, stamp_s=stamp_s,
                    not_before=None if stamp_s is not None else not_before):
            if request.late and self.worker.current(request):
                # Solved after its start on the executing plan: that start is behind the
                # robot now.  Again from twice as far ahead (or from the plan's rest).
                request.late, request.lead_scale = False, 2.0 * request.lead_scale
                request.restart_reason = (
                    f'solved after its start on the executing plan ({result.wall_time_s:.3f} s)'
                    f': again from {config.node.goal_lead * request.lead_scale:.3g} s ahead')
                self._log.warning(f'goal from {request.source} {request.restart_reason}')
                return
            if self.worker.current(request):
                request.restart_reason = 'planning data changed at the end of the solve'
                return
            status, message = Status.CANCELED, f'{request.stop_reason}: not published'
        report = schema.result_report(
            result, message, goal_source=request.source, start_source=start_source,
            goal=tuple(float(v) for v in np.round(request.goal, 9)),
            obstacles_hash=schema.obstacles_hash(problem.obstacles, problem.margin),
            margin=problem.margin, data_revision=revision, event=request.event,
            estimate=estimate if estimated is not None else '', **config.model_keys())
        if status is not result.status:
            report = dataclasses.replace(report, status=status, level=None)
        text = (f'{status.value} for goal from {request.source}: {message} '
                f'({result.iterations} iterations, {result.wall_time_s:.3f} s)')
        # One call site per severity: rclpy refuses to change it between calls of a site.
        level = schema.LEVELS[status]
        if level == schema.DiagnosticStatus.OK:
            self._log.info(text)
        elif level == schema.DiagnosticStatus.WARN:
            self._log.warning(text)
        else:
            self._log.error(text)
        port.report(report)

    def _with_less_margin(self, problem, result, guess, config, cancel):
        """Solve a failed goal from the executing plan again with starts.retry_margin."""
        margin = starts.retry_margin(problem.robot_model, problem.x0, problem.obstacles,
                                     problem.margin)
        if margin is None:
            return result, problem
        self._log.warning(
            f'{result.status.value} from the executing plan with margin {problem.margin:.4g} m '
            f'(the robot moves into it): again with margin {margin:.4g} m')
        retry = dataclasses.replace(problem, margin=margin)
        again = solve(retry, config.options, progress=self._on_progress, cancel=cancel,
                      initial_guess=guess)
        # (a second failure reports the first; a cancel or timeout during it, itself)
        return (result, problem) if again.status in starts.RETRIED else (again, retry)

    @staticmethod
    def _rebased(plan, problem, result, options, cancel):
        """
        Return (result, problem) of an arm goal started on plan, its start set for its own step.

        The start's published position is plan's there (its Euler node shifted by plan's
        h dq / 2); the goal's plan shifts its start by its own h = t_f / N, known only now:
        millimetres apart at full speed, a jump of the commanded reference.  Solved again from
        the start moved by the difference, warm-started from the last result (2 iterations
        each), until the start moves by at most REBASE_TOL (the change of t_f moves it again,
        by some 3 % of the last move) or REBASE_ROUNDS; the last solved one is kept.
        """
        if result.status is not Status.SOLVED or not result.has_trajectory:
            return result, problem
        published = plan.published_start(np.asarray(problem.x0, dtype=float))
        first = result
        for _ in range(REBASE_ROUNDS):
            x0 = np.asarray(problem.x0, dtype=float)
            start = plan.start_for(published, result.final_time / problem.n_intervals)
            if np.max(np.abs(start - x0)) <= REBASE_TOL:
                break
            rebased = dataclasses.replace(problem, x0=tuple(float(v) for v in start))
            again = solve(rebased, options, cancel=cancel, initial_guess=result)
            if again.status is not Status.SOLVED or not again.has_trajectory:
                break
            result, problem = again, rebased
        if result is first:
            return result, problem
        # Reported as one solve: every run's iterations and time.
        return dataclasses.replace(
            result, iterations=first.iterations + result.iterations,
            wall_time_s=first.wall_time_s + result.wall_time_s,
            message=f'{first.message}; from the start set for its step: '
                    f'{result.message}'), problem

    def _publish_plan(self, request, result, problem, config, revision, stamp_s=None,
                      not_before=None):
        """
        Publish the plan unless its data revision is stale or its goal canceled (then False).

        stamp_s: the plan's header.stamp [s, node clock], when it starts to apply (replan
        cycles, and goals started on the executing plan: ahead of now; a goal's is late, and
        not published, from then on); None: start_lead after publication for a start at rest
        (the stamp is taken once the message is built), else now; not before not_before [s]
        (the rest of the braking stop or plan it starts from).  A replan cycle's plan whose data
        changed meanwhile is published when it also satisfies the current data (checked as
        executing plans are).
        """
        port, plans = self._port, self.plans

        def late():
            # A cycle past its deadline, or a goal started on the executing plan past the
            # time of that start: the robot is no longer where its plan begins.
            if request.cycle is None and stamp_s is not None and port.now() >= stamp_s:
                request.late = True
            return overdue(request)
        arm = config.is_arm         # the node's view of the arm (the problem's is the core's)
        model = config.model if arm else problem.robot_model
        rest = stamp_s is None and policy.at_rest(model, problem.x0)
        lead = config.node.start_lead if rest else 0.0
        names = config.frames.joint_names
        hold_effort = None
        if arm:
            trajectory = model.trajectory_msg(result, names, conversions.time_msg(0.0),
                                              problem.model)
            if rest:
                hold_effort = model.holding_torque(model.positions(problem.x0), problem.model)
        else:
            trajectory = conversions.trajectory_msg(result, names, model,
                                                    conversions.time_msg(0.0))
        now = port.now()
        if late():                     # over the cycle's budget (the lead): keep the old plan
            return False
        start = now + lead if stamp_s is None else float(stamp_s)
        if not_before is not None:
            start = max(start, float(not_before))
        stamp = trajectory.header.stamp = conversions.time_msg(start)
        plan = plan_from_result(result, start, request.goal, request.source, model, names)
        with plans.lock:
            if not self.worker.current(request):
                return False            # its goal was canceled (~/cancel_goal)
            if revision != plans.revision:
                current = port.settings()
                if request.cycle is None or goals.plan_violation(plan, current, 0.0):
                    return False
                problem = (arm_goals.goal_problem(current, problem.x0, problem.x_goal)
                           if current.is_arm else problem_from_parameters(
                               current.flat, x0=problem.x0, x_goal=problem.x_goal))
                revision = plans.revision
            if late():
                # Checked again at the last moment: building the messages and taking the lock
                # take milliseconds on a loaded machine, and a cycle's plan starts at its
                # stamp, right after the deadline.
                return False
            port.publish_trajectory(trajectory, hold_effort)
            request.published_at = time.monotonic()
            request.published_stamp = port.now()
            plans.executing = plan
            plans.plan_info = (schema.obstacles_hash(problem.obstacles, problem.margin),
                               revision)
        # The path and the markers only after the trajectory: they are not on its latency.
        if arm:
            path = model.path_msg(result.states, arm_config.settings(config.flat).tip_link,
                                  config.frames.base_frame, stamp)
        else:
            path = conversions.hand_path_msg(result.states, model, config.frames.base_frame,
                                             stamp)
        request.path = path
        port.publish_path(path)
        if request.cycle is None:
            port.publish_markers()    # cycles: the marker timer redraws (no solve delay)
        else:
            port.arm_moved()
        return True
