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
Fast mode against live IPOPT on random start/goal/obstacle scenarios (same discretisation).

    PYTHONPATH=. python benchmarks/random_scenarios.py [--markdown FILE] [--json FILE]
    PYTHONPATH=. python benchmarks/random_scenarios.py --seed S --count K --N N [--moving P]
                                                       [--max-obstacles M]

Without --seed/--count: the default suite of 46 scenarios (SUITE: seeds 1-4, N = 300 and
1000, up to 2 or 3 circles).  Each scenario: a start angle anywhere (all quadrants), a goal
0.5-2.5 rad away in either direction, extensions in [0.2, 1.4] m, 0..max-obstacles circles
(radius 0.08-0.3 m, 0.8-2.2 m from the base, between the start and goal bearings), and with
probability --moving non-zero start velocities and a non-zero goal rotation rate.  Scenarios
the core refuses (start/goal inside an obstacle) are redrawn.

The reference is IPOPT on fast mode's own discretisation (benchmarks/reference_solvers.py:
obstacle constraints on the whole arm at nodes 1..N, same integrator), started from fast mode's
cold starting point; when that run fails or its re-integrated controls are infeasible, IPOPT is
run again with the adaptive barrier update and the better feasible result kept (said in the
table).  Both solutions are re-measured by re-integrating their controls.  Prints one line per
scenario, then the worst gap, the statuses and fast mode's time distribution (median, p95,
max); exit 1 if any scenario is not SOLVED within 0.1 % of IPOPT (where IPOPT solved it).
Needs casadi (extra 'bench').
"""

import argparse
import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from benchmarks.bench_solvers import write_outputs  # noqa: E402, I100
from benchmarks.reference_ipopt import solve_reference  # noqa: E402
from benchmarks.reference_solvers import Reference  # noqa: E402
from toc_ros.core import (CylindricalRobot, measure_violations, Problem,  # noqa: E402
                          ProblemError, solve, SolverOptions, warm_up)

# (seed, count, N, max_obstacles): 46 scenarios, 0-3 circles, N = 300 and 1000.
SUITE = ((1, 15, 300, 2), (2, 15, 300, 3), (3, 8, 1000, 2), (4, 8, 1000, 3))
MOVING = 0.3
GAP_LIMIT = 0.1          # [%]


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


def _candidate(label, problem, t_f, controls, status, success, solve_time, iterations):
    _, v = measure_violations(problem, controls, t_f)
    return {'label': label, 't_f': float(t_f), 'status': status, 'success': bool(success),
            'feasible': bool(v.feasible()), 'solve_time_s': solve_time,
            'iterations': iterations}


def reference(problem):
    """
    IPOPT on the problem: (same-start run, best feasible run, note).

    The same-start run is IPOPT (default options) from fast mode's cold starting point; when it
    fails or is infeasible, it is repeated with the adaptive barrier.  For the cylindrical
    robot IPOPT is also run from reference_ipopt.py's own initial guesses (straight line and
    retract-rotate-extend), whose discrete problem is the same (its extra constraint at node 0
    holds at the fixed, validated start); the best feasible t_f of all runs is the reference.
    """
    out = Reference(problem, 'ipopt').solve()
    same = _candidate('same start', problem, out['t_f'], out['controls'], out['status'],
                      out['success'], out['solve_time_s'], out['iterations'])
    runs, note = [same], ''
    if not (same['success'] and same['feasible']):
        retry = Reference(problem, 'ipopt', options={'mu_strategy': 'adaptive'}).solve()
        cand = _candidate('same start, adaptive mu', problem, retry['t_f'], retry['controls'],
                          retry['status'], retry['success'], retry['solve_time_s'],
                          retry['iterations'])
        note = f'same-start IPOPT: {same["status"]}, feasible {same["feasible"]}; ' \
            f'adaptive mu: {cand["status"]}, feasible {cand["feasible"]}'
        runs.append(cand)
        if cand['success'] and cand['feasible']:
            same = cand
    if isinstance(problem.model, CylindricalRobot):
        res = solve_reference(list(problem.x0), list(problem.x_goal), list(problem.obstacles),
                              problem.margin, N=problem.n_intervals,
                              integrator=problem.integrator)
        runs.append(_candidate(f'reference_ipopt.py ({res["guess"]})', problem, res['t_f'],
                               res['controls'], res['status'], res['success'],
                               res['wall_time_s'], res['iterations']))
    good = [r for r in runs if r['success'] and r['feasible']]
    best = min(good, key=lambda r: r['t_f']) if good else same
    return same, best, note


def run_one(problem):
    """Solve one scenario with fast mode and IPOPT; returns a row dict."""
    started = time.perf_counter()
    result = solve(problem, SolverOptions(timeout=120.0))
    wall = time.perf_counter() - started
    ref, best, note = reference(problem)
    ref_ok = best['success'] and best['feasible']
    gap = 100.0 * (result.final_time / best['t_f'] - 1.0) if ref_ok else math.nan
    same_gap = (100.0 * (result.final_time / ref['t_f'] - 1.0)
                if ref['success'] and ref['feasible'] else math.nan)
    ok = result.success and (not ref_ok or gap < GAP_LIMIT)
    v = result.violations
    return {'N': problem.n_intervals, 'circles': len(problem.obstacles),
            'x0': [float(v) for v in problem.x0],
            'x_goal': [float(v) for v in problem.x_goal],
            'obstacles': [[float(v) for v in c] for c in problem.obstacles],
            'fast_status': result.status.value, 'fast_t_f': float(result.final_time),
            'fast_time_s': wall, 'fast_iterations': int(result.iterations),
            'fast_message': result.message,
            'fast_violations': v.as_dict() if v is not None else {},
            'ipopt_status': ref['status'], 'ipopt_feasible': ref['feasible'],
            'ipopt_t_f': ref['t_f'], 'ipopt_time_s': ref['solve_time_s'],
            'ipopt_iterations': ref['iterations'], 'ipopt_note': note,
            'best_t_f': best['t_f'], 'best_label': best['label'],
            'same_start_gap_percent': same_gap, 'gap_percent': gap, 'ok': ok}


def summary(rows):
    """Lines: count within the limit, worst gap, statuses, fast-mode time distribution."""
    lines = []
    good = sum(r['ok'] for r in rows)
    gaps = [r['gap_percent'] for r in rows if math.isfinite(r['gap_percent'])]
    worst = max(gaps) if gaps else math.nan
    best = min(gaps) if gaps else math.nan
    solved = [r['gap_percent'] for r in rows
              if r['fast_status'] == 'SOLVED' and math.isfinite(r['gap_percent'])]
    lines.append(f'{good}/{len(rows)} SOLVED within {GAP_LIMIT} % of the best IPOPT; largest gap '
                 f'{worst:+.4f} % (over SOLVED ones {max(solved) if solved else math.nan:+.4f} '
                 f'%), smallest {best:+.4f} % (negative: fast mode shorter)')
    statuses = {}
    for r in rows:
        statuses[r['fast_status']] = statuses.get(r['fast_status'], 0) + 1
    lines.append('fast mode statuses: ' + ', '.join(f'{k} {v}' for k, v in statuses.items()))
    no_ref = [r['index'] for r in rows if r['ipopt_note'] or not r['ipopt_feasible']]
    lines.append(f'same-start IPOPT with default options failed or was infeasible on '
                 f'{len(no_ref)} scenario(s)' + (f': {no_ref} (rerun with adaptive mu, see '
                                                 'below)' if no_ref else ''))
    worse = [r['index'] for r in rows if r['same_start_gap_percent'] < -GAP_LIMIT]
    lines.append(f'same-start IPOPT ended > {GAP_LIMIT} % above fast mode (another local '
                 f'optimum) on {len(worse)} scenario(s)' + (f': {worse}' if worse else ''))
    for n in sorted({r['N'] for r in rows}):
        t = np.array([r['fast_time_s'] for r in rows if r['N'] == n])
        ti = np.array([r['ipopt_time_s'] for r in rows if r['N'] == n])
        lines.append(f'N = {n}: fast mode time median {1e3 * np.median(t):.1f} ms, p95 '
                     f'{1e3 * np.percentile(t, 95):.1f} ms, max {1e3 * np.max(t):.1f} ms '
                     f'({t.size} scenarios); IPOPT median {1e3 * np.median(ti):.0f} ms, '
                     f'max {1e3 * np.max(ti):.0f} ms')
    return lines


def markdown(rows, load_start, load_end):
    """Return the table and summary as Markdown."""
    out = [f'load average at start {load_start[0]:.2f} / {load_start[1]:.2f} / '
           f'{load_start[2]:.2f}, at end {load_end[0]:.2f} / {load_end[1]:.2f} / '
           f'{load_end[2]:.2f} (1 / 5 / 15 min)', '',
           '| # | N | circles | moving | fast status | fast t_f [s] | fast [ms] | IPOPT status '
           '| IPOPT t_f [s] | IPOPT [ms] | gap same start [%] | best IPOPT t_f [s] (start) '
           '| gap [%] |',
           '|---:|---:|---:|---|---|---:|---:|---|---:|---:|---:|---:|---:|']
    for r in rows:
        k = r['index']
        moving = 'yes' if (r['x0'][1] or r['x0'][3] or r['x_goal'][1]) else 'no'
        flag = '' if r['ok'] else ' **FAIL**'
        out.append(f'| {k} | {r["N"]} | {r["circles"]} | {moving} | {r["fast_status"]}{flag} | '
                   f'{r["fast_t_f"]:.5f} | {1e3 * r["fast_time_s"]:.1f} | {r["ipopt_status"]}'
                   f'{"" if r["ipopt_feasible"] else " (infeasible)"} | {r["ipopt_t_f"]:.5f} | '
                   f'{1e3 * r["ipopt_time_s"]:.0f} | {r["same_start_gap_percent"]:+.4f} | '
                   f'{r["best_t_f"]:.5f} ({r["best_label"]}) | {r["gap_percent"]:+.4f} |')
    out.append('')
    out += [f'- {line}' for line in summary(rows)]
    for r in rows:
        k = r['index']
        if r['ipopt_note']:
            out.append(f'- scenario {k}: {r["ipopt_note"]}')
        if not r['ok']:
            out.append(f'- scenario {k} FAILED: fast {r["fast_status"]} ({r["fast_message"]}), '
                       f'x0 = {r["x0"]}, x_goal = {r["x_goal"]}, obstacles = {r["obstacles"]}, '
                       f'N = {r["N"]}')
    return '\n'.join(out) + '\n'


def main(argv=None):
    """Run the comparison; exit code 1 if any scenario is not SOLVED within 0.1 %."""
    parser = argparse.ArgumentParser(description=__doc__.strip().split('\n')[0])
    parser.add_argument('--seed', type=int, help='one batch instead of the default suite')
    parser.add_argument('--count', type=int, default=10)
    parser.add_argument('--N', type=int, default=300)
    parser.add_argument('--moving', type=float, default=MOVING)
    parser.add_argument('--max-obstacles', type=int, default=2)
    parser.add_argument('--only', type=int, nargs='+', metavar='K',
                        help='run only these scenario numbers (of the suite or batch)')
    parser.add_argument('--markdown', metavar='FILE', help='also write the table here')
    parser.add_argument('--json', metavar='FILE', help='also write the rows as JSON')
    args = parser.parse_args(argv)
    batches = SUITE if args.seed is None else ((args.seed, args.count, args.N,
                                                args.max_obstacles),)
    warm_up()
    load_start = os.getloadavg()
    rows = []
    index = -1
    for seed, count, n, max_obstacles in batches:
        rng = np.random.default_rng(seed)
        for _ in range(count):
            problem = draw(rng, n, args.moving, max_obstacles)
            index += 1
            if args.only is not None and index not in args.only:
                continue
            row = run_one(problem)
            row['index'] = index
            rows.append(row)
            print(f'{index:3d} N={n:<5d} {row["fast_status"]:17s} fast '
                  f'{row["fast_t_f"]:.5f} s ({1e3 * row["fast_time_s"]:.0f} ms)  ipopt '
                  f'{row["ipopt_t_f"]:.5f} s ({row["ipopt_status"]})  gap '
                  f'{row["gap_percent"]:+.4f} %  circles {row["circles"]}'
                  f'{"" if row["ok"] else "  <-- " + row["fast_message"]}', flush=True)
    write_outputs(markdown(rows, load_start, os.getloadavg()), {'rows': rows}, args.markdown,
                  args.json)
    return 0 if all(r['ok'] for r in rows) else 1


if __name__ == '__main__':
    sys.exit(main())
