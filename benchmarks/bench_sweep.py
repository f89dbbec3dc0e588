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
toc-sweep throughput with 1 and 2 LocalCluster workers on 200 paper-like cases.

The cases: the paper's robot, start and obstacle, goals q1 in [1.0, 1.6] rad (20 values) x
q2 in [0.8, 1.2] m (10 values), fast mode, Euler, N intervals (default the paper's 1000).
For each worker count the same toc-sweep code runs them (toc_ros.sweep.runner: adaptive
batches, Parquet files in a temporary directory) on a freshly started and warmed-up
LocalCluster; the clock runs from the first submission to the last result.  Reported:

* speed-up = wall(1 worker) / wall(2 workers)  (target >= 1.8);
* overhead = (worker threads x wall - sum of task compute times) / sum of solve times: the
  scheduling, serialisation, result transfer and idling of the Dask layer as a share of the
  solving (target <= 5 %);  per-case work = (sum of task times - sum of solve times) / sum of
  solve times: argument parsing, Problem building and row assembly inside the tasks;
* CPU / task time: the workers' CPU time over their task time (below 1: the cores were
  shared with other processes, which slows every solve and caps the speed-up).

    PYTHONPATH=. python benchmarks/bench_sweep.py [--N 1000] [--cases 200] [--json PATH]
        [--max-iterations 300]    # ~3 ms solves (N = 60), a stand-in for a millisecond solver
"""

import argparse
import json
import os
import platform
import sys
import tempfile
import time

from toc_ros.sweep.cases import CaseBuilder
from toc_ros.sweep.dataset import Dataset, schema_for
from toc_ros.sweep.runner import connect, run_cases, RunStats
from toc_ros.sweep.spec import parse_spec


def paper_like_spec(n_intervals, n_cases, max_iterations=None):
    """Spec of n_cases goals around the paper's (n_cases = 20 x k)."""
    n_q2 = max(1, n_cases // 20)
    base = {'mode': 'fast', 'integrator': 'euler', 'N': n_intervals}
    if max_iterations:
        base['max-iterations'] = max_iterations
    return {'base': base,
            'grid': {'goal.q1': {'linspace': [1.0, 1.6, 20]},
                     'goal.q2': {'linspace': [0.8, 1.2, n_q2]}}}


def run(workers, sweep, cases, folder):
    """Run every case on a new LocalCluster of `workers` processes; return RunStats."""
    started = time.perf_counter()
    client, cluster, _ = connect(None, workers, log=lambda *a: None)
    stats = RunStats(warm_s=time.perf_counter() - started)
    try:
        dataset = Dataset(os.path.join(folder, f'w{workers}'), schema_for(sweep))
        dataset.prepare(False)
        run_cases(client, cases, dataset, stats=stats)
    finally:
        client.close()
        cluster.close()
    return stats


def main(argv=None):
    """Run the benchmark and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--N', type=int, default=1000, help='intervals per solve (1000)')
    parser.add_argument('--cases', type=int, default=200, help='cases (multiple of 20; 200)')
    parser.add_argument('--max-iterations', type=int, metavar='M',
                        help='stop every solve after M iterations (status MAX_ITERATIONS): '
                             'millisecond solves, a stand-in for a faster solver')
    parser.add_argument('--json', metavar='PATH', help='write the numbers as JSON')
    args = parser.parse_args(argv)
    sweep = parse_spec(paper_like_spec(args.N, args.cases, args.max_iterations),
                       path='bench_sweep')
    builder = CaseBuilder(sweep)
    cases = builder.cases()
    load = os.getloadavg()
    limit = f', max_iterations {args.max_iterations}' if args.max_iterations else ''
    print(f'bench_sweep: {len(cases)} cases, fast mode, N = {args.N}{limit}, '
          f'{os.cpu_count()} cores, load average {load[0]:.2f} at start, '
          f'{platform.python_version()}')
    results = {}
    with tempfile.TemporaryDirectory(prefix='bench_sweep-') as folder:
        for workers in (1, 2):
            stats = run(workers, sweep, cases, folder)
            if stats.lost or stats.done != len(cases):
                print(f'bench_sweep: {workers} worker(s): only {stats.done} of {len(cases)} '
                      'cases done', file=sys.stderr)
                return 1
            results[workers] = stats
    print('\n| workers | wall [s] | cases/s | tasks | sum solve [s] | sum task [s] | '
          'overhead | per-case work | CPU / task time | start + warm-up [s] |')
    print('|---|---|---|---|---|---|---|---|---|---|')
    for workers, s in results.items():
        per_case = (s.task_s - s.solve_s) / s.solve_s
        print(f'| {workers} | {s.wall_s:.2f} | {s.done / s.wall_s:.1f} | {s.tasks} | '
              f'{s.solve_s:.2f} | {s.task_s:.2f} | {100 * s.overhead_share():.2f} % | '
              f'{100 * per_case:.2f} % | {s.cpu_s / s.task_s:.2f} | {s.warm_s:.1f} |')
    speedup = results[1].wall_s / results[2].wall_s
    overhead = max(s.overhead_share() for s in results.values())
    print(f'\nspeed-up 1 -> 2 workers: {speedup:.2f}x (target >= 1.8); overhead at most '
          f'{100 * overhead:.2f} % of solve time (target <= 5 %); load average '
          f'{os.getloadavg()[0]:.2f} at the end')
    if args.json:
        with open(args.json, 'w') as stream:
            json.dump({'N': args.N, 'cases': len(cases), 'speedup': speedup,
                       'max_iterations': args.max_iterations,
                       'load_average_start': load[0],
                       'runs': {str(w): s.as_dict() for w, s in results.items()}}, stream,
                      indent=1)
            stream.write('\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
