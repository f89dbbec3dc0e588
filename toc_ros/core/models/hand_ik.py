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
Hand inverse kinematics of model-file robots (symbolic.py): closed-form branches and Newton.

The generated kernel module of a model file has hand(q, p) (the end of the last link and its
exact Jacobian, plain Python) and, when the file has an inverse_kinematics section, the
branches IK[name](x, y, p), the reach conditions ik_reach(x, y, p) -> [(small, big), ...],
their texts IK_REACH and IK_STRICT (True for < and >).

Closed form: a goal is refused when a reach condition fails (small <= big holds up to
REACH_RTOL, small < big exactly), when a branch expression has no value there (acos or sqrt
out of domain, division by zero: the ValueError / ArithmeticError of Python's math) or is not
finite, and when the answer does not put the hand on the goal (round trip FK(IK(goal)) within
ROUND_TRIP_RTOL).  At load every branch is checked against the file's links at the hands of
fixed poses (check_branches).

Numeric (no inverse_kinematics section): defined only for 2 joints (as many as the hand's
coordinates x, y); Levenberg-Marquardt steps on |hand(q) - goal| from a seed, which become
Newton steps near the solution, to NEWTON_RTOL; refused when it does not get there or ends at
a singular pose.  Revolute joints are returned within pi of the seed.
"""

import math

import numpy as np

from .base import ModelError

REACH_RTOL = 1e-12         # reach condition small <= big + REACH_RTOL * max(1, |small|, |big|)
ROUND_TRIP_RTOL = 1e-9     # |FK(IK(goal)) - goal| <= ROUND_TRIP_RTOL * max(1, |goal|)
NEWTON_RTOL = 1e-12        # numeric IK: |FK(q) - goal| <= NEWTON_RTOL * max(1, |goal|)
NEWTON_MAX_STEPS = 200
SINGULAR_RCOND = 1e-9      # numeric IK: smallest / largest singular value of d hand / dq
CHECK_POSES = 8            # load-time round-trip check of the closed-form branches
CHECK_SEED = 20261


def _goal_text(x, y):
    return f'({x:.6g}, {y:.6g})'


def _q_text(q):
    return np.array2string(np.asarray(q, dtype=float), precision=6)


def hand_and_jacobian(kernels, p, q):
    """Hand position (2,) and d hand / dq (2, n) of the model file's kernels at q."""
    n = len(q)
    out = kernels.hand([float(v) for v in q], p)
    return np.array(out[:2]), np.array(out[2:]).reshape(2, n)


def hand_distance(kernels, p, q, x, y):
    """Distance [m] from the hand at q to the goal (x, y)."""
    hand, _ = hand_and_jacobian(kernels, p, q)
    return math.hypot(hand[0] - x, hand[1] - y)


def round_trip_tolerance(x, y):
    """Largest accepted distance [m] between FK(IK(goal)) and the goal."""
    return ROUND_TRIP_RTOL * max(1.0, math.hypot(x, y))


def failed_reach(kernels, p, x, y):
    """Return the first reach condition that (x, y) fails, with its sides, or None."""
    try:
        sides = kernels.ik_reach(x, y, p)
    except (ValueError, ArithmeticError) as exc:
        return f'the reach conditions cannot be evaluated there ({exc})'
    for text, strict, (small, big) in zip(kernels.IK_REACH, kernels.IK_STRICT, sides):
        holds = (small < big if strict
                 else small <= big + REACH_RTOL * max(1.0, abs(small), abs(big)))
        if not holds:
            return f'reach condition {text!r} fails ({small:.6g} vs {big:.6g})'
    return None


def branch_solution(kernels, p, branch, x, y):
    """Return (q, None) of a closed-form branch at (x, y), or (None, reason) where it has none."""
    reason = failed_reach(kernels, p, x, y)
    if reason:
        return None, reason
    try:
        q = np.array(kernels.IK[branch](x, y, p), dtype=float)
    except (ValueError, ArithmeticError) as exc:
        return None, f'branch {branch!r} has no value there ({exc})'
    if not np.all(np.isfinite(q)):
        return None, f'branch {branch!r} gives q = {_q_text(q)}'
    return q, None


def closed_form_ik(model, x, y, branch):
    """Joint positions of the model file's IK branch at (x, y) (ModelError with the reason)."""
    kernels = model.kernels
    names = kernels.IK_BRANCHES
    goal = _goal_text(x, y)
    if len(names) == 1:
        branch = names[0]          # one solution: robot.ik_branch does not apply
    elif branch not in names:
        raise ModelError(f'model {model.name!r}: hand goal {goal} is ambiguous: choose the IK '
                         f'branch (robot.ik_branch), one of {names} (got {branch!r})')
    p = model.packed()
    q, reason = branch_solution(kernels, p, branch, x, y)
    if q is None:
        raise ModelError(f'model {model.name!r}: hand goal {goal} is out of reach: {reason}')
    distance = hand_distance(kernels, p, q, x, y)
    if not distance <= round_trip_tolerance(x, y):
        raise ModelError(f'model {model.name!r}: hand goal {goal} is out of reach: branch '
                         f'{branch!r} gives q = {_q_text(q)}, whose hand is {distance:.3g} m '
                         'from the goal')
    return q


def check_poses(joint_kinds):
    """Return the poses of the load-time check (revolute in [-pi, pi], prismatic +-0.5 m)."""
    rng = np.random.default_rng(CHECK_SEED)
    half = np.array([math.pi if kind == 'revolute' else 0.5 for kind in joint_kinds])
    return [rng.uniform(-half, half) for _ in range(CHECK_POSES)]


def check_branches(model, source):
    """
    Refuse IK branches that are not an inverse of the links (ModelError with the reason).

    At the hand of each pose of check_poses() a branch must either have no answer (a reach
    condition fails, a domain error) or put the hand back on that point; and it must answer
    at one point at least.
    """
    kernels = model.kernels
    p = model.packed()
    hands = [hand_and_jacobian(kernels, p, q)[0] for q in check_poses(model.joint_kinds)]
    for branch in kernels.IK_BRANCHES:
        where = f'model file {source}: inverse_kinematics.branches.{branch}'
        reasons = []
        for x, y in hands:
            q, reason = branch_solution(kernels, p, branch, float(x), float(y))
            if q is None:
                reasons.append(reason)
                continue
            distance = hand_distance(kernels, p, q, x, y)
            if not distance <= round_trip_tolerance(x, y):
                raise ModelError(f'{where}: not an inverse of the links: for the hand point '
                                 f'{_goal_text(x, y)} it gives q = {_q_text(q)}, whose hand '
                                 f'is {distance:.3g} m away')
        if len(reasons) == len(hands):
            raise ModelError(f'{where}: no answer at any of {len(hands)} hand points of fixed '
                             f'poses (first: {reasons[0]})')


def _wrap_near(q, seed, joint_kinds):
    """Revolute joint angles moved by multiples of 2 pi to within pi of the seed."""
    q = q.copy()
    for j, kind in enumerate(joint_kinds):
        if kind == 'revolute':
            q[j] = seed[j] + math.remainder(q[j] - seed[j], 2.0 * math.pi)
    return q


def _seed_positions(model, seed):
    if seed is None:
        return np.zeros(model.n_joints)
    seed = np.asarray(seed, dtype=float).reshape(-1)
    if seed.size != model.n_joints or not np.all(np.isfinite(seed)):
        raise ModelError(f'model {model.name!r}: the IK seed must be {model.n_joints} finite '
                         f'joint positions, got {seed.tolist()}')
    return seed


def _levenberg_marquardt(kernels, p, goal, q):
    """Return (q, distance, gradient norm, steps) of damped Newton steps towards the goal."""
    hand, jac = hand_and_jacobian(kernels, p, q)
    error = goal - hand
    distance = float(np.linalg.norm(error))
    # Aim below the acceptance NEWTON_RTOL (the steps end at rounding level or in a stall).
    tol = 1e-3 * NEWTON_RTOL * max(1.0, float(np.linalg.norm(goal)))
    damping = 1e-3 * (float(np.sum(jac * jac)) + 1e-12)
    steps = 0
    while distance > tol and steps < NEWTON_MAX_STEPS:
        steps += 1
        normal = jac.T @ jac
        step = np.linalg.solve(normal + damping * np.eye(len(q)), jac.T @ error)
        trial = q + step
        hand_t, jac_t = hand_and_jacobian(kernels, p, trial)
        distance_t = float(np.linalg.norm(goal - hand_t))
        if distance_t < distance:     # accept: towards Gauss-Newton (Newton for 2 joints)
            q, jac, error, distance = trial, jac_t, goal - hand_t, distance_t
            damping = max(0.1 * damping, 1e-300)
        else:                         # reject: towards a short gradient step
            damping *= 10.0
            if damping > 1e16 * (float(np.trace(normal)) + 1.0):
                break
    return q, distance, float(np.linalg.norm(jac.T @ error)), steps


def numeric_ik(model, x, y, seed=None):
    """
    Joint positions that put the hand of a 2-joint model at (x, y), by Newton from a seed.

    seed: joint positions to start from (default zero), e.g. the current state: of several
    solutions the one Newton reaches from there.  ModelError for another joint count, a goal
    it does not reach to NEWTON_RTOL and a singular pose at the goal.
    """
    goal_text = _goal_text(x, y)
    n = model.n_joints
    if n != 2:
        what = (f'ambiguous: a redundant arm ({n} joints for the 2 hand coordinates x, y)'
                if n > 2 else 'not determined: 1 joint cannot place the hand at any (x, y)')
        raise ModelError(f'model {model.name!r}: hand goal {goal_text} is {what}; the model '
                         'file has no inverse_kinematics section: send goal_joints, or add '
                         'the section')
    kernels = model.kernels
    p = model.packed()
    start = _seed_positions(model, seed)
    goal = np.array([x, y])
    try:
        q, distance, gradient, steps = _levenberg_marquardt(kernels, p, goal, start)
    except (np.linalg.LinAlgError, ValueError, ArithmeticError) as exc:
        raise ModelError(f'model {model.name!r}: numeric IK for hand goal {goal_text} failed '
                         f'from q = {_q_text(start)}: {exc}') from None
    tol = NEWTON_RTOL * max(1.0, math.hypot(x, y))
    if not distance <= tol:
        stuck = gradient <= 1e-9 * max(1.0, distance)
        why = ('the nearest hand position found is' if stuck else 'after '
               f'{steps} steps the hand is still')
        raise ModelError(f'model {model.name!r}: hand goal {goal_text} is out of reach or '
                         f'not found by numeric IK from q = {_q_text(start)}: {why} '
                         f'{distance:.3g} m from it')
    singular = np.linalg.svd(hand_and_jacobian(kernels, p, q)[1], compute_uv=False)
    if not singular[-1] > SINGULAR_RCOND * singular[0]:
        raise ModelError(f'model {model.name!r}: hand goal {goal_text} is at a singular pose '
                         f'q = {_q_text(q)} (workspace boundary: d hand / dq has rank < 2), '
                         'where numeric IK is not well defined')
    return _wrap_near(q, start, model.joint_kinds)
