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
Circular obstacles and the arm: the paper's penalty (eqs. 38-46) and exact clearance.

The arm is the segment from the base (origin) to the hand, [0, (a + q2) e(q1)] with
e = (cos q1, sin q1).  Obstacles are rows (cx, cy, R) of an array, R = R' + dR already
inflated by the margin dR.

Generalisation of eqs. (38)-(41): the paper intersects the line y = x tan q1 with one circle in
the first quadrant and takes r_min = r1.  Here the ray s e(q1), s >= 0, meets the circle where
s^2 - 2 b s + (|c|^2 - R^2) = 0 with b = c . e, so for any quadrant
    r_min = b - sqrt(D),   D = b^2 - |c|^2 + R^2   (D is eq. 40 divided by 4 (1 + tan^2 q1)),
and the ray hits the circle ahead of the base iff D > 0 and b > 0 (the base is outside every
circle, which Problem validation enforces).  Eq. (41): a + q2 <= r_min.
"""

import math

from numba import njit
import numpy as np

# Obstacle-gradient variants of the paper's penalty.
GRAD_EXACT = 0      # eqs. (44)-(45)
GRAD_SHORTCUT = 1   # eq. (46): dJ3/dq1 = 0, dJ3/dq2 = K_p H


@njit(cache=True)
def ray_penetration(q1, q2, a, cx, cy, radius):
    """
    Return (r_min - a - q2, d r_min / d q1, active) of eqs. (39)-(43) for one circle.

    active is H-(r_min - q2 - a) H+(D) of eq. (43); the other two are 0 when inactive.
    """
    c, s = math.cos(q1), math.sin(q1)
    b = cx * c + cy * s
    disc = b * b - (cx * cx + cy * cy - radius * radius)
    if disc <= 0.0 or b <= 0.0:
        return 0.0, 0.0, False
    root = math.sqrt(disc)
    gap = b - root - a - q2
    if gap >= 0.0:
        return 0.0, 0.0, False
    db = -cx * s + cy * c
    return gap, db * (1.0 - b / root), True


@njit(cache=True)
def obstacle_penalty(states, a, circles, k_p_hat, grad_mode, grad_x):
    """
    J3 of eq. (42) summed over circles and nodes 0..N; writes dJ3/dx into grad_x (N+1 x 4).

    Every row of grad_x is overwritten (zero where no circle is hit), so callers need not clear
    it.  grad_mode GRAD_EXACT uses eq. (44) with the exact d r_min/d q1 (eq. 45); GRAD_SHORTCUT
    the paper's eq. (46), which is not the gradient of J3 (only a descent heuristic).
    """
    total = 0.0
    n_circles = circles.shape[0]
    # The ray at angle q1 can only meet circle k within its angular half-width around the
    # centre's bearing; testing that first skips the trigonometry at most nodes.
    bearing = np.empty(n_circles)
    half_width = np.empty(n_circles)
    for k in range(n_circles):
        bearing[k] = math.atan2(circles[k, 1], circles[k, 0])
        distance = math.hypot(circles[k, 0], circles[k, 1])
        half_width[k] = math.asin(min(1.0, circles[k, 2] / distance))
    two_pi = 2.0 * math.pi
    inv_two_pi = 1.0 / two_pi
    # Two passes: a tight loop picks the (node, circle) pairs inside the angular window, then
    # the ray formula runs on those only (keeping it out of the first loop halves its cost).
    pairs = np.empty((states.shape[0] * n_circles, 2), dtype=np.int64)
    n_pairs = 0
    for i in range(states.shape[0]):
        q1 = states[i, 0]
        grad_x[i, 0] = 0.0
        grad_x[i, 1] = 0.0
        grad_x[i, 2] = 0.0
        grad_x[i, 3] = 0.0
        for k in range(n_circles):
            off = q1 - bearing[k]
            off -= two_pi * math.floor(off * inv_two_pi + 0.5)
            if abs(off) < half_width[k]:
                pairs[n_pairs, 0] = i
                pairs[n_pairs, 1] = k
                n_pairs += 1
    for j in range(n_pairs):
        i, k = pairs[j, 0], pairs[j, 1]
        gap, dr_dq1, active = ray_penetration(states[i, 0], states[i, 2], a, circles[k, 0],
                                              circles[k, 1], circles[k, 2])
        if not active:
            continue
        total += k_p_hat * gap * gap
        if grad_mode == GRAD_EXACT:
            grad_x[i, 0] += 2.0 * k_p_hat * dr_dq1 * gap
            grad_x[i, 2] += -2.0 * k_p_hat * gap
        else:
            grad_x[i, 2] += k_p_hat
    return total


def arm_clearance(states, a, circles):
    """
    Distance from the arm segment to each circle's edge at every node: (N+1, K) [m].

    The arm of the paper's robot, [0, (a + q2) e(q1)]; negative means the arm cuts the
    inflated circle.
    """
    states = np.atleast_2d(np.asarray(states, dtype=float))
    reach = a + states[:, 2]
    tip = np.stack([reach * np.cos(states[:, 0]), reach * np.sin(states[:, 0])], axis=1)
    segments = np.concatenate([np.zeros_like(tip), tip], axis=1)[:, None, :]
    return segment_clearance(segments, circles)


def segment_clearance(segments, circles, squared=False):
    """
    Clearance of segments (..., L, 4) rows (ax, ay, bx, by) to circles (K, 3): (..., L K).

    Column link * K + k.  squared=False: distance to the circle's edge d - R [m];
    squared=True: (d^2 - R^2) / (2 R), the fast mode's constraint (same sign, ~ d - R).
    The one clearance of the package (solver, class search, validation, nodes, analysis).
    """
    seg = np.asarray(segments, dtype=float)
    if seg.ndim < 2 or seg.shape[-1] != 4:
        raise ValueError(f'segments must be an (..., L, 4) array, got shape {seg.shape}')
    circles = np.ascontiguousarray(np.reshape(np.asarray(circles, dtype=float), (-1, 3)))
    rows = np.ascontiguousarray(seg.reshape((-1,) + seg.shape[-2:]))
    out = np.empty((rows.shape[0], rows.shape[1] * circles.shape[0]))
    segment_clearance_rows(rows, circles, bool(squared), out)
    return out.reshape(seg.shape[:-2] + (out.shape[1],))


@njit(cache=True)
def segment_clearance_rows(seg, circles, squared, out):
    """
    segment_clearance for segments (M, L, 4) into out (M, L K), compiled.

    Compiled because the fast mode's starts and the class search call it on every node of a
    grid, where numpy's temporaries would cost more than the arithmetic.
    """
    n_circles = circles.shape[0]
    for m in range(seg.shape[0]):
        for link in range(seg.shape[1]):
            ax, ay = seg[m, link, 0], seg[m, link, 1]
            vx, vy = seg[m, link, 2] - ax, seg[m, link, 3] - ay
            length_sq = vx * vx + vy * vy
            for k in range(n_circles):
                cx, cy, radius = circles[k, 0], circles[k, 1], circles[k, 2]
                t = 0.0
                if length_sq > 0.0:
                    t = min(max(((cx - ax) * vx + (cy - ay) * vy) / length_sq, 0.0), 1.0)
                dx, dy = ax + t * vx - cx, ay + t * vy - cy
                d_sq = dx * dx + dy * dy
                if squared:
                    value = (d_sq - radius * radius) / (2.0 * radius)
                else:
                    value = math.sqrt(d_sq) - radius
                out[m, link * n_circles + k] = value


def model_clearance(model, states, circles):
    """Clearance d - R [m] of every link of model to every circle at each state: (M, L K)."""
    states = np.atleast_2d(np.asarray(states, dtype=float))
    return segment_clearance(model.link_segments(model.positions(states)), circles)


def scheduled_clearance(model, times, positions, schedule):
    """
    Clearance [m] of every link to each obstacle row in force at each sample: (n, K).

    times (n,) [s] and joint positions (n, n_joints) of samples; schedule: [(start time,
    rows (K_j, 3))] sorted by time, each set in force from its start to the next one's.  Column
    k is the least clearance of the links to row k of the set in force; nan where that set has
    no row k or no set is in force yet.
    """
    times = np.asarray(times, dtype=float)
    positions = np.asarray(positions, dtype=float)
    width = max((len(rows) for _, rows in schedule), default=0)
    out = np.full((len(times), width), np.nan)
    starts = [t for t, _ in schedule]
    for j, (start, rows) in enumerate(schedule):
        stop = starts[j + 1] if j + 1 < len(schedule) else math.inf
        inside = (times >= start) & (times < stop)
        if not np.any(inside) or not len(rows):
            continue
        gaps = segment_clearance(model.link_segments(positions[inside]), rows)
        out[np.nonzero(inside)[0], :len(rows)] = gaps.reshape(
            int(np.sum(inside)), -1, len(rows)).min(axis=1)
    return out
