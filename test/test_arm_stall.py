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

"""When the cheap curvature model counts as stalled (cold_runs._stall_watch)."""

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from toc_ros.core.arms import cold_runs  # noqa: E402
from toc_ros.core.arms.cold_runs import (STALL_ALPHA, STALL_MU, STALL_STEPS,  # noqa: E402
                                         STALL_WINDOW)


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
