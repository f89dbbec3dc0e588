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

"""benchmarks/bench_arm_scaling.py --random: its rows are the solves of the motions it draws."""

import itertools
import os
import sys

import numpy as np
import pytest

pytest.importorskip('pinocchio')

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from benchmarks import bench_arm_scaling  # noqa: E402, I100
from benchmarks.bench_arm_suite import draw_cases, MARGIN  # noqa: E402
from toc_ros.core import Problem, solve  # noqa: E402
from toc_ros.core.arms import load_arm, load_spheres  # noqa: E402
from toc_ros.core.arms.arm_ipm import MU_INIT  # noqa: E402
from toc_ros.core.arms.arm_solve import ArmRobot  # noqa: E402


def test_random_rows_report_each_drawn_motion_and_its_slope(capsys):
    grid = (20, 40)
    bench_arm_scaling.main(['--random', '2', '--arms', 'ur5', '--obstacles', 'free',
                            '--N', *map(str, grid), '--repeats', '1', '--seed', '5'])
    out = capsys.readouterr().out
    rows = [line.split('|')[1:-1] for line in out.splitlines()
            if line.startswith('| ur5 | free |')]
    assert len(rows) == 2
    cases = draw_cases('ur5', 2, 1.2, False, np.random.default_rng(5))
    arm = load_arm('ur5')
    robot = ArmRobot(arm, load_spheres(os.path.join(bench_arm_scaling.HERE, 'data',
                                                    'arm_spheres_ur5.yaml'), arm))
    slopes = []
    totals = {n: {} for n in grid}
    for row, (start, goal, obstacles) in zip(rows, cases):
        assert row[3].strip() == 'SOLVED'
        # The iterations printed are those of solving the drawn motion itself.
        expected = [solve(Problem(x0=start, x_goal=goal, model=robot, obstacles=obstacles,
                                  margin=MARGIN, n_intervals=n)).iterations for n in grid]
        assert [int(k) for k in row[4].split('/')] == expected
        times = [float(t) for t in row[5].split('/')]
        assert all(t >= 0.0 for t in times)
        slopes.append(float(row[6]))
        # The bound arcs, counted again here: runs of entries at +bound or at -bound.
        arcs = []
        for n in grid:
            result = solve(Problem(x0=start, x_goal=goal, model=robot, obstacles=obstacles,
                                   margin=MARGIN, n_intervals=n))
            count = 0
            for values, bound in ((result.controls, arm.effort),
                                  (result.states[:, arm.n:], arm.velocity)):
                for column, limit in zip(np.transpose(values), bound):
                    sides = [1 if x >= (1 - 1e-3) * limit else -1 if x <= -(1 - 1e-3) * limit
                             else 0 for x in column]
                    count += sum(1 for side, _ in itertools.groupby(sides) if side)
            arcs.append(count)
        assert [int(k) for k in row[8].split('/')] == arcs
        # A free motion is one run: its iterations per barrier parameter add up to the
        # solve's, the parameter falling from the first one (arm_ipm.MU_INIT) on.
        for cell, n, n_iterations in zip(row[9].split('/'), grid, expected):
            pairs = [item.split(':') for item in cell.split()]
            assert sum(int(count) for _, count in pairs) == n_iterations
            levels = [float(key) for key, _ in pairs]
            assert levels[0] == pytest.approx(MU_INIT) and levels == sorted(levels)[::-1]
            for key, count in pairs:
                totals[n][float(key)] = totals[n].get(float(key), 0) + int(count)
    summary = [line for line in out.splitlines() if line.startswith('* ur5, free:')]
    assert len(summary) == 1
    median = float(summary[0].split('median ')[1].split()[0])
    assert abs(median - np.median(slopes)) <= 0.006        # (the rows' slopes are rounded)
    assert f'{sum(s <= 1.1 for s in slopes)} of 2 <= 1.1' in summary[0]
    # ... and the iterations per barrier parameter summed over both motions, per N.
    summed = summary[0].split('summed: ')[1].split('; ')
    for part, n in zip(summed, grid):
        head, cells = part.split(': ')
        assert head == f'N = {n}'
        assert {float(c.split()[0]): int(c.split()[1]) for c in cells.split(', ')} == totals[n]


def test_bound_arcs_counts_runs_at_either_bound():
    bound = np.array([1.0, 2.0])
    values = np.array([[1.0, 0.0], [1.0, 2.0], [0.2, 2.0], [-1.0, -2.0], [1.0, 1.999]])
    # column 0: +, +, 0, -, + -> 3 arcs; column 1: 0, +, +, -, + (1.999 within 1e-3) -> 3
    assert bench_arm_scaling.bound_arcs(values, bound) == 6
    assert bench_arm_scaling.bound_arcs(np.zeros((4, 2)), bound) == 0


def test_random_with_ipopt_reports_its_iterations_and_their_slope(capsys):
    pytest.importorskip('casadi')
    grid = (20, 40)
    bench_arm_scaling.main(['--random', '1', '--arms', 'ur5', '--obstacles', 'free',
                            '--N', *map(str, grid), '--repeats', '1', '--seed', '5',
                            '--ipopt'])
    out = capsys.readouterr().out
    row = [line.split('|')[1:-1] for line in out.splitlines()
           if line.startswith('| ur5 | free |')][0]
    assert len(row) == 12
    ipopt = [int(cell.split()[0]) for cell in row[10].split('/')]
    assert all(k > 0 for k in ipopt)
    expected = np.polyfit(np.log(grid), np.log(ipopt), 1)[0]
    assert abs(float(row[11]) - expected) <= 0.006
    summary = [line for line in out.splitlines() if line.startswith('* ur5, free:')][0]
    assert f"IPOPT's median {expected:+.2f}" in summary


def test_ipopt_needs_random():
    with pytest.raises(SystemExit):
        bench_arm_scaling.main(['--ipopt'])
