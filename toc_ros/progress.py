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
The schema of solver_node's ``~/progress`` (diagnostic_msgs/DiagnosticStatus): the one place.

A ProgressReport is what one message says; ``progress_msg(name, report)`` writes it and
``progress_from_msg(msg)`` reads it back (also from messages decoded out of a recording: only
``level``, ``name``, ``message`` and ``values[*].key/value`` are used).  While a solve runs the
status is None (written as ``SOLVING``); afterwards it is a core ``Status``.  Values are
strings: integers as digits, floats with 9 significant digits (clock times 17; 'nan' when
unknown), vectors as '[a, b, ...]', lists of names as 'a, b, ...'.  Keys whose value is unset
are left out.
"""

from dataclasses import dataclass, fields
import hashlib
import math
from typing import Optional, Tuple

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from toc_ros.core import Status

SOLVING = 'SOLVING'       # the status value of a running solve
IDLE = 'IDLE'             # the status value of a notice outside a solve (ready, queued)

LEVELS = {
    Status.SOLVED: DiagnosticStatus.OK,
    Status.SOLVED_INACCURATE: DiagnosticStatus.WARN,
    Status.CANCELED: DiagnosticStatus.WARN,
    Status.TIMEOUT: DiagnosticStatus.WARN,
    Status.MAX_ITERATIONS: DiagnosticStatus.ERROR,
    Status.STALLED: DiagnosticStatus.ERROR,
    Status.INVALID_INPUT: DiagnosticStatus.ERROR,
}
PUBLISHED = (Status.SOLVED, Status.SOLVED_INACCURATE)   # results that publish a trajectory

# What an 'event' key says besides the status (absent: a plain running or result message).
EVENT_REFUSED = 'refused'            # bad input, not queued
EVENT_SUPERSEDED = 'superseded'      # a queued request replaced before its solve started
EVENT_RESTARTED = 'restarted'        # the data changed during the solve: solved again
EVENT_QUEUED = 'queued'              # a goal that arrived before the node was ready
EVENT_READY = 'ready'                # the kernels are loaded (elapsed_s: how long it took)
EVENT_IDLE = 'idle'                  # an IDLE notice without a known event
SOLVE_EVENTS = ('', EVENT_RESTARTED)     # events of running-solve reports
EVENT_STOPPED = 'trajectory_stopped'     # the executing plan violates new data: stop sent
EVENT_REPLACED = 'trajectory_replaced'   # ... and a replacement plan was published
EVENT_REPLANNED = 'replanned'            # a replan cycle published a new plan (stamp ahead)
EVENT_REPLAN_KEPT = 'replan_kept'        # a replan cycle failed or was late: plan kept
EVENT_GOAL_CANCELED = 'goal_canceled'    # the goal was abandoned: no more cycles, braking
EVENT_START_IGNORED = 'start_ignored'    # a plan request's start differs from the measured
EVENT_EXECUTION = 'execution'            # a FollowJointTrajectory goal's outcome


@dataclass(frozen=True)
class ProgressReport:
    """What one ~/progress message says; None / '' fields are not written."""

    status: Optional[Status] = None          # None: solving
    message: str = ''
    level: Optional[bytes] = None            # None: by status (LEVELS; OK while solving)
    name: str = ''                           # node name (DiagnosticStatus.name)
    iteration: Optional[int] = None
    t_f: Optional[float] = None              # [s]
    cost: Optional[float] = None
    best_feasible_t_f: Optional[float] = None
    max_control_excess: Optional[float] = None
    terminal_error: Optional[float] = None
    min_clearance: Optional[float] = None    # [m], to the obstacles inflated by margin
    margin: Optional[float] = None           # [m] the obstacle margin planned with
    elapsed_s: Optional[float] = None
    phase: str = ''
    mode: str = ''
    integrator: str = ''
    n_intervals: Optional[int] = None
    goal_source: str = ''
    start_source: str = ''
    goal: Optional[Tuple[float, ...]] = None
    data_revision: Optional[int] = None   # counter of obstacle/margin/robot/limit changes
    obstacles_hash: str = ''                   # of the obstacle set (and margin) planned for
    event: str = ''
    robot_model: str = ''         # robot.model planned for (ready and result reports)
    model_parameters: str = ''    # its robot.model_parameters, 'name=value' joined by ', '
    # URDF arms (ready and result reports): what rebuilds the model planned for, so that a
    # recording analyses on another machine (toc_ros.arm_record writes and reads them).
    # Recordings made before these existed have none of them (arm_urdf_source empty).
    arm_joints: Tuple[str, ...] = ()         # the planned joints, in order
    arm_locked: Tuple[str, ...] = ()         # every locked joint 'JOINT=VALUE' [rad or m]
    arm_joint_limits: Tuple[str, ...] = ()   # robot.joint_limits 'JOINT.KEY=VALUE' overrides
    arm_tip_link: str = ''                   # the tip link in force (default resolved)
    # The URDF: 'panda' / 'ur5' (example-robot-data's), 'parameter' or 'topic' (the
    # robot_description parameter or topic); the sha256 of its text; the text itself only on
    # ready reports (once per model load) and only for 'parameter' (the topic is recorded).
    arm_urdf_source: str = ''
    arm_urdf_sha256: str = ''
    arm_urdf: str = ''
    # The collision spheres: the sphere file's path as the node had it, or 'shipped' (the
    # package's set of panda / ur5); the sha256 of its YAML text; the text on ready reports
    # (the path may not exist where the recording is analysed).
    arm_spheres_source: str = ''
    arm_spheres_sha256: str = ''
    arm_spheres: str = ''
    # Replan cycles: joint_states received -> trajectory published [s], the state's deviation
    # from the executing plan [rad or m], the new plan's header.stamp and the header.stamp of
    # the joint_states it started from [s, node clock].
    latency_s: Optional[float] = None
    deviation: Optional[float] = None
    plan_stamp: Optional[float] = None
    state_stamp: Optional[float] = None
    # Published cycles: the node clock when the trajectory was published [s] (before plan_stamp).
    published_stamp: Optional[float] = None
    # With replan.estimate: the estimated model parameters planned with, 'name=value, ...';
    # replan cycles say 'none: <reason>' while there is no usable estimate, goals ''.
    estimate: str = ''

    @property
    def solving(self):
        """Tell whether this reports a running solve."""
        return self.status is None and self.event in SOLVE_EVENTS

    @property
    def final(self):
        """Tell whether this ends a request (anything but a running solve)."""
        return self.status is not None

    @property
    def status_name(self):
        """Status as written: SOLVING, IDLE (a notice outside a solve) or the Status value."""
        if self.status is not None:
            return self.status.value
        return SOLVING if self.solving else IDLE


# Field -> key (the field name unless listed here).  name, message and level are the
# DiagnosticStatus's own fields, not key/values.
_KEYS = {'n_intervals': 'N'}
_OWN = ('name', 'message', 'level')
_INT = ('iteration', 'n_intervals', 'data_revision')
_FLOAT = ('t_f', 'cost', 'best_feasible_t_f', 'max_control_excess', 'terminal_error',
          'min_clearance', 'margin', 'elapsed_s', 'latency_s', 'deviation', 'plan_stamp',
          'state_stamp', 'published_stamp')
# Clock times: every digit (9 would lose the fraction).
_EXACT = ('plan_stamp', 'state_stamp', 'published_stamp')
# Tuples of names or entries (no commas in them): written joined by ', '; () is not written.
_NAMES = ('arm_joints', 'arm_locked', 'arm_joint_limits')
KEYS = tuple(_KEYS.get(f.name, f.name) for f in fields(ProgressReport) if f.name not in _OWN)


def _text(value, digits=9):
    if isinstance(value, Status):
        return value.value
    if isinstance(value, str):
        return value
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, int):
        return str(value)
    if isinstance(value, (tuple, list)):
        return '[' + ', '.join(_text(float(v)) for v in value) + ']'
    return f'{float(value):.{digits}g}'


def progress_msg(name, report):
    """Build the DiagnosticStatus of a report (name: the node's fully qualified name)."""
    level = report.level
    if level is None:
        level = DiagnosticStatus.OK if report.status is None else LEVELS[report.status]
    values = [KeyValue(key='status', value=report.status_name)]
    for f in fields(ProgressReport):
        if f.name in _OWN or f.name == 'status':
            continue
        value = getattr(report, f.name)
        if value is None or value == '' or (f.name in _NAMES and not value):
            continue
        text = (', '.join(str(v) for v in value) if f.name in _NAMES
                else _text(value, 17 if f.name in _EXACT else 9))
        values.append(KeyValue(key=_KEYS.get(f.name, f.name), value=text))
    return DiagnosticStatus(level=level, name=name, message=report.message, values=values)


def _number(text, kind):
    try:
        return kind(float(text)) if kind is int else float(text)
    except (TypeError, ValueError, OverflowError):
        return math.nan if kind is float else None


def _vector(text):
    try:
        values = tuple(float(v) for v in str(text).strip('[]() ').split(','))
    except ValueError:
        return None
    return values


def progress_from_msg(msg):
    """
    Read a ~/progress message into a ProgressReport (unknown keys ignored, bad numbers nan).

    An unknown status text (another version of the node) reads as a failure to report it:
    status INVALID_INPUT with the text in the message.
    """
    raw = {kv.key: kv.value for kv in msg.values}
    level = msg.level     # bytes in rclpy, an int in messages decoded from a recording
    level = level if isinstance(level, bytes) else bytes([int(level)])
    kwargs = {'name': msg.name, 'message': msg.message, 'level': level}
    text = raw.get('status', SOLVING)
    if text == IDLE:
        kwargs['event'] = EVENT_IDLE     # replaced by the event key when there is one
    elif text != SOLVING:
        try:
            kwargs['status'] = Status(text)
        except ValueError:
            kwargs['status'] = Status.INVALID_INPUT
            kwargs['message'] = f'{msg.message} (unknown status {text!r})'
    for f in fields(ProgressReport):
        key = _KEYS.get(f.name, f.name)
        if f.name in _OWN or f.name == 'status' or key not in raw:
            continue
        value = raw[key]
        if f.name in _INT:
            kwargs[f.name] = _number(value, int)
        elif f.name in _FLOAT:
            kwargs[f.name] = _number(value, float)
        elif f.name == 'goal':
            kwargs[f.name] = _vector(value)
        elif f.name in _NAMES:
            kwargs[f.name] = tuple(v.strip() for v in str(value).split(',') if v.strip())
        else:
            kwargs[f.name] = value
    return ProgressReport(**kwargs)


def obstacles_hash(rows, margin):
    """
    Short hash of an obstacle set (rows x, y, radius R'; arms: x, y, z, r) and its margin.

    As ~/progress has it.  Values are rounded to 1e-9 m first, so that a client computes the
    same hash from the numbers it sent.
    """
    text = ';'.join(','.join(f'{float(v) + 0.0:.9f}' for v in row) for row in rows)
    text += f'|{float(margin):.9f}'
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def running_report(progress, **values):
    """Report of a running solve from a core Progress (violations unset until measured)."""
    v = progress.violations
    extra = {} if v is None else {'max_control_excess': v.max_control_excess,
                                  'terminal_error': v.terminal_error,
                                  'min_clearance': v.min_clearance}
    return ProgressReport(
        message='solving', iteration=int(progress.iteration), t_f=progress.t_f,
        cost=progress.cost, best_feasible_t_f=progress.best_feasible_t_f,
        elapsed_s=progress.elapsed_s, phase=progress.phase, **extra, **values)


def result_report(result, message=None, **values):
    """Build the final report of a core SolveResult: status, numbers, the solve's settings."""
    v = result.violations
    return ProgressReport(
        status=result.status, message=result.message if message is None else message,
        iteration=int(result.iterations), t_f=result.final_time,
        best_feasible_t_f=result.final_time if result.success else math.nan,
        max_control_excess=v.max_control_excess, terminal_error=v.terminal_error,
        min_clearance=v.min_clearance, elapsed_s=result.wall_time_s, phase='done',
        mode=result.mode, integrator=result.integrator, n_intervals=int(result.n_intervals),
        **values)


def refusal_report(reason, status=Status.INVALID_INPUT, **values):
    """Level-ERROR report of a refused input."""
    return ProgressReport(status=status, message=reason, level=DiagnosticStatus.ERROR,
                          event=values.pop('event', EVENT_REFUSED), **values)
