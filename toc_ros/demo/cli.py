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

"""Command line of toc-demo: arguments, signals, the output folder and the exit code."""

import argparse
import json
import os
import random
import shutil
import signal
import sys
import tempfile
import time

from toc_ros.demo import checks
from toc_ros.demo.panda import PandaDemo
from toc_ros.demo.run import Demo, DemoError, Printer, SCENARIOS
from toc_ros.demo.summary import format_summary
from toc_ros.recording.process import default_output_dir


class _Interrupted(Exception):
    """SIGINT or SIGTERM of the demo itself."""


def parse_args(argv):
    """Parse toc-demo's arguments (exit 2 for bad ones, before anything starts)."""
    from toc_ros import demo
    parser = argparse.ArgumentParser(
        prog='toc-demo', description=demo.__doc__.split('\n\n')[0].strip() + '.',
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog='Runs solver_node, plant_node and recorder_node on a private ROS domain '
               '(ROS_DOMAIN_ID random unless set, localhost discovery).')
    parser.add_argument('--output', metavar='DIR',
                        help='bag directory of the recording, must not exist or be empty '
                             '(default runs/<UTC timestamp>); summary.json and logs/ go there')
    parser.add_argument('--no-record', dest='record', action='store_false',
                        help='do not start recorder_node')
    parser.add_argument('--timeout', metavar='S', type=float, default=180.0,
                        help='give up after S seconds (default %(default)g; the first run '
                             'compiles the numba kernels for about a minute)')
    parser.add_argument('--quiet', action='store_true', help='print the summary only')
    parser.add_argument('--model', '--robot', choices=sorted(SCENARIOS) + ['panda'],
                        default='cylindrical',
                        help="robot of the demo: 'cylindrical' (the paper's scenario, "
                             "config/toc_ros.yaml), 'planar_2r' (config/toc_ros_planar_2r.yaml) "
                             "or 'panda' (config/panda.yaml: three goals around two spheres on "
                             'MuJoCo); default %(default)s')
    parser.add_argument('--no-closed-loop', dest='closed_loop', action='store_false',
                        help='skip the closed-loop stage (cylindrical model: model mismatch '
                             'and a moving circle, open loop against replanning)')
    args = parser.parse_args(argv)
    if not args.timeout > 0:
        parser.error('--timeout must be > 0')
    if args.output is None and args.record:
        args.output = default_output_dir()
    if args.output is not None:
        args.output = os.path.abspath(args.output)
        if os.path.exists(args.output) and (not os.path.isdir(args.output)
                                            or os.listdir(args.output)):
            parser.error(f'--output {args.output} exists and is not an empty directory')
    return args


def _raise_interrupted(signum, _frame):
    raise _Interrupted(signal.Signals(signum).name)


def main(argv=None):
    """Run the demo; return the exit code (0: both goals reached, recording complete)."""
    args = parse_args(argv)
    os.environ.setdefault('ROS_DOMAIN_ID', str(random.randint(1, 101)))
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    printer = Printer(args.quiet)
    printer.stage(f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']} ROS_AUTOMATIC_DISCOVERY_RANGE="
                  f"{os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE']}")
    previous = {s: signal.signal(s, _raise_interrupted) for s in (signal.SIGINT, signal.SIGTERM)}
    log_dir = tempfile.mkdtemp(prefix='toc-demo-')
    arm = args.model == 'panda'
    demo = PandaDemo(args, printer) if arm else Demo(args, printer)
    code = 1
    try:
        try:
            demo.start(log_dir)
            demo.wait_ready()
            if arm:
                demo.run()
            else:
                for number, stage in enumerate(demo.stages, 1):
                    demo.run_stage(number, stage)
            if demo.closed_loop and args.closed_loop:
                demo.run_closed_loop()
            demo.summarize_replanning()
        except DemoError as error:
            demo.summary['error'] = str(error)
            print(f'toc-demo: error: {error}', file=sys.stderr)
        except _Interrupted as interrupted:
            demo.summary['error'] = f'interrupted by {interrupted}'
            code = 130
        printer.stage('stopping the nodes')
        signal.signal(signal.SIGINT, signal.SIG_IGN)   # a second Ctrl-C must not orphan them
        demo.stop()
    finally:
        demo.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    summary = demo.summary
    summary['wall_time_s'] = time.monotonic() - printer.start
    summary['success'] = (checks.arm_success(summary, demo.stage_count) if arm
                          else checks.success(summary, len(demo.stages)))
    if args.output is not None:
        os.makedirs(args.output, exist_ok=True)
        logs = os.path.join(args.output, 'logs')
        shutil.copytree(log_dir, logs, dirs_exist_ok=True)
        shutil.rmtree(log_dir, ignore_errors=True)
        summary['logs'] = logs
        with open(os.path.join(args.output, 'summary.json'), 'w') as stream:
            json.dump(summary, stream, indent=2, allow_nan=True)
    elif summary['success']:
        shutil.rmtree(log_dir, ignore_errors=True)
    else:
        summary['logs'] = log_dir    # kept for the post-mortem
    print(format_summary(summary), flush=True)
    if code == 130:
        return code
    return 0 if summary['success'] else 1
