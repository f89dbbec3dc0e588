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
CasADi expressions of the robot models for the IPOPT / FATROP reference transcriptions.

Written independently of toc_ros' numba kernels (and of its SymPy generator), from the model
definitions of the paper and of issue 13:

* 'cylindrical': eq. (37) of the paper, x = [q1, dq1, q2, dq2], A1 = I + M a^2, A2 = 2 M a,
  A3 = m + M, D = A1 + A2 q2 + A3 q2^2,
  dq1' = (u1 - (A2 + 2 A3 q2) dq1 dq2) / D,  dq2' = (q2 + s A2 / (2 A3)) dq1^2 + u2 / A3,
  s = -1 ('eq37', as printed) or +1 ('eq36'); one link from the base to the hand at distance
  a + q2 along (cos q1, sin q1).
* 'planar_2r': the Lagrangian of two uniform rods and a hand payload written from the points'
  positions (centres of mass and rod inertias m l^2 / 12), with gravity g along -y; the mass
  matrix and the Euler-Lagrange equations come from CasADi's algorithmic differentiation:
  M = d2T/d dq2, ddq = M^-1 (u - (d2L/d dq dq) dq + dL/dq).
* a model file path (.yaml, format of toc_ros.core.models.symbolic): its expressions are
  evaluated with CasADi functions (Python eval, a restricted namespace), ddt(e) = de/dq dq,
  and the Lagrangian case differentiated by CasADi as above.

    f, segments, u_max = casadi_model('planar_2r', {'g': 9.81})
    xdot = f(x, u)            # casadi Function (nx, 1) from x (nx,), u (nu,); SX/MX/DM
    seg = segments(q)         # casadi Function: (L, 4) rows (ax, ay, bx, by)
    f_lag = with_actuators(f, u_max, 0.01)    # with first-order actuators (actuated.py)

casadi is optional (setup.py extra 'bench'); importing this module without it works, calling
casadi_model raises ImportError.
"""

import math

import numpy as np
import yaml

try:  # optional dependency: only the expressions need it
    import casadi as ca
except ImportError:  # pragma: no cover - exercised only where casadi is absent
    ca = None

CYLINDRICAL_DEFAULTS = {'hand_mass': 50.0, 'link_mass': 97.0, 'inertia': 193.0, 'a': 1.1,
                        'u1_max': 600.0, 'u2_max': 500.0, 'model_variant': 'eq37'}
PLANAR_2R_DEFAULTS = {'l1': 1.0, 'l2': 0.8, 'm1': 12.0, 'm2': 8.0, 'm_p': 2.0,
                      'u1_max': 250.0, 'u2_max': 120.0, 'g': 0.0}
BUILT_IN = ('cylindrical', 'planar_2r')


def _merged(defaults, params, name):
    values = dict(defaults)
    unknown = sorted(set(params or {}) - set(defaults))
    if unknown:
        raise ValueError(f'model {name!r} has no parameter(s) {unknown}')
    values.update(params or {})
    return values


def _functions(x, u, q, xdot, seg):
    f = ca.Function('f', [x, u], [xdot], ['x', 'u'], ['xdot'])
    segments = ca.Function('segments', [q], [seg], ['q'], ['seg'])
    return f, segments


def _cylindrical(params):
    v = _merged(CYLINDRICAL_DEFAULTS, params, 'cylindrical')
    sign = {'eq37': -1.0, 'eq36': 1.0}[v['model_variant']]
    big_m, small_m, inertia, a = v['hand_mass'], v['link_mass'], v['inertia'], v['a']
    a1, a2, a3 = inertia + big_m * a * a, 2.0 * big_m * a, small_m + big_m
    x, u = ca.SX.sym('x', 4), ca.SX.sym('u', 2)
    dq1, q2, dq2 = x[1], x[2], x[3]
    den = a1 + a2 * q2 + a3 * q2 ** 2
    xdot = ca.vertcat(dq1, (u[0] - (a2 + 2.0 * a3 * q2) * dq1 * dq2) / den, dq2,
                      (q2 + sign * a2 / (2.0 * a3)) * dq1 ** 2 + u[1] / a3)
    q = ca.SX.sym('q', 2)
    reach = a + q[1]
    seg = ca.horzcat(0.0, 0.0, reach * ca.cos(q[0]), reach * ca.sin(q[0]))
    return _functions(x, u, q, xdot, seg) + (np.array([v['u1_max'], v['u2_max']]),)


def _euler_lagrange(x, u, kinetic, potential, forces):
    """Return dx/dt of a Lagrangian model by CasADi AD (x interleaved (q1, dq1, ...))."""
    n = x.shape[0] // 2
    q = ca.vertcat(*[x[2 * j] for j in range(n)])
    dq = ca.vertcat(*[x[2 * j + 1] for j in range(n)])
    lagrangian = kinetic - potential
    mass, momentum = ca.hessian(lagrangian, dq)
    cross = ca.jacobian(momentum, q)
    ddq = ca.solve(mass, forces - ca.mtimes(cross, dq) + ca.gradient(lagrangian, q))
    return ca.vertcat(*[e for j in range(n) for e in (dq[j], ddq[j])])


def _planar_2r(params):
    v = _merged(PLANAR_2R_DEFAULTS, params, 'planar_2r')
    l1, l2, m1, m2, mp, g = v['l1'], v['l2'], v['m1'], v['m2'], v['m_p'], v['g']
    x, u = ca.SX.sym('x', 4), ca.SX.sym('u', 2)
    q1, dq1, q2, dq2 = x[0], x[1], x[2], x[3]

    def point(s1, s2):
        # Position and velocity of the point s1 l1 e(q1) + s2 l2 e(q1 + q2).
        pos = ca.vertcat(s1 * l1 * ca.cos(q1) + s2 * l2 * ca.cos(q1 + q2),
                         s1 * l1 * ca.sin(q1) + s2 * l2 * ca.sin(q1 + q2))
        vel = ca.jtimes(pos, ca.vertcat(q1, q2), ca.vertcat(dq1, dq2))
        return pos, vel

    c1, v1 = point(0.5, 0.0)          # centre of rod 1
    c2, v2 = point(1.0, 0.5)          # centre of rod 2
    hand, vh = point(1.0, 1.0)
    kinetic = (0.5 * m1 * ca.dot(v1, v1) + 0.5 * (m1 * l1 ** 2 / 12.0) * dq1 ** 2
               + 0.5 * m2 * ca.dot(v2, v2) + 0.5 * (m2 * l2 ** 2 / 12.0) * (dq1 + dq2) ** 2
               + 0.5 * mp * ca.dot(vh, vh))
    potential = g * (m1 * c1[1] + m2 * c2[1] + mp * hand[1])
    xdot = _euler_lagrange(x, u, kinetic, potential, u)
    q = ca.SX.sym('q', 2)
    elbow = l1 * ca.vertcat(ca.cos(q[0]), ca.sin(q[0]))
    tip = elbow + l2 * ca.vertcat(ca.cos(q[0] + q[1]), ca.sin(q[0] + q[1]))
    seg = ca.vertcat(ca.horzcat(0.0, 0.0, elbow[0], elbow[1]),
                     ca.horzcat(elbow[0], elbow[1], tip[0], tip[1]))
    return _functions(x, u, q, xdot, seg) + (np.array([v['u1_max'], v['u2_max']]),)


_CASADI_FUNCTIONS = ('sin', 'cos', 'tan', 'asin', 'acos', 'atan', 'sinh', 'cosh', 'tanh',
                     'exp', 'log', 'sqrt')


def _from_file(path, params):
    with open(path, encoding='utf-8') as stream:
        data = yaml.safe_load(stream)
    n = len(data['joints'])
    values = _merged({k: float(v) for k, v in (data.get('parameters') or {}).items()},
                     params, data['name'])
    x, u, qs = ca.SX.sym('x', 2 * n), ca.SX.sym('u', n), ca.SX.sym('q', n)
    q = ca.vertcat(*[x[2 * j] for j in range(n)])
    dq = ca.vertcat(*[x[2 * j + 1] for j in range(n)])
    env = {name: getattr(ca, name) for name in _CASADI_FUNCTIONS}
    env.update(atan2=ca.atan2, pi=math.pi, ddt=lambda e: ca.jtimes(e, q, dq))
    env.update(values)
    for j in range(n):
        env[f'q{j + 1}'], env[f'dq{j + 1}'], env[f'u{j + 1}'] = q[j], dq[j], u[j]

    def ev(text):
        return eval(str(text).replace('^', '**'), {'__builtins__': {}}, env)  # noqa: S307

    u_max = np.array([float(ev(e)) for e in data['u_max']])
    for name, text in (data.get('definitions') or {}).items():
        env[name] = ev(text)
    links = [[ev(e) for e in link] for link in data['links']]
    seg = ca.vertcat(*[ca.horzcat(*row) for row in links])
    seg = ca.substitute(seg, q, qs)      # the segments as a function of q alone
    if 'dynamics' in data:
        xdot = ca.vertcat(*[ev(e) for e in data['dynamics']])
    else:
        lag = data['lagrangian']
        forces = ca.vertcat(*[ev(e) for e in lag['forces']]) if 'forces' in lag else u
        xdot = _euler_lagrange(x, u, ev(lag['kinetic']), ev(lag.get('potential', 0)),
                               forces)
    return _functions(x, u, qs, xdot, seg) + (u_max,)


def with_actuators(f, u_max, lag):
    """
    Return f with first-order actuators: x = [joint states; s], s = a / u_max (scaled).

    ds/dt = (u / u_max - s) / lag, the joints driven by the applied a = u_max s (the layout of
    toc_ros.core.models.actuated, written here from its definition).
    """
    nxb, nu = f.size1_in(0), f.size1_in(1)
    x, u = ca.SX.sym('x', nxb + nu), ca.SX.sym('u', nu)
    scale = ca.DM(np.asarray(u_max, dtype=float))
    s = x[nxb:]
    xdot = ca.vertcat(f(x[:nxb], scale * s), (u / scale - s) / float(lag))
    return ca.Function('f', [x, u], [xdot], ['x', 'u'], ['xdot'])


def casadi_model(name, params=None):
    """
    Return (f, segments, u_max) of a model.

    f(x, u) -> dx/dt and segments(q) -> (L, 4) are casadi Functions, u_max a numpy array.
    name: 'cylindrical', 'planar_2r' or a model file path;
    params: parameter overrides ({'model_variant': 'eq36'}, {'g': 9.81, 'l1': 0.9}, ...).
    """
    if ca is None:
        raise ImportError('casadi_model needs casadi: pip install casadi')
    if name == 'cylindrical':
        return _cylindrical(params)
    if name == 'planar_2r':
        return _planar_2r(params)
    if str(name).lower().endswith(('.yaml', '.yml')):
        return _from_file(name, params)
    raise ValueError(f'unknown model {name!r}: one of {BUILT_IN} or a model file (.yaml)')
