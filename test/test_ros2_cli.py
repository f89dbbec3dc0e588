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
toc_ros as a ROS user gets it: colcon build, ros2 run, ros2 launch, colcon test.

Needs a ROS 2 Jazzy environment: `ros2` and `colcon` on PATH, or the one that
.ci/ros2_env.sh builds in <repo>/.ros2env. Skipped without either. Every command runs in a
bash subshell that sources the underlay and the workspace, as a user's terminal would, with
the caller's PYTHONPATH/venv removed so that only the colcon-installed package is used.
"""

import os
import random
import re
import shutil
import signal
import subprocess
import sys
import time

import pytest
import yaml

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXECUTABLES = ('solver_node', 'plant_node', 'recorder_node', 'replay_node')
LAUNCHED = ('solver_node', 'plant_node', 'recorder_node')
# What `colcon build` copies: the package as a user clones it.
PACKAGE_ITEMS = ('package.xml', 'setup.py', 'setup.cfg', 'resource', 'toc_ros', 'launch',
                 'config', 'test', 'README.md', 'LICENSE')
LINT_TESTS = ('test/test_flake8.py', 'test/test_pep257.py', 'test/test_copyright.py')
READY_TIMEOUT = 120.0   # [s] start-up with the workspace's numba cache warm (see ws)
WARM_TIMEOUT = 900.0    # [s] compiling every kernel once into a fresh workspace, on a busy CI
STOP_TIMEOUT = 30.0     # [s] SIGINT to exit, launch's own SIGTERM escalation included


def _find_underlay():
    """Return the setup.bash of the ROS environment to use, or None."""
    ros2, colcon = shutil.which('ros2'), shutil.which('colcon')
    if ros2 and colcon:
        # <prefix>/bin/ros2 -> <prefix>/setup.bash (/opt/ros/jazzy, or the kit's venv)
        setup = os.path.join(os.path.dirname(os.path.dirname(ros2)), 'setup.bash')
        return setup if os.path.isfile(setup) else ''
    setup = os.path.join(REPO, '.ros2env', 'setup.bash')
    if os.path.isfile(os.path.join(REPO, '.ros2env', '.toc_ros_env_ready')):
        return setup
    return None


UNDERLAY = _find_underlay()
pytestmark = [pytest.mark.slow, pytest.mark.skipif(
    UNDERLAY is None,
    reason='no ROS 2 environment: ros2/colcon not on PATH and no .ros2env '
           '(build it with .ci/ros2_env.sh)')]


def _child_env(log_dir):
    env = dict(os.environ)
    # The caller's venv and source tree must not leak into the workspace's processes; the
    # underlay's setup.bash, sourced again in every subshell, sets what ROS needs.
    env.pop('PYTHONPATH', None)
    if UNDERLAY:
        for name in ('AMENT_PREFIX_PATH', 'CMAKE_PREFIX_PATH', 'COLCON_PREFIX_PATH',
                     'VIRTUAL_ENV', 'PYTHONHOME', 'ROS_LOCALHOST_ONLY'):
            env.pop(name, None)
        venv_bin = os.path.join(sys.prefix, 'bin')
        env['PATH'] = os.pathsep.join(
            p for p in env.get('PATH', '').split(os.pathsep) if p and p != venv_bin)
        # The ROS wheels of this venv put their libraries on LD_LIBRARY_PATH and mark that
        # done: the underlay's wheels must set up their own (else, e.g., its control_msgs type
        # support does not load).
        env.pop('_ROS_WHEELS_BOOTSTRAP_COMPLETE', None)
        libraries = [p for p in env.pop('LD_LIBRARY_PATH', '').split(os.pathsep)
                     if p and not p.startswith(sys.prefix)]
        if libraries:
            env['LD_LIBRARY_PATH'] = os.pathsep.join(libraries)
    env.update({
        'ROS_DOMAIN_ID': str(random.randint(1, 100)),
        'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
        'ROS_LOG_DIR': str(log_dir),
        'PYTHONUNBUFFERED': '1',
    })
    return env


class Workspace:
    """A colcon workspace holding a copy of this package, and a way to run commands in it."""

    def __init__(self, root, env):
        self.root = root
        self.env = env

    def script(self, command, installed=True):
        lines = ['set -e']
        if UNDERLAY:
            lines.append(f'source "{UNDERLAY}"')
        if installed:
            lines.append(f'source "{self.root}/install/setup.bash"')
        lines.append(f'cd "{self.root}"')
        lines.append('exec ' + command)
        return '\n'.join(lines)

    def run(self, command, timeout, installed=True):
        try:
            return subprocess.run(
                ['bash', '-c', self.script(command, installed)], env=self.env,
                stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                text=True, timeout=timeout)
        except subprocess.TimeoutExpired as e:
            pytest.fail(f'`{command}` did not finish in {timeout} s:\n{e.stdout}')

    def start(self, command, log_path):
        """Start a long-running command in its own process group, output to log_path."""
        with open(log_path, 'w') as log:
            return subprocess.Popen(
                ['bash', '-c', self.script(command)], env=self.env,
                stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                start_new_session=True)


def _read(path):
    with open(path, errors='replace') as f:
        return f.read()


def _wait_until(predicate, timeout, interval=0.5):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(interval)
    return predicate()


def _stop(proc, timeout=STOP_TIMEOUT, group=True):
    """SIGINT (Ctrl-C) the process (group); return its exit code, None if it had to be killed."""
    if proc.poll() is None:
        if group:
            os.killpg(proc.pid, signal.SIGINT)
        else:
            proc.send_signal(signal.SIGINT)
    try:
        return proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        return None


def _kill(proc):
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


@pytest.fixture(scope='module')
def ws(tmp_path_factory):
    root = tmp_path_factory.mktemp('ws')
    src = root / 'src' / 'toc_ros'
    src.mkdir(parents=True)
    ignore = shutil.ignore_patterns('__pycache__', '*.pyc', '*.egg-info', '.pytest_cache')
    for item in PACKAGE_ITEMS:
        path = os.path.join(REPO, item)
        if os.path.isdir(path):
            shutil.copytree(path, src / item, ignore=ignore)
        elif os.path.isfile(path):
            shutil.copy2(path, src / item)
    workspace = Workspace(root, _child_env(tmp_path_factory.mktemp('ros_log')))
    # No --symlink-install: test what a plain install (and a binary package) contains.
    build = workspace.run('colcon build --event-handlers console_direct+', timeout=300,
                          installed=False)
    assert build.returncode == 0, f'colcon build failed:\n{build.stdout[-5000:]}'
    # A fresh install has a cold numba cache: compile it once here (what a user's first start
    # does), so that the tests' start-up waits measure a start, not a compile under CI load.
    warm = workspace.run("python3 -c 'from toc_ros.core import warm_up; warm_up()'",
                         timeout=WARM_TIMEOUT)
    assert warm.returncode == 0, f'warming the numba cache failed:\n{warm.stdout[-5000:]}'
    return workspace


def test_executables_are_installed(ws):
    result = ws.run('ros2 pkg executables toc_ros', timeout=60)
    assert result.returncode == 0, result.stdout
    listed = {line.split()[-1] for line in result.stdout.splitlines()
              if line.startswith('toc_ros ')}
    assert set(EXECUTABLES) <= listed, result.stdout


def test_installed_share_files(ws):
    share = ws.root / 'install' / 'toc_ros' / 'share' / 'toc_ros'
    for rel in ('package.xml', 'launch/demo.launch.py', 'config/toc_ros.yaml'):
        assert (share / rel).is_file(), f'{rel} is not installed'


def test_launch_arguments(ws):
    result = ws.run('ros2 launch toc_ros demo.launch.py --show-args', timeout=60)
    assert result.returncode == 0, result.stdout
    for name in ('params_file', 'namespace', 'record', 'output', 'use_sim_time'):
        assert f"'{name}':" in result.stdout, result.stdout
    # The default params file is the installed one, not a path into the source tree.
    assert str(ws.root / 'install' / 'toc_ros' / 'share' / 'toc_ros' / 'config' /
               'toc_ros.yaml') in result.stdout, result.stdout


def test_run_solver_node(ws, tmp_path):
    log = tmp_path / 'solver.log'
    proc = ws.start('ros2 run toc_ros solver_node', log)
    try:
        ready = _wait_until(
            lambda: proc.poll() is not None or re.search(r'\bready\b', _read(log), re.I),
            READY_TIMEOUT)
        assert ready and proc.poll() is None, \
            f'solver_node did not log "ready" within {READY_TIMEOUT} s:\n{_read(log)}'
        rc = _stop(proc)
    finally:
        _kill(proc)
    output = _read(log)
    assert rc == 0, f'solver_node did not exit cleanly on SIGINT (rc={rc}):\n{output}'
    assert 'Traceback' not in output, output


def _node_names(ws):
    result = ws.run('ros2 node list --no-daemon --spin-time 1', timeout=30)
    return set(result.stdout.split()) if result.returncode == 0 else set()


def _solver_ready(log):
    return re.search(r'\[solver_node-\d+\].*\bready\b', _read(log), re.I)


def _launch(ws, log, arguments, expected, check, launch_file='demo.launch.py'):
    """
    Launch launch_file, wait for the expected nodes, run check(), stop with SIGINT.

    Returns the launch output after asserting that launch and every node exited cleanly.
    """
    # --noninteractive: launch itself forwards SIGINT to the nodes (interactive launch leaves
    # that to the terminal's process-group signal, which this test does not send).
    proc = ws.start(f'ros2 launch --noninteractive toc_ros {launch_file} ' + arguments, log)
    try:
        names = set()

        def all_up():
            nonlocal names
            names = _node_names(ws)
            # Launch outlives a node that died: stop waiting then, too.
            return (proc.poll() is not None or set(expected) <= names or
                    'process has died' in _read(log))

        _wait_until(all_up, READY_TIMEOUT, interval=0.0)
        assert set(expected) <= names and proc.poll() is None, \
            f'nodes seen: {sorted(names)}, launch output:\n{_read(log)}'
        check(names)
        # Stop only once the solver is up, as a user would: a clean stop mid-compile is
        # test_run_solver_node's business, not this one's.
        assert _wait_until(lambda: _solver_ready(log), READY_TIMEOUT), _read(log)
        # SIGINT to `ros2 launch` alone, as launch_testing does.
        rc = _stop(proc, group=False)
    finally:
        _kill(proc)
    output = _read(log)
    assert rc == 0, f'ros2 launch did not exit cleanly on SIGINT (rc={rc}):\n{output}'
    for name in expected:
        exe = name.rsplit('/', 1)[-1]
        assert re.search(rf'\[INFO\] \[{exe}-\d+\]: process has finished cleanly', output), \
            f'{exe} did not finish cleanly:\n{output}'
    assert 'Traceback' not in output, output
    return output


def _param(ws, node, name):
    # A fresh CLI process needs discovery time before it sees the node: retry briefly.
    for _ in range(5):
        result = ws.run(f'ros2 param get --no-daemon --spin-time 2 {node} {name}', timeout=30)
        if 'Node not found' not in result.stdout:
            break
    return result.stdout.strip()


def _readme_ros_commands():
    """Return the goal and echo commands of the README's 'ROS 2: three lines', as written."""
    with open(os.path.join(REPO, 'README.md')) as f:
        text = f.read()
    block = text.split('## ROS 2: three lines', 1)[1].split('```bash', 1)[1].split('```', 1)[0]
    lines = [line.split('  #', 1)[0].strip() for line in block.strip().splitlines()]
    publish = [line for line in lines if line.startswith('ros2 topic pub')]
    echo = [line for line in lines if line.startswith('ros2 topic echo')]
    assert len(publish) == 1 and len(echo) == 1, lines
    return publish[0], echo[0]


def test_launch_demo(ws, tmp_path):
    bag = tmp_path / 'bag'
    log = tmp_path / 'launch.log'
    publish, echo = _readme_ros_commands()

    def check(names):
        # The installed params file reaches the nodes (config/toc_ros.yaml: solver.N 1000).
        assert _param(ws, '/solver_node', 'solver.N') == 'Integer value is: 1000'
        assert _wait_until(lambda: _solver_ready(log), READY_TIMEOUT), _read(log)
        # The README's goal, sent three times as written while recorder_node records: with
        # `-w 1` a goal published after the recorder's match alone was lost in 1-4 of 6 sends.
        for sent_goals in range(1, 4):
            sent = ws.run(publish, timeout=60)
            assert sent.returncode == 0, sent.stdout
            assert _wait_until(lambda: len(re.findall(
                r'\[solver_node\]: goal from goal_joints:', _read(log))) >= sent_goals, 30.0), \
                f'goal {sent_goals} of `{publish}` did not reach solver_node:\n{_read(log)}'
        shown = ws.run(echo, timeout=60)
        assert 'rotation_joint' in shown.stdout and 'positions' in shown.stdout, shown.stdout

    output = _launch(ws, log, f'output:={bag}', ['/' + name for name in LAUNCHED], check)
    assert list(bag.glob('*.mcap')), f'no .mcap in output:={bag}:\n{output}'


def test_launch_arguments_apply(ws, tmp_path):
    with open(os.path.join(REPO, 'config', 'toc_ros.yaml')) as f:
        config = yaml.safe_load(f)
    config['/**']['ros__parameters']['solver']['N'] = 500
    params = tmp_path / 'params.yaml'
    params.write_text(yaml.safe_dump(config))

    def check(names):
        assert not any(n.endswith('recorder_node') for n in names), names
        assert _param(ws, '/toc_test/solver_node', 'solver.N') == 'Integer value is: 500'

    _launch(ws, tmp_path / 'launch.log',
            f'namespace:=toc_test record:=false params_file:={params}',
            ['/toc_test/solver_node', '/toc_test/plant_node'], check)


PANDA_GOAL = (0.8, -0.3, 0.0, -2.0, 0.0, 1.8, 0.785)


@pytest.mark.parametrize('execute, interface', [('topic', 'effort'), ('action', 'effort'),
                                                ('action', 'position')])
def test_launch_panda_plans_and_the_mujoco_plant_arrives(ws, tmp_path, execute, interface):
    """
    panda.launch.py: a joint goal is planned, executed (topic or action) and reached.

    command_interface:=position: the plant is a position-controlled arm whose controller
    refuses goals with efforts; the launch file has the solver send them without.
    """
    if execute == 'action':
        probe = ws.run("python3 -c 'import control_msgs.action'", timeout=60)
        if probe.returncode != 0:
            pytest.skip('control_msgs is not installed in this ROS environment')
    names = ', '.join(f'panda_joint{i}' for i in range(1, 8))
    goal = ', '.join(str(q) for q in PANDA_GOAL)
    log = tmp_path / 'launch.log'

    def check(_names):
        assert _wait_until(lambda: _solver_ready(log), READY_TIMEOUT), _read(log)
        # --keep-alive: ros2 topic pub's default 0.1 s can end the publisher before the
        # solver's (volatile) subscription has matched it on a loaded machine: the goal is lost.
        sent = ws.run(f'ros2 topic pub --once --keep-alive 1 goal_joints '
                      f'sensor_msgs/msg/JointState "{{name: [{names}], position: [{goal}]}}"',
                      timeout=60)
        assert sent.returncode == 0, sent.stdout
        assert _wait_until(lambda: 'SOLVED for goal from goal_joints' in _read(log), 120.0), \
            _read(log)
        if execute == 'action':
            # The solver's trajectory topic is remapped away: only the action reaches the plant.
            assert re.search(r'action server \S*follow_joint_trajectory found', _read(log)), \
                _read(log)
            assert ('FollowJointTrajectory, with efforts)' in _read(log)) is (
                interface == 'effort'), _read(log)

        def arrived():      # the plant rests at the goal: its joint_states, by the ROS CLI
            echo = ws.run('ros2 topic echo --once --no-daemon --field position joint_states',
                          timeout=30)
            values = [float(v) for v in re.findall(r'-?\d+\.\d+(?:e-?\d+)?', echo.stdout)]
            return len(values) == 7 and max(
                abs(v - g) for v, g in zip(values, PANDA_GOAL)) < 1e-3
        assert _wait_until(arrived, 60.0, interval=1.0), _read(log)

    _launch(ws, log, f'record:=false execute:={execute} command_interface:={interface}',
            ['/solver_node', '/plant_node'], check, launch_file='panda.launch.py')


def test_colcon_test_linters(ws):
    # Only the ament linters: the rest of the suite already runs outside colcon.
    result = ws.run('colcon test --packages-select toc_ros --return-code-on-test-failure '
                    '--pytest-args ' + ' '.join(LINT_TESTS), timeout=300)
    summary = ws.run('colcon test-result --verbose', timeout=60)
    assert result.returncode == 0, result.stdout + summary.stdout
    assert summary.returncode == 0, summary.stdout
    match = re.search(r'Summary: (\d+) tests?, (\d+) errors?, (\d+) failures?, (\d+) skipped',
                      summary.stdout)
    assert match, summary.stdout
    tests, errors, failures, skipped = map(int, match.groups())
    # test_copyright must really run here: ament_copyright is part of the ROS environment.
    assert (tests, errors, failures, skipped) == (len(LINT_TESTS), 0, 0, 0), summary.stdout
