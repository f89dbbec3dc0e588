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
Fast mode for URDF arms against CasADi + IPOPT and FATROP, in one process.

For the Panda and the UR5 (scenarios and stand-in robot spheres of bench_arms_reference.py),
free, with one or with three obstacle spheres (--obstacles), Euler with N = 50 and 100
(--N): toc_ros' solve() cold (median and spread of --repeats runs after one warm-up run
that loads the compiled kernels), then
IPOPT and FATROP on the same transcription from the same initial guess (fast mode's start
point), each --repeats times.  Every fast result is re-checked independently
(toc_ros/bench/arm_check.py).  Per iteration, fast mode's time is split into Pinocchio
calls (derivatives, and the line search's batched ABA), the Riccati step (compiled) and the
rest (sphere rows, the compiled barrier and line-search kernels and the Python driving them,
start point and final re-integration).  Ratios to IPOPT and FATROP: median over median, and
the range over the paired runs; the repeated fast runs are checked to give the same bits.

    python benchmarks/bench_arm_fast.py                 # the table
    python benchmarks/bench_arm_fast.py --write         # also append it to RESULTS.md
"""

import argparse
import datetime
import os
import platform
import statistics
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from benchmarks.bench_arms_reference import SCENARIOS as REFERENCE_SCENARIOS  # noqa: E402, I100
from toc_ros.bench.arm_check import check_trajectory, example_robot_urdf  # noqa: E402
from toc_ros.bench.arm_problem import ArmProblem, ArmSpec  # noqa: E402
from toc_ros.bench.arm_reference import ArmTranscription  # noqa: E402
from toc_ros.core import Problem, solve, Status  # noqa: E402
from toc_ros.core.arms import load_arm, load_spheres  # noqa: E402
from toc_ros.core.arms.arm_eval import ArmEvaluator  # noqa: E402
from toc_ros.core.arms.arm_solve import ArmRobot  # noqa: E402
from toc_ros.core.arms.cold_runs import start_point  # noqa: E402

MARGIN = 0.02
SCENARIOS = {name: (sc['start'], sc['goal'], sc['obstacles'])
             for name, sc in REFERENCE_SCENARIOS.items()}


def run_case(name, obstacle_set, n_int, repeats):
    """One row: fast mode, IPOPT and FATROP from fast mode's start point."""
    start, goal, sets = SCENARIOS[name]
    obstacles = sets[obstacle_set]
    spheres_file = os.path.join(HERE, 'data', f'arm_spheres_{name}.yaml')
    arm = load_arm(name)
    robot = ArmRobot(arm, load_spheres(spheres_file, arm, self_collision=False))
    problem = Problem(x0=start, x_goal=goal, model=robot, obstacles=obstacles, margin=MARGIN,
                      n_intervals=n_int)
    solve(problem)          # warm-up: loads the compiled kernels
    times, results = [], []
    for _ in range(repeats):
        started = time.perf_counter()
        result = solve(problem)
        times.append(time.perf_counter() - started)
        results.append(result)
    result = results[-1]
    state = result.solver_state or {}
    spec = ArmSpec(urdf=example_robot_urdf(name), joints=arm.joint_names, start=start,
                   goal=goal, obstacles=obstacles, robot_spheres=spheres_file, margin=MARGIN)
    check = check_trajectory(spec, result.final_time, result.controls, 'euler', result.states)
    n = arm.n
    x0, xg = np.concatenate([start, np.zeros(n)]), np.concatenate([goal, np.zeros(n)])
    evaluator = ArmEvaluator(arm, robot.spheres, obstacles, MARGIN, n_int)
    guess = start_point(robot, evaluator, x0, xg, n_int)[:3]
    reference = ArmProblem(spec)
    ref = {}
    for solver in ('ipopt', 'fatrop'):
        nlp = ArmTranscription(reference, n_int, 'euler', solver)
        runs = [nlp.solve(guess) for _ in range(repeats)]
        ref[solver] = (runs[-1], statistics.median(r['solve_time_s'] for r in runs))
        ref[solver + '_all_s'] = [r['solve_time_s'] for r in runs]
    iterations = max(result.iterations, 1)
    total = statistics.median(times)
    return {
        'arm': name, 'obstacles': obstacle_set, 'N': n_int,
        'status': result.status.value, 't_f': result.final_time,
        'iterations': result.iterations, 'median_ms': 1e3 * total,
        'min_ms': 1e3 * min(times), 'max_ms': 1e3 * max(times),
        'pin_ms_it': 1e3 * state.get('pin_time_s', float('nan')) / iterations,
        'linalg_ms_it': 1e3 * state.get('linalg_time_s', float('nan')) / iterations,
        'rest_ms_it': 1e3 * (result.wall_time_s - state.get('pin_time_s', 0.0)
                             - state.get('linalg_time_s', 0.0)) / iterations,
        'pin_calls_it': state.get('pin_calls', 0) / iterations,
        'check': max(check['terminal_error'], check['max_position_excess'],
                     check['max_velocity_excess'], check['max_effort_excess']),
        'clearance': check['min_clearance'], 'start': state.get('start', ''),
        'ipopt': ref['ipopt'], 'fatrop': ref['fatrop'],
        'ipopt_all_s': ref['ipopt_all_s'], 'fatrop_all_s': ref['fatrop_all_s'],
        'times_s': times,
        'same_bits': all(r.final_time == results[0].final_time
                         and np.array_equal(r.controls, results[0].controls) for r in results),
        'solved': result.status is Status.SOLVED,
    }


def _ratio(row, solver):
    """Median ratio fast / reference and its spread: min and max over paired runs."""
    fast, ref = row['times_s'], row[solver + '_all_s']
    pairs = [f / r for f, r in zip(fast, ref)]
    return (f"{row['median_ms'] / (1e3 * statistics.median(ref)):.3f} "
            f'({min(pairs):.3f}-{max(pairs):.3f})')


def _gap(t_f, ref):
    return f'{(t_f - ref) / ref:+.1e}'


def table(rows):
    """Markdown table of the rows."""
    head = ('| arm | obstacles | N | status | t_f [s] | vs IPOPT (relative) | it | median [ms] | '
            'min-max [ms] | per it: pin / Riccati / rest [ms] (pin calls) | IPOPT t_f, it, '
            '[ms] | FATROP t_f, it, [ms] | fast / IPOPT, median (range) | fast / FATROP, '
            'median (range) | re-check: limits '
            '& terminal / min clearance |')
    lines = [head, '|' + '---|' * 15]
    for r in rows:
        ip, ip_ms = r['ipopt']
        fa, fa_ms = r['fatrop']
        lines.append(
            f"| {r['arm']} | {r['obstacles']} | {r['N']} | {r['status']} | {r['t_f']:.6f} | "
            f"{_gap(r['t_f'], ip['t_f'])} | {r['iterations']} | {r['median_ms']:.1f} | "
            f"{r['min_ms']:.1f}-{r['max_ms']:.1f} | {r['pin_ms_it']:.2f} / "
            f"{r['linalg_ms_it']:.2f} / {r['rest_ms_it']:.2f} ({r['pin_calls_it']:.0f}) | "
            f"{ip['t_f']:.6f}{'' if ip['success'] else ' (fail)'}, {ip['iterations']}, "
            f"{1e3 * ip_ms:.1f} | {fa['t_f']:.6f}{'' if fa['success'] else ' (fail)'}, "
            f"{fa['iterations']}, {1e3 * fa_ms:.1f} | {_ratio(r, 'ipopt')} | "
            f"{_ratio(r, 'fatrop')} | {r['check']:.1e} / "
            f"{r['clearance']:+.1e} |")
    return '\n'.join(lines)


def main(argv=None):
    """Run the benchmark and print (and optionally append) the table."""
    p = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    p.add_argument('--repeats', type=int, default=5)
    p.add_argument('--N', type=int, nargs='+', default=[50, 100])
    p.add_argument('--arms', nargs='+', default=['panda', 'ur5'])
    p.add_argument('--obstacles', nargs='+', default=['free', '1 sphere'],
                   choices=['free', '1 sphere', '3 spheres'])
    p.add_argument('--write', action='store_true', help='append the table to RESULTS.md')
    p.add_argument('--json', help='write the rows (times in s) to this file')
    args = p.parse_args(argv)
    rows = []
    for name in args.arms:
        for n_int in args.N:
            for obstacle_set in args.obstacles:
                row = run_case(name, obstacle_set, n_int, args.repeats)
                print(table([row]).splitlines()[-1], flush=True)
                rows.append(row)
    text = table(rows)
    same = all(r['same_bits'] for r in rows)
    text += (f'\n\nRepeated fast runs of each row gave {"identical" if same else "DIFFERENT"} '
             'final times and controls (bit for bit).')
    print(text)
    if args.json:
        import json
        with open(args.json, 'w') as stream:
            json.dump([{k: v for k, v in r.items() if k not in ('ipopt', 'fatrop')}
                       | {'ipopt_t_f': r['ipopt'][0]['t_f'], 'fatrop_t_f': r['fatrop'][0]['t_f']}
                       for r in rows], stream, indent=1)
    if args.write:
        load = os.getloadavg()[0] if hasattr(os, 'getloadavg') else float('nan')
        with open(os.path.join(HERE, 'RESULTS.md'), 'a') as stream:
            stream.write(f'\n\n## Arms: fast mode vs IPOPT and FATROP (Euler, same start)\n\n'
                         f'`python benchmarks/bench_arm_fast.py --repeats {args.repeats}`, '
                         f'{datetime.date.today()}, Python {platform.python_version()}, '
                         f'load average {load:.1f} on the shared 2-core machine.\n\n'
                         f'{text}\n')
    return 0 if all(r['solved'] for r in rows) else 1


if __name__ == '__main__':
    sys.exit(main())
