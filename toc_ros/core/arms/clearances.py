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
Clearances of an arm's collision spheres: to obstacle spheres and between its own links.

Centres and Jacobians (LOCAL_WORLD_ALIGNED: d centre / dq in the base frame) come from the
compiled kernels.py for one configuration or a batch (sphere_kinematics_batch), with the
clearances of a batch in obstacle_clearances_batch and self_clearances_batch.

Obstacles are spheres (cx, cy, cz, R) in the base frame (check_obstacles).  Clearance of
robot sphere s and obstacle o: |p_s - c_o| - (r_s + R_o + margin) (negative: penetration
depth).  sphere_reach bounds how far each sphere can get from the base, so that obstacles out
of every sphere's reach need no constraint rows (reachable_obstacles).  The spheres come from
spheres.load_spheres.
"""

import dataclasses

import numpy as np

from . import kernels
from .model import ArmError

# Obstacle centres and radii are refused beyond this [m]: far larger than any workspace, and
# squared distances of such values lose every digit of a clearance (or overflow).
OBSTACLE_EXTENT = 1e5


def sphere_kinematics_batch(spheres, qs):
    """Centres (N, S, 3) and d centre / dq (N, S, 3, n) for configurations qs (N, n)."""
    qs = np.ascontiguousarray(qs, dtype=float)
    if qs.ndim != 2 or qs.shape[1] != spheres.support.shape[1]:
        raise ArmError(f'configurations of shape {qs.shape}: the spheres move with '
                       f'{spheres.support.shape[1]} joints')
    count, n = qs.shape
    centres = np.empty((count, len(spheres), 3))
    jacobians = np.empty((count, len(spheres), 3, n))
    kernels.sphere_kinematics(qs, *spheres.chain, spheres.joint_ids, spheres.joint_offsets,
                              spheres.support, centres, jacobians)
    return centres, jacobians


def sphere_centres(arm, spheres, q):
    """Centres (S, 3) of the spheres in the base frame at configuration q."""
    return sphere_kinematics_batch(spheres, np.reshape(q, (1, arm.n)))[0][0]


def sphere_jacobians(arm, spheres, q):
    """(centres (S, 3), d centre / dq (S, 3, n)) in the base frame at configuration q."""
    centres, jacobians = sphere_kinematics_batch(spheres, np.reshape(q, (1, arm.n)))
    return centres[0], jacobians[0]


def obstacle_clearances_batch(centres, jacobians, radii, obstacles, margin=0.0):
    """Clearances (N, S, O) and their gradients (N, S, O, n) for batched kinematics."""
    obstacles = np.ascontiguousarray(obstacles, dtype=float).reshape(-1, 4)
    count, n_spheres, _, n = jacobians.shape
    values = np.empty((count, n_spheres, len(obstacles)))
    gradients = np.empty((count, n_spheres, len(obstacles), n))
    kernels.obstacle_clearances(centres, jacobians, radii, obstacles, float(margin), values,
                                gradients)
    return values, gradients


def self_clearances_batch(centres, jacobians, radii, pairs, margin=0.0):
    """Clearances (N, P) of sphere pairs and their gradients (N, P, n) for batched kinematics."""
    count, _, _, n = jacobians.shape
    values = np.empty((count, len(pairs)))
    gradients = np.empty((count, len(pairs), n))
    kernels.pair_clearances(centres, jacobians, radii, np.ascontiguousarray(pairs),
                            float(margin), values, gradients)
    return values, gradients


def check_obstacles(obstacles):
    """Obstacle spheres as an (O, 4) array of (cx, cy, cz, R); ArmError for bad rows."""
    if obstacles is None:
        return np.zeros((0, 4))
    try:
        rows = np.array(obstacles, dtype=float)
    except (TypeError, ValueError):
        raise ArmError(f'obstacles must be rows (cx, cy, cz, R), got {obstacles!r}') from None
    if rows.size == 0:
        return np.zeros((0, 4))
    rows = rows.reshape(1, -1) if rows.ndim == 1 else rows
    if rows.ndim != 2 or rows.shape[1] != 4:
        raise ArmError(f'obstacles must be rows (cx, cy, cz, R), got shape {rows.shape}')
    for o, row in enumerate(rows):
        if not np.all(np.isfinite(row)):
            raise ArmError(f'obstacle {o}: NaN or infinite value in {row.tolist()}')
        if row[3] < 0:
            raise ArmError(f'obstacle {o}: negative radius {row[3]}')
        if np.max(np.abs(row)) > OBSTACLE_EXTENT:
            raise ArmError(f'obstacle {o}: {row.tolist()} reaches beyond {OBSTACLE_EXTENT:g} m '
                           'from the base (a workspace obstacle is far smaller and nearer)')
    return rows


def sphere_reach(spheres, arm):
    """
    Return (S,) bounds on each sphere's distance from the base origin over all configurations.

    Joint placements and rotations keep lengths, so a sphere is never farther than the sum of
    its chain's placement offsets, its own offset and its prismatic joints' largest travel
    (inf for a prismatic joint without limits).
    """
    parent, _, place_t, _, prismatic, v_index = spheres.chain
    reach = np.zeros(len(parent))
    for j in range(1, len(parent)):
        travel = 0.0
        if prismatic[j]:
            k = v_index[j]
            travel = max(abs(arm.lower[k]), abs(arm.upper[k]))
        reach[j] = reach[parent[j]] + np.linalg.norm(place_t[j]) + travel
    return reach[spheres.joint_ids] + np.linalg.norm(spheres.joint_offsets, axis=1)


def reachable_obstacles(spheres, arm, obstacles, margin):
    """
    Return a bool mask of the obstacles that some sphere can come within margin of.

    The others (farther from the base than every sphere's reach, sphere_reach) keep every
    clearance positive in every configuration: constraint rows for them only cost time, and
    far away their values are large enough to spoil the solver's scaling.
    """
    if spheres is None or not len(obstacles):
        return np.zeros(len(obstacles), dtype=bool)
    reach = sphere_reach(spheres, arm) + spheres.radii                         # (S,)
    gap = np.linalg.norm(obstacles[:, :3], axis=1) - obstacles[:, 3] - margin   # (O,)
    return np.any(gap[:, None] <= reach[None, :] * (1.0 + 1e-9) + 1e-9, axis=1)


def obstacle_clearance(centres, radii, obstacles, margin=0.0):
    """Clearances (S, O): |p_s - c_o| - (r_s + R_o + margin)."""
    obstacles = np.asarray(obstacles, dtype=float).reshape(-1, 4)
    gap = np.linalg.norm(centres[:, None] - obstacles[None, :, :3], axis=2)
    return gap - (radii[:, None] + obstacles[None, :, 3] + margin)


def _unit(vectors):
    norm = np.linalg.norm(vectors, axis=-1, keepdims=True)
    # Coincident centres: the distance is not differentiable there; any unit vector is a
    # subgradient, zero keeps Newton steps finite.
    return np.divide(vectors, norm, out=np.zeros_like(vectors), where=norm > 0)


def obstacle_clearance_jacobian(centres, jacobians, obstacles):
    """Return d clearance / dq (S, O, n) of obstacle_clearance."""
    obstacles = np.asarray(obstacles, dtype=float).reshape(-1, 4)
    normal = _unit(centres[:, None] - obstacles[None, :, :3])     # (S, O, 3)
    return np.matmul(normal, jacobians)


def self_clearance(centres, radii, pairs, margin=0.0):
    """Clearances (P,) of sphere pairs: |p_a - p_b| - (r_a + r_b + margin)."""
    a, b = pairs[:, 0], pairs[:, 1]
    return np.linalg.norm(centres[a] - centres[b], axis=1) - (radii[a] + radii[b] + margin)


def self_clearance_jacobian(centres, jacobians, pairs):
    """Return d clearance / dq (P, n) of self_clearance."""
    a, b = pairs[:, 0], pairs[:, 1]
    normal = _unit(centres[a] - centres[b])
    return np.matmul(normal[:, None], jacobians[a] - jacobians[b])[:, 0]


@dataclasses.dataclass(frozen=True)
class Collision:
    """The deepest penetration of a configuration: depth (m, > 0) and who touches whom."""

    depth: float
    text: str


def worst_collision(arm, spheres, q, obstacles=None, margin=0.0, self_collision=True):
    """Deepest collision at q (obstacles with margin, self without), or None if clear."""
    obstacles = check_obstacles(obstacles)
    centres = sphere_centres(arm, spheres, q)
    worst = None
    if len(obstacles):
        clearance = obstacle_clearance(centres, spheres.radii, obstacles, margin)
        s, o = np.unravel_index(np.argmin(clearance), clearance.shape)
        if clearance[s, o] < 0:
            worst = Collision(float(-clearance[s, o]),
                              f'{spheres.label(s)} vs obstacle {o}, depth '
                              f'{-clearance[s, o]:.3f} m')
    if self_collision and len(spheres.self_pairs):
        clearance = self_clearance(centres, spheres.radii, spheres.self_pairs)
        p = int(np.argmin(clearance))
        if clearance[p] < 0 and (worst is None or -clearance[p] > worst.depth):
            a, b = spheres.self_pairs[p]
            worst = Collision(float(-clearance[p]),
                              f'{spheres.label(a)} vs {spheres.label(b)} (self-collision), '
                              f'depth {-clearance[p]:.3f} m')
    return worst
