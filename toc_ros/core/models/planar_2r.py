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
The planar two-link arm 'planar_2r' behind the model interface (base.py).

Geometry: joints q1 (shoulder, absolute angle from the base x axis) and q2 (elbow, relative to
link 1), revolute, in the base x-y plane; base at the origin; elbow p1 = l1 (cos q1, sin q1),
hand p2 = p1 + l2 (cos(q1 + q2), sin(q1 + q2)); link 1 = [0, p1], link 2 = [p1, p2].

Dynamics from the Lagrangian of two uniform rods (mass m_i, length l_i, centre of mass at
l_i / 2, inertia m_i l_i^2 / 12 about it), a point payload m_p at the hand and gravity g along
-y of the base frame:

    T = a/2 dq1^2 + b/2 (dq1 + dq2)^2 + c cos(q2) dq1 (dq1 + dq2)
    V = g1 sin(q1) + g2 sin(q1 + q2)
    a = (m1/3 + m2 + m_p) l1^2,  b = (m2/3 + m_p) l2^2,  c = (m2/2 + m_p) l1 l2,
    g1 = g (m1/2 + m2 + m_p) l1,  g2 = g (m2/2 + m_p) l2,

    M(q) = [[a + b + 2 c cos q2, b + c cos q2], [b + c cos q2, b]],
    C(q, dq) dq = c sin(q2) (-(2 dq1 dq2 + dq2^2), dq1^2),
    G(q) = (g1 cos q1 + g2 cos(q1 + q2), g2 cos(q1 + q2)),
    M(q) ddq + C(q, dq) dq + G(q) = u,   det M = a b - c^2 cos^2 q2 >= a b - c^2 > 0.

State x = (q1, dq1, q2, dq2), u = (u1, u2).  With r = u - C dq - G and w = ddq = M^-1 r the
kernels differentiate implicitly: dw/dz = M^-1 (dr/dz - dM/dz w) and, for the Hessian of
lam . f with nu = M^-1 (lam[1], lam[3]),
    d2(lam . f)/dz dy = nu . (d2r/dz dy - dM/dz dw/dy - dM/dy dw/dz - d2M/dz dy w),
where M depends on q2 only.

Hand inverse kinematics: 'elbow_up' is the solution with q2 <= 0, 'elbow_down' the one with
q2 >= 0 (reaching along +x with y = 0, the elbow is then above resp. below the x axis: the elbow
lies counter-clockwise resp. clockwise of the base-to-hand line).
"""

from dataclasses import dataclass
import math
import sys

from numba import njit
import numpy as np

from .base import ModelError, RobotModel
from .. import horizon, ipm

N_JOINTS = 2
N_LINKS = 2

# Indices into the packed parameter vector.
P_L1, P_L2, P_A, P_B, P_C, P_G1, P_G2 = range(7)
N_PARAMS = 7

IK_BRANCHES = ('elbow_up', 'elbow_down')


@dataclass(frozen=True)
class Planar2RParams:
    """Physical data of the planar two-link arm."""

    l1: float = 1.0          # [m] link 1 (shoulder to elbow)
    l2: float = 0.8          # [m] link 2 (elbow to hand)
    m1: float = 12.0         # [kg] uniform rod 1
    m2: float = 8.0          # [kg] uniform rod 2
    m_p: float = 2.0         # [kg] point payload at the hand
    u1_max: float = 250.0    # [N m] shoulder torque bound
    u2_max: float = 120.0    # [N m] elbow torque bound
    g: float = 0.0           # [m/s^2] gravity along -y of the base frame (0: horizontal plane)

    def check(self):
        """Return a list of problems with the data (empty when valid)."""
        errors = []
        for name in ('l1', 'l2', 'm1', 'm2', 'm_p', 'u1_max', 'u2_max'):
            value = getattr(self, name)
            if (isinstance(value, bool) or not isinstance(value, (int, float))
                    or not math.isfinite(value) or value <= 0.0):
                errors.append(f'robot.{name} must be a finite positive number, got {value!r}')
        g = self.g
        if isinstance(g, bool) or not isinstance(g, (int, float)) or not math.isfinite(g):
            errors.append(f'robot.g must be a finite number, got {g!r}')
        return errors

    @property
    def u_max(self):
        """Control bounds [u1_max, u2_max] as an array."""
        return np.array([float(self.u1_max), float(self.u2_max)])

    def packed(self):
        """Pack l1, l2 and the Lagrangian constants a, b, c, g1, g2 (module docstring)."""
        l1, l2, m1, m2, mp, g = (float(v) for v in (self.l1, self.l2, self.m1, self.m2,
                                                    self.m_p, self.g))
        p = np.empty(N_PARAMS)
        p[P_L1] = l1
        p[P_L2] = l2
        p[P_A] = (m1 / 3.0 + m2 + mp) * l1 * l1
        p[P_B] = (m2 / 3.0 + mp) * l2 * l2
        p[P_C] = (0.5 * m2 + mp) * l1 * l2
        p[P_G1] = g * (0.5 * m1 + m2 + mp) * l1
        p[P_G2] = g * (0.5 * m2 + mp) * l2
        return p


@njit(cache=True, inline='always')
def _dynamics(x, u, p):
    """
    Scalars of the dynamics shared by the kernels.

    Returns (c2, s2, c1, s1, c12, s12, i11, i12, i22, r1, r2, w1, w2): trigonometry, the entries
    of M^-1, the residual r = u - C dq - G and the accelerations w = M^-1 r.
    """
    b, c = p[P_B], p[P_C]
    c1, s1 = math.cos(x[0]), math.sin(x[0])
    c2, s2 = math.cos(x[2]), math.sin(x[2])
    c12, s12 = math.cos(x[0] + x[2]), math.sin(x[0] + x[2])
    dq1, dq2 = x[1], x[3]
    m11 = p[P_A] + b + 2.0 * c * c2
    m12 = b + c * c2
    inv_det = 1.0 / (m11 * b - m12 * m12)
    i11 = b * inv_det
    i12 = -m12 * inv_det
    i22 = m11 * inv_det
    gc12 = p[P_G2] * c12
    r1 = u[0] + c * s2 * (2.0 * dq1 + dq2) * dq2 - p[P_G1] * c1 - gc12
    r2 = u[1] - c * s2 * dq1 * dq1 - gc12
    return (c2, s2, c1, s1, c12, s12, i11, i12, i22, r1, r2,
            i11 * r1 + i12 * r2, i12 * r1 + i22 * r2)


@njit(cache=True, inline='always')
def rhs(x, u, p, f):
    """dx/dt of the planar two-link arm into f."""
    d = _dynamics(x, u, p)
    f[0] = x[1]
    f[1] = d[11]
    f[2] = x[3]
    f[3] = d[12]


@njit(cache=True, inline='always')
def _partials(x, p, c2, s2, s1, s12, i11, i12, i22, w1, w2):
    """
    dw/dz for z = q1, dq1, q2, dq2 (w = M^-1 r, module docstring), as 8 scalars.

    Returns (w1_q1, w2_q1, w1_dq1, w2_dq1, w1_q2, w2_q2, w1_dq2, w2_dq2).
    """
    c = p[P_C]
    dq1, dq2 = x[1], x[3]
    gs12 = p[P_G2] * s12
    # dr/dz (r1, r2).
    r1_q1 = p[P_G1] * s1 + gs12
    r2_q1 = gs12
    r1_dq1 = 2.0 * c * s2 * dq2
    r2_dq1 = -2.0 * c * s2 * dq1
    cs2 = c * s2
    # dM/dq2 w = -c s2 (2 w1 + w2, w1).
    r1_q2 = c * c2 * (2.0 * dq1 + dq2) * dq2 + gs12 + cs2 * (2.0 * w1 + w2)
    r2_q2 = -c * c2 * dq1 * dq1 + gs12 + cs2 * w1
    r1_dq2 = 2.0 * cs2 * (dq1 + dq2)
    return (i11 * r1_q1 + i12 * r2_q1, i12 * r1_q1 + i22 * r2_q1,
            i11 * r1_dq1 + i12 * r2_dq1, i12 * r1_dq1 + i22 * r2_dq1,
            i11 * r1_q2 + i12 * r2_q2, i12 * r1_q2 + i22 * r2_q2,
            i11 * r1_dq2, i12 * r1_dq2)


@njit(cache=True, inline='always')
def rhs_jac(x, u, p, f, fx, fu):
    """f, df/dx, df/du of the planar two-link arm."""
    c2, s2, c1, s1, c12, s12, i11, i12, i22, r1, r2, w1, w2 = _dynamics(x, u, p)
    d = _partials(x, p, c2, s2, s1, s12, i11, i12, i22, w1, w2)
    f[0] = x[1]
    f[1] = w1
    f[2] = x[3]
    f[3] = w2
    for c in range(4):
        fx[0, c] = 0.0
        fx[2, c] = 0.0
    fx[0, 1] = 1.0
    fx[2, 3] = 1.0
    fx[1, 0], fx[3, 0] = d[0], d[1]
    fx[1, 1], fx[3, 1] = d[2], d[3]
    fx[1, 2], fx[3, 2] = d[4], d[5]
    fx[1, 3], fx[3, 3] = d[6], d[7]
    fu[0, 0] = 0.0
    fu[0, 1] = 0.0
    fu[2, 0] = 0.0
    fu[2, 1] = 0.0
    fu[1, 0], fu[1, 1] = i11, i12
    fu[3, 0], fu[3, 1] = i12, i22


@njit(cache=True, inline='always')
def rhs_hess(x, u, p, lam, hxx, hxu, huu):
    """Second derivatives of lam . f(x, u) for the planar two-link arm (module docstring)."""
    c2, s2, c1, s1, c12, s12, i11, i12, i22, r1, r2, w1, w2 = _dynamics(x, u, p)
    w1_q1, w2_q1, w1_dq1, w2_dq1, w1_q2, w2_q2, w1_dq2, w2_dq2 = _partials(
        x, p, c2, s2, s1, s12, i11, i12, i22, w1, w2)
    c = p[P_C]
    dq1, dq2 = x[1], x[3]
    # nu = M^-1 (lam1, lam3); only the acceleration rows of f are nonlinear.
    nu1 = i11 * lam[1] + i12 * lam[3]
    nu2 = i12 * lam[1] + i22 * lam[3]
    cs2, cc2 = c * s2, c * c2
    # M' nu with M' = dM/dq2 = -c s2 [[2, 1], [1, 0]]; M'' = -c c2 [[2, 1], [1, 0]].
    mn1 = -cs2 * (2.0 * nu1 + nu2)
    mn2 = -cs2 * nu1
    t_q1 = mn1 * w1_q1 + mn2 * w2_q1
    t_dq1 = mn1 * w1_dq1 + mn2 * w2_dq1
    t_q2 = mn1 * w1_q2 + mn2 * w2_q2
    t_dq2 = mn1 * w1_dq2 + mn2 * w2_dq2
    t_u1 = mn1 * i11 + mn2 * i12
    t_u2 = mn1 * i12 + mn2 * i22
    nmw = -cc2 * (nu1 * (2.0 * w1 + w2) + nu2 * w1)
    # nu . d2r (r1 and r2 are linear in u: no u terms).
    g1c1 = p[P_G1] * c1
    g2c12 = p[P_G2] * c12
    r_q1q1 = nu1 * (g1c1 + g2c12) + nu2 * g2c12
    r_q1q2 = (nu1 + nu2) * g2c12
    r_q2q2 = (nu1 * (-cs2 * (2.0 * dq1 + dq2) * dq2 + g2c12)
              + nu2 * (cs2 * dq1 * dq1 + g2c12))
    r_q2dq1 = nu1 * 2.0 * cc2 * dq2 - nu2 * 2.0 * cc2 * dq1
    r_q2dq2 = nu1 * 2.0 * cc2 * (dq1 + dq2)
    r_dq1dq1 = -nu2 * 2.0 * cs2
    r_dq1dq2 = nu1 * 2.0 * cs2
    r_dq2dq2 = nu1 * 2.0 * cs2
    for r in range(4):
        hxx[0, r] = 0.0
        hxx[2, r] = 0.0
        hxx[r, 0] = 0.0
        hxx[r, 2] = 0.0
        hxu[r, 0] = 0.0
        hxu[r, 1] = 0.0
    # State order (q1, dq1, q2, dq2) = indices (0, 1, 2, 3).
    hxx[0, 0] = r_q1q1
    hxx[0, 1] = hxx[1, 0] = 0.0
    hxx[0, 2] = hxx[2, 0] = r_q1q2 - t_q1
    hxx[0, 3] = hxx[3, 0] = 0.0
    hxx[1, 1] = r_dq1dq1
    hxx[1, 2] = hxx[2, 1] = r_q2dq1 - t_dq1
    hxx[1, 3] = hxx[3, 1] = r_dq1dq2
    hxx[2, 2] = r_q2q2 - 2.0 * t_q2 - nmw
    hxx[2, 3] = hxx[3, 2] = r_q2dq2 - t_dq2
    hxx[3, 3] = r_dq2dq2
    hxu[2, 0] = -t_u1
    hxu[2, 1] = -t_u2
    huu[0, 0] = 0.0
    huu[0, 1] = 0.0
    huu[1, 0] = 0.0
    huu[1, 1] = 0.0


@njit(cache=True, inline='always')
def segments(q, p, seg, seg_q, seg_qq):
    """Link 1 = [0, p1], link 2 = [p1, p2] with first and second derivatives wrt q."""
    l1, l2 = p[P_L1], p[P_L2]
    c1, s1 = math.cos(q[0]), math.sin(q[0])
    c12, s12 = math.cos(q[0] + q[1]), math.sin(q[0] + q[1])
    ex, ey = l1 * c1, l1 * s1            # elbow p1
    hx, hy = l2 * c12, l2 * s12          # hand minus elbow
    for k in range(2):
        for r in range(4):
            for j in range(2):
                seg_q[k, r, j] = 0.0
                for i in range(2):
                    seg_qq[k, r, j, i] = 0.0
    seg[0, 0] = 0.0
    seg[0, 1] = 0.0
    seg[0, 2] = ex
    seg[0, 3] = ey
    seg[1, 0] = ex
    seg[1, 1] = ey
    seg[1, 2] = ex + hx
    seg[1, 3] = ey + hy
    # The elbow depends on q1 only.
    seg_q[0, 2, 0] = seg_q[1, 0, 0] = -ey
    seg_q[0, 3, 0] = seg_q[1, 1, 0] = ex
    seg_qq[0, 2, 0, 0] = seg_qq[1, 0, 0, 0] = -ex
    seg_qq[0, 3, 0, 0] = seg_qq[1, 1, 0, 0] = -ey
    # The hand.
    seg_q[1, 2, 0] = -ey - hy
    seg_q[1, 2, 1] = -hy
    seg_q[1, 3, 0] = ex + hx
    seg_q[1, 3, 1] = hx
    seg_qq[1, 2, 0, 0] = -ex - hx
    seg_qq[1, 2, 0, 1] = seg_qq[1, 2, 1, 0] = seg_qq[1, 2, 1, 1] = -hx
    seg_qq[1, 3, 0, 0] = -ey - hy
    seg_qq[1, 3, 0, 1] = seg_qq[1, 3, 1, 0] = seg_qq[1, 3, 1, 1] = -hy


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


class Planar2R(RobotModel):
    """The planar two-link arm (shoulder q1, elbow q2 relative, both in rad)."""

    name = 'planar_2r'
    n_joints = N_JOINTS
    n_links = N_LINKS
    joint_kinds = ('revolute', 'revolute')
    default_joint_names = ('shoulder_joint', 'elbow_joint')
    ik_branches = IK_BRANCHES

    def __init__(self, params=None):
        super().__init__(Planar2RParams() if params is None else params)

    @property
    def kernels(self):
        """Return the kernel module (this one)."""
        return this

    def packed(self):
        """l1, l2, a, b, c, g1, g2 (module docstring)."""
        return self.params.packed()

    @property
    def u_max(self):
        """[u1_max, u2_max]."""
        return self.params.u_max

    def check(self):
        """Problems with the robot data."""
        if not isinstance(self.params, Planar2RParams):
            return ['robot must be a toc_ros.core.models.planar_2r.Planar2RParams']
        return self.params.check()

    def mass_matrix(self, q):
        """M(q) (2, 2) at joint positions q (module docstring)."""
        p = self.packed()
        c2 = math.cos(float(q[1]))
        m12 = p[P_B] + p[P_C] * c2
        return np.array([[p[P_A] + p[P_B] + 2.0 * p[P_C] * c2, m12], [m12, p[P_B]]])

    def link_segments(self, q):
        """(..., 2, 4): [0, elbow] and [elbow, hand]."""
        q = np.asarray(q, dtype=float)
        l1, l2 = float(self.params.l1), float(self.params.l2)
        q1, q12 = q[..., 0], q[..., 0] + q[..., 1]
        seg = np.zeros(q.shape[:-1] + (2, 4))
        seg[..., 0, 2] = seg[..., 1, 0] = l1 * np.cos(q1)
        seg[..., 0, 3] = seg[..., 1, 1] = l1 * np.sin(q1)
        seg[..., 1, 2] = seg[..., 1, 0] + l2 * np.cos(q12)
        seg[..., 1, 3] = seg[..., 1, 1] + l2 * np.sin(q12)
        return seg

    def inverse_kinematics(self, x, y, branch=None, seed=None):
        """
        Joint positions (q1, q2) that put the hand at (x, y) [m].

        branch 'elbow_up' gives q2 <= 0, 'elbow_down' q2 >= 0 (module docstring); q1 is in
        (-pi, pi].  Raises ModelError when branch is not one of them (the answer is ambiguous
        without it), when the point is outside the annulus |l1 - l2| <= r <= l1 + l2, or at the
        base when l1 = l2 (every q1 is a solution).
        """
        if branch not in IK_BRANCHES:
            raise ModelError(
                f'planar_2r hand goal ({x:.6g}, {y:.6g}) is ambiguous: choose the IK branch, '
                f'one of {IK_BRANCHES} (got {branch!r})')
        x, y = float(x), float(y)
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ModelError(f'planar_2r hand goal ({x!r}, {y!r}) is not finite')
        l1, l2 = float(self.params.l1), float(self.params.l2)
        r = math.hypot(x, y)
        outer, inner = l1 + l2, abs(l1 - l2)
        tol = 1e-12 * outer
        if r > outer + tol:
            raise ModelError(f'planar_2r hand goal ({x:.6g}, {y:.6g}) is out of reach: '
                             f'distance {r:.6g} m > l1 + l2 = {outer:.6g} m')
        if r < inner - tol:
            raise ModelError(f'planar_2r hand goal ({x:.6g}, {y:.6g}) is too close to the '
                             f'base: distance {r:.6g} m < |l1 - l2| = {inner:.6g} m')
        if r <= tol:
            raise ModelError('planar_2r hand goal at the base (l1 = l2): every shoulder angle '
                             'q1 reaches it, the goal does not determine the pose')
        cos_q2 = (r * r - l1 * l1 - l2 * l2) / (2.0 * l1 * l2)
        q2 = math.acos(min(1.0, max(-1.0, cos_q2)))
        if branch == 'elbow_up':
            q2 = -q2
        q1 = math.atan2(y, x) - math.atan2(l2 * math.sin(q2), l1 + l2 * math.cos(q2))
        q1 = math.atan2(math.sin(q1), math.cos(q1))
        return np.array([q1, q2])
