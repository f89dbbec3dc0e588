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
How FastSolve's interior-point runs are executed, recorded and reported.

A mixin of fast_solver.FastSolve (it uses the solve's problem, clock, limit, done, history and
run).  A run executes on the calling thread (_solve_on) or, side by side, on the worker threads
(_parallel, _bind; workers.py).  Either way its iterations are counted and its history recorded
on the calling thread, in task order, so the result does not depend on the threads' timing;
progress is reported from the calling thread between iteration chunks.
"""

import math
import threading

import numpy as np

from . import ipm, workers
from .ip_run import BOUND_PUSH, Cancelled, InteriorPointRun, Stop
from .ipm_workspace import F_THETA
from .result import Status


class RunExecution:
    """Execution and bookkeeping of the interior-point runs of FastSolve (a mixin)."""

    def _check(self, run):
        reason = self.clock.stop_reason()
        if reason is not None:
            raise Stop(reason)
        from .result import Progress
        fs = run.ws.fscal
        self.clock.report(lambda: Progress(
            self.offset + self.done + run.iterations, run.t_f, run.t_f, math.nan,
            self.clock.elapsed(),
            f'fast N={run.n}', None, float(fs[F_THETA])))

    def _solve_on(self, n, states, controls, t_f, mu, duals=None, budget=None,
                  push=BOUND_PUSH, elastic=None, relaxed=None):
        left = max(1, self.limit - self.done)
        problem, kept = relaxed or (self.problem, None)
        run = InteriorPointRun(problem, n, left if budget is None else min(budget, left),
                               elastic, kept)
        run.start(states, controls, t_f, mu, duals, push)
        self.run = run
        try:
            code = run.run(self._check, lambda: self.clock.stop_reason() is not None)
        finally:
            self._record(run)
        if code == ipm.STOPPED:
            raise Stop(self.clock.stop_reason() or Status.CANCELED)
        return run, code

    def _record(self, run):
        rows = run.history()
        if rows.shape[0]:
            first = sum(block.shape[0] for block in self.history)
            self.history.append(np.column_stack([np.arange(first, first + rows.shape[0]),
                                                 rows[:, 0], rows[:, 0], rows[:, 1]]))
        self.done += run.iterations

    def _parallel(self, tasks, done=None):
        """
        Run tasks (callables solve -> value) on the worker threads; return their values.

        solve(n, states, controls, t_f, mu, duals, budget, elastic[, relaxed]) is a worker's
        _solve_on:
        it neither records its run nor reports progress (this thread does, meanwhile and, in
        task order, afterwards), and only the fixed budget caps it, so a task's result does not
        depend on the others' timing (workers.py).  done: {index: (value, runs)} of tasks
        already run (_class_attempts); their runs are recorded in their place.
        """
        done = done or {}
        logs = [list(done[k][1]) if k in done else [] for k in range(len(tasks))]
        todo = [k for k in range(len(tasks)) if k not in done]
        poll = self._poller(logs)
        values = {k: value for k, (value, _) in done.items()}
        try:
            out = workers.run_tasks([self._bind(tasks[k], logs[k], poll) for k in todo], poll)
            values.update(zip(todo, out))
            return [values[k] for k in range(len(tasks))]
        finally:
            for run in (run for log in logs for run in log):
                self._record(run)
                self.run = run

    def _bind(self, task, log, poll, cancelled=None, caller=None):
        """
        Return a worker's callable: task(solve), its runs appended to log.

        poll() runs between iteration chunks when this is the caller's thread (default: the
        current one).  cancelled(): a prefetch no longer wanted; its kernel stops within one
        phase and Cancelled is raised.
        """
        caller = caller or threading.current_thread()

        def stop_requested():
            return self.clock.stop_reason() is not None or (cancelled is not None and
                                                            cancelled())

        def check(run):
            if cancelled is not None and cancelled():
                raise Cancelled()
            reason = self.clock.stop_reason()
            if reason is not None:
                raise Stop(reason)
            if threading.current_thread() is caller:
                poll()

        def solve(n, states, controls, t_f, mu, duals, budget, elastic, relaxed=None):
            problem, kept = relaxed or (self.problem, None)
            run = InteriorPointRun(problem, n, budget, elastic, kept)
            run.start(states, controls, t_f, mu, duals)
            log.append(run)
            code = run.run(check, stop_requested)
            if code == ipm.STOPPED:
                if cancelled is not None and cancelled():
                    raise Cancelled()
                raise Stop(self.clock.stop_reason() or Status.CANCELED)
            return run, code
        return lambda: task(solve)

    def _poller(self, logs):
        """Return poll(): a progress report on the newest run of logs (lists of runs)."""
        def poll():
            runs = [run for log in logs for run in log]
            if runs:
                from .result import Progress
                its = self.offset + self.done + sum(run.iterations for run in runs)
                self.clock.report(lambda: Progress(
                    its, runs[-1].t_f, runs[-1].t_f, math.nan, self.clock.elapsed(),
                    f'fast N={runs[-1].n}', None, float(runs[-1].ws.fscal[F_THETA])))
        return poll

    def _history(self):
        return np.concatenate(self.history) if self.history else np.zeros((0, 4))
