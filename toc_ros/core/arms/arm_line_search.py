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
IPOPT's filter line search (Waechter & Biegler 2006) for the arm interior point (arm_ipm.py).

Backtracking from the fraction-to-the-boundary step on the pair (theta = l1 constraint
violation, phi = barrier objective) with IPOPT's switching rule, Armijo condition and one
filter reset; unlike IPOPT, a step that lowers the violation without raising phi is taken
where Armijo's test fails (_acceptable says why).  A mixin of ArmInteriorPoint: it reads the
iterate (x, v, t, s and the duals), the evaluator ev, mu and the bound arguments (_bounds),
and moves them by the accepted step (_take).
"""

import numpy as np

from . import ipm_kernels

ARMIJO = 1e-4
MIN_ALPHA = 1e-12
ROUNDING = 10.0 * np.finfo(float).eps


class FilterLineSearch:
    """The line search of ArmInteriorPoint (module docstring)."""

    def new_filter(self):
        """Start with an empty filter and no bounds on the violation (set at the first step)."""
        self.filter = []
        self.theta_max = None
        self.theta_min = None
        self.first_taken = True

    def _merit(self, x, v, t, s, defect, values):
        return ipm_kernels.merit(x[1:-1], v, t, s, defect, values, *self._bounds(), self.mu)

    def _in_filter(self, theta, phi):
        return any(theta >= f_theta and phi >= f_phi for f_theta, f_phi in self.filter)

    def _line_search(self, terms, values, grads, dx, dv, d_t, lam_qp):
        """Backtracking on the l1 merit; updates the iterate and duals; returns alpha."""
        mu = self.mu
        frac = max(0.99, 1.0 - mu)
        # Fraction to the boundary (primal and dual), the bound-dual steps of the condensed
        # system and the barrier objective's slope along the step.
        direction = self._direction(values, grads, dx, dv, d_t, lam_qp, frac)
        alpha_max, slope = direction['alpha_max'], direction['slope']
        # IPOPT's filter line search on (theta = l1 constraint violation, phi = barrier
        # objective), with its switching rule and constants.
        phi0, theta0 = self._merit(self.x, self.v, self.t, self.s, terms['defect'], values)
        if self.theta_max is None:
            self.theta_max = 1e4 * max(1.0, theta0)
            self.theta_min = 1e-4 * max(1.0, theta0)
        alpha = alpha_max
        self.alpha_max = alpha_max
        # The first trial's dynamics come with their derivatives (the next iteration's) while
        # first trials are being taken: a rejected one costs 3.5 times an ABA pass.
        first = self.first_taken
        while alpha >= MIN_ALPHA:
            trial = self._trial(direction, alpha, keep_derivatives=first)
            taken = self._acceptable(trial, alpha, phi0, theta0, slope)
            if first is not None:
                self.first_taken, first = taken, None
            if taken:
                return self._take(direction, trial, alpha)
            alpha *= 0.5
        if self.filter:
            # IPOPT's filter reset heuristic, once: forget the filter and search again.
            self.filter = []
            return self._line_search(terms, values, grads, dx, dv, d_t, lam_qp)
        return None

    def _direction(self, values, grads, dx, dv, d_t, lam_qp, frac):
        """Return a primal step with its slack and dual steps and step lengths (a dict)."""
        out = {'dx': dx, 'dv': dv, 'd_t': d_t, 'lam': lam_qp, 'ds': np.empty_like(self.s),
               'dz': np.empty_like(self.z), 'dzlx': np.empty_like(self.zlx),
               'dzux': np.empty_like(self.zux), 'dzlv': np.empty_like(self.zlv),
               'dzuv': np.empty_like(self.zuv)}
        (out['alpha_max'], out['alpha_dual'], out['dzlt'], out['dzut'],
         out['slope']) = ipm_kernels.step_to_boundary(
            dx[1:-1], dv, d_t, grads, values, self.s, self.z, self.x[1:-1], self.v, self.t,
            self.zlx, self.zux, self.zlv, self.zuv, self.zlt, self.zut, *self._bounds(),
            self.mu, frac, out['ds'], out['dzlx'], out['dzux'], out['dzlv'], out['dzuv'],
            out['dz'])
        return out

    def _trial(self, direction, alpha, keep_derivatives=False):
        """Return the point alpha along direction, its defects and its (phi, theta)."""
        trial = {'x': self.x + alpha * direction['dx'], 'v': self.v + alpha * direction['dv'],
                 't': self.t + alpha * direction['d_t'], 's': self.s + alpha * direction['ds']}
        trial['defect'] = self.ev.defects(trial['x'], trial['v'], trial['t'],
                                          keep_derivatives=bool(keep_derivatives))
        values = self.ev.clearances(trial['x'][1:-1, :self.n])
        trial['phi'], trial['theta'] = self._merit(trial['x'], trial['v'], trial['t'],
                                                   trial['s'], trial['defect'], values)
        return trial

    def _acceptable(self, trial, alpha, phi0, theta0, slope):
        """Return IPOPT's filter acceptance of a trial point (the filter grows on h-type steps)."""
        phi, theta = trial['phi'], trial['theta']
        if not (np.isfinite(phi) and theta <= self.theta_max
                and not self._in_filter(theta, phi)):
            return False
        rounding = ROUNDING * abs(phi0)
        switching = slope < 0.0 and alpha * (-slope) ** 2.3 > theta0 ** 1.1
        if theta0 <= self.theta_min and switching:
            # f-type: the filter is not augmented.
            if phi <= phi0 + ARMIJO * alpha * slope + rounding:
                return True
            # ... or, unlike IPOPT, a step that lowers the violation without raising phi, taken
            # as an h-type step below.  Near the solution (mu <= 1e-9) a step that moves
            # controls off their bounds (a switching time moving) has a slope dominated by
            # mu / slack terms whose slacks are ~ mu: the linear model promises a decrease the
            # barrier cannot give, Armijo rejects the full step, and the backtracking to an
            # h-type step raised the proximal weight, whose decay cost ~10 iterations (UR5
            # free at N = 200: 39 -> 28 iterations; benchmarks/RESULTS.md, "Arms: more ways
            # around a sphere").
            if not (phi <= phi0 + rounding and theta <= (1.0 - 1e-5) * theta0):
                return False
        if theta <= (1.0 - 1e-5) * theta0 or phi <= phi0 - 1e-8 * theta0 + rounding:
            self.filter.append(((1.0 - 1e-5) * theta0, phi0 - 1e-8 * theta0))
            return True
        return False

    def _take(self, direction, trial, alpha):
        """Move to trial; the duals by direction's dual step length; return alpha."""
        self.x, self.v, self.t, self.s = trial['x'], trial['v'], trial['t'], trial['s']
        ad = direction['alpha_dual']
        self.zlx = self.zlx + ad * direction['dzlx']
        self.zux = self.zux + ad * direction['dzux']
        self.zlv = self.zlv + ad * direction['dzlv']
        self.zuv = self.zuv + ad * direction['dzuv']
        self.zlt = self.zlt + ad * direction['dzlt']
        self.zut = self.zut + ad * direction['dzut']
        if self.z.size:
            self.z = self.z + ad * direction['dz']
        self.lam = self.lam + alpha * (direction['lam'] - self.lam)
        self._safeguard_duals()
        return alpha
