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
replay_node: plays a recording back on its original topics, types and timing.

Like ``ros2 bag play``: reads a rosbag2 bag directory or a bare ``.mcap`` (parameter ``bag``),
publishes the recorded CDR bytes as they are (no re-serialisation) with the recorded spacing of
log times divided by ``rate``, from ``start_offset`` seconds into the recording, optionally only
some ``topics``, in a ``loop``, and with ``/clock`` from the recorded times (``publish_clock``).
Publishers use the QoS the recorded publishers offered (latched topics stay transient-local).
Topics of unknown types and a cut-off file are reported; the rest still plays. Exits 0 after
playing (never with ``loop``), 1 when the recording cannot be played.

Run: ``ros2 run toc_ros replay_node --ros-args -p bag:=runs/x -p rate:=2.0``
"""

import sys
import threading
import time
from typing import Callable, Dict, Iterable, List, Optional

from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor, SetParametersResult
import rclpy
from rclpy.duration import Duration
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock

from toc_ros.nodes.common import run_node, topic_list
from toc_ros.recording.bag_reader import message_class, Recording, RecordingError

CLOCK_TOPIC = '/clock'
# /clock is published at least this often between messages (ros2 bag play's default 40 Hz).
CLOCK_PERIOD_S = 0.025
# Longest sleep between two looks at the rate parameter and the stop flag.
MAX_SLEEP_S = 0.1
# How long to wait at the end for reliable subscribers to acknowledge the last messages.
ACK_TIMEOUT_S = 2.0
DEFAULT_DEPTH = 10

# rmw enum values as older rosbag2 versions (Humble) stored them, before policy names.
_RELIABILITY_CODES = {1: 'reliable', 2: 'best_effort'}
_DURABILITY_CODES = {1: 'transient_local', 2: 'volatile'}
_HISTORY_CODES = {1: 'keep_last', 2: 'keep_all'}


class ReplayError(RuntimeError):
    """The recording cannot be played; the message says why."""


def _policy(profile: dict, key: str, codes: Dict[int, str]) -> str:
    value = profile.get(key, '')
    if isinstance(value, int) and not isinstance(value, bool):
        return codes.get(value, 'system_default')
    return str(value).lower()


def qos_from_offers(profiles: Iterable[dict]) -> QoSProfile:
    """
    Choose the publisher QoS of a topic from what its recorded publishers offered.

    Transient-local only if every recorded publisher was (latched topics stay latched),
    best-effort only if every one was, depth the largest offered. Discovery does not tell a
    publisher's depth (rosbag2 stores 0), so an unknown depth is 1 for latched topics (late
    subscribers get the last message, not a backlog) and 10 otherwise.
    """
    profiles = list(profiles)
    qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=DEFAULT_DEPTH)
    if not profiles:
        return qos
    depths = [int(p.get('depth', 0) or 0) for p in profiles
              if _policy(p, 'history', _HISTORY_CODES) != 'keep_all']
    if depths and max(depths) > 0:
        qos.depth = max(depths)
    if all(_policy(p, 'reliability', _RELIABILITY_CODES) == 'best_effort' for p in profiles):
        qos.reliability = ReliabilityPolicy.BEST_EFFORT
    if all(_policy(p, 'durability', _DURABILITY_CODES) == 'transient_local'
           for p in profiles):
        qos.durability = DurabilityPolicy.TRANSIENT_LOCAL
        if not depths or max(depths) <= 0:
            qos.depth = 1
    return qos


class Player:
    """
    Plays raw messages with their recorded spacing divided by the rate; no ROS inside.

    ``messages()`` iterates the whole recording (its first message is the start that
    start_offset counts from), ``topics`` (None: all) selects what is played,
    ``publish(raw)`` sends one message, ``publish_clock(ns)`` (optional) a recorded time.
    ``set_rate`` may be called from another thread while playing; ``stop()`` ends play.
    """

    def __init__(self, messages: Callable[[], Iterable], publish: Callable,
                 publish_clock: Optional[Callable[[int], None]] = None, rate: float = 1.0,
                 start_offset: float = 0.0, loop: bool = False,
                 topics: Optional[Iterable[str]] = None,
                 monotonic: Callable[[], float] = time.monotonic,
                 wait: Optional[Callable[[float], bool]] = None):
        if not rate > 0.0:
            raise ValueError(f'rate must be > 0, got {rate}')
        if not start_offset >= 0.0:
            raise ValueError(f'start_offset must be >= 0, got {start_offset}')
        self._messages = messages
        self._topics = None if topics is None else frozenset(topics)
        self._publish = publish
        self._publish_clock = publish_clock
        self._offset_ns = int(round(start_offset * 1e9))
        self.loop = loop
        self._now = monotonic
        self._stop = threading.Event()
        # wait(seconds) -> True when stopped meanwhile; injectable so tests need no real time.
        self._wait = wait or self._stop.wait
        self._lock = threading.Lock()
        self._rate = float(rate)
        self._wall0 = 0.0
        self._bag0 = 0
        self.published = 0
        self.loops = 0

    def set_rate(self, rate: float):
        """Change the rate, continuing from the current recorded time."""
        with self._lock:
            now = self._now()
            self._bag0 = self._bag_time(now)
            self._wall0 = now
            self._rate = float(rate)

    def stop(self):
        """End play (from any thread)."""
        self._stop.set()

    @property
    def stopped(self) -> bool:
        """Tell whether stop() was called."""
        return self._stop.is_set()

    def sleep(self, seconds: float) -> bool:
        """Wait, unless stopped; True when the time passed without a stop."""
        return not self._wait(seconds)

    def _bag_time(self, now: float) -> int:
        return self._bag0 + int((now - self._wall0) * self._rate * 1e9)

    def run(self) -> int:
        """Play until the end (each pass of a loop) or stop(); return messages published."""
        start_ns = None
        while not self._stop.is_set():
            played_any = False
            for raw in self._messages():
                if start_ns is None:
                    start_ns = raw.log_time_ns
                    with self._lock:
                        self._bag0, self._wall0 = start_ns + self._offset_ns, self._now()
                if raw.log_time_ns < start_ns + self._offset_ns or (
                        self._topics is not None and raw.topic not in self._topics):
                    continue
                if not self._wait_until(raw.log_time_ns):
                    return self.published
                if self._publish_clock is not None:
                    self._publish_clock(raw.log_time_ns)
                self._publish(raw)
                played_any = True
                self.published += 1
            self.loops += 1
            if not (self.loop and played_any):
                break
            with self._lock:
                self._bag0, self._wall0 = start_ns + self._offset_ns, self._now()
        return self.published

    def _wait_until(self, bag_ns: int) -> bool:
        """Sleep until the recorded time bag_ns is due; False when stopped meanwhile."""
        while True:
            with self._lock:
                remaining = self._wall0 + (bag_ns - self._bag0) / self._rate * 1e-9 - self._now()
            if remaining <= 0.0:
                return not self._stop.is_set()
            step = min(remaining, MAX_SLEEP_S)
            if self._publish_clock is not None:
                step = min(step, CLOCK_PERIOD_S)
            if self._wait(step) or self._stop.is_set():
                return False
            if self._publish_clock is not None:
                with self._lock:
                    now_ns = self._bag_time(self._now())
                if now_ns < bag_ns:
                    self._publish_clock(now_ns)


class ReplayNode(Node):
    """Opens the recording, creates one publisher per played topic and plays in a thread."""

    def __init__(self, **kwargs):
        super().__init__('replay_node', **kwargs)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.declare_parameter('bag', '', ParameterDescriptor(
            description='rosbag2 bag directory or .mcap file to play', read_only=True))
        self.declare_parameter('rate', 1.0, ParameterDescriptor(
            description='playback speed multiplier (2.0: twice as fast); may change while '
                        'playing',
            floating_point_range=[FloatingPointRange(from_value=0.001, to_value=1000.0)]))
        self.declare_parameter('start_offset', 0.0, ParameterDescriptor(
            description='s into the recording (from its first message) to start playing at',
            floating_point_range=[FloatingPointRange(from_value=0.0, to_value=1e9)],
            read_only=True))
        self.declare_parameter('topics', [], ParameterDescriptor(
            description='topics to play (string array); empty: every topic',
            dynamic_typing=True, read_only=True))
        self.declare_parameter('loop', False, ParameterDescriptor(
            description='play again from start_offset after the end, until stopped'))
        self.declare_parameter('publish_clock', False, ParameterDescriptor(
            description='publish /clock (rosgraph_msgs/Clock) from the recorded times, at '
                        'each message and at least every 25 ms between them; the recorded '
                        '/clock topic, if any, is then not played',
            read_only=True))
        self.declare_parameter('delay', 0.0, ParameterDescriptor(
            description='s to wait after creating the publishers before playing (discovery)',
            floating_point_range=[FloatingPointRange(from_value=0.0, to_value=3600.0)],
            read_only=True))
        self.declare_parameter('wait_for_subscribers', 0.0, ParameterDescriptor(
            description='wait up to this many s until every played topic has a subscriber '
                        '(0: do not wait)',
            floating_point_range=[FloatingPointRange(from_value=0.0, to_value=3600.0)],
            read_only=True))

        bag = str(self.get_parameter('bag').value or '')
        if not bag:
            raise ReplayError('parameter bag is required (a bag directory or .mcap file): '
                              '--ros-args -p bag:=PATH')
        self.recording = Recording(bag, warn=self.get_logger().warning)
        self._players: Dict[str, object] = {}
        self._create_publishers(
            ['/' + n.lstrip('/') for n in topic_list(self.get_parameter('topics'))])
        if not self._players:
            self.recording.close()
            raise ReplayError(f'nothing to play in {bag}: no playable topic')
        self._clock_publisher = None
        if self.get_parameter('publish_clock').value:
            self._clock_publisher = self.create_publisher(
                Clock, CLOCK_TOPIC, QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))
        self.player = Player(
            lambda: self.recording.messages(), self._publish,
            self._publish_clock if self._clock_publisher is not None else None,
            rate=float(self.get_parameter('rate').value),
            start_offset=float(self.get_parameter('start_offset').value),
            loop=bool(self.get_parameter('loop').value), topics=list(self._players))
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.exit_code = 0
        self.finished = False
        self._thread = threading.Thread(target=self._play, name='replay', daemon=True)
        # Ctrl-C shuts the context down: stop publishing at once, not into a dead context.
        self.context.on_shutdown(self.player.stop)

    # -- parameters -----------------------------------------------------------------------
    def _validate_parameters(self, parameters: List[Parameter]) -> SetParametersResult:
        for parameter in parameters:
            try:
                if parameter.name == 'topics':
                    for name in ['/' + n.lstrip('/') for n in topic_list(parameter)]:
                        self.resolve_topic_name(name)
                elif parameter.name == 'bag' and parameter.type_ != Parameter.Type.STRING:
                    raise ValueError(f'bag must be a path, got {parameter.value!r}')
                elif parameter.name == 'rate' and not (
                        isinstance(parameter.value, (int, float)) and parameter.value > 0):
                    raise ValueError(f'rate must be a number > 0, got {parameter.value!r}')
            except (ValueError, TypeError, RuntimeError) as error:  # RCLError: bad name
                return SetParametersResult(
                    successful=False, reason=f'invalid {parameter.name}: {error}')
        return SetParametersResult(successful=True)

    def _apply_parameters(self, parameters: List[Parameter]):
        for parameter in parameters:
            if parameter.name == 'rate':
                self.player.set_rate(float(parameter.value))
            elif parameter.name == 'loop':
                self.player.loop = bool(parameter.value)

    # -- publishers ---------------------------------------------------------------------------
    def _create_publishers(self, wanted: List[str]):
        readable = self.recording.readable_topics()
        for name in wanted:
            if name not in self.recording.topics:
                self.get_logger().warning(f'topic {name} is not in the recording')
        publish_clock = bool(self.get_parameter('publish_clock').value)
        for name, info in readable.items():
            if wanted and name not in wanted:
                continue
            if publish_clock and name == CLOCK_TOPIC:
                self.get_logger().info('publish_clock is set: the recorded /clock is not played')
                continue
            qos = qos_from_offers(info.qos_profiles)
            try:
                self._players[name] = self.create_publisher(
                    message_class(info.type_name), name, qos)
            except (LookupError, RuntimeError, ValueError, TypeError) as error:
                self.get_logger().warning(f'topic {name} [{info.type_name}] not played: {error}')
                continue
            self.get_logger().info(
                f'playing {name} [{info.type_name}] {qos.reliability.name.lower()} '
                f'{qos.durability.name.lower()} depth {qos.depth}')

    def _publish(self, raw):
        # bytes: rclpy publishes them as they are (serialised CDR)
        self._players[raw.topic].publish(raw.data)

    def _publish_clock(self, nanoseconds: int):
        message = Clock()
        message.clock.sec, message.clock.nanosec = divmod(int(nanoseconds), 1_000_000_000)
        self._clock_publisher.publish(message)

    # -- playing --------------------------------------------------------------------------
    def start(self):
        """Wait for subscribers if asked, then play in a background thread."""
        self._thread.start()

    def _wait_for_subscribers(self):
        timeout = float(self.get_parameter('wait_for_subscribers').value)
        deadline = time.monotonic() + timeout
        while timeout > 0 and not self.player.stopped:
            missing = [t for t, p in self._players.items() if p.get_subscription_count() == 0]
            if not missing:
                return
            if time.monotonic() >= deadline:
                self.get_logger().warning(
                    f'no subscriber after {timeout} s on {", ".join(missing)}; playing anyway')
                return
            time.sleep(0.02)

    def _play(self):
        try:
            self._wait_for_subscribers()
            delay = float(self.get_parameter('delay').value)
            if delay > 0 and not self.player.sleep(delay):
                return
            started = time.monotonic()
            count = self.player.run()
            elapsed = time.monotonic() - started
            if self.player.stopped:
                return  # shutdown (Ctrl-C): the context may be gone, log nothing more
            for publisher in self._players.values():
                publisher.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT_S))
            self.get_logger().info(
                f'played {count} messages on {len(self._players)} topics in {elapsed:.3f} s'
                + (f' ({self.player.loops} passes)' if self.player.loops > 1 else ''))
        except Exception as error:  # noqa: B902 - reported and turned into the exit code
            if not self.player.stopped and self.context.ok():
                self.get_logger().error(f'playback failed: {error}')
                self.exit_code = 1
        finally:
            self.finished = True

    def stop(self):
        """Stop playing and wait for the playback thread."""
        self.player.stop()
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)

    def destroy_node(self):
        """Stop playing and close the recording before the node goes."""
        self.stop()
        self.recording.close()
        super().destroy_node()


def _play(node, executor):
    node.start()
    while rclpy.ok() and not node.finished:
        executor.spin_once(timeout_sec=0.05)
    return node.exit_code


def main(args=None):
    """Play the recording given by parameter bag; exit code 0 when it was played."""
    return run_node('replay_node', ReplayNode, SingleThreadedExecutor, args=args, spin=_play,
                    errors=(ReplayError, RecordingError, InvalidParameterValueException,
                            InvalidParameterTypeException), error_code=1)


if __name__ == '__main__':
    sys.exit(main())
