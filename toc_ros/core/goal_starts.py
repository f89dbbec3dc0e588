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
Where a goal starts and with which obstacle margin (the policy of goal_requests.py).

- whether the measured state is recent enough to start a goal from (``stale_state``);
- a goal that arrives while a plan moves the robot starts on that plan ahead
  (``goal_start_on_plan``), one solved while the robot brakes at the stop's rest
  (``braking_rest_start``);
- the node's own starts inside the obstacle margin plan with part of their clearance
  (``recovery_margin``), and a goal from the executing plan that stalls is solved again with
  less margin (``retry_margin``).

The replan cycles and braking decisions are replan_policy.py's.
"""

import numpy as np

from toc_ros.core.executing_plan import true_conflict_time
from toc_ros.core.obstacles import model_clearance
from toc_ros.core.replan_policy import ARM_STITCH, at_rest, cycle_start_state, state_time
from toc_ros.core.result import Status

# [rad, m] a measured state this far from a braking stop's reference does not follow it (a reset
# plant): goals then start from the measured state, not from the stop's rest.  A plant that
# brakes later than the reference (a heavier payload) stays within a few hundredths.
BRAKING_FOLLOW_TOL = 0.2

# [rad or m] a goal that arrives while a plan moves the robot starts on the plan's own state
# while the robot is within this of it (replan.stitch -1, for every model).
GOAL_STITCH = ARM_STITCH


def goal_start_on_plan(plan, nx, measured, measured_time, now, lead, stitch):
    """
    Return (start state, its time [s, node clock], whether it is the plan's rest) or None.

    A goal that arrives while plan moves the robot cannot start from the measured state: its
    plan would be stamped when it is published, a solve later, and the robot has moved on
    along plan meanwhile, so the reference would jump back (a Panda goal solved in 0.33 s
    jumped it by 0.37 rad).  It starts on plan instead, at its node at or after now + lead,
    from the plan's state there while the robot is within stitch of plan, else the measured
    state predicted to it (cycle_start_state; stitch < 0: GOAL_STITCH for every model, as a
    goal's start should continue the commanded reference); its plan applies from that node's
    time, and the robot follows plan until then.  When plan ends before now + lead: its final
    state, at rest from its end; so also when it is over and the newest measured state is
    from before its end.  None (the measured state is the start) when no measured state is
    known or it is at rest, and when plan is a braking stop (braking_rest_start), of another
    model (nx), or over by the measured state.
    """
    if plan is None or plan.braking or plan.states.shape[1] != nx:
        return None
    if measured is None or np.shape(measured) != (nx,) or measured_time is None \
            or at_rest(plan.model, measured):
        return None
    measured_at = plan.elapsed(state_time(measured_time, now))
    elapsed = plan.elapsed(now)
    if elapsed >= plan.duration and measured_at >= plan.duration:
        return None
    start_at = elapsed + float(lead)
    if start_at >= plan.duration:
        return np.array(plan.states[-1], dtype=float), plan.start + plan.duration, True
    node = int(np.searchsorted(plan.times, max(start_at, 0.0)))
    start_at = float(plan.times[node])
    if measured_at < 0.0 or measured_at > start_at:
        # Measured before plan started (or stamped oddly): plan's own state there.
        return np.array(plan.states[node], dtype=float), plan.start + start_at, False
    deviation = plan.deviation(measured, measured_at)
    start = cycle_start_state(plan, measured, measured_at, start_at, deviation,
                              GOAL_STITCH if stitch < 0.0 else stitch)
    return np.asarray(start, dtype=float), plan.start + start_at, False


def braking_rest_start(plan, now, nx, measured=None, measured_time=None, rows=None, lead=0.0):
    """
    Return (rest state, rest time [s, node clock]) of a braking stop executing at now, or None.

    A goal solved while the robot brakes (the replan after a stop, or a new goal) starts where
    the stop rests, and its plan applies from the rest time on: the measured state is moving,
    and a plan from it would start where the robot was when the solve began, however long the
    solve takes (on a loaded machine, hundreds of milliseconds of braking later).  The stop's
    rest is where the plant will be, as long as the robot follows the stop: None when a
    measured state (at measured_time) is more than BRAKING_FOLLOW_TOL off it (a plant reset,
    a robot moved by hand), and when plan is no braking stop or its state is not of size nx
    (another model).  After the stop's end the robot may still be moving (a short stop the
    controller overshot and now pulls back to its held end): the rest holds, from now, until a
    measured state is at rest (then that is the start) or none is known.

    rows (the true circles, planar models): a stop whose path from now enters one (a circle
    that moved into it after the stop was made) does not rest anywhere a plan may start
    from: the start is then the stop's node at or after now + lead [s], and its time, so
    that the plan steers out while the robot still moves (with the recovery margin when it
    is inside the obstacle margin there).
    """
    if plan is None or not plan.braking or plan.states.shape[1] != nx:
        return None
    known = measured is not None and np.shape(measured) == (nx,) and measured_time is not None
    if known and plan.deviation(measured, plan.elapsed(state_time(measured_time, now))) \
            > BRAKING_FOLLOW_TOL:
        return None
    rest = np.array(plan.states[-1], dtype=float)
    elapsed = plan.elapsed(now)
    if elapsed < plan.duration:
        if rows is not None and true_conflict_time(plan, rows, elapsed) is not None:
            k = min(int(np.searchsorted(plan.times, elapsed + lead)), len(plan.times) - 1)
            return np.array(plan.states[k], dtype=float), plan.start + float(plan.times[k])
        return rest, plan.start + plan.duration
    if not known or at_rest(plan.model, measured):
        return None
    return rest, float(now)


def stale_state(received, now, max_age):
    """
    Return why a measured state received at node-clock time received [s] is stale, or None.

    Stale: received more than max_age [s] before now, or after now (the clock went back, a
    simulation reset: the state is from before it).  None also when nothing was received
    (received None: goals then start from initial_state).
    """
    if received is None:
        return None
    age = now - received
    if 0.0 <= age <= max_age:
        return None
    when = (f'{age:.3g} s ago' if age > 0.0
            else f'{-age:.3g} s after now (the node clock went back)')
    return (f'no recent joint_states: the newest was received {when} (max_state_age = '
            f'{max_age:g} s), so the robot may not be where it was; planning from it could start '
            'a motion from the wrong state')


def recovery_margin(model, start, rows, margin, step=0.0):
    """
    Return the obstacle margin of a replan from start when start is inside the margin, or None.

    For the replan after a stop: braking may end inside the margin (or pass inside it on its
    way into a circle that moved: braking_rest_start), and the plan out of there may use half
    the start's true clearance as its margin.  step [s] > 0: also the state one Euler step of
    that length along the start's velocity, which no control changes (a start just outside
    the margin moving into it: a start on the executing plan).  None when they clear the
    margin or one is inside a circle.
    """
    if np.shape(start) != (model.nx,):
        return None
    states = np.array([start, start], dtype=float)
    n2 = 2 * model.n_joints
    states[1, 0:n2:2] += max(step, 0.0) * states[1, 1:n2:2]
    gap = _clearance(model, states, rows)
    if gap is None or gap >= margin or gap <= 0.0:
        return None
    return 0.5 * gap


# Outcomes of a goal's solve from the executing plan that are solved again with retry_margin.
RETRIED = (Status.STALLED, Status.MAX_ITERATIONS)


def retry_margin(model, start, rows, margin):
    """
    Return the obstacle margin of a failed goal's second solve from the executing plan, or None.

    A start predicted along the plan for a robot lagging it can move into the margin faster
    than any control stops it (the paper's robot 44 ms behind its plan, 2 mm outside the
    margin: the best plan passes 0.3-1 mm inside it, so the solve stalls): the second solve
    keeps half the margin (half the start's true clearance when that is smaller).  None
    without obstacles, with a start inside a circle or a zero margin.
    """
    if not margin > 0.0 or np.shape(start) != (model.nx,):
        return None
    gap = _clearance(model, np.asarray(start, dtype=float)[None, :], rows)
    if gap is None or gap <= 0.0:
        return None
    return 0.5 * min(margin, gap)


def _clearance(model, states, rows):
    """Return the least true clearance [m] of states (K, nx) from circles rows, None if none."""
    rows = np.asarray(rows, dtype=float).reshape(-1, 3)
    if not len(rows):
        return None
    return float(np.min(model_clearance(model, states, rows)))
