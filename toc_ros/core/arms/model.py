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
Arms from URDF: the planned joints' rigid-body model (Pinocchio), their limits and dynamics.

load_arm(source, joints, locked, limits) builds an ArmModel from
  - 'panda' or 'ur5': the Franka Panda (7 arm joints, fingers locked) and the UR5 (6 joints)
    of the example-robot-data wheel,
  - 'urdf:PATH': a URDF file,
  - a URDF XML string (a ROS user's robot_description).
Meshes are never loaded: the model is built from the XML without geometry.

The plan model has only the planned joints free; every other joint is locked at its value
(default 0 clamped into its limits) with pinocchio.buildReducedModel, which fuses the links
beyond a locked joint into their parent body.  Joints are kept in the URDF's kinematic order
(Pinocchio's depth-first order), so q, v and tau are vectors over joint_names in that order.

Physics of the plan model: the URDF inertials only, gravity (0, 0, -9.81) m/s^2 in the base
(root link) frame, z up (REP-103).  The URDF's <dynamics damping/friction> and any rotor
inertia (armature) are NOT modelled: a real arm's friction and damping then act as a small
unmodelled disturbance that the drives' tracking must absorb.

Limits come from the URDF's <limit effort velocity lower upper>; a limits mapping overrides
them per joint like MoveIt's joint_limits.yaml ({'joint': {'effort': .., 'velocity': ..,
'lower': .., 'upper': ..}}).  A planned joint without an effort or velocity limit (0 or
missing) is refused unless overridden.  Continuous joints are modelled as revolute joints
with an unbounded angle (lower/upper = -inf/+inf, continuous mask True) so that nq = nv = n.

Reading the URDF (named arms, sources, joints, limits, the XML Pinocchio parses): urdf.py.

Mimic joints are not modelled: a joint with <mimic> cannot be planned (lock it).  The model
has one pinocchio.Data workspace; the dynamics methods are therefore not thread-safe (give
each thread its own Data: model.createData(), and pass it as data=).
"""

import dataclasses
import math
from typing import Dict, Tuple

import numpy as np
import pinocchio as pin

# The names other modules import from here (ArmError, NAMED_ARMS, ...) stay importable.
from .urdf import (ArmError, check_overrides, example_robot_data_dir, joint_limits,  # noqa: F401
                   LIMIT_KEYS, LIMIT_RANGES, LIMITS_HOW, named_arm_path, NAMED_ARMS, number,
                   ONE_DOF_TYPES, parse_urdf, pinocchio_xml, read_source, tip_link)

GRAVITY = (0.0, 0.0, -9.81)
# Suffix of link frames renamed while joints of the same name are locked (_reduced).
RENAMED = '#link'


@dataclasses.dataclass(frozen=True, eq=False)
class ArmModel:
    """The planned joints of a URDF arm: reduced Pinocchio model, limits and dynamics."""

    model: pin.Model                # reduced: only the planned joints are free
    data: pin.Data                  # workspace of the methods below (not thread-safe)
    joint_names: Tuple[str, ...]    # planned joints, in the model's (kinematic) order
    lower: np.ndarray               # position limits (rad or m); -inf for continuous joints
    upper: np.ndarray               # +inf for continuous joints
    velocity: np.ndarray            # |dq_i| <= velocity_i
    effort: np.ndarray              # |tau_i| <= effort_i
    continuous: np.ndarray          # bool mask: continuous (unbounded angle) joints
    locked: Dict[str, float]        # locked joints and their values
    source: Dict[str, object]       # named model / path / string, and the URDF's sha256
    urdf: str                       # the URDF text as given
    full_model: pin.Model           # every 1-DOF joint of the URDF free
    links: Dict[str, Tuple[str, str, str]]  # child link -> (parent link, joint, joint type)

    @property
    def n(self):
        """Return the number of planned joints."""
        return len(self.joint_names)

    @property
    def nq(self):
        """Return the configuration size (= n: revolute and prismatic joints only)."""
        return self.model.nq

    @property
    def nv(self):
        """Return the velocity size (= n)."""
        return self.model.nv

    @property
    def gravity(self):
        """Return the gravity acceleration in the base frame (m/s^2)."""
        return np.array(self.model.gravity.linear)

    @property
    def name(self):
        """Return the named model ('panda', 'ur5'), or None for a URDF path or string."""
        return self.source.get('model')

    def full_configuration(self, q):
        """Return the full_model configuration: q for the planned joints, locked values else."""
        q_full = pin.neutral(self.full_model)
        values = dict(self.locked)
        values.update(zip(self.joint_names, np.asarray(q, dtype=float)))
        for name, value in values.items():
            q_full[self.full_model.idx_qs[self.full_model.getJointId(name)]] = value
        return q_full

    def frame_id(self, link):
        """Pinocchio frame index of a link (or any frame) name; ArmError if unknown."""
        if not isinstance(link, str) or not self.model.existFrame(link):
            known = [f.name for f in self.model.frames if f.type == pin.FrameType.BODY]
            raise ArmError(f'unknown link {link!r} (links: {", ".join(known)})')
        if self.model.existFrame(link, pin.FrameType.BODY):
            return self.model.getFrameId(link, pin.FrameType.BODY)      # a link before a joint
        return self.model.getFrameId(link)

    def forward_dynamics(self, q, v, tau, data=None):
        """Joint accelerations ddq = ABA(q, v, tau)."""
        return pin.aba(self.model, data or self.data, q, v, tau).copy()

    def inverse_dynamics(self, q, v, a, data=None):
        """Joint torques tau = RNEA(q, v, a)."""
        return pin.rnea(self.model, data or self.data, q, v, a).copy()

    def dynamics_derivatives(self, q, v, tau, data=None):
        """(d ddq/dq, d ddq/dv, d ddq/dtau = M^-1) of ABA, each (n, n)."""
        ddq_dq, ddq_dv, ddq_dtau = pin.computeABADerivatives(self.model, data or self.data,
                                                             q, v, tau)
        return ddq_dq.copy(), ddq_dv.copy(), ddq_dtau.copy()

    def dynamics_and_derivatives(self, q, v, tau, data=None):
        """(ddq, d ddq/dq, d ddq/dv, M^-1) from one pass (ddq agrees with ABA to rounding)."""
        data = data or self.data
        ddq_dq, ddq_dv, ddq_dtau = pin.computeABADerivatives(self.model, data, q, v, tau)
        return data.ddq.copy(), ddq_dq.copy(), ddq_dv.copy(), ddq_dtau.copy()

    def frame_pose(self, q, link, data=None):
        """Pose (pin.SE3) of a link frame in the base frame."""
        data = data or self.data
        fid = self.frame_id(link)
        pin.forwardKinematics(self.model, data, q)
        return pin.SE3(pin.updateFramePlacement(self.model, data, fid))

    def frame_position(self, q, link, data=None):
        """Position (3,) of a link frame's origin in the base frame."""
        return self.frame_pose(q, link, data).translation.copy()

    def frame_jacobian(self, q, link, reference=pin.LOCAL_WORLD_ALIGNED, data=None):
        """Frame Jacobian (6, n): linear rows first, then angular (reference frame given)."""
        # (reshaped: a one-joint model's 6 x 1 Jacobian comes back from Pinocchio as a vector)
        return np.reshape(pin.computeFrameJacobian(self.model, data or self.data, q,
                                                   self.frame_id(link), reference),
                          (6, self.model.nv)).copy()


def _reduced(full, lock_ids, q_ref):
    """Return full with the joints lock_ids locked at q_ref (a copy of full without any)."""
    if not lock_ids:
        return full.copy()
    # Pinocchio's buildReducedModel looks a locked joint up by name among all frames: a link
    # named like it (example-robot-data's so100 'gripper') makes that ambiguous.  Such links'
    # frames are renamed while it runs, in full and then in the reduced model.
    locked = {full.names[j] for j in lock_ids}
    renamed = [f for f in full.frames if f.name in locked and f.type == pin.FrameType.BODY]
    for frame in renamed:
        frame.name += RENAMED
    try:
        model = pin.buildReducedModel(full, lock_ids, q_ref)
    finally:
        for frame in renamed:
            frame.name = frame.name[:-len(RENAMED)]
    for frame in model.frames:
        if frame.name.endswith(RENAMED):
            frame.name = frame.name[:-len(RENAMED)]
    return model


def _select_joints(joints, requested, defaults, full):
    """Planned joint names in the model's order (ArmError for unknown or misordered names)."""
    movable = list(full.names[1:])
    if requested is None:
        if defaults is not None:
            return tuple(defaults)
        planned = tuple(name for name in movable if joints[name].mimic is None)
        if not planned:
            raise ArmError('the URDF has no movable joint to plan')
        return planned
    if isinstance(requested, str):
        requested = [part.strip() for part in requested.split(',') if part.strip()]
    if not isinstance(requested, (list, tuple)):
        raise ArmError(f'joints must be joint names (a list, or a string "j1,j2,..."), got '
                       f'{requested!r}')
    requested = list(requested)
    if not requested:
        raise ArmError('joints is empty: name at least one joint to plan')
    for name in requested:
        if not isinstance(name, str) or name not in joints:
            raise ArmError(f'unknown joint {name!r} (joints of the URDF: '
                           f'{", ".join(movable)})')
        if joints[name].type == 'fixed':
            raise ArmError(f'joint {name!r} is fixed: it cannot be planned')
    if len(set(requested)) != len(requested):
        raise ArmError(f'joints names a joint twice: {", ".join(requested)}')
    order = sorted(requested, key=movable.index)
    if order != requested:
        raise ArmError('joints must be listed in the URDF kinematic order: '
                       f'{", ".join(order)}')
    for name in requested:
        if joints[name].mimic is not None:
            raise ArmError(f'joint {name!r} mimics {joints[name].mimic!r}: mimic joints '
                           'cannot be planned (lock it)')
    return tuple(requested)


def _lock_values(full, urdf_joints, planned, locked, overrides):
    """
    {joint: value} of the joints not planned: given, else 0 clamped into the joint's limits.

    A mimic joint without a value follows its joint (multiplier * value + offset, the URDF's
    <mimic>): a gripper's second finger moves with the first.  A mimic of a planned joint
    cannot follow it in the reduced model and is refused.
    """
    values = {}
    pending = [name for name in full.names[1:] if name not in planned]
    movable = set(pending)
    for _ in range(len(pending) + 1):
        waiting = []
        for name in pending:
            joint = urdf_joints[name]
            if joint.mimic in planned:
                raise ArmError(f'joint {name!r} mimics the planned joint {joint.mimic!r}: a '
                               'mimic joint cannot follow a planned one (plan without it)')
            if joint.mimic in movable and joint.mimic not in values:
                waiting.append(name)        # after the joint it follows
                continue
            _, _, lower, upper, _ = joint_limits(joint, overrides.get(name, {}), planned=False)
            follows = None if joint.mimic not in values else \
                joint.mimic_multiplier * values[joint.mimic] + joint.mimic_offset
            if name in locked:
                value = number(locked[name], f'locked value of joint {name!r}')
            elif follows is not None:
                value = follows
            else:
                value = min(max(0.0, lower), upper)
            if not math.isfinite(value) or not lower <= value <= upper:
                raise ArmError(f'locked value {value} of joint {name!r} is outside its limits '
                               f'[{lower}, {upper}]')
            values[name] = value
        if not waiting:
            return values
        pending = waiting
    raise ArmError(f'the <mimic> joints {", ".join(pending)} follow each other in a cycle')


def load_arm(source, joints=None, locked=None, limits=None):
    """
    Return the ArmModel of a URDF arm with the planned joints free, the others locked.

    source: 'panda', 'ur5', 'urdf:PATH' or a URDF XML string; joints: planned joint names in
    kinematic order (None: the named arm's arm joints, or every movable non-mimic joint of a
    URDF); locked: {joint: value} for joints not planned (default 0 clamped into the joint's
    limits); limits: {joint: {'effort', 'velocity', 'lower', 'upper'}} overrides.
    Raises ArmError with the reason for anything that cannot be used.
    """
    urdf, described, defaults = read_source(source)
    root, urdf_joints = parse_urdf(urdf)
    for joint in urdf_joints.values():
        if joint.type not in ONE_DOF_TYPES + ('fixed',):
            raise ArmError(f'joint {joint.name!r} is of type {joint.type!r}: only revolute, '
                           'continuous, prismatic and fixed joints are supported')
    pin_xml = pinocchio_xml(root, urdf_joints) or urdf
    try:
        full = pin.buildModelFromXML(pin_xml)
    except (RuntimeError, ValueError) as exc:
        raise ArmError(f'Pinocchio cannot build the URDF: {exc}') from None
    full.gravity = pin.Motion(np.array(GRAVITY), np.zeros(3))
    planned = _select_joints(urdf_joints, joints, defaults, full)
    overrides = check_overrides(limits, urdf_joints)

    locked = {} if locked is None else locked
    if not isinstance(locked, dict):
        raise ArmError(f'locked must map joint names to values, got {locked!r}')
    for name in locked:
        if name not in urdf_joints or urdf_joints[name].type == 'fixed':
            raise ArmError(f'locked names unknown or fixed joint {name!r}')
        if name in planned:
            raise ArmError(f'joint {name!r} is both planned and locked')
    lock_values = _lock_values(full, urdf_joints, planned, locked, overrides)

    rows = []
    for name in planned:
        effort, velocity, lower, upper, continuous = joint_limits(
            urdf_joints[name], overrides.get(name, {}))
        for key, value in (('effort', effort), ('velocity', velocity)):
            if not value > 0:
                raise ArmError(f'joint {name!r} has no {key} limit in the URDF (0 or missing): '
                               f'give one ({LIMITS_HOW.format(joint=name, key=key)})')
            low, high = LIMIT_RANGES[key]
            if not low <= value <= high:
                raise ArmError(f'joint {name!r}: {key} limit {value:g} is outside [{low:g}, '
                               f'{high:g}] (SI units)')
        rows.append((lower, upper, velocity, effort, continuous))
    lower, upper, velocity, effort, continuous = (np.array(col) for col in zip(*rows))

    q_ref = pin.neutral(full)
    for name, value in lock_values.items():
        q_ref[full.idx_qs[full.getJointId(name)]] = value
    lock_ids = [full.getJointId(name) for name in lock_values]
    model = _reduced(full, lock_ids, q_ref)
    # Pinocchio's own limit fields follow the overrides (continuous: left unbounded-ish).
    model.effortLimit = effort.astype(float)
    model.velocityLimit = velocity.astype(float)
    model.lowerPositionLimit = np.where(continuous, model.lowerPositionLimit, lower)
    model.upperPositionLimit = np.where(continuous, model.upperPositionLimit, upper)

    links = {joint.child: (joint.parent, joint.name, joint.type)
             for joint in urdf_joints.values()}
    return ArmModel(model=model, data=model.createData(), joint_names=planned,
                    lower=lower.astype(float), upper=upper.astype(float),
                    velocity=velocity.astype(float), effort=effort.astype(float),
                    continuous=continuous.astype(bool), locked=lock_values, source=described,
                    urdf=urdf, full_model=full, links=links)
