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
rosbag2 bag directory writer (MCAP storage) on top of the ``mcap`` library, without rclpy.

Writes what ``ros2 bag record -s mcap`` of ROS 2 Jazzy writes: a directory ``<name>/`` with
``<name>_0.mcap`` (profile ``ros2``, one ``ros2msg`` schema per type, ``cdr`` channels whose
metadata hold ``offered_qos_profiles`` and ``topic_type_hash``, a ``rosbag2`` metadata record)
and ``metadata.yaml`` (rosbag2_bagfile_information version 9).

Crash durability: with ``flush_period`` (default 0.1 s) a background thread finishes the chunk
in progress and hands it to the OS at least that often (``mcap.Writer.flush``), then fsyncs it
(``fsync``, default on), so a SIGKILL or a power loss loses at most the last period or two:
the chunk in memory and one being written. ``metadata.yaml`` is written at ``create()``,
rewritten after new topics and at most every ``metadata_period`` while recording (counts of
the data flushed so far), and written with the final counts at ``close()``. A file cut off
this way is read up to its last complete chunk by ``bag_reader`` and rewritten into a
complete bag by ``toc-bag recover`` (``bag_tool``).

All public methods are thread-safe. Do not call them from a signal handler: set a flag there
and close from the main thread, or a handler that interrupts a write would deadlock on the lock.
"""

import os
import shutil
import threading
import time
from typing import Dict, Iterable, List, Mapping, NamedTuple, Optional

from mcap.writer import CompressionType, Writer

from .bag_metadata import complete_qos_profile, dump_yaml, qos_profiles_yaml
from .msg_definitions import full_definition, MessageDefinition, type_description_hash

METADATA_VERSION = 9
ROS_DISTRO = 'jazzy'
STORAGE_IDENTIFIER = 'mcap'
SERIALIZATION_FORMAT = 'cdr'
# Refuse to start with less free space than this; a full disk mid-run is reported on write.
MIN_FREE_BYTES = 4 * 1024 * 1024
# Crash durability defaults: at most this much recording time lives only in memory.
FLUSH_PERIOD_S = 0.1
METADATA_PERIOD_S = 1.0
_NO_MESSAGE_START = 2**63 - 1


def _library_string() -> str:
    try:
        from importlib.metadata import version
        return f'toc_ros recorder; mcap-python {version("mcap")}'
    except Exception:  # noqa: B902 - the version is only informative
        return 'toc_ros recorder; mcap-python'


class RecordingError(Exception):
    """A bag cannot be created, written or read; the message says what and where."""


class TopicSummary(NamedTuple):
    """What was recorded on one topic."""

    name: str
    type_name: str
    message_count: int


class BagSummary(NamedTuple):
    """What a closed bag holds."""

    path: str
    mcap_path: str
    message_count: int
    topics: List[TopicSummary]
    starting_time_ns: int
    duration_ns: int


class _Topic:
    __slots__ = ('name', 'type_name', 'qos_profiles', 'type_hash', 'channel_id', 'count')

    def __init__(self, name, type_name, qos_profiles, type_hash, channel_id):
        self.name = name
        self.type_name = type_name
        self.qos_profiles = qos_profiles
        self.type_hash = type_hash
        self.channel_id = channel_id
        self.count = 0


class BagWriter:
    """
    Writes one rosbag2 bag directory with a single MCAP file.

    ``create()`` makes the directory (which must not exist or be empty), ``add_topic()``
    declares a topic, ``write()`` stores CDR bytes as given, ``close()`` writes the MCAP
    summary and footer and ``metadata.yaml``. Also a context manager.

    ``flush_period`` [s]: the longest time a written message stays in memory only (a chunk is
    also finished when it reaches ``chunk_size`` bytes); None: only ``chunk_size`` and
    ``flush()`` calls finish chunks. ``fsync``: each periodic flush also fsyncs the file.
    """

    def __init__(self, path: str, *, chunk_size: int = 1024 * 1024,
                 min_free_bytes: int = MIN_FREE_BYTES, ros_distro: str = ROS_DISTRO,
                 flush_period: Optional[float] = FLUSH_PERIOD_S, fsync: bool = True,
                 metadata_period: float = METADATA_PERIOD_S):
        if flush_period is not None and not float(flush_period) > 0.0:
            raise ValueError(f'flush_period must be > 0 s or None, got {flush_period!r}')
        self.path = os.path.abspath(os.fspath(path))
        name = os.path.basename(self.path.rstrip(os.sep)) or 'bag'
        self.mcap_name = f'{name}_0.mcap'
        self.mcap_path = os.path.join(self.path, self.mcap_name)
        self._chunk_size = int(chunk_size)
        self._min_free_bytes = int(min_free_bytes)
        self._ros_distro = ros_distro
        self._lock = threading.Lock()
        self._stream = None
        self._writer: Optional[Writer] = None
        self._schemas: Dict[str, int] = {}
        self._topics: Dict[str, _Topic] = {}
        self._message_count = 0
        self._first_ns = _NO_MESSAGE_START
        self._last_ns = 0
        self._error: Optional[BaseException] = None
        self._closed = False
        self._flush_period = None if flush_period is None else float(flush_period)
        self._fsync = bool(fsync)
        self._metadata_period = float(metadata_period)
        # _flush_lock orders flushes (and close) without holding _lock during fsync.
        self._flush_lock = threading.Lock()
        self._unflushed = 0               # messages accepted since the last flush
        self._metadata_written = 0.0      # time.monotonic() of the last metadata.yaml
        self._metadata_lock = threading.Lock()
        self._metadata_generation = 0
        self._metadata_generation_written = 0
        self._flusher: Optional[threading.Thread] = None
        self._stop_flusher = threading.Event()
        self.flush_count = 0              # flushes that wrote data (for tests and benchmarks)

    # -- state ------------------------------------------------------------------------------
    @property
    def is_open(self) -> bool:
        """Tell whether the bag is between a successful create() and close()."""
        return self._writer is not None and not self._closed

    @property
    def message_count(self) -> int:
        """Messages written so far."""
        return self._message_count

    # -- create -----------------------------------------------------------------------------
    def create(self) -> 'BagWriter':
        """Create the bag directory and the MCAP file; RecordingError if that is impossible."""
        with self._lock:
            if self._writer is not None or self._closed:
                raise RecordingError(f'bag {self.path} was already created')
            self._create_directory()
            self._check_free_space()
            try:
                self._stream = open(self.mcap_path, 'xb')
                self._writer = Writer(self._stream, chunk_size=self._chunk_size,
                                      compression=CompressionType.NONE)
                self._writer.start(profile='ros2', library=_library_string())
                self._stream.flush()
                self._write_metadata_yaml(self._metadata_snapshot())
            except OSError as error:
                self._abandon()
                raise RecordingError(
                    f'cannot create {self.mcap_path}: {error.strerror or error}') from error
            self._metadata_written = time.monotonic()
            if self._flush_period is not None:
                self._flusher = threading.Thread(
                    target=self._flush_loop, name='bag-flush', daemon=True)
                self._flusher.start()
        return self

    def _create_directory(self):
        if os.path.exists(self.path):
            if not os.path.isdir(self.path):
                raise RecordingError(f'output {self.path} exists and is not a directory')
            if os.listdir(self.path):
                raise RecordingError(
                    f'output directory {self.path} already exists and is not empty; '
                    'choose a new one so no earlier recording is overwritten')
        try:
            os.makedirs(self.path, exist_ok=True)
        except OSError as error:
            raise RecordingError(
                f'cannot create output directory {self.path}: {error.strerror or error}'
            ) from error
        if not os.access(self.path, os.W_OK | os.X_OK):
            raise RecordingError(f'output directory {self.path} is not writable')

    def _check_free_space(self):
        try:
            free = shutil.disk_usage(self.path).free
        except OSError:
            return  # unknown: a full disk is still reported by write()
        if free < self._min_free_bytes:
            raise RecordingError(
                f'only {free} bytes free on the file system of {self.path} '
                f'(need at least {self._min_free_bytes})')

    def _abandon(self):
        if self._stream is not None:
            try:
                self._stream.close()
            except OSError:
                pass  # abandoning a broken stream: the error that got us here is reported
        self._stream = None
        self._writer = None

    # -- topics and messages -----------------------------------------------------------------
    def add_topic(self, name: str, type_name: str, qos_profiles: Iterable[Mapping] = (),
                  type_hash: Optional[str] = None,
                  definition: Optional[MessageDefinition] = None) -> bool:
        """
        Declare a topic (and its type's schema, once per type); False if already declared.

        ``type_hash`` (RIHS01) and ``definition`` default to those of the installed type.
        """
        if definition is None:
            definition = full_definition(type_name)
        if type_hash is None:
            type_hash = type_description_hash(type_name)
        profiles = [complete_qos_profile(p) for p in qos_profiles]
        with self._lock:
            self._check_writable()
            if name in self._topics:
                return False
            try:
                schema_id = self._schemas.get(type_name)
                if schema_id is None:
                    schema_id = self._writer.register_schema(
                        name=type_name, encoding=definition.encoding,
                        data=definition.text.encode('utf-8'))
                    self._schemas[type_name] = schema_id
                channel_id = self._writer.register_channel(
                    topic=name, message_encoding=SERIALIZATION_FORMAT, schema_id=schema_id,
                    metadata={'offered_qos_profiles': qos_profiles_yaml(profiles),
                              'topic_type_hash': type_hash})
            except OSError as error:
                raise self._fail(error) from error
            self._topics[name] = _Topic(name, type_name, profiles, type_hash, channel_id)
            # At once, so a bag that is never closed still lists every topic (rare: cheap).
            try:
                self._write_metadata_yaml(self._metadata_snapshot())
            except OSError as error:
                raise self._fail(error) from error
            self._metadata_written = time.monotonic()
            return True

    def write(self, topic: str, data, log_time_ns: int,
              publish_time_ns: Optional[int] = None) -> None:
        """Store one serialised message; log time = receive time, publish time = send time."""
        with self._lock:
            self._check_writable()
            entry = self._topics.get(topic)
            if entry is None:
                raise RecordingError(f'topic {topic!r} was not added to bag {self.path}')
            log_time_ns = int(log_time_ns)
            publish = log_time_ns if publish_time_ns is None else int(publish_time_ns)
            try:
                self._writer.add_message(
                    channel_id=entry.channel_id, log_time=log_time_ns, data=bytes(data),
                    publish_time=publish, sequence=(entry.count + 1) & 0xFFFFFFFF)
            except OSError as error:
                raise self._fail(error) from error
            entry.count += 1
            self._message_count += 1
            self._unflushed += 1
            self._first_ns = min(self._first_ns, log_time_ns)
            self._last_ns = max(self._last_ns, log_time_ns)

    def _check_writable(self):
        if self._error is not None:
            raise RecordingError(f'bag {self.path} stopped after an error: {self._error}')
        if self._writer is None or self._closed:
            raise RecordingError(f'bag {self.path} is not open')

    def _fail(self, error: OSError) -> RecordingError:
        self._error = error
        return RecordingError(
            f'writing {self.mcap_path} failed ({self._message_count} messages accepted '
            f'so far): {error.strerror or error}')

    # -- durability -------------------------------------------------------------------------
    @property
    def error(self) -> Optional[str]:
        """Why the bag stopped accepting data (e.g. disk full during a flush), or None."""
        error = self._error
        return None if error is None else str(getattr(error, 'strerror', None) or error)

    def flush(self) -> bool:
        """
        Finish the chunk in progress and hand it to the OS (fsync if enabled); True if written.

        Also rewrites metadata.yaml (counts so far) when ``metadata_period`` has passed.
        RecordingError when the bag is not open or the write fails.
        """
        with self._flush_lock:
            with self._lock:
                self._check_writable()
                wrote = self._unflushed > 0
                try:
                    if wrote:
                        self._writer.flush()
                    fileno = self._stream.fileno()
                except OSError as error:
                    raise self._fail(error) from error
                self._unflushed = 0
                metadata = None
                now = time.monotonic()
                if wrote and now - self._metadata_written >= self._metadata_period:
                    metadata = self._metadata_snapshot()
                    self._metadata_written = now
            # Outside _lock: writers go on while the disk syncs; close() waits on _flush_lock.
            try:
                if wrote and self._fsync:
                    os.fsync(fileno)
                if metadata is not None:
                    self._write_metadata_yaml(metadata)
            except OSError as error:
                with self._lock:
                    raise self._fail(error) from error
            if wrote:
                self.flush_count += 1
            return wrote

    def _flush_loop(self):
        while not self._stop_flusher.wait(self._flush_period):
            try:
                self.flush()
            except RecordingError:
                return  # kept in self._error: the next write() and close() report it

    def _stop_flush_loop(self):
        self._stop_flusher.set()
        flusher = self._flusher
        if flusher is not None and flusher is not threading.current_thread():
            flusher.join()
        self._flusher = None

    # -- close ------------------------------------------------------------------------------
    def close(self) -> BagSummary:
        """
        Finish the MCAP file (summary and footer), then write metadata.yaml. Idempotent.

        Raises RecordingError (naming the incomplete file) when this cannot be done, e.g.
        after a write failed because the disk is full.
        """
        self._stop_flush_loop()
        with self._flush_lock, self._lock:
            if self._closed or self._writer is None:
                self._closed = True
                return self._summary()
            self._closed = True
            failure = self._error
            try:
                if failure is None:
                    self._writer.add_metadata(
                        'rosbag2', {'serialized_metadata': dump_yaml(self._metadata())})
                    self._writer.finish()
                    self._stream.flush()
                    os.fsync(self._stream.fileno())
            except OSError as error:
                failure = error
            finally:
                self._abandon()
            if failure is None:
                try:
                    self._write_metadata_yaml(self._metadata_snapshot())
                except OSError as error:
                    failure = error
            if failure is not None:
                reason = getattr(failure, 'strerror', None) or failure
                raise RecordingError(
                    f'bag {self.path} is incomplete (no MCAP summary, metadata.yaml not '
                    f'final): {reason}; `toc-bag recover {self.path}` rewrites the chunks '
                    'written before the failure into a complete bag')
            return self._summary()

    def _summary(self) -> BagSummary:
        topics = [TopicSummary(t.name, t.type_name, t.count) for t in self._topics.values()]
        start, duration = self._time_span()
        return BagSummary(self.path, self.mcap_path, self._message_count, topics, start,
                          duration)

    def _time_span(self):
        if self._message_count == 0:
            return _NO_MESSAGE_START, 0
        return self._first_ns, self._last_ns - self._first_ns

    def _metadata(self) -> dict:
        start, duration = self._time_span()
        return {
            'version': METADATA_VERSION,
            'storage_identifier': STORAGE_IDENTIFIER,
            'duration': {'nanoseconds': duration},
            'starting_time': {'nanoseconds_since_epoch': start},
            'message_count': self._message_count,
            'topics_with_message_count': [
                {
                    'topic_metadata': {
                        'name': t.name,
                        'type': t.type_name,
                        'serialization_format': SERIALIZATION_FORMAT,
                        'offered_qos_profiles': t.qos_profiles,
                        'type_description_hash': t.type_hash,
                    },
                    'message_count': t.count,
                }
                for t in self._topics.values()
            ],
            'compression_format': '',
            'compression_mode': '',
            'relative_file_paths': [self.mcap_name],
            'files': [{
                'path': self.mcap_name,
                'starting_time': {'nanoseconds_since_epoch': start},
                'duration': {'nanoseconds': duration},
                'message_count': self._message_count,
            }],
            'custom_data': None,
            'ros_distro': self._ros_distro,
        }

    def _metadata_snapshot(self):
        """Numbered metadata (call under _lock): a later one is never replaced by an earlier."""
        self._metadata_generation += 1
        return self._metadata_generation, self._metadata()

    def _write_metadata_yaml(self, snapshot):
        generation, metadata = snapshot
        with self._metadata_lock:  # the flush thread writes outside _lock
            if generation <= self._metadata_generation_written:
                return
            self._write_metadata_file(metadata)
            self._metadata_generation_written = generation

    def _write_metadata_file(self, metadata: dict):
        text = dump_yaml({'rosbag2_bagfile_information': metadata})
        final = os.path.join(self.path, 'metadata.yaml')
        temporary = final + '.tmp'
        with open(temporary, 'w', encoding='utf-8') as stream:
            stream.write(text)
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(temporary, final)
        try:  # make the rename itself durable
            directory = os.open(self.path, os.O_RDONLY)
        except OSError:
            return
        try:
            os.fsync(directory)
        except OSError:
            pass  # some file systems cannot fsync a directory; the data is synced anyway
        finally:
            os.close(directory)

    # -- context manager ----------------------------------------------------------------------
    def __enter__(self) -> 'BagWriter':
        if self._writer is None:
            self.create()
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()
