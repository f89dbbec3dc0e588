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
The plant's dynamics: the solver's robot model with the mismatch knobs, or a MuJoCo URDF arm.

``plant_model`` builds what the plant integrates from its flat parameters: the joints' model
of robot.model (the plant simulates its drives itself: actuator_lag, control_delay) with
payload_mass_offset and inertia_scale applied, or with engine mujoco a ``MujocoEngine`` of
robot_description.  ``step`` advances either by one integration step.
"""

import dataclasses

import numpy as np

from toc_ros.config import model_from_parameters
from toc_ros.core import ProblemError
from toc_ros.core.horizon import integrator_id
from toc_ros.core.models import CylindricalRobot, Planar2R

RK4 = integrator_id('rk4')
# What payload_mass_offset and inertia_scale change, per robot model.
MISMATCH = {'cylindrical': 'robot.hand_mass + payload_mass_offset, robot.inertia * '
                           'inertia_scale',
            'planar_2r': 'm_p + payload_mass_offset, m1 and m2 * inertia_scale'}


class MujocoEngine:
    """
    The plant's dynamics on MuJoCo (engine mujoco): the URDF of robot_description.

    toc_ros.plant.mujoco_arm.MujocoArm with the plant's mismatch knobs (payload_mass_offset on
    robot.tip_link, inertia_scale), stepped at 1 / integration_rate; presents what plant_node
    uses of a RobotModel (n_joints, nx, u_max = the URDF effort limits, check) and a step of
    the interleaved state [q1, dq1, q2, dq2, ...].  mujoco is imported here only.
    """

    name = 'urdf (mujoco)'

    def __init__(self, params):
        try:
            from toc_ros.plant.mujoco_arm import MujocoArm
        except ImportError as exc:
            raise ProblemError(f'engine mujoco needs the mujoco package: {exc}') from None
        if not params['robot_description']:
            raise ProblemError('engine mujoco needs the URDF in robot_description')
        self.arm = MujocoArm(
            params['robot_description'], params['joint_names'],
            tip_link=params.get('robot.tip_link') or None,
            payload_mass_offset=float(params['payload_mass_offset']),
            inertia_scale=float(params['inertia_scale']),
            timestep=1.0 / float(params['integration_rate']))
        self.n_joints = self.arm.n_joints
        self.nx = 2 * self.n_joints
        self.u_max = self.arm.effort_limits.copy()
        self._held = (None, None)       # (positions' bytes, their holding torque)

    def check(self):
        """Return the model's errors: none once MuJoCo compiled it."""
        return []

    def holding_torque(self, q):
        """Return the torques that hold the joints at positions q at rest (gravity)."""
        key = np.asarray(q, dtype=float).tobytes()
        if key != self._held[0]:
            self._held = (key, self.arm.holding_torque(np.frombuffer(key)))
        return self._held[1]

    def step(self, x, u):
        """Return the interleaved state one time step after x under torque u (clamped)."""
        q, v = self.arm.state()
        if not (np.array_equal(q, x[0::2]) and np.array_equal(v, x[1::2])):
            self.arm.set_state(x[0::2], x[1::2])
        self.arm.step(u)
        q, v = self.arm.state()
        out = np.empty(self.nx)
        out[0::2], out[1::2] = q, v
        return out


def plant_model(params):
    """
    Return the plant's RobotModel: the solver's model with the mismatch knobs applied.

    With engine mujoco: a MujocoEngine of robot_description (robot.model is not used).

    The joints' model: the plant's own actuator_lag and control_delay simulate the drives
    (robot.actuator_lag is what the planner assumes of them).  Raises ProblemError for a bad
    model, or for mismatch knobs on a model without a mapping.
    """
    if params['engine'] == 'mujoco':
        return MujocoEngine(params)
    model = model_from_parameters(params).joint_model
    offset, scale = float(params['payload_mass_offset']), float(params['inertia_scale'])
    if isinstance(model, CylindricalRobot):
        robot = model.params
        return CylindricalRobot(dataclasses.replace(
            robot, hand_mass=robot.hand_mass + offset, inertia=robot.inertia * scale))
    if isinstance(model, Planar2R):
        data = model.params
        return Planar2R(dataclasses.replace(data, m_p=data.m_p + offset, m1=data.m1 * scale,
                                            m2=data.m2 * scale))
    if offset != 0.0 or scale != 1.0:
        raise ProblemError(f'payload_mass_offset and inertia_scale have no meaning for robot '
                           f'model {model.name!r} (defined for cylindrical and planar_2r): '
                           'set them to 0 and 1, or give the plant other robot.model_parameters')
    return model


class Stepper:
    """One integration step of dt [s] of a plant model: RK4 of its kernels, or MuJoCo's."""

    def __init__(self, model, dt):
        self.model = model
        self.dt = float(dt)
        self._mujoco = isinstance(model, MujocoEngine)
        self._p = None if self._mujoco else model.packed()
        self._states = np.empty((2, model.nx))

    def __call__(self, x, u):
        """Return the state one step after x under the applied control u."""
        if self._mujoco:
            return self.model.step(x, np.asarray(u, dtype=float))
        self.model.kernels.rollout(np.ascontiguousarray(x, dtype=float),
                                   np.ascontiguousarray(u, dtype=float).reshape(1, -1),
                                   self.dt, self._p, RK4, self._states)
        return self._states[1].copy()
