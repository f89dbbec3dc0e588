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
recorder_node: records topics into a rosbag2 bag directory with MCAP storage.

Like ``ros2 bag record [-a]``: parameter ``topics`` (empty: every topic, new ones included),
``output`` (default ``runs/<UTC timestamp>``), ``exclude`` (regex). Messages are stored as
the CDR bytes received (``raw=True``); each topic is subscribed with QoS adapted to its
publishers, so latched (transient-local) messages are caught. SIGINT, SIGTERM and node
shutdown close the bag with a valid summary; errors exit non-zero with a message.

Crash durability: the chunk in progress is written and fsynced at least every
``flush_period`` s (default 0.1), so a SIGKILL or a power loss loses at most about two periods
(the chunk in memory and one being written); ``toc-bag recover`` rewrites such a bag into a
complete one, and ``toc-analyze`` and ``replay_node`` read it as it is.

Run: ``ros2 run toc_ros recorder_node --ros-args -p output:=runs/x -p "topics:=[/a, /b]"``
"""

import functools
import importlib
import re
import signal
import sys
import time
from typing import Dict, List, Optional, Set

from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor, SetParametersResult
import rclpy
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

from toc_ros.nodes.common import topic_list
from toc_ros.recording.bag_metadata import qos_profile_to_dict
from toc_ros.recording.bag_writer import BagWriter, FLUSH_PERIOD_S, RecordingError
from toc_ros.recording.msg_definitions import (
    full_definition, MessageDefinitionError, split_type_name, type_description_hash)
from toc_ros.recording.process import default_output_dir

# Bounds the time spent taking already-received messages after a stop request.
DRAIN_TIMEOUT_S = 5.0


def _is_hidden(topic: str) -> bool:
    return any(token.startswith('_') for token in topic.split('/'))


def _message_class(type_name: str):
    package, namespace, name = split_type_name(type_name)
    module = importlib.import_module(f'{package}.{namespace}')
    return getattr(module, name)


def adapt_qos(offered: List[QoSProfile]):
    """
    Request QoS compatible with every publisher, as rosbag2 does, plus warnings.

    Reliable only if all publishers are, transient-local only if all are (so latched
    messages are received), keep-all history unless publishers advertise a depth > 1.
    """
    warnings = []
    depth = max((int(p.depth) for p in offered), default=0)
    if depth > 1:
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth)
    else:
        qos = QoSProfile(history=HistoryPolicy.KEEP_ALL, depth=1000)
    reliable = sum(p.reliability == ReliabilityPolicy.RELIABLE for p in offered)
    if offered and reliable == len(offered):
        qos.reliability = ReliabilityPolicy.RELIABLE
    else:
        qos.reliability = ReliabilityPolicy.BEST_EFFORT
        if reliable:
            warnings.append('some publishers are best-effort: recording best-effort, '
                            'messages of reliable publishers may be dropped')
    latched = sum(p.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in offered)
    if offered and latched == len(offered):
        qos.durability = DurabilityPolicy.TRANSIENT_LOCAL
    else:
        qos.durability = DurabilityPolicy.VOLATILE
        if latched:
            warnings.append('not all publishers are transient-local: recording volatile, '
                            'latched messages published earlier are missed')
    return qos, warnings


class RecorderNode(Node):
    """Subscribes to the selected topics and writes every received message to a bag."""

    def __init__(self, **kwargs):
        super().__init__('recorder_node', **kwargs)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.declare_parameter('output', '', ParameterDescriptor(
            description='bag directory to create (must not exist or be empty); '
                        'empty: runs/<UTC timestamp> below the working directory',
            dynamic_typing=True, read_only=True))
        self.declare_parameter('topics', [], ParameterDescriptor(
            description='topics to record (string array, or one comma-separated string); '
                        'empty: every topic discovered, new ones included',
            dynamic_typing=True, read_only=True))
        self.declare_parameter('exclude', '', ParameterDescriptor(
            description='regular expression (re.search); matching topics are not recorded',
            read_only=True))
        self.declare_parameter('include_hidden_topics', False, ParameterDescriptor(
            description='with empty topics, also record hidden topics (a token starts with _)',
            read_only=True))
        self.declare_parameter('discovery_period', 0.5, ParameterDescriptor(
            description='s between two scans of the ROS graph for new topics',
            floating_point_range=[FloatingPointRange(from_value=0.05, to_value=10.0)],
            read_only=True))
        self.declare_parameter('flush_period', FLUSH_PERIOD_S, ParameterDescriptor(
            description='s: the chunk in progress is written to the file at least this often, '
                        'so a crash (SIGKILL, power loss) loses at most about twice this much '
                        'recording; shorter periods make more, smaller chunks',
            floating_point_range=[FloatingPointRange(from_value=0.01, to_value=10.0)],
            read_only=True))
        self.declare_parameter('fsync', True, ParameterDescriptor(
            description='fsync the file after each periodic flush (survives a power loss, '
                        'not only a killed process)',
            read_only=True))

        self._topics = {self.resolve_topic_name(t) for t in
                        topic_list(self.get_parameter('topics'))}
        exclude = self.get_parameter('exclude').value
        self._exclude = re.compile(exclude) if exclude else None
        self._include_hidden = bool(self.get_parameter('include_hidden_topics').value)
        self._use_sim_time = bool(self.get_parameter('use_sim_time').value)
        output = str(self.get_parameter('output').value or '') or default_output_dir()

        self.writer = BagWriter(output,
                                flush_period=float(self.get_parameter('flush_period').value),
                                fsync=bool(self.get_parameter('fsync').value))
        self.writer.create()  # RecordingError: reported by main(), nothing to clean up
        self.error: Optional[str] = None
        self._last_dds_receive_ns = 0
        self._recorded: Dict[str, object] = {}
        self._ignored: Set[str] = set()
        what = ', '.join(sorted(self._topics)) if self._topics else 'all topics'
        self.get_logger().info(
            f'recording {what} to {self.writer.path} (flushed every '
            f"{self.get_parameter('flush_period').value:g} s"
            f"{', fsync' if self.get_parameter('fsync').value else ''})")
        self._timer = self.create_timer(
            float(self.get_parameter('discovery_period').value), self._discover)
        self._discover()

    # -- parameters ---------------------------------------------------------------------------
    def _validate_parameters(self, parameters: List[Parameter]) -> SetParametersResult:
        for parameter in parameters:
            try:
                if parameter.name == 'topics':
                    for name in topic_list(parameter):
                        self.resolve_topic_name(name)
                elif parameter.name == 'exclude' and parameter.value:
                    re.compile(parameter.value)
                elif parameter.name == 'output' and parameter.type_ not in (
                        Parameter.Type.STRING, Parameter.Type.INTEGER, Parameter.Type.DOUBLE,
                        Parameter.Type.NOT_SET):
                    raise ValueError(f'output must be a path, got {parameter.value!r}')
            except (ValueError, re.error, TypeError, RuntimeError) as error:  # RCLError: bad name
                return SetParametersResult(
                    successful=False, reason=f'invalid {parameter.name}: {error}')
        return SetParametersResult(successful=True)

    # -- discovery ------------------------------------------------------------------------
    def _wanted(self, topic: str) -> bool:
        if self._topics:
            wanted = topic in self._topics
        else:
            wanted = self._include_hidden or not _is_hidden(topic)
        return wanted and not (self._exclude and self._exclude.search(topic))

    def _ignore(self, topic: str, reason: str):
        self._ignored.add(topic)
        self.get_logger().warning(f'not recording {topic}: {reason}')

    def _discover(self):
        if self.writer.error is not None:  # a periodic flush failed (e.g. disk full)
            self._stop_with_error(f'writing {self.writer.mcap_path} failed: '
                                  f'{self.writer.error}')
        if self.error is not None or not self.writer.is_open:
            return
        for topic, types in self.get_topic_names_and_types():
            if topic in self._recorded or topic in self._ignored or not self._wanted(topic):
                continue
            if len(types) != 1:
                self._ignore(topic, f'it has several types {types}')
                continue
            publishers = self.get_publishers_info_by_topic(topic)
            if not publishers:
                continue  # only subscribers so far; their QoS tells nothing about the data
            self._subscribe(topic, types[0], publishers)

    def _subscribe(self, topic: str, type_name: str, publishers):
        try:
            message_class = _message_class(type_name)
            definition = full_definition(type_name)
        except (ImportError, AttributeError, MessageDefinitionError) as error:
            self._ignore(topic, f'type {type_name} unavailable ({error})')
            return
        offered = [p.qos_profile for p in publishers]
        qos, warnings = adapt_qos(offered)
        for warning in warnings:
            self.get_logger().warning(f'{topic}: {warning}')
        type_hash = str(publishers[0].topic_type_hash)
        if not type_hash.startswith('RIHS01_') or type_hash.endswith('0' * 64):
            type_hash = type_description_hash(type_name)
        try:
            self.writer.add_topic(topic, type_name, [qos_profile_to_dict(p) for p in offered],
                                  type_hash, definition)
        except RecordingError as error:
            self._stop_with_error(str(error))
            return
        self._recorded[topic] = self.create_subscription(
            message_class, topic, functools.partial(self._on_message, topic), qos, raw=True)
        self.get_logger().info(f'subscribed to {topic} [{type_name}]')

    # -- messages --------------------------------------------------------------------------
    def _on_message(self, topic: str, data: bytes, info: dict):
        received = int(info.get('received_timestamp', 0) or 0)
        self._last_dds_receive_ns = max(self._last_dds_receive_ns, received)
        if self._use_sim_time or received <= 0:
            received = self.get_clock().now().nanoseconds
        sent = int(info.get('source_timestamp', 0) or 0) or received
        try:
            self.writer.write(topic, data, received, sent)
        except RecordingError as error:
            self._stop_with_error(str(error))

    def _stop_with_error(self, message: str):
        if self.error is None:
            self.error = message
            self.get_logger().error(message)

    @property
    def message_count(self) -> int:
        """Messages written so far."""
        return self.writer.message_count

    def drain(self, executor, timeout: float = DRAIN_TIMEOUT_S):
        """
        Execute the callbacks of the messages received before now, so none is lost at a stop.

        Ends when the queues are idle or a message received after the call comes up (DDS
        receive stamps), so a publisher that keeps going does not delay the stop.
        """
        stop_ns = time.time_ns()
        deadline = time.monotonic() + timeout
        idle = 0
        while (idle < 3 and time.monotonic() < deadline and self.error is None
               and self._last_dds_receive_ns <= stop_ns):
            before = self.writer.message_count
            executor.spin_once(timeout_sec=0.02)
            idle = idle + 1 if self.writer.message_count == before else 0

    def close(self) -> int:
        """Close the bag, log the outcome; return a process exit code."""
        if self.writer.is_open:
            try:
                summary = self.writer.close()
            except RecordingError as error:
                self.get_logger().error(str(error))
                self.error = f'{self.error}; {error}' if self.error else str(error)
            else:
                per_topic = ', '.join(f'{t.name}: {t.message_count}' for t in summary.topics)
                self.get_logger().info(
                    f'recorded {summary.message_count} messages to {summary.path}'
                    + (f' ({per_topic})' if per_topic else ''))
        return 1 if self.error else 0

    def destroy_node(self):
        """Close the bag (valid summary and footer) before the node goes."""
        self.close()
        super().destroy_node()


class _StopRequest:
    """Set by SIGINT/SIGTERM; the main loop polls it (closing inside a handler could deadlock)."""

    def __init__(self):
        self.signal_name = None

    def __call__(self, signum, _frame):
        self.signal_name = signal.Signals(signum).name

    def __bool__(self):
        return self.signal_name is not None


def main(args=None):
    """Record until SIGINT/SIGTERM or shutdown; exit code 0 when the bag is complete."""
    # Own handlers instead of rclpy's: they only set a flag, and the loop below drains the
    # queues and closes the bag from the main thread.
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = _StopRequest()
    previous = {s: signal.signal(s, stop) for s in (signal.SIGINT, signal.SIGTERM)}
    node = None
    exit_code = 0
    try:
        node = RecorderNode()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        while not stop and node.error is None and rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
        if stop:
            node.get_logger().info(f'{stop.signal_name} received, closing the bag')
        if rclpy.ok():
            node.drain(executor)
    except (RecordingError, InvalidParameterValueException,
            InvalidParameterTypeException) as error:
        print(f'recorder_node: error: {error}', file=sys.stderr)
        exit_code = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            exit_code = exit_code or node.close()
            if node.error:
                print(f'recorder_node: error: {node.error}', file=sys.stderr)
            node.destroy_node()
        rclpy.try_shutdown()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return exit_code


if __name__ == '__main__':
    sys.exit(main())
