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
Rigid-body dynamics of a URDF arm written in CasADi symbols, independent of Pinocchio.

The URDF XML is parsed here (xml.etree) into a kinematic tree; the recursions are the textbook
ones (Featherstone, "Rigid Body Dynamics Algorithms", 2008) in the spatial-vector conventions
Pinocchio also uses, so that the two can be compared number for number:

* motion vectors (v, w) and force vectors (f, n), linear part first, each expressed in the
  frame of its body; a body's frame is its joint's frame (the URDF child link frame);
* the placement of a child in its parent, (R, p): x_parent = R x_child + p;
* gravity enters as the base's acceleration a_0 = -g, g = (0, 0, -9.81) in the base frame (the
  URDF root link's frame, REP-103: z up).

The tree (which joints move; the others locked and fused into their parent bodies) is
urdf_tree.py's.

    tree = parse_urdf(path_or_xml, ['panda_joint1', ...], locked={'panda_finger_joint1': 0.0})
    model = ArmCasadi(tree)
    model.forward_dynamics        # casadi Function (q, qd, tau) -> qdd, the ABA
    model.mass_matrix, model.rnea, model.crba_dynamics, model.point_positions(...)

casadi is the package extra 'bench': importing this module without it works; building the
CasADi functions raises ImportError naming the extra.
"""

import numpy as np

from .urdf_tree import GRAVITY, parse_urdf, skew_matrix, UrdfError


def _casadi():
    try:
        import casadi
    except ImportError as exc:  # pragma: no cover - exercised only where casadi is absent
        raise ImportError('toc_ros.bench needs casadi: install the package extra '
                          "'bench' (pip install .[bench]) or pip install casadi") from exc
    return casadi


# ----------------------------------------------------------------------------------------
# CasADi recursions
# ----------------------------------------------------------------------------------------

def _skew(ca, v):
    return ca.vertcat(ca.horzcat(0, -v[2], v[1]), ca.horzcat(v[2], 0, -v[0]),
                      ca.horzcat(-v[1], v[0], 0))


def _dm(ca, array):
    """Return a numeric matrix as a sparse DM: exact zeros become structural (no work in SX)."""
    out = ca.DM(np.asarray(array, dtype=float))
    return ca.sparsify(out)


class ArmCasadi:
    """
    CasADi Functions of an ArmTree (SX graphs; the caller's joint order throughout).

    forward_dynamics(q, qd, tau) -> qdd by the articulated-body algorithm; crba_dynamics the
    same through M(q) (CRBA) and the bias (RNEA at qdd = 0) with casadi.solve; rnea(q, qd, qdd)
    -> tau; mass_matrix(q) -> M; placement(link)(q) -> (R, p) of a link frame in the base.
    """

    def __init__(self, tree):
        self.ca = ca = _casadi()
        self.tree = tree
        n = tree.nq
        self.q = ca.SX.sym('q', n)
        self.qd = ca.SX.sym('qd', n)
        self.qdd = ca.SX.sym('qdd', n)
        self.tau = ca.SX.sym('tau', n)
        self._kin = self._kinematics(self.q)
        a0 = ca.vertcat(*[-g for g in tree.gravity], 0.0, 0.0, 0.0)
        self._a0 = a0
        self.rnea = ca.Function('rnea', [self.q, self.qd, self.qdd],
                                [self._rnea(self.q, self.qd, self.qdd, a0)],
                                ['q', 'qd', 'qdd'], ['tau'])
        self.mass_matrix = ca.Function('crba', [self.q], [self._crba(self.q)], ['q'], ['M'])
        self.forward_dynamics = ca.Function(
            'aba', [self.q, self.qd, self.tau], [self._aba(self.q, self.qd, self.tau, a0)],
            ['q', 'qd', 'tau'], ['qdd'])
        bias = self._rnea(self.q, self.qd, ca.DM.zeros(n), a0)
        self.crba_dynamics = ca.Function(
            'crba_fd', [self.q, self.qd, self.tau],
            [ca.solve(self._crba(self.q), self.tau - bias)], ['q', 'qd', 'tau'], ['qdd'])

    # Per-body joint quantities -------------------------------------------------------------
    def _joint(self, body, qi):
        """(X motion transform parent -> body (6x6), S (6x1), R, p) at joint value qi."""
        ca = self.ca
        axis = body.axis
        if body.kind == 'revolute':
            k = skew_matrix(axis)
            r_joint = (ca.DM.eye(3) + ca.sin(qi) * _dm(ca, k)
                       + (1.0 - ca.cos(qi)) * _dm(ca, k @ k))
            rotation = _dm(ca, body.rotation) @ r_joint
            position = _dm(ca, body.position)
            s = np.concatenate([np.zeros(3), axis])
        else:
            rotation = _dm(ca, body.rotation)
            position = _dm(ca, body.position) + _dm(ca, body.rotation @ axis) * qi
            s = np.concatenate([axis, np.zeros(3)])
        rt = rotation.T
        x = ca.vertcat(ca.horzcat(rt, -rt @ _skew(ca, position)),
                       ca.horzcat(ca.SX.zeros(3, 3), rt))
        return x, _dm(ca, s), rotation, position

    def _kinematics(self, q):
        return [self._joint(body, q[i]) for body, i in zip(self.tree.bodies, self.tree.q_index)]

    def _joint_data(self, q):
        if q is self.q:
            return self._kin
        return self._kinematics(q)

    # Recursions ------------------------------------------------------------------------------
    @staticmethod
    def _crm(ca, v):
        """Motion cross product matrix v x (linear first)."""
        lin, ang = _skew(ca, v[:3]), _skew(ca, v[3:])
        return ca.vertcat(ca.horzcat(ang, lin), ca.horzcat(ca.SX.zeros(3, 3), ang))

    def _rnea(self, q, qd, qdd, a0):
        ca = self.ca
        bodies, idx = self.tree.bodies, self.tree.q_index
        data = self._joint_data(q)
        v, a, f = [], [], []
        for k, body in enumerate(bodies):
            x, s, _, _ = data[k]
            i = idx[k]
            vp = v[body.parent] if body.parent >= 0 else ca.SX.zeros(6)
            ap = a[body.parent] if body.parent >= 0 else a0
            vj = s * qd[i]
            vk = x @ vp + vj
            ak = x @ ap + s * qdd[i] + self._crm(ca, vk) @ vj
            inertia = _dm(ca, body.inertia.matrix())
            fk = inertia @ ak - self._crm(ca, vk).T @ (inertia @ vk)
            v.append(vk)
            a.append(ak)
            f.append(fk)
        tau = [None] * len(bodies)
        for k in range(len(bodies) - 1, -1, -1):
            x, s, _, _ = data[k]
            tau[idx[k]] = s.T @ f[k]
            parent = bodies[k].parent
            if parent >= 0:
                f[parent] = f[parent] + x.T @ f[k]
        return ca.vertcat(*tau)

    def _crba(self, q):
        ca = self.ca
        bodies, idx = self.tree.bodies, self.tree.q_index
        data = self._joint_data(q)
        n = len(bodies)
        composite = [_dm(ca, b.inertia.matrix()) for b in bodies]
        for k in range(n - 1, -1, -1):
            parent = bodies[k].parent
            if parent >= 0:
                x = data[k][0]
                composite[parent] = composite[parent] + x.T @ composite[k] @ x
        mass = ca.SX.zeros(n, n)
        for k in range(n):
            s = data[k][1]
            force = composite[k] @ s
            mass[idx[k], idx[k]] = s.T @ force
            j = k
            while bodies[j].parent >= 0:
                force = data[j][0].T @ force
                j = bodies[j].parent
                value = force.T @ data[j][1]
                mass[idx[k], idx[j]] = value
                mass[idx[j], idx[k]] = value
        return mass

    def _aba(self, q, qd, tau, a0):
        ca = self.ca
        bodies, idx = self.tree.bodies, self.tree.q_index
        data = self._joint_data(q)
        n = len(bodies)
        v, c, art, bias = [], [], [], []
        for k, body in enumerate(bodies):
            x, s, _, _ = data[k]
            vp = v[body.parent] if body.parent >= 0 else ca.SX.zeros(6)
            vj = s * qd[idx[k]]
            vk = x @ vp + vj
            inertia = _dm(ca, body.inertia.matrix())
            v.append(vk)
            c.append(self._crm(ca, vk) @ vj)
            art.append(inertia)
            bias.append(-self._crm(ca, vk).T @ (inertia @ vk))
        u_vec, d_inv, u_sc = [None] * n, [None] * n, [None] * n
        for k in range(n - 1, -1, -1):
            x, s, _, _ = data[k]
            u_vec[k] = art[k] @ s
            d_inv[k] = 1.0 / (s.T @ u_vec[k])
            u_sc[k] = tau[idx[k]] - s.T @ bias[k]
            parent = bodies[k].parent
            if parent >= 0:
                ia = art[k] - u_vec[k] @ (d_inv[k] * u_vec[k].T)
                pa = bias[k] + ia @ c[k] + u_vec[k] * (d_inv[k] * u_sc[k])
                art[parent] = art[parent] + x.T @ ia @ x
                bias[parent] = bias[parent] + x.T @ pa
        acc, qdd = [None] * n, [None] * n
        for k in range(n):
            x, s, _, _ = data[k]
            parent = bodies[k].parent
            ap = acc[parent] if parent >= 0 else a0
            ak = x @ ap + c[k]
            qdd[idx[k]] = d_inv[k] * (u_sc[k] - u_vec[k].T @ ak)
            acc[k] = ak + s * qdd[idx[k]]
        return ca.vertcat(*qdd)

    # Kinematics ---------------------------------------------------------------------------
    def body_placements(self, q):
        """[(R, p)] of every body frame in the base frame (SX or DM, per q)."""
        out = []
        data = self._joint_data(q)
        for k, body in enumerate(self.tree.bodies):
            _, _, rot, pos = data[k]
            if body.parent >= 0:
                r_p, p_p = out[body.parent]
                out.append((r_p @ rot, r_p @ pos + p_p))
            else:
                out.append((rot, pos))
        return out

    def link_placement(self, link, q=None):
        """(R, p) of a link frame in the base frame as SX of q (default the model's symbol)."""
        ca = self.ca
        q = self.q if q is None else q
        if link not in self.tree.links:
            raise UrdfError(f'unknown link {link!r}; the URDF has {sorted(self.tree.links)}')
        body, rot, pos = self.tree.links[link]
        if body < 0:
            return _dm(ca, rot), _dm(ca, pos)
        r_b, p_b = self.body_placements(q)[body]
        return r_b @ _dm(ca, rot), r_b @ _dm(ca, pos) + p_b

    def point_positions(self, points):
        """
        Return a Function q -> (3, P): base-frame positions of points [(link, (x, y, z))].

        The points are given in their link's frame (collision sphere centres).
        """
        ca = self.ca
        if not points:
            return ca.Function('points', [self.q], [ca.SX.zeros(3, 0)], ['q'], ['p'])
        placements = self.body_placements(self.q)
        cols = []
        for link, xyz in points:
            if link not in self.tree.links:
                raise UrdfError(f'unknown link {link!r}; the URDF has {sorted(self.tree.links)}')
            body, rot, pos = self.tree.links[link]
            local = rot @ np.asarray(xyz, dtype=float) + pos      # in the body frame
            if body < 0:
                cols.append(_dm(ca, local))
            else:
                r_b, p_b = placements[body]
                cols.append(r_b @ _dm(ca, local) + p_b)
        return ca.Function('points', [self.q], [ca.horzcat(*cols)], ['q'], ['p'])

    def state_derivative(self, dynamics='aba'):
        """Return the Function (x, u) -> dx/dt, x = (q, qd) positions first, u = torques."""
        ca = self.ca
        n = self.tree.nq
        x, u = ca.SX.sym('x', 2 * n), ca.SX.sym('u', n)
        fd = {'aba': self.forward_dynamics, 'crba': self.crba_dynamics}[dynamics]
        return ca.Function('f', [x, u], [ca.vertcat(x[n:], fd(x[:n], x[n:], u))],
                           ['x', 'u'], ['xdot'])


def load_arm(urdf, joints, locked=None, limits=None, gravity=GRAVITY):
    """parse_urdf + ArmCasadi in one call."""
    return ArmCasadi(parse_urdf(urdf, joints, locked, limits, gravity))
