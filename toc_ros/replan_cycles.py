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
The replan cycles of solver_node's Planner (a mixin of it).

From a measured state, a warm-started solve of the executing plan's remainder, published by
its deadline or the executing plan kept.

maybe_replan queues a cycle when core/replan_policy.py says one is due; _run_cycle solves it on
the goal worker's thread and publishes it through Planner._publish_plan, or keeps the
executing plan (a late solve seeds the next cycle) and, when that plan now violates the
current data, retries or stops it (_stop_if_violating).
"""

import dataclasses
import time

import numpy as np

from toc_ros import goal_requests as goals
from toc_ros import progress as schema
from toc_ros.core import ProblemError, solve, Status
from toc_ros.core import replan_policy as policy
from toc_ros.goal_worker import Request

CYCLE_SOURCE = 'replan_cycle'     # goal_source of the replan cycles' ~/progress reports


def overdue(request):
    """Return whether request is a replan cycle past its deadline; mark it late if so."""
    if request.cycle is not None and time.monotonic() > request.cycle.deadline:
        request.late = True
    return request.late


class ReplanCycles:
    """Planner's replan cycles (uses its _port, plans, worker, ready and _publish_plan)."""

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
                published = not overdue(request) and self._publish_plan(
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
