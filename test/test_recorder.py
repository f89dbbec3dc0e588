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

"""recorder_node as a separate process, fed over DDS by publishers in this test process."""

import datetime
import os
from pathlib import Path
import random
import resource
import signal
import subprocess
import sys
import threading
import time

from builtin_interfaces.msg import Duration as DurationMsg
from mcap.reader import make_reader
from mcap_ros2.reader import read_ros2_messages
import pytest
import rclpy
from rclpy.context import Context
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from rclpy.signals import SignalHandlerOptions
from rosbags.highlevel import AnyReader
from std_msgs.msg import String
from toc_ros.nodes.common import topic_list
from toc_ros.nodes.recorder_node import adapt_qos, RecorderNode
from toc_ros.recording.bag_reader import Recording
from toc_ros.recording.bag_writer import BagWriter
from toc_ros.recording.process import default_output_dir, recorder_command, RecorderProcess
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
import yaml

MCAP_MAGIC = b'\x89MCAP0\r\n'
RELIABLE = {'reliability': ReliabilityPolicy.RELIABLE, 'history': HistoryPolicy.KEEP_LAST}


@pytest.fixture(scope='module')
def ros():
    """Give a node in a private rclpy context on a random domain (recorders inherit it)."""
    saved = {k: os.environ.get(k) for k in ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE')}
    os.environ['ROS_DOMAIN_ID'] = str(random.randint(1, 100))
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    context = Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node('recorder_test_publisher', context=context)
    yield node
    node.destroy_node()
    rclpy.try_shutdown(context=context)
    for key, value in saved.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value


def start_recorder(tmp_path, topics=None, **popen_kwargs):
    log = open(tmp_path / 'recorder.log', 'w')
    recorder = RecorderProcess(tmp_path / 'bag', topics=topics,
                               env={'ROS_LOG_DIR': str(tmp_path / 'ros_log')},
                               stdout=log, stderr=subprocess.STDOUT, **popen_kwargs)
    recorder.start()
    log.close()
    return recorder


def recorder_log(tmp_path):
    return (tmp_path / 'recorder.log').read_text()


def wait_for_subscribers(recorder, *publishers, timeout=20.0):
    """Discovery: every publisher matched the recorder's subscription."""
    deadline = time.monotonic() + timeout
    while any(p.get_subscription_count() < 1 for p in publishers):
        assert recorder.process.poll() is None, 'recorder exited early'
        assert time.monotonic() < deadline, 'recorder did not subscribe'
        time.sleep(0.02)


def publish_strings(publisher, first, count, rate_hz=1000.0):
    """Publish 'msg <k>' for k in [first, first + count) at a steady rate."""
    start = time.perf_counter()
    for k in range(count):
        publisher.publish(String(data=f'msg {first + k:05d}'))
        delay = start + (k + 1) / rate_hz - time.perf_counter()
        if delay > 0:
            time.sleep(delay)


def assert_complete_mcap(path):
    """Footer and summary present (the reader finds the summary through the footer)."""
    data = Path(path).read_bytes()
    assert data.startswith(MCAP_MAGIC) and data.endswith(MCAP_MAGIC)
    with open(path, 'rb') as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None and summary.statistics is not None
    return summary


@pytest.mark.slow
def test_records_10000_messages_at_1khz_without_loss(ros, tmp_path):
    count = 10_000
    publisher = ros.create_publisher(String, '/rec/chatter', QoSProfile(depth=count, **RELIABLE))
    recorder = start_recorder(tmp_path, topics=['/rec/chatter'])
    wait_for_subscribers(recorder, publisher)
    began = time.monotonic()
    publish_strings(publisher, 0, count)
    assert time.monotonic() - began >= count / 1000.0  # really paced at 1 kHz
    assert publisher.wait_for_all_acked(Duration(seconds=20))
    exit_code = recorder.stop(sig=signal.SIGINT)
    log = recorder_log(tmp_path)
    assert exit_code == 0, log
    assert f'recording /rec/chatter to {recorder.output}' in log
    assert f'recorded {count} messages' in log

    summary = assert_complete_mcap(recorder.mcap_path)
    assert summary.statistics.message_count == count
    messages = list(read_ros2_messages(recorder.mcap_path))
    assert [m.ros_msg.data for m in messages] == [f'msg {k:05d}' for k in range(count)]
    assert [m.sequence_count for m in messages] == list(range(1, count + 1))
    assert all(m.log_time_ns >= m.publish_time_ns for m in messages)  # receive after send
    publish_times = [m.publish_time_ns for m in messages]
    assert publish_times == sorted(publish_times)
    assert publish_times[-1] - publish_times[0] >= 0.99 * (count - 1) * 1e6  # sender stamps
    channel = messages[0].channel
    assert channel.message_encoding == 'cdr'
    assert yaml.safe_load(channel.metadata['offered_qos_profiles'])[0]['reliability'] == (
        'reliable')
    assert messages[0].schema.name == 'std_msgs/msg/String'

    info = yaml.safe_load((Path(recorder.output) / 'metadata.yaml').read_text())
    info = info['rosbag2_bagfile_information']
    assert (info['version'], info['storage_identifier'], info['ros_distro']) == (
        9, 'mcap', 'jazzy')
    assert info['relative_file_paths'] == ['bag_0.mcap'] and info['message_count'] == count
    [topic] = info['topics_with_message_count']
    assert topic['message_count'] == count
    assert topic['topic_metadata']['type_description_hash'] == channel.metadata[
        'topic_type_hash'] and channel.metadata['topic_type_hash'].startswith('RIHS01_')
    with AnyReader([Path(recorder.output)]) as reader:  # checks the hash against the schema
        assert reader.message_count == count
        last = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages()][-1]
    assert last.data == f'msg {count - 1:05d}'


@pytest.mark.slow
def test_sigterm_mid_run_leaves_a_valid_bag_with_latched_messages(ros, tmp_path):
    trajectory = JointTrajectory(joint_names=['rotation_joint', 'extension_joint'])
    trajectory.header.frame_id = 'base_link'
    trajectory.points = [JointTrajectoryPoint(
        positions=[0.26, 1.0], effort=[600.0, -500.0],
        time_from_start=DurationMsg(sec=1, nanosec=250_000_000))]
    latched = ros.create_publisher(JointTrajectory, '/rec/trajectory', QoSProfile(
        depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, **RELIABLE))
    latched.publish(trajectory)  # before the recorder exists
    stream = ros.create_publisher(String, '/rec/stream', QoSProfile(depth=2000, **RELIABLE))

    recorder = start_recorder(tmp_path)  # no topics: everything, discovered on the fly
    wait_for_subscribers(recorder, latched, stream)
    publish_strings(stream, 0, 1000)
    assert stream.wait_for_all_acked(Duration(seconds=10))
    assert latched.wait_for_all_acked(Duration(seconds=10))
    recorder.process.send_signal(signal.SIGTERM)
    publish_strings(stream, 1000, 1000)  # still publishing while it shuts down
    exit_code = recorder.process.wait(timeout=20)
    log = recorder_log(tmp_path)
    assert exit_code == 0, log
    assert 'SIGTERM received' in log

    assert_complete_mcap(recorder.mcap_path)
    with AnyReader([Path(recorder.output)]) as reader:  # types from the bag's schemas only
        assert {'/rec/trajectory', '/rec/stream'} <= {c.topic for c in reader.connections}
        latched_qos = next(c for c in reader.connections if c.topic == '/rec/trajectory')
        assert latched_qos.ext.offered_qos_profiles[0].durability.name == 'TRANSIENT_LOCAL'
        received = {}
        for connection, _, raw in reader.messages():
            received.setdefault(connection.topic, []).append(
                reader.deserialize(raw, connection.msgtype))
    data = [m.data for m in received['/rec/stream']]
    assert 1000 <= len(data) <= 2000
    assert data == [f'msg {k:05d}' for k in range(len(data))]  # no gap, nothing after a loss
    [recorded] = received['/rec/trajectory']
    assert recorded.header.frame_id == 'base_link'
    assert recorded.joint_names == ['rotation_joint', 'extension_joint']
    assert list(recorded.points[0].positions) == [0.26, 1.0]
    assert list(recorded.points[0].effort) == [600.0, -500.0]
    assert recorded.points[0].time_from_start.nanosec == 250_000_000


@pytest.mark.slow
def test_disk_full_while_recording_stops_with_a_message(ros, tmp_path):
    def limit_file_size():  # EFBIG past 300 kB, like a full disk
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (300_000, 300_000))

    publisher = ros.create_publisher(String, '/rec/big', QoSProfile(depth=200, **RELIABLE))
    recorder = start_recorder(tmp_path, topics=['/rec/big'], preexec_fn=limit_file_size)
    wait_for_subscribers(recorder, publisher)
    for k in range(200):  # 2 MB, more than one 1 MiB chunk
        publisher.publish(String(data=f'{k:05d}' + 'x' * 10_000))
    try:
        exit_code = recorder.process.wait(timeout=20)  # stops by itself
    finally:
        recorder.stop()
    log = recorder_log(tmp_path)
    assert exit_code == 1, log
    assert 'recorder_node: error: ' in log and 'File too large' in log
    assert 'is incomplete' in log and 'Traceback' not in log


def test_node_in_process_closes_the_bag_when_destroyed(ros, tmp_path):
    publisher = ros.create_publisher(String, '/rec/inproc', QoSProfile(depth=10, **RELIABLE))
    node = RecorderNode(context=ros.context, parameter_overrides=[
        Parameter('output', value=str(tmp_path / 'bag')),
        Parameter('topics', value=['/rec/inproc'])])
    executor = SingleThreadedExecutor(context=ros.context)
    executor.add_node(node)
    try:
        deadline = time.monotonic() + 20
        while publisher.get_subscription_count() < 1 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        for k in range(5):
            publisher.publish(String(data=f'in-process {k}'))
        while node.message_count < 5 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
    finally:
        executor.remove_node(node)
        node.destroy_node()
    assert_complete_mcap(node.writer.mcap_path)
    with AnyReader([tmp_path / 'bag']) as reader:
        data = [reader.deserialize(raw, c.msgtype).data for c, _, raw in reader.messages()]
    assert data == [f'in-process {k}' for k in range(5)]


@pytest.mark.slow
@pytest.mark.parametrize('case', ['parent_is_a_file', 'not_empty', 'bad_regex'])
def test_start_errors_exit_non_zero_with_a_clear_message(ros, tmp_path, case):
    output, extra, expected = tmp_path / 'bag', [], None
    if case == 'parent_is_a_file':
        (tmp_path / 'file').write_text('')
        output, expected = tmp_path / 'file' / 'bag', 'cannot create output directory'
    elif case == 'not_empty':
        output.mkdir()
        (output / 'old.mcap').write_text('earlier run')
        expected = 'already exists and is not empty'
    else:
        extra, expected = ['-p', 'exclude:=(unclosed'], 'invalid exclude'
    result = subprocess.run(
        recorder_command(output, ['/x'], extra_ros_args=extra), capture_output=True,
        text=True, timeout=30, cwd=tmp_path,
        env=dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]),
                 ROS_LOG_DIR=str(tmp_path / 'ros_log')))
    assert result.returncode != 0
    assert 'recorder_node: error: ' in result.stderr and expected in result.stderr, result.stderr
    assert 'Traceback' not in result.stderr
    if case == 'not_empty':
        assert (output / 'old.mcap').read_text() == 'earlier run'


def test_command_line_values_are_quoted_and_parsed_back():
    argv = recorder_command('runs/2026', ['/a', '~/progress'], exclude='^/rosout$')
    assert argv[1:4] == ['-m', 'toc_ros.nodes.recorder_node', '--ros-args']
    assert argv[4:] == ['-p', 'output:="runs/2026"', '-p', 'topics:=["/a", "~/progress"]',
                        '-p', 'exclude:="^/rosout$"']
    assert default_output_dir(now=datetime.datetime(
        2026, 11, 25, 17, 0, 0, tzinfo=datetime.timezone.utc)) == 'runs/2026-11-25T17-00-00Z'
    assert topic_list(Parameter('t', Parameter.Type.STRING_ARRAY, ['/a', ' b '])) == ['/a', 'b']
    assert topic_list(Parameter('t', Parameter.Type.STRING, '/a, /b  /c')) == ['/a', '/b', '/c']
    assert topic_list(Parameter('t', Parameter.Type.NOT_SET, None)) == []
    assert topic_list(Parameter('t', Parameter.Type.BYTE_ARRAY, [])) == []
    with pytest.raises(ValueError):
        topic_list(Parameter('t', Parameter.Type.INTEGER, 3))


def test_qos_adapts_to_publishers_like_rosbag2():
    latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                         reliability=ReliabilityPolicy.RELIABLE)
    volatile_best_effort = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)
    qos, warnings = adapt_qos([latched])
    assert qos.durability == DurabilityPolicy.TRANSIENT_LOCAL
    assert qos.reliability == ReliabilityPolicy.RELIABLE
    assert qos.history == HistoryPolicy.KEEP_ALL and not warnings
    qos, warnings = adapt_qos([latched, volatile_best_effort])
    assert qos.durability == DurabilityPolicy.VOLATILE
    assert qos.reliability == ReliabilityPolicy.BEST_EFFORT and len(warnings) == 2
    qos, _ = adapt_qos([QoSProfile(depth=50)])
    assert (qos.history, qos.depth) == (HistoryPolicy.KEEP_LAST, 50)


@pytest.mark.slow
def test_sigkill_at_1khz_loses_at_most_0_2_s_and_recover_gives_a_valid_bag(
        ros, tmp_path, record_property):
    publisher = ros.create_publisher(String, '/rec/crash', QoSProfile(depth=10_000, **RELIABLE))
    recorder = start_recorder(tmp_path, topics=['/rec/crash'])
    wait_for_subscribers(recorder, publisher)
    published = []  # send time [ns] of 'msg k', while the recorder lives
    stop = threading.Event()

    def publish():
        start = time.perf_counter()
        for k in range(10_000):
            if stop.is_set():
                return
            published.append(time.time_ns())
            publisher.publish(String(data=f'msg {k:05d}'))
            delay = start + (k + 1) / 1000.0 - time.perf_counter()
            if delay > 0:
                time.sleep(delay)

    thread = threading.Thread(target=publish)
    thread.start()
    time.sleep(5.0)
    killed_ns = time.time_ns()
    sent_before_kill = len(published)
    recorder.process.kill()
    assert recorder.process.wait(timeout=10) == -signal.SIGKILL
    stop.set()
    thread.join()
    assert sent_before_kill >= 4900

    # The killed bag: metadata.yaml (written while recording) and every complete chunk.
    bag = Path(recorder.output)
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert [t['topic_metadata']['name'] for t in info['topics_with_message_count']] == [
        '/rec/crash']
    warnings = []
    with Recording(bag, warnings.append) as recording:
        assert recording.damaged
        raws = list(recording.messages())
    data = [deserialize_message(raw.data, String).data for raw in raws]
    assert data == [f'msg {k:05d}' for k in range(len(data))]  # complete chunks, no holes
    lost_messages = sent_before_kill - len(data)
    lost_s = (killed_ns - raws[-1].log_time_ns) * 1e-9
    record_property('sigkill_lost_messages', lost_messages)
    record_property('sigkill_lost_s', round(lost_s, 4))
    print(f'SIGKILL after 5 s at 1 kHz: {len(data)} of {sent_before_kill} messages recovered, '
          f'lost {lost_messages} messages, last recovered {lost_s:.3f} s before the kill')
    assert lost_messages <= 200 and lost_s <= 0.2, warnings
    [warning] = warnings
    assert 'cut off' in warning and f'recovered {len(data)} messages' in warning

    # toc-bag info says what it is; toc-bag recover writes a complete, indexed bag.
    result = subprocess.run([sys.executable, '-m', 'toc_ros.recording.bag_tool', 'info',
                             str(bag)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 1, result.stderr
    assert 'NOT COMPLETE' in result.stdout and f'messages: {len(data)},' in result.stdout
    result = subprocess.run([sys.executable, '-m', 'toc_ros.recording.bag_tool', 'recover',
                             str(bag)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    fixed = Path(str(bag) + '-recovered')
    assert f'recovered {len(data)} messages on 1 topics' in result.stdout
    assert f'into {fixed}' in result.stdout
    summary = assert_complete_mcap(fixed / 'bag-recovered_0.mcap')
    assert summary.statistics.message_count == len(data) and summary.chunk_indexes
    messages = list(read_ros2_messages(str(fixed / 'bag-recovered_0.mcap')))
    assert [m.ros_msg.data for m in messages] == data
    assert [m.log_time_ns for m in messages] == [raw.log_time_ns for raw in raws]
    info = yaml.safe_load((fixed / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['message_count'] == len(data)
    assert info['relative_file_paths'] == ['bag-recovered_0.mcap']
    with AnyReader([fixed]) as reader:
        assert reader.message_count == len(data)
        assert [reader.deserialize(raw, c.msgtype).data
                for c, _, raw in reader.messages()] == data
    result = subprocess.run([sys.executable, '-m', 'toc_ros.recording.bag_tool', 'info',
                             str(fixed)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0 and 'complete' in result.stdout, result.stdout

    # replay_node plays the killed bag as it is and says how much it recovered.
    log_path = tmp_path / 'replay.log'
    with open(log_path, 'w') as log:
        replay = subprocess.run(
            [sys.executable, '-m', 'toc_ros.nodes.replay_node', '--ros-args',
             '-p', f'bag:={bag}', '-p', 'rate:=20.0'],
            stdout=log, stderr=subprocess.STDOUT, timeout=60,
            env=dict(os.environ, ROS_LOG_DIR=str(tmp_path / 'ros_log')))
    log = log_path.read_text()
    assert replay.returncode == 0, log
    assert 'cut off' in log and f'recovered {len(data)} messages' in log
    assert f'played {len(data)} messages' in log


def test_flush_period_bounds_what_is_only_in_memory(tmp_path):
    """Without a close, the file on disk holds everything written up to one period ago."""
    writer = BagWriter(tmp_path / 'bag', flush_period=0.05).create()
    writer.add_topic('/t', 'std_msgs/msg/String')
    for k in range(20):
        writer.write('/t', serialize_message(String(data=f'm{k}')), 1_000 + k)
    # Six periods; on a loaded machine the flusher thread (and its fsync) may need longer:
    # wait for its first flush, then one more period for a flush that began mid-writes.
    time.sleep(0.3)
    deadline = time.monotonic() + 10.0
    while writer.flush_count == 0 and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.1)
    before = writer.flush_count
    with Recording(tmp_path / 'bag') as recording:  # the file as a crash would leave it
        assert [deserialize_message(r.data, String).data for r in recording.messages()] == [
            f'm{k}' for k in range(20)]
        assert recording.damaged
    time.sleep(0.2)
    assert writer.flush_count == before  # nothing new: no empty chunks
    writer.close()
    with Recording(tmp_path / 'bag') as recording:
        assert len(list(recording.messages())) == 20 and not recording.damaged
    with pytest.raises(ValueError):
        BagWriter(tmp_path / 'other', flush_period=0.0)
