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

The straight path may pass through an obstacle, and the interior point (no restoration phase)
often does not find its way out of a start inside one: such a path is bent,
path + offsets * sin(pi s)^2, with offsets found by corrections of the worst clearance
(detour_offsets), for the line and for any other path (arm_solve.py bends the free optimum).
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
    # One batched call on one thread (pin.rnea's bits, without a Python call per node).
    out = np.empty((n, n_int), order='F')
    pin.rneaInParallel(1, pin.ModelPool(arm.model, 1), np.asfortranarray(states[:-1, :n].T),
                       np.asfortranarray(states[:-1, n:].T), np.asfortranarray(acc.T), out)
    return out.T


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


def bend_profile(count):
    """(b, db/ds) of the bend b(s) = sin(pi s)^2 at count nodes s = 0..1."""
    # Flat at both ends, so a bent path keeps the ends' velocities: with sin(pi s) the bend
    # added pi * offset / t_f to the velocities at the (fixed) start and goal, and the first
    # iterations of a bent start went to closing those defects (0.88 rad/s on the Panda past a
    # sphere; benchmarks/RESULTS.md, "Arms: bends flat at the ends").
    s = np.linspace(0.0, 1.0, count)
    return np.sin(np.pi * s) ** 2, np.pi * np.sin(2.0 * np.pi * s)


def bent_states(path, rate, offsets, t_f):
    """
    States (N + 1, 2n) of path + offsets * b(s) over t_f (b: bend_profile).

    path (N + 1, n): positions at s = k / N; rate: their derivative d path / ds.
    """
    bend, slope = bend_profile(path.shape[0])
    q = path + bend[:, None] * offsets[None, :]
    dq = (rate + slope[:, None] * offsets[None, :]) / t_f
    return np.hstack([q, dq])


def _offset_bounds(arm, path, bend, inner=1e-3):
    """Per joint, the offsets [low, high] that keep every node of the bent path in limits."""
    bent = bend > 0.0
    with np.errstate(invalid='ignore'):
        low = np.where(bent[:, None], (arm.lower + inner - path) / np.where(
            bent, bend, 1.0)[:, None], -np.inf)
        high = np.where(bent[:, None], (arm.upper - inner - path) / np.where(
            bent, bend, 1.0)[:, None], np.inf)
    return np.minimum(np.max(low, axis=0), 0.0), np.maximum(np.min(high, axis=0), 0.0)


def _corrected(evaluator, path, bend, low, high, target, offsets, iterations, max_step):
    """Offsets from offsets by worst-row corrections until every row meets target, or None."""
    inner = slice(1, len(bend) - 1)
    for _ in range(iterations):
        q = path[inner] + bend[inner, None] * offsets[None, :]
        values, grads, _ = evaluator.clearance_terms(q)
        deficit = target[None, :] - values
        worst = np.unravel_index(np.argmax(deficit), deficit.shape)
        if deficit[worst] <= 0.0:
            return offsets
        grad = grads[worst] * bend[inner][worst[0]]
        held = (((offsets <= low) & (grad < 0.0)) | ((offsets >= high) & (grad > 0.0)))
        grad = np.where(held, 0.0, grad)
        norm = grad @ grad
        if not norm > 1e-12:
            return None
        step = 1.2 * deficit[worst] * grad / norm
        length = np.linalg.norm(step)
        if length > max_step:
            step *= max_step / length
        offsets = np.clip(offsets + step, low, high)
    return None


def detour_offsets(arm, evaluator, path, count=1, clearance=0.02, iterations=100, restarts=8,
                   max_step=0.3, distinct=0.3):
    """
    Yield up to count offsets (n,) whose bent path (bent_states) clears every obstacle row.

    Each row must clear by clearance, or by half of what it clears at the path's ends when
    that is less (the ends are fixed).  Repeated minimum-norm corrections at the worst node
    along its worst row's gradient, scaled by the node's bend and at most max_step [rad]
    long; a joint whose offset reached the bound that keeps the path within its limits is held
    there.  From zero offsets, then from the mirror image (-o) of each offset o found, then
    from seeded random ones (0.5 rad), restarts in all; offsets within distinct [rad] of one
    found before are not returned again.  The mirror image starts the corrections on the
    other side of the obstacle, which the nearest corrections from zero or a small random
    seed rarely reach (UR10 past a sphere: the other side is 3 % faster).
    """
    n = arm.n
    bend = bend_profile(path.shape[0])[0]
    low, high = _offset_bounds(arm, path, bend)
    ends = evaluator.clearance_terms(path[[0, -1]])[0].min(axis=0)
    target = np.clip(0.5 * ends, 1e-4, clearance)
    rng = np.random.default_rng(0)
    first = np.zeros(n)
    found = []
    mirrored = 0
    for _ in range(restarts + 1):
        offsets = _corrected(evaluator, path, bend, low, high, target, first, iterations,
                             max_step)
        if offsets is not None and all(np.linalg.norm(offsets - other) > distinct
                                       for other in found):
            found.append(offsets)
            yield offsets       # (one at a time: a search often needs only the first)
            if len(found) == count:
                return
        if mirrored < len(found):
            first = np.clip(-found[mirrored], low, high)
            mirrored += 1
        else:
            first = np.clip(rng.normal(0.0, 0.5, n), low, high)


def timed_start(arm, states_at, t_first):
    """
    (states, torques, t_f): states_at(t_f) over the shortest final time >= t_first.

    On a 5 % grid (at most 60 s), the first whose velocities and torques are within the
    limits; the torques clipped to the efforts.
    """
    n = arm.n
    t_f = t_first
    for _ in range(200):
        states = states_at(t_f)
        torques = path_torques(arm, states, t_f)
        within = (np.all(np.abs(torques) <= arm.effort)
                  and np.all(np.abs(states[:, n:]) <= arm.velocity))
        if within or t_f > 60.0:
            break
        t_f *= 1.05
    return states, np.clip(torques, -arm.effort, arm.effort), float(t_f)


def line_detours(arm, evaluator, x0, x_goal, n_intervals, count=1):
    """[(states, torques, t_f)] of up to count bent lines clear of the obstacles."""
    return [make() for make in line_detour_makers(arm, evaluator, x0, x_goal, n_intervals,
                                                  count)]


def line_detour_makers(arm, evaluator, x0, x_goal, n_intervals, count=1):
    """
    Yield up to count makes: bent lines clear of the obstacles, each timed when make() is called.

    Each one's offsets are found when it is asked for; timing a start (timed_start: inverse
    dynamics at every node, on a 5 % grid) is left to the starts that are run.
    """
    n = arm.n
    unit = cubic_path(x0, x_goal, 1.0, n_intervals)

    def maker(offsets):
        dq = np.abs(x_goal[:n] - x0[:n]) + np.pi * np.abs(offsets)
        t_first = max(1.5 * float(np.max(dq / arm.velocity)), 0.05)

        def states_at(t_f):
            # The cubic's shape depends on t_f when the ends move: rebuilt for each t_f.
            line = cubic_path(x0, x_goal, t_f, n_intervals)
            return bent_states(line[:, :n], line[:, n:] * t_f, offsets, t_f)
        return lambda: timed_start(arm, states_at, t_first)
    for offsets in detour_offsets(arm, evaluator, unit[:, :n], count):
        yield maker(offsets)
