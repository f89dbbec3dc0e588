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
JointTrajectoryController's goal validation and trajectory sampling, ROS-free.

This mirrors ros2_controllers' joint_trajectory_controller (jazzy branch: trajectory.cpp,
joint_trajectory_controller.cpp, tolerances.hpp) for a controller with an effort command
interface and position + velocity state interfaces, as the simulated plant is; its tolerances,
goal replacement and the follower are follow_joint_trajectory.py.

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
"""

import dataclasses

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
# What a JTC without an effort command interface logs when it rejects a goal with efforts.
EFFORT_REFUSED = ('Trajectories with effort fields are only supported for controllers using the '
                  "'effort' command interface.")


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


def nanoseconds(duration):
    """Integer nanoseconds of a Duration or Time-like object (sec, nanosec)."""
    return int(duration.sec) * NS + int(duration.nanosec)


def validate(msg, joint_names, now_ns, allow_nonzero_velocity_at_end=False,
             effort_interface=True):
    """
    Return the Trajectory of a JointTrajectory-like msg, or raise GoalError.

    joint_names: the controller's joints (the order of the returned arrays).  now_ns: the
    current time in the stamps' time base.  msg needs joint_names, header.stamp (sec,
    nanosec) and points with positions, velocities, accelerations, effort, time_from_start.
    effort_interface: the controller commands efforts; without, points with efforts are
    refused (JTC's validate_trajectory_msg).
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
    stamp = nanoseconds(msg.header.stamp)
    times = [nanoseconds(p.time_from_start) for p in points]
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

    if not effort_interface and any(len(p.effort) for p in points):
        raise GoalError(INVALID_GOAL, EFFORT_REFUSED)
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
