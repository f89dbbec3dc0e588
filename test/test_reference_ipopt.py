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
Checks of the CasADi/IPOPT reference (benchmarks/reference_ipopt.py) at small N.

Every solution is re-checked here with code written independently of the module: a plain
Euler/RK4 loop over eq. (37) with the paper's constants, and clearance by dense sampling of
points along the arm instead of the closed-form segment distance.
"""

import math

from benchmarks import reference_ipopt as ref
import numpy as np
import pytest

pytestmark = pytest.mark.slow

pytest.importorskip('casadi')

X0 = np.array([math.pi / 12.0, 0.0, 1.0, 0.0])
XF = np.array([5.0 * math.pi / 12.0, 0.0, 1.0, 0.0])
OBSTACLES = [(1.0, 1.0, 0.2)]
MARGIN = 0.01
# IPOPT optimum at N = 1000 (Euler): 2.06728 s with the obstacle, 1.61075 s without.  The
# discrete optimum moves by < 1e-3 s between N = 100 and N = 1000.
T_ARM_1000 = 2.06728
T_NONE_1000 = 1.61075


def _f(x, u):
    """Eq. (37), written out again with the paper's numbers (M 50, m 97, I 193, a 1.1)."""
    big_m, small_m, inertia, a = 50.0, 97.0, 193.0, 1.1
    a1, a2, a3 = inertia + big_m * a ** 2, 2.0 * big_m * a, small_m + big_m
    q1d, q2, q2d = x[1], x[2], x[3]
    return np.array([
        q1d,
        (-2.0 * a3 * q1d * q2 * q2d - a2 * q1d * q2d + u[0]) / (a1 + a2 * q2 + a3 * q2 ** 2),
        q2d,
        q2 * q1d ** 2 - a2 / (2.0 * a3) * q1d ** 2 + u[1] / a3,
    ])


def _rollout(controls, t_f, rk4):
    tau = t_f / len(controls)
    x = X0.copy()
    xs = [x]
    for u in controls:
        if rk4:
            k1 = _f(x, u)
            k2 = _f(x + tau / 2 * k1, u)
            k3 = _f(x + tau / 2 * k2, u)
            k4 = _f(x + tau * k3, u)
            x = x + tau / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        else:
            x = x + tau * _f(x, u)
        xs.append(x)
    return np.array(xs)


def _sampled_clearance(states, hand_only=False):
    """Smallest distance minus inflated radius over 2001 points along each arm."""
    s = np.array([1.0]) if hand_only else np.linspace(0.0, 1.0, 2001)
    reach = (1.1 + states[:, 2])[:, None] * s[None, :]
    px = reach * np.cos(states[:, 0])[:, None]
    py = reach * np.sin(states[:, 0])[:, None]
    return min(float(np.min(np.hypot(px - cx, py - cy))) - r - MARGIN for cx, cy, r in OBSTACLES)


def _check_feasible(res, rk4=False, hand_only=False):
    assert res['success'], res['attempts']
    controls = res['controls']
    assert np.all(np.abs(controls[:, 0]) <= 600.0 + 1e-9)
    assert np.all(np.abs(controls[:, 1]) <= 500.0 + 1e-9)
    states = _rollout(controls, res['t_f'], rk4)
    assert np.max(np.abs(states - res['states'])) < 1e-7
    assert np.max(np.abs(states[-1] - XF)) < 1e-7
    return states


@pytest.mark.parametrize('rk4', [False, True])
def test_paper_scenario_whole_arm_is_feasible_and_near_the_n1000_optimum(rk4):
    res = ref.solve_reference(X0, XF, OBSTACLES, MARGIN, N=200,
                              integrator='rk4' if rk4 else 'euler')
    states = _check_feasible(res, rk4=rk4)
    # Dense sampling reaches the segment's closest point only to ~1e-4 m; the active
    # constraint makes the true clearance ~0, so allow that sampling error, not more.
    assert _sampled_clearance(states) > -1e-9
    assert abs(_sampled_clearance(states)) < 1e-3
    assert abs(res['t_f'] - T_ARM_1000) < 2e-3
    # The obstacle is active: the arm retracts to just below the circle (q2 ~ 0.104 m).
    assert np.min(states[:, 2]) < 1.41421356 - 0.21 - 1.1 + 1e-3


def test_obstacle_modes_are_ordered_and_hand_mode_passes_outside():
    none = ref.solve_reference(X0, XF, OBSTACLES, MARGIN, N=100, obstacle_mode='none')
    hand = ref.solve_reference(X0, XF, OBSTACLES, MARGIN, N=100, obstacle_mode='hand')
    _check_feasible(none)
    hand_states = _check_feasible(hand, hand_only=True)
    assert abs(none['t_f'] - T_NONE_1000) < 2e-3
    assert none['t_f'] < hand['t_f'] < T_ARM_1000 - 0.3
    assert _sampled_clearance(hand_states, hand_only=True) > -1e-9
    # Allowed to swing the hand around the far side, the arm itself cuts the circle.
    assert _sampled_clearance(hand_states) < -0.1


def test_numpy_verifier_agrees_with_the_independent_check():
    res = ref.solve_reference(X0, XF, OBSTACLES, MARGIN, N=100)
    check = ref.verify_solution(res, X0, XF, OBSTACLES, MARGIN)
    states = _check_feasible(res)
    assert check['terminal_error'] < 1e-7 and check['control_excess'] == 0.0
    assert abs(check['min_clearance'] - _sampled_clearance(states)) < 1e-4


def test_collision_at_start_and_bad_options_raise_clear_errors():
    with pytest.raises(ValueError, match='start configuration'):
        ref.solve_reference([math.pi / 4, 0, 1, 0], XF, OBSTACLES, MARGIN, N=20)
    with pytest.raises(ValueError, match='integrator'):
        ref.solve_reference(X0, XF, OBSTACLES, MARGIN, N=20, integrator='rk45')


def test_missing_casadi_gives_a_clear_error(monkeypatch):
    monkeypatch.setattr(ref, 'ca', None)
    with pytest.raises(RuntimeError, match='needs casadi'):
        ref.solve_reference(X0, XF, OBSTACLES, MARGIN, N=20)
