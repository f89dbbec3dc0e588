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
The robot-model interface of the numeric core.

A robot model is a Python object (a RobotModel subclass) plus a module of numba kernels.  The
solvers are written once against this interface and never look inside a model.

State and control layout (n joints, every model):
    x = (q_1, dq_1, q_2, dq_2, ..., q_n, dq_n)   (nx = 2 n),   u = (u_1, ..., u_n)  (nu = n)
    q_j in rad (revolute) or m (prismatic), u_j in N m or N.  A model with actuator states
    (actuated.py) appends them: nx = 3 n, the joints keep the first 2 n entries.

Pointwise kernels (module-level @njit(cache=True) functions of the model's kernel module; p is
the model's packed parameter vector, float64; every output entry is written, nothing allocated):
    rhs(x, u, p, f)                      f[:] = dx/dt = f(x, u)
    rhs_jac(x, u, p, f, fx, fu)          f, df/dx (nx, nx), df/du (nx, nu)
    rhs_hess(x, u, p, lam, hxx, hxu, huu)
                                         second derivatives of lam . f(x, u):
                                         hxx (nx, nx), hxu (nx, nu), huu (nu, nu)
    segments(q, p, seg, seg_q, seg_qq)   the links as straight segments in the base x-y plane:
                                         seg (L, 4) rows (ax, ay, bx, by) [m];
                                         seg_q (L, 4, n) d seg / d q;
                                         seg_qq (L, 4, n, n) second derivatives
The horizon kernels that the solvers call (rollouts, shooting Jacobians, Hessians, obstacle
constraints, the interior-point iterations) are generic code in toc_ros.core.horizon /
toc_ros.core.ipm that take those pointwise kernels as arguments; each model module binds them
in a few small cached wrappers (see cylindrical.py), so machine code is cached per model.
"""

import dataclasses

import numpy as np


class ModelError(ValueError):
    """Invalid model data or a request the model cannot answer (e.g. unreachable hand goal)."""


class RobotModel:
    """
    Base class of robot models; subclasses set the class attributes and implement the methods.

    Instances are immutable value objects: the physical data is fixed at construction (a frozen
    dataclass in self.params), so a model can be shared between threads and compared/hashed.
    """

    name = ''                 # registry name, e.g. 'cylindrical', 'planar_2r'
    n_joints = 0
    n_links = 0               # number of collision segments
    joint_kinds = ()          # 'revolute' | 'prismatic' per joint (units rad | m)
    default_joint_names = ()
    kernels = None            # the kernel module (pointwise kernels + cached wrappers)

    def __init__(self, params):
        self.params = params

    # Sizes -------------------------------------------------------------------------------
    @property
    def nx(self):
        """State size 2 n."""
        return 2 * self.n_joints

    @property
    def nu(self):
        """Control size n."""
        return self.n_joints

    # Data --------------------------------------------------------------------------------
    def packed(self):
        """Packed float64 parameter vector p for the kernels."""
        raise NotImplementedError

    @property
    def u_max(self):
        """Control bounds (nu,) [N m or N], all > 0."""
        raise NotImplementedError

    def check(self):
        """Return a list of problems with the model data (empty when valid)."""
        raise NotImplementedError

    def check_state(self, x, name='state'):
        """Return problems with a state for this model (e.g. a non-positive arm length)."""
        return []

    # Geometry (numpy, vectorised over rows of q) -----------------------------------------
    def link_segments(self, q):
        """Segments (..., L, 4) rows (ax, ay, bx, by) [m] for joint positions q (..., n)."""
        raise NotImplementedError

    def hand_position(self, q):
        """Hand (end of the last link) position (..., 2) [m] for joint positions q (..., n)."""
        seg = self.link_segments(q)
        return seg[..., -1, 2:4]

    def inverse_kinematics(self, x, y, branch=None, seed=None):
        """
        Joint positions (n,) that put the hand at (x, y) [m] in the base frame.

        branch selects one of several closed-form solutions (ik_branches); seed (joint
        positions, e.g. the current ones) starts a numeric solution.  Raises ModelError with a
        reason when the point is unreachable or the answer is ambiguous for this model and no
        branch selects one.
        """
        raise ModelError(f'model {self.name!r} has no hand inverse kinematics')

    # Helpers shared by every model -------------------------------------------------------
    def positions(self, states):
        """Joint positions q (..., n) of states (..., nx): the even entries of the first 2 n."""
        return np.asarray(states)[..., 0:2 * self.n_joints:2]

    def velocities(self, states):
        """Joint velocities dq (..., n) of states (..., nx): the odd entries of the first 2 n."""
        return np.asarray(states)[..., 1:2 * self.n_joints:2]

    def joint_states(self, states):
        """Joint part (q_1, dq_1, ..., q_n, dq_n) (..., 2 n) of states (..., nx)."""
        return np.asarray(states)[..., :2 * self.n_joints]

    # Largest time step [s] of a plan that resolves the model's fast states (inf: none).
    max_step = float('inf')

    @property
    def joint_model(self):
        """Return the model of the joints driven directly by u (actuated.py wraps one)."""
        return self

    def full_state(self, x, effort=None):
        """
        Return the model's state from a joint state (q_1, dq_1, ..., q_n, dq_n).

        effort: the applied controls (the measured joint efforts), used by models with actuator
        states (actuated.py); here the joint state is the whole state.
        """
        return np.asarray(x, dtype=float).reshape(-1).copy()

    def state(self, q, dq=None):
        """State vector (2 n,) from positions and (default zero) velocities."""
        q = np.asarray(q, dtype=float).reshape(-1)
        x = np.zeros(2 * q.size)
        x[0::2] = q
        if dq is not None:
            x[1::2] = np.asarray(dq, dtype=float).reshape(-1)
        return x

    def parameter_values(self):
        """Return {name: value} of the physical data (self.params, a frozen dataclass)."""
        return {f.name: getattr(self.params, f.name) for f in dataclasses.fields(self.params)}

    def with_parameters(self, values):
        """Return the same model with some parameter values replaced ({name: value})."""
        unknown = sorted(set(values) - set(self.parameter_values()))
        if unknown:
            raise ModelError(f'model {self.name!r} has no parameter(s) {", ".join(unknown)}')
        return type(self)(dataclasses.replace(self.params, **values))

    def __eq__(self, other):
        return type(self) is type(other) and self.params == other.params

    def __hash__(self):
        return hash((type(self).__name__, self.params))

    def __repr__(self):
        return f'{type(self).__name__}({self.params!r})'
