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
Independent oracles of the plant's reference and drives, written out without the package.

Shared by the process tests (test_plant_stamps.py, on the message traffic) and the unit tests
of the ROS-free simulator (test_plant_simulator.py).
"""

import math

import numpy as np

NS = 1_000_000_000


class Expected:
    """q_ref, dq_ref, u_ff of a trajectory (times [s] from its stamp), as the plant defines it."""

    def __init__(self, times, positions, velocities, efforts=None):
        # As sent: time_from_start has whole nanoseconds.
        self.times = np.round(np.asarray(times, dtype=float) * NS) / NS
        self.positions = np.asarray(positions, dtype=float)
        self.velocities = np.asarray(velocities, dtype=float)
        self.efforts = None if efforts is None else np.asarray(efforts, dtype=float)

    def __call__(self, tau):
        zero = np.zeros(2)
        if tau >= self.times[-1]:
            return self.positions[-1], zero, zero
        k = int(np.flatnonzero(self.times <= tau)[-1])
        h = self.times[k + 1] - self.times[k]
        p0, p1 = self.positions[k], self.positions[k + 1]
        v0, v1 = self.velocities[k], self.velocities[k + 1]
        c2 = (3.0 * (p1 - p0) / h - 2.0 * v0 - v1) / h
        c3 = (2.0 * (p0 - p1) / h + v0 + v1) / (h * h)
        s = tau - self.times[k]
        q = p0 + v0 * s + c2 * s * s + c3 * s * s * s
        dq = v0 + 2.0 * c2 * s + 3.0 * c3 * s * s
        return q, dq, (zero if self.efforts is None else self.efforts[k])


def hold(q):
    """Return the reference of holding q."""
    return lambda tau: (np.asarray(q, dtype=float), np.zeros(2), np.zeros(2))


def rest_to_rest(start, goal, duration, points=7):
    """Return the Expected reference of a smoothstep from start to goal (no effort)."""
    s = np.linspace(0.0, 1.0, points)
    blend = 3 * s ** 2 - 2 * s ** 3
    rate = (6 * s - 6 * s ** 2) / duration
    delta = np.asarray(goal, dtype=float) - np.asarray(start, dtype=float)
    return Expected(s * duration, start + np.outer(blend, delta), np.outer(rate, delta))


def lagged(t, width, u, lag):
    """Output at t [s] of a lag (time constant lag, 0: none) fed u on [0, width), else 0."""
    if t <= 0.0:
        return np.zeros_like(u)
    if lag == 0.0:
        return u if t <= width else np.zeros_like(u)
    rise = u * (1.0 - math.exp(-min(t, width) / lag))
    return rise if t <= width else rise * math.exp(-(t - width) / lag)


def deviation(samples, pieces):
    """Largest |reference - expected| over samples; pieces: [(start ns, expected)] in order."""
    worst = 0.0
    for t, q, dq, u in samples:
        start, expected = [p for p in pieces if p[0] <= t][-1]
        q_e, dq_e, u_e = expected((t - start) / NS)
        worst = max(worst, float(np.max(np.abs(q - q_e))), float(np.max(np.abs(dq - dq_e))),
                    float(np.max(np.abs(u - u_e))))
    return worst
