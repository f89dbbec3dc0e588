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
The progress of a planner node's running solve and its heartbeat, without ROS.

The core reports a solve's progress every 0.1 s; set-up and slow iterations leave gaps.  A
``SolveProgress`` keeps the running solve's latest progress and the time of the last report
sent, and tells the node's heartbeat when a report is due so that no gap exceeds
MAX_PROGRESS_GAP_S (the elapsed time then counts from the solve's start).
"""

import dataclasses
import threading
import time

MAX_PROGRESS_GAP_S = 0.15


class SolveProgress:
    """The running solve's latest progress (thread-safe) and when a report went out."""

    def __init__(self, max_gap=MAX_PROGRESS_GAP_S, clock=time.monotonic):
        self.max_gap = max_gap
        self._clock = clock
        self._lock = threading.Lock()
        self._current = None        # (Progress, solve start) of the running solve
        self._sent = 0.0

    def start(self, progress):
        """Record the start of a solve with its first progress; return that progress."""
        with self._lock:
            self._current = (progress, self._clock())
        return progress

    def update(self, progress):
        """Record a progress of the core; return it when it is to be reported, else None."""
        if progress.phase == 'done':   # the result message follows
            return None
        with self._lock:
            if self._current is None:
                return None
            self._current = (progress, self._current[1])
        return progress

    def end(self):
        """Record that no solve runs."""
        with self._lock:
            self._current = None

    def sent(self):
        """Record that a report went out now."""
        self._sent = self._clock()

    def due(self):
        """Return the latest progress (elapsed since the solve's start) when a gap is due."""
        with self._lock:
            current = self._current
        now = self._clock()
        if current is None or now - self._sent < self.max_gap:
            return None
        progress, started = current
        return dataclasses.replace(progress, elapsed_s=now - started)
