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
URDF text of an arm: where the named arms are, the source read, its joints and their limits.

Everything load_arm (model.py) needs before Pinocchio builds a model: the named arms of the
example-robot-data wheel and their default tip links, a source ('panda', 'urdf:PATH' or XML
text) read into text, the joints parsed with their <limit> values and the per-joint
overrides checked, and the XML handed to Pinocchio (continuous joints as unbounded revolute
ones).  Errors are ArmError with the reason.
"""

import dataclasses
import hashlib
import math
import os
import sys
from typing import Dict, Optional
import xml.etree.ElementTree as ElementTree

import pinocchio as pin

LIMIT_KEYS = ('effort', 'velocity', 'lower', 'upper')
# How a user gives a missing limit, in each of the interfaces.
LIMITS_HOW = ("toc-solve --limit {joint}.{key}=VALUE, the node's robot.joint_limits "
              "'{joint}.{key}=VALUE', or load_arm(limits={{'{joint}': {{'{key}': VALUE}}}})")
ONE_DOF_TYPES = ('revolute', 'continuous', 'prismatic')

# Named arms shipped by the example-robot-data wheel: URDF below its robots/ folder and the
# default set of planned joints (everything else locked).
NAMED_ARMS = {
    'panda': ('panda_description/urdf/panda.urdf',
              tuple(f'panda_joint{i}' for i in range(1, 8))),
    'ur5': ('ur_description/urdf/ur5_robot.urdf',
            ('shoulder_pan_joint', 'shoulder_lift_joint', 'elbow_joint', 'wrist_1_joint',
             'wrist_2_joint', 'wrist_3_joint')),
}

# The tip link of pose goals of the named arms (toc-solve --tip, the node's robot.tip_link).
DEFAULT_TIPS = {'panda': 'panda_hand', 'ur5': 'tool0'}


# Joint origins farther than this [m] from their parent link are refused (no arm is that
# large; such values only lose the kinematics' digits).
MAX_OFFSET = 1e3
# Effort [N m or N] and velocity [rad/s or m/s] limits are refused outside these ranges: no
# actuator reaches them, and the solver's scaling (controls over efforts) breaks beyond.
LIMIT_RANGES = {'effort': (1e-6, 1e6), 'velocity': (1e-6, 1e4)}


class ArmError(ValueError):
    """An arm, its limits, spheres or goals that cannot be used; the message is the reason."""


def _robots_dir_candidates():
    """Folders that may hold example-robot-data's robots/ (wheel, env override, ROS share)."""
    rel = os.path.join('share', 'example-robot-data', 'robots')
    env = os.environ.get('EXAMPLE_ROBOT_DATA_MODEL_DIR')
    if env:
        yield env
    # The pin wheel lives in <site-packages>/cmeel.prefix/lib/pythonX.Y/site-packages: its
    # cmeel prefix is the one example-robot-data was installed into.
    pin_dir = os.path.dirname(os.path.abspath(pin.__file__))
    yield os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(
        pin_dir)))), rel)
    for entry in sys.path:
        if entry:
            yield os.path.join(entry, 'cmeel.prefix', rel)
    try:
        from ament_index_python.packages import get_package_share_directory
        yield os.path.join(get_package_share_directory('example-robot-data'), 'robots')
    except (ImportError, LookupError, OSError, ValueError):
        pass    # no ament index or no example-robot-data package in it


def example_robot_data_dir():
    """Return the robots/ folder of example-robot-data (ArmError if it is not installed)."""
    for folder in _robots_dir_candidates():
        if os.path.isdir(os.path.join(folder, 'panda_description')):
            return folder
    raise ArmError('the named arms need the example-robot-data package (pip install '
                   'example-robot-data): its robots/ folder was not found')


def named_arm_path(name):
    """Return the URDF path of a named arm ('panda', 'ur5')."""
    if name not in NAMED_ARMS:
        raise ArmError(f'unknown arm {name!r}: named arms are {", ".join(sorted(NAMED_ARMS))}')
    path = os.path.join(example_robot_data_dir(), NAMED_ARMS[name][0])
    if not os.path.isfile(path):
        raise ArmError(f'arm {name!r}: {path} is missing from example-robot-data')
    return path


def read_source(source):
    """(URDF text, source description, default joints) of a load_arm source."""
    if isinstance(source, os.PathLike):
        source = 'urdf:' + os.fspath(source)
    if not isinstance(source, str) or not source.strip():
        raise ArmError(f"arm source must be 'panda', 'ur5', 'urdf:PATH' or a URDF XML string, "
                       f'got {source!r}')
    text = source.strip()
    if text in NAMED_ARMS:
        path = named_arm_path(text)
        with open(path) as stream:
            urdf = stream.read()
        described = {'model': text, 'path': path}
        defaults = NAMED_ARMS[text][1]
    elif text.startswith('urdf:'):
        path = os.path.expanduser(text[len('urdf:'):].strip())
        try:
            with open(path) as stream:
                urdf = stream.read()
        except (OSError, UnicodeDecodeError) as exc:
            raise ArmError(f'cannot read URDF {path!r}: {exc}') from None
        described = {'path': os.path.abspath(path)}
        defaults = None
    elif text.startswith('<'):
        urdf = source
        described = {'string': True}
        defaults = None
    else:
        raise ArmError(f"unknown arm {text!r}: give 'panda', 'ur5', 'urdf:PATH' or a URDF XML "
                       'string')
    try:
        described['sha256'] = hashlib.sha256(urdf.encode()).hexdigest()
    except UnicodeEncodeError as exc:
        raise ArmError(f'the URDF is not valid text: {exc}') from None
    return urdf, described, defaults


def number(text, what):
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise ArmError(f'{what} is not a number: {text!r}') from None
    if math.isnan(value):
        raise ArmError(f'{what} is NaN')
    return value


@dataclasses.dataclass(frozen=True)
class UrdfJoint:
    """A URDF joint as written (before any override): kinematics and <limit>."""

    name: str
    type: str  # noqa: A003 (the URDF attribute's name)
    parent: str
    child: str
    limits: Dict[str, float]        # the attributes present in <limit>
    mimic: Optional[str]            # <mimic joint>: value = multiplier * that joint's + offset
    mimic_multiplier: float = 1.0
    mimic_offset: float = 0.0


def parse_urdf(urdf):
    """Return (robot element, {joint name: UrdfJoint}) or raise ArmError for invalid XML."""
    try:
        root = ElementTree.fromstring(urdf)
    except ElementTree.ParseError as exc:
        raise ArmError(f'the URDF does not parse as XML: {exc}') from None
    if root.tag != 'robot':
        raise ArmError(f'the URDF root element is <{root.tag}>, not <robot>')
    joints = {}
    for element in root.findall('joint'):
        name = element.get('name')
        kind = element.get('type')
        parent, child = element.find('parent'), element.find('child')
        if not name or kind is None or parent is None or child is None:
            raise ArmError(f'URDF joint {name!r} lacks a name, type, parent or child')
        if name in joints:
            raise ArmError(f'URDF joint {name!r} is defined twice')
        limit = element.find('limit')
        limits = {}
        if limit is not None:
            for key in LIMIT_KEYS:
                if limit.get(key) is not None:
                    limits[key] = number(limit.get(key), f'joint {name!r} <limit {key}>')
                    if not math.isfinite(limits[key]):
                        raise ArmError(f'joint {name!r} <limit {key}> must be finite, got '
                                       f'{limits[key]}')
        mimic = element.find('mimic')
        coupling = {}
        if mimic is not None:
            for key, default in (('multiplier', 1.0), ('offset', 0.0)):
                value = number(mimic.get(key, default), f'joint {name!r} <mimic {key}>')
                if not math.isfinite(value):
                    raise ArmError(f'joint {name!r} <mimic {key}> must be finite')
                coupling[f'mimic_{key}'] = value
        joints[name] = UrdfJoint(name, kind, parent.get('link'), child.get('link'), limits,
                                 None if mimic is None else mimic.get('joint'), **coupling)
        _check_joint_geometry(element, name, kind)
    parents = {}
    for joint in joints.values():
        if joint.child in parents:
            raise ArmError(f'URDF link {joint.child!r} is the child of two joints '
                           f'({parents[joint.child]!r} and {joint.name!r}): a URDF is a tree')
        parents[joint.child] = joint.name
    for link in root.findall('link'):
        _check_inertial(link)
    return root, joints


def _vector(element, attribute, default, what):
    """Return the finite 3-vector of an attribute ('x y z'), default when absent (ArmError)."""
    text = None if element is None else element.get(attribute)
    if text is None:
        return default
    parts = text.split()
    if len(parts) != 3:
        raise ArmError(f'{what} must be three numbers, got {text!r}')
    values = [number(part, what) for part in parts]
    if not all(math.isfinite(value) for value in values):
        raise ArmError(f'{what} must be finite, got {text!r}')
    return values


def _check_joint_geometry(element, name, kind):
    """Raise ArmError for a joint origin that is not finite or absurdly far, or a zero axis."""
    origin = element.find('origin')
    xyz = _vector(origin, 'xyz', [0.0, 0.0, 0.0], f'joint {name!r} <origin xyz>')
    _vector(origin, 'rpy', [0.0, 0.0, 0.0], f'joint {name!r} <origin rpy>')
    if max(abs(value) for value in xyz) > MAX_OFFSET:
        raise ArmError(f'joint {name!r} <origin xyz> {xyz} lies beyond {MAX_OFFSET:g} m of its '
                       'parent link')
    if kind in ONE_DOF_TYPES:
        axis = _vector(element.find('axis'), 'xyz', [1.0, 0.0, 0.0], f'joint {name!r} <axis>')
        if math.sqrt(sum(value * value for value in axis)) < 1e-9:
            raise ArmError(f'joint {name!r} <axis xyz> is zero: a joint needs a direction')


def _check_inertial(link):
    """Raise ArmError for a link's mass or inertia that is not finite, or a negative mass."""
    inertial = link.find('inertial')
    if inertial is None:
        return
    name = link.get('name')
    mass = inertial.find('mass')
    if mass is not None and mass.get('value') is not None:
        value = number(mass.get('value'), f'link {name!r} <mass>')
        if not (math.isfinite(value) and value >= 0.0):
            raise ArmError(f'link {name!r} <mass> must be finite and >= 0 [kg], got {value}')
    inertia = inertial.find('inertia')
    if inertia is not None:
        for key in ('ixx', 'ixy', 'ixz', 'iyy', 'iyz', 'izz'):
            if inertia.get(key) is not None:
                value = number(inertia.get(key), f'link {name!r} <inertia {key}>')
                if not math.isfinite(value):
                    raise ArmError(f'link {name!r} <inertia {key}> must be finite, got {value}')
    _vector(inertial.find('origin'), 'xyz', None, f'link {name!r} <inertial><origin xyz>')


def pinocchio_xml(root, joints):
    """URDF text for Pinocchio: continuous joints as revolute, every 1-DOF joint with <limit>."""
    changed = False
    for element in root.findall('joint'):
        joint = joints[element.get('name')]
        if joint.type not in ONE_DOF_TYPES:
            continue
        if joint.type == 'continuous':
            # Angle coordinates (nq = nv) instead of Pinocchio's (cos, sin) for continuous.
            element.set('type', 'revolute')
            changed = True
        limit = element.find('limit')
        if limit is None:
            limit = ElementTree.SubElement(element, 'limit')
            changed = True
        for key in LIMIT_KEYS:
            if limit.get(key) is None:
                # The real limits are kept in ArmModel; these only make the XML parse.
                limit.set(key, {'lower': '-1e6', 'upper': '1e6'}.get(key, '0'))
                changed = True
        if joint.type == 'continuous':
            limit.set('lower', '-1e6')
            limit.set('upper', '1e6')
    return ElementTree.tostring(root, encoding='unicode') if changed else None


def joint_limits(joint, override, planned=True):
    """(effort, velocity, lower, upper, continuous) of a planned (or a locked) joint."""
    values = dict(joint.limits)
    continuous = joint.type == 'continuous'
    if continuous:
        values.pop('lower', None)
        values.pop('upper', None)
    for key, value in override.items():
        values[key] = value
    if continuous and ('lower' in override or 'upper' in override):
        continuous = False      # the override bounds the angle
    if continuous or (not planned and ('lower' not in values or 'upper' not in values)):
        lower, upper = -math.inf, math.inf
    elif not planned:
        if ('lower' in override or 'upper' in override) and values['lower'] > values['upper']:
            raise ArmError(f'joint {joint.name!r}: lower limit {values["lower"]} is above the '
                           f'upper limit {values["upper"]}')
        # A locked joint may have an empty range: its value is clamped into it.
        lower, upper = values['lower'], max(values['upper'], values['lower'])
    else:
        if 'lower' not in values or 'upper' not in values:
            raise ArmError(f'joint {joint.name!r} has no lower/upper position limit: give '
                           f'them ({LIMITS_HOW.format(joint=joint.name, key="lower")}, and '
                           'upper)')
        lower, upper = values['lower'], values['upper']
        if not math.isfinite(lower) or not math.isfinite(upper):
            raise ArmError(f'joint {joint.name!r}: position limits must be finite, got '
                           f'[{lower}, {upper}]')
        if lower >= upper:
            raise ArmError(f'joint {joint.name!r}: lower limit {lower} is not below the upper '
                           f'limit {upper} (lock a joint that must not move)')
    return values.get('effort', 0.0), values.get('velocity', 0.0), lower, upper, continuous


def check_overrides(limits, joints):
    if limits is None:
        return {}
    if not isinstance(limits, dict):
        raise ArmError(f"limits must map joint names to {{'effort': .., 'velocity': .., "
                       f"'lower': .., 'upper': ..}}, got {limits!r}")
    checked = {}
    for name, entry in limits.items():
        if name not in joints:
            raise ArmError(f'limits name unknown joint {name!r}')
        if not isinstance(entry, dict):
            raise ArmError(f'limits of joint {name!r} must be a mapping, got {entry!r}')
        unknown = sorted(set(entry) - set(LIMIT_KEYS))
        if unknown:
            raise ArmError(f'limits of joint {name!r}: unknown key(s) {", ".join(unknown)} '
                           f'(known: {", ".join(LIMIT_KEYS)})')
        checked[name] = {}
        for key, value in entry.items():
            value = number(value, f'limits of joint {name!r}: {key}')
            if not math.isfinite(value):
                raise ArmError(f'limits of joint {name!r}: {key} must be finite, got {value}')
            if key in ('effort', 'velocity') and value <= 0:
                raise ArmError(f'limits of joint {name!r}: {key} must be positive, got {value}')
            checked[name][key] = value
    return checked


def tip_link(model_name, arm, link=None):
    """Return the tip link: link, else the named arm's default, else the last joint's child."""
    if link:
        return link
    if model_name in DEFAULT_TIPS:
        return DEFAULT_TIPS[model_name]
    last = arm.joint_names[-1]
    return next(child for child, (_, joint, _) in arm.links.items() if joint == last)
