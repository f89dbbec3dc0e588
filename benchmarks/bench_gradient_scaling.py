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
Seconds per BPTT gradient evaluation versus N, and the log-log slope (expected: 1).

One evaluation = rollout with step Jacobians + J1 + J2 + J3 + the adjoint sweep
(toc_ros.core.bptt.paper_cost_gradient) with a preallocated Workspace, Euler, the paper's
scenario and constants.  Each timing is the median over repeats of a batch of calls.

    PYTHONPATH=. python benchmarks/bench_gradient_scaling.py [--json PATH]
"""

import argparse
import json
import math
import os
import platform
import sys
import time

import numpy as np

from toc_ros.core import PaperOptions, Problem, warm_up
from toc_ros.core.bptt import paper_cost_gradient, Workspace
from toc_ros.core.integrators import EULER

SIZES = (250, 500, 1000, 2000, 4000, 8000)


def _controls(n):
    """Rotate-and-brake controls with a retraction, so that every penalty term is active."""
    t = (np.arange(n) + 0.5) / n
    u = np.empty((n, 2))
    u[:, 0] = np.where(t < 0.5, 620.0, -620.0)         # slightly beyond the bound: J2 active
    u[:, 1] = np.where(t < 0.5, -300.0, 300.0)
    return u


def time_gradient(n, repeats=15, batch_seconds=0.02):
    """Median seconds per paper_cost_gradient call at horizon n."""
    problem = Problem.paper(n_intervals=n)
    po = PaperOptions()
    tau0 = problem.t_f0 / n
    args = (np.asarray(problem.x0, float), np.asarray(problem.x_goal, float), _controls(n),
            tau0, problem.model.packed(), EULER, problem.model.u_max,
            np.ascontiguousarray(problem.circles()), po.k_b, tau0 * po.k_v, tau0 * po.k_p,
            po.grad_mode())
    ws = Workspace(n)
    buffers = (ws.states, ws.jac_x, ws.jac_u, ws.jac_tau, ws.grad_x, ws.grad_u, ws.out_grad_u)
    paper_cost_gradient(*args, *buffers)
    start = time.perf_counter()
    paper_cost_gradient(*args, *buffers)
    calls = max(1, int(batch_seconds / max(time.perf_counter() - start, 1e-9)))
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(calls):
            paper_cost_gradient(*args, *buffers)
        samples.append((time.perf_counter() - start) / calls)
    return float(np.median(samples)), calls


def main(argv=None):
    """Print the scaling table; optionally save it as JSON."""
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--json', metavar='PATH', help='also write the table as JSON')
    parser.add_argument('--repeats', type=int, default=15)
    args = parser.parse_args(argv)
    warm_up()
    rows = []
    for n in SIZES:
        seconds, calls = time_gradient(n, args.repeats)
        rows.append({'N': n, 'seconds_per_gradient': seconds, 'us_per_interval': seconds / n * 1e6,
                     'calls_per_repeat': calls})
    slope = float(np.polyfit(np.log([r['N'] for r in rows]),
                             np.log([r['seconds_per_gradient'] for r in rows]), 1)[0])
    load = os.getloadavg()[0] if hasattr(os, 'getloadavg') else math.nan
    print(f'BPTT gradient (paper_cost_gradient, Euler, paper scenario), median of '
          f'{args.repeats} repeats; {platform.machine()}, {os.cpu_count()} CPUs, '
          f'load {load:.2f}, Python {platform.python_version()}')
    print(f'{"N":>6}  {"s / gradient":>13}  {"us / interval":>13}')
    for r in rows:
        print(f'{r["N"]:>6}  {r["seconds_per_gradient"]:>13.3e}  {r["us_per_interval"]:>13.4f}')
    print(f'log-log slope: {slope:.3f} (target: within 10 % of 1)')
    if args.json:
        with open(args.json, 'w') as stream:
            json.dump({'rows': rows, 'slope': slope, 'repeats': args.repeats}, stream, indent=1)
    return 0 if math.isfinite(slope) else 1


if __name__ == '__main__':
    sys.exit(main())
