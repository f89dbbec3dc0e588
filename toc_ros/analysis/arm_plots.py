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

"""The plots of an arm run (arm_run.analyse_arm's series): PNG on matplotlib's Agg canvas."""

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
import numpy as np

from .plots import _figure, DPI, draw_all


def draw_joints(s, path):
    """Draw positions, velocities and efforts of every joint over time, limits dashed."""
    if not len(s['times']):
        return 'no joint_states of the arm'
    fig, axes = _figure(3)
    rows = (('position [rad or m]', s['q'], s['lower'], s['upper']),
            ('velocity [rad/s or m/s]', s['dq'], -s['velocity'], s['velocity']),
            ('effort [N m or N]', s['effort'], -s['effort_limit'], s['effort_limit']))
    for ax, (label, values, low, high) in zip(axes, rows):
        for j, name in enumerate(s['names']):
            colour = f'C{j % 10}'
            ax.plot(s['times'], values[:, j], color=colour, linewidth=1.0, label=name)
            for bound in (low[j], high[j]):
                if np.isfinite(bound):
                    ax.axhline(bound, color=colour, linewidth=0.6, linestyle='--', alpha=0.6)
        ax.set_ylabel(label)
    axes[0].legend(fontsize=7, ncol=4)
    axes[-1].set_xlabel('time [s]')
    fig.savefig(path)
    return None


def draw_clearance(s, path):
    """Draw the clearance of the collision spheres to the obstacles in force over time."""
    finite = np.isfinite(s['clearance'])
    if not np.any(finite):
        return 'no obstacle spheres were sent during the joint_states'
    fig, (ax,) = _figure(1)
    ax.plot(s['times'][finite], s['clearance'][finite], color='k', linewidth=1.0)
    ax.axhline(0.0, color='r', linewidth=0.8)
    ax.set_xlabel('time [s]')
    ax.set_ylabel('min clearance [m]')
    fig.savefig(path)
    return None


def draw_tip_path(s, path):
    """Draw the tip's path in 3D (base frame) among the last obstacle set's spheres."""
    tips = s['tips']
    if not len(tips):
        return 'no joint_states of the arm'
    fig = Figure(figsize=(6.5, 6.0), dpi=DPI, layout='constrained')
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(projection='3d')
    ax.plot(tips[:, 0], tips[:, 1], tips[:, 2], color='k', linewidth=1.2, label='tip')
    ax.scatter(*tips[0], color='g', label='start')
    ax.scatter(*tips[-1], color='b', label='end')
    u, v = np.meshgrid(np.linspace(0.0, 2.0 * np.pi, 24), np.linspace(0.0, np.pi, 12))
    rows = s['schedule'][-1][1] if s['schedule'] else np.empty((0, 4))
    for x, y, z, r in rows:
        ax.plot_surface(x + r * np.cos(u) * np.sin(v), y + r * np.sin(u) * np.sin(v),
                        z + r * np.cos(v), color='r', alpha=0.3, linewidth=0)
    parts = [tips]
    if len(rows):
        parts += [rows[:, :3] - rows[:, 3:4], rows[:, :3] + rows[:, 3:4]]
    points = np.vstack(parts)
    centre = 0.5 * (points.min(0) + points.max(0))
    half = 0.5 * float(np.max(points.max(0) - points.min(0))) + 0.05
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(centre[2] - half, centre[2] + half)
    ax.set_xlabel('x [m]')
    ax.set_ylabel('y [m]')
    ax.set_zlabel('z [m]')
    ax.legend(fontsize=8)
    fig.savefig(path)
    return None


PLOTS = {'joints': draw_joints, 'clearance': draw_clearance, 'tip_path': draw_tip_path}


def draw_arm(series, out_dir):
    """Draw every arm plot into out_dir (as plots.draw_all does a planar run's)."""
    return draw_all(series, out_dir, PLOTS)
