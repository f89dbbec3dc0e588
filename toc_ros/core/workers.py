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
Run independent tasks WORKERS at a time on worker threads.

Fast mode's cold attempts from the class starts and the refinements of their candidates
(run_tasks: a list of tasks; share: threads that take their next task from the caller's queue
themselves).

The interior-point kernels release the GIL, so two solves run on two cores at once.  A task
owns its workspaces and shares no state with the others, and its iteration budget is fixed
before it starts: its arithmetic, hence its result, is the same bit for bit as when the tasks
run one after the other (no reduction crosses tasks; the caller combines the results in task
order).  Tasks never submit tasks, so a pool shared by concurrent solves cannot deadlock (their
tasks only queue).
"""

from concurrent.futures import ThreadPoolExecutor, wait
import os
import threading

# Threads for the tasks (1: run them on the calling thread, one after the other).
WORKERS = 2 if (os.cpu_count() or 1) >= 2 else 1
# [s] period of the caller's poll (progress reports) while it waits.
POLL = 0.02

_lock = threading.Lock()
_pool = None


def _reset():
    global _pool, _lock
    _pool, _lock = None, threading.Lock()


if hasattr(os, 'register_at_fork'):
    # A forked child (e.g. a sweep worker) has neither the threads nor a usable lock.
    os.register_at_fork(after_in_child=_reset)


def _executor():
    global _pool
    with _lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(max_workers=WORKERS, thread_name_prefix='toc_ros-solve')
        return _pool


def run_tasks(tasks, poll):
    """
    Return [task() for task in tasks], WORKERS at a time.

    poll() runs on the calling thread every POLL s while it waits (and after each task when
    they run one after the other).  Every task ends before an exception is raised: the first
    one in task order (a poll's exception after that).
    """
    if WORKERS < 2 or len(tasks) < 2:
        out = []
        for task in tasks:
            out.append(task())
            poll()
        return out
    futures = [_executor().submit(task) for task in tasks]
    pending, failure = set(futures), None
    while pending:
        _, pending = wait(pending, timeout=POLL)
        if pending and failure is None:
            try:
                poll()
            except Exception as error:      # raised once the tasks have ended
                failure = error
    out = [future.result() for future in futures]
    if failure is not None:
        raise failure
    return out


def share(work):
    """
    Run work() on the calling thread and on WORKERS - 1 worker threads; return when all have.

    work() takes tasks from a queue of its own (fast mode's prefetching class attempts) until
    none is left: a thread that ends a task takes the next one itself, without waking another
    thread (which cost milliseconds on a loaded machine), and the caller works too.  work()
    handles its tasks' exceptions; one it raises is re-raised here once all have returned.
    """
    helpers = [_executor().submit(work) for _ in range(WORKERS - 1)]
    try:
        work()
    finally:
        wait(helpers)
    for future in helpers:
        future.result()
