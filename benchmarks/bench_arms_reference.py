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
Reference minimum times of the Panda and the UR5 by CasADi + IPOPT (multi-started) and FATROP.

For each arm, each obstacle set (none, 1 sphere, 3 spheres) and each discretisation (Euler
with N = 50, 100, 200; RK4 with N = 100) this solves the minimum-time problem of
toc_ros/bench/arm_reference.py with IPOPT from several starts (the cubic line at two final
times and perturbed cubics, seeded) and keeps the best t*, then with FATROP from the line
start.  Every reported optimum is re-checked with Pinocchio (toc_ros/bench/arm_check.py: the
controls re-integrated with pinocchio.aba, limits and clearances measured at every node).

Scenarios: the obstacles stand in the way of the straight joint-space motion (the script
checks that the straight path collides and prints its worst clearance) while the start and
goal are clear.  Robot spheres: the stand-in sets in benchmarks/data/ (--spheres-panda /
--spheres-ur5 to use others, e.g. the shipped sets).

    python benchmarks/bench_arms_reference.py             # the full table (~10 min here)
    python benchmarks/bench_arms_reference.py --quick     # Euler N = 50 only
    python benchmarks/bench_arms_reference.py --write     # also append it to RESULTS.md
"""

import argparse
import datetime
import math
import os
import pickle
import platform
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from toc_ros.bench.arm_check import (  # noqa: E402, I100
    check_trajectory, example_robot_urdf, PANDA_JOINTS, UR5_JOINTS)
from toc_ros.bench.arm_problem import ArmProblem, ArmSpec  # noqa: E402
from toc_ros.bench.arm_reference import solve_arm_fatrop, solve_arm_ipopt  # noqa: E402

MARGIN = 0.02
SCENARIOS = {
    # The arm sweeps about its base axis past the spheres: the base joint's motion sets t*,
    # so the other joints may dodge them at little or no cost in time.
    'panda': {
        'joints': PANDA_JOINTS,
        'start': (-1.2, 0.2, 0.0, -2.0, 0.0, 2.2, 0.8),
        'goal': (1.2, 0.1, 0.3, -1.8, 0.2, 2.0, 0.3),
        'obstacles': {
            'free': (),
            '1 sphere': ((0.60, 0.0, 0.42, 0.08),),
            '3 spheres': ((0.56, -0.22, 0.40, 0.06), (0.60, 0.09, 0.44, 0.05),
                          (0.30, 0.13, 0.65, 0.05)),
        },
    },
    # The arm swings up in front of itself; going around the spheres costs time.
    'ur5': {
        'joints': UR5_JOINTS,
        'start': (0.0, -0.4, 0.4, -1.57, -1.57, 0.0),
        'goal': (0.0, -2.0, 0.9, -1.57, -1.57, 0.0),
        'obstacles': {
            'free': (),
            '1 sphere': ((0.60, 0.0, 0.55, 0.2),),
            '3 spheres': ((0.60, 0.0, 0.55, 0.12), (0.42, 0.12, 0.80, 0.08),
                          (0.72, -0.1, 0.40, 0.08)),
        },
    },
}
RUNS = (('euler', 50), ('euler', 100), ('rk4', 100), ('euler', 200))


def make_spec(robot, obstacles_name, spheres):
    """Return the ArmSpec of a benchmark scenario."""
    sc = SCENARIOS[robot]
    return ArmSpec(urdf=example_robot_urdf(robot), joints=sc['joints'], start=sc['start'],
                   goal=sc['goal'], obstacles=sc['obstacles'][obstacles_name],
                   robot_spheres=spheres, margin=MARGIN)


def line_clearance(problem, samples=201):
    """Worst clearance [m] along the straight joint-space path from start to goal."""
    n = problem.n
    q0, qg = problem.x0[:n], problem.xg[:n]
    worst = math.inf
    for s in np.linspace(0.0, 1.0, samples):
        gaps = problem.clearance(q0 + s * (qg - q0))
        if gaps.size:
            worst = min(worst, float(np.min(gaps)))
    return worst


def _check(spec, out, integrator):
    if not np.all(np.isfinite(out['controls'])):
        return {'terminal_error': math.inf, 'limit_excess': math.inf, 'min_clearance': -math.inf}
    c = check_trajectory(spec, out['t_f'], out['controls'], integrator, out['states'])
    return {'terminal_error': c['terminal_error'],
            'limit_excess': max(c['max_position_excess'], c['max_velocity_excess'],
                                c['max_effort_excess']),
            'min_clearance': c['min_clearance']}


def run_case(robot, obstacles_name, integrator, n_int, spheres, n_starts, seed,
             budget_s=None):
    """Solve one scenario with IPOPT (multi-start) and FATROP; return a row dict."""
    spec = make_spec(robot, obstacles_name, spheres)
    problem = ArmProblem(spec)
    line = line_clearance(problem) if problem.n_pairs else math.inf
    if problem.n_pairs and not line < 0.0:
        raise RuntimeError(f'{robot} {obstacles_name}: the straight path does not collide')
    ipopt = solve_arm_ipopt(problem, n_int, integrator, n_starts=n_starts, seed=seed,
                            budget_s=budget_s)
    fatrop = solve_arm_fatrop(problem, n_int, integrator)
    return {'robot': robot, 'obstacles': obstacles_name, 'integrator': integrator,
            'N': n_int, 'line_clearance': line, 'ipopt': ipopt, 'fatrop': fatrop,
            'ipopt_check': _check(spec, ipopt, integrator),
            'fatrop_check': _check(spec, fatrop, integrator)}


def _fmt(value, spec):
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return '-'
    if isinstance(value, float) and math.isinf(value):
        return 'inf' if value > 0 else '-inf'
    return format(value, spec)


def _violations(check):
    return (f'{_fmt(check["terminal_error"], ".1e")} / {_fmt(check["limit_excess"], ".1e")} / '
            f'{_fmt(check["min_clearance"], "+.1e")}')


HEADER = ('| robot | obstacles | integrator | N | line clearance [m] | IPOPT t* [s] | vs free | '
          'spread [s] | converged | IPOPT it (best) | IPOPT time best / all [s] | '
          'IPOPT check | FATROP t_f [s] | FATROP - t* [%] | FATROP it | FATROP time [s] | '
          'FATROP status | FATROP check |')


def table(rows):
    """Markdown table of the rows."""
    lines = [HEADER, '|' + '---|' * HEADER.count(' | ') + '---|']
    free = {(r['robot'], r['integrator'], r['N']): r['ipopt']['t_f'] for r in rows
            if r['obstacles'] == 'free' and r['ipopt']['success']}
    for r in rows:
        t_free = free.get((r['robot'], r['integrator'], r['N']))
        versus = (f'{100.0 * (r["ipopt"]["t_f"] / t_free - 1.0):+.2f} %'
                  if t_free and r['obstacles'] != 'free' else '-')
        ip, fa = r['ipopt'], r['fatrop']
        conv = sum(a['success'] for a in ip['attempts'])
        gap = 100.0 * (fa['t_f'] - ip['t_f']) / ip['t_f'] if fa['success'] else math.nan
        line = ('-' if math.isinf(r['line_clearance'])
                else _fmt(r['line_clearance'], '.3f'))
        lines.append(
            f'| {r["robot"]} | {r["obstacles"]} | {r["integrator"]} | {r["N"]} | {line} | '
            f'{ip["t_f"]:.6f} | {versus} | {_fmt(ip["t_spread"], ".1e")} | '
            f'{conv}/{len(ip["attempts"])} | '
            f'{ip["best_iterations"]} | {ip["best_solve_time_s"]:.2f} / '
            f'{ip["solve_time_s"]:.2f} | {_violations(r["ipopt_check"])} | '
            f'{fa["t_f"]:.6f} | {_fmt(gap, "+.2e")} | {fa["iterations"]} | '
            f'{fa["solve_time_s"]:.2f} | {fa["status"]} | {_violations(r["fatrop_check"])} |')
    return '\n'.join(lines)


def _parse(argv):
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--robots', default='panda,ur5')
    p.add_argument('--obstacles', default='free,1 sphere,3 spheres')
    p.add_argument('--quick', action='store_true', help='Euler N = 50 only')
    p.add_argument('--runs', help="discretisations, e.g. 'euler:200,rk4:100' (default all)")
    p.add_argument('--starts', type=int, default=3, help='IPOPT starts for N = 50')
    p.add_argument('--starts-large', type=int, default=2, help='IPOPT starts for N >= 100')
    p.add_argument('--starts-rk4', type=int, default=2, help='IPOPT starts with RK4')
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--budget', type=float, default=60.0,
                   help='no further IPOPT start once a scenario has used this many seconds')
    p.add_argument('--save', help='also pickle the rows to this file')
    p.add_argument('--merge', nargs='+', help='only tabulate rows pickled by --save runs')
    p.add_argument('--spheres-panda', default=os.path.join(HERE, 'data',
                                                           'arm_spheres_panda.yaml'))
    p.add_argument('--spheres-ur5', default=os.path.join(HERE, 'data', 'arm_spheres_ur5.yaml'))
    p.add_argument('--write', action='store_true',
                   help='append the table as a new section of benchmarks/RESULTS.md')
    return p.parse_args(argv)


def main(argv=None):
    """Run the benchmark, print the table, optionally append it to RESULTS.md."""
    args = _parse(argv)
    runs = (('euler', 50),) if args.quick else RUNS
    if args.runs:
        runs = tuple((item.split(':')[0], int(item.split(':')[1]))
                     for item in args.runs.split(','))
    spheres = {'panda': args.spheres_panda, 'ur5': args.spheres_ur5}
    load0 = os.getloadavg()[0]
    started = time.perf_counter()
    rows = []
    merged = []
    for path in args.merge or ():
        with open(path, 'rb') as stream:
            merged.append(pickle.load(stream))
        rows += merged[-1]['rows']
    if merged:
        runs = ()
    # Cheapest discretisations first over all scenarios: a run cut short keeps the most rows.
    cases = [(robot, obstacles_name, integrator, n_int) for integrator, n_int in runs
             for robot in args.robots.split(',') for obstacles_name in args.obstacles.split(',')]
    for robot, obstacles_name, integrator, n_int in cases:
        starts = args.starts if n_int <= 50 else args.starts_large
        if integrator == 'rk4':
            starts = args.starts_rk4
        row = run_case(robot, obstacles_name, integrator, n_int, spheres[robot],
                       starts, args.seed, args.budget)
        rows.append(row)
        ip, fa = row['ipopt'], row['fatrop']
        print(f'{robot} {obstacles_name} {integrator} N={n_int}: IPOPT t* = '
              f'{ip["t_f"]:.6f} ({ip["solve_time_s"]:.1f} s, '
              f'{[round(a["t_f"], 6) for a in ip["attempts"]]}), FATROP '
              f'{fa["t_f"]:.6f} {fa["status"]} ({fa["solve_time_s"]:.1f} s)', flush=True)
        if args.save:       # after every row: a run cut short keeps what it did
            _save(args.save, rows, time.perf_counter() - started, load0)
    total = time.perf_counter() - started
    load1 = os.getloadavg()[0]
    if merged:      # runs in parallel processes: the longest one, the highest loads
        total = max(m['total'] for m in merged)
        load0 = max(m['loads'][0] for m in merged)
        load1 = max(m['loads'][1] for m in merged)
    if args.save:
        _save(args.save, rows, total, load0)
    text = table(rows)
    print(text)
    print(f'total {total:.0f} s, load average {load0:.1f} -> {load1:.1f}')
    if args.write:
        _append_results(text, rows, args, total, (load0, load1))
    return 0 if all(r['ipopt']['success'] for r in rows) else 1


def _missing(rows, args):
    done = {(r['robot'], r['obstacles'], r['integrator'], r['N']) for r in rows}
    missing = [f'{robot} {obs} {integ} N = {n}' for integ, n in RUNS
               for robot in args.robots.split(',') for obs in args.obstacles.split(',')
               if (robot, obs, integ, n) not in done]
    if not missing:
        return ''
    return ('\nNot run (the machine time ran out before the deadline): ' + '; '.join(missing)
            + '.\n')


def _save(path, rows, total, load0):
    with open(path, 'wb') as stream:
        pickle.dump({'rows': rows, 'total': total, 'loads': (load0, os.getloadavg()[0])},
                    stream)


def _append_results(text, rows, args, total, loads):
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime('%Y-%m-%d %H:%M UTC')
    starts = (f'{args.starts} starts at N = 50, {args.starts_large} at N = 100 and 200, '
              f'{args.starts_rk4} with RK4 (no further start once a scenario has spent '
              f'{args.budget:.0f} s), seed {args.seed}')
    section = f"""
## Arms: reference minimum times by CasADi + IPOPT and FATROP (Panda, UR5)

`python benchmarks/bench_arms_reference.py` ({stamp}, {platform.machine()}, 2 cores shared
with other jobs, load average {loads[0]:.1f} -> {loads[1]:.1f}, {total:.0f} s; with --merge:
one process per robot run side by side, then tabulated together).
The problem and its transcription: toc_ros/bench/arm_problem.py and arm_reference.py
(rigid-body recursions in CasADi from the URDF, toc_ros/bench/arm_casadi.py, equal to
Pinocchio's ABA/RNEA/CRBA and frame placements to 1e-10, test/test_arm_casadi.py).
x = (q, qd), u = torques constant on N intervals, h = t_f / N, minimise t_f; limits at every
node (efforts on every interval),
sphere clearance (|p_s - c_o|^2 - R^2) / (2 R) >= 0 with R = r_s + R_o + margin, margin
{MARGIN} m; start and goal at rest. Accelerations of the integrator stages are lifted into
variables tied to the torques by RNEA equalities (the same discrete problem as the ABA inside
the step; the two formulations reach the same t* to 1e-8 in the tests; the Hessian of the
lifted stage has ~3x (Euler) and ~10x (RK4) fewer operations). IPOPT: tol 1e-8,
constr_viol_tol 1e-10, bound_relax_factor 0, MUMPS, exact Hessian; {starts}: the cubic line
at 1.0 and 1.5 x a
feasible-looking final time, then cubics bent through a random midpoint offset
(0.5 rad standard deviation); best converged t* kept. FATROP (structure detection 'auto',
tol 1e-8, constr_viol_tol 1e-10) from the line start. Times are solver calls only (the NLP's
construction is not counted) on a loaded machine: read them as orders of magnitude.

Columns: *line clearance*: worst clearance along the straight joint path (< 0: it collides);
*spread*: max - min t_f over IPOPT's converged starts; *check*: the solution's controls
re-integrated by pinocchio.aba (same integrator and h), terminal error (inf-norm) / largest
limit excess (position, velocity, effort; 0 = within) / minimum clearance over all nodes and
sphere pairs [m].

{text}
{_missing(rows, args)}"""
    with open(os.path.join(HERE, 'RESULTS.md'), 'a', encoding='utf-8') as stream:
        stream.write(section)
    del rows


if __name__ == '__main__':
    sys.exit(main())
