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
Flat parameters of URDF arms (robot.model panda, ur5 or urdf) -> the arm model and its Problem.

The arm settings are declared once here (``ArmSettings``); solver_node declares them as ROS
parameters and plant_node the two it shares (robot_description, robot.tip_link).  Two values
come from topics, not parameters, and travel in the same flat dict under keys that are no ROS
parameter: ``robot_description.topic`` (the latest URDF on the robot_description topic, used
when the parameter is empty) and ``obstacles.spheres`` (the arm's obstacle rows (x, y, z, r)
from the obstacles and obstacle_markers topics).  Being part of the flat values, a change of
either is a new data revision like a parameter change (solver_settings.planning_data).

Pinocchio is imported only when an arm is built (toc_ros.arm_model), not for planar models.
"""

from dataclasses import dataclass
import functools
import math
import os
from typing import Tuple

import numpy as np

from toc_ros.core.problem import finite_number, Problem, ProblemError
from toc_ros.core.settings import from_parameters, setting

ARM_MODELS = ('panda', 'ur5', 'urdf')
# Flat keys filled from topics (not ROS parameters), with their values before any message.
TOPIC_DESCRIPTION = 'robot_description.topic'
SPHERES = 'obstacles.spheres'
TOPIC_DEFAULTS = {TOPIC_DESCRIPTION: '', SPHERES: ()}
# core.arms.urdf.LIMIT_KEYS, spelled out so that the settings do not import Pinocchio (a test
# keeps them equal).
LIMIT_KEYS = ('effort', 'velocity', 'lower', 'upper')
# What replan.estimate can fit for URDF arms (the other inertials are the URDF's).
ARM_ESTIMATES = ('payload_mass',)


@dataclass(frozen=True)
class ArmSettings:
    """The parameters of URDF arms beyond robot.model, joint_names and the scenario's."""

    description: str = setting(
        '', 'URDF of the arm (the robot_state_publisher parameter of the same name). '
        'solver_node with robot.model urdf: when empty, the URDF of the robot_description '
        'topic (std_msgs/String, transient local) is used, a new one reloads the model; '
        'plant_node: the URDF simulated by engine mujoco', ros_name='robot_description')
    collision_spheres: str = setting(
        '', "sphere file of the arm's collision geometry (YAML 'link: [[x, y, z, r], ...]', "
        'centres in the link frame); empty: the shipped set of panda / ur5; required for urdf',
        ros_name='robot.collision_spheres')
    tip_link: str = setting(
        '', 'link whose pose goal_pose and ~/plan give, and whose path is drawn (URDF arms); '
        'empty: panda_hand (panda), tool0 (ur5), the child link of the last planned joint '
        '(urdf). plant_node: the link that carries payload_mass_offset',
        ros_name='robot.tip_link')
    joint_limits: Tuple[str, ...] = setting(
        (), "joint-limit overrides of URDF arms, 'JOINT.KEY=VALUE' with KEY effort [N m or N], "
        "velocity [rad/s or m/s], lower or upper [rad or m] (like MoveIt's joint_limits.yaml), "
        'e.g. panda_joint1.velocity=1.0', ros_name='robot.joint_limits', ros_type='string_array')
    payload_mass: float = setting(
        0.0, 'payload [kg] the plans of URDF arms assume: a point mass at the origin of '
        'robot.tip_link (replan.estimate: [payload_mass] fits it online, from this value)',
        unit='kg', low=0.0, high=1e4, ros_name='robot.payload_mass')
    locked_joints: Tuple[str, ...] = setting(
        (), "URDF joints not in joint_names are locked: 'JOINT=VALUE' [rad or m] gives the "
        'value, the others are locked at 0 clamped into their limits (as plant_node locks '
        'them)', ros_name='robot.locked_joints', ros_type='string_array')


def is_arm(params):
    """Tell whether flat parameters choose a URDF arm (robot.model panda, ur5 or urdf)."""
    return str(params.get('robot.model', '')).strip() in ARM_MODELS


def settings(params):
    """Return the ArmSettings of flat parameters (ProblemError for a wrong type)."""
    try:
        return from_parameters(ArmSettings, params)
    except (TypeError, ValueError) as exc:
        raise ProblemError(str(exc)) from None


def effective_description(params):
    """Return the URDF of robot.model urdf: the parameter, else the topic's ('' if none)."""
    return str(params.get('robot_description', '')).strip() \
        or str(params.get(TOPIC_DESCRIPTION, '')).strip()


def _entries(values, what, example):
    """Yield (left, value) of 'LEFT=VALUE' entries (ProblemError for another form)."""
    for entry in values:
        left, sep, right = str(entry).partition('=')
        left, right = left.strip(), right.strip()
        if not sep or not left or not right:
            raise ProblemError(f'{what} entries must be {example!r}, got {entry!r}')
        try:
            value = float(right)
        except ValueError:
            raise ProblemError(f'{what} {entry!r}: {right!r} is not a number') from None
        if not math.isfinite(value):
            raise ProblemError(f'{what} {entry!r}: the value must be finite')
        yield left, value


def limit_overrides(entries, what='robot.joint_limits'):
    """Return {joint: {key: value}} of entries 'JOINT.KEY=VALUE' (what: their name in errors)."""
    limits = {}
    for left, value in _entries(entries, what, 'JOINT.KEY=VALUE'):
        joint, dot, key = left.rpartition('.')
        if not dot or not joint or key not in LIMIT_KEYS:
            raise ProblemError(f'{what} entry {left!r}: give JOINT.KEY with KEY one '
                               f'of {", ".join(LIMIT_KEYS)}')
        if key in limits.setdefault(joint, {}):
            raise ProblemError(f'{what} gives {left} twice')
        limits[joint][key] = value
    return limits


def locked_values(entries, what='robot.locked_joints'):
    """Return {joint: value} of entries 'JOINT=VALUE' (what: their name in errors)."""
    locked = {}
    for joint, value in _entries(entries, what, 'JOINT=VALUE'):
        if joint in locked:
            raise ProblemError(f'{what} gives {joint} twice')
        locked[joint] = value
    return locked


def arm_model(params):
    """
    Return the arm model of flat parameters: an ArmPlanModel, or a PendingArm (no URDF yet).

    Built once per (model, URDF, joints, locked values, limits, sphere file and its
    modification time), so that an unchanged set gives the same object (kernels, plans).
    Raises ProblemError with the reason for anything that cannot be used.
    """
    name = str(params['robot.model']).strip()
    arm = settings(params)
    joints = tuple(str(j) for j in params['joint_names'])
    locked = tuple(sorted(locked_values(arm.locked_joints).items()))
    limits = tuple(sorted((j, tuple(sorted(v.items())))
                          for j, v in limit_overrides(arm.joint_limits).items()))
    spheres = arm.collision_spheres.strip()
    if spheres:
        spheres = os.path.abspath(os.path.expanduser(spheres))
        try:
            stamp = os.stat(spheres).st_mtime_ns
        except OSError as exc:
            raise ProblemError(f'robot.collision_spheres: cannot read {spheres!r}: '
                               f'{exc}') from None
    else:
        stamp = 0
    description = effective_description(params) if name == 'urdf' else ''
    if name == 'urdf' and not spheres:
        raise ProblemError('robot.model urdf needs robot.collision_spheres (a sphere file of '
                           'the arm: see docs/own_arm.md)')
    if name == 'urdf' and not description:
        from toc_ros.arm_model import PendingArm
        return PendingArm(joints)
    return _cached_arm(name, description, joints, locked, limits, spheres, stamp,
                       arm.tip_link.strip(), float(arm.payload_mass))


@functools.lru_cache(maxsize=8)
def _cached_arm(name, description, joints, locked, limits, spheres, stamp, tip, payload):
    from toc_ros.arm_model import build_arm
    return build_arm(name, description, joints, dict(locked),
                     {j: dict(v) for j, v in limits}, spheres or None, tip, payload)


def obstacle_rows(params):
    """Return the arm's obstacle rows (x, y, z, r) [m] (the topics' set)."""
    return tuple(tuple(float(v) for v in row) for row in params.get(SPHERES, ()))


def initial_arm_state(params, model):
    """
    Return the start state (q, dq) of initial_state for an arm, or None when it is not one.

    initial_state gives n positions (at rest) or 2 n values q1, dq1, q2, dq2, ... (the node's
    joint-state order); any other size (e.g. the planar default) is no arm state: goals then
    wait for joint_states.
    """
    values = np.asarray(params.get('initial_state', ()), dtype=float).reshape(-1)
    n = model.n_joints
    if values.size == n:
        return np.concatenate([values, np.zeros(n)])
    if values.size == 2 * n:
        return np.concatenate([values[0::2], values[1::2]])
    return None


def arm_problem(params, x0=None, x_goal=None, obstacles=None, strict=True):
    """
    Return the Problem of an arm: its ArmRobot, states (q, dq), obstacle spheres, solver.*.

    x0 / x_goal: positions-first states (default: initial_state, and the same as goal);
    obstacles: rows (x, y, z, r) (default: the topics' set).  strict: a model still waiting for
    its URDF raises ProblemError (else the Problem has the model None).
    """
    model = arm_model(params)
    if model.pending and strict:
        raise ProblemError(model.reason)
    if x0 is None:
        start = None if model.pending else initial_arm_state(params, model)
        x0 = () if start is None else start
    try:
        return Problem(
            x0=tuple(float(v) for v in x0),
            x_goal=tuple(float(v) for v in (x0 if x_goal is None else x_goal)),
            model=None if model.pending else model.robot,
            obstacles=obstacle_rows(params) if obstacles is None else tuple(
                tuple(float(v) for v in row) for row in obstacles),
            margin=float(params['obstacles.margin']), n_intervals=int(params['solver.N']),
            integrator=str(params['solver.integrator']), t_f0=float(params['solver.t_f0']))
    except (TypeError, ValueError) as exc:
        raise ProblemError(str(exc)) from None


def arm_errors(params, model):
    """
    Everything wrong with a candidate set of solver_node parameters for an arm (empty: valid).

    Start and goal states are checked per goal, against the measured start.
    """
    errors = []
    if str(params.get('solver.mode', 'fast')) != 'fast':
        errors.append(f"solver.mode {params['solver.mode']!r} is not offered for URDF arms in "
                      'solver_node: its goals and replan cycles are planned in fast mode (plans '
                      'that meet every limit, warm-started from the last plan); paper mode for '
                      'arms is a reference to compare with, in solve() and toc-solve')
    if str(params.get('solver.integrator', 'euler')) != 'euler':
        errors.append(f"solver.integrator {params['solver.integrator']!r} is not implemented "
                      "for URDF arms in solver_node: use 'euler' (solve() and toc-solve have "
                      'RK4 for arms, at several times the cost of an Euler solve)')
    if float(params.get('robot.actuator_lag', 0.0)) != 0.0:
        errors.append('robot.actuator_lag: actuator lag is not modelled for URDF arms (give 0)')
    if params.get('robot.model_parameters'):
        errors.append('robot.model_parameters: not used by URDF arms (the URDF is the model; '
                      'limits: robot.joint_limits)')
    estimate = tuple(params.get('replan.estimate') or ())
    other = sorted(set(estimate) - set(ARM_ESTIMATES))
    if other:
        errors.append(f'replan.estimate: URDF arms estimate {", ".join(ARM_ESTIMATES)} only '
                      f'(a point mass at robot.tip_link), not {", ".join(other)}')
    elif estimate and not model.pending:
        from toc_ros.core.estimation import ParameterEstimator
        from toc_ros.core.models.base import ModelError
        try:        # the estimator the joint_states will feed: duplicates, the window
            ParameterEstimator(model, estimate, float(params['replan.estimate_window']))
        except ModelError as exc:
            errors.append(f'replan.estimate: {exc}')
    if not str(params['base_frame']).strip('/'):
        errors.append('base_frame must not be empty')
    from toc_ros.core.arms.arm_solve import MAX_INTERVALS     # Pinocchio: arms only
    if finite_number(params.get('solver.N')) and int(params['solver.N']) > MAX_INTERVALS:
        errors.append(f"solver.N = {params['solver.N']} exceeds the {MAX_INTERVALS} intervals "
                      'URDF arms are planned on')
    count, limit = len(params.get(SPHERES, ())), int(params['obstacles.max_count'])
    if count > limit:
        errors.append(f'{count} obstacles exceed obstacles.max_count = {limit}')
    margin = params['obstacles.margin']
    if not finite_number(margin) or margin < 0:
        errors.append(f'obstacles.margin must be finite and >= 0 [m], got {margin!r}')
    if not model.pending:
        try:
            model.tip_frame(settings(params).tip_link)
        except ValueError as exc:
            errors.append(f'robot.tip_link: {exc}')
    return errors
