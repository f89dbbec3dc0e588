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
Cases of an arm sweep (base.model panda, ur5 or urdf:PATH) -> arguments of toc-solve for arms.

Varied names: goal_pose.{x,y,z} (the tip target's position; an orientation comes from
base.goal-pose), spheres.K.{x,y,z,radius} (sphere K of base.sphere), start.qK / start.dqK and
goal.qK / goal.dqK (K = 1..n, elements of base.start / base.goal), and any scalar option of
the arm's toc-solve (N, margin, tip, max-iterations, timeout, integrator).  One arm per spec:
model, joints, locked, collision-spheres and self-collision come from the base.

Unlike a planar case, an arm case goes to the workers as its arguments only, and each worker
builds the problem with toc-solve's own functions (arm_cli.build_arm_problem, one loaded arm
per process and thread): a pose goal's inverse kinematics costs milliseconds to a tenth of a
second per case, worth spreading over the workers, and a Pinocchio model per case would be
heavy to ship.  An unreachable target is therefore an INVALID_INPUT row with IK's reason.
Here, before anything is solved, the arm is loaded once and every case's arguments go through
the arm's own parser.
"""

import math
import re
import threading
import time

from toc_ros import arm_cli

from .cases import (case_hash, CaseArgumentError, CaseBuilder, format_number, long_options,
                    raising)
from .spec import SpecError

POSE_FIELDS = ('x', 'y', 'z')
SPHERE_FIELDS = ('x', 'y', 'z', 'radius')
REFUSED = ('json', 'quiet', 'help')
# Options that make the arm (one per spec) or that only the base can give as a whole.
ROBOT = ('model', 'joints', 'locked', 'collision-spheres', 'self-collision')
WHOLE = ('start', 'goal', 'goal-pose', 'sphere')
_SPHERE_NAME = re.compile(r'^spheres\.(\d+)\.(\w+)$')
_JOINT_NAME = re.compile(r'^(start|goal)\.(d?q)(\d+)$')
_LOCAL = threading.local()      # the workers' loaded arms: Pinocchio's Data is per thread


def is_arm_case(argv):
    """Return True when a case's arguments name a URDF arm (as toc-solve routes them)."""
    return arm_cli.is_arm_model_name(arm_cli.requested_model(argv))


def _number(value):
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(
        value)


class ArmCaseBuilder:
    """Turns the cases of an arm Sweep into toc-solve arguments (checked on the client)."""

    is_arm = True

    def __init__(self, sweep):
        self.sweep = sweep
        self.parser = raising(arm_cli.build_parser())
        self.options = long_options(self.parser)
        self.base = dict(sweep.base)
        self._check_base()
        self.robot = self._load_robot()
        self.n = self.robot.arm.n
        self._check_base_vectors()
        self.kinds = {name: self._classify(name) for name in sweep.names}
        self._check_goal_axes()

    def _error(self, message):
        raise SpecError(f'{self.sweep.path}: {message}')

    def report_options(self):
        """Keyword arguments of report.write_report for this sweep."""
        return {'arm': True}

    # -- checks ------------------------------------------------------------------------------

    def _check_base(self):
        for name, value in self.base.items():
            if name in REFUSED or name not in self.options:
                self._error(f'base.{name}: not an option of toc-solve for arms usable in a '
                            'sweep (toc-solve --model panda --help; json, quiet and help are '
                            'not)')
            nargs = self.options[name].nargs
            if name == 'sphere':
                if not isinstance(value, list) or not all(
                        isinstance(r, list) and len(r) == 4 and all(map(_number, r))
                        for r in value):
                    self._error('base.sphere must be a list of [x, y, z, radius] rows, got '
                                f'{value!r}')
            elif name == 'locked':
                if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
                    self._error(f'base.locked must be a list of NAME=VALUE, got {value!r}')
            elif nargs == 0:
                if not isinstance(value, bool):
                    self._error(f'base.{name} is a flag: true or false, got {value!r}')
            elif nargs == '+':
                if not isinstance(value, list) or not value or not all(map(_number, value)):
                    self._error(f'base.{name} takes a list of numbers, got {value!r}')
            elif isinstance(value, (list, dict, bool)) or value is None:
                self._error(f'base.{name} takes one number or word, got {value!r}')
        if 'start' not in self.base:
            self._error('base.start is required (toc-solve --start Q1 .. Qn of the arm)')
        if 'goal' in self.base and 'goal-pose' in self.base:
            self._error('base: goal (joints) and goal-pose (tip target) exclude each other')

    def _load_robot(self):
        """Load the spec's arm by toc-solve's own parser and loader; SpecError if unusable."""
        from toc_ros.core.arms.model import ArmError
        argv = self._robot_argv() + ['--start', '0', '--goal', '0']   # placeholders
        try:
            return arm_cli.load_robot(self.parser.parse_args(argv))
        except CaseArgumentError as exc:
            self._error(f'base: toc-solve refuses the arm options: {exc}')
        except ArmError as exc:
            self._error(f'base: {exc}')

    def _check_base_vectors(self):
        for name in ('start', 'goal'):
            if name in self.base and len(self.base[name]) not in (self.n, 2 * self.n):
                self._error(f'base.{name} takes the {self.n} joint positions of the arm '
                            f'(then optionally {self.n} velocities), got '
                            f'{len(self.base[name])} values')
        if 'goal-pose' in self.base and len(self.base['goal-pose']) not in (3, 7):
            self._error('base.goal-pose takes [X, Y, Z] or [X, Y, Z, QX, QY, QZ, QW], got '
                        f'{len(self.base["goal-pose"])} values')
        from toc_ros.core.arms.model import ArmError, tip_link
        arm = self.robot.arm
        try:            # the tip link must exist even while no case gives a pose goal yet
            arm.frame_id(tip_link(self.base['model'], arm, self.base.get('tip')))
        except ArmError as exc:
            self._error(f'base.tip: {exc}')

    def _classify(self, name):
        head, _, tail = name.partition('.')
        if head == 'goal_pose':
            if tail not in POSE_FIELDS:
                self._error(f'{name}: goal_pose.* takes one of {", ".join(POSE_FIELDS)} (the '
                            "tip target's position; its orientation comes from "
                            'base.goal-pose)')
            return ('pose', POSE_FIELDS.index(tail))
        match = _SPHERE_NAME.match(name)
        if match:
            k, field = int(match.group(1)), match.group(2)
            if field not in SPHERE_FIELDS:
                self._error(f'{name}: spheres.K.* takes one of {", ".join(SPHERE_FIELDS)}')
            count = len(self.base.get('sphere', []))
            if k >= count:
                self._error(f'{name}: base.sphere has {count} sphere(s), so there is no '
                            f'sphere {k} to vary (give it in base.sphere)')
            return ('sphere', k, SPHERE_FIELDS.index(field))
        match = _JOINT_NAME.match(name)
        if match:
            which, kind, k = match.group(1), match.group(2), int(match.group(3))
            if not 1 <= k <= self.n:
                self._error(f'{name}: the arm has {self.n} joints ({which}.q1 .. '
                            f'{which}.q{self.n}, {which}.dq1 .. {which}.dq{self.n})')
            return ('joint', which, k - 1 + (self.n if kind == 'dq' else 0))
        if head in ('start', 'goal') or head == 'obstacles':
            self._error(f'{name}: an arm sweep varies start.qK/dqK, goal.qK/dqK (K = 1..'
                        f'{self.n}), goal_pose.{{x,y,z}} and spheres.K.{{x,y,z,radius}}')
        if name in ROBOT:
            self._error(f'{name} cannot be varied: one arm per spec (give it in base)')
        if name in WHOLE:
            self._error(f'{name} cannot be varied as a whole: vary goal_pose.x ..., '
                        'spheres.K.x ..., start.q1 ..., goal.q1 ... instead')
        if name in REFUSED or name not in self.options:
            self._error(f'unknown name {name!r} for an arm sweep: not an option of toc-solve '
                        'for arms, nor start.qK/dqK, goal.qK/dqK, goal_pose.{x,y,z}, '
                        'spheres.K.{x,y,z,radius}')
        if self.options[name].nargs == 0:
            self._error(f'{name} is a flag and cannot be varied')
        return ('option', name)

    def _check_goal_axes(self):
        kinds = self.kinds.values()
        pose = {k[1] for k in kinds if k[0] == 'pose'}
        joints = any(k[:2] == ('joint', 'goal') for k in kinds)
        if pose and joints:
            self._error('goal_pose.* (tip target) and goal.qK (joint goal) exclude each other')
        if pose and 'goal' in self.base:
            self._error('goal_pose.* vary a tip target, but base.goal is a joint goal: give '
                        'base.goal-pose instead (or no goal and vary x, y and z)')
        if pose and 'goal-pose' not in self.base and len(pose) != 3:
            self._error('goal_pose.x, goal_pose.y and goal_pose.z must all be varied when '
                        'base.goal-pose does not give the rest')
        if joints and 'goal' not in self.base:
            self._error('goal.qK vary a joint goal: give base.goal (the joints not varied)')
        if not pose and 'goal' not in self.base and 'goal-pose' not in self.base:
            self._error('no goal: give base.goal (joints) or base.goal-pose (tip target), or '
                        'vary goal_pose.x/y/z')

    # -- arguments ---------------------------------------------------------------------------

    def _robot_argv(self):
        argv = []
        for name in ROBOT:
            value = self.base.get(name)
            if name == 'locked':
                for entry in value or ():
                    argv += ['--locked', entry]
            elif name == 'self-collision':
                argv += ['--self-collision'] if value else []
            elif value is not None:
                argv += [f'--{name}', format_number(value)]
        return argv

    def argv(self, values):
        """toc-solve arguments of one case ({name: value} of the varied names)."""
        opts = {k: v for k, v in self.base.items() if k not in ROBOT + WHOLE}
        start = list(self.base['start'])
        goal = list(self.base['goal']) if 'goal' in self.base else None
        pose = list(self.base.get('goal-pose', [math.nan] * 3))
        spheres = [list(row) for row in self.base.get('sphere', [])]
        for name, value in values.items():
            kind = self.kinds[name]
            if kind[0] == 'option':
                opts[name] = value
            elif kind[0] == 'pose':
                pose[kind[1]] = value
            elif kind[0] == 'sphere':
                spheres[kind[1]][kind[2]] = value
            else:
                vector = start if kind[1] == 'start' else goal
                if kind[2] >= len(vector):          # a velocity of a positions-only vector
                    vector += [0.0] * (2 * self.n - len(vector))
                vector[kind[2]] = value
        argv = self._robot_argv()
        for name, value in opts.items():
            if self.options[name].nargs == 0:
                argv += [f'--{name}'] if value else []
            else:
                argv += [f'--{name}', format_number(value)]
        argv += ['--start'] + [format_number(v) for v in start]
        if goal is not None:
            argv += ['--goal'] + [format_number(v) for v in goal]
        else:
            argv += ['--goal-pose'] + [format_number(v) for v in pose]
        for row in spheres:
            argv += ['--sphere'] + [format_number(v) for v in row]
        return argv

    def cases(self):
        """
        Check every case: [(case_id, argv, values, None, None)] (the workers build problems).

        SpecError, before anything is solved, for arguments toc-solve refuses, solver options
        that do not validate, an unknown tip link, or duplicate cases.
        """
        from toc_ros.core import ProblemError
        from toc_ros.core.arms.model import ArmError, tip_link
        out, seen = [], {}
        arm = self.robot.arm
        for index, values in enumerate(self.sweep.cases()):
            where = f'case {index} ({_describe(values)})'
            argv = self.argv(values)
            try:
                args = self.parser.parse_args(argv)
            except CaseArgumentError as exc:
                self._error(f'{where}: toc-solve refuses its arguments: {exc}')
            try:
                arm_cli.solver_options(args).validate()
                if args.goal_pose is not None:
                    arm.frame_id(tip_link(args.model, arm, args.tip))
            except (ProblemError, ArmError) as exc:
                self._error(f'{where}: {exc}')
            case_id = case_hash(argv, {})
            if case_id in seen:
                self._error(f'{where} is the same case as case {seen[case_id]}')
            seen[case_id] = index
            out.append((case_id, argv, values, None, None))
        return out


def _describe(values):
    return ', '.join(f'{k}={v}' for k, v in values.items()) or 'the base scenario'


# -- on the workers ---------------------------------------------------------------------------

def build_case(argv):
    """
    Return (problem, options, guess) of an arm case, built as toc-solve builds it.

    ValueError (ArmError, ProblemError, refused arguments) with the reason when the case is
    not a problem, e.g. an unreachable tip target.  The first problem of each arm in a process
    warms its solver kernels, so that the loading stays out of the row's solve time; the
    cases until then (loading, IK, warm-up) count as warm-up time (warm_up_seconds).
    """
    from toc_ros.core import warm_up_for
    args = raising(arm_cli.build_parser()).parse_args(argv)
    _local()
    key = arm_cli.robot_key(args)
    started = time.perf_counter()
    warming = key not in _LOCAL.warm      # until a problem of this arm has warmed its kernels
    try:
        if key not in _LOCAL.robots:
            _LOCAL.robots[key] = arm_cli.load_robot(args)
        problem, options, _ = arm_cli.build_arm_problem(args, _LOCAL.robots[key])
        guess = arm_cli.initial_guess(args.initial_guess)
        if key not in _LOCAL.warm:
            warm_up_for(problem, options)
            _LOCAL.warm.add(key)
    finally:
        if warming:     # numba kernels compile or load here: minutes on a cold cache
            _LOCAL.warm_s += time.perf_counter() - started
    return problem, options, guess


def _local():
    if not hasattr(_LOCAL, 'robots'):
        _LOCAL.robots, _LOCAL.warm, _LOCAL.warm_s = {}, set(), 0.0
    return _LOCAL


def warm_up_seconds():
    """Return the seconds this thread spent loading arms and warming their kernels."""
    return _local().warm_s


def arm_columns(problem, result):
    """Return the arm rows' own columns: goal_q (the solver's goal), final_q (last state)."""
    if problem is None:
        return {'goal_q': None, 'final_q': None}
    n = problem.model.arm.n
    states = getattr(result, 'states', None)
    final = None
    if states is not None and len(states):
        final = [float(v) for v in states[-1][:n]]
    return {'goal_q': [float(v) for v in problem.x_goal[:n]], 'final_q': final}


def case_builder(sweep):
    """Return the builder of a sweep's cases: ArmCaseBuilder when base.model is an arm."""
    if arm_cli.is_arm_model_name(sweep.base.get('model')):
        return ArmCaseBuilder(sweep)
    return CaseBuilder(sweep)
