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

*Validation* (validate_trajectory_msg): the goal names every controller joint once, in any
order (partial goals are not allowed, JTC's default) else INVALID_JOINTS; it has points; the
last point's velocities are zero (|v| <= float32 epsilon; allow_nonzero_velocity_at_trajectory_end
is false by default); time_from_start strictly increasing; positions for every joint at every
point, velocities/accelerations/effort either absent or one per joint (else INVALID_GOAL); a
non-zero header.stamp whose trajectory ends before now is OLD_HEADER_TIMESTAMP.  Here also:
values must be finite and the first time_from_start >= 0 (INVALID_GOAL).  JTC *rejects* such
goals (a rejected goal has no result in ROS 2); this module reports the code instead, so that
the action server can return it in the result (ROS 1's controller did that).

*Sampling* (Trajectory::sample, interpolate_between_points): header.stamp is the time of
time_from_start = 0; a zero stamp means the time of the first sample.  Between two points:
linear if either lacks velocities, cubic with positions + velocities, quintic with
accelerations too; effort (the feed-forward) linear.  Before the first point, the same
interpolation from the state at the first sample ("the point before the trajectory"): with
``interpolate_from_desired_state`` the reference the controller was following then (no jump in
the commanded reference: what MPC-style replanning needs), else the measured state (JTC's
default).  Missing velocities/accelerations of that state count as zero when the first point
has them.  After the last point: the last point (velocities, accelerations, effort as given).

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

SUCCESSFUL = 0
INVALID_GOAL = -1
INVALID_JOINTS = -2
OLD_HEADER_TIMESTAMP = -3
PATH_TOLERANCE_VIOLATED = -4
GOAL_TOLERANCE_VIOLATED = -5
# Not a control_msgs code: the goal was cancelled on request (the action's CANCELED status).
CANCELED = None
NS = 1_000_000_000
FLOAT32_EPSILON = float(np.finfo(np.float32).eps)
ERASE = -1.0
PREEMPTED = 'Current goal preempted by new incoming action.'
STOPPED_VELOCITY_TOLERANCE = 0.01


class GoalError(ValueError):
    """A goal that cannot be executed: error_code (the control_msgs constant) and the reason."""

    def __init__(self, code, text):
        super().__init__(text)
        self.code = code
        self.text = text


@dataclasses.dataclass
class Point:
    """One trajectory point in the controller's joint order; absent fields are None."""

    positions: np.ndarray
    velocities: np.ndarray = None
    accelerations: np.ndarray = None
    effort: np.ndarray = None


def _ns(duration):
    """Integer nanoseconds of a Duration or Time-like object (sec, nanosec)."""
    return int(duration.sec) * NS + int(duration.nanosec)


def validate(msg, joint_names, now_ns, allow_nonzero_velocity_at_end=False):
    """
    Return the Trajectory of a JointTrajectory-like msg, or raise GoalError.

    joint_names: the controller's joints (the order of the returned arrays).  now_ns: the
    current time in the stamps' time base.  msg needs joint_names, header.stamp (sec,
    nanosec) and points with positions, velocities, accelerations, effort, time_from_start.
    """
    names = [str(n) for n in msg.joint_names]
    expected = list(joint_names)
    if not names:
        raise GoalError(INVALID_JOINTS, 'empty joint names on incoming trajectory')
    if len(names) != len(expected) or sorted(names) != sorted(expected):
        unknown = [n for n in names if n not in expected]
        missing = [n for n in expected if n not in names]
        raise GoalError(INVALID_JOINTS, f'joints on incoming trajectory {names} do not match '
                                        f'the controller joints {expected} (unknown: {unknown}, '
                                        f'missing: {missing}, each joint exactly once)')
    points = list(msg.points)
    if not points:
        raise GoalError(INVALID_GOAL, 'empty trajectory received')
    last_velocities = list(points[-1].velocities)
    if not allow_nonzero_velocity_at_end and any(
            abs(v) > FLOAT32_EPSILON for v in last_velocities):
        raise GoalError(INVALID_GOAL, f'velocity of the last trajectory point is not zero: '
                                      f'{last_velocities}')
    stamp = _ns(msg.header.stamp)
    times = [_ns(p.time_from_start) for p in points]
    if stamp != 0 and stamp + times[-1] < now_ns:
        raise GoalError(OLD_HEADER_TIMESTAMP,
                        f'trajectory with non-zero start time {stamp / NS:.9f} s ends in the past '
                        f'({(stamp + times[-1]) / NS:.9f} s < now {now_ns / NS:.9f} s)')
    if times[0] < 0:
        raise GoalError(INVALID_GOAL, f'time_from_start of the first point is negative '
                                      f'({times[0] / NS} s)')
    for i in range(1, len(times)):
        if times[i] <= times[i - 1]:
            raise GoalError(INVALID_GOAL, f'time between points {i - 1} and {i} is not strictly '
                                          f'increasing, it is {times[i - 1] / NS} and '
                                          f'{times[i] / NS} s respectively')
    order = [names.index(n) for n in expected]

    def field(values, what, i, required):
        values = list(values)
        if not values and not required:
            return None
        if len(values) != len(names):
            raise GoalError(INVALID_GOAL, f'mismatch between joint_names size ({len(names)}) '
                                          f'and {what} ({len(values)}) at point #{i}')
        array = np.asarray(values, dtype=float)[order]
        if not np.all(np.isfinite(array)):
            raise GoalError(INVALID_GOAL, f'non-finite {what} at point #{i}')
        return array

    converted = [Point(field(p.positions, 'positions', i, True),
                       field(p.velocities, 'velocities', i, False),
                       field(p.accelerations, 'accelerations', i, False),
                       field(p.effort, 'effort', i, False)) for i, p in enumerate(points)]
    return Trajectory(np.array(times, dtype=np.int64), converted,
                      None if stamp == 0 else stamp)


def interpolate(t, duration, a, b):
    """
    Interpolate as JTC's interpolate_between_points: (q, dq, ddq, effort) at t [s].

    t is the time since point a, duration the time from a to b.  Linear / cubic / quintic as
    the two points' fields allow; t is clamped to [0, duration], and a clamped sample is
    linear (as in JTC).
    """
    has_velocity = a.velocities is not None and b.velocities is not None
    has_accel = a.accelerations is not None and b.accelerations is not None
    if t < 0.0:
        t, has_velocity, has_accel = 0.0, False, False
    if t > duration:
        t, has_velocity, has_accel = duration, False, False
    n = a.positions.shape[0]
    zero = np.zeros(n)
    effort = zero
    if a.effort is not None and b.effort is not None:
        slope = (b.effort - a.effort) / duration if duration != 0.0 else zero
        effort = a.effort + t * slope
    p0, p1 = a.positions, b.positions
    if not has_velocity and not has_accel:
        slope = (p1 - p0) / duration if duration != 0.0 else zero
        return p0 + t * slope, slope.copy(), zero, effort
    T = duration
    v0, v1 = a.velocities, b.velocities
    if not has_accel:
        c2 = (-3.0 * p0 + 3.0 * p1 - 2.0 * v0 * T - v1 * T) / T ** 2 if T else zero
        c3 = (2.0 * p0 - 2.0 * p1 + v0 * T + v1 * T) / T ** 3 if T else zero
        return (p0 + v0 * t + c2 * t ** 2 + c3 * t ** 3, v0 + 2.0 * c2 * t + 3.0 * c3 * t ** 2,
                2.0 * c2 + 6.0 * c3 * t, effort)
    a0, a1 = a.accelerations, b.accelerations
    c2 = 0.5 * a0
    if T:
        c3 = (-20.0 * p0 + 20.0 * p1 - 3.0 * a0 * T ** 2 + a1 * T ** 2 - 12.0 * v0 * T
              - 8.0 * v1 * T) / (2.0 * T ** 3)
        c4 = (30.0 * p0 - 30.0 * p1 + 3.0 * a0 * T ** 2 - 2.0 * a1 * T ** 2 + 16.0 * v0 * T
              + 14.0 * v1 * T) / (2.0 * T ** 4)
        c5 = (-12.0 * p0 + 12.0 * p1 - a0 * T ** 2 + a1 * T ** 2 - 6.0 * v0 * T
              - 6.0 * v1 * T) / (2.0 * T ** 5)
    else:
        c3 = c4 = c5 = zero
    return (p0 + v0 * t + c2 * t ** 2 + c3 * t ** 3 + c4 * t ** 4 + c5 * t ** 5,
            v0 + 2.0 * c2 * t + 3.0 * c3 * t ** 2 + 4.0 * c4 * t ** 3 + 5.0 * c5 * t ** 4,
            2.0 * c2 + 6.0 * c3 * t + 12.0 * c4 * t ** 2 + 20.0 * c5 * t ** 3, effort)


@dataclasses.dataclass
class Sample:
    """A sampled reference: desired state and effort, and where in the trajectory it lies."""

    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray
    effort: np.ndarray
    segment: int        # -1: before the first point; i: between points i and i+1; last: after


class Trajectory:
    """A validated trajectory: times (ns from its start), points, start time (None: now)."""

    def __init__(self, times_ns, points, start_ns=None):
        self.times_ns = np.asarray(times_ns, dtype=np.int64)
        self.points = points
        self.start_ns = start_ns
        self.before_ns = None
        self.before = None

    @property
    def last(self):
        """Index of the last point."""
        return len(self.points) - 1

    def end_ns(self):
        """Time of the last point (the start must be known)."""
        return self.start_ns + int(self.times_ns[-1])

    def begin(self, t_ns, state):
        """First sample at t_ns from state (a Point): the start if none, the point before."""
        if self.start_ns is None:
            self.start_ns = int(t_ns)
        first = self.points[0]
        n = first.positions.shape[0]
        zero = np.zeros(n)
        velocities = state.velocities
        if velocities is None and first.velocities is not None:
            velocities = zero
        accelerations = state.accelerations
        if accelerations is None and first.accelerations is not None:
            accelerations = zero
        # JTC's deduce_from_derivatives: a missing effort is zero for the interpolation.
        effort = zero if state.effort is None else state.effort
        self.before_ns = int(t_ns)
        self.before = Point(np.array(state.positions, dtype=float), velocities, accelerations,
                            effort)

    def sample(self, t_ns):
        """Sample at t_ns (after begin)."""
        first_ns = self.start_ns + int(self.times_ns[0])
        if t_ns < first_ns:
            a = self.before
            b = self._with_effort(self.points[0])
            values = interpolate((t_ns - self.before_ns) / NS, (first_ns - self.before_ns) / NS,
                                 a, b)
            return Sample(*values, segment=-1)
        since = t_ns - self.start_ns
        i = int(np.searchsorted(self.times_ns, since, side='right')) - 1
        if i < self.last:
            a, b = self._with_effort(self.points[i]), self._with_effort(self.points[i + 1])
            values = interpolate((since - int(self.times_ns[i])) / NS,
                                 (int(self.times_ns[i + 1]) - int(self.times_ns[i])) / NS, a, b)
            return Sample(*values, segment=i)
        point = self.points[-1]
        zero = np.zeros(point.positions.shape[0])
        return Sample(point.positions.copy(),
                      zero if point.velocities is None else point.velocities.copy(),
                      zero if point.accelerations is None else point.accelerations.copy(),
                      zero if point.effort is None else point.effort.copy(), segment=self.last)

    @staticmethod
    def _with_effort(point):
        if point.effort is not None:
            return point
        return dataclasses.replace(point, effort=np.zeros(point.positions.shape[0]))


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
    goal_time = _ns(goal.goal_time_tolerance) / NS
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
