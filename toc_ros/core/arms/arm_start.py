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
Cold start of the arm interior point: a cubic joint path from start to goal and its time.

The joints follow cubic Hermite curves that match both ends' positions and velocities; the
controls are the torques (inverse dynamics, pinocchio.rnea) that make the Euler steps of the
velocities follow the curve, clipped to the efforts.  The final time is the shortest on a 5 %
grid (from 1.5 times the slowest joint's distance over its velocity limit) whose velocities
and torques stay within the limits.  The CasADi reference (toc_ros/bench/arm_reference.py)
builds its line start by the same recipe, so both start from the same point.

The straight path may pass through an obstacle: the interior point then starts infeasible
(slacks of the sphere rows positive, the rows violated) and has to find the way around; no
detour is invented here.
"""

import numpy as np
import pinocchio as pin


def cubic_path(x0, x_goal, t_f, n_intervals):
    """States (N + 1, 2n) on the cubic Hermite curves from x0 to x_goal over t_f."""
    n = len(x0) // 2
    s = np.linspace(0.0, 1.0, n_intervals + 1)[:, None]
    q0, qg = x0[:n], x_goal[:n]
    v0, vg = x0[n:] * t_f, x_goal[n:] * t_f
    h00, h10 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s
    h01, h11 = -2 * s**3 + 3 * s**2, s**3 - s**2
    d00, d10 = 6 * s**2 - 6 * s, 3 * s**2 - 4 * s + 1
    d01, d11 = -6 * s**2 + 6 * s, 3 * s**2 - 2 * s
    q = h00 * q0 + h10 * v0 + h01 * qg + h11 * vg
    dq = (d00 * q0 + d10 * v0 + d01 * qg + d11 * vg) / t_f
    states = np.hstack([q, dq])
    states[0], states[-1] = x0, x_goal
    return states


def path_torques(arm, states, t_f):
    """Torques (N, n) whose Euler velocity steps follow states (unclipped)."""
    n = arm.n
    n_int = states.shape[0] - 1
    h = t_f / n_int
    acc = (states[1:, n:] - states[:-1, n:]) / h
    return np.array([pin.rnea(arm.model, arm.data, states[k, :n], states[k, n:], acc[k])
                     for k in range(n_int)])


def line_time(arm, x0, x_goal, n_intervals=50):
    """Shortest final time on the 5 % grid whose cubic path is within the limits (<= 60 s)."""
    n = arm.n
    dq = np.abs(x_goal[:n] - x0[:n])
    t_f = max(1.5 * float(np.max(dq / arm.velocity)), 0.05)
    for _ in range(200):
        states = cubic_path(x0, x_goal, t_f, n_intervals)
        torques = path_torques(arm, states, t_f)
        if (np.all(np.abs(torques) <= arm.effort) and np.all(np.abs(states[:, n:])
                                                              <= arm.velocity)) or t_f > 60.0:
            break
        t_f *= 1.05
    return float(t_f)


def cold_start(arm, x0, x_goal, n_intervals):
    """(states (N + 1, 2n), torques (N, n), t_f) of the line start."""
    t_f = line_time(arm, x0, x_goal)
    states = cubic_path(x0, x_goal, t_f, n_intervals)
    torques = np.clip(path_torques(arm, states, t_f), -arm.effort, arm.effort)
    return states, torques, t_f


def push_out_of_obstacles(arm, evaluator, states, clearance=0.01, iterations=100):
    """
    Positions of states moved (node by node, joints within limits) until every sphere row
    is >= clearance [m]: repeated minimum-norm corrections along the worst row's gradient.

    Returns (states with the new positions and velocities by central differences scaled to
    the old time grid, True if every node is clear).  The end nodes are left as they are.
    """
    n = arm.n
    q = states[:, :n].copy()
    inner = q[1:-1]
    low = np.where(np.isfinite(arm.lower), arm.lower, -np.inf)
    high = np.where(np.isfinite(arm.upper), arm.upper, np.inf)
    for _ in range(iterations):
        values, grads, _ = evaluator.clearance_terms(inner)
        if not values.size or values.min() >= clearance:
            break
        worst = np.argmin(values, axis=1)
        rows = np.arange(inner.shape[0])
        g = values[rows, worst]
        grad = grads[rows, worst]
        need = np.maximum(clearance - g, 0.0) * 1.2
        norm2 = np.maximum(np.sum(grad * grad, axis=1), 1e-12)
        inner += (need / norm2)[:, None] * grad
        inner[:] = np.clip(inner, low, high)
    clear = (not evaluator.n_pairs) or evaluator.clearances(inner).min() >= 0.5 * clearance
    out = states.copy()
    out[1:-1, :n] = inner
    return out, bool(clear)


def retime(arm, states, x0, x_goal, n_intervals):
    """(states, torques, t_f) along the positions of states, timed like line_time."""
    n = arm.n
    q = states[:, :n]
    dist = np.max(np.sum(np.abs(np.diff(q, axis=0)), axis=0) / arm.velocity)
    t_f = max(1.5 * float(dist), 0.05)
    for _ in range(200):
        h = t_f / n_intervals
        dq = np.gradient(q, h, axis=0)
        out = np.hstack([q, dq])
        out[0], out[-1] = x0, x_goal
        torques = path_torques(arm, out, t_f)
        if (np.all(np.abs(torques) <= arm.effort) and np.all(np.abs(out[:, n:])
                                                              <= arm.velocity)) or t_f > 60.0:
            break
        t_f *= 1.05
    return out, np.clip(torques, -arm.effort, arm.effort), float(t_f)
