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
Cost of the recorder's flush policy: BagWriter throughput and CPU per flush setting.

For each policy (no periodic flush = 1 MiB chunks only; flush every 100 ms without and with
fsync; every 10 ms with fsync):

* burst: N messages of one size written as fast as possible, then close(): messages/s, MB/s,
  file size and chunk count, and the longest single write() call (fsync runs outside the
  writer's lock, so it should not show there);
* paced: 1 kHz for a few seconds (the plant's joint_states rate is 100 Hz, the integration
  1 kHz): CPU time of the whole process (writer and flush thread) per second recorded.

Medians over --repeat runs, in a temporary directory on the file system of --dir.

    PYTHONPATH=. python benchmarks/bench_recording.py [--repeat 3] [--dir .] [--json PATH]
"""

import argparse
import json
import os
import platform
import statistics
import tempfile
import time

from mcap.reader import make_reader

from toc_ros.recording.bag_writer import BagWriter

POLICIES = [
    ('1 MiB chunks only (no periodic flush)', None, False),
    ('flush every 100 ms, no fsync', 0.1, False),
    ('flush every 100 ms + fsync (default)', 0.1, True),
    ('flush every 10 ms + fsync', 0.01, True),
]
SIZES = [(200, 200_000), (10_000, 5_000)]  # (bytes per message, messages per burst)
PACED_RATE_HZ = 1000.0


def _payload(size):
    return bytes(4) + bytes((k * 7) & 0xFF for k in range(size - 4))


def burst(directory, flush_period, fsync, size, count):
    """Write count messages as fast as possible; return the measurements."""
    path = os.path.join(directory, f'burst_{time.monotonic_ns()}')
    writer = BagWriter(path, flush_period=flush_period, fsync=fsync).create()
    writer.add_topic('/bench', 'std_msgs/msg/String')
    data = _payload(size)
    longest = 0.0
    start = time.perf_counter()
    for k in range(count):
        before = time.perf_counter()
        writer.write('/bench', data, 1_000_000_000 + k * 1000)
        longest = max(longest, time.perf_counter() - before)
    summary = writer.close()
    elapsed = time.perf_counter() - start
    file_size = os.path.getsize(summary.mcap_path)
    with open(summary.mcap_path, 'rb') as stream:
        chunks = len(make_reader(stream).get_summary().chunk_indexes)
    return {'messages_per_s': count / elapsed, 'mb_per_s': count * size / elapsed / 1e6,
            'file_mb': file_size / 1e6, 'chunks': chunks, 'longest_write_ms': longest * 1e3,
            'flushes': writer.flush_count}


def paced(directory, flush_period, fsync, size, seconds):
    """Write at PACED_RATE_HZ for seconds; return CPU seconds per recorded second."""
    path = os.path.join(directory, f'paced_{time.monotonic_ns()}')
    writer = BagWriter(path, flush_period=flush_period, fsync=fsync).create()
    writer.add_topic('/bench', 'std_msgs/msg/String')
    data = _payload(size)
    count = int(seconds * PACED_RATE_HZ)
    cpu0 = time.process_time()
    start = time.perf_counter()
    for k in range(count):
        writer.write('/bench', data, 1_000_000_000 + k * 1_000_000)
        delay = start + (k + 1) / PACED_RATE_HZ - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
    writer.close()
    return {'cpu_ms_per_s': (time.process_time() - cpu0) / seconds * 1e3,
            'flushes': writer.flush_count}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--repeat', type=int, default=3)
    parser.add_argument('--dir', default='.', help='file system to write on (a temporary '
                        'directory is made and removed there)')
    parser.add_argument('--paced-seconds', type=float, default=3.0)
    parser.add_argument('--json', help='also write the results here')
    args = parser.parse_args()
    print(f'{platform.processor() or platform.machine()}, {os.cpu_count()} cores, '
          f'load {os.getloadavg()[0]:.2f}; median of {args.repeat}')
    results = []
    with tempfile.TemporaryDirectory(prefix='toc_bench_', dir=args.dir) as directory:
        for size, count in SIZES:
            print(f'\nburst: {count} messages of {size} B')
            print('| policy | msg/s | MB/s | file MB | chunks | longest write() [ms] |')
            print('|---|---|---|---|---|---|')
            for name, period, fsync in POLICIES:
                runs = [burst(directory, period, fsync, size, count)
                        for _ in range(args.repeat)]
                row = {key: statistics.median(r[key] for r in runs) for key in runs[0]}
                row.update(kind='burst', policy=name, size=size, count=count)
                results.append(row)
                print(f"| {name} | {row['messages_per_s']:,.0f} | {row['mb_per_s']:.1f} | "
                      f"{row['file_mb']:.2f} | {row['chunks']:.0f} | "
                      f"{row['longest_write_ms']:.2f} |")
        print(f'\npaced: {PACED_RATE_HZ:.0f} Hz, 200 B, {args.paced_seconds:g} s')
        print('| policy | CPU [ms per s recorded] | flushes |')
        print('|---|---|---|')
        for name, period, fsync in POLICIES:
            runs = [paced(directory, period, fsync, 200, args.paced_seconds)
                    for _ in range(args.repeat)]
            row = {key: statistics.median(r[key] for r in runs) for key in runs[0]}
            row.update(kind='paced', policy=name, size=200, rate_hz=PACED_RATE_HZ)
            results.append(row)
            print(f"| {name} | {row['cpu_ms_per_s']:.1f} | {row['flushes']:.0f} |")
    if args.json:
        with open(args.json, 'w') as stream:
            json.dump(results, stream, indent=1)


if __name__ == '__main__':
    main()
