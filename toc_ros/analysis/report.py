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
The report of a recorded run: its numbers (summary, JSON-ready) and their Markdown text.

analyse() builds a Report from a loaded run (recorded_run.py): the plans and their executions
(recorded_plans.py), the closed-loop executions (recorded_loops.py) and their summary entries
(report_numbers.py); markdown() renders the summary.  The names of those modules are importable
from here as well.
"""

from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np

from toc_ros.conversions import ConversionError, joint_state_to_state
from toc_ros.core import Status

from .closed_loop import ARRIVAL_TOL
from .recorded_loops import build_closed_loops, ClosedLoop, EVENTS, group_plans, \
    obstacle_clearance, obstacle_schedule
from .recorded_plans import build_executions, build_plans, Execution, mark_executed, \
    measured_series, obstacles_from_markers, Plan, reference_at
from .recorded_run import as_float, clock_offset, find_topics, hand_xy, json_number, \
    latest_before, load_run, NEEDED_FOR, recorded_model, RecordedRun, ROLES, run_model, \
    Solve, solves_from_progress
from .report_numbers import closed_loop_numbers, execution_numbers, plan_numbers, \
    tracking_errors

__all__ = [
    'analyse', 'build_closed_loops', 'build_executions', 'build_plans', 'clock_offset',
    'closed_loop_numbers', 'ClosedLoop', 'execution_numbers', 'Execution', 'find_topics',
    'group_plans', 'hand_xy', 'load_run', 'mark_executed', 'markdown', 'measured_series',
    'missing_roles', 'NEEDED_FOR', 'obstacle_clearance', 'obstacle_schedule',
    'obstacles_from_markers', 'Plan', 'plan_numbers', 'recorded_model', 'RecordedRun',
    'reference_at', 'Report', 'ROLES', 'run_model', 'Solve', 'solves_from_progress',
    'tracking_errors',
]


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
        before = latest_before(run.messages['joint_states'], plan.time)
        start = None
        if before is not None:
            try:
                start = joint_state_to_state(before[1], plan.joint_names)
            except ConversionError:
                pass            # not a state of the plan's joints: its numbers without a start
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
                    'time_s': json_number(s.final_time), 'progress_messages': len(s.points),
                    'iterations': json_number(as_float(s.report.iteration)),
                    'elapsed_s': json_number(as_float(s.report.elapsed_s))} for s in solves],
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
             f'the start of the first plan; arrival: every joint within {ARRIVAL_TOL:g} of the '
             'goal from then on; final error: max joint error 0.2 s after the end of the last '
             'plan; min clearance: every link to the true (uninflated) obstacles in force, every '
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
