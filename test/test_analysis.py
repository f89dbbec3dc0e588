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
toc-analyze on a synthetic recording of a two-plan run, checked against the raw messages.

The run: a minimum-time plan of the paper's scenario (core solver, N = 100), executed by a
simulated plant (eq. 37 with a heavier payload, feed-forward plus PD, 100 Hz joint_states),
then a second plan back to the start around a changed obstacle set. The expected numbers are
recomputed here from the messages as mcap_ros2 decodes them (an independent reader).
"""

import json
import math

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import numpy_model as nm
import pytest
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String
from toc_ros import conversions, progress as schema
from toc_ros.analysis.cli import main
from toc_ros.core import Problem, RobotParams, solve
from toc_ros.core.integrators import RK4, rollout
from toc_ros.recording.bag_reader import Recording
from toc_ros.recording.bag_writer import BagWriter

T0 = 1_700_000_000_000_000_000
NAMES = ['rotation_joint', 'extension_joint']
U_MAX = np.array([600.0, 500.0])
A = 1.1
MARGIN = 0.01
OBSTACLES_1 = [(1.0, 1.0, 0.2)]
OBSTACLES_2 = [(1.0, 1.0, 0.2), (2.0, -0.2, 0.1)]
PLOTS = ('controls', 'states', 'path', 'convergence', 'tracking_error')
LATCHED = [{'history': 'keep_last', 'depth': 1, 'reliability': 'reliable',
            'durability': 'transient_local'}]


def stamp(t):
    ns = T0 + int(round(t * 1e9))
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


class Plant:
    """Eq. (37) with 10 % more payload than planned, feed-forward + PD at 1 kHz, saturated."""

    def __init__(self, x0):
        self.x = np.array(x0, dtype=float)
        self.params = RobotParams(hand_mass=55.0).packed()
        self.kp = np.array([2000.0, 2000.0])
        self.kd = np.array([300.0, 300.0])

    def run(self, times, states, efforts, duration, dt=1e-3, every=10):
        """Track the plan for duration [s]; joint_states samples every `every` steps."""
        samples = []
        next_state = np.empty((2, 4))
        for step in range(int(round(duration / dt))):
            t = step * dt
            k = min(np.searchsorted(times, t, side='right') - 1, len(efforts) - 1)
            ref = np.array([np.interp(t, times, states[:, j]) for j in range(4)])
            u = (efforts[k] if t < times[-1] else np.zeros(2))
            u = u + self.kp * (ref[[0, 2]] - self.x[[0, 2]]) + self.kd * (ref[[1, 3]]
                                                                          - self.x[[1, 3]])
            u = np.clip(u, -U_MAX, U_MAX)
            if step % every == 0:
                samples.append((t, self.x.copy(), u.copy()))
            rollout(self.x, u[None, :], dt, self.params, RK4, next_state)
            self.x = next_state[1].copy()
        return samples


def progress(report):
    return schema.progress_msg('solver_node', report)


def build_run(path, result):
    """Write the synthetic two-plan run; return the message log as (time, topic, msg)."""
    states, controls = result.states, result.controls
    times = result.time_grid
    t_min = result.final_time
    events = []

    def add(t, topic, msg):
        events.append((t, topic, msg))

    # plan 1: paper goal as a hand pose, obstacles from the topic
    add(0.05, '/obstacles', Float64MultiArray(data=[v for row in OBSTACLES_1 for v in row]))
    goal = states[-1]
    pose = PoseStamped()
    pose.header.frame_id = 'base_link'
    pose.pose.position.x = (A + goal[2]) * math.cos(goal[0])
    pose.pose.position.y = (A + goal[2]) * math.sin(goal[0])
    add(0.10, '/goal_pose', pose)
    history = result.history[np.linspace(0, len(result.history) - 1, 6).astype(int)]
    for k, (iteration, t_f, cost) in enumerate(history[:, :3]):   # iteration, t_f, cost, ...
        add(0.2 + 0.15 * k, '/solver_node/progress', progress(schema.ProgressReport(
            iteration=int(iteration), t_f=t_f, cost=cost, best_feasible_t_f=math.nan,
            elapsed_s=0.1 + 0.15 * k)))
    t1 = 1.1
    traj1 = conversions.trajectory_msg(result, NAMES, RobotParams(), stamp(t1))
    add(t1, '/trajectory', traj1)
    add(t1, '/planned_path', conversions.hand_path_msg(states, A, 'base_link', stamp(t1)))
    add(t1 + 0.001, '/markers', conversions.markers_msg(OBSTACLES_1, MARGIN, A, 'base_link',
                                                        stamp(t1), states))
    add(t1 + 0.002, '/solver_node/progress', progress(schema.result_report(result)))
    # a refused request between the plans
    add(1.5, '/solver_node/progress', progress(schema.refusal_report('goal is NaN')))

    # plan 2: back to the start (the time-reversed motion), new obstacles, the goal only in
    # the final progress (as for a ~/plan service request)
    t2 = t1 + t_min + 0.6
    add(t2 - 0.3, '/obstacles', Float64MultiArray(data=[v for row in OBSTACLES_2 for v in row]))
    for k in range(3):
        add(t2 - 0.2 + 0.05 * k, '/solver_node/progress', progress(schema.ProgressReport(
            iteration=100 * (k + 1), t_f=2.5 - 0.1 * k, cost=10.0 / (k + 1),
            elapsed_s=0.05 * (k + 1))))
    reversed_result = type(result)(
        status=result.status, message='', final_time=t_min, time_grid=times,
        states=(states[::-1] * np.array([1.0, -1.0, 1.0, -1.0])),
        controls=controls[::-1].copy(), iterations=300, wall_time_s=0.17,
        violations=result.violations)
    traj2 = conversions.trajectory_msg(reversed_result, NAMES, RobotParams(), stamp(t2))
    add(t2, '/trajectory', traj2)
    add(t2 + 0.003, '/solver_node/progress', progress(schema.result_report(
        reversed_result, goal=tuple(states[0].tolist()))))

    # the plant: at rest until plan 1, tracks it, then plan 2
    rest = [(k * 0.01, states[0], np.zeros(2)) for k in range(int(t1 / 0.01))]
    plant = Plant(states[0])
    arrays1 = conversions.trajectory_arrays(traj1, NAMES)
    arrays2 = conversions.trajectory_arrays(traj2, NAMES)

    def as_states(arr):
        return np.column_stack([arr.positions[:, 0], arr.velocities[:, 0],
                                arr.positions[:, 1], arr.velocities[:, 1]])

    run1 = [(t1 + 0.004 + t, x, u) for t, x, u in
            plant.run(arrays1.times, as_states(arrays1), arrays1.efforts, t2 - t1)]
    run2 = [(t2 + 0.004 + t, x, u) for t, x, u in
            plant.run(arrays2.times, as_states(arrays2), arrays2.efforts, t_min + 0.5)]
    for t, x, u in rest + run1 + run2:
        add(t, '/joint_states', JointState(
            name=NAMES, position=[x[0], x[2]], velocity=[x[1], x[3]], effort=[u[0], u[1]]))
        if round(t * 100) % 10 == 0:
            add(t + 0.0005, '/plant_node/tracking', conversions.diagnostic_msg(
                'plant_node', DiagnosticStatus.OK, 'tracking', {'position_error': 0.0}))

    types = {'/obstacles': 'std_msgs/msg/Float64MultiArray',
             '/goal_pose': 'geometry_msgs/msg/PoseStamped',
             '/solver_node/progress': 'diagnostic_msgs/msg/DiagnosticStatus',
             '/trajectory': 'trajectory_msgs/msg/JointTrajectory',
             '/planned_path': 'nav_msgs/msg/Path',
             '/markers': 'visualization_msgs/msg/MarkerArray',
             '/joint_states': 'sensor_msgs/msg/JointState',
             '/plant_node/tracking': 'diagnostic_msgs/msg/DiagnosticStatus'}
    # Chunks by size only (no flush thread): the cut below then lands at the same place.
    writer = BagWriter(path, chunk_size=64 * 1024, flush_period=None).create()
    for topic, type_name in types.items():
        writer.add_topic(topic, type_name,
                         LATCHED if topic in ('/trajectory', '/markers') else [])
    events.sort(key=lambda e: e[0])
    for t, topic, msg in events:
        writer.write(topic, serialize_message(msg), T0 + int(round(t * 1e9)))
    writer.close()


@pytest.fixture(scope='module')
def solved():
    # N = 100 rather than 200: a quarter of the solve time, same kind of trajectory.
    result = solve(Problem.paper(n_intervals=100))
    assert result.success, result.message
    return result


@pytest.fixture(scope='module')
def run_bag(solved, tmp_path_factory):
    path = tmp_path_factory.mktemp('analysis') / 'run'
    build_run(path, solved)
    return path


# -- independent recomputation from the raw messages ---------------------------------------
def read_all(mcap_path):
    """{topic: [(time [s], message)]} decoded by mcap_ros2 from the message definitions."""
    out = {}
    with open(mcap_path, 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, message, decoded in reader.iter_decoded_messages():
            out.setdefault(channel.topic, []).append(((message.log_time - T0) * 1e-9, decoded))
    return out


def seconds(duration):
    return duration.sec + duration.nanosec * 1e-9


def clearance(q1, q2, circles):
    """Distance of the arm segment from base to hand to each inflated circle's edge."""
    inflated = np.array(circles, dtype=float).reshape(-1, 3) + [0.0, 0.0, MARGIN]
    gaps = nm.arm_clearance(np.column_stack([q1, q2]), inflated, A)
    return float(np.min(gaps, initial=math.inf))


def expected_numbers(msgs):
    trajectories = msgs['/trajectory']
    finals = [(t, {kv.key: kv.value for kv in m.values}) for t, m in
              msgs['/solver_node/progress']]
    finals = [(t, v) for t, v in finals if v['status'] not in ('SOLVING', 'INVALID_INPUT')]
    goals = [None, None]
    pose = msgs['/goal_pose'][0][1].pose.position
    goals[0] = np.array([math.atan2(pose.y, pose.x), 0.0, math.hypot(pose.x, pose.y) - A, 0])
    goals[1] = np.array(json.loads(finals[1][1]['goal']))
    obstacles = [OBSTACLES_1, OBSTACLES_2]
    plans, executions = [], []
    for k, (t, traj) in enumerate(trajectories):
        pts = traj.points
        times = np.array([seconds(p.time_from_start) for p in pts])
        q = np.array([p.positions for p in pts])
        dq = np.array([p.velocities for p in pts])
        u = np.array([p.effort for p in pts])
        x = np.column_stack([q[:, 0], dq[:, 0], q[:, 1], dq[:, 1]])
        final_t, final = min(finals, key=lambda f: abs(f[0] - t))
        plans.append({
            'status': final['status'], 't_min': times[-1],
            'iterations': int(final['iteration']), 'solve_wall_time_s': float(final['elapsed_s']),
            'max_control_excess': max(float(np.max(np.abs(u) - U_MAX)), 0.0),
            'terminal_error': float(np.linalg.norm(x[-1] - goals[k])),
            'min_clearance': clearance(q[:, 0], q[:, 1], obstacles[k]),
        })
        end = trajectories[k + 1][0] if k + 1 < len(trajectories) else math.inf
        js = [(s, m) for s, m in msgs['/joint_states'] if t <= s < end]
        ts = np.array([s for s, _ in js])
        meas = np.array([[m.position[0], m.velocity[0], m.position[1], m.velocity[1]]
                         for _, m in js])
        eff = np.array([m.effort for _, m in js])
        ref = np.column_stack([np.interp(ts - t, times, x[:, j]) for j in range(4)])
        hand = np.hypot((A + meas[:, 2]) * np.cos(meas[:, 0]) - (A + ref[:, 2])
                        * np.cos(ref[:, 0]),
                        (A + meas[:, 2]) * np.sin(meas[:, 0]) - (A + ref[:, 2])
                        * np.sin(ref[:, 0]))
        executions.append({
            'samples': len(js),
            'final_error': float(np.linalg.norm(meas[-1] - x[-1])),
            'rms_q1': float(np.sqrt(np.mean((meas[:, 0] - ref[:, 0]) ** 2))),
            'rms_q2': float(np.sqrt(np.mean((meas[:, 2] - ref[:, 2]) ** 2))),
            'rms_hand': float(np.sqrt(np.mean(hand ** 2))),
            'max_effort': np.max(np.abs(eff), axis=0),
        })
    return plans, executions


@pytest.mark.slow
def test_report_of_a_two_plan_run(run_bag, tmp_path, capsys):
    out = tmp_path / 'report'
    assert main([str(run_bag), '--out', str(out)]) == 0
    for name in PLOTS:
        png = (out / f'{name}.png').read_bytes()
        assert png[:8] == b'\x89PNG\r\n\x1a\n' and len(png) > 20_000, name
    summary = json.loads((out / 'summary.json').read_text())
    md = (out / 'summary.md').read_text()
    assert summary['missing'] == [] and summary['damaged'] is False
    assert all(summary['plots'][name]['file'] == f'{name}.png' for name in PLOTS)

    plans, executions = expected_numbers(read_all(run_bag / 'run_0.mcap'))
    assert len(summary['plans']) == 2 and len(summary['executions']) == 2
    for got, want in zip(summary['plans'], plans):
        v = got['violations']
        assert got['status'] == want['status'] == 'SOLVED'
        assert got['t_min'] == pytest.approx(want['t_min'], abs=1e-9)
        assert got['iterations'] == want['iterations']
        assert got['solve_wall_time_s'] == pytest.approx(want['solve_wall_time_s'], rel=1e-8)
        assert v['max_control_excess'] == pytest.approx(want['max_control_excess'], abs=1e-12)
        assert v['terminal_error'] == pytest.approx(want['terminal_error'], abs=1e-9)
        assert v['min_clearance'] == pytest.approx(want['min_clearance'], abs=1e-9)
        assert f'{got["t_min"]:.4f}' in md
    assert summary['plans'][0]['obstacles'] == [list(o) for o in OBSTACLES_1]
    assert summary['plans'][1]['obstacles'] == [list(o) for o in OBSTACLES_2]
    assert summary['plans'][1]['goal_source'] == 'solver progress'
    # the solver's plan meets the goal and the bounds, and touches the inflated circle
    assert summary['plans'][0]['violations']['terminal_error'] < 1e-6
    assert abs(summary['plans'][0]['violations']['min_clearance']) < 1e-4
    for got, want in zip(summary['executions'], executions):
        assert got['samples'] == want['samples']
        assert got['final_error'] == pytest.approx(want['final_error'], rel=1e-9)
        assert got['rms_error']['q1'] == pytest.approx(want['rms_q1'], rel=1e-9)
        assert got['rms_error']['q2'] == pytest.approx(want['rms_q2'], rel=1e-9)
        assert got['rms_error']['hand'] == pytest.approx(want['rms_hand'], rel=1e-9)
        assert got['max_effort'] == pytest.approx(want['max_effort'].tolist(), rel=1e-12)
        assert got['rms_error']['hand'] > 1e-4  # the payload mismatch shows
    statuses = [s['status'] for s in summary['solves']]
    assert statuses == ['SOLVED', 'INVALID_INPUT', 'SOLVED']
    assert 'INVALID_INPUT: goal is NaN' in md
    printed = capsys.readouterr().out
    assert 'plan 1' in printed and 'summary.md' in printed


def test_missing_topics_are_reported(tmp_path):
    writer = BagWriter(tmp_path / 'bag').create()
    writer.add_topic('/joint_states', 'sensor_msgs/msg/JointState', [])
    writer.add_topic('/chatter', 'std_msgs/msg/String', [])
    for k in range(50):
        writer.write('/joint_states', serialize_message(JointState(
            name=NAMES, position=[0.1 * k, 1.0], velocity=[0.0, 0.0])), T0 + k * 10_000_000)
        writer.write('/chatter', serialize_message(String(data='hi')), T0 + k * 10_000_000)
    writer.close()
    out = tmp_path / 'out'
    assert main([str(tmp_path / 'bag'), '--out', str(out)]) == 0
    summary = json.loads((out / 'summary.json').read_text())
    missing = ' '.join(summary['missing'])
    for topic in ('trajectory', 'progress', 'obstacles'):
        assert f'no topic {topic}' in missing
    assert 'goal_pose' not in missing  # no plan, so no goal needed
    assert summary['plans'] == [] and summary['executions'] == []
    assert summary['plots']['states']['file'] == 'states.png'
    for name in ('controls', 'path', 'convergence', 'tracking_error'):
        assert summary['plots'][name]['file'] is None
        assert summary['plots'][name]['reason']
    md = (out / 'summary.md').read_text()
    assert 'missing: no topic trajectory' in md


@pytest.mark.slow
def test_truncated_recording_still_reports(run_bag, tmp_path, capsys):
    data = (run_bag / 'run_0.mcap').read_bytes()
    with open(run_bag / 'run_0.mcap', 'rb') as stream:
        chunks = sorted(make_reader(stream).get_summary().chunk_indexes,
                        key=lambda c: c.chunk_start_offset)
    last = chunks[-1]  # cut inside the last chunk: the end of plan 2's execution is lost
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(data[:last.chunk_start_offset + last.chunk_length // 2])
    assert main([str(cut)]) == 1
    err = capsys.readouterr().err
    assert 'cut off' in err
    summary = json.loads((tmp_path / 'cut_analysis' / 'summary.json').read_text())
    assert summary['damaged'] is True
    assert len(summary['plans']) == 2 and len(summary['executions']) == 2
    full = sum(1 for _ in Recording(run_bag).messages(['/joint_states']))
    assert sum(e['samples'] for e in summary['executions']) < full - 100
    assert any('cut off' in w for w in summary['warnings'])


def test_foreign_and_missing_recordings(tmp_path, capsys):
    assert main([str(tmp_path / 'nothing')]) == 2
    assert 'no such file or directory' in capsys.readouterr().err
    text = tmp_path / 'notes.mcap'
    text.write_text('not a recording\n')
    assert main([str(text)]) == 2
    assert 'not an MCAP file' in capsys.readouterr().err
    # an MCAP of JSON messages (e.g. from Foxglove): readable, but nothing ROS 2 in it
    foreign = tmp_path / 'json.mcap'
    with open(foreign, 'wb') as stream:
        writer = Writer(stream)
        writer.start(profile='', library='test')
        schema = writer.register_schema('Pose', 'jsonschema', b'{"type": "object"}')
        channel = writer.register_channel('/trajectory', 'json', schema)
        for k in range(3):
            writer.add_message(channel, T0 + k, json.dumps({'x': k}).encode(), T0 + k)
        writer.finish()
    assert main([str(foreign), '--out', str(tmp_path / 'o')]) == 2
    err = capsys.readouterr().err
    assert "message encoding 'json' is not ROS 2 CDR" in err
    assert 'no toc_ros data to analyse' in err and '/trajectory' in err
    assert not (tmp_path / 'o').exists()
    assert main(['--bogus']) == 2


def test_reader_on_a_zstd_mcap_as_ros2_bag_record_writes_it(tmp_path):
    """Bare .mcap, zstd chunks, rosbag2 channel metadata; then the same file cut short."""
    path = tmp_path / 'rosbag2.mcap'
    qos = ('- history: unknown\n  depth: 0\n  reliability: reliable\n'
           '  durability: transient_local\n')
    with open(path, 'wb') as stream:
        writer = Writer(stream, chunk_size=2000, compression=CompressionType.ZSTD)
        writer.start(profile='ros2', library='libmcap 1.4.0')
        schema = writer.register_schema('std_msgs/msg/String', 'ros2msg', b'string data')
        channel = writer.register_channel('/chatter', 'cdr', schema, {
            'offered_qos_profiles': qos, 'topic_type_hash': ''})
        sent = [serialize_message(String(data=f'message {k} ' + 'z' * (k % 40)))
                for k in range(200)]
        for k, data in enumerate(sent):
            writer.add_message(channel, T0 + k * 1000, data, T0 + k * 1000, k)
        writer.finish()
    warnings = []
    recording = Recording(path, warnings.append)
    assert recording.topics['/chatter'].qos_profiles[0]['durability'] == 'transient_local'
    got = [raw.data for raw in recording.messages()]
    assert got == sent and warnings == [] and not recording.damaged
    recording.close()
    data = path.read_bytes()
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(data[:len(data) // 2])
    with Recording(cut, warnings.append) as recording:
        got = [raw.data for raw in recording.messages()]
        assert recording.damaged
    assert 0 < len(got) < len(sent) and got == sent[:len(got)]
    assert len(warnings) == 1 and 'cut off' in warnings[0]
