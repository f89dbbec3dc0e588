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

"""Bag writer and schema texts, checked with independent readers (no ROS graph needed)."""

import os
from pathlib import Path
import subprocess
import sys
import textwrap
import threading
import time

from builtin_interfaces.msg import Duration, Time
from geometry_msgs.msg import Point
from mcap.reader import make_reader
from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosbags.highlevel import AnyReader
from rosbags.interfaces import Nodetype
from rosbags.typesys import get_typestore, Stores
from std_msgs.msg import String
from toc_ros.recording.bag_metadata import qos_profile_to_dict
from toc_ros.recording.bag_reader import Recording
from toc_ros.recording.bag_writer import BagWriter, RecordingError
from toc_ros.recording.msg_definitions import (
    full_definition, MessageDefinitionError, MessageDefinitionSource, type_description_hash)
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
from visualization_msgs.msg import Marker, MarkerArray
import yaml

REPO = Path(__file__).resolve().parents[1]
DELIM = '=' * 80 + '\n'


def fake_source(files):
    """Definition source over an in-memory {('pkg/msg/Type', '.msg'): text} dict."""
    def loader(package, namespace, name, extension):
        try:
            return files[(f'{package}/{namespace}/{name}', extension)]
        except KeyError:
            raise MessageDefinitionError(f'no {package}/{namespace}/{name}{extension}')
    return MessageDefinitionSource(loader)


TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
NUMPY_TYPES = {'bool': np.bool_, 'float32': np.float32, 'float64': np.float64}
NUMPY_TYPES.update(
    {f'{u}int{n}': np.dtype(f'{u}int{n}') for u in ('', 'u') for n in (8, 16, 32, 64)})


def to_rosbags(msg, type_name):
    """Copy an rclpy message into a rosbags one, field by field."""
    values = {}
    for name, (kind, spec) in TYPESTORE.fielddefs[type_name][1]:
        value = getattr(msg, name)
        if kind == Nodetype.BASE:
            values[name] = value
        elif kind == Nodetype.NAME:
            values[name] = to_rosbags(value, spec)
        elif spec[0][0] == Nodetype.NAME:
            values[name] = [to_rosbags(v, spec[0][1]) for v in value]
        elif spec[0][1][0] == 'string':
            values[name] = list(value)
        else:
            values[name] = np.array(list(value), dtype=NUMPY_TYPES[spec[0][1][0]])
    return TYPESTORE.types[type_name](**values)


def cdr(msg, type_name):
    """
    CDR bytes of an rclpy message, serialised by rosbags (independent of our schema texts).

    Not rclpy's serialize_message: in these wheels it returns trailing garbage bytes.
    """
    return bytes(TYPESTORE.serialize_cdr(to_rosbags(msg, type_name), type_name))


def decode(type_name, cdr):
    """Decode CDR bytes with mcap-ros2-support, using our schema text."""
    definition = full_definition(type_name)
    schema = Schema(id=1, name=type_name, encoding=definition.encoding,
                    data=definition.text.encode())
    return DecoderFactory().decoder_for('cdr', schema)(cdr)


# -- schema texts ------------------------------------------------------------------------------

def test_schema_text_is_rosbag2s_layout():
    # The expected string of rosbag2_cpp's own test (can_find_msg_deps).
    source = fake_source({
        ('rosbag2_test_msgdefs/msg/ComplexMsg', '.msg'): 'rosbag2_test_msgdefs/BasicMsg b\n',
        ('rosbag2_test_msgdefs/msg/BasicMsg', '.msg'): 'float32 c\n',
    })
    text = source.get('rosbag2_test_msgdefs/msg/ComplexMsg').text
    assert text == ('rosbag2_test_msgdefs/BasicMsg b\n\n' + DELIM
                    + 'MSG: rosbag2_test_msgdefs/BasicMsg\nfloat32 c\n')


def test_schema_dependencies_depth_first_sorted_once_and_field_syntax_kept():
    root = textwrap.dedent("""\
        # Comment naming other_pkg/Ghost ghost: not a field
        int32 ANSWER=42
        string<=10 name "default"
        wstring wide
        Zed[<=3] zeds
        Inner inner
        other_pkg/Leaf[4] leaves
        float64 x 1.5
        """)
    source = fake_source({
        ('pkg/msg/Root', '.msg'): root,
        ('pkg/msg/Inner', '.msg'): 'other_pkg/Leaf leaf\nuint8[] raw\n',
        ('pkg/msg/Zed', '.msg'): 'other_pkg/Leaf leaf\n',
        ('other_pkg/msg/Leaf', '.msg'): 'float32 c\n',
    })
    definition = source.get('pkg/msg/Root')
    assert definition.encoding == 'ros2msg'
    # Depth first: Leaf follows Inner (its first user), not the end; each type once.
    assert definition.text == (
        root + '\n' + DELIM + 'MSG: other_pkg/Leaf\nfloat32 c\n'
        + '\n' + DELIM + 'MSG: pkg/Inner\nother_pkg/Leaf leaf\nuint8[] raw\n'
        + '\n' + DELIM + 'MSG: pkg/Zed\nother_pkg/Leaf leaf\n')


def test_schema_falls_back_to_idl_and_reports_missing_types():
    source = fake_source({
        ('pkg/msg/OnlyIdl', '.idl'): '#include "pkg/msg/Dep.idl"\nmodule pkg {};\n',
        ('pkg/msg/Dep', '.idl'): 'module pkg { module msg { struct Dep { float x; }; }; };\n',
    })
    definition = source.get('pkg/msg/OnlyIdl')
    assert definition.encoding == 'ros2idl'
    assert definition.text.startswith(DELIM + 'IDL: pkg/msg/OnlyIdl\n#include')
    assert '\n' + DELIM + 'IDL: pkg/msg/Dep\nmodule pkg' in definition.text
    with pytest.raises(MessageDefinitionError, match='pkg/msg/Nothing'):
        source.get('pkg/msg/Nothing')
    with pytest.raises(MessageDefinitionError, match='not of the form'):
        source.get('no slash')


def test_installed_nested_schemas_decode_real_cdr():
    # CDR from rosbags' type store, decoded by mcap-ros2-support from our schema text only.
    trajectory = JointTrajectory(joint_names=['rotation_joint', 'extension_joint'])
    trajectory.header.stamp = Time(sec=12, nanosec=345)
    trajectory.header.frame_id = 'base_link'
    trajectory.points = [JointTrajectoryPoint(
        positions=[0.1 * k, 1.0], velocities=[0.5, -0.5], accelerations=[1.0, 2.0],
        effort=[600.0, -500.0], time_from_start=Duration(sec=k, nanosec=5)) for k in range(3)]
    out = decode('trajectory_msgs/msg/JointTrajectory',
                 cdr(trajectory, 'trajectory_msgs/msg/JointTrajectory'))
    assert out.header.stamp.sec == 12 and out.header.frame_id == 'base_link'
    assert out.joint_names == ['rotation_joint', 'extension_joint']
    assert [list(p.positions) for p in out.points] == [[0.0, 1.0], [0.1, 1.0], [0.2, 1.0]]
    assert list(out.points[2].effort) == [600.0, -500.0]
    assert out.points[2].time_from_start.sec == 2

    marker = Marker(ns='obstacles', id=7, type=Marker.CYLINDER, text='clearance')
    marker.pose.position.x = 1.0
    marker.scale.x = 0.4
    marker.color.a = 0.5
    marker.lifetime = Duration(sec=3)
    marker.points = [Point(x=1.0, y=2.0, z=3.0)]
    marker.mesh_file.filename = 'mesh.stl'
    marker.mesh_file.data = [1, 2, 3]
    text = full_definition('visualization_msgs/msg/MarkerArray').text
    assert 'MSG: visualization_msgs/Marker\n' in text and 'MSG: geometry_msgs/Pose\n' in text
    array = MarkerArray(markers=[marker, Marker(id=8)])
    out = decode('visualization_msgs/msg/MarkerArray',
                 cdr(array, 'visualization_msgs/msg/MarkerArray'))
    first = out.markers[0]
    assert (first.ns, first.id, first.type, first.text) == ('obstacles', 7, 3, 'clearance')
    assert (first.pose.position.x, first.scale.x, first.color.a) == (1.0, 0.4, 0.5)
    assert (first.points[0].y, first.lifetime.sec) == (2.0, 3)
    assert first.mesh_file.filename == 'mesh.stl' and bytes(first.mesh_file.data) == b'\1\2\3'
    assert out.markers[1].id == 8


def test_type_description_hash_from_generated_json():
    rihs = type_description_hash('std_msgs/msg/String')
    assert rihs.startswith('RIHS01_') and len(rihs) == 7 + 64
    assert type_description_hash('std_msgs/msg/NoSuchType') == ''


# -- bag writer ------------------------------------------------------------------------------

RELIABLE_LATCHED = qos_profile_to_dict(QoSProfile(
    depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL))


def string_cdr(text):
    return cdr(String(data=text), 'std_msgs/msg/String')


def test_bag_is_rosbag2_layout_and_reads_back(tmp_path):
    bag = tmp_path / 'run1'
    string_hash = type_description_hash('std_msgs/msg/String')
    trajectory = JointTrajectory(joint_names=['a'], points=[JointTrajectoryPoint(positions=[2.5])])
    with BagWriter(bag) as writer:
        writer.add_topic('/chatter', 'std_msgs/msg/String', [RELIABLE_LATCHED], string_hash)
        writer.add_topic('/trajectory', 'trajectory_msgs/msg/JointTrajectory')
        assert writer.add_topic('/chatter', 'std_msgs/msg/String') is False
        for k in range(5):
            writer.write('/chatter', string_cdr(f'm{k}'), 1_000 + k, 900 + k)
        writer.write('/trajectory', cdr(trajectory, 'trajectory_msgs/msg/JointTrajectory'), 2_000)
    assert sorted(os.listdir(bag)) == ['metadata.yaml', 'run1_0.mcap']

    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['version'] == 9 and info['storage_identifier'] == 'mcap'
    assert info['ros_distro'] == 'jazzy'
    assert info['relative_file_paths'] == ['run1_0.mcap']
    assert info['message_count'] == 6 and info['files'][0]['message_count'] == 6
    assert info['starting_time'] == {'nanoseconds_since_epoch': 1000}
    assert info['duration'] == {'nanoseconds': 1000}
    chatter = info['topics_with_message_count'][0]
    assert chatter['message_count'] == 5
    assert chatter['topic_metadata'] == {
        'name': '/chatter', 'type': 'std_msgs/msg/String', 'serialization_format': 'cdr',
        'offered_qos_profiles': [RELIABLE_LATCHED], 'type_description_hash': string_hash}
    assert RELIABLE_LATCHED['reliability'] == 'reliable'
    assert RELIABLE_LATCHED['durability'] == 'transient_local'
    assert RELIABLE_LATCHED['deadline'] == {'sec': 0, 'nsec': 0}

    with open(bag / 'run1_0.mcap', 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == 'ros2'
        summary = reader.get_summary()
        assert summary.statistics.message_count == 6
        assert {s.name: s.encoding for s in summary.schemas.values()} == {
            'std_msgs/msg/String': 'ros2msg', 'trajectory_msgs/msg/JointTrajectory': 'ros2msg'}
        channel = next(c for c in summary.channels.values() if c.topic == '/chatter')
        assert channel.message_encoding == 'cdr'
        assert yaml.safe_load(channel.metadata['offered_qos_profiles']) == [RELIABLE_LATCHED]
        assert channel.metadata['topic_type_hash'] == string_hash
        rosbag2_record = next(reader.iter_metadata())
        assert rosbag2_record.name == 'rosbag2'
        assert yaml.safe_load(rosbag2_record.metadata['serialized_metadata'])['message_count'] == 6
        decoded = [(c.topic, m.log_time, m.publish_time, m.sequence, d)
                   for _, c, m, d in reader.iter_decoded_messages()]
    assert [(t, lt, pt, s, d.data) for t, lt, pt, s, d in decoded[:5]] == [
        ('/chatter', 1000 + k, 900 + k, k + 1, f'm{k}') for k in range(5)]
    assert decoded[5][4].points[0].positions == [2.5]

    # rosbags reads metadata.yaml, builds its types from our schema texts alone and checks
    # that their RIHS01 hashes equal the recorded type_description_hash.
    assert info['topics_with_message_count'][1]['topic_metadata']['type_description_hash'] == (
        type_description_hash('trajectory_msgs/msg/JointTrajectory'))
    with AnyReader([bag]) as reader:
        assert reader.message_count == 6
        values = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages()]
    assert [v.data for v in values[:5]] == [f'm{k}' for k in range(5)]
    assert list(values[5].points[0].positions) == [2.5]


def test_close_is_idempotent_and_writing_after_close_fails(tmp_path):
    writer = BagWriter(tmp_path / 'bag').create()
    writer.add_topic('/a', 'std_msgs/msg/String')
    first = writer.close()
    assert writer.close() == first and first.message_count == 0
    with pytest.raises(RecordingError, match='not open'):
        writer.write('/a', string_cdr('late'), 1)
    with AnyReader([tmp_path / 'bag']) as reader:  # empty bags are valid too
        assert reader.message_count == 0


def test_output_directory_rules(tmp_path):
    (tmp_path / 'used').mkdir()
    (tmp_path / 'used' / 'keep.txt').write_text('earlier run')
    with pytest.raises(RecordingError, match='not empty'):
        BagWriter(tmp_path / 'used').create()
    assert (tmp_path / 'used' / 'keep.txt').read_text() == 'earlier run'
    (tmp_path / 'a_file').write_text('')
    with pytest.raises(RecordingError, match='cannot create output directory'):
        BagWriter(tmp_path / 'a_file' / 'bag').create()
    (tmp_path / 'empty').mkdir()
    BagWriter(tmp_path / 'empty').create().close()  # an existing empty directory is fine
    assert (tmp_path / 'empty' / 'metadata.yaml').exists()
    with pytest.raises(RecordingError, match='was not added'):
        with BagWriter(tmp_path / 'deep' / 'er' / 'bag') as writer:
            writer.write('/unknown', b'', 1)
    assert (tmp_path / 'deep' / 'er' / 'bag' / 'metadata.yaml').exists()


def test_concurrent_writers_lose_nothing(tmp_path):
    writer = BagWriter(tmp_path / 'bag', chunk_size=4096).create()
    topics = [f'/t{k}' for k in range(4)]
    for topic in topics:
        writer.add_topic(topic, 'std_msgs/msg/String')

    def produce(topic):
        for k in range(2500):
            writer.write(topic, string_cdr(f'{topic} {k}'), 10_000 + k)

    threads = [threading.Thread(target=produce, args=(t,)) for t in topics]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    writer.close()
    with AnyReader([tmp_path / 'bag']) as reader:
        got = {}
        for connection, _, raw in reader.messages():
            got.setdefault(connection.topic, []).append(
                reader.deserialize(raw, connection.msgtype).data)
    assert got == {t: [f'{t} {k}' for k in range(2500)] for t in topics}


def test_topics_added_while_the_flush_thread_rewrites_metadata(tmp_path):
    """Each thread adds its topic mid-recording; metadata.yaml always parses, lists them all."""
    writer = BagWriter(tmp_path / 'bag', flush_period=0.005, metadata_period=0.0).create()
    topics = [f'/m{k}' for k in range(8)]

    def produce(topic):
        writer.add_topic(topic, 'std_msgs/msg/String')
        for k in range(300):
            writer.write(topic, string_cdr(f'{topic} {k}'), 10_000 + k)
            if k % 10 == 0:
                time.sleep(0.002)       # (the recording lasts several flush periods)

    def listed():
        info = yaml.safe_load((tmp_path / 'bag' / 'metadata.yaml').read_text())
        info = info['rosbag2_bagfile_information']
        return {t['topic_metadata']['name'] for t in info['topics_with_message_count']}

    threads = [threading.Thread(target=produce, args=(t,)) for t in topics]
    for thread in threads:
        thread.start()
    reads = 0
    while any(thread.is_alive() for thread in threads):
        assert listed() <= set(topics)
        reads += 1
        # Yield the GIL: a reader parsing YAML without pause starved the producers (30-90 s).
        time.sleep(0)
    assert reads >= 1
    for thread in threads:
        thread.join()
    assert writer.error is None and listed() == set(topics)  # not yet closed
    assert writer.flush_count > 0
    writer.close()
    assert listed() == set(topics)
    with Recording(tmp_path / 'bag') as recording:
        assert len(list(recording.messages())) == 8 * 300 and not recording.damaged


def test_full_disk_is_a_clear_error(tmp_path):
    # RLIMIT_FSIZE makes writes fail with EFBIG past 200 kB, like a full disk.
    script = textwrap.dedent(f"""
        import resource, signal, sys
        sys.path.insert(0, {str(REPO)!r})
        from toc_ros.recording.bag_writer import BagWriter, RecordingError
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (200_000, 200_000))
        writer = BagWriter({str(tmp_path / 'bag')!r}, chunk_size=16_000).create()
        writer.add_topic('/big', 'std_msgs/msg/String')
        data = bytes(4) + bytes(1000)  # any bytes: nothing decodes them here
        try:
            for k in range(1000):
                writer.write('/big', data, k)
        except RecordingError as error:
            print('WRITE', error)
        try:
            writer.close()
        except RecordingError as error:
            print('CLOSE', error)
        """)
    result = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True,
                            timeout=60, env=dict(os.environ))
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0].startswith('WRITE writing ') and 'File too large' in lines[0], lines
    assert lines[1].startswith('CLOSE bag ') and 'incomplete' in lines[1], lines
    # metadata.yaml is the one of the last flush (written at create, then while recording)
    info = yaml.safe_load((tmp_path / 'bag' / 'metadata.yaml').read_text())
    info = info['rosbag2_bagfile_information']
    assert [t['topic_metadata']['name'] for t in info['topics_with_message_count']] == ['/big']
    assert info['message_count'] < 200
