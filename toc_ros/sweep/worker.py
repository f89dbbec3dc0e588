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
What runs on a Dask worker: the numba warm-up plugin and the batch task.

A task solves a batch of cases one after the other (one thread: the kernels are
single-threaded) and returns their result rows; it never raises for a case: a bad case is an
INVALID_INPUT row, an unexpected exception an ERROR row.
"""

import asyncio
import math
import time
import traceback

from distributed.diagnostics.plugin import WorkerPlugin

from .arm_cases import arm_columns, build_case, is_arm_case, warm_up_seconds
from .cases import command_line

PLUGIN_NAME = 'toc_ros-warm-up'
VIOLATIONS = ('max_control_excess', 'terminal_error', 'min_clearance')
_STATE = {'warm_s': None}


def warm_up_once():
    """Compile or load the numba kernels once per process; return (seconds, warmed now)."""
    if _STATE['warm_s'] is None:
        start = time.perf_counter()
        from toc_ros.core import warm_up
        warm_up()
        _STATE['warm_s'] = time.perf_counter() - start
        return _STATE['warm_s'], True
    return _STATE['warm_s'], False


class WarmUpPlugin(WorkerPlugin):
    """Warms the numba cache when a worker joins (again on a restarted worker), not per case."""

    name = PLUGIN_NAME

    async def setup(self, worker):
        """Run the warm-up off the worker's event loop (heartbeats go on meanwhile)."""
        seconds, now = await asyncio.get_running_loop().run_in_executor(None, warm_up_once)
        # Visible to clients: client.get_events('toc_ros').
        worker.log_event('toc_ros', {'action': 'warm-up', 'seconds': seconds, 'now': now,
                                     'worker': worker.address})


def _worker_name():
    try:
        from distributed import get_worker
        return str(get_worker().address)
    except ValueError:      # called outside a worker (serial runs, tests)
        return 'local'


def solve_case(case, worker='local'):
    """Solve one case (case_id, argv, values, problem, options); return its result row."""
    from toc_ros.core import solve, SolveResult, Status
    case_id, argv, values, problem, options = case
    # Arm cases carry their arguments only: the problem is built here (arm_cases.py).
    arm = problem is None and is_arm_case(argv)
    try:
        result = guess = None
        if arm:
            try:
                problem, options, guess = build_case(argv)
            except ValueError as exc:     # e.g. an unreachable tip target: the row says why
                result = SolveResult(status=Status.INVALID_INPUT, message=str(exc))
        if result is None:
            result = (solve(problem, options) if guess is None
                      else solve(problem, options, initial_guess=guess))
        status = result.status.value
    except Exception:       # noqa: B902 - a bug must not take the batch down
        result = SolveResult(status=Status.INVALID_INPUT, message=traceback.format_exc(limit=3))
        status = 'ERROR'
    v = result.violations
    row = {'case_id': case_id}
    row.update(values)
    row.update({
        'status': status, 'final_time': float(result.final_time),
        'iterations': int(result.iterations), 'wall_time_s': float(result.wall_time_s)})
    row.update({name: float(getattr(v, name, math.nan)) for name in VIOLATIONS})
    row.update({'worker': worker, 'message': str(getattr(result, 'message', '')),
                'args': command_line(argv)})
    if arm:
        row.update(arm_columns(problem, result))
    return row


def solve_batch(batch):
    """Dask task: solve a list of cases; their rows plus the task's timing."""
    start = time.perf_counter()
    cpu = time.process_time()
    started_at = time.time()
    worker = _worker_name()
    warm_up_once()          # a no-op after the plugin; covers a worker that missed it
    warm = time.perf_counter() - start
    arm_warm = warm_up_seconds()
    rows = [solve_case(case, worker) for case in batch]
    # An arm's first case in this process loaded and warmed it: not solving, and it would
    # make the batcher think every case takes that long.
    warm += warm_up_seconds() - arm_warm
    return {'rows': rows, 'worker': worker, 'task_s': time.perf_counter() - start - warm,
            'cpu_s': time.process_time() - cpu, 'warm_s': warm, 'started_at': started_at,
            'finished_at': time.time()}
