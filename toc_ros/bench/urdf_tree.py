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
A URDF arm parsed into the reduced kinematic tree of its planned joints, in numpy.

The URDF XML is read with xml.etree.  Which joints move: a planned subset, in the caller's
order.  Every other joint is locked at a given value (default 0 clamped into its limits) and,
with the fixed joints, fused into its parent body: the child's inertia is added to the
parent's, its frame becomes a constant placement in the parent's.  Joint types revolute,
continuous and prismatic can be planned; floating and planar joints are refused.  <mimic> is
ignored (each joint independent, as Pinocchio's default URDF parser does); <dynamics> damping
and friction are not modelled.  Placements follow the conventions of arm_casadi.py: a child in
its parent as (R, p) with x_parent = R x_child + p; gravity in the frame of the URDF root link
(REP-103: z up).

    tree = parse_urdf(path_or_xml, ['panda_joint1', ...], locked={'panda_finger_joint1': 0.0})
"""

import dataclasses
import math
import os
from typing import Dict, Optional, Tuple
import xml.etree.ElementTree as ET  # noqa: N817

import numpy as np

PLANNABLE = ('revolute', 'continuous', 'prismatic')
FIXED = 'fixed'
GRAVITY = (0.0, 0.0, -9.81)


class UrdfError(ValueError):
    """The URDF or the choice of joints cannot be used; the message says why."""


# ----------------------------------------------------------------------------------------
# numeric rotations and inertias
# ----------------------------------------------------------------------------------------

def rpy_matrix(roll, pitch, yaw):
    """URDF rotation of fixed-axis roll-pitch-yaw: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    return rz @ ry @ rx


def axis_rotation(axis, angle):
    """Rotation by angle about a unit axis (Rodrigues), numpy."""
    k = skew_matrix(axis)
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def skew_matrix(v):
    """Matrix [v]x of the cross product with v: [v]x w = v x w."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


@dataclasses.dataclass
class RigidInertia:
    """Mass m, centre of mass c and rotational inertia about c (3x3), in one frame."""

    mass: float = 0.0
    com: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))
    rot: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((3, 3)))

    def moved(self, rotation, position):
        """Return the same inertia expressed in a parent frame (x_parent = R x + p)."""
        return RigidInertia(self.mass, rotation @ self.com + position,
                            rotation @ self.rot @ rotation.T)

    def plus(self, other):
        """Inertia of the union of two bodies given in the same frame (parallel axes)."""
        mass = self.mass + other.mass
        if mass <= 0.0:
            return RigidInertia()
        com = (self.mass * self.com + other.mass * other.com) / mass
        rot = np.zeros((3, 3))
        for part in (self, other):
            d = part.com - com
            rot += part.rot + part.mass * (np.dot(d, d) * np.eye(3) - np.outer(d, d))
        return RigidInertia(mass, com, rot)

    def matrix(self):
        """6x6 spatial inertia (linear part first) about the frame's origin."""
        c = skew_matrix(self.com)
        out = np.zeros((6, 6))
        out[:3, :3] = self.mass * np.eye(3)
        out[:3, 3:] = -self.mass * c
        out[3:, :3] = self.mass * c
        out[3:, 3:] = self.rot - self.mass * c @ c
        return out


# ----------------------------------------------------------------------------------------
# URDF parsing into a reduced tree
# ----------------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class JointLimits:
    """Limits of one planned joint; lower/upper are -inf/inf for a continuous joint."""

    lower: float
    upper: float
    effort: float
    velocity: float


@dataclasses.dataclass
class Body:
    """One moving body: its joint, the placement of the joint frame in the parent body."""

    joint: str
    kind: str                      # 'revolute' (also continuous) or 'prismatic'
    continuous: bool
    axis: np.ndarray               # unit axis in the joint frame
    parent: int                    # index of the parent body, -1 for the base
    rotation: np.ndarray           # placement of the joint frame at q = 0 in the parent body
    position: np.ndarray
    inertia: RigidInertia
    limits: JointLimits


@dataclasses.dataclass
class ArmTree:
    """
    A URDF reduced to its planned joints: bodies in tree order and links' placements.

    bodies: one per planned joint, parents before children (tree order).
    q_index: position of each body's joint in the caller's joint order.
    links: link name -> (body index or -1 for the base, rotation, position) of the link's
    frame in that body's frame.
    """

    joints: Tuple[str, ...]
    bodies: list
    q_index: Tuple[int, ...]
    links: Dict[str, tuple]
    locked: Dict[str, float]
    root: str
    base_inertia: RigidInertia
    gravity: Tuple[float, float, float] = GRAVITY

    @property
    def nq(self):
        """Return the number of planned joints."""
        return len(self.joints)

    def limits(self):
        """Arrays (lower, upper, effort, velocity) in the caller's joint order."""
        out = np.empty((4, self.nq))
        for body, i in zip(self.bodies, self.q_index):
            lim = body.limits
            out[:, i] = (lim.lower, lim.upper, lim.effort, lim.velocity)
        return out[0], out[1], out[2], out[3]


def _floats(text, n, what):
    try:
        values = [float(v) for v in (text or '').split()]
    except ValueError:
        raise UrdfError(f'{what}: {text!r} is not {n} numbers') from None
    if len(values) != n or not all(map(math.isfinite, values)):
        raise UrdfError(f'{what}: {text!r} is not {n} finite numbers')
    return values


def _origin(element, what):
    origin = element.find('origin') if element is not None else None
    if origin is None:
        return np.eye(3), np.zeros(3)
    xyz = _floats(origin.get('xyz', '0 0 0'), 3, f'{what} origin xyz')
    rpy = _floats(origin.get('rpy', '0 0 0'), 3, f'{what} origin rpy')
    return rpy_matrix(*rpy), np.array(xyz)


def _link_inertia(link):
    inertial = link.find('inertial')
    if inertial is None:
        return RigidInertia()
    name = link.get('name')
    rotation, com = _origin(inertial, f'link {name} inertial')
    mass_el, inertia_el = inertial.find('mass'), inertial.find('inertia')
    mass = float(_floats(mass_el.get('value') if mass_el is not None else '0', 1,
                         f'link {name} mass')[0])
    if mass < 0.0:
        raise UrdfError(f'link {name} has a negative mass {mass}')
    keys = ('ixx', 'ixy', 'ixz', 'iyy', 'iyz', 'izz')
    if inertia_el is None:
        vals = [0.0] * 6
    else:
        vals = [_floats(inertia_el.get(k, '0'), 1, f'link {name} inertia {k}')[0] for k in keys]
    ixx, ixy, ixz, iyy, iyz, izz = vals
    rot = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    return RigidInertia(mass, com, rotation @ rot @ rotation.T)


def _read_xml(urdf):
    text = str(urdf)
    if not text.lstrip().startswith('<'):
        if not os.path.isfile(text):
            raise UrdfError(f'URDF {text!r} is neither XML text nor an existing file')
        with open(text, encoding='utf-8') as stream:
            text = stream.read()
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise UrdfError(f'the URDF does not parse: {exc}') from None
    if root.tag != 'robot':
        raise UrdfError(f"the URDF's root element is <{root.tag}>, not <robot>")
    return root


def _joint_record(joint):
    name = joint.get('name')
    kind = joint.get('type')
    parent, child = joint.find('parent'), joint.find('child')
    if not name or parent is None or child is None:
        raise UrdfError(f'joint {name!r} lacks a name, a parent or a child')
    axis_el = joint.find('axis')
    axis = np.array(_floats(axis_el.get('xyz', '1 0 0') if axis_el is not None else '1 0 0',
                            3, f'joint {name} axis'))
    limit = joint.find('limit')
    lim = {}
    if limit is not None:
        for key in ('lower', 'upper', 'effort', 'velocity'):
            if limit.get(key) is not None:
                lim[key] = _floats(limit.get(key), 1, f'joint {name} limit {key}')[0]
    rotation, position = _origin(joint, f'joint {name}')
    return {'name': name, 'type': kind, 'parent': parent.get('link'), 'child': child.get('link'),
            'axis': axis, 'limit': lim, 'rotation': rotation, 'position': position}


def _joint_motion(record, value):
    """Placement of the child frame in the joint's origin frame at joint value `value`."""
    if record['type'] in ('revolute', 'continuous'):
        return axis_rotation(record['axis'] / np.linalg.norm(record['axis']), value), np.zeros(3)
    if record['type'] == 'prismatic':
        return np.eye(3), record['axis'] / np.linalg.norm(record['axis']) * value
    return np.eye(3), np.zeros(3)


def _planned_limits(record, overrides):
    lim = dict(record['limit'])
    lim.update({k: float(v) for k, v in (overrides or {}).items()})
    unknown = set(overrides or {}) - {'lower', 'upper', 'effort', 'velocity'}
    if unknown:
        raise UrdfError(f'joint {record["name"]}: unknown limit override(s) {sorted(unknown)}')
    continuous = record['type'] == 'continuous'
    missing = [k for k in ('effort', 'velocity') if not lim.get(k, 0.0) > 0.0]
    if not continuous:
        missing += [k for k in ('lower', 'upper') if k not in lim]
    if missing:
        raise UrdfError(f'joint {record["name"]} has no positive {"/".join(missing)} limit: '
                        'give one as an override')
    lower = -math.inf if continuous else lim['lower']
    upper = math.inf if continuous else lim['upper']
    if not lower < upper:
        raise UrdfError(f'joint {record["name"]}: lower limit {lower} is not below upper {upper}')
    return JointLimits(lower, upper, lim['effort'], lim['velocity'])


def parse_urdf(urdf, joints, locked=None, limits=None, gravity=GRAVITY):
    """
    Parse a URDF (file path or XML text) into an ArmTree planning `joints` (names, in order).

    locked: {joint name: value} for joints not planned (default 0 clamped into the joint's
    limits); limits: {joint name: {'lower'|'upper'|'effort'|'velocity': value}} overrides.
    UrdfError for XML that does not parse, unknown names, unsupported joint types, a planned
    joint without effort/velocity (or position, unless continuous) limits, or a tree that is
    not a tree.
    """
    xml = _read_xml(urdf)
    link_inertia = {}
    for link in xml.findall('link'):
        if not link.get('name'):
            raise UrdfError('a <link> has no name')
        link_inertia[link.get('name')] = _link_inertia(link)
    records = [_joint_record(j) for j in xml.findall('joint')]
    by_child, children = {}, {}
    for rec in records:
        for end in ('parent', 'child'):
            if rec[end] not in link_inertia:
                raise UrdfError(f'joint {rec["name"]} names an unknown {end} link {rec[end]!r}')
        if rec['child'] in by_child:
            raise UrdfError(f'link {rec["child"]} is the child of two joints')
        by_child[rec['child']] = rec
        children.setdefault(rec['parent'], []).append(rec)
    roots = [name for name in link_inertia if name not in by_child]
    if len(roots) != 1:
        raise UrdfError(f'the URDF must have one root link, found {roots}')
    names = {rec['name']: rec for rec in records}
    joints = tuple(joints)
    locked = dict(locked or {})
    limits = dict(limits or {})
    for what, group in (('planned', joints), ('locked', locked), ('limit override', limits)):
        unknown = [j for j in group if j not in names]
        if unknown:
            raise UrdfError(f'unknown {what} joint(s) {unknown}; the URDF has '
                            f'{[r["name"] for r in records if r["type"] != FIXED]}')
    if len(set(joints)) != len(joints) or not joints:
        raise UrdfError(f'planned joints must be distinct and at least one, got {list(joints)}')
    for name in joints:
        if names[name]['type'] not in PLANNABLE:
            raise UrdfError(f'joint {name} of type {names[name]["type"]!r} cannot be planned '
                            f'(one of {PLANNABLE})')
        if name in locked:
            raise UrdfError(f'joint {name} is both planned and locked')
    locked_values = {}
    for rec in records:
        if rec['name'] in joints or rec['type'] == FIXED:
            continue
        if rec['type'] not in PLANNABLE:
            raise UrdfError(f'joint {rec["name"]} of type {rec["type"]!r} is not supported')
        value = float(locked.get(rec['name'], 0.0))
        if not math.isfinite(value):
            raise UrdfError(f'locked joint {rec["name"]} value {value} is not finite')
        if rec['name'] not in locked and rec['type'] != 'continuous':
            lo, hi = rec['limit'].get('lower', -math.inf), rec['limit'].get('upper', math.inf)
            value = min(max(value, lo), hi)
        locked_values[rec['name']] = value

    bodies, links = [], {}
    base_inertia = link_inertia[roots[0]]
    links[roots[0]] = (-1, np.eye(3), np.zeros(3))
    stack = [roots[0]]
    seen = set()
    while stack:        # depth first from the root: parents are placed before children
        parent_link = stack.pop()
        if parent_link in seen:
            raise UrdfError(f'the URDF joints form a loop through link {parent_link}')
        seen.add(parent_link)
        body, rot, pos = links[parent_link]
        for rec in reversed(children.get(parent_link, [])):
            child = rec['child']
            o_rot, o_pos = rot @ rec['rotation'], rot @ rec['position'] + pos
            if rec['name'] in joints:
                lim = _planned_limits(rec, limits.get(rec['name']))
                kind = 'prismatic' if rec['type'] == 'prismatic' else 'revolute'
                bodies.append(Body(rec['name'], kind, rec['type'] == 'continuous',
                                   rec['axis'] / np.linalg.norm(rec['axis']), body, o_rot,
                                   o_pos, link_inertia[child], lim))
                links[child] = (len(bodies) - 1, np.eye(3), np.zeros(3))
            else:
                m_rot, m_pos = _joint_motion(rec, locked_values.get(rec['name'], 0.0))
                c_rot, c_pos = o_rot @ m_rot, o_rot @ m_pos + o_pos
                links[child] = (body, c_rot, c_pos)
                inertia = link_inertia[child].moved(c_rot, c_pos)
                if body >= 0:
                    bodies[body].inertia = bodies[body].inertia.plus(inertia)
                else:
                    base_inertia = base_inertia.plus(inertia)
            stack.append(child)
    for rec in records:
        if np.linalg.norm(rec['axis']) == 0.0 and rec['type'] in PLANNABLE:
            raise UrdfError(f'joint {rec["name"]} has a zero axis')
    order = {name: i for i, name in enumerate(joints)}
    q_index = tuple(order[b.joint] for b in bodies)
    planned = {b.joint for b in bodies}
    for name in joints:
        if name not in planned:
            raise UrdfError(f'joint {name} is not reachable from the root link {roots[0]}')
    g = tuple(float(v) for v in gravity)
    if len(g) != 3 or not all(map(math.isfinite, g)):
        raise UrdfError(f'gravity must be 3 finite numbers, got {gravity!r}')
    return ArmTree(joints, bodies, q_index, links, locked_values, roots[0], base_inertia, g)


def sphere_points(spheres: Optional[dict]):
    """[(link, (x, y, z))], radii array from {link: [[x, y, z, r], ...]} (checked)."""
    points, radii = [], []
    for link, rows in (spheres or {}).items():
        for row in rows:
            values = [float(v) for v in row]
            if len(values) != 4 or not all(map(math.isfinite, values)):
                raise UrdfError(f'sphere of link {link}: {row!r} is not 4 finite numbers '
                                '[x, y, z, r]')
            if values[3] < 0.0:
                raise UrdfError(f'sphere of link {link}: negative radius {values[3]}')
            points.append((str(link), tuple(values[:3])))
            radii.append(values[3])
    return points, np.asarray(radii, dtype=float)
