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
The class attempts of one cold solve with the climbs of their candidates started early.

Used by fast_solver.FastSolve._class_attempts: the attempts run on the worker threads
(workers.py), and a converged attempt that is a candidate among those converged so far starts
its climb up the ladder, ahead of the attempts still waiting; the best climbed one its
refinement to N.  The values are the ones the strategy would get after all attempts.
"""

import threading

from . import ipm, workers
from .ip_run import Cancelled


class Prefetch:
    """
    The class attempts of one FastSolve, with the climbs of their candidates started early.

    The calling thread and the workers.share helpers each take the next task when theirs ends
    (no hand-over through a waiting thread: a wake-up cost milliseconds on a loaded machine):
    first the climb of an attempt that is a candidate among the converged ones so far, then
    the refinement to N (refine) of the shortest climbed one so far, else the next attempt.  A
    task that later results put out (a shorter attempt, a shorter climb) is cancelled.
    """

    def __init__(self, solver, tasks, climb, refine, usable=None):
        self.solver = solver
        self.tasks = tasks
        self.climb = climb
        self.refine = refine
        # usable(run): whether a candidate can stand (a relaxation's: clear of the other
        # circles); while one cannot, _finish will not run (_lazy_classes): no climbs.
        self.usable = usable or (lambda run: True)
        self.verdicts = {}                       # id(attempt run) -> usable(run)
        self.finals = {}                         # id(climbed run) -> [runs, value, wanted]
        self.logs = [[] for _ in tasks]          # runs of the attempts, in task order
        self.all_logs = list(self.logs)          # and of the climbs (progress reports)
        self.results = {}                        # attempt index -> (run, code)
        self.climbs = {}                         # attempt index -> [runs, value or None, wanted]
        self.waiting = list(range(len(tasks)))   # attempts not started
        self.busy = 0                            # tasks running
        self.failure = None
        self.cond = threading.Condition()
        self.poll = solver._poller(self.all_logs)
        self.caller = threading.current_thread()       # reports progress

    def run(self):
        """
        Return (converged attempt runs in task order, prefetched).

        prefetched: {'climbs': {id(attempt run): (climb value, runs)}, 'finals': {id(climbed
        run): (refinement value, runs)}} for the final candidates and the best climbed one.
        """
        solver = self.solver
        try:
            workers.share(self._work)
        finally:
            logs = self.logs
            if self.failure is not None:    # stopped: keep the wanted runs for best-so-far
                logs = logs + [c[0] for c in self.climbs.values() if c[2]] + \
                    [f[0] for f in self.finals.values() if f[2]]
            for run in (run for log in logs for run in log):
                solver._record(run)
                solver.run = run
        if self.failure is not None:
            raise self.failure
        found = [self.results[k][0] for k in sorted(self.results)
                 if self.results[k][1] == ipm.CONVERGED]
        wanted = {id(run) for run in self._candidates()}
        climbs = {id(self.results[k][0]): (c[1], c[0]) for k, c in self.climbs.items()
                  if c[1] is not None and id(self.results[k][0]) in wanted}
        best = self._best_climbed()
        finals = {key: (f[1], f[0]) for key, f in self.finals.items()
                  if f[1] is not None and best is not None and key == id(best)}
        return found, {'climbs': climbs, 'finals': finals}

    def _work(self):
        """Run tasks until none is left and none can come (a thread's loop)."""
        caller = threading.current_thread() is self.caller
        while True:
            with self.cond:
                job = self._next()
                while job is None and self.busy and self.failure is None:
                    self.cond.wait(workers.POLL)
                    if caller:
                        self.poll()
                    job = self._next()
                if job is None:
                    return
                self.busy += 1
            key, task = job
            value, error = None, None
            try:
                value = task()
            except Cancelled:
                key = None
            except BaseException as exc:        # Stop, or a bug: raised by run()
                error = exc
            with self.cond:
                self.busy -= 1
                if error is not None:
                    self.failure = self.failure or error
                elif key is not None:
                    self._finished(key, value)
                self.cond.notify_all()

    def _candidates(self):
        """_finish's candidates among the attempts converged so far."""
        return self.solver._candidates([self.results[k][0] for k in sorted(self.results)
                                        if self.results[k][1] == ipm.CONVERGED])

    def _next(self):
        """Return the next (key, task): a candidate's climb before an attempt; None if none."""
        if self.failure is not None:
            return None
        index = {id(self.results[k][0]): k for k in self.results}
        candidates = self._candidates()
        usable = all(self._usable(run) for run in candidates)
        for run in candidates if usable else []:
            k = index[id(run)]
            if k not in self.climbs:
                log = []
                self.all_logs.append(log)
                self.climbs[k] = [log, None, True]
                return ('climb', k), self.solver._bind(
                    lambda solve, run=run: self.climb(solve, run), log, self.poll,
                    cancelled=lambda c=self.climbs[k]: not c[2], caller=self.caller)
        best = self._best_climbed() if usable else None
        if best is not None and id(best) not in self.finals:
            log = []
            self.all_logs.append(log)
            self.finals[id(best)] = [log, None, True]
            return ('final', id(best)), self.solver._bind(
                lambda solve: self.refine(solve, best), log, self.poll,
                cancelled=lambda f=self.finals[id(best)]: not f[2], caller=self.caller)
        if self.waiting:
            k = self.waiting.pop(0)
            return ('attempt', k), self.solver._bind(self.tasks[k], self.logs[k], self.poll,
                                                     caller=self.caller)
        return None

    def _usable(self, run):
        if id(run) not in self.verdicts:
            self.verdicts[id(run)] = self.usable(run)
        return self.verdicts[id(run)]

    def _best_climbed(self):
        """Return the shortest converged climb of a candidate so far (None if none)."""
        climbs = [self.climbs.get(self._index(run)) for run in self._candidates()]
        ranked = [c[1][0] for c in climbs
                  if c is not None and c[1] is not None and c[1][1] == ipm.CONVERGED]
        return min(ranked, key=lambda r: r.t_f) if ranked else None

    def _index(self, run):
        return next(k for k in self.results if self.results[k][0] is run)

    def _finished(self, key, value):
        kind, k = key
        if kind == 'final':
            self.finals[k][1] = value
            return
        if kind == 'climb':
            self.climbs[k][1] = value
        else:
            self.results[k] = value
        # A later, shorter attempt may put earlier candidates out, a later climb the best one:
        # cancel their climbs and refinements.
        wanted = {id(run) for run in self._candidates()}
        for j, climb in self.climbs.items():
            if id(self.results[j][0]) not in wanted:
                climb[2] = False
        best = self._best_climbed()
        for key, final in self.finals.items():
            if best is None or key != id(best):
                final[2] = False
