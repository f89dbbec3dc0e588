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
An independent check of arm trajectories: Pinocchio straight from the URDF, spheres from YAML.

Nothing of toc_ros is used to judge a plan: the model is pinocchio.buildModelFromUrdf of the
URDF file (the fingers locked at 0, or at given values, with buildReducedModel), the
limits are the URDF's as Pinocchio reads them, the sphere centres are the link frames'
placements applied to the sphere file's offsets, and the dynamics is pinocchio.aba.
"""

from pathlib import Path

import numpy as np
import pinocchio as pin
import yaml

REPO = Path(__file__).resolve().parents[1]
PANDA_SPHERES = REPO / 'config' / 'spheres' / 'panda.yaml'
PANDA_JOINTS = [f'panda_joint{i}' for i in range(1, 8)]


def find_panda_urdf():
    """Return the path of example-robot-data's panda.urdf (searched below site-packages)."""
    import site
    for root in site.getsitepackages():
        for path in Path(root).glob('cmeel.prefix/share/example-robot-data/robots/'
                                    'panda_description/urdf/panda.urdf'):
            return path
    raise AssertionError('example-robot-data panda.urdf not found')


class ArmOracle:
    """The Panda (7 joints, fingers locked at 0) and its collision spheres, independently."""

    def __init__(self, urdf_text, spheres_path=PANDA_SPHERES, joints=PANDA_JOINTS, locked=None):
        """locked: {joint: value} of joints not planned (the others locked at 0)."""
        full = pin.buildModelFromXML(urdf_text)
        q_locked = pin.neutral(full)
        for name, value in (locked or {}).items():
            q_locked[full.idx_qs[full.getJointId(name)]] = value
        ids = [full.getJointId(name) for name in full.names[1:] if name not in joints]
        self.model = pin.buildReducedModel(full, ids, q_locked)
        assert list(self.model.names[1:]) == list(joints)
        self.data = self.model.createData()
        self.n = self.model.nq
        self.lower = self.model.lowerPositionLimit.copy()
        self.upper = self.model.upperPositionLimit.copy()
        self.velocity = self.model.velocityLimit.copy()
        self.effort = self.model.effortLimit.copy()
        with open(spheres_path) as stream:
            doc = yaml.safe_load(stream)
        self.spheres = [(self.model.getFrameId(link), np.array(row[:3]), float(row[3]))
                        for link, rows in doc.items() if link != 'ignore_pairs'
                        for row in rows]

    def tip(self, q, link='panda_hand'):
        """Return the pose (pin.SE3) of a link at q."""
        pin.framesForwardKinematics(self.model, self.data, np.asarray(q, dtype=float))
        return pin.SE3(self.data.oMf[self.model.getFrameId(link)])

    def clearance(self, q, obstacles, margin):
        """Return min over robot spheres and obstacles of |p - c| - (r + R + margin)."""
        pin.framesForwardKinematics(self.model, self.data, np.asarray(q, dtype=float))
        worst = np.inf
        for frame, offset, radius in self.spheres:
            centre = self.data.oMf[frame].act(offset)
            for x, y, z, big in obstacles:
                gap = np.linalg.norm(centre - np.array([x, y, z])) - (radius + big + margin)
                worst = min(worst, gap)
        return worst

    def arrays(self, msg):
        """Return (times, q, dq, effort) of a JointTrajectory."""
        times = np.array([p.time_from_start.sec + 1e-9 * p.time_from_start.nanosec
                          for p in msg.points])
        return (times, np.array([p.positions for p in msg.points]),
                np.array([p.velocities for p in msg.points]),
                np.array([p.effort for p in msg.points]))

    def check(self, msg, start, goal, obstacles=(), margin=0.0, goal_tol=1e-6):
        """
        Assert a planned trajectory: names, start, goal, limits at every node, Euler dynamics.

        start / goal: joint positions (rest; start None: a replan from a moving state, not
        checked, its velocities within 1.1 times the limits); obstacles: rows (x, y, z, r).
        Returns the worst clearance (inf without obstacles) and the final time.
        """
        assert list(msg.joint_names) == PANDA_JOINTS
        times, q, dq, u = self.arrays(msg)
        h = np.diff(times)
        assert np.all(h > 0) and np.allclose(h, h[0], rtol=0, atol=2e-9)
        if start is not None:
            assert np.allclose(q[0], start, atol=1e-9) and np.allclose(dq[0], 0.0, atol=1e-9)
        assert np.max(np.abs(q[-1] - goal)) <= goal_tol, q[-1] - goal
        assert np.max(np.abs(dq[-1])) <= goal_tol
        assert np.all(q >= self.lower - 1e-9) and np.all(q <= self.upper + 1e-9)
        # A replan's start is a measured state the tracking may have carried a little past a
        # velocity limit (the solver allows 10 %): the plan keeps the limits from node 1 on.
        first = 0 if start is not None else 1
        assert np.all(np.abs(dq[first:]) <= self.velocity + 1e-9)
        assert np.all(np.abs(dq[0]) <= 1.1 * self.velocity + 1e-9)
        assert np.all(np.abs(u) <= self.effort + 1e-9)
        # The points are the motion of an explicit-Euler plan, each half a step ahead of its
        # node (core/plan_reference.py): the nodes q_k = p_k - h dq_k / 2 are re-integrated
        # here with the piecewise-constant torques (the step from the final time: the
        # message's times are rounded to nanoseconds).
        step = times[-1] / (len(times) - 1)
        nodes = q - 0.5 * step * dq
        for k in range(len(times) - 1):
            acc = pin.aba(self.model, self.data, nodes[k], dq[k], u[k])
            assert np.allclose(nodes[k + 1], nodes[k] + step * dq[k], rtol=0, atol=1e-8)
            assert np.allclose(dq[k + 1], dq[k] + step * acc, rtol=0, atol=1e-7)
        # Clearance at the plan's nodes and at the published points between them.
        worst = min((self.clearance(qk, obstacles, margin) for qk in np.vstack([q, nodes])),
                    default=np.inf) if len(obstacles) else np.inf
        return worst, float(times[-1])
