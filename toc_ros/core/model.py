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
The 2-DOF cylindrical robot of the paper, eq. (37), with analytic Jacobians.

State x = [q1, dq1, q2, dq2] (rotation [rad], its rate, extension [m], its rate), control
u = [u1, u2] (torque [N m], force [N]).  The hand is at distance a + q2 from the base, along
(cos q1, sin q1) in the base frame.

Eq. (36) and eq. (37) disagree on the sign of the centrifugal term A2/(2 A3) x2^2 in dx4:
eq. (36) (N2 = -[m q2 + M (a + q2)] dq1^2) gives +, eq. (37) as printed gives -.  The default
follows eq. (37) as printed ('eq37'); 'eq36' selects the sign derived from eq. (36).

All kernels take a packed parameter vector (see RobotParams.packed) so that numba sees plain
float64 arrays.
"""

from dataclasses import dataclass
import math

from numba import njit
import numpy as np

from .settings import setting

NX = 4
NU = 2

# Indices into the packed parameter vector.
P_A1, P_A2, P_A3, P_A, P_SIGN = 0, 1, 2, 3, 4
N_PARAMS = 5

MODEL_VARIANTS = ('eq37', 'eq36')


@dataclass(frozen=True)
class RobotParams:
    """Physical data of the robot (paper, section 4.1); defaults are the paper's values."""

    hand_mass: float = setting(50.0, 'M: mass of the manipulator hand and its load',
                               unit='kg', low=0.0, high=1e4)
    link_mass: float = setting(97.0, 'm: mass of the extension link', unit='kg', low=0.0,
                               high=1e4)
    inertia: float = setting(193.0, 'I1 + I2: inertia about the rotation axis',
                             unit='kg m^2', low=0.0, high=1e5)
    a: float = setting(1.1, 'a: distance from point S to the centre of mass of the hand',
                       unit='m', low=0.0, high=100.0)
    u1_max: float = setting(600.0, 'control bounds |u1| <= u_max[0], |u2| <= u_max[1], both '
                            '> 0', unit='N m, N', ros_name='u_max', index=0)
    u2_max: float = setting(500.0, 'control bounds (see u1_max)', ros_name='u_max', index=1)
    model_variant: str = setting(
        'eq37', "sign of the centrifugal term: 'eq37' (as printed in the paper) or 'eq36' "
        '(derived from eq. 36)', choices=MODEL_VARIANTS)

    def check(self):
        """Return a list of problems with the data (empty when valid)."""
        errors = []
        for name in ('hand_mass', 'link_mass', 'inertia', 'a', 'u1_max', 'u2_max'):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0.0:
                errors.append(f'robot.{name} must be a finite positive number, got {value!r}')
        if self.model_variant not in MODEL_VARIANTS:
            errors.append(f'robot.model_variant must be one of {MODEL_VARIANTS}, '
                          f'got {self.model_variant!r}')
        return errors

    @property
    def u_max(self):
        """Control bounds [u1_max, u2_max] as an array."""
        return np.array([self.u1_max, self.u2_max])

    def packed(self):
        """Pack A1, A2, A3 (section 4.1), a and the eq. (36)/(37) sign for the kernels."""
        p = np.empty(N_PARAMS)
        p[P_A1] = self.inertia + self.hand_mass * self.a ** 2
        p[P_A2] = 2.0 * self.hand_mass * self.a
        p[P_A3] = self.link_mass + self.hand_mass
        p[P_A] = self.a
        p[P_SIGN] = -1.0 if self.model_variant == 'eq37' else 1.0
        return p


@njit(cache=True, inline='always')
def rhs(x1, x2, x3, x4, u1, u2, p):
    """
    Right-hand side of eq. (37) on scalars: (dx1, dx2, dx3, dx4).

    Scalar arguments and tuple results keep the hot loops free of array views.
    """
    a1, a2, a3 = p[P_A1], p[P_A2], p[P_A3]
    inertia = a1 + a2 * x3 + a3 * x3 * x3
    d_inertia = a2 + 2.0 * a3 * x3
    centrifugal = x3 + p[P_SIGN] * a2 / (2.0 * a3)
    return (x2, (u1 - d_inertia * x2 * x4) / inertia, x4,
            centrifugal * x2 * x2 + u2 / a3)


@njit(cache=True, inline='always')
def rhs_partials(x1, x2, x3, x4, u1, u2, p):
    """
    Non-zero entries of df/dx and df/du of eq. (37) that depend on the state.

    Returns (f1_x2, f1_x3, f1_x4, f3_x2, f3_x3, f1_u1, f3_u2) with f indexed from 0;
    the constant ones are f0_x2 = f2_x4 = 1 (0-based: df0/dx1 = df2/dx3 = 1).
    """
    a1, a2, a3 = p[P_A1], p[P_A2], p[P_A3]
    inertia = a1 + a2 * x3 + a3 * x3 * x3
    d_inertia = a2 + 2.0 * a3 * x3
    num = u1 - d_inertia * x2 * x4
    centrifugal = x3 + p[P_SIGN] * a2 / (2.0 * a3)
    return (-d_inertia * x4 / inertia,
            -2.0 * a3 * x2 * x4 / inertia - num * d_inertia / (inertia * inertia),
            -d_inertia * x2 / inertia,
            2.0 * centrifugal * x2,
            x2 * x2,
            1.0 / inertia,
            1.0 / a3)


@njit(cache=True, inline='always')
def rhs_second_partials(x1, x2, x3, x4, u1, u2, p):
    """
    Non-zero second derivatives of eq. (37), same argument order as rhs_partials.

    Returns (f1_x2x3, f1_x2x4, f1_x3x3, f1_x3x4, f1_x3u1, f3_x2x2, f3_x2x3) with f indexed
    from 0 and x, u from 1 as in the paper (x2 = dq1, x3 = q2, x4 = dq2); every other second
    derivative of f is zero (f0 = x2 and f2 = x4 are linear, f3 is linear in u2).
    """
    a1, a2, a3 = p[P_A1], p[P_A2], p[P_A3]
    inertia = a1 + a2 * x3 + a3 * x3 * x3
    d_inertia = a2 + 2.0 * a3 * x3
    dd_inertia = 2.0 * a3
    num = u1 - d_inertia * x2 * x4
    inv = 1.0 / inertia
    inv2 = inv * inv
    centrifugal = x3 + p[P_SIGN] * a2 / (2.0 * a3)
    return (-dd_inertia * x4 * inv + d_inertia * d_inertia * x4 * inv2,
            -d_inertia * inv,
            2.0 * d_inertia * dd_inertia * x2 * x4 * inv2 - num * dd_inertia * inv2
            + 2.0 * num * d_inertia * d_inertia * inv2 * inv,
            -dd_inertia * x2 * inv + d_inertia * d_inertia * x2 * inv2,
            -d_inertia * inv2,
            2.0 * centrifugal,
            2.0 * x2)


@njit(cache=True)
def dynamics(x, u, p):
    """Right-hand side dx/dt = f(x, u) of eq. (37) as an array."""
    f0, f1, f2, f3 = rhs(x[0], x[1], x[2], x[3], u[0], u[1], p)
    out = np.empty(NX)
    out[0], out[1], out[2], out[3] = f0, f1, f2, f3
    return out


@njit(cache=True)
def dynamics_jacobians(x, u, p):
    """Return (f, df/dx (4x4), df/du (4x2)) of eq. (37) as new arrays."""
    f = dynamics(x, u, p)
    f1_x2, f1_x3, f1_x4, f3_x2, f3_x3, f1_u1, f3_u2 = rhs_partials(
        x[0], x[1], x[2], x[3], u[0], u[1], p)
    fx = np.zeros((NX, NX))
    fx[0, 1] = 1.0
    fx[1, 1], fx[1, 2], fx[1, 3] = f1_x2, f1_x3, f1_x4
    fx[2, 3] = 1.0
    fx[3, 1], fx[3, 2] = f3_x2, f3_x3
    fu = np.zeros((NX, NU))
    fu[1, 0], fu[3, 1] = f1_u1, f3_u2
    return f, fx, fu


def hand_position(q1, q2, a):
    """Hand position (x, y) [m] in the base frame for joint positions q1, q2 (arrays ok)."""
    reach = a + np.asarray(q2)
    return reach * np.cos(q1), reach * np.sin(q1)
