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

"""The demo's summary: the recording's facts from its metadata.yaml, and the printed text."""

import math
import os

import yaml


def recording_facts(path, closed_cleanly):
    """Path, clean close and message count of a recording (count from its metadata.yaml)."""
    count = None
    try:
        with open(os.path.join(path, 'metadata.yaml')) as stream:
            info = (yaml.safe_load(stream) or {}).get('rosbag2_bagfile_information') or {}
        count = int(info['message_count'])
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError, AttributeError):
        pass     # no metadata (the recorder failed early): the count stays unknown
    return {'path': os.path.abspath(path), 'closed_cleanly': closed_cleanly, 'messages': count}


def format_summary(summary):
    """Return the human-readable summary."""
    lines = ['', 'toc-demo summary']
    tol = summary['position_tolerance']
    u1, u2 = summary.get('joint_units') or ('rad', 'm')
    if 'arm_stages' in summary:
        lines += _arm_lines(summary)
    for k, plan in enumerate(summary['plans'], 1):
        q = plan['goal_q']
        lines.append(f"  plan {k} ({plan['label']}) to q = ({q[0]:.4f} {u1}, {q[1]:.4f} {u2}), "
                     f"{len(plan['obstacles'])} obstacle(s): {plan.get('status', 'not finished')}")
        if 't_min' in plan:
            lines.append(f"    t_min {plan['t_min']:.4f} s, solve wall time "
                         f"{plan['solve_wall_time_s']:.2f} s ({plan['iterations']} "
                         f"iterations), start from {plan['start_source']}")
        if 'final_error' in plan:
            e = plan['final_error']
            lines.append(
                f'    final tracking error ({e[0]:.2e} {u1}, {e[1]:.2e} {u2}), distance '
                f"{plan['final_distance']:.2e}: "
                + ('within' if plan['reached'] else 'OUTSIDE')
                + f' the tolerance ({tol[0]:g} {u1}, {tol[1]:g} {u2})'
                + ('' if plan['at_rest'] else ', not at rest'))
    loop = summary.get('closed_loop')
    if loop:
        lines.append('  closed loop (paper goal; plant payload +20 %, inertia x 1.2; a circle '
                     f"moving into the path; {loop.get('integrator', 'euler')} plans; the true "
                     "plant's best plan around the circle's final place: t_min "
                     f"{loop['true_t_min']:.4f} s, arrival {loop['true_arrival_s']:.4f} s):")
        for name, m in loop['runs'].items():
            latency = ('' if not m['latencies'] else
                       f", replan latency median/p99 {1e3 * m['latency_median_s']:.1f}/"
                       f"{1e3 * m['latency_p99_s']:.1f} ms")
            lines.append(f"    {name}: {m['plans']} plan(s), arrival {m['arrival_s']:.4f} s, "
                         f"final error {m['final_error']:.2e} (0.2 s after the last plan), "
                         f"min clearance {m['min_clearance']:.4f} m{latency}"
                         + (f", estimate {m['last_estimate']}" if m.get('last_estimate') else ''))
    cycles = summary.get('replanning')
    if cycles and cycles['latencies']:
        lines.append(f"  replan cycles of the whole demo: {cycles['latencies']} published, "
                     f"{cycles['kept']} kept; latency (joint_states received -> trajectory "
                     f"published) median {1e3 * cycles['latency_median_s']:.1f} ms, p99 "
                     f"{1e3 * cycles['latency_p99_s']:.1f} ms, max "
                     f"{1e3 * cycles['latency_max_s']:.1f} ms")
    recording = summary.get('recording')
    if recording:
        count = recording['messages']
        lines.append(f"  recording: {recording['path']} ("
                     + ('unknown number of' if count is None else str(count)) + ' messages, '
                     + ('closed cleanly)' if recording['closed_cleanly'] else
                        'recorder FAILED: see logs)'))
    else:
        lines.append('  recording: none (--no-record)')
    codes = summary.get('exit_codes', {})
    if any(codes.values()):
        lines.append(f'  exit codes of the nodes: {codes}')
    if summary.get('logs'):
        lines.append(f"  node logs: {summary['logs']}")
    if summary.get('error'):
        lines.append(f"  error: {summary['error']}")
    lines.append(f"  wall time {summary['wall_time_s']:.1f} s: "
                 + ('OK' if summary['success'] else 'FAILED'))
    return '\n'.join(lines)


def _arm_lines(summary):
    """Return the summary lines of an arm demo's goals (toc-demo --robot panda)."""
    lines = [f"  Panda on MuJoCo, payload {summary['payload_kg']:g} kg (the plans assume "
             f"{summary.get('planned_payload_kg', 0.0):g} kg), obstacle margin "
             f"{summary['margin']:g} m; the three goals with replanning, then with replanning "
             'and the payload estimated online:']
    run, k = None, 0
    for s in summary['arm_stages']:
        if s.get('run') != run:
            run, k = s.get('run'), 0
            lines.append(f'  {run}:')
        k += 1
        head = f"    goal {k} ({s['label']}, {s['goal']}): {s.get('status', 'not finished')}"
        if 'arrival_s' in s:
            latency = ('' if not s['latencies'] else
                       f", replan latency median/p99 {1e3 * s['latency_median_s']:.1f}/"
                       f"{1e3 * s['latency_p99_s']:.1f} ms")
            plant = s.get('plant_arrival_s', math.nan)
            head += (f"; t_min {s['t_min']:.4f} s (the plant's {s['t_min_plant']:.4f} s), arrival "
                     f"{s['arrival_s']:.4f} s ({100.0 * (s['arrival_s'] / plant - 1.0):+.1f} % vs "
                     f"the plant's best plan, {plant:.4f} s), within 1e-3 rad at "
                     f"{s['settled_s']:.4f} s, final error "
                     f"{s['final_error']:.2e} rad" + ('' if s['at_rest'] else ' (NOT at rest)')
                     + f", min clearance {s['min_clearance']:.4f} m, {s['cycles']} cycle(s) "
                     f"replanned, {s['kept']} kept{latency}; estimate "
                     f"{s.get('payload_estimate') or 'none'}")
        lines.append(head)
    return lines
