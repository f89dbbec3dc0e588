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
JointTrajectoryController's semantics for control_msgs/action/FollowJointTrajectory, ROS-free.

This mirrors ros2_controllers' joint_trajectory_controller (jazzy branch: trajectory.cpp,
joint_trajectory_controller.cpp, tolerances.hpp) for a controller with an effort command
interface and position + velocity state interfaces, as the simulated plant is:

*Validation* and *sampling*: jtc_trajectory.py.

*Tolerances* (get_segment_tolerances, check_state_tolerance_per_joint): defaults per joint
(path position, goal position, stopped velocity 0.01 rad/s, goal_time 0); a goal's value > 0
overrides, -1 erases (0 = not enforced), 0 keeps the default, another negative value or an
unknown joint name makes the whole goal use the defaults.  Errors are desired - actual; the
acceleration error is 0 (no acceleration state interface), so acceleration tolerances never
trip.  While a segment runs (and on the first sample), a path tolerance violation aborts
with PATH_TOLERANCE_VIOLATED and holds the current position.  After the last point: within
the goal tolerances → SUCCESSFUL and the last point is held; outside them, with goal_time > 0
and more than goal_time after the end → GOAL_TOLERANCE_VIOLATED and the current position is
held; with goal_time 0 the goal waits (JTC: "potentially infinite").

*Replacement* (goal_accepted_callback, preempt_active_goal): a new valid goal aborts the
active one with INVALID_GOAL "Current goal preempted by new incoming action." and starts from
the point before (above) at the next update; an invalid goal leaves the active one alone.  A
cancel holds the current position.

One deliberate difference: JTC stores as "last commanded state" the sample one control period
ahead (command_next_) with the current time; here the desired state at the update's own time
is stored, so that a trajectory joined to it continues the reference exactly.
"""

import dataclasses
import math

import numpy as np
# The codes, validation and sampling are used through this module too (fjt.validate, ...).
from toc_ros.plant.jtc_trajectory import (  # noqa: F401
    CANCELED, FLOAT32_EPSILON, GOAL_TOLERANCE_VIOLATED, GoalError, INVALID_GOAL, INVALID_JOINTS,
    nanoseconds, NS, OLD_HEADER_TIMESTAMP, PATH_TOLERANCE_VIOLATED, Point, Sample, SUCCESSFUL,
    Trajectory, validate)

ERASE = -1.0
PREEMPTED = 'Current goal preempted by new incoming action.'
STOPPED_VELOCITY_TOLERANCE = 0.01


@dataclasses.dataclass
class Tolerances:
    """Per-joint tolerances (0: not enforced) and the goal time tolerance [s]."""

    path_position: np.ndarray
    path_velocity: np.ndarray
    path_acceleration: np.ndarray
    goal_position: np.ndarray
    goal_velocity: np.ndarray
    goal_acceleration: np.ndarray
    goal_time: float = 0.0

    @classmethod
    def defaults(cls, n, path_position=0.0, goal_position=0.0,
                 stopped_velocity=STOPPED_VELOCITY_TOLERANCE, goal_time=0.0):
        """Build JTC's defaults from its constraints.* parameters (scalar or per joint)."""

        def per_joint(value):
            return np.broadcast_to(np.asarray(value, dtype=float), (n,)).copy()
        zero = np.zeros(n)
        return cls(per_joint(path_position), zero.copy(), zero.copy(), per_joint(goal_position),
                   per_joint(stopped_velocity), zero.copy(), float(goal_time))

    def copy(self):
        """Deep copy."""
        return Tolerances(*(np.array(getattr(self, f.name)) if f.name != 'goal_time'
                            else self.goal_time for f in dataclasses.fields(self)))


def _resolve(default, value):
    """Resolve as JTC's resolve_tolerance_source: > 0 overrides, -1 erases, 0 default."""
    if value > 0.0:
        return float(value)
    if abs(value - ERASE) < FLOAT32_EPSILON:
        return 0.0
    if value < 0.0 or not math.isfinite(value):
        raise ValueError(f'illegal tolerance value {value}')
    return default


def goal_tolerances(defaults, goal, joint_names):
    """
    Return (tolerances, warning) for a FollowJointTrajectory goal-like object.

    goal needs path_tolerance and goal_tolerance (lists of name, position, velocity,
    acceleration) and goal_time_tolerance (sec, nanosec).  As JTC: an illegal value or an
    unknown joint makes the whole goal use the defaults; warning says why (else None).
    """
    active = defaults.copy()
    names = list(joint_names)
    goal_time = nanoseconds(goal.goal_time_tolerance) / NS
    try:
        active.goal_time = _resolve(defaults.goal_time, goal_time)
    except ValueError:
        return defaults.copy(), f'illegal goal_time_tolerance {goal_time}: using the defaults'
    for kind in ('path', 'goal'):
        for tolerance in getattr(goal, f'{kind}_tolerance'):
            if tolerance.name not in names:
                return defaults.copy(), (f'joint {tolerance.name!r} in goal.{kind}_tolerance '
                                         'does not exist: using the default tolerances')
            i = names.index(tolerance.name)
            for field in ('position', 'velocity', 'acceleration'):
                array = getattr(active, f'{kind}_{field}')
                try:
                    array[i] = _resolve(getattr(defaults, f'{kind}_{field}')[i],
                                        float(getattr(tolerance, field)))
                except ValueError:
                    return defaults.copy(), (
                        f'joint {tolerance.name!r} in goal.{kind}_tolerance has an invalid '
                        f'{field} tolerance: using the default tolerances')
    return active, None


def violations(tolerance_position, tolerance_velocity, tolerance_acceleration, error_position,
               error_velocity, joint_names):
    """Descriptions of the joints whose |error| exceeds an enforced (> 0) tolerance."""
    found = []
    for i, name in enumerate(joint_names):
        for what, tol, err in (('position', tolerance_position[i], error_position[i]),
                               ('velocity', tolerance_velocity[i], error_velocity[i])):
            if tol > 0.0 and abs(err) > tol:
                found.append(f'{name} {what} error {err:.6g} (tolerance {tol:.6g})')
    # The acceleration error is zero (no acceleration state): its tolerance never trips.
    del tolerance_acceleration
    return found


@dataclasses.dataclass
class Feedback:
    """FollowJointTrajectory feedback: desired, actual and error (desired - actual)."""

    time_ns: int
    desired: Sample
    actual_positions: np.ndarray
    actual_velocities: np.ndarray
    error_positions: np.ndarray
    error_velocities: np.ndarray


@dataclasses.dataclass
class Outcome:
    """How a goal ended: code (control_msgs constant, CANCELED for a cancel) and the text."""

    goal: object
    code: object
    text: str


class TrajectoryFollower:
    """
    The controller's update loop for action goals: one active trajectory, tolerance checks.

    Call follow() for a validated goal (it preempts the active one), then update() once per
    control step with the measured state and the reference the plant followed until then;
    take_outcomes() returns the goals that ended.
    """

    def __init__(self, joint_names, interpolate_from_desired_state=True):
        self.joint_names = list(joint_names)
        self.interpolate_from_desired_state = bool(interpolate_from_desired_state)
        self._trajectory = None      # the active Trajectory, or the hold point's
        self._goal = None            # the goal being executed (None: holding, no goal)
        self._tolerances = None
        self._holding = True
        self._first = False
        self._pending = None         # (trajectory, tolerances, goal) until the next update
        self._outcomes = []
        self.feedback = None

    @property
    def active(self):
        """Return True while a trajectory (not a hold) is followed or pending."""
        return self._pending is not None or (self._trajectory is not None
                                             and not self._holding)

    @property
    def trajectory(self):
        """Return the trajectory being followed or held (None before the first goal)."""
        return self._trajectory

    @property
    def goal(self):
        """Return the goal being executed or pending, or None."""
        return self._pending[2] if self._pending is not None else self._goal

    def follow(self, trajectory, tolerances, goal):
        """Start trajectory at the next update; the active (or pending) goal is preempted."""
        self._finish(INVALID_GOAL, PREEMPTED)
        if self._pending is not None:
            self._outcomes.append(Outcome(self._pending[2], INVALID_GOAL, PREEMPTED))
        self._pending = (trajectory, tolerances, goal)

    def cancel(self, goal, actual_positions):
        """Cancel the goal if it is the active or pending one: hold the current position."""
        if goal is None:
            return False
        if self._pending is not None and self._pending[2] is goal:
            self._pending = None
            self._outcomes.append(Outcome(goal, CANCELED, 'canceled'))
            return True
        if self._goal is goal:
            self._finish(CANCELED, 'canceled')
            self._hold(actual_positions)
            return True
        return False

    def stop(self, code, text, actual_positions=None):
        """End the active and pending goals with code/text; hold actual_positions if given."""
        self._finish(code, text)
        if self._pending is not None:
            self._outcomes.append(Outcome(self._pending[2], code, text))
            self._pending = None
        if actual_positions is not None:
            self._hold(actual_positions)

    def take_outcomes(self):
        """Goals that ended since the last call, oldest first."""
        outcomes, self._outcomes = self._outcomes, []
        return outcomes

    def reference(self, t_ns):
        """Return the reference at t_ns without checks (None before the first goal)."""
        if self._trajectory is None:
            return None
        return self._trajectory.sample(t_ns)

    def holds(self, t_ns):
        """Tell whether the reference holds a position at t_ns (a hold, or after the end)."""
        return self._trajectory is None or self._holding or t_ns >= self._trajectory.end_ns()

    def update(self, t_ns, actual_positions, actual_velocities, reference_before=None):
        """
        One control step at t_ns: return the desired Sample; check the tolerances.

        reference_before: (positions, velocities, accelerations or None, effort or None) the
        plant was following until now, used when a pending trajectory starts here with
        interpolate_from_desired_state.
        """
        q = np.asarray(actual_positions, dtype=float)
        v = np.asarray(actual_velocities, dtype=float)
        if self._pending is not None:
            trajectory, self._tolerances, self._goal = self._pending
            self._pending = None
            if self.interpolate_from_desired_state and reference_before is not None:
                state = Point(*(None if x is None else np.asarray(x, dtype=float)
                                for x in reference_before))
            else:
                state = Point(q.copy(), v.copy())
            trajectory.begin(t_ns, state)
            self._trajectory = trajectory
            self._holding = False
            self._first = True
        if self._trajectory is None:
            return None
        desired = self._trajectory.sample(t_ns)
        error_q = desired.positions - q
        error_v = desired.velocities - v
        self.feedback = Feedback(int(t_ns), desired, q.copy(), v.copy(), error_q, error_v)
        if self._holding:
            return desired
        tol = self._tolerances
        before_last = desired.segment < self._trajectory.last
        if before_last or self._first:
            found = violations(tol.path_position, tol.path_velocity, tol.path_acceleration,
                               error_q, error_v, self.joint_names)
            if found:
                self._finish(PATH_TOLERANCE_VIOLATED,
                             'Aborted due to path tolerance violation: ' + '; '.join(found))
                self._hold(q)
                return desired
        self._first = False
        if before_last:
            return desired
        outside = violations(tol.goal_position, tol.goal_velocity, tol.goal_acceleration,
                             error_q, error_v, self.joint_names)
        if not outside:
            self._finish(SUCCESSFUL, 'Goal successfully reached!')
            self._holding = True        # JTC holds the last point, checks no more
            return desired
        late = (t_ns - self._trajectory.end_ns()) / NS
        if tol.goal_time != 0.0 and late > tol.goal_time:
            self._finish(GOAL_TOLERANCE_VIOLATED,
                         f'Aborted due to goal_time_tolerance exceeding by {late:.6f} seconds: '
                         + '; '.join(outside))
            self._hold(q)
        return desired

    def _finish(self, code, text):
        if self._goal is not None:
            self._outcomes.append(Outcome(self._goal, code, text))
            self._goal = None

    def _hold(self, positions):
        """Hold positions from now on (zero velocity and effort), without tolerance checks."""
        positions = np.array(positions, dtype=float)
        hold = Trajectory(np.zeros(1, dtype=np.int64), [Point(positions)], start_ns=0)
        hold.begin(0, Point(positions))
        self._trajectory = hold
        self._holding = True
        self._goal = None
