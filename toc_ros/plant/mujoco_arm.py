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
A URDF arm simulated by MuJoCo: torque motors on the planned joints, the others locked.

The URDF is loaded by MuJoCo's own URDF importer (``mujoco.MjSpec.from_string``) after its
``<visual>`` and ``<collision>`` elements are removed: the dynamics need the links' inertials
only, and the meshes are not available to the plant.  What the model keeps, and why:

- *Locked joints* (every joint not in ``joint_names``) are removed from the model: the child
  body is fixed to its parent at the joint's locked position (``locked_positions``, default 0),
  exactly what ``pinocchio.buildReducedModel`` does.  An equality constraint (or a joint whose
  qpos is reset every step) would leave the locked dof in the mass matrix and let it move
  within the constraint's softness; removing it gives the reduced dynamics exactly.  The
  ``<mimic>`` equalities that MuJoCo makes of the URDF go with the joints they refer to; one
  between two planned joints is kept (a real coupling of the arm).
- *Joint ranges* stay hard limits (``joint_limits=True``): a real arm has end stops, and a
  limit constraint is inactive strictly inside the range, so it does not change the dynamics
  there.  ``joint_limits=False`` removes them.
- *Damping and friction* of the URDF (``<dynamics damping friction>``) are applied only with
  ``damping=True``: the planner's model has none, and the mismatch should be chosen, not
  inherited.  Armature is zero either way (URDF has no such field).
- *Contacts* are off: the model has no geometry.
- *Motors*: one torque motor (gear 1) per planned joint, its control clamped to the joint's
  URDF effort limit (MuJoCo's ctrlrange), so ``step(tau)`` applies ``clip(tau, -limit, limit)``.
- *Integration*: ``mjINT_RK4`` at ``timestep``: 4th order like the planner's own RK4, so the
  drift against the plan measures the model, not the integrator; without damping nothing is
  stiff enough to need the implicit integrators (``integrator='implicitfast'`` is available for
  a damped model).

Mismatch knobs: ``inertia_scale`` multiplies every link's mass and rotational inertia (the
URDF's ``<inertial>``, before loading); ``payload_mass_offset`` adds a point mass at the origin
of ``tip_link`` (a massive child body of the tip link, which MuJoCo fuses into it).
"""

import xml.etree.ElementTree as ElementTree

import mujoco
import numpy as np

INTEGRATORS = {'rk4': mujoco.mjtIntegrator.mjINT_RK4,
               'implicitfast': mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
               'implicit': mujoco.mjtIntegrator.mjINT_IMPLICIT,
               'euler': mujoco.mjtIntegrator.mjINT_EULER}
INERTIA_ATTRIBUTES = ('ixx', 'ixy', 'ixz', 'iyy', 'iyz', 'izz')
PAYLOAD_BODY = 'toc_ros_payload'
# A point mass has no rotational inertia; MuJoCo wants a positive one on a body with mass.
# It is fused into the tip link, where this is far below the link's own inertia.
POINT_MASS_INERTIA = 1e-12


class ArmModelError(ValueError):
    """The URDF or the plant's settings cannot make a simulation; the text says why."""


def dynamics_urdf(urdf_text, inertia_scale=1.0):
    """
    Return the URDF text without visual and collision elements, inertials scaled.

    inertia_scale multiplies each link's mass and inertia tensor (the centre of mass stays).
    """
    try:
        root = ElementTree.fromstring(urdf_text)
    except ElementTree.ParseError as exc:
        raise ArmModelError(f'the URDF is not valid XML: {exc}') from None
    if root.tag != 'robot':
        raise ArmModelError(f'the URDF root element is <{root.tag}>, expected <robot>')
    for link in root.iter('link'):
        for tag in ('visual', 'collision'):
            for element in link.findall(tag):
                link.remove(element)
        inertial = link.find('inertial')
        if inertial is None or inertia_scale == 1.0:
            continue
        mass = inertial.find('mass')
        if mass is not None:
            mass.set('value', repr(float(mass.get('value', '0')) * inertia_scale))
        inertia = inertial.find('inertia')
        if inertia is not None:
            for name in INERTIA_ATTRIBUTES:
                inertia.set(name, repr(float(inertia.get(name, '0')) * inertia_scale))
    return ElementTree.tostring(root, encoding='unicode')


def _lock_joint(spec, joint, position):
    """Fix the joint's body to its parent at the given joint position, and delete the joint."""
    body = joint.parent
    quat = np.array(body.quat, dtype=float)
    quat /= np.linalg.norm(quat)
    axis = np.array(joint.axis, dtype=float)
    axis /= np.linalg.norm(axis)
    anchor = np.array(joint.pos, dtype=float)
    offset = np.zeros(3)
    if joint.type == mujoco.mjtJoint.mjJNT_HINGE:
        turn = np.zeros(4)
        mujoco.mju_axisAngle2Quat(turn, axis, float(position))
        # The body rotates about the joint's anchor: its origin moves by anchor - R anchor.
        turned = np.zeros(3)
        mujoco.mju_rotVecQuat(turned, anchor, turn)
        mujoco.mju_rotVecQuat(offset, anchor - turned, quat)
        new_quat = np.zeros(4)
        mujoco.mju_mulQuat(new_quat, quat, turn)
        body.quat = new_quat
    elif joint.type == mujoco.mjtJoint.mjJNT_SLIDE:
        mujoco.mju_rotVecQuat(offset, axis * float(position), quat)
    else:
        raise ArmModelError(f'joint {joint.name!r} is neither revolute nor prismatic: it '
                            'cannot be locked')
    body.pos = np.array(body.pos, dtype=float) + offset
    spec.delete(joint)


class MujocoArm:
    """A URDF arm in MuJoCo; see the module docstring.  State and torques in joint_names order."""

    def __init__(self, urdf_text, joint_names, tip_link=None, payload_mass_offset=0.0,
                 inertia_scale=1.0, damping=False, joint_limits=True, timestep=1e-3,
                 integrator='rk4', locked_positions=None):
        self.joint_names = [str(n) for n in joint_names]
        payload = float(payload_mass_offset)
        scale = float(inertia_scale)
        if not (np.isfinite(scale) and scale > 0.0):
            raise ArmModelError(f'inertia_scale must be finite and > 0, got {inertia_scale}')
        if not (np.isfinite(payload) and payload >= 0.0):
            raise ArmModelError('payload_mass_offset must be finite and >= 0 (a point mass '
                                f'added to the tip link), got {payload_mass_offset}')
        if payload > 0.0 and not tip_link:
            raise ArmModelError('payload_mass_offset needs tip_link (the link that carries it)')
        if not (np.isfinite(timestep) and timestep > 0.0):
            raise ArmModelError(f'timestep must be finite and > 0, got {timestep}')
        if integrator not in INTEGRATORS:
            raise ArmModelError(f'integrator must be one of {sorted(INTEGRATORS)}, got '
                                f'{integrator!r}')
        if len(set(self.joint_names)) != len(self.joint_names) or not self.joint_names:
            raise ArmModelError(f'joint_names must be distinct and not empty, got '
                                f'{self.joint_names}')
        try:
            spec = mujoco.MjSpec.from_string(dynamics_urdf(urdf_text, scale))
        except ValueError as exc:
            raise ArmModelError(f'MuJoCo cannot load the URDF: {exc}') from None
        joints = {joint.name: joint for joint in spec.joints}
        unknown = [n for n in self.joint_names if n not in joints]
        if unknown:
            raise ArmModelError(f'joint_names {unknown} are not joints of the URDF (it has '
                                f'{sorted(joints)})')
        locked = {n: float((locked_positions or {}).get(n, 0.0)) for n in joints
                  if n not in self.joint_names}
        for equality in list(spec.equalities):
            if equality.name1 in locked or equality.name2 in locked:
                spec.delete(equality)
        for name, position in locked.items():
            _lock_joint(spec, joints[name], position)
        self.effort_limits = np.empty(len(self.joint_names))
        for i, name in enumerate(self.joint_names):
            joint = joints[name]
            if joint.type not in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE):
                raise ArmModelError(f'joint {name!r} is neither revolute nor prismatic')
            low, high = joint.actfrcrange
            if joint.actfrclimited == mujoco.mjtLimited.mjLIMITED_FALSE or not high > 0.0:
                raise ArmModelError(f'joint {name!r} has no effort limit in the URDF '
                                    '(<limit effort> > 0): the motors need one')
            self.effort_limits[i] = min(-low, high)
            if not damping:
                joint.damping = np.zeros_like(np.asarray(joint.damping))
                joint.frictionloss = 0.0
            joint.armature = 0.0
            if not joint_limits:
                joint.limited = mujoco.mjtLimited.mjLIMITED_FALSE
            motor = spec.add_actuator(name=f'{name}_motor', target=name,
                                      trntype=mujoco.mjtTrn.mjTRN_JOINT)
            motor.gainprm[0] = 1.0
            motor.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
            motor.ctrlrange = [-self.effort_limits[i], self.effort_limits[i]]
        if payload > 0.0:
            tip = spec.body(tip_link)
            if tip is None:
                raise ArmModelError(f'tip_link {tip_link!r} is not a link of the URDF')
            tip.add_body(name=PAYLOAD_BODY, mass=payload, ipos=[0.0, 0.0, 0.0],
                         inertia=[POINT_MASS_INERTIA] * 3)
        elif tip_link and spec.body(tip_link) is None:
            raise ArmModelError(f'tip_link {tip_link!r} is not a link of the URDF')
        try:
            self.model = spec.compile()
        except ValueError as exc:
            raise ArmModelError(f'MuJoCo cannot compile the arm: {exc}') from None
        model = self.model
        model.opt.timestep = float(timestep)
        model.opt.integrator = INTEGRATORS[integrator]
        model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
        self.data = mujoco.MjData(model)
        self._holding_data = mujoco.MjData(model)      # scratch of holding_torque
        ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n) for n in self.joint_names]
        self._qpos = np.array([model.jnt_qposadr[i] for i in ids])
        self._dof = np.array([model.jnt_dofadr[i] for i in ids])
        if model.nv != len(self.joint_names):
            raise ArmModelError(f'the model has {model.nv} degrees of freedom for '
                                f'{len(self.joint_names)} planned joints')
        self.timestep = float(timestep)
        self.set_state(np.zeros(model.nq), np.zeros(model.nv))

    @property
    def n_joints(self):
        """Return the number of planned (moving) joints."""
        return len(self.joint_names)

    @property
    def time(self):
        """Return the simulated time [s] since the last set_state."""
        return float(self.data.time)

    def state(self):
        """(q, v) of the planned joints, copies."""
        return self.data.qpos[self._qpos].copy(), self.data.qvel[self._dof].copy()

    def set_state(self, q, v):
        """Set positions and velocities of the planned joints; the simulated time restarts."""
        q = np.asarray(q, dtype=float)
        v = np.asarray(v, dtype=float)
        if q.shape != (self.n_joints,) or v.shape != (self.n_joints,):
            raise ArmModelError(f'set_state needs {self.n_joints} positions and velocities, '
                                f'got shapes {q.shape} and {v.shape}')
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v))):
            raise ArmModelError('set_state needs finite positions and velocities')
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[self._qpos] = q
        self.data.qvel[self._dof] = v
        mujoco.mj_forward(self.model, self.data)

    def clamp(self, tau):
        """Return the torques the motors apply for a command tau (clipped to the limits)."""
        return np.clip(np.asarray(tau, dtype=float), -self.effort_limits, self.effort_limits)

    def acceleration(self, tau):
        """Joint accelerations at the current state under torque tau (clamped); no step."""
        self.data.ctrl[:] = self._command(tau)
        mujoco.mj_forward(self.model, self.data)
        return self.data.qacc[self._dof].copy()

    def gravity_torque(self):
        """Torques that hold the current positions at rest (MuJoCo's bias force at v = 0)."""
        data = mujoco.MjData(self.model)
        data.qpos[:] = self.data.qpos
        mujoco.mj_forward(self.model, data)
        return data.qfrc_bias[self._dof].copy()

    def holding_torque(self, q):
        """Torques that hold the planned joints at positions q at rest (the others as now)."""
        data = self._holding_data
        data.qpos[:] = self.data.qpos
        data.qpos[self._qpos] = q
        data.qvel[:] = 0.0
        mujoco.mj_forward(self.model, data)
        return data.qfrc_bias[self._dof].copy()

    def step(self, tau, steps=1):
        """Advance by steps time steps under the torque command tau; return the applied torque."""
        applied = self._command(tau)
        self.data.ctrl[:] = applied
        for _ in range(int(steps)):
            mujoco.mj_step(self.model, self.data)
        return applied

    def _command(self, tau):
        tau = np.asarray(tau, dtype=float)
        if tau.shape != (self.n_joints,) or not np.all(np.isfinite(tau)):
            raise ArmModelError(f'the torque command needs {self.n_joints} finite values, got '
                                f'{tau!r}')
        # Actuators were added in joint_names order: actuator i drives joint_names[i].
        return self.clamp(tau)
