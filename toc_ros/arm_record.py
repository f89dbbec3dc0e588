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
What rebuilds a URDF arm from a recording: the arm_* fields of solver_node's ~/progress.

The node's ready and result reports name the arm they plan for (``ArmRecord``): the planned
joints, the value of every locked joint, the robot.joint_limits overrides, the tip link in
force, where the URDF and the collision spheres came from and the sha256 of their texts.  The
texts themselves (the sphere file's YAML; the URDF when the robot_description parameter gave
it: a URDF from the topic is recorded as the topic) go on the ready report only, once per
model load: result reports come up to replan.rate times a second and a URDF is tens of kB.
Paths alone would not do: the sphere file may not exist where the recording is analysed.
"""

from dataclasses import dataclass
import functools
import hashlib
import os
from typing import Tuple

from toc_ros import arm_config
from toc_ros.core.models import ModelChoice
from toc_ros.core.problem import ProblemError

SHIPPED = 'shipped'             # arm_spheres_source of the package's sets (panda, ur5)
URDF_PARAMETER, URDF_TOPIC = 'parameter', 'topic'     # arm_urdf_source of robot.model urdf
PAYLOAD = 'payload_mass'


def sha256(text):
    """Return the hex sha256 of a text (as the arm core hashes the URDF it loads)."""
    return hashlib.sha256(text.encode()).hexdigest()


@dataclass(frozen=True)
class ArmRecord:
    """The arm a progress report names (see the module docstring)."""

    joints: Tuple[str, ...]
    locked: Tuple[str, ...]             # 'JOINT=VALUE' of every locked joint
    joint_limits: Tuple[str, ...]       # 'JOINT.KEY=VALUE' overrides
    tip_link: str
    urdf_source: str                    # 'panda', 'ur5', URDF_PARAMETER or URDF_TOPIC
    urdf_sha256: str
    spheres_source: str                 # the sphere file's path, or SHIPPED
    spheres_sha256: str
    payload_mass: float = 0.0           # robot.payload_mass [kg] at the tip link
    urdf: str = ''                      # the URDF text ('' when not carried)
    spheres: str = ''                   # the sphere file's YAML text ('' when not carried)

    def fields(self, texts=False):
        """Return the ProgressReport fields; texts: with the URDF (parameter) and sphere text."""
        values = {'arm_joints': self.joints, 'arm_locked': self.locked,
                  'arm_joint_limits': self.joint_limits, 'arm_tip_link': self.tip_link,
                  'arm_urdf_source': self.urdf_source, 'arm_urdf_sha256': self.urdf_sha256,
                  'arm_spheres_source': self.spheres_source,
                  'arm_spheres_sha256': self.spheres_sha256,
                  # The arm's one model parameter, as the planar models' are reported.
                  'model_parameters': (f'{PAYLOAD}={self.payload_mass!r}'
                                       if self.payload_mass else '')}
        if texts:
            values['arm_spheres'] = self.spheres
            if self.urdf_source == URDF_PARAMETER:
                values['arm_urdf'] = self.urdf
        return values

    @classmethod
    def from_report(cls, report):
        """Return the record of a ProgressReport, None when it has none (older recordings)."""
        if not report.arm_urdf_source:
            return None
        return cls(joints=tuple(report.arm_joints), locked=tuple(report.arm_locked),
                   joint_limits=tuple(report.arm_joint_limits), tip_link=report.arm_tip_link,
                   urdf_source=report.arm_urdf_source, urdf_sha256=report.arm_urdf_sha256,
                   spheres_source=report.arm_spheres_source,
                   spheres_sha256=report.arm_spheres_sha256, urdf=report.arm_urdf,
                   spheres=report.arm_spheres, payload_mass=_payload(report.model_parameters))

    def same_arm(self, other):
        """Tell whether two records name the same arm (texts aside: digests compare them)."""
        return self.fields() == other.fields()


def _payload(text):
    """Return the payload mass of a report's model_parameters ('payload_mass=M' or '')."""
    entries = tuple(entry for entry in str(text).split(',') if entry.strip())
    return float(ModelChoice(parameters=entries).parameter_values().get(PAYLOAD, 0.0))


@functools.lru_cache(maxsize=8)
def _file_text(path, stamp):
    """Return a file's text, read once per modification time (stamp: the cache key)."""
    with open(path, encoding='utf-8') as stream:
        return stream.read()


def file_text(path):
    """Return the text of a file (OSError, UnicodeDecodeError when it cannot be read)."""
    return _file_text(path, os.stat(path).st_mtime_ns)


def spheres_file(name, collision_spheres):
    """Return (path, source) of an arm's sphere file: robot.collision_spheres or the shipped."""
    path = str(collision_spheres).strip()
    if path:
        path = os.path.abspath(os.path.expanduser(path))
        return path, path
    from toc_ros.core.arms import shipped_spheres_path
    return shipped_spheres_path(name), SHIPPED


def arm_record(params, model):
    """
    Return the ArmRecord of a loaded arm model built from flat parameters.

    ProblemError when the sphere file cannot be read (it was read to build the model: it
    changed or vanished since).
    """
    arm = arm_config.settings(params)
    if model.name == 'urdf':
        urdf_source = URDF_PARAMETER if str(params.get('robot_description', '')).strip() \
            else URDF_TOPIC
    else:
        urdf_source = model.name
    path, spheres_source = spheres_file(model.name, arm.collision_spheres)
    try:
        spheres = file_text(path)
    except (OSError, UnicodeDecodeError) as exc:
        raise ProblemError(f'robot.collision_spheres: cannot read {path!r}: {exc}') from None
    limits = tuple(f'{joint}.{key}={value!r}'
                   for joint, keys in sorted(arm_config.limit_overrides(arm.joint_limits).items())
                   for key, value in sorted(keys.items()))
    try:
        tip = model.tip_frame(arm.tip_link)[0]
    except ValueError:      # refused by arm_errors before a config is built: as given
        tip = arm.tip_link
    return ArmRecord(
        joints=tuple(model.arm.joint_names),
        locked=tuple(f'{joint}={float(value)!r}' for joint, value in model.arm.locked.items()),
        joint_limits=limits, tip_link=tip, urdf_source=urdf_source,
        urdf_sha256=model.arm.source['sha256'], spheres_source=spheres_source,
        spheres_sha256=sha256(spheres), urdf=model.arm.urdf, spheres=spheres,
        payload_mass=model.payload_mass)
