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
planar_2r in fast mode against IPOPT (and optionally FATROP) on the same discretisation.

Euler, N = 1000, the default arm of issue 13 (l1 = 1.0 m, l2 = 0.8 m, u_max = (250, 120) N m),
without gravity and with g = 9.81 m/s^2 along -y.  How the scenarios are chosen:

* rest to rest, the shoulder turning by 1.6 rad (q1: 0 -> 1.6) with the elbow slightly bent
  (q2 = 0.3 at both ends; the hand at r = 1.77 m).  Without obstacles the optimum (0.62 s, or
  0.79 s with gravity) whips: q1 first swings back to -0.22 rad while the elbow folds to
  q2 = 2.4 rad, then the arm unfolds towards the goal;
* circles sit between the start and goal bearings at 1.45-1.5 m from the base with inflated
  radius 0.13 m: beyond link 1's reach (r - R > l1 = 1 m), so link 1 never meets them and a
  feasible path always exists (fold the elbow while passing); off the straight joint-space path
  of the hand (r = 1.77 m) and clear of the start and goal configurations (Problem.validate
  checks both links, with the margin).  Circle A (bearing 0.35 rad) lies where link 2 sweeps
  when the elbow folds the unconstrained way, so it is active and forces another fold; circle B
  (bearing 1.30 rad, near the goal's unfolding) is the second circle;
* moving start: the same scenarios started with dq = (0.8, -0.5) rad/s.

IPOPT runs twice: from fast mode's cold starting point (the same start) and, as a check of
fast mode's local optimality, from fast mode's own solution (warm-start options); the smaller
feasible t_f is the reference.  IPOPT is limited to 1000 iterations and 30 s per run.

Fast mode's time is the median of --repeat solves (numba warmed up, one untimed solve first),
IPOPT's the solver call without its construction.  Both solutions are re-measured by
re-integrating their controls (measure_violations: control excess, terminal error, clearance of
both links).  The cylindrical robot's fast-mode time on the paper scenario at the same N is
given for comparison (target of issue 13: planar_2r within 2x of it).

    PYTHONPATH=. python benchmarks/bench_planar_2r.py [--repeat 1] [--fatrop]
        [--markdown FILE] [--json FILE]

--fast-only [--rounds R] times fast mode alone against the cylindrical robot on a noisy
machine: each of R rounds solves, for every scenario, the cylindrical robot and the scenario
--repeat times each, alternately, and takes the ratio of their medians; the table gives the
median and range over the rounds (no IPOPT, a few seconds per round).
"""

import argparse
import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from benchmarks import reference_solvers as rs  # noqa: E402, I100
from benchmarks.bench_solvers import (  # noqa: E402
    load_average, time_fast, time_reference, write_outputs)
from toc_ros.core import Problem, solve, SolverOptions, warm_up  # noqa: E402
from toc_ros.core.models import load_model  # noqa: E402

N = 1000
START = (0.0, 0.3)
GOAL = (1.6, 0.3)
MOVING = (0.8, -0.5)


def _polar(bearing, distance, radius):
    return (distance * math.cos(bearing), distance * math.sin(bearing), radius)


CIRCLE_A = _polar(0.35, 1.50, 0.12)
CIRCLE_B = _polar(1.30, 1.45, 0.12)
CIRCLES = {0: (), 1: (CIRCLE_A,), 2: (CIRCLE_A, CIRCLE_B)}
IPOPT_LIMITS = {'max_iter': 1000, 'max_wall_time': 30.0}


def scenarios():
    """(name, Problem) pairs: 0, 1, 2 circles x gravity 0 / 9.81, and moving starts."""
    out = []
    for g in (0.0, 9.81):
        model = load_model('planar_2r', g=g)
        for k, circles in CIRCLES.items():
            for moving in (False, True):
                dq = MOVING if moving else (0.0, 0.0)
                x0 = tuple(float(v) for v in model.state(np.array(START), np.array(dq)))
                xg = tuple(float(v) for v in model.state(np.array(GOAL)))
                problem = Problem(model=model, x0=x0, x_goal=xg, obstacles=circles,
                                  n_intervals=N)
                problem.validate()
                name = f'{k} circle{"s" if k != 1 else ""}, g = {g:g}' + \
                    (', moving start' if moving else '')
                out.append((name, problem))
    return out


def run(repeat=1, fatrop=False):
    """All scenarios; returns the report dict."""
    warm_up([load_model('planar_2r'), load_model('planar_2r', g=9.81)])
    load_start = load_average()
    fast_options = SolverOptions(mode='fast', timeout=300.0)
    cyl, _ = time_fast(Problem.paper(n_intervals=N), repeat, fast_options)
    rows = []
    for name, problem in scenarios():
        fast, result = time_fast(problem, repeat, fast_options)
        row = {'scenario': name, 'fast': fast}
        ref = rs.Reference(problem, 'ipopt', options=IPOPT_LIMITS)
        row['ipopt'], _ = time_reference(ref, 1)
        row['ipopt_from_fast'] = None
        if result.has_trajectory and np.all(np.isfinite(result.states)):
            row['ipopt_from_fast'], _ = time_reference(
                ref, 1, (result.states, result.controls, result.final_time), warm=True)
        if fatrop:
            row['fatrop'], _ = time_reference(rs.Reference(problem, 'fatrop'), 1)
        good = [r for r in (row['ipopt'], row['ipopt_from_fast'])
                if r is not None and r['success'] and r['feasible']]
        ip = min(good, key=lambda r: r['t_f']) if good else row['ipopt']
        row['best_ipopt'] = ip
        row['best_from'] = ('-' if not good else
                            'same start' if ip is row['ipopt'] else 'fast solution')
        ok_ref = bool(good)
        row['gap_percent'] = rs.gap_percent(fast['t_f'], ip['t_f']) if ok_ref else math.nan
        row['ok'] = (fast['status'] == 'SOLVED' and fast['feasible']
                     and (not ok_ref or row['gap_percent'] < 0.1))
        row['vs_cylindrical'] = fast['median_s'] / cyl['median_s']
        rows.append(row)
        same = row['ipopt']
        print(f'{name:<36} fast {fast["status"]} {fast["t_f"]:.6f} s '
              f'{1e3 * fast["median_s"]:.1f} ms | IPOPT {same["status"]} {same["t_f"]:.6f} s '
              f'{1e3 * same["median_s"]:.0f} ms | best {ip["t_f"]:.6f} ({row["best_from"]}) '
              f'| gap {row["gap_percent"]:+.5f} %', flush=True)
    return {'rows': rows, 'cylindrical': cyl, 'repeat': repeat, 'load_start': load_start,
            'load_end': load_average()}


def run_fast_only(repeat=5, rounds=3):
    """Fast mode only, interleaved with the cylindrical robot; returns the report dict."""
    warm_up([load_model('planar_2r'), load_model('planar_2r', g=9.81)])
    load_start = load_average()
    options = SolverOptions(mode='fast', timeout=300.0)
    cyl = Problem.paper(n_intervals=N)
    cases = scenarios()
    for _, problem in [('cylindrical', cyl)] + cases:
        solve(problem, options)             # untimed
    rows = {name: {'ratios': [], 'medians': [], 'cylindrical': []} for name, _ in cases}
    for _ in range(rounds):
        for name, problem in cases:
            times = {'cyl': [], 'fast': []}
            for _ in range(repeat):
                for key, case in (('cyl', cyl), ('fast', problem)):
                    started = time.perf_counter()
                    result = solve(case, options)
                    times[key].append(time.perf_counter() - started)
            row = rows[name]
            row['medians'].append(float(np.median(times['fast'])))
            row['cylindrical'].append(float(np.median(times['cyl'])))
            row['ratios'].append(row['medians'][-1] / row['cylindrical'][-1])
            row.update(status=result.status.value, t_f=float(result.final_time),
                       iterations=int(result.iterations))
    return {'rows': rows, 'repeat': repeat, 'rounds': rounds, 'load_start': load_start,
            'load_end': load_average()}


def markdown_fast_only(report):
    """Return the --fast-only table as Markdown."""
    ls, le = report['load_start'], report['load_end']
    cyl = [t for row in report['rows'].values() for t in row['cylindrical']]
    out = [f'planar_2r, Euler, N = {N}, fast mode only: {report["rounds"]} rounds of '
           f'{report["repeat"]} solves of each scenario alternating with the cylindrical robot '
           f'(paper scenario, same N; median of its round medians {1e3 * np.median(cyl):.1f} '
           f'ms); median (range) over the rounds.  Load average at start {ls[0]:.2f} / '
           f'{ls[1]:.2f} / {ls[2]:.2f}, at end {le[0]:.2f} / {le[1]:.2f} / {le[2]:.2f}.', '',
           '| scenario | status | t_f [s] | iterations | fast [ms] | fast / cylindrical |',
           '|---|---|---:|---:|---:|---:|']
    for name, row in report['rows'].items():
        ms, q = 1e3 * np.asarray(row['medians']), np.asarray(row['ratios'])
        out.append(f'| {name} | {row["status"]} | {row["t_f"]:.6f} | {row["iterations"]} | '
                   f'{np.median(ms):.1f} ({ms.min():.1f}-{ms.max():.1f}) | '
                   f'{np.median(q):.2f} ({q.min():.2f}-{q.max():.2f}) |')
    worst = max(np.median(row['ratios']) for row in report['rows'].values())
    out += ['', f'- largest median ratio to the cylindrical robot: {worst:.2f}']
    return '\n'.join(out) + '\n'


def markdown(report):
    """Return the table as Markdown."""
    ls, le = report['load_start'], report['load_end']
    cyl = report['cylindrical']
    fatrop = 'fatrop' in report['rows'][0]
    out = [f'planar_2r, Euler, N = {N}; load average at start {ls[0]:.2f} / {ls[1]:.2f} / '
           f'{ls[2]:.2f}, at end {le[0]:.2f} / {le[1]:.2f} / {le[2]:.2f}. Fast mode: median of '
           f'{report["repeat"]}; cylindrical robot (paper scenario, same N): '
           f'{1e3 * cyl["median_s"]:.1f} ms ({cyl["status"]}).', '']
    head = ('| scenario | fast status | fast t_f [s] | fast [ms] | iterations | feasible '
            '| IPOPT (same start) | t_f [s] | [ms] | it. | IPOPT from fast sol. t_f [s] '
            '| gap to best IPOPT [%] | fast / cylindrical |')
    sep = '|---|---|---:|---:|---:|---|---|---:|---:|---:|---:|---:|---:|'
    if fatrop:
        head += ' FATROP t_f [s] | FATROP [ms] |'
        sep += '---:|---:|'
    out += [head, sep]
    for r in report['rows']:
        f, ip, wf = r['fast'], r['ipopt'], r['ipopt_from_fast']
        warm = 'n/a' if wf is None else (
            f'{wf["t_f"]:.6f}' + ('' if wf['success'] and wf['feasible'] else
                                  f' ({wf["status"]}, feasible {wf["feasible"]})'))
        line = (f'| {r["scenario"]} | {f["status"]}{"" if r["ok"] else " **FAIL**"} | '
                f'{f["t_f"]:.6f} | {1e3 * f["median_s"]:.1f} | {f["iterations"]} | '
                f'{"yes" if f["feasible"] else "NO"} | {ip["status"]}'
                f'{"" if ip["feasible"] else " (infeasible)"} | {ip["t_f"]:.6f} | '
                f'{1e3 * ip["median_s"]:.0f} | {ip["iterations"]} | {warm} | '
                f'{r["gap_percent"]:+.5f} | {r["vs_cylindrical"]:.2f} |')
        if fatrop:
            fa = r['fatrop']
            line += f' {fa["t_f"]:.6f} | {1e3 * fa["median_s"]:.0f} |'
        out.append(line)
    gaps = [r['gap_percent'] for r in report['rows'] if math.isfinite(r['gap_percent'])]
    ratios = [r['vs_cylindrical'] for r in report['rows']]
    out += ['', f'- {sum(r["ok"] for r in report["rows"])}/{len(report["rows"])} SOLVED, '
            f'feasible and within 0.1 % of IPOPT; largest gap '
            f'{max(gaps) if gaps else math.nan:+.5f} %; fast time '
            f'{min(ratios):.2f}-{max(ratios):.2f} x the cylindrical robot time']
    return '\n'.join(out) + '\n'


def main(argv=None):
    """Run the scenarios, print the Markdown table; exit 1 if any is not SOLVED within 0.1 %."""
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--repeat', type=int, default=1, help='fast-mode solves per scenario')
    parser.add_argument('--fatrop', action='store_true', help='also solve with FATROP')
    parser.add_argument('--markdown', metavar='FILE', help='also write the table here')
    parser.add_argument('--json', metavar='FILE', help='also write the rows as JSON')
    parser.add_argument('--fast-only', action='store_true',
                        help='fast mode only, interleaved with the cylindrical robot')
    parser.add_argument('--rounds', type=int, default=3, help='rounds of --fast-only')
    args = parser.parse_args(argv)
    if args.fast_only:
        report = run_fast_only(max(1, args.repeat), max(1, args.rounds))
        write_outputs(markdown_fast_only(report), report, args.markdown, args.json)
        return 0 if all(r['status'] == 'SOLVED' for r in report['rows'].values()) else 1
    report = run(max(1, args.repeat), args.fatrop)
    write_outputs(markdown(report), report, args.markdown, args.json)
    return 0 if all(r['ok'] for r in report['rows']) else 1


if __name__ == '__main__':
    sys.exit(main())
