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
Fast mode's cold start against a multi-started IPOPT on random free and one-circle problems.

    PYTHONPATH=. python benchmarks/bench_cold_start.py [--seed 7] [--count 4] [--N 300]
        [--circles 0 1 2] [--models 2R 3R] [--gravity 0 9.81] [--shoulder 0.8 2.5]
        [--upward 3] [--no-timing] [--markdown FILE] [--json FILE]

The suite (seeded): planar_2r (built-in) and the three-link arm of config/models/planar_3r.yaml,
each without gravity and with g = 9.81 m/s^2, each with each of --circles circles (0, 1, 2),
--count random rest-to-rest scenarios per combination (--models, --gravity select): the
shoulder turns 0.8-2.5 rad (--shoulder) either way, the other joints start and end anywhere
in [-1.5, 1.5] rad; the circles (radius 0.1-0.2 m before the margin) sit near the hand's
path (draw), and scenarios whose start or goal the core refuses are redrawn.  Explicit
Euler, N intervals, t_f0 left at the Problem's default.

Per scenario:

* fast mode with its cold start (the result) and with the cold start of a single t_f0 (the
  problem's: one search, without fitted attempts, FOLDING_SEARCHES = (None,)), each
  re-measured by re-integrating its controls (measure_violations);
* IPOPT (benchmarks/reference_solvers.py, the same discretisation) from the interpolation start
  over each t_f0 of IPOPT_STARTS (multiples of the fitted bang-bang time, and the problem's
  t_f0) and from fast mode's solutions, with and without the fitted starts (a check of their
  local optimality); the best feasible t_f of these runs is the reference;
* which start gave IPOPT's best, the gaps to it, and whether the result's joints span more
  than a turn beyond the direct motion.

A second table times the cold start (median of --repeat solves) with and without the fitted
starts on the paper scenario and on the planar_2r scenario of bench_planar_2r.py.
Needs casadi (extra 'bench').
"""

import argparse
import json
import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from reference_solvers import Reference  # noqa: E402, I100
from toc_ros.core import fast_solver  # noqa: E402
from toc_ros.core import (load_model, measure_violations, Problem, ProblemError,  # noqa: E402
                          solve, SolverOptions, warm_up)
from toc_ros.core.solver import warm_up_for  # noqa: E402
from toc_ros.core.start_points import fitted_final_time, interpolation_start  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
MODELS = {'2R': 'planar_2r',
          '3R': os.path.join(os.path.dirname(HERE), 'config', 'models', 'planar_3r.yaml')}
# IPOPT's starts: the interpolation start over these multiples of the fitted time, and over
# the problem's t_f0 ('t_f0').
IPOPT_STARTS = (0.8, 1.2, 2.0, 't_f0')
GAP_LIMIT = 0.1      # [%]


def hand_path(model, q):
    """Return the hand (end of the last link) at joint positions q (M, n)."""
    return model.link_segments(q)[:, -1, 2:4]


def draw(rng, model, g, circles, n, upward=False, shoulder=(0.8, 2.5)):
    """
    Draw one valid rest-to-rest scenario of model with `circles` circles (0, 1 or 2).

    The circles sit near the hand's straight joint-space path at its middle (one) or at a
    third and two thirds of it (two).  upward: the shoulder starts in [-1.2, 0.2] rad and
    rises by 0.8-1.8 rad (against gravity along -y); otherwise it turns by shoulder (low,
    high) [rad] either way.
    """
    joints = model.n_joints
    while True:
        if upward:
            first = rng.uniform(-1.2, 0.2)
            q0 = np.concatenate([[first], rng.uniform(-1.5, 1.5, joints - 1)])
            qg = np.concatenate([[first + rng.uniform(0.8, 1.8)],
                                 rng.uniform(-1.5, 1.5, joints - 1)])
        else:
            q0 = np.concatenate([[rng.uniform(-math.pi, math.pi)],
                                 rng.uniform(-1.5, 1.5, joints - 1)])
            qg = np.concatenate([[q0[0] + rng.choice([-1.0, 1.0]) * rng.uniform(*shoulder)],
                                 rng.uniform(-1.5, 1.5, joints - 1)])
        obstacles = []
        for k in range(circles):
            s = (k + 1.0) / (circles + 1.0)
            at = hand_path(model, ((1.0 - s) * q0 + s * qg)[None, :])[0]
            offset = rng.uniform(-0.15, 0.15, 2)
            obstacles.append((float(at[0] + offset[0]), float(at[1] + offset[1]),
                              float(rng.uniform(0.1, 0.2))))
        obstacles = tuple(obstacles)
        problem = Problem(model=model, x0=tuple(float(v) for v in model.state(q0)),
                          x_goal=tuple(float(v) for v in model.state(qg)),
                          obstacles=obstacles, n_intervals=n)
        try:
            problem.validate()
        except ProblemError:
            continue
        return problem


def upward_fixed(n):
    """Return bench_planar_2r's vertical-plane scenario: q (0, 0.3) -> (1.6, 0.3), circle A."""
    model = load_model('planar_2r', g=9.81)
    circle = (1.5 * math.cos(0.35), 1.5 * math.sin(0.35), 0.12)
    return Problem(model=model, x0=tuple(float(v) for v in model.state(np.array([0.0, 0.3]))),
                   x_goal=tuple(float(v) for v in model.state(np.array([1.6, 0.3]))),
                   obstacles=(circle,), n_intervals=n)


def suite(seed, count, n, circle_counts=(0, 1), upward=0, models=tuple(MODELS),
          gravity=(0.0, 9.81), shoulder=(0.8, 2.5)):
    """Return [(label, problem)] of the random cases and of `upward` vertical 2R ones."""
    rng = np.random.default_rng(seed)
    cases = []
    names = {0: 'free', 1: '1 circle', 2: '2 circles'}
    for name in models:
        for g in gravity:
            model = load_model(MODELS[name], g=g)
            for circles in circle_counts:
                for k in range(count):
                    label = f'{name} g={g:g} {names[circles]} #{k}'
                    cases.append((label, draw(rng, model, g, circles, n, shoulder=shoulder)))
    if upward:
        cases.append(('2R g=9.81 upward 1 circle (bench_planar_2r)', upward_fixed(n)))
        model = load_model('planar_2r', g=9.81)
        for k in range(upward - 1):
            cases.append((f'2R g=9.81 upward 1 circle #{k}',
                          draw(rng, model, 9.81, 1, n, upward=True)))
    return cases


def extra_turns(problem, states):
    """Return by how much [rad] a joint's range exceeds its direct motion's (revolute)."""
    model = problem.robot_model
    q = model.positions(np.asarray(states))
    q0 = model.positions(np.asarray(problem.x0))
    qg = model.positions(np.asarray(problem.x_goal))
    span = q.max(axis=0) - q.min(axis=0)
    return float(np.max(span - np.abs(qg - q0)))


def fast(problem, fitted=True):
    """
    Solve in fast mode; return a row dict.

    fitted=False: the single search without fitted attempts (the start over t_f0 alone).
    """
    saved = fast_solver.FOLDING_SEARCHES
    if not fitted:
        fast_solver.FOLDING_SEARCHES = (None,)
    try:
        # A model file's kernels compile on its first solve (tens of seconds after an edit of
        # toc_ros/core, which keys the cache): not part of the solve's time.
        warm_up_for(problem, SolverOptions(mode='fast'))
        started = time.perf_counter()
        result = solve(problem, SolverOptions(mode='fast'))
        wall = time.perf_counter() - started
    finally:
        fast_solver.FOLDING_SEARCHES = saved
    feasible = False
    if result.controls is not None:
        _, v = measure_violations(problem, result.controls, result.final_time)
        feasible = v.feasible()
    return {'status': result.status.value, 't_f': float(result.final_time or math.nan),
            'feasible': bool(feasible), 'time_s': wall, 'iterations': int(result.iterations),
            'extra_turns': extra_turns(problem, result.states)
            if result.states is not None else math.nan,
            'controls': result.controls, 'states': result.states}


def ipopt(problem, fast_row, single_row=None):
    """
    Return {start label: (t_f or nan)} of IPOPT's runs (nan: failed or infeasible).

    Besides its interpolation starts, IPOPT starts from fast mode's solution and from the
    single-start variant's (a local optimum either found is then the reference's too).
    """
    reference = Reference(problem, 'ipopt')
    fitted = fitted_final_time(problem) or float(problem.t_f0)
    starts = {}
    for factor in IPOPT_STARTS:
        t_f = float(problem.t_f0) if factor == 't_f0' else factor * fitted
        label = 't_f0' if factor == 't_f0' else f'{factor:g} x fitted'
        starts[label] = interpolation_start(problem, problem.n_intervals, t_f)
    if fast_row['controls'] is not None:
        starts['fast solution'] = (fast_row['states'], fast_row['controls'], fast_row['t_f'])
    if single_row is not None and single_row['controls'] is not None:
        starts['single-start solution'] = (single_row['states'], single_row['controls'],
                                           single_row['t_f'])
    out = {}
    for label, guess in starts.items():
        run = reference.solve(guess, warm=label.endswith('solution'))
        out[label] = run['t_f'] if run['success'] and run['feasible'] else math.nan
    return out


def gap(t_f, best):
    """Return 100 (t_f / best - 1) [%] (nan when either is missing)."""
    return 100.0 * (t_f / best - 1.0) if math.isfinite(t_f) and math.isfinite(best) \
        else math.nan


def run_suite(seed, count, n, circle_counts=(0, 1), upward=0, only=None, **draws):
    """
    Solve every scenario of the suite (only: those whose label contains it); return rows.

    draws: suite's models, gravity and shoulder.
    """
    rows = []
    for label, problem in suite(seed, count, n, circle_counts, upward, **draws):
        if only and only not in label:
            continue
        new = fast(problem)
        old = fast(problem, fitted=False)
        runs = ipopt(problem, new, old)
        best_label = min((k for k in runs if math.isfinite(runs[k])), key=lambda k: runs[k],
                         default=None)
        best = runs[best_label] if best_label else math.nan
        # Starts within 1e-6 (relative) of the best count as winners too.
        winners = [k for k, t in runs.items() if math.isfinite(t) and t <= best * (1 + 1e-6)]
        row = {'case': label, 'fitted_t_f': fitted_final_time(problem),
               'best_ipopt': best, 'winners': winners, 'ipopt': runs,
               'fast': {k: v for k, v in new.items() if k not in ('controls', 'states')},
               'single_start': {k: v for k, v in old.items()
                                if k not in ('controls', 'states')},
               'gap_percent': gap(new['t_f'], best),
               'single_start_gap_percent': gap(old['t_f'], best)}
        rows.append(row)
        print(f"{label}: fast {new['status']} {new['t_f']:.6f} s ({row['gap_percent']:+.4f} %, "
              f"{new['time_s'] * 1e3:.0f} ms, extra turns {new['extra_turns']:.2f} rad), "
              f"single start {old['t_f']:.6f} s ({row['single_start_gap_percent']:+.4f} %), "
              f'IPOPT best {best:.6f} s from {winners}', flush=True)
    return rows


def paper_timing(repeat):
    """Cold-start times [s] (median of repeat) with and without the fitted starts."""
    model = load_model('planar_2r')
    cases = {
        'paper scenario': Problem.paper(),
        'planar_2r (bench_planar_2r, free)': Problem(
            model=model, x0=tuple(float(v) for v in model.state(np.array([0.0, 0.3]))),
            x_goal=tuple(float(v) for v in model.state(np.array([1.6, 0.3]))), obstacles=(),
            n_intervals=1000),
        'planar_2r (bench_planar_2r, circle A)': Problem(
            model=model, x0=tuple(float(v) for v in model.state(np.array([0.0, 0.3]))),
            x_goal=tuple(float(v) for v in model.state(np.array([1.6, 0.3]))),
            obstacles=((1.5 * math.cos(0.35), 1.5 * math.sin(0.35), 0.12),), n_intervals=1000),
    }
    rows = []
    for label, problem in cases.items():
        times = {True: [], False: []}
        results = {}
        for _ in range(repeat):
            for fitted in (False, True):          # alternately: the same machine load
                row = fast(problem, fitted)
                times[fitted].append(row['time_s'])
                results[fitted] = row
        rows.append({'case': label, 'single_ms': 1e3 * float(np.median(times[False])),
                     'fitted_ms': 1e3 * float(np.median(times[True])),
                     'single_t_f': results[False]['t_f'], 'fitted_t_f': results[True]['t_f'],
                     'same_bits': bool(results[False]['t_f'] == results[True]['t_f'])})
        print(rows[-1], flush=True)
    return rows


def markdown(rows, timing, seed, count, n):
    """Return the Markdown section of the results."""
    lines = [f'Random suite (seed {seed}, {count} per combination, Euler N = {n}): fast mode '
             'with the fitted cold starts, and with the single start of t_f0 alone, against '
             'the best feasible of the IPOPT runs.', '',
             '| case | fitted t_f [s] | IPOPT best [s] | IPOPT best from | fast [s] | gap [%] '
             '| extra turns [rad] | single start gap [%] | fast time [ms] |',
             '|---|---:|---:|---|---:|---:|---:|---:|---:|']
    for r in rows:
        f = r['fast']
        lines.append(
            f"| {r['case']} | {r['fitted_t_f']:.3f} | {r['best_ipopt']:.6f} | "
            f"{', '.join(r['winners'])} | {f['t_f']:.6f} | {r['gap_percent']:+.4f} | "
            f"{f['extra_turns']:.2f} | {r['single_start_gap_percent']:+.3f} | "
            f"{f['time_s'] * 1e3:.0f} |")
    ok = [r for r in rows if r['gap_percent'] <= GAP_LIMIT and r['fast']['status'] == 'SOLVED']
    old_ok = [r for r in rows if r['single_start_gap_percent'] <= GAP_LIMIT]
    wins = {}
    for r in rows:
        for k in r['winners']:
            wins[k] = wins.get(k, 0) + 1
    lines += ['', f"Within {GAP_LIMIT} % of IPOPT's best (or better): {len(ok)} of {len(rows)} "
              f'(single start: {len(old_ok)} of {len(rows)}); worst gap '
              f"{max(r['gap_percent'] for r in rows):+.4f} %.  IPOPT start that reached the "
              'best (ties counted for each): ' +
              ', '.join(f'{k} {v}' for k, v in sorted(wins.items(), key=lambda kv: -kv[1])) +
              '.', '',
              '| cold start | single start [ms] | fitted starts [ms] | ratio | t_f single / '
              'fitted [s] |', '|---|---:|---:|---:|---|']
    for t in timing:
        lines.append(f"| {t['case']} | {t['single_ms']:.1f} | {t['fitted_ms']:.1f} | "
                     f"{t['fitted_ms'] / t['single_ms']:.2f} | {t['single_t_f']!r} / "
                     f"{t['fitted_t_f']!r} |")
    return '\n'.join(lines) + '\n'


def main(argv=None):
    """Run the suite and the timing; print (and optionally write) the tables."""
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--seed', type=int, default=7)
    parser.add_argument('--count', type=int, default=3, help='scenarios per combination')
    parser.add_argument('--N', type=int, default=300, help='intervals')
    parser.add_argument('--repeat', type=int, default=5, help='timed solves per timing case')
    parser.add_argument('--circles', type=int, nargs='+', default=[0, 1], choices=(0, 1, 2),
                        help='circle counts of the suite')
    parser.add_argument('--models', nargs='+', default=list(MODELS), choices=tuple(MODELS))
    parser.add_argument('--gravity', type=float, nargs='+', default=[0.0, 9.81],
                        help='g [m/s^2] of the suite (each)')
    parser.add_argument('--shoulder', type=float, nargs=2, default=[0.8, 2.5],
                        metavar=('LOW', 'HIGH'), help="range of the shoulder's turn [rad]")
    parser.add_argument('--upward', type=int, default=0,
                        help='vertical-plane 2R cases (g = 9.81, the shoulder rising, one '
                        'circle): the one of bench_planar_2r and upward - 1 random ones')
    parser.add_argument('--no-timing', action='store_true', help='skip the timing table')
    parser.add_argument('--only', metavar='TEXT',
                        help='run only the cases whose label contains TEXT (the same draws)')
    parser.add_argument('--markdown', metavar='FILE')
    parser.add_argument('--json', metavar='FILE')
    args = parser.parse_args(argv)
    warm_up()
    rows = run_suite(args.seed, args.count, args.N, tuple(args.circles), args.upward,
                     args.only, models=tuple(args.models), gravity=tuple(args.gravity),
                     shoulder=tuple(args.shoulder))
    timing = [] if args.no_timing else paper_timing(args.repeat)
    text = markdown(rows, timing, args.seed, args.count, args.N)
    print(text)
    if args.markdown:
        with open(args.markdown, 'w') as stream:
            stream.write(text)
    if args.json:
        with open(args.json, 'w') as stream:
            json.dump({'rows': rows, 'timing': timing}, stream, indent=1, default=float)
    bad = [r for r in rows if not r['gap_percent'] <= GAP_LIMIT]
    return 1 if bad else 0


if __name__ == '__main__':
    sys.exit(main())
