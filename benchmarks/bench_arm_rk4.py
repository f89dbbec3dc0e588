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
Fast mode on RK4 steps for URDF arms: the cheap model alone against 'auto' (cheap, then exact).

    python benchmarks/bench_arm_rk4.py [--N 30 50 100] [--arms panda ur5]
    python benchmarks/bench_arm_rk4.py --random 4 --N 40 [--seed 7]

The scenarios of bench_arm_fast.py (free, 1 sphere, 3 spheres), or --random K motions per arm
free and K past a sphere (bench_arm_suite.py's draw), on RK4 steps, solved cold in
one process with hessian='none' (no curvature of the dynamics: RK4 solves before the exact
curvature of rk4_steps.py) and hessian='auto' (the default: that model, then the exact
curvature once it stalls); every SOLVED result re-checked independently (arm_check.py:
limits, terminal error, clearances of the re-integrated RK4 motion).
"""

import argparse
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

from bench_arm_fast import MARGIN, SCENARIOS  # noqa: E402, I100
from bench_arm_suite import draw_cases  # noqa: E402
from toc_ros.bench.arm_check import check_trajectory, example_robot_urdf  # noqa: E402, I100
from toc_ros.bench.arm_problem import ArmSpec  # noqa: E402
from toc_ros.core import Problem, Status  # noqa: E402
from toc_ros.core.arms import load_arm, load_spheres  # noqa: E402
from toc_ros.core.arms.arm_solve import ArmRobot, solve_arm  # noqa: E402
from toc_ros.core.problem import SolverOptions  # noqa: E402

MODELS = ('none', 'auto')


def run_row(name, obstacle_set, n_int, case=None):
    """Both curvature models on a scenario (or case): {model: (result, seconds, re-check)}."""
    if case is None:
        start, goal, sets = SCENARIOS[name]
        obstacles = () if obstacle_set == 'free' else sets[obstacle_set]
    else:
        start, goal, obstacles = (tuple(float(v) for v in case[0]),
                                  tuple(float(v) for v in case[1]), case[2])
    spheres = os.path.join(HERE, 'data', f'arm_spheres_{name}.yaml')
    arm = load_arm(name)
    robot = ArmRobot(arm, load_spheres(spheres, arm, self_collision=False))
    problem = Problem(x0=start, x_goal=goal, model=robot, obstacles=obstacles, margin=MARGIN,
                      n_intervals=n_int, integrator='rk4')
    spec = ArmSpec(urdf=example_robot_urdf(name), joints=arm.joint_names, start=start,
                   goal=goal, obstacles=obstacles, robot_spheres=spheres, margin=MARGIN)
    out = {}
    for model in MODELS:
        started = time.perf_counter()
        result = solve_arm(problem, SolverOptions(), hessian=model)
        seconds = time.perf_counter() - started
        check = None
        if result.status is Status.SOLVED:
            c = check_trajectory(spec, result.final_time, result.controls, 'rk4', result.states)
            check = (max(c['terminal_error'], c['max_position_excess'],
                         c['max_velocity_excess'], c['max_effort_excess']), c['min_clearance'])
        out[model] = (result, seconds, check)
    return out


def _cell(result, seconds, check):
    status = '' if result.status is Status.SOLVED else f' {result.status.value}'
    recheck = '' if check is None else f', {check[0]:.0e} / {check[1]:+.0e}'
    return f'{result.final_time:.6f}{status}, {result.iterations}, {seconds:.2f} s{recheck}'


def main(argv=None):
    """Print the table (and warm up first: the RK4 kernels load outside the timed solves)."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--N', type=int, nargs='+', default=[30, 50, 100])
    parser.add_argument('--arms', nargs='+', default=['panda', 'ur5'])
    parser.add_argument('--random', type=int, default=0, metavar='K')
    parser.add_argument('--seed', type=int, default=7)
    args = parser.parse_args(argv)
    run_row('ur5', 'free', 5)
    rng = np.random.default_rng(args.seed)
    print('| arm | obstacles | N | cheap model only: t_f, it, time, re-check | auto (cheap, '
          'then exact): t_f, it, time, re-check | t_f change | time ratio |')
    print('|' + '---|' * 7)
    results = []
    for name in args.arms:
        if args.random:
            rows = [(f'random {k + 1}' + (' past a sphere' if sphere else ''), case)
                    for sphere in (False, True)
                    for k, case in enumerate(draw_cases(name, args.random, 1.2, sphere, rng))]
        else:
            rows = [(obstacle_set, None) for obstacle_set in ('free', '1 sphere', '3 spheres')]
        for obstacle_set, case in rows:
            for n_int in args.N:
                out = run_row(name, obstacle_set, n_int, case)
                (old, old_s, _), (new, new_s, _) = out['none'], out['auto']
                both = old.status is Status.SOLVED and new.status is Status.SOLVED
                change = (new.final_time - old.final_time) / old.final_time if both else np.nan
                results.append(out)
                print(f'| {name} | {obstacle_set} | {n_int} | {_cell(*out["none"])} | '
                      f'{_cell(*out["auto"])} | {change:+.2e} | {new_s / old_s:.2f} |',
                      flush=True)
    solved = dict.fromkeys(MODELS, 0)
    for out in results:
        for model in MODELS:
            solved[model] += out[model][0].status is Status.SOLVED
    print(f'\nSOLVED: cheap model only {solved["none"]} of {len(results)}, auto '
          f'{solved["auto"]}; iterations {sum(o["none"][0].iterations for o in results)} / '
          f'{sum(o["auto"][0].iterations for o in results)}; seconds '
          f'{sum(o["none"][1] for o in results):.1f} / {sum(o["auto"][1] for o in results):.1f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
