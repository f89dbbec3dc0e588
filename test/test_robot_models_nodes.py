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
Robot models in the nodes (issue 13), with real node processes on a private domain.

planar_2r end to end (toc-demo --model planar_2r: goal_pose -> trajectory -> plant reaches the
goal -> recording -> toc-analyze), and bad models refused while solver_node keeps serving.
"""

import json
import time

from diagnostic_msgs.msg import DiagnosticStatus
from node_harness import (handshake, NodeProcess, pose, REPO, report, RosClient,
                          SOLVE_TIMEOUT, TEST_PARAMS)
import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from sensor_msgs.msg import JointState
from test_demo import run_demo
from toc_ros.analysis import cli as analyze
from toc_ros.core import Status
from toc_ros.core.models import Planar2R
from toc_ros.core.obstacles import model_clearance
from trajectory_msgs.msg import JointTrajectory
from visualization_msgs.msg import Marker, MarkerArray

pytestmark = pytest.mark.slow

PLANAR_CONFIG = REPO / 'config' / 'toc_ros_planar_2r.yaml'
PLANAR_JOINTS = ['shoulder_joint', 'elbow_joint']


@pytest.fixture(scope='module')
def planar_demo(tmp_path_factory):
    output = tmp_path_factory.mktemp('planar_demo') / 'run'
    proc = run_demo('--model', 'planar_2r', '--output', str(output), '--timeout', '300',
                    timeout=400.0)
    assert proc.returncode == 0, f'demo failed:\n{proc.stdout}\n{proc.stderr}'
    with open(output / 'summary.json') as stream:
        summary = json.load(stream)
    return output, summary


def test_planar_2r_demo_reaches_both_goals(planar_demo):
    _, summary = planar_demo
    assert summary['success'] and summary['model'] == 'planar_2r'
    assert summary['joint_names'] == PLANAR_JOINTS
    for plan in summary['plans']:
        assert plan['status'] == Status.SOLVED.value and plan['reached'], plan
        assert max(abs(e) for e in plan['final_error']) < 1e-3


def test_planar_2r_recording_has_the_model_links_and_joint_names(planar_demo):
    output, _ = planar_demo
    model = Planar2R()
    messages = {}
    with AnyReader([output]) as reader:
        for connection, _, raw in reader.messages():
            messages.setdefault(connection.topic, []).append(
                reader.deserialize(raw, connection.msgtype))
    trajectories = [t for t in messages['/trajectory'] if t.points]
    assert len(trajectories) >= 2       # each goal's plan, then its replan cycles' plans
    for trajectory in trajectories:
        assert list(trajectory.joint_names) == PLANAR_JOINTS
        end = trajectory.points[-1]
        assert len(end.positions) == len(end.velocities) == len(end.effort) == 2
    arms = [m for array in messages['/markers'] for m in array.markers if m.ns == 'arm']
    assert arms
    for arm in arms:      # base, elbow, hand: every link of the chain
        assert arm.type == Marker.LINE_STRIP and len(arm.points) == 3
        hand = np.array([arm.points[2].x, arm.points[2].y])
        elbow = np.array([arm.points[1].x, arm.points[1].y])
        assert abs(np.hypot(*elbow) - model.params.l1) < 1e-9
        assert abs(np.hypot(*(hand - elbow)) - model.params.l2) < 1e-9
        assert arm.points[0].x == arm.points[0].y == 0.0
    results = [report(m) for m in messages['/solver_node/progress'] if report(m).final]
    assert results and all(r.robot_model == 'planar_2r' for r in results)


def test_planar_2r_analysis_uses_the_recorded_model(planar_demo, tmp_path):
    output, summary = planar_demo
    out = tmp_path / 'analysis'
    # No --params: the model comes from the recording (solver_node's ~/progress).
    assert analyze.main([str(output), '--out', str(out)]) == 0
    with open(out / 'summary.json') as stream:
        analysis = json.load(stream)
    robot = analysis['robot']
    assert robot['model'] == 'planar_2r' and robot['model_source'] == 'solver progress'
    assert robot['n_links'] == 2 and robot['u_max'] == [250.0, 120.0]
    # One closed-loop execution per goal (its plan and the replan cycles' plans).
    loops = analysis['closed_loop']
    assert len(loops) == 2 and len(analysis['plans']) == sum(len(x['plans']) for x in loops)
    model = Planar2R()
    firsts = [analysis['plans'][loop['plans'][0]] for loop in loops]
    for entry in analysis['plans']:
        assert entry['status'] == Status.SOLVED.value
        v = entry['violations']
        assert v['max_control_excess'] == 0.0 and v['terminal_error'] < 1e-6
    for entry, stage in zip(firsts, summary['plans']):
        assert entry['status'] == Status.SOLVED.value
        v = entry['violations']
        assert v['max_control_excess'] == 0.0 and v['terminal_error'] < 1e-6
        assert v['min_clearance'] > -1e-6, entry
        # Independently: both links of the goal pose clear the stage's circles.
        circles = np.array(stage['obstacles'], dtype=float)
        circles[:, 2] += 0.01
        goal = model.state(stage['goal_q'])
        assert np.min(model_clearance(model, goal[None, :], circles)) > 0.0
    for execution in analysis['executions']:
        assert execution['effort_within_bounds']
    # The last plan of each goal's execution ends at rest near the goal (the plant settles).
    by_plan = {e['plan']: e for e in analysis['executions']}
    for loop in loops:
        last = [by_plan[i] for i in loop['plans'] if i in by_plan][-1]
        assert last['final_error'] < 1e-2 and not last['interrupted']
    for name in ('path', 'controls', 'states', 'tracking_error'):
        assert analysis['plots'][name]['file'], analysis['plots'][name]
    assert 'Robot model: planar_2r' in (out / 'summary.md').read_text()


# -- bad models ------------------------------------------------------------------------------

BAD_FILES = {
    'unparsable.yaml': ('name: broken\njoints: [{name: j1, kind: revolute}, {name: j2, kind: '
                        'revolute}]\nparameters: {}\nu_max: [1.0, 1.0]\nlinks: [[0, 0, '
                        'cos(q1), sin(q1)]]\ndynamics: [dq1, u1 +* 2, dq2, u2]\n',
                        'unparsable.yaml'),
    'one_joint.yaml': ('name: one_joint\njoints: [{name: j1, kind: revolute}]\nparameters: '
                       '{m: 1.0}\nu_max: [1.0]\nlinks: [[0, 0, cos(q1), sin(q1)]]\n'
                       'lagrangian: {kinetic: m/2*dq1^2, potential: 0}\n',
                       'joint_names must be 1 distinct'),
}


@pytest.fixture(scope='module')
def planar_solver(tmp_path_factory):
    log_dir = tmp_path_factory.mktemp('planar_solver')
    client = RosClient()
    node = NodeProcess('solver_node', client.namespace, log_dir, TEST_PARAMS,
                       params_file=PLANAR_CONFIG)
    try:
        node.wait_for_log('ready:')
        client.collect(DiagnosticStatus, 'solver_node/progress', 100)
        client.collect(JointTrajectory, 'trajectory')
        client.collect(MarkerArray, 'markers')
        goal_joints = client.node.create_publisher(JointState, client.name('goal_joints'), 10)
        goal_pose = client.node.create_publisher(type(pose(0, 0)), client.name('goal_pose'),
                                                 10)
        for publisher in (goal_joints, goal_pose):
            client.wait_for(lambda p=publisher: p.get_subscription_count() > 0,
                            what=f'subscriber of {publisher.topic_name}')
            wrong = (JointState(name=['handshake'], position=[0.0])
                     if publisher is goal_joints else pose(1.0, 0.0, 'handshake'))
            since = time.monotonic()
            handshake(client, publisher, wrong, lambda s=since: [
                m for m in client.messages('solver_node/progress', s)
                if 'handshake' in m.message])
        yield client, node, goal_joints, goal_pose, log_dir
        assert node.stop() == 0, node.log()
    finally:
        node.stop()
        client.close()


def _final(client, since, timeout=SOLVE_TIMEOUT):
    found = []

    def done():
        found[:] = [report(m) for m in client.messages('solver_node/progress', since)
                    if report(m).final]
        return found
    client.wait_for(done, timeout=timeout, what='a final ~/progress report')
    return found[0]


@pytest.mark.parametrize('name', sorted(BAD_FILES))
def test_bad_model_file_refused_and_the_node_keeps_serving(planar_solver, tmp_path, name):
    client, node, goal_joints, _, _ = planar_solver
    text, reason = BAD_FILES[name]
    path = tmp_path / name
    path.write_text(text)
    since = time.monotonic()
    results = client.set_parameters('solver_node', {'robot.model': str(path)}, timeout=300.0)
    assert not results[0].successful and reason in results[0].reason, results[0].reason
    client.wait_for(lambda: [m for m in client.messages('solver_node/progress', since)
                             if 'refused robot model' in m.message and reason in m.message],
                    what='the refusal on ~/progress')
    assert client.get_parameters('solver_node', ['robot.model'])['robot.model'] == 'planar_2r'
    # Still serving the planar arm.
    since = time.monotonic()
    goal_joints.publish(JointState(name=PLANAR_JOINTS, position=[0.9, 0.9]))
    result = _final(client, since)
    assert result.status is Status.SOLVED, result
    assert result.robot_model == 'planar_2r'
    assert node.alive()


def test_planar_goal_pose_ik_and_unreachable_goal(planar_solver):
    client, _, _, goal_pose, _ = planar_solver
    since = time.monotonic()
    goal_pose.publish(pose(3.0, 0.0))       # beyond l1 + l2 = 1.8 m
    refused = _final(client, since, timeout=30.0)
    assert refused.status is Status.INVALID_INPUT and 'out of reach' in refused.message
    model = Planar2R()
    hand = model.hand_position(np.array([0.9, 0.9]))
    since = time.monotonic()
    seen = client.count('trajectory')
    goal_pose.publish(pose(*hand))
    result = _final(client, since)
    assert result.status is Status.SOLVED, result
    # robot.ik_branch elbow_down (the scenario file): q2 >= 0, the goal (0.9, 0.9) itself.
    assert np.allclose(result.goal, [0.9, 0.0, 0.9, 0.0], atol=1e-6), result.goal
    client.wait_for(lambda: client.count('trajectory') > seen, what='the trajectory')
    trajectory = client.messages('trajectory')[-1]
    assert list(trajectory.joint_names) == PLANAR_JOINTS
    assert np.allclose(trajectory.points[-1].positions, [0.9, 0.9], atol=1e-6)


def test_goal_pose_with_a_model_file_uses_its_ik_section(planar_solver):
    client, _, _, goal_pose, _ = planar_solver
    file_model = str(REPO / 'config' / 'models' / 'planar_2r.yaml')
    results = client.set_parameters('solver_node', {'robot.model': file_model}, timeout=300.0)
    assert results[0].successful, results[0].reason
    try:
        since = time.monotonic()
        goal_pose.publish(pose(3.0, 0.0))
        refused = _final(client, since, timeout=30.0)
        assert refused.status is Status.INVALID_INPUT, refused
        assert "reach condition 'x^2 + y^2 <= (l1 + l2)^2' fails" in refused.message
        hand = Planar2R().hand_position(np.array([0.9, 0.9]))
        since = time.monotonic()
        goal_pose.publish(pose(*hand))       # robot.ik_branch elbow_down: q2 >= 0
        result = _final(client, since)
        assert result.status is Status.SOLVED and result.robot_model == file_model, result
        assert np.allclose(result.goal, [0.9, 0.0, 0.9, 0.0], atol=1e-9), result.goal
        assert client.set_parameters('solver_node', {'robot.ik_branch': 'sideways'})[0] \
            .successful
        since = time.monotonic()
        goal_pose.publish(pose(*hand))
        refused = _final(client, since, timeout=30.0)
        assert refused.status is Status.INVALID_INPUT and 'ambiguous' in refused.message
    finally:
        results = client.set_parameters('solver_node', {'robot.model': 'planar_2r',
                                                        'robot.ik_branch': 'elbow_down'})
        assert all(r.successful for r in results), results


def test_joint_names_must_match_the_model(planar_solver):
    client = planar_solver[0]
    results = client.set_parameters('solver_node', {'joint_names': ['a', 'b', 'c']})
    assert not results[0].successful
    assert "2 distinct non-empty names (one per joint of robot model 'planar_2r')" in \
        results[0].reason


def test_solver_node_with_a_bad_model_exits_2(tmp_path):
    client = RosClient()
    node = NodeProcess('solver_node', client.namespace, tmp_path,
                       {**TEST_PARAMS, 'robot.model': 'no_such_model'}, params_file=PLANAR_CONFIG)
    try:
        deadline = time.monotonic() + 120.0
        while node.alive() and time.monotonic() < deadline:
            time.sleep(0.2)
        assert node.stop() == 2, node.log()
        assert "unknown model 'no_such_model'" in node.log()
    finally:
        node.stop()
        client.close()


# -- plant_node's model (no process) ---------------------------------------------------------

def _plant_params(**values):
    from toc_ros.nodes import parameters
    params = {name: parameters.default(name) for name in parameters.PLANT_NODE_NAMES}
    params.update({'robot.model': 'planar_2r', 'joint_names': PLANAR_JOINTS,
                   'kp': [2000.0, 800.0], 'kd': [300.0, 100.0]})
    params.update(values)
    return params


def test_plant_mismatch_knobs_map_onto_planar_2r():
    from toc_ros.nodes import plant_node
    model = plant_node.plant_model(_plant_params(payload_mass_offset=1.5, inertia_scale=2.0))
    assert isinstance(model, Planar2R)
    assert (model.params.m_p, model.params.m1, model.params.m2) == (3.5, 24.0, 16.0)
    assert plant_node.parameter_errors(_plant_params()) == []
    errors = plant_node.parameter_errors(_plant_params(payload_mass_offset=-5.0))
    assert errors and 'robot.m_p must be a finite positive' in errors[0], errors
    assert 'm_p + payload_mass_offset' in errors[0]


def test_plant_refuses_knobs_and_gain_sizes_that_do_not_fit_the_model():
    from toc_ros.nodes import plant_node
    file_model = str(REPO / 'config' / 'models' / 'planar_2r.yaml')
    assert plant_node.parameter_errors(_plant_params(**{'robot.model': file_model})) == []
    errors = plant_node.parameter_errors(_plant_params(**{'robot.model': file_model},
                                                       inertia_scale=1.2))
    assert errors and 'no meaning for robot model' in errors[0], errors
    errors = plant_node.parameter_errors(_plant_params(kp=[1.0, 2.0, 3.0]))
    assert len(errors) == 1 and errors[0].startswith('kp must have 2 entries, got 3 (one per '
                                                     'joint of planar_2r;'), errors
    assert 'config/panda.yaml' in errors[0]


def test_plant_step_is_the_models_rk4():
    """One plant step equals the model kernels' RK4 rollout over the same step."""
    from toc_ros.core.horizon import integrator_id
    model = Planar2R()
    x = model.state([0.3, 1.1], [0.5, -0.2])
    u = np.array([[40.0, -10.0]])
    states = np.empty((2, 4))
    model.kernels.rollout(x, u, 1e-3, model.packed(), integrator_id('rk4'), states)
    # Independent RK4 of the planar_2r equations (test_cli's written-out version).
    from numpy_model import planar_2r_f as f
    h = 1e-3
    k1 = f(x, u[0])
    k2 = f(x + h / 2 * k1, u[0])
    k3 = f(x + h / 2 * k2, u[0])
    k4 = f(x + h * k3, u[0])
    assert np.allclose(states[1], x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4), atol=1e-12)
