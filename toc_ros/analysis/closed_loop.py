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
Numbers of one closed-loop execution (one goal, any number of replans), from raw samples.

Times are header stamps [s] of the node clock: the plans' header.stamp (when each starts to
apply) and the joint_states' stamps, so a live run and a recording give the same numbers.
The demo, ``benchmarks/bench_replanning.py`` and toc-analyze all call ``execution_metrics``.
"""

from dataclasses import dataclass
import math
from typing import Optional, Sequence, Tuple

import numpy as np

from toc_ros.core.obstacles import scheduled_clearance

# The robot has arrived once every joint stays within this of the goal [rad or m] (1 cm of
# extension, 0.01 rad): the tracking PD settles the last millimetres slowly.
ARRIVAL_TOL = 1e-2
# The final error is taken this long after the end of the last plan [s].
FINAL_ERROR_DELAY_S = 0.2


@dataclass(frozen=True)
class PlanSpan:
    """One published plan: when it starts to apply and how long it lasts [s]."""

    stamp: float
    duration: float

    @property
    def end(self):
        """Return the plan's end time [s]."""
        return self.stamp + self.duration


def arrival_time(times, positions, goal_q, tol=ARRIVAL_TOL):
    """Return the first time after which every later sample is within tol of goal_q (nan)."""
    error = np.max(np.abs(np.asarray(positions) - np.asarray(goal_q)[None, :]), axis=1)
    outside = np.nonzero(error > tol)[0]
    if outside.size == 0:
        return float(times[0])
    last = int(outside[-1])
    return float(times[last + 1]) if last + 1 < len(times) else math.nan


def obstacles_at(schedule, t):
    """Return the obstacle rows in force at time t from a [(time, rows)] schedule."""
    rows = ()
    for start, value in schedule:
        if start <= t:
            rows = value
        else:
            break
    return rows


def executed_clearance(model, times, positions, schedule):
    """
    Return (per-sample min clearance [m], per-obstacle-set-row min) to the true obstacles.

    Each joint_states sample is checked, every link, against the obstacle rows (x, y, R'
    without margin) in force at its time; samples without obstacles give +inf.
    """
    gaps = scheduled_clearance(model, times, positions, schedule)
    return np.min(np.where(np.isnan(gaps), np.inf, gaps), axis=1, initial=np.inf)


def execution_metrics(model, goal_q, plans: Sequence[PlanSpan], times, positions,
                      schedule: Sequence[Tuple[float, tuple]] = (), latencies=(),
                      kept=0):
    """
    Return a dict of the numbers of one execution.

    plans: every plan for this goal in publication order (the first one gives the planned
    t_min and the start time t0); times (M,) / positions (M, n): the joint_states from t0 on;
    schedule: the true obstacle sets over time; latencies: replan cycle latencies [s].
    """
    times = np.asarray(times, dtype=float)
    positions = np.asarray(positions, dtype=float)
    t0 = plans[0].stamp
    keep = times >= t0 - 1e-9
    times, positions = times[keep], positions[keep]
    goal_q = np.asarray(goal_q, dtype=float)
    arrival = arrival_time(times, positions, goal_q) if times.size else math.nan
    end = plans[-1].end + FINAL_ERROR_DELAY_S
    final_error = math.nan
    if times.size and times[-1] >= end - 1e-9:
        k = int(np.searchsorted(times, end))
        final_error = float(np.max(np.abs(positions[min(k, len(times) - 1)] - goal_q)))
    clearance = executed_clearance(model, times, positions, schedule)
    return dict({
        'planned_t_min': plans[0].duration,
        'plans': len(plans),
        'replans_kept': int(kept),
        'arrival_s': arrival - t0 if math.isfinite(arrival) else math.nan,
        'last_plan_end_s': plans[-1].end - t0,
        'final_error': final_error,
        'min_clearance': float(np.min(clearance)) if clearance.size else math.nan,
    }, **latency_stats(latencies))


def latency_stats(latencies):
    """Return the median, p99 and max [s] and the count of replan cycle latencies [s]."""
    latencies = np.asarray(latencies, dtype=float)
    return {'latency_median_s': _percentile(latencies, 50),
            'latency_p99_s': _percentile(latencies, 99),
            'latency_max_s': float(np.max(latencies)) if latencies.size else math.nan,
            'latencies': int(latencies.size)}


def _percentile(values, q) -> Optional[float]:
    return float(np.percentile(values, q)) if len(values) else math.nan
