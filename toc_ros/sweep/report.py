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
Summary of a sweep (OUT/summary.json, OUT/summary.md) and its t_min heat map (OUT/heatmap.png).

The heat map is drawn over the spec's two plot axes; the other varied names make one panel per
combination (up to MAX_PANELS), else each cell shows the worst (largest) t_min over them.
Goal axes (goal.x/goal.y, goal.q1/goal.q2) are drawn in the hand's x-y plane with the
obstacles.  Arm sweeps (arm=True) over the tip target (goal_pose.x/goal_pose.y) are drawn in the
base frame's x-y plane with the obstacle spheres seen from above; their joint axes stay joint
axes.  Failures are marked: x = the solver did not succeed, dot = invalid problem (e.g. goal
inside an obstacle; for arms also a tip target IK cannot reach).
"""

import json
import math
import os
import re
import shlex

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Circle
import numpy as np

MAX_PANELS = 6
WORST = 10
GRID_MAX_VALUES = 400
SOLVED = ('SOLVED', 'SOLVED_INACCURATE')
INVALID = 'INVALID_INPUT'
TITLE_WIDTH = 60
_OBSTACLE_FIELD = re.compile(r'^(obstacles|spheres)\.(\d+)\.(\w+)$')


def _percentiles(values):
    if not len(values):
        return {}
    q = np.percentile(values, [0, 5, 25, 50, 75, 95, 100])
    return {'min': q[0], 'p5': q[1], 'p25': q[2], 'median': q[3], 'p75': q[4], 'p95': q[5],
            'max': q[6], 'mean': float(np.mean(values))}


def _clean(value):
    if isinstance(value, (float, np.floating)):
        value = float(value)
        return value if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    return value


def summarize(table, sweep, stats=None, n_cases=None):
    """Summary dict of the rows (a pyarrow Table) of a sweep."""
    cols = table.to_pydict()
    n = table.num_rows
    status = cols['status']
    t = np.array(cols['final_time'], dtype=float)
    by_status = {}
    for s in status:
        by_status[s] = by_status.get(s, 0) + 1
    solved = np.array([s == 'SOLVED' for s in status], dtype=bool)
    names = list(sweep.names)

    def case(i, *extra):
        item = {'case_id': cols['case_id'][i]}
        item.update({name: cols[name][i] for name in names})
        item.update({k: cols[k][i] for k in extra})
        return item

    order = [i for i in np.argsort(-np.where(solved, t, -np.inf), kind='stable') if solved[i]]
    failures = [i for i in range(n) if status[i] != 'SOLVED']
    failures.sort(key=lambda i: (status[i] == INVALID, cols['case_id'][i]))
    return _clean({
        'spec': sweep.path,
        'cases': n if n_cases is None else n_cases, 'rows': n,
        'missing': (n_cases - n) if n_cases is not None else 0,
        'varied': names,
        'by_status': dict(sorted(by_status.items())),
        't_min_solved': dict(count=int(solved.sum()), **_percentiles(t[solved])),
        'longest': [case(i, 'final_time', 'args') for i in order[:WORST]],
        'failures': [case(i, 'status', 'message', 'args') for i in failures[:WORST]],
        'run': stats.as_dict() if stats is not None else None,
    })


def _fmt(value):
    if value is None:
        return '—'
    if isinstance(value, float):
        return f'{value:.6g}'
    return str(value)


def markdown(summary, plots=()):
    """Render the summary as Markdown."""
    names = summary['varied']
    lines = [f'# Sweep summary: {os.path.basename(summary["spec"])}', '',
             f'{summary["rows"]} of {summary["cases"]} cases in the dataset'
             + (f' ({summary["missing"]} missing)' if summary['missing'] else '') + '; varied: '
             + (', '.join(f'`{n}`' for n in names) or 'nothing') + '.', '',
             '| status | cases |', '|---|---|']
    lines += [f'| {k} | {v} |' for k, v in summary['by_status'].items()]
    dist = summary['t_min_solved']
    lines += ['', f't_min of the {dist["count"]} SOLVED cases [s]:', '']
    if dist['count']:
        keys = ('min', 'p5', 'p25', 'median', 'p75', 'p95', 'max', 'mean')
        lines += ['| ' + ' | '.join(keys) + ' |', '|' + '---|' * len(keys),
                  '| ' + ' | '.join(f'{dist[k]:.4f}' for k in keys) + ' |']
    if summary['longest']:
        lines += ['', f'Longest t_min (worst {len(summary["longest"])} solved cases):', '',
                  '| ' + ' | '.join(names + ['t_min [s]', 'case_id']) + ' |',
                  '|' + '---|' * (len(names) + 2)]
        lines += ['| ' + ' | '.join([_fmt(c[n]) for n in names]
                                    + [f'{c["final_time"]:.4f}', f'`{c["case_id"]}`']) + ' |'
                  for c in summary['longest']]
    if summary['failures']:
        lines += ['', f'Not SOLVED (first {len(summary["failures"])}):', '',
                  '| ' + ' | '.join(names + ['status', 'message']) + ' |',
                  '|' + '---|' * (len(names) + 2)]
        lines += ['| ' + ' | '.join([_fmt(c[n]) for n in names]
                                    + [c['status'], (c['message'] or '')[:120].replace(
                                        '|', '/').replace('\n', ' ')]) + ' |'
                  for c in summary['failures']]
    run = summary.get('run')
    if run:
        lines += ['', f'This run: {run["done"]} cases in {run["wall_s"]:.1f} s on '
                  f'{run["worker_threads"]} worker thread(s) ({run["cases_per_s"] or 0:.1f} '
                  f'cases/s, {run["tasks"]} tasks), solver time {run["solve_s"]:.1f} s, '
                  f'scheduling + serialisation + idle {_share(run["overhead_share"])} of it; '
                  f'cluster start and warm-up {run["startup_s"]:.1f} s'
                  + (f'; {run["lost"]} case(s) lost' if run['lost'] else '') + '.']
    for plot in plots:
        lines += ['', f'![t_min heat map]({plot})']
    return '\n'.join(lines) + '\n'


def _share(value):
    return '—' if value is None else f'{100 * value:.1f} %'


def _obstacles(args, option='--obstacle', width=3):
    """Obstacle rows (--obstacle X Y R, or for arms --sphere X Y Z R) of a command line."""
    words = shlex.split(args)
    return [tuple(float(w) for w in words[k + 1:k + 1 + width])
            for k, w in enumerate(words) if w == option]


def _edges(centers):
    c = np.asarray(centers, dtype=float)
    if len(c) == 1:
        return np.array([c[0] - 0.5, c[0] + 0.5])
    mid = 0.5 * (c[1:] + c[:-1])
    return np.concatenate([[2 * c[0] - mid[0]], mid, [2 * c[-1] - mid[-1]]])


def heatmap(table, sweep, path, a=1.1, arm=False):
    """
    Draw t_min over the plot axes; return path, or None when fewer than 2 numeric axes.

    a: the planar robot's arm offset (goal.q1/q2 axes drawn as hand positions); arm: a URDF
    arm's sweep (no hand plane; tip-target axes drawn with the obstacle spheres).
    """
    axes = sweep.plot_axes()
    if not axes or table.num_rows == 0:
        return None
    xname, yname = axes
    cols = table.to_pydict()
    x = np.array(cols[xname], dtype=float)
    y = np.array(cols[yname], dtype=float)
    t = np.array(cols['final_time'], dtype=float)
    status = np.array(cols['status'])
    ok = np.isin(status, SOLVED) & np.isfinite(t)
    invalid = status == INVALID
    failed = ~ok & ~invalid
    others = [n for n in sweep.names if n not in axes]
    keys = [tuple(cols[n][i] for n in others) for i in range(len(x))]
    groups = sorted(set(keys), key=lambda k: [str(v) for v in k])
    if len(groups) > MAX_PANELS:
        panels = [('worst case over ' + ', '.join(others), np.ones(len(x), bool))]
    else:
        panels = [(_panel_title(others, g), np.array([k == g for k in keys])) for g in groups]
    hand = not arm and {xname, yname} in ({'goal.x', 'goal.y'}, {'goal.q1', 'goal.q2'})
    tip = arm and (xname, yname) == ('goal_pose.x', 'goal_pose.y')
    if arm:
        a = None        # joint axes of an arm are not the planar robot's hand plane
    ncol = min(3, len(panels))
    nrow = math.ceil(len(panels) / ncol)
    fig = Figure(figsize=(4.6 * ncol + 0.8, 4.2 * nrow), dpi=110, layout='constrained')
    FigureCanvasAgg(fig)
    grid = fig.subplots(nrow, ncol, squeeze=False)
    vmin, vmax = (np.min(t[ok]), np.max(t[ok])) if ok.any() else (0.0, 1.0)
    mesh = None
    for k, (title, mask) in enumerate(panels):
        ax = grid[k // ncol][k % ncol]
        xs, ys = np.unique(x[mask]), np.unique(y[mask])
        cells = len(set(zip(x[mask].tolist(), y[mask].tolist())))
        if (len(xs) <= GRID_MAX_VALUES and len(ys) <= GRID_MAX_VALUES
                and cells >= 0.5 * len(xs) * len(ys)):      # a grid: cells, else points
            value = np.full((len(ys), len(xs)), np.nan)
            ix, iy = np.searchsorted(xs, x), np.searchsorted(ys, y)
            for i in np.flatnonzero(mask & ok):
                cur = value[iy[i], ix[i]]
                value[iy[i], ix[i]] = t[i] if np.isnan(cur) else max(cur, t[i])
            ex, ey = _plane(*np.meshgrid(_edges(xs), _edges(ys)), xname, yname, a)
            mesh = ax.pcolormesh(ex, ey, np.ma.masked_invalid(value), vmin=vmin, vmax=vmax,
                                 cmap='viridis', shading='flat')
        else:
            mesh = ax.scatter(*_plane(x[mask & ok], y[mask & ok], xname, yname, a), c=t[mask & ok],
                              s=8, vmin=vmin, vmax=vmax, cmap='viridis')
        for sel, marker, color, label in ((failed, 'x', 'red', 'not solved'),
                                          (invalid, '.', '0.4', 'unreachable or invalid'
                                           if arm else 'invalid problem')):
            sel = sel & mask
            if sel.any():
                ax.scatter(*_plane(x[sel], y[sel], xname, yname, a), marker=marker, c=color,
                           s=18, linewidths=1.0, label=label)
        if hand:
            first = np.flatnonzero(mask)[0]
            for cx, cy, r in _obstacles(cols['args'][first]):
                ax.add_patch(Circle((cx, cy), r, fill=False, color='k', linewidth=1.2))
            ax.plot([0], [0], 'k+', markersize=8)
            ax.set_aspect('equal')
            ax.set_xlabel('hand x [m]')
            ax.set_ylabel('hand y [m]')
        elif tip:
            first = np.flatnonzero(mask)[0]
            for cx, cy, _, r in _obstacles(cols['args'][first], '--sphere', 4):
                ax.add_patch(Circle((cx, cy), r, fill=False, color='k', linewidth=1.2,
                                    linestyle='--'))
            ax.set_aspect('equal')
            ax.set_xlabel('tip target x [m] (base frame)')
            ax.set_ylabel('tip target y [m]')
        else:
            ax.set_xlabel(xname)
            ax.set_ylabel(yname)
        ax.set_title(title, fontsize=9)
        if (failed | invalid)[mask].any() and tip:       # below: the targets fill the axes
            ax.legend(fontsize=7, loc='upper center', bbox_to_anchor=(0.5, -0.13), ncol=2)
        elif (failed | invalid)[mask].any():
            ax.legend(fontsize=7, loc='upper right')
    for k in range(len(panels), nrow * ncol):
        grid[k // ncol][k % ncol].set_visible(False)
    if mesh is not None:
        fig.colorbar(mesh, ax=grid.ravel().tolist(), label='t_min [s]')
    fig.suptitle(f'{os.path.basename(sweep.path)}: t_min over {xname}, {yname}', fontsize=10)
    fig.savefig(path)
    return path


def _panel_title(names, values):
    """Return a panel's title: name = value, the fields of one obstacle or sphere as one."""
    parts, groups = [], {}
    for name, value in zip(names, values):
        match = _OBSTACLE_FIELD.match(name)
        if not match:
            parts.append(f'{name} = {_fmt(value)}')
            continue
        key = (match.group(1), match.group(2))
        if key not in groups:
            groups[key] = ([], [])
            parts.append(key)
        groups[key][0].append(match.group(3))
        groups[key][1].append(_fmt(value))
    lines = ['']
    for part in parts:
        if not isinstance(part, str):
            fields, values = groups[part]
            part = (f'{part[0][:-1]} {part[1]} ({", ".join(fields)}) = '
                    f'({", ".join(values)})')
        if lines[-1] and len(lines[-1]) + len(part) + 2 > TITLE_WIDTH:
            lines[-1] += ','
            lines.append('')
        lines[-1] += (', ' if lines[-1] else '') + part
    return '\n'.join(lines) if parts else 'all cases'


def _plane(x, y, xname, yname, a):
    """Drawing coordinates: the hand's x-y for goal.q1/goal.q2 axes, else the axis values."""
    if a is None or {xname, yname} != {'goal.q1', 'goal.q2'}:
        return x, y
    q1, q2 = (x, y) if xname == 'goal.q1' else (y, x)
    return (a + q2) * np.cos(q1), (a + q2) * np.sin(q1)


def write_report(table, sweep, out_dir, stats=None, n_cases=None, a=1.1, arm=False):
    """Write summary.json, summary.md and heatmap.png into out_dir; return the summary."""
    plot = heatmap(table, sweep, os.path.join(out_dir, 'heatmap.png'), a=a, arm=arm)
    summary = summarize(table, sweep, stats, n_cases)
    summary['plots'] = ['heatmap.png'] if plot else []
    with open(os.path.join(out_dir, 'summary.json'), 'w') as stream:
        json.dump(summary, stream, indent=1, allow_nan=False)
        stream.write('\n')
    with open(os.path.join(out_dir, 'summary.md'), 'w') as stream:
        stream.write(markdown(summary, summary['plots']))
    return summary
