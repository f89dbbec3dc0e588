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
End-effector pose goals: inverse kinematics within the joint limits and free of collisions.

Levenberg-Marquardt on the frame's error: for a pose, the SE(3) log of the frame's pose
relative to the target (6 rows, Pinocchio's Jlog6 times the LOCAL frame Jacobian); for a
position only, the position error (3 rows, LOCAL_WORLD_ALIGNED Jacobian).  Joint limits are
kept by projection: joints at a bound whose step points outward are frozen for that step and
the step is clipped into the limits.  Seeds are tried in a fixed order (the start state, the
middle of the limits, then uniform samples from a fixed random generator), so the answer is
deterministic; the first converged seed whose configuration is clear of the obstacle spheres
(with margin) and of self-collision is returned.
"""

import numpy as np
import pinocchio as pin

from .clearances import check_obstacles, worst_collision
from .model import ArmError
from .urdf import MAX_OFFSET
from .validate import joint_vector
from ..problem import finite_number


def _target(position, orientation):
    try:
        position = np.array(position, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ArmError(f'goal position must be 3 numbers, got {position!r}') from None
    if position.size != 3 or not np.all(np.isfinite(position)):
        raise ArmError(f'goal position must be 3 finite numbers, got {position.tolist()}')
    if np.max(np.abs(position)) > MAX_OFFSET:
        raise ArmError(f'goal position {position.tolist()} is more than {MAX_OFFSET:g} m from '
                       "the base: beyond any arm's reach")
    if orientation is None:
        return pin.SE3(np.eye(3), position), False
    try:
        quat = np.array(orientation, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ArmError(f'goal orientation must be a quaternion (x, y, z, w), got '
                       f'{orientation!r}') from None
    if quat.size != 4 or not np.all(np.isfinite(quat)):
        raise ArmError(f'goal orientation must be 4 finite numbers (x, y, z, w), got '
                       f'{quat.tolist()}')
    norm = np.linalg.norm(quat)
    if abs(norm - 1.0) > 1e-3:
        raise ArmError(f'goal orientation quaternion has norm {norm:.6g}, not 1')
    x, y, z, w = quat / norm
    return pin.SE3(pin.Quaternion(w, x, y, z).toRotationMatrix(), position), True


def _seeds(arm, q_start, count):
    low = np.where(arm.continuous, -np.pi, arm.lower)
    high = np.where(arm.continuous, np.pi, arm.upper)
    seeds = []
    if q_start is not None:
        seeds.append(np.clip(q_start, arm.lower, arm.upper))
    seeds.append(0.5 * (low + high))
    rng = np.random.default_rng(0)
    while len(seeds) < count:
        seeds.append(rng.uniform(low, high))
    return seeds[:max(count, 1)]


class _Residual:
    """Frame error and its Jacobian at q (pose: 6 rows, position only: 3 rows)."""

    def __init__(self, arm, frame, target, with_orientation):
        self.arm, self.frame, self.target = arm, frame, target
        self.with_orientation = with_orientation

    def error(self, q):
        model, data = self.arm.model, self.arm.data
        pin.forwardKinematics(model, data, q)
        pose = pin.updateFramePlacement(model, data, self.frame)
        if self.with_orientation:
            return pin.log6(pose.actInv(self.target)).vector
        return pose.translation - self.target.translation

    def jacobian(self, q):
        model, data = self.arm.model, self.arm.data
        # (reshaped: a one-joint model's 6 x 1 Jacobian comes back from Pinocchio as a vector)
        if self.with_orientation:
            jac = np.reshape(pin.computeFrameJacobian(model, data, q, self.frame, pin.LOCAL),
                             (6, model.nv))
            pose = pin.updateFramePlacement(model, data, self.frame)
            # d log6(pose^-1 target)/dq = -Jlog6((pose^-1 target)^-1) J_local
            return -pin.Jlog6(self.target.actInv(pose)) @ jac
        return np.reshape(pin.computeFrameJacobian(model, data, q, self.frame,
                                                   pin.LOCAL_WORLD_ALIGNED), (6, model.nv))[:3]


def _levenberg_marquardt(arm, residual, q, tolerance, max_iterations):
    """(q, error norm) after LM steps projected onto the joint limits."""
    error = residual.error(q)
    cost = float(error @ error)
    damping = 1e-3
    for _ in range(max_iterations):
        if np.sqrt(cost) < tolerance:
            break
        jac = residual.jacobian(q)
        free = np.ones(arm.n, dtype=bool)
        for _ in range(arm.n):
            jf = jac[:, free]
            step = np.zeros(arm.n)
            step[free] = -np.linalg.solve(jf.T @ jf + damping * np.eye(int(free.sum())),
                                          jf.T @ error)
            blocked = free & (((q <= arm.lower) & (step < 0)) | ((q >= arm.upper) & (step > 0)))
            if not blocked.any():
                break
            free &= ~blocked
        if not free.any():
            break
        trial = np.clip(q + step, arm.lower, arm.upper)
        trial_error = residual.error(trial)
        trial_cost = float(trial_error @ trial_error)
        if trial_cost < cost:
            q, error, cost = trial, trial_error, trial_cost
            damping = max(damping / 3.0, 1e-12)
        else:
            damping *= 4.0
            if damping > 1e8:
                break
    return q, np.sqrt(cost)


def solve_ik(arm, link, position, orientation=None, q_start=None, spheres=None,
             obstacles=None, margin=0.0, self_collision=True, seeds=16, tolerance=1e-10,
             max_iterations=100):
    """
    Return joint positions (n,) that put link at the goal, within limits and collision-free.

    position: (x, y, z) in the base frame; orientation: quaternion (x, y, z, w), or None for
    a position-only goal.  With spheres, the answer is clear of the obstacle spheres
    (cx, cy, cz, R) by margin and, if self_collision, of self-collision.  Raises ArmError
    with the reason when no seed reaches the goal or every solution found collides.
    """
    frame = arm.frame_id(link)
    target, with_orientation = _target(position, orientation)
    if not finite_number(margin) or margin < 0:
        raise ArmError(f'margin must be finite and >= 0 [m], got {margin!r}')
    obstacles = check_obstacles(obstacles)
    if len(obstacles) and spheres is None:
        raise ArmError("inverse kinematics with obstacles needs the arm's collision spheres")
    if q_start is not None:
        q_start = joint_vector(arm, q_start, 'IK start positions')
    residual = _Residual(arm, frame, target, with_orientation)
    best_error, collision = np.inf, None
    for seed in _seeds(arm, q_start, seeds):
        q, error = _levenberg_marquardt(arm, residual, seed, tolerance, max_iterations)
        if error >= tolerance:
            best_error = min(best_error, error)
            continue
        if spheres is None:
            return q
        hit = worst_collision(arm, spheres, q, obstacles, margin, self_collision)
        if hit is None:
            return q
        if collision is None or hit.depth < collision.depth:
            collision = hit
    goal = f'{link} at {np.round(target.translation, 6).tolist()}' + (
        ' with the given orientation' if with_orientation else '')
    if collision is not None:
        raise ArmError(f'goal pose {goal}: every solution found is in collision (least deep: '
                       f'{collision.text})')
    raise ArmError(f'goal pose {goal} is unreachable within the joint limits (closest error '
                   f'{best_error:.3g} after {seeds} seeds)')
