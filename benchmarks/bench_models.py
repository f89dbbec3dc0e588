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
Kernel times of the generated robot models against the hand-written ones (issue 13).

For each pair (built-in model, the same robot from its model file in config/models) the
pointwise kernels rhs, rhs_jac, rhs_hess and segments are timed inside a compiled loop over a
batch of random states (nanoseconds per call), plus the rollout wrapper (Euler and RK4,
N = 1000); the two models are timed interleaved and the fastest of the repeats is kept.
Target: generated within 1.5x of hand-written.  The generation (SymPy derivation + code
printing) and the first-use compile time of a model file are measured in a fresh process with
an empty cache.

    PYTHONPATH=. python benchmarks/bench_models.py [--json PATH] [--repeat 15]
"""

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time

from numba import njit
import numpy as np

from toc_ros.core import horizon
from toc_ros.core.models import load_model

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PAIRS = (
    ('planar_2r', {'g': 9.81}, 'config/models/planar_2r.yaml', {'g': 9.81}),
    ('cylindrical', {}, 'config/models/cylindrical_eq37.yaml', {}),
)
KERNELS = ('rhs', 'rhs_jac', 'rhs_hess', 'segments')
BATCH = 1024


@njit
def _loop_rhs(kernel, xs, us, p, reps, f):
    acc = 0.0
    for _ in range(reps):
        for i in range(xs.shape[0]):
            kernel(xs[i], us[i], p, f)
            acc += f[1]
    return acc


@njit
def _loop_jac(kernel, xs, us, p, reps, f, fx, fu):
    acc = 0.0
    for _ in range(reps):
        for i in range(xs.shape[0]):
            kernel(xs[i], us[i], p, f, fx, fu)
            acc += fx[1, 2] + fu[1, 0]
    return acc


@njit
def _loop_hess(kernel, xs, us, lams, p, reps, hxx, hxu, huu):
    acc = 0.0
    for _ in range(reps):
        for i in range(xs.shape[0]):
            kernel(xs[i], us[i], p, lams[i], hxx, hxu, huu)
            acc += hxx[2, 2] + hxu[2, 0]
    return acc


@njit
def _loop_segments(kernel, qs, p, reps, seg, seg_q, seg_qq):
    acc = 0.0
    for _ in range(reps):
        for i in range(qs.shape[0]):
            kernel(qs[i], p, seg, seg_q, seg_qq)
            acc += seg[0, 2] + seg_q[0, 2, 0] + seg_qq[0, 2, 0, 0]
    return acc


def _best_ns(calls, calls_per_run, repeat):
    """
    Fastest time per call (ns) of each of the calls, measured interleaved.

    Interleaving and the minimum over the repeats keep a shared machine's load from biasing
    the ratio of two kernels (both see the same conditions).
    """
    for call in calls:
        call()                                   # compile / warm up
    best = [float('inf')] * len(calls)
    for _ in range(repeat):
        for k, call in enumerate(calls):
            start = time.perf_counter()
            call()
            best[k] = min(best[k], time.perf_counter() - start)
    return [b / calls_per_run * 1e9 for b in best]


def kernel_calls(model, reps=200):
    """Zero-argument callables {kernel: (call, calls per run)} timing a model's kernels."""
    rng = np.random.default_rng(0)
    nx, nu, nl, n = model.nx, model.nu, model.n_links, model.n_joints
    xs = rng.uniform(-1.0, 1.0, size=(BATCH, nx))
    if model.joint_kinds[-1] == 'prismatic':
        xs[:, 2] = rng.uniform(-0.3, 1.0, size=BATCH)
    us = rng.uniform(-1.0, 1.0, size=(BATCH, nu)) * model.u_max
    lams = rng.normal(size=(BATCH, nx))
    qs = np.ascontiguousarray(xs[:, 0::2])
    p, k = model.packed(), model.kernels
    calls = reps * BATCH
    f, fx, fu = np.zeros(nx), np.zeros((nx, nx)), np.zeros((nx, nu))
    hxx, hxu, huu = np.zeros((nx, nx)), np.zeros((nx, nu)), np.zeros((nu, nu))
    seg, seg_q, seg_qq = np.zeros((nl, 4)), np.zeros((nl, 4, n)), np.zeros((nl, 4, n, n))
    controls = rng.uniform(-0.5, 0.5, size=(1000, nu)) * model.u_max
    states = np.zeros((1001, nx))
    x0 = xs[0].copy()
    return {
        'rhs': (lambda: _loop_rhs(k.rhs, xs, us, p, reps, f), calls),
        'rhs_jac': (lambda: _loop_jac(k.rhs_jac, xs, us, p, reps, f, fx, fu), calls),
        'rhs_hess': (lambda: _loop_hess(k.rhs_hess, xs, us, lams, p, reps, hxx, hxu, huu),
                     calls),
        'segments': (lambda: _loop_segments(k.segments, qs, p, reps, seg, seg_q, seg_qq),
                     calls),
        # us per rollout (N = 1000).
        'rollout_euler': (lambda: k.rollout(x0, controls, 1e-3, p, horizon.EULER, states),
                          1e3),
        'rollout_rk4': (lambda: k.rollout(x0, controls, 1e-3, p, horizon.RK4, states), 1e3),
    }


_COLD = r"""
import json, sys, time
import numpy as np
t0 = time.perf_counter()
from toc_ros.core.models import symbolic
from toc_ros.core import horizon
text = open(sys.argv[1]).read()
t1 = time.perf_counter()
symbolic.generate_source(text, sys.argv[1])
t2 = time.perf_counter()
model = symbolic.model_from_text(text, sys.argv[1])
t3 = time.perf_counter()
nx, nu, nl, n = model.nx, model.nu, model.n_links, model.n_joints
x, u, p = np.zeros(nx) + 0.1, np.zeros(nu), model.packed()
model.kernels.rhs(x, u, p, np.zeros(nx))
model.kernels.rhs_jac(x, u, p, np.zeros(nx), np.zeros((nx, nx)), np.zeros((nx, nu)))
model.kernels.rhs_hess(x, u, p, np.ones(nx), np.zeros((nx, nx)), np.zeros((nx, nu)),
                       np.zeros((nu, nu)))
model.kernels.segments(x[0::2], p, np.zeros((nl, 4)), np.zeros((nl, 4, n)),
                       np.zeros((nl, 4, n, n)))
model.kernels.rollout(x, np.zeros((10, nu)), 1e-3, p, horizon.EULER, np.zeros((11, nx)))
t4 = time.perf_counter()
print(json.dumps({'import_s': t1 - t0, 'generate_s': t2 - t1, 'load_s': t3 - t2,
                  'compile_s': t4 - t3}))
"""


def cold_start(path):
    """Measure generation and compile times of a model file in fresh processes."""
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache, PYTHONPATH=ROOT)
        runs = []
        for _ in range(2):                   # cold, then warm (both caches filled)
            done = subprocess.run([sys.executable, '-c', _COLD, path], env=env, check=True,
                                  capture_output=True, text=True, cwd=ROOT)
            runs.append(json.loads(done.stdout.strip().splitlines()[-1]))
    return {'cold': runs[0], 'warm': runs[1]}


def main(argv=None):
    """Print the table (and optionally write JSON)."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--json', help='write the results to this file')
    parser.add_argument('--repeat', type=int, default=15)
    args = parser.parse_args(argv)
    print(f'python {platform.python_version()}, load average {os.getloadavg()[0]:.2f}')
    results = {}
    worst = 0.0
    for name, params, path, file_params in PAIRS:
        built_in = kernel_calls(load_model(name, **params))
        generated = kernel_calls(load_model(os.path.join(ROOT, path), **file_params))
        times = {}
        for kernel in built_in:
            (a, count), (b, _) = built_in[kernel], generated[kernel]
            times[kernel] = _best_ns([a, b], count, args.repeat)
        cold = cold_start(os.path.join(ROOT, path))
        results[name] = {'file': path, 'generation': cold,
                         'hand_written': {k: v[0] for k, v in times.items()},
                         'generated': {k: v[1] for k, v in times.items()}}
        print(f'\n{name} (hand-written) vs {path} (generated), fastest of {args.repeat}')
        print(f'  {"kernel":<15} {"hand-written":>13} {"generated":>11} {"ratio":>7}')
        for kernel, (a, b) in times.items():
            unit = 'ns' if kernel in KERNELS else 'us'
            worst = max(worst, b / a)
            print(f'  {kernel:<15} {a:10.1f} {unit} {b:8.1f} {unit} {b / a:7.2f}')
        print('  generation + compile (fresh process, empty caches): '
              f'SymPy derivation {cold["cold"]["generate_s"]:.2f} s, first load (derivation, '
              f'write, import) {cold["cold"]["load_s"]:.2f} s, kernel + rollout compile '
              f'{cold["cold"]["compile_s"]:.2f} s; from the caches: load '
              f'{cold["warm"]["load_s"]:.2f} s, first calls {cold["warm"]["compile_s"]:.2f} s')
    print(f'\nworst generated / hand-written ratio: {worst:.2f} (target <= 1.5)')
    if args.json:
        with open(args.json, 'w') as stream:
            json.dump(results, stream, indent=2)
    return 0


if __name__ == '__main__':
    sys.exit(main())
