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
Arms the solver was not tuned on: example-robot-data's UR10, UR3, xArm7, Z1, SO-100, Kinova.

For each robot, --count random rest-to-rest motions (every joint from a random start within
its limits, capped to +-pi, by a uniform offset of at most 1 rad, both 0.1 rad inside the
limits; seeded by the robot's name), Euler, --N intervals, no obstacles; and the UR10 past one
sphere with the hand-placed four-sphere set of benchmarks/data/arm_spheres_ur10_wrist.yaml.
With --past-sphere K, for the robots with a rough sphere set (benchmarks/data/
arm_spheres_<robot>_rough.yaml: xArm7, UR3, Kinova, Z1) also K motions drawn alike (their own
seed) past one obstacle sphere of radius 0.08 m at the last sphere link's position halfway
along the straight joint path (the line start collides), start and goal at least 3 cm clear.
Grippers are locked at 0.  Fast mode (Python API, cold, timed after a warm-up solve) against
IPOPT (toc_ros/bench/arm_reference.py, the same discretisation) from the straight-line start
and from fast mode's solution, its best converged t_f the reference; every result re-checked
independently (toc_ros/bench/arm_check.py, Pinocchio's own URDF parser).

    python benchmarks/bench_arm_robots.py [--count 3] [--N 60] [--robots ur10 ...]
                                          [--past-sphere 4]
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

from toc_ros.bench.arm_check import check_trajectory  # noqa: E402, I100
from toc_ros.bench.arm_problem import ArmProblem, ArmSpec  # noqa: E402
from toc_ros.bench.arm_reference import ArmTranscription  # noqa: E402
from toc_ros.core import Problem, solve, Status  # noqa: E402
from toc_ros.core.arms import load_arm, load_spheres, sphere_centres  # noqa: E402
from toc_ros.core.arms.arm_solve import ArmRobot  # noqa: E402
from toc_ros.core.arms.model import example_robot_data_dir  # noqa: E402

UR_JOINTS = ('shoulder_pan_joint', 'shoulder_lift_joint', 'elbow_joint', 'wrist_1_joint',
             'wrist_2_joint', 'wrist_3_joint')
# name: (URDF below example-robot-data's robots/, planned joints, locked joints)
ROBOTS = {
    'ur10': ('ur_description/urdf/ur10_robot.urdf', UR_JOINTS, {}),
    'ur3': ('ur_description/urdf/ur3_robot.urdf', UR_JOINTS, {}),
    'xarm7': ('xarm_description/urdf/xarm7.urdf', tuple(f'joint{i}' for i in range(1, 8)), {}),
    'z1': ('z1_description/urdf/z1.urdf', tuple(f'joint{i}' for i in range(1, 7)),
           {'jointGripper': 0.0}),
    'so100': ('so_arm_description/urdf/so100.urdf',
              ('shoulder_pan', 'shoulder_lift', 'elbow_flex', 'wrist_flex', 'wrist_roll'),
              {'gripper': 0.0}),
    'kinova': ('kinova_description/robots/kinova.urdf',
               tuple(f'j2s6s200_joint_{i}' for i in range(1, 7)), {}),
}
# The UR10 case with an obstacle: its start, goal and sphere (where the straight line passes).
UR10_SPHERE = ((2.6021, -0.6977, 1.6416, 1.0277, 1.9161, 0.873),
               (2.5222, 0.1167, 1.6854, 1.0052, 1.6318, 0.3537), (-0.62, 0.22, -0.2, 0.15))
UR10_SPHERES = os.path.join(HERE, 'data', 'arm_spheres_ur10_wrist.yaml')
MARGIN = 0.02
ROUGH_SPHERES = {name: os.path.join(HERE, 'data', f'arm_spheres_{name}_rough.yaml')
                 for name in ('xarm7', 'ur3', 'kinova', 'z1')}
PAST_RADIUS = 0.08


def draw(arm, count, rng):
    """[(start, goal)]: random starts within the limits (+-pi at most), offsets <= 1 rad."""
    low = np.maximum(np.where(arm.continuous, -np.pi, arm.lower), -np.pi) + 0.1
    high = np.minimum(np.where(arm.continuous, np.pi, arm.upper), np.pi) - 0.1
    cases = []
    for _ in range(count):
        start = np.round(rng.uniform(low, high), 4)
        goal = np.round(np.clip(start + rng.uniform(-1.0, 1.0, arm.n), low, high), 4)
        cases.append((tuple(start), tuple(goal)))
    return cases


def draw_past_sphere(arm, spheres, count, rng, max_draws=100):
    """[(start, goal, obstacle)]: draw()'s motions past a sphere at the tip's midpoint."""
    tip = spheres.links[-1]
    cases = []
    for _ in range(max_draws):
        if len(cases) == count:
            break
        (start, goal), = draw(arm, 1, rng)
        middle = arm.frame_position(0.5 * (np.array(start) + np.array(goal)), tip)
        obstacle = (*np.round(middle, 4).tolist(), PAST_RADIUS)
        clear = min(float(np.min(np.linalg.norm(sphere_centres(arm, spheres, np.array(q))
                                                - middle, axis=1) - spheres.radii))
                    for q in (start, goal)) - PAST_RADIUS
        if clear > MARGIN + 0.01:
            cases.append((start, goal, obstacle))
    return cases


def run_case(label, urdf, joints, locked, start, goal, n_int, spheres=None, obstacles=()):
    """One row: fast mode (timed), IPOPT from two starts, the independent check."""
    arm = load_arm(f'urdf:{urdf}', joints=list(joints), locked=locked)
    model = ArmRobot(arm, load_spheres(spheres, arm, self_collision=False)) if spheres else arm
    problem = Problem(x0=start, x_goal=goal, model=model, obstacles=obstacles, margin=MARGIN,
                      n_intervals=n_int)
    solve(dataclasses.replace(problem, n_intervals=5))      # kernels and caches warm
    started = time.perf_counter()
    result = solve(problem)
    ms = 1e3 * (time.perf_counter() - started)
    spec = ArmSpec(urdf=urdf, joints=tuple(joints), start=start, goal=goal, locked=locked,
                   obstacles=tuple(obstacles), robot_spheres=spheres, margin=MARGIN)
    row = {'case': label, 'status': result.status.value, 't_f': result.final_time,
           'it': result.iterations, 'ms': ms, 'check': '-', 'ipopt': None}
    if result.status is Status.SOLVED:
        check = check_trajectory(spec, result.final_time, result.controls, 'euler',
                                 result.states)
        worst = max(check['terminal_error'], check['max_position_excess'],
                    check['max_velocity_excess'], check['max_effort_excess'],
                    -min(check['min_clearance'], 0.0))
        row['check'] = f'{worst:.1e}'
    reference = ArmProblem(spec)
    nlp = ArmTranscription(reference, n_int, 'euler', 'ipopt')
    guesses = {'line': reference.path_guess(reference.line_time(), n_int)}
    if np.isfinite(result.final_time):
        guesses['fast'] = (result.states, result.controls, result.final_time)
    for name, guess in guesses.items():
        out = nlp.solve(guess)
        if out['success'] and (row['ipopt'] is None or out['t_f'] < row['ipopt'][1]):
            row['ipopt'] = (name, out['t_f'])
    return row


def table(rows):
    """Markdown table and a summary line."""
    lines = ['| case | status | t_f [s] | IPOPT best [s] (from) | gap | iterations | ms | '
             're-check |', '|---|---|---|---|---|---|---|---|']
    for row in rows:
        ref = '-' if row['ipopt'] is None else f"{row['ipopt'][1]:.6f} ({row['ipopt'][0]})"
        gap = ('-' if row['ipopt'] is None or not np.isfinite(row['t_f'])
               else f"{100 * (row['t_f'] / row['ipopt'][1] - 1):+.4f} %")
        lines.append(f"| {row['case']} | {row['status']} | {row['t_f']:.6f} | {ref} | {gap} | "
                     f"{row['it']} | {row['ms']:.0f} | {row['check']} |")
    close = [r for r in rows if r['status'] == 'SOLVED' and r['ipopt'] is not None
             and r['t_f'] <= r['ipopt'][1] * (1 + 1e-3)]
    lines += ['', f'SOLVED {sum(r["status"] == "SOLVED" for r in rows)}/{len(rows)}, within '
              f'0.1 % of IPOPT {len(close)}/{len(rows)}; time median '
              f'{statistics.median(r["ms"] for r in rows):.0f} ms, iterations median '
              f'{statistics.median(r["it"] for r in rows):.0f}.']
    return '\n'.join(lines)


def main(argv=None):
    """Run the robots and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--robots', nargs='+', default=list(ROBOTS), choices=list(ROBOTS))
    parser.add_argument('--count', type=int, default=3)
    parser.add_argument('--N', type=int, default=60)
    parser.add_argument('--past-sphere', type=int, default=0, metavar='K',
                        help='K motions past a sphere per robot with a rough sphere set')
    args = parser.parse_args(argv)
    robots = example_robot_data_dir()
    rows = []
    for name in args.robots:
        rel, joints, locked = ROBOTS[name]
        urdf = os.path.join(robots, rel)
        arm = load_arm(f'urdf:{urdf}', joints=list(joints), locked=locked)
        rng = np.random.default_rng(sum(map(ord, name)))
        for i, (start, goal) in enumerate(draw(arm, args.count, rng)):
            rows.append(run_case(f'{name} #{i}', urdf, joints, locked, start, goal, args.N))
            print(table(rows[-1:]).splitlines()[2], flush=True)
        if name == 'ur10':
            start, goal, sphere = UR10_SPHERE
            rows.append(run_case('ur10, 1 sphere', urdf, joints, locked, start, goal, args.N,
                                 UR10_SPHERES, (sphere,)))
            print(table(rows[-1:]).splitlines()[2], flush=True)
        if args.past_sphere and name in ROUGH_SPHERES:
            spheres = load_spheres(ROUGH_SPHERES[name], arm, self_collision=False)
            rng = np.random.default_rng(1000 + sum(map(ord, name)))
            for i, (start, goal, obstacle) in enumerate(
                    draw_past_sphere(arm, spheres, args.past_sphere, rng)):
                rows.append(run_case(f'{name} past a sphere #{i}', urdf, joints, locked, start,
                                     goal, args.N, ROUGH_SPHERES[name], (obstacle,)))
                print(table(rows[-1:]).splitlines()[2], flush=True)
    print()
    print(table(rows))


if __name__ == '__main__':
    main()
