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
Compiled kernels of the arm interior point against plain numpy and a dense KKT solve.

The Riccati step at the arm's sizes (14 states, 7 controls, Euler-structured A and B) is held
to one dense KKT system; every per-iteration kernel of ipm_kernels.py is recomputed here with
numpy expressions of the same formulas on random data with unbounded coordinates, empty and
non-empty sphere rows.
"""

import math

import numpy as np
import pytest

from test_arm_solve import _dense_step  # noqa: I100

from toc_ros.core.arms import ipm_kernels, riccati, riccati_euler  # noqa: I100

T_LOW, T_HIGH = 1e-3, 100.0


def _euler_structured(rng, n_int, n):
    """Random (A, B) with an Euler step's structure and zeros: [[I, h I], [h Dq, I + h Dv]]."""
    h = 0.02
    nx = 2 * n
    a = np.zeros((n_int, nx, nx))
    a[:, :n, :n] = np.eye(n)
    a[:, :n, n:] = h * np.eye(n)
    a[:, n:, :n] = h * rng.normal(size=(n_int, n, n))
    a[:, n:, n:] = np.eye(n) + h * rng.normal(size=(n_int, n, n))
    b = np.zeros((n_int, nx, n))
    b[:, n:] = h * rng.normal(size=(n_int, n, n))
    return a, b


def _qp(rng, n_int, nx, nu):
    hxx = np.zeros((n_int, nx + 1, nx + 1))
    for k in range(n_int):
        m = rng.normal(size=(nx + 1, nx + 1))
        hxx[k] = m @ m.T / nx + np.eye(nx + 1)
    hux = 0.1 * rng.normal(size=(n_int, nu, nx + 1))
    huu = np.array([np.eye(nu) * 2.0 for _ in range(n_int)])
    return (0.3 * rng.normal(size=(n_int, nx)), 0.1 * rng.normal(size=(n_int, nx)), hxx, hux,
            huu, rng.normal(size=(n_int, nx + 1)), rng.normal(size=(n_int, nu)))


def _solve(a, b, c, d, hxx, hux, huu, gx, gu, work):
    n_int, nx, nu = b.shape
    dx, du = np.zeros((n_int + 1, nx)), np.zeros((n_int, nu))
    lam, nu_out = np.zeros((n_int + 1, nx)), np.zeros(nx)
    code, d_t = riccati.riccati_solve(a, b, c, d, hxx, hux, huu, gx, gu, 1.0, *work, dx, du,
                                      lam, nu_out)
    return code, d_t, dx, du, lam, nu_out


def test_arm_sized_riccati_step_matches_a_dense_kkt_solve():
    rng = np.random.default_rng(11)
    n_int, n = 5, 7
    a, b = _euler_structured(rng, n_int, n)
    c, d, hxx, hux, huu, gx, gu = _qp(rng, n_int, 2 * n, n)
    code, d_t, dx, du, lam, _ = _solve(a, b, c, d, hxx, hux, huu, gx, gu,
                                       riccati.work_arrays(n_int, 2 * n, n))
    assert code == riccati.OK
    d_t_ref, dx_ref, du_ref, y = _dense_step(a, b, c, d, hxx, hux, huu, gx, gu)
    scale = max(1.0, np.abs(du_ref).max())
    assert d_t == pytest.approx(d_t_ref, abs=1e-9 * scale)
    np.testing.assert_allclose(dx[1:-1], dx_ref[1:-1], atol=1e-9 * scale)
    np.testing.assert_allclose(du, du_ref, atol=1e-9 * scale)
    assert np.max(np.abs(dx[-1])) < 1e-9 * scale
    np.testing.assert_allclose(lam[1:], y, atol=1e-7 * max(1.0, np.abs(y).max()))


def test_riccati_padded_and_unpadded_work_arrays_give_the_same_bits():
    rng = np.random.default_rng(12)
    n_int, n = 8, 7
    nx = 2 * n
    a, b = _euler_structured(rng, n_int, n)
    qp = _qp(rng, n_int, nx, n)
    padded = riccati.work_arrays(n_int, nx, n)
    assert padded[0].shape[1] % 8 == 0 and padded[1].shape[2] % 8 == 0
    unpadded = (np.zeros((n_int + 1, nx + 1, nx + 1)), np.zeros((n_int + 1, nx + 1, 1 + nx)),
                np.zeros((n_int, n, nx + 1)), np.zeros((n_int, n, 1 + nx)),
                np.zeros((n_int + 1, nx + 1, 1 + nx)), np.zeros((n_int, n, 1 + nx)))
    first = _solve(a, b, *qp, padded)
    # Reused work arrays (left over from the first solve) must not change the result.
    for out in (_solve(a, b, *qp, unpadded), _solve(a, b, *qp, padded)):
        assert out[0] == first[0] == riccati.OK and out[1] == first[1]
        for got, want in zip(out[2:], first[2:]):
            assert np.array_equal(got, want)


# Per-iteration kernels against numpy ------------------------------------------------------

def _iterate(rng, n_int, n, n_rows):
    """Return a random interior iterate: bounds (some infinite), duals, sphere rows."""
    nx = 2 * n
    lx = -rng.uniform(1.0, 2.0, nx)
    ux = rng.uniform(1.0, 2.0, nx)
    lx[0] = -np.inf                 # a continuous joint: no position bounds
    ux[0] = np.inf
    ux[n + 1] = np.inf              # one-sided
    has_l, has_u = np.isfinite(lx), np.isfinite(ux)
    x = rng.uniform(-0.9, 0.9, (n_int + 1, nx))
    it = {
        'x': x, 'v': rng.uniform(-0.9, 0.9, (n_int, n)), 't': 0.8,
        'lx': lx, 'ux': ux, 'has_l': has_l, 'has_u': has_u,
        'zlx': np.where(has_l, rng.uniform(0.1, 1.0, (n_int - 1, nx)), 0.0),
        'zux': np.where(has_u, rng.uniform(0.1, 1.0, (n_int - 1, nx)), 0.0),
        'zlv': rng.uniform(0.1, 1.0, (n_int, n)), 'zuv': rng.uniform(0.1, 1.0, (n_int, n)),
        'zlt': 0.3, 'zut': 0.01,
        's': rng.uniform(0.1, 1.0, (n_int - 1, n_rows)),
        'z': rng.uniform(0.1, 1.0, (n_int - 1, n_rows)),
        'values': rng.uniform(-0.2, 1.0, (n_int - 1, n_rows)),
        'grads': rng.normal(size=(n_int - 1, n_rows, n)),
        'lam': rng.normal(size=(n_int + 1, nx)),
        'a': rng.normal(size=(n_int, nx, nx)), 'b': rng.normal(size=(n_int, nx, n)),
        'c': rng.normal(size=(n_int, nx)), 'defect': rng.normal(size=(n_int, nx)),
        'mu': 1e-3,
    }
    curvature = rng.normal(size=(n_int - 1, n, n))
    it['curvature'] = curvature + np.transpose(curvature, (0, 2, 1))
    return it


def _slacks(it, x=None, v=None, t=None):
    x = it['x'] if x is None else x
    v = it['v'] if v is None else v
    t = it['t'] if t is None else t
    inner = x[1:-1]
    lo = np.where(it['has_l'], inner - np.where(it['has_l'], it['lx'], 0.0), np.inf)
    hi = np.where(it['has_u'], np.where(it['has_u'], it['ux'], 0.0) - inner, np.inf)
    return (lo, v + 1.0, t - T_LOW), (hi, 1.0 - v, T_HIGH - t)


def _bounds(it):
    return it['lx'], it['ux'], it['has_l'], it['has_u'], T_LOW, T_HIGH


def _duals(it):
    return it['zlx'], it['zux'], it['zlv'], it['zuv'], it['zlt'], it['zut']


@pytest.mark.parametrize('n_rows', [0, 3])
def test_kkt_errors_and_complementarity_match_numpy(n_rows):
    it = _iterate(np.random.default_rng(21), 6, 3, n_rows)
    n = 3
    lam, z = it['lam'], it['z']
    dual_x = (-lam[1:-1] + np.einsum('kij,ki->kj', it['a'][1:], lam[2:]) - it['zlx']
              + it['zux'])
    dual_x[:, :n] -= np.einsum('kpn,kp->kn', it['grads'], z)
    dual_v = np.einsum('kij,ki->kj', it['b'], lam[1:]) - it['zlv'] + it['zuv']
    dual_t = 1.0 + np.sum(it['c'] * lam[1:]) - it['zlt'] + it['zut']
    dual = max(np.abs(dual_x).max(), np.abs(dual_v).max(), abs(dual_t))
    primal = max(np.abs(it['defect']).max(), np.max(np.abs(it['values'] - it['s']),
                                                    initial=0.0))
    lo, hi = _slacks(it)

    def compl(mu):
        # inf * 0 where a coordinate has no bound: masked by np.where.
        with np.errstate(invalid='ignore'):
            return _compl(mu)

    def _compl(mu):
        terms = [np.where(it['has_l'], np.abs(lo[0] * it['zlx'] - mu), 0.0),
                 np.where(it['has_u'], np.abs(hi[0] * it['zux'] - mu), 0.0),
                 np.abs(lo[1] * it['zlv'] - mu), np.abs(hi[1] * it['zuv'] - mu),
                 np.abs(it['s'] * z - mu)]
        return max(max(np.max(term, initial=0.0) for term in terms),
                   abs(lo[2] * it['zlt'] - mu), abs(hi[2] * it['zut'] - mu))

    bound_duals = (np.abs(it['zlx']).sum() + np.abs(it['zux']).sum() + it['zlv'].sum()
                   + it['zuv'].sum() + it['zlt'] + it['zut'] + z.sum())
    count = (np.count_nonzero(it['zlx']) + np.count_nonzero(it['zux']) + 2 * it['v'].size + 2
             + z.size)
    s_d = max(100.0, (np.abs(lam).sum() + bound_duals) / (count + lam.size)) / 100.0
    s_c = max(100.0, bound_duals / count) / 100.0
    got = ipm_kernels.kkt_errors(lam, it['a'], it['b'], it['c'], it['defect'], it['grads'],
                                 it['values'], it['s'], z, it['x'][1:-1], it['v'], it['t'],
                                 *_duals(it), *_bounds(it), 100.0)
    np.testing.assert_allclose(got, (dual, primal, compl(0.0), s_d, s_c), rtol=1e-12)
    got_mu = ipm_kernels.complementarity(it['x'][1:-1], it['v'], it['t'], it['s'], z,
                                         *_duals(it), *_bounds(it), 0.4)
    assert got_mu == pytest.approx(compl(0.4), rel=1e-12)


@pytest.mark.parametrize('n_rows', [0, 3])
def test_qp_blocks_and_regularisation_match_numpy(n_rows):
    n_int, n = 6, 3
    nx = 2 * n
    rng = np.random.default_rng(22)
    it = _iterate(rng, n_int, n, n_rows)
    model_hxx = rng.normal(size=(n_int, nx + 1, nx + 1))
    lo, hi = _slacks(it)
    mu, s, z = it['mu'], it['s'], it['z']
    hxx = model_hxx.copy()
    inner = hxx[1:, :nx, :nx]
    sig_x = (np.where(it['has_l'], it['zlx'] / lo[0], 0.0)
             + np.where(it['has_u'], it['zux'] / hi[0], 0.0))
    inner[:, np.arange(nx), np.arange(nx)] += sig_x
    gx = np.zeros((n_int, nx + 1))
    gx[1:, :nx] = (np.where(it['has_l'], -mu / lo[0], 0.0)
                   + np.where(it['has_u'], mu / hi[0], 0.0))
    curvature = it['curvature'] if n_rows else np.zeros((0, 0, 0))
    if n_rows:
        inner[:, :n, :n] += (np.einsum('kpi,kp,kpj->kij', it['grads'], z / s, it['grads'])
                             - curvature)
        gx[1:, :n] += np.einsum('kpn,kp->kn', it['grads'],
                                z / s * (it['values'] - s) - mu / s)
    hxx[0, nx, nx] += it['zlt'] / lo[2] + it['zut'] / hi[2]
    gx[0, nx] = 1.0 - mu / lo[2] + mu / hi[2]
    huu_diag = it['zlv'] / lo[1] + it['zuv'] / hi[1]
    gu = -mu / lo[1] + mu / hi[1]
    out = (np.empty_like(hxx), np.empty_like(gx), np.empty_like(huu_diag), np.empty_like(gu))
    ipm_kernels.qp_blocks(model_hxx, it['grads'], it['values'], curvature, s, z,
                          it['x'][1:-1], it['v'], it['t'], *_duals(it), *_bounds(it), mu, *out)
    for got, want in zip(out, (hxx, gx, huu_diag, gu)):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    hxx_reg, huu = np.empty_like(hxx), np.empty((n_int, n, n))
    ipm_kernels.regularised(out[0], out[2], 0.5, 0.25, hxx_reg, huu)
    np.testing.assert_allclose(hxx_reg, out[0] + 0.75 * np.eye(nx + 1), rtol=1e-15)
    np.testing.assert_allclose(huu, (out[2] + 0.75)[:, :, None] * np.eye(n), rtol=1e-15)


def _max_step(value, step, frac):
    neg = step < 0
    return 1.0 if not np.any(neg) else float(min(1.0, np.min(-frac * value[neg] / step[neg])))


@pytest.mark.parametrize('n_rows', [0, 3])
def test_step_to_boundary_matches_numpy(n_rows):
    n_int, n = 6, 3
    nx = 2 * n
    rng = np.random.default_rng(23)
    it = _iterate(rng, n_int, n, n_rows)
    mu, frac = it['mu'], 0.99
    dx = rng.normal(size=(n_int + 1, nx))
    dv = rng.normal(size=(n_int, n))
    d_t = -0.5
    lo, hi = _slacks(it)
    inner = dx[1:-1]
    s, z, has_l, has_u = it['s'], it['z'], it['has_l'], it['has_u']
    ds = it['values'] - s + np.einsum('kpn,kn->kp', it['grads'], inner[:, :n])
    alpha_max = min(_max_step(lo[0][:, has_l], inner[:, has_l], frac),
                    _max_step(hi[0][:, has_u], -inner[:, has_u], frac),
                    _max_step(lo[1], dv, frac), _max_step(hi[1], -dv, frac),
                    _max_step(np.array([lo[2]]), np.array([d_t]), frac),
                    _max_step(np.array([hi[2]]), np.array([-d_t]), frac),
                    _max_step(s, ds, frac))
    dzlx = np.where(has_l, mu / lo[0] - it['zlx'] - it['zlx'] / lo[0] * inner, 0.0)
    dzux = np.where(has_u, mu / hi[0] - it['zux'] + it['zux'] / hi[0] * inner, 0.0)
    dzlv = mu / lo[1] - it['zlv'] - it['zlv'] / lo[1] * dv
    dzuv = mu / hi[1] - it['zuv'] + it['zuv'] / hi[1] * dv
    dzlt = mu / lo[2] - it['zlt'] - it['zlt'] / lo[2] * d_t
    dzut = mu / hi[2] - it['zut'] + it['zut'] / hi[2] * d_t
    dz = mu / s - z - z / s * ds
    alpha_dual = min(_max_step(it['zlx'][:, has_l], dzlx[:, has_l], frac),
                     _max_step(it['zux'][:, has_u], dzux[:, has_u], frac),
                     _max_step(it['zlv'], dzlv, frac), _max_step(it['zuv'], dzuv, frac),
                     _max_step(np.array([it['zlt']]), np.array([dzlt]), frac),
                     _max_step(np.array([it['zut']]), np.array([dzut]), frac),
                     _max_step(z, dz, frac))
    slope = (d_t * (1.0 - mu / lo[2] + mu / hi[2])
             + np.sum(np.where(has_l, -mu / lo[0], 0.0) * inner)
             + np.sum(np.where(has_u, mu / hi[0], 0.0) * inner)
             + np.sum((-mu / lo[1] + mu / hi[1]) * dv) - np.sum(mu / s * ds))
    out = [np.empty_like(a) for a in (s, it['zlx'], it['zux'], it['zlv'], it['zuv'], z)]
    got = ipm_kernels.step_to_boundary(inner, dv, d_t, it['grads'], it['values'], s, z,
                                       it['x'][1:-1], it['v'], it['t'], *_duals(it),
                                       *_bounds(it), mu, frac, *out)
    np.testing.assert_allclose(got, (alpha_max, alpha_dual, dzlt, dzut, slope), rtol=1e-12)
    assert 0.0 < got[0] < 1.0 and 0.0 < got[1] < 1.0       # the random steps hit a bound
    for arr, want in zip(out, (ds, dzlx, dzux, dzlv, dzuv, dz)):
        np.testing.assert_allclose(arr, want, rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize('n_rows', [0, 3])
def test_merit_and_dual_safeguard_match_numpy(n_rows):
    n_int, n = 6, 3
    it = _iterate(np.random.default_rng(24), n_int, n, n_rows)
    mu, s = it['mu'], it['s']
    lo, hi = _slacks(it)
    phi = it['t'] - mu * (np.log(lo[0][:, it['has_l']]).sum()
                          + np.log(hi[0][:, it['has_u']]).sum() + np.log(lo[1]).sum()
                          + np.log(hi[1]).sum() + math.log(lo[2]) + math.log(hi[2])
                          + np.log(s).sum())
    theta = np.abs(it['defect']).sum() + np.abs(it['values'] - s).sum()
    args = (it['v'], it['t'], s, it['defect'], it['values'], *_bounds(it), mu)
    got = ipm_kernels.merit(it['x'][1:-1], *args)
    assert got[0] == pytest.approx(phi, rel=1e-12)
    assert got[1] == pytest.approx(theta, rel=1e-12)
    outside = it['x'].copy()
    outside[2, 1] = it['ux'][1] + 0.1
    assert ipm_kernels.merit(outside[1:-1], *args) == (math.inf, math.inf)
    # The safeguard clips every bound dual into [mu / (k slack), k mu / slack].
    kappa = 10.0
    z = {key: it[key].copy() for key in ('zlx', 'zux', 'zlv', 'zuv', 'z')}
    z['zlx'][0] = 1e3
    z['zuv'][1] = 1e-12
    want = {'zlx': np.where(it['has_l'], np.clip(z['zlx'], mu / (kappa * lo[0]),
                                                 kappa * mu / lo[0]), 0.0),
            'zux': np.where(it['has_u'], np.clip(z['zux'], mu / (kappa * hi[0]),
                                                 kappa * mu / hi[0]), 0.0),
            'zlv': np.clip(z['zlv'], mu / (kappa * lo[1]), kappa * mu / lo[1]),
            'zuv': np.clip(z['zuv'], mu / (kappa * hi[1]), kappa * mu / hi[1]),
            'z': np.clip(z['z'], mu / (kappa * s), kappa * mu / s)}
    ipm_kernels.safeguard_duals(it['x'][1:-1], it['v'], s, z['z'], z['zlx'], z['zux'],
                                z['zlv'], z['zuv'], *_bounds(it)[:4], mu, kappa)
    for key in want:
        np.testing.assert_allclose(z[key], want[key], rtol=1e-15)


def test_euler_terms_match_the_numpy_assembly():
    rng = np.random.default_rng(25)
    n_int, n = 5, 4
    nx = 2 * n
    x = rng.normal(size=(n_int + 1, nx))
    v = rng.uniform(-1, 1, (n_int, n))
    acc, d_q, d_v = (rng.normal(size=(n_int, n)), rng.normal(size=(n_int, n, n)),
                     rng.normal(size=(n_int, n, n)))
    minv, effort, t_f = rng.normal(size=(n_int, n, n)), rng.uniform(1, 50, n), 0.7
    h = t_f / n_int
    f = np.concatenate([x[:-1, n:], acc], axis=1)
    a = np.zeros((n_int, nx, nx))
    a[:, np.arange(nx), np.arange(nx)] = 1.0
    a[:, np.arange(n), n + np.arange(n)] += h
    a[:, n:, :n] += h * d_q
    a[:, n:, n:] += h * d_v
    b = np.zeros((n_int, nx, n))
    b[:, n:, :] = h * minv * effort[None, None, :]
    out = [np.empty((n_int, nx)), np.empty((n_int, nx, nx)), np.empty((n_int, nx, n)),
           np.empty((n_int, nx))]
    ipm_kernels.euler_terms(x, v, t_f, acc, d_q, d_v, minv, effort, *out)
    for got, want in zip(out, (x[:-1] + h * f - x[1:], a, b, f / n_int)):
        np.testing.assert_allclose(got, want, rtol=1e-14, atol=1e-15)


# The Euler step with the goal eliminated (riccati_euler.py) ----------------------------------

def _solve_euler(a, b, c, d, hxx, hux, huu, gx, gu):
    n_int, nx, nu = b.shape
    dx, du, lam = np.zeros((n_int + 1, nx)), np.zeros((n_int, nu)), np.zeros((n_int + 1, nx))
    code, d_t = riccati_euler.riccati_solve_euler(
        a, b, c, d, hxx, hux, huu, gx, gu, *riccati_euler.work_arrays_euler(n_int, nx, nu),
        dx, du, lam)
    return code, d_t, dx, du, lam


@pytest.mark.parametrize('n_int, n', [(2, 2), (3, 7), (6, 7), (5, 2)])
def test_euler_riccati_step_matches_a_dense_kkt_solve(n_int, n):
    rng = np.random.default_rng(40 + n_int)
    a, b = _euler_structured(rng, n_int, n)
    c, d, hxx, hux, huu, gx, gu = _qp(rng, n_int, 2 * n, n)
    code, d_t, dx, du, lam = _solve_euler(a, b, c, d, hxx, hux, huu, gx, gu)
    assert code == riccati.OK
    d_t_ref, dx_ref, du_ref, y = _dense_step(a, b, c, d, hxx, hux, huu, gx, gu)
    # (Random steps of 0.02 s reaching the goal in two or three intervals need controls of
    # ~1e2: the dense solve is accurate to ~1e-9 of them.)
    scale = max(1.0, np.abs(du_ref).max())
    assert d_t == pytest.approx(d_t_ref, abs=1e-8 * scale)
    np.testing.assert_allclose(dx, np.vstack([np.zeros(2 * n), dx_ref[1:-1],
                                              np.zeros(2 * n)]), atol=1e-8 * scale)
    np.testing.assert_allclose(du, du_ref, atol=1e-8 * scale)
    # Every step's multipliers, the goal's (lam_N) included.
    np.testing.assert_allclose(lam[1:], y, atol=1e-8 * max(1.0, np.abs(y).max()))
    # ... and the step of the recursion that carries the goal's multipliers.
    work = riccati.work_arrays(n_int, 2 * n, n)
    _, d_t_gen, dx_gen, du_gen, lam_gen, _ = _solve(a, b, c, d, hxx, hux, huu, gx, gu, work)
    assert d_t == pytest.approx(d_t_gen, abs=1e-8 * scale)
    np.testing.assert_allclose(du, du_gen, atol=1e-8 * scale)


def test_euler_riccati_refuses_exactly_the_steps_whose_qp_is_not_convex():
    # Less curvature in T at the first interval (the last test, P_0(T, T) > 0, fails), then
    # an indefinite control block at an early interval: the code says which test failed, and
    # OK means the dense null-space Hessian is positive definite (and the step is the dense
    # one).
    rng = np.random.default_rng(5)
    n_int, n = 6, 3
    a, b = _euler_structured(rng, n_int, n)
    c, d, hxx, hux, huu, gx, gu = _qp(rng, n_int, 2 * n, n)
    seen = set()
    # (The reduced curvature in T is ~1e5 here: the last two intervals' controls, ~1/h^2,
    # depend on dT.)
    for lowered, control in ((0.0, 2.0), (1e5, 2.0), (1e6, 2.0), (1e8, 2.0), (0.0, -50.0)):
        h = hxx.copy()
        h[0, 2 * n, 2 * n] -= lowered
        r = huu.copy()
        r[1] = control * np.eye(n)
        convex = []
        ref = _dense_step(a, b, c, d, h, hux, r, gx, gu, convex)
        code, d_t = _solve_euler(a, b, c, d, h, hux, r, gx, gu)[:2]
        seen.add((code, convex[0]))
        assert (code == riccati.OK) == convex[0]
        if convex[0]:
            assert d_t == pytest.approx(ref[0], rel=1e-8, abs=1e-10)
    assert (riccati.OK, True) in seen and (riccati.FINAL_TIME_CURVATURE, False) in seen
    assert (riccati.REDUCED_HESSIAN_INDEFINITE, False) in seen


def test_euler_riccati_reports_steps_without_control_authority():
    rng = np.random.default_rng(6)
    a, b = _euler_structured(rng, 4, 2)
    b[2] = 0.0      # the interval before the last cannot move the velocities
    code, _ = _solve_euler(a, b, *_qp(rng, 4, 4, 2))[:2]
    assert code == riccati_euler.SINGULAR_STEP
