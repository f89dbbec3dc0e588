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
toc-analyze for URDF arms: the executed motion against the joint limits and the obstacle spheres.

A recording of solver_node with robot.model panda, ur5 or urdf names its model on ~/progress
(robot_model and the arm_* fields); recorded_arm rebuilds it.  The obstacles in force at each
joint_states sample are the latest `obstacles` rows (x, y, z, r) or `obstacle_markers` set
recorded before it (a run without either has no clearance to report).  Clearance is the core's
sphere clearance (toc_ros.core.arms) of the arm's collision spheres to the true obstacle
spheres (no margin).
"""

import math

import numpy as np

from toc_ros import arm_config
from toc_ros.arm_inputs import sphere_rows
from toc_ros.conversions import ConversionError
from toc_ros.marker_obstacles import MarkerObstacles
from toc_ros.progress import EVENT_REPLANNED, progress_from_msg

from .recorded_run import json_number


def is_arm_run(run):
    """Tell whether a RecordedRun's model is a URDF arm (an ArmPlanModel)."""
    return getattr(run.model, 'arm', None) is not None


def obstacle_schedule(run, base_frame, warn=None):
    """Return [(time [s], rows (O, 4))] of the obstacle sets sent, in time order."""
    markers = MarkerObstacles(base_frame)
    events = [(t, 'obstacles', m) for t, m in run.messages.get('obstacles', ())]
    events += [(t, 'obstacle_markers', m) for t, m in run.messages.get('obstacle_markers', ())]
    schedule = []
    for t, kind, msg in sorted(events, key=lambda e: e[0]):
        try:
            if kind == 'obstacles':
                rows = sphere_rows(msg)
                markers.clear()
            else:
                rows = markers.apply(msg, 10 ** 6)
        except ConversionError as error:
            if warn is not None:
                warn(f'{kind} message at {t:.3f} s not used (as solver_node refuses it): {error}')
            continue
        schedule.append((t, np.asarray(rows, dtype=float).reshape(-1, 4)))
    return schedule


def joint_samples(run, names):
    """Return (times, q, dq, effort) of joint_states in the arm's joint order (nan: missing)."""
    times, rows = [], []
    for t, msg in run.messages.get('joint_states', ()):
        index = {n: k for k, n in enumerate(msg.name)}
        if not all(n in index for n in names):
            continue
        row = []
        for field in (msg.position, msg.velocity, msg.effort):
            row.append([field[index[n]] if index[n] < len(field) else math.nan for n in names])
        times.append(run.sample_time(t, msg))
        rows.append(row)
    if not rows:
        empty = np.empty((0, len(names)))
        return np.empty(0), empty, empty, empty
    values = np.asarray(rows, dtype=float)
    return np.asarray(times), values[:, 0], values[:, 1], values[:, 2]


def sample_clearance(robot, q, times, schedule):
    """Return (clearance (M,) [m], obstacle index (M,)) to the set in force at each sample."""
    from toc_ros.core.arms import obstacle_clearance, sphere_kinematics_batch
    clearance = np.full(len(times), math.inf)
    nearest = np.full(len(times), -1)
    if robot.spheres is None or not len(times):
        return clearance, nearest
    centres, _ = sphere_kinematics_batch(robot.spheres, q)
    for k, t in enumerate(times):
        in_force = [rows for s, rows in schedule if s <= t]
        if not in_force or not len(in_force[-1]):
            continue
        gaps = obstacle_clearance(centres[k], robot.spheres.radii, in_force[-1])
        clearance[k] = float(np.min(gaps))
        nearest[k] = int(np.unravel_index(np.argmin(gaps), gaps.shape)[1])
    return clearance, nearest


def _excess(values, low, high):
    """Per joint max of values beyond [low, high] (0 inside; nan where nothing is known)."""
    finite = np.isfinite(values)
    over = np.where(finite, np.maximum(values - high, low - values), -math.inf)
    worst = np.max(over, axis=0, initial=-math.inf) if len(values) \
        else np.full(low.shape, -math.inf)
    return [json_number(max(w, 0.0)) if math.isfinite(w) else None for w in worst]


def analyse_arm(run, info, warn=None):
    """Return (summary dict, series for the plots) of an arm run."""
    model = run.model
    arm = model.arm
    names = list(arm.joint_names)
    times, q, dq, effort = joint_samples(run, names)
    # The URDF's root link (REP-103 base), unless --params are this arm's own.
    base = arm.model.frames[1].name
    if arm_config.is_arm(run.params) and run.params.get('base_frame'):
        base = str(run.params['base_frame'])
    schedule = obstacle_schedule(run, base, warn)
    clearance, nearest = sample_clearance(model.robot, q, times, schedule)
    # The tip link planned with (the recording's, else --params' or the model's default).
    tip, _ = model.tip_frame(str(run.model_params.get('robot.tip_link', '')))
    tips = np.array([p.translation for p in model.tip_poses(q, tip)]) if len(q) \
        else np.empty((0, 3))
    worst = int(np.argmin(clearance)) if len(clearance) else None
    plans = run.messages.get('trajectory', ())
    reports = [progress_from_msg(m) for _, m in run.messages.get('progress', ())]
    latencies = np.array([r.latency_s for r in reports if r.event == EVENT_REPLANNED
                          and r.latency_s is not None])
    statuses = {}
    for r in reports:
        if r.status is not None:
            statuses[r.status.value] = statuses.get(r.status.value, 0) + 1
    final = None
    if plans and len(q):
        goal = np.array(plans[-1][1].points[-1].positions, dtype=float) \
            if plans[-1][1].points else None
        if goal is not None and goal.shape == q[-1].shape:
            final = json_number(float(np.max(np.abs(q[-1] - goal))))
    lower = np.where(arm.continuous, -math.inf, arm.lower)
    upper = np.where(arm.continuous, math.inf, arm.upper)
    has_clearance = worst is not None and math.isfinite(clearance[worst])
    summary = {
        'recording': info, 'robot': 'arm',
        'model': {'name': model.name, 'joints': names, 'source': run.model_source,
                  'spheres': 0 if model.robot.spheres is None else len(model.robot.spheres),
                  'tip_link': tip},
        'samples': int(len(times)),
        'duration_s': json_number(times[-1] - times[0]) if len(times) else None,
        'obstacle_sets': [{'time_s': json_number(t), 'rows': rows.tolist()}
                          for t, rows in schedule],
        'min_clearance': {
            'value': json_number(clearance[worst]) if has_clearance else None,
            'time_s': json_number(times[worst]) if has_clearance else None,
            'obstacle': int(nearest[worst]) if has_clearance else None,
            'samples_inside': int(np.sum(clearance < 0.0))},
        'limit_excess': {
            'position': _excess(q, lower, upper),
            'velocity': _excess(dq, -arm.velocity, arm.velocity),
            'effort': _excess(effort, -arm.effort, arm.effort)},
        'plans': len(plans), 'final_statuses': statuses,
        'final_error': final,
        'replan_latency': {
            'count': int(latencies.size),
            'median_s': json_number(np.median(latencies)) if latencies.size else None,
            'p99_s': json_number(np.percentile(latencies, 99)) if latencies.size else None},
    }
    series = {'times': times, 'q': q, 'dq': dq, 'effort': effort, 'clearance': clearance,
              'tips': tips, 'schedule': schedule, 'lower': lower, 'upper': upper,
              'velocity': arm.velocity, 'effort_limit': arm.effort, 'names': names}
    return summary, series


def markdown(summary):
    """Summary of an arm run as Markdown."""
    m, c, e = summary['model'], summary['min_clearance'], summary['limit_excess']

    def fmt(values):
        return ', '.join('-' if v is None else f'{v:.3g}' for v in values)

    lines = [f"# toc-analyze: {m['name']} arm ({len(m['joints'])} joints)", '',
             f"- recording: {summary['recording']['recording']}",
             f"- joint_states samples: {summary['samples']}",
             f"- plans (trajectory messages): {summary['plans']}; final statuses "
             f"{summary['final_statuses'] or 'none'}",
             '- min clearance of the collision spheres to the obstacle spheres: '
             + ('no obstacles sent' if c['value'] is None else
                f"{c['value']:.4g} m at {c['time_s']:.3f} s (obstacle {c['obstacle']}), "
                f"{c['samples_inside']} samples inside"),
             f"- beyond the position limits [rad or m]: {fmt(e['position'])}",
             f"- beyond the velocity limits: {fmt(e['velocity'])}",
             f"- beyond the effort limits: {fmt(e['effort'])}"]
    if summary['final_error'] is not None:
        lines.append(f"- final error to the last plan's end: {summary['final_error']:.3g}")
    lat = summary['replan_latency']
    if lat['count']:
        lines.append(f"- replan latency: median {1e3 * lat['median_s']:.1f} ms, p99 "
                     f"{1e3 * lat['p99_s']:.1f} ms over {lat['count']} cycles")
    return '\n'.join(lines) + '\n'
