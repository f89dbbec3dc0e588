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
The closed-loop executions of a recorded run: successive plans to one goal, and their numbers.

A closed-loop execution is a run of successive plans to the same goal: replan cycles, braking
trajectories (no goal of their own) and replacements join the execution in progress; a plan to
another goal starts a new one. Its numbers are ``closed_loop.execution_metrics`` of the plans'
stamps and durations, the joint_states, and the obstacle schedule (the obstacles messages at
their log times; before the first, what the first plan was checked against), plus the replan
latencies twice: as solver_node reported them (``latency_s`` of the ``replanned`` reports) and
recomputed from the recording (log time of the trajectory whose header.stamp is the report's
``plan_stamp`` minus log time of the joint_states whose header.stamp is its ``state_stamp``).
"""

import bisect
from dataclasses import dataclass
import math
from typing import List

import numpy as np

from toc_ros.conversions import ConversionError, nanoseconds, obstacle_rows_from_msg
from toc_ros.core.obstacles import scheduled_clearance
from toc_ros.progress import (EVENT_REPLACED, EVENT_REPLAN_KEPT, EVENT_REPLANNED, EVENT_STOPPED,
                              progress_from_msg)

from .closed_loop import execution_metrics, PlanSpan
from .recorded_plans import joint_samples, Plan, STAMP_MATCH_S
from .recorded_run import as_float


# Plans whose goals differ by at most this belong to one closed-loop execution [rad or m].
GOAL_TOL = 1e-6
# Goal sources of user requests: such a plan after the previous execution ended starts anew.
REQUEST_SOURCES = ('goal_pose', 'goal_joints', '~/plan')
# A joint_states step larger than this is a reset of the (simulated) robot, not motion: it
# ends the execution's samples [rad or m].
RESET_JUMP = 0.1
# Events counted per closed-loop execution (summary key -> event).
EVENTS = {'replanned': EVENT_REPLANNED, 'replan_kept': EVENT_REPLAN_KEPT,
          'trajectory_stopped': EVENT_STOPPED, 'trajectory_replaced': EVENT_REPLACED}


@dataclass
class ClosedLoop:
    """Successive plans to one goal and what the recording shows of their execution."""

    index: int
    plans: List[int]                  # plan indices, in publication order
    goal: np.ndarray                  # (4,) the joint goal
    goal_source: str
    t0: float                         # the first plan's start [s]
    end: float                        # the next execution's takeover [s] (inf: none)
    times: np.ndarray                 # (K,) joint_states stamps from t0 to end [s]
    positions: np.ndarray             # (K, 2)
    schedule: list                    # [(time [s], rows (n, 3))] true obstacles over time
    clearance: np.ndarray             # (K, n) per obstacle row, every link (nan: absent)
    node_latency: list                # [(time [s], latency [s])] of the replanned reports
    recorded_latency: list            # [(time [s], latency [s])] recomputed from log times
    unmatched: int                    # replanned reports without both raw messages
    events: dict                      # EVENTS key -> count
    metrics: dict                     # closed_loop.execution_metrics


def _is_brake(plan):
    return plan.solve is not None and plan.solve.report.event == EVENT_STOPPED


def group_plans(plans) -> List[List[Plan]]:
    """
    Group plans into closed-loop executions: successive plans to the same goal.

    A plan's goal is the one it was planned for (solver progress or the goal messages), else
    its last state; a braking trajectory (matched to a trajectory_stopped report) has none
    and joins the execution in progress, as does a plan whose goal is within GOAL_TOL, unless
    it answers a new user goal (REQUEST_SOURCES) once the execution's plans have all ended.
    """
    groups, goal, ends = [], None, -math.inf
    for plan in plans:
        own = plan.goal if plan.goal is not None else (None if _is_brake(plan)
                                                       else plan.states[-1])
        source = plan.solve.report.goal_source if plan.solve is not None else ''
        again = source in REQUEST_SOURCES and plan.begin > ends
        if not groups or again or (own is not None and goal is not None
                                   and float(np.max(np.abs(own - goal))) > GOAL_TOL):
            groups.append([])
            goal = None
        if goal is None and own is not None:
            goal = own
        plan.execution = len(groups) - 1
        groups[-1].append(plan)
        ends = max(ends if len(groups[-1]) > 1 else -math.inf, plan.start + plan.duration)
    return groups


def obstacle_schedule(run, first_rows, warn=None):
    """Return [(time [s], rows)]: first_rows from -inf, then each obstacles message's rows."""
    schedule = [(-math.inf, np.asarray(first_rows, dtype=float).reshape(-1, 3))]
    for time, msg in run.messages['obstacles']:
        try:
            rows = np.array(obstacle_rows_from_msg(msg), dtype=float).reshape(-1, 3)
        except ConversionError:
            continue
        schedule.append((time, rows))
    return schedule


def obstacle_clearance(model, times, positions, schedule):
    """Return (K, n) clearance [m] of every link to each true obstacle row (nan: absent)."""
    return scheduled_clearance(model, times, positions, schedule)


def _by_stamp(items):
    """Return (stamps, log times): header.stamp [s, node clock] sorted, log time [s]."""
    pairs = sorted((nanoseconds(m.header.stamp) * 1e-9, t) for t, m in items
                   if nanoseconds(m.header.stamp) > 0)
    return [k for k, _ in pairs], [t for _, t in pairs]


def _log_time_of(index, stamp):
    """Log time [s] of the first message in index whose stamp is within STAMP_MATCH_S."""
    if stamp is None or not math.isfinite(stamp):
        return None
    keys, times = index
    k = bisect.bisect_left(keys, stamp - STAMP_MATCH_S)
    if k < len(keys) and abs(keys[k] - stamp) <= STAMP_MATCH_S:
        return times[k]
    return None


def build_closed_loops(run, plans, model) -> List[ClosedLoop]:
    """Group the plans by goal and compute each execution's numbers (module docstring)."""
    if not plans:
        return []
    groups = group_plans(plans)
    samples = run.messages['joint_states']
    names = plans[0].joint_names
    all_times, all_states, _, _ = joint_samples(samples, names, run)
    order = np.argsort(all_times, kind='stable')
    all_times, all_positions = all_times[order], all_states[order][:, 0::2]
    trajectories = _by_stamp(run.messages['trajectory'])
    states_index = _by_stamp(samples)
    reports = [(t, progress_from_msg(m)) for t, m in run.messages['progress']]
    loops = []
    for g, group in enumerate(groups):
        first = group[0]
        end = groups[g + 1][0].begin if g + 1 < len(groups) else math.inf
        received_end = groups[g + 1][0].time if g + 1 < len(groups) else math.inf
        goal = next((p.goal for p in group if p.goal is not None), None)
        source = next((p.goal_source for p in group if p.goal is not None), '')
        if goal is None:
            goal, source = group[-1].states[-1], 'last planned state'
        keep = (all_times >= first.start - 1e-9) & (all_times < end)
        times, positions = all_times[keep], all_positions[keep]
        jumps = np.nonzero(np.max(np.abs(np.diff(positions, axis=0)), axis=1) > RESET_JUMP)[0] \
            if len(times) > 1 else ()
        if len(jumps):          # a reset of the robot ends what this execution did
            times, positions = times[:jumps[0] + 1], positions[:jumps[0] + 1]
        schedule = obstacle_schedule(run, first.obstacles)
        mine = [r for t, r in reports if first.time <= t < received_end and r.final]
        events = {key: sum(r.event == event for r in mine) for key, event in EVENTS.items()}
        node_latency, recorded_latency, unmatched = [], [], 0
        for r in mine:
            if r.event != EVENT_REPLANNED:
                continue
            published = _log_time_of(trajectories, r.plan_stamp)
            measured = _log_time_of(states_index, r.state_stamp)
            at = published if published is not None else run.node_time(as_float(r.plan_stamp))
            if r.latency_s is not None and math.isfinite(r.latency_s):
                node_latency.append((at, float(r.latency_s)))
            if published is None or measured is None:
                unmatched += 1
            else:
                recorded_latency.append((published, published - measured))
        spans = [PlanSpan(p.start, p.duration) for p in group]
        metrics = execution_metrics(model, goal[0::2], spans, times, positions, schedule,
                                    [v for _, v in node_latency], events['replan_kept'])
        recorded = np.array([v for _, v in recorded_latency])
        metrics.update({
            'recorded_latency_median_s': _percentile(recorded, 50),
            'recorded_latency_p99_s': _percentile(recorded, 99),
            'recorded_latency_max_s': float(np.max(recorded)) if recorded.size else math.nan,
            'recorded_latencies': int(recorded.size)})
        loops.append(ClosedLoop(
            index=g, plans=[p.index for p in group], goal=np.asarray(goal, dtype=float),
            goal_source=source, t0=first.start, end=end, times=times, positions=positions,
            schedule=schedule,
            clearance=obstacle_clearance(model, times, positions, schedule),
            node_latency=node_latency, recorded_latency=recorded_latency,
            unmatched=unmatched, events=events, metrics=metrics))
    return loops


def _percentile(values, q):
    return float(np.percentile(values, q)) if len(values) else math.nan
