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

"""replay_node: the player's schedule (simulated clock) and real replays into a subscriber."""

import functools
import os
from pathlib import Path
import random
import subprocess
import sys
import threading

from mcap.reader import make_reader
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from toc_ros.nodes.replay_node import Player, qos_from_offers
from toc_ros.recording.bag_reader import RawMessage
from toc_ros.recording.bag_writer import BagWriter
from toc_ros.recording.msg_definitions import MessageDefinition
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

REPO = Path(__file__).resolve().parents[1]
DOMAIN_ID = random.Random().randint(1, 100)
T0 = 1_700_000_000_000_000_000  # recorded log time of the first message [ns]
LATCHED = {'history': 'keep_last', 'depth': 1, 'reliability': 'reliable',
           'durability': 'transient_local'}
RELIABLE = {'history': 'keep_last', 'depth': 10, 'reliability': 'reliable',
            'durability': 'volatile'}


# -- the schedule, on a simulated clock ------------------------------------------------------
class FakeClock:
    """monotonic() and wait() for the Player: waiting advances the time, nothing sleeps."""

    def __init__(self):
        self.now = 100.0

    def monotonic(self):
        return self.now

    def wait(self, seconds):
        self.now += seconds
        return False


def raw(topic, t_ns):
    return RawMessage(topic, 'std_msgs/msg/String', t_ns, t_ns, topic.encode())


def play(messages, **kwargs):
    clock = FakeClock()
    published, clocks = [], []
    player = Player(lambda: iter(messages), lambda m: published.append((clock.now, m)),
                    clocks.append if kwargs.pop('with_clock', False) else None,
                    monotonic=clock.monotonic, wait=clock.wait, **kwargs)
    return player, published, clocks, player.run()


MESSAGES = [raw('/a', T0), raw('/b', T0 + 200_000_000), raw('/a', T0 + 500_000_000),
            raw('/b', T0 + 1_500_000_000)]


def test_player_keeps_recorded_spacing_divided_by_rate():
    for rate in (1.0, 2.5, 0.5):
        _, published, _, count = play(MESSAGES, rate=rate)
        assert count == 4
        assert [m for _, m in published] == MESSAGES
        start = published[0][0]
        for wall, message in published:
            assert wall - start == pytest.approx((message.log_time_ns - T0) * 1e-9 / rate,
                                                 abs=1e-6)


def test_player_start_offset_and_topic_filter():
    # start_offset counts from the recording's first message, even one that is filtered out.
    _, published, _, count = play(MESSAGES, start_offset=0.3, topics=['/b'])
    assert count == 1 and published[0][1] == MESSAGES[3]
    _, published, _, _ = play(MESSAGES, start_offset=0.3)
    assert [m for _, m in published] == MESSAGES[2:]
    # the first played message keeps its distance from the start offset
    assert published[1][0] - published[0][0] == pytest.approx(1.0, abs=1e-6)


def test_player_rate_change_while_playing_and_loop():
    clock = FakeClock()
    times = []

    def publish(message):
        times.append(clock.now)
        if len(times) == 2:
            player.set_rate(4.0)  # from recorded time 0.2 s on, four times as fast
        if len(times) == 2 * len(MESSAGES):
            player.stop()

    player = Player(lambda: iter(MESSAGES), publish, monotonic=clock.monotonic,
                    wait=clock.wait, loop=True)
    assert player.run() == 8
    offsets = [t - times[0] for t in times[:4]]
    assert offsets == pytest.approx([0.0, 0.2, 0.2 + 0.3 / 4, 0.2 + 1.3 / 4], abs=1e-6)
    # the second pass starts over at the (new) rate
    second = [t - times[4] for t in times[4:]]
    assert second == pytest.approx([0.0, 0.05, 0.125, 0.375], abs=1e-6)
    assert player.loops == 2


def test_player_publishes_clock_between_messages():
    _, published, clocks, _ = play(MESSAGES, with_clock=True)
    assert clocks == sorted(clocks)
    assert clocks[0] == T0 and clocks[-1] == MESSAGES[-1].log_time_ns
    for message in MESSAGES:
        assert message.log_time_ns in clocks
    gaps = [b - a for a, b in zip(clocks, clocks[1:])]
    assert max(gaps) <= 25_000_000 + 1000  # at least every 25 ms of recorded time


def test_player_rejects_bad_rate():
    with pytest.raises(ValueError, match='rate'):
        Player(lambda: iter(()), print, rate=0.0)


def test_qos_from_recorded_offers():
    latched = qos_from_offers([LATCHED])
    assert latched.durability == DurabilityPolicy.TRANSIENT_LOCAL and latched.depth == 1
    mixed = qos_from_offers([LATCHED, RELIABLE])
    assert mixed.durability == DurabilityPolicy.VOLATILE and mixed.depth == 10
    assert mixed.reliability == ReliabilityPolicy.RELIABLE
    best_effort = qos_from_offers([{'reliability': 'best_effort', 'depth': 5,
                                    'history': 'keep_last', 'durability': 'volatile'}])
    assert best_effort.reliability == ReliabilityPolicy.BEST_EFFORT
    assert best_effort.depth == 5
    # Humble stored rmw enum values instead of names
    humble = qos_from_offers([{'history': 1, 'depth': 1, 'reliability': 1, 'durability': 1}])
    assert humble.durability == DurabilityPolicy.TRANSIENT_LOCAL
    # what rosbag2 records from discovery: no depth; a latched topic replays its last message
    jazzy = qos_from_offers([{'history': 'unknown', 'depth': 0, 'reliability': 'reliable',
                              'durability': 'transient_local'}])
    assert jazzy.durability == DurabilityPolicy.TRANSIENT_LOCAL and jazzy.depth == 1
    volatile = qos_from_offers([{'history': 'unknown', 'depth': 0, 'reliability': 'reliable',
                                 'durability': 'volatile'}])
    assert volatile.depth == 10
    default = qos_from_offers([])
    assert default.reliability == ReliabilityPolicy.RELIABLE and default.depth == 10


# -- real replays ---------------------------------------------------------------------------
def make_bag(path, chunk_size=1024 * 1024):
    """Write three ROS topics with irregular spacing, and one of an unknown type."""
    writer = BagWriter(path, chunk_size=chunk_size).create()
    writer.add_topic('/chatter', 'std_msgs/msg/String', [RELIABLE])
    writer.add_topic('/joint_states', 'sensor_msgs/msg/JointState', [RELIABLE])
    writer.add_topic('/trajectory', 'trajectory_msgs/msg/JointTrajectory', [LATCHED])
    writer.add_topic('/gadget', 'foo_msgs/msg/Gadget', [RELIABLE], type_hash='',
                     definition=MessageDefinition('foo_msgs/msg/Gadget', 'ros2msg', 'int32 x'))
    rng = random.Random(6)
    expected = []
    t = T0
    for i in range(40):
        t += rng.choice((6, 15, 30, 45)) * 1_000_000
        if i % 10 == 3:
            topic = '/trajectory'
            msg = JointTrajectory(joint_names=['rotation_joint', 'extension_joint'], points=[
                JointTrajectoryPoint(positions=[0.1 * i, 1.0], effort=[600.0, -500.0])])
        elif i % 2:
            topic, msg = '/chatter', String(data=f'message {i} ' + 'x' * i)
        else:
            topic, msg = '/joint_states', JointState(name=['rotation_joint'],
                                                     position=[float(i)])
        data = serialize_message(msg)
        writer.write(topic, data, t)
        expected.append((topic, data, t))
        if i % 7 == 0:
            writer.write('/gadget', b'\x00\x01\x00\x00\x07\x00\x00\x00', t + 1_000_000)
    writer.close()
    return expected


@pytest.fixture(scope='module')
def ros_env():
    env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN_ID),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               AMENT_PREFIX_PATH=os.environ.get('AMENT_PREFIX_PATH', sys.prefix),
               PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get('PYTHONPATH', '')]),
               PYTHONUNBUFFERED='1')
    os.environ['ROS_DOMAIN_ID'] = env['ROS_DOMAIN_ID']
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    return env


class Listener:
    """Raw subscriptions in this process; each message with its DDS receive time."""

    def __init__(self, topics):
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node('replay_listener', context=self.context)
        self.received = []
        self.lock = threading.Lock()
        for topic, msg_type, qos in topics:
            self.node.create_subscription(msg_type, topic, functools.partial(self.on, topic),
                                          qos, raw=True)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.spin, daemon=True)
        self.running = True
        self.thread.start()

    def on(self, topic, data, info):
        with self.lock:
            self.received.append((topic, bytes(data), int(info['received_timestamp'])))

    def spin(self):
        while self.running:
            self.executor.spin_once(timeout_sec=0.05)

    def close(self):
        self.running = False
        self.thread.join()
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


def same_payload(sent, received):
    """DDS pads a serialised payload to a multiple of 4 bytes; the rest is byte for byte."""
    return received[:len(sent)] == sent and len(received) - len(sent) < 4


def run_replay(env, *params, timeout=60):
    command = [sys.executable, '-m', 'toc_ros.nodes.replay_node', '--ros-args']
    for param in params:
        command += ['-p', param]
    return subprocess.run(command, env=env, capture_output=True, text=True, timeout=timeout)


LATCHED_QOS = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
TOPICS = [('/chatter', String, 10), ('/joint_states', JointState, 10),
          ('/trajectory', JointTrajectory, LATCHED_QOS)]


@pytest.mark.slow
def test_replay_same_messages_order_and_timing(tmp_path, ros_env):
    expected = make_bag(tmp_path / 'run')
    listener = Listener(TOPICS)
    try:
        result = run_replay(ros_env, f'bag:={tmp_path / "run"}', 'wait_for_subscribers:=10.0',
                            'delay:=0.3')
    finally:
        listener.close()
    assert result.returncode == 0, result.stderr
    log = result.stdout + result.stderr
    assert 'foo_msgs/msg/Gadget' in log and 'not installed' in log
    received = sorted(listener.received, key=lambda r: r[2])
    assert [t for t, _, _ in received] == [t for t, _, _ in expected]
    for (_, got, _), (_, sent, _) in zip(received, expected):
        assert same_payload(sent, got), (sent, got)
    recv0, log0 = received[0][2], expected[0][2]
    errors = [abs((r[2] - recv0) - (e[2] - log0)) * 1e-9 for r, e in zip(received, expected)]
    assert max(errors) < 0.010, f'timing error up to {max(errors) * 1e3:.1f} ms'


@pytest.mark.slow
def test_replay_truncated_filtered_offset_clock(tmp_path, ros_env):
    expected = make_bag(tmp_path / 'run', chunk_size=600)
    mcap = tmp_path / 'run' / 'run_0.mcap'
    with open(mcap, 'rb') as stream:
        chunks = sorted(make_reader(stream).get_summary().chunk_indexes,
                        key=lambda c: c.chunk_start_offset)
    middle = chunks[len(chunks) // 2]  # cut the file in the middle of its middle chunk
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(mcap.read_bytes()[:middle.chunk_start_offset + middle.chunk_length // 2])
    listener = Listener(TOPICS + [('/clock', Clock, QoSProfile(
        depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))])
    try:
        result = run_replay(ros_env, f'bag:={cut}', 'wait_for_subscribers:=10.0',
                            'delay:=0.3', 'rate:=3.0', 'start_offset:=0.2',
                            'topics:=[/chatter, /trajectory]', 'publish_clock:=true')
    finally:
        listener.close()
    assert result.returncode == 0, result.stderr
    assert 'cut off' in result.stderr
    received = sorted(listener.received, key=lambda r: r[2])
    played = [r for r in received if r[0] != '/clock']
    start = expected[0][2] + 200_000_000
    wanted = [e for e in expected if e[0] in ('/chatter', '/trajectory') and e[2] >= start]
    # the cut-off file holds a prefix of the wanted messages: some, not all
    assert 0 < len(played) < len(wanted)
    assert [p[0] for p in played] == [w[0] for w in wanted[:len(played)]]
    assert all(same_payload(w[1], p[1]) for w, p in zip(wanted, played))
    # three times as fast
    errors = [abs((p[2] - played[0][2]) - (w[2] - wanted[0][2]) / 3.0) * 1e-9
              for p, w in zip(played, wanted)]
    assert max(errors) < 0.010, f'timing error up to {max(errors) * 1e3:.1f} ms'
    # one /clock per played message at least, rising, within the played part
    stamps = []
    for topic, data, _ in received:
        if topic == '/clock':
            clock = deserialize_message(data, Clock).clock
            stamps.append(clock.sec * 1_000_000_000 + clock.nanosec)
    assert len(stamps) >= len(played) and stamps == sorted(stamps)
    assert stamps[0] >= start and stamps[-1] == wanted[len(played) - 1][2]


@pytest.mark.slow
def test_replay_refuses_missing_and_foreign_files(tmp_path, ros_env):
    missing = run_replay(ros_env, f'bag:={tmp_path / "nothing"}')
    assert missing.returncode == 1
    assert 'no such file or directory' in missing.stderr
    foreign = tmp_path / 'notes.mcap'
    foreign.write_text('just text\n')
    result = run_replay(ros_env, f'bag:={foreign}')
    assert result.returncode == 1
    assert 'not an MCAP file' in result.stderr
