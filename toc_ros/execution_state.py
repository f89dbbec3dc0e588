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
What a planner node knows of the plan in execution, shared by its callbacks and its worker.

``ExecutionState`` is thread-safe (one lock, held by the node around a publication so that a
trajectory goes out only while its data revision is still current).  It records the planning
data and their revision, the plan published last (an ``ExecutingPlan``), the late cycle's plan
that seeds the next cycle, what the last plan was checked against, when the next regular
replan cycle is due and the recent cycle latencies that set the cycles' lead.  Its methods are
the decisions on that record: a data change (``new_data``), a plan that the new data makes
unsafe (``stale_plan``), what a cycle starts from (``cycle_source``), the lead (``cycle_lead``).
"""

import collections
import threading

import numpy as np

from toc_ros.core import replan_policy as policy
from toc_ros.core.executing_plan import Seed


class ExecutionState:
    """The executing plan, its data revision and the replan cycles' bookkeeping."""

    def __init__(self, planning):
        self.lock = threading.Lock()    # guards the fields below
        self.revision = 0               # counts the changes of the planning data
        self.planning = planning        # the flat values a plan depends on beyond its goal
        self.executing = None           # ExecutingPlan: the last published plan
        self.seed = None                # Seed: a late cycle's plan, the next warm start
        self.plan_info = None           # (obstacles hash, revision) of the last published plan
        self.next_cycle = 0.0           # monotonic time [s] of the next regular cycle
        self.brake_by = None            # (plan, node-clock time [s]): brake then unless replaced
        self._latencies = collections.deque(maxlen=policy.LATENCY_WINDOW)   # of cycles [s]

    def current(self):
        """Return (executing plan or None, data revision)."""
        with self.lock:
            return self.executing, self.revision

    def new_data(self, planning):
        """Record the planning data; return the new revision, or None when unchanged."""
        with self.lock:
            if planning == self.planning:
                return None
            self.planning = planning
            self.revision += 1
            return self.revision

    def stale_plan(self, revision, now, violation):
        """
        Return (plan, plan time, what it violates) when the executing plan is unsafe, or None.

        Checked at node-clock time now for data revision revision (None when the data changed
        again meanwhile); violation(plan, elapsed) tells what the plan's rest violates (None:
        nothing).  A plan whose execution is over is forgotten.
        """
        with self.lock:
            plan = self.executing
            if plan is None or revision != self.revision:
                return None
            if not plan.executing(now):
                self.executing = None
                return None
            elapsed = plan.elapsed(now)
            problem = violation(plan, elapsed)
        return None if problem is None else (plan, elapsed, problem)

    def is_current(self, plan, revision=None):
        """Tell whether plan still executes (and, given a revision, on that data)."""
        with self.lock:
            return self.executing is plan and (revision is None or revision == self.revision)

    def defer_brake(self, plan, deadline):
        """Record that plan, unsafe under new data, runs on until deadline for a replan."""
        with self.lock:
            if self.executing is plan:
                self.brake_by = (plan, float(deadline))

    def overdue_brake(self, now):
        """Return the executing plan when its deferred braking is due at now (once), or None."""
        with self.lock:
            if self.brake_by is None:
                return None
            plan, deadline = self.brake_by
            if self.executing is not plan:
                self.brake_by = None        # replaced (a replan or a stop) meanwhile
                return None
            if now < deadline:
                return None
            self.brake_by = None
            return plan

    def cycle_source(self, plan):
        """
        Return (revision, warm-start source) of a cycle for plan, or None when it was replaced.

        The source: the plan, or a late cycle's plan for it (when the data changed since, still
        closer to the new optimum than the executing plan).
        """
        with self.lock:
            if self.executing is not plan:
                return None
            return self.revision, policy.cycle_warm_source(plan, self.seed)

    def seed_next(self, plan, result, problem):
        """Keep a late cycle's plan: the next cycle for the same executing plan starts there."""
        with self.lock:
            if self.executing is plan:
                # An arm's plans carry the node's arm model (the problem's is the core's).
                model = plan.model if getattr(plan.model, 'is_arm', False) \
                    else problem.robot_model
                self.seed = Seed(plan, result, np.asarray(result.time_grid),
                                 np.asarray(result.states), model)

    def cycle_taken(self, received, rate):
        """Record that a regular cycle started from a state received at received [s]."""
        self.next_cycle = received + 1.0 / rate

    def record_latency(self, latency):
        """Add a solved cycle's latency [s] (joint_states received -> trajectory published)."""
        with self.lock:
            self._latencies.append(policy.latency_sample(latency))

    def clear_latencies(self):
        """Forget the latencies (another lead or model: measured afresh)."""
        with self.lock:
            self._latencies.clear()

    def cycle_lead(self, lead):
        """Return a cycle's lead [s] (policy.cycle_lead of the recent cycle latencies)."""
        with self.lock:
            recent = list(self._latencies)
        return policy.cycle_lead(lead, recent)

    def drawing(self):
        """Return (joint states of the executing plan's path or None, plan info, revision)."""
        with self.lock:
            plan = self.executing
            path_states = None if plan is None else plan.path_states
            if path_states is not None and plan.model is not None:
                path_states = plan.model.joint_states(path_states)
            return path_states, self.plan_info, self.revision
