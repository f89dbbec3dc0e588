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
The C++ loop of Pinocchio's calls (core/arms/pin_batch.py) against the Python loop.

Its contract is the same bits: every derivative, every Euler rollout and every solve must be
identical with and without it.  The library is built here when it is missing (once per
Pinocchio install; .ci/setup builds it first); the tests skip only where no C++ compiler
exists.
"""

import dataclasses
import os
import shutil

import numpy as np
import pytest

pin = pytest.importorskip('pinocchio')

from test_arm_solve import _problem  # noqa: E402, I100
from toc_ros.core import solve, Status  # noqa: E402, I100
from toc_ros.core.arms import load_arm, pin_batch  # noqa: E402
from toc_ros.core.arms.arm_warm import rollout  # noqa: E402
from toc_ros.core.arms.payload import with_payload  # noqa: E402


@pytest.fixture(scope='module')
def lib():
    """Return the compiled library (built here when missing; a skip only without a compiler)."""
    if pin_batch.library()[0] is None:
        if shutil.which(os.environ.get('CXX', 'c++')) is None:
            pytest.skip('no C++ compiler: the solver uses the Python loop')
        pin_batch.build()
    found, reason = pin_batch.library()
    assert found is not None, reason
    return found


def _python_derivatives(arm, states, tau):
    data = arm.model.createData()
    n, count = arm.n, len(states)
    out = [np.empty((count, n)), np.empty((count, n, n)), np.empty((count, n, n)),
           np.empty((count, n, n))]
    for k in range(count):
        pin.computeABADerivatives(arm.model, data, states[k, :n], states[k, n:], tau[k])
        for target, value in zip(out, (data.ddq, data.ddq_dq, data.ddq_dv, data.Minv)):
            target[k] = value
    return out


def _random_nodes(arm, count, seed):
    rng = np.random.default_rng(seed)
    q = rng.uniform(arm.lower, arm.upper, (count, arm.n))
    v = rng.uniform(-1.0, 1.0, (count, arm.n)) * arm.velocity
    tau = rng.uniform(-1.0, 1.0, (count, arm.n)) * arm.effort
    return np.hstack([q, v]), tau


def _batched(arm, states, tau):
    n, count = arm.n, len(states)
    out = [np.empty((count, n)), np.empty((count, n, n)), np.empty((count, n, n)),
           np.empty((count, n, n))]
    pin_batch.workspace(arm.model).aba_derivatives(states, tau, *out)
    return out


@pytest.mark.parametrize('name', ['panda', 'ur5'])
def test_batched_derivatives_are_the_python_loops_bits(lib, name):
    arm = load_arm(name)
    states, tau = _random_nodes(arm, 50, seed=3)
    for got, want in zip(_batched(arm, states, tau), _python_derivatives(arm, states, tau)):
        assert np.array_equal(got, want)


def test_batched_euler_rollout_is_the_python_rollouts_bits(lib, monkeypatch):
    arm = load_arm('panda')
    states, tau = _random_nodes(arm, 40, seed=5)
    x0 = np.concatenate([np.zeros(arm.n), 0.1 * arm.velocity])
    got = rollout(arm, x0, 0.3 * tau, 0.8)
    monkeypatch.setattr(pin_batch, 'workspace', lambda model: None)
    want = rollout(arm, x0, 0.3 * tau, 0.8)
    assert got.shape == (41, 2 * arm.n) and np.array_equal(got, want)


def test_a_model_changed_in_place_is_not_served_a_stale_copy(lib):
    arm = load_arm('panda')
    arm = dataclasses.replace(arm, model=arm.model.copy())
    states, tau = _random_nodes(arm, 10, seed=7)
    before = _batched(arm, states, tau)[0]
    # The payload's inertia added to the last joint of the same Python model object.
    heavy = with_payload(arm, 2.0, 'panda_link8').model
    arm.model.inertias[arm.n] = heavy.inertias[arm.n]
    after = _batched(arm, states, tau)[0]
    assert not np.array_equal(before, after)
    assert np.array_equal(after, _python_derivatives(arm, states, tau)[0])


def test_wrong_shapes_are_refused_before_the_cpp_loop_runs(lib):
    arm = load_arm('ur5')
    states, tau = _random_nodes(arm, 4, seed=1)
    work = pin_batch.workspace(arm.model)
    out = [np.empty((4, 6)), np.empty((4, 6, 6)), np.empty((4, 6, 6)), np.empty((3, 6, 6))]
    with pytest.raises(ValueError, match='expected'):
        work.aba_derivatives(states, tau, *out)
    with pytest.raises(ValueError, match='expected'):
        work.rollout_euler(np.zeros(5), tau, 0.1)


def test_a_model_the_loop_cannot_take_gets_the_python_loop(lib):
    # A free-flyer's configuration (a quaternion) is not its velocity space: no workspace.
    assert pin_batch.workspace(pin.buildSampleModelHumanoidRandom()) is None
    assert pin_batch.workspace(load_arm('ur5').model) is not None


def test_solves_have_the_same_bits_with_and_without_the_cpp_loop(lib, monkeypatch):
    # A cold solve past a sphere (cheap model, then the exact curvature: every path of
    # derivatives_at) and a warm replan off its remainder, RK4 steps too.
    results = {}
    for native in (True, False):
        if not native:
            monkeypatch.setattr(pin_batch, 'workspace', lambda model: None)
        problem = _problem('panda', 30)
        cold = solve(problem)
        rest = cold.remainder(0.3 * cold.final_time)
        x0 = rest.states[0] + 1e-3
        replan = dataclasses.replace(problem, x0=tuple(x0), n_intervals=len(rest.controls))
        warm = solve(replan, initial_guess=rest)
        rk4 = solve(_problem('ur5', 12, integrator='rk4'))
        results[native] = (cold, warm, rk4)
    for with_cpp, without in zip(results[True], results[False]):
        assert with_cpp.status is Status.SOLVED, with_cpp.message
        assert with_cpp.iterations == without.iterations
        assert with_cpp.final_time == without.final_time
        assert np.array_equal(with_cpp.controls, without.controls)
        assert np.array_equal(with_cpp.states, without.states)


def test_without_the_library_the_status_says_why_and_solves_go_on(monkeypatch):
    monkeypatch.setenv('TOC_ROS_PIN_BATCH', '0')
    pin_batch.library.cache_clear()
    try:
        assert pin_batch.workspace(load_arm('ur5').model) is None
        assert 'Python' in pin_batch.status() and 'TOC_ROS_PIN_BATCH=0' in pin_batch.status()
        assert solve(_problem('ur5', 10, with_obstacles=False)).status is Status.SOLVED
    finally:
        monkeypatch.delenv('TOC_ROS_PIN_BATCH')
        pin_batch.library.cache_clear()


def test_a_failed_build_says_why_and_leaves_no_file(tmp_path, monkeypatch):
    monkeypatch.setenv('TOC_ROS_CACHE_DIR', str(tmp_path))
    monkeypatch.setenv('CXX', str(tmp_path / 'no-such-compiler'))
    with pytest.raises(pin_batch.BuildError, match='cannot run the C\\+\\+ compiler'):
        pin_batch.build()
    assert list(tmp_path.iterdir()) == []
    monkeypatch.setenv('CXX', 'false')      # a compiler that fails
    with pytest.raises(pin_batch.BuildError, match='failed'):
        pin_batch.build()
    assert list(tmp_path.iterdir()) == []
    assert pin_batch.main([]) == 1
