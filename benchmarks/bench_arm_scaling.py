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
How the arm solver's time grows with N: fast mode only, the scenarios of bench_arm_fast.py.

For each arm and obstacle set and N in --N (default 50 100 200 400): one warm-up solve, then
--repeats cold solves; the median wall time, the iterations, the time per iteration and its
split (Pinocchio / Riccati / rest), per degree of freedom.  The log-log slopes of the median
time and of the time per iteration against N are least-squares fits over the N given.
With obstacles from N = 200 on (coarse_grid.py) the iterations are the coarse search's on N / 4
plus the refinement's on N, and the time per iteration is their mean.

With --random K: instead, K random motions per arm and obstacle set, drawn as
bench_arm_suite.py draws them (--seed; 'free' or '1 sphere' on the way), each solved at every
N (the best of --repeats cold solves after a warm-up), and the median and range of their
per-motion slopes: the benchmark's two motions are two points of that spread.  Each row also
counts the bound arcs of the solution at every N (bound_arcs: how much switching structure the
grid resolves) and the returned run's iterations per barrier parameter (barrier_phases: where
on the barrier path the iterations go), and with --ipopt the iterations of IPOPT
(toc_ros/bench/arm_reference.py, the same discretisation from fast mode's cold start point)
and their slope.

    python benchmarks/bench_arm_scaling.py [--arms panda ur5] [--obstacles free '1 sphere']
                                           [--random 10 --seed 21 [--ipopt]]
"""

import argparse
from collections import Counter
import os
import statistics
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from benchmarks.bench_arm_fast import MARGIN, SCENARIOS  # noqa: E402, I100
from benchmarks.bench_arm_suite import draw_cases, fast_start, reference_spec  # noqa: E402
from toc_ros.core import Problem, solve  # noqa: E402
from toc_ros.core.arms import load_arm, load_spheres  # noqa: E402
from toc_ros.core.arms.arm_solve import ArmRobot  # noqa: E402
from toc_ros.core.arms.coarse_grid import COARSE_FACTOR, COARSE_FROM  # noqa: E402

# An entry counts as at its bound within this fraction of the bound (the solver stops with
# barrier slacks of order 1e-9 relative; a loose test would count nearly active entries).
AT_BOUND = 1e-3


def measure(name, obstacle_set, n_int, repeats):
    """One row: status, t_f, iterations, median/min/max time, per-iteration split."""
    start, goal, sets = SCENARIOS[name]
    arm = load_arm(name)
    robot = ArmRobot(arm, load_spheres(os.path.join(HERE, 'data', f'arm_spheres_{name}.yaml'),
                                       arm))
    problem = Problem(x0=start, x_goal=goal, model=robot, obstacles=sets[obstacle_set],
                      margin=MARGIN, n_intervals=n_int)
    solve(problem)
    times, result = [], None
    for _ in range(repeats):
        started = time.perf_counter()
        result = solve(problem)
        times.append(time.perf_counter() - started)
    state = result.solver_state or {}
    it = max(result.iterations, 1)
    median = statistics.median(times)
    return {'arm': name, 'dof': arm.n, 'obstacles': obstacle_set, 'N': n_int,
            'status': result.status.value, 't_f': result.final_time, 'it': result.iterations,
            'median_s': median, 'min_s': min(times), 'max_s': max(times),
            'per_it_s': median / it, 'pin_s': state.get('pin_time_s', np.nan) / it,
            'riccati_s': state.get('linalg_time_s', np.nan) / it}


def bound_arcs(values, bound):
    """
    Count the arcs at a bound, summed over the columns (values (rows, n), bound (n,)).

    An arc is a maximal run of consecutive rows where a column is at +bound, or at -bound
    (within AT_BOUND).
    """
    scaled = np.asarray(values) / np.asarray(bound)
    side = np.where(scaled >= 1.0 - AT_BOUND, 1, np.where(scaled <= AT_BOUND - 1.0, -1, 0))
    starts = (side[1:] != side[:-1]) & (side[1:] != 0)
    return int(np.count_nonzero(starts) + np.count_nonzero(side[0]))


def barrier_phases(result):
    """
    Return a Counter {barrier parameter: iterations} of the result's returned run (arm_solve).

    Keys are the parameters rounded to one digit ('1e-06'), in the order the run met them; the
    counts add up to result.iterations when the solve made one run (a free motion).
    """
    return Counter(f'{mu:.0e}'
                   for mu in (result.solver_state or {}).get('barrier_parameters', ()))


def ipopt_iterations(name, robot, start, goal, obstacles, n_int):
    """Return IPOPT's (iterations, t_f, success) on the same grid from fast mode's start."""
    from toc_ros.bench.arm_problem import ArmProblem
    from toc_ros.bench.arm_reference import ArmTranscription
    spec = reference_spec(name, robot.arm, start, goal, obstacles)
    out = ArmTranscription(ArmProblem(spec), n_int, 'euler', 'ipopt').solve(
        fast_start(robot, start, goal, obstacles, n_int))
    return out['iterations'], out['t_f'], bool(out['success'])


def random_slopes(name, obstacle_set, count, seed, n_grid, repeats, ipopt=False):
    """Print one line per random motion (iterations, times, slopes, arcs); return the slopes."""
    arm = load_arm(name)
    robot = ArmRobot(arm, load_spheres(os.path.join(HERE, 'data', f'arm_spheres_{name}.yaml'),
                                       arm))
    cases = draw_cases(name, count, 1.2, obstacle_set != 'free', np.random.default_rng(seed))
    found = {'time': [], 'it': [], 'ipopt': [], 'phases': {n_int: Counter() for n_int in n_grid}}
    for index, (start, goal, obstacles) in enumerate(cases):
        rows = []
        for n_int in n_grid:
            problem = Problem(x0=start, x_goal=goal, model=robot, obstacles=obstacles,
                              margin=MARGIN, n_intervals=n_int)
            result = solve(problem)
            best = None
            for _ in range(repeats):
                started = time.perf_counter()
                result = solve(problem)
                elapsed = time.perf_counter() - started
                best = elapsed if best is None else min(best, elapsed)
            arcs = (bound_arcs(result.controls, arm.effort)
                    + bound_arcs(result.states[:, arm.n:], arm.velocity))
            row = {'N': n_int, 'time': best, 'it': max(result.iterations, 1),
                   'status': result.status.value, 'arcs': arcs,
                   'phases': barrier_phases(result)}
            found['phases'][n_int].update(row['phases'])
            if ipopt:
                row['ipopt'], t_f, success = ipopt_iterations(name, robot, start, goal,
                                                              obstacles, n_int)
                row['ipopt_note'] = '' if success else ' (failed)'
                if success and t_f > result.final_time * (1 + 1e-6):
                    row['ipopt_note'] = f' (t_f +{100 * (t_f / result.final_time - 1):.3f} %)'
            rows.append(row)
        for key in ('time', 'it', 'ipopt'):
            if key in rows[0]:
                found[key].append(slope(rows, key))
        unsolved = [r['status'] for r in rows if r['status'] != 'SOLVED']
        iterations = ' / '.join(str(r['it']) for r in rows)
        times = ' / '.join(f"{1e3 * r['time']:.0f}" for r in rows)
        arcs = ' / '.join(str(r['arcs']) for r in rows)
        phases = ' / '.join(' '.join(f'{key}:{count}' for key, count in r['phases'].items())
                            for r in rows)
        line = (f"| {name} | {obstacle_set} | {index} | {' / '.join(unsolved) or 'SOLVED'} | "
                f"{iterations} | {times} | {found['time'][-1]:.2f} | {found['it'][-1]:+.2f} | "
                f'{arcs} | {phases} |')
        if ipopt:
            line += (' ' + ' / '.join(f"{r['ipopt']}{r['ipopt_note']}" for r in rows)
                     + f" | {found['ipopt'][-1]:+.2f} |")
        print(line, flush=True)
    return found


def slope(rows, key):
    """Least-squares slope of log(row[key]) against log(N)."""
    x = np.log([r['N'] for r in rows])
    y = np.log([r[key] for r in rows])
    return float(np.polyfit(x, y, 1)[0])


def main(argv=None):
    """Print the table and the slopes."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--arms', nargs='+', default=['panda', 'ur5'])
    parser.add_argument('--obstacles', nargs='+', default=['free', '1 sphere'])
    parser.add_argument('--N', type=int, nargs='+', default=[50, 100, 200, 400])
    parser.add_argument('--repeats', type=int, default=3)
    parser.add_argument('--random', type=int, default=0, metavar='K',
                        help='K random motions per arm and obstacle set (docstring)')
    parser.add_argument('--seed', type=int, default=21)
    parser.add_argument('--ipopt', action='store_true',
                        help='with --random: also IPOPT on each motion and N (slow at N = 400)')
    args = parser.parse_args(argv)
    if args.ipopt and not args.random:
        parser.error('--ipopt goes with --random')
    if args.random:
        if not set(args.obstacles) <= {'free', '1 sphere'}:
            parser.error("--random draws 'free' motions or motions past '1 sphere'")
        header = ('| arm | obstacles | motion | status | iterations at N = '
                  f"{' / '.join(map(str, args.N))} | best time [ms] | slope of time | "
                  'slope of iterations | bound arcs | iterations per barrier parameter |')
        if args.ipopt:
            header += ' IPOPT iterations | IPOPT slope of iterations |'
        print(header)
        print('|---' * (header.count('|') - 1) + '|')
        summary = []
        for name in args.arms:
            for obstacle_set in args.obstacles:
                found = random_slopes(name, obstacle_set, args.random, args.seed, args.N,
                                      args.repeats, args.ipopt)
                times = np.array(found['time'])
                line = (f'* {name}, {obstacle_set}: slope of time median '
                        f'{np.median(times):.2f} ({times.min():.2f}-{times.max():.2f}), '
                        f'{np.count_nonzero(times <= 1.1)} of {times.size} <= 1.1; '
                        f"slope of iterations median {np.median(found['it']):+.2f}")
                if args.ipopt:
                    line += f"; IPOPT's median {np.median(found['ipopt']):+.2f}"
                line += '; iterations per barrier parameter, summed: ' + '; '.join(
                    f'N = {n_int}: ' + ', '.join(f'{key} {count}' for key, count in
                                                 sorted(found['phases'][n_int].items(),
                                                        key=lambda item: -float(item[0])))
                    for n_int in args.N)
                summary.append(line)
        print()
        print('\n'.join(summary))
        return
    print('| arm | obstacles | N | status | t_f [s] | it | median [ms] | min-max [ms] | '
          'per it [ms] | per it and DOF [ms] | per it: pin / Riccati / rest [ms] |')
    print('|---|---|---|---|---|---|---|---|---|---|---|')
    slopes = []
    for name in args.arms:
        for obstacle_set in args.obstacles:
            rows = []
            for n_int in args.N:
                r = measure(name, obstacle_set, n_int, args.repeats)
                rows.append(r)
                rest = r['per_it_s'] - r['pin_s'] - r['riccati_s']
                print(f"| {name} | {obstacle_set} | {n_int} | {r['status']} | {r['t_f']:.6f} | "
                      f"{r['it']} | {1e3 * r['median_s']:.1f} | {1e3 * r['min_s']:.1f}-"
                      f"{1e3 * r['max_s']:.1f} | {1e3 * r['per_it_s']:.2f} | "
                      f"{1e3 * r['per_it_s'] / r['dof']:.3f} | {1e3 * r['pin_s']:.2f} / "
                      f"{1e3 * r['riccati_s']:.2f} / {1e3 * rest:.2f} |", flush=True)
            slopes.append(f'* {name}, {obstacle_set}: log-log slope over N = '
                          f'{", ".join(map(str, args.N))}: time {slope(rows, "median_s"):.2f}, '
                          f'time per iteration {slope(rows, "per_it_s"):.2f}')
    print()
    print('\n'.join(slopes))
    print(f'* with obstacles from N = {COARSE_FROM} on: the search on N / {COARSE_FACTOR} '
          'intervals, then one run on N (the iterations add up: "per it" is their mean)')


if __name__ == '__main__':
    main()
