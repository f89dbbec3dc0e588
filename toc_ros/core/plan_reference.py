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
The motion a published arm plan stands for, and the cubic that reproduces it between points.

Controllers interpolate a JointTrajectory's points (positions, velocities) with a cubic per
segment: ros2_control's JointTrajectoryController does, and so does the plant's reference.
An explicit-Euler plan moves q_{k+1} = q_k + h dq_k (its positions advance by the velocity at
the segment's start) while its velocity changes by h ddq_k.  A cubic through (q_k, dq_k) has
to bend its velocity past both nodes' wherever dq changes: on Panda plans, where a wrist joint
reaches its velocity limit within a step, 1.3-2x the limit.

The motion whose velocity goes linearly from dq_k to dq_{k+1} on every segment (the plan's
acceleration held over the step) passes q_k + h dq_k / 2 at t_k, the middle of the Euler step.
Published at these positions with the node velocities, a cubic per segment is exactly that
motion: its velocity stays between the nodes' (within the limits), it ends at the goal (at
rest), and a plan that starts at a node of an earlier one starts where the earlier one's
reference is there (up to the change of h).  A plan from a moving measured start begins
h dq_0 / 2 ahead of it.  RK4 plans and braking stops have their nodes on the motion and are
published as they are.

A plan that ends at rest is published ending exactly at rest (``rest_at_end``): a solved plan
reaches its goal within the solver's tolerance, its last velocities up to ~1e-7 rad/s, and
JointTrajectoryController refuses a goal whose last point moves by more than float32's epsilon
(1.2e-7, unless allow_nonzero_velocity_at_trajectory_end).
"""

import numpy as np

# Last velocities at most this [rad/s or m/s] are published as zero: far above a solved plan's
# terminal residual, far below anything a controller could follow.
END_REST_SPEED = 1e-6


def reference_positions(positions, velocities, times, integrator):
    """
    Return the node positions of the motion a plan stands for (see the module docstring).

    positions, velocities: (N + 1, n) of the plan's nodes; times: (N + 1,) [s]; integrator:
    the plan's ('euler' shifts each node by half its step along its velocity, the last by
    half the last step; anything else is returned as it is).
    """
    positions = np.asarray(positions, dtype=float)
    if integrator != 'euler' or positions.shape[0] < 2:
        return positions
    steps = np.diff(np.asarray(times, dtype=float))
    steps = np.append(steps, steps[-1])
    return positions + 0.5 * steps[:, None] * np.asarray(velocities, dtype=float)


def rest_at_end(velocities):
    """Return (velocities with the last row zeroed when within END_REST_SPEED, at rest)."""
    velocities = np.array(velocities, dtype=float)
    at_rest = bool(np.max(np.abs(velocities[-1]), initial=0.0) <= END_REST_SPEED)
    if at_rest:
        velocities[-1] = 0.0
    return velocities, at_rest


def hermite(t0, t1, p0, v0, p1, v1, t):
    """Cubic Hermite position and velocity at t in [t0, t1] (arrays per joint)."""
    h = t1 - t0
    s = (t - t0) / h
    s2, s3 = s * s, s * s * s
    pos = ((2 * s3 - 3 * s2 + 1) * p0 + (s3 - 2 * s2 + s) * h * v0
           + (3 * s2 - 2 * s3) * p1 + (s3 - s2) * h * v1)
    vel = ((6 * s2 - 6 * s) / h * p0 + (3 * s2 - 4 * s + 1) * v0
           + (6 * s - 6 * s2) / h * p1 + (3 * s2 - 2 * s) * v1)
    return pos, vel


def cubic_at(times, positions, velocities, t):
    """Return the cubic Hermite position at t of points (held before the first, after the last)."""
    times = np.asarray(times, dtype=float)
    if t <= times[0]:
        return np.array(positions[0], dtype=float)
    if t >= times[-1]:
        return np.array(positions[-1], dtype=float)
    i = int(np.searchsorted(times, t, side='right')) - 1
    return hermite(times[i], times[i + 1], positions[i], velocities[i], positions[i + 1],
                   velocities[i + 1], t)[0]
