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
Arm solves with Pinocchio's calls looped in C++ (pin_batch.py) against the Python loop.

For the scenarios of bench_arm_fast.py (Panda, UR5; free, 1 and 3 spheres) at --N intervals:
cold Euler solves, warm replans from 30 % of the plan 1e-3 rad off it (bench_arm_warm.py's
row) and, with --rk4 N, cold RK4 solves.  The two loops run alternately in one process,
--repeats times each; the table has each one's median time, the median (range) of the
per-pair time ratios, Pinocchio's share of the Python loop's time, and whether the two gave
the same bits (they must: the same calls, compiled).

    toc-build-native && python benchmarks/bench_arm_pin_batch.py [--N 50 100] [--write]
"""

import argparse
import dataclasses
import os
import statistics
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

from bench_arm_fast import MARGIN, SCENARIOS  # noqa: E402, I100
import results_md  # noqa: E402
from toc_ros.core import Problem, solve, Status  # noqa: E402, I100
from toc_ros.core.arms import load_arm, load_spheres, pin_batch  # noqa: E402
from toc_ros.core.arms.arm_solve import ArmRobot  # noqa: E402

LOOPS = ('C++', 'Python')


def _problem(name, obstacle_set, n_int, integrator='euler'):
    start, goal, sets = SCENARIOS[name]
    arm = load_arm(name)
    robot = ArmRobot(arm, load_spheres(os.path.join(HERE, 'data', f'arm_spheres_{name}.yaml'),
                                       arm, self_collision=False))
    return Problem(x0=start, x_goal=goal, model=robot, obstacles=sets[obstacle_set],
                   margin=MARGIN, n_intervals=n_int, integrator=integrator)


def _replan(problem, drift=1e-3, fraction=0.3):
    """bench_arm_warm.py's replan: (problem from the drifted node, the plan's remainder)."""
    plan = solve(problem)
    rest = plan.remainder(fraction * plan.final_time)
    n = problem.model.arm.n
    x0 = rest.states[0].copy()
    x0[:n] += drift
    x0[n:] *= 1.0 - drift
    return dataclasses.replace(problem, x0=tuple(x0), n_intervals=len(rest.controls)), rest


def _run(loop, call, native_workspace):
    pin_batch.workspace = native_workspace if loop == 'C++' else (lambda model: None)
    started = time.perf_counter()
    result = call()
    return time.perf_counter() - started, result


def run_case(label, call, repeats):
    """Alternate the two loops on call(); return the row."""
    native = pin_batch.workspace
    try:
        for loop in LOOPS:              # warm-up: compiled kernels loaded
            _run(loop, call, native)
        times = {loop: [] for loop in LOOPS}
        results = {}
        for _ in range(repeats):
            for loop in LOOPS:
                elapsed, results[loop] = _run(loop, call, native)
                times[loop].append(elapsed)
    finally:
        pin_batch.workspace = native
    fast, slow = results['C++'], results['Python']
    ratios = [a / b for a, b in zip(times['C++'], times['Python'])]
    state = slow.solver_state or {}
    return {
        'case': label, 'status': fast.status.value, 'iterations': fast.iterations,
        'cpp_ms': 1e3 * statistics.median(times['C++']),
        'python_ms': 1e3 * statistics.median(times['Python']),
        'ratio': statistics.median(ratios), 'ratio_min': min(ratios), 'ratio_max': max(ratios),
        'pin_share': state.get('pin_time_s', float('nan')) / max(slow.wall_time_s, 1e-12),
        'pin_calls': state.get('pin_calls', 0),
        'same_bits': (fast.final_time == slow.final_time and fast.iterations == slow.iterations
                      and np.array_equal(fast.controls, slow.controls)),
        'solved': fast.status is Status.SOLVED,
    }


def table(rows):
    """Markdown table of the rows."""
    lines = ['| case | status | it | C++ loop [ms] | Python loop [ms] | C++ / Python, median '
             '(range) | Pinocchio share of the Python loop | Pinocchio calls | same bits |',
             '|---|---|---|---|---|---|---|---|---|']
    for r in rows:
        lines.append(f"| {r['case']} | {r['status']} | {r['iterations']} | {r['cpp_ms']:.2f} | "
                     f"{r['python_ms']:.2f} | {r['ratio']:.3f} ({r['ratio_min']:.3f}-"
                     f"{r['ratio_max']:.3f}) | {100 * r['pin_share']:.0f} % | {r['pin_calls']} "
                     f"| {'yes' if r['same_bits'] else 'NO'} |")
    return '\n'.join(lines)


def main(argv=None):
    """Run the benchmark and print (and optionally append) the table."""
    p = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    p.add_argument('--repeats', type=int, default=7)
    p.add_argument('--N', type=int, nargs='+', default=[50, 100])
    p.add_argument('--arms', nargs='+', default=['panda', 'ur5'])
    p.add_argument('--rk4', type=int, default=30, help='RK4 rows at this N (0: none)')
    p.add_argument('--write', action='store_true', help='append the table to RESULTS.md')
    args = p.parse_args(argv)
    if pin_batch.library()[0] is None:
        print(f'{pin_batch.status()}: nothing to compare', file=sys.stderr)
        return 1
    cases = []
    for name in args.arms:
        for obstacles in ('free', '1 sphere', '3 spheres'):
            for n_int in args.N:
                problem = _problem(name, obstacles, n_int)
                cases.append((f'{name}, {obstacles}, N = {n_int}, cold',
                              lambda problem=problem: solve(problem)))
        for obstacles in ('free', '1 sphere'):
            replan, rest = _replan(_problem(name, obstacles, 100))
            cases.append((f'{name}, {obstacles}, N = 100, warm replan 1e-3 off',
                          lambda replan=replan, rest=rest: solve(replan, initial_guess=rest)))
        if args.rk4:
            problem = _problem(name, '1 sphere', args.rk4, 'rk4')
            cases.append((f'{name}, 1 sphere, N = {args.rk4}, cold RK4',
                          lambda problem=problem: solve(problem)))
    rows = []
    for label, call in cases:
        rows.append(run_case(label, call, args.repeats))
        print(table(rows[-1:]).splitlines()[-1], flush=True)
    text = table(rows)
    print(text)
    if args.write:
        results_md.append("### Arms: Pinocchio's calls looped in C++ against Python",
                          f'python benchmarks/bench_arm_pin_batch.py --repeats {args.repeats}',
                          text)
    return 0 if all(r['solved'] and r['same_bits'] for r in rows) else 1


if __name__ == '__main__':
    sys.exit(main())
