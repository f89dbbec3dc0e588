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
Read rosbag2 recordings (bag directory or bare ``.mcap``) with the ``mcap`` library.

A complete file is read through its summary (lazily, in log-time order). A file without a
valid footer and summary (recorder killed, power loss, disk full, copy cut short) is read
with the library's StreamReader up to the point where it breaks: every complete chunk is
recovered, and a warning says how much (messages, chunks, time span, bytes lost). Channels
that are not ROS 2 CDR messages (e.g. JSON) or whose type is not installed are listed with the
reason and skipped by ``decode``; fatal problems (no such path, not an MCAP file) raise
RecordingError.
"""

import functools
import importlib
import io
import os
import re
import struct
from typing import Callable, Dict, Iterable, Iterator, List, NamedTuple, Optional, Tuple

from mcap.exceptions import EndOfFile, McapError, RecordLengthLimitExceeded
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk, StreamReader
import yaml

from .bag_writer import RecordingError

MAGIC = b'\x89MCAP0\r\n'
_TYPE_NAME = re.compile(r'^[A-Za-z][A-Za-z0-9_]*/(msg|srv|action)/[A-Za-z][A-Za-z0-9_]*$')
ROS2_SCHEMA_ENCODINGS = ('ros2msg', 'ros2idl')
# Errors the mcap library and the decompressors raise on damaged bytes.
_DAMAGE = (McapError, struct.error, ValueError, EOFError, UnicodeDecodeError, IndexError,
           KeyError, RuntimeError)


class TopicInfo(NamedTuple):
    """One recorded topic: name, type and how its messages are encoded."""

    name: str
    type_name: str                 # 'pkg/msg/Type' ('' when the channel has no schema)
    message_encoding: str          # 'cdr' for ROS 2
    schema_encoding: str           # 'ros2msg' or 'ros2idl' for ROS 2
    qos_profiles: Tuple[dict, ...]  # offered QoS of the recorded publishers (rosbag2 metadata)
    schema_text: str = ''          # the stored message definition
    type_hash: str = ''            # RIHS01 hash of the type (rosbag2 channel metadata)

    @property
    def problem(self) -> Optional[str]:
        """Why messages of this topic cannot be decoded, or None when they can."""
        if self.message_encoding != 'cdr':
            return (f'message encoding {self.message_encoding!r} is not ROS 2 CDR '
                    "(only 'cdr' channels are read)")
        if not self.type_name:
            return 'the channel has no schema, so its message type is unknown'
        if self.schema_encoding not in ROS2_SCHEMA_ENCODINGS:
            return (f'schema encoding {self.schema_encoding!r} is not a ROS 2 message '
                    'definition (ros2msg or ros2idl)')
        return message_class_problem(self.type_name)


class FileStatus(NamedTuple):
    """How one .mcap file of a recording was read."""

    path: str
    size: int
    complete: bool            # read through its summary (closed cleanly)
    problem: Optional[str]    # why reading stopped before the footer, or None
    recovered: str            # what a sequential read recovered ('' when complete)


class RawMessage(NamedTuple):
    """One recorded message: the CDR bytes as stored, with its times [ns]."""

    topic: str
    type_name: str
    log_time_ns: int
    publish_time_ns: int
    data: bytes


@functools.lru_cache(maxsize=None)
def _import_message_class(type_name: str):
    if not _TYPE_NAME.match(type_name):
        return None, f'type name {type_name!r} is not of the form pkg/msg/Type'
    package, namespace, name = type_name.split('/')
    try:
        cls = getattr(importlib.import_module(f'{package}.{namespace}'), name)
    except (ImportError, AttributeError) as error:
        return None, (f'message type {type_name} is not installed here ({error}); '
                      'source the workspace that defines it')
    return cls, None


def message_class(type_name: str):
    """Python class of a ROS 2 message type 'pkg/msg/Type' (LookupError if unavailable)."""
    cls, problem = _import_message_class(type_name)
    if cls is None:
        raise LookupError(problem)
    return cls


def message_class_problem(type_name: str) -> Optional[str]:
    """Why the class of type_name cannot be imported, or None."""
    return _import_message_class(type_name)[1]


def parse_qos_profiles(text: str) -> Tuple[dict, ...]:
    """Parse the offered_qos_profiles YAML of a rosbag2 channel into dicts (empty if bad)."""
    if not text:
        return ()
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError:
        return ()
    if not isinstance(data, list):
        return ()
    return tuple(p for p in data if isinstance(p, dict))


def _topic_info(channel: Channel, schema: Optional[Schema]) -> TopicInfo:
    return TopicInfo(
        name=channel.topic, type_name=schema.name if schema is not None else '',
        message_encoding=channel.message_encoding,
        schema_encoding=schema.encoding if schema is not None else '',
        qos_profiles=parse_qos_profiles(channel.metadata.get('offered_qos_profiles', '')),
        schema_text=bytes(schema.data).decode('utf-8', 'replace') if schema is not None else '',
        type_hash=channel.metadata.get('topic_type_hash', ''))


# -- locating the files ---------------------------------------------------------------------
def _natural_key(name: str):
    return [int(part) if part.isdigit() else part for part in re.split(r'(\d+)', name)]


def mcap_files(path: str) -> List[str]:
    """List the .mcap files of a bag directory (metadata.yaml order) or a bare .mcap file."""
    path = os.path.abspath(os.path.expanduser(os.fspath(path)))
    if not os.path.exists(path):
        raise RecordingError(f'{path}: no such file or directory')
    if os.path.isfile(path):
        if os.path.basename(path) != 'metadata.yaml':
            return [path]
        path = os.path.dirname(path)
    metadata_path = os.path.join(path, 'metadata.yaml')
    if os.path.isfile(metadata_path):
        files = _files_from_metadata(path, metadata_path)
        if files:
            return files
    files = sorted((f for f in os.listdir(path) if f.endswith('.mcap')), key=_natural_key)
    if not files:
        raise RecordingError(f'{path}: no .mcap file in this directory (is it a bag?)')
    return [os.path.join(path, f) for f in files]


def _files_from_metadata(directory: str, metadata_path: str) -> List[str]:
    try:
        with open(metadata_path, encoding='utf-8') as stream:
            info = (yaml.safe_load(stream) or {}).get('rosbag2_bagfile_information', {})
    except (OSError, yaml.YAMLError, AttributeError):
        return []  # fall back to the .mcap files present
    if not isinstance(info, dict):
        return []
    storage = info.get('storage_identifier', 'mcap')
    if storage != 'mcap':
        raise RecordingError(
            f'{directory}: storage {storage!r} is not supported (only mcap); convert it with '
            '`ros2 bag convert`')
    names = info.get('relative_file_paths') or []
    files = [os.path.join(directory, str(n)) for n in names]
    return [f for f in files if os.path.isfile(f)]


# -- one file -------------------------------------------------------------------------------
class _Scan:
    """
    Sequential read (the mcap library's StreamReader) of a file without a usable summary.

    Reads every record up to where the file breaks: a file cut off (recorder killed, disk
    full, copy cut short) keeps every complete chunk; the chunk being written when it broke is
    dropped (its CRC or length does not check out). ``problem`` says why it stopped, if not
    at the footer.
    """

    def __init__(self, path: str, size: int):
        self.size = size
        self.schemas: Dict[int, Schema] = {}
        self.channels: Dict[int, Channel] = {}
        self.messages: List[Message] = []
        self.metadata: List[Metadata] = []
        self.problem: Optional[str] = None
        self.cut_off = False
        self.orphans = 0
        self.chunks = 0
        self.good_bytes = len(MAGIC)   # end of the last complete record
        with open(path, 'rb') as stream:
            # No record can be longer than the file: a cut-off one fails the size limit.
            reader = StreamReader(stream, emit_chunks=True, record_size_limit=size)
            try:
                for record in reader.records:
                    if isinstance(record, Chunk):
                        for inner in breakup_chunk(record, validate_crc=True):
                            self._record(inner)
                        self.chunks += 1
                    else:
                        self._record(record)
                    self.good_bytes = stream.tell()
            except _DAMAGE as error:
                # Cut off: the last record runs past the end of the file (its header, body or
                # padding); anything else is damage in the middle.
                self.cut_off = (isinstance(error, (EndOfFile, RecordLengthLimitExceeded))
                                or stream.tell() >= size)
                why = 'not closed: recorder killed, power loss or disk full?'
                if self.cut_off and self.good_bytes >= size:
                    self.problem = (f'the file is cut off after its last complete record, at '
                                    f'byte {size}, without summary and footer ({why})')
                elif self.cut_off:
                    self.problem = (f'the file is cut off inside a record: {self.good_bytes} '
                                    f'of {size} bytes readable ({why})')
                else:
                    self.problem = (f'damaged record after byte {self.good_bytes} of {size}: '
                                    f'{error or type(error).__name__}')

    def _record(self, record):
        if isinstance(record, Schema):
            self.schemas[record.id] = record
        elif isinstance(record, Channel):
            self.channels[record.id] = record
        elif isinstance(record, Message):
            if record.channel_id in self.channels:
                self.messages.append(record)
            else:
                self.orphans += 1
        elif isinstance(record, Metadata):
            self.metadata.append(record)

    def recovered(self) -> str:
        """Say how much was read: messages, chunks, the time they span."""
        text = f'recovered {len(self.messages)} messages'
        if self.chunks:
            text += f' from {self.chunks} complete chunk(s)'
        if self.messages:
            times = [m.log_time for m in self.messages]
            text += f' spanning {(max(times) - min(times)) * 1e-9:.3f} s'
        lost = self.size - self.good_bytes
        if lost > 0:
            text += f'; the last {lost} bytes are lost'
        return text


class _McapFile:
    """One .mcap file: topics known up front, messages in log-time order."""

    def __init__(self, path: str, warn: Callable[[str], None]):
        self.path = path
        self._warn = warn
        self._scan: Optional[_Scan] = None
        self._reader: Optional[SeekingReader] = None
        self._stream = None
        self.damaged = False
        try:
            with open(path, 'rb') as stream:
                head = stream.read(len(MAGIC))
                stream.seek(0, io.SEEK_END)
                size = stream.tell()
                stream.seek(max(0, size - len(MAGIC)))
                tail = stream.read(len(MAGIC))
        except OSError as error:
            raise RecordingError(f'{path}: cannot read: {error.strerror or error}') from error
        if head != MAGIC:
            raise RecordingError(
                f'{path}: not an MCAP file (it starts with {head[:8]!r}, not the MCAP magic); '
                'toc_ros reads rosbag2 recordings in MCAP storage only')
        self.size = size
        summary = self._open_summary() if tail == MAGIC and size > 2 * len(MAGIC) else None
        if summary is None:
            try:
                self._scan = _Scan(path, size)
            except OSError as error:
                raise RecordingError(
                    f'{path}: cannot read: {error.strerror or error}') from error
            self.damaged = bool(self._scan.problem or self._scan.orphans)
            if self._scan.problem:
                warn(f'{path}: {self._scan.problem}; {self._scan.recovered()}')
            if self._scan.orphans:
                warn(f'{path}: {self._scan.orphans} messages refer to unknown channels '
                     'and were skipped')
            self._scan.messages.sort(key=lambda m: m.log_time)
            self.schemas, self.channels = self._scan.schemas, self._scan.channels
        else:
            self.schemas, self.channels = summary.schemas, summary.channels

    def _open_summary(self):
        try:
            self._stream = open(self.path, 'rb')
            # No record is longer than the file: a damaged length fails, not a MemoryError.
            self._reader = SeekingReader(self._stream, record_size_limit=self.size)
            summary = self._reader.get_summary()
        except _DAMAGE:
            summary = None
        if summary is None:
            self.close()
        return summary

    def status(self) -> FileStatus:
        """How this file was read."""
        scan = self._scan
        if scan is None:
            return FileStatus(self.path, self.size, True, None, '')
        return FileStatus(self.path, self.size, False, scan.problem, scan.recovered())

    def topics(self) -> List[TopicInfo]:
        """Every channel of the file as a TopicInfo."""
        return [_topic_info(c, self.schemas.get(c.schema_id)) for c in self.channels.values()]

    def messages(self, topics: Optional[Iterable[str]] = None) -> Iterator[RawMessage]:
        """Messages (optionally of some topics only) in log-time order."""
        wanted = None if topics is None else set(topics)
        if self._scan is not None:
            source = ((self.channels[m.channel_id], m) for m in self._scan.messages)
        else:
            source = self._indexed(wanted)
        for channel, message in source:
            if wanted is not None and channel.topic not in wanted:
                continue
            schema = self.schemas.get(channel.schema_id)
            yield RawMessage(channel.topic, schema.name if schema is not None else '',
                             message.log_time, message.publish_time, bytes(message.data))

    def _indexed(self, wanted):
        try:
            for _schema, channel, message in self._reader.iter_messages(
                    topics=None if wanted is None else list(wanted)):
                yield channel, message
        except _DAMAGE as error:
            self.damaged = True
            self._warn(f'{self.path}: damaged chunk, stopped reading this file there: '
                       f'{error or type(error).__name__}')

    def close(self):
        """Release the file handle."""
        if self._stream is not None:
            self._stream.close()
        self._stream = None
        self._reader = None


class Recording:
    """
    A recording: a rosbag2 bag directory (one or more .mcap files) or a bare .mcap file.

    ``warnings`` collects every recoverable problem (cut-off file, foreign channels, messages
    that do not decode), also passed to ``warn`` as they occur.
    """

    def __init__(self, path: str, warn: Optional[Callable[[str], None]] = None):
        self.path = os.path.abspath(os.fspath(path))
        self.warnings: List[str] = []
        self._warn_callback = warn
        self._files: List[_McapFile] = []
        try:
            for file_path in mcap_files(self.path):
                self._files.append(_McapFile(file_path, self._warn))
        except RecordingError:
            self.close()
            raise
        self.topics: Dict[str, TopicInfo] = {}
        for mcap_file in self._files:
            for info in mcap_file.topics():
                known = self.topics.setdefault(info.name, info)
                if known.type_name != info.type_name:
                    self._warn(f'topic {info.name} has several types ({known.type_name}, '
                               f'{info.type_name}); only {known.type_name} is read')
        self._reported: set = set()
        self._decode_failures = 0

    def _warn(self, text: str):
        self.warnings.append(text)
        if self._warn_callback is not None:
            self._warn_callback(text)

    @property
    def damaged(self) -> bool:
        """Tell whether some data was lost: a file cut short or damaged, undecodable bytes."""
        return self._decode_failures > 0 or any(f.damaged for f in self._files)

    @property
    def files(self) -> List[str]:
        """Paths of the .mcap files, in playback order."""
        return [f.path for f in self._files]

    def file_status(self) -> List[FileStatus]:
        """How each .mcap file was read (complete, or cut off and how much was recovered)."""
        return [f.status() for f in self._files]

    def readable_topics(self) -> Dict[str, TopicInfo]:
        """Topics whose messages decode here; warns once about each of the others."""
        readable = {}
        for name, info in self.topics.items():
            problem = info.problem
            if problem is None:
                readable[name] = info
            elif name not in self._reported:
                self._reported.add(name)
                self._warn(f'topic {name} [{info.type_name or "?"}] skipped: {problem}')
        return readable

    def messages(self, topics: Optional[Iterable[str]] = None) -> Iterator[RawMessage]:
        """Raw messages of all files (optionally some topics only), file by file."""
        topics = None if topics is None else list(topics)
        for mcap_file in self._files:
            for raw in mcap_file.messages(topics):
                if raw.type_name == self.topics[raw.topic].type_name:
                    yield raw

    def decode(self, raw: RawMessage):
        """Deserialise one raw message (LookupError for unknown types, others on bad CDR)."""
        from rclpy.serialization import deserialize_message
        return deserialize_message(raw.data, message_class(raw.type_name))

    def decoded(self, topics: Optional[Iterable[str]] = None
                ) -> Iterator[Tuple[RawMessage, object]]:
        """(raw, message) pairs of the readable topics; undecodable messages are warned about."""
        readable = self.readable_topics()
        wanted = [t for t in (readable if topics is None else topics) if t in readable]
        failures: Dict[str, int] = {}
        for raw in self.messages(wanted):
            try:
                yield raw, self.decode(raw)
            except Exception as error:  # noqa: B902 - rclpy raises plain exceptions on bad CDR
                if raw.topic not in failures:
                    self._warn(f'a message on {raw.topic} does not decode as {raw.type_name}: '
                               f'{error}')
                failures[raw.topic] = failures.get(raw.topic, 0) + 1
                self._decode_failures += 1
        for topic, count in failures.items():
            if count > 1:
                self._warn(f'{count} messages on {topic} did not decode and were skipped')

    def close(self):
        """Release the file handles."""
        for mcap_file in self._files:
            mcap_file.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
