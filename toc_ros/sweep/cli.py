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
toc-sweep: solve every case of a sweep spec on Dask, results to a Parquet dataset.

Exit codes: 0 every case of the spec is in the dataset, 1 some cases could not be solved
(their tasks failed: rerun with --resume), 2 bad arguments, bad spec or unusable --out,
3 the scheduler cannot be reached, 130 interrupted (rerun with --resume).
"""

import argparse
import os
import sys
import time

EXIT_INCOMPLETE = 1
EXIT_USAGE = 2
EXIT_CONNECT = 3
EXIT_INTERRUPTED = 130
BAR_WIDTH = 24


def build_parser():
    """Argument parser of toc-sweep."""
    parser = argparse.ArgumentParser(
        prog='toc-sweep',
        description='Minimum-time solves over a grid or random sample of scenarios (a YAML '
                    'spec) on Dask distributed; one Parquet row per case, a summary and a '
                    't_min heat map next to the dataset.',
        epilog='Exit codes: 0 all cases done, 1 some cases failed to run (rerun with --resume), '
               '2 bad arguments or spec, 3 scheduler unreachable, 130 interrupted.')
    parser.add_argument('spec', metavar='SPEC.yaml', help='the sweep spec')
    parser.add_argument('--scheduler', metavar='ADDRESS',
                        help='address of a running Dask scheduler (tcp://host:8786); default: '
                             'an embedded LocalCluster')
    parser.add_argument('--workers', type=int, metavar='N',
                        help='LocalCluster worker processes (1 thread each; default: one per '
                             'core)')
    parser.add_argument('--out', metavar='DIR',
                        help='output directory (default: sweeps/<spec name>)')
    parser.add_argument('--resume', action='store_true',
                        help='keep the rows already in DIR and solve only the missing cases')
    parser.add_argument('--batch-size', type=int, metavar='N',
                        help='cases per task (default: adaptive, about 1 s of solving each)')
    parser.add_argument('--dry-run', action='store_true',
                        help='check the spec, print the number of cases, solve nothing')
    parser.add_argument('--quiet', action='store_true', help='no progress bar, no summary')
    return parser


class ProgressBar:
    """Cases done / not solved and ETA: a redrawn line on a terminal, else a line every 30 s."""

    LOG_PERIOD_S = 30.0

    def __init__(self, stream, total, done, terminal=True):
        self.stream = stream
        self.terminal = terminal
        self.last_log = time.monotonic()
        self.total = total
        self.start_done = done
        self.done = done
        self.failed = 0
        self.lost = 0
        self.start = time.monotonic()
        self.width = 0

    def __call__(self, rows, lost=0):
        """Account the rows of one finished task and redraw."""
        self.done += len(rows)
        self.lost += lost
        self.failed += sum(r['status'] not in ('SOLVED', 'SOLVED_INACCURATE') for r in rows)
        frac = self.done / max(self.total, 1)
        filled = int(round(frac * BAR_WIDTH))
        elapsed = time.monotonic() - self.start
        rate = (self.done - self.start_done) / elapsed if elapsed > 0 else 0.0
        left = self.total - self.done - self.lost
        eta = f'ETA {left / rate:.0f} s' if rate > 0 and left > 0 else ''
        bar = f'[{"#" * filled}{"-" * (BAR_WIDTH - filled)}] ' if self.terminal else ''
        line = (f'{bar}{self.done}/{self.total} cases, '
                f'{self.failed} not solved' + (f', {self.lost} lost' if self.lost else '')
                + f', {rate:.1f} cases/s {eta}')
        if self.terminal:
            self.stream.write('\r' + line.ljust(self.width))
            self.width = len(line)
        elif time.monotonic() - self.last_log >= self.LOG_PERIOD_S:
            self.last_log = time.monotonic()
            self.stream.write(f'toc-sweep: {line}\n')
        self.stream.flush()

    def clear(self):
        """Erase the line."""
        if self.width:
            self.stream.write('\r' + ' ' * self.width + '\r')
            self.stream.flush()
            self.width = 0


def main(argv=None):
    """Entry point of toc-sweep; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.workers is not None and (args.workers < 1 or args.scheduler):
        parser.error('--workers takes N >= 1 and only applies without --scheduler')
    if args.batch_size is not None and args.batch_size < 1:
        parser.error('--batch-size must be >= 1')
    try:
        return _run(args)
    except KeyboardInterrupt:
        print('\ntoc-sweep: interrupted; the rows written so far stay in the dataset, rerun '
              'with --resume to solve the rest', file=sys.stderr)
        return EXIT_INTERRUPTED


def _say(args, *text):
    if not args.quiet:
        print(*text, flush=True)


def _run(args):
    from .arm_cases import case_builder
    from .dataset import Dataset, DatasetError, schema_for
    from .spec import load_spec, SpecError
    try:
        sweep = load_spec(args.spec)
        builder = case_builder(sweep)
        if sweep.n_cases >= 10000:
            _say(args, f'toc-sweep: checking {sweep.n_cases} cases (about '
                       f'{sweep.n_cases * 0.4e-3:.0f} s) ...')
        cases = builder.cases()
        schema = schema_for(sweep, arm=builder.is_arm)
    except (SpecError, DatasetError) as exc:
        print(f'toc-sweep: bad spec: {exc}', file=sys.stderr)
        return EXIT_USAGE
    if args.dry_run:
        print(f'toc-sweep: {args.spec}: {len(cases)} case(s), varied: '
              f'{", ".join(sweep.names) or "nothing"}')
        return 0
    out = args.out or os.path.join(
        'sweeps', os.path.splitext(os.path.basename(args.spec))[0])
    dataset = Dataset(out, schema)
    try:
        done_ids = dataset.prepare(args.resume, sweep.text)
    except DatasetError as exc:
        print(f'toc-sweep: {exc}', file=sys.stderr)
        return EXIT_USAGE
    try:
        return _sweep(args, sweep, builder, cases, dataset, done_ids)
    finally:
        dataset.close()


def _sweep(args, sweep, builder, cases, dataset, done_ids):
    pending = [c for c in cases if c[0] not in done_ids]
    _say(args, f'toc-sweep: {len(cases)} case(s) in {args.spec}, '
               f'{len(cases) - len(pending)} already in {dataset.out}, solving {len(pending)}')
    stats = None
    if pending:
        stats, code = _solve(args, builder, pending, dataset, len(cases))
        if code:
            return code
    ids = {c[0] for c in cases}
    table = dataset.read(ids)
    from .report import write_report
    summary = write_report(table, sweep, dataset.out, stats, len(cases),
                           **builder.report_options())
    if not args.quiet:
        counts = ', '.join(f'{k} {v}' for k, v in summary['by_status'].items())
        print(f'toc-sweep: {summary["rows"]}/{len(cases)} cases in {dataset.dir}: '
              f'{counts}')
        print(f'toc-sweep: summary {os.path.join(dataset.out, "summary.md")}'
              + (f', heat map {os.path.join(dataset.out, "heatmap.png")}'
                 if summary['plots'] else ''))
    if summary['missing']:
        print(f'toc-sweep: {summary["missing"]} case(s) missing (their tasks failed); rerun '
              'with --resume', file=sys.stderr)
        return EXIT_INCOMPLETE
    return 0


def _solve(args, builder, pending, dataset, total):
    from .runner import connect, run_cases, RunStats
    started = time.perf_counter()
    try:
        client, cluster, _ = connect(args.scheduler, args.workers,
                                     log=(lambda *a: None) if args.quiet else print)
    except (ConnectionError, OSError, TimeoutError) as exc:
        print(f'toc-sweep: {exc}', file=sys.stderr)
        return None, EXIT_CONNECT
    stats = RunStats(warm_s=time.perf_counter() - started)
    bar = None if args.quiet else ProgressBar(sys.stderr, total, total - len(pending),
                                              terminal=sys.stderr.isatty())
    try:
        run_cases(client, pending, dataset, batch_size=args.batch_size,
                  on_progress=bar, stats=stats)
    finally:
        if bar:
            bar.clear()
        client.close()
        if cluster is not None:
            cluster.close()
    if stats.lost:
        print(f'toc-sweep: {len(stats.lost)} case(s) lost: {stats.lost[0][1]}',
              file=sys.stderr)
    return stats, 0


if __name__ == '__main__':
    sys.exit(main())
