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
The interior-point obstacle constraints at one node: c = (d^2 - R^2) / (2 R) per link and circle.

d is the distance from a link segment (the model's segments kernel) to a circle's centre;
obstacle_terms also gives the constraint's joint gradient and its block of the condensed
Newton system, obstacle_values the values only (line search).  Inlined into the kernels of
ipm_evaluation.py and ipm_linesearch.py.
"""

from numba import njit
import numpy as np


@njit(inline='always')
def _segment_distance_sq(seg, cx, cy, g, h):
    """
    Compute the squared distance from segment (ax, ay, bx, by) to (cx, cy).

    Also fills the gradient g (4) and Hessian h (4x4) with respect to the endpoint
    coordinates.  Written with w = C - A, v = B - A.
    """
    wx, wy = cx - seg[0], cy - seg[1]
    vx, vy = seg[2] - seg[0], seg[3] - seg[1]
    length_sq = vx * vx + vy * vy
    proj = wx * vx + wy * vy
    for i in range(4):
        g[i] = 0.0
        for j in range(4):
            h[i, j] = 0.0
    # Derivatives in (w, v): gw, gv (2 each), hww, hwv, hvv (2x2 each).
    if length_sq <= 1e-300 or proj <= 0.0:
        d2 = wx * wx + wy * wy
        gwx, gwy, gvx, gvy = 2.0 * wx, 2.0 * wy, 0.0, 0.0
        hww = ((2.0, 0.0), (0.0, 2.0))
        hwv = ((0.0, 0.0), (0.0, 0.0))
        hvv = ((0.0, 0.0), (0.0, 0.0))
    elif proj >= length_sq:
        ex, ey = wx - vx, wy - vy
        d2 = ex * ex + ey * ey
        gwx, gwy, gvx, gvy = 2.0 * ex, 2.0 * ey, -2.0 * ex, -2.0 * ey
        hww = ((2.0, 0.0), (0.0, 2.0))
        hwv = ((-2.0, 0.0), (0.0, -2.0))
        hvv = ((2.0, 0.0), (0.0, 2.0))
    else:
        inv = 1.0 / length_sq
        t = proj * inv
        d2 = wx * wx + wy * wy - proj * t
        gwx, gwy = 2.0 * wx - 2.0 * t * vx, 2.0 * wy - 2.0 * t * vy
        gvx = -2.0 * t * wx + 2.0 * t * t * vx
        gvy = -2.0 * t * wy + 2.0 * t * t * vy
        w = (wx, wy)
        v = (vx, vy)
        hww = ((2.0 - 2.0 * vx * vx * inv, -2.0 * vx * vy * inv),
               (-2.0 * vy * vx * inv, 2.0 - 2.0 * vy * vy * inv))
        hwv = ((-2.0 * v[0] * w[0] * inv - 2.0 * t + 4.0 * t * v[0] * v[0] * inv,
                -2.0 * v[0] * w[1] * inv + 4.0 * t * v[0] * v[1] * inv),
               (-2.0 * v[1] * w[0] * inv + 4.0 * t * v[1] * v[0] * inv,
                -2.0 * v[1] * w[1] * inv - 2.0 * t + 4.0 * t * v[1] * v[1] * inv))
        hvv = ((-2.0 * w[0] * w[0] * inv + 8.0 * t * w[0] * v[0] * inv + 2.0 * t * t
                - 8.0 * t * t * v[0] * v[0] * inv,
                -2.0 * w[0] * w[1] * inv + 4.0 * t * (w[0] * v[1] + v[0] * w[1]) * inv
                - 8.0 * t * t * v[0] * v[1] * inv),
               (-2.0 * w[1] * w[0] * inv + 4.0 * t * (w[1] * v[0] + v[1] * w[0]) * inv
                - 8.0 * t * t * v[1] * v[0] * inv,
                -2.0 * w[1] * w[1] * inv + 8.0 * t * w[1] * v[1] * inv + 2.0 * t * t
                - 8.0 * t * t * v[1] * v[1] * inv))
    # Endpoint coordinates: w = C - A, v = B - A, so d/dA = -d/dw - d/dv, d/dB = d/dv.
    g[0], g[1] = -gwx - gvx, -gwy - gvy
    g[2], g[3] = gvx, gvy
    for i in range(2):
        for j in range(2):
            h[i, j] = hww[i][j] + hwv[i][j] + hwv[j][i] + hvv[i][j]
            h[i, 2 + j] = -hwv[i][j] - hvv[i][j]
            h[2 + j, i] = h[i, 2 + j]
            h[2 + i, 2 + j] = hvv[i][j]
    return d2


@njit(inline='always')
def obstacle_terms(segments, q, p, circles, cons, cons_q, z, sigma, hess_q, work):
    """
    Evaluate the obstacle constraints of one node.

    Fills cons (L K), cons_q (L K, n); hess_q (n x n) receives
    sum_j sigma_j grad c_j grad c_j^T - z_j grad^2 c_j (the node's obstacle block of the
    condensed Newton system).
    """
    seg, seg_q, seg_qq, ge, he = work
    n = q.shape[0]
    n_links = seg.shape[0]
    n_circles = circles.shape[0]
    segments(q, p, seg, seg_q, seg_qq)
    for a in range(n):
        for b in range(n):
            hess_q[a, b] = 0.0
    for link in range(n_links):
        for k in range(n_circles):
            j = link * n_circles + k
            radius = circles[k, 2]
            scale = 0.5 / radius
            d2 = _segment_distance_sq(seg[link], circles[k, 0], circles[k, 1], ge, he)
            cons[j] = (d2 - radius * radius) * scale
            for a in range(n):
                acc = 0.0
                for r in range(4):
                    acc += ge[r] * seg_q[link, r, a]
                cons_q[j, a] = acc * scale
            sig = sigma[j]
            zj = z[j]
            for a in range(n):
                for b in range(a, n):
                    acc = 0.0
                    for r in range(4):
                        acc += ge[r] * seg_qq[link, r, a, b]
                        for t in range(4):
                            acc += seg_q[link, r, a] * he[r, t] * seg_q[link, t, b]
                    val = sig * cons_q[j, a] * cons_q[j, b] - zj * acc * scale
                    hess_q[a, b] += val
                    if b != a:
                        hess_q[b, a] += val


@njit(inline='always')
def _segment_distance_sq_value(seg, cx, cy):
    """Squared distance from segment (ax, ay, bx, by) to (cx, cy) (no derivatives)."""
    wx, wy = cx - seg[0], cy - seg[1]
    vx, vy = seg[2] - seg[0], seg[3] - seg[1]
    length_sq = vx * vx + vy * vy
    proj = wx * vx + wy * vy
    if length_sq <= 1e-300 or proj <= 0.0:
        return wx * wx + wy * wy
    if proj >= length_sq:
        ex, ey = wx - vx, wy - vy
        return ex * ex + ey * ey
    return wx * wx + wy * wy - proj * proj / length_sq


@njit(inline='always')
def obstacle_values(segments, q, p, circles, cons, work):
    """Obstacle constraints c = (d^2 - R^2) / (2 R) of one node (values only)."""
    seg, seg_q, seg_qq = work[0], work[1], work[2]
    n_circles = circles.shape[0]
    segments(q, p, seg, seg_q, seg_qq)
    for link in range(seg.shape[0]):
        for k in range(n_circles):
            radius = circles[k, 2]
            d2 = _segment_distance_sq_value(seg[link], circles[k, 0], circles[k, 1])
            cons[link * n_circles + k] = (d2 - radius * radius) * (0.5 / radius)


@njit
def obstacle_work(n_links, n):
    """Work buffers of obstacle_terms."""
    return (np.zeros((n_links, 4)), np.zeros((n_links, 4, n)), np.zeros((n_links, 4, n, n)),
            np.zeros(4), np.zeros((4, 4)))
