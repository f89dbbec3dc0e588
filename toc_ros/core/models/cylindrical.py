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
The cylindrical robot of eq. (37) behind the model interface (base.py).

The equations live once, in toc_ros/core/model.py (scalar kernels shared with paper mode);
this module adapts them to the array interface, describes the arm as one segment from the base
to the hand, and binds the generic horizon / interior-point kernels to them (cached per model).
"""

import math
import sys

from numba import njit
import numpy as np

from .base import ModelError, RobotModel
from .. import horizon, ipm
from ..model import (MODEL_VARIANTS, P_A, rhs as rhs_scalar, rhs_partials,
                     rhs_second_partials, RobotParams)

N_JOINTS = 2
N_LINKS = 1


@njit(cache=True, inline='always')
def rhs(x, u, p, f):
    """dx/dt of eq. (37) into f."""
    f[0], f[1], f[2], f[3] = rhs_scalar(x[0], x[1], x[2], x[3], u[0], u[1], p)


@njit(cache=True, inline='always')
def rhs_jac(x, u, p, f, fx, fu):
    """f, df/dx, df/du of eq. (37); the sparsity of eq. (37) is written here once."""
    f[0], f[1], f[2], f[3] = rhs_scalar(x[0], x[1], x[2], x[3], u[0], u[1], p)
    f1_x2, f1_x3, f1_x4, f3_x2, f3_x3, f1_u1, f3_u2 = rhs_partials(
        x[0], x[1], x[2], x[3], u[0], u[1], p)
    for r in range(4):
        for c in range(4):
            fx[r, c] = 0.0
        fu[r, 0] = 0.0
        fu[r, 1] = 0.0
    fx[0, 1] = 1.0
    fx[1, 1], fx[1, 2], fx[1, 3] = f1_x2, f1_x3, f1_x4
    fx[2, 3] = 1.0
    fx[3, 1], fx[3, 2] = f3_x2, f3_x3
    fu[1, 0] = f1_u1
    fu[3, 1] = f3_u2


@njit(cache=True, inline='always')
def rhs_hess(x, u, p, lam, hxx, hxu, huu):
    """Second derivatives of lam . f(x, u) for eq. (37)."""
    f1_x2x3, f1_x2x4, f1_x3x3, f1_x3x4, f1_x3u1, f3_x2x2, f3_x2x3 = rhs_second_partials(
        x[0], x[1], x[2], x[3], u[0], u[1], p)
    for r in range(4):
        for c in range(4):
            hxx[r, c] = 0.0
        hxu[r, 0] = 0.0
        hxu[r, 1] = 0.0
    huu[0, 0] = 0.0
    huu[0, 1] = 0.0
    huu[1, 0] = 0.0
    huu[1, 1] = 0.0
    l1, l3 = lam[1], lam[3]
    # 0-based state indices: dq1 = 1, q2 = 2, dq2 = 3.
    hxx[1, 1] = l3 * f3_x2x2
    hxx[1, 2] = hxx[2, 1] = l1 * f1_x2x3 + l3 * f3_x2x3
    hxx[1, 3] = hxx[3, 1] = l1 * f1_x2x4
    hxx[2, 2] = l1 * f1_x3x3
    hxx[2, 3] = hxx[3, 2] = l1 * f1_x3x4
    hxu[2, 0] = l1 * f1_x3u1


@njit(cache=True, inline='always')
def segments(q, p, seg, seg_q, seg_qq):
    """Compute the arm: one segment from the base to the hand (a + q2)(cos q1, sin q1)."""
    c, s = math.cos(q[0]), math.sin(q[0])
    reach = p[P_A] + q[1]
    for r in range(4):
        for j in range(2):
            seg_q[0, r, j] = 0.0
            for k in range(2):
                seg_qq[0, r, j, k] = 0.0
    seg[0, 0] = 0.0
    seg[0, 1] = 0.0
    seg[0, 2] = reach * c
    seg[0, 3] = reach * s
    seg_q[0, 2, 0], seg_q[0, 2, 1] = -reach * s, c
    seg_q[0, 3, 0], seg_q[0, 3, 1] = reach * c, s
    seg_qq[0, 2, 0, 0] = -reach * c
    seg_qq[0, 2, 0, 1] = seg_qq[0, 2, 1, 0] = -s
    seg_qq[0, 3, 0, 0] = -reach * s
    seg_qq[0, 3, 0, 1] = seg_qq[0, 3, 1, 0] = c


# The wrappers name the kernels through the module object: numba refuses to cache a function
# that passes a plain global dispatcher on to another function ("dynamic globals").
this = sys.modules[__name__]


@njit(cache=True, nogil=True)
def rollout(x0, controls, tau, p, method, states):
    """Trajectory from x0 under piecewise-constant controls (N x nu) into states (N+1 x nx)."""
    horizon.rollout(this.rhs, x0, controls, tau, p, method, states)


@njit(cache=True, nogil=True)
def ipm_iterate(ws, n_iter):
    """Run up to n_iter interior-point iterations on workspace ws (see ipm.py)."""
    return ipm.iterate(this.rhs, this.rhs_jac, this.rhs_hess, this.segments, ws, n_iter)


@njit(cache=True, nogil=True)
def ipm_evaluate(ws):
    """Evaluate derivatives and KKT residuals at the current point of ws (see ipm.py)."""
    return ipm.evaluate(this.rhs, this.rhs_jac, this.rhs_hess, this.segments, ws)


class CylindricalRobot(RobotModel):
    """The 2-DOF cylindrical robot of the paper (rotation q1 [rad], extension q2 [m])."""

    name = 'cylindrical'
    n_joints = N_JOINTS
    n_links = N_LINKS
    joint_kinds = ('revolute', 'prismatic')
    default_joint_names = ('rotation_joint', 'extension_joint')

    def __init__(self, params=None):
        super().__init__(RobotParams() if params is None else params)

    @property
    def kernels(self):
        """Return the kernel module (this one)."""
        return this

    def packed(self):
        """A1, A2, A3, a and the eq. (36)/(37) sign."""
        return self.params.packed()

    @property
    def u_max(self):
        """[u1_max, u2_max]."""
        return self.params.u_max

    def check(self):
        """Problems with the robot data."""
        if not isinstance(self.params, RobotParams):
            return ['robot must be a toc_ros.core.RobotParams']
        return self.params.check()

    def check_state(self, x, name='state'):
        """Check that the arm length a + q2 stays positive."""
        length = self.params.a + float(x[2])
        if not length > 0.0:
            return [f'{name} arm length a + q2 = {length:.6g} m must be > 0']
        return []

    def link_segments(self, q):
        """(..., 1, 4): base (0, 0) to hand."""
        q = np.asarray(q, dtype=float)
        reach = self.params.a + q[..., 1]
        seg = np.zeros(q.shape[:-1] + (1, 4))
        seg[..., 0, 2] = reach * np.cos(q[..., 0])
        seg[..., 0, 3] = reach * np.sin(q[..., 0])
        return seg

    def inverse_kinematics(self, x, y, branch=None, seed=None):
        """q1 = atan2(y, x), q2 = sqrt(x^2 + y^2) - a (unique: the arm is a ray)."""
        distance = math.hypot(x, y)
        if not distance > 0.0:
            raise ModelError('the hand cannot reach the base axis (x = y = 0)')
        return np.array([math.atan2(y, x), distance - self.params.a])


def variants():
    """Return the model-variant names (eq37 as printed, eq36 sign)."""
    return MODEL_VARIANTS
