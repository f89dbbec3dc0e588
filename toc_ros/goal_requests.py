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
A planner node's goal requests without ROS: checks, the problem to solve, and the outcome.

The node translates a goal message into a joint goal; this module decides whether the goal
is refused against the measured start and the current data (``goal_refusal``), whether a
``~/plan`` request's start is ignored (``ignored_start``), builds the problem a goal is solved
as (``goal_problem``: the margin of a recovery, the warm start from the executing plan), names
what the rest of an executing plan violates under new data (``plan_violation``), and words the
result of a goal's solve (``goal_outcome``) and of a replan cycle that kept its plan
(``cycle_failure``).  ``config`` is a ``nodes.solver_settings.SolverNodeConfig``.
"""

import math

import numpy as np

from toc_ros import arm_goals
from toc_ros.config import problem_from_parameters
from toc_ros.core import goal_starts as starts, ProblemError, Status
from toc_ros.core.executing_plan import goal_warm_start, violation
from toc_ros.core.result import CLEARANCE_TOL

# [m] a ~/plan start farther than this from the measured hand position is warned about.
START_TOLERANCE_M = 1e-3
# The source of the goals that the node plans again after stopping a plan.
REPLAN = 'replan'
# The start_source of a goal solved while the robot brakes.
BRAKING_REST = 'braking stop (its rest)'
# ... and of one solved while the robot brakes into a true circle (starts.braking_rest_start).
BRAKING_AHEAD = 'braking stop (its state at now + replan.lead: it rests inside a circle)'
# ... and of one that arrives while a plan moves the robot (starts.goal_start_on_plan): its
# plan must be published before the start's time (a strict stamp), else it is solved again.
ON_PLAN = 'executing plan (its state at now + goal_lead)'
# ... when that plan ends before then: its rest, from its end on.
ON_PLAN_REST = 'executing plan (its rest)'


def start_state(config, measured):
    """Return (start state, its source): the measured state, else initial_state."""
    if measured is not None:
        return measured, 'joint_states'
    return np.asarray(config.problem.x0, dtype=float), 'initial_state'


def goal_start(config, measured, executing, now, measured_time=None, lead_scale=1.0):
    """
    Return (start state, its source, earliest plan start [s, node clock] or None) of a goal.

    While a braking stop executes that the measured state (at measured_time) follows, the
    stop's rest (starts.braking_rest_start), or its node at now + replan.lead when its path
    enters a true circle.  While another plan executes, its node at now + goal_lead x
    lead_scale or its rest (starts.goal_start_on_plan: ON_PLAN, whose time is the plan's
    stamp, or ON_PLAN_REST).  Else start_state.
    """
    nx = np.shape(config.problem.x0)[0]
    rows = None if config.is_arm else config.problem.obstacles
    rest = starts.braking_rest_start(executing, now, nx, measured, measured_time, rows,
                                     config.node.replan_lead)
    if rest is not None:
        at_rest = rest[1] >= executing.start + executing.duration
        return rest[0], BRAKING_REST if at_rest else BRAKING_AHEAD, rest[1]
    on_plan = starts.goal_start_on_plan(
        executing, nx, measured, measured_time, now, config.node.goal_lead * lead_scale,
        config.node.replan_stitch)
    if on_plan is not None:
        return on_plan[0], ON_PLAN_REST if on_plan[2] else ON_PLAN, on_plan[1]
    return (*start_state(config, measured), None)


def recovery_params(config, start, step=0.0):
    """
    Return the flat parameters of a replan from start inside the margin (None: as is).

    step: starts.recovery_margin's (a start on the executing plan: its step).
    """
    margin = starts.recovery_margin(config.model, start, config.problem.obstacles,
                                    config.problem.margin, step)
    return None if margin is None else dict(config.flat, **{'obstacles.margin': margin})


def cycle_base_problem(config, start, goal):
    """
    Return (problem, recovery parameters or None) of a replan cycle from start to goal.

    A planar start inside the obstacle margin plans with the recovery margin (recovery_params);
    an arm's start is checked by the arm solver like a goal's (inside the margin: refused).
    """
    if config.is_arm:
        return arm_goals.goal_problem(config, start, goal), None
    recovery = recovery_params(config, start)
    return problem_from_parameters(recovery or config.flat, x0=start, x_goal=goal), recovery


def plan_violation(plan, config, elapsed):
    """Return what the rest of an executing plan violates under config, or None."""
    if config.is_arm:
        return arm_goals.plan_violation(plan, config, elapsed)
    try:
        problem = problem_from_parameters(config.flat, x0=plan.states[0], x_goal=plan.goal)
    except ProblemError as exc:
        return f'cannot be checked ({exc})'
    return violation(plan, problem.robot_model, problem.circles(), elapsed, CLEARANCE_TOL)


def ignored_start(frame, x, y, base_frame, joint_model, measured_state):
    """
    Return why a ~/plan request's start pose is ignored with a warning, or None.

    frame, x, y: the request's start (frame without slashes; the empty frame with x = y = 0 is
    no start); the start must be in base_frame, finite and within START_TOLERANCE_M of the
    hand position of measured_state [q1, dq1, ...].
    """
    if not frame and x == 0.0 and y == 0.0:
        return None         # the empty pose: no start given
    q = np.asarray(measured_state, dtype=float)[0:2 * joint_model.n_joints:2]
    hand = np.asarray(joint_model.hand_position(q), dtype=float)
    where = f'({x:.6g}, {y:.6g})'
    if frame and frame != base_frame.strip('/'):
        return f'its frame {frame!r} is not {base_frame!r}'
    if not (math.isfinite(x) and math.isfinite(y)):
        return f'{where} is not finite'
    gap = math.hypot(x - hand[0], y - hand[1])
    if gap > START_TOLERANCE_M:
        return f'{where} is {gap:.4g} m from the measured hand position'
    return None


def goal_refusal(config, start, start_source, goal, source):
    """
    Return why a joint goal is refused from start under config, or None when it is taken.

    Checked: the cylindrical extension against extension_limits, then the problem from the
    start (with the recovery margin for a replan after a stop and a start on the executing
    plan: recovers) to the goal.  URDF arms: arm_goals.goal_refusal (their limits and
    collisions).
    """
    if config.is_arm:
        return arm_goals.goal_refusal(config, start, start_source, goal)
    low, high = config.node.extension_limits
    if config.robot.name == 'cylindrical' and len(goal) == 4 and not low <= goal[2] <= high:
        return (f'goal extension q2 = {goal[2]:.6g} m is outside extension_limits '
                f'[{low:.6g}, {high:.6g}] m')
    flat = config.flat
    if recovers(source, start_source):
        flat = recovery_params(config, start) or flat
    try:
        problem_from_parameters(flat, x0=start, x_goal=goal).validate()
    except ProblemError as exc:
        return f'{exc} (start state from {start_source}: {np.round(start, 6).tolist()})'
    return None


def recovers(source, start_source):
    """
    Tell whether a goal's start inside the obstacle margin is planned with the recovery margin.

    For the node's own starts: a replan after a stop (braking may end inside the margin), and a
    start on the executing plan (the plan keeps the margin at its nodes only, and the state
    predicted along it from a robot lagging it may lie inside: 5 mm with a 30 ms lag past the
    paper's circle).  A user's goal from a measured state inside the margin is refused.
    """
    return source == REPLAN or start_source == ON_PLAN


def goal_problem(config, start, goal, source, plan, now, start_source=None):
    """
    Return (problem, warm start or None, recovery margin or None) of a goal's solve.

    A start inside the obstacle margin plans with the recovery margin when it recovers
    (``recovers``); plan: the executing plan when start is measured (its rest warm-starts a
    solve to the same goal in fast mode).  Raises ProblemError (TypeError, ValueError) for data
    that do not make a problem.
    """
    if config.is_arm:
        return arm_goals.goal_problem(config, start, goal), None, None
    flat, margin = config.flat, None
    if recovers(source, start_source):
        on_plan = start_source == ON_PLAN and plan is not None and len(plan.times) > 1
        step = float(np.median(np.diff(plan.times))) if on_plan else 0.0
        recovery = recovery_params(config, start, step)
        if recovery is not None:
            flat, margin = recovery, recovery['obstacles.margin']
    problem = problem_from_parameters(flat, x0=start, x_goal=goal)
    problem, guess = goal_warm_start(plan, problem, now, config.options.mode == 'fast')
    return problem, guess, margin


def goal_outcome(result, stop_reason, start_source):
    """Return (status, message) of a goal's solve result as reported."""
    message = result.message
    if result.status is Status.CANCELED and stop_reason:
        message = f'{stop_reason} ({result.message})'
    if result.status is Status.INVALID_INPUT:
        message = f'{message} (start state from {start_source})'
    return result.status, message


def cycle_failure(result, stop_reason, late_by, budget, published, current):
    """
    Return why a solved replan cycle kept the executing plan, or None when it published.

    late_by: how long [s] after its deadline its plan was ready (None: in time); budget: its
    lead [s] (deadline - joint_states receipt); current: whether its goal is still active.
    """
    if result.status is not Status.SOLVED or not result.has_trajectory:
        return f'{result.status.value}: {stop_reason or result.message}'
    if late_by is not None:
        return (f'late: ready {1e3 * late_by:.1f} ms after its deadline ({1e3 * budget:.0f} ms '
                'after its joint_states); it seeds the next cycle')
    if published:
        return None
    if not current:
        return f'{stop_reason}: not published'
    return 'the planning data changed during the cycle and the plan violates the new data'
