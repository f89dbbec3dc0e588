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
toc-analyze: plots and a summary (Markdown and JSON) of a recorded toc_ros run.

Exit codes: 0 report written; 1 report written from a damaged recording (cut off, undecodable
messages: what was readable is analysed); 2 no report (no such recording, not MCAP, no toc_ros
topics, bad arguments, output not writable).
"""

import argparse
import json
import os
import sys

from toc_ros.config import load_parameters
from toc_ros.core import ProblemError
from toc_ros.recording.bag_reader import Recording, RecordingError

from .arm_plots import draw_arm
from .arm_run import analyse_arm, is_arm_run, markdown as arm_markdown
from .plots import draw_all
from .recorded_run import load_run, ROLES
from .report import analyse, markdown

EXIT_OK, EXIT_DAMAGED, EXIT_ERROR = 0, 1, 2


def build_parser():
    """Argument parser of toc-analyze."""
    parser = argparse.ArgumentParser(
        prog='toc-analyze',
        description='Plots and a summary of a recorded toc_ros run (rosbag2 bag directory or '
                    '.mcap file): controls, states, hand path with obstacles, solver '
                    'convergence, tracking error; per plan and per execution numbers; per '
                    'closed-loop execution (successive plans to one goal: replan cycles, '
                    'braking, replacements) the replanned paths, executed clearance, arrival '
                    'against the planned t_min and replan latencies.',
        epilog='Exit codes: 0 report written, 1 report written but the recording is damaged '
               '(cut off or undecodable messages), 2 no report.')
    parser.add_argument('path', help='bag directory, its metadata.yaml, or a .mcap file')
    parser.add_argument('--out', metavar='DIR',
                        help='output directory (default: <recording>_analysis next to it)')
    parser.add_argument('--params', metavar='FILE.yaml', default=None,
                        help='ROS 2 parameter file with the robot data and the obstacles used '
                             "when the recording has none (default: the package's "
                             'config/toc_ros.yaml)')
    return parser


def default_out_dir(path):
    """<recording>_analysis beside the bag directory or .mcap file."""
    path = os.path.abspath(path).rstrip(os.sep)
    if os.path.basename(path) == 'metadata.yaml':
        path = os.path.dirname(path)
    root, ext = os.path.splitext(path)
    return (root if ext == '.mcap' else path) + '_analysis'


def _error(text):
    print(f'toc-analyze: error: {text}', file=sys.stderr)
    return EXIT_ERROR


def _write(path, text):
    with open(path, 'w', encoding='utf-8') as stream:
        stream.write(text)


def main(argv=None):
    """Analyse one recording; return the exit code."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exit_request:  # --help (0) or bad arguments (2)
        return exit_request.code
    warnings = []

    def warn(text):
        warnings.append(text)
        print(f'toc-analyze: warning: {text}', file=sys.stderr)

    try:
        params = load_parameters(args.params)
    except ProblemError as error:
        return _error(str(error))
    try:
        recording = Recording(args.path, warn)
    except RecordingError as error:
        return _error(str(error))
    with recording:
        try:
            run = load_run(recording, params, warn)
        except ProblemError as error:
            return _error(f'{recording.path}: {error}')
        damaged = recording.damaged
        info = {'recording': recording.path, 'files': recording.files,
                'damaged': damaged}
        topics = dict(recording.topics)
    if not any(run.messages.values()):
        found = ', '.join(f'{n} [{t.type_name or t.message_encoding}]'
                          for n, t in sorted(topics.items())) or 'none'
        wanted = ', '.join(token for token, _ in ROLES.values())
        return _error(f'{recording.path}: no toc_ros data to analyse (looked for topics '
                      f'named {wanted} with their ROS 2 types; found: {found})')
    out_dir = os.path.abspath(args.out or default_out_dir(args.path))
    if is_arm_run(run):
        summary = _write_report(out_dir, lambda: _arm_summary(run, info, warn, out_dir),
                                arm_markdown, warnings)
        if summary is None:
            return EXIT_ERROR
        print(arm_markdown(summary), end='')
        print(f'report: {out_dir}')
    else:
        summary = _write_report(out_dir, lambda: _planar_summary(run, info, warn, out_dir),
                                markdown, warnings)
        if summary is None:
            return EXIT_ERROR
        _print_summary(summary, out_dir)
    return EXIT_DAMAGED if damaged else EXIT_OK


def _planar_summary(run, info, warn, out_dir):
    report = analyse(run, info, warn)
    report.summary['plots'] = draw_all(report, out_dir)
    return report.summary


def _arm_summary(run, info, warn, out_dir):
    summary, series = analyse_arm(run, info, warn)
    summary['plots'] = draw_arm(series, out_dir)
    return summary


def _write_report(out_dir, make_summary, to_markdown, warnings):
    """
    Write summary.json and summary.md of make_summary() (which draws the plots) to out_dir.

    Returns the summary with the warnings, or None when the report cannot be written (said).
    """
    try:
        os.makedirs(out_dir, exist_ok=True)
        summary = make_summary()
        summary['warnings'] = warnings
        text = json.dumps(summary, indent=2, allow_nan=False)
        _write(os.path.join(out_dir, 'summary.json'), text + '\n')
        _write(os.path.join(out_dir, 'summary.md'), to_markdown(summary))
    except OSError as error:
        _error(f'cannot write the report to {out_dir}: {error.strerror or error}')
        return None
    return summary


def _print_summary(summary, out_dir):
    for plan in summary['plans']:
        v = plan['violations']
        clearance = v['min_clearance']
        print(f'plan {plan["index"]} at {plan["received_s"]:.3f} s: {plan["status"]}, '
              f't_min {plan["t_min"]:.4f} s'
              + (f', min clearance {clearance:.4g} m' if clearance is not None else ''))
    for execution in summary['executions']:
        print(f'execution of plan {execution["plan"]}: final error '
              f'{execution["final_error"]:.3g}, RMS hand error '
              f'{execution["rms_error"]["hand"]:.3g} m')
    for loop in summary.get('closed_loop', []):
        events = loop['events']
        arrival = loop['arrival_s']
        print(f'closed-loop execution {loop["index"]}: {loop["plan_count"]} plan(s), '
              f'{events["replanned"]} replanned, {events["replan_kept"]} kept, '
              f'{events["trajectory_stopped"]} stopped; planned t_min '
              f'{loop["planned_t_min"]:.4f} s, arrival '
              + ('never' if arrival is None else f'{arrival:.4f} s'))
    for missing in summary['missing']:
        print(f'missing: {missing}')
    print(f'report: {os.path.join(out_dir, "summary.md")}')


if __name__ == '__main__':
    sys.exit(main())
