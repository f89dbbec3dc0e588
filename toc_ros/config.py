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

import math
import os

import yaml

from .core.model import RobotParams
from .core.problem import PaperOptions, Problem, ProblemError, SolverOptions

# Flat parameter name -> default; the defaults are the paper's scenario.
DEFAULTS = {
    'robot.hand_mass': 50.0,
    'robot.link_mass': 97.0,
    'robot.inertia': 193.0,
    'robot.a': 1.1,
    'robot.u_max': [600.0, 500.0],
    'robot.model_variant': 'eq37',
    'joint_names': ['rotation_joint', 'extension_joint'],
    'base_frame': 'base_link',
    'initial_state': [math.pi / 12.0, 0.0, 1.0, 0.0],
    'goal_state': [5.0 * math.pi / 12.0, 0.0, 1.0, 0.0],
    'obstacles.x': [1.0],
    'obstacles.y': [1.0],
    'obstacles.radius': [0.2],
    'obstacles.margin': 0.01,
    'solver.mode': 'fast',
    'solver.integrator': 'euler',
    'solver.N': 1000,
    'solver.t_f0': 2.5,
    'solver.max_iterations': 0,          # 0: the mode's default (paper: M = 30000)
    'solver.timeout': 60.0,
    'solver.paper.K_B': 600.0,
    'solver.paper.K_V': 0.01,
    'solver.paper.K_p': 1000.0,
    'solver.paper.eta': 1000.0,
    'solver.paper.d_tau': 1e-5,
    'solver.paper.J_eps': 0.01,
    'solver.paper.obstacle_gradient': 'shortcut',
}


def default_config_path():
    """config/toc_ros.yaml from the installed share directory, else from the source tree."""
    try:
        from ament_index_python.packages import get_package_share_directory
        path = os.path.join(get_package_share_directory('toc_ros'), 'config', 'toc_ros.yaml')
        if os.path.isfile(path):
            return path
    except (ImportError, LookupError, OSError):
        pass    # no ament index, or toc_ros not in it: fall back to the source tree
    return os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                        'config', 'toc_ros.yaml')


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
    xs, ys, rs = (list(params[f'obstacles.{k}']) for k in ('x', 'y', 'radius'))
    if not len(xs) == len(ys) == len(rs):
        raise ProblemError('obstacles.x, obstacles.y and obstacles.radius must have equal '
                           f'lengths, got {len(xs)}, {len(ys)}, {len(rs)}')
    return tuple((float(x), float(y), float(r)) for x, y, r in zip(xs, ys, rs))


def robot_from_parameters(params):
    """Build the RobotParams from flat parameters."""
    u_max = list(params['robot.u_max'])
    if len(u_max) != 2:
        raise ProblemError(f'robot.u_max must have 2 entries, got {len(u_max)}')
    return RobotParams(hand_mass=float(params['robot.hand_mass']),
                       link_mass=float(params['robot.link_mass']),
                       inertia=float(params['robot.inertia']), a=float(params['robot.a']),
                       u1_max=float(u_max[0]), u2_max=float(u_max[1]),
                       model_variant=str(params['robot.model_variant']))


def problem_from_parameters(params, x0=None, x_goal=None, obstacles=None):
    """Problem from flat parameters; x0, x_goal, obstacles override the parameter values."""
    return Problem(
        x0=tuple(float(v) for v in (params['initial_state'] if x0 is None else x0)),
        x_goal=tuple(float(v) for v in (params['goal_state'] if x_goal is None else x_goal)),
        obstacles=obstacle_rows(params) if obstacles is None else tuple(obstacles),
        margin=float(params['obstacles.margin']),
        robot=robot_from_parameters(params),
        n_intervals=int(params['solver.N']),
        integrator=str(params['solver.integrator']),
        t_f0=float(params['solver.t_f0']))


def options_from_parameters(params):
    """Build the SolverOptions (timeout <= 0: no limit; max_iterations 0: mode default)."""
    timeout = float(params['solver.timeout'])
    return SolverOptions(
        mode=str(params['solver.mode']),
        max_iterations=int(params['solver.max_iterations']) or None,
        timeout=timeout if timeout > 0 else None,
        paper=PaperOptions(k_b=float(params['solver.paper.K_B']),
                           k_v=float(params['solver.paper.K_V']),
                           k_p=float(params['solver.paper.K_p']),
                           eta=float(params['solver.paper.eta']),
                           d_tau=float(params['solver.paper.d_tau']),
                           j_eps=float(params['solver.paper.J_eps']),
                           obstacle_gradient=str(params['solver.paper.obstacle_gradient'])))
