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
why it cannot (the data it needs is not in the recording).
"""

import os

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Circle
import numpy as np


from .report import hand_xy, run_model, tracking_errors

DPI = 110
# Arm drawn at this many instants of each plan (the paper's Fig. 7).
ARM_INSTANTS = 7
PLANNED = {'linewidth': 1.6, 'alpha': 0.9}
MEASURED = {'linewidth': 1.0, 'linestyle': '--', 'color': 'k', 'alpha': 0.8}


def _figure(rows, height=2.4, width=8.0):
    """Make a figure of stacked axes sharing the x axis."""
    fig = Figure(figsize=(width, height * rows), dpi=DPI, layout='constrained')
    FigureCanvasAgg(fig)
    return fig, fig.subplots(rows, 1, sharex=True, squeeze=False)[:, 0]


def _mark_plans(ax, report):
    for plan in report.plans:
        ax.axvline(plan.time, color='0.6', linewidth=0.8, linestyle=':')


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
                ax.step(plan.time + plan.times, plan.efforts[:, j], where='post',
                        label=f'planned {plan.index}', **PLANNED)
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
            ax.plot(plan.time + plan.times, plan.states[:, j], label=f'planned {plan.index}',
                    **PLANNED)
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
    for plan in report.plans:
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
        ax.plot(hx, hy, color=colour, label=f'plan {plan.index} hand path', **PLANNED)
        for i in np.linspace(0, len(plan.times) - 1, ARM_INSTANTS).round().astype(int):
            for ax_, ay, bx, by in model.link_segments(plan.states[i, 0::2]):
                ax.plot([ax_, bx], [ay, by], color=colour, linewidth=2.2, alpha=0.35)
            ax.plot(hx[i], hy[i], 'o', color=colour, markersize=4)
    for execution in report.executions:
        mx, my = hand_xy(model, execution.states)
        ax.plot(mx, my, label='measured' if execution.plan == 0 else None, **MEASURED)
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
        for ax, key in zip(axes, ('q1', 'q2', 'hand')):
            ax.plot(execution.times, errors[key], linewidth=1.0,
                    label=f'plan {execution.plan}')
    for ax, label in zip(axes, ('q1 error [rad]', 'q2 error [m]', 'hand error [m]')):
        _mark_plans(ax, report)
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc='upper right', fontsize='small')
    axes[0].set_title('Tracking error (measured - planned)')
    axes[-1].set_xlabel('time [s]')
    return _save(fig, path)


PLOTS = {
    'controls': controls,
    'states': states,
    'path': path,
    'convergence': convergence,
    'tracking_error': tracking_error,
}


def draw_all(report, out_dir):
    """Draw every plot into out_dir; {name: {'file': name.png or None, 'reason': ...}}."""
    results = {}
    for name, draw in PLOTS.items():
        file_name = f'{name}.png'
        reason = draw(report, os.path.join(out_dir, file_name))
        results[name] = {'file': None, 'reason': reason} if reason else {'file': file_name}
    return results
