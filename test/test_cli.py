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

"""toc-solve as a subprocess (python -m toc_ros.solve): the JSON contract and exit codes."""

import json
import os
from pathlib import Path
import pty
import select
import signal
import subprocess
import sys
import time

import numpy as np
import numpy_model as nm
import pytest

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]
CONTRACT_KEYS = {'status', 'message', 'final_time', 'integrator', 'N', 'iterations',
                 'wall_time_s', 'states', 'controls', 'violations'}
VIOLATION_KEYS = {'max_control_excess', 'terminal_error', 'min_clearance'}


def _env():
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(filter(None, [str(ROOT), env.get('PYTHONPATH')]))
    return env


def _run(*args, timeout=300):
    return subprocess.run([sys.executable, '-m', 'toc_ros.solve', *args], cwd=ROOT,
                          env=_env(), capture_output=True, text=True, timeout=timeout)


def _load(path, n):
    with open(path) as stream:
        data = json.load(stream)
    assert CONTRACT_KEYS <= set(data), set(data)
    assert set(data['violations']) == VIOLATION_KEYS
    assert data['N'] == n
    assert np.shape(data['states']) == (n + 1, 4)
    assert np.shape(data['controls']) == (n, 2)
    return data


def test_paper_scenario_fast_mode_json(tmp_path):
    out = tmp_path / 'paper.json'
    proc = _run('--mode', 'fast', '--N', '1000', '--json', str(out))
    assert proc.returncode == 0, proc.stderr
    assert 'SOLVED' in proc.stdout and 't_min' in proc.stdout
    data = _load(out, 1000)
    assert data['status'] == 'SOLVED' and data['integrator'] == 'euler'
    assert isinstance(data['iterations'], int) and data['wall_time_s'] > 0.0
    controls = np.array(data['controls'])
    measured = nm.violations(nm.X0, nm.XG, controls, data['final_time'], nm.PAPER_CIRCLES)
    assert np.all(np.abs(controls) <= nm.U_MAX)
    assert measured['terminal_error'] <= 1e-6
    assert measured['min_clearance'] >= -1e-6
    np.testing.assert_allclose(data['states'], measured['states'], rtol=0, atol=1e-9)
    assert data['violations']['terminal_error'] == pytest.approx(measured['terminal_error'],
                                                                 abs=1e-9)
    assert abs(data['final_time'] - nm.T_STAR_PAPER) <= 1e-3 * nm.T_STAR_PAPER


def test_obstacle_containing_the_base_exits_4_with_a_message(tmp_path):
    out = tmp_path / 'bad.json'
    proc = _run('--obstacle', '0', '0', '0.5', '--json', str(out))
    assert proc.returncode == 4
    assert 'base' in proc.stderr and 'Traceback' not in proc.stderr
    with open(out) as stream:
        assert json.load(stream)['status'] == 'INVALID_INPUT'


@pytest.mark.parametrize('args', [['--start', '1', '2', '3'], ['--mode', 'slow'],
                                  ['--N', 'many'], ['--obstacle', '1', '1'],
                                  ['--no-obstacles', '--obstacle', '1', '1', '0.2']])
def test_argument_errors_exit_2(args):
    proc = _run(*args)
    assert proc.returncode == 2
    assert 'usage' in proc.stderr and 'Traceback' not in proc.stderr


def test_bad_config_file_exits_4(tmp_path):
    config = tmp_path / 'bad.yaml'
    config.write_text('/**:\n  ros__parameters:\n    solver:\n      N: many\n')
    proc = _run('--config', str(config))
    assert proc.returncode == 4 and 'Traceback' not in proc.stderr
    missing = _run('--config', str(tmp_path / 'missing.yaml'))
    assert missing.returncode == 4 and 'missing.yaml' in missing.stderr


def test_no_obstacles_with_start_and_goal(tmp_path):
    out = tmp_path / 'free.json'
    proc = _run('--no-obstacles', '--N', '200', '--start', '0.5', '1.2', '--goal', '1.5', '0.9',
                '--json', str(out))
    assert proc.returncode == 0, proc.stderr
    data = _load(out, 200)
    states = np.array(data['states'])
    # Velocities default to zero.
    np.testing.assert_allclose(states[0], [0.5, 0.0, 1.2, 0.0], atol=1e-15)
    measured = nm.violations(states[0], [1.5, 0.0, 0.9, 0.0], data['controls'],
                             data['final_time'], np.zeros((0, 3)))
    assert measured['terminal_error'] <= 1e-6
    assert data['violations']['min_clearance'] is None       # no obstacles: +inf -> null
    # The straight swing cuts the paper's circle: the config's obstacle really was dropped.
    assert np.min(nm.clearance(states, nm.PAPER_CIRCLES)) < -0.05


def test_paper_mode_with_few_iterations_writes_json(tmp_path):
    out = tmp_path / 'paper_mode.json'
    proc = _run('--mode', 'paper', '--max-iterations', '500', '--json', str(out))
    assert proc.returncode in (1, 2), proc.stderr
    data = _load(out, 1000)
    assert data['status'] == {1: 'SOLVED_INACCURATE', 2: 'MAX_ITERATIONS'}[proc.returncode]
    assert data['iterations'] == 500 and data['mode'] == 'paper'
    assert data['status'] in proc.stdout


def test_overrides_reach_the_problem(tmp_path):
    """Two --obstacle flags, --margin, --integrator, --N, --variant and --config all apply."""
    config = tmp_path / 'scenario.yaml'
    config.write_text('/**:\n  ros__parameters:\n    solver:\n      N: 600\n'
                      '      t_f0: 2.6\n')
    out = tmp_path / 'overrides.json'
    circles = [(1.2, 0.9, 0.15), (-0.4, 1.8, 0.1)]
    args = ['--config', str(config), '--N', '1000', '--mode', 'paper', '--max-iterations', '50',
            '--integrator', 'rk4', '--margin', '0.02', '--variant', 'eq36', '--json', str(out)]
    for c in circles:
        args += ['--obstacle'] + [str(v) for v in c]
    proc = _run(*args)
    assert proc.returncode in (1, 2), proc.stderr
    data = _load(out, 1000)                  # --N wins over the file's N
    assert data['integrator'] == 'rk4'
    assert data['time_grid'][-1] == pytest.approx(2.6)     # t_f0 from the file, not accepted
    inflated = np.array(circles) + [0.0, 0.0, 0.02]
    measured = nm.violations(nm.X0, nm.XG, data['controls'], data['final_time'], inflated,
                             integrator='rk4', variant='eq36')
    np.testing.assert_allclose(data['states'], measured['states'], rtol=0, atol=1e-9)
    assert data['violations']['min_clearance'] == pytest.approx(measured['min_clearance'],
                                                                abs=1e-9)


def test_diverging_paper_mode_still_writes_strict_json(tmp_path):
    # The paper's eta = 1000 is tuned for N = 1000; at N = 60 the iteration blows up to NaN.
    out = tmp_path / 'diverged.json'
    proc = _run('--mode', 'paper', '--N', '60', '--max-iterations', '50', '--json', str(out))
    assert proc.returncode == 2, proc.stderr

    def reject(constant):
        raise AssertionError(f'non-JSON number {constant}')

    with open(out) as stream:
        data = json.load(stream, parse_constant=reject)
    assert data['status'] in ('MAX_ITERATIONS', 'STALLED') and data['N'] == 60


def test_ctrl_c_cancels_and_returns_the_best_so_far(tmp_path):
    out = tmp_path / 'canceled.json'
    master, slave = pty.openpty()      # stderr on a terminal: the progress line shows the start
    proc = subprocess.Popen(
        [sys.executable, '-m', 'toc_ros.solve', '--mode', 'paper', '--max-iterations',
         '1000000', '--timeout', '0', '--json', str(out)],
        cwd=ROOT, env=_env(), stdout=subprocess.PIPE, stderr=slave, text=True)
    os.close(slave)
    seen = b''
    try:
        deadline = time.monotonic() + 120.0
        while b' it ' not in seen:
            assert time.monotonic() < deadline and proc.poll() is None, seen
            if select.select([master], [], [], 0.2)[0]:
                seen += os.read(master, 4096)
        proc.send_signal(signal.SIGINT)
        while proc.poll() is None:          # keep draining the terminal while it stops
            if select.select([master], [], [], 0.1)[0]:
                try:
                    seen += os.read(master, 4096)
                except OSError:
                    break
        stdout = proc.communicate(timeout=30)[0]
    finally:
        if proc.poll() is None:
            proc.kill()
        os.close(master)
    assert proc.returncode == 3, seen
    assert 'CANCELED' in stdout and b'Traceback' not in seen
    data = _load(out, 1000)
    assert data['status'] == 'CANCELED' and 0 < data['iterations'] < 1000000


def test_model_planar_2r_solves_and_reintegrates_independently(tmp_path):
    out = tmp_path / 'planar.json'
    proc = _run('--model', 'planar_2r', '--no-obstacles', '--N', '100', '--start', '0', '1',
                '--goal', '1', '0.5', '--json', str(out))
    assert proc.returncode == 0, proc.stderr
    assert 'model       planar_2r' in proc.stdout
    data = _load(out, 100)
    controls = np.array(data['controls'])
    assert np.all(np.abs(controls) <= np.array([250.0, 120.0]) + 1e-9)
    tau = data['final_time'] / 100
    x = np.array([0.0, 0.0, 1.0, 0.0])
    for u in controls:      # the paper's Euler discretisation
        x = x + tau * nm.planar_2r_f(x, u)
    assert np.allclose(x, [1.0, 0.0, 0.5, 0.0], atol=1e-6), x
    assert np.allclose(data['states'][-1], x, atol=1e-9)


def test_model_file_with_param_and_gravity(tmp_path):
    out = tmp_path / 'file.json'
    proc = _run('--model', 'planar_2r.yaml', '--param', 'l1=0.9', '--gravity', '9.81',
                '--no-obstacles', '--N', '100', '--start', '0', '1', '0', '0', '--goal', '1',
                '0.5', '--timeout', '0', '--json', str(out), timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert 'model       planar_2r_file' in proc.stdout
    data = _load(out, 100)
    tau = data['final_time'] / 100
    x = np.array([0.0, 0.0, 1.0, 0.0])
    for u in np.array(data['controls']):
        x = x + tau * nm.planar_2r_f(x, u, l1=0.9, g=9.81)
    assert np.allclose(x, [1.0, 0.0, 0.5, 0.0], atol=1e-6), x


@pytest.mark.parametrize('args, code, text', [
    (['--gravity', '9.81'], 2, "robot model 'cylindrical' has no gravity parameter g"),
    (['--model', 'planar_2r', '--start', '1', '2', '3'], 2, '2 or 4 numbers'),
    (['--model', 'planar_2r', '--param', 'l1'], 2, 'NAME=VALUE'),
    (['--model', 'planar_2r', '--param', 'l9=1'], 4, 'no parameter(s) l9'),
    (['--model', 'planar_2r', '--param', 'l1=-1'], 4, 'robot.l1 must be a finite positive'),
    (['--model', 'no_such_model'], 4, "unknown model 'no_such_model'"),
    (['--model', 'no_such_file.yaml'], 4, "no model file 'no_such_file.yaml'"),
])
def test_model_option_errors(args, code, text):
    proc = _run(*args, '--N', '50')
    assert proc.returncode == code, proc.stderr
    assert text in proc.stderr, proc.stderr


def test_bad_model_file_exits_4(tmp_path):
    bad = tmp_path / 'bad.yaml'
    bad.write_text('name: bad\njoints: [{name: j1, kind: revolute}]\nparameters: {}\n'
                   'u_max: [1.0]\nlinks: [[0, 0, cos(q1), sin(q1)]]\n'
                   'dynamics: [dq1, u1 +* 2]\n')
    proc = _run('--model', str(bad), '--no-obstacles', '--N', '50', '--start', '0',
                '--goal', '1')
    assert proc.returncode == 4, proc.stderr
    assert 'invalid problem' in proc.stderr and 'bad.yaml' in proc.stderr, proc.stderr
