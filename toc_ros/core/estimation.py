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
Online estimation of model parameters from measured joint states and efforts (ROS-free).

A replan cycle plans with the model; when the robot is heavier than the model says, every
plan asks for accelerations the robot cannot reach.  ``ParameterEstimator`` fits chosen model
parameters (masses, inertias) to what the robot does.

For a rigid-body model M(q; theta) ddq + h(q, dq; theta) = u the inverse dynamics
tau(x, ddq; theta) = M (ddq - b), with b = ddq(u = 0), is linear in the inertial parameters
(the standard identification result).  The model's own forward kernel gives it:
ddq = A(x) u + b(x), A = d ddq / du = M^-1.  Two consecutive samples give the mean
acceleration over their interval, regressed at the midpoint state and effort (second-order
accurate); pairs across a control switch are skipped.  Each pair adds its rows to a
recursive least-squares fit with exponential forgetting (time constant ``window``).  The
regressor columns are differences in each parameter, exact for parameters that enter
linearly and a linearisation at the model's values otherwise.  Rows are scaled by u_max and
columns by the model's values, so joints and parameters of any units weigh alike.
"""

import math

import numpy as np

from .models.base import ModelError

# Consecutive samples further apart than this are not paired (a dropped message or a stall).
MAX_GAP_S = 0.05
# A pair whose effort changes by more than this fraction of u_max has a switch inside: skipped.
MAX_EFFORT_STEP = 0.05
# Before an estimate is used: this many pairs (forgetting-weighted) ...
MIN_PAIRS = 20.0
# ... and every parameter direction excited: smallest eigenvalue of the information per pair.
MIN_EXCITATION = 1e-4
# An estimate outside these factors of the model's value is refused (bad efforts, no data).
RATIO_BOUNDS = (0.2, 5.0)
# Relative step of the regressor's parameter differences.
STEP = 0.1
# Weight of the model's values as a prior, in pairs: keeps the fit defined before excitation.
PRIOR_PAIRS = 1e-3


def torque_function(model, values):
    """
    Return tau(q, dq, ddq): the inverse dynamics of model with parameter values changed.

    A model with its own (inverse_dynamics_with, e.g. a URDF arm: RNEA) gives it; otherwise it
    comes from the forward kernel, tau = (d ddq / du)^-1 (ddq - ddq(u = 0)).
    """
    own = getattr(model, 'inverse_dynamics_with', None)
    if own is not None:
        return own(values)
    p = (model.with_parameters(values) if values else model).packed()
    n = model.n_joints
    f, fx, fu, zero = (np.empty(model.nx), np.empty((model.nx, model.nx)),
                       np.empty((model.nx, n)), np.zeros(n))

    def tau(q, dq, ddq):
        x = np.empty(model.nx)
        x[0::2], x[1::2] = q, dq
        model.kernels.rhs_jac(x, zero, p, f, fx, fu)
        return np.linalg.solve(fu[1::2, :], ddq - f[1::2])
    return tau


def parameter_names(model):
    """Return the names of the model's numeric parameters."""
    return tuple(name for name, value in model.parameter_values().items()
                 if isinstance(value, (int, float)) and not isinstance(value, bool))


class ParameterEstimator:
    """
    Recursive least squares on the inverse dynamics of the model, for parameters `names`.

    add() takes each measured sample (time [s], positions, velocities, efforts = the applied
    u); estimate() returns {name: value} once the data determines them (else None, with the
    reason in .status); model() the model with those values.
    """

    def __init__(self, model, names, window):
        names = tuple(str(n) for n in names)
        known = parameter_names(model)
        unknown = [n for n in names if n not in known]
        if unknown or not names or len(set(names)) != len(names):
            raise ModelError(
                f'cannot estimate {", ".join(unknown) or list(names)} of model {model.name!r}: '
                f'give distinct names among its numeric parameters ({", ".join(known)})')
        if not (math.isfinite(window) and window > 0.0):
            raise ModelError(f'the estimation window must be > 0 s, got {window!r}')
        self.model_, self.names, self.window = model, names, float(window)
        values = model.parameter_values()
        self._theta0 = np.array([float(values[n]) for n in names])
        self._scale = np.where(self._theta0 != 0.0, np.abs(self._theta0), 1.0)
        # Inverse dynamics of the model and of each parameter stepped by STEP * scale.
        self._tau0 = torque_function(model, {})
        self._stepped = [torque_function(model, {name: self._theta0[j] + STEP * self._scale[j]})
                         for j, name in enumerate(names)]
        self._u_max = np.asarray(model.u_max, dtype=float)
        self.reset()

    def reset(self):
        """Forget every sample."""
        k = len(self.names)
        self._info = PRIOR_PAIRS * np.eye(k)
        self._rhs = np.zeros(k)
        self._pairs = 0.0
        self._last = None
        self._updated = None
        self.status = 'no samples yet'

    def add(self, t, q, dq, u):
        """Add a sample at time t [s]: positions q, velocities dq, applied efforts u."""
        t = float(t)
        sample = (t, np.asarray(q, dtype=float), np.asarray(dq, dtype=float),
                  np.asarray(u, dtype=float))
        last, self._last = self._last, sample
        if last is None:
            return
        dt = t - last[0]
        if not (0.0 < dt <= MAX_GAP_S) or np.any(
                np.abs(sample[3] - last[3]) > MAX_EFFORT_STEP * self._u_max):
            return
        q, dq = 0.5 * (sample[1] + last[1]), 0.5 * (sample[2] + last[2])
        ddq = (sample[2] - last[2]) / dt
        u_mid = 0.5 * (sample[3] + last[3])
        try:
            tau0 = self._tau0(q, dq, ddq)
            columns = [(tau(q, dq, ddq) - tau0) / STEP for tau in self._stepped]
        except np.linalg.LinAlgError:
            return
        rows = np.column_stack(columns) / self._u_max[:, None]      # d(tau / u_max) / d s
        target = (u_mid - tau0) / self._u_max
        if not (np.all(np.isfinite(rows)) and np.all(np.isfinite(target))):
            return
        decay = 1.0 if self._updated is None else math.exp(
            -max(t - self._updated, 0.0) / self.window)
        self._updated = t
        self._info = decay * (self._info - PRIOR_PAIRS * np.eye(len(self.names))) \
            + PRIOR_PAIRS * np.eye(len(self.names)) + rows.T @ rows
        self._rhs = decay * self._rhs + rows.T @ target
        self._pairs = decay * self._pairs + 1.0

    def estimate(self):
        """Return {name: value} when the samples determine the parameters, else None."""
        if self._pairs < MIN_PAIRS:
            self.status = f'{self._pairs:.0f} of {MIN_PAIRS:.0f} sample pairs'
            return None
        excitation = float(np.linalg.eigvalsh(self._info)[0]) / self._pairs
        if excitation < MIN_EXCITATION:
            self.status = f'not excited enough ({excitation:.2g} < {MIN_EXCITATION:g})'
            return None
        theta = self._theta0 + self._scale * np.linalg.solve(self._info, self._rhs)
        low, high = RATIO_BOUNDS
        for name, value, nominal in zip(self.names, theta, self._theta0):
            if not math.isfinite(value) or (nominal != 0.0 and not (
                    low <= value / nominal <= high)):
                self.status = f'{name} = {value:.4g} is implausible (model value {nominal:g})'
                return None
        self.status = 'estimated'
        return {name: float(value) for name, value in zip(self.names, theta)}

    def model(self, values=None):
        """Return the model with values (default: estimate()), None while there are none."""
        values = self.estimate() if values is None else values
        if values is None:
            return None
        try:
            model = self.model_.with_parameters(values)
        except ValueError as exc:     # values the model cannot be built with (e.g. mass < 0)
            self.status = f'estimate refused: {exc}'
            return None
        problems = model.check()
        if problems:
            self.status = f'estimate refused: {"; ".join(problems)}'
            return None
        return model


def estimate_text(values):
    """Return the estimate as 'name=value, ...' (9 significant digits), '' for None."""
    if not values:
        return ''
    return ', '.join(f'{name}={value:.9g}' for name, value in values.items())
