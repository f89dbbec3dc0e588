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
(``ExecutionState``), runs the replan cycles of the executing plan (``maybe_replan``), and
replans around or stops a plan that new data make unsafe (``data_changed``).  It builds the
messages (toc_ros.conversions) and ~/progress reports (toc_ros.progress) but sends nothing
itself: the node gives it a *port*, an object with

- ``snapshot()``: (settings, measured state of their model or None); ``settings()``: the
  settings only (cheap, called under the plan lock); ``measured_time()``: the node-clock time
  [s] of that measured state (None: none);
- ``now()``: the node clock [s]; ``estimated_model(settings)``: (model, text) of the online
  estimate (replan.estimate);
- ``publish_trajectory(msg)``, ``publish_path(msg)``, ``publish_markers()``, ``arm_moved()``
  (the markers are due), ``report(progress_report)``; ``logger`` (info, warning, error).

The settings are a ``nodes.solver_settings.SolverNodeConfig``.  The policy it applies is
core/replan_policy.py; see solver_node's docstring for the behaviour on the topics.
"""

import dataclasses
import math
import time

import numpy as np

from toc_ros import arm_config, arm_goals, conversions, goal_requests as goals
from toc_ros import progress as schema
from toc_ros.config import problem_from_parameters
from toc_ros.core import ProblemError, Progress, solve, Status
from toc_ros.core import replan_policy as policy
from toc_ros.core.executing_plan import braking_plan, plan_from_result, true_conflict_time
from toc_ros.execution_state import ExecutionState
from toc_ros.goal_worker import GoalWorker, Request
from toc_ros.solve_progress import SolveProgress
from trajectory_msgs.msg import JointTrajectory

CYCLE_SOURCE = 'replan_cycle'     # goal_source of the replan cycles' ~/progress reports


def _overdue(request):
    """Return whether request is a replan cycle past its deadline; mark it late if so."""
    if request.cycle is not None and time.monotonic() > request.cycle.deadline:
        request.late = True
    return request.late


class Planner:
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
        names = config.frames.joint_names
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
        executing, revision = self.plans.current()
        start, start_source, not_before = goals.goal_start(
            config, measured, executing, port.now(), port.measured_time())
        try:
            problem, guess, margin = goals.goal_problem(
                config, start, request.goal, request.source,
                executing if start_source == 'joint_states' else None, port.now())
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
                and not self._publish_plan(request, result, problem, config, revision,
                                           not_before=not_before):
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

    def _publish_plan(self, request, result, problem, config, revision, stamp_s=None,
                      not_before=None):
        """
        Publish the plan unless its data revision is stale or its goal canceled (then False).

        stamp_s: the plan's header.stamp [s, node clock], when it starts to apply (replan
        cycles: ahead of now); None: start_lead after publication for a start at rest (the
        stamp is taken once the message is built), else now; not before not_before [s] (the
        rest of the braking stop it starts from).  A replan cycle's plan whose data
        changed meanwhile is published when it also satisfies the current data (checked as
        executing plans are).
        """
        port, plans = self._port, self.plans
        arm = config.is_arm         # the node's view of the arm (the problem's is the core's)
        model = config.model if arm else problem.robot_model
        rest = stamp_s is None and policy.at_rest(model, problem.x0)
        lead = config.node.start_lead if rest else 0.0
        names = config.frames.joint_names
        if arm:
            trajectory = model.trajectory_msg(result, names, conversions.time_msg(0.0))
        else:
            trajectory = conversions.trajectory_msg(result, names, model,
                                                    conversions.time_msg(0.0))
        now = port.now()
        if _overdue(request):           # over the cycle's budget (the lead): keep the old plan
            return False
        start = now + lead if stamp_s is None else float(stamp_s)
        if not_before is not None:
            start = max(start, float(not_before))
        stamp = trajectory.header.stamp = conversions.time_msg(start)
        plan = plan_from_result(result, start, request.goal, request.source, model)
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
            if _overdue(request):
                # Checked again at the last moment: building the messages and taking the lock
                # take milliseconds on a loaded machine, and a cycle's plan starts at its
                # stamp, right after the deadline.
                return False
            port.publish_trajectory(trajectory)
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

    # -- replanning (receding horizon) ----------------------------------------------------------

    def maybe_replan(self, config, state, state_time, received, reason=None):
        """
        Start a replan cycle from a measured state when one is due; True when it was queued.

        Due (policy.cycle_reason): at replan.rate, at once when the state deviates from the
        executing plan by more than replan.deviation, or for a reason (new data).  The cycle's
        plan starts on the executing plan's node at or after now + lead (policy.cycle_start)
        from the state predicted along the executing plan; the worker takes it only when no
        goal is queued or solving.
        """
        if reason is None:
            self.brake_if_overdue(config)     # new data decide afresh (_replan_before_braking)
        plans = self.plans
        plan, revision = plans.current()
        if not policy.cycle_allowed(plan, config.replanning, self.ready.is_set()) \
                or state.shape[0] != plan.model.nx:
            return False
        cycle = policy.next_cycle(plan, state, state_time, self._port.now(), received,
                                  plans.cycle_lead(config.node.replan_lead), config.node,
                                  plans.next_cycle, revision, reason)
        if cycle is None:
            return False
        request = Request(plan.goal, CYCLE_SOURCE, cycle)
        if not self.worker.offer(request, behind_cycle=cycle.reason == policy.DATA_CHANGE):
            return False
        plans.cycle_taken(received, config.node.replan_rate)
        return True

    def _run_cycle(self, request, cancel):
        """Solve one replan cycle (worker thread); publish it or keep the executing plan."""
        cycle, plan = request.cycle, request.cycle.plan
        config = self._port.snapshot()[0]
        taken = self.plans.cycle_source(plan)
        if taken is None:
            return          # a newer plan was published meanwhile: nothing to replace
        revision, source = taken
        result, problem, why, recovery = None, None, '', None
        estimated, estimate = self._port.estimated_model(config)
        try:
            # A start the plant carried inside the margin (it did not follow the plan) plans
            # out of there with part of its true clearance as the margin (as the replan after a
            # stop): keeping the plan it is not following would carry it on into the circle.
            problem, recovery = goals.cycle_base_problem(config, cycle.start, plan.goal)
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
            self._log.error(f'replan cycle failed: {exc!r}')
            why = f'internal solver error: {exc!r}'
        published = False
        if result is not None:
            late_by = None
            if result.status is Status.SOLVED and result.has_trajectory:
                # Published only when its message is ready by the deadline (else late).
                published = not _overdue(request) and self._publish_plan(
                    request, result, problem, config, revision, stamp_s=cycle.stamp_s)
                if request.late:
                    late_by = time.monotonic() - cycle.deadline
                    self.plans.seed_next(plan, result, problem)
            why = goals.cycle_failure(result, request.stop_reason, late_by,
                                      cycle.deadline - cycle.received, published,
                                      published or self.worker.current(request)) or why
        # joint_states received -> trajectory published (the path and markers come after).
        latency = (request.published_at if published else time.monotonic()) - cycle.received
        if result is not None and result.status is Status.SOLVED:
            # Solved cycles, published or late: the median follows cycles that are slow most
            # of the time, not the rare one that seeds the next.  Not timed-out ones: those
            # are the final braking's overshoot problems, hundreds of iterations whatever the
            # lead (they would stretch every later cycle's lead to the cap).
            self.plans.record_latency(latency)
        values = dict(goal_source=CYCLE_SOURCE, start_source='predicted joint_states',
                      goal=tuple(float(v) for v in np.round(plan.goal, 9)),
                      data_revision=revision, latency_s=latency, deviation=cycle.deviation,
                      plan_stamp=cycle.stamp_s, state_stamp=cycle.state_stamp,
                      estimate=estimate if estimated is not None else
                      (f'none: {estimate}' if estimate else ''), **config.model_keys())
        if problem is not None:
            values['obstacles_hash'] = schema.obstacles_hash(problem.obstacles, problem.margin)
            values['margin'] = problem.margin
        if published:       # the data it was checked against
            values['published_stamp'] = request.published_stamp
            with self.plans.lock:
                values['obstacles_hash'], values['data_revision'] = self.plans.plan_info
            inside = '' if recovery is None else (
                f' from inside the obstacle margin (margin {problem.margin:.4g} m)')
            self._port.report(schema.result_report(
                result, f'replanned ({cycle.reason}){inside}: {result.message}',
                event=schema.EVENT_REPLANNED, **values))
            return
        message = f'replan cycle ({cycle.reason}) kept the executing plan: {why}'
        self._log.warning(message, throttle_duration_sec=1.0)
        report = (schema.result_report(result, message, **values) if result is not None
                  else schema.ProgressReport(status=Status.INVALID_INPUT, message=message,
                                             **values))
        self._port.report(dataclasses.replace(
            report, level=schema.DiagnosticStatus.WARN, event=schema.EVENT_REPLAN_KEPT))
        self._stop_if_violating(plan, self._port.snapshot()[0], cycle, request.late)

    def _stop_if_violating(self, plan, config, cycle, late=False):
        """
        After a failed cycle: act on the plan it kept if that violates the current data.

        Another data-change cycle is tried when policy.retry_after_failed_cycle says so and
        braking can wait for it (_brake_can_wait); else the plan is stopped.
        """
        port = self._port
        plan_now, revision = self.plans.current()
        if plan_now is not plan:
            return
        elapsed = plan.elapsed(port.now())
        problem = goals.plan_violation(plan, config, elapsed)
        if problem is None:
            return
        again = policy.retry_after_failed_cycle(cycle.reason, cycle.revision, revision, late)
        if again and self._replan_before_braking(plan, config):
            return
        self._stop(plan, config, revision, problem)
