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
The numbers of a recorded run: per plan, per execution and per closed-loop execution.

Time base: seconds from the first message read, on the recorder's log (receive) time axis.
Header stamps (node clock: joint_states, trajectories, the stamps in ~/progress) are mapped
onto it by the clock offset: the median of log time - header.stamp over the joint_states
with a stamp (0 when none has one: the node clock is taken to be the recorder's).

A plan is one trajectory message. Its execution starts at its header.stamp when that is
nonzero (JTC semantics: a plan received after its stamp is trimmed, i.e. runs from its
receipt at the stamp's elapsed time), else at its receipt; a plan replaced (a later plan
received) before its stamp never executed. An executed plan runs until the next executed
plan starts or the recording ends. Everything a plan is checked against is what was in force
when it arrived: the latest obstacles message before it (else the solver's obstacle markers,
else the parameter file), the latest goal since the previous plan (or the goal its solve
reported). Missing topics leave the numbers that need them at None and are listed in
``missing``.

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
from dataclasses import dataclass, field
import math
from typing import Dict, List, Optional

import numpy as np

from toc_ros.config import model_from_parameters, obstacle_rows
from toc_ros.conversions import (as_model, ConversionError, joint_state_arrays,
                                 joint_state_to_state, obstacle_rows_from_msg,
                                 pose_to_joint_goal, trajectory_arrays)
from toc_ros.core import ProblemError, Status
from toc_ros.core.obstacles import model_clearance, scheduled_clearance
from toc_ros.progress import (EVENT_REPLACED, EVENT_REPLAN_KEPT, EVENT_REPLANNED, EVENT_STOPPED,
                              progress_from_msg, ProgressReport)

from .closed_loop import execution_metrics, PlanSpan

# Role -> (last name token, type). Names are matched below any namespace.
ROLES = {
    'trajectory': ('trajectory', 'trajectory_msgs/msg/JointTrajectory'),
    'joint_states': ('joint_states', 'sensor_msgs/msg/JointState'),
    'progress': ('progress', 'diagnostic_msgs/msg/DiagnosticStatus'),
    'goal_pose': ('goal_pose', 'geometry_msgs/msg/PoseStamped'),
    'goal_joints': ('goal_joints', 'sensor_msgs/msg/JointState'),
    'obstacles': ('obstacles', 'std_msgs/msg/Float64MultiArray'),
    'markers': ('markers', 'visualization_msgs/msg/MarkerArray'),
}
# What is lost without a role (for the 'missing' list).
NEEDED_FOR = {
    'trajectory': 'plans, planned curves, violations',
    'joint_states': 'executions: measured states, applied effort, tracking error',
    'progress': 'solver status, iterations, solve time, convergence plot',
    'obstacles': 'obstacles sent at run time (else markers or the parameter file are used)',
    'goal_pose': 'the goal of a plan the solver did not report (its terminal error)',
}
# A plan and the final progress of its solve are published within this time [s].
PROGRESS_MATCH_S = 2.0
# Markers up to this long after a plan still show the obstacles it was planned around [s].
MARKER_DELAY_S = 1.0
MARKER_SPHERE, MARKER_CYLINDER, MARKER_LINE_STRIP = 2, 3, 4
# Header stamps written in ~/progress (plan_stamp, state_stamp) match a message's within [s].
STAMP_MATCH_S = 1e-6
# A header.stamp mapped farther than this from the plan's receipt is not trusted [s].
STAMP_SANITY_S = 10.0
# Plans whose goals differ by at most this belong to one closed-loop execution [rad or m].
GOAL_TOL = 1e-6
# Goal sources of user requests: such a plan after the previous execution ended starts anew.
REQUEST_SOURCES = ('goal_pose', 'goal_joints', '~/plan')
# A joint_states step larger than this is a reset of the (simulated) robot, not motion: it
# ends the execution's samples [rad or m].
RESET_JUMP = 0.1
# Events of ~/progress that are not the solve of a published plan matched by time.
NOT_A_PLAN = (EVENT_REPLAN_KEPT, EVENT_REPLANNED)
# Events counted per closed-loop execution (summary key -> event).
EVENTS = {'replanned': EVENT_REPLANNED, 'replan_kept': EVENT_REPLAN_KEPT,
          'trajectory_stopped': EVENT_STOPPED, 'trajectory_replaced': EVENT_REPLACED}


def _float(value) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def _num(value):
    """JSON number or None for nan/inf/missing."""
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def find_topics(topics: Dict[str, object], warn=None) -> Dict[str, Optional[str]]:
    """Topic of each role: last name token and type match; the shortest name wins."""
    found = {}
    for role, (token, type_name) in ROLES.items():
        names = sorted((n for n, info in topics.items()
                        if n.rstrip('/').split('/')[-1] == token
                        and info.type_name == type_name), key=lambda n: (n.count('/'), n))
        found[role] = names[0] if names else None
        if len(names) > 1 and warn is not None:
            warn(f'several {token} topics ({", ".join(names)}); analysing {names[0]}')
    return found


@dataclass
class Solve:
    """One solve as progress shows it: running values and the final status message."""

    points: List[dict] = field(default_factory=list)   # iteration, t_f, cost, elapsed_s
    final_time: Optional[float] = None                  # [s] of the final progress message
    status: str = 'unfinished'
    message: str = ''
    report: ProgressReport = field(default_factory=ProgressReport)   # the final message


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


@dataclass
class RecordedRun:
    """Everything read from a recording, decoded, by role."""

    topics: Dict[str, Optional[str]]
    messages: Dict[str, list]           # role -> [(time [s], message)]
    start_ns: int
    params: dict
    model: object = None                # the RobotModel (recorded_model), set by load_run
    model_source: str = 'parameters'
    clock_offset_ns: int = 0            # log time - header.stamp (see the module docstring)
    clock_source: str = 'none'

    def stamp_time(self, stamp) -> Optional[float]:
        """Return a builtin_interfaces/Time on the time base [s] (None for a zero stamp)."""
        ns = stamp.sec * 1_000_000_000 + stamp.nanosec
        return None if ns == 0 else (ns + self.clock_offset_ns - self.start_ns) * 1e-9

    def node_time(self, seconds) -> float:
        """Return a node-clock time [s] (e.g. a stamp written in ~/progress) on the base."""
        return seconds + (self.clock_offset_ns - self.start_ns) * 1e-9

    def sample_time(self, time, msg) -> float:
        """Return a message's time on the base [s]: its header.stamp, else its log time."""
        stamped = self.stamp_time(msg.header.stamp)
        return time if stamped is None else stamped


def load_run(recording, params, warn=None) -> RecordedRun:
    """Decode the messages of every role from a toc_ros.recording.bag_reader.Recording."""
    readable = recording.readable_topics()
    topics = find_topics(readable, warn)
    by_topic = {t: r for r, t in topics.items() if t is not None}
    raw = {role: [] for role in ROLES}
    for message, decoded in recording.decoded(list(by_topic)):
        raw[by_topic[message.topic]].append((message.log_time_ns, decoded))
    firsts = [items[0][0] for items in raw.values() if items]
    start_ns = min(firsts) if firsts else 0
    messages = {role: [((t - start_ns) * 1e-9, m) for t, m in sorted(items, key=lambda x: x[0])]
                for role, items in raw.items()}
    run = RecordedRun(topics, messages, start_ns, dict(params))
    run.model, run.model_source = recorded_model(run, warn)
    run.clock_offset_ns, run.clock_source = clock_offset(raw['joint_states'], warn)
    return run


def _stamp_ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def clock_offset(joint_states, warn=None):
    """
    Return (offset [ns], source): the median of log time - header.stamp of joint_states.

    joint_states: [(log time [ns], message)]. Without stamped joint_states the offset is 0
    (the node clock is taken to be the recorder's log clock).
    """
    gaps = np.array([t - _stamp_ns(m.header.stamp) for t, m in joint_states
                     if _stamp_ns(m.header.stamp) > 0], dtype=float)
    if not gaps.size:
        return 0, 'none (no stamped joint_states): node clock = log clock'
    offset = int(round(float(np.median(gaps))))
    spread = float(np.percentile(gaps, 95) - np.percentile(gaps, 5)) * 1e-9
    if spread > 0.5 and warn is not None:
        warn(f'the joint_states stamps and log times drift apart by {spread:.3g} s (5-95 %): '
             'times mapped from header stamps are uncertain by that much')
    return offset, f'median log time - header.stamp of {gaps.size} joint_states'


def recorded_model(run, warn=None):
    """
    Return (RobotModel, source) of a run.

    The robot_model / model_parameters that solver_node wrote on ~/progress (ready and result
    reports), else the parameters (--params).
    """
    for _, msg in run.messages.get('progress', ()):
        report = progress_from_msg(msg)
        if not report.robot_model:
            continue
        params = dict(run.params)
        params['robot.model'] = report.robot_model
        params['robot.model_parameters'] = [
            p.strip() for p in report.model_parameters.split(',') if p.strip()]
        try:
            return model_from_parameters(params), 'solver progress'
        except ProblemError as error:
            if warn is not None:
                warn(f'the recorded robot model {report.robot_model!r} cannot be built here '
                     f'({error}); using the parameters')
            break
    try:
        return model_from_parameters(run.params), 'parameters'
    except ProblemError as error:
        if warn is not None:
            warn(f'robot model of the parameters: {error}; using the cylindrical robot')
        return as_model(1.1), 'default'


def run_model(run_or_a):
    """Return the RobotModel of a RecordedRun, or as_model of a model / hand offset."""
    if isinstance(run_or_a, RecordedRun):
        return run_or_a.model if run_or_a.model is not None else recorded_model(run_or_a)[0]
    return as_model(run_or_a)


def hand_xy(model, states):
    """Return the hand positions (x, y) [m] of 2-joint states (M, 4) of the model."""
    hand = model.hand_position(np.asarray(states, dtype=float)[..., 0::2])
    return hand[..., 0], hand[..., 1]


# -- solves, plans, executions --------------------------------------------------------------
def solves_from_progress(progress) -> List[Solve]:
    """
    Group progress messages into solves, in the order they end.

    A solve is the running messages of one node name ended by its result (a final status
    with an iteration count). A final status without one (a refused goal, a dropped request)
    is a solve of its own that does not end the one running.
    """
    solves = []
    running: Dict[str, Solve] = {}
    for time, msg in progress:
        report = progress_from_msg(msg)
        if report.solving:
            running.setdefault(msg.name, Solve()).points.append({
                'time': time, 'iteration': _float(report.iteration), 't_f': _float(report.t_f),
                'cost': _float(report.cost), 'elapsed_s': _float(report.elapsed_s)})
            continue
        if not report.final:       # a notice (ready, queued), not part of a solve
            continue
        if report.iteration is not None:
            solve = running.pop(msg.name, None) or Solve()
        else:
            solve = Solve()
        solve.final_time, solve.status = time, report.status.value
        solve.message, solve.report = msg.message, report
        solves.append(solve)
    for solve in running.values():  # the recording ends during a solve
        solve.message = (f'the recording ends during this solve (last progress at '
                         f'{solve.points[-1]["time"]:.3f} s, iteration '
                         f'{solve.points[-1]["iteration"]:.0f})')
        solves.append(solve)
    return solves


def _vector(values, size=4):
    """Array of size finite numbers from a sequence (None when it is not one)."""
    if values is None:
        return None
    values = np.asarray(values, dtype=float)
    return values if values.shape == (size,) and np.all(np.isfinite(values)) else None


def _latest(items, before, after=-math.inf):
    """Latest (time, message) with after < time <= before, or None."""
    chosen = None
    for time, msg in items:
        if time > before:
            break
        if time > after:
            chosen = (time, msg)
    return chosen


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
    latest = _latest(run.messages['obstacles'], time)
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
    pose = _latest(run.messages['goal_pose'], time, previous_time)
    model = as_model(a)
    if pose is not None:
        goals = []
        for branch in getattr(model, 'ik_branches', None) or (None,):
            try:
                goals.append(pose_to_joint_goal(pose[1], pose[1].header.frame_id, model,
                                                branch=branch))
            except ConversionError:
                pass
        if goals:
            goal = min(goals, key=lambda g: 0.0 if end is None else np.linalg.norm(g - end))
            candidates.append((pose[0], goal, f'{run.topics["goal_pose"]} at {pose[0]:.3f} s'))
    joints = _latest(run.messages['goal_joints'], time, previous_time)
    if joints is not None:
        try:
            candidates.append((joints[0], joint_state_to_state(joints[1], joint_names),
                               f'{run.topics["goal_joints"]} at {joints[0]:.3f} s'))
        except ConversionError:
            pass
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
        stamp_ns = _stamp_ns(msg.header.stamp)
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
                and abs(_float(s.report.plan_stamp) - plan.stamp_abs) <= STAMP_MATCH_S]
        near = near or [s for s in free if abs(s.final_time - time) <= PROGRESS_MATCH_S
                        and s.status != Status.INVALID_INPUT.value
                        and s.report.event not in NOT_A_PLAN]
        if near:
            plan.solve = min(near, key=lambda s: abs(s.final_time - time))
            free.remove(plan.solve)
            reported = _vector(plan.solve.report.goal)
            if reported is not None:  # the goal the solver used (covers ~/plan requests)
                plan.goal, plan.goal_source = reported, 'solver progress'
        plans.append(plan)
        previous = time
    return plans


def reference_at(plan: Plan, elapsed: np.ndarray) -> np.ndarray:
    """Planned state at times elapsed [s] after the plan's start (linear; held after)."""
    return np.column_stack([np.interp(elapsed, plan.times, plan.states[:, j])
                            for j in range(4)])


def _joint_samples(items, joint_names, run=None):
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
    times, states, efforts, _ = _joint_samples(run.messages['joint_states'], joint_names, run)
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
        times, states, efforts, bad = _joint_samples(window, plan.joint_names, run)
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


# -- closed-loop executions -----------------------------------------------------------------
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
    """Return (n, K) clearance [m] of every link to each true obstacle row (nan: absent)."""
    return scheduled_clearance(model, times, positions, schedule)


def _by_stamp(items):
    """Return (stamps, log times): header.stamp [s, node clock] sorted, log time [s]."""
    pairs = sorted((_stamp_ns(m.header.stamp) * 1e-9, t) for t, m in items
                   if _stamp_ns(m.header.stamp) > 0)
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
    all_times, all_states, _, _ = _joint_samples(samples, names, run)
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
            at = published if published is not None else run.node_time(_float(r.plan_stamp))
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


def closed_loop_numbers(loop: ClosedLoop, plans: List[Plan]) -> dict:
    """Summary entry of a closed-loop execution (times from its t0 unless said otherwise)."""
    m = loop.metrics
    mine = [plans[i] for i in loop.plans]
    late = [p.time - p.start for p in mine if p.stamp is not None and p.time > p.start]

    def latency(prefix, count):
        return {'median_s': _num(m[f'{prefix}_median_s']), 'p99_s': _num(m[f'{prefix}_p99_s']),
                'max_s': _num(m[f'{prefix}_max_s']), 'count': count}
    return {
        'index': loop.index,
        'plans': loop.plans,
        'plan_count': len(loop.plans),
        'executed_plans': sum(p.executed for p in mine),
        'goal': loop.goal.tolist(),
        'goal_source': loop.goal_source or None,
        'start_s': loop.t0,
        'samples': int(loop.times.size),
        'events': loop.events,
        'planned_t_min': _num(m['planned_t_min']),
        'arrival_s': _num(m['arrival_s']),
        'last_plan_end_s': _num(m['last_plan_end_s']),
        'final_error': _num(m['final_error']),
        'min_clearance': _num(m['min_clearance']),
        # plans the recorder received after their stamp (the plant trims their start)
        'late_receipts': {'count': len(late), 'max_s': max(late) if late else None},
        'planned_arrivals': [{'plan': p.index, 'received_s': p.time - loop.t0,
                              'arrival_s': p.start + p.duration - loop.t0,
                              'executed': p.executed} for p in mine],
        'latency_node': latency('latency', m['latencies']),
        'latency_recorded': {**latency('recorded_latency', m['recorded_latencies']),
                             'unmatched': loop.unmatched},
    }


# -- numbers --------------------------------------------------------------------------------
def plan_numbers(plan: Plan, u_max: np.ndarray, a, start_state=None) -> dict:
    """Summary entry of a plan (a: RobotModel or hand offset): report and violations."""
    solve = plan.solve or Solve(status='unknown')
    report = solve.report
    excess = None
    if plan.efforts is not None:
        excess = max(float(np.max(np.abs(plan.efforts) - u_max[None, :])), 0.0)
    circles = plan.obstacles.copy()
    circles[:, 2] += plan.margin
    clearance = (float(np.min(model_clearance(as_model(a), plan.states, circles)))
                 if len(circles) else None)
    terminal = (float(np.linalg.norm(plan.states[-1] - plan.goal))
                if plan.goal is not None else None)
    start_error = (float(np.linalg.norm(plan.states[0] - start_state))
                   if start_state is not None else None)
    return {
        'index': plan.index,
        'received_s': plan.time,
        'stamp_s': plan.stamp,
        'start_s': plan.start,
        'executed': plan.executed,
        'closed_loop': plan.execution,
        'event': report.event or None,
        'status': solve.status,
        'message': solve.message,
        't_min': float(plan.times[-1]),
        'solve_wall_time_s': _num(_float(report.elapsed_s)),
        'iterations': report.iteration,
        'points': int(plan.times.size),
        'joint_names': plan.joint_names,
        'goal': None if plan.goal is None else plan.goal.tolist(),
        'goal_source': plan.goal_source or None,
        'obstacles': plan.obstacles.tolist(),
        'obstacles_source': plan.obstacles_source,
        'margin': plan.margin,
        'margin_source': plan.margin_source,
        'violations': {'max_control_excess': _num(excess), 'terminal_error': _num(terminal),
                       'min_clearance': _num(clearance), 'start_error': _num(start_error)},
        'reported_violations': {
            'max_control_excess': _num(_float(report.max_control_excess)),
            'terminal_error': _num(_float(report.terminal_error)),
            'min_clearance': _num(_float(report.min_clearance))},
    }


def tracking_errors(execution: Execution, a) -> dict:
    """Per-sample errors: q1, q2 [rad or m] and hand position [m] (measured - planned)."""
    meas, ref = execution.states, execution.reference
    model = as_model(a)
    hand_m = np.column_stack(hand_xy(model, meas))
    hand_r = np.column_stack(hand_xy(model, ref))
    return {'q1': meas[:, 0] - ref[:, 0], 'q2': meas[:, 2] - ref[:, 2],
            'hand': np.hypot(*(hand_m - hand_r).T)}


def execution_numbers(execution: Execution, plan: Plan, a, u_max: np.ndarray) -> dict:
    """Summary entry of an execution: final error, RMS tracking error, max effort."""
    errors = tracking_errors(execution, a)
    final = execution.states[-1]
    target = plan.states[-1]
    model = as_model(a)
    hand_final = np.hypot(*(np.array(hand_xy(model, final)) - np.array(hand_xy(model, target))))
    max_effort = (None if execution.efforts is None
                  else np.nanmax(np.abs(execution.efforts), axis=0))
    return {
        'plan': execution.plan,
        'start_s': float(execution.times[0]),
        'end_s': float(execution.times[-1]),
        'samples': int(execution.times.size),
        'interrupted': bool(execution.interrupted),
        'final_error': float(np.linalg.norm(final - target)),
        'final_state': final.tolist(),
        'final_hand_error': float(hand_final),
        'rms_error': {k: float(np.sqrt(np.mean(v ** 2))) for k, v in errors.items()},
        'max_hand_error': float(np.max(errors['hand'])),
        'max_effort': None if max_effort is None else max_effort.tolist(),
        'effort_within_bounds': (None if max_effort is None
                                 else bool(np.all(max_effort <= u_max * (1 + 1e-9)))),
    }


@dataclass
class Report:
    """A run's numbers (summary, JSON-ready) and the arrays the plots draw."""

    run: RecordedRun
    solves: List[Solve]
    plans: List[Plan]
    executions: List[Execution]
    summary: dict
    measured: Optional[tuple] = None    # (times, states, efforts) of all joint_states
    closed_loops: List[ClosedLoop] = field(default_factory=list)


def missing_roles(run, goal_needed=True) -> List[str]:
    """Sentences for the roles a recording lacks (goals only if a plan's goal is unknown)."""
    missing = []
    for role, what in NEEDED_FOR.items():
        if run.topics.get(role) is not None and run.messages[role]:
            continue
        if role == 'goal_pose' and (run.messages['goal_joints'] or not goal_needed):
            continue
        token, type_name = ROLES[role]
        state = 'no messages on' if run.topics.get(role) else 'no topic'
        missing.append(f'{state} {run.topics.get(role) or token} ({type_name}): '
                       f'without it: {what}')
    return missing


def analyse(run: RecordedRun, recording_info: dict, warn) -> Report:
    """Plans, executions and the summary of a loaded run."""
    model = run_model(run)
    a = float(model.params.a) if model.name == 'cylindrical' else None
    u_max = np.asarray(model.u_max, dtype=float)
    solves = solves_from_progress(run.messages['progress'])
    plans = build_plans(run, solves, warn)
    mark_executed(plans)
    executions = build_executions(run, plans, warn)
    loops = build_closed_loops(run, plans, model)
    plan_entries = []
    for plan in plans:
        before = _latest(run.messages['joint_states'], plan.time)
        start = None
        if before is not None:
            try:
                start = joint_state_to_state(before[1], plan.joint_names)
            except ConversionError:
                pass
        plan_entries.append(plan_numbers(plan, u_max, model, start))
    duration = max((items[-1][0] for items in run.messages.values() if items), default=0.0)
    summary = {
        **recording_info,
        'start_time_ns': run.start_ns,
        'duration_s': duration,
        'topics': run.topics,
        'robot': {'model': model.name, 'model_source': run.model_source,
                  'model_parameters': _model_parameters(model), 'joint_kinds':
                  list(model.joint_kinds), 'n_links': int(model.n_links), 'a': a,
                  'u_max': u_max.tolist()},
        'plans': plan_entries,
        'executions': [execution_numbers(e, plans[e.plan], model, u_max) for e in executions],
        'closed_loop': [closed_loop_numbers(loop, plans) for loop in loops],
        'events': {key: sum(loop.events[key] for loop in loops) for key in EVENTS},
        'clock': {'offset_s': run.clock_offset_ns * 1e-9, 'source': run.clock_source},
        'solves': [{'status': s.status, 'message': s.message,
                    'time_s': _num(s.final_time), 'progress_messages': len(s.points),
                    'iterations': _num(_float(s.report.iteration)),
                    'elapsed_s': _num(_float(s.report.elapsed_s))} for s in solves],
        'missing': missing_roles(run, any(p.goal is None for p in plans)),
    }
    names = plans[0].joint_names if plans else list(run.params['joint_names'])
    return Report(run, solves, plans, executions, summary, measured_series(run, names), loops)


def _model_parameters(model):
    """Return the model's parameter values as {name: value} (JSON-ready)."""
    data = model.params
    if hasattr(data, 'as_dict'):
        return {k: float(v) for k, v in data.as_dict().items()}
    return {f: getattr(data, f) for f in data.__dataclass_fields__}


# -- Markdown -------------------------------------------------------------------------------
def _fmt(value, digits=4, unit=''):
    if value is None:
        return 'n/a'
    if isinstance(value, float):
        return f'{value:.{digits}g}{unit}'
    return f'{value}{unit}'


def markdown(summary: dict) -> str:
    """Render the summary as Markdown (tables, plots linked by file name)."""
    lines = [f'# Run report: {summary["recording"]}', '',
             f'{len(summary["plans"])} plan(s), {len(summary["executions"])} execution(s), '
             f'{len(summary.get("closed_loop", []))} closed-loop execution(s), '
             f'{len(summary["solves"])} solve(s) over {summary["duration_s"]:.2f} s. '
             'Times are log (receive) times from the first message; header stamps are mapped '
             'onto them by the clock offset '
             f'{_fmt((summary.get("clock") or {}).get("offset_s"), 6, " s")} '
             f'({(summary.get("clock") or {}).get("source", "n/a")}). A plan starts at its '
             'header.stamp (else at its receipt). Violations are recomputed from the '
             'trajectory (min clearance of the whole arm to the inflated circles, '
             'negative = collision).', '']
    robot = summary.get('robot') or {}
    if robot.get('model'):
        given = robot['model_parameters'] if 'model_parameters' in robot else {}
        values = ', '.join(f'{k} = {v}' for k, v in (given or {}).items())
        lines += [f'Robot model: {robot["model"]} (from the {robot.get("model_source")}): '
                  f'{values}.', '']
    if summary['plans']:
        lines += ['## Plans', '',
                  '| # | received [s] | starts [s] | status | t_min [s] | solve time [s] '
                  '| iterations | control excess | terminal error | min clearance [m] '
                  '| start error |',
                  '|---|---|---|---|---|---|---|---|---|---|---|']
        for p in summary['plans']:
            v = p['violations']
            start = (f'{p["start_s"]:.3f}' if p.get('start_s') is not None else 'n/a') + (
                '' if p.get('executed', True) else ' (replaced before)')
            lines.append(
                f'| {p["index"]} | {p["received_s"]:.3f} | {start} | {p["status"]} '
                f'| {p["t_min"]:.4f} '
                f'| {_fmt(p["solve_wall_time_s"], 3)} | {_fmt(p["iterations"])} '
                f'| {_fmt(v["max_control_excess"], 3)} | {_fmt(v["terminal_error"], 3)} '
                f'| {_fmt(v["min_clearance"], 3)} | {_fmt(v["start_error"], 3)} |')
        lines.append('')
        for p in summary['plans']:
            lines.append(f'- plan {p["index"]}: obstacles {p["obstacles"]} from '
                         f'{p["obstacles_source"]}, margin {p["margin"]:.3g} m from '
                         f'{p["margin_source"]}; goal from {_fmt(p["goal_source"])}')
        lines.append('')
    if summary['executions']:
        lines += ['## Executions', '',
                  '| plan | from [s] | to [s] | final error | final hand error [m] '
                  '| RMS q1 [rad] | RMS q2 [m] | RMS hand [m] | max effort u1 [N m], u2 [N] |',
                  '|---|---|---|---|---|---|---|---|---|']
        for e in summary['executions']:
            rms = e['rms_error']
            effort = ('n/a' if e['max_effort'] is None
                      else ', '.join(f'{u:.4g}' for u in e['max_effort']))
            lines.append(
                f'| {e["plan"]}{" (interrupted)" if e["interrupted"] else ""} '
                f'| {e["start_s"]:.3f} | {e["end_s"]:.3f} | {e["final_error"]:.3g} '
                f'| {e["final_hand_error"]:.3g} | {rms["q1"]:.3g} | {rms["q2"]:.3g} '
                f'| {rms["hand"]:.3g} | {effort} |')
        lines.append('')
    lines += _closed_loop_markdown(summary.get('closed_loop') or [])
    other = [s for s in summary['solves']
             if s['status'] not in (Status.SOLVED.value, 'unknown')]
    if other:
        lines += ['## Other solver outcomes', '']
        lines += [f'- {_fmt(s["time_s"], 5)} s: {s["status"]}: {s["message"]}'
                  if s['time_s'] is not None else f'- {s["status"]}: {s["message"]}'
                  for s in other]
        lines.append('')
    plots = summary.get('plots', {})
    if plots:
        lines += ['## Plots', '']
        for name, entry in plots.items():
            if entry.get('file'):
                lines.append(f'![{name}]({entry["file"]})')
            else:
                lines.append(f'- {name}: not drawn: {entry.get("reason")}')
        lines.append('')
    if summary['missing'] or summary['warnings']:
        lines += ['## Missing data and warnings', '']
        lines += [f'- missing: {m}' for m in summary['missing']]
        lines += [f'- warning: {w}' for w in summary['warnings']]
        lines.append('')
    return '\n'.join(lines)


def _ms(latency):
    values = [latency.get(k) for k in ('median_s', 'p99_s', 'max_s')]
    if not latency.get('count'):
        return 'n/a'
    return ' / '.join('n/a' if v is None else f'{1e3 * v:.3g}' for v in values)


def _late(late):
    if not late.get('count'):
        return '0'
    return f'{late["count"]} ({1e3 * late["max_s"]:.3g})'


def _closed_loop_markdown(loops):
    """Lines of the closed-loop table (one row per execution)."""
    if not loops:
        return []
    lines = ['## Closed-loop executions', '',
             'Successive plans to one goal (replan cycles, braking, replacements). Times from '
             'the start of the first plan; arrival: every joint within 1e-3 of the goal from '
             'then on; final error: max joint error 0.2 s after the end of the last plan; min '
             'clearance: every link to the true (uninflated) obstacles in force, every '
             'joint_states sample. Latency node: latency_s of the replanned reports; '
             'recorded: log time of the trajectory minus that of the joint_states the cycle '
             'started from (its state_stamp). Received after stamp: plans the recorder '
             'received after their header.stamp (the plant trims their start).', '',
             '| # | plans (executed) | replanned | kept | stopped | planned t_min [s] '
             '| arrival [s] | last plan end [s] | final error | min clearance [m] '
             '| latency node median / p99 / max [ms] | latency recorded median / p99 / max '
             '[ms] | received after stamp (max [ms]) |',
             '|---|---|---|---|---|---|---|---|---|---|---|---|---|']
    for c in loops:
        ev = c['events']
        recorded = _ms(c['latency_recorded'])
        if c['latency_recorded'].get('unmatched'):
            recorded += f' ({c["latency_recorded"]["unmatched"]} unmatched)'
        lines.append(
            f'| {c["index"]} | {c["plan_count"]} ({c["executed_plans"]}) | {ev["replanned"]} '
            f'| {ev["replan_kept"]} | {ev["trajectory_stopped"]} '
            f'| {_fmt(c["planned_t_min"], 5)} | {_fmt(c["arrival_s"], 5)} '
            f'| {_fmt(c["last_plan_end_s"], 5)} | {_fmt(c["final_error"], 3)} '
            f'| {_fmt(c["min_clearance"], 4)} | {_ms(c["latency_node"])} | {recorded} '
            f'| {_late(c.get("late_receipts") or {})} |')
    lines.append('')
    return lines
