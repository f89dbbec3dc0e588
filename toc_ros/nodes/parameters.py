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
from dataclasses import dataclass
import math
from typing import Tuple

from rcl_interfaces.msg import (
    FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult)
from rclpy.parameter import Parameter

from toc_ros.arm_config import ArmSettings
from toc_ros.config import SCENARIO_TABLE
from toc_ros.core.settings import parameter_table, setting


class ParameterError(ValueError):
    """Invalid node parameters at start-up (the on-set callbacks guard later changes)."""


@dataclass(frozen=True)
class SolverNodeSettings:
    """solver_node's own parameters (beyond the scenario's)."""

    extension_limits: Tuple[float, float] = setting(
        (-1.0, 3.0), '[q2_min, q2_max] m: reachable extension of goals (goal_pose, goal_joints, '
        '~/plan) of the cylindrical robot; the paper gives none, so generous defaults')
    ik_branch: str = setting(
        'elbow_up', 'inverse-kinematics branch of hand goals (goal_pose, ~/plan) for models '
        "with several: planar_2r 'elbow_up' (q2 <= 0) or 'elbow_down' (q2 >= 0), a model "
        'file: a branch name of its inverse_kinematics section; ignored by models with one '
        'solution', ros_name='robot.ik_branch')
    max_count: int = setting(
        64, 'largest obstacle set accepted (obstacles topic and obstacles.* parameters); '
        'larger sets are refused with the reason on ~/progress', low=0, high=100000,
        ros_name='obstacles.max_count')
    # Receding-horizon replanning (fast mode): see solver_node's module docstring.
    replan_rate: float = setting(
        20.0, 'rate of replan cycles while a fast-mode plan executes: each solves to the same '
        'goal from replan.lead ahead on the executing plan (or from the latest joint_states '
        'predicted forward when the robot is off the plan, replan.stitch), warm-started from '
        'the rest of the executing plan; 0 = off (plan once per goal)', unit='Hz',
        low=0.0, high=200.0, ros_name='replan.rate')
    replan_min_remaining: float = setting(
        0.15, 'no replan cycles once less than this is left of the executing plan (the '
        'tracker finishes it)', unit='s', low=0.0, high=1e3, ros_name='replan.min_remaining')
    replan_deviation: float = setting(
        0.02, 'largest |q - q_ref| over the joints (measured against the executing plan) that '
        'starts a replan cycle at once instead of at the next replan.rate tick; 0 = off',
        unit='rad or m', low=0.0, high=1e3, ros_name='replan.deviation')
    replan_stitch: float = setting(
        -1.0, "while the measured joint positions are within this of the executing plan's "
        "(max |q - q_ref|), a replan cycle starts on the plan's own state at its start node: "
        'the tracking controller holds the robot on its reference, and the new plan continues '
        'that reference without a jump; farther off, it starts from the measured state '
        "predicted forward under the plan's controls (open loop); 0 = always predicted; "
        '-1 = by model: 0.02 for URDF arms (light wrist links under a stiff tracker: the open '
        'loop drifts off within tens of ms), 0 for the planar models (heavy links: the cycles '
        'correct a model mismatch from the measurement)',
        unit='rad or m', low=-1.0, high=1e3, ros_name='replan.stitch')
    replan_max_nodes: int = setting(
        100, 'largest N of a replan cycle: the rest of the executing plan is resampled to at '
        'most this many intervals (fewer intervals, faster cycles)', low=20, high=100000,
        ros_name='replan.max_nodes')
    replan_integrator: str = setting(
        'rk4', "discretisation of the replan cycles' plans: 'rk4' (the plan is what the robot "
        'does under its piecewise-constant controls, so the cycles correct the mismatch and '
        "not their own discretisation error) or 'euler'; goals are planned with "
        'solver.integrator', choices=('rk4', 'euler'), ros_name='replan.integrator')
    replan_lead: float = setting(
        0.025, 'a replanned trajectory starts (header.stamp) at least this long after the '
        'joint_states it starts from was received (longer when recent cycles took longer, up '
        'to 0.2 s), from the state predicted along the executing plan; a cycle not published '
        'by then keeps the executing plan (and seeds the next)', unit='s', low=0.001,
        high=1.0, ros_name='replan.lead')
    goal_lead: float = setting(
        0.15, 'a goal that arrives while a plan moves the robot starts on that plan this long '
        'ahead (its node then; the robot follows the plan meanwhile): a plan from the measured '
        'state would start where the robot was when its solve began. A solve not done by then '
        'is solved again from twice as far ahead; a plan that ends sooner is continued from '
        'its rest', unit='s', low=0.01, high=2.0)
    start_lead: float = setting(
        0.03, "a goal's plan from rest starts (header.stamp) this long after it is published, "
        'so that the controller has it before its first point applies (the robot holds its '
        'rest meanwhile; a plan stamped now would start partway, its first motion lost); '
        'plans from a moving state start at once', unit='s', low=0.0, high=1.0)
    max_state_age: float = setting(
        1.0, 'a goal is refused while the newest joint_states is older than this (node clock '
        'since its receipt; a clock that jumps back makes it stale too): its start would be '
        'where the robot was, not where it is. Without any joint_states goals start from '
        'initial_state', unit='s', low=0.01, high=3600.0)
    replan_estimate: Tuple[str, ...] = setting(
        (), 'model parameters (e.g. hand_mass, inertia; m_p) that the replan cycles estimate '
        'online from joint_states (position, velocity and effort = the applied u) and plan '
        'with, and so do new goals once an estimate is in use; empty = off',
        ros_name='replan.estimate', ros_type='string_array')
    replan_estimate_window: float = setting(
        2.0, 'time constant of the exponential forgetting of the online estimation (older '
        'joint_states weigh less)', unit='s', low=0.01, high=1e4,
        ros_name='replan.estimate_window')
    # Execution through ros2_control (toc_ros.execution).
    execute_action: str = setting(
        '', 'FollowJointTrajectory action (e.g. /arm_controller/follow_joint_trajectory) that '
        'every published plan and replan cycle is also sent to as a goal, as MoveIt executes '
        'through ros2_control; empty = the trajectory topic only. Needs control_msgs: without '
        'it the node runs topic-only and says why', ros_name='execute.follow_joint_trajectory')
    execute_path_tolerance: float = setting(
        0.0, 'path_tolerance (position, every joint) sent with each goal; 0 = the '
        "controller's own", unit='rad or m', low=0.0, high=1e3,
        ros_name='execute.path_tolerance')
    execute_goal_tolerance: float = setting(
        0.0, 'goal_tolerance (position, every joint) sent with each goal; 0 = the '
        "controller's own", unit='rad or m', low=0.0, high=1e3,
        ros_name='execute.goal_tolerance')
    execute_goal_time: float = setting(
        0.0, 'goal_time_tolerance sent with each goal: how long after the end the joints may '
        "take to get within the goal tolerance; 0 = the controller's own", unit='s', low=0.0,
        high=1e3, ros_name='execute.goal_time_tolerance')
    execute_effort: bool = setting(
        False, "send the planned joint torques in each goal's effort field, for a "
        'JointTrajectoryController with an effort command interface (it feeds them forward); '
        "one without rejects goals that carry efforts ('Trajectories with effort fields are "
        "only supported for controllers using the effort command interface')",
        ros_name='execute.effort')


# Largest plant actuator_lag and control_delay [s]: the delay's ring buffer holds
# control_delay * integration_rate commands.
MAX_ACTUATOR_LAG_S = 10.0
MAX_CONTROL_DELAY_S = 1.0


@dataclass(frozen=True)
class PlantSettings:
    """plant_node's own parameters (beyond the robot data and joint names)."""

    rate: float = setting(100.0, 'publishing rate of joint_states (and /clock)', unit='Hz',
                          low=1.0, high=1000.0)
    integration_rate: float = setting(1000.0, 'fixed RK4 step rate of the simulation (>= rate)',
                                      unit='Hz', low=1.0, high=100000.0)
    # About critically damped around the paper's configuration (rotation inertia ~510 kg m^2
    # at q2 = 1 m, moving mass 147 kg): settles to < 1e-3 within ~1 s after a plan.
    kp: Tuple[float, float] = setting(
        (15000.0, 8000.0), 'proportional gains of the tracking PD per joint (>= 0)',
        unit='N m/rad, N/m')
    kd: Tuple[float, float] = setting(
        (5000.0, 2000.0), 'derivative gains of the tracking PD per joint (>= 0)',
        unit='N m s/rad, N s/m')
    payload_mass_offset: float = setting(
        0.0, 'added to robot.hand_mass in the simulated plant only (model mismatch; the hand '
        'mass stays > 0)', unit='kg', low=-1e4, high=1e4)
    inertia_scale: float = setting(
        1.0, 'factor on robot.inertia in the simulated plant only (model mismatch)', low=0.0,
        high=100.0)
    actuator_lag: float = setting(
        0.0, 'time constant of a first-order lag on the control applied to the simulated plant '
        '(du/dt = (u_cmd - u) / actuator_lag: the simulated drives; robot.actuator_lag is what '
        'the planner assumes of them); 0: off', unit='s', low=0.0,
        high=MAX_ACTUATOR_LAG_S)
    control_delay: float = setting(
        0.0, 'pure delay of the commanded control in the simulated plant, rounded to the '
        'integration step (model mismatch); 0: off', unit='s', low=0.0, high=MAX_CONTROL_DELAY_S)
    publish_clock: bool = setting(False, 'publish the simulated time on /clock')
    command_interface: str = setting(
        'effort', 'what the simulated drives take, as the command interface of a '
        "JointTrajectoryController: effort (PD + the trajectory's efforts fed forward) or "
        'position (a position-controlled arm: PD on the commanded position with gravity '
        'compensation, no feed-forward; FollowJointTrajectory goals with efforts are refused, '
        'as JTC refuses them)', choices=('effort', 'position'))
    engine: str = setting(
        'builtin', "the plant's dynamics: builtin (the planner's model, robot.*), or mujoco (the "
        'URDF in robot_description simulated by MuJoCo: joint_names planned, the others '
        'locked; needs the mujoco package)', choices=('builtin', 'mujoco'))


# Every flat parameter of the nodes: name -> settings.Parameter (default, type, range, text).
TABLE = {p.name: p for p in (list(SCENARIO_TABLE) + parameter_table(SolverNodeSettings)
                             + parameter_table(ArmSettings) + parameter_table(PlantSettings))}
SOLVER_NODE_NAMES = [p.name for p in SCENARIO_TABLE] + [
    p.name for p in parameter_table(SolverNodeSettings) + parameter_table(ArmSettings)]
# The plant simulates the robot of the scenario: every robot.* setting, so a new robot
# parameter reaches it without an edit here; of the arm settings the URDF (engine mujoco)
# and the tip link (payload_mass_offset).
PLANT_NODE_NAMES = [p.name for p in SCENARIO_TABLE if p.name.startswith('robot.')] + [
    'joint_names', 'initial_state'] + [p.name for p in parameter_table(PlantSettings)] + [
    'robot_description', 'robot.tip_link']


def default(name):
    """Return the default value of a flat parameter."""
    return TABLE[name].default


def descriptor(name):
    """Build the ParameterDescriptor (description, range, choices) of a flat parameter."""
    spec = TABLE[name]
    extra = {}
    if spec.low is not None and spec.high is not None:
        if spec.ros_type == 'double':
            extra['floating_point_range'] = [FloatingPointRange(
                from_value=float(spec.low), to_value=float(spec.high), step=0.0)]
        elif spec.ros_type == 'integer':
            extra['integer_range'] = [IntegerRange(from_value=int(spec.low),
                                                   to_value=int(spec.high), step=1)]
    if spec.choices:
        extra['additional_constraints'] = 'one of: ' + ', '.join(spec.choices)
    return ParameterDescriptor(description=spec.full_description(), **extra)


def declare(node, names):
    """Declare names on node with defaults and descriptors (overrides from --ros-args apply)."""
    for name in names:
        spec = TABLE[name]
        if spec.ros_type == 'string_array' and not spec.default:
            # rclpy types an empty default as a byte array, and an empty list in a parameter
            # file or on the command line arrives unset: declare the type, then set [].
            node.declare_parameter(name, Parameter.Type.STRING_ARRAY, descriptor(name))
            if node.get_parameter_or(name).type_ == Parameter.Type.NOT_SET:
                node.set_parameters([Parameter(name, Parameter.Type.STRING_ARRAY, [])])
            continue
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


def vector_errors(name, value, size, minimum=None, size_hint=''):
    """
    Errors of an array parameter that must hold size finite numbers (>= minimum).

    size_hint: appended to the error of a wrong number of entries (what the size is for).
    """
    try:
        numbers = [float(v) for v in value]
    except (TypeError, ValueError):
        return [f'{name} must be {size} numbers, got {value!r}']
    if len(numbers) != size:
        return [f'{name} must have {size} entries, got {len(numbers)}{size_hint}']
    if not all(math.isfinite(v) for v in numbers):
        return [f'{name} must be finite, got {numbers}']
    if minimum is not None and min(numbers) < minimum:
        return [f'{name} entries must be >= {minimum}, got {numbers}']
    return []


def joint_name_errors(names, count=2, model='cylindrical'):
    """Errors of the joint_names parameter (count distinct non-empty names for the model)."""
    names = list(names)
    if len(names) != count or len(set(names)) != count or not all(names):
        return [f'joint_names must be {count} distinct non-empty names (one per joint of '
                f'robot model {model!r}), got {names}']
    return []
