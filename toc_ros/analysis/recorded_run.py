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
A recorded run, decoded: its messages by role, its time base, its robot model and its solves.

Time base: seconds from the first message read, on the recorder's log (receive) time axis.
Header stamps (node clock: joint_states, trajectories, the stamps in ~/progress) are mapped
onto it by the clock offset: the median of log time - header.stamp over the joint_states
with a stamp (0 when none has one: the node clock is taken to be the recorder's).
"""

from dataclasses import dataclass, field
import math
from typing import Dict, List, Optional

import numpy as np

from toc_ros import arm_config
from toc_ros.config import model_from_parameters
from toc_ros.conversions import as_model, nanoseconds
from toc_ros.core import ProblemError
from toc_ros.progress import progress_from_msg, ProgressReport

from .recorded_arm import recorded_arm


# Role -> (last name token, type). Names are matched below any namespace.
ROLES = {
    'trajectory': ('trajectory', 'trajectory_msgs/msg/JointTrajectory'),
    'joint_states': ('joint_states', 'sensor_msgs/msg/JointState'),
    'progress': ('progress', 'diagnostic_msgs/msg/DiagnosticStatus'),
    'goal_pose': ('goal_pose', 'geometry_msgs/msg/PoseStamped'),
    'goal_joints': ('goal_joints', 'sensor_msgs/msg/JointState'),
    'obstacles': ('obstacles', 'std_msgs/msg/Float64MultiArray'),
    'markers': ('markers', 'visualization_msgs/msg/MarkerArray'),
    # URDF arms: the obstacle spheres as markers, and the URDF of robot.model urdf.
    'obstacle_markers': ('obstacle_markers', 'visualization_msgs/msg/MarkerArray'),
    'robot_description': ('robot_description', 'std_msgs/msg/String'),
}
# Names a role's topic has when no topic has its own: panda.launch.py execute:=action remaps
# solver_node's trajectory to planned_trajectory (the plant hears the plans as action goals).
FALLBACK_TOKENS = {'trajectory': ('planned_trajectory',)}
# What is lost without a role (for the 'missing' list).
NEEDED_FOR = {
    'trajectory': 'plans, planned curves, violations',
    'joint_states': 'executions: measured states, applied effort, tracking error',
    'progress': 'solver status, iterations, solve time, convergence plot',
    'obstacles': 'obstacles sent at run time (else markers or the parameter file are used)',
    'goal_pose': 'the goal of a plan the solver did not report (its terminal error)',
}


def as_float(value) -> float:
    """Return value as a float, nan when it is not a number."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def json_number(value):
    """JSON number or None for nan/inf/missing."""
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def find_topics(topics: Dict[str, object], warn=None) -> Dict[str, Optional[str]]:
    """Topic of each role: last name token and type match; the shortest name wins."""
    found = {}
    for role, (token, type_name) in ROLES.items():
        for name in (token,) + FALLBACK_TOKENS.get(role, ()):
            names = sorted((n for n, info in topics.items()
                            if n.rstrip('/').split('/')[-1] == name
                            and info.type_name == type_name), key=lambda n: (n.count('/'), n))
            if names:
                break
        found[role] = names[0] if names else None
        if len(names) > 1 and warn is not None:
            warn(f'several {name} topics ({", ".join(names)}); analysing {names[0]}')
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
class RecordedRun:
    """Everything read from a recording, decoded, by role."""

    topics: Dict[str, Optional[str]]
    messages: Dict[str, list]           # role -> [(time [s], message)]
    start_ns: int
    params: dict
    model: object = None                # the RobotModel (recorded_model), set by load_run
    model_source: str = 'parameters'
    # The flat parameters the model was built from (arms: their settings, e.g. robot.tip_link,
    # as recorded, else as --params give them).
    model_params: dict = field(default_factory=dict)
    clock_offset_ns: int = 0            # log time - header.stamp (see the module docstring)
    clock_source: str = 'none'

    def stamp_time(self, stamp) -> Optional[float]:
        """Return a builtin_interfaces/Time on the time base [s] (None for a zero stamp)."""
        ns = nanoseconds(stamp)
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
    run.model, run.model_source, run.model_params = rebuild_model(run, warn)
    run.clock_offset_ns, run.clock_source = clock_offset(raw['joint_states'], warn)
    return run


def clock_offset(joint_states, warn=None):
    """
    Return (offset [ns], source): the median of log time - header.stamp of joint_states.

    joint_states: [(log time [ns], message)]. Without stamped joint_states the offset is 0
    (the node clock is taken to be the recorder's log clock).
    """
    gaps = np.array([t - nanoseconds(m.header.stamp) for t, m in joint_states
                     if nanoseconds(m.header.stamp) > 0], dtype=float)
    if not gaps.size:
        return 0, 'none (no stamped joint_states): node clock = log clock'
    offset = int(round(float(np.median(gaps))))
    spread = float(np.percentile(gaps, 95) - np.percentile(gaps, 5)) * 1e-9
    if spread > 0.5 and warn is not None:
        warn(f'the joint_states stamps and log times drift apart by {spread:.3g} s (5-95 %): '
             'times mapped from header stamps are uncertain by that much')
    return offset, f'median log time - header.stamp of {gaps.size} joint_states'


def recorded_model(run, warn=None):
    """Return (RobotModel, source) of a run (see rebuild_model)."""
    return rebuild_model(run, warn)[:2]


def rebuild_model(run, warn=None):
    """
    Return (RobotModel, source, the flat parameters it was built from) of a run.

    The robot_model / model_parameters that solver_node wrote on ~/progress (ready and result
    reports; URDF arms: with what rebuilds them, see recorded_arm), else the parameters
    (--params).  A URDF arm that cannot be rebuilt is a ProblemError with the reason (no
    planar stand-in could analyse its joints).
    """
    reports = [progress_from_msg(msg) for _, msg in run.messages.get('progress', ())]
    for report in reports:
        if not report.robot_model:
            continue
        if arm_config.is_arm({'robot.model': report.robot_model}):
            model, params = recorded_arm(run, report.robot_model, [
                r for r in reports if r.robot_model == report.robot_model], warn)
            return model, 'solver progress', params
        params = dict(run.params)
        params['robot.model'] = report.robot_model
        params['robot.model_parameters'] = [
            p.strip() for p in report.model_parameters.split(',') if p.strip()]
        try:
            return model_from_parameters(params), 'solver progress', params
        except ProblemError as error:
            if warn is not None:
                warn(f'the recorded robot model {report.robot_model!r} cannot be built here '
                     f'({error}); using the parameters')
            break
    if arm_config.is_arm(run.params):
        model, params = recorded_arm(run, run.params['robot.model'], [], warn)
        return model, 'parameters', params
    try:
        return model_from_parameters(run.params), 'parameters', run.params
    except ProblemError as error:
        if warn is not None:
            warn(f'robot model of the parameters: {error}; using the cylindrical robot')
        return as_model(1.1), 'default', run.params


def run_model(run_or_a):
    """Return the RobotModel of a RecordedRun, or as_model of a model / hand offset."""
    if isinstance(run_or_a, RecordedRun):
        return run_or_a.model if run_or_a.model is not None else recorded_model(run_or_a)[0]
    return as_model(run_or_a)


def hand_xy(model, states):
    """Return the hand positions (x, y) [m] of 2-joint states (M, 4) of the model."""
    hand = model.hand_position(np.asarray(states, dtype=float)[..., 0::2])
    return hand[..., 0], hand[..., 1]


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
                'time': time, 'iteration': as_float(report.iteration), 't_f': as_float(report.t_f),
                'cost': as_float(report.cost), 'elapsed_s': as_float(report.elapsed_s)})
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


def finite_vector(values, size=4):
    """Array of size finite numbers from a sequence (None when it is not one)."""
    if values is None:
        return None
    values = np.asarray(values, dtype=float)
    return values if values.shape == (size,) and np.all(np.isfinite(values)) else None


def latest_before(items, before, after=-math.inf):
    """Latest (time, message) with after < time <= before, or None."""
    chosen = None
    for time, msg in items:
        if time > before:
            break
        if time > after:
            chosen = (time, msg)
    return chosen
