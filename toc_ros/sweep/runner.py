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
Run cases on Dask distributed: an embedded LocalCluster or an existing scheduler, same path.

Cases go out in batches (one task each) through a bounded window of tasks in flight, so a
million cases never sit in the scheduler at once; each finished task's rows are written to
the Parquet dataset at once.  Batch sizes adapt to the measured solve time: about
TARGET_TASK_S seconds per task (scheduling and serialisation stay a small fraction), and
smaller towards the end so that no worker idles while another finishes a long batch.
A worker that dies takes its running task with it; Dask reruns that task elsewhere
(distributed.scheduler.allowed-failures times), and a finished result that died with its
worker before it was fetched is computed again (the future is still wanted; a batch whose
future is cancelled or lost anyway is submitted again, RESUBMIT times), so no case is lost or
written twice.
"""

from collections import deque
from dataclasses import dataclass, field
import logging
import math
import os
import time
import uuid

TARGET_TASK_S = 1.0          # aimed-for duration of one task
MIN_TASK_S = 0.05            # tasks at the end are not made shorter than this
WAIT_FOR_WORKERS_S = 120     # an external scheduler without workers: give up after this
FIRST_BATCH = 1              # cases per task until solve times have been measured
MAX_BATCH = 2000
TASKS_PER_WORKER = 3         # tasks in flight per worker thread
RESUBMIT = 2                 # a batch whose result was lost (not an error) goes out again


def default_workers():
    """One worker per core available to this process."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:          # not on Linux
        return os.cpu_count() or 1


@dataclass
class RunStats:
    """What a run did and how long it took (the summary's timing section)."""

    cases: int = 0                 # cases submitted in this run
    done: int = 0                  # rows written in this run
    lost: list = field(default_factory=list)      # (case_id, reason) of cases not solved
    tasks: int = 0
    wall_s: float = 0.0            # first submission to last result
    task_s: float = 0.0            # sum of the tasks' compute time on the workers
    cpu_s: float = 0.0             # sum of the worker processes' CPU time in the tasks
    task_warm_s: float = 0.0       # warm-up inside tasks (0 with the plugin; arms: loading)
    solve_s: float = 0.0           # sum of the solvers' wall_time_s
    threads: int = 0               # worker threads (max seen during the run)
    workers: set = field(default_factory=set)
    warm_s: float = 0.0            # cluster start and warm-up (before the first task)
    files: int = 0

    def overhead_share(self):
        """(threads x wall - task time) / solve time: scheduling, serialisation, idling."""
        if self.solve_s <= 0.0:
            return math.nan
        return (self.threads * self.wall_s - self.task_s) / self.solve_s

    def as_dict(self):
        """JSON-ready dict."""
        return {'cases': self.cases, 'done': self.done, 'lost': len(self.lost),
                'tasks': self.tasks, 'wall_s': self.wall_s, 'task_s': self.task_s,
                'solve_s': self.solve_s, 'cpu_s': self.cpu_s,
                'task_warm_up_s': self.task_warm_s, 'worker_threads': self.threads,
                'workers': sorted(self.workers), 'startup_s': self.warm_s,
                'overhead_share': self.overhead_share(),
                'cases_per_s': self.done / self.wall_s if self.wall_s > 0 else math.nan}


class Batcher:
    """Batch sizes: FIRST_BATCH until measured, then ~target seconds, shrinking at the end."""

    def __init__(self, fixed=None, target_s=TARGET_TASK_S):
        self.fixed = fixed
        self.target_s = target_s
        self.cases = 0
        self.seconds = 0.0

    def record(self, n_cases, task_s):
        """Account a finished task."""
        self.cases += n_cases
        self.seconds += task_s

    def size(self, remaining, threads):
        """Cases for the next task."""
        if self.fixed:
            return max(1, min(self.fixed, remaining))
        if self.cases == 0:
            return max(1, min(FIRST_BATCH, remaining))
        per_case = max(self.seconds / self.cases, 1e-6)
        size = int(self.target_s / per_case)
        tail = max(math.ceil(remaining / (2 * max(threads, 1))), int(MIN_TASK_S / per_case))
        return max(1, min(size, tail, MAX_BATCH, remaining))


def _dashboard_available():
    try:
        import bokeh  # noqa: F401
        return True
    except ImportError:
        return False


def connect(scheduler=None, workers=None, log=print):
    """Return (client, cluster or None, description) and register the warm-up plugin."""
    from distributed import Client, LocalCluster
    from .worker import WarmUpPlugin
    dashboard = _dashboard_available()
    if scheduler:
        try:
            client = Client(scheduler, timeout=30)
        except (OSError, TimeoutError) as exc:
            raise ConnectionError(f'cannot reach the Dask scheduler {scheduler}: {exc}')
        cluster = None
        what = f'scheduler {scheduler}'
        try:
            client.wait_for_workers(1, timeout=WAIT_FOR_WORKERS_S)
        except TimeoutError:
            client.close()
            raise ConnectionError(f'no worker joined the Dask scheduler {scheduler} within '
                                  f'{WAIT_FOR_WORKERS_S} s (start some: dask worker '
                                  f'{scheduler} --nthreads 1)')
    else:
        n = workers or default_workers()
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                               host='127.0.0.1', dashboard_address='127.0.0.1:0',
                               silence_logs=logging.ERROR)
        client = Client(cluster)
        what = f'LocalCluster, {n} worker process(es) x 1 thread'
    try:
        link = client.dashboard_link if dashboard else None
    except (KeyError, AttributeError):
        link = None
    log(f'toc-sweep: {what}; dashboard: '
        + (link or 'not available (install bokeh for the Dask dashboard)'))
    try:
        client.register_plugin(WarmUpPlugin())
    except Exception as exc:      # noqa: B902 - whatever the workers raised
        client.close()
        if cluster is not None:
            cluster.close()
        raise ConnectionError(f'the Dask workers could not load toc_ros (install the same '
                              f'toc_ros on every worker): {exc!r}')
    return client, cluster, what


def _threads(client):
    try:
        info = client.scheduler_info(n_workers=-1)
    except TypeError:       # older distributed
        info = client.scheduler_info()
    return sum(w.get('nthreads', 1) for w in info.get('workers', {}).values())


class _Threads:
    """Worker threads of the cluster, asked of the scheduler at most once a second."""

    def __init__(self, client, stats):
        self.client = client
        self.stats = stats
        self.value = 0
        self.when = -math.inf

    def __call__(self):
        now = time.monotonic()
        if now - self.when >= 1.0:
            self.value = max(_threads(self.client), 1)
            self.when = now
            self.stats.threads = max(self.stats.threads, self.value)
        return self.value


def run_cases(client, cases, dataset, batch_size=None, on_progress=None,
              target_task_s=TARGET_TASK_S, stats=None):
    """
    Solve cases (CaseBuilder.cases()) on the client's cluster, writing rows as tasks finish.

    on_progress(rows, n_lost) is called for every finished task.  Returns RunStats;
    cases whose task failed (e.g. too many workers died running it) are in stats.lost.
    """
    from distributed import as_completed
    from .worker import solve_batch
    stats = stats or RunStats()
    stats.cases = len(cases)
    if not cases:
        return stats
    pending = deque(cases)
    batcher = Batcher(batch_size, target_task_s)
    batches = {}
    stream = as_completed()
    run_id = uuid.uuid4().hex[:12]      # keys unique across runs sharing a scheduler
    start = time.perf_counter()

    threads = _Threads(client, stats)

    tries = {}

    def send(batch, attempt=0):
        future = client.submit(solve_batch, batch, pure=False,
                               key=f'toc-sweep-{run_id}-{stats.tasks}')
        stats.tasks += 1
        batches[future.key] = batch
        tries[future.key] = attempt
        stream.add(future)

    def submit():
        # Until a first task has been timed, two single-case tasks per thread (a case may take
        # minutes); then TASKS_PER_WORKER per thread, so that none waits for the client.
        window = (TASKS_PER_WORKER if batcher.cases else 2) * threads()
        while pending and len(batches) < window:
            n = batcher.size(len(pending), threads())
            send([pending.popleft() for _ in range(n)])

    try:
        submit()
        for future in stream:
            batch = batches.pop(future.key)
            attempt = tries.pop(future.key)
            out, reason = None, future.status
            if future.status not in ('error', 'cancelled'):
                try:
                    # 'lost': the worker holding the result died before it was fetched; the
                    # scheduler computes it again for this still-wanted future.
                    out = future.result()
                except Exception as exc:      # noqa: B902 - KilledWorker, CancelledError, ...
                    reason = repr(exc)
            elif future.status == 'error':
                reason = repr(future.exception())
            if out is not None:
                batcher.record(len(batch), out['task_s'])
                submit()            # refill first: the workers go on while the rows are written
                dataset.write(out['rows'])
                stats.files += 1
                stats.done += len(out['rows'])
                stats.task_s += out['task_s']
                stats.cpu_s += out.get('cpu_s', 0.0)
                stats.task_warm_s += out.get('warm_s', 0.0)
                stats.solve_s += sum(r['wall_time_s'] for r in out['rows'])
                stats.workers.add(out['worker'])
                if on_progress:
                    on_progress(out['rows'], 0)
            elif future.status != 'error' and attempt < RESUBMIT:
                send(batch, attempt + 1)     # not the task's fault: try it again
            else:
                stats.lost += [(case[0], reason) for case in batch]
                if on_progress:
                    on_progress([], len(batch))
            future.release()
            submit()
    finally:
        stats.wall_s = time.perf_counter() - start
        for key in list(batches):
            batches.pop(key)
        stream.clear()
    return stats
