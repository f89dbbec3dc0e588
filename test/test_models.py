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
Robot models (core/models).

Kernels against finite differences, generated against built-in models, planar_2r against an
independent Euler-Lagrange evaluation, IK, model-file errors.
"""

import math
import os
import pickle

import numpy as np
import pytest

from toc_ros.core import horizon
from toc_ros.core.models import (ActuatedModel, load_model, ModelError, MODELS, Planar2R,
                                 Planar2RParams, with_actuator_lag)

pytest.importorskip('sympy')

from toc_ros.core.models import symbolic  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PLANAR_FILE = os.path.join(ROOT, 'config', 'models', 'planar_2r.yaml')
CYLINDRICAL_FILE = os.path.join(ROOT, 'config', 'models', 'cylindrical_eq37.yaml')
PLANAR_OTHER = {'l1': 0.9, 'l2': 0.6, 'm1': 10.0, 'm2': 5.0, 'm_p': 3.0, 'g': 9.81}
CYLINDRICAL_OTHER = {'hand_mass': 20.0, 'link_mass': 40.0, 'inertia': 80.0, 'a': 0.7}

# A three-link planar arm with a damped elbow (n = 3: the generator is not specialised to 2).
PLANAR_3R = """
name: planar_3r
joints:
  - {name: j1, kind: revolute}
  - {name: j2, kind: revolute}
  - {name: j3, kind: revolute}
parameters: {l1: 1.0, l2: 0.7, l3: 0.4, m1: 5.0, m2: 3.0, m3: 1.0, g: 9.81, damping: 0.5}
positive: [l1, l2, l3, m1, m2, m3]
u_max: [100, 60, 20]
definitions:
  x1: l1*cos(q1)
  y1: l1*sin(q1)
  x2: x1 + l2*cos(q1 + q2)
  y2: y1 + l2*sin(q1 + q2)
  x3: x2 + l3*cos(q1 + q2 + q3)
  y3: y2 + l3*sin(q1 + q2 + q3)
links: [[0, 0, x1, y1], [x1, y1, x2, y2], [x2, y2, x3, y3]]
lagrangian:
  kinetic: >-
    m1/2*(ddt(x1/2)^2 + ddt(y1/2)^2) + m1*l1^2/24*dq1^2
    + m2/2*(ddt((x1 + x2)/2)^2 + ddt((y1 + y2)/2)^2) + m2*l2^2/24*(dq1 + dq2)^2
    + m3/2*(ddt((x2 + x3)/2)^2 + ddt((y2 + y3)/2)^2) + m3*l3^2/24*(dq1 + dq2 + dq3)^2
  potential: g*(m1*y1/2 + m2*(y1 + y2)/2 + m3*(y2 + y3)/2)
  forces: [u1, u2 - damping*dq2, u3]
"""

# The cylindrical robot from its Lagrangian T = (D(q2) dq1^2 + A3 dq2^2) / 2: the Euler-Lagrange
# equations give the centrifugal sign of eq. (36) (the built-in 'eq36' variant).
CYLINDRICAL_LAGRANGIAN = """
name: cylindrical_lagrangian
joints: [{name: rotation_joint, kind: revolute}, {name: extension_joint, kind: prismatic}]
parameters: {hand_mass: 20.0, link_mass: 40.0, inertia: 80.0, a: 0.7}
u_max: [600, 500]
links: [[0, 0, (a + q2)*cos(q1), (a + q2)*sin(q1)]]
lagrangian:
  kinetic: >-
    (inertia + hand_mass*(a + q2)^2 + link_mass*q2^2)*dq1^2/2
    + (link_mass + hand_mass)*dq2^2/2
"""

# (id, loader) of every model the kernel checks run on.
MODEL_CASES = [
    ('cylindrical-eq37', lambda: load_model('cylindrical')),
    ('cylindrical-eq36', lambda: load_model('cylindrical', model_variant='eq36',
                                            **CYLINDRICAL_OTHER)),
    ('planar_2r', lambda: load_model('planar_2r')),
    ('planar_2r-gravity', lambda: load_model('planar_2r', **PLANAR_OTHER)),
    ('planar_2r-file', lambda: load_model(PLANAR_FILE, **PLANAR_OTHER)),
    ('cylindrical-file-eq36', lambda: load_model(CYLINDRICAL_FILE, sign=1.0,
                                                 **CYLINDRICAL_OTHER)),
    ('planar_3r-text', lambda: symbolic.model_from_text(PLANAR_3R, 'planar_3r.yaml')),
    ('cylindrical-lagrangian-text', lambda: symbolic.model_from_text(
        CYLINDRICAL_LAGRANGIAN, 'cylindrical_lagrangian.yaml')),
    # With first-order actuators (actuated.py): nx = 3 n.
    ('cylindrical-actuated', lambda: with_actuator_lag(load_model('cylindrical'), 0.01)),
    ('planar_2r-gravity-actuated', lambda: with_actuator_lag(
        load_model('planar_2r', **PLANAR_OTHER), 0.02)),
    ('planar_3r-text-actuated', lambda: with_actuator_lag(
        symbolic.model_from_text(PLANAR_3R, 'planar_3r.yaml'), 0.005)),
]


@pytest.fixture(scope='module', params=MODEL_CASES, ids=[c[0] for c in MODEL_CASES])
def model(request):
    return request.param[1]()


# ------------------------------------------------------------------------------------------
# Kernel calls
# ------------------------------------------------------------------------------------------

def _rhs(model, x, u):
    f = np.full(model.nx, np.nan)
    model.kernels.rhs(x, u, model.packed(), f)
    return f


def _jac(model, x, u):
    nx, nu = model.nx, model.nu
    f, fx, fu = np.full(nx, np.nan), np.full((nx, nx), np.nan), np.full((nx, nu), np.nan)
    model.kernels.rhs_jac(x, u, model.packed(), f, fx, fu)
    return f, fx, fu


def _hess(model, x, u, lam):
    nx, nu = model.nx, model.nu
    hxx, hxu, huu = (np.full((nx, nx), np.nan), np.full((nx, nu), np.nan),
                     np.full((nu, nu), np.nan))
    model.kernels.rhs_hess(x, u, model.packed(), lam, hxx, hxu, huu)
    return hxx, hxu, huu


def _seg(model, q):
    n, nl = model.n_joints, model.n_links
    seg, seg_q, seg_qq = (np.full((nl, 4), np.nan), np.full((nl, 4, n), np.nan),
                          np.full((nl, 4, n, n), np.nan))
    model.kernels.segments(q, model.packed(), seg, seg_q, seg_qq)
    return seg, seg_q, seg_qq


def _points(model, rng, count):
    """States, controls (beyond the bounds too) and multipliers for the checks."""
    x = rng.uniform(-2.0, 2.0, size=(count, model.nx))
    if model.joint_kinds[-1] == 'prismatic':
        x[:, 2] = rng.uniform(-0.5, 1.5, size=count)      # arm length a + q2 > 0
    u = rng.uniform(-1.5, 1.5, size=(count, model.nu)) * model.u_max
    lam = rng.normal(size=(count, model.nx))
    return x, u, lam


def _central(fun, z, h=1e-6):
    """Central differences of fun (array valued) wrt the vector z; last axis = z."""
    cols = []
    for k in range(z.size):
        dz = np.zeros_like(z)
        dz[k] = h * max(1.0, abs(z[k]))
        cols.append((fun(z + dz) - fun(z - dz)) / (2.0 * dz[k]))
    return np.stack(cols, axis=-1)


def _close(actual, expected, rtol, what):
    scale = 1.0 + np.max(np.abs(expected))
    err = np.max(np.abs(actual - expected)) / scale
    assert err <= rtol, f'{what}: relative error {err:.3g} > {rtol:g}'


# ------------------------------------------------------------------------------------------
# Interface and finite-difference checks (every model)
# ------------------------------------------------------------------------------------------

def test_interface_sizes(model):
    actuators = model.n_joints if isinstance(model, ActuatedModel) else 0
    assert model.nx == 2 * model.n_joints + actuators and model.nu == model.n_joints
    assert len(model.default_joint_names) == model.n_joints
    assert len(model.joint_kinds) == model.n_joints
    assert set(model.joint_kinds) <= {'revolute', 'prismatic'}
    assert model.u_max.shape == (model.nu,) and np.all(model.u_max > 0.0)
    assert model.check() == []
    p = model.packed()
    assert p.dtype == np.float64 and np.all(np.isfinite(p))


def test_every_output_entry_is_written(model):
    # The helpers fill the outputs with NaN first: a kernel must overwrite every entry.
    x, u, lam = _points(model, np.random.default_rng(0), 1)
    for out in (_rhs(model, x[0], u[0]),) + _jac(model, x[0], u[0]) + _hess(
            model, x[0], u[0], lam[0]) + _seg(model, model.positions(x[0])):
        assert np.all(np.isfinite(out))


def test_rhs_jac_matches_rhs_and_finite_differences(model):
    x, u, _ = _points(model, np.random.default_rng(1), 30)
    for xi, ui in zip(x, u):
        f, fx, fu = _jac(model, xi, ui)
        np.testing.assert_array_equal(f, _rhs(model, xi, ui))
        _close(fx, _central(lambda z: _rhs(model, z, ui), xi), 1e-7, 'df/dx')
        _close(fu, _central(lambda z: _rhs(model, xi, z), ui), 1e-7, 'df/du')


def test_rhs_hess_matches_finite_differences_of_the_jacobian(model):
    x, u, lam = _points(model, np.random.default_rng(2), 30)
    for xi, ui, li in zip(x, u, lam):
        hxx, hxu, huu = _hess(model, xi, ui, li)
        np.testing.assert_allclose(hxx, hxx.T, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(huu, huu.T, rtol=1e-12, atol=1e-12)
        # d/dx (lam . df/dx) and d/du (lam . df/du).
        _close(hxx, _central(lambda z: li @ _jac(model, z, ui)[1], xi), 1e-6, 'hxx')
        _close(hxu, _central(lambda z: li @ _jac(model, z, ui)[2], xi).T, 1e-6, 'hxu')
        _close(hxu, _central(lambda z: li @ _jac(model, xi, z)[1], ui), 1e-6, 'hxu (u)')
        _close(huu, _central(lambda z: li @ _jac(model, xi, z)[2], ui), 1e-6, 'huu')


def test_segments_and_their_derivatives(model):
    rng = np.random.default_rng(3)
    x, _, _ = _points(model, rng, 30)
    for q in model.positions(x):
        seg, seg_q, seg_qq = _seg(model, q)
        np.testing.assert_allclose(seg, model.link_segments(q), rtol=1e-13, atol=1e-13)
        _close(seg_q, _central(lambda z: _seg(model, z)[0], q), 1e-8, 'seg_q')
        _close(seg_qq, _central(lambda z: _seg(model, z)[1], q), 1e-8, 'seg_qq')
        np.testing.assert_array_equal(seg_qq, np.swapaxes(seg_qq, 2, 3))
    # Vectorised numpy geometry: rows of q, and the hand at the end of the last link.
    qs = model.positions(x).reshape(5, 6, -1)
    segs = model.link_segments(qs)
    assert segs.shape == (5, 6, model.n_links, 4)
    np.testing.assert_array_equal(model.hand_position(qs), segs[..., -1, 2:4])
    # The links form a chain from the base.
    np.testing.assert_allclose(segs[..., 0, 0:2], 0.0, atol=1e-15)
    np.testing.assert_allclose(segs[..., 1:, 0:2], segs[..., :-1, 2:4], atol=1e-15)


def test_rollout_wrapper_matches_pointwise_euler(model):
    rng = np.random.default_rng(4)
    x, u, _ = _points(model, rng, 1)
    controls = rng.uniform(-1.0, 1.0, size=(20, model.nu)) * model.u_max
    states = np.zeros((21, model.nx))
    tau = 0.01
    model.kernels.rollout(x[0], controls, tau, model.packed(), horizon.EULER, states)
    expected = x[0].copy()
    for i in range(20):
        expected = expected + tau * _rhs(model, expected, controls[i])
        np.testing.assert_allclose(states[i + 1], expected, rtol=1e-13, atol=1e-13)


def test_actuated_model_is_the_base_driven_by_its_actuator_states():
    # d(q, dq)/dt = f_base(q, dq, a), da/dt = (u - a) / T, from the base model's own kernel.
    base = load_model('planar_2r', **PLANAR_OTHER)
    model = with_actuator_lag(base, 0.02)
    rng = np.random.default_rng(5)
    for _ in range(10):
        x = rng.uniform(-2.0, 2.0, size=6)
        u = rng.uniform(-1.0, 1.0, size=2) * base.u_max
        f = _rhs(model, x, u)
        # The actuator states are the applied controls scaled by u_max.
        applied = x[4:] * base.u_max
        np.testing.assert_array_equal(f[:4], _rhs(base, x[:4], applied))
        np.testing.assert_allclose(f[4:] * base.u_max, (u - applied) / 0.02, rtol=1e-14)
    np.testing.assert_array_equal(model.positions(x), x[[0, 2]])
    np.testing.assert_array_equal(model.velocities(x), x[[1, 3]])
    np.testing.assert_array_equal(model.actuators(x), applied)
    assert model.u_max.tolist() == base.u_max.tolist()
    assert model.joint_model is base and base.joint_model is base
    assert with_actuator_lag(model, 0.0) is base
    assert with_actuator_lag(base, 0.02) == model and hash(with_actuator_lag(base, 0.02)) == \
        hash(model)
    assert pickle.loads(pickle.dumps(model)) == model
    assert model.with_parameters({'m_p': 4.0}) == with_actuator_lag(
        load_model('planar_2r', **dict(PLANAR_OTHER, m_p=4.0)), 0.02)
    with pytest.raises(ModelError, match='time constant'):
        with_actuator_lag(base, -0.01)


def test_actuated_full_state_holds_the_joints():
    # Without a measured effort the actuators start at the torques that hold the joints'
    # velocities: at rest under gravity the hold torque, so the arm does not move.
    base = load_model('planar_2r', **PLANAR_OTHER)
    model = with_actuator_lag(base, 0.02)
    x = base.state([0.3, -0.7])
    full = model.full_state(x)
    assert full.shape == (6,)
    np.testing.assert_array_equal(full[:4], x)
    f = _rhs(model, full, model.actuators(full))
    np.testing.assert_allclose(f, 0.0, atol=1e-12)
    np.testing.assert_allclose(model.actuators(model.full_state(x, effort=[1.0, -2.0])),
                               [1.0, -2.0], rtol=1e-15)
    np.testing.assert_array_equal(model.full_state(full), full)
    with pytest.raises(ModelError, match='2 actuator'):
        model.full_state(x, effort=[1.0])


# ------------------------------------------------------------------------------------------
# Generated against built-in models
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize('params', [{}, PLANAR_OTHER], ids=['defaults', 'other'])
def test_generated_planar_2r_agrees_with_the_built_in(params):
    gen, ref = load_model(PLANAR_FILE, **params), load_model('planar_2r', **params)
    assert (gen.n_joints, gen.n_links, gen.joint_kinds, gen.default_joint_names) == (
        ref.n_joints, ref.n_links, ref.joint_kinds, ref.default_joint_names)
    np.testing.assert_array_equal(gen.u_max, ref.u_max)
    x, u, lam = _points(ref, np.random.default_rng(5), 300)
    x[:, 0::2] *= 2.0          # angles over several turns
    for xi, ui, li in zip(x, u, lam):
        for a, b in zip(_jac(gen, xi, ui) + _hess(gen, xi, ui, li) + _seg(gen, xi[0::2]),
                        _jac(ref, xi, ui) + _hess(ref, xi, ui, li) + _seg(ref, xi[0::2])):
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(gen.mass_matrix(xi[0::2]), ref.mass_matrix(xi[0::2]),
                                   rtol=1e-12, atol=1e-12)
    q = x[:40, 0::2].reshape(4, 10, 2)
    np.testing.assert_allclose(gen.link_segments(q), ref.link_segments(q), rtol=1e-13,
                               atol=1e-13)


@pytest.mark.parametrize('variant,sign', [('eq37', -1.0), ('eq36', 1.0)])
def test_generated_explicit_cylindrical_agrees_with_the_built_in(variant, sign):
    gen = load_model(CYLINDRICAL_FILE, sign=sign, **CYLINDRICAL_OTHER)
    ref = load_model('cylindrical', model_variant=variant, **CYLINDRICAL_OTHER)
    assert gen.joint_kinds == ('revolute', 'prismatic')
    x, u, lam = _points(ref, np.random.default_rng(6), 200)
    for xi, ui, li in zip(x, u, lam):
        for a, b in zip(_jac(gen, xi, ui) + _hess(gen, xi, ui, li) + _seg(gen, xi[0::2]),
                        _jac(ref, xi, ui) + _hess(ref, xi, ui, li) + _seg(ref, xi[0::2])):
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)


def test_cylindrical_from_its_lagrangian_is_the_eq36_variant():
    gen = symbolic.model_from_text(CYLINDRICAL_LAGRANGIAN, 'cylindrical_lagrangian.yaml')
    ref = load_model('cylindrical', model_variant='eq36', **CYLINDRICAL_OTHER)
    x, u, lam = _points(ref, np.random.default_rng(9), 200)
    for xi, ui, li in zip(x, u, lam):
        for a, b in zip(_jac(gen, xi, ui) + _hess(gen, xi, ui, li),
                        _jac(ref, xi, ui) + _hess(ref, xi, ui, li)):
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)


def test_three_link_model_sizes_and_damping():
    model = symbolic.model_from_text(PLANAR_3R, 'planar_3r.yaml')
    assert (model.n_joints, model.nx, model.nu, model.n_links) == (3, 6, 3, 3)
    assert model.default_joint_names == ('j1', 'j2', 'j3')
    # The damping force enters as -damping dq2 in the generalised forces: with u = 0 it acts
    # like an elbow torque -0.5 dq2.
    x = model.state([0.2, 0.4, -0.3], [0.1, 2.0, -0.5])
    moved = _rhs(model, x, np.array([0.0, -1.0, 0.0]))
    np.testing.assert_allclose(_rhs(symbolic.model_from_text(PLANAR_3R, 'planar_3r.yaml',
                                                             damping=0.0),
                                    x, np.array([0.0, -2.0, 0.0])), moved, rtol=1e-12)


# The explicit right-hand side derives in about a second; the planar arm's Lagrangian (several
# seconds of sympy on every run, its text being new) is left to the full run.
@pytest.mark.parametrize('model_file', [
    CYLINDRICAL_FILE, pytest.param(PLANAR_FILE, marks=pytest.mark.slow)],
    ids=['cylindrical_eq37', 'planar_2r'])
def test_generation_is_deterministic_and_cached(tmp_path, model_file):
    with open(model_file) as stream:
        # A comment makes a new file content: a module of its own, not yet imported.
        text = stream.read() + f'\n# {tmp_path}\n'
    name = os.path.basename(model_file)
    first, key = symbolic.generate_source(text)
    second, key2 = symbolic.generate_source(text)
    assert first == second and key == key2
    assert symbolic.content_hash(text + '\n') != key
    model = symbolic.model_from_text(text, name, cache_dir=str(tmp_path))
    path = tmp_path / key / f'model_{key}.py'
    assert path.read_text() == first
    assert model.kernels.MODEL_HASH == key and model.kernels.__file__ == str(path)
    # Loaded again: the same module, no regeneration.
    assert symbolic.model_from_text(text, name, cache_dir=str(tmp_path)) == model


def test_generated_model_is_a_value_object():
    a, b = load_model(PLANAR_FILE, g=1.0), load_model(PLANAR_FILE, g=1.0)
    assert a == b and hash(a) == hash(b) and a != load_model(PLANAR_FILE, g=2.0)
    c = pickle.loads(pickle.dumps(a))
    assert c == a and c.params.as_dict()['g'] == 1.0
    np.testing.assert_array_equal(c.packed(), a.packed())


# ------------------------------------------------------------------------------------------
# planar_2r against an independent Euler-Lagrange evaluation
# ------------------------------------------------------------------------------------------

_GAUSS_S, _GAUSS_W = np.polynomial.legendre.leggauss(4)


def _lagrangian_2r(q, dq, prm):
    """
    Return L = T - V of the planar 2R arm.

    Computed from the points of the rods (Gauss quadrature along each rod: exact for the
    quadratic integrands), not from inertia formulas.
    """
    l1, l2, m1, m2, mp, g = (prm[k] for k in ('l1', 'l2', 'm1', 'm2', 'm_p', 'g'))
    kinetic = potential = 0.0
    for s, w in zip(0.5 * (_GAUSS_S + 1.0), 0.5 * _GAUSS_W):
        # Point at s l1 on rod 1 and at p1 + s l2 on rod 2 (s in [0, 1]).
        v1 = s * l1 * dq[0] * np.array([-math.sin(q[0]), math.cos(q[0])])
        y1 = s * l1 * math.sin(q[0])
        v2 = (l1 * dq[0] * np.array([-math.sin(q[0]), math.cos(q[0])])
              + s * l2 * (dq[0] + dq[1]) * np.array([-math.sin(q[0] + q[1]),
                                                     math.cos(q[0] + q[1])]))
        y2 = l1 * math.sin(q[0]) + s * l2 * math.sin(q[0] + q[1])
        kinetic += w * (0.5 * m1 * v1 @ v1 + 0.5 * m2 * v2 @ v2)
        potential += w * g * (m1 * y1 + m2 * y2)
    vh = (l1 * dq[0] * np.array([-math.sin(q[0]), math.cos(q[0])])
          + l2 * (dq[0] + dq[1]) * np.array([-math.sin(q[0] + q[1]), math.cos(q[0] + q[1])]))
    kinetic += 0.5 * mp * vh @ vh
    potential += g * mp * (l1 * math.sin(q[0]) + l2 * math.sin(q[0] + q[1]))
    return kinetic - potential


def _euler_lagrange_torques(q, dq, ddq, prm, h=1e-4):
    """Return u = d/dt dL/d dq - dL/dq by central differences of the Lagrangian."""
    def lag(qq, vv):
        return _lagrangian_2r(qq, vv, prm)

    def grad(fun, z):
        return np.array([(fun(z + h * e) - fun(z - h * e)) / (2.0 * h) for e in np.eye(2)])

    def dl_ddq(qq, vv):
        return grad(lambda v: lag(qq, v), vv)

    # d/dt dL/d dq = (d2L/d dq2) ddq + (d2L/d dq dq) dq.
    mass = np.stack([(dl_ddq(q, dq + h * e) - dl_ddq(q, dq - h * e)) / (2.0 * h)
                     for e in np.eye(2)], axis=1)
    cross = np.stack([(dl_ddq(q + h * e, dq) - dl_ddq(q - h * e, dq)) / (2.0 * h)
                      for e in np.eye(2)], axis=1)
    return mass @ ddq + cross @ dq - grad(lambda z: lag(z, dq), q)


@pytest.mark.parametrize('params', [{}, PLANAR_OTHER], ids=['defaults', 'gravity'])
def test_planar_2r_satisfies_the_euler_lagrange_equations(params):
    model = load_model('planar_2r', **params)
    prm = dict(vars(Planar2RParams()), **params)
    rng = np.random.default_rng(7)
    for _ in range(20):
        x = rng.uniform(-3.0, 3.0, 4)
        u = rng.uniform(-1.0, 1.0, 2) * model.u_max
        f = _rhs(model, x, u)
        torques = _euler_lagrange_torques(x[0::2], x[1::2], f[1::2], prm)
        np.testing.assert_allclose(torques, u, rtol=0.0, atol=1e-6 * np.max(model.u_max))
        np.testing.assert_array_equal(f[0::2], x[1::2])


def test_planar_2r_energy_balance_under_gravity():
    # Unforced motion conserves T + V (RK4 with a small step), T + V from the test's own
    # Lagrangian pieces: E = 2 T - L with T from the quadrature.
    params = dict(PLANAR_OTHER)
    model = load_model('planar_2r', **params)
    prm = dict(vars(Planar2RParams()), **params)

    def energy(x):
        q, dq = x[0::2], x[1::2]
        kinetic = _lagrangian_2r(q, dq, prm) - _lagrangian_2r(q, 0.0 * dq, prm)
        return 2.0 * kinetic - _lagrangian_2r(q, dq, prm)

    x0 = np.array([0.3, 1.0, -0.7, -2.0])
    states = np.zeros((2001, 4))
    model.kernels.rollout(x0, np.zeros((2000, 2)), 1e-3, model.packed(), horizon.RK4, states)
    e = np.array([energy(x) for x in states[::100]])
    assert np.max(np.abs(e - e[0])) < 1e-9 * (1.0 + abs(e[0]))


# ------------------------------------------------------------------------------------------
# Inverse kinematics
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize('branch,sign', [('elbow_up', -1.0), ('elbow_down', 1.0)])
@pytest.mark.parametrize('params', [{}, {'l1': 0.7, 'l2': 1.1}])
def test_planar_2r_ik_round_trip(branch, sign, params):
    model = load_model('planar_2r', **params)
    l1, l2 = model.params.l1, model.params.l2
    rng = np.random.default_rng(8)
    for _ in range(200):
        r = rng.uniform(abs(l1 - l2) + 1e-6, l1 + l2 - 1e-6)
        phi = rng.uniform(-math.pi, math.pi)
        goal = np.array([r * math.cos(phi), r * math.sin(phi)])
        q = model.inverse_kinematics(goal[0], goal[1], branch)
        assert sign * q[1] >= 0.0 and -math.pi < q[0] <= math.pi
        np.testing.assert_allclose(model.hand_position(q), goal, atol=1e-12)
    # Forward then inverse recovers the joint positions of the branch.
    for _ in range(100):
        q = np.array([rng.uniform(-3.1, 3.1), sign * rng.uniform(0.05, 3.1)])
        hand = model.hand_position(q)
        np.testing.assert_allclose(model.inverse_kinematics(hand[0], hand[1], branch), q,
                                   atol=1e-9)


def test_planar_2r_ik_branch_convention():
    # Reaching along +x: elbow_up puts the elbow above the x axis, elbow_down below.
    model = Planar2R()
    for branch, above in (('elbow_up', True), ('elbow_down', False)):
        q = model.inverse_kinematics(1.2, 0.0, branch)
        elbow_y = model.link_segments(q)[0, 3]
        assert (elbow_y > 0.0) == above
    # Fully stretched: both branches coincide (q2 = 0).
    for branch in ('elbow_up', 'elbow_down'):
        np.testing.assert_allclose(model.inverse_kinematics(1.8, 0.0, branch), [0.0, 0.0],
                                   atol=1e-7)


@pytest.mark.parametrize('goal,branch,message', [
    ((1.0, 0.5), None, 'ambiguous'),
    ((1.0, 0.5), 'elbow_left', 'ambiguous'),
    ((1.5, 1.5), 'elbow_up', 'out of reach'),
    ((0.1, 0.05), 'elbow_down', 'too close to the base'),
    ((float('nan'), 0.0), 'elbow_up', 'not finite'),
])
def test_planar_2r_ik_refusals(goal, branch, message):
    with pytest.raises(ModelError, match=message):
        Planar2R().inverse_kinematics(goal[0], goal[1], branch)


def test_planar_2r_ik_at_the_base_with_equal_links():
    with pytest.raises(ModelError, match='every shoulder angle'):
        load_model('planar_2r', l1=0.8, l2=0.8).inverse_kinematics(0.0, 0.0, 'elbow_up')


def test_generated_model_ik():
    # The file's inverse_kinematics section (test_model_file_ik.py has the details).
    q = load_model(PLANAR_FILE).inverse_kinematics(1.0, 0.5, 'elbow_up')
    np.testing.assert_allclose(q, Planar2R().inverse_kinematics(1.0, 0.5, 'elbow_up'),
                               atol=1e-12)
    # No section and 3 joints: no numeric IK either.
    with pytest.raises(ModelError, match='ambiguous: a redundant arm'):
        symbolic.model_from_text(PLANAR_3R, 'planar_3r.yaml').inverse_kinematics(1.0, 0.5)


# ------------------------------------------------------------------------------------------
# load_model and parameters
# ------------------------------------------------------------------------------------------

def test_load_model_built_in_names_and_parameters():
    assert set(MODELS) == {'cylindrical', 'planar_2r'}
    model = load_model('planar_2r', l1='0.9', g=9.81)
    assert isinstance(model, Planar2R) and model.params.l1 == 0.9 and model.params.g == 9.81
    assert load_model('planar_2r') == Planar2R()
    assert load_model('cylindrical', model_variant='eq36').params.model_variant == 'eq36'


@pytest.mark.parametrize('name,params,message', [
    ('planar_3r', {}, 'unknown model'),
    ('planar_2r', {'l3': 1.0}, 'no parameter'),
    ('planar_2r', {'l1': -1.0}, 'l1 must be a finite positive number'),
    ('planar_2r', {'m_p': 0.0}, 'm_p must be a finite positive number'),
    ('planar_2r', {'g': float('inf')}, 'g must be a finite number'),
    ('planar_2r', {'l1': 'long'}, 'must be a number'),
    ('cylindrical', {'model_variant': 'eq38'}, 'model_variant'),
    ('missing_model.yaml', {}, 'cannot read model file'),
    (PLANAR_FILE, {'l3': 1.0}, 'no parameter'),
    (PLANAR_FILE, {'m1': -2.0}, 'm1 must be a finite positive number'),
])
def test_load_model_refusals(name, params, message):
    with pytest.raises(ModelError, match=message):
        load_model(name, **params)


# ------------------------------------------------------------------------------------------
# Bad model files
# ------------------------------------------------------------------------------------------

def _planar_text():
    with open(PLANAR_FILE) as stream:
        return stream.read()


def _head():
    """Return the planar file up to (without) its lagrangian section."""
    return _planar_text().split('lagrangian:')[0]


BAD_FILES = [
    ('yaml', lambda: 'name: [unclosed', 'not valid YAML'),
    ('top-level-list', lambda: '- 1\n- 2\n', 'mapping at the top level'),
    ('expression', lambda: _planar_text().replace('hx: ex + l2*cos(q1 + q2)',
                                                  'hx: ex + l2*cos(q1 + (q2)'),
     r'definitions.hx: cannot parse'),
    ('operator', lambda: _planar_text().replace('ey: l1*sin(q1)', 'ey: l1*sin(q1) +'),
     r'definitions.ey: cannot parse'),
    # SymPy's parser evaluates Python: a power tower would compute an integer for ever, an
    # attribute chain reaches os.system; both are refused before it runs.
    ('power-tower', lambda: _planar_text().replace('ey: l1*sin(q1)',
                                                   'ey: l1*sin(q1) + 0*9^9^9^9'),
     r'definitions.ey: cannot parse.*numeric exponent beyond 64'),
    ('python-escape', lambda: _planar_text().replace(
        'ey: l1*sin(q1)', 'ey: l1*sin(q1) + 0*().__class__.__base__.__subclasses__()[0]'),
     r'definitions.ey: cannot parse.*is not allowed'),
    ('unknown-symbol', lambda: _planar_text().replace('hy: ey + l2*sin(q1 + q2)',
                                                      'hy: ey + l3*sin(q1 + q2)'),
     'unknown symbol.*l3'),
    ('unknown-function', lambda: _planar_text().replace('hy: ey + l2*sin(q1 + q2)',
                                                        'hy: ey + l2*sinus(q1 + q2)'),
     'unknown function.*sinus'),
    ('joint-out-of-range', lambda: _planar_text().replace('ey: l1*sin(q1)',
                                                          'ey: l1*sin(q3)'),
     'unknown symbol.*q3'),
    ('segment-size', lambda: _planar_text().replace('  - [ex, ey, hx, hy]', '  - [ex, ey, hx]'),
     r'links\[1\]: expected a list of 4'),
    ('segment-velocity', lambda: _planar_text().replace('  - [ex, ey, hx, hy]',
                                                        '  - [ex, ey, hx, dq1]'),
     r'links\[1\]\[3\].*may not depend on dq1'),
    ('bounds-size', lambda: _planar_text().replace('u_max: [u1_max, u2_max]',
                                                   'u_max: [u1_max]'),
     'u_max: expected a list of 2'),
    ('bounds-state', lambda: _planar_text().replace('u_max: [u1_max, u2_max]',
                                                    'u_max: [u1_max, q1]'),
     'may not depend on q1'),
    ('bound-negative', lambda: _planar_text().replace('u_max: [u1_max, u2_max]',
                                                      'u_max: [u1_max, -u2_max]'),
     r'u_max\[1\] must be finite and > 0'),
    ('f-size', lambda: _head() + 'dynamics: [dq1, u1, dq2]\n', 'dynamics: expected a list of 4'),
    ('both', lambda: _planar_text() + 'dynamics: [dq1, u1, dq2, u2]\n', 'exactly one of'),
    ('neither', lambda: _head(), 'exactly one of'),
    ('unknown-key', lambda: _planar_text() + 'dynamic: [dq1, u1, dq2, u2]\n', 'unknown key'),
    ('no-joints', lambda: _planar_text().replace('joints:', 'joint_list:'), 'unknown key'),
    ('joint-kind', lambda: _planar_text().replace('kind: revolute}', 'kind: spherical}', 1),
     'kind must be one of'),
    ('parameter-name', lambda: _planar_text().replace('  m_p: 2.0', '  q1: 2.0'),
     'parameter name'),
    ('parameter-value', lambda: _planar_text().replace('  m_p: 2.0', '  m_p: heavy'),
     'default must be a finite number'),
    ('not-quadratic', lambda: _head() + 'lagrangian:\n  kinetic: m1/2*dq1^4 + m2/2*dq2^2\n',
     'quadratic in the joint velocities'),
    ('singular-everywhere', lambda: _head() + 'lagrangian:\n  kinetic: m1/2*(dq1 + dq2)^2\n',
     'singular at every pose'),
]


@pytest.mark.parametrize('make,message', [c[1:] for c in BAD_FILES],
                         ids=[c[0] for c in BAD_FILES])
def test_bad_model_files_are_refused(tmp_path, make, message):
    path = tmp_path / 'robot.yaml'
    path.write_text(make())
    with pytest.raises(ModelError, match=message) as info:
        load_model(str(path))
    assert str(path) in str(info.value)          # the message names the file


SINGULAR_AT_POLE = """
name: pole_arm
joints: [{name: a, kind: revolute}, {name: b, kind: revolute}]
parameters: {m1: 2.0, m2: 3.0}
u_max: [10, 10]
links: [[0, 0, cos(q1), sin(q1)]]
lagrangian:
  kinetic: m1/2*dq1^2 + m2/2*(cos(q1)*dq2)^2
"""


def test_singular_mass_matrix_at_the_start_state():
    model = symbolic.model_from_text(SINGULAR_AT_POLE, 'pole_arm.yaml')
    regular = model.state([0.3, 0.0])
    assert model.check_state(regular) == []
    start = model.state([math.pi / 2.0, 0.1], [0.2, 0.0])
    problems = model.check_state(start, 'start state')
    assert len(problems) == 1 and 'start state' in problems[0] and 'singular' in problems[0]
    # The kernels refuse rather than return inf; NaN inputs propagate as NaN.
    for kernel_call in (lambda: _rhs(model, start, np.zeros(2)),
                        lambda: _jac(model, start, np.zeros(2)),
                        lambda: _hess(model, start, np.zeros(2), np.ones(4))):
        with pytest.raises(ModelError, match='singular mass matrix'):
            kernel_call()
    assert np.all(np.isnan(_rhs(model, np.full(4, np.nan), np.zeros(2))))
    assert np.all(np.isfinite(_rhs(model, regular, np.ones(2))))


def test_explicit_model_state_check_reports_non_finite_f():
    text = """
name: bad_f
joints: [{name: j, kind: prismatic}]
parameters: {m: 1.0}
u_max: [1]
links: [[0, 0, q1, 0]]
dynamics: [dq1, u1/(m*q1)]
"""
    model = symbolic.model_from_text(text, 'bad_f.yaml')
    assert model.check_state(model.state([1.0])) == []
    assert model.check_state(model.state([0.0]), 'start state')
