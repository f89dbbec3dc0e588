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
toc-bag: look at a recording and recover one that was not closed.

``toc-bag info PATH`` says whether each file was closed cleanly or how much of a cut-off one
is readable, and lists the topics with their message counts. ``toc-bag recover IN [OUT]``
rewrites what is readable of IN (every complete chunk of a file cut off by a SIGKILL, power
loss or full disk) into a new, complete bag directory OUT (default ``IN-recovered``): indexed
MCAP with summary and footer, plus ``metadata.yaml`` with the real counts, which rosbag2,
rosbags and the ``mcap`` library read. IN is never modified. No rclpy needed.

Exit codes: 0 done (info: every file complete), 1 info: some file cut off or damaged,
2 error (no such recording, not MCAP, output exists...).
"""

import argparse
import datetime
import os
import sys
from typing import Callable, Dict, List, Optional

from .bag_reader import Recording, ROS2_SCHEMA_ENCODINGS
from .bag_writer import BagSummary, BagWriter, RecordingError, SERIALIZATION_FORMAT
from .msg_definitions import MessageDefinition

EXIT_OK, EXIT_DAMAGED, EXIT_ERROR = 0, 1, 2


def default_output(path: str) -> str:
    """``<bag directory or .mcap file without extension>-recovered``."""
    path = os.path.abspath(os.fspath(path)).rstrip(os.sep)
    if os.path.basename(path) == 'metadata.yaml':
        path = os.path.dirname(path)
    elif os.path.isfile(path):
        path = os.path.splitext(path)[0]
    return path + '-recovered'


def recover(source: str, output: str, warn: Callable[[str], None]) -> BagSummary:
    """
    Copy every readable message of ``source`` into a new complete bag at ``output``.

    Channels that are not ROS 2 (CDR with a ros2msg/ros2idl schema) are left out with a
    warning. RecordingError when source cannot be read or output cannot be written.
    """
    with Recording(source, warn) as recording:
        writer = BagWriter(output, flush_period=None, fsync=False)  # close() fsyncs once
        writer.create()
        try:
            copied: List[str] = []
            for name, info in recording.topics.items():
                if (info.message_encoding != SERIALIZATION_FORMAT or not info.type_name
                        or info.schema_encoding not in ROS2_SCHEMA_ENCODINGS):
                    warn(f'topic {name} left out: {info.problem}')
                    continue
                writer.add_topic(name, info.type_name, info.qos_profiles, info.type_hash,
                                 MessageDefinition(info.type_name, info.schema_encoding,
                                                   info.schema_text))
                copied.append(name)
            for raw in recording.messages(copied):
                writer.write(raw.topic, raw.data, raw.log_time_ns, raw.publish_time_ns)
        finally:
            summary = writer.close()
    return summary


def _time_text(nanoseconds: int) -> str:
    moment = datetime.datetime.fromtimestamp(nanoseconds * 1e-9, datetime.timezone.utc)
    return moment.strftime('%Y-%m-%dT%H:%M:%S.%f')[:-3] + 'Z'


def info_text(recording: Recording) -> str:
    """Describe a recording: files (complete or cut off, how much recovered), topics."""
    lines = [f'recording: {recording.path}']
    for status in recording.file_status():
        state = 'complete' if status.complete else (
            f'NOT COMPLETE: {status.problem or "no summary"}; {status.recovered}')
        lines.append(f'file: {os.path.basename(status.path)} ({status.size} bytes), {state}')
    counts: Dict[str, int] = dict.fromkeys(recording.topics, 0)
    first: Optional[int] = None
    last: Optional[int] = None
    for raw in recording.messages():
        counts[raw.topic] += 1
        first = raw.log_time_ns if first is None else min(first, raw.log_time_ns)
        last = raw.log_time_ns if last is None else max(last, raw.log_time_ns)
    total = sum(counts.values())
    if first is None:
        lines.append('messages: 0')
    else:
        lines.append(f'messages: {total}, start {_time_text(first)}, '
                     f'duration {(last - first) * 1e-9:.3f} s')
    lines.append(f'topics: {len(counts)}')
    width = max((len(name) for name in counts), default=0)
    for name, info in sorted(recording.topics.items()):
        lines.append(f'  {name:<{width}}  {info.type_name or "?"}  {counts[name]} messages'
                     + ('' if info.message_encoding == 'cdr' else f' ({info.message_encoding})'))
    return '\n'.join(lines)


def build_parser() -> argparse.ArgumentParser:
    """Argument parser of toc-bag."""
    parser = argparse.ArgumentParser(
        prog='toc-bag', description='Inspect a rosbag2 MCAP recording, or recover one that '
        'was not closed (recorder killed, power loss, full disk).',
        epilog='Exit codes: 0 done, 1 (info) the recording is not complete, 2 error.')
    commands = parser.add_subparsers(dest='command', required=True)
    info = commands.add_parser('info', help='files, completeness, topics and message counts')
    info.add_argument('path', help='bag directory, its metadata.yaml or a .mcap file')
    rec = commands.add_parser(
        'recover', help='rewrite the readable part into a new, complete bag directory')
    rec.add_argument('input', help='bag directory, its metadata.yaml or a .mcap file')
    rec.add_argument('output', nargs='?', help='new bag directory (default: INPUT-recovered)')
    return parser


def main(argv: Optional[List[str]] = None) -> int:
    """Run toc-bag; return the exit code."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exit_:
        return EXIT_OK if exit_.code == 0 else EXIT_ERROR

    def warn(text):
        print(f'toc-bag: warning: {text}', file=sys.stderr)

    try:
        if args.command == 'info':
            with Recording(args.path) as recording:
                print(info_text(recording))
                problems = [s.problem for s in recording.file_status() if s.problem]
                for text in recording.warnings:
                    if not any(problem in text for problem in problems):
                        warn(text)
                complete = all(s.complete for s in recording.file_status())
                if not complete:
                    print(f'run `toc-bag recover {args.path}` for a complete copy')
                return EXIT_OK if complete and not recording.damaged else EXIT_DAMAGED
        output = args.output or default_output(args.input)
        summary = recover(args.input, output, warn)
    except RecordingError as error:
        print(f'toc-bag: error: {error}', file=sys.stderr)
        return EXIT_ERROR
    print(f'recovered {summary.message_count} messages on {len(summary.topics)} topics, '
          f'{summary.duration_ns * 1e-9:.3f} s, into {summary.path}')
    return EXIT_OK


if __name__ == '__main__':
    sys.exit(main())
