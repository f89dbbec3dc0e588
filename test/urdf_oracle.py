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
An independent forward kinematics of URDF files for the arm tests: numpy and xml.etree only.

Each joint's <origin xyz rpy> (rpy: fixed-axis roll, pitch, yaw, R = Rz Ry Rx) and its motion
about or along <axis> give the child link's pose in the parent link's frame; link poses are
chained from the root link.  Sphere centres and clearances are recomputed from these poses
with plain loops, so they share nothing with toc_ros.core.arms or Pinocchio.
"""

import math
import xml.etree.ElementTree as ElementTree

import numpy as np


def _vector(text, default):
    return np.array([float(x) for x in text.split()]) if text else np.array(default, float)


def _rpy(roll, pitch, yaw):
    rx = np.array([[1, 0, 0], [0, math.cos(roll), -math.sin(roll)],
                   [0, math.sin(roll), math.cos(roll)]])
    ry = np.array([[math.cos(pitch), 0, math.sin(pitch)], [0, 1, 0],
                   [-math.sin(pitch), 0, math.cos(pitch)]])
    rz = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0],
                   [0, 0, 1]])
    return rz @ ry @ rx


def _axis_rotation(axis, angle):
    k = axis / np.linalg.norm(axis)
    skew = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * skew + (1 - math.cos(angle)) * skew @ skew


class UrdfOracle:
    """Link poses of a URDF for joint values given by name (missing joints: 0)."""

    def __init__(self, urdf_text):
        root = ElementTree.fromstring(urdf_text)
        self.joints = {}
        for joint in root.findall('joint'):
            origin = joint.find('origin')
            axis = joint.find('axis')
            self.joints[joint.get('name')] = {
                'type': joint.get('type'), 'parent': joint.find('parent').get('link'),
                'child': joint.find('child').get('link'),
                'xyz': _vector(origin.get('xyz') if origin is not None else None, [0, 0, 0]),
                'rpy': _vector(origin.get('rpy') if origin is not None else None, [0, 0, 0]),
                'axis': _vector(axis.get('xyz') if axis is not None else None, [1, 0, 0])}
        children = {j['child'] for j in self.joints.values()}
        links = [link.get('name') for link in root.findall('link')]
        self.root = [link for link in links if link not in children][0]
        self.links = links

    def link_poses(self, values):
        """{link: 4x4 pose in the root frame} for {joint name: value}."""
        poses = {self.root: np.eye(4)}
        pending = list(self.joints.items())
        while pending:
            rest = []
            for name, joint in pending:
                if joint['parent'] not in poses:
                    rest.append((name, joint))
                    continue
                origin = np.eye(4)
                origin[:3, :3] = _rpy(*joint['rpy'])
                origin[:3, 3] = joint['xyz']
                motion = np.eye(4)
                value = values.get(name, 0.0)
                if joint['type'] in ('revolute', 'continuous'):
                    motion[:3, :3] = _axis_rotation(joint['axis'], value)
                elif joint['type'] == 'prismatic':
                    motion[:3, 3] = joint['axis'] / np.linalg.norm(joint['axis']) * value
                poses[joint['child']] = poses[joint['parent']] @ origin @ motion
            if len(rest) == len(pending):
                raise ValueError('URDF tree is not connected')
            pending = rest
        return poses

    def adjacent(self, link_a, link_b):
        """Return True if the links are parent and child (fixed-joined links count as one)."""
        def group(link):
            # walk up and down fixed joints
            members, frontier = {link}, [link]
            while frontier:
                current = frontier.pop()
                for joint in self.joints.values():
                    if joint['type'] != 'fixed':
                        continue
                    for a, b in ((joint['parent'], joint['child']),
                                 (joint['child'], joint['parent'])):
                        if a == current and b not in members:
                            members.add(b)
                            frontier.append(b)
            return members
        group_a, group_b = group(link_a), group(link_b)
        if group_a & group_b:
            return True
        return any(joint['type'] != 'fixed' and (
            (joint['parent'] in group_a and joint['child'] in group_b)
            or (joint['parent'] in group_b and joint['child'] in group_a))
            for joint in self.joints.values())


def sphere_centres(oracle, values, links, offsets):
    """Centres (S, 3) of spheres given by link and link-frame offset."""
    poses = oracle.link_poses(values)
    return np.array([poses[link][:3, :3] @ offset + poses[link][:3, 3]
                     for link, offset in zip(links, offsets)])


def pair_clearance(centre_a, radius_a, centre_b, radius_b, margin=0.0):
    """Distance between two spheres' surfaces minus margin, by hand."""
    gap = math.sqrt(sum((a - b) ** 2 for a, b in zip(centre_a, centre_b)))
    return gap - radius_a - radius_b - margin
