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
Cases -> toc-solve arguments -> Problem/SolverOptions, by the code path of toc-solve itself.

Arm specs (base.model panda, ur5 or urdf:PATH) go to arm_cases.py (its case_builder picks).
Every case becomes the argument list toc-solve would be given (base options, then the varied
values: start.*/goal.* as --start/--goal, obstacles.K.* as --obstacle rows, NAME.K as element K
of the array option --NAME, any other name as --NAME); toc_ros.solve parses it and builds the
Problem from the scenario file read once, here on the client while the spec is checked: the
tasks carry the built Problem/SolverOptions, the workers only solve.  A case is keyed by a
hash of its arguments (without the --config path) and the scenario parameters, so --resume
recognises it whatever the spec.
"""

import hashlib
import json
import math
import re
import shlex

import numpy as np

from .spec import SpecError

STATE_FIELDS = ('q1', 'q2', 'dq1', 'dq2', 'x', 'y')
OBSTACLE_FIELDS = ('x', 'y', 'radius')
COMPOSITE = ('start', 'goal', 'obstacle', 'no-obstacles', 'config')
REFUSED = ('json', 'quiet', 'help')
_OBSTACLE_NAME = re.compile(r'^obstacles\.(\d+)\.(\w+)$')
_ELEMENT_NAME = re.compile(r'^(.+)\.(\d+)$')


class CaseArgumentError(SpecError):
    """toc-solve refused a case's arguments."""


def raising(parser):
    """Return the parser, made to raise CaseArgumentError instead of exiting."""
    def error(message):
        raise CaseArgumentError(message)

    parser.error = error
    return parser


def toc_solve_parser():
    """toc-solve's own argument parser, raising CaseArgumentError instead of exiting."""
    from toc_ros.solve import build_parser
    return raising(build_parser())


def long_options(parser):
    """Long option name (without '--') -> argparse action."""
    return {opt[2:]: action for action in parser._actions for opt in action.option_strings
            if opt.startswith('--')}


def format_number(value):
    """Shortest text that parses back to the same float (no exponent: argparse-safe)."""
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return str(int(value))
    if isinstance(value, str):
        return value
    return np.format_float_positional(float(value), unique=True, trim='0')


def case_hash(argv, params):
    """16 hex digits of sha256 over the arguments (less --config) and the scenario values."""
    args = list(argv)
    if '--config' in args:
        k = args.index('--config')
        del args[k:k + 2]
    blob = json.dumps({'args': args, 'parameters': params}, sort_keys=True,
                      separators=(',', ':'), default=_jsonable)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _jsonable(value):
    if isinstance(value, (np.integer, np.floating)):
        return value.item()
    if isinstance(value, tuple):
        return list(value)
    raise TypeError(f'{value!r} is not JSON')


class CaseBuilder:
    """Turns the cases of a Sweep into toc-solve argument lists (checked on the client)."""

    is_arm = False

    def __init__(self, sweep):
        from toc_ros.config import default_config_path, load_parameters
        from toc_ros.core import ProblemError
        self.sweep = sweep
        self.parser = toc_solve_parser()
        self.options = long_options(self.parser)
        base = dict(sweep.base)
        self._check_base(base)
        self.config = base.pop('config', None)
        try:
            self.params = load_parameters(self.config or default_config_path())
        except ProblemError as exc:
            raise SpecError(f'{sweep.path}: base.config: {exc}')
        self.start = self._base_state(base.pop('start', None), 'start')
        self.goal = self._base_state(base.pop('goal', None), 'goal')
        rows = base.pop('obstacle', None)
        no_obstacles = bool(base.pop('no-obstacles', False))
        self.obstacles = None if rows is None and not no_obstacles else [
            list(map(float, r)) for r in (rows or [])]
        self.base = base
        self.kinds = {name: self._classify(name) for name in sweep.names}
        self._check_obstacle_axes()

    def report_options(self):
        """Keyword arguments of report.write_report: the arm offset a of the hand plane."""
        return {'a': float(self.params['robot.a'])}

    # -- checks ------------------------------------------------------------------------------

    def _error(self, message):
        raise SpecError(f'{self.sweep.path}: {message}')

    def _check_base(self, base):
        for name, value in base.items():
            if name in REFUSED or name not in self.options:
                self._error(f'base.{name}: not a toc-solve option usable in a sweep (see '
                            'toc-solve --help; json, quiet and help are not)')
            nargs = self.options[name].nargs
            if name == 'config':
                if not isinstance(value, str):
                    self._error(f'base.config must be a file name, got {value!r}')
            elif name == 'obstacle':
                if not isinstance(value, list) or not all(
                        isinstance(r, list) and len(r) == 3 and all(map(_number, r))
                        for r in value):
                    self._error('base.obstacle must be a list of [x, y, radius] rows, got '
                                f'{value!r}')
            elif nargs == 0:
                if not isinstance(value, bool):
                    self._error(f'base.{name} is a flag: true or false, got {value!r}')
            elif nargs == '+':
                if not isinstance(value, list) or not value or not all(
                        _number(v) or isinstance(v, str) for v in value):
                    self._error(f'base.{name} takes a list of values, got {value!r}')
            elif isinstance(value, (list, dict, bool)) or value is None:
                self._error(f'base.{name} takes one number or word, got {value!r}')
        if base.get('no-obstacles') and base.get('obstacle'):
            self._error('base: obstacle and no-obstacles exclude each other')

    def _base_state(self, values, name):
        if values is None:
            return None
        if not isinstance(values, list) or len(values) not in (2, 4) or not all(
                map(_number, values)):
            self._error(f'base.{name} takes [Q1, Q2] or [Q1, Q2, DQ1, DQ2], got {values!r}')
        values = [float(v) for v in values]
        return values + [0.0, 0.0] if len(values) == 2 else values

    def _classify(self, name):
        head, _, tail = name.partition('.')
        if head in ('start', 'goal') and tail:
            if tail not in STATE_FIELDS:
                self._error(f'{name}: {head}.* takes one of {", ".join(STATE_FIELDS)}')
            return ('state', head, tail)
        match = _OBSTACLE_NAME.match(name)
        if match:
            if match.group(2) not in OBSTACLE_FIELDS:
                self._error(f'{name}: obstacles.K.* takes one of {", ".join(OBSTACLE_FIELDS)}')
            return ('obstacle', int(match.group(1)), match.group(2))
        if name in COMPOSITE or name in REFUSED:
            self._error(f'{name} cannot be varied as a whole: vary start.q1 ..., goal.x ..., '
                        'obstacles.K.x ... instead' if name in COMPOSITE
                        else f'{name} cannot be varied')
        if name in self.options:
            if self.options[name].nargs == '+':
                self._error(f'{name} takes a list: vary its elements as {name}.0, {name}.1 ...')
            if self.options[name].nargs == 0:
                self._error(f'{name} is a flag and cannot be varied')
            return ('option', name)
        match = _ELEMENT_NAME.match(name)
        if match and match.group(1) in self.options and (
                self.options[match.group(1)].nargs == '+'):
            option = match.group(1)
            if option not in self.base and option not in self.params:
                self._error(f'{name}: --{option} has no base value (give base.{option})')
            return ('element', option, int(match.group(2)))
        self._error(f'unknown name {name!r}: not a toc-solve long option (toc-solve --help), '
                    'nor start.{q1,q2,dq1,dq2,x,y}, goal.{...}, obstacles.K.{x,y,radius}, '
                    'OPTION.K')

    def _check_obstacle_axes(self):
        base_rows = len(self._base_obstacles())
        fields = {}
        for kind in self.kinds.values():
            if kind[0] == 'obstacle':
                fields.setdefault(kind[1], set()).add(kind[2])
        for k, have in sorted(fields.items()):
            if k >= base_rows and have != set(OBSTACLE_FIELDS):
                self._error(f'obstacles.{k}: the base has {base_rows} obstacle(s), so a new '
                            f'obstacle {k} needs x, y and radius varied, got '
                            f'{", ".join(sorted(have))}')
            if k > base_rows and k - 1 not in fields:
                self._error(f'obstacles.{k}: obstacle {k - 1} is missing (indices must follow '
                            f"the base's {base_rows} obstacle(s) without gaps)")
        for kind in self.kinds.values():
            if kind[0] == 'state':
                fields_of = {k[2] for k in self.kinds.values() if k[:2] == kind[:2]}
                if fields_of & {'x', 'y'}:
                    if not {'x', 'y'} <= fields_of:
                        self._error(f'{kind[1]}.x and {kind[1]}.y (hand position) must be '
                                    'varied together')
                    if fields_of & {'q1', 'q2'}:
                        self._error(f'{kind[1]}.x/y (hand position) and {kind[1]}.q1/q2 '
                                    'exclude each other')

    # -- arguments ---------------------------------------------------------------------------

    def _base_obstacles(self):
        if self.obstacles is not None:
            return [list(r) for r in self.obstacles]
        from toc_ros.config import obstacle_rows
        return [list(r) for r in obstacle_rows(self.params)]

    def _state(self, which, opts, changed):
        base = self.start if which == 'start' else self.goal
        if base is None:
            name = 'initial_state' if which == 'start' else 'goal_state'
            q1, dq1, q2, dq2 = [float(v) for v in opts.get(name, self.params[name])]
            base = [q1, q2, dq1, dq2]
        elif not changed:
            return base
        state = list(base)
        if 'x' in changed:
            a = float(opts.get('robot.a', self.params['robot.a']))
            x, y = float(changed['x']), float(changed['y'])
            state[0], state[1] = math.atan2(y, x), math.hypot(x, y) - a
        for k, f in enumerate(('q1', 'q2', 'dq1', 'dq2')):
            if f in changed:
                state[k] = changed[f]
        return state

    def argv(self, values):
        """toc-solve arguments of one case ({name: value} of the varied names)."""
        opts = {k: list(v) if isinstance(v, list) else v for k, v in self.base.items()}
        states = {'start': {}, 'goal': {}}
        obstacle_changes = {}
        for name, value in values.items():
            kind = self.kinds[name]
            if kind[0] == 'option':
                opts[name] = value
            elif kind[0] == 'element':
                option, k = kind[1], kind[2]
                if option not in opts:
                    opts[option] = list(self.params[option])
                if k >= len(opts[option]):
                    raise CaseArgumentError(f'{name}: --{option} has only '
                                            f'{len(opts[option])} value(s)')
                opts[option][k] = value
            elif kind[0] == 'state':
                states[kind[1]][kind[2]] = value
            else:
                obstacle_changes[(kind[1], kind[2])] = value
        argv = ['--config', self.config] if self.config else []
        for name, value in opts.items():
            nargs = self.options[name].nargs
            if nargs == 0:
                argv += [f'--{name}'] if value else []
            elif nargs == '+':
                argv += [f'--{name}'] + [format_number(v) for v in value]
            else:
                argv += [f'--{name}', format_number(value)]
        for which in ('start', 'goal'):
            base = self.start if which == 'start' else self.goal
            if base is not None or states[which]:
                state = self._state(which, opts, states[which])
                argv += [f'--{which}'] + [format_number(v) for v in state]
        if self.obstacles is not None or obstacle_changes:
            rows = self._base_obstacles()
            for (k, f), value in sorted(obstacle_changes.items()):
                while k >= len(rows):
                    rows.append([math.nan] * 3)
                rows[k][OBSTACLE_FIELDS.index(f)] = value
            if rows:
                for row in rows:
                    argv += ['--obstacle'] + [format_number(v) for v in row]
            else:
                argv += ['--no-obstacles']
        return argv

    def cases(self):
        """
        Check and build every case: [(case_id, argv, values, problem, options)].

        SpecError, before anything is solved, for arguments toc-solve refuses, options that do
        not validate, duplicate cases, or when every case is an invalid problem.
        """
        from toc_ros.core import ProblemError
        from toc_ros.solve import ArgumentError, build_problem, parse_args
        out = []
        seen = {}
        n_invalid = 0
        first_invalid = None
        for index, values in enumerate(self.sweep.cases()):
            where = f'case {index} ({_describe(values)})'
            try:
                argv = self.argv(values)
                args = parse_args(argv, self.parser)
            except CaseArgumentError as exc:
                self._error(f'{where}: toc-solve refuses its arguments: {exc}')
            try:
                problem, options = build_problem(args, self.params)
                options.validate()
            except (ProblemError, ArgumentError) as exc:
                self._error(f'{where}: {exc}')
            try:
                problem.validate()
            except ProblemError as exc:      # a result row (INVALID_INPUT), unless all are
                n_invalid += 1
                first_invalid = first_invalid or f'{where}: {exc}'
            case_id = case_hash(argv, self.params)
            if case_id in seen:
                self._error(f'{where} is the same case as case {seen[case_id]}')
            seen[case_id] = index
            out.append((case_id, argv, values, problem, options))
        if out and n_invalid == len(out):
            self._error(f'every case is an invalid problem, e.g. {first_invalid}')
        return out


def _number(value):
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(
        value)


def _describe(values):
    return ', '.join(f'{k}={v}' for k, v in values.items()) or 'the base scenario'


def command_line(argv):
    """Return the case as a toc-solve shell command line."""
    return shlex.join(['toc-solve'] + list(argv))
