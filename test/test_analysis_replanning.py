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
toc-analyze on a synthetic replanned execution with known numbers, written with BagWriter.

Node clock = log clock - LAG (the joint_states are logged LAG after their stamps; one of them
later still). Execution 0 (goal G): plan A (stamp = receipt), replan cycles B, C, D (stamps
ahead of their receipt; D arrives before C's stamp, so C never executes), a kept cycle, a
braking trajectory (zero stamp) with its trajectory_stopped report and a replacement E; an
obstacle moves into the arm's way meanwhile. Execution 1: plan F to goal H. The plant's
joint_states are a ramp from S to G (arriving at 2.70 s, then 5e-4 off the goal) and back.
"""

import json
import math

from builtin_interfaces.msg import Duration, Time
from diagnostic_msgs.msg import DiagnosticStatus
import numpy as np
import numpy_model as nm
import pytest
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from toc_ros import progress as schema
from toc_ros.analysis.cli import main
from toc_ros.analysis.closed_loop import ARRIVAL_TOL
from toc_ros.core import Status
from toc_ros.recording.bag_writer import BagWriter
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

pytestmark = pytest.mark.slow

T0 = 1_700_000_000_000_000_000          # log time of the first message [ns]
LAG_NS = 252_000_000                     # log time - header.stamp of the joint_states
A = 1.1
NAMES = ['rotation_joint', 'extension_joint']
S = np.array([0.2, 0.5])
G = np.array([1.0, 0.8])
H = np.array([0.2, 0.5])
FINAL_OFFSET = np.array([5e-4, -2e-4])  # the plant rests this far from G
STATIC = (2.5, -1.0, 0.1)                # a second obstacle that does not move
MOVES = [(1.0 + 0.1 * k, (1.6 - 0.1 * k, 1.6 - 0.1 * k, 0.15)) for k in range(6)]
# (name, received [s], stamp [s] or None, duration [s], report event, report time offset)
PLANS = [('A', 0.50, 0.50, 2.00), ('B', 1.03, 1.10, 1.50), ('C', 1.25, 1.30, 1.25),
         ('D', 1.28, 1.38, 1.15), ('brake', 2.00, None, 0.10), ('E', 2.20, 2.20, 0.60),
         ('F', 3.60, 3.60, 1.00)]
# replan cycles: plan -> (state stamp [s], node-reported latency [s])
CYCLES = {'B': (1.00, 0.028), 'C': (1.20, 0.045), 'D': (1.25, 0.029)}
LATE_LOG = {1.00: 0.005}                 # joint_states logged later than LAG (stamp: log)
PLOTS = ('replanned_paths', 'clearance', 'arrival', 'replan_latency')


def ns(t):
    return T0 + int(round(t * 1e9))


def node_time(t):
    """Time msg of the node clock at base time t [s]."""
    value = ns(t) - LAG_NS
    return Time(sec=value // 1_000_000_000, nanosec=value % 1_000_000_000)


def node_seconds(t):
    return (ns(t) - LAG_NS) * 1e-9


def executed(t):
    """Joint positions of the synthetic plant at base time t [s]."""
    if t < 3.6:
        frac = min(max((t - 0.5) / 2.2, 0.0), 1.0)
        q = S + (G - S) * frac
        return q + FINAL_OFFSET if frac >= 1.0 else q
    frac = min((t - 3.6) / 1.0, 1.0)
    return (G + FINAL_OFFSET) + (H - G - FINAL_OFFSET) * frac


def trajectory(start_q, end_q, duration, stamp):
    msg = JointTrajectory()
    msg.joint_names = NAMES
    if stamp is not None:
        msg.header.stamp = node_time(stamp)
    for s in np.linspace(0.0, 1.0, 11):
        point = JointTrajectoryPoint()
        point.positions = (start_q + (end_q - start_q) * s).tolist()
        point.velocities = ((end_q - start_q) / duration).tolist()
        point.effort = [0.0, 0.0]
        value = int(round(s * duration * 1e9))
        point.time_from_start = Duration(sec=value // 1_000_000_000,
                                         nanosec=value % 1_000_000_000)
        msg.points.append(point)
    return msg


def report(**values):
    return schema.progress_msg('/solver_node', schema.ProgressReport(**values))


def goal4(q):
    return (float(q[0]), 0.0, float(q[1]), 0.0)


def build(path):
    events = []
    for k in range(501):                 # joint_states at 100 Hz from 0 to 5 s
        t = round(0.01 * k, 2)
        msg = JointState(name=NAMES, position=executed(t).tolist(), velocity=[0.0, 0.0])
        msg.header.stamp = node_time(t)
        events.append((ns(t) + int(LATE_LOG.get(t, 0.0) * 1e9), '/joint_states', msg))
    events.append((ns(0.05), '/obstacles', Float64MultiArray(data=[*MOVES[0][1], *STATIC])))
    for t, row in MOVES[1:]:
        events.append((ns(t), '/obstacles', Float64MultiArray(data=[*row, *STATIC])))
    events.append((ns(0.10), '/goal_joints', JointState(name=NAMES, position=G.tolist(),
                                                        velocity=[0.0, 0.0])))
    events.append((ns(3.50), '/goal_joints', JointState(name=NAMES, position=H.tolist(),
                                                        velocity=[0.0, 0.0])))
    for name, received, stamp, duration in PLANS:
        start = executed(received if stamp is None else stamp)
        end = {'brake': start + 0.01, 'F': H}.get(name, G)
        events.append((ns(received), '/trajectory', trajectory(start, end, duration, stamp)))
        at = ns(received + 0.001)
        if name in CYCLES:
            state, latency = CYCLES[name]
            events.append((at, '/solver_node/progress', report(
                status=Status.SOLVED, message='replanned (rate)', iteration=5, t_f=duration,
                goal=goal4(G), goal_source='replan_cycle', event=schema.EVENT_REPLANNED,
                latency_s=latency, deviation=0.01, plan_stamp=node_seconds(stamp),
                state_stamp=node_seconds(state), elapsed_s=0.02)))
        elif name == 'brake':
            events.append((at, '/solver_node/progress', report(
                status=Status.CANCELED, message='stopped', level=DiagnosticStatus.WARN,
                goal_source='replan_cycle', event=schema.EVENT_STOPPED)))
        else:
            events.append((at, '/solver_node/progress', report(
                status=Status.SOLVED, message='solved', iteration=40, t_f=duration,
                goal=goal4(H if name == 'F' else G), elapsed_s=0.1,
                goal_source='replan' if name == 'E' else 'goal_joints',
                event=schema.EVENT_REPLACED if name == 'E' else '')))
    events.append((ns(1.40), '/solver_node/progress', report(
        status=Status.TIMEOUT, message='replan cycle (rate) kept the executing plan: late',
        level=DiagnosticStatus.WARN, iteration=3, goal=goal4(G), goal_source='replan_cycle',
        event=schema.EVENT_REPLAN_KEPT, latency_s=0.2, plan_stamp=node_seconds(1.45),
        state_stamp=node_seconds(1.35))))
    types = {'/joint_states': 'sensor_msgs/msg/JointState',
             '/goal_joints': 'sensor_msgs/msg/JointState',
             '/obstacles': 'std_msgs/msg/Float64MultiArray',
             '/trajectory': 'trajectory_msgs/msg/JointTrajectory',
             '/solver_node/progress': 'diagnostic_msgs/msg/DiagnosticStatus'}
    writer = BagWriter(path).create()
    for topic, type_name in types.items():
        writer.add_topic(topic, type_name, [])
    for log_ns, topic, msg in sorted(events, key=lambda e: e[0]):
        writer.write(topic, serialize_message(msg), log_ns)
    writer.close()


def arm_clearance(q, rows):
    """Clearance [m] of the arm segment (base to hand) to each circle's edge."""
    return [float(v) for v in nm.arm_clearance(q, rows, A)[0]]


def expected_clearance(t_from, t_to, moving=True):
    """Min clearance over the joint_states samples in [t_from, t_to) to the obstacles then."""
    best = math.inf
    for k in range(501):
        t = round(0.01 * k, 2)
        if not t_from <= t < t_to:
            continue
        row = MOVES[0][1]
        for start, moved in MOVES if moving else ():
            if start <= t:
                row = moved
        best = min(best, *arm_clearance(executed(t), [row, STATIC]))
    return best


@pytest.fixture(scope='module')
def analysed(tmp_path_factory):
    root = tmp_path_factory.mktemp('replanned')
    build(root / 'bag')
    out = root / 'report'
    assert main([str(root / 'bag'), '--out', str(out)]) == 0
    return json.loads((out / 'summary.json').read_text()), (out / 'summary.md').read_text(), out


def test_plans_start_at_their_stamp_and_replaced_plans_never_execute(analysed):
    summary, md, _ = analysed
    assert summary['clock']['offset_s'] == pytest.approx(LAG_NS * 1e-9, abs=1e-12)
    plans = summary['plans']
    assert len(plans) == len(PLANS)
    for got, (name, received, stamp, duration) in zip(plans, PLANS):
        assert got['received_s'] == pytest.approx(received, abs=1e-9), name
        assert got['start_s'] == pytest.approx(received if stamp is None else stamp,
                                               abs=1e-9), name
        assert got['t_min'] == pytest.approx(duration, abs=1e-9)
        assert got['executed'] is (name != 'C'), name
        assert got['closed_loop'] == (1 if name == 'F' else 0), name
    assert [p['status'] for p in plans] == ['SOLVED'] * 4 + ['CANCELED'] + ['SOLVED'] * 2
    # the per-plan executions: executed plans only, each from its start to the next one's
    executions = summary['executions']
    assert [e['plan'] for e in executions] == [0, 1, 3, 4, 5, 6]
    bounds = [0.50, 1.10, 1.38, 2.00, 2.20, 3.60, 5.01]
    for e, start, end in zip(executions, bounds, bounds[1:]):
        assert e['start_s'] == pytest.approx(start, abs=1e-9)
        assert e['samples'] == int(round((end - start) / 0.01))
    assert '(replaced before)' in md


def test_closed_loop_numbers_from_the_raw_messages(analysed):
    summary, md, _ = analysed
    first, second = summary['closed_loop']
    assert first['plans'] == [0, 1, 2, 3, 4, 5] and second['plans'] == [6]
    assert first['plan_count'] == 6 and first['executed_plans'] == 5
    assert first['goal'] == pytest.approx(goal4(G)) and second['goal'] == pytest.approx(goal4(H))
    assert first['events'] == {'replanned': 3, 'replan_kept': 1, 'trajectory_stopped': 1,
                               'trajectory_replaced': 1}
    assert second['events'] == dict.fromkeys(first['events'], 0)
    assert summary['events'] == first['events']
    assert first['start_s'] == pytest.approx(0.5) and second['start_s'] == pytest.approx(3.6)
    assert first['planned_t_min'] == pytest.approx(2.0, abs=1e-9)
    # Arrival: from the first 100 Hz sample after which every joint stays within ARRIVAL_TOL
    # of G (the synthetic plant approaches G linearly until t = 2.7 s, then rests near it).
    samples = [round(0.01 * k, 2) for k in range(360)]
    outside = [t for t in samples if np.max(np.abs(executed(t) - G)) > ARRIVAL_TOL]
    assert first['arrival_s'] == pytest.approx(round(outside[-1] + 0.01, 2) - 0.5, abs=1e-9)
    assert 2.0 < first['arrival_s'] <= 2.70 - 0.5
    assert first['last_plan_end_s'] == pytest.approx(2.2 + 0.6 - 0.5, abs=1e-9)
    assert first['final_error'] == pytest.approx(float(np.max(np.abs(FINAL_OFFSET))),
                                                 abs=1e-12)
    # The second execution approaches H linearly over 1 s from t = 3.6 s (100 Hz samples).
    samples = [round(3.6 + 0.01 * k, 2) for k in range(140)]
    outside = [t for t in samples if np.max(np.abs(executed(t) - H)) > ARRIVAL_TOL]
    assert second['arrival_s'] == pytest.approx(round(outside[-1] + 0.01, 2) - 3.6, abs=1e-9)
    assert 0.9 < second['arrival_s'] <= 1.0
    assert second['final_error'] == pytest.approx(0.0, abs=1e-12)
    # planned arrival of each successive plan: stamp (or receipt) + duration, from t0
    assert [a['arrival_s'] for a in first['planned_arrivals']] == pytest.approx(
        [(r if s is None else s) + d - 0.5 for _, r, s, d in PLANS[:6]], abs=1e-9)
    # clearance against the obstacle as it moved (log times), not the first position
    moving = expected_clearance(0.5, 3.6)
    assert first['min_clearance'] == pytest.approx(moving, abs=1e-9)
    assert moving < 0.0 < expected_clearance(0.5, 3.6, moving=False)
    assert second['min_clearance'] == pytest.approx(expected_clearance(3.6, 99.0), abs=1e-9)
    # latencies: as reported, and from the log times of the trajectory and the state
    node = [CYCLES[n][1] for n in 'BCD']
    recorded = [1.03 - 1.005, 1.25 - 1.20, 1.28 - 1.25]
    for got, want in ((first['latency_node'], node), (first['latency_recorded'], recorded)):
        assert got['count'] == 3
        assert got['median_s'] == pytest.approx(float(np.median(want)), abs=1e-9)
        assert got['p99_s'] == pytest.approx(float(np.percentile(want, 99)), abs=1e-9)
        assert got['max_s'] == pytest.approx(max(want), abs=1e-9)
    assert first['latency_recorded']['unmatched'] == 0
    assert first['late_receipts'] == {'count': 0, 'max_s': None}
    assert second['latency_node']['count'] == 0 and second['latency_node']['median_s'] is None
    assert '## Closed-loop executions' in md
    row = next(line for line in md.splitlines() if line.startswith('| 0 | 6 (5) |'))
    assert '| 3 | 1 | 1 |' in row and '29 / 44.7 / 45' in row and '30 / 49.6 / 50' in row


def test_closed_loop_plots_are_drawn(analysed):
    summary, _, out = analysed
    for name in PLOTS + ('controls', 'states', 'path', 'tracking_error'):
        assert summary['plots'][name]['file'] == f'{name}.png', summary['plots'][name]
        png = (out / f'{name}.png').read_bytes()
        assert png[:8] == b'\x89PNG\r\n\x1a\n' and len(png) > 20_000, name
