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
Warm replanning of URDF arms: from a point along a plan, with the plan's remainder.

For each scenario of bench_arm_fast.py (Panda, UR5; free and one sphere) at --N intervals:
a cold plan, then the replan problem from the plan's node at --fraction of its time (the
robot exactly on the plan, or --drift off it: positions + drift rad, velocities x (1 - drift))
on the remainder's grid, solved by fast mode cold, warm from the remainder with its
multipliers and warm from its (controls, t_f) only; and IPOPT and FATROP on the same
transcription from the remainder's states and controls.  Median and min-max of --repeats runs
of each in one process; every warm result re-checked independently (arm_check.py) and its t_f
compared with the cold solve's.

    python benchmarks/bench_arm_warm.py                 # the table
    python benchmarks/bench_arm_warm.py --write         # also append it to RESULTS.md
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
from toc_ros.bench.arm_check import check_trajectory, example_robot_urdf  # noqa: E402, I100
from toc_ros.bench.arm_problem import ArmProblem, ArmSpec  # noqa: E402
from toc_ros.bench.arm_reference import ArmTranscription  # noqa: E402
from toc_ros.core import Problem, solve, Status  # noqa: E402
from toc_ros.core.arms import load_arm, load_spheres  # noqa: E402
from toc_ros.core.arms.arm_solve import ArmRobot  # noqa: E402


def _timed(repeats, call):
    times, result = [], None
    for _ in range(repeats):
        started = time.perf_counter()
        result = call()
        times.append(time.perf_counter() - started)
    return result, times


def run_case(name, with_obstacle, n_int, fraction, drift, repeats):
    """One row: the replan problem solved cold, warm (two ways), by IPOPT and FATROP."""
    start, goal, sets = SCENARIOS[name]
    obstacles = sets['1 sphere'] if with_obstacle else ()
    spheres_file = os.path.join(HERE, 'data', f'arm_spheres_{name}.yaml')
    arm = load_arm(name)
    n = arm.n
    robot = ArmRobot(arm, load_spheres(spheres_file, arm, self_collision=False))
    problem = Problem(x0=start, x_goal=goal, model=robot, obstacles=obstacles, margin=MARGIN,
                      n_intervals=n_int)
    plan = solve(problem)
    rest = plan.remainder(fraction * plan.final_time)
    x0 = rest.states[0].copy()
    x0[:n] += drift
    x0[n:] *= 1.0 - drift
    replan = dataclasses.replace(problem, x0=tuple(x0), n_intervals=rest.controls.shape[0])
    solve(replan, initial_guess=rest)       # warm-up (kernels are loaded by the plan already)
    runs = {'cold': _timed(repeats, lambda: solve(replan)),
            'warm': _timed(repeats, lambda: solve(replan, initial_guess=rest)),
            'primal': _timed(repeats, lambda: solve(
                replan, initial_guess=(rest.controls, rest.final_time)))}
    spec = ArmSpec(urdf=example_robot_urdf(name), joints=arm.joint_names, start=tuple(x0),
                   goal=goal, obstacles=obstacles, robot_spheres=spheres_file, margin=MARGIN)
    checks = {}
    for key in ('warm', 'primal'):
        result = runs[key][0]
        check = check_trajectory(spec, result.final_time, result.controls, 'euler',
                                 result.states)
        checks[key] = (max(check['terminal_error'], check['max_position_excess'],
                           check['max_velocity_excess'], check['max_effort_excess']),
                       check['min_clearance'])
    guess = (np.vstack([x0, rest.states[1:]]), rest.controls, rest.final_time)
    reference = ArmProblem(spec)
    for solver in ('ipopt', 'fatrop'):
        nlp = ArmTranscription(reference, replan.n_intervals, 'euler', solver)
        outs = [nlp.solve(guess) for _ in range(repeats)]
        runs[solver] = (outs[-1], [r['solve_time_s'] for r in outs])
    return {'arm': name, 'obstacles': '1 sphere' if with_obstacle else 'free', 'N': n_int,
            'M': replan.n_intervals, 'fraction': fraction, 'drift': drift, 'runs': runs,
            'checks': checks,
            'solved': all(runs[k][0].status is Status.SOLVED for k in ('cold', 'warm',
                                                                       'primal'))}


def _ms(times):
    return f'{1e3 * statistics.median(times):.1f} ({1e3 * min(times):.1f}-{1e3 * max(times):.1f})'


def table(rows):
    """Markdown table of the rows."""
    head = ('| arm | obstacles | N (replan M) | drift | cold: t_f, it, ms | warm + multipliers: '
            'gap to cold, it, ms | warm primal: gap, it, ms | IPOPT: t_f, it, ms | FATROP: '
            't_f, it, ms | warm / cold | warm / IPOPT | warm / FATROP | re-check warm, '
            'primal: limits & terminal / clearance |')
    lines = [head, '|' + '---|' * 13]
    for r in rows:
        runs = r['runs']
        cold, cold_t = runs['cold']
        cells = [f"{r['arm']}", r['obstacles'], f"{r['N']} ({r['M']})", f"{r['drift']:g}",
                 f'{cold.final_time:.6f}, {cold.iterations}, {_ms(cold_t)}']
        for key in ('warm', 'primal'):
            result, times = runs[key]
            gap = (result.final_time - cold.final_time) / cold.final_time
            status = '' if result.status is Status.SOLVED else ' ' + result.status.value
            cells.append(f'{gap:+.1e}{status}, {result.iterations}, {_ms(times)}')
        for key in ('ipopt', 'fatrop'):
            out, times = runs[key]
            cells.append(f"{out['t_f']:.6f}{'' if out['success'] else ' (fail)'}, "
                         f"{out['iterations']}, {_ms(times)}")
        warm = statistics.median(runs['warm'][1])
        for key in ('cold', 'ipopt', 'fatrop'):
            cells.append(f'{warm / statistics.median(runs[key][1]):.3f}')
        cells.append(' ; '.join(f'{c[0]:.1e} / {c[1]:+.1e}' for c in r['checks'].values()))
        lines.append('| ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines)


def main(argv=None):
    """Run the benchmark and print (and optionally append) the table."""
    p = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    p.add_argument('--repeats', type=int, default=7)
    p.add_argument('--N', type=int, default=100)
    p.add_argument('--fraction', type=float, default=0.3)
    p.add_argument('--drift', type=float, nargs='+', default=[0.0, 1e-3])
    p.add_argument('--arms', nargs='+', default=['panda', 'ur5'])
    p.add_argument('--write', action='store_true', help='append the table to RESULTS.md')
    args = p.parse_args(argv)
    rows = []
    for name in args.arms:
        for with_obstacle in (False, True):
            for drift in args.drift:
                row = run_case(name, with_obstacle, args.N, args.fraction, drift, args.repeats)
                print(table([row]).splitlines()[-1], flush=True)
                rows.append(row)
    text = table(rows)
    print(text)
    if args.write:
        results_md.append(f'## Arms: warm replanning from {args.fraction:g} of the plan',
                          f'python benchmarks/bench_arm_warm.py --repeats {args.repeats}', text)
    return 0 if all(r['solved'] for r in rows) else 1


if __name__ == '__main__':
    sys.exit(main())
