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
toc-solve for URDF arms: --model panda | ur5 | urdf:PATH (toc_ros.solve hands these over).

    toc-solve --model panda --start Q1..Q7 [DQ1..DQ7]
              (--goal Q1..Q7 [DQ1..DQ7] | --goal-pose X Y Z [QX QY QZ QW] [--tip LINK])
              [--joints j1,...,jn] [--locked NAME=VALUE ...] [--limit JOINT.KEY=VALUE ...]
              [--collision-spheres FILE]
              [--sphere X Y Z R ...] [--margin M] [--self-collision]
              [--mode fast|paper] [--t-f0 S] [--integrator euler|rk4] [--N N]
              [--max-iterations M] [--timeout S] [--json OUT] [--quiet]

States are positions first, then velocities (velocities 0 when omitted).  --goal-pose is
the tip link's position (and orientation) in the base frame: the goal is the configuration at
rest that the core's inverse kinematics finds, seeded by the start's positions, within the
joint limits and clear of the --sphere obstacles by the margin (as solver_node's goal_pose);
an unreachable pose is an invalid problem (exit code 4) with IK's reason.  The JSON is
SolveResult.to_dict() (status, final_time, states (N + 1) x 2n, controls N x n torques, the
measured violations) plus joint_names.  Exit codes as toc-solve: 0 only when SOLVED.
"""

import argparse
import json
import sys

from toc_ros.cli_run import EXIT_WRITE_ERROR, ProgressLine, solve_interruptible, write_json

ARM_PREFIXES = ('urdf:',)
# The keys of toc_ros.core.arms.model.NAMED_ARMS (a test keeps them equal), spelled out so that
# toc-solve for the planar models does not import Pinocchio.
ARM_NAMES = ('panda', 'ur5')


def is_arm_model_name(name):
    """Return True when --model names a URDF arm (panda, ur5, urdf:PATH)."""
    return isinstance(name, str) and (name in ARM_NAMES or name.startswith(ARM_PREFIXES))


def requested_model(argv):
    """Return the value of --model in argv (None when absent)."""
    for i, arg in enumerate(argv):
        if arg == '--model' and i + 1 < len(argv):
            return argv[i + 1]
        if arg.startswith('--model='):
            return arg[len('--model='):]
    return None


def build_parser():
    """Argument parser of toc-solve for arms."""
    from toc_ros.core.problem import MODES
    p = argparse.ArgumentParser(
        prog='toc-solve', description='Minimum-time trajectory of a URDF arm (Pinocchio '
        'dynamics, torque/velocity/position limits, sphere obstacles). SI units, radians.',
        epilog='Exit codes: 0 solved, 1 solved inaccurately, 2 not converged or bad '
               'arguments, 3 canceled or timed out, 4 invalid problem, 5 --json not writable.',
        allow_abbrev=False)     # (--mode must not pass for --model)
    p.add_argument('--model', required=True, metavar='panda|ur5|urdf:PATH')
    p.add_argument('--joints', metavar='J1,...,JN',
                   help="planned joints in kinematic order (default: the named arm's arm "
                        'joints, or every movable joint of the URDF)')
    p.add_argument('--locked', action='append', metavar='NAME=VALUE', default=[],
                   help='value of a joint that is not planned (default 0 clamped into its '
                        'limits); repeat for several')
    p.add_argument('--limit', action='append', metavar='JOINT.KEY=VALUE', default=[],
                   help='override a URDF limit, KEY one of effort [N m or N], velocity [rad/s '
                        'or m/s], lower, upper [rad or m] (like robot.joint_limits of the '
                        'node); repeat for several')
    p.add_argument('--collision-spheres', metavar='FILE',
                   help='YAML link_name: [[x, y, z, r], ...] (default: the shipped set of the '
                        'Panda / UR5)')
    p.add_argument('--start', type=float, nargs='+', required=True, metavar='X',
                   help='Q1 .. Qn [DQ1 .. DQn]')
    goal = p.add_mutually_exclusive_group(required=True)
    goal.add_argument('--goal', type=float, nargs='+', metavar='X',
                      help='Q1 .. Qn [DQ1 .. DQn]')
    goal.add_argument('--goal-pose', type=float, nargs='+', metavar='X',
                      help='X Y Z [QX QY QZ QW]: pose of --tip in the base frame [m] (without '
                           'the quaternion: position only); the goal joints come from inverse '
                           'kinematics seeded by --start')
    p.add_argument('--tip', metavar='LINK',
                   help='link placed by --goal-pose (default: panda_hand, tool0, else the '
                        'child link of the last planned joint)')
    p.add_argument('--sphere', type=float, nargs=4, action='append', default=[],
                   metavar=('X', 'Y', 'Z', 'R'), help='obstacle sphere in the base frame [m]; '
                   'repeat for several')
    p.add_argument('--self-collision', action='store_true',
                   help='also keep the spheres of non-adjacent links apart (no margin)')
    p.add_argument('--margin', type=float, default=0.0, metavar='M',
                   help='clearance margin added to every sphere pair [m] (default 0)')
    p.add_argument('--mode', choices=MODES, default='fast',
                   help='fast (default); paper: the section-3 heuristic in joint accelerations '
                        '(Euler only; penalties, so limits may be exceeded a little)')
    p.add_argument('--t-f0', type=float, default=2.5, metavar='S',
                   help='paper mode: the final time it starts from and shortens [s] (default '
                        "2.5, the paper's; fast mode times its own start)")
    p.add_argument('--integrator', choices=('euler', 'rk4'), default='euler')
    p.add_argument('--N', type=int, default=100, metavar='N', help='intervals (default 100)')
    p.add_argument('--max-iterations', type=int, default=None, metavar='M')
    p.add_argument('--timeout', type=float, default=None, metavar='S',
                   help="wall-clock limit [s]; 0 = none (default: the node's solver.timeout, "
                        '60)')
    p.add_argument('--initial-guess', metavar='RESULT.json',
                   help='warm start from a result written by --json: its controls and final '
                        'time, rolled out from --start (resampled to N)')
    p.add_argument('--json', metavar='PATH', help='write the result as JSON to PATH')
    p.add_argument('--quiet', action='store_true', help='no summary')
    return p


def robot_key(args):
    """Return the arguments that make the robot of load_robot (a cache key)."""
    return (args.model, args.joints, tuple(args.locked), tuple(args.limit),
            args.collision_spheres, bool(args.self_collision))


def load_robot(args):
    """Return the ArmRobot (arm, collision spheres) of the arguments; ArmError if unusable."""
    from toc_ros.arm_config import limit_overrides, locked_values
    from toc_ros.core.arms import load_arm, load_spheres
    from toc_ros.core.arms.arm_solve import ArmRobot
    arm = load_arm(args.model, joints=args.joints, locked=locked_values(args.locked, '--locked'),
                   limits=limit_overrides(args.limit, '--limit') or None)
    if args.collision_spheres:
        return ArmRobot(arm, load_spheres(args.collision_spheres, arm), args.self_collision)
    return ArmRobot.shipped(arm, args.self_collision)


def goal_state(args, robot):
    """Return --goal, or the joint positions (at rest) that put the tip at --goal-pose."""
    from toc_ros.core.arms import solve_ik
    from toc_ros.core.arms.model import ArmError, tip_link
    if args.goal_pose is None:
        return tuple(args.goal)
    pose = list(args.goal_pose)
    if len(pose) not in (3, 7):
        raise ArmError(f'--goal-pose takes X Y Z [QX QY QZ QW], got {len(pose)} values')
    arm = robot.arm
    start = list(args.start)
    # A start of the wrong size is refused by the problem's checks; IK then starts unseeded.
    seed = start[:arm.n] if len(start) in (arm.n, 2 * arm.n) else None
    q = solve_ik(arm, tip_link(args.model, arm, args.tip), pose[:3], pose[3:] or None,
                 q_start=seed, spheres=robot.spheres, obstacles=args.sphere,
                 margin=args.margin)
    return tuple(float(v) for v in q)


def solver_options(args):
    """Return the SolverOptions of the arguments."""
    from toc_ros.core import SolverOptions
    from toc_ros.core.settings import parameter_table
    timeout = args.timeout
    if timeout is None:     # the node's default, so that no solve runs unbounded by default
        timeout = next(p.default for p in parameter_table(SolverOptions, 'solver.')
                       if p.name == 'solver.timeout')
    return SolverOptions(mode=args.mode, max_iterations=args.max_iterations,
                         timeout=timeout if timeout else None)


def build_arm_problem(args, robot=None):
    """
    (Problem, SolverOptions, arm) from the arguments; ArmError / ProblemError if unusable.

    robot: the ArmRobot of load_robot(args), when the caller keeps one (toc-sweep's workers
    load each arm once per process); the goal pose's IK uses its Pinocchio Data.
    """
    from toc_ros.core import Problem
    robot = load_robot(args) if robot is None else robot
    problem = Problem(x0=tuple(args.start), x_goal=goal_state(args, robot), model=robot,
                      obstacles=tuple(tuple(row) for row in args.sphere), margin=args.margin,
                      n_intervals=args.N, integrator=args.integrator, t_f0=args.t_f0)
    return problem, solver_options(args), robot.arm


def initial_guess(path):
    """Return (controls, t_f) of a --json result file, None without one; ValueError: why."""
    from toc_ros.core.result import guess_from_dict
    if not path:
        return None
    try:
        with open(path) as stream:
            return guess_from_dict(json.load(stream))
    except (OSError, ValueError) as exc:
        raise ValueError(f'--initial-guess {path}: {exc}') from None


def main(argv):
    """Run toc-solve for an arm; return the exit code."""
    from toc_ros.core import SolveResult, Status, warm_up_for
    args = build_parser().parse_args(argv)
    arm = None
    try:
        problem, options, arm = build_arm_problem(args)
        guess = initial_guess(args.initial_guess)
    except ValueError as exc:      # ArmError, ProblemError, an unusable --initial-guess
        result = SolveResult(status=Status.INVALID_INPUT, message=str(exc), mode='fast',
                             integrator=args.integrator)
    else:
        line = ProgressLine(sys.stderr, options.iteration_limit(), options.mode)
        show_progress = not args.quiet and sys.stderr.isatty()
        try:
            # --timeout limits the solve, not the one-time compile of the solver's kernels.
            warm_up_for(problem, options)
            result = solve_interruptible(problem, options, line if show_progress else None,
                                         guess)
        finally:
            line.clear()
    if result.status is Status.INVALID_INPUT:
        print(f'toc-solve: invalid problem: {result.message}', file=sys.stderr)
    elif not args.quiet:
        v = result.violations
        print(f'status      {result.status.value}\nmessage     {result.message}\n'
              f'model       {args.model} ({", ".join(arm.joint_names)})\n'
              f'mode        {result.mode}, {args.integrator}, N = {args.N}, '
              f'{len(args.sphere)} obstacle sphere(s), margin {args.margin} m\n'
              f't_min       {result.final_time:.6f} s\niterations  {result.iterations}\n'
              f'wall time   {result.wall_time_s:.3f} s\nviolations  '
              + json.dumps(v.as_dict()))
    if args.json:
        try:
            write_json(args.json, _with_joints(result, arm))
        except (OSError, ValueError) as exc:
            print(f'toc-solve: cannot write {args.json}: {exc}', file=sys.stderr)
            return EXIT_WRITE_ERROR
    return result.status.exit_code()


class _with_joints:   # noqa: N801 (a thin adapter, used like a function)
    """A result whose to_dict() also names the planned joints."""

    def __init__(self, result, arm):
        self.result = result
        self.arm = arm

    def to_dict(self):
        out = self.result.to_dict()
        out['joint_names'] = list(self.arm.joint_names) if self.arm is not None else []
        out['state_layout'] = 'positions then velocities'
        return out
