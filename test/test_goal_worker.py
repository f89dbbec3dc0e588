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

"""The goal worker's "newest goal wins" semantics, without ROS: a fake solve per request."""

import threading
import time

import pytest
from toc_ros.goal_worker import GoalWorker, Request, SETTLE_MAX_S

WAIT_S = 5.0


class Solver:
    """A fake solve: runs until canceled (or released), records what happened."""

    def __init__(self, ready=True):
        self.ready = threading.Event()
        if ready:
            self.ready.set()
        self.runs = []             # requests in the order their solves started
        self.dropped = []          # (request, reason, event)
        self.errors = []
        self.started = threading.Semaphore(0)
        self.release = threading.Event()
        self.on_run = None         # optional hook(request, cancel) inside the solve
        self.worker = GoalWorker(self.run, self.drop, self.ready, self.errors.append)

    def run(self, request, cancel):
        self.runs.append(request)
        self.started.release()
        if self.on_run is not None:
            self.on_run(request, cancel)
        while not cancel.is_set() and not self.release.is_set():
            time.sleep(0.001)
        request.result = 'canceled' if cancel.is_set() else 'solved'

    def drop(self, request, reason, event):
        self.dropped.append((request, reason, event))
        request.finish()

    def wait_started(self, count=1):
        for _ in range(count):
            assert self.started.acquire(timeout=WAIT_S), 'no solve started'


@pytest.fixture
def solver():
    s = Solver()
    yield s
    s.worker.stop()


def goal(name, cycle=None):
    return Request([0.0], name, cycle=cycle)


def test_a_single_goal_is_solved_at_once(solver):
    a = goal('a')
    started = time.monotonic()
    solver.worker.submit(a)
    solver.wait_started()
    assert time.monotonic() - started < 0.5
    assert solver.worker.busy() and solver.worker.goal_busy()
    solver.release.set()
    assert a.done.wait(WAIT_S) and a.result == 'solved' and a.stop_reason is None
    assert not solver.dropped


def test_a_newer_goal_preempts_the_running_one_and_replaces_a_queued_one(solver):
    a, b, c = goal('a'), goal('b'), goal('c')
    solver.worker.submit(a)
    solver.wait_started()
    solver.worker.submit(b)        # preempts a; queued
    solver.worker.submit(c)        # replaces b before its solve started
    solver.wait_started()
    assert [r.source for r in solver.runs] == ['a', 'c']
    assert a.stop_reason == 'preempted by a newer goal' and a.result == 'canceled'
    assert [(r.source, reason, event) for r, reason, event in solver.dropped] == [
        ('b', 'superseded by a newer goal before its solve started', None)]
    assert b.done.is_set() and b.result is None
    solver.release.set()
    assert c.done.wait(WAIT_S) and c.result == 'solved'


def test_a_burst_is_settled_and_only_its_newest_goal_solved():
    solver = Solver(ready=False)
    try:
        burst = [goal(f'g{k}') for k in range(20)]
        for request in burst:
            solver.worker.submit(request)
        solver.ready.set()
        solver.wait_started()
        solver.release.set()
        assert burst[-1].done.wait(WAIT_S)
        assert [r.source for r in solver.runs] == ['g19']
        assert [r.source for r, _, _ in solver.dropped] == [f'g{k}' for k in range(19)]
    finally:
        solver.worker.stop()


def test_goals_are_queued_until_ready():
    solver = Solver(ready=False)
    try:
        a = goal('a')
        solver.worker.submit(a)
        assert not solver.started.acquire(timeout=0.3)      # not ready: not started
        assert solver.worker.busy() and not a.done.is_set()
        solver.ready.set()
        solver.wait_started()
        solver.release.set()
        assert a.done.wait(WAIT_S) and a.result == 'solved'
    finally:
        solver.worker.stop()


def test_cancel_stops_the_solve_and_drops_the_queued_goal(solver):
    assert solver.worker.cancel('canceled by the user') is False      # idle
    a = goal('a')
    solver.worker.submit(a)
    solver.wait_started()
    assert solver.worker.cancel('canceled by the user') is True
    assert a.done.is_set() and a.result == 'canceled'
    assert a.stop_reason == 'canceled by the user'
    assert not solver.worker.busy()
    # A new goal after a cancel is solved as usual.
    b = goal('b')
    solver.worker.submit(b)
    solver.wait_started()
    solver.release.set()
    assert b.done.wait(WAIT_S) and b.result == 'solved'


def test_cancel_of_a_goal_not_yet_started_reports_it_with_the_reason():
    solver = Solver(ready=False)
    try:
        a = goal('a')
        solver.worker.submit(a)
        assert solver.worker.cancel('canceled by the user') is False    # none was running
        assert solver.dropped == [(a, 'canceled by the user before its solve started', '')]
        assert a.done.is_set() and not solver.worker.busy()
    finally:
        solver.worker.stop()


def test_cancel_goal_voids_the_requests_of_the_goal(solver):
    a = goal('a')
    solver.worker.submit(a)
    solver.wait_started()
    assert solver.worker.current(a)
    stopped, dropped = solver.worker.cancel_goal('goal canceled')
    assert stopped and not dropped and a.result == 'canceled'
    assert not solver.worker.current(a)           # a plan it solved must not be published
    cycle = goal('cycle', cycle=object())
    assert solver.worker.offer(cycle)             # a new generation: current again
    assert solver.worker.current(cycle)
    solver.wait_started()
    assert solver.worker.cancel_goal('goal canceled') == (True, False)
    assert not solver.worker.current(cycle)
    assert solver.worker.cancel_goal('goal canceled') == (False, False)    # nothing left


def test_a_restart_solves_the_same_goal_again_unless_a_newer_one_came(solver):
    a = goal('a')
    solver.worker.submit(a)
    solver.wait_started()
    assert solver.worker.restart('data changed')
    solver.wait_started()                          # the same request once more
    assert solver.runs == [a, a] and not a.done.is_set()
    solver.release.set()
    assert a.done.wait(WAIT_S) and a.result == 'solved'
    assert not solver.dropped
    # Restart while a newer goal waits: the old one is reported superseded, never rerun.
    solver.release.clear()
    b, c = goal('b'), goal('c')

    def newer_goal_arrives(request, cancel):
        if request is b:
            solver.worker.restart('data changed')
            solver.worker.submit(c)
    solver.on_run = newer_goal_arrives
    solver.worker.submit(b)
    solver.wait_started(2)
    solver.release.set()
    assert c.done.wait(WAIT_S)
    assert solver.runs[-2:] == [b, c]
    assert solver.dropped == [(b, 'superseded by a newer goal while restarting', None)]
    assert b.stop_reason == 'preempted by a newer goal' and b.done.is_set()


def test_a_restart_never_stops_a_replan_cycle(solver):
    cycle = goal('cycle', cycle=object())
    assert solver.worker.offer(cycle)
    solver.wait_started()
    assert not solver.worker.restart('data changed')
    assert not solver.worker.goal_busy() and solver.worker.busy()
    solver.release.set()
    assert cycle.done.wait(WAIT_S) and solver.runs == [cycle]


def test_cycles_go_after_goals(solver):
    a = goal('a')
    solver.worker.submit(a)
    solver.wait_started()
    assert not solver.worker.offer(goal('cycle', cycle=object()))          # a goal solves
    assert not solver.worker.offer(goal('cycle', cycle=object()), True)
    solver.release.set()
    assert a.done.wait(WAIT_S)
    solver.release.clear()
    first = goal('c1', cycle=object())
    assert solver.worker.offer(first)
    solver.wait_started()
    assert not solver.worker.offer(goal('c2', cycle=object()))      # the next regular one waits
    urgent = goal('c3', cycle=object())
    assert solver.worker.offer(urgent, behind_cycle=True)           # new data: queued behind
    newer = goal('c4', cycle=object())
    assert solver.worker.offer(newer, behind_cycle=True)            # replaces c3
    g = goal('g')
    solver.worker.submit(g)                 # a goal preempts the cycle and replaces c4
    solver.wait_started()
    assert solver.runs == [a, first, g]
    assert first.stop_reason == 'preempted by a newer goal'
    assert [r.source for r, _, _ in solver.dropped] == ['c4']
    assert not urgent.done.is_set()          # replaced silently: a cycle is not reported
    solver.release.set()
    assert g.done.wait(WAIT_S)


def test_a_failing_solve_is_reported_and_the_worker_goes_on(solver):
    def fail(request, cancel):
        if request.source == 'bad':
            raise RuntimeError('boom')
    solver.on_run = fail
    bad = goal('bad')
    solver.worker.submit(bad)
    solver.wait_started()
    assert bad.done.wait(WAIT_S)
    assert solver.errors == ["solve of goal from bad failed: RuntimeError('boom')"]
    solver.release.set()
    ok = goal('ok')
    solver.worker.submit(ok)
    assert ok.done.wait(WAIT_S) and ok.result == 'solved'


def test_stop_ends_the_thread_and_finishes_a_queued_goal():
    solver = Solver(ready=False)
    a = goal('a')
    solver.worker.submit(a)
    started = time.monotonic()
    solver.worker.stop()
    assert time.monotonic() - started < SETTLE_MAX_S + 1.0
    assert a.done.is_set() and not solver.runs
    assert not solver.worker.offer(goal('cycle', cycle=object()))


def test_on_done_runs_once_and_at_once_when_done():
    request = goal('a')
    calls = []
    request.on_done(lambda: calls.append(1))
    request.finish()
    request.on_done(lambda: calls.append(2))
    assert calls == [1, 2]
