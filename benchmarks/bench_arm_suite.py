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
A random suite of arm motions: fast mode's curvature models against a two-start IPOPT.

Each case moves the Panda or the UR5 at rest from its ready pose to a random goal (every
joint offset uniformly by at most --spread rad, clipped 0.05 rad inside its limits), free or
(--sphere) past one obstacle sphere of radius 0.08 m placed at the tip's position halfway
along the straight joint path, so that the line start collides.  Euler, --N intervals,
robot spheres of benchmarks/data/ (margin 0.02 m).  Fast mode is run cold with
hessian='none' (no curvature of the dynamics, the model before 2026-12-04) and with the
default 'auto' (exact curvature from the 61st iteration on, arm_solve.py); IPOPT
(toc_ros/bench/arm_reference.py, tol 1e-8) from fast mode's line/detour start and from fast
mode's solution; the reference is the best converged IPOPT t_f.  Every SOLVED fast result is
re-checked independently (toc_ros/bench/arm_check.py: limits, terminal error, clearance).

    python benchmarks/bench_arm_suite.py --count 15 --N 60 [--sphere] [--seed 1]
"""

import argparse
import os
import statistics
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from toc_ros.bench.arm_check import check_trajectory, example_robot_urdf  # noqa: E402, I100
from toc_ros.bench.arm_problem import ArmProblem, ArmSpec  # noqa: E402
from toc_ros.bench.arm_reference import ArmTranscription  # noqa: E402
from toc_ros.core import Problem, Status  # noqa: E402
from toc_ros.core.arms import load_arm, load_spheres, sphere_centres  # noqa: E402
from toc_ros.core.arms.arm_eval import ArmEvaluator  # noqa: E402
from toc_ros.core.arms.arm_solve import ArmRobot, solve_arm  # noqa: E402
from toc_ros.core.arms.cold_runs import start_point  # noqa: E402
from toc_ros.core.problem import SolverOptions  # noqa: E402

MARGIN = 0.02
READY = {'panda': (0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785),
         'ur5': (0.0, -1.57, 1.57, -1.57, -1.57, 0.0)}
MODELS = ('none', 'auto')


def draw_cases(name, count, spread, with_sphere, rng):
    """[(start, goal, obstacles)]: goals offset from the ready pose; optional sphere."""
    arm = load_arm(name)
    spheres = load_spheres(os.path.join(HERE, 'data', f'arm_spheres_{name}.yaml'), arm)
    ready = np.array(READY[name])
    cases = []
    while len(cases) < count:
        goal = np.clip(ready + rng.uniform(-spread, spread, arm.n), arm.lower + 0.05,
                       arm.upper - 0.05)
        obstacles = ()
        if with_sphere:
            middle = arm.frame_position(0.5 * (ready + goal), spheres.links[-1])
            obstacles = ((*middle, 0.08),)
            clear = all(np.min(np.linalg.norm(sphere_centres(arm, spheres, q) - middle, axis=1)
                               - spheres.radii) > 0.08 + MARGIN + 0.01 for q in (ready, goal))
            if not clear:
                continue
        cases.append((ready, goal, obstacles))
    return cases


def run_case_fast_only(name, start, goal, obstacles, n_int, model):
    """Solve once (a warm-up); return the result."""
    arm = load_arm(name)
    robot = ArmRobot(arm, load_spheres(os.path.join(HERE, 'data', f'arm_spheres_{name}.yaml'),
                                       arm))
    return solve_arm(Problem(x0=start, x_goal=goal, model=robot, obstacles=obstacles,
                             margin=MARGIN, n_intervals=n_int), SolverOptions(), hessian=model)


def reference_spec(name, arm, start, goal, obstacles):
    """Return the ArmSpec of a case (the CasADi reference and the independent checks)."""
    return ArmSpec(urdf=example_robot_urdf(name), joints=arm.joint_names, start=start,
                   goal=goal, obstacles=obstacles,
                   robot_spheres=os.path.join(HERE, 'data', f'arm_spheres_{name}.yaml'),
                   margin=MARGIN)


def fast_start(robot, start, goal, obstacles, n_int):
    """(states, torques, t_f): fast mode's cold start point of a case (rest to rest)."""
    zeros = np.zeros(robot.arm.n)
    x0, xg = np.concatenate([start, zeros]), np.concatenate([goal, zeros])
    evaluator = ArmEvaluator(robot.arm, robot.spheres, obstacles, MARGIN, n_int)
    return start_point(robot, evaluator, x0, xg, n_int)[:3]


def run_case(name, start, goal, obstacles, n_int):
    """One row: fast mode with each curvature model, IPOPT from two starts, checks."""
    arm = load_arm(name)
    spheres_file = os.path.join(HERE, 'data', f'arm_spheres_{name}.yaml')
    robot = ArmRobot(arm, load_spheres(spheres_file, arm))
    problem = Problem(x0=start, x_goal=goal, model=robot, obstacles=obstacles, margin=MARGIN,
                      n_intervals=n_int)
    row = {'arm': name, 'goal': np.round(goal, 3).tolist()}
    spec = reference_spec(name, arm, start, goal, obstacles)
    for model in MODELS:
        started = time.perf_counter()
        result = solve_arm(problem, SolverOptions(), hessian=model)
        row[model] = {'status': result.status.value, 't_f': result.final_time,
                      'it': result.iterations, 'ms': 1e3 * (time.perf_counter() - started),
                      'result': result}
        if result.status is Status.SOLVED:
            check = check_trajectory(spec, result.final_time, result.controls, 'euler',
                                     result.states)
            row[model]['check'] = max(check['terminal_error'], check['max_position_excess'],
                                      check['max_velocity_excess'], check['max_effort_excess'],
                                      -min(check['min_clearance'], 0.0))
    guesses = {'start': fast_start(robot, start, goal, obstacles, n_int)}
    fast = row['auto']['result']
    if np.isfinite(fast.final_time):
        guesses['fast'] = (fast.states, fast.controls, fast.final_time)
    nlp = ArmTranscription(ArmProblem(spec), n_int, 'euler', 'ipopt')
    best, ipopt_s = None, 0.0
    for label, guess in guesses.items():
        out = nlp.solve(guess)
        ipopt_s += out['solve_time_s']
        if out['success'] and (best is None or out['t_f'] < best[1]):
            best = (label, out['t_f'])
    row['ipopt'] = best
    row['ipopt_s'] = ipopt_s
    return row


def _cell(row, model):
    fast = row[model]
    gap = ''
    if row['ipopt'] is not None and np.isfinite(fast['t_f']):
        gap = f'{100 * (fast["t_f"] / row["ipopt"][1] - 1):+.4f} %'
    check = f'{fast["check"]:.1e}' if 'check' in fast else '-'
    return (f'{fast["status"]} | {fast["t_f"]:.6f} | {gap} | {fast["it"]} | '
            f'{fast["ms"]:.0f} | {check}')


def table(rows):
    """Markdown table and summary lines."""
    head = ('| case | goal [rad] | IPOPT best [s] (from) | '
            + ' | '.join(f'{m}: status | t_f [s] | gap | it | ms | re-check' for m in MODELS)
            + ' |')
    lines = [head, '|' + '---|' * (3 + 6 * len(MODELS))]
    for row in rows:
        ref = '-' if row['ipopt'] is None else f'{row["ipopt"][1]:.6f} ({row["ipopt"][0]})'
        lines.append(f'| {row["arm"]} #{row["index"]} | {row["goal"]} | {ref} | '
                     + ' | '.join(_cell(row, m) for m in MODELS) + ' |')
    lines.append('')
    for model in MODELS:
        solved = [r for r in rows if r[model]['status'] == 'SOLVED']
        close = [r for r in solved if r['ipopt'] is not None
                 and r[model]['t_f'] <= r['ipopt'][1] * (1 + 1e-3)]
        times = [r[model]['ms'] for r in rows]
        lines.append(f'* {model}: SOLVED {len(solved)}/{len(rows)}, within 0.1 % of IPOPT '
                     f'{len(close)}/{len(rows)}, time median {statistics.median(times):.0f} '
                     f'ms (min {min(times):.0f}, max {max(times):.0f}), iterations median '
                     f'{statistics.median(r[model]["it"] for r in rows):.0f}')
    return '\n'.join(lines)


def main(argv=None):
    """Run the suite and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--robots', nargs='+', default=['panda', 'ur5'])
    parser.add_argument('--count', type=int, default=15)
    parser.add_argument('--N', type=int, default=60)
    parser.add_argument('--spread', type=float, default=1.2)
    parser.add_argument('--sphere', action='store_true')
    parser.add_argument('--seed', type=int, default=1)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    rows = []
    for name in args.robots:
        cases = draw_cases(name, args.count, args.spread, args.sphere, rng)
        for model in MODELS:        # loads the compiled kernels outside the timed solves
            run_case_fast_only(name, *cases[0], 5, model)
        for index, (start, goal, obstacles) in enumerate(cases):
            rows.append(run_case(name, start, goal, obstacles, args.N))
            rows[-1]['index'] = index           # (the case's number for its arm)
            print(table(rows[-1:]).splitlines()[2], flush=True)
    print()
    print(table(rows))


if __name__ == '__main__':
    main()
