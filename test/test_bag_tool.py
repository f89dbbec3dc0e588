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

"""toc-bag info / recover on complete, cut-off, foreign and bad inputs (no ROS graph)."""

import json
from pathlib import Path
import re
import subprocess
import sys

from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from mcap_ros2.reader import read_ros2_messages
import pytest
from rclpy.serialization import serialize_message
from rosbags.highlevel import AnyReader
from std_msgs.msg import String
from toc_ros.recording.bag_reader import Recording
from toc_ros.recording.bag_tool import default_output, main
from toc_ros.recording.bag_writer import BagWriter
from toc_ros.recording.msg_definitions import full_definition
import yaml

T0 = 1_700_000_000_000_000_000


def strings(count):
    return [serialize_message(String(data=f'message {k}')) for k in range(count)]


def write_bag(path, count, **kwargs):
    sent = strings(count)
    with BagWriter(path, flush_period=None, **kwargs) as writer:
        writer.add_topic('/chatter', 'std_msgs/msg/String')
        for k, data in enumerate(sent):
            writer.write('/chatter', data, T0 + k * 1_000_000)
    return sent


def test_info_and_recover_of_a_complete_bag(tmp_path, capsys):
    sent = write_bag(tmp_path / 'bag', 300)
    assert main(['info', str(tmp_path / 'bag')]) == 0
    out = capsys.readouterr().out
    assert 'bag_0.mcap' in out and ', complete' in out and 'messages: 300,' in out
    assert '/chatter  std_msgs/msg/String  300 messages' in out
    assert main(['recover', str(tmp_path / 'bag'), str(tmp_path / 'copy')]) == 0
    assert 'recovered 300 messages on 1 topics' in capsys.readouterr().out
    with Recording(tmp_path / 'copy') as recording:
        assert [raw.data for raw in recording.messages()] == sent
        assert not recording.damaged
        assert recording.topics['/chatter'].type_hash.startswith('RIHS01_')
    # output exists: a clear error, nothing overwritten
    assert main(['recover', str(tmp_path / 'bag'), str(tmp_path / 'copy')]) == 2
    assert 'already exists and is not empty' in capsys.readouterr().err


def test_recover_a_cut_off_bare_mcap_with_a_foreign_channel(tmp_path, capsys):
    """Zstd chunks as `ros2 bag record` writes them, plus a JSON channel, cut in the middle."""
    path = tmp_path / 'rec.mcap'
    definition = full_definition('std_msgs/msg/String')
    sent = strings(400)
    with open(path, 'wb') as stream:
        writer = Writer(stream, chunk_size=4000, compression=CompressionType.ZSTD)
        writer.start(profile='ros2', library='libmcap 1.4.0')
        schema = writer.register_schema('std_msgs/msg/String', 'ros2msg',
                                        definition.text.encode())
        channel = writer.register_channel('/chatter', 'cdr', schema, {
            'offered_qos_profiles': '- history: keep_last\n  depth: 10\n', 'topic_type_hash': ''})
        json_schema = writer.register_schema('Note', 'jsonschema', b'{}')
        notes = writer.register_channel('/notes', 'json', json_schema)
        for k, data in enumerate(sent):
            writer.add_message(channel, T0 + k * 1000, data, T0 + k * 1000, k)
            writer.add_message(notes, T0 + k * 1000, json.dumps({'k': k}).encode(), T0, k)
        writer.finish()
    data = path.read_bytes()
    path.write_bytes(data[:len(data) // 2])
    assert main(['info', str(path)]) == 1
    captured = capsys.readouterr()
    assert 'NOT COMPLETE: the file is cut off inside a record' in captured.out
    assert 'toc-bag recover' in captured.out
    assert main(['recover', str(path)]) == 0
    captured = capsys.readouterr()
    assert "topic /notes left out: message encoding 'json'" in captured.err
    out = Path(default_output(str(path)))
    assert out == tmp_path / 'rec-recovered'
    mcap_path = out / 'rec-recovered_0.mcap'
    with open(mcap_path, 'rb') as stream:
        summary = make_reader(stream).get_summary()
    got = [m.ros_msg.data for m in read_ros2_messages(str(mcap_path))]
    assert 0 < len(got) < 400 and summary.statistics.message_count == len(got)
    assert got == [f'message {k}' for k in range(len(got))]
    with AnyReader([out]) as reader:
        assert reader.message_count == len(got)
        [connection] = reader.connections
        assert connection.ext.offered_qos_profiles[0].depth == 10
    info = yaml.safe_load((out / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['message_count'] == len(got)


def test_nothing_readable_and_bad_inputs(tmp_path, capsys):
    bag = tmp_path / 'bag'
    write_bag(bag, 0)
    mcap_path = bag / 'bag_0.mcap'
    mcap_path.write_bytes(mcap_path.read_bytes()[:40])  # killed before the first chunk
    assert main(['info', str(bag)]) == 1
    assert 'messages: 0' in capsys.readouterr().out
    assert main(['recover', str(bag)]) == 0
    assert 'recovered 0 messages' in capsys.readouterr().out
    (tmp_path / 'notes.mcap').write_text('not a recording\n')
    assert main(['info', str(tmp_path / 'notes.mcap')]) == 2
    assert 'not an MCAP file' in capsys.readouterr().err
    assert main(['recover', str(tmp_path / 'missing')]) == 2
    assert 'no such file or directory' in capsys.readouterr().err
    assert main(['bogus']) == 2


KILLED_WRITER = """
import os, sys, time
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState
from toc_ros.recording.bag_writer import BagWriter
writer = BagWriter(sys.argv[1]).create()  # default flush policy: 0.1 s, fsync
writer.add_topic('/joint_states', 'sensor_msgs/msg/JointState')
t0 = time.time_ns()
for k in range(1000):
    msg = JointState(name=['rotation_joint', 'extension_joint'], position=[0.26, 1.0],
                     velocity=[0.0, 0.0], effort=[0.0, 0.0])
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t0 + k * 1_000_000, 10**9)
    writer.write('/joint_states', serialize_message(msg), t0 + k * 1_000_000)
    time.sleep(0.001)
print(writer.message_count, flush=True)
os._exit(0)  # no close(), like a SIGKILL
"""


# Two processes (a writer killed mid-recording, then the analysis CLI): an integration test.
@pytest.mark.slow
def test_toc_analyze_reads_a_bag_whose_writer_died(tmp_path):
    bag = tmp_path / 'died'
    written = subprocess.run([sys.executable, '-c', KILLED_WRITER, str(bag)],
                             capture_output=True, text=True, timeout=60)
    assert written.returncode == 0, written.stderr
    assert int(written.stdout) == 1000
    result = subprocess.run([sys.executable, '-m', 'toc_ros.analysis.cli', str(bag),
                             '--out', str(tmp_path / 'report')],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 1, result.stderr  # report written, recording damaged
    [warning] = [line for line in result.stderr.splitlines() if 'cut off' in line]
    recovered = int(re.search(r'recovered (\d+) messages', warning).group(1))
    assert 800 <= recovered < 1000, warning  # at most ~0.2 s of 1 kHz lost
    assert (tmp_path / 'report' / 'summary.md').exists()
