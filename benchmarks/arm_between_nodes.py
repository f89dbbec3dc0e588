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
How close arm plans come to their obstacle spheres between the nodes the solver constrains.

    python benchmarks/arm_between_nodes.py [--count 10] [--N 30 60 100] [--seed 41]

Fast mode constrains each sphere's clearance (margin included) at the nodes k = 0..N.  What a
controller executes is the motion the plan stands for (core/plan_reference.py): the published
points q_k + h dq_k / 2 and, between them, the velocity going linearly from dq_k to dq_k+1.
For the benchmark motion past one sphere and --count random motions past a sphere per arm
(bench_arm_suite.py's draw), solved cold at each N, the smallest clearance [mm] over every
sphere and obstacle: at the nodes, at the published points, at --samples points inside every
segment of that motion, and on the straight chords between the solver's nodes.  Negative:
that far inside the margin (the margin is MARGIN = 20 mm here).
"""

import argparse
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

from bench_arm_fast import SCENARIOS  # noqa: E402, I100
from bench_arm_suite import draw_cases, MARGIN  # noqa: E402
from toc_ros.core import Problem, solve, Status  # noqa: E402
from toc_ros.core.arms import load_arm, load_spheres  # noqa: E402
from toc_ros.core.arms.arm_solve import ArmRobot  # noqa: E402
from toc_ros.core.arms.clearances import obstacle_clearance, sphere_kinematics_batch  # noqa: E402
from toc_ros.core.plan_reference import hermite, reference_positions  # noqa: E402


def min_clearance(robot, obstacles, margin, configurations):
    """Smallest sphere-obstacle clearance [m] over configurations (K, n)."""
    centres, _ = sphere_kinematics_batch(robot.spheres, configurations)
    count = centres.shape[0]
    radii = np.tile(robot.spheres.radii, count)
    return float(np.min(obstacle_clearance(centres.reshape(-1, 3), radii, obstacles, margin)))


def clearances(robot, result, obstacles, margin, samples):
    """(nodes, published points, between them, node chords) clearances [m] of a solved plan."""
    n = robot.arm.n
    q, dq = result.states[:, :n], result.states[:, n:]
    times = result.time_grid
    points = reference_positions(q, dq, times, 'euler')
    fractions = np.arange(1, samples + 1) / (samples + 1)
    # The published motion over a segment: a controller's cubic through the points with the
    # nodes' velocities (plan_reference.hermite), every segment at once.
    t0, t1 = times[:-1, None], times[1:, None]
    between = [hermite(t0, t1, points[:-1], dq[:-1], points[1:], dq[1:], t0 + s * (t1 - t0))[0]
               for s in fractions]
    chords = [q[:-1] + (q[1:] - q[:-1]) * s for s in fractions]
    return (min_clearance(robot, obstacles, margin, q),
            min_clearance(robot, obstacles, margin, points),
            min(min_clearance(robot, obstacles, margin, c) for c in between),
            min(min_clearance(robot, obstacles, margin, c) for c in chords))


def main(argv=None):
    """Print one row per solved plan and the worst and median of each column."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--count', type=int, default=10)
    parser.add_argument('--N', type=int, nargs='+', default=[30, 60, 100])
    parser.add_argument('--seed', type=int, default=41)
    parser.add_argument('--samples', type=int, default=7)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    print('| arm | case | N | h [ms] | t_f [s] | nodes [mm] | published points [mm] | between '
          'them [mm] | node chords [mm] |')
    print('|' + '---|' * 9)
    rows = {}
    for name in ('panda', 'ur5'):
        arm = load_arm(name)
        robot = ArmRobot(arm, load_spheres(os.path.join(HERE, 'data', f'arm_spheres_{name}.yaml'),
                                           arm))
        start, goal, sets = SCENARIOS[name]
        cases = [(start, goal, sets['1 sphere'])] + draw_cases(name, args.count, 1.2, True, rng)
        for index, (start, goal, obstacles) in enumerate(cases):
            obstacles = np.asarray(obstacles, dtype=float).reshape(-1, 4)
            for n_int in args.N:
                result = solve(Problem(x0=tuple(start), x_goal=tuple(goal), model=robot,
                                       obstacles=obstacles, margin=MARGIN, n_intervals=n_int))
                if result.status is not Status.SOLVED:
                    print(f'| {name} | {index} | {n_int} | {result.status.value} |')
                    continue
                values = clearances(robot, result, obstacles, MARGIN, args.samples)
                rows.setdefault(n_int, []).append(values)
                h = result.final_time / n_int
                print(f'| {name} | {"bench" if index == 0 else index} | {n_int} | {1e3 * h:.1f} | '
                      f'{result.final_time:.4f} | '
                      + ' | '.join(f'{1e3 * v:+.2f}' for v in values) + ' |', flush=True)
    print()
    print('| N | plans | worst: nodes / points / between / chords [mm] | median [mm] |')
    print('|---|---|---|---|')
    for n_int, values in sorted(rows.items()):
        values = 1e3 * np.array(values)
        worst = ' / '.join(f'{v:+.2f}' for v in values.min(axis=0))
        median = ' / '.join(f'{v:+.2f}' for v in np.median(values, axis=0))
        print(f'| {n_int} | {len(values)} | {worst} | {median} |')
    return 0


if __name__ == '__main__':
    sys.exit(main())
