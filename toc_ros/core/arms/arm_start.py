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
        within = (np.all(np.abs(torques) <= arm.effort)
                  and np.all(np.abs(states[:, n:]) <= arm.velocity))
        if within or t_f > 60.0:
            break
        t_f *= 1.05
    return float(t_f)


def cold_start(arm, x0, x_goal, n_intervals):
    """(states (N + 1, 2n), torques (N, n), t_f) of the line start."""
    t_f = line_time(arm, x0, x_goal)
    states = cubic_path(x0, x_goal, t_f, n_intervals)
    torques = np.clip(path_torques(arm, states, t_f), -arm.effort, arm.effort)
    return states, torques, t_f


def bent_path(x0, x_goal, t_f, n_intervals, offsets):
    """
    Return cubic_path plus offsets (n,) * sin(pi s) on the positions, velocities to match.

    A detour through a shifted midpoint: the reference's perturbed start.
    """
    n = len(x0) // 2
    states = cubic_path(x0, x_goal, t_f, n_intervals)
    s = np.linspace(0.0, 1.0, n_intervals + 1)[:, None]
    states[:, :n] += np.sin(np.pi * s) * offsets[None, :]
    states[:, n:] += np.pi * np.cos(np.pi * s) * offsets[None, :] / t_f
    return states


def detour_offsets(arm, evaluator, x0, x_goal, n_intervals, clearance=0.02, iterations=60):
    """
    Offsets (n,) for bent_path whose nodes clear every obstacle by clearance [m], or None.

    Repeated minimum-norm corrections at the worst node along its worst row's gradient,
    scaled by the node's sin(pi s); positions must stay within the joint limits.
    """
    n = arm.n
    s = np.linspace(0.0, 1.0, n_intervals + 1)
    bend = np.sin(np.pi * s)
    offsets = np.zeros(n)
    line = cubic_path(x0, x_goal, 1.0, n_intervals)[:, :n]
    for _ in range(iterations):
        q = line + bend[:, None] * offsets[None, :]
        if np.any(q < arm.lower) or np.any(q > arm.upper):
            return None
        values, grads, _ = evaluator.clearance_terms(q)
        worst = np.unravel_index(np.argmin(values), values.shape)
        if values[worst] >= clearance:
            return offsets
        k = worst[0]
        if bend[k] <= 0.0:
            return None
        grad = grads[worst] * bend[k]
        offsets = offsets + 1.2 * (clearance - values[worst]) * grad / max(grad @ grad, 1e-12)
    return None


def detour_start(arm, evaluator, x0, x_goal, n_intervals):
    """(states, torques, t_f) of a bent path clear of the obstacles, or None."""
    offsets = detour_offsets(arm, evaluator, x0, x_goal, n_intervals)
    if offsets is None:
        return None
    n = arm.n
    dq = np.abs(x_goal[:n] - x0[:n]) + np.pi * np.abs(offsets)
    t_f = max(1.5 * float(np.max(dq / arm.velocity)), 0.05)
    for _ in range(200):
        states = bent_path(x0, x_goal, t_f, 50, offsets)
        torques = path_torques(arm, states, t_f)
        within = (np.all(np.abs(torques) <= arm.effort)
                  and np.all(np.abs(states[:, n:]) <= arm.velocity))
        if within or t_f > 60.0:
            break
        t_f *= 1.05
    states = bent_path(x0, x_goal, t_f, n_intervals, offsets)
    return states, np.clip(path_torques(arm, states, t_f), -arm.effort, arm.effort), float(t_f)
