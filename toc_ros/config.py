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
The scenario file (config/toc_ros.yaml, a ROS 2 parameter file) <-> core Problem/options.

One mapping from flat parameter names ('robot.a', 'solver.N', ...) to the core types, used by
toc-solve and by the nodes (whose ROS parameters carry the same names).
"""

from dataclasses import asdict, dataclass, replace
import functools
import os
import sys
import textwrap
from typing import Tuple

import yaml

from . import arm_config
from .core.model import RobotParams
from .core.models import load_model, ModelChoice, ModelError, with_actuator_lag
from .core.problem import Problem, ProblemError, SolverOptions
from .core.settings import from_parameters, parameter_table, setting


@dataclass(frozen=True)
class Frames:
    """Names the nodes and the scenario file share (not part of the numeric problem)."""

    joint_names: Tuple[str, ...] = setting(
        ('rotation_joint', 'extension_joint'), 'one name per joint of robot.model (cylindrical: '
        'rotation, extension; planar_2r: shoulder, elbow), used in joint_states, goals and '
        'trajectories')
    base_frame: str = setting(
        'base_link', 'frame of goal poses, planned paths and markers (the robot base)')


# The scenario's settings: (dataclass, prefix of its flat names).  The flat names are the ROS
# parameter names of the nodes; each field's setting() in the core is the one definition.
SCENARIO = ((Frames, ''), (Problem, ''), (ModelChoice, 'robot.'), (RobotParams, 'robot.'),
            (SolverOptions, 'solver.'))
# What the nodes do with a core setting, added to its description (the core says what the
# value is; these say where it comes from on ROS).
NODE_NOTES = {
    'initial_state': ' while no joint_states arrived (plant: state at start-up and after '
                     '~/reset)',
    'goal_state': ' of the scenario file (toc-solve); the node plans to goals from goal_pose, '
                  'goal_joints and ~/plan',
}
NODE_NOTES.update(dict.fromkeys(
    ('obstacles.x', 'obstacles.y', 'obstacles.radius'),
    '; set them together (atomically) or publish on the obstacles topic'))


def _scenario_table():
    """Return the flat parameters of SCENARIO: robot.* between obstacles.* and solver.*."""
    table = []
    for cls, prefix in SCENARIO:
        for p in parameter_table(cls, prefix):
            note = NODE_NOTES.get(p.name, '')
            table.append(replace(p, description=p.description + note) if note else p)
    robot = [p for p in table if p.name.startswith('robot.')]
    rest = [p for p in table if not p.name.startswith('robot.')]
    first = next(k for k, p in enumerate(rest) if p.name.startswith('solver.'))
    return tuple(rest[:first] + robot + rest[first:])


SCENARIO_TABLE = _scenario_table()
# Flat parameter name -> default; the defaults are the paper's scenario (Problem.paper()).
DEFAULTS = {p.name: p.default for p in SCENARIO_TABLE}

YAML_HEADER = """\
# The paper's scenario (Kasac & Novakovic, section 4): a 2-DOF cylindrical robot (rotation q1,
# extension q2) moves from q = (pi/12 rad, 1 m) to (5 pi/12 rad, 1 m) at rest, around a circle
# of radius 0.2 m at (1 m, 1 m) with clearance margin 0.01 m, |u1| <= 600 N m, |u2| <= 500 N.
# ROS 2 parameter file (ros2 run toc_ros solver_node --ros-args --params-file ...); the CLI
# toc-solve reads the same file. SI units and radians throughout; x forward, y left (REP-103).
# Generated from the settings of the core dataclasses: python -m toc_ros.config --write
"""


def default_config_path(name='toc_ros.yaml'):
    """config/<name> from the installed share directory, else from the source tree."""
    try:
        from ament_index_python.packages import get_package_share_directory
        path = os.path.join(get_package_share_directory('toc_ros'), 'config', name)
        if os.path.isfile(path):
            return path
    except (ImportError, LookupError, OSError):
        pass    # no ament index, or toc_ros not in it: fall back to the source tree
    return os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                        'config', name)


def _flatten(tree, prefix=''):
    flat = {}
    for key, value in tree.items():
        name = f'{prefix}{key}'
        if isinstance(value, dict):
            flat.update(_flatten(value, name + '.'))
        else:
            flat[name] = value
    return flat


def load_parameters(path=None, node_name='solver_node'):
    """Flat parameters from a ROS 2 parameter file ('/**' and node_name sections merged)."""
    path = path or default_config_path()
    try:
        with open(path) as stream:
            doc = yaml.safe_load(stream) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise ProblemError(f'cannot read parameter file {path}: {exc}')
    params = dict(DEFAULTS)
    for section in ('/**', node_name, '/' + node_name):
        body = doc.get(section, {}) if isinstance(doc, dict) else {}
        if isinstance(body, dict) and isinstance(body.get('ros__parameters'), dict):
            params.update(_flatten(body['ros__parameters']))
    return params


def obstacle_rows(params):
    """(x, y, radius) rows from the equal-length obstacles.* arrays."""
    try:
        return from_parameters(Problem, params).obstacles
    except (TypeError, ValueError) as exc:
        raise ProblemError(str(exc))


def robot_from_parameters(params):
    """Build the RobotParams from flat parameters (ProblemError for a wrong array size)."""
    try:
        return from_parameters(RobotParams, params, 'robot.')
    except ValueError as exc:      # e.g. robot.u_max with 3 entries
        raise ProblemError(str(exc))


def model_search_path():
    """Return the folders searched for a bare model file name (share, then source tree)."""
    folders = []
    try:
        from ament_index_python.packages import get_package_share_directory
        folders.append(os.path.join(get_package_share_directory('toc_ros'), 'config',
                                    'models'))
    except (ImportError, LookupError, OSError):
        pass    # no ament index, or toc_ros not in it: the source tree only
    folders.append(os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                                'config', 'models'))
    return folders


def resolve_model_name(name):
    """Return a built-in model name as is, a model file as a path (ProblemError if absent)."""
    from .core.models import MODELS
    name = str(name).strip()
    if name in MODELS:
        return name
    expanded = os.path.expanduser(name)
    if os.path.isfile(expanded):
        return os.path.abspath(expanded)
    if os.sep not in name:
        for folder in model_search_path():
            path = os.path.join(folder, name)
            if os.path.isfile(path):
                return path
    if expanded.lower().endswith(('.yaml', '.yml')) or os.sep in name:
        raise ProblemError(f'robot.model: no model file {name!r} (looked in the working '
                           'directory' + ('' if os.sep in name else ' and '
                                          + ', '.join(model_search_path())) + ')')
    raise ProblemError(f'robot.model: unknown model {name!r}: the built-in models are '
                       f'{", ".join(sorted(MODELS))}, or give a model file (.yaml)')


@functools.lru_cache(maxsize=32)
def _cached_model(key, stamp, values):
    try:
        return load_model(key, **dict(values))
    except ModelError as exc:
        raise ProblemError(f'robot.model {key}: {exc}')


def model_choice(params):
    """Return the ModelChoice of flat parameters (ProblemError for a bad value)."""
    try:
        choice = from_parameters(ModelChoice, params, 'robot.')
        choice.parameter_values()
    except (ModelError, TypeError, ValueError) as exc:
        raise ProblemError(str(exc))
    return choice


def _cylindrical(robot, values):
    """Return robot with the robot.model_parameters overrides (not yet validated)."""
    known = {name: getattr(robot, name) for name in asdict(robot)}
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise ProblemError(f"model 'cylindrical' has no parameter(s) {', '.join(unknown)} "
                           f"(known: {', '.join(known)})")
    converted = {}
    for name, text in values.items():
        try:
            converted[name] = text if isinstance(known[name], str) else float(text)
        except ValueError:
            raise ProblemError(f"model 'cylindrical': parameter {name} must be a number, got "
                               f'{text!r}') from None
    return replace(robot, **converted)


def model_from_parameters(params):
    """
    Return the RobotModel of flat parameters (robot.model, robot.model_parameters, robot.*).

    Built once per (model, parameters, file modification time): a model file is derived and
    compiled at its first use.  Raises ProblemError with the reason for a bad model.  A URDF
    arm (robot.model panda, ur5 or urdf) is toc_ros.arm_config's.
    """
    if arm_config.is_arm(params):
        return arm_config.arm_model(params)
    choice = model_choice(params)
    model = _joint_model(choice, params)
    try:
        return with_actuator_lag(model, choice.actuator_lag)
    except ModelError as exc:
        raise ProblemError(f'robot.actuator_lag: {exc}')


def _joint_model(choice, params):
    from .core.models import CylindricalRobot
    values = choice.parameter_values()
    key = resolve_model_name(choice.name)
    if key == 'cylindrical':
        return CylindricalRobot(_cylindrical(robot_from_parameters(params), values))
    try:
        stamp = os.stat(key).st_mtime_ns if os.path.isfile(key) else 0
        return _cached_model(key, stamp, tuple(sorted(values.items())))
    except (OSError, TypeError, ValueError) as exc:
        if isinstance(exc, ProblemError):
            raise
        raise ProblemError(f'robot.model {choice.name}: {exc}')


def problem_from_parameters(params, x0=None, x_goal=None, obstacles=None):
    """Problem from flat parameters; x0, x_goal, obstacles override the parameter values."""
    if arm_config.is_arm(params):
        return arm_config.arm_problem(params, x0, x_goal, obstacles)
    overrides = {k: tuple(float(v) for v in value)
                 for k, value in (('x0', x0), ('x_goal', x_goal)) if value is not None}
    if obstacles is not None:
        overrides['obstacles'] = tuple(tuple(row) for row in obstacles)
    try:
        problem = from_parameters(Problem, params, **overrides)
    except ValueError as exc:
        if isinstance(exc, ProblemError):
            raise
        raise ProblemError(str(exc))
    return problem.with_model(model_from_parameters(params))


def options_from_parameters(params):
    """Build the SolverOptions (timeout 0: no limit; max_iterations 0: mode default)."""
    try:
        return from_parameters(SolverOptions, params, 'solver.')
    except ValueError as exc:
        if isinstance(exc, ProblemError):
            raise
        raise ProblemError(str(exc))


def _yaml_value(value):
    if isinstance(value, (list, tuple)):
        return '[' + ', '.join(_yaml_value(v) for v in value) + ']'
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, float):
        text = repr(value)
        mantissa, _, exponent = text.partition('e')
        if exponent and '.' not in mantissa:      # YAML 1.1 needs the dot: 1.0e-05
            text = f'{mantissa}.0e{exponent}'
        return text
    return str(value)


def parameter_comment(parameter):
    """One-line explanation of a parameter: unit, description, choices (YAML and --help)."""
    return parameter.full_description()


def scenario_yaml(table=SCENARIO_TABLE):
    """Text of config/toc_ros.yaml: every scenario parameter with its default and comment."""
    lines = [YAML_HEADER.rstrip('\n'), '/**:', '  ros__parameters:']
    opened = []
    previous = None
    for parameter in table:
        *groups, key = parameter.name.split('.')
        common = 0
        while common < min(len(opened), len(groups)) and opened[common] == groups[common]:
            common += 1
        opened = opened[:common]
        for group in groups[common:]:
            lines.append('    ' + '  ' * len(opened) + f'{group}:')
            opened.append(group)
        indent = '    ' + '  ' * len(opened)
        comment = parameter_comment(parameter)
        if comment != previous:      # columns of one setting share their comment
            lines += [f'{indent}# {text}' for text in textwrap.wrap(comment, 97 - len(indent))]
        previous = comment
        lines.append(f'{indent}{key}: {_yaml_value(parameter.default)}')
    return '\n'.join(lines) + '\n'


def main(argv=None):
    """Print, write (--write) or check (--check) config/toc_ros.yaml: python -m toc_ros.config."""
    argv = sys.argv[1:] if argv is None else argv
    path = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                        'config', 'toc_ros.yaml')
    text = scenario_yaml()
    if argv == ['--write']:
        with open(path, 'w') as stream:
            stream.write(text)
        return 0
    if argv == ['--check']:
        with open(path) as stream:
            same = stream.read() == text
        print(f'{path} is ' + ('up to date' if same else 'out of date: run python -m '
                               'toc_ros.config --write'))
        return 0 if same else 1
    if argv:
        print('usage: python -m toc_ros.config [--write | --check]', file=sys.stderr)
        return 2
    sys.stdout.write(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
