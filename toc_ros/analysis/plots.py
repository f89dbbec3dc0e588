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
The plots of a run report (PNG, matplotlib's Agg canvas: no display, no pyplot state).

Each function draws one figure from a report.Report and returns None, or returns the reason
why it cannot (the data it needs is not in the recording). Times are the report's time base
(log times from the first message, header stamps mapped onto it); plans are drawn from their
start (header.stamp). With many plans (replanning) the per-plan plots label and mark one plan
per closed-loop execution and draw the others faintly; the closed-loop plots (replanned
paths, clearance, arrival, replan latency) show each execution as a whole.
"""

import math
import os

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Circle
import numpy as np


from .recorded_run import hand_xy, run_model
from .report_numbers import tracking_errors

DPI = 110
# Arm drawn at this many instants of each plan (the paper's Fig. 7).
ARM_INSTANTS = 7
PLANNED = {'linewidth': 1.6, 'alpha': 0.9}
MEASURED = {'linewidth': 1.0, 'linestyle': '--', 'color': 'k', 'alpha': 0.8}
# With more plans than this the per-plan plots label one plan per closed-loop execution.
MANY_PLANS = 6
FAINT = {'linewidth': 0.7, 'alpha': 0.3}
EXECUTED = {'linewidth': 2.2, 'color': 'k', 'alpha': 0.9}
# Obstacle positions drawn per closed-loop execution: first, last and a few between.
OBSTACLE_SNAPSHOTS = 5
COLOURS = ['C0', 'C1', 'C2', 'C3', 'C4', 'C5', 'C6', 'C7', 'C8', 'C9']


def _figure(rows, height=2.4, width=8.0):
    """Make a figure of stacked axes sharing the x axis."""
    fig = Figure(figsize=(width, height * rows), dpi=DPI, layout='constrained')
    FigureCanvasAgg(fig)
    return fig, fig.subplots(rows, 1, sharex=True, squeeze=False)[:, 0]


def _many(report):
    return len(report.plans) > MANY_PLANS


def _plan_style(report, plan):
    """Return (label, style) of a plan's line: one labelled line per execution when many."""
    if not _many(report):
        return f'planned {plan.index}', PLANNED
    colour = COLOURS[plan.execution % len(COLOURS)]
    first = report.closed_loops[plan.execution].plans[0] == plan.index \
        if report.closed_loops else plan.index == 0
    label = f'plans of execution {plan.execution}' if first else None
    return label, {**FAINT, 'color': colour}


def _mark_plans(ax, report):
    """Mark each plan's start (when many: each closed-loop execution's start)."""
    starts = ([loop.t0 for loop in report.closed_loops] if _many(report)
              else [plan.start for plan in report.plans])
    for start in starts:
        ax.axvline(start, color='0.6', linewidth=0.8, linestyle=':')


def _save(fig, path):
    fig.savefig(path)
    return None


def controls(report, path):
    """u1, u2 over time: planned (steps), applied (joint_states effort) and the bounds."""
    measured = report.measured
    has_applied = measured is not None and measured[2] is not None
    has_planned = any(p.efforts is not None for p in report.plans)
    if not (has_applied or has_planned):
        return 'no planned controls (trajectory effort) and no applied effort (joint_states)'
    model = run_model(report.run)
    u_max = [float(u) for u in model.u_max]
    units = ['N m' if kind == 'revolute' else 'N' for kind in model.joint_kinds]
    fig, axes = _figure(2)
    for j, (ax, label) in enumerate(zip(axes, (f'u1 [{units[0]}]', f'u2 [{units[1]}]'))):
        for plan in report.plans:
            if plan.efforts is not None:
                label, style = _plan_style(report, plan)
                ax.step(plan.start + plan.times, plan.efforts[:, j], where='post',
                        label=label, **style)
        if has_applied:
            ax.plot(measured[0], measured[2][:, j], label='applied', **MEASURED)
        for bound in (-u_max[j], u_max[j]):
            ax.axhline(bound, color='r', linewidth=0.8, linestyle='-.')
        _mark_plans(ax, report)
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc='upper right', fontsize='small')
    axes[0].set_title(f'Controls with bounds ±{u_max[0]:g} {units[0]}, '
                      f'±{u_max[1]:g} {units[1]} ({model.name})')
    axes[-1].set_xlabel('time [s]')
    return _save(fig, path)


def states(report, path):
    """q1, dq1, q2, dq2 over time: planned and measured."""
    if not report.plans and report.measured is None:
        return 'no trajectory and no joint_states of the configured joints'
    kinds = run_model(report.run).joint_kinds
    units = ['rad' if kind == 'revolute' else 'm' for kind in kinds]
    labels = (f'q1 [{units[0]}]', f'dq1 [{units[0]}/s]', f'q2 [{units[1]}]',
              f'dq2 [{units[1]}/s]')
    fig, axes = _figure(4, height=1.9)
    measured = report.measured
    for j, ax in enumerate(axes):
        for plan in report.plans:
            label, style = _plan_style(report, plan)
            ax.plot(plan.start + plan.times, plan.states[:, j], label=label, **style)
        if measured is not None:
            ax.plot(measured[0], measured[1][:, j], label='measured', **MEASURED)
        _mark_plans(ax, report)
        ax.set_ylabel(labels[j])
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc='upper right', fontsize='small')
    axes[0].set_title('States: planned and measured')
    axes[-1].set_xlabel('time [s]')
    return _save(fig, path)


def path(report, out_path):
    """Hand path in the x-y plane, obstacles (radius and inflated), every link (Fig. 7)."""
    if not report.plans:
        return 'no trajectory: nothing planned to draw'
    model = run_model(report.run)
    fig = Figure(figsize=(7.0, 7.0), dpi=DPI, layout='constrained')
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    colours = ['C0', 'C1', 'C2', 'C3', 'C4', 'C5']
    # Each obstacle in the colour of the plan it belongs to (grey when several plans share it):
    # a later plan's obstacles must not look like collisions of an earlier path.
    owners = {}
    firsts = {loop.plans[0] for loop in report.closed_loops}
    for plan in report.plans:
        if _many(report) and plan.index not in firsts:
            continue       # the closed-loop plots show the obstacles over time
        for x, y, r in plan.obstacles:
            key = (round(x, 6), round(y, 6), round(r, 6), round(plan.margin, 6))
            owners.setdefault(key, []).append(plan.index)
    for (x, y, r, margin), plans in owners.items():
        shade = colours[plans[0] % len(colours)] if len(set(plans)) == 1 else '0.45'
        ax.add_patch(Circle((x, y), r, color=shade, alpha=0.3))
        ax.add_patch(Circle((x, y), r + margin, fill=False, color=shade, linestyle='--',
                            linewidth=0.9))
    for plan in report.plans:
        colour = colours[plan.index % len(colours)]
        hx, hy = hand_xy(model, plan.states)
        if _many(report):
            label, style = _plan_style(report, plan)
            ax.plot(hx, hy, label=label and f'{label} (hand)', **style)
            if plan.index not in firsts:
                continue
            colour = style['color']
        else:
            ax.plot(hx, hy, color=colour, label=f'plan {plan.index} hand path', **PLANNED)
        for i in np.linspace(0, len(plan.times) - 1, ARM_INSTANTS).round().astype(int):
            for ax_, ay, bx, by in model.link_segments(plan.states[i, 0::2]):
                ax.plot([ax_, bx], [ay, by], color=colour, linewidth=2.2, alpha=0.35)
            ax.plot(hx[i], hy[i], 'o', color=colour, markersize=4)
    for k, execution in enumerate(report.executions):
        mx, my = hand_xy(model, execution.states)
        ax.plot(mx, my, label='measured' if k == 0 else None, **MEASURED)
    finish_plane_axes(ax, f'Hand path, every link of {model.name} at equal times; obstacles '
                      'coloured by plan (dashed: inflated)')
    return _save(fig, out_path)


def finish_plane_axes(ax, title, legend_loc='best'):
    """Mark the base and label an x-y plane plot in metres with equal scales."""
    ax.plot(0.0, 0.0, 'ks', markersize=6, label='base')
    ax.set_aspect('equal')
    ax.autoscale_view()
    ax.set_xlabel('x [m]')
    ax.set_ylabel('y [m]')
    ax.grid(True, alpha=0.3)
    ax.legend(loc=legend_loc, fontsize='small')
    ax.set_title(title, fontsize='medium')


def convergence(report, path):
    """t_f and cost against iteration, one line per solve, from the progress messages."""
    solves = [s for s in report.solves if s.points]
    if not solves:
        return 'no progress messages of a running solve (solver_node ~/progress)'
    fig, axes = _figure(2, height=2.6)
    for k, solve in enumerate(solves):
        iteration = np.array([p['iteration'] for p in solve.points])
        for ax, key in zip(axes, ('t_f', 'cost')):
            values = np.array([p[key] for p in solve.points])
            ok = np.isfinite(iteration) & np.isfinite(values)
            if np.any(ok):
                ax.plot(iteration[ok], values[ok], '.-', markersize=3,
                        label=f'solve {k}: {solve.status}')
    axes[0].set_ylabel('t_f [s]')
    axes[1].set_ylabel('cost')
    costs = [p['cost'] for s in solves for p in s.points if np.isfinite(p['cost'])]
    if costs and min(costs) > 0:
        axes[1].set_yscale('log')
    for ax in axes:
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc='upper right', fontsize='small')
    axes[0].set_title('Solver convergence')
    axes[-1].set_xlabel('iteration')
    return _save(fig, path)


def tracking_error(report, path):
    """Measured minus planned q1, q2 and hand position over time."""
    if not report.executions:
        return 'no execution: needs a trajectory and joint_states after it'
    a = run_model(report.run)
    fig, axes = _figure(3, height=2.0)
    for execution in report.executions:
        errors = tracking_errors(execution, a)
        plan = report.plans[execution.plan]
        label, colour = f'plan {execution.plan}', None
        if _many(report):
            colour = COLOURS[plan.execution % len(COLOURS)]
            first = next(e for e in report.executions
                         if report.plans[e.plan].execution == plan.execution)
            label = f'execution {plan.execution}' if first is execution else None
        for ax, key in zip(axes, ('q1', 'q2', 'hand')):
            ax.plot(execution.times, errors[key], linewidth=1.0, label=label, color=colour)
    for ax, label in zip(axes, ('q1 error [rad]', 'q2 error [m]', 'hand error [m]')):
        _mark_plans(ax, report)
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc='upper right', fontsize='small')
    axes[0].set_title('Tracking error (measured - planned)')
    axes[-1].set_xlabel('time [s]')
    return _save(fig, path)


# -- closed-loop executions ------------------------------------------------------------------
def _grid(n, size=5.6):
    """Make a figure of n square axes, two per row."""
    cols = min(n, 2)
    rows = int(math.ceil(n / cols))
    fig = Figure(figsize=(size * cols, size * rows), dpi=DPI, layout='constrained')
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, cols, squeeze=False).ravel()
    for ax in axes[n:]:
        ax.set_visible(False)
    return fig, axes[:n]


def _loop_end(loop):
    """Return the end of what the recording shows of a closed-loop execution [s]."""
    last = float(loop.times[-1]) if loop.times.size else loop.t0
    return min(loop.end, last)


def obstacle_snapshots(loop, count=OBSTACLE_SNAPSHOTS):
    """Return [(time [s], rows)]: the obstacle sets in force, first, last and a few between."""
    end = _loop_end(loop)
    initial = [rows for t, rows in loop.schedule if t <= loop.t0]
    sets = [(loop.t0, initial[-1])] if initial else []
    for t, rows in loop.schedule:
        if loop.t0 < t <= end and not (sets and np.array_equal(sets[-1][1], rows)):
            sets.append((t, rows))
    if len(sets) <= count:
        return sets
    return [sets[i] for i in sorted(set(np.linspace(0, len(sets) - 1, count).round()
                                        .astype(int)))]


def replanned_paths(report, out_path):
    """Per closed-loop execution: every plan's hand path faint, executed links bold, obstacles."""
    loops = [loop for loop in report.closed_loops if loop.times.size]
    if not loops:
        return 'no closed-loop execution: needs a trajectory and joint_states after its start'
    model = run_model(report.run)
    fig, axes = _grid(len(loops))
    for ax, loop in zip(axes, loops):
        snapshots = obstacle_snapshots(loop)
        margin = report.plans[loop.plans[0]].margin
        for k, (t, rows) in enumerate(snapshots):
            shade = 0.15 + 0.35 * (k + 1) / len(snapshots)
            label = f'obstacles at +{t - loop.t0:.2f} s' if k in (0, len(snapshots) - 1) \
                else None
            for j, (x, y, r) in enumerate(rows):
                ax.add_patch(Circle((x, y), r, color='C3', alpha=shade,
                                    label=label if j == 0 else None))
                if k == 0:
                    ax.add_patch(Circle((x, y), r + margin, fill=False, color='C3',
                                        linestyle='--', linewidth=0.8))
        moving = [(t, rows) for t, rows in loop.schedule
                  if loop.t0 <= t <= _loop_end(loop)]
        if len(moving) > 1:      # the obstacle centres' tracks
            width = min(len(rows) for _, rows in moving)
            for j in range(width):
                track = np.array([rows[j, :2] for _, rows in moving])
                if np.ptp(track, axis=0).max() > 0.0:
                    ax.plot(track[:, 0], track[:, 1], color='C3', linewidth=0.8)
        for n, index in enumerate(loop.plans):
            plan = report.plans[index]
            hx, hy = hand_xy(model, plan.states)
            ax.plot(hx, hy, color='C0' if plan.executed else 'C7', linewidth=0.8, alpha=0.4,
                    label='each plan (hand)' if n == 0 else None)
        ends = model.link_segments(loop.positions)[..., 2:4]      # (K, L, 2)
        for link in range(ends.shape[1]):
            last = link == ends.shape[1] - 1
            ax.plot(ends[:, link, 0], ends[:, link, 1],
                    **(EXECUTED if last else {**EXECUTED, 'color': '0.45'}),
                    label='executed hand' if last else f'executed end of link {link + 1}')
        first_arm = model.link_segments(loop.positions[0])
        for ax_, ay, bx, by in first_arm:
            ax.plot([ax_, bx], [ay, by], color='k', linewidth=3.0, alpha=0.25)
        goal = model.link_segments(loop.goal[0::2])[-1, 2:4]
        ax.plot(goal[0], goal[1], 'g*', markersize=12, label='goal')
        m = loop.metrics
        finish_plane_axes(ax, f'Execution {loop.index}: {len(loop.plans)} plan(s), '
                          f'{loop.events["replanned"]} replanned, min clearance '
                          f'{m["min_clearance"]:.3g} m', legend_loc='best')
    return _save(fig, out_path)


def clearance(report, out_path):
    """Draw the executed clearance of every link to each true obstacle over time."""
    loops = [loop for loop in report.closed_loops
             if loop.times.size and loop.clearance.shape[1]]
    if not loops:
        return 'no obstacles or no joint_states during a closed-loop execution'
    fig, axes = _figure(1, height=3.4)
    ax = axes[0]
    labelled = set()
    for loop in loops:
        for j in range(loop.clearance.shape[1]):
            ax.plot(loop.times, loop.clearance[:, j], color=COLOURS[j % len(COLOURS)],
                    linewidth=1.2, label=None if j in labelled else f'obstacle {j}')
            labelled.add(j)
        ax.axvline(loop.t0, color='0.6', linewidth=0.8, linestyle=':')
    ax.axhline(0.0, color='r', linewidth=1.0)
    ax.set_ylabel('clearance [m]')
    ax.set_xlabel('time [s]')
    ax.grid(True, alpha=0.3)
    ax.legend(loc='upper right', fontsize='small')
    worst = min(float(np.nanmin(loop.clearance)) for loop in loops)
    ax.set_title(f'Executed clearance of every link to the true obstacles (min {worst:.3g} m; '
                 'dotted: execution starts)', fontsize='medium')
    return _save(fig, out_path)


def arrival(report, out_path):
    """Draw when each successive plan is to arrive (stamp + duration) and the actual time."""
    loops = report.closed_loops
    if not loops:
        return 'no plan: nothing planned to arrive'
    fig, axes = _figure(1, height=4.0, width=7.0)
    ax = axes[0]
    top = 0.0
    for loop in loops:
        colour = COLOURS[loop.index % len(COLOURS)]
        plans = [report.plans[i] for i in loop.plans]
        received = np.array([p.time - loop.t0 for p in plans])
        planned = np.array([p.start + p.duration - loop.t0 for p in plans])
        m = loop.metrics
        until = max(float(received[-1]), _loop_end(loop) - loop.t0,
                    m['arrival_s'] if math.isfinite(m['arrival_s']) else 0.0)
        ax.step(np.append(received, until), np.append(planned, planned[-1]), where='post',
                color=colour, label=f'execution {loop.index}: planned arrival')
        ax.plot(received, planned, '.', color=colour, markersize=4)
        ax.axhline(m['planned_t_min'], color=colour, linestyle='--', linewidth=0.8)
        if math.isfinite(m['arrival_s']):
            ax.plot(m['arrival_s'], m['arrival_s'], '*', color=colour, markersize=12,
                    label=f'execution {loop.index}: arrived at {m["arrival_s"]:.3f} s '
                          f'(t_min {m["planned_t_min"]:.3f} s)')
        top = max([top, float(np.max(planned)), float(np.max(received))]
                  + ([m['arrival_s']] if math.isfinite(m['arrival_s']) else []))
    ax.plot([0.0, top], [0.0, top], color='0.6', linewidth=0.8, label='now')
    ax.set_xlabel('time since the start of the first plan [s] (each plan at its receipt)')
    ax.set_ylabel('planned arrival [s]')
    ax.grid(True, alpha=0.3)
    ax.legend(loc='lower right', fontsize='small')
    ax.set_title('Arrival: planned (stamp + duration of each plan, dashed: first t_min) and '
                 'actual (star)', fontsize='medium')
    return _save(fig, out_path)


def replan_latency(report, out_path):
    """Replan cycle latencies: node-reported and recomputed from log times, over time."""
    node = [v for loop in report.closed_loops for v in loop.node_latency]
    recorded = [v for loop in report.closed_loops for v in loop.recorded_latency]
    if not node and not recorded:
        return 'no replanned reports on ~/progress (no replan cycle published a plan)'
    fig = Figure(figsize=(8.0, 5.6), dpi=DPI, layout='constrained')
    FigureCanvasAgg(fig)
    over_time, histogram = fig.subplots(2, 1)
    values = []
    for data, style, label in ((node, {'marker': 'o', 'color': 'C0'}, 'node (latency_s)'),
                               (recorded, {'marker': 'x', 'color': 'C1'},
                                'recorded (log times)')):
        if not data:
            continue
        t, v = np.array(data).T
        over_time.plot(t, 1e3 * v, linestyle='none', markersize=4, label=label, **style)
        values.append((1e3 * v, style['color'], label))
    for loop in report.closed_loops:
        over_time.axvline(loop.t0, color='0.6', linewidth=0.8, linestyle=':')
    over_time.set_xlabel('time [s] (trajectory receipt)')
    over_time.set_ylabel('latency [ms]')
    over_time.legend(loc='upper right', fontsize='small')
    over_time.set_title('Replan latency: joint_states -> trajectory', fontsize='medium')
    bins = np.histogram_bin_edges(np.concatenate([v for v, _, _ in values]), bins=30)
    for v, colour, label in values:
        histogram.hist(v, bins=bins, color=colour, alpha=0.5, label=label)
    histogram.set_xlabel('latency [ms]')
    histogram.set_ylabel('cycles')
    for ax in (over_time, histogram):
        ax.grid(True, alpha=0.3)
    return _save(fig, out_path)


PLOTS = {
    'controls': controls,
    'states': states,
    'path': path,
    'convergence': convergence,
    'tracking_error': tracking_error,
    'replanned_paths': replanned_paths,
    'clearance': clearance,
    'arrival': arrival,
    'replan_latency': replan_latency,
}


def draw_all(report, out_dir, plots=None):
    """
    Draw every plot into out_dir; {name: {'file': name.png or None, 'reason': ...}}.

    plots: {name: draw(report, path) -> None or the reason}, default PLOTS.
    """
    results = {}
    for name, draw in (PLOTS if plots is None else plots).items():
        file_name = f'{name}.png'
        reason = draw(report, os.path.join(out_dir, file_name))
        results[name] = {'file': None, 'reason': reason} if reason else {'file': file_name}
    return results
