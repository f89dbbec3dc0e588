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

"""Checks of an arm's start or goal state: finite, the right size, within limits, no collision."""

import numpy as np
import pinocchio as pin

from .clearances import worst_collision
from .model import ArmError

# Mass matrices whose smallest eigenvalue is below this fraction of the largest are refused
# as singular (a joint moving no mass); real arms sit near 1e-3 (Panda's wrist vs shoulder).
MASS_CONDITION = 1e-10
# [rad/s, m/s] a goal on a position limit may move out of it this fast at most (a solved plan's
# terminal velocity residual; anything faster leaves the limits right after the goal).
OUTWARD_SPEED = 1e-6


def joint_vector(arm, values, what):
    """Return values as a float vector of the arm's size (ArmError: wrong size, NaN, inf)."""
    try:
        vector = np.array(values, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ArmError(f'{what} must be {arm.n} numbers, got {values!r}') from None
    if vector.size != arm.n:
        raise ArmError(f'{what} has {vector.size} values; the arm has {arm.n} joints '
                       f'({", ".join(arm.joint_names)})')
    bad = np.flatnonzero(~np.isfinite(vector))
    if len(bad):
        i = int(bad[0])
        raise ArmError(f'{what}: {arm.joint_names[i]} is {vector[i]} (NaN or infinite)')
    return vector


def check_mass_matrix(arm, q, what='start'):
    """
    Raise ArmError unless the joint-space mass matrix at q is positive definite.

    A singular one (a planned joint that moves no mass or inertia: links without <inertial>,
    zero masses) has no forward dynamics; the reason names the joints whose diagonal vanishes.
    """
    mass = pin.crba(arm.model, arm.model.createData(), np.asarray(q, dtype=float))
    mass = 0.5 * (mass + mass.T)
    if np.all(np.isfinite(mass)):
        values = np.linalg.eigvalsh(mass)
        if values[0] > MASS_CONDITION * max(values[-1], 0.0):
            return
    scale = np.max(np.abs(np.diag(mass))) if np.all(np.isfinite(mass)) else 0.0
    light = [name for name, d in zip(arm.joint_names, np.diag(mass))
             if not d > MASS_CONDITION * scale]
    verb = 'moves' if len(light) == 1 else 'move'
    which = f' ({", ".join(light)} {verb} no mass or inertia)' if light else ''
    raise ArmError(f'{what}: the mass matrix of the planned joints is singular there{which}: '
                   'check the URDF inertials (every moving link needs a mass and inertia)')


def check_not_leaving(arm, q, v, what='goal'):
    """
    Raise ArmError when a state on a position limit moves out of it.

    The motion goes on past a goal with a velocity: from a limit, out of it.  (A plan's
    published motion reaches the goal half a step before its last point, core/plan_reference.py,
    so that point would lie past the limit too.)
    """
    for i, name in enumerate(arm.joint_names):
        if q[i] >= arm.upper[i] and v[i] > OUTWARD_SPEED:
            side, limit = 'upper', arm.upper[i]
        elif q[i] <= arm.lower[i] and v[i] < -OUTWARD_SPEED:
            side, limit = 'lower', arm.lower[i]
        else:
            continue
        raise ArmError(f'{what}: {name} = {q[i]:.6g} is on its {side} limit {limit:.6g} with '
                       f'velocity {v[i]:.6g} out of it: the arm would leave its limits right '
                       'after; give a velocity away from the limit (or 0), or a goal inside it')


def check_holdable(arm, q, what='goal'):
    """
    Raise ArmError when the efforts cannot hold the arm at rest at q (gravity beyond an effort).

    A goal at rest the arm cannot hold is reached for an instant at best (it falls at once):
    the usual cause of a failed solve with a payload (robot.payload_mass) too heavy for the
    shoulder.  The torques are RNEA's at rest.
    """
    hold = arm.inverse_dynamics(np.asarray(q, dtype=float), np.zeros(arm.n), np.zeros(arm.n),
                                arm.model.createData())
    excess = np.abs(hold) - arm.effort
    i = int(np.argmax(excess))
    if excess[i] > 0.0:
        payload = arm.source.get('payload_mass')
        carrying = f' (with a payload of {payload:g} kg)' if payload else ''
        raise ArmError(f'{what}: the arm cannot hold it at rest{carrying}: {arm.joint_names[i]} '
                       f'needs {abs(hold[i]):.4g} N m against gravity, its effort limit is '
                       f'{arm.effort[i]:.4g}')


def check_state(arm, q, v=None, what='start', spheres=None, obstacles=None, margin=0.0,
                self_collision=True, velocity_slack=0.0):
    """
    Return (q, v) as float vectors after checking them; ArmError with the reason otherwise.

    q within [lower, upper], |v| <= (1 + velocity_slack) velocity (v default zeros), and,
    with spheres, no sphere closer than margin to an obstacle nor (self_collision) two
    non-adjacent links touching.
    """
    q = joint_vector(arm, q, f'{what} positions')
    v = np.zeros(arm.n) if v is None else joint_vector(arm, v, f'{what} velocities')
    fine = ((arm.lower <= q) & (q <= arm.upper)
            & (np.abs(v) <= (1.0 + velocity_slack) * arm.velocity))
    for i in np.flatnonzero(~fine):         # (the reason of the first joint that fails)
        name = arm.joint_names[i]
        if not arm.lower[i] <= q[i] <= arm.upper[i]:
            raise ArmError(f'{what}: {name} = {q[i]:.6g} is outside its limits '
                           f'[{arm.lower[i]:.6g}, {arm.upper[i]:.6g}]')
        if abs(v[i]) > (1.0 + velocity_slack) * arm.velocity[i]:
            allowed = f' (+{100 * velocity_slack:g} % allowed)' if velocity_slack else ''
            raise ArmError(f'{what}: {name} velocity {v[i]:.6g} exceeds its limit '
                           f'{arm.velocity[i]:.6g}{allowed}')
    check_mass_matrix(arm, q, what)
    if spheres is not None:
        collision = worst_collision(arm, spheres, q, obstacles, margin, self_collision)
        if collision is not None:
            raise ArmError(f'{what} in collision: {collision.text}')
    elif obstacles is not None and len(obstacles):
        raise ArmError(f"{what}: obstacles need the arm's collision spheres")
    return q, v
