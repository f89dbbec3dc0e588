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
Fast mode against IPOPT and FATROP on the same discretisation, in one process (issue 9).

Cases (paper scenario unless stated; the reference NLPs are benchmarks/reference_solvers.py,
started from the same point as fast mode: its cold start fast_solver.interpolation_start, or
the same warm-start point):

* cold, Euler, N = 1000 and N = 100: fast mode, IPOPT, FATROP (and, for context, IPOPT from
  the older reference_ipopt.py's own initial guesses), plus paper mode (unchanged);
* scaling of fast mode over N = 100 ... 8000 (log-log slope of the median solve time);
* RK4 (N = 1000) against Euler, and the eq. (36) sign variant;
* replanning: from the state at node 0.3 N of the optimal paper trajectory (moving), to the same
  goal, fast mode warm-started from the remainder (controls from that node on, remaining time)
  against a cold solve, and IPOPT / FATROP started from the same warm point (fast mode's
  warm_start_point: the remainder rolled out and resampled), with their default options and
  with warm-start options (small initial barrier).  Both N = 1000 (a node's fixed N) and
  N = 0.7 * 1000 (the remainder's own grid).

Times are solve times (wall clock): fast mode's whole solve() call, the references' solver
call without the graph construction (reported separately as setup).  Median and range over
--repeat solves (fast mode; numba warmed up and one untimed solve first) and --ref-repeat
solves (references).  Every solution is re-measured the same way: its controls re-integrated by
toc_ros.core.measure_violations ('feasible' = within the SOLVED tolerances).

    PYTHONPATH=. python benchmarks/bench_solvers.py [--repeat 5] [--ref-repeat 3]
        [--markdown FILE] [--json FILE] [--quick]
"""

import argparse
from dataclasses import replace
import json
import math
import os
import platform
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from benchmarks import reference_solvers as rs  # noqa: E402, I100
from toc_ros.core import (CylindricalRobot, measure_violations, Problem,  # noqa: E402
                          RobotParams, solve, SolverOptions, warm_up)
from toc_ros.core.start_points import warm_start_point  # noqa: E402

SCALING_N = (100, 200, 500, 1000, 2000, 4000, 8000)
REPLAN_FRACTION = 0.3


def load_average():
    """1, 5 and 15 minute load averages (nan where unavailable)."""
    return os.getloadavg() if hasattr(os, 'getloadavg') else (math.nan,) * 3


def _stats(times):
    times = np.asarray(times, dtype=float)
    return {'median_s': float(np.median(times)), 'min_s': float(np.min(times)),
            'max_s': float(np.max(times)), 'repeats': int(times.size)}


def time_fast(problem, repeat, options=None, initial_guess=None, untimed=True):
    """Median/range of fast-mode solves (one untimed solve first); returns (row, result)."""
    options = options or SolverOptions(mode='fast', timeout=300.0)
    if untimed:
        solve(problem, options, initial_guess=initial_guess)
    times, result = [], None
    for _ in range(repeat):
        started = time.perf_counter()
        result = solve(problem, options, initial_guess=initial_guess)
        times.append(time.perf_counter() - started)
    _, v = measure_violations(problem, result.controls, result.final_time) \
        if result.has_trajectory else (None, None)
    row = {'method': f'{options.mode} mode', 'status': result.status.value,
           't_f': float(result.final_time) if result.has_trajectory else math.nan,
           'iterations': int(result.iterations),
           'feasible': bool(v.feasible()) if v else False,
           'violations': v.as_dict() if v else {}, 'setup_s': 0.0}
    row.update(_stats(times))
    return row, result


def time_reference(ref, repeat, guess=None, warm=False, label=None):
    """Median/range of repeated solves of one built Reference; returns (row, last output)."""
    times, out = [], None
    for _ in range(repeat):
        out = ref.solve(guess, warm=warm)
        times.append(out['solve_time_s'])
    setup = ref.setup_time_s + (getattr(ref, 'warm_setup_time_s', 0.0) if warm else 0.0)
    row = {'method': label or ref.solver_name.upper(), 'status': out['status'],
           't_f': out['t_f'], 'iterations': out['iterations'], 'feasible': out['feasible'],
           'violations': out['violations'], 'setup_s': setup, 'success': out['success']}
    row.update(_stats(times))
    return row, out


def _references(problem, repeat, notes, guess=None, warm_variants=False, solvers=None,
                adaptive=False):
    """IPOPT and FATROP rows for one problem (cold, or from guess with/without warm options)."""
    rows, outs = [], {}
    for name in solvers or rs.SOLVERS:
        if not rs.have_solver(name):
            notes.append(f'{name}: not available in this casadi, skipped')
            continue
        try:
            ref = rs.Reference(problem, name)
        except Exception as exc:      # noqa: BLE001 - report any construction failure
            notes.append(f'{name}: construction failed: {exc}')
            continue
        variants = [(False, name.upper())]
        if warm_variants:
            variants = [(False, f'{name.upper()} (default options)'),
                        (True, f'{name.upper()} (warm options)')]
        for warm, label in variants:
            row, out = time_reference(ref, repeat, guess, warm, label)
            rows.append(row)
            outs[(name, warm)] = out
        if adaptive and name == 'ipopt':
            # IPOPT's adaptive barrier update: fewer iterations here than the default monotone.
            tuned = rs.Reference(problem, name, options={'mu_strategy': 'adaptive'})
            row, out = time_reference(tuned, repeat, guess, False, 'IPOPT (adaptive mu)')
            rows.append(row)
            outs[(name, 'adaptive')] = out
    return rows, outs


def _finish(case, rows, t_ref):
    for row in rows:
        row['case'] = case
        row['gap_percent'] = rs.gap_percent(row['t_f'], t_ref)
    return rows


def _t_ref(rows):
    """Best (smallest) t_f of the references that succeeded with a feasible solution."""
    good = [r['t_f'] for r in rows if r.get('success', False) and r['feasible']]
    return min(good) if good else math.nan


def _ratio(a, b):
    return a / b if b and math.isfinite(b) and b > 0 else math.nan


def run(repeat=5, ref_repeat=3, quick=False):
    """Run every case; returns a dict of sections (rows, summary lines, notes)."""
    warm_up()
    load_start = load_average()
    notes, sections, summary = [], {}, {}
    paper = Problem.paper()
    fast_options = SolverOptions(mode='fast', timeout=300.0)

    # Cold, N = 1000 and N = 100 ------------------------------------------------------------
    cold = {}
    for n in (1000, 100):
        problem = replace(paper, n_intervals=n)
        fast_row, fast_result = time_fast(problem, repeat, fast_options)
        ref_rows, _ = _references(problem, ref_repeat, notes, adaptive=True)
        rows = [fast_row] + ref_rows
        if n == 1000:
            cold['result'] = fast_result
            rows += _old_reference(problem, notes)
            paper_row, _ = time_fast(problem, min(repeat, 3),
                                     SolverOptions(mode='paper', max_iterations=30000))
            rows.append(paper_row)
        sections[f'cold N={n}'] = _finish(f'paper scenario, Euler, N = {n}, cold', rows,
                                          _t_ref(ref_rows))
        fast_t = fast_row['median_s']
        for name in ('IPOPT', 'IPOPT (adaptive mu)', 'FATROP'):
            other = [r for r in ref_rows if r['method'] == name]
            if other:
                summary[f'N={n}: fast / {name}'] = _ratio(fast_t, other[0]['median_s'])
        summary[f'N={n}: fast median [ms]'] = 1e3 * fast_t

    # Scaling -------------------------------------------------------------------------------
    scaling = []
    for n in SCALING_N[:4] if quick else SCALING_N:
        row, _ = time_fast(replace(paper, n_intervals=n), repeat, fast_options)
        row['N'] = n
        row['case'] = f'scaling N = {n}'
        scaling.append(row)
    ns = np.array([r['N'] for r in scaling], dtype=float)
    ts = np.array([r['median_s'] for r in scaling])
    slope = float(np.polyfit(np.log(ns), np.log(ts), 1)[0])
    summary['scaling log-log slope (N = %d..%d)' % (ns[0], ns[-1])] = slope
    sections['scaling'] = scaling

    # RK4 and eq36 --------------------------------------------------------------------------
    for key, problem, label in (
            ('rk4', replace(paper, integrator='rk4'), 'paper scenario, RK4, N = 1000, cold'),
            ('eq36', replace(paper, model=CylindricalRobot(RobotParams(model_variant='eq36'))),
             'paper scenario, eq. (36) variant, Euler, N = 1000, cold')):
        fast_row, _ = time_fast(problem, repeat, fast_options)
        ref_rows, _ = _references(problem, 1 if quick else ref_repeat, notes)
        sections[key] = _finish(label, [fast_row] + ref_rows, _t_ref(ref_rows))
        euler = sections['cold N=1000'][0]['median_s']
        summary[f'{key}: fast / fast Euler'] = _ratio(fast_row['median_s'], euler)
        for name in ('IPOPT', 'FATROP'):
            other = [r for r in ref_rows if r['method'] == name]
            if other:
                summary[f'{key}: fast / {name}'] = _ratio(fast_row['median_s'],
                                                          other[0]['median_s'])

    # Replanning ----------------------------------------------------------------------------
    previous = cold['result']
    n_full = paper.n_intervals
    node = int(round(REPLAN_FRACTION * n_full))
    remainder = (np.asarray(previous.controls[node:]),
                 previous.final_time * (n_full - node) / n_full)
    start = tuple(float(v) for v in previous.states[node])
    for n in ((n_full, n_full - node) if not quick else (n_full,)):
        problem = replace(paper, x0=start, n_intervals=n)
        warm_row, _ = time_fast(problem, repeat, fast_options, initial_guess=remainder)
        warm_row['method'] = 'fast mode, warm (remainder: controls, remaining time)'
        # The remainder as solver_node passes it: the plan's states, controls and multipliers
        # from that node on (SolveResult.remainder).
        full_row, _ = time_fast(problem, repeat, fast_options,
                                initial_guess=previous.remainder(previous.time_grid[node]))
        full_row['method'] = 'fast mode, warm (SolveResult.remainder, with multipliers)'
        cold_row, _ = time_fast(problem, repeat, fast_options)
        cold_row['method'] = 'fast mode, cold'
        states, controls, t_f = warm_start_point(problem, remainder, n)[:3]
        guess = (states, controls, t_f)
        warm_refs, _ = _references(problem, ref_repeat, notes, guess=guess, warm_variants=True)
        cold_refs, _ = _references(problem, 1 if quick else ref_repeat, notes)
        for r in cold_refs:
            r['method'] += ', cold'
        rows = [warm_row, full_row, cold_row] + warm_refs + cold_refs
        shown = ', '.join(f'{v:.4f}' for v in start)
        label = f'replanning from node {node} of {n_full} (x0 = ({shown})), N = {n}'
        sections[f'replan N={n}'] = _finish(label, rows, _t_ref(warm_refs + cold_refs))
        w = warm_row['median_s']
        summary[f'replan N={n}: fast warm / fast cold'] = _ratio(w, cold_row['median_s'])
        summary[f'replan N={n}: fast warm with multipliers / fast cold'] = _ratio(
            full_row['median_s'], cold_row['median_s'])
        for r in warm_refs:
            summary[f'replan N={n}: fast warm with multipliers / {r["method"]}'] = _ratio(
                full_row['median_s'], r['median_s'])
        for r in warm_refs:
            summary[f'replan N={n}: fast warm / {r["method"]}'] = _ratio(w, r['median_s'])
    return {'sections': sections, 'summary': summary, 'notes': notes,
            'load_start': load_start, 'load_end': load_average(), 'repeat': repeat,
            'ref_repeat': ref_repeat, 'machine': f'{platform.machine()}, {os.cpu_count()} CPUs',
            'date_utc': time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}


def _old_reference(problem, notes):
    """IPOPT from reference_ipopt.py's own initial guesses (context: the earlier numbers)."""
    try:
        from benchmarks import reference_ipopt
    except ImportError as exc:     # pragma: no cover
        notes.append(f'reference_ipopt.py: {exc}')
        return []
    res = reference_ipopt.solve_reference(problem.x0, problem.x_goal, problem.obstacles,
                                          problem.margin, N=problem.n_intervals,
                                          integrator=problem.integrator)
    _, v = measure_violations(problem, res['controls'], res['t_f'])
    best = min(a['wall_time_s'] for a in res['attempts'] if a['guess'] == res['guess'])
    notes.append('IPOPT (reference_ipopt.py): its own initial guesses '
                 f'({", ".join(a["guess"] for a in res["attempts"])}; winner {res["guess"]}, '
                 f'{best:.3f} s alone), obstacle constraints at nodes 0..N and a single-link '
                 'model; time = all its attempts')
    return [{'method': 'IPOPT (reference_ipopt.py guesses)', 'status': res['status'],
             't_f': res['t_f'], 'iterations': res['iterations'], 'feasible': v.feasible(),
             'violations': v.as_dict(), 'setup_s': res['setup_time_s'],
             'median_s': res['wall_time_s'], 'min_s': res['wall_time_s'],
             'max_s': res['wall_time_s'], 'repeats': 1}]


def _fmt(value, spec, missing='n/a'):
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return missing
    return format(value, spec)


def markdown(report):
    """Return the report as Markdown text."""
    out = []
    ls, le = report['load_start'], report['load_end']
    out.append(f'{report["date_utc"]}, {report["machine"]}; load average at start '
               f'{ls[0]:.2f} / {ls[1]:.2f} / {ls[2]:.2f}, at end {le[0]:.2f} / {le[1]:.2f} / '
               f'{le[2]:.2f} (1 / 5 / 15 min). Fast mode: median (min-max) of '
               f'{report["repeat"]} solves; references: {report["ref_repeat"]} solves. Gap: to '
               'the smallest t_f of the IPOPT / FATROP runs of the same case that succeeded '
               'with a feasible (re-integrated) solution.')
    out.append('')
    head = ('| method | status | t_f [s] | gap vs best ref. [%] | iterations | solve median [ms] '
            '| range [ms] | setup [s] | feasible |')
    for key, rows in report['sections'].items():
        if key == 'scaling':
            continue
        out.append(f'**{rows[0]["case"]}**')
        out.append('')
        out.append(head)
        out.append('|---|---|---:|---:|---:|---:|---:|---:|---|')
        for r in rows:
            out.append(f'| {r["method"]} | {r["status"]} | {_fmt(r["t_f"], ".6f")} | '
                       f'{_fmt(r["gap_percent"], "+.5f")} | {r["iterations"]} | '
                       f'{1e3 * r["median_s"]:.1f} | {1e3 * r["min_s"]:.1f}-'
                       f'{1e3 * r["max_s"]:.1f} | {_fmt(r["setup_s"], ".3f")} | '
                       f'{"yes" if r["feasible"] else "NO"} |')
        out.append('')
    out.append('**fast mode scaling (paper scenario, Euler, cold)**')
    out.append('')
    out.append('| N | status | t_f [s] | iterations | median [ms] | range [ms] | ms per 1000 N |')
    out.append('|---:|---|---:|---:|---:|---:|---:|')
    for r in report['sections']['scaling']:
        out.append(f'| {r["N"]} | {r["status"]} | {r["t_f"]:.6f} | {r["iterations"]} | '
                   f'{1e3 * r["median_s"]:.1f} | {1e3 * r["min_s"]:.1f}-{1e3 * r["max_s"]:.1f}'
                   f' | {1e6 * r["median_s"] / r["N"]:.1f} |')
    out.append('')
    out.append('**ratios**')
    out.append('')
    out.append('| quantity | value |')
    out.append('|---|---:|')
    for key, value in report['summary'].items():
        out.append(f'| {key} | {_fmt(value, ".3f")} |')
    out.append('')
    for note in report['notes']:
        out.append(f'- {note}')
    return '\n'.join(out) + '\n'


def _clean(value):
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, (np.floating, np.integer, np.bool_)):
        return _clean(value.item())
    return value


def write_outputs(text, data, markdown_path=None, json_path=None):
    """Print the tables; write them to markdown_path and data (nan as null) to json_path."""
    print(text)
    if markdown_path:
        with open(markdown_path, 'w') as stream:
            stream.write(text)
    if json_path:
        with open(json_path, 'w') as stream:
            json.dump(_clean(data), stream, indent=1)


def main(argv=None):
    """Run the benchmark; print the Markdown tables, optionally write them and JSON."""
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--repeat', type=int, default=5, help='fast-mode solves per case')
    parser.add_argument('--ref-repeat', type=int, default=3, help='IPOPT/FATROP solves per case')
    parser.add_argument('--quick', action='store_true',
                        help='fewer cases (scaling to N = 1000, one replanning grid)')
    parser.add_argument('--markdown', metavar='FILE', help='also write the tables here')
    parser.add_argument('--json', metavar='FILE', help='also write the rows as JSON')
    args = parser.parse_args(argv)
    if args.repeat < 1 or args.ref_repeat < 1:
        parser.error('--repeat and --ref-repeat must be >= 1')
    report = run(args.repeat, args.ref_repeat, args.quick)
    write_outputs(markdown(report), report, args.markdown, args.json)
    return 0


if __name__ == '__main__':
    sys.exit(main())
