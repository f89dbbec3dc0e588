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
Per-call cost of the arm model layer from Python (toc_ros.core.arms), Panda and UR5.

Median over 1000 calls (each call timed alone with perf_counter, after 100 warm-up calls) at
random in-limit states: Pinocchio's aba, rnea and computeABADerivatives as raw calls and
through ArmModel (which copies the results), the sphere centres and their Jacobians for every
shipped sphere, the obstacle and self clearances with their Jacobians, and the
self-collision pair counts.  Then what one interior-point iteration's model evaluations cost
for N intervals (Euler: N derivative calls; RK4: 4 N) evaluated call by call from Python,
Pinocchio's batched abaInParallel (ModelPool) against a Python loop of aba, and the solver's
compiled sphere rows (ArmEvaluator.clearance_terms: values; with gradients; with the weighted
curvature) at the N - 1 inner nodes, shipped spheres, one obstacle, with and without the
self-collision pairs.

    PYTHONPATH=. python benchmarks/bench_arms.py [--json PATH] [--calls 1000] [--N 100]
"""

import argparse
import json
import platform
import statistics
import time

import numpy as np
import pinocchio as pin

from toc_ros.core.arms import (default_spheres, load_arm, obstacle_clearance,
                               obstacle_clearance_jacobian, obstacle_clearances_batch,
                               self_clearance, self_clearance_jacobian, self_clearances_batch,
                               sphere_centres, sphere_jacobians, sphere_kinematics_batch)
from toc_ros.core.arms.arm_eval import ArmEvaluator


def per_call(function, states, calls):
    """Median seconds of function(*state) over calls, cycling through states."""
    for i in range(100):
        function(*states[i % len(states)])
    times = []
    for i in range(calls):
        state = states[i % len(states)]
        start = time.perf_counter()
        function(*state)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def batch_time(function, repeats=50):
    """Median seconds of function() over repeats."""
    function()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def measure(name, calls, horizon):
    arm = load_arm(name)
    spheres = default_spheres(arm)
    model, data = arm.model, arm.data
    rng = np.random.default_rng(0)
    states = [(rng.uniform(arm.lower, arm.upper), rng.uniform(-arm.velocity, arm.velocity),
               rng.uniform(-arm.effort, arm.effort)) for _ in range(64)]
    qs = [(q,) for q, _, _ in states]
    obstacle = np.array([[0.5, 0.0, 0.4, 0.1]])
    centres_jac = [sphere_jacobians(arm, spheres, q) for (q,) in qs]
    us = {
        'aba': per_call(lambda q, v, t: pin.aba(model, data, q, v, t), states, calls),
        'aba_world': per_call(lambda q, v, t: pin.aba(model, data, q, v, t,
                                                      pin.Convention.WORLD), states, calls),
        'rnea': per_call(lambda q, v, t: pin.rnea(model, data, q, v, t), states, calls),
        'computeABADerivatives': per_call(
            lambda q, v, t: pin.computeABADerivatives(model, data, q, v, t), states, calls),
        'arm.forward_dynamics': per_call(arm.forward_dynamics, states, calls),
        'arm.dynamics_and_derivatives': per_call(arm.dynamics_and_derivatives, states, calls),
        'sphere_centres': per_call(lambda q: sphere_centres(arm, spheres, q), qs, calls),
        'sphere_jacobians': per_call(lambda q: sphere_jacobians(arm, spheres, q), qs, calls),
        'obstacle_clearance+jacobian (1 obstacle)': per_call(
            lambda c, j: (obstacle_clearance(c, spheres.radii, obstacle),
                          obstacle_clearance_jacobian(c, j, obstacle)), centres_jac, calls),
        'self_clearance+jacobian (all pairs)': per_call(
            lambda c, j: (self_clearance(c, spheres.radii, spheres.self_pairs),
                          self_clearance_jacobian(c, j, spheres.self_pairs)), centres_jac,
            calls),
    }
    us = {key: 1e6 * value for key, value in us.items()}
    node = (us['arm.dynamics_and_derivatives'] + us['sphere_jacobians']
            + us['obstacle_clearance+jacobian (1 obstacle)']
            + us['self_clearance+jacobian (all pairs)'])
    # The same for all N + 1 nodes at once: derivatives call by call, spheres batched.
    q_nodes = np.array([states[i % 64][0] for i in range(horizon + 1)])
    batch = {
        'derivatives_python_loop': batch_time(lambda: [
            arm.dynamics_and_derivatives(*states[i % 64]) for i in range(horizon)]),
        'sphere_kinematics_batch': batch_time(lambda: sphere_kinematics_batch(spheres,
                                                                              q_nodes)),
    }
    centres_n, jac_n = sphere_kinematics_batch(spheres, q_nodes)
    batch['obstacle_clearances_batch (1 obstacle)'] = batch_time(
        lambda: obstacle_clearances_batch(centres_n, jac_n, spheres.radii, obstacle))
    batch['self_clearances_batch'] = batch_time(
        lambda: self_clearances_batch(centres_n, jac_n, spheres.radii, spheres.self_pairs))
    batch = {key: 1e6 * value for key, value in batch.items()}
    # Batched ABA: one call for N states against N Python calls, 1 and 2 threads.
    q_batch = np.array([states[i % 64][0] for i in range(horizon)]).T.copy()
    v_batch = np.array([states[i % 64][1] for i in range(horizon)]).T.copy()
    t_batch = np.array([states[i % 64][2] for i in range(horizon)]).T.copy()
    pool = pin.ModelPool(model, 2)
    out = np.zeros((arm.n, horizon))
    loop = batch_time(lambda: [pin.aba(model, data, q_batch[:, k], v_batch[:, k],
                                       t_batch[:, k]) for k in range(horizon)])
    batched = {threads: batch_time(lambda threads=threads: pin.abaInParallel(
        threads, pool, q_batch, v_batch, t_batch, out)) for threads in (1, 2)}
    check = np.array([pin.aba(model, data, q_batch[:, k], v_batch[:, k], t_batch[:, k])
                      for k in range(horizon)]).T
    rows = {}
    inner = q_nodes[1:-1]
    for self_collision in (False, True):
        evaluator = ArmEvaluator(arm, spheres, obstacle, 0.0, horizon, self_collision)
        weights = rng.uniform(0.0, 1.0, (len(inner), evaluator.n_pairs))
        key = 'with self pairs' if self_collision else 'obstacle rows only'
        rows[key] = {
            'values': 1e6 * batch_time(lambda e=evaluator: e.clearances(inner)),
            '+ gradients': 1e6 * batch_time(lambda e=evaluator: e.clearance_terms(inner)),
            '+ curvature': 1e6 * batch_time(
                lambda e=evaluator, w=weights: e.clearance_terms(inner, w))}
    return {
        'arm': name, 'dof': arm.n, 'spheres': len(spheres),
        'self_pairs': len(spheres.self_pairs), 'median_us': us,
        'per_node_us (derivatives + sphere jacobians + clearances)': node,
        f'iteration_ms_N{horizon}_call_by_call': {
            'euler': horizon * node / 1e3,
            'rk4 (4 derivative calls per interval)':
            horizon * (node + 3 * us['arm.dynamics_and_derivatives']) / 1e3},
        f'nodes_N{horizon}_us': batch,
        f'iteration_ms_N{horizon}_spheres_batched': {
            'euler': (batch['derivatives_python_loop'] + batch['sphere_kinematics_batch']
                      + batch['obstacle_clearances_batch (1 obstacle)']
                      + batch['self_clearances_batch']) / 1e3,
            'rk4': (4 * batch['derivatives_python_loop'] + batch['sphere_kinematics_batch']
                    + batch['obstacle_clearances_batch (1 obstacle)']
                    + batch['self_clearances_batch']) / 1e3},
        f'aba_batch_N{horizon}_us': {'python_loop': 1e6 * loop,
                                     'abaInParallel_1_thread': 1e6 * batched[1],
                                     'abaInParallel_2_threads': 1e6 * batched[2],
                                     'max_difference': float(np.abs(out - check).max())},
        f'solver_sphere_rows_N{horizon}_us': rows,
    }


def main(argv=None):
    """Print (and optionally save) the measurements."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--json', help='write the results here')
    parser.add_argument('--calls', type=int, default=1000)
    parser.add_argument('--N', type=int, default=100, dest='horizon')
    args = parser.parse_args(argv)
    results = {'machine': platform.processor() or platform.machine(),
               'python': platform.python_version(), 'pinocchio': pin.__version__,
               'arms': [measure(name, args.calls, args.horizon) for name in ('panda', 'ur5')]}
    print(json.dumps(results, indent=2))
    if args.json:
        with open(args.json, 'w') as stream:
            json.dump(results, stream, indent=2)


if __name__ == '__main__':
    main()
