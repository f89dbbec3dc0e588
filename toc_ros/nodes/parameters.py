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
Declaration of the nodes' flat parameters (names of toc_ros.config) with descriptors.

Each node declares the names it uses with a ParameterDescriptor (description, range), reads
them back as plain Python values, and validates candidate sets in its on-set callback with
the candidate() dict built here.
"""

import array
import math

from rcl_interfaces.msg import (
    FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult)

from toc_ros.config import DEFAULTS


def _fr(low, high):
    return {'floating_point_range': [FloatingPointRange(from_value=float(low),
                                                        to_value=float(high), step=0.0)]}


def _ir(low, high):
    return {'integer_range': [IntegerRange(from_value=low, to_value=high, step=1)]}


def _one_of(*choices):
    return {'additional_constraints': 'one of: ' + ', '.join(choices)}


# Node-specific parameters (not in the scenario file's DEFAULTS).
NODE_DEFAULTS = {
    'extension_limits': [-1.0, 3.0],
    'rate': 100.0,
    'integration_rate': 1000.0,
    # About critically damped around the paper's configuration (rotation inertia ~510 kg m^2 at
    # q2 = 1 m, moving mass 147 kg): settles to < 1e-3 within ~1 s after a plan.
    'kp': [15000.0, 8000.0],
    'kd': [5000.0, 2000.0],
    'payload_mass_offset': 0.0,
    'inertia_scale': 1.0,
    'publish_clock': False,
}

# name -> (description, extra descriptor fields)
SPECS = {
    'robot.hand_mass': ('M [kg]: mass of the manipulator hand and its load', _fr(0, 1e4)),
    'robot.link_mass': ('m [kg]: mass of the extension link', _fr(0, 1e4)),
    'robot.inertia': ('I1 + I2 [kg m^2]: inertia about the rotation axis', _fr(0, 1e5)),
    'robot.a': ('a [m]: distance from point S to the centre of mass of the hand', _fr(0, 100)),
    'robot.u_max': ('[N m, N]: control bounds |u1| <= u_max[0], |u2| <= u_max[1], both > 0',
                    {}),
    'robot.model_variant': ("sign of the centrifugal term: 'eq37' (as printed in the paper) or "
                            "'eq36' (derived from eq. 36)", _one_of('eq37', 'eq36')),
    'joint_names': ('[rotation joint, extension joint]: names used in joint_states, goals and '
                    'trajectories', {}),
    'base_frame': ('frame of goal poses, planned paths and markers (the robot base)', {}),
    'initial_state': ('[q1 rad, dq1 rad/s, q2 m, dq2 m/s]: start state while no joint_states '
                      'arrived (plant: state at start-up and after ~/reset)', {}),
    'goal_state': ('[q1 rad, dq1 rad/s, q2 m, dq2 m/s]: goal of the scenario file (toc-solve); '
                   'the node plans to goals from goal_pose, goal_joints and ~/plan', {}),
    'obstacles.x': ('[m] obstacle centres x; obstacles.x/.y/.radius have equal lengths: set '
                    'them together (atomically) or publish on the obstacles topic', {}),
    'obstacles.y': ('[m] obstacle centres y (see obstacles.x)', {}),
    'obstacles.radius': ("[m] obstacle radii R' > 0 (see obstacles.x)", {}),
    'obstacles.margin': ("dR [m]: clearance margin, the arm stays outside R' + dR",
                         _fr(0, 100)),
    'solver.mode': ("'fast' (feasible minimum time) or 'paper' (the section-3 heuristic)",
                    _one_of('fast', 'paper')),
    'solver.integrator': ("discretisation of eq. (37): 'euler' (the paper's) or 'rk4'",
                          _one_of('euler', 'rk4')),
    'solver.N': ('number of time intervals of the trajectory', _ir(2, 200000)),
    'solver.t_f0': ('[s] initial guess of the final time (> 0)', _fr(0, 1e4)),
    'solver.max_iterations': ("iteration limit of one solve; 0 = the mode's default (paper: "
                              'M = 30000 gradient steps, fast: 500000 L-BFGS steps)',
                              _ir(0, 1_000_000_000)),
    'solver.timeout': ('[s] wall-clock limit of one solve; 0 = none', _fr(0, 86400)),
    'solver.paper.K_B': ('K_B of eq. (7), paper mode (> 0)', _fr(0, 1e12)),
    'solver.paper.K_V': ('K_V, paper mode (> 0)', _fr(0, 1e12)),
    'solver.paper.K_p': ('K_p of eq. (42), obstacle penalty, paper mode (> 0)', _fr(0, 1e12)),
    'solver.paper.eta': ('learning rate eta of eq. (32), paper mode (> 0)', _fr(0, 1e12)),
    'solver.paper.d_tau': ('[s] decrement of tau of eq. (34), paper mode (> 0)', _fr(0, 1)),
    'solver.paper.J_eps': ('J_eps of eq. (34), paper mode (> 0)', _fr(0, 1e12)),
    'solver.paper.obstacle_gradient': ("'shortcut' (eq. 46) or 'exact' (eqs. 44-45)",
                                       _one_of('shortcut', 'exact')),
    'extension_limits': ('[q2_min, q2_max] m: reachable extension of goals (goal_pose, '
                         'goal_joints, ~/plan); the paper gives none, so generous defaults',
                         {}),
    'rate': ('[Hz] publishing rate of joint_states (and /clock)', _fr(1, 1000)),
    'integration_rate': ('[Hz] fixed RK4 step rate of the simulation (>= rate)',
                         _fr(1, 100000)),
    'kp': ('[N m/rad, N/m] proportional gains of the tracking PD per joint (>= 0)', {}),
    'kd': ('[N m s/rad, N s/m] derivative gains of the tracking PD per joint (>= 0)', {}),
    'payload_mass_offset': ('[kg] added to robot.hand_mass in the simulated plant only '
                            '(model mismatch; the hand mass stays > 0)', _fr(-1e4, 1e4)),
    'inertia_scale': ('factor on robot.inertia in the simulated plant only (model mismatch)',
                      _fr(0, 100)),
    'publish_clock': ('publish the simulated time on /clock', {}),
}


def default(name):
    """Return the default value of a flat parameter."""
    return NODE_DEFAULTS[name] if name in NODE_DEFAULTS else DEFAULTS[name]


def descriptor(name):
    """Build the ParameterDescriptor (description, range) of a flat parameter."""
    description, extra = SPECS[name]
    return ParameterDescriptor(description=description, **extra)


def declare(node, names):
    """Declare names on node with defaults and descriptors (overrides from --ros-args apply)."""
    for name in names:
        node.declare_parameter(name, default(name), descriptor(name))


def plain(value):
    """Parameter value as plain Python (arrays as lists)."""
    if isinstance(value, (array.array, tuple, list)):
        return list(value)
    return value


def values(node, names):
    """Return the current values of names as a dict of plain Python values."""
    return {name: plain(node.get_parameter(name).value) for name in names}


def candidate(current, parameters):
    """Return current (a dict) with the values of parameters (rclpy Parameters) applied."""
    params = dict(current)
    for parameter in parameters:
        if parameter.name in params:
            params[parameter.name] = plain(parameter.value)
    return params


def result(errors):
    """Build a SetParametersResult: refused with the joined errors, or successful."""
    if errors:
        return SetParametersResult(successful=False, reason='; '.join(errors))
    return SetParametersResult(successful=True)


def vector_errors(name, value, size, minimum=None):
    """Errors of an array parameter that must hold size finite numbers (>= minimum)."""
    try:
        numbers = [float(v) for v in value]
    except (TypeError, ValueError):
        return [f'{name} must be {size} numbers, got {value!r}']
    if len(numbers) != size:
        return [f'{name} must have {size} entries, got {len(numbers)}']
    if not all(math.isfinite(v) for v in numbers):
        return [f'{name} must be finite, got {numbers}']
    if minimum is not None and min(numbers) < minimum:
        return [f'{name} entries must be >= {minimum}, got {numbers}']
    return []


def joint_name_errors(names):
    """Errors of the joint_names parameter (two distinct non-empty names)."""
    names = list(names)
    if len(names) != 2 or len(set(names)) != 2 or not all(names):
        return [f'joint_names must be 2 distinct non-empty names, got {names}']
    return []
