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
Warm starts of replan cycles from drifted states: the barrier parameter they start with.

The paper scenario's plan (RK4, N = 1000; with --lag its model with first-order actuators) is
cut at t = 0.1, 0.2, ... 1.6 s; each start is perturbed as a tracking error would (positions
1e-3 rad / m, velocities 1e-2, with --lag the applied efforts 2 % of u_max; --scale multiplies
them; --seeds draws) and solved warm from the plan's remainder on the grid solver_node uses
(at most --max-nodes intervals, steps <= the model's max_step), as fast mode does with
fast_solver.MU_DRIFT set to each value of --mu.  Reported per value: SOLVED count, iterations
median / p90, wall time median / p90 and the number of cold fallbacks (more than WARM_BUDGET
iterations).  Starts inside the obstacle's margin are refused (INVALID_INPUT) and not counted.

    PYTHONPATH=. python benchmarks/bench_cycle_warm.py [--lag 0.01] [--mu 1e-5 1e-4 1e-3]
"""

import argparse
import dataclasses
import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from toc_ros import config  # noqa: E402
from toc_ros.core import fast_solver, ProblemError, solve  # noqa: E402

PERTURBATION = np.array([1e-3, 1e-2, 1e-3, 1e-2])
EFFORT_PERTURBATION = 0.02


def cycle_problems(params, seeds, scale, max_nodes):
    """Return [(problem, guess)] of the perturbed cycle starts along the scenario's plan."""
    plan_problem = config.problem_from_parameters(params)
    plan = solve(plan_problem, config.options_from_parameters(params))
    model = plan_problem.robot_model
    times = np.asarray(plan.time_grid)
    cases = []
    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        for t in np.arange(0.1, 1.65, 0.1):
            k = int(np.searchsorted(times, t))
            x = np.asarray(plan.states[k], dtype=float).copy()
            x[:4] += scale * rng.normal(0.0, PERTURBATION)
            if model.nx > 4:
                x[4:] = np.clip(x[4:] + scale * rng.normal(0.0, EFFORT_PERTURBATION,
                                                           model.nx - 4), -1.0, 1.0)
            guess = plan.remainder(times[k])
            nodes = max(min(guess.controls.shape[0], max_nodes),
                        math.ceil(1.02 * guess.final_time / model.max_step))
            try:
                problem = config.problem_from_parameters(params, x0=tuple(x))
            except ProblemError:
                continue
            cases.append((dataclasses.replace(problem, n_intervals=nodes), guess))
    return cases


def measure(cases, options, mu_drift):
    """Solve every case warm with MU_DRIFT = mu_drift; return the summary row."""
    saved = fast_solver.MU_DRIFT
    fast_solver.MU_DRIFT = mu_drift
    iterations, times, fallbacks, solved, refused = [], [], 0, 0, 0
    try:
        for problem, guess in cases:
            start = time.perf_counter()
            result = solve(problem, options, initial_guess=guess)
            refused += result.status.value == 'INVALID_INPUT'
            if result.status.value != 'SOLVED':
                continue
            solved += 1
            iterations.append(result.iterations)
            times.append(1e3 * (time.perf_counter() - start))
            fallbacks += result.iterations > fast_solver.WARM_BUDGET
    finally:
        fast_solver.MU_DRIFT = saved
    return {'mu_drift': mu_drift, 'cases': len(cases) - refused, 'solved': solved,
            'it_median': float(np.median(iterations)),
            'it_p90': float(np.percentile(iterations, 90)),
            'ms_median': float(np.median(times)), 'ms_p90': float(np.percentile(times, 90)),
            'fallbacks': fallbacks}


def main(argv=None):
    """Run the comparison and print a Markdown table."""
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--lag', type=float, default=0.0, help='robot.actuator_lag [s]')
    parser.add_argument('--mu', type=float, nargs='+', default=[1e-5, 1e-4, 1e-3])
    parser.add_argument('--seeds', type=int, default=3)
    parser.add_argument('--scale', type=float, default=1.0)
    parser.add_argument('--max-nodes', type=int, default=150)
    args = parser.parse_args(argv)
    params = dict(config.load_parameters(), **{
        'robot.actuator_lag': args.lag, 'solver.N': 1000, 'solver.timeout': 0.0,
        'solver.integrator': 'rk4'})
    cases = cycle_problems(params, args.seeds, args.scale, args.max_nodes)
    options = dataclasses.replace(config.options_from_parameters(params), timeout=5.0)
    measure(cases[:2], options, args.mu[0])         # compile and warm the caches
    print(f'cycle warm starts: lag {args.lag} s, scale {args.scale}, {len(cases)} starts, '
          f'<= {args.max_nodes} intervals, load {os.getloadavg()[0]:.2f}\n')
    print('| MU_DRIFT | SOLVED | iterations median / p90 | ms median / p90 | cold fallbacks |')
    print('|---:|---:|---|---|---:|')
    for mu in args.mu:
        row = measure(cases, options, mu)
        print(f"| {mu:g} | {row['solved']}/{row['cases']} | {row['it_median']:.0f} / "
              f"{row['it_p90']:.0f} | {row['ms_median']:.1f} / {row['ms_p90']:.1f} | "
              f"{row['fallbacks']} |")
    return 0


if __name__ == '__main__':
    sys.exit(main())
