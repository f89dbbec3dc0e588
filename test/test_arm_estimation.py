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
A payload on a URDF arm (core/arms/payload.py) and its online estimate (replan.estimate).

The plan model with a payload is checked against MuJoCo (plant_node's engine, an independent
implementation) carrying the same point mass; the estimator runs on joint states simulated by
MuJoCo, sampled at 100 Hz with the applied efforts, as plant_node publishes them.
"""

import math

import numpy as np
import pytest
from test_arm_node_modules import checked, config, flat
from test_mujoco_arm import ARMS, ROBOTS
from toc_ros.arm_model import build_arm
from toc_ros.core.arms import ArmError
from toc_ros.core.arms.payload import with_payload
from toc_ros.core.estimation import MIN_PAIRS, ParameterEstimator
from toc_ros.core.problem import ProblemError

pytestmark = pytest.mark.skipif(ROBOTS is None, reason='example-robot-data is not installed')
mujoco_arm = pytest.importorskip('toc_ros.plant.mujoco_arm')


def _urdf(name):
    import os
    with open(os.path.join(ROBOTS, ARMS[name][0])) as stream:
        return stream.read()


def _plan_model(name, payload=0.0):
    _, joints, _ = ARMS[name]
    return build_arm(name, '', joints, {}, {}, None, '', payload)


@pytest.mark.parametrize('name', sorted(ARMS))
def test_payload_model_equals_mujoco_with_the_same_point_mass(name):
    _, joints, tip = ARMS[name]
    mass = 1.7
    model = _plan_model(name).with_parameters({'payload_mass': mass})
    assert model.payload_link == tip and model.arm.source['payload_mass'] == mass
    plant = mujoco_arm.MujocoArm(_urdf(name), joints, tip_link=tip, payload_mass_offset=mass)
    bare = mujoco_arm.MujocoArm(_urdf(name), joints, tip_link=tip)
    rng = np.random.default_rng(4)
    arm = model.arm
    worst = effect = 0.0
    for _ in range(100):
        q = rng.uniform(arm.lower, arm.upper)
        v = rng.uniform(-arm.velocity, arm.velocity)
        tau = rng.uniform(-arm.effort, arm.effort)
        plant.set_state(q, v)
        bare.set_state(q, v)
        expected = plant.acceleration(tau)
        got = arm.forward_dynamics(q, v, tau)
        worst = max(worst, np.max(np.abs(got - expected)) / max(1.0, np.max(np.abs(expected))))
        effect = max(effect, np.max(np.abs(bare.acceleration(tau) - expected)))
    assert worst < 1e-8, worst
    assert effect > 0.1         # the payload changes the accelerations: the check has teeth


def test_bad_payloads_are_refused_with_the_reason():
    arm = _plan_model('panda').arm
    for mass in (-1.0, math.nan, math.inf):
        with pytest.raises(ArmError, match='payload mass must be finite and >= 0'):
            with_payload(arm, mass, 'panda_hand')
    with pytest.raises(ArmError, match='unknown link'):
        with_payload(arm, 1.0, 'no_such_link')
    with pytest.raises(ProblemError, match='robot.payload_mass'):
        _plan_model('panda', -0.5)
    with pytest.raises(ProblemError, match='only payload_mass'):
        _plan_model('panda').with_parameters({'hand_mass': 2.0})
    assert with_payload(arm, 0.0, 'panda_hand') is arm


def _excite(plant, seconds, rng):
    """Yield (t, q, dq, applied effort) at 100 Hz of the plant under PD to moving targets."""
    arm = _plan_model('panda').arm
    q0, _ = plant.state()
    targets = [q0 + rng.uniform(-0.4, 0.4, q0.size) for _ in range(int(seconds / 0.5) + 1)]
    kp = np.array([300.0, 300.0, 300.0, 300.0, 100.0, 60.0, 20.0])
    kd = np.array([20.0, 20.0, 20.0, 20.0, 4.0, 3.0, 1.0])
    for k in range(int(round(seconds / 1e-3))):
        q, dq = plant.state()
        target = np.clip(targets[k // 500], arm.lower, arm.upper)
        # PD at the 1 kHz steps (as plant_node) around the plant's own holding torque.
        applied = plant.step(plant.holding_torque(q) + kp * (target - q) - kd * dq)
        if k % 10 == 0:
            yield k * 1e-3, q, dq, applied


@pytest.mark.parametrize('true_mass, planned', [(1.5, 0.0), (0.0, 0.0), (1.2, 1.0)])
def test_estimator_finds_the_payload_of_a_mujoco_plant(true_mass, planned):
    _, joints, tip = ARMS['panda']
    plant = mujoco_arm.MujocoArm(_urdf('panda'), joints, tip_link=tip,
                                 payload_mass_offset=true_mass)
    plant.set_state(np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785]), np.zeros(7))
    model = _plan_model('panda', planned)
    estimator = ParameterEstimator(model, ['payload_mass'], 2.0)
    samples = list(_excite(plant, 3.0, np.random.default_rng(5)))
    for t, q, dq, u in samples[:5]:
        estimator.add(t, q, dq, u)
    assert estimator.estimate() is None and 'sample pairs' in estimator.status
    for t, q, dq, u in samples[5:]:
        estimator.add(t, q, dq, u)
    values = estimator.estimate()
    assert values is not None, estimator.status
    assert estimator._pairs >= MIN_PAIRS
    assert abs(values['payload_mass'] - true_mass) < 0.03 * max(true_mass, 1.0), values
    estimated = estimator.model(values)
    if values['payload_mass'] >= 0.0:
        assert estimated.payload_mass == values['payload_mass']
        assert estimated.robot.arm.source['payload_mass'] == values['payload_mass'] or \
            values['payload_mass'] == 0.0
    else:       # a plant without payload may fit slightly below 0: refused with the reason
        assert estimated is None and 'payload mass must be finite and >= 0' in estimator.status
    # A negative value is refused with the reason, never raised into the caller (a cycle).
    assert estimator.model({'payload_mass': -0.01}) is None
    assert 'estimate refused' in estimator.status and '>= 0' in estimator.status


def test_solver_node_settings_plan_with_the_payload_and_estimate_it():
    built = config(replan__estimate=['payload_mass'], robot__payload_mass=0.8)
    assert built.model.payload_mass == 0.8 and built.model.payload_link == 'panda_hand'
    assert built.problem.model.arm.source['payload_mass'] == 0.8
    assert config().model.payload_mass == 0.0
    errors, _ = checked(flat(replan__estimate=['payload_mass', 'hand_mass']))
    assert any('payload_mass only' in e and 'hand_mass' in e for e in errors), errors
    errors, _ = checked(flat(replan__estimate=['payload_mass', 'payload_mass']))
    assert any('replan.estimate' in e and 'distinct' in e for e in errors), errors
    errors, _ = checked(flat(robot__payload_mass=-1.0))
    assert any('robot.payload_mass' in e for e in errors), errors


def test_recordings_name_the_payload_planned_with():
    from toc_ros import progress as schema
    from toc_ros.analysis.recorded_arm import arm_parameters
    from toc_ros.arm_record import ArmRecord

    built = config(robot__payload_mass=0.8)
    msg = schema.progress_msg('/solver_node', schema.ProgressReport(
        message='ready', event=schema.EVENT_READY, **built.model_keys()))
    record = ArmRecord.from_report(schema.progress_from_msg(msg))
    assert record.payload_mass == 0.8
    assert ArmRecord.from_report(schema.ProgressReport(**config().model_keys())).payload_mass == 0

    class Run:
        params = {}
    params = arm_parameters(Run(), 'panda', record)
    assert params['robot.payload_mass'] == 0.8


def test_an_estimate_the_arm_cannot_make_is_a_reason_not_a_crash():
    from toc_ros.core.online_estimate import OnlineEstimate
    online = OnlineEstimate()
    model = _plan_model('panda')
    state = np.zeros(14)
    online.add(model, ['payload_mass', 'payload_mass'], 2.0, 0.0, state, np.zeros(7))
    built, why = online.model(model, 0.0)
    assert built is None and 'distinct' in why, why
    online.add(model, ['payload_mass'], 2.0, 0.01, state, np.zeros(7))
    assert online.model(model, 0.0) == (None, '0 of 20 sample pairs')


def test_a_payload_the_arm_cannot_hold_is_named_when_the_solve_fails():
    from toc_ros.core import Problem, solve, Status
    from toc_ros.core.arms import default_spheres, load_arm
    from toc_ros.core.arms.arm_solve import ArmRobot
    from toc_ros.core.arms.validate import check_holdable
    arm = with_payload(load_arm('panda'), 50.0, 'panda_hand')
    goal = (0.5, -0.3, 0.0, -2.0, 0.0, 1.8, 0.785)
    with pytest.raises(ArmError, match='panda_joint4 needs 262.9 N m against gravity'):
        check_holdable(arm, goal)
    check_holdable(load_arm('panda'), goal)     # without the payload it holds
    result = solve(Problem(model=ArmRobot(arm, default_spheres(arm)),
                           x0=(0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785), x_goal=goal,
                           n_intervals=40))
    assert result.status is not Status.SOLVED
    assert 'cannot hold it at rest (with a payload of 50 kg)' in result.message, result.message
