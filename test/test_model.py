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

"""Robot model (eq. 37), its Jacobians and the Euler/RK4 steps against plain numpy."""

import numpy as np
from numpy_model import f as np_f, step as np_step
import pytest

from toc_ros.core.integrators import EULER, integrator_id, RK4, rollout, rollout_linearized, \
    step
from toc_ros.core.model import dynamics, dynamics_jacobians, RobotParams

# A robot with non-paper numbers as well, so that the parameter plumbing is exercised.
ROBOTS = [{}, {'hand_mass': 20.0, 'link_mass': 40.0, 'inertia': 80.0, 'a': 0.7}]
METHODS = [('euler', EULER), ('rk4', RK4)]


def _core_params(robot, variant):
    return RobotParams(model_variant=variant, **robot).packed()


def _random_points(rng, count):
    """States and controls over a wide range, including u beyond the bounds."""
    lo = np.array([-np.pi, -3.0, -0.5, -2.0])
    x = rng.uniform(lo, -lo + np.array([0.0, 0.0, 2.0, 0.0]), size=(count, 4))
    u = rng.uniform(-1.5, 1.5, size=(count, 2)) * np.array([600.0, 500.0])
    return x, u


def _central_difference(fun, z, h):
    z = np.asarray(z, dtype=float)
    cols = []
    for k in range(z.size):
        dz = np.zeros_like(z)
        dz[k] = h * max(1.0, abs(z[k]))
        cols.append((fun(z + dz) - fun(z - dz)) / (2.0 * dz[k]))
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize('robot', ROBOTS)
@pytest.mark.parametrize('variant', ['eq37', 'eq36'])
def test_rhs_matches_hand_written_eq37(variant, robot):
    rng = np.random.default_rng(1)
    p = _core_params(robot, variant)
    for x, u in zip(*_random_points(rng, 200)):
        np.testing.assert_allclose(dynamics(x, u, p), np_f(x, u, variant, robot),
                                   rtol=1e-12, atol=1e-12)


def test_variants_differ_only_in_the_centrifugal_sign():
    rng = np.random.default_rng(2)
    p37, p36 = _core_params({}, 'eq37'), _core_params({}, 'eq36')
    a2_over_a3 = 2.0 * 50.0 * 1.1 / (97.0 + 50.0)
    for x, u in zip(*_random_points(rng, 50)):
        diff = dynamics(x, u, p36) - dynamics(x, u, p37)
        # eq. (36) gives +A2/(2 A3) x2^2, eq. (37) as printed -A2/(2 A3) x2^2.
        np.testing.assert_allclose(diff, [0.0, 0.0, 0.0, a2_over_a3 * x[1] ** 2],
                                   rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize('variant', ['eq37', 'eq36'])
def test_analytic_jacobians_match_finite_differences(variant):
    rng = np.random.default_rng(3)
    robot = ROBOTS[1]
    p = _core_params(robot, variant)
    for x, u in zip(*_random_points(rng, 50)):
        f0, fx, fu = dynamics_jacobians(x, u, p)
        np.testing.assert_allclose(f0, np_f(x, u, variant, robot), rtol=1e-12, atol=1e-12)
        fd_x = _central_difference(lambda z: np_f(z, u, variant, robot), x, 1e-6)
        fd_u = _central_difference(lambda z: np_f(x, z, variant, robot), u, 1e-6)
        scale = max(1.0, np.max(np.abs(fd_x)))
        np.testing.assert_allclose(fx, fd_x, rtol=1e-6, atol=1e-7 * scale)
        np.testing.assert_allclose(fu, fd_u, rtol=1e-6, atol=1e-12)


@pytest.mark.parametrize('name, method', METHODS)
def test_step_matches_numpy(name, method):
    rng = np.random.default_rng(4)
    p = _core_params({}, 'eq37')
    for x, u in zip(*_random_points(rng, 100)):
        tau = rng.uniform(1e-4, 0.05)
        np.testing.assert_allclose(step(x, u, tau, p, method), np_step(x, u, tau, name),
                                   rtol=1e-13, atol=1e-13)


def test_integrator_names():
    assert integrator_id('euler') == EULER and integrator_id('rk4') == RK4
    with pytest.raises(ValueError, match='integrator'):
        integrator_id('rk45')


@pytest.mark.parametrize('name, method', METHODS)
def test_rollout_linearized_jacobians_match_finite_differences(name, method):
    rng = np.random.default_rng(5)
    n = 12
    p = _core_params({}, 'eq37')
    x0 = np.array([0.3, 0.8, 0.9, -0.4])
    controls = rng.uniform(-1.2, 1.2, size=(n, 2)) * np.array([600.0, 500.0])
    tau = 0.02
    states = np.zeros((n + 1, 4))
    jac_x, jac_u, jac_tau = np.zeros((n, 4, 4)), np.zeros((n, 4, 2)), np.zeros((n, 4))
    rollout_linearized(x0, controls, tau, p, method, states, jac_x, jac_u, jac_tau)

    expected = [x0]
    for u in controls:
        expected.append(np_step(expected[-1], u, tau, name))
    np.testing.assert_allclose(states, np.array(expected), rtol=1e-13, atol=1e-13)
    plain = np.zeros((n + 1, 4))
    rollout(x0, controls, tau, p, method, plain)
    # Same maths, different evaluation order for RK4: equal up to rounding.
    np.testing.assert_allclose(plain, states, rtol=1e-14, atol=1e-14)

    for i in range(n):
        x, u = states[i], controls[i]
        fd_x = _central_difference(lambda z: np_step(z, u, tau, name), x, 1e-6)
        fd_u = _central_difference(lambda z: np_step(x, z, tau, name), u, 1e-6)
        fd_tau = _central_difference(lambda z: np_step(x, u, z[0], name), [tau], 1e-6)[:, 0]
        # Entries far below a matrix's largest are compared on the matrix's scale.
        for got, want in ((jac_x[i], fd_x), (jac_u[i], fd_u), (jac_tau[i], fd_tau)):
            np.testing.assert_allclose(got, want, rtol=1e-7, atol=1e-7 * np.max(np.abs(want)))
