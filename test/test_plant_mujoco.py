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

"""plant_node with engine mujoco on the Panda URDF, checked against Pinocchio's gravity."""

import time

from node_harness import CONFIG, NodeProcess, RosClient
import numpy as np
import pytest
from sensor_msgs.msg import JointState
# Skips this module where pinocchio or mujoco is missing (importorskip there).
from test_mujoco_arm import _reduced_pinocchio, _urdf, PANDA_ARM, pin, ROBOTS
import yaml

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(ROBOTS is None, reason='example-robot-data is not installed')]
Q0 = [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785]
KP = [600.0, 600.0, 600.0, 600.0, 250.0, 150.0, 50.0]
KD = [20.0, 20.0, 20.0, 20.0, 8.0, 6.0, 2.0]     # config/panda.yaml's


def _params_file(tmp_path, **overrides):
    with open(CONFIG) as f:
        config = yaml.safe_load(f)
    params = config['/**']['ros__parameters']
    params.update({'engine': 'mujoco', 'robot_description': _urdf('panda'),
                   'joint_names': PANDA_ARM,
                   'initial_state': [v for q in Q0 for v in (q, 0.0)], 'kp': KP, 'kd': KD})
    params.update(overrides)
    path = tmp_path / 'panda_plant.yaml'
    path.write_text(yaml.safe_dump(config))
    return path


def test_holding_under_gravity_rests_on_pinocchio_gravity_without_sag(tmp_path):
    client = RosClient()
    node = NodeProcess('plant_node', client.namespace, tmp_path, params_file=_params_file(
        tmp_path))
    try:
        node.wait_for_log('ready:', timeout=120.0)
        client.collect(JointState, 'joint_states', keep=50)
        client.wait_for(lambda: client.count('joint_states') > 0, what='joint_states')
        time.sleep(3.0)         # the PD settles (slowest: the wrist, kd/kp = 0.1 s)
        msg = client.messages('joint_states')[-1]
        assert list(msg.name) == PANDA_ARM
        q = np.array(msg.position)
        effort = np.array(msg.effort)
        model = _reduced_pinocchio(_urdf('panda'), PANDA_ARM)
        gravity = pin.computeGeneralizedGravity(model, model.createData(), q)
        # Holding, the plant commands the holding torque (as an arm's gravity compensation):
        # it rests at Q0 itself, not sagged by g / kp, on Pinocchio's gravity torque.
        np.testing.assert_allclose(np.array(msg.velocity), 0.0, atol=1e-4)
        np.testing.assert_allclose(q, Q0, atol=1e-6)
        np.testing.assert_allclose(effort, gravity, rtol=1e-3, atol=1e-3)
        assert np.max(np.abs(gravity)) > 5.0, 'the pose loads the shoulder'
    finally:
        node.stop()
        client.close()


def test_mujoco_without_robot_description_is_refused(tmp_path):
    client = RosClient()
    node = NodeProcess('plant_node', client.namespace, tmp_path,
                       params_file=_params_file(tmp_path, robot_description=''))
    try:
        deadline = time.monotonic() + 60.0
        while node.alive() and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not node.alive() and node.process.returncode == 2, node.tail()
        assert 'engine mujoco needs the URDF in robot_description' in node.log()
    finally:
        node.stop()
        client.close()


def test_payload_needs_a_tip_link(tmp_path):
    client = RosClient()
    node = NodeProcess('plant_node', client.namespace, tmp_path,
                       params_file=_params_file(tmp_path, payload_mass_offset=1.0))
    try:
        deadline = time.monotonic() + 60.0
        while node.alive() and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not node.alive() and node.process.returncode == 2, node.tail()
        assert 'needs tip_link' in node.log()
    finally:
        node.stop()
        client.close()
