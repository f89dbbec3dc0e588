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
Warm starts of the arm interior point.

A previous trajectory (e.g. the remainder of the plan being executed, SolveResult.remainder)
or a pair (controls, t_f) as the start point.

A SolveResult with states on the problem's grid is taken as it is (its first state replaced
by the problem's start: the first Euler defect absorbs the robot's drift from the plan) with
its multipliers when it has them; a pair, or states that do not fit, are rolled out from the
start with pinocchio.aba (zero defects).  Another number of intervals is resampled
(start_points.resample) and starts without multipliers.
"""

import math

import numpy as np
import pinocchio as pin

from . import pin_batch
from .arm_ipm import DUAL_NAMES
from .model import ArmError
from ..result import SolveResult
from ..start_points import resample


class UnusableGuess(Exception):
    """A well-formed initial guess that gives no start point (the cold start is used)."""


def rollout(arm, x0, controls, t_f, integrator='euler'):
    """States (M + 1, 2n) of the controls (M, n) from x0: explicit Euler or RK4 steps t_f / M."""
    n = arm.n
    controls = np.asarray(controls, dtype=float)
    n_int = controls.shape[0]
    h = t_f / n_int
    batch = pin_batch.workspace(arm.model) if integrator != 'rk4' else None
    if batch is not None:
        # The same Euler steps in one call of the C++ loop (pin_batch.py): the same bits.
        return batch.rollout_euler(x0, controls, h)
    data = arm.model.createData()
    states = np.empty((n_int + 1, 2 * n))
    states[0] = x0

    def f(x, tau):
        # ABA in the WORLD convention: bit for bit the accelerations the solver's steps use
        # (arm_eval.py); the default LOCAL one differs by ~3e-11, which an open-loop unstable
        # motion amplifies past the terminal tolerance however small the plan's defects.
        return np.concatenate([x[n:], pin.aba(arm.model, data, x[:n], x[n:], tau,
                                              pin.Convention.WORLD)])
    for k in range(n_int):
        x, tau = states[k], controls[k]
        k1 = f(x, tau)
        if integrator != 'rk4':
            states[k + 1] = x + h * k1
            continue
        k2 = f(x + 0.5 * h * k1, tau)
        k3 = f(x + 0.5 * h * k2, tau)
        k4 = f(x + h * k3, tau)
        states[k + 1] = x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return states


def _fitting_duals(duals, m, nx, n, n_pairs):
    """Return the multipliers whose shapes fit m intervals (sphere duals: n_pairs columns)."""
    shapes = {'lam': (m + 1, nx), 'z': (m - 1, n_pairs), 'zlx': (m - 1, nx),
              'zux': (m - 1, nx), 'zlv': (m, n), 'zuv': (m, n), 'zlt': (), 'zut': ()}
    out = {}
    for name in DUAL_NAMES:
        value = duals.get(name)
        if value is not None and np.shape(value) == shapes[name] \
                and np.all(np.isfinite(value)):
            out[name] = value
    if 'lam' not in out or not math.isfinite(duals.get('prox', math.nan)):
        return None
    out['prox'] = float(duals['prox'])
    return out


def warm_point(arm, x0, guess, n_int, n_pairs, integrator='euler'):
    """
    Return (states, controls, t_f, duals or None, drift) of an initial guess for n_int intervals.

    drift: how far [max norm] the problem's start lies from the guess's first state (0 for a
    rolled-out guess).  ArmError with the reason for a malformed guess, UnusableGuess for one
    whose rollout diverges.
    """
    n = arm.n
    states = duals = None
    if isinstance(guess, SolveResult):
        controls, t_f = guess.controls, guess.final_time
        if guess.states is not None:
            states = np.asarray(guess.states, dtype=float)
        duals = (guess.solver_state or {}).get('arm_duals')
    else:
        try:
            controls, t_f = guess
        except (TypeError, ValueError):
            raise ArmError('initial_guess must be a SolveResult or a pair (controls, t_f), got '
                           f'{type(guess).__name__}') from None
    try:
        controls = np.array(controls, dtype=float)
        t_f = float(t_f)
    except (TypeError, ValueError):
        raise ArmError('initial guess controls must be numbers and t_f a number') from None
    if controls.ndim != 2 or controls.shape[1] != n or controls.shape[0] < 1:
        raise ArmError(f'initial guess controls must be an M x {n} array, got shape '
                       f'{controls.shape}')
    if not (np.all(np.isfinite(controls)) and math.isfinite(t_f) and t_f > 0.0):
        raise ArmError('initial guess must have finite controls and a positive final time')
    m = controls.shape[0]
    drift = 0.0
    if states is not None and states.shape == (m + 1, 2 * n) and np.all(np.isfinite(states)):
        drift = float(np.max(np.abs(states[0] - x0)))
        states = states.copy()
        states[0] = x0
    else:
        with np.errstate(all='ignore'):
            states = rollout(arm, x0, np.clip(controls, -arm.effort, arm.effort), t_f,
                             integrator)
        duals = None
        if not np.all(np.isfinite(states)):
            raise UnusableGuess('its controls make the state diverge')
    if duals is not None:
        duals = _fitting_duals(duals, m, 2 * n, n, n_pairs) if m == n_int else None
    if m != n_int:
        states, controls = resample(states, controls, n_int)
    return states, controls, t_f, duals, drift
