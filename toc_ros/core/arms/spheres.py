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
Collision spheres of an arm's links: the sphere file, its checks, the self-collision pairs.

Sphere file (YAML), like cuRobo's collision_spheres: centres in the link's frame, metres,

    panda_link1: [[0.0, -0.02, -0.1, 0.08], [0.0, 0.0, -0.01, 0.07]]   # [x, y, z, r]
    panda_hand: [[0.0, 0.0, 0.05, 0.07]]
    ignore_pairs:              # optional: link pairs never checked against each other
      - [panda_link5, panda_link7]

cuRobo's own layout (a top-level collision_spheres: mapping whose entries are
{center: [x, y, z], radius: r}) is read as well.  Radii must be >= 0; links must be links of
the URDF.  After pinocchio.buildReducedModel the links beyond a locked joint are fused into
their parent body; their Pinocchio frames (found by link name) keep the right placement, so a
sphere is attached to its frame's parent joint with the frame's placement.

Their centres, Jacobians and clearances (to obstacle spheres, between links) are in
clearances.py.

Self-collision is checked between spheres of links that are not adjacent: two links are
adjacent when they are parent and child in the URDF tree, counting links joined by fixed
joints as one link (so the Panda's hand is adjacent to link7 and to both fingers).  Pairs of
links that the reduced model keeps rigidly together (e.g. across a locked joint) are skipped
too, as their distance cannot change; load_spheres refuses them if they overlap (with
self-collision on).  Further
pairs to skip come from the file's ignore_pairs and the ignore_pairs argument (the shipped
files list the SRDF's disable_collisions: pairs MoveIt found adjacent or never colliding).
"""

import dataclasses
import math
import os
from typing import FrozenSet, Optional, Tuple

import numpy as np
import pinocchio as pin
import yaml

from .clearances import self_clearance, sphere_centres
from .model import ArmError

SHIPPED_NAMES = ('panda', 'ur5')


@dataclasses.dataclass(frozen=True, eq=False)
class Spheres:
    """An arm's collision spheres, attached to the reduced model's joints."""

    links: Tuple[str, ...]          # link of each sphere
    index: np.ndarray               # number of each sphere within its link (0, 1, ...)
    offsets: np.ndarray             # (S, 3) centres in their link frames
    radii: np.ndarray               # (S,)
    joint_ids: np.ndarray           # (S,) parent joint of each sphere in the reduced model
    joint_offsets: np.ndarray       # (S, 3) centres in their parent joint's frame
    support: np.ndarray             # (S, n) bool: planned joint k moves sphere s
    ignore_pairs: FrozenSet[FrozenSet[str]]
    self_pairs: np.ndarray          # (P, 2) sphere index pairs checked for self-collision
    source: Optional[str]           # file path, or None for a mapping
    chain: Tuple[np.ndarray, ...]   # the reduced model's joints for kernels.sphere_kinematics

    def __len__(self):
        """Return the number of spheres."""
        return len(self.radii)

    def label(self, s):
        """Name of sphere s in messages ('panda_link4 sphere 1')."""
        return f'{self.links[s]} sphere {int(self.index[s])}'


def shipped_spheres_path(name):
    """Return config/spheres/<name>.yaml of the installed package, else of the source tree."""
    if name not in SHIPPED_NAMES:
        raise ArmError(f'no shipped collision spheres for {name!r} (shipped: '
                       f'{", ".join(SHIPPED_NAMES)})')
    file_name = f'{name}.yaml'
    try:
        from ament_index_python.packages import get_package_share_directory
        path = os.path.join(get_package_share_directory('toc_ros'), 'config', 'spheres',
                            file_name)
        if os.path.isfile(path):
            return path
    except (ImportError, LookupError, OSError, ValueError):
        pass    # no ament index, or toc_ros not in it: the source tree
    return os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(
        os.path.abspath(__file__))))), 'config', 'spheres', file_name)


def default_spheres(arm, self_collision=True):
    """Return the shipped spheres of a named arm ('panda', 'ur5'); None for other arms."""
    if arm.name not in SHIPPED_NAMES:
        return None
    return load_spheres(shipped_spheres_path(arm.name), arm, self_collision=self_collision)


def _read_mapping(path_or_mapping):
    if isinstance(path_or_mapping, dict):
        return path_or_mapping, None
    if not isinstance(path_or_mapping, (str, os.PathLike)):
        raise ArmError(f'collision spheres must be a YAML file path or a mapping, got '
                       f'{path_or_mapping!r}')
    path = os.fspath(path_or_mapping)
    try:
        with open(path) as stream:
            doc = yaml.safe_load(stream)
    except (OSError, UnicodeDecodeError) as exc:
        raise ArmError(f'cannot read collision spheres {path!r}: {exc}') from None
    except yaml.YAMLError as exc:
        raise ArmError(f'collision spheres {path!r} is not valid YAML: {exc}') from None
    if not isinstance(doc, dict):
        raise ArmError(f'collision spheres {path!r} must map link names to [[x, y, z, r], ...]')
    return doc, path


def _sphere_row(entry, where):
    if isinstance(entry, dict):     # cuRobo: {center: [x, y, z], radius: r}
        if set(entry) != {'center', 'radius'} or not isinstance(entry['center'], (list, tuple)):
            raise ArmError(f'{where}: expected {{center: [x, y, z], radius: r}}, got {entry!r}')
        entry = list(entry['center']) + [entry['radius']]
    if not isinstance(entry, (list, tuple)) or len(entry) != 4:
        raise ArmError(f'{where}: expected [x, y, z, r], got {entry!r}')
    if any(isinstance(value, bool) for value in entry):
        raise ArmError(f'{where}: entries must be numbers, got {entry!r}')
    try:
        row = [float(value) for value in entry]
    except (TypeError, ValueError):
        raise ArmError(f'{where}: entries must be numbers, got {entry!r}') from None
    if not all(math.isfinite(value) for value in row):
        raise ArmError(f'{where}: NaN or infinite value in {entry!r}')
    if row[3] < 0:
        raise ArmError(f'{where}: negative radius {row[3]}')
    return row


def _link_groups(arm):
    """{link: representative}: links joined by fixed joints share a representative."""
    parent = {}

    def find(link):
        while parent.get(link, link) != link:
            link = parent[link]
        return link

    for child, (par, _, kind) in arm.links.items():
        if kind == 'fixed':
            parent[find(child)] = find(par)
    every = set(arm.links) | {par for par, _, _ in arm.links.values()}
    return {link: find(link) for link in every}


def adjacent_links(arm):
    """Set of frozenset({a, b}) of URDF links that are adjacent (see the module docstring)."""
    group = _link_groups(arm)
    members = {}
    for link, rep in group.items():
        members.setdefault(rep, set()).add(link)
    adjacent = set()
    for links in members.values():
        adjacent |= {frozenset((a, b)) for a in links for b in links if a != b}
    for child, (par, _, kind) in arm.links.items():
        if kind != 'fixed':
            for a in members[group[child]]:
                for b in members[group[par]]:
                    adjacent.add(frozenset((a, b)))
    return adjacent


def kinematic_chain(model):
    """(parent, placement R, placement t, axis, prismatic, v index) of a 1-DOF joint tree."""
    data = model.createData()
    pin.computeJointJacobians(model, data, pin.neutral(model))
    count = model.njoints
    axis = np.zeros((count, 3))
    prismatic = np.zeros(count, dtype=np.bool_)
    v_index = np.zeros(count, dtype=np.int64)
    for j in range(1, count):
        if model.nvs[j] != 1:
            raise ArmError(f'joint {model.names[j]!r} has {model.nvs[j]} degrees of freedom: '
                           'only 1-DOF joints are supported')
        # The joint's motion in its own frame: (0, axis) if revolute, (axis, 0) if prismatic.
        # (reshaped: a one-joint model's 6 x 1 Jacobian comes back as a vector)
        jacobian = np.reshape(pin.getJointJacobian(model, data, j, pin.LOCAL), (6, model.nv))
        column = jacobian[:, model.idx_vs[j]]
        prismatic[j] = np.linalg.norm(column[3:]) < 0.5
        axis[j] = column[:3] if prismatic[j] else column[3:]
        v_index[j] = model.idx_vs[j]
    return (np.array(list(model.parents), dtype=np.int64),
            np.array([placement.rotation for placement in model.jointPlacements]),
            np.array([placement.translation for placement in model.jointPlacements]),
            axis, prismatic, v_index)


def _check_pairs(pairs, arm, where):
    checked = set()
    for pair in pairs or ():
        if not isinstance(pair, (list, tuple)) or len(pair) != 2:
            raise ArmError(f'{where}: each entry must be a pair of link names, got {pair!r}')
        for link in pair:
            if not isinstance(link, str) or not arm.model.existFrame(link, pin.FrameType.BODY):
                raise ArmError(f'{where}: unknown link {link!r}')
        checked.add(frozenset(pair))
    return checked


def load_spheres(path_or_mapping, arm, ignore_pairs=None, self_collision=True):
    """
    Read and check collision spheres for an arm; return Spheres (ArmError with the reason).

    ignore_pairs: further [link_a, link_b] pairs not checked for self-collision;
    self_collision=False leaves self_pairs empty.
    """
    doc, path = _read_mapping(path_or_mapping)
    where = f'collision spheres {path!r}' if path else 'collision spheres'
    doc = dict(doc)
    file_pairs = doc.pop('ignore_pairs', None)
    if isinstance(doc.get('collision_spheres'), dict):
        if len(doc) != 1:
            raise ArmError(f'{where}: collision_spheres beside other keys '
                           f'({", ".join(k for k in doc if k != "collision_spheres")})')
        doc = doc['collision_spheres']
    if file_pairs is not None and not isinstance(file_pairs, list):
        raise ArmError(f'{where}: ignore_pairs must be a list of [link_a, link_b]')
    ignored = _check_pairs(file_pairs, arm, f'{where} ignore_pairs')
    ignored |= _check_pairs(ignore_pairs, arm, 'ignore_pairs')

    model = arm.model
    unknown = [str(link) for link in doc
               if not isinstance(link, str) or not model.existFrame(link, pin.FrameType.BODY)]
    if unknown:
        known = [f.name for f in model.frames if f.type == pin.FrameType.BODY]
        raise ArmError(f'{where}: unknown link(s) {", ".join(unknown)} (links of the URDF: '
                       f'{", ".join(known)})')
    links, index, rows, joint_ids, joint_offsets = [], [], [], [], []
    for link, entries in doc.items():
        if entries is None:
            continue
        if not isinstance(entries, list):
            raise ArmError(f'{where}: {link} must be a list of [x, y, z, r], got {entries!r}')
        frame = model.frames[model.getFrameId(link, pin.FrameType.BODY)]
        for i, entry in enumerate(entries):
            row = _sphere_row(entry, f'{where}: {link} sphere {i}')
            links.append(link)
            index.append(i)
            rows.append(row)
            joint_ids.append(frame.parentJoint)
            joint_offsets.append(frame.placement.act(np.array(row[:3])))
    if not rows:
        raise ArmError(f'{where}: no spheres')
    rows = np.array(rows)
    joint_ids = np.array(joint_ids, dtype=int)
    support = np.zeros((len(rows), model.nv), dtype=bool)
    for s, joint in enumerate(joint_ids):
        for ancestor in model.supports[int(joint)]:
            if ancestor > 0:
                support[s, model.idx_vs[ancestor]] = True
    spheres = Spheres(links=tuple(links), index=np.array(index), offsets=rows[:, :3].copy(),
                      radii=rows[:, 3].copy(), joint_ids=joint_ids,
                      joint_offsets=np.array(joint_offsets), support=support,
                      ignore_pairs=frozenset(ignored), self_pairs=np.zeros((0, 2), dtype=int),
                      source=path, chain=kinematic_chain(model))
    pairs, rigid = _self_pairs(arm, spheres)
    # Overlapping rigid pairs matter only to self-collision (without it, e.g. one planned
    # joint of the Panda with the others locked at 0 is a valid arm to plan around obstacles).
    if self_collision and len(rigid):
        centres = sphere_centres(arm, spheres, pin.neutral(model))
        depth = -self_clearance(centres, spheres.radii, rigid)
        if depth.max() > 0:
            a, b = rigid[int(np.argmax(depth))]
            raise ArmError(f'{where}: {spheres.label(a)} and {spheres.label(b)} are held '
                           f'together in collision (depth {depth.max():.3f} m) by the locked '
                           'joints: ignore that link pair or change the locked values')
    if not self_collision:
        pairs = np.zeros((0, 2), dtype=int)
    return dataclasses.replace(spheres, self_pairs=pairs)


def _self_pairs(arm, spheres):
    """((P, 2) pairs to check, (R, 2) rigid non-adjacent pairs) of sphere indices."""
    skip = adjacent_links(arm) | spheres.ignore_pairs
    pairs, rigid = [], []
    for a in range(len(spheres)):
        for b in range(a + 1, len(spheres)):
            link_a, link_b = spheres.links[a], spheres.links[b]
            if link_a == link_b or frozenset((link_a, link_b)) in skip:
                continue
            if spheres.joint_ids[a] == spheres.joint_ids[b]:
                rigid.append((a, b))
            else:
                pairs.append((a, b))
    return (np.array(pairs, dtype=int).reshape(-1, 2), np.array(rigid, dtype=int).reshape(-1, 2))


def check_spheres_fit(spheres, arm):
    """
    Raise ArmError unless spheres were loaded (load_spheres) for this arm's reduced model.

    The compiled kernels index the configuration by the spheres' joint data without bounds
    checks: a set loaded for another arm, or for other planned or locked joints, would read
    and write outside its arrays.
    """
    if not isinstance(spheres, Spheres):
        raise ArmError(f'collision spheres must come from load_spheres, got '
                       f'{type(spheres).__name__}')
    model = arm.model
    chain = kinematic_chain(model)
    fits = (spheres.support.shape[1] == arm.n and len(chain) == len(spheres.chain)
            and all(a.shape == b.shape and np.array_equal(a, b)
                    for a, b in zip(chain, spheres.chain)))
    for s, link in enumerate(spheres.links if fits else ()):
        # Each sphere's placement on its joint (a locked joint between moves it).
        if not model.existFrame(link, pin.FrameType.BODY):
            fits = False
            break
        frame = model.frames[model.getFrameId(link, pin.FrameType.BODY)]
        if (frame.parentJoint != spheres.joint_ids[s] or not np.array_equal(
                frame.placement.act(spheres.offsets[s]), spheres.joint_offsets[s])):
            fits = False
            break
    if not fits:
        raise ArmError('the collision spheres were loaded for another arm or other planned '
                       f'and locked joints: load them for this one ({arm.n} joints: '
                       f'{", ".join(arm.joint_names)}) with load_spheres(..., arm)')
