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
The reference a plant follows on a topic trajectory, as a function of time.

q_ref, dq_ref are the cubic Hermite interpolation of the points and u_ff their effort held from
each point to the next (the solver's piecewise-constant controls); after the last point the
reference holds the final position with zero velocity and feed-forward.  Times are seconds
since the trajectory's start; a ``Scheduled`` trajectory places one on the plant's simulated
time in integer nanoseconds.
"""

import dataclasses

import numpy as np

from toc_ros.core.plan_reference import hermite

NS = 1_000_000_000


class Reference:
    """Reference (q, dq, u_ff) of a trajectory over time since its start; holds the end."""

    def __init__(self, times, positions, velocities, efforts=None):
        self.n = positions.shape[1]
        self.times = times
        self.positions = positions
        self.velocities = velocities
        self.efforts = efforts
        self.duration = float(self.times[-1])

    @classmethod
    def of(cls, arrays):
        """Build the Reference of conversions.TrajectoryArrays."""
        return cls(arrays.times, arrays.positions, arrays.velocities, arrays.efforts)

    def starting_from(self, t, q, dq):
        """Return this reference led in from (q, dq) at time t when its first point is later."""
        if not self.times[0] > t:
            return self
        zero = np.zeros((1, self.n))
        efforts = None if self.efforts is None else np.vstack([zero, self.efforts])
        return Reference(np.concatenate([[t], self.times]),
                         np.vstack([np.reshape(q, (1, -1)), self.positions]),
                         np.vstack([np.reshape(dq, (1, -1)), self.velocities]), efforts)

    def at(self, t):
        """(q_ref, dq_ref, u_ff) at time t [s] after the start."""
        times = self.times
        zero = np.zeros(self.n)
        if t >= self.duration:
            return self.positions[-1], zero, zero
        if t < times[0]:
            return self.positions[0], zero, zero
        i = int(np.searchsorted(times, t, side='right')) - 1
        pos, vel = hermite(times[i], times[i + 1], self.positions[i], self.velocities[i],
                           self.positions[i + 1], self.velocities[i + 1], t)
        return pos, vel, (zero if self.efforts is None else self.efforts[i])


@dataclasses.dataclass
class Scheduled:
    """A trajectory and its start (stamp) and activation time, in simulated nanoseconds."""

    reference: Reference
    start_ns: int          # simulated time of time_from_start = 0
    activate_ns: int       # first step at or after this runs it: max(stamp, receipt)
