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
A payload on a URDF arm: a point mass at the origin of a link (what a gripper holds).

The plan model of an arm with a payload of mass m [kg] at the origin of link L is the URDF
model whose inertia of L's parent joint has the point mass added at L's placement (Pinocchio
adds inertias exactly: mass, centre of mass and rotational inertia about the joint).  This is
what plant_node's payload_mass_offset adds to MuJoCo's model (a massive child body of the tip
link, at its origin), so that an estimated payload (replan.estimate: [payload_mass]) is the
plant's offset.  The inverse dynamics tau(q, dq, ddq; m) = RNEA of that model is linear in m
(inertial parameters enter RNEA linearly): the online estimator's regressor is exact.
"""

import dataclasses
import math

import numpy as np
import pinocchio as pin

from .model import ArmError


def with_payload(arm, mass, link):
    """
    Return the ArmModel of arm with a point mass [kg] at the origin of link (arm itself for 0).

    ArmError when the mass is not finite and >= 0 or the link is unknown.  The returned
    model's source records the payload ('payload_mass', 'payload_link').
    """
    mass = float(mass)
    if not (math.isfinite(mass) and mass >= 0.0):
        raise ArmError(f'payload mass must be finite and >= 0 [kg], got {mass!r}')
    frame = arm.model.frames[arm.frame_id(link)]
    if mass == 0.0:
        return arm
    model = arm.model.copy()
    point = pin.Inertia(mass, frame.placement.translation.copy(), np.zeros((3, 3)))
    model.inertias[frame.parentJoint] = model.inertias[frame.parentJoint] + point
    source = dict(arm.source)
    source.update(payload_mass=mass, payload_link=link)
    return dataclasses.replace(arm, model=model, data=model.createData(), source=source)


__all__ = ['with_payload']
