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
Paper mode for URDF arms (the section-3 heuristic in joint accelerations) against fast mode.

For the Panda and the UR5 (the scenarios and stand-in spheres of bench_arms_reference.py),
free and past one or three spheres, Euler: paper mode with the paper's constants (M = --iterations
gradient steps from t_f0 = --t-f0, the learning rate --arm-step / L) and fast mode on the same
problem (its t_f is the reference minimum: it matches IPOPT's best, RESULTS.md "Arms: fast
mode vs IPOPT and FATROP").  Every paper result is re-integrated and measured by the
independent check (toc_ros/bench/arm_check.py): the terminal error, the torque, velocity and
position excess and the clearance are what the penalties left.

    python benchmarks/bench_arm_paper.py                       # the table
    python benchmarks/bench_arm_paper.py --arm-step 1 1.9      # two learning rates
    python benchmarks/bench_arm_paper.py --d-tau 1e-5 1e-4     # two decrements of tau
"""

import argparse
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from benchmarks.bench_arms_reference import SCENARIOS  # noqa: E402, I100
from toc_ros.bench.arm_check import check_trajectory, example_robot_urdf  # noqa: E402
from toc_ros.bench.arm_problem import ArmSpec  # noqa: E402
from toc_ros.core import PaperOptions, Problem, solve, SolverOptions  # noqa: E402
from toc_ros.core.arms import load_arm, load_spheres  # noqa: E402
from toc_ros.core.arms.arm_solve import ArmRobot  # noqa: E402

MARGIN = 0.02


def run_case(name, obstacle_set, n_int, iterations, t_f0, arm_step, d_tau=1e-5):
    """One row: paper mode, its independent re-check, and fast mode's t_f."""
    sc = SCENARIOS[name]
    obstacles = sc['obstacles'][obstacle_set]
    spheres_file = os.path.join(HERE, 'data', f'arm_spheres_{name}.yaml')
    arm = load_arm(name)
    robot = ArmRobot(arm, load_spheres(spheres_file, arm, self_collision=False))
    problem = Problem(x0=sc['start'], x_goal=sc['goal'], model=robot, obstacles=obstacles,
                      margin=MARGIN, n_intervals=n_int, t_f0=t_f0)
    fast = solve(problem)
    options = SolverOptions(mode='paper', max_iterations=iterations,
                            paper=PaperOptions(arm_step=arm_step, d_tau=d_tau))
    started = time.perf_counter()
    paper = solve(problem, options)
    wall = time.perf_counter() - started
    spec = ArmSpec(urdf=example_robot_urdf(name), joints=arm.joint_names, start=sc['start'],
                   goal=sc['goal'], obstacles=obstacles, robot_spheres=spheres_file,
                   margin=MARGIN)
    check = (check_trajectory(spec, paper.final_time, paper.controls, 'euler')
             if paper.has_trajectory else None)
    return {'arm': name, 'obstacles': obstacle_set, 'N': n_int, 'arm_step': arm_step,
            'd_tau': d_tau,
            'status': paper.status.value, 't_f': paper.final_time,
            'fast_status': fast.status.value, 'fast_t_f': fast.final_time,
            'iterations': paper.iterations,
            'accepted': (paper.solver_state or {}).get('accepted', 0),
            'wall_s': wall, 'check': check}


def table(rows):
    """Markdown table of the rows."""
    head = ('| arm | obstacles | N | arm_step | d_tau [s] | status | t_f [s] | fast t_f [s] | '
            'gap | iterations (accepted) | wall [s] | ms / it | re-check: terminal error / '
            'torque / velocity / position excess / min clearance [m] |')
    lines = [head, '|' + '---|' * 13]
    for r in rows:
        c = r['check']
        measured = ('-' if c is None else
                    f"{c['terminal_error']:.1e} / {c['max_effort_excess']:.2g} / "
                    f"{c['max_velocity_excess']:.2g} / {c['max_position_excess']:.2g} / "
                    f"{c['min_clearance']:+.4f}")
        gap = (r['t_f'] - r['fast_t_f']) / r['fast_t_f']
        lines.append(
            f"| {r['arm']} | {r['obstacles']} | {r['N']} | {r['arm_step']:g} | {r['d_tau']:g} | "
            f"{r['status']} | "
            f"{r['t_f']:.4f} | {r['fast_t_f']:.4f} ({r['fast_status']}) | {100 * gap:+.1f} % | "
            f"{r['iterations']} ({r['accepted']}) | {r['wall_s']:.1f} | "
            f"{1e3 * r['wall_s'] / max(r['iterations'], 1):.2f} | {measured} |")
    return '\n'.join(lines)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--arms', default='panda,ur5')
    p.add_argument('--obstacles', nargs='+', default=['free', '1 sphere', '3 spheres'])
    p.add_argument('--N', type=int, nargs='+', default=[100])
    p.add_argument('--iterations', type=int, default=30000, help="M (the paper's 30000)")
    p.add_argument('--t-f0', type=float, default=2.5, help="t_f0 [s] (the paper's 2.5)")
    p.add_argument('--arm-step', type=float, nargs='+', default=[1.0])
    p.add_argument('--d-tau', type=float, nargs='+', default=[1e-5],
                   help="d_tau [s] (the paper's 1e-5: t_f falls by N d_tau per acceptance)")
    args = p.parse_args(argv)
    rows = []
    for name in args.arms.split(','):
        for obstacle_set in args.obstacles:
            for n_int in args.N:
                for step in args.arm_step:
                    for d_tau in args.d_tau:
                        rows.append(run_case(name, obstacle_set, n_int, args.iterations,
                                             args.t_f0, step, d_tau))
                        print(table(rows[-1:]).splitlines()[-1], flush=True)
    print()
    print(table(rows))


if __name__ == '__main__':
    main()
