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
BPTT gradients (paper cost, fast mode's augmented Lagrangian) against finite differences.

The penalties are only C1 (Heaviside forms) and the ray formula of eq. (41) is discontinuous
where the ray is tangent to a circle, so every case first checks, in plain numpy, that no node
sits near a kink (control bound, zero penetration, tangency, ALM switch); the perturbations of
the finite differences then stay on one smooth piece and central differences are accurate.
"""

import math

import numpy as np
import numpy_model as nm
import pytest

from toc_ros.core.bptt import paper_cost, paper_cost_gradient, Workspace
from toc_ros.core.integrators import EULER, RK4
from toc_ros.core.model import RobotParams
from toc_ros.core.obstacles import GRAD_EXACT, GRAD_SHORTCUT, obstacle_penalty

N = 30
T_F = 2.5
P = RobotParams().packed()
A = 1.1
METHODS = [('euler', EULER), ('rk4', RK4)]
# Two circles in the sweep of the arm: the paper's (inflated) and one near the goal bearing.
CIRCLES = np.array([[1.0, 1.0, 0.21], [0.55, 1.9, 0.2]])
# Constants chosen so that J1, J2 and J3 are of similar size (each ~10-400).
K_B, K_V_HAT, K_P = 600.0, 1e-3, 10.0
FD_TOL = 1e-6


def _controls(seed):
    """Return a rotate-and-brake motion through both circles, noisy, with 4 bound violations."""
    rng = np.random.default_rng(seed)
    u = np.zeros((N, 2))
    u[:N // 2, 0], u[N // 2:, 0] = 350.0, -350.0
    u += rng.normal(0.0, 60.0, size=(N, 2))
    u[3, 0], u[22, 0], u[20, 1], u[25, 1] = 680.0, -650.0, -590.0, 560.0
    return u


def _ray_terms(states, circles):
    """Per node and circle: (b = c.e, D of eq. 40 / 4(1 + tan^2), gap r_min - a - q2 or None)."""
    out = []
    for x in states:
        e = np.array([math.cos(x[0]), math.sin(x[0])])
        row = []
        for cx, cy, radius in circles:
            b = e @ (cx, cy)
            disc = b * b - (cx * cx + cy * cy - radius * radius)
            hit = nm.ray_first_hit(x[0], cx, cy, radius)
            row.append((b, disc, None if hit is None else hit - A - x[2]))
        out.append(row)
    return out


def _numpy_paper_cost(states, controls, circles, k_b, k_v_hat, k_p):
    """J1 + J2 + J3 of eqs. (7), (8), (42) from the trajectory, by plain numpy."""
    j1 = k_b * np.sum((states[-1] - nm.XG) ** 2)
    excess = np.maximum(np.abs(controls) - nm.U_MAX[None, :], 0.0)
    j2 = k_v_hat * np.sum(excess ** 2)
    j3 = k_p * sum(gap * gap for row in _ray_terms(states, circles) for _, _, gap in row
                   if gap is not None and gap < 0.0)
    return j1 + j2 + j3


def _check_away_from_kinks(states, controls, circles):
    """Return the number of penetrating (node, circle) pairs; assert no kink is close."""
    assert np.min(np.abs(np.abs(controls) - nm.U_MAX[None, :])) > 1.0
    hits = 0
    for row in _ray_terms(states, circles):
        for b, disc, gap in row:
            if b > 0.0:
                assert abs(disc) > 2e-3, 'a node is near tangency: choose other controls'
            if gap is not None:
                assert abs(gap) > 1e-3
                hits += gap < 0.0
    return hits


def _central_difference(fun, z, h):
    z = np.asarray(z, dtype=float)
    grad = np.zeros(z.size)
    flat = z.reshape(-1)
    for k in range(flat.size):
        zp, zm = flat.copy(), flat.copy()
        zp[k] += h
        zm[k] -= h
        grad[k] = (fun(zp.reshape(z.shape)) - fun(zm.reshape(z.shape))) / (2.0 * h)
    return grad.reshape(z.shape)


def _relative_error(got, want):
    return float(np.max(np.abs(got - want)) / np.max(np.abs(want)))


@pytest.mark.parametrize('terms', ['all', 'terminal', 'bounds', 'obstacles'])
@pytest.mark.parametrize('name, method', METHODS)
def test_exact_paper_gradient_matches_finite_differences(name, method, terms):
    k_b = K_B if terms in ('all', 'terminal') else 0.0
    k_v = K_V_HAT if terms in ('all', 'bounds') else 0.0
    k_p = K_P if terms in ('all', 'obstacles') else 0.0
    controls = _controls(seed=0)
    tau = T_F / N
    states = nm.simulate(nm.X0, controls, T_F, name)
    assert _check_away_from_kinks(states, controls, CIRCLES) >= 6

    def cost(u, t=tau):
        return paper_cost(nm.X0, nm.XG, u, t, P, method, nm.U_MAX, CIRCLES, k_b, k_v, k_p,
                          GRAD_EXACT)[0]

    value, grad = paper_cost(nm.X0, nm.XG, controls, tau, P, method, nm.U_MAX, CIRCLES,
                             k_b, k_v, k_p, GRAD_EXACT)
    # The cost itself, recomputed independently, and every active term is non-zero.
    assert value == pytest.approx(_numpy_paper_cost(states, controls, CIRCLES, k_b, k_v, k_p),
                                  rel=1e-10)
    assert value > 1.0
    fd = _central_difference(cost, controls, 1e-2)
    assert _relative_error(grad, fd) < FD_TOL

    # dJ/dtau from the same sweep (free final time).
    ws = Workspace(N)
    *_, d_tau = paper_cost_gradient(nm.X0, nm.XG, controls, tau, P, method, nm.U_MAX,
                                    CIRCLES, k_b, k_v, k_p, GRAD_EXACT, ws.states, ws.jac_x,
                                    ws.jac_u, ws.jac_tau, ws.grad_x, ws.grad_u,
                                    ws.out_grad_u)
    np.testing.assert_array_equal(ws.out_grad_u, grad)
    fd_tau = _central_difference(lambda t: cost(controls, float(t[0])), [tau], 1e-6)[0]
    if terms == 'bounds':          # J2 does not depend on tau
        assert d_tau == 0.0 and fd_tau == 0.0
    else:
        assert abs(d_tau - fd_tau) < FD_TOL * abs(fd_tau)


def _quadrant_states(seed, count=400):
    rng = np.random.default_rng(seed)
    states = np.zeros((count, 4))
    states[:, 0] = rng.uniform(-math.pi, math.pi, count)
    states[:, 2] = rng.uniform(-0.3, 1.4, count)
    return states


QUADRANT_CIRCLES = np.array([[1.0, 1.0, 0.3], [-1.2, 0.8, 0.4], [-0.9, -1.1, 0.35],
                             [1.3, -0.7, 0.3]])


def test_obstacle_penalty_in_every_quadrant_value_and_state_gradient():
    """Value vs np.roots intersections; exact dJ3/dq1, dJ3/dq2 (eqs. 44-45) vs FD."""
    states = _quadrant_states(7)
    k_p = 3.0
    terms = _ray_terms(states, QUADRANT_CIRCLES)
    # Keep the nodes that are not near a kink of any circle.
    keep = [i for i, row in enumerate(terms)
            if all((b <= 0.0 or abs(disc) > 1e-3) and (gap is None or abs(gap) > 1e-4)
                   for b, disc, gap in row)]
    states = states[keep]
    active = np.array([[gap is not None and gap < 0.0 for _, _, gap in terms[i]] for i in keep])
    assert np.all(np.sum(active, axis=0) >= 10), 'every circle must be penetrated'

    grad_x = np.zeros_like(states)
    value = obstacle_penalty(states, A, QUADRANT_CIRCLES, k_p, GRAD_EXACT, grad_x)
    expected = k_p * sum(gap ** 2 for i in keep for _, _, gap in terms[i]
                         if gap is not None and gap < 0.0)
    assert value == pytest.approx(expected, rel=1e-10)

    for i in range(states.shape[0]):
        def node_cost(q, i=i):
            x = states[i:i + 1].copy()
            x[0, 0], x[0, 2] = q
            return obstacle_penalty(x, A, QUADRANT_CIRCLES, k_p, GRAD_EXACT, np.zeros((1, 4)))
        fd = _central_difference(node_cost, states[i, [0, 2]], 1e-7)
        np.testing.assert_allclose(grad_x[i, [0, 2]], fd, rtol=1e-6,
                                   atol=1e-6 * max(1.0, np.max(np.abs(fd))))
    assert np.all(grad_x[:, [1, 3]] == 0.0)


def test_shortcut_gradient_is_eq46():
    """GRAD_SHORTCUT: dJ3/dq1 = 0 and dJ3/dq2 = K_p at each penetration, whatever the depth."""
    states = _quadrant_states(8)
    k_p = 7.0
    terms = _ray_terms(states, QUADRANT_CIRCLES)
    hits = np.array([sum(gap is not None and gap < 0.0 for _, _, gap in row) for row in terms])
    assert np.sum(hits > 0) >= 40 and np.any(hits == 0)
    grad_x = np.zeros_like(states)
    value_short = obstacle_penalty(states, A, QUADRANT_CIRCLES, k_p, GRAD_SHORTCUT, grad_x)
    np.testing.assert_array_equal(grad_x[:, 0], 0.0)
    np.testing.assert_array_equal(grad_x[:, 1], 0.0)
    np.testing.assert_array_equal(grad_x[:, 3], 0.0)
    np.testing.assert_allclose(grad_x[:, 2], k_p * hits, rtol=0, atol=1e-12)
    # The value is the same J3 whichever gradient is requested.
    value_exact = obstacle_penalty(states, A, QUADRANT_CIRCLES, k_p, GRAD_EXACT,
                                   np.zeros_like(states))
    assert value_short == value_exact > 0.0
