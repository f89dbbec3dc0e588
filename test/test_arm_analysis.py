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
toc-analyze on a synthetic Panda recording, checked by the independent oracle (arm_oracle).

The run: the Panda's 7 joints move from the ready pose along a smooth-step in 1 s (100 Hz
joint_states with one velocity and one effort sample beyond the URDF's limits), a sphere in the
tip's way at 0.45 s and, from 0.6 s on, a far one instead (an RViz marker); solver_node's
progress names the model (robot_model panda) and reports two replan cycles.
"""

import json

from arm_oracle import ArmOracle, find_panda_urdf, PANDA_JOINTS
from builtin_interfaces.msg import Duration, Time
import numpy as np
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from toc_ros import progress as schema
from toc_ros.analysis.cli import main
from toc_ros.core import Status
from toc_ros.recording.bag_writer import BagWriter
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
from visualization_msgs.msg import Marker, MarkerArray

T0 = 1_700_000_000_000_000_000
READY = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])
GOAL = np.array([1.0, -0.3, 0.4, -1.8, 0.3, 1.9, 0.5])
SWITCH_S = 0.6


def stamp(t):
    ns = T0 + int(round(t * 1e9))
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def motion(oracle):
    """Return (times, q, dq, effort) of the synthetic execution, starting at 0.2 s."""
    times = 0.2 + np.arange(101) * 0.01
    s = np.clip((times - 0.2) / 1.0, 0.0, 1.0)
    q = READY + (GOAL - READY) * (3 * s ** 2 - 2 * s ** 3)[:, None]
    dq = (GOAL - READY) * ((6 * s - 6 * s ** 2) / 1.0)[:, None]
    effort = np.tile(0.5 * oracle.effort, (len(times), 1))
    dq[40, 1] = oracle.velocity[1] + 0.25          # beyond the limits on one sample each
    effort[70, 6] = -(oracle.effort[6] + 3.0)
    return times, q, dq, effort


def obstacle_sets(oracle):
    """Return the obstacle sets: a sphere on the tip's path at 0.45 s, then a far one."""
    on_path = oracle.tip(motion(oracle)[1][25]).translation
    return [(0.1, [(on_path[0], on_path[1], on_path[2] + 0.02, 0.05)]),
            (SWITCH_S, [(2.0, 2.0, 2.0, 0.1)])]


def old_reports():
    """Return the progress reports of a recording made before they named the arm settings."""
    return [schema.ProgressReport(status=Status.SOLVED, message='solved', robot_model='panda',
                                  event=''),
            schema.ProgressReport(status=Status.SOLVED, event=schema.EVENT_REPLANNED,
                                  latency_s=0.012),
            schema.ProgressReport(status=Status.SOLVED, event=schema.EVENT_REPLANNED,
                                  latency_s=0.020)]


def write_run(path, oracle, reports=None, sets=None, plans='/trajectory'):
    """
    Write the synthetic run; return (times, q, dq, effort) of its joint_states.

    reports: the progress reports, one every 0.3 s from 0.18 s (default: old_reports());
    sets: the two obstacle sets [(time, rows)] (default: obstacle_sets(oracle)); plans: the
    topic of the plan.
    """
    times, q, dq, effort = motion(oracle)
    events = []
    (first, rows), (second, (far,)) = sets or obstacle_sets(oracle)
    events.append((first, '/obstacles', Float64MultiArray(data=[v for r in rows for v in r])))
    # The second set as an RViz marker in the URDF's root frame (diameter as the scale).
    marker = Marker(type=Marker.SPHERE, action=Marker.ADD, ns='far', id=0)
    marker.header.frame_id = 'panda_link0'
    marker.pose.position.x, marker.pose.position.y, marker.pose.position.z = far[:3]
    marker.pose.orientation.w = 1.0
    marker.scale.x = marker.scale.y = marker.scale.z = 2.0 * far[3]
    events.append((second, '/obstacle_markers', MarkerArray(markers=[marker])))
    plan = JointTrajectory(joint_names=PANDA_JOINTS)
    plan.header.stamp = stamp(0.2)
    plan.points = [JointTrajectoryPoint(positions=list(p), time_from_start=Duration(
        sec=0, nanosec=int(k * 5e8))) for k, p in enumerate((READY, 0.5 * (READY + GOAL), GOAL))]
    events.append((0.19, plans, plan))
    for k, report in enumerate(old_reports() if reports is None else reports):
        events.append((0.18 + 0.3 * k, '/solver_node/progress',
                       schema.progress_msg('solver_node', report)))
    for k, t in enumerate(times):
        msg = JointState(name=PANDA_JOINTS + ['panda_finger_joint1'],
                         position=list(q[k]) + [0.0], velocity=list(dq[k]) + [0.0],
                         effort=list(effort[k]) + [0.0])
        msg.header.stamp = stamp(t)
        events.append((t, '/joint_states', msg))
    types = {'/obstacles': 'std_msgs/msg/Float64MultiArray',
             '/obstacle_markers': 'visualization_msgs/msg/MarkerArray',
             plans: 'trajectory_msgs/msg/JointTrajectory',
             '/solver_node/progress': 'diagnostic_msgs/msg/DiagnosticStatus',
             '/joint_states': 'sensor_msgs/msg/JointState'}
    writer = BagWriter(path, flush_period=None).create()
    for topic, type_name in types.items():
        writer.add_topic(topic, type_name, [])
    for t, topic, msg in sorted(events, key=lambda e: e[0]):
        writer.write(topic, serialize_message(msg), T0 + int(round(t * 1e9)))
    writer.close()
    return times, q, dq, effort


def test_arm_recording_is_analysed_against_its_spheres_and_limits(tmp_path, capsys):
    oracle = ArmOracle(find_panda_urdf().read_text())
    bag = tmp_path / 'panda_run'
    times, q, dq, effort = write_run(bag, oracle)
    out = tmp_path / 'report'
    assert main([str(bag), '--out', str(out)]) == 0, capsys.readouterr().err
    summary = json.loads((out / 'summary.json').read_text())
    assert summary['model']['name'] == 'panda' and summary['model']['joints'] == PANDA_JOINTS
    assert summary['samples'] == len(times)
    # Clearance: to the set in force at each sample's stamp, recomputed by the oracle.
    sets = obstacle_sets(oracle)
    assert [s['rows'] for s in summary['obstacle_sets']] == [
        [list(r) for r in rows] for _, rows in sets]
    expected = np.array([oracle.clearance(qk, [r for s, r in sets if s <= t][-1], 0.0)
                         for t, qk in zip(times, q)])
    worst = int(np.argmin(expected))
    assert expected[worst] < 0.0 and times[worst] < SWITCH_S    # the first sphere is cut
    c = summary['min_clearance']
    # Times from the recording's first message (the first obstacle set, at 0.1 s).
    assert abs(c['value'] - expected[worst]) < 1e-9
    assert abs(c['time_s'] - (times[worst] - 0.1)) < 1e-6
    assert c['samples_inside'] == int(np.sum(expected < 0.0)) and c['obstacle'] == 0
    # Limits as the URDF gives them (Pinocchio's reading in the oracle).
    excess = summary['limit_excess']
    assert abs(excess['velocity'][1] - 0.25) < 1e-9 and abs(excess['effort'][6] - 3.0) < 1e-9
    assert all(v == 0.0 for j, v in enumerate(excess['velocity']) if j != 1)
    assert all(v == 0.0 for j, v in enumerate(excess['effort']) if j != 6)
    inside = np.maximum(q - oracle.upper, oracle.lower - q).max(axis=0)
    assert np.allclose(excess['position'], np.maximum(inside, 0.0), atol=1e-12)
    assert summary['plans'] == 1 and abs(summary['final_error']) < 1e-12
    assert summary['replan_latency']['count'] == 2
    assert abs(summary['replan_latency']['median_s'] - 0.016) < 1e-12
    for name in ('joints', 'clearance', 'tip_path'):
        assert summary['plots'][name]['file'] == f'{name}.png'
        assert (out / f'{name}.png').stat().st_size > 10_000
    assert 'min clearance' in (out / 'summary.md').read_text()
    # A recording made before the reports named the arm settings: what was assumed is said.
    assumed = [w for w in summary['warnings'] if 'does not name the settings' in w]
    assert len(assumed) == 1 and 'assumed the shipped panda collision spheres' in assumed[0]
    assert "the URDF's joint limits" in assumed[0] and 'default tip link' in assumed[0]
    assert summary['model']['tip_link'] == 'panda_hand'


def test_plans_executed_through_the_action_are_read_from_planned_trajectory(tmp_path, capsys):
    # panda.launch.py execute:=action remaps solver_node's trajectory to planned_trajectory.
    oracle = ArmOracle(find_panda_urdf().read_text())
    summaries = []
    for topic in ('/trajectory', '/planned_trajectory'):
        bag = tmp_path / topic.strip('/')
        write_run(bag, oracle, plans=topic)
        out = tmp_path / (topic.strip('/') + '_report')
        assert main([str(bag), '--out', str(out)]) == 0, capsys.readouterr().err
        summaries.append(json.loads((out / 'summary.json').read_text()))
    assert summaries[1]['plans'] == summaries[0]['plans'] == 1
    assert summaries[1]['final_error'] == summaries[0]['final_error']


def test_an_arm_that_cannot_be_rebuilt_is_refused_with_the_reason(tmp_path, capsys):
    bag = tmp_path / 'urdf_run'
    writer = BagWriter(bag, flush_period=None).create()
    writer.add_topic('/solver_node/progress', 'diagnostic_msgs/msg/DiagnosticStatus', [])
    report = schema.ProgressReport(status=Status.SOLVED, robot_model='urdf')
    writer.write('/solver_node/progress',
                 serialize_message(schema.progress_msg('solver_node', report)), T0)
    writer.close()
    assert main([str(bag), '--out', str(tmp_path / 'r')]) == 2
    err = capsys.readouterr().err
    assert "the recorded arm 'urdf' cannot be rebuilt" in err and 'collision_spheres' in err
