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
Fast mode against the IPOPT reference on random start/goal/obstacle scenarios.

python benchmarks/random_scenarios.py [--seed S] [--count K] [--N N] [--moving P]
                                      [--max-obstacles M]

Each scenario: a start angle anywhere, a goal 0.5-2.5 rad away in either direction, extensions in
[0.2, 1.4] m, 0..max-obstacles circles (radius 0.08-0.3 m, 0.8-2.2 m from the base, between the
start and goal bearings), and with probability --moving non-zero start velocities and a non-zero
goal rotation rate.  Scenarios the core refuses (start/goal inside an obstacle) are redrawn.
Prints fast mode's status and t_f, IPOPT's t_f on the same discretisation, and the gap.  Needs
casadi (extra 'bench').
"""

import argparse
import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from reference_ipopt import solve_reference  # noqa: E402
from toc_ros.core import Problem, ProblemError, solve, SolverOptions, warm_up  # noqa: E402


def draw(rng, n, moving, max_obstacles):
    """Draw one valid scenario."""
    while True:
        q1 = rng.uniform(-math.pi, math.pi)
        turn = rng.choice([-1.0, 1.0]) * rng.uniform(0.5, 2.5)
        x0 = [q1, 0.0, rng.uniform(0.2, 1.4), 0.0]
        goal = [q1 + turn, 0.0, rng.uniform(0.2, 1.4), 0.0]
        if rng.random() < moving:
            x0[1], x0[3], goal[1] = (rng.uniform(-0.5, 0.5), rng.uniform(-0.3, 0.3),
                                     rng.uniform(-0.3, 0.3))
        circles = []
        for _ in range(rng.integers(0, max_obstacles + 1)):
            bearing = q1 + turn * rng.uniform(0.2, 0.8)
            distance = rng.uniform(0.8, 2.2)
            circles.append((distance * math.cos(bearing), distance * math.sin(bearing),
                            rng.uniform(0.08, 0.3)))
        problem = Problem(x0=tuple(x0), x_goal=tuple(goal), obstacles=tuple(circles),
                          n_intervals=n)
        try:
            problem.validate()
        except ProblemError:
            continue
        return problem


def main(argv=None):
    """Run the comparison; exit code 1 if any scenario is not SOLVED within 0.1 %."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seed', type=int, default=1)
    parser.add_argument('--count', type=int, default=10)
    parser.add_argument('--N', type=int, default=300)
    parser.add_argument('--moving', type=float, default=0.3)
    parser.add_argument('--max-obstacles', type=int, default=2)
    args = parser.parse_args(argv)
    warm_up()
    rng = np.random.default_rng(args.seed)
    worst = 0.0
    failures = 0
    for k in range(args.count):
        problem = draw(rng, args.N, args.moving, args.max_obstacles)
        start = time.perf_counter()
        result = solve(problem, SolverOptions(timeout=120.0))
        wall = time.perf_counter() - start
        ref = solve_reference(list(problem.x0), list(problem.x_goal), list(problem.obstacles),
                              problem.margin, N=args.N)
        gap = 100.0 * (result.final_time / ref['t_f'] - 1.0)
        ok = result.success and gap < 0.1
        failures += not ok
        worst = max(worst, gap)
        print(f'{k:3d} {result.status.value:17s} fast {result.final_time:.5f} s ({wall:.1f} s)  '
              f'ipopt {ref["t_f"]:.5f} s  gap {gap:+.4f} %  circles {len(problem.obstacles)}'
              f'{"" if ok else "  <-- " + result.message}', flush=True)
    print(f'{args.count - failures}/{args.count} SOLVED within 0.1 %, largest gap {worst:+.4f} %')
    return 1 if failures else 0


if __name__ == '__main__':
    sys.exit(main())
