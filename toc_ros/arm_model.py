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
A URDF arm as solver_node plans for it: the core's ArmRobot plus what the node reads of a model.

States are the core's arm states x = (q_1..q_n, dq_1..dq_n), positions first; joint_states
arrive as (q1, dq1, q2, dq2, ...) and ``full_state`` reorders them.  The messages of an arm
plan are built here: the JointTrajectory (the motion the plan stands for,
core/plan_reference.py), the tip link's path, the braking stop.  Pinocchio's Data is not
thread-safe, so every function here uses its own (the solver thread and the node's thread both
call them).
"""

import dataclasses
import math

from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path
import numpy as np
import pinocchio as pin

from toc_ros import conversions
from toc_ros.core import SolverOptions
from toc_ros.core.arms import ArmError, default_spheres, load_arm, load_spheres
from toc_ros.core.arms.arm_eval import ArmEvaluator
from toc_ros.core.arms.arm_solve import ArmRobot
from toc_ros.core.arms.model import tip_link
from toc_ros.core.arms.payload import with_payload
from toc_ros.core.plan_reference import reference_positions, rest_at_end
from toc_ros.core.problem import Problem, ProblemError
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

# Braking: the stop's duration is searched on this geometric grid [s] (shortest first).
BRAKE_DURATIONS_S = np.geomspace(0.01, 20.0, 60)


class PendingArm:
    """robot.model urdf before any URDF arrived: goals are refused, ~/ready stays false."""

    is_arm = True
    pending = True
    name = 'urdf'
    reason = ('robot.model urdf: no URDF yet (robot_description parameter empty, nothing '
              'received on the robot_description topic)')

    def __init__(self, joint_names):
        """joint_names: the planned joints (their count sizes the measured states)."""
        self.joint_names = tuple(joint_names)
        self.n_joints = len(self.joint_names)
        self.nx = 2 * self.n_joints
        self.kernels = self

    @property
    def joint_model(self):
        """Return the model of the joints (itself)."""
        return self

    def full_state(self, x, effort=None):
        """Return (q, dq) from a joint state (q1, dq1, q2, dq2, ...)."""
        x = np.asarray(x, dtype=float).reshape(-1)
        return np.concatenate([x[0::2], x[1::2]])


class ArmPlanModel(PendingArm):
    """
    A loaded arm: ArmRobot (model, limits, spheres), its tip link and payload.

    Its one model parameter, payload_mass [kg] (a point mass at the origin of payload_link,
    core/arms/payload.py), is what the online estimate (replan.estimate) fits.
    """

    pending = False

    def __init__(self, name, robot, payload_link, payload_mass=0.0):
        """
        Build the plan model of an arm with its payload.

        name: robot.model ('panda', 'ur5', 'urdf'); robot: the core's ArmRobot without payload;
        payload_link: the link carrying payload_mass [kg].
        """
        super().__init__(robot.arm.joint_names)
        self.name = name
        self.bare_robot = robot
        self.payload_link = payload_link
        self.payload_mass = float(payload_mass)
        try:
            arm = with_payload(robot.arm, self.payload_mass, payload_link)
        except ArmError as exc:
            raise ProblemError(f'robot.payload_mass: {exc}') from None
        self.robot = dataclasses.replace(robot, arm=arm)
        self.arm = arm
        self.nu = self.n_joints
        self.u_max = self.arm.effort.copy()

    def parameter_values(self):
        """Return the model's parameters: {'payload_mass': kg}."""
        return {'payload_mass': self.payload_mass}

    def with_parameters(self, values):
        """Return this arm with parameters changed (ProblemError for unknown or bad values)."""
        unknown = set(values) - {'payload_mass'}
        if unknown:
            raise ProblemError(f'URDF arms have no parameter {", ".join(sorted(unknown))} '
                               '(only payload_mass)')
        return ArmPlanModel(self.name, self.bare_robot, self.payload_link,
                            values.get('payload_mass', self.payload_mass))

    def check(self):
        """Return what is wrong with the parameters: nothing (construction refuses bad ones)."""
        return []

    def inverse_dynamics_with(self, values):
        """Return tau(q, dq, ddq) (RNEA) of this arm with the payload of values (estimation)."""
        arm = with_payload(self.bare_robot.arm, values.get('payload_mass', self.payload_mass),
                           self.payload_link)
        data = arm.model.createData()       # its own: the estimator runs off the solver thread
        return lambda q, dq, ddq: arm.inverse_dynamics(q, dq, ddq, data)

    def positions(self, states):
        """Return q of states (..., 2 n)."""
        return np.asarray(states, dtype=float)[..., :self.n_joints]

    def velocities(self, states):
        """Return dq of states (..., 2 n)."""
        return np.asarray(states, dtype=float)[..., self.n_joints:]

    def joint_states(self, states):
        """Return the states as compared between plans (the arm's own layout)."""
        return np.asarray(states, dtype=float)

    def state(self, q, dq=None):
        """Return (q, dq) (default dq = 0)."""
        q = np.asarray(q, dtype=float).reshape(-1)
        return np.concatenate([q, np.zeros_like(q) if dq is None else
                               np.asarray(dq, dtype=float).reshape(-1)])

    def tip_frame(self, link):
        """Return (link name, frame id) of the tip: link, else the model's default."""
        link = tip_link(self.name, self.arm, link)
        return link, self.arm.frame_id(link)

    def tip_poses(self, qs, link):
        """Return the tip's poses (pin.SE3) in the base frame for configurations qs (M, n)."""
        _, frame = self.tip_frame(link)
        model = self.arm.model
        data = model.createData()
        poses = []
        for q in np.asarray(qs, dtype=float).reshape(-1, self.n_joints):
            pin.framesForwardKinematics(model, data, q)
            poses.append(pin.SE3(data.oMf[frame]))
        return poses

    def private_robot(self):
        """Return the ArmRobot with a Data of its own (for use off the solver thread)."""
        own = dataclasses.replace(self.arm, data=self.arm.model.createData())
        return ArmRobot(own, self.robot.spheres, self.robot.self_collision)

    def warm_up(self):
        """Compile (or load from the cache) the arm solver's kernels: tiny solves, sphere rows."""
        from toc_ros.core import solve
        arm = self.arm
        middle = np.where(arm.continuous, 0.0, 0.5 * (arm.lower + arm.upper))
        goal = np.clip(middle + 0.05, arm.lower, arm.upper)
        for integrator in ('euler', 'rk4'):
            solve(Problem(model=self.robot, x0=tuple(self.state(middle)),
                          x_goal=tuple(self.state(goal)), n_intervals=10, integrator=integrator),
                  SolverOptions(mode='fast', max_iterations=3))
        spheres = self.robot.spheres
        if spheres is not None:
            # The sphere rows' kernel runs only for obstacles within the arm's reach, which a
            # solve refuses when they touch its start: called here on an obstacle at the tip.
            tip = arm.frame_position(middle, spheres.links[-1])
            evaluator = ArmEvaluator(arm, spheres, ((*tip, 0.05),), 0.0, 2)
            evaluator.clearance_terms(middle[None, :], np.ones((1, evaluator.n_pairs)))

    def trajectory_msg(self, result, joint_names, stamp, robot=None):
        """
        Build the JointTrajectory of an arm plan (a result or an ExecutingPlan).

        Every node at its time: the positions of the motion the plan stands for (an Euler
        plan's shifted by half a step, core/plan_reference.py), its velocities (a plan that
        ends at rest ends exactly at rest), effort = the torque held from that node; the last
        point's effort is the torque that holds the arm there (robot's gravity torque, robot:
        the ArmRobot planned with, default this arm's) when the plan ends at rest, so that a
        controller that keeps the last point's effort holds the arm, else it repeats the last
        torque.  No accelerations: they jump at every node, and a controller's quintic through
        one value per point would bend the velocity past the limits where the cubic of
        positions and velocities is the motion.
        """
        states = np.asarray(result.states, dtype=float)
        controls = np.asarray(result.controls, dtype=float)
        times = np.asarray(result.time_grid, dtype=float)
        velocities, at_rest = rest_at_end(self.velocities(states))
        # A SolveResult's integrator, or an ExecutingPlan's ('' for a braking stop).
        positions = reference_positions(self.positions(states), velocities, times,
                                        getattr(result, 'integrator', ''))
        last = np.minimum(np.arange(states.shape[0]), controls.shape[0] - 1)
        efforts = controls[last]
        if at_rest:
            efforts[-1] = self.holding_torque(positions[-1], robot)
        msg = JointTrajectory()
        msg.header.stamp = stamp
        msg.joint_names = list(joint_names)
        msg.points = [
            JointTrajectoryPoint(positions=q, velocities=dq, effort=u,
                                 time_from_start=conversions.duration_msg(t))
            for q, dq, u, t in zip(positions.tolist(), velocities.tolist(), efforts.tolist(),
                                   times.tolist())]
        return msg

    def holding_torque(self, q, robot=None):
        """
        Return the torques that hold the arm at q at rest, within its effort limits.

        robot: the ArmRobot to hold (the one planned with, e.g. an estimated payload), else
        this arm's.
        """
        arm = (self.robot if robot is None else robot).arm
        zero = np.zeros(arm.model.nv)
        # Its own Data: this runs beside the solver, which uses the arm's.
        tau = arm.inverse_dynamics(np.asarray(q, dtype=float), zero, zero,
                                   arm.model.createData())
        return np.clip(tau, -arm.effort, arm.effort)

    def path_msg(self, states, link, frame_id, stamp):
        """Return the nav_msgs/Path of the tip link (position and orientation) along states."""
        msg = Path()
        msg.header.frame_id = frame_id
        msg.header.stamp = stamp
        for pose in self.tip_poses(self.positions(states), link):
            entry = PoseStamped(header=msg.header)
            p = pose.translation
            entry.pose.position.x, entry.pose.position.y, entry.pose.position.z = (
                float(p[0]), float(p[1]), float(p[2]))
            x, y, z, w = pin.Quaternion(pose.rotation).coeffs()
            o = entry.pose.orientation
            o.x, o.y, o.z, o.w = float(x), float(y), float(z), float(w)
            msg.poses.append(entry)
        return msg

    def brake(self, x, dt):
        """
        Return (times, states, controls) of a stop from x, or None when none is found.

        Every joint decelerates uniformly to rest over the same duration T (dq(t) =
        dq0 (1 - t / T)); T is the shortest of BRAKE_DURATIONS_S whose inverse-dynamics
        torques stay within the effort limits and whose positions stay within the joint
        limits at every node dt apart.  A stop that cannot keep both (e.g. fast towards a
        limit) is None: the caller sends the empty trajectory (the controller holds).
        """
        x = np.asarray(x, dtype=float).reshape(-1)
        n = self.n_joints
        q0, dq0 = x[:n], x[n:]
        model = self.arm.model
        data = model.createData()
        lower = np.where(self.arm.continuous, -np.inf, self.arm.lower)
        upper = np.where(self.arm.continuous, np.inf, self.arm.upper)
        for duration in BRAKE_DURATIONS_S:
            steps = max(2, int(math.ceil(duration / dt)))
            times = np.linspace(0.0, duration, steps + 1)
            s = times[:, None]
            q = q0 + dq0 * (s - s * s / (2.0 * duration))
            dq = dq0 * (1.0 - s / duration)
            if np.any(q < lower - 1e-9) or np.any(q > upper + 1e-9):
                return None     # longer stops travel further: none keeps the limits
            ddq = -dq0 / duration
            tau = np.array([pin.rnea(model, data, q[k], dq[k], ddq) for k in range(steps)])
            if np.all(np.abs(tau) <= self.arm.effort[None, :]):
                return times, np.hstack([q, dq]), tau
        return None


def build_arm(name, description, joints, locked, limits, spheres_path, tip='',
              payload_mass=0.0):
    """
    Return the ArmPlanModel of a URDF arm (ProblemError with the reason).

    name: 'panda', 'ur5' or 'urdf' (then description is the URDF text); joints: the planned
    joints; spheres_path: a sphere file, or None for the shipped set of panda / ur5; tip: the
    tip link (robot.tip_link, '' for the default), which carries payload_mass [kg].
    """
    source = description if name == 'urdf' else name
    try:
        arm = load_arm(source, joints=list(joints), locked=locked or None, limits=limits or None)
        spheres = (load_spheres(spheres_path, arm) if spheres_path
                   else default_spheres(arm, self_collision=True))
    except (ArmError, OSError) as exc:
        raise ProblemError(f'robot.model {name}: {exc}') from None
    link = tip_link(name, arm, tip)
    try:
        arm.frame_id(link)
    except ArmError as exc:
        raise ProblemError(f'robot.tip_link: {exc}') from None
    return ArmPlanModel(name, ArmRobot(arm, spheres), link, payload_mass)
