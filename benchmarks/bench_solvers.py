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
Paper mode vs fast mode vs the IPOPT reference on the paper's scenario (Euler, N = 1000).

All three run in this one process after the numba kernels are warmed up.  Violations are
measured the same way for every method: re-integrate the returned controls over the returned
t_f (toc_ros.core.measure_violations).  The reference is benchmarks/reference_ipopt.py
(CasADi + IPOPT, direct transcription with free t_f); its wall time is IPOPT's solve time over
all its initial guesses, without the graph construction (printed separately).  Without casadi
the reference row is skipped and gaps are taken to the recorded optimum 2.067276 s.

    PYTHONPATH=. python benchmarks/bench_solvers.py [--repeat K] [--json PATH]
"""

import argparse
import importlib.util
import json
import math
import os
from pathlib import Path
import platform
import sys
import time

import numpy as np

from toc_ros.core import measure_violations, Problem, solve, SolverOptions, warm_up

RECORDED_T_STAR = 2.067276     # IPOPT, Euler N = 1000, paper scenario (reference_ipopt.py)


def _load_reference():
    path = Path(__file__).resolve().parent / 'reference_ipopt.py'
    spec = importlib.util.spec_from_file_location('reference_ipopt', path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _row(name, problem, t_f, controls, wall, extra=None):
    _, v = measure_violations(problem, controls, t_f)
    row = {'method': name, 't_min': float(t_f), 'wall_time_s': float(wall),
           'max_control_excess': v.max_control_excess, 'terminal_error': v.terminal_error,
           'min_clearance': v.min_clearance}
    row.update(extra or {})
    return row


def _median_solve(problem, options, repeat):
    walls, result = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        result = solve(problem, options)
        walls.append(time.perf_counter() - start)
    return result, float(np.median(walls))


def run(repeat=1):
    """Run the three methods; returns (rows, notes)."""
    problem = Problem()            # the paper's scenario: Euler, N = 1000
    warm_up()
    rows, notes = [], []

    paper, wall = _median_solve(problem, SolverOptions(mode='paper', max_iterations=30000),
                                repeat)
    rows.append(_row('paper mode (M = 30000)', problem, paper.final_time, paper.controls, wall,
                     {'status': paper.status.value, 'iterations': paper.iterations,
                      'seconds_per_iteration': wall / max(paper.iterations, 1)}))

    fast, wall = _median_solve(problem, SolverOptions(mode='fast'), repeat)
    rows.append(_row('fast mode', problem, fast.final_time, fast.controls, wall,
                     {'status': fast.status.value, 'iterations': fast.iterations}))

    reference = None
    if importlib.util.find_spec('casadi') is None:
        notes.append('casadi is not importable: IPOPT reference skipped '
                     f'(gaps to the recorded optimum {RECORDED_T_STAR} s, no wall-time ratio)')
    else:
        ref = _load_reference()
        walls, res = [], None
        for _ in range(repeat):
            res = ref.solve_reference(problem.x0, problem.x_goal, problem.obstacles,
                                      problem.margin, N=problem.n_intervals,
                                      integrator=problem.integrator)
            walls.append(res['wall_time_s'])
        reference = _row('IPOPT reference', problem, res['t_f'], res['controls'],
                         float(np.median(walls)),
                         {'status': res['status'], 'iterations': res['iterations'],
                          'setup_time_s': res['setup_time_s'],
                          'best_attempt_s': min(a['wall_time_s'] for a in res['attempts'])})
        rows.append(reference)
        notes.append(f'IPOPT: {len(res["attempts"])} initial guesses, '
                     f'graph construction {res["setup_time_s"]:.3f} s (not in its wall time), '
                     f'fastest single attempt {reference["best_attempt_s"]:.3f} s')

    t_ref = reference['t_min'] if reference else RECORDED_T_STAR
    for row in rows:
        row['gap_percent'] = 100.0 * (row['t_min'] - t_ref) / t_ref
        row['wall_ratio'] = (row['wall_time_s'] / reference['wall_time_s']
                             if reference else math.nan)
    return rows, notes


def _fmt(value, spec):
    return 'n/a' if value is None or not math.isfinite(value) else format(value, spec)


def print_table(rows, notes, repeat):
    """Print the comparison table."""
    load = os.getloadavg()[0] if hasattr(os, 'getloadavg') else math.nan
    print(f'Paper scenario, Euler, N = 1000; {platform.machine()}, {os.cpu_count()} CPUs, '
          f'load {load:.2f}; wall times: median of {repeat}')
    head = (f'{"method":<24} {"status":<18} {"t_min [s]":>10} {"gap [%]":>9} '
            f'{"u excess":>9} {"term. err":>9} {"clear. [m]":>10} {"wall [s]":>9} '
            f'{"/ ref":>7}')
    print(head)
    print('-' * len(head))
    for r in rows:
        print(f'{r["method"]:<24} {r["status"]:<18} {r["t_min"]:>10.6f} '
              f'{_fmt(r["gap_percent"], "+9.4f")} {_fmt(r["max_control_excess"], "9.3g")} '
              f'{_fmt(r["terminal_error"], "9.2e")} {_fmt(r["min_clearance"], "10.2e")} '
              f'{r["wall_time_s"]:>9.3f} {_fmt(r["wall_ratio"], "7.3f")}')
    paper = rows[0]
    print(f'paper mode: {paper["seconds_per_iteration"] * 1e6:.1f} us per iteration, '
          f'{paper["iterations"]} iterations in {paper["wall_time_s"]:.3f} s '
          '(target: 30000 iterations <= 1.0 s)')
    for note in notes:
        print(note)


def main(argv=None):
    """Run the benchmark, print the table, optionally save it as JSON."""
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--repeat', type=int, default=1,
                        help='solves per method; the median wall time is reported')
    parser.add_argument('--json', metavar='PATH', help='also write the rows as JSON')
    args = parser.parse_args(argv)
    if args.repeat < 1:
        parser.error('--repeat must be >= 1')
    rows, notes = run(args.repeat)
    print_table(rows, notes, args.repeat)
    if args.json:
        clean = [{k: (v if not isinstance(v, float) or math.isfinite(v) else None)
                  for k, v in r.items()} for r in rows]
        with open(args.json, 'w') as stream:
            json.dump({'rows': clean, 'notes': notes, 'repeat': args.repeat}, stream, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
