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
Goals of a URDF arm without ROS: joint and pose goals, their checks, problems and stale plans.

The arm counterparts of goal_requests.py (which delegates here when ``config.model`` is an
arm): ``joint_goal`` (goal_joints by name), ``pose_goal`` (goal_pose and ~/plan: the tip link's
pose by the core's inverse kinematics, within the joint limits and clear of the obstacles;
orientation all zero = position only), ``goal_refusal`` (the core's checks of start and goal:
limits, collisions with the sphere pair and depth), ``goal_problem``, ``plan_violation`` (what
the rest of an executing plan violates under new obstacles) and ``ignored_start`` (a ~/plan
request's start pose against the measured tip) and ``braking_plan`` (the stop that replaces
a plan).  States are (q, dq), positions first.
"""

import dataclasses
import math

import numpy as np

from toc_ros import arm_config, conversions
from toc_ros.conversions import ConversionError
from toc_ros.core import ProblemError
from toc_ros.core.executing_plan import ExecutingPlan, remaining_nodes
from toc_ros.core.result import CLEARANCE_TOL

# [m] a ~/plan start farther than this from the measured tip position is warned about.
START_TOLERANCE_M = 1e-3


def _model(config):
    model = config.model
    if model.pending:
        raise ConversionError(model.reason)
    return model


def joint_goal(msg, config):
    """Return the goal (q, dq) of a goal_joints JointState (by name; velocities default 0)."""
    model = _model(config)
    q, dq = conversions.joint_state_arrays(msg, list(model.joint_names))
    return np.concatenate([q, dq])


def _orientation(msg):
    """Return the quaternion (x, y, z, w) of a pose, or None when it is all zero."""
    o = msg.pose.orientation
    quat = (o.x, o.y, o.z, o.w)
    if all(v == 0.0 for v in quat):
        return None
    return quat


def pose_goal(msg, config, start):
    """
    Return the goal (q, 0) that puts the tip link at a PoseStamped (ConversionError).

    The pose must be in base_frame; IK is seeded by the start's positions (when known) and the
    answer is within the joint limits and clear of the current obstacles by the margin.
    """
    model = _model(config)
    frame = msg.header.frame_id.strip('/')
    base = config.frames.base_frame.strip('/')
    if frame != base:
        raise ConversionError(f"goal pose is in frame '{msg.header.frame_id}', expected "
                              f"'{config.frames.base_frame}' (no TF lookup: send it in the "
                              'base frame)')
    p = msg.pose.position
    position = (p.x, p.y, p.z)
    if not all(math.isfinite(v) for v in position):
        raise ConversionError(f'goal position {position} is not finite')
    link, _ = model.tip_frame(arm_config.settings(config.flat).tip_link)
    seed = None
    if start is not None and np.size(start) == model.nx:
        seed = np.asarray(start, dtype=float)[:model.n_joints]
    robot = model.private_robot()
    from toc_ros.core.arms import solve_ik
    try:
        q = solve_ik(robot.arm, link, position, _orientation(msg), q_start=seed,
                     spheres=robot.spheres, obstacles=arm_config.obstacle_rows(config.flat),
                     margin=config.problem.margin)
    except ValueError as exc:       # ArmError: unreachable, in collision, bad quaternion
        raise ConversionError(str(exc)) from None
    return model.state(q)


def no_start(config, start):
    """Return why there is no start state for a goal, or None."""
    model = config.model
    if model.pending:
        return model.reason
    if np.size(start) != model.nx:
        size = len(config.flat.get('initial_state', ()))
        return (f'no start state: no joint_states received yet, and initial_state ({size} '
                f'values) is not a state of this arm ({model.n_joints} positions or '
                f'{model.nx} values q1, dq1, ...)')
    return None


def goal_refusal(config, start, start_source, goal):
    """Return why a goal (q, dq) is refused from start, or None when it is taken."""
    why = no_start(config, start)
    if why is not None:
        return why
    from toc_ros.core.arms.arm_solve import check_arm_problem
    try:
        problem = goal_problem(config, start, goal)
        # A Data of its own: the solver thread may be using the model's meanwhile.
        check_arm_problem(dataclasses.replace(problem, model=config.model.private_robot()),
                          config.options)
    except (ProblemError, ValueError) as exc:     # ArmError is a ValueError
        return f'{exc} (start state from {start_source}: {np.round(start, 6).tolist()})'
    return None


def goal_problem(config, start, goal):
    """Return the Problem of an arm goal from start (no warm start: the arm solver has none)."""
    return arm_config.arm_problem(config.flat, x0=start, x_goal=goal)


def plan_violation(plan, config, elapsed):
    """Return what the rest of an executing arm plan violates under config, or None."""
    model = config.model
    if model is not plan.model:
        return f'was planned for another robot model (now {model.name!r})'
    rest = remaining_nodes(plan.times, elapsed)
    rows = np.asarray(arm_config.obstacle_rows(config.flat), dtype=float).reshape(-1, 4)
    spheres = model.robot.spheres
    if len(rows) and spheres is not None:
        from toc_ros.core.arms import obstacle_clearance, sphere_kinematics_batch
        centres, _ = sphere_kinematics_batch(spheres, model.positions(plan.states[rest]))
        margin = config.problem.margin
        gaps = np.array([obstacle_clearance(c, spheres.radii, rows, margin) for c in centres])
        worst = float(np.min(gaps))
        if worst < -CLEARANCE_TOL:
            k = int(np.unravel_index(np.argmin(gaps), gaps.shape)[2])
            return f'cuts obstacle {k} by {-worst:.3g} m'
    controls = plan.controls[rest[:len(plan.controls)]]
    if len(controls):
        excess = float(np.max(np.abs(controls) - model.u_max[None, :]))
        if excess > 0.0:
            return f'exceeds the effort limits by {excess:.3g}'
    return None


def braking_plan(plan, measured, now, dt):
    """
    Return the stop from a measured state that replaces an arm plan, or None.

    None when there is no usable state or no stop within the limits (ArmPlanModel.brake):
    then only the empty trajectory (the controller holds) can stop it.
    """
    model = plan.model
    if measured is None or np.shape(measured) != (model.nx,):
        return None
    stop = model.brake(measured, dt)
    if stop is None:
        return None
    times, states, controls = stop
    return ExecutingPlan(start=float(now), times=times, states=states, controls=controls,
                         goal=plan.goal, source='brake', model=model, result=None,
                         path_states=plan.path_states, goal_active=plan.goal_active,
                         joint_names=plan.joint_names)


def ignored_start(start_msg, config, measured_state):
    """Return why a ~/plan request's start pose is ignored with a warning, or None."""
    p = start_msg.pose.position
    frame = start_msg.header.frame_id.strip('/')
    if not frame and p.x == 0.0 and p.y == 0.0 and p.z == 0.0:
        return None         # the empty pose: no start given
    where = f'({p.x:.6g}, {p.y:.6g}, {p.z:.6g})'
    if frame != config.frames.base_frame.strip('/'):
        return f'its frame {frame!r} is not {config.frames.base_frame!r}'
    if not all(math.isfinite(v) for v in (p.x, p.y, p.z)):
        return f'{where} is not finite'
    model = config.model
    if model.pending or np.size(measured_state) != model.nx:
        return 'cannot be compared with a measured state (none yet)'
    link = arm_config.settings(config.flat).tip_link
    tip = model.tip_poses(model.positions(measured_state), link)[0].translation
    gap = float(np.linalg.norm(np.array([p.x, p.y, p.z]) - tip))
    if gap > START_TOLERANCE_M:
        return f'{where} is {gap:.4g} m from the measured tip position'
    return None
