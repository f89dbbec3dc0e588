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
Cold starts around the obstacles, one per homotopy class of a two-joint configuration space.

A local method started from the straight joint-space interpolation (start_points'
interpolation_start) must carry its iterates through the obstacles to one side or the other;
which side it ends on is a matter of its path.  For a model with two joints the configuration
space is a plane, and the obstacles (every link against every inflated circle) are holes in
it; the collision-free paths between two configurations fall into homotopy classes, told apart
by the parities of their crossings of one ray from each hole to the border of the grid (the
homotopy signature of Bhattacharya, Likhachev and Kumar, "Topological constraints in
search-based robot path planning", Autonomous Robots 33, 2012).  A Dijkstra search over
(grid cell, crossing parities) finds the shortest collision-free path of each class on a
CELLS x CELLS grid, coarse enough to cost little next to the solves; each path (timed by
start_points.path_start) is a start already on one side of every obstacle.

The model's link_segments and obstacles.segment_clearance, a numba search; the results are
joint paths, and nothing here knows the model beyond that interface, nor the solver.  Models
with another number of joints, or problems whose obstacles leave no hole inside the grid, get
no class starts.
"""

import math

from numba import njit
import numpy as np

from .obstacles import segment_clearance

# Grid cells per joint.
CELLS = 64
# At most this many holes (the largest ones) get a crossing parity; at most MAX_CLASSES
# classes, the shortest paths first, each at most CLASS_FACTOR times the shortest one's length.
MAX_HOLES = 4
# Cells per joint of has_holes' coarse check.
CHECK_CELLS = 32
MAX_CLASSES = 4
CLASS_FACTOR = 2.0


@njit(cache=True)
def label_holes(occupied):
    """
    Label the 8-connected components of occupied cells; return (labels, count).

    labels is -1 on free cells.  Depth-first flood fill with an explicit stack.
    """
    n0, n1 = occupied.shape
    labels = np.full((n0, n1), -1, dtype=np.int64)
    stack = np.empty(n0 * n1, dtype=np.int64)
    count = 0
    for i0 in range(n0):
        for j0 in range(n1):
            if not occupied[i0, j0] or labels[i0, j0] >= 0:
                continue
            labels[i0, j0] = count
            top = 0
            stack[0] = i0 * n1 + j0
            while top >= 0:
                cell = stack[top]
                top -= 1
                i, j = cell // n1, cell % n1
                for a in range(max(i - 1, 0), min(i + 2, n0)):
                    for b in range(max(j - 1, 0), min(j + 2, n1)):
                        if occupied[a, b] and labels[a, b] < 0:
                            labels[a, b] = count
                            top += 1
                            stack[top] = a * n1 + b
            count += 1
    return labels, count


@njit(cache=True, inline='always')
def _push(keys, vals, size, key, val):
    """Binary min-heap on arrays: insert (key, val); return the new size."""
    k = size
    while k > 0:
        up = (k - 1) // 2
        if keys[up] <= key:
            break
        keys[k], vals[k] = keys[up], vals[up]
        k = up
    keys[k], vals[k] = key, val
    return size + 1


@njit(cache=True, inline='always')
def _pop(keys, vals, size):
    """Remove the smallest entry of the heap; return (key, val, new size)."""
    key, val = keys[0], vals[0]
    size -= 1
    last_key, last_val = keys[size], vals[size]
    k = 0
    while True:
        child = 2 * k + 1
        if child >= size:
            break
        if child + 1 < size and keys[child + 1] < keys[child]:
            child += 1
        if keys[child] >= last_key:
            break
        keys[k], vals[k] = keys[child], vals[child]
        k = child
    keys[k], vals[k] = last_key, last_val
    return key, val, size


@njit(cache=True)
def class_search(free, start, goal, ray_col, ray_row, w0, w1, max_ends, factor):
    """
    Dijkstra over (cell, crossing parities) from start; return (dist, parent) per state.

    State (i n1 + j) 2^K + s.  Moves to the 8 neighbours, diagonals only when both side cells
    are free (no corner cutting), cost sqrt((di w0)^2 + (dj w1)^2).  Ray r is the line between
    grid columns ray_col[r] and ray_col[r] + 1 above row ray_row[r] (the top cell of hole r);
    a move between those columns with both rows above it flips bit r.  Without corner cutting
    no move passes the ray's foot, so each loop around hole r flips bit r once.  The heap keeps
    stale entries (lazy deletion); ties pop in a fixed order, so the result is deterministic.

    The search stops once the states it pops are longer than factor times the shortest path
    to the goal, or than the max_ends-th goal state popped: the goal states it returns (the
    others get dist inf) are then exactly the ones class_paths keeps, with the same dist and
    parent chains as after a full search (their ancestors were popped before them).
    """
    n0, n1 = free.shape
    k = ray_col.shape[0]
    s_count = 1 << k
    total = n0 * n1 * s_count
    dist = np.full(total, np.inf)
    parent = np.full(total, -1, dtype=np.int64)
    done = np.zeros(total, dtype=np.bool_)
    keys = np.empty(8 * total + 1)
    vals = np.empty(8 * total + 1, dtype=np.int64)
    source = (start[0] * n1 + start[1]) * s_count
    dist[source] = 0.0
    size = _push(keys, vals, 0, 0.0, source)
    goal_cell = goal[0] * n1 + goal[1]
    ends, limit = 0, np.inf
    cost = np.empty((3, 3))
    for di in range(-1, 2):
        for dj in range(-1, 2):
            cost[di + 1, dj + 1] = math.sqrt((di * w0) ** 2 + (dj * w1) ** 2)
    while size > 0:
        d, state, size = _pop(keys, vals, size)
        if done[state]:
            continue
        if d > limit:
            break
        done[state] = True
        sig = state % s_count
        i, j = (state // s_count) // n1, (state // s_count) % n1
        if state // s_count == goal_cell:
            ends += 1
            if ends == 1:
                limit = factor * d
            if ends >= max_ends:
                limit = min(limit, d)
        for di in range(-1, 2):
            for dj in range(-1, 2):
                a, b = i + di, j + dj
                if (di == 0 and dj == 0) or a < 0 or b < 0 or a >= n0 or b >= n1 \
                        or not free[a, b]:
                    continue
                if di != 0 and dj != 0 and not (free[a, j] and free[i, b]):
                    continue
                new_sig = sig
                if di != 0:
                    for r in range(k):
                        if min(i, a) == ray_col[r] and min(j, b) > ray_row[r]:
                            new_sig ^= 1 << r
                nxt = (a * n1 + b) * s_count + new_sig
                nd = d + cost[di + 1, dj + 1]
                if nd < dist[nxt]:
                    dist[nxt] = nd
                    parent[nxt] = state
                    size = _push(keys, vals, size, nd, nxt)
    for state in range(total):
        if not done[state]:
            dist[state] = np.inf
    return dist, parent


def _box(model, q0, qg):
    """Grid box per joint: +-pi around the midpoint for revolute joints, else the move +-."""
    lo, hi = np.empty(2), np.empty(2)
    for j, kind in enumerate(model.joint_kinds):
        mid, half = 0.5 * (q0[j] + qg[j]), 0.5 * abs(qg[j] - q0[j])
        pad = max(math.pi if kind == 'revolute' else 2.0 * half, half + 0.1)
        lo[j], hi[j] = mid - pad, mid + pad
    return lo, hi


def _metric(problem):
    """
    Per-joint weights 1 / a_j, a_j = u_max_j |df/du|_jj at the start (joint j's acceleration).

    Equal weighted lengths are then roughly equal times for bang-bang moves of single joints.
    """
    model = problem.robot_model.joint_model      # the joints driven directly by u
    f = np.zeros(model.nx)
    fx = np.zeros((model.nx, model.nx))
    fu = np.zeros((model.nx, model.nu))
    model.kernels.rhs_jac(model.joint_states(np.asarray(problem.x0, dtype=float)),
                          np.zeros(model.nu), model.packed(), f, fx, fu)
    acc = np.abs(np.diag(fu[1::2, :])) * np.asarray(model.u_max, dtype=float)
    return 1.0 / np.maximum(acc, 1e-12 * max(acc.max(), 1e-300))


def class_paths(problem, cells=CELLS):
    """
    Return joint paths (M, 2) from the start to the goal, one per homotopy class.

    Shortest (in the _metric) first; an empty list when the model has not two joints, there
    is no obstacle, no hole lies inside the grid or the goal cannot be reached on it.
    """
    return classes(problem, cells)[0]


def winding(loop, point):
    """Return the winding number of the closed polygon loop (M, 2) around point (2,)."""
    d = loop - point
    angle = np.arctan2(d[:, 1], d[:, 0])
    step = np.diff(np.concatenate([angle, angle[:1]]))
    return int(round(np.sum((step + np.pi) % (2.0 * np.pi) - np.pi) / (2.0 * np.pi)))


def same_class(path, other, feet):
    """
    Return whether two joint paths (M, 2) with the same ends wind alike around every hole.

    feet (H, 2): a point in each hole (classes()); the loop path + other reversed must not
    wind around any of them.
    """
    loop = np.concatenate([path, other[::-1][1:-1]])
    return all(winding(loop, foot) == 0 for foot in feet)


def has_holes(problem, cells=CHECK_CELLS):
    """
    Return whether an obstacle of the problem is a hole of its joint plane on a cells grid.

    A cheap coarse check (fast_solver._cold: the circles' classes are searched lazily only
    where there are holes; none for the cylindrical robot, whose obstacles reach the border).
    """
    return bool(_holes(problem, cells)[-1])


def _holes(problem, cells):
    """Return (q0, qg, lo, step, occupied, start, goal, holes) of the joint grid (holes: [])."""
    model = problem.robot_model
    circles = problem.circles()
    if model.n_joints != 2 or circles.shape[0] == 0:
        return (None,) * 7 + ([],)
    q0 = model.positions(np.asarray(problem.x0, dtype=float))
    qg = model.positions(np.asarray(problem.x_goal, dtype=float))
    lo, hi = _box(model, q0, qg)
    axes = [np.linspace(lo[j], hi[j], cells) for j in range(2)]
    g0, g1 = np.meshgrid(axes[0], axes[1], indexing='ij')
    q = np.stack([g0.ravel(), g1.ravel()], axis=1)
    clear = segment_clearance(model.link_segments(q), circles).min(axis=1)
    occupied = (clear < 0.0).reshape(cells, cells)
    step = (hi - lo) / (cells - 1)
    start = np.rint((q0 - lo) / step).astype(np.int64)
    goal = np.rint((qg - lo) / step).astype(np.int64)
    occupied[start[0], start[1]] = occupied[goal[0], goal[1]] = False
    labels, count = label_holes(occupied)
    holes = []
    for c in range(count):
        ii, jj = np.nonzero(labels == c)
        if ii.min() > 0 and jj.min() > 0 and ii.max() < cells - 1 and jj.max() < cells - 1:
            top = int(np.argmax(jj))         # first cell of the top row (row-major order)
            holes.append((-ii.size, c, ii[top], jj[top]))
    return q0, qg, lo, step, occupied, start, goal, holes


def classes(problem, cells=CELLS):
    """
    Return (class_paths, feet): feet (H, 2) the joint coordinates of a cell in each hole.

    The feet are the rays' feet (the top cell of each hole whose crossing parity tells the
    classes apart); empty when there are no paths.
    """
    none = [], np.zeros((0, 2))
    q0, qg, lo, step, occupied, start, goal, holes = _holes(problem, cells)
    if not holes:
        return none
    holes = sorted(holes)[:MAX_HOLES]        # the largest, ties by label: deterministic
    ray_col = np.array([h[2] for h in holes], dtype=np.int64)
    ray_row = np.array([h[3] for h in holes], dtype=np.int64)
    w = step * _metric(problem)
    w = w / w.min()
    dist, parent = class_search(~occupied, start, goal, ray_col, ray_row, w[0], w[1],
                                MAX_CLASSES, CLASS_FACTOR)
    s_count = 1 << len(holes)
    base = (goal[0] * cells + goal[1]) * s_count
    ends = sorted((dist[base + s], base + s) for s in range(s_count)
                  if np.isfinite(dist[base + s]))
    paths = []
    for length, state in ends[:MAX_CLASSES]:
        if length > CLASS_FACTOR * ends[0][0]:
            break
        cells_on_path = []
        while state >= 0:
            cell = state // s_count
            cells_on_path.append((cell // cells, cell % cells))
            state = parent[state]
        path = lo + np.array(cells_on_path[::-1], dtype=float) * step
        path[0], path[-1] = q0, qg
        paths.append(path)
    feet = lo + np.column_stack([ray_col, ray_row]) * step
    return paths, (feet if paths else none[1])


def warm_up():
    """Compile (or load from the cache) the kernels on a tiny grid."""
    segment_clearance(np.zeros((1, 1, 4)), np.array([[1.0, 0.0, 0.5]]))
    occupied = np.zeros((3, 3), dtype=np.bool_)
    occupied[1, 1] = True
    label_holes(occupied)
    class_search(~occupied, np.array([0, 0]), np.array([2, 2]), np.array([1]), np.array([1]),
                 1.0, 1.0, MAX_CLASSES, CLASS_FACTOR)
