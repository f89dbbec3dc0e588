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
The "newest goal wins" worker of solver_node, free of ROS: one thread solves one request at once.

A new goal preempts the running solve (its cancel event is set) and replaces a queued one (which
is reported as superseded, never solved).  Replan cycles are offered, not submitted: the worker
takes one only when no goal is queued or solving, so goals always go first.  A request whose
planning data changed during its solve is restarted (solved again with the latest data) unless
a newer request is queued.  Requests that arrive before the solver is ready (``ready`` unset)
are queued and solved once it is.  After a burst of goals the worker waits until the burst is
quiet, so that only the newest goal of the burst is solved.
"""

import math
import threading
import time

# How long cancel() waits for the running solve to stop (the core stops within ~0.1 s).
CANCEL_WAIT_S = 2.0
# Before a solve starts, the worker waits until no goal arrived for QUIET_S (at most
# SETTLE_MAX_S): after a burst the executor takes the newer goals first, so only the newest
# is solved.  A goal with no other goal within QUIET_S before it waits only QUIET_FIRST_S (the
# goals of a burst follow each other within a fraction of a millisecond; a goal arriving in
# that window turns the wait into the burst's QUIET_S), so a single goal starts at once.
QUIET_S = 0.05
QUIET_FIRST_S = 0.005
SETTLE_MAX_S = 0.5


class Request:
    """One goal on its way through the worker (a restart keeps the same request)."""

    def __init__(self, goal, source, cycle=None):
        self.goal = goal
        self.source = source
        self.stop_reason = None          # set when preempted or canceled
        self.restart_reason = None       # set when the planning data changed during the solve
        self.event = ''                  # schema event of its result (e.g. a replacement)
        self.result = None               # the solve's result once solved (None when dropped)
        self.cycle = cycle               # a replan cycle's data, None for goals
        self.generation = 0              # the goal generation it belongs to (set by submit)
        self.published_at = None         # time.monotonic() when its trajectory was published
        self.published_stamp = None      # the node clock then [s]
        self.late = False                # a cycle's plan was ready only after its deadline
        #                                  (a goal's: after the stamp of its start on a plan)
        self.lead_scale = 1.0            # a goal's goal_lead factor (doubled when late)
        self.path = None                 # what the node answers a plan request with
        self.done = threading.Event()
        self._lock = threading.Lock()
        self._callbacks = []

    def on_done(self, callback):
        """Call callback() once the request is done (at once if it is)."""
        with self._lock:
            if not self.done.is_set():
                self._callbacks.append(callback)
                return
        callback()

    def finish(self):
        """Mark the request done and run the on_done callbacks."""
        with self._lock:
            self.done.set()
            callbacks, self._callbacks = self._callbacks, []
        for callback in callbacks:
            callback()


class GoalWorker:
    """
    A thread solving one request at a time; the newest request preempts older ones.

    run(request, cancel_event) solves and publishes; drop(request, reason, event) reports a
    request that is never solved (event None: the default, superseded); ready is a
    threading.Event (the solver can run); on_error(text) reports an exception of run.
    """

    def __init__(self, run, drop, ready, on_error, clock=time.monotonic):
        self._run = run
        self._drop = drop
        self._ready = ready
        self._on_error = on_error
        self._clock = clock
        self._cond = threading.Condition()
        self._pending = None
        self._active = None
        self._cancel = None
        self._stopping = False
        self._generation = 0     # counts goal cancels: requests of older generations are void
        self._last_submit = -math.inf
        self._gap = math.inf     # [s] between the last two submits
        self._thread = threading.Thread(target=self._loop, name='solver', daemon=True)
        self._thread.start()

    @property
    def generation(self):
        """Return how many goal cancels there were: the current goal generation."""
        with self._cond:
            return self._generation

    def submit(self, request):
        """Queue request, dropping a queued one and canceling the running one."""
        with self._cond:
            request.generation = self._generation
            dropped, self._pending = self._pending, request
            now = self._clock()
            self._gap, self._last_submit = now - self._last_submit, now
            if self._active is not None:
                self._active.stop_reason = 'preempted by a newer goal'
                self._cancel.set()
            self._cond.notify_all()
        if dropped is not None:
            self._drop(dropped, 'superseded by a newer goal before its solve started', None)

    def offer(self, request, behind_cycle=False):
        """
        Queue a replan cycle when idle (goals go first); True when taken.

        behind_cycle: also queue it behind a running cycle (new data cannot wait for the
        next regular cycle).
        """
        with self._cond:
            active = self._active
            waits = active is not None and active.cycle is not None and (
                behind_cycle or self._cancel.is_set())
            pending_goal = self._pending is not None and self._pending.cycle is None
            if (active is not None and not waits) or pending_goal or self._stopping:
                return False
            request.generation = self._generation
            self._pending = request      # a newer cycle replaces a queued one
            self._cond.notify_all()
        return True

    def restart(self, reason):
        """Stop the running solve and solve its goal again (unless a newer goal is queued)."""
        with self._cond:
            active = self._active
            # A replan cycle runs on: its plan is checked against the data current when it
            # ends (obstacles may change faster than a cycle solves).
            if active is not None and active.stop_reason is None and active.cycle is None:
                active.restart_reason = reason
                self._cancel.set()
                return True
        return False

    def cancel(self, reason):
        """
        Stop the running solve and drop a queued one; True when a solve was stopped.

        reason: why, as the reports say it (e.g. 'canceled by the user').
        """
        return self._stop_current(reason, new_generation=False)[0]

    def cancel_goal(self, reason):
        """
        Abandon the goal: cancel() and start a new goal generation (True: a solve was stopped).

        Requests of older generations are void (current() tells): a cycle that solved just
        before the cancel must not publish.  Returns (stopped, dropped): whether a running
        solve was stopped, and whether a queued request was dropped.
        """
        return self._stop_current(reason, new_generation=True)

    def current(self, request):
        """Tell whether request belongs to the current goal generation (not canceled)."""
        with self._cond:
            return request.generation == self._generation

    def _stop_current(self, reason, new_generation):
        with self._cond:
            if new_generation:
                self._generation += 1
            dropped, self._pending = self._pending, None
            active = self._active
            if active is not None:
                active.stop_reason = reason
                active.restart_reason = None
                self._cancel.set()
        if dropped is not None:
            self._drop(dropped, f'{reason} before its solve started', '')
        stopped = active is not None and active.done.wait(CANCEL_WAIT_S)
        return stopped, dropped is not None

    def busy(self):
        """Tell whether a request is queued or solving."""
        with self._cond:
            return self._active is not None or self._pending is not None

    def goal_busy(self):
        """Tell whether a goal (not a replan cycle) is queued or solving."""
        with self._cond:
            return any(r is not None and r.cycle is None for r in (self._active, self._pending))

    def stop(self):
        """Cancel everything and end the thread."""
        with self._cond:
            self._stopping = True
            if self._cancel is not None:
                self._cancel.set()
            dropped, self._pending = self._pending, None
            self._cond.notify_all()
        if dropped is not None:
            dropped.finish()
        self._thread.join(timeout=CANCEL_WAIT_S)

    def _next(self):
        """Wait for readiness and a request, let a burst settle; None when stopping."""
        while not self._ready.wait(0.1):
            with self._cond:
                if self._stopping:
                    return None
        with self._cond:
            while self._pending is None and not self._stopping:
                self._cond.wait()
            settle_end = self._clock() + SETTLE_MAX_S
            while (not self._stopping and self._pending is not None
                   and self._pending.cycle is None):
                wait_s = QUIET_S if self._gap < QUIET_S else QUIET_FIRST_S
                quiet = self._last_submit + wait_s - self._clock()
                if quiet <= 0.0 or self._clock() >= settle_end:
                    break
                self._cond.wait(min(quiet, settle_end - self._clock()))
            if self._stopping or self._pending is None:
                return None
            request, self._pending = self._pending, None
            self._active, self._cancel = request, threading.Event()
            return request, self._cancel

    def _loop(self):
        while True:
            taken = self._next()
            if taken is None:
                with self._cond:
                    if self._stopping:
                        return
                continue
            request, cancel = taken
            try:
                self._run(request, cancel)
            except Exception as exc:  # noqa: B902 - a bug must not end the worker thread
                self._on_error(f'solve of goal from {request.source} failed: {exc!r}')
                request.restart_reason = None
            with self._cond:
                self._active = None
                again = (request.restart_reason is not None and self._pending is None
                         and not self._stopping)
                if again:
                    self._pending = request
                superseded = request.restart_reason is not None and not again
                request.restart_reason = None
            if superseded:
                self._drop(request, 'superseded by a newer goal while restarting', None)
            elif not again:
                request.finish()
