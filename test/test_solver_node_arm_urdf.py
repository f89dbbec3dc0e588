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
solver_node with robot.model urdf: the URDF from the robot_description parameter or topic.

The URDF is the Panda's from example-robot-data, given as text (as robot_state_publisher
has it) with the shipped sphere file; plans are re-checked by test/arm_oracle.py.
"""

import hashlib
import re
import time

from arm_oracle import ArmOracle, find_panda_urdf, PANDA_JOINTS, PANDA_SPHERES
from diagnostic_msgs.msg import DiagnosticStatus
from node_harness import handshake, LATCHED, NodeProcess, reports, RosClient
import numpy as np
import pytest
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import Trigger
from toc_ros.core import Status
from toc_ros.progress import EVENT_READY, EVENT_REFUSED
from trajectory_msgs.msg import JointTrajectory
import yaml

pytestmark = pytest.mark.slow

Q0 = [0.0, -0.5, 0.0, -2.0, 0.0, 1.6, 0.8]
# Joint 1 over 1.5 rad (its URDF limits: +-2.8973 rad).
Q_TURN = [1.5, -0.5, 0.0, -2.0, 0.0, 1.6, 0.8]
BASE = {'robot.model': 'urdf', 'robot.collision_spheres': str(PANDA_SPHERES),
        'joint_names': PANDA_JOINTS, 'initial_state': Q0, 'solver.N': 40,
        'solver.timeout': 300.0, 'replan.rate': 0.0}
TIMEOUT = 300.0
# State as robot_state_publisher publishes robot_description.
DESCRIPTION_QOS = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                             reliability=ReliabilityPolicy.RELIABLE)


def with_joint1_upper(urdf, upper):
    """Return the URDF text with panda_joint1's upper position limit replaced."""
    head, joint, tail = urdf.partition('<joint name="panda_joint1"')
    body, end, rest = tail.partition('</joint>')
    body, count = re.subn(r'\supper="[^"]*"', f' upper="{upper}"', body)
    assert count == 1
    return head + joint + body + end + rest


def params_file(path, values):
    """Write a ROS 2 parameter file (nested names) for every node."""
    tree = {}
    for name, value in values.items():
        *groups, key = name.split('.')
        node = tree
        for group in groups:
            node = node.setdefault(group, {})
        node[key] = value
    path.write_text(yaml.safe_dump({'/**': {'ros__parameters': tree}}))
    return path


class Solver:
    """A solver_node process with its client, goal publisher and ~/ready client."""

    def __init__(self, log_dir, values=None, overrides=None):
        """values: the parameter file's; None: the scenario file with -p overrides."""
        self.client = RosClient()
        if values is None:
            self.node = NodeProcess('solver_node', self.client.namespace, log_dir, overrides)
        else:
            self.node = NodeProcess('solver_node', self.client.namespace, log_dir,
                                    params_file=params_file(log_dir / 'arm.yaml', values))
        self.client.collect(DiagnosticStatus, 'solver_node/progress', 100)
        self.client.collect(JointTrajectory, 'trajectory', LATCHED)
        self.goal_joints = self.client.node.create_publisher(
            JointState, self.client.name('goal_joints'), 10)
        self.description = self.client.node.create_publisher(
            String, self.client.name('robot_description'), DESCRIPTION_QOS)
        self.ready = self.client.node.create_client(Trigger,
                                                    self.client.name('solver_node/ready'))

    def handshake(self, text="'handshake'"):
        """Publish a refused goal until its refusal (with text) proves the topic matched."""
        handshake(self.client, self.goal_joints, JointState(name=['handshake'], position=[0.0]),
                  lambda: [r for r in reports(self, 0.0)
                           if r.event == EVENT_REFUSED and text in r.message])

    def ask_ready(self):
        return self.client.call(self.ready, Trigger.Request())

    def wait_ready(self):
        self.client.wait_for(lambda: self.ask_ready().success, TIMEOUT, '~/ready')

    def plan(self, goal):
        """Publish a joint goal; return (final report, its trajectory or None)."""
        since = time.monotonic()
        self.goal_joints.publish(JointState(name=PANDA_JOINTS, position=goal))
        result = self.client.wait_for(lambda: [
            r for r in reports(self, since) if r.final and r.goal_source == 'goal_joints'],
            TIMEOUT, 'the result')[0]
        if result.status is not Status.SOLVED:
            return result, None
        msg = self.client.wait_for(lambda: [
            m for m in self.client.messages('trajectory', since) if m.points
            and np.max(np.abs(np.array(m.points[-1].positions) - goal)) < 1e-4],
            30.0, 'the plan')[0]
        return result, msg

    def close(self):
        try:
            assert self.node.stop() == 0, self.node.log()
        finally:
            self.node.stop()
            self.client.close()


def max_joint1(msg):
    return max(p.positions[0] for p in msg.points)


def refused(solver, goal, text):
    """Publish a joint goal that must be refused; return the refusal's message."""
    since = time.monotonic()
    solver.goal_joints.publish(JointState(name=PANDA_JOINTS, position=goal))
    return solver.client.wait_for(lambda: [
        r.message for r in reports(solver, since) if r.event == EVENT_REFUSED
        and text in r.message], 30.0, f'a refusal with {text!r}')[0]


def test_robot_description_parameter_and_limit_override(tmp_path):
    urdf = find_panda_urdf().read_text()
    solver = Solver(tmp_path, dict(BASE, robot_description=urdf,
                                   **{'robot.joint_limits': ['panda_joint1.upper=1.6'],
                                      'robot.tip_link': 'panda_hand'}))
    try:
        solver.node.wait_for_log('ready:')
        solver.handshake()
        oracle = ArmOracle(urdf)
        oracle.upper[0] = 1.6           # the override, applied by the test to the URDF's
        result, msg = solver.plan(Q_TURN)
        assert result.status is Status.SOLVED and result.robot_model == 'urdf', result.message
        oracle.check(msg, Q0, Q_TURN)
        # The result names the arm (toc-analyze rebuilds it); the texts are the ready
        # report's only.
        assert result.arm_joints == tuple(PANDA_JOINTS)
        assert result.arm_joint_limits == ('panda_joint1.upper=1.6',)
        assert (result.arm_urdf_source, result.arm_urdf_sha256) == (
            'parameter', hashlib.sha256(urdf.strip().encode()).hexdigest())
        assert result.arm_spheres_source == str(PANDA_SPHERES)
        assert result.arm_tip_link == 'panda_hand' and not result.arm_urdf
        assert not result.arm_spheres
        far = list(Q_TURN)
        far[0] = 2.0        # within the URDF's limits, not within the override
        assert 'outside its limits [-2.8973, 1.6]' in refused(solver, far, 'panda_joint1')
        # The parameter wins over the topic: a URDF published there is not used.
        solver.description.publish(String(data=with_joint1_upper(urdf, 1.0)))
        time.sleep(1.0)
        result, msg = solver.plan(Q_TURN)
        assert result.status is Status.SOLVED, result.message
        oracle.check(msg, Q0, Q_TURN)
    finally:
        solver.close()


def test_robot_description_topic_loads_and_reloads(tmp_path):
    urdf = find_panda_urdf().read_text()
    solver = Solver(tmp_path, BASE)
    try:
        answer = solver.client.wait_for(lambda: solver.ask_ready(), 120.0, '~/ready')
        assert not answer.success and 'no URDF yet' in answer.message, answer.message
        solver.handshake('no URDF yet')     # goals are refused until a URDF arrives
        solver.description.publish(String(data=urdf))     # latched: as robot_state_publisher
        solver.wait_ready()
        result, msg = solver.plan(Q_TURN)
        assert result.status is Status.SOLVED, result.message
        ArmOracle(urdf).check(msg, Q0, Q_TURN)
        assert max_joint1(msg) > 1.0 - 1e-9
        # A new description reloads the model (a new 'ready'); goals obey its limits.
        narrow = with_joint1_upper(urdf, 1.0)
        since = time.monotonic()
        solver.description.publish(String(data=narrow))
        ready = solver.client.wait_for(lambda: [r for r in reports(solver, since)
                                                if r.event == EVENT_READY], TIMEOUT,
                                       'the reload')[0]
        # The ready report names the new URDF by its sha256 (the text is the topic's) and
        # carries the sphere file's text.
        assert (ready.arm_urdf_source, ready.arm_urdf) == ('topic', '')
        assert ready.arm_urdf_sha256 == hashlib.sha256(narrow.strip().encode()).hexdigest()
        assert ready.arm_spheres == PANDA_SPHERES.read_text()
        assert 'outside its limits [-2.8973, 1]' in refused(solver, Q_TURN, 'panda_joint1')
        inside = list(Q_TURN)
        inside[0] = 0.9
        result, msg = solver.plan(inside)
        assert result.status is Status.SOLVED, result.message
        ArmOracle(narrow).check(msg, Q0, inside)
        # A URDF that does not parse is refused with the reason; the model stays.
        since = time.monotonic()
        solver.description.publish(String(data='<robot name="broken"><link name='))
        report = solver.client.wait_for(lambda: [
            r for r in reports(solver, since) if r.event == EVENT_REFUSED], 30.0,
            'the refusal')[0]
        assert report.message.startswith('robot_description:') and 'parse' in report.message
        assert solver.ask_ready().success
    finally:
        solver.close()


def test_switch_between_a_planar_model_and_an_arm_at_run_time(tmp_path):
    from rcl_interfaces.srv import SetParametersAtomically
    from rclpy.parameter import Parameter
    solver = Solver(tmp_path, overrides={'solver.N': 40, 'solver.timeout': 300.0,
                                         'replan.rate': 0.0})
    client, node = solver.client, solver.node
    setter = client.node.create_client(SetParametersAtomically,
                                       client.name('solver_node/set_parameters_atomically'))

    def switch(values):
        since = time.monotonic()
        request = SetParametersAtomically.Request(parameters=[
            Parameter(k, value=v).to_parameter_msg() for k, v in values.items()])
        result = client.call(setter, request).result
        assert result.successful, result.reason
        client.wait_for(lambda: [r for r in reports(solver, since) if r.event == EVENT_READY],
                        TIMEOUT, 'the new model ready')

    try:
        node.wait_for_log('ready:')
        solver.handshake()
        switch({'robot.model': 'panda', 'joint_names': PANDA_JOINTS, 'initial_state': Q0})
        result, msg = solver.plan(Q_TURN)
        assert result.status is Status.SOLVED and result.robot_model == 'panda', result.message
        ArmOracle(find_panda_urdf().read_text()).check(msg, Q0, Q_TURN)
        switch({'robot.model': 'cylindrical',
                'joint_names': ['rotation_joint', 'extension_joint'],
                'initial_state': [0.2, 0.0, 1.0, 0.0]})
        since = time.monotonic()
        solver.goal_joints.publish(JointState(name=['rotation_joint', 'extension_joint'],
                                              position=[-0.5, 1.0]))
        result = client.wait_for(lambda: [r for r in reports(solver, since) if r.final],
                                 TIMEOUT, 'the planar result')[0]
        assert result.status is Status.SOLVED and result.robot_model == 'cylindrical', result
        planar = client.wait_for(lambda: [m for m in client.messages('trajectory', since)
                                          if m.points], 30.0, 'the planar plan')[0]
        assert list(planar.joint_names) == ['rotation_joint', 'extension_joint']
        assert np.allclose(planar.points[-1].positions, [-0.5, 1.0], atol=1e-6)
    finally:
        solver.close()
