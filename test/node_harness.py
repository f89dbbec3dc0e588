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
Helpers for tests that run toc_ros nodes as processes and talk to them with rclpy.

Each test module gets a private rclpy context on a random ROS_DOMAIN_ID (localhost discovery)
and a random namespace, so concurrent test runs do not see each other.
"""

import contextlib
import math
import os
from pathlib import Path
import random
import signal
import subprocess
import sys
import threading
import time
from types import SimpleNamespace

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from nav_msgs.srv import GetPlan
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / 'config' / 'toc_ros.yaml'
LATCHED = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     reliability=ReliabilityPolicy.RELIABLE)
PAPER_X0 = (math.pi / 12.0, 0.0, 1.0, 0.0)
PAPER_GOAL = (5.0 * math.pi / 12.0, 0.0, 1.0, 0.0)
# A goal away from the paper's obstacle: a real plan that solves quicker than the paper's.
NEAR_GOAL = (-0.5, 0.0, 1.0, 0.0)
# Parameters of the nodes under test: small N for speed, a generous wall-clock limit because
# test machines are shared.
TEST_PARAMS = {'solver.N': 100, 'solver.timeout': 300.0}
SOLVE_TIMEOUT = 300.0
A = 1.1
U_MAX = (600.0, 500.0)
JOINTS = ['rotation_joint', 'extension_joint']


def ros_value(value):
    """Format a parameter value for --ros-args -p name:=value."""
    if isinstance(value, (list, tuple)):
        return '[' + ', '.join(ros_value(v) for v in value) + ']'
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, float):
        return repr(value)
    return str(value)


class NodeProcess:
    """A toc_ros node started with python -m toc_ros.nodes.<module>, logging to a file."""

    def __init__(self, module, namespace, log_dir, params=None, params_file=CONFIG):
        self.log_path = Path(log_dir) / f'{module}.log'
        command = [sys.executable, '-m', f'toc_ros.nodes.{module}', '--ros-args',
                   '-r', f'__ns:={namespace}']
        if params_file:
            command += ['--params-file', str(params_file)]
        for name, value in (params or {}).items():
            command += ['-p', f'{name}:={ros_value(value)}']
        env = dict(os.environ)
        env['PYTHONPATH'] = os.pathsep.join(
            [str(REPO)] + [p for p in env.get('PYTHONPATH', '').split(os.pathsep) if p])
        env.setdefault('AMENT_PREFIX_PATH', str(Path(sys.prefix)))
        env['ROS_LOG_DIR'] = str(Path(log_dir) / 'ros_log')
        env['PYTHONUNBUFFERED'] = '1'
        with open(self.log_path, 'w') as log:
            self.process = subprocess.Popen(command, env=env, stdout=log,
                                            stderr=subprocess.STDOUT)

    def log(self):
        """Return the output so far."""
        return self.log_path.read_text()

    def wait_for_log(self, text, timeout=60.0):
        """Wait until text appears in the output (fails if the process exits)."""
        deadline = time.monotonic() + timeout
        while text not in self.log():
            assert self.process.poll() is None, f'node exited early:\n{self.log()}'
            assert time.monotonic() < deadline, f'no {text!r} in the log:\n{self.log()}'
            time.sleep(0.05)

    def stop(self, timeout=10.0):
        """SIGINT, then SIGKILL if needed; return the exit code."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(timeout)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        return self.process.returncode


class RosClient:
    """A node in a private context, spun by a background thread; collects messages."""

    def __init__(self, name='toc_test_client'):
        self.saved_env = {k: os.environ.get(k) for k in
                          ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE')}
        os.environ['ROS_DOMAIN_ID'] = str(random.randint(1, 101))
        os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
        self.namespace = f'/toc_test_{os.getpid()}_{random.randint(0, 10 ** 6)}'
        self.context = Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.lock = threading.Lock()
        self.received = {}
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self):
        while self.context.ok():
            try:
                self.executor.spin_once(timeout_sec=0.05)
            except Exception:  # noqa: B902 - shutting down
                if not self.context.ok():
                    return
                raise

    def name(self, relative):
        """Absolute name of a topic/service of the nodes under test."""
        return f'{self.namespace}/{relative}'

    def collect(self, msg_type, relative, qos=10):
        """Subscribe and store (receipt time, message) in received[relative]."""
        self.received[relative] = []

        def store(msg):
            with self.lock:
                self.received[relative].append((time.monotonic(), msg))
        return self.node.create_subscription(msg_type, self.name(relative), store, qos)

    def messages(self, relative, since=0.0):
        """Messages of a collected topic received at or after monotonic time since."""
        with self.lock:
            return [m for t, m in self.received[relative] if t >= since]

    def stamped(self, relative, since=0.0):
        """(receipt time, message) pairs of a collected topic since a monotonic time."""
        with self.lock:
            return [(t, m) for t, m in self.received[relative] if t >= since]

    def wait_for(self, predicate, timeout=30.0, what='condition'):
        """Poll predicate() until it returns a truthy value; return it."""
        deadline = time.monotonic() + timeout
        while True:
            value = predicate()
            if value:
                return value
            assert time.monotonic() < deadline, f'timed out waiting for {what}'
            time.sleep(0.01)

    def call(self, client, request, timeout=60.0):
        """Call a service and wait for the response."""
        assert client.wait_for_service(timeout_sec=30.0), f'no service {client.srv_name}'
        future = client.call_async(request)
        done = threading.Event()
        future.add_done_callback(lambda _f: done.set())
        assert done.wait(timeout), f'{client.srv_name} did not answer in {timeout} s'
        return future.result()

    def set_parameters(self, node_name, values, timeout=10.0):
        """Set parameters of a node under test one by one; return the SetParametersResults."""
        from rcl_interfaces.srv import SetParameters
        client = self.node.create_client(SetParameters, self.name(f'{node_name}/set_parameters'))
        request = SetParameters.Request()
        request.parameters = [Parameter(k, value=v).to_parameter_msg() for k, v in
                              values.items()]
        response = self.call(client, request, timeout)
        self.node.destroy_client(client)
        return response.results

    def close(self):
        """Shut the context down and restore the environment."""
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
        self._thread.join(timeout=2.0)
        for key, value in self.saved_env.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


def pose(x, y, frame='base_link'):
    """Build the PoseStamped of a hand target."""
    msg = PoseStamped()
    msg.header.frame_id = frame
    msg.pose.position.x = float(x)
    msg.pose.position.y = float(y)
    msg.pose.orientation.w = 1.0
    return msg


def pose_of(state):
    """Build the PoseStamped of the hand for a joint state (q1, dq1, q2, dq2)."""
    return pose((A + state[2]) * math.cos(state[0]), (A + state[2]) * math.sin(state[0]))


def values(status):
    """Key/values of a DiagnosticStatus."""
    return {kv.key: kv.value for kv in status.values}


def is_final(status):
    """Tell whether a ~/progress message ends a request (anything but a running solve)."""
    return values(status).get('status') != 'SOLVING'


def level_name(status):
    """Name of a DiagnosticStatus level."""
    return {DiagnosticStatus.OK: 'OK', DiagnosticStatus.WARN: 'WARN',
            DiagnosticStatus.ERROR: 'ERROR', DiagnosticStatus.STALE: 'STALE'}[status.level]


def eq37(x, u, hand_mass=50.0, link_mass=97.0, inertia=193.0, a=A):
    """Right-hand side of the paper's eq. (37), written out independently of the package."""
    a1, a2, a3 = inertia + hand_mass * a * a, 2.0 * hand_mass * a, link_mass + hand_mass
    x1, x2, x3, x4 = x
    den = a1 + a2 * x3 + a3 * x3 * x3
    return [x2, (-2.0 * a3 * x2 * x3 * x4 - a2 * x2 * x4 + u[0]) / den, x4,
            x3 * x2 * x2 - a2 / (2.0 * a3) * x2 * x2 + u[1] / a3]


def handshake(client, publisher, msg, heard, timeout=30.0, period=1.0):
    """
    Publish msg until heard() is true: proves the subscriber side matched the publisher.

    get_subscription_count() > 0 only says that the publisher matched the subscription; the
    node's side may match later and miss a volatile message sent in between.  msg should be
    harmless (e.g. an input the node refuses) and heard() detect the node's reaction.
    """
    deadline = time.monotonic() + timeout
    while True:
        publisher.publish(msg)
        until = min(deadline, time.monotonic() + period)
        while time.monotonic() < until:
            if heard():
                return
            time.sleep(0.01)
        assert time.monotonic() < deadline, f'no reaction to {publisher.topic_name}'


def refused_inputs_handshake(ctx):
    """Make sure each input topic reaches the node: send refused inputs until they are heard."""
    bad_pose = pose_of(PAPER_GOAL)
    bad_pose.header.frame_id = 'handshake'
    for publisher, msg, text in [
            (ctx.goal_pose, bad_pose, "'handshake'"),
            (ctx.goal_joints, JointState(name=['handshake'], position=[0.0]), "'handshake'"),
            (ctx.obstacles, Float64MultiArray(data=[1.0]), 'multiple of 3')]:
        since = time.monotonic()
        handshake(ctx.client, publisher, msg, lambda: [
            m for m in ctx.client.messages('solver_node/progress', since) if text in m.message])
    time.sleep(0.5)    # joint_states has no reaction to wait for; give discovery a moment


@contextlib.contextmanager
def running_solver(log_dir, collect=(), depth=10):
    """
    Run solver_node with TEST_PARAMS; yield its client, process, input publishers and clients.

    collect: (message type, relative topic, qos) the client records; depth: history of the
    goal publishers.  Every input topic is proven matched (refused_inputs_handshake) before the
    body runs, and the node must exit cleanly at the end.
    """
    client = RosClient()
    node = NodeProcess('solver_node', client.namespace, log_dir, TEST_PARAMS)
    try:
        node.wait_for_log('ready:')
        for msg_type, topic, qos in collect:
            client.collect(msg_type, topic, qos)
        create = client.node.create_publisher
        ctx = SimpleNamespace(
            client=client, node=node,
            goal_pose=create(PoseStamped, client.name('goal_pose'), depth),
            goal_joints=create(JointState, client.name('goal_joints'), depth),
            joint_states=create(JointState, client.name('joint_states'), 10),
            obstacles=create(Float64MultiArray, client.name('obstacles'), 10),
            plan=client.node.create_client(GetPlan, client.name('solver_node/plan')),
            cancel=client.node.create_client(Trigger, client.name('solver_node/cancel')))
        for publisher in (ctx.goal_pose, ctx.goal_joints, ctx.joint_states, ctx.obstacles):
            client.wait_for(lambda p=publisher: p.get_subscription_count() > 0,
                            what=f'subscriber of {publisher.topic_name}')
        refused_inputs_handshake(ctx)
        yield ctx
        assert node.stop() == 0, node.log()
    finally:
        node.stop()
        client.close()
