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
toc-demo: the closed-loop demo, solver_node + plant_node + recorder_node as separate processes.

On a private ROS domain (a random ROS_DOMAIN_ID unless one is set; localhost discovery) it
starts the three nodes, waits until the solver is ready and the plant publishes joint_states,
sends the paper's obstacle and goal, lets the plant execute the minimum-time trajectory, then
sends a second goal with a changed obstacle set (the solver replans from the plant's measured
state), stops every process with SIGINT and prints a summary, also written to
``summary.json`` next to the recording (default ``runs/<UTC timestamp>/``).

Exit code 0 when both plans were SOLVED, the plant came to rest within POSITION_TOL of each
goal and every process exited cleanly (so the recording is complete); 1 otherwise; 2 for bad
arguments; 130 when interrupted.
"""

import argparse
import dataclasses
import json
import math
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from rcl_interfaces.srv import GetParameters
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension
from toc_ros import config
from toc_ros.recording.process import default_output_dir, recorder_command
from trajectory_msgs.msg import JointTrajectory

# The folder holding the toc_ros package: put on the children's PYTHONPATH so that the demo
# also runs from a source tree that is not installed.
_PACKAGE_PARENT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@dataclasses.dataclass(frozen=True)
class Stage:
    """One goal of the demo: joint target (q1 rad, q2 m) and the obstacle set sent before."""

    label: str
    q_goal: tuple
    obstacles: tuple


STAGES = (
    # Section 4 of the paper: to q = (5 pi/12, 1 m) around one circle.
    Stage('paper goal', (5.0 * math.pi / 12.0, 1.0), ((1.0, 1.0, 0.2),)),
    # Back past a moved circle and a new one, starting wherever the plant came to rest.
    Stage('replan', (math.pi / 12.0, 0.8), ((0.9, 1.2, 0.2), (1.5, 0.6, 0.15))),
)

# Acceptance: |q - q_goal| per joint once the plant is at rest [rad, m].  The plant's PD (the
# default gains of parameters.PlantSettings) rests within ~1e-5 of the goal about 0.8 s after
# the end.
POSITION_TOL = (1e-3, 1e-3)
# At rest: every joint_states sample over SETTLE_WINDOW_S within these bounds.
SETTLE_POSITION = 1e-3      # [rad, m]
SETTLE_VELOCITY = 1e-3      # [rad/s, m/s]
SETTLE_WINDOW_S = 0.3
# Longest wait for rest after the trajectory's end.
SETTLE_TIMEOUT_S = 5.0
# The trajectory must end at the goal (the solver's SOLVED tolerance is far below).
TRAJECTORY_END_TOL = 1e-6
PROGRESS_PRINT_PERIOD_S = 0.5
STOP_TIMEOUT_S = 10.0
REQUIRED_TOPICS = (
    '/goal_pose', '/goal_joints', '/obstacles', '/trajectory', '/planned_path', '/markers',
    '/solver_node/progress', '/joint_states', '/plant_node/tracking')
# Topics that must be recorded before the first goal (/goal_joints has no publisher here).
WATCHED_TOPICS = tuple(t for t in REQUIRED_TOPICS if t != '/goal_joints')
RECORDER_NODE = 'recorder_node'
LATCHED = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     reliability=ReliabilityPolicy.RELIABLE)


class DemoError(RuntimeError):
    """The demo cannot go on (a node died, a wait timed out); the message says why."""


class _Interrupted(Exception):
    """SIGINT or SIGTERM of the demo itself."""


# -- output ------------------------------------------------------------------------------------

class _Printer:
    def __init__(self, quiet):
        self.quiet = quiet
        self.start = time.monotonic()

    def stage(self, text):
        if not self.quiet:
            print(f'[{time.monotonic() - self.start:6.1f} s] {text}', flush=True)

    def detail(self, text):
        if not self.quiet:
            print(f'           {text}', flush=True)


# -- child processes ---------------------------------------------------------------------------

class _Child:
    """A node process in its own session (the demo decides when and how it stops)."""

    def __init__(self, name, argv, env, log_path):
        self.name = name
        self.log_path = log_path
        self._log = open(log_path, 'w')
        self.process = subprocess.Popen(argv, env=env, stdout=self._log,
                                        stderr=subprocess.STDOUT, start_new_session=True)
        self.exit_code = None
        self.stopped_by = None      # the last signal sent

    def alive(self):
        return self.process.poll() is None

    def log_text(self):
        try:
            with open(self.log_path, errors='replace') as stream:
                return stream.read()
        except OSError:
            return ''

    def tail(self, lines=20):
        return '\n'.join(self.log_text().splitlines()[-lines:])

    def _signal(self, sig):
        if self.process.poll() is None:
            self.stopped_by = signal.Signals(sig).name
            self.process.send_signal(sig)

    def interrupt(self):
        """Send SIGINT once (a second one would interrupt the node's own clean-up)."""
        if self.stopped_by is None:
            self._signal(signal.SIGINT)

    def stop(self, timeout=STOP_TIMEOUT_S):
        """SIGINT, then SIGTERM, then SIGKILL if it hangs; return the exit code."""
        if self.exit_code is not None:
            return self.exit_code
        self.interrupt()
        for sig in (None, signal.SIGTERM, signal.SIGKILL):
            if sig is not None:
                self._signal(sig)
            try:
                self.process.wait(timeout)
                break
            except subprocess.TimeoutExpired:
                continue
        self.exit_code = self.process.wait()
        self._log.close()
        return self.exit_code


def child_environment(env=None):
    """
    Environment of the nodes: the caller's with this toc_ros first on PYTHONPATH.

    (Importing toc_ros already set AMENT_PREFIX_PATH for a plain venv, see toc_ros/__init__.)
    """
    env = dict(os.environ if env is None else env)
    paths = [p for p in env.get('PYTHONPATH', '').split(os.pathsep) if p]
    env['PYTHONPATH'] = os.pathsep.join([_PACKAGE_PARENT] + [
        p for p in paths if p != _PACKAGE_PARENT])
    env['PYTHONUNBUFFERED'] = '1'
    return env


def node_command(module, params_file, extra=()):
    """Argv of a toc_ros node run with python -m and the scenario's parameter file."""
    return [sys.executable, '-m', f'toc_ros.nodes.{module}', '--ros-args',
            '--params-file', params_file] + list(extra)


def kernel_cache_found():
    """Tell whether numba's cache holds compiled toc_ros kernels (else the solver compiles)."""
    import numba
    import toc_ros.core  # noqa: F401 - points numba's cache at the core's directory
    cache_dir = numba.config.CACHE_DIR
    return bool(cache_dir) and os.path.isdir(cache_dir) and any(
        name.endswith('.nbi') for _, _, files in os.walk(cache_dir) for name in files)


# -- ROS side ----------------------------------------------------------------------------------

def obstacles_msg(rows):
    """Float64MultiArray with rows (x, y, radius) and a (rows, 3) layout."""
    msg = Float64MultiArray()
    msg.layout.dim = [MultiArrayDimension(label='rows', size=len(rows), stride=3 * len(rows)),
                      MultiArrayDimension(label='x_y_radius', size=3, stride=3)]
    msg.data = [float(v) for row in rows for v in row]
    return msg


def goal_pose_msg(q_goal, a, frame_id):
    """Build the hand's PoseStamped at joint position (q1, q2): x = (a + q2) cos q1, y = ..."""
    msg = PoseStamped()
    msg.header.frame_id = frame_id
    reach = a + q_goal[1]
    msg.pose.position.x = reach * math.cos(q_goal[0])
    msg.pose.position.y = reach * math.sin(q_goal[0])
    msg.pose.orientation.z = math.sin(0.5 * q_goal[0])
    msg.pose.orientation.w = math.cos(0.5 * q_goal[0])
    return msg


class _Link:
    """The demo's own node: publishes goals and obstacles, collects what the nodes report."""

    def __init__(self, joint_names):
        self.node = rclpy.create_node('toc_demo')
        self.joint_names = list(joint_names)
        self.lock = threading.Lock()
        self.progress = []          # (monotonic time, level, message, values)
        self.joint_state = None     # (monotonic time, positions, velocities)
        self.joint_state_count = 0
        self.tracking = []          # (monotonic time, values)
        self.trajectories = []      # (monotonic time, JointTrajectory)
        node = self.node
        self.goal_pub = node.create_publisher(PoseStamped, '/goal_pose', LATCHED)
        self.obstacles_pub = node.create_publisher(Float64MultiArray, '/obstacles', LATCHED)
        node.create_subscription(DiagnosticStatus, '/solver_node/progress', self._on_progress,
                                 100)
        node.create_subscription(JointState, '/joint_states', self._on_joint_state, 10)
        node.create_subscription(DiagnosticStatus, '/plant_node/tracking', self._on_tracking,
                                 10)
        node.create_subscription(JointTrajectory, '/trajectory', self._on_trajectory, LATCHED)
        self.parameters = node.create_client(GetParameters, '/solver_node/get_parameters')
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self):
        while rclpy.ok():
            try:
                self.executor.spin_once(timeout_sec=0.05)
            except Exception:  # noqa: B902 - the context went down while spinning
                if rclpy.ok():
                    raise
                return

    def _on_progress(self, msg):
        values = {kv.key: kv.value for kv in msg.values}
        with self.lock:
            self.progress.append((time.monotonic(), msg.level, msg.message, values))

    def _on_joint_state(self, msg):
        names = list(msg.name)
        try:
            index = [names.index(n) for n in self.joint_names]
            positions = [float(msg.position[i]) for i in index]
            velocities = [float(msg.velocity[i]) for i in index]
        except (ValueError, IndexError):
            return
        with self.lock:
            self.joint_state = (time.monotonic(), positions, velocities)
            self.joint_state_count += 1

    def _on_tracking(self, msg):
        values = {kv.key: kv.value for kv in msg.values}
        with self.lock:
            self.tracking.append((time.monotonic(), values))
            del self.tracking[:-50]

    def _on_trajectory(self, msg):
        with self.lock:
            self.trajectories.append((time.monotonic(), msg))

    def subscribers(self, topic):
        """Names of the nodes subscribed to topic (as this node discovered them)."""
        return {info.node_name for info in self.node.get_subscriptions_info_by_topic(topic)}

    def solver_obstacles(self, timeout=2.0):
        """Return the solver's obstacle rows (its parameters); None when it does not answer."""
        if not self.parameters.service_is_ready():
            return None
        request = GetParameters.Request(names=['obstacles.x', 'obstacles.y', 'obstacles.radius'])
        future = self.parameters.call_async(request)
        done = threading.Event()
        future.add_done_callback(lambda _f: done.set())
        if not done.wait(timeout) or future.result() is None:
            return None
        columns = [list(v.double_array_value) for v in future.result().values]
        if len(columns) != 3:
            return None
        return tuple(zip(*columns))

    def close(self):
        self.node.destroy_node()


# -- the run -----------------------------------------------------------------------------------

class Demo:
    """One run of the demo: start, wait_ready, run_stage per Stage, stop; fills summary."""

    def __init__(self, args, printer):
        self.args = args
        self.out = printer
        self.deadline = time.monotonic() + args.timeout
        self.params_file = config.default_config_path()
        params = config.load_parameters(self.params_file, 'solver_node')
        self.a = float(params['robot.a'])
        self.base_frame = str(params['base_frame'])
        self.joint_names = list(params['joint_names'])
        self.solver_timeout = float(params['solver.timeout'])
        self.children = {}
        self.link = None
        self.summary = {'plans': [], 'position_tolerance': list(POSITION_TOL),
                        'joint_names': self.joint_names, 'robot_a': self.a,
                        'base_frame': self.base_frame, 'ros_domain_id':
                        os.environ.get('ROS_DOMAIN_ID'), 'recording': None}

    # waiting ------------------------------------------------------------------------------------

    def _check_children(self):
        for child in self.children.values():
            if not child.alive():
                raise DemoError(f'{child.name} exited with code {child.process.returncode}:\n'
                                f'{child.tail()}')

    def _wait(self, predicate, what, timeout=None, tick=None, optional=False):
        """
        Poll predicate until truthy and return its value.

        DemoError when a node exits or the time is up; after an optional wait's own timeout
        (not the demo's --timeout) the result is None instead.
        """
        own_end = math.inf if timeout is None else time.monotonic() + timeout
        while True:
            value = predicate()
            if value:
                return value
            self._check_children()
            now = time.monotonic()
            if now > self.deadline:
                raise DemoError(f'timed out waiting for {what} (--timeout)')
            if now > own_end:
                if optional:
                    return None
                raise DemoError(f'timed out waiting for {what}')
            if tick is not None:
                tick()
            time.sleep(0.02)

    # start --------------------------------------------------------------------------------------

    def start(self, log_dir):
        env = child_environment()
        if self.args.record:
            argv = recorder_command(self.args.output, extra_ros_args=[
                '-r', f'__node:={RECORDER_NODE}'])
            self.children['recorder'] = _Child(RECORDER_NODE, argv, env,
                                               os.path.join(log_dir, 'recorder_node.log'))
        for name in ('solver_node', 'plant_node'):
            self.children[name] = _Child(name, node_command(name, self.params_file), env,
                                         os.path.join(log_dir, f'{name}.log'))
        self.link = _Link(self.joint_names)

    def wait_ready(self):
        out = self.out
        started = time.monotonic()
        cached = kernel_cache_found()
        if cached:
            out.stage('solver_node: loading the numba kernels from the cache ...')
        else:
            out.stage('solver_node: first run, compiling the numba kernels '
                      '(about a minute; cached for later runs) ...')
        last = [started]

        def tick():
            if time.monotonic() - last[0] >= 10.0:
                last[0] = time.monotonic()
                out.detail(f'still waiting for solver_node ({last[0] - started:.0f} s): '
                           + ('kernels missing from the cache are compiled' if cached
                              else 'compiling'))

        self._wait(lambda: 'solver_node' in self.link.subscribers('/goal_pose'),
                   'solver_node to become ready', tick=tick)
        found = re.search(r'numba kernels \w+ in ([0-9.]+) s',
                          self.children['solver_node'].log_text())
        if found:
            self.summary['kernel_load_s'] = float(found.group(1))
        out.stage(f'solver_node ready ({time.monotonic() - started:.1f} s)')
        self._wait(lambda: self.link.joint_state is not None, 'joint_states from plant_node',
                   timeout=30.0)
        out.stage('plant_node publishes joint_states')
        subscribers = 2 if self.args.record else 1
        self._wait(lambda: (self.link.goal_pub.get_subscription_count() >= subscribers
                            and self.link.obstacles_pub.get_subscription_count() >= subscribers
                            and 'solver_node' in self.link.subscribers('/joint_states')
                            and 'plant_node' in self.link.subscribers('/trajectory')),
                   'the nodes to connect', timeout=30.0)
        self._wait(lambda: self.link.parameters.service_is_ready(),
                   "solver_node's parameter service", timeout=30.0)
        if self.args.record:
            self._wait(lambda: all(RECORDER_NODE in self.link.subscribers(t)
                                   for t in WATCHED_TOPICS),
                       f'recorder_node to subscribe to {", ".join(WATCHED_TOPICS)}',
                       timeout=30.0)
            out.stage(f'recorder_node records to {self.args.output}')

    # one goal -----------------------------------------------------------------------------------

    def run_stage(self, number, stage):
        out, link = self.out, self.link
        q_goal = stage.q_goal
        plan = {'label': stage.label, 'goal_q': list(q_goal), 'obstacles':
                [list(r) for r in stage.obstacles]}
        self.summary['plans'].append(plan)
        out.stage(f'plan {number} ({stage.label}): {len(stage.obstacles)} obstacle(s) '
                  f'{list(stage.obstacles)}')
        link.obstacles_pub.publish(obstacles_msg(stage.obstacles))
        expected = tuple(tuple(float(v) for v in row) for row in stage.obstacles)
        self._wait(lambda: link.solver_obstacles() == expected,
                   'solver_node to take the obstacles', timeout=10.0)

        goal = goal_pose_msg(q_goal, self.a, self.base_frame)
        plan['goal_pose'] = [goal.pose.position.x, goal.pose.position.y]
        with link.lock:
            progress_seen = len(link.progress)
            trajectories_seen = len(link.trajectories)
        sent = time.monotonic()
        link.goal_pub.publish(goal)
        out.stage(f'plan {number}: goal_pose ({goal.pose.position.x:.4f}, '
                  f'{goal.pose.position.y:.4f}) m in {self.base_frame}, i.e. q = '
                  f'({q_goal[0]:.4f} rad, {q_goal[1]:.4f} m)')

        printed = [0.0]

        def final():
            with link.lock:
                for _, level, message, values in link.progress[progress_seen:]:
                    if values.get('status') != 'SOLVING':
                        return level, message, values
                latest = link.progress[-1] if len(link.progress) > progress_seen else None
            if latest is not None and time.monotonic() - printed[0] >= PROGRESS_PRINT_PERIOD_S:
                printed[0] = time.monotonic()
                v = latest[3]
                best = _num(v.get('best_feasible_t_f'))
                out.detail(f"solving: {_num(v.get('elapsed_s')):.1f} s, iteration "
                           f"{v.get('iteration')}, t_f {_num(v.get('t_f')):.4f} s, best "
                           'feasible t_f ' + ('none yet' if math.isnan(best)
                                              else f'{best:.4f} s'))
            return None

        level, message, values = self._wait(final, f'the result of plan {number}',
                                            timeout=self.solver_timeout + 30.0)
        plan.update(status=values.get('status'), message=message,
                    t_min=_num(values.get('t_f')), solve_wall_time_s=_num(
                        values.get('elapsed_s')), iterations=values.get('iteration'),
                    start_source=values.get('start_source'),
                    goal_to_result_s=time.monotonic() - sent)
        out.stage(f"plan {number}: {plan['status']}: t_min {plan['t_min']:.4f} s, solved in "
                  f"{plan['solve_wall_time_s']:.2f} s ({plan['iterations']} iterations), "
                  f'start from {plan["start_source"]}')
        if plan['status'] != 'SOLVED':
            raise DemoError(f'plan {number} ended {plan["status"]}: {message}')

        def new_trajectory():
            with link.lock:
                return link.trajectories[trajectories_seen:]
        received, trajectory = self._wait(new_trajectory, f'the trajectory of plan {number}',
                                          timeout=10.0)[-1]
        start, end = trajectory.points[0], trajectory.points[-1]
        duration = _duration(end.time_from_start)
        plan['trajectory'] = {'points': len(trajectory.points), 'duration_s': duration,
                              'start_q': list(start.positions), 'end_q': list(end.positions)}
        end_error = max(abs(e - g) for e, g in zip(end.positions, q_goal))
        if end_error > TRAJECTORY_END_TOL:
            raise DemoError(f'plan {number}: the trajectory ends {end_error:.3g} from the goal')
        out.stage(f'plan {number}: plant_node executes {len(trajectory.points)} points, '
                  f'{duration:.4f} s')
        self._execute(number, plan, received, duration)

    def _execute(self, number, plan, received, duration):
        """Wait until the plant rests at the goal (or gave up), record the final error."""
        link, q_goal = self.link, plan['goal_q']
        window = []   # receipt times of the resting samples since the last moving one
        seen = [0]

        def settled():
            with link.lock:
                count, state = link.joint_state_count, link.joint_state
            if count == seen[0] or state is None:
                return False
            seen[0] = count
            stamp, positions, velocities = state
            errors = [abs(p - g) for p, g in zip(positions, q_goal)]
            if (stamp - received < duration or max(errors) > SETTLE_POSITION
                    or max(abs(v) for v in velocities) > SETTLE_VELOCITY):
                window.clear()
                return False
            window.append(stamp)
            return window[-1] - window[0] >= SETTLE_WINDOW_S

        at_rest = bool(self._wait(settled, f'plant_node to settle at goal {number}',
                                  timeout=duration + SETTLE_TIMEOUT_S, optional=True))
        with link.lock:
            stamp, positions, velocities = link.joint_state
            tracking = link.tracking[-1][1] if link.tracking else {}
        errors = [p - g for p, g in zip(positions, q_goal)]
        plan.update(
            final_q=positions, final_dq=velocities, final_error=errors,
            final_distance=math.hypot(*errors), at_rest=at_rest,
            settle_time_s=stamp - received - duration,
            max_tracking_error=[_num(tracking.get('max_position_error_q1')),
                                _num(tracking.get('max_position_error_q2'))],
            reached=at_rest and all(abs(e) <= tol for e, tol in zip(errors, POSITION_TOL)))
        self.out.stage(
            f"plan {number}: plant {'at rest' if at_rest else 'NOT at rest'} "
            f'{plan["settle_time_s"]:.2f} s after the trajectory end, error '
            f'({errors[0]:.2e} rad, {errors[1]:.2e} m), max tracking error during execution '
            f'({plan["max_tracking_error"][0]:.2e} rad, {plan["max_tracking_error"][1]:.2e} m)')

    # stop ---------------------------------------------------------------------------------------

    def stop(self):
        """Stop the nodes (recorder last, so it gets their final messages); log exit codes."""
        nodes = [c for n, c in self.children.items() if n != 'recorder']
        for child in nodes:
            child.interrupt()
        for child in nodes + [self.children.get('recorder')]:
            if child is not None:
                child.stop()
        self.summary['exit_codes'] = {c.name: c.exit_code for c in self.children.values()}
        self.summary['stopped_by'] = {c.name: c.stopped_by for c in self.children.values()}
        recorder = self.children.get('recorder')
        if recorder is not None:
            text = recorder.log_text()
            count = None
            if 'recorded ' in text:
                count = text.rsplit('recorded ', 1)[1].split(' ', 1)[0]
            self.summary['recording'] = {
                'path': os.path.abspath(self.args.output),
                'closed_cleanly': recorder.exit_code == 0,
                'messages': int(count) if count and count.isdigit() else None}

    def close(self):
        if self.link is not None:
            self.link.close()


def _num(text):
    try:
        return float(text)
    except (TypeError, ValueError):
        return math.nan


def _duration(msg):
    return msg.sec + 1e-9 * msg.nanosec


def success(summary):
    """Return the demo's verdict: every plan SOLVED and reached, every process exited 0."""
    plans = summary['plans']
    return (len(plans) == len(STAGES) and all(
        p.get('status') == 'SOLVED' and p.get('reached') for p in plans)
        and summary.get('error') is None
        and all(code == 0 for code in summary.get('exit_codes', {None: 1}).values()))


def format_summary(summary):
    """Return the human-readable summary."""
    lines = ['', 'toc-demo summary']
    tol = summary['position_tolerance']
    for k, plan in enumerate(summary['plans'], 1):
        q = plan['goal_q']
        lines.append(f"  plan {k} ({plan['label']}) to q = ({q[0]:.4f} rad, {q[1]:.4f} m), "
                     f"{len(plan['obstacles'])} obstacle(s): {plan.get('status', 'not finished')}")
        if 't_min' in plan:
            lines.append(f"    t_min {plan['t_min']:.4f} s, solve wall time "
                         f"{plan['solve_wall_time_s']:.2f} s ({plan['iterations']} "
                         f"iterations), start from {plan['start_source']}")
        if 'final_error' in plan:
            e = plan['final_error']
            lines.append(
                f'    final tracking error ({e[0]:.2e} rad, {e[1]:.2e} m), distance '
                f"{plan['final_distance']:.2e}: "
                + ('within' if plan['reached'] else 'OUTSIDE')
                + f' the tolerance ({tol[0]:g} rad, {tol[1]:g} m)'
                + ('' if plan['at_rest'] else ', not at rest'))
    recording = summary.get('recording')
    if recording:
        lines.append(f"  recording: {recording['path']} ({recording['messages']} messages, "
                     + ('closed cleanly)' if recording['closed_cleanly'] else
                        'recorder FAILED: see logs)'))
    else:
        lines.append('  recording: none (--no-record)')
    codes = summary.get('exit_codes', {})
    if any(codes.values()):
        lines.append(f'  exit codes of the nodes: {codes}')
    if summary.get('logs'):
        lines.append(f"  node logs: {summary['logs']}")
    if summary.get('error'):
        lines.append(f"  error: {summary['error']}")
    lines.append(f"  wall time {summary['wall_time_s']:.1f} s: "
                 + ('OK' if summary['success'] else 'FAILED'))
    return '\n'.join(lines)


def parse_args(argv):
    parser = argparse.ArgumentParser(
        prog='toc-demo', description=__doc__.split('\n\n')[0].strip() + '.',
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog='Runs solver_node, plant_node and recorder_node on a private ROS domain '
               '(ROS_DOMAIN_ID random unless set, localhost discovery).')
    parser.add_argument('--output', metavar='DIR',
                        help='bag directory of the recording, must not exist or be empty '
                             '(default runs/<UTC timestamp>); summary.json and logs/ go there')
    parser.add_argument('--no-record', dest='record', action='store_false',
                        help='do not start recorder_node')
    parser.add_argument('--timeout', metavar='S', type=float, default=180.0,
                        help='give up after S seconds (default %(default)g; the first run '
                             'compiles the numba kernels for about a minute)')
    parser.add_argument('--quiet', action='store_true', help='print the summary only')
    args = parser.parse_args(argv)
    if not args.timeout > 0:
        parser.error('--timeout must be > 0')
    if args.output is None and args.record:
        args.output = default_output_dir()
    if args.output is not None:
        args.output = os.path.abspath(args.output)
        if os.path.exists(args.output) and (not os.path.isdir(args.output)
                                            or os.listdir(args.output)):
            parser.error(f'--output {args.output} exists and is not an empty directory')
    return args


def _raise_interrupted(signum, _frame):
    raise _Interrupted(signal.Signals(signum).name)


def main(argv=None):
    """Run the demo; return the exit code (0: both goals reached, recording complete)."""
    args = parse_args(argv)
    os.environ.setdefault('ROS_DOMAIN_ID', str(random.randint(1, 101)))
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    printer = _Printer(args.quiet)
    printer.stage(f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']} ROS_AUTOMATIC_DISCOVERY_RANGE="
                  f"{os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE']}")
    previous = {s: signal.signal(s, _raise_interrupted) for s in (signal.SIGINT, signal.SIGTERM)}
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    log_dir = tempfile.mkdtemp(prefix='toc-demo-')
    demo = Demo(args, printer)
    code = 1
    try:
        try:
            demo.start(log_dir)
            demo.wait_ready()
            for number, stage in enumerate(STAGES, 1):
                demo.run_stage(number, stage)
        except DemoError as error:
            demo.summary['error'] = str(error)
            print(f'toc-demo: error: {error}', file=sys.stderr)
        except _Interrupted as interrupted:
            demo.summary['error'] = f'interrupted by {interrupted}'
            code = 130
        printer.stage('stopping the nodes')
        signal.signal(signal.SIGINT, signal.SIG_IGN)   # a second Ctrl-C must not orphan them
        demo.stop()
    finally:
        for child in demo.children.values():
            child.stop()
        demo.close()
        rclpy.try_shutdown()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    summary = demo.summary
    summary['wall_time_s'] = time.monotonic() - printer.start
    summary['success'] = success(summary)
    if args.output is not None:
        os.makedirs(args.output, exist_ok=True)
        logs = os.path.join(args.output, 'logs')
        shutil.copytree(log_dir, logs, dirs_exist_ok=True)
        shutil.rmtree(log_dir, ignore_errors=True)
        summary['logs'] = logs
        with open(os.path.join(args.output, 'summary.json'), 'w') as stream:
            json.dump(summary, stream, indent=2, allow_nan=True)
    elif summary['success']:
        shutil.rmtree(log_dir, ignore_errors=True)
    else:
        summary['logs'] = log_dir    # kept for the post-mortem
    print(format_summary(summary), flush=True)
    if code == 130:
        return code
    return 0 if summary['success'] else 1


if __name__ == '__main__':
    sys.exit(main())
