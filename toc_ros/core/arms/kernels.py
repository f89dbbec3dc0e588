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
Compiled sphere kinematics and clearances for many configurations at once.

Why not Pinocchio here: from Python every access to a joint placement (data.oMi[j]) or frame
Jacobian is a separate bound call that costs more than the kinematics itself, and a solver
needs every sphere at every node.  The chain is taken from the reduced Pinocchio model once
(joint placements, parents, and each joint's motion axis read from Pinocchio's own LOCAL
Jacobian), then these kernels chain the 1-DOF joints, place the spheres and form their
Jacobians for a whole batch of configurations in one call.  The tests hold them to
Pinocchio's frame placements, an independent URDF kinematics and finite differences.
"""

import math

from numba import njit
import numpy as np


@njit(cache=True)
def _axis_rotation(axis, angle, out):
    c, s = math.cos(angle), math.sin(angle)
    t = 1.0 - c
    x, y, z = axis[0], axis[1], axis[2]
    out[0, 0] = c + t * x * x
    out[0, 1] = t * x * y - s * z
    out[0, 2] = t * x * z + s * y
    out[1, 0] = t * x * y + s * z
    out[1, 1] = c + t * y * y
    out[1, 2] = t * y * z - s * x
    out[2, 0] = t * x * z - s * y
    out[2, 1] = t * y * z + s * x
    out[2, 2] = c + t * z * z


@njit(cache=True)
def _chain_pose(q, parent, place_r, place_t, axis, prismatic, v_index, rot, pos, world_axis,
                motion, tmp, offset):
    """Fill every joint's rotation, origin and world motion axis at configuration q."""
    for j in range(1, parent.shape[0]):
        p = parent[j]
        value = q[v_index[j]]
        # rot_j = rot_p place_r_j motion, pos_j = pos_p + rot_p (place_t_j + ...)
        for a in range(3):
            for b in range(3):
                acc = 0.0
                for c in range(3):
                    acc += rot[p, a, c] * place_r[j, c, b]
                tmp[a, b] = acc
        for a in range(3):
            offset[a] = place_t[j, a]
        if prismatic[j]:
            for a in range(3):
                for b in range(3):
                    rot[j, a, b] = tmp[a, b]
                    offset[a] += place_r[j, a, b] * axis[j, b] * value
        else:
            _axis_rotation(axis[j], value, motion)
            for a in range(3):
                for b in range(3):
                    acc = 0.0
                    for c in range(3):
                        acc += tmp[a, c] * motion[c, b]
                    rot[j, a, b] = acc
        for a in range(3):
            acc = pos[p, a]
            for c in range(3):
                acc += rot[p, a, c] * offset[c]
            pos[j, a] = acc
            acc = 0.0
            for c in range(3):
                acc += rot[j, a, c] * axis[j, c]
            world_axis[j, a] = acc


@njit(cache=True)
def _sphere_pose(s, parent, prismatic, v_index, sphere_joint, sphere_offset, support, rot, pos,
                 world_axis, centre, jacobian):
    """Fill sphere s's centre (3,) and d centre / dq (3, n)."""
    j = sphere_joint[s]
    for a in range(3):
        acc = pos[j, a]
        for c in range(3):
            acc += rot[j, a, c] * sphere_offset[s, c]
        centre[a] = acc
    for j in range(1, parent.shape[0]):
        k = v_index[j]
        if not support[s, k]:
            for a in range(3):
                jacobian[a, k] = 0.0
            continue
        w = world_axis[j]
        if prismatic[j]:
            for a in range(3):
                jacobian[a, k] = w[a]
        else:
            dx = centre[0] - pos[j, 0]
            dy = centre[1] - pos[j, 1]
            dz = centre[2] - pos[j, 2]
            jacobian[0, k] = w[1] * dz - w[2] * dy
            jacobian[1, k] = w[2] * dx - w[0] * dz
            jacobian[2, k] = w[0] * dy - w[1] * dx


@njit(cache=True)
def sphere_kinematics(qs, parent, place_r, place_t, axis, prismatic, v_index, sphere_joint,
                      sphere_offset, support, centres, jacobians):
    """
    Fill centres (N, S, 3) and d centre / dq (N, S, 3, n) (base frame) for configurations qs.

    Joints j = 1..J-1 in Pinocchio's order (parents first): parent[j], the placement in the
    parent (place_r[j], place_t[j]), the unit motion axis in the joint frame, prismatic[j]
    (else revolute) and the joint's coordinate v_index[j].  Spheres hang on sphere_joint[s]
    at sphere_offset[s] (joint frame); support[s, k] marks the coordinates that move them.
    """
    n_joints = parent.shape[0]
    rot = np.zeros((n_joints, 3, 3))
    pos = np.zeros((n_joints, 3))
    world_axis = np.zeros((n_joints, 3))
    motion = np.zeros((3, 3))
    tmp = np.zeros((3, 3))
    offset = np.zeros(3)
    for i in range(3):
        rot[0, i, i] = 1.0
    for node in range(qs.shape[0]):
        _chain_pose(qs[node], parent, place_r, place_t, axis, prismatic, v_index, rot, pos,
                    world_axis, motion, tmp, offset)
        for s in range(sphere_joint.shape[0]):
            _sphere_pose(s, parent, prismatic, v_index, sphere_joint, sphere_offset, support,
                         rot, pos, world_axis, centres[node, s], jacobians[node, s])


@njit(cache=True)
def sphere_rows(qs, parent, place_r, place_t, axis, prismatic, v_index, sphere_joint,
                sphere_offset, support, obstacles, radius, pairs, pair_radius, weights, level,
                values, gradients, curvature):
    """
    Sphere constraint rows g = (d^2 - R^2) / (2 R) at configurations qs (K, n), compiled.

    Rows: robot sphere s against obstacle o (row s * O + o, R = radius[s, o]), then the sphere
    pairs (R = pair_radius[p]).  level 0 fills values (K, rows); level 1 also gradients
    (K, rows, n); level 2 also curvature (K, n, n) of sum_p weights[k, p] g_p.

    The curvature is exact: with p_s the centre, d p_s / dq_k = J_k and, for joints i and k
    that both move the sphere with i = k or i an ancestor of k (Pinocchio numbers parents
    first), d^2 p_s / dq_i dq_k = w_i x J_k if joint i is revolute (world axis w_i) and 0 if it
    is prismatic (a translation changes neither axes nor relative positions).
    """
    n_joints = parent.shape[0]
    n_spheres = sphere_joint.shape[0]
    n = qs.shape[1]
    n_obs = obstacles.shape[0]
    n_obs_rows = n_spheres * n_obs
    rot = np.zeros((n_joints, 3, 3))
    pos = np.zeros((n_joints, 3))
    world_axis = np.zeros((n_joints, 3))
    motion = np.zeros((3, 3))
    tmp = np.zeros((3, 3))
    offset = np.zeros(3)
    centres = np.empty((n_spheres, 3))
    jac = np.empty((n_spheres, 3, n))
    direction = np.empty((n_spheres, 3))
    gram_scale = np.empty(n_spheres)
    gap = np.empty(3)
    jac_gap = np.empty((3, n))
    for i in range(3):
        rot[0, i, i] = 1.0
    for node in range(qs.shape[0]):
        _chain_pose(qs[node], parent, place_r, place_t, axis, prismatic, v_index, rot, pos,
                    world_axis, motion, tmp, offset)
        # The Jacobians even where only values are asked for: skipping them on a flag known
        # only at run time made the compiled kernel about twice as slow at every level.
        for s in range(n_spheres):
            _sphere_pose(s, parent, prismatic, v_index, sphere_joint, sphere_offset, support,
                         rot, pos, world_axis, centres[s], jac[s])
        if level >= 2:
            curvature[node] = 0.0
            direction[:] = 0.0
            gram_scale[:] = 0.0
        for s in range(n_spheres):
            for o in range(n_obs):
                row = s * n_obs + o
                big_r = radius[s, o]
                sq = 0.0
                for a in range(3):
                    gap[a] = centres[s, a] - obstacles[o, a]
                    sq += gap[a] * gap[a]
                values[node, row] = (sq - big_r * big_r) / (2.0 * big_r)
                if level == 0:
                    continue
                for k in range(n):
                    acc = 0.0
                    for a in range(3):
                        acc += gap[a] / big_r * jac[s, a, k]
                    gradients[node, row, k] = acc
                if level >= 2:
                    weight = weights[node, row]
                    gram_scale[s] += weight / big_r
                    for a in range(3):
                        direction[s, a] += weight * (gap[a] / big_r)
            if level >= 2 and gram_scale[s] != 0.0:
                # Every obstacle row of sphere s has the curvature scale J_s^T J_s: one Gram
                # matrix per sphere, its upper triangle mirrored; the columns of the joints
                # that do not move the sphere are zero: skipped.
                scale = gram_scale[s]
                for i in range(n):
                    if not support[s, i]:
                        continue
                    for k in range(i, n):
                        if not support[s, k]:
                            continue
                        acc = 0.0
                        for a in range(3):
                            acc += jac[s, a, i] * jac[s, a, k]
                        curvature[node, i, k] += scale * acc
                        if k != i:
                            curvature[node, k, i] += scale * acc
        for p in range(pairs.shape[0]):
            row = n_obs_rows + p
            sa, sb = pairs[p, 0], pairs[p, 1]
            big_r = pair_radius[p]
            sq = 0.0
            for a in range(3):
                gap[a] = centres[sa, a] - centres[sb, a]
                sq += gap[a] * gap[a]
            values[node, row] = (sq - big_r * big_r) / (2.0 * big_r)
            if level == 0:
                continue
            for a in range(3):
                for k in range(n):
                    jac_gap[a, k] = jac[sa, a, k] - jac[sb, a, k]
            for k in range(n):
                acc = 0.0
                for a in range(3):
                    acc += gap[a] / big_r * jac_gap[a, k]
                gradients[node, row, k] = acc
            if level >= 2:
                weight = weights[node, row]
                scale = weight / big_r
                for a in range(3):
                    direction[sa, a] += weight * (gap[a] / big_r)
                    direction[sb, a] -= weight * (gap[a] / big_r)
                for i in range(n):
                    for k in range(i, n):
                        acc = 0.0
                        for a in range(3):
                            acc += jac_gap[a, i] * jac_gap[a, k]
                        curvature[node, i, k] += scale * acc
                        if k != i:
                            curvature[node, k, i] += scale * acc
        if level < 2:
            continue
        # sum_s direction_s . d^2 p_s: the second derivatives of the centres.
        for s in range(n_spheres):
            dsx, dsy, dsz = direction[s, 0], direction[s, 1], direction[s, 2]
            if dsx == 0.0 and dsy == 0.0 and dsz == 0.0:
                continue
            for ji in range(1, n_joints):
                i = v_index[ji]
                if prismatic[ji] or not support[s, i]:
                    continue
                w = world_axis[ji]
                # direction . (w x J_k) = (direction x w) . J_k
                cx = dsy * w[2] - dsz * w[1]
                cy = dsz * w[0] - dsx * w[2]
                cz = dsx * w[1] - dsy * w[0]
                for jk in range(ji, n_joints):
                    k = v_index[jk]
                    if not support[s, k]:
                        continue
                    value = cx * jac[s, 0, k] + cy * jac[s, 1, k] + cz * jac[s, 2, k]
                    curvature[node, i, k] += value
                    if k != i:
                        curvature[node, k, i] += value


@njit(cache=True)
def obstacle_clearances(centres, jacobians, radii, obstacles, margin, values, gradients):
    """Fill values (N, S, O) = |p_s - c_o| - (r_s + R_o + margin), gradients (N, S, O, n)."""
    n = jacobians.shape[3]
    for node in range(centres.shape[0]):
        for s in range(centres.shape[1]):
            for o in range(obstacles.shape[0]):
                dx = centres[node, s, 0] - obstacles[o, 0]
                dy = centres[node, s, 1] - obstacles[o, 1]
                dz = centres[node, s, 2] - obstacles[o, 2]
                dist = math.sqrt(dx * dx + dy * dy + dz * dz)
                values[node, s, o] = dist - (radii[s] + obstacles[o, 3] + margin)
                # Coincident centres: not differentiable; zero keeps Newton steps finite.
                inv = 1.0 / dist if dist > 0.0 else 0.0
                for k in range(n):
                    gradients[node, s, o, k] = inv * (dx * jacobians[node, s, 0, k]
                                                      + dy * jacobians[node, s, 1, k]
                                                      + dz * jacobians[node, s, 2, k])


@njit(cache=True)
def pair_clearances(centres, jacobians, radii, pairs, margin, values, gradients):
    """Fill values (N, P) = |p_a - p_b| - (r_a + r_b + margin) and gradients (N, P, n)."""
    n = jacobians.shape[3]
    for node in range(centres.shape[0]):
        for i in range(pairs.shape[0]):
            a, b = pairs[i, 0], pairs[i, 1]
            dx = centres[node, a, 0] - centres[node, b, 0]
            dy = centres[node, a, 1] - centres[node, b, 1]
            dz = centres[node, a, 2] - centres[node, b, 2]
            dist = math.sqrt(dx * dx + dy * dy + dz * dz)
            values[node, i] = dist - (radii[a] + radii[b] + margin)
            inv = 1.0 / dist if dist > 0.0 else 0.0
            for k in range(n):
                gradients[node, i, k] = inv * (
                    dx * (jacobians[node, a, 0, k] - jacobians[node, b, 0, k])
                    + dy * (jacobians[node, a, 1, k] - jacobians[node, b, 1, k])
                    + dz * (jacobians[node, a, 2, k] - jacobians[node, b, 2, k]))
