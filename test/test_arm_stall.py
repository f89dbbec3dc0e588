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

"""When a cold search run stalls (cold_runs._stall_watch) or is abandoned (_abandon_above)."""

import os
import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from toc_ros.core.arms import cold_runs  # noqa: E402
from toc_ros.core.arms.cold_runs import (ABANDON_GAP, DUPLICATE_PATH,  # noqa: E402
                                         REPEAT_PATH, REPEAT_TIME, SETTLED_PRIMAL,
                                         STALL_ALPHA, STALL_MU, STALL_STEPS, STALL_WINDOW)


class FakeRun:
    """The attributes of ArmInteriorPoint the watch reads."""

    def __init__(self, mu, mu_min=1e-9):
        self.mu, self.mu_min = mu, mu_min
        self.last_alpha, self.e0, self.primal = None, 1.0, 1.0

    def at_last_barrier(self):
        return self.mu <= 1.5 * self.mu_min


def _calls_until_stalled(run, update, limit=100):
    """Call the watch as run() does, once per iteration; the call that fired (or None)."""
    watch = cold_runs._stall_watch(run, lambda: False)
    for call in range(1, limit + 1):
        update(run, call)
        if watch():
            assert watch.stalled
            return call
    return None


def _rate(rate):
    def update(run, call):
        run.last_alpha = 1.0
        run.e0 = run.primal = rate ** call
    return update


def test_full_steps_at_a_linear_rate_near_the_end_are_a_stall():
    # 0.97 per iteration (a refining run measured): the error does not halve in the window.
    assert _calls_until_stalled(FakeRun(1e-7), _rate(0.97)) == STALL_WINDOW + 1


def test_steps_that_halve_the_error_within_the_window_are_progress():
    assert _calls_until_stalled(FakeRun(1e-7), _rate(0.5 ** (1.0 / (STALL_WINDOW - 1)))) \
        is None


def test_slow_progress_early_in_a_run_is_not_a_stall():
    # Above STALL_MU the run is still far from the optimum: slow steps are expected there.
    assert _calls_until_stalled(FakeRun(10.0 * STALL_MU), _rate(0.97)) is None


def test_the_window_restarts_when_the_barrier_parameter_falls():
    def update(run, call):
        run.last_alpha = 1.0
        run.e0 = 0.97 ** call
        if call == STALL_WINDOW:
            run.mu = 1e-9         # a new barrier problem: its own progress is measured
    assert _calls_until_stalled(FakeRun(1e-6), update) == 2 * STALL_WINDOW


def test_short_steps_in_a_row_at_the_last_barrier_parameter_are_a_stall():
    def update(run, call):
        run.last_alpha = 0.5 * STALL_ALPHA
        run.e0 = run.primal = 0.5 ** call    # (progress: only the step lengths stall)
    assert _calls_until_stalled(FakeRun(1e-9), update) == STALL_STEPS
    # ... not above it, where the fraction to the boundary cuts steps as mu falls.
    assert _calls_until_stalled(FakeRun(1e-6), update) is None


def test_a_stop_request_is_not_a_stall():
    run = FakeRun(1e-7)
    watch = cold_runs._stall_watch(run, lambda: True)
    assert watch() and not watch.stalled


class FakeBest:
    """A converged run: its final time and states (N + 1 nodes, n = 2 joints)."""

    def __init__(self, t, x):
        self.t, self.x = t, x


# A run's states for the abandon watch: 11 nodes of n = 2 joints (positions, then velocities).
STATES = np.linspace(0.0, 1.0, 11)[:, None] * np.array([1.0, -0.5, 0.0, 0.0])
PATH = STATES[:, :2]


def _abandon(t, shift, mu=1e-4 ** 1.5, primal=0.1 * SETTLED_PRIMAL, t_best=1.0):
    """Return (fired, duplicate) for a run at t whose path is the best's shifted by shift."""
    x = STATES
    run = FakeRun(mu)
    run.n, run.t, run.primal = 2, t, primal
    run.x = x.copy()
    run.x[5, 1] += shift                      # one node of one joint, the velocities alike
    watch = cold_runs._abandon_above(run, FakeBest(t_best, x), lambda: False)
    return watch(), watch.duplicate


def test_a_start_settled_above_the_best_is_abandoned():
    # mu = 1e-4 ** 1.5 (the first decrease) rounds to 1.0000000000000002e-06: settled.
    assert _abandon(1.0 + 2.0 * ABANDON_GAP, shift=1.0) == (True, False)


def test_a_start_settled_on_the_best_way_around_is_abandoned_as_a_duplicate():
    assert _abandon(1.0 + 0.5 * ABANDON_GAP, shift=0.5 * DUPLICATE_PATH) == (True, True)
    assert _abandon(1.0, shift=0.0) == (True, True)


def test_a_start_that_may_still_do_better_is_kept():
    # Another way around (its path far from the best's), just above the best's time.
    assert _abandon(1.0 + 0.5 * ABANDON_GAP, shift=2.0 * DUPLICATE_PATH) == (False, False)
    # Below the best's time, even on its path.
    assert _abandon(1.0 - 1e-6, shift=0.0) == (False, False)
    # Not settled yet: the barrier parameter or the violation still large.
    assert _abandon(1.0 + 2.0 * ABANDON_GAP, shift=0.0, mu=1e-4) == (False, False)
    assert _abandon(1.0 + 2.0 * ABANDON_GAP, shift=0.0, primal=10 * SETTLED_PRIMAL) == \
        (False, False)


def _first_barrier_problem(ends, t=1.0, shift=0.0):
    """Run the watch as run() calls it: mu 1e-4 twice, then 1e-6; return (calls, watch)."""
    run = FakeRun(1e-4)
    run.n, run.t, run.primal = 2, t, 1.0
    run.x = STATES.copy()
    run.x[5, 1] += shift
    watch = cold_runs._abandon_above(run, None, lambda: False, ends)
    calls = []
    for mu in (1e-4, 1e-4, 1e-6, 1e-6):
        run.mu = mu
        calls.append(watch())
    return calls, watch


def test_a_start_that_repeats_an_ended_run_is_abandoned_after_its_first_barrier_problem():
    ends = [(2.0, PATH + 1.0), (1.0 + 0.5 * REPEAT_TIME, PATH)]
    calls, watch = _first_barrier_problem(ends, shift=0.5 * REPEAT_PATH)
    # Not while its first barrier problem is solved; at the first call after mu fell.
    assert calls == [False, False, True, True]
    assert watch.fired and watch.repeat and not watch.duplicate
    assert watch.first[0] == 1.0 and watch.first[1].shape == (11, 2)


def test_a_start_off_every_ended_run_is_kept_and_its_first_point_recorded():
    for ends, t, shift in ((((1.0, PATH),), 1.0, 2.0 * REPEAT_PATH),
                           (((1.0, PATH),), 1.0 + 2.0 * REPEAT_TIME, 0.0),
                           ((), 1.0, 0.0)):
        calls, watch = _first_barrier_problem(ends, t=t, shift=shift)
        assert calls == [False] * 4 and not watch.repeat
        assert watch.first[0] == t
        assert np.abs(watch.first[1] - PATH).max() == pytest.approx(shift)
