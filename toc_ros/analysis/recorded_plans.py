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
The plans of a recorded run (one per trajectory message) and their executions.

A plan is one trajectory message. Its execution starts at its header.stamp when that is
nonzero (JTC semantics: a plan received after its stamp is trimmed, i.e. runs from its
receipt at the stamp's elapsed time), else at its receipt; a plan replaced (a later plan
received) before its stamp never executed. An executed plan runs until the next executed
plan starts or the recording ends. Everything a plan is checked against is what was in force
when it arrived: the latest obstacles message before it (else the solver's obstacle markers,
else the parameter file), the latest goal since the previous plan (or the goal its solve
reported). Missing topics leave the numbers that need them at None and are listed in
``missing``.
"""

import bisect
from dataclasses import dataclass
import math
from typing import List, Optional

import numpy as np

from toc_ros.config import obstacle_rows
from toc_ros.conversions import (as_model, ConversionError, joint_state_arrays,
                                 joint_state_to_state, nanoseconds, obstacle_rows_from_msg,
                                 pose_to_joint_goal, trajectory_arrays)
from toc_ros.core import Status
from toc_ros.progress import EVENT_REPLAN_KEPT, EVENT_REPLANNED

from .recorded_run import as_float, finite_vector, latest_before, run_model, Solve


# A plan and the final progress of its solve are published within this time [s].
PROGRESS_MATCH_S = 2.0
# Markers up to this long after a plan still show the obstacles it was planned around [s].
MARKER_DELAY_S = 1.0
MARKER_SPHERE, MARKER_CYLINDER, MARKER_LINE_STRIP = 2, 3, 4
# Header stamps written in ~/progress (plan_stamp, state_stamp) match a message's within [s].
STAMP_MATCH_S = 1e-6
# A header.stamp mapped farther than this from the plan's receipt is not trusted [s].
STAMP_SANITY_S = 10.0
# Events of ~/progress that are not the solve of a published plan matched by time.
NOT_A_PLAN = (EVENT_REPLAN_KEPT, EVENT_REPLANNED)


@dataclass
class Plan:
    """One trajectory message and what was in force when it arrived."""

    index: int
    time: float                    # receipt [s]
    joint_names: List[str]
    times: np.ndarray              # (M,) from the trajectory start [s]
    states: np.ndarray             # (M, 4) q1, dq1, q2, dq2
    efforts: Optional[np.ndarray]  # (M, 2) planned controls u
    obstacles: np.ndarray          # (K, 3) x, y, radius R'
    obstacles_source: str
    margin: float
    margin_source: str
    goal: Optional[np.ndarray] = None
    goal_source: str = ''
    solve: Optional[Solve] = None
    stamp: Optional[float] = None      # header.stamp on the time base [s] (None: zero stamp)
    stamp_abs: Optional[float] = None  # header.stamp [s, node clock]
    executed: bool = True              # False: replaced before its stamp
    execution: int = 0                 # index of its closed-loop execution

    @property
    def start(self):
        """Return when the plan starts to apply [s]: its header.stamp, else its receipt."""
        return self.time if self.stamp is None else self.stamp

    @property
    def begin(self):
        """Return when the plan takes over [s]: its start, or its receipt if that is later."""
        return max(self.start, self.time)

    @property
    def duration(self):
        """Return the plan's duration [s]."""
        return float(self.times[-1])


@dataclass
class Execution:
    """The measured run of one plan, with the plan's reference at the measured times."""

    plan: int
    times: np.ndarray                   # (K,) [s]
    states: np.ndarray                  # (K, 4) measured
    efforts: Optional[np.ndarray]       # (K, 2) applied
    reference: np.ndarray               # (K, 4) planned state at the same times
    interrupted: bool                   # the next plan came before this one ended


def obstacles_from_markers(marker_array):
    """
    Read (rows x, y, R', margin or None) from obstacle markers; None when there are none.

    Bodies: spheres/cylinders in a namespace mentioning 'obstacle'; inflated circles: a
    namespace mentioning 'inflat' (a ring of points or a sphere/cylinder).
    """
    bodies, rings = [], []
    for marker in marker_array.markers:
        ns = marker.ns.lower()
        if 'obstacle' not in ns and 'inflat' not in ns:
            continue
        if marker.type in (MARKER_SPHERE, MARKER_CYLINDER):
            row = (marker.pose.position.x, marker.pose.position.y, 0.5 * marker.scale.x)
        elif marker.type == MARKER_LINE_STRIP and len(marker.points) >= 3:
            pts = np.array([(p.x, p.y) for p in marker.points])
            if np.allclose(pts[0], pts[-1]):
                pts = pts[:-1]
            centre = pts.mean(axis=0)
            row = (centre[0], centre[1], float(np.mean(np.hypot(*(pts - centre).T))))
        else:
            continue
        (rings if 'inflat' in ns else bodies).append(row)
    if not bodies:
        return None
    margins = []
    for x, y, r in bodies:
        near = [ring for ring in rings if math.hypot(ring[0] - x, ring[1] - y) < 1e-3]
        if near:
            margins.append(near[0][2] - r)
    margin = float(np.median(margins)) if margins else None
    return np.array(bodies, dtype=float).reshape(-1, 3), margin


def _obstacles_for(run, time, previous_time, warn):
    """Obstacles (rows, source) and margin in force for a plan received at time."""
    params = run.params
    margin, margin_source = float(params['obstacles.margin']), 'parameters'
    rows, source = None, None
    latest = latest_before(run.messages['obstacles'], time)
    if latest is not None:
        try:
            rows = np.array(obstacle_rows_from_msg(latest[1]), dtype=float).reshape(-1, 3)
            source = f'{run.topics["obstacles"]} at {latest[0]:.3f} s'
        except ConversionError as error:
            warn(f'obstacles message at {latest[0]:.3f} s unusable: {error}')
    markers = [(t, m) for t, m in run.messages['markers']
               if previous_time < t <= time + MARKER_DELAY_S]
    parsed = None
    for t, msg in reversed(markers):
        parsed = obstacles_from_markers(msg)
        if parsed is not None:
            break
    if parsed is not None:
        if rows is None:
            rows, source = parsed[0], f'{run.topics["markers"]} at {t:.3f} s'
        if parsed[1] is not None:
            margin, margin_source = parsed[1], 'markers'
    if rows is None:
        rows = np.array(obstacle_rows(params), dtype=float).reshape(-1, 3)
        source = 'parameter file'
    return rows, source, margin, margin_source


def _goal_for(run, time, previous_time, a, joint_names, end=None):
    """
    Joint goal (q1, dq1, q2, dq2) sent since the previous plan, and its source.

    a: the RobotModel (or hand offset); of several IK branches, the one nearest to end.
    """
    candidates = []
    pose = latest_before(run.messages['goal_pose'], time, previous_time)
    model = as_model(a)
    if pose is not None:
        goals = []
        for branch in getattr(model, 'ik_branches', None) or (None,):
            try:
                goals.append(pose_to_joint_goal(pose[1], pose[1].header.frame_id, model,
                                                branch=branch))
            except ConversionError:
                pass            # not reachable on this branch (or another frame): try the others
        if goals:
            goal = min(goals, key=lambda g: 0.0 if end is None else np.linalg.norm(g - end))
            candidates.append((pose[0], goal, f'{run.topics["goal_pose"]} at {pose[0]:.3f} s'))
    joints = latest_before(run.messages['goal_joints'], time, previous_time)
    if joints is not None:
        try:
            candidates.append((joints[0], joint_state_to_state(joints[1], joint_names),
                               f'{run.topics["goal_joints"]} at {joints[0]:.3f} s'))
        except ConversionError:
            pass                # not a goal for this model's joints
    if not candidates:
        return None, ''
    _, goal, source = max(candidates, key=lambda c: c[0])
    return goal, source


def build_plans(run, solves, warn) -> List[Plan]:
    """One Plan per usable trajectory message, matched with its solve's final progress."""
    plans = []
    model = run_model(run)
    free = [s for s in solves if s.final_time is not None]
    previous = -math.inf
    for time, msg in run.messages['trajectory']:
        names = list(msg.joint_names)
        if len(names) != 2 or len(msg.points) < 2:
            warn(f'trajectory at {time:.3f} s skipped: it needs 2 joints and >= 2 points '
                 f'(has {len(names)} joints, {len(msg.points)} points)')
            continue
        try:
            arrays = trajectory_arrays(msg, names)
        except ConversionError as error:
            warn(f'trajectory at {time:.3f} s skipped: {error}')
            continue
        states = np.column_stack([arrays.positions[:, 0], arrays.velocities[:, 0],
                                  arrays.positions[:, 1], arrays.velocities[:, 1]])
        rows, source, margin, margin_source = _obstacles_for(run, time, previous, warn)
        goal, goal_source = _goal_for(run, time, previous, model, names, states[-1])
        stamp_ns = nanoseconds(msg.header.stamp)
        plan = Plan(index=len(plans), time=time, joint_names=names, times=arrays.times,
                    states=states, efforts=arrays.efforts, obstacles=rows,
                    obstacles_source=source, margin=margin, margin_source=margin_source,
                    goal=goal, goal_source=goal_source, stamp=run.stamp_time(msg.header.stamp),
                    stamp_abs=stamp_ns * 1e-9 if stamp_ns else None)
        if plan.stamp is not None and abs(plan.stamp - time) > STAMP_SANITY_S:
            warn(f'trajectory at {time:.3f} s: its header.stamp maps to {plan.stamp:.3f} s '
                 f'(clock offset {run.clock_offset_ns * 1e-9:.6g} s); using its receipt')
            plan.stamp = None
        # A replan cycle's report names its plan by stamp; other solves are matched by time.
        near = [s for s in free if plan.stamp_abs is not None
                and abs(as_float(s.report.plan_stamp) - plan.stamp_abs) <= STAMP_MATCH_S]
        near = near or [s for s in free if abs(s.final_time - time) <= PROGRESS_MATCH_S
                        and s.status != Status.INVALID_INPUT.value
                        and s.report.event not in NOT_A_PLAN]
        if near:
            plan.solve = min(near, key=lambda s: abs(s.final_time - time))
            free.remove(plan.solve)
            reported = finite_vector(plan.solve.report.goal)
            if reported is not None:  # the goal the solver used (covers ~/plan requests)
                plan.goal, plan.goal_source = reported, 'solver progress'
        plans.append(plan)
        previous = time
    return plans


def reference_at(plan: Plan, elapsed: np.ndarray) -> np.ndarray:
    """Planned state at times elapsed [s] after the plan's start (linear; held after)."""
    return np.column_stack([np.interp(elapsed, plan.times, plan.states[:, j])
                            for j in range(4)])


def joint_samples(items, joint_names, run=None):
    """
    Split joint_states into times, states (K, 4), efforts (K, 2; nan if absent), skipped.

    Times are the messages' header stamps on the time base (run given), else log times.
    """
    times, states, efforts = [], [], []
    skipped = 0
    for time, msg in items:
        try:
            pos, vel = joint_state_arrays(msg, joint_names)
        except ConversionError:
            skipped += 1
            continue
        names = list(msg.name)
        times.append(time if run is None else run.sample_time(time, msg))
        states.append((pos[0], vel[0], pos[1], vel[1]))
        efforts.append([msg.effort[names.index(n)] for n in joint_names]
                       if len(msg.effort) == len(names) else [math.nan, math.nan])
    return (np.array(times, dtype=float), np.array(states, dtype=float).reshape(-1, 4),
            np.array(efforts, dtype=float).reshape(-1, 2), skipped)


def measured_series(run, joint_names):
    """Collect (times, states (K, 4), efforts (K, 2) or None) of all usable joint_states."""
    times, states, efforts, _ = joint_samples(run.messages['joint_states'], joint_names, run)
    if not times.size:
        return None
    return times, states, None if np.all(np.isnan(efforts)) else efforts


def mark_executed(plans):
    """Set Plan.executed: False for a plan that a later plan replaced before its start."""
    for k, plan in enumerate(plans):
        plan.executed = not (k + 1 < len(plans) and plans[k + 1].time < plan.start)


def build_executions(run, plans, warn) -> List[Execution]:
    """Collect the joint_states of each executed plan's window, by the plan's joint names."""
    executions = []
    samples = run.messages['joint_states']
    order = sorted(range(len(samples)), key=lambda i: run.sample_time(*samples[i]))
    samples = [samples[i] for i in order]
    sample_times = [run.sample_time(t, m) for t, m in samples]
    skipped = 0
    executed = [plan for plan in plans if plan.executed]
    for k, plan in enumerate(executed):
        end = executed[k + 1].begin if k + 1 < len(executed) else math.inf
        window = samples[bisect.bisect_left(sample_times, plan.begin):
                         bisect.bisect_left(sample_times, end)]
        times, states, efforts, bad = joint_samples(window, plan.joint_names, run)
        skipped += bad
        if not times.size:
            continue
        executions.append(Execution(
            plan=plan.index, times=times, states=states,
            efforts=None if np.all(np.isnan(efforts)) else efforts,
            reference=reference_at(plan, times - plan.start),
            interrupted=end < plan.start + plan.duration))
    if skipped:
        warn(f'{skipped} joint_states messages lack the planned joints and were skipped')
    return executions
