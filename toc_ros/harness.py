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
Run toc_ros nodes as child processes and talk to them: shared by toc-demo and the tests.

NodeProcess starts ``python -m toc_ros.nodes.<module>`` (or any argv) with this toc_ros first
on PYTHONPATH and its output in a log file, and stops it SIGINT -> SIGTERM -> SIGKILL.
RosClient is an rclpy node in a private context spun by a background thread, optionally on a
random ROS_DOMAIN_ID with localhost discovery; it collects messages with their receipt times
and calls services with a timeout.
"""

import os
from pathlib import Path
import random
import signal
import subprocess
import sys
import threading
import time

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

# The folder holding the toc_ros package: first on the children's PYTHONPATH, so that nodes
# also run from a source tree that is not installed.
PACKAGE_PARENT = str(Path(__file__).resolve().parents[1])
LATCHED = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     reliability=ReliabilityPolicy.RELIABLE)
# Collecting a latched topic: the latched message on joining, then every one (a subscription of
# depth 1 drops a message when two arrive before the executor takes the first).
LATCHED_HISTORY = QoSProfile(depth=100, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                             reliability=ReliabilityPolicy.RELIABLE)
STOP_TIMEOUT_S = 10.0


class HarnessError(RuntimeError):
    """A child process or a ROS call did not do what was waited for; the text says what."""


def ros_value(value):
    """Format a parameter value for --ros-args -p name:=value."""
    if isinstance(value, (list, tuple)):
        return '[' + ', '.join(ros_value(v) for v in value) + ']'
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, float):
        return repr(value)
    return str(value)


def child_environment(env=None, ros_log_dir=None):
    """Return the caller's environment with this toc_ros first on PYTHONPATH, unbuffered."""
    env = dict(os.environ if env is None else env)
    paths = [p for p in env.get('PYTHONPATH', '').split(os.pathsep) if p]
    env['PYTHONPATH'] = os.pathsep.join([PACKAGE_PARENT] + [
        p for p in paths if p != PACKAGE_PARENT])
    env.setdefault('AMENT_PREFIX_PATH', sys.prefix)
    env['PYTHONUNBUFFERED'] = '1'
    if ros_log_dir is not None:
        env['ROS_LOG_DIR'] = str(ros_log_dir)
    return env


def node_command(module, params_file=None, params=None, namespace=None, extra=()):
    """Argv of a toc_ros node run with python -m, a parameter file and -p overrides."""
    command = [sys.executable, '-m', f'toc_ros.nodes.{module}', '--ros-args']
    if namespace:
        command += ['-r', f'__ns:={namespace}']
    if params_file:
        command += ['--params-file', str(params_file)]
    for name, value in (params or {}).items():
        command += ['-p', f'{name}:={ros_value(value)}']
    return command + list(extra)


class NodeProcess:
    """
    A toc_ros node (or any argv) in a child process, logging to ``<log_dir>/<name>.log``.

    module, namespace, params (name -> value) and params_file build the node's command line;
    argv replaces it.  new_session puts the child in its own session (a Ctrl-C of the
    terminal then reaches only the caller, which decides how the child stops).
    """

    def __init__(self, module=None, namespace=None, log_dir='.', params=None,
                 params_file=None, *, argv=None, name=None, env=None, new_session=False):
        self.name = name or module
        self.log_path = Path(log_dir) / f'{self.name}.log'
        command = argv or node_command(module, params_file, params, namespace)
        environment = child_environment(env, Path(log_dir) / 'ros_log')
        self.exit_code = None
        self.stopped_by = None        # name of the last signal sent
        with open(self.log_path, 'w') as log:
            self.process = subprocess.Popen(command, env=environment, stdout=log,
                                            stderr=subprocess.STDOUT,
                                            start_new_session=new_session)

    def alive(self):
        """Tell whether the process still runs."""
        return self.process.poll() is None

    def log(self):
        """Return the output so far ('' when the log cannot be read)."""
        try:
            return self.log_path.read_text(errors='replace')
        except OSError:
            return ''

    def tail(self, lines=20):
        """Return the last lines of the output."""
        return '\n'.join(self.log().splitlines()[-lines:])

    def wait_for_log(self, text, timeout=60.0):
        """Wait until text appears in the output; HarnessError if it exits or times out."""
        deadline = time.monotonic() + timeout
        while text not in self.log():
            if not self.alive():
                raise HarnessError(f'{self.name} exited early:\n{self.log()}')
            if time.monotonic() > deadline:
                raise HarnessError(f'no {text!r} in the log of {self.name}:\n{self.log()}')
            time.sleep(0.05)

    def _signal(self, sig):
        if self.alive():
            self.stopped_by = signal.Signals(sig).name
            self.process.send_signal(sig)

    def interrupt(self):
        """Send SIGINT once (a second one would interrupt the node's own clean-up)."""
        if self.stopped_by is None:
            self._signal(signal.SIGINT)

    def stop(self, timeout=STOP_TIMEOUT_S):
        """SIGINT, then SIGTERM, then SIGKILL while it hangs; return the exit code."""
        if self.exit_code is not None:
            return self.exit_code
        self.interrupt()
        for sig in (None, signal.SIGTERM, signal.SIGKILL):
            if sig is signal.SIGKILL and self.alive():
                # A node's stacks into its log first (run_node registers SIGUSR1).
                self.process.send_signal(signal.SIGUSR1)
                time.sleep(0.5)
            if sig is not None:
                self._signal(sig)
            try:
                self.process.wait(timeout)
                break
            except subprocess.TimeoutExpired:
                continue
        self.exit_code = self.process.wait()
        return self.exit_code


class RosClient:
    """
    A node in a private rclpy context, spun by a background thread; collects messages.

    private_domain: pick a random ROS_DOMAIN_ID with localhost discovery for this process
    (and the children started after it), restored by close().  namespace: prefix of the
    relative names given to name(); '' for absolute names.
    """

    def __init__(self, name='toc_test_client', namespace=None, private_domain=True):
        self.saved_env = {k: os.environ.get(k) for k in
                          ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE')}
        if private_domain:
            os.environ['ROS_DOMAIN_ID'] = str(random.randint(1, 101))
            os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
        self.namespace = (f'/toc_test_{os.getpid()}_{random.randint(0, 10 ** 6)}'
                          if namespace is None else namespace.rstrip('/'))
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

    def collect(self, msg_type, relative, qos=10, keep=None):
        """Subscribe and store (receipt time, message) in received[relative] (last keep)."""
        self.received[relative] = []

        def store(msg):
            with self.lock:
                items = self.received[relative]
                items.append((time.monotonic(), msg))
                if keep is not None and len(items) > keep:
                    del items[:-keep]
        return self.node.create_subscription(msg_type, self.name(relative), store, qos)

    def messages(self, relative, since=0.0):
        """Messages of a collected topic received at or after monotonic time since."""
        with self.lock:
            return [m for t, m in self.received[relative] if t >= since]

    def stamped(self, relative, since=0.0):
        """(receipt time, message) pairs of a collected topic since a monotonic time."""
        with self.lock:
            return [(t, m) for t, m in self.received[relative] if t >= since]

    def count(self, relative):
        """Return the number of messages collected on a topic so far."""
        with self.lock:
            return len(self.received[relative])

    def subscribers(self, relative):
        """Names of the nodes subscribed to a topic (as this node discovered them)."""
        return {info.node_name for info in
                self.node.get_subscriptions_info_by_topic(self.name(relative))}

    def wait_for(self, predicate, timeout=30.0, what='condition'):
        """Poll predicate() until it returns a truthy value; return it (HarnessError)."""
        deadline = time.monotonic() + timeout
        while True:
            value = predicate()
            if value:
                return value
            if time.monotonic() >= deadline:
                raise HarnessError(f'timed out waiting for {what}')
            time.sleep(0.01)

    def call(self, client, request, timeout=60.0, attempts=1):
        """
        Call a service and wait for the response (HarnessError when none comes).

        attempts > 1, for requests that may be repeated (queries): the request is sent again
        when no answer came within timeout / attempts.  rmw_fastrtps drops a response when the
        server has not matched the client's response reader within 100 ms (ros2/rmw_fastrtps
        #390, #467): a new client on a loaded machine can lose its first answer.
        """
        if not client.wait_for_service(timeout_sec=min(30.0, timeout)):
            raise HarnessError(f'no service {client.srv_name}')
        for _ in range(attempts):
            future = client.call_async(request)
            done = threading.Event()
            future.add_done_callback(lambda _f, done=done: done.set())
            if done.wait(timeout / attempts):
                return future.result()
            client.remove_pending_request(future)
        raise HarnessError(f'{client.srv_name} did not answer in {timeout} s '
                           f'({attempts} request(s))')

    def trigger(self, relative, timeout=10.0):
        """Call a std_srvs/Trigger service of the nodes under test; return its response."""
        from std_srvs.srv import Trigger
        client = self.node.create_client(Trigger, self.name(relative))
        try:
            return self.call(client, Trigger.Request(), timeout)
        finally:
            self.node.destroy_client(client)

    def set_parameters(self, node_name, values, timeout=10.0):
        """
        Set parameters of a node one by one; return the SetParametersResults.

        A value may be an rclpy Parameter (for a type the value does not tell: an empty list).
        """
        from rcl_interfaces.srv import SetParameters
        client = self.node.create_client(SetParameters, self.name(f'{node_name}/set_parameters'))
        request = SetParameters.Request()
        request.parameters = [(v if isinstance(v, Parameter) else Parameter(k, value=v))
                              .to_parameter_msg() for k, v in values.items()]
        try:
            return self.call(client, request, timeout).results
        finally:
            self.node.destroy_client(client)

    def get_parameters(self, node_name, names, timeout=10.0):
        """Return the current values of a node's parameters as plain Python values."""
        from rcl_interfaces.srv import GetParameters
        from rclpy.parameter import parameter_value_to_python
        client = self.node.create_client(GetParameters, self.name(f'{node_name}/get_parameters'))
        try:
            reply = self.call(client, GetParameters.Request(names=list(names)), timeout)
        finally:
            self.node.destroy_client(client)
        return {n: (list(v) if isinstance(v, (list, tuple)) or hasattr(v, 'tolist') else v)
                for n, v in zip(names, (parameter_value_to_python(p) for p in reply.values))}

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
