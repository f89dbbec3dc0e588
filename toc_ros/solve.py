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
toc-solve: solve one minimum-time problem from the command line (no ROS needed).

The scenario comes from a ROS 2 parameter file (default: the paper's, config/toc_ros.yaml);
command-line options override it.  Exit codes follow Status.exit_code(): 0 solved,
1 solved inaccurately, 2 no convergence (or bad arguments, from argparse), 3 canceled/timed
out, 4 invalid problem, 5 the --json file could not be written, 130 a second Ctrl-C.
"""

import argparse
import json
import math
import os
import sys

from toc_ros.cli_run import EXIT_INTERRUPTED, EXIT_WRITE_ERROR, ProgressLine, \
    solve_interruptible, write_json

# The solver (numba kernels) is imported after the arguments are parsed, so that --help and
# argument errors answer at once; toc_ros.config only reads the settings table.


def build_parser():
    """Argument parser of toc-solve."""
    parser = argparse.ArgumentParser(
        prog='toc-solve',
        description='Minimum-time trajectory of a robot model (default: the 2-DOF cylindrical '
                    'robot of the paper) around circular obstacles. SI units, radians.',
        epilog='Exit codes: 0 solved, 1 solved inaccurately (paper mode), 2 not converged or '
               'bad arguments, 3 canceled (Ctrl-C) or timed out, 4 invalid problem, '
               '5 --json not writable, 130 interrupted twice.')
    parser.add_argument('--config', metavar='FILE.yaml', default=None,
                        help='ROS 2 parameter file with the scenario (default: the paper '
                             "scenario, the package's config/toc_ros.yaml)")
    parser.add_argument('--mode', choices=('paper', 'fast'),
                        help='fast: feasible minimum time (default); paper: section-3 heuristic')
    parser.add_argument('--integrator', choices=('euler', 'rk4'))
    parser.add_argument('--N', type=int, metavar='N', help='number of intervals')
    parser.add_argument('--model', metavar='NAME|FILE',
                        help="robot model: 'cylindrical' (default), 'planar_2r' or a model file "
                             '(.yaml; a bare name is also looked up in config/models); sets '
                             'robot.model.  URDF arms: panda, ur5 or urdf:PATH, with options of '
                             'their own (--joints, --locked, --limit, --collision-spheres, '
                             '--sphere X Y Z R, --goal-pose ...): see toc-solve --model panda '
                             '--help')
    parser.add_argument('--param', action='append', metavar='NAME=VALUE',
                        help='model parameter, e.g. l1=0.9; repeat for several (added to '
                             'robot.model_parameters)')
    parser.add_argument('--gravity', type=float, metavar='G',
                        help='gravity [m/s^2] along -y of the base frame: the model parameter g '
                             '(refused for models without one, e.g. cylindrical)')
    parser.add_argument('--start', type=float, nargs='+', metavar='X',
                        help='start Q1 .. Qn [DQ1 .. DQn] for the n joints of the model '
                             '[rad or m, rad/s or m/s]; velocities 0 if omitted')
    parser.add_argument('--goal', type=float, nargs='+', metavar='X',
                        help='goal Q1 .. Qn [DQ1 .. DQn]; velocities 0 if omitted')
    obstacles = parser.add_mutually_exclusive_group()
    obstacles.add_argument('--obstacle', type=float, nargs=3, action='append',
                           metavar=('X', 'Y', 'RADIUS'),
                           help="circle [m]; repeat for several (replaces the config's)")
    obstacles.add_argument('--no-obstacles', action='store_true', help='solve without obstacles')
    parser.add_argument('--margin', type=float, metavar='DR',
                        help='clearance margin added to every radius [m]')
    parser.add_argument('--max-iterations', type=int, metavar='M',
                        help="iteration limit; 0 = the mode's default (paper: M = 30000)")
    parser.add_argument('--timeout', type=float, metavar='S',
                        help='wall-clock limit [s]; 0 = none (config default: 60)')
    parser.add_argument('--variant', choices=('eq37', 'eq36'),
                        help='sign of the A2/(2 A3) dq1^2 term: eq. (37) as printed or eq. (36)')
    parser.add_argument('--paper-gradient', choices=('shortcut', 'exact'),
                        help='paper mode obstacle gradient: eq. (46) shortcut or exact')
    parser.add_argument('--initial-guess', metavar='RESULT.json',
                        help='warm start (fast mode) from a result written by --json: its '
                             'controls and final time, resampled to N')
    parser.add_argument('--json', metavar='PATH', help='write the result as JSON to PATH')
    parser.add_argument('--quiet', action='store_true',
                        help='no progress line and no summary (errors still go to stderr)')
    _add_parameter_options(parser)
    return parser


PARAMETER_DEST = 'parameter:'
_TYPES = {'double': float, 'integer': int, 'string': str, 'double_array': float,
          'string_array': str}


def _bool(text):
    if text.lower() in ('true', '1', 'yes'):
        return True
    if text.lower() in ('false', '0', 'no'):
        return False
    raise argparse.ArgumentTypeError(f'expected true or false, got {text!r}')


def _add_parameter_options(parser):
    """One --<name> option per scenario parameter (the table of toc_ros.config)."""
    from toc_ros.config import SCENARIO_TABLE
    group = parser.add_argument_group(
        'scenario parameters', 'every parameter of the scenario file by its ROS name; '
        'overrides --config, the shortcuts above override these')
    for spec in SCENARIO_TABLE:
        text = spec.full_description()
        facts = [f'default {spec.default}']
        if spec.low is not None and spec.high is not None:
            facts.append(f'range [{spec.low:g}, {spec.high:g}]')
        kwargs = {'type': _bool if spec.ros_type == 'bool' else _TYPES[spec.ros_type],
                  'dest': PARAMETER_DEST + spec.name, 'default': None,
                  'help': f'{text} ({"; ".join(facts)})'.replace('%', '%%')}
        if spec.ros_type.endswith('_array'):
            kwargs.update(nargs='+', metavar='V')
        elif spec.choices:
            kwargs['choices'] = spec.choices
        else:
            kwargs['metavar'] = spec.ros_type.upper()
        group.add_argument(f'--{spec.name}', **kwargs)


def parameter_overrides(args):
    """Flat parameters given as --<name> options (name -> value)."""
    return {dest[len(PARAMETER_DEST):]: value for dest, value in vars(args).items()
            if dest.startswith(PARAMETER_DEST) and value is not None}


class ArgumentError(ValueError):
    """A command-line value that does not fit the model (exit code 2, like argparse)."""


def joint_state(name, values, n=2):
    """[Q1 .. Qn] or [Q1 .. Qn, DQ1 .. DQn] -> state (q1, dq1, ..., qn, dqn) (ArgumentError)."""
    if values is None:
        return None
    values = [float(v) for v in values]
    if len(values) == n:
        values = values + [0.0] * n
    elif len(values) != 2 * n:
        raise ArgumentError(f'--{name} takes Q1 .. Q{n} [DQ1 .. DQ{n}] ({n} or {2 * n} '
                            f'numbers for the {n} joints of the model), got {len(values)}')
    state = [0.0] * (2 * n)
    state[0::2], state[1::2] = values[:n], values[n:]
    return tuple(state)


def _joint_state(parser, name, values):
    """State of a two-joint model from --start/--goal, or None when another n may fit."""
    if values is None or len(values) not in (2, 4):
        return None
    return joint_state(name, values)


def parse_args(argv, parser=None):
    """Parse toc-solve's arguments (parser: one from build_parser(), to reuse it)."""
    parser = build_parser() if parser is None else parser
    args = parser.parse_args(argv)
    # Two-joint states now (both shipped models); other counts are checked against the model.
    args.x0 = _joint_state(parser, 'start', args.start)
    args.x_goal = _joint_state(parser, 'goal', args.goal)
    for entry in args.param or ():
        key, sep, value = entry.partition('=')
        if not sep or not key.strip() or not value.strip():
            parser.error(f'--param takes NAME=VALUE, got {entry!r}')
    if args.gravity is not None and not math.isfinite(args.gravity):
        parser.error(f'--gravity must be finite, got {args.gravity}')
    if args.timeout is not None and not (math.isfinite(args.timeout) and args.timeout >= 0.0):
        parser.error(f'--timeout must be >= 0 seconds, got {args.timeout}')
    if args.json:
        folder = os.path.dirname(os.path.abspath(args.json))
        if not os.path.isdir(folder):
            parser.error(f'--json: directory {folder} does not exist')
    args.guess = None
    if args.initial_guess:
        from toc_ros.core.result import guess_from_dict
        try:
            with open(args.initial_guess) as stream:
                args.guess = guess_from_dict(json.load(stream))
        except (OSError, ValueError) as exc:
            parser.error(f'--initial-guess {args.initial_guess}: {exc}')
    return args


_parse = parse_args


def model_parameter_names(model):
    """Names of a model's parameters (robot.model_parameters may set them)."""
    import dataclasses
    data = model.params
    if hasattr(data, 'as_dict'):
        return list(data.as_dict())
    return [f.name for f in dataclasses.fields(data)]


def _apply_model_options(args, params):
    """--model, --param, --gravity into params; the states of --start/--goal for its n."""
    from toc_ros.config import model_from_parameters
    if getattr(args, 'model', None):
        params['robot.model'] = args.model
    extra = list(getattr(args, 'param', None) or ())
    if extra:
        params['robot.model_parameters'] = list(params.get('robot.model_parameters') or ())
        params['robot.model_parameters'] += extra
    gravity = getattr(args, 'gravity', None)
    if gravity is None and args.start is None and args.goal is None:
        return None, None
    model = model_from_parameters(params)
    if gravity is not None:
        if 'g' not in model_parameter_names(model):
            raise ArgumentError(f'--gravity: robot model {model.name!r} has no gravity parameter '
                                f'g (its parameters: {", ".join(model_parameter_names(model))})')
        params['robot.model_parameters'] = list(params.get('robot.model_parameters') or ())
        params['robot.model_parameters'] += [f'g={gravity!r}']
    return (joint_state('start', args.start, model.n_joints),
            joint_state('goal', args.goal, model.n_joints))


def build_problem(args, parameters=None):
    """
    Build the Problem and SolverOptions from the parameter file plus the command-line overrides.

    parameters: the flat parameters of the file, already loaded (toc-sweep reads it once).
    Raises ProblemError when the file or a value in it is unusable, ArgumentError (exit code
    2) when --start, --goal or --gravity do not fit the model.
    """
    from toc_ros.config import (default_config_path, load_parameters, options_from_parameters,
                                problem_from_parameters)
    from toc_ros.core import ProblemError
    params = (load_parameters(args.config or default_config_path()) if parameters is None
              else dict(parameters))
    params.update(parameter_overrides(args))
    x0, x_goal = _apply_model_options(args, params)
    overrides = {'solver.mode': args.mode, 'solver.integrator': args.integrator,
                 'solver.N': args.N, 'solver.max_iterations': args.max_iterations,
                 'solver.timeout': args.timeout, 'obstacles.margin': args.margin,
                 'robot.model_variant': args.variant,
                 'solver.paper.obstacle_gradient': args.paper_gradient}
    params.update({k: v for k, v in overrides.items() if v is not None})
    obstacles = None
    if args.no_obstacles:
        obstacles = ()
    elif args.obstacle:
        obstacles = tuple(tuple(row) for row in args.obstacle)
    try:
        problem = problem_from_parameters(params, x0=x0, x_goal=x_goal, obstacles=obstacles)
        options = options_from_parameters(params)
    except (TypeError, ValueError, KeyError) as exc:
        # ProblemError is a ValueError; float('abc') and the like from a bad file land here too.
        raise ProblemError(str(exc) if isinstance(exc, ProblemError)
                           else f'bad value in the parameter file: {exc}')
    return problem, options


def summary(result, problem):
    """Short human-readable summary of a result."""
    v = result.violations
    lines = [f'status      {result.status.value}',
             f'message     {result.message}',
             f'model       {problem.robot_model.name}' + (
                 f', actuator lag {problem.robot_model.lag:g} s'
                 if getattr(problem.robot_model, 'lag', None) else ''),
             f'mode        {result.mode}, {problem.integrator}, N = {problem.n_intervals}, '
             f'{len(problem.obstacles)} obstacle(s), margin {problem.margin} m',
             f't_min       {_seconds(result.final_time)}',
             f'iterations  {result.iterations}',
             f'wall time   {result.wall_time_s:.3f} s']
    if result.has_trajectory:
        lines.append(f'violations  control excess {v.max_control_excess:.3g}, terminal error '
                     f'{v.terminal_error:.3g}, min clearance {v.min_clearance:.3g} m')
    return '\n'.join(lines)


def _seconds(value):
    return f'{value:.6f} s' if math.isfinite(value) else 'n/a (no trajectory)'


def main(argv=None):
    """Entry point of toc-solve; returns the process exit code."""
    from toc_ros import arm_cli
    arm_argv = sys.argv[1:] if argv is None else list(argv)
    try:
        if arm_cli.is_arm_model_name(arm_cli.requested_model(arm_argv)):
            return arm_cli.main(arm_argv)       # URDF arms: their own options (arm_cli.py)
        return _run(parse_args(argv))
    except KeyboardInterrupt:      # a second Ctrl-C, or one before the solve started
        print('toc-solve: interrupted', file=sys.stderr)
        return EXIT_INTERRUPTED


def _run(args):
    from toc_ros.core import ProblemError, SolveResult, Status, warm_up_for
    try:
        problem, options = build_problem(args)
    except ArgumentError as exc:
        build_parser().print_usage(sys.stderr)
        print(f'toc-solve: error: {exc}', file=sys.stderr)
        return 2
    except ProblemError as exc:
        result = SolveResult(status=Status.INVALID_INPUT, message=str(exc),
                             mode=args.mode or '', integrator=args.integrator or '')
        problem = None
    else:
        show_progress = not args.quiet and sys.stderr.isatty()
        line = ProgressLine(sys.stderr, options.iteration_limit(), options.mode)
        try:
            # --timeout limits the solve, not the one-time compile of a model's kernels.
            warm_up_for(problem, options)
            result = solve_interruptible(problem, options, line if show_progress else None,
                                         getattr(args, 'guess', None))
        finally:
            line.clear()
    if result.status is Status.INVALID_INPUT:
        print(f'toc-solve: invalid problem: {result.message}', file=sys.stderr)
    elif not args.quiet:
        print(summary(result, problem))
    if args.json:
        try:
            write_json(args.json, result)
        except (OSError, ValueError) as exc:
            print(f'toc-solve: cannot write {args.json}: {exc}', file=sys.stderr)
            return EXIT_WRITE_ERROR
    return result.status.exit_code()


if __name__ == '__main__':
    sys.exit(main())
