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
plant_node: simulated robot (robot.model, default eq. 37) that executes JointTrajectory messages.

The state is integrated with the RK4 step of the solver's model kernels (the same model code
as the solver: model.kernels.rollout over one step) at a fixed step 1 / integration_rate
(rounded to whole nanoseconds), in real time: a timer at ``rate`` runs as many steps as wall
time has advanced, then publishes ``joint_states`` (position, velocity, effort = the u applied
to the plant over the last step) and ``~/reference``.

*Time base.*  The plant counts its own simulated time ``_sim_time`` (whole steps, in integer
nanoseconds).  With ``publish_clock`` true it publishes it on /clock and stamps everything with
it (the other nodes then run with use_sim_time), so a stamp is a simulated time.  With
``publish_clock`` false the stamps are in the node's ROS clock: stamp = _sim_time + offset,
the offset (integer nanoseconds) being taken from the ROS clock at start-up, when publish_clock
changes, when the timer skips a stall (see MAX_CATCH_UP_S) and when the ROS clock jumps by
more than CLOCK_JUMP_S; a received stamp maps back to simulated time as stamp - offset.  So
joint_states stamps are the exact time of the published state, and a trajectory stamped with
a joint_states stamp + d starts exactly d after that state, on the integration step grid.

*Trajectories* (ros2_controllers JointTrajectoryController semantics).  A trajectory's
``header.stamp`` is the time of its time_from_start = 0:

- a zero stamp means "now": it starts at the first step after receipt;
- a stamp in the future is pending: the current trajectory (or hold) goes on until the first
  step at or after the stamp, then the new one replaces it.  A newer trajectory (of any stamp,
  or an empty one) replaces a pending one, which is then never executed;
- a stamp in the past is trimmed: the trajectory starts at once, at the point that
  corresponds to now (partway).  A trajectory that ends before now is refused with a log
  message (as JTC does) and the current one goes on;
- an empty trajectory stops at once: hold the current position (a pending one is dropped).

q_ref, dq_ref are the cubic Hermite interpolation of the points and u_ff their effort held from
each point to the next (the solver's piecewise-constant controls); after the last point the PD
holds the final position with zero feed-forward.  The reference is a function of time only,
evaluated at the step times with the same interpolation before and after a switch: a new
trajectory whose first point equals the old reference at its stamp continues it without a jump.
If the first point has time_from_start > 0, the reference goes (Hermite, zero u_ff) from the
old reference at the activation instant (the stamp, or the receipt for a past or zero stamp) to
that point, as JTC interpolates from the current state.  The subscription is volatile: a plan
latched before the plant started is not executed (it would start from a state the robot is not
in).

*Control*, evaluated every step: u_cmd = sat(u_ff + kp (q_ref - q) + kd (dq_ref - dq)),
saturated at robot.u_max, then the actuator model gives the applied u:

- ``control_delay`` [s] (0: off): u_cmd is delayed by round(control_delay * integration_rate)
  steps (a ring buffer on the step grid, at most MAX_CONTROL_DELAY_S);
- ``actuator_lag`` [s] (0: off): a first-order lag du/dt = (u_in - u) / actuator_lag on the
  delayed command u_in, discretised exactly with u_in held over the step; the u applied over a
  step is the lag's output at the end of that step.  A command step of height U at time T (the
  delay included) thus gives the effort U (1 - exp(-(t - T) / actuator_lag)) in the joint_states
  stamped t.

Both may change at run time (a longer delay repeats the oldest buffered command, a shorter one
drops the oldest commands); ``~/reset`` clears their state (zero commands, zero lag output).
``payload_mass_offset`` and ``inertia_scale`` make the plant's dynamics differ from the
solver's model: cylindrical: hand_mass + offset, inertia * scale; planar_2r: m_p + offset, m1
and m2 * scale; other models refuse values other than 0 and 1.  kp and kd have one gain per
joint.

``~/reference`` (sensor_msgs/JointState, with joint_states and the same stamp): position =
q_ref, velocity = dq_ref, effort = u_ff at the stamp.  ``~/tracking`` (DiagnosticStatus,
10 Hz) reports the tracking error and the trajectory's start stamp; ``~/reset``
(std_srvs/Trigger) returns to ``initial_state`` and drops the trajectories.

*Engines* (``engine``): ``builtin`` integrates robot.model as above; ``mujoco`` simulates the
URDF in ``robot_description`` with MuJoCo (toc_ros.plant.mujoco_arm: ``joint_names`` planned,
the other joints locked at 0, torque motors clamped to the URDF effort limits, no damping or
friction, joint ranges as end stops, RK4 at 1 / integration_rate; payload_mass_offset is a
point mass at ``robot.tip_link``, inertia_scale scales every link).  robot.model is then not
used; joint_names, initial_state, kp and kd size the arm.  The rest (PD + feed-forward,
actuator lag and delay, time base, trajectories, the action) is the same for both.

*FollowJointTrajectory* (``~/follow_joint_trajectory``, control_msgs/action): served with
ros2_controllers JointTrajectoryController's semantics, as implemented (ROS-free) in
toc_ros.plant.follow_joint_trajectory: the goal names every joint (else INVALID_JOINTS),
header.stamp = start (zero: now), splines (linear / cubic / quintic, effort linear), path and
goal tolerances from the goal over JTC's defaults (not enforced, stopped velocity 0.01,
goal_time 0), the result's error_code, feedback (desired, actual, error) every
FEEDBACK_PERIOD_S.  A goal starts at the next integration step from the reference being
followed then (JTC's ``interpolate_from_desired_state``: no jump in the commanded reference
when a replan preempts a goal).  The command is u_ff (the sampled effort) + PD on the sampled
position and velocity, as above.  Either path replaces the other, the newest wins: a valid
goal aborts the active goal (INVALID_GOAL, "Current goal preempted by new incoming action.",
as JTC) and drops a topic trajectory (active or pending); a topic trajectory aborts the active
goal (INVALID_GOAL, "preempted by a trajectory on the trajectory topic") when it starts, so
that the client learns that its goal no longer runs.  Invalid goals are accepted and at once
aborted with their code (JTC rejects them, but a rejection carries no error code in ROS 2).
control_msgs is imported lazily: without it the node runs without the action and says why.

Run: ``ros2 run toc_ros plant_node --ros-args --params-file config/toc_ros.yaml``
"""

from collections import deque
import dataclasses
import math
import sys
import time

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus
import numpy as np
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.task import Future
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger
from toc_ros import conversions
from toc_ros.config import model_from_parameters
from toc_ros.core import ProblemError
from toc_ros.core.horizon import integrator_id
from toc_ros.core.models import CylindricalRobot, Planar2R
from toc_ros.nodes import parameters
from toc_ros.nodes.common import run_node, survives_shutdown
from toc_ros.plant import follow_joint_trajectory as fjt
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

PARAMETER_NAMES = parameters.PLANT_NODE_NAMES
TRACKING_PERIOD_S = 0.1
FEEDBACK_PERIOD_S = 0.05
ACTION_NAME = '~/follow_joint_trajectory'
TOPIC_PREEMPTED = 'preempted by a trajectory on the trajectory topic'
# Longer stalls of the timer (suspended process, overloaded machine) are skipped, not replayed.
MAX_CATCH_UP_S = 0.5
# Without publish_clock: a ROS clock this far from _sim_time + offset re-takes the offset.
CLOCK_JUMP_S = 1.0
MAX_CONTROL_DELAY_S = parameters.MAX_CONTROL_DELAY_S
MAX_ACTUATOR_LAG_S = parameters.MAX_ACTUATOR_LAG_S
NS = 1_000_000_000


RK4 = integrator_id('rk4')
MISMATCH = {'cylindrical': 'robot.hand_mass + payload_mass_offset, robot.inertia * '
                           'inertia_scale',
            'planar_2r': 'm_p + payload_mass_offset, m1 and m2 * inertia_scale'}


def follow_joint_trajectory_action():
    """Return (the FollowJointTrajectory action type, None), or (None, why it is missing)."""
    try:
        from control_msgs.action import FollowJointTrajectory
    except ImportError as exc:
        return None, (f'control_msgs is not installed ({exc}); a ROS install has it '
                      '(ros-jazzy-control-msgs)')
    return FollowJointTrajectory, None


def trajectory_point(positions, velocities, accelerations=None, effort=None):
    """Build a JointTrajectoryPoint of arrays (absent fields stay empty)."""
    point = JointTrajectoryPoint()
    point.positions = [float(v) for v in positions]
    point.velocities = [float(v) for v in velocities]
    if accelerations is not None:
        point.accelerations = [float(v) for v in accelerations]
    if effort is not None:
        point.effort = [float(v) for v in effort]
    return point


class MujocoEngine:
    """
    The plant's dynamics on MuJoCo (engine mujoco): the URDF of robot_description.

    toc_ros.plant.mujoco_arm.MujocoArm with the plant's mismatch knobs (payload_mass_offset on
    robot.tip_link, inertia_scale), stepped at 1 / integration_rate; presents what plant_node
    uses of a RobotModel (n_joints, nx, u_max = the URDF effort limits, check) and a step of
    the interleaved state [q1, dq1, q2, dq2, ...].  mujoco is imported here only.
    """

    name = 'urdf (mujoco)'

    def __init__(self, params):
        try:
            from toc_ros.plant.mujoco_arm import MujocoArm
        except ImportError as exc:
            raise ProblemError(f'engine mujoco needs the mujoco package: {exc}') from None
        if not params['robot_description']:
            raise ProblemError('engine mujoco needs the URDF in robot_description')
        self.arm = MujocoArm(
            params['robot_description'], params['joint_names'],
            tip_link=params.get('robot.tip_link') or None,
            payload_mass_offset=float(params['payload_mass_offset']),
            inertia_scale=float(params['inertia_scale']),
            timestep=1.0 / float(params['integration_rate']))
        self.n_joints = self.arm.n_joints
        self.nx = 2 * self.n_joints
        self.u_max = self.arm.effort_limits.copy()

    def check(self):
        """Return the model's errors: none once MuJoCo compiled it."""
        return []

    def step(self, x, u):
        """Return the interleaved state one time step after x under torque u (clamped)."""
        q, v = self.arm.state()
        if not (np.array_equal(q, x[0::2]) and np.array_equal(v, x[1::2])):
            self.arm.set_state(x[0::2], x[1::2])
        self.arm.step(u)
        q, v = self.arm.state()
        out = np.empty(self.nx)
        out[0::2], out[1::2] = q, v
        return out


def plant_model(params):
    """
    Return the plant's RobotModel: the solver's model with the mismatch knobs applied.

    With engine mujoco: a MujocoEngine of robot_description (robot.model is not used).

    The joints' model: the plant's own actuator_lag and control_delay simulate the drives
    (robot.actuator_lag is what the planner assumes of them).  Raises ProblemError for a bad
    model, or for mismatch knobs on a model without a mapping.
    """
    if params['engine'] == 'mujoco':
        return MujocoEngine(params)
    model = model_from_parameters(params).joint_model
    offset, scale = float(params['payload_mass_offset']), float(params['inertia_scale'])
    if isinstance(model, CylindricalRobot):
        robot = model.params
        return CylindricalRobot(dataclasses.replace(
            robot, hand_mass=robot.hand_mass + offset, inertia=robot.inertia * scale))
    if isinstance(model, Planar2R):
        data = model.params
        return Planar2R(dataclasses.replace(data, m_p=data.m_p + offset, m1=data.m1 * scale,
                                            m2=data.m2 * scale))
    if offset != 0.0 or scale != 1.0:
        raise ProblemError(f'payload_mass_offset and inertia_scale have no meaning for robot '
                           f'model {model.name!r} (defined for cylindrical and planar_2r): '
                           'set them to 0 and 1, or give the plant other robot.model_parameters')
    return model


def actuator_errors(params):
    """Errors of actuator_lag and control_delay (finite, >= 0, at most their maximum)."""
    errors = []
    for name, maximum in (('actuator_lag', MAX_ACTUATOR_LAG_S),
                          ('control_delay', MAX_CONTROL_DELAY_S)):
        try:
            value = float(params[name])
        except (TypeError, ValueError):
            errors.append(f'{name} must be a number of seconds, got {params[name]!r}')
            continue
        if not (math.isfinite(value) and 0.0 <= value <= maximum):
            errors.append(f'{name} must be finite, >= 0 and <= {maximum} s, got {value}')
    return errors


def parameter_errors(params):
    """Everything wrong with a candidate set of plant_node parameters (empty: valid)."""
    try:
        model = plant_model(params)
    except (ProblemError, TypeError, ValueError) as exc:
        return [str(exc)]
    n = model.n_joints
    errors = parameters.joint_name_errors(params['joint_names'], n, model.name)
    errors += parameters.vector_errors('initial_state', params['initial_state'], model.nx)
    errors += parameters.vector_errors('kp', params['kp'], n, minimum=0.0)
    errors += parameters.vector_errors('kd', params['kd'], n, minimum=0.0)
    errors += actuator_errors(params)
    errors += [e + f' (plant: {MISMATCH.get(model.name, "")})' for e in model.check()]
    if not float(params['integration_rate']) >= float(params['rate']):
        errors.append(f"integration_rate ({params['integration_rate']} Hz) must be >= rate "
                      f"({params['rate']} Hz)")
    return errors


def hermite(t0, t1, p0, v0, p1, v1, t):
    """Cubic Hermite position and velocity at t in [t0, t1] (arrays per joint)."""
    h = t1 - t0
    s = (t - t0) / h
    s2, s3 = s * s, s * s * s
    pos = ((2 * s3 - 3 * s2 + 1) * p0 + (s3 - 2 * s2 + s) * h * v0
           + (3 * s2 - 2 * s3) * p1 + (s3 - s2) * h * v1)
    vel = ((6 * s2 - 6 * s) / h * p0 + (3 * s2 - 4 * s + 1) * v0
           + (6 * s - 6 * s2) / h * p1 + (3 * s2 - 2 * s) * v1)
    return pos, vel


def stamp_ns(stamp):
    """Integer nanoseconds of a builtin_interfaces/Time."""
    return int(stamp.sec) * NS + int(stamp.nanosec)


def time_of_ns(total):
    """builtin_interfaces/Time of integer nanoseconds (>= 0)."""
    return Time(sec=total // NS, nanosec=total % NS)


class Reference:
    """Reference (q, dq, u_ff) of a trajectory over time since its start; holds the end."""

    def __init__(self, times, positions, velocities, efforts=None):
        self.n = positions.shape[1]
        self.times = times
        self.positions = positions
        self.velocities = velocities
        self.efforts = efforts
        self.duration = float(self.times[-1])

    @classmethod
    def of(cls, arrays):
        """Build the Reference of conversions.TrajectoryArrays."""
        return cls(arrays.times, arrays.positions, arrays.velocities, arrays.efforts)

    def starting_from(self, t, q, dq):
        """Return this reference led in from (q, dq) at time t when its first point is later."""
        if not self.times[0] > t:
            return self
        zero = np.zeros((1, self.n))
        efforts = None if self.efforts is None else np.vstack([zero, self.efforts])
        return Reference(np.concatenate([[t], self.times]),
                         np.vstack([np.reshape(q, (1, -1)), self.positions]),
                         np.vstack([np.reshape(dq, (1, -1)), self.velocities]), efforts)

    def at(self, t):
        """(q_ref, dq_ref, u_ff) at time t [s] after the start."""
        times = self.times
        zero = np.zeros(self.n)
        if t >= self.duration:
            return self.positions[-1], zero, zero
        if t < times[0]:
            return self.positions[0], zero, zero
        i = int(np.searchsorted(times, t, side='right')) - 1
        pos, vel = hermite(times[i], times[i + 1], self.positions[i], self.velocities[i],
                           self.positions[i + 1], self.velocities[i + 1], t)
        return pos, vel, (zero if self.efforts is None else self.efforts[i])


@dataclasses.dataclass
class Scheduled:
    """A trajectory and its start (stamp) and activation time, in simulated nanoseconds."""

    reference: Reference
    start_ns: int          # simulated time of time_from_start = 0
    activate_ns: int       # first step at or after this runs it: max(stamp, receipt)


class PlantNode(Node):
    """Simulated robot; see the module docstring."""

    def __init__(self, **kwargs):
        super().__init__('plant_node', **kwargs)
        parameters.declare(self, PARAMETER_NAMES)
        self._params = parameters.values(self, PARAMETER_NAMES)
        errors = parameter_errors(self._params)
        if errors:
            raise parameters.ParameterError('; '.join(errors))
        self._delay = deque()
        self._u_lag = None
        self._apply_parameters()
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._after_set_parameters)
        self._state_pub = self.create_publisher(JointState, 'joint_states', 10)
        self._reference_pub = self.create_publisher(JointState, '~/reference', 10)
        self._clock_pub = None    # created when publish_clock is first true
        self._tracking_pub = self.create_publisher(DiagnosticStatus, '~/tracking', 10)
        self.create_subscription(JointTrajectory, 'trajectory', self._on_trajectory, 10)
        self.create_service(Trigger, '~/reset', self._on_reset)
        self._follower = None
        self._goal_futures = {}
        self._sim_ns = 0
        self._sim_time = 0.0
        self._wall_start = time.monotonic()
        self._sync_clock()
        self._reset_state()
        self._step(np.zeros(self._n))   # compile/load the model kernels before the timer
        self._timer = self.create_timer(1.0 / float(self._params['rate']), self._tick)
        self.create_timer(TRACKING_PERIOD_S, self._publish_tracking)
        self._action_type, reason = follow_joint_trajectory_action()
        if self._action_type is None:
            self.get_logger().warning(f'{ACTION_NAME} is not served: {reason}; the trajectory '
                                      'topic works as usual')
        else:
            from rclpy.action import ActionServer, CancelResponse
            self._action_server = ActionServer(
                self, self._action_type, ACTION_NAME, self._execute_goal,
                cancel_callback=lambda _goal: CancelResponse.ACCEPT)
            self.create_timer(FEEDBACK_PERIOD_S, self._publish_feedback)
        self.get_logger().info(
            f'ready: state {np.round(self._x, 6).tolist()}, RK4 at '
            f"{self._params['integration_rate']} Hz, joint_states at {self._params['rate']} Hz")

    # -- parameters ---------------------------------------------------------------------------

    def _apply_parameters(self):
        params = self._params
        model = plant_model(params)
        self._model = model
        self._n = model.n_joints
        self._p = None if isinstance(model, MujocoEngine) else model.packed()
        self._u_max = np.asarray(model.u_max, dtype=float)
        self._states = np.empty((2, model.nx))
        self._kp = np.asarray(params['kp'], dtype=float)
        self._kd = np.asarray(params['kd'], dtype=float)
        self._dt_ns = max(1, int(round(NS / float(params['integration_rate']))))
        self._dt = self._dt_ns / NS
        lag = float(params['actuator_lag'])
        self._lag_decay = math.exp(-self._dt / lag) if lag > 0.0 else 0.0
        self._delay_steps = int(round(float(params['control_delay']) / self._dt))
        if self._u_lag is not None and self._u_lag.shape[0] != self._n:
            self._u_lag = None              # another model: _reset_state follows
        if self._u_lag is not None:
            self._resize_delay()

    def _resize_delay(self):
        """Give the delay buffer _delay_steps commands: repeat the oldest, or drop the oldest."""
        delay = self._delay
        while len(delay) > self._delay_steps:
            delay.popleft()
        oldest = delay[0] if delay else self._u_lag
        while len(delay) < self._delay_steps:
            delay.appendleft(oldest.copy())

    def _on_set_parameters(self, changed):
        result = parameters.result(parameter_errors(parameters.candidate(self._params,
                                                                         changed)))
        if not result.successful:
            self.get_logger().warning(f'refused parameter change: {result.reason}')
        return result

    def _after_set_parameters(self, changed):
        rate, clock = self._params['rate'], self._params['publish_clock']
        self._params = parameters.candidate(self._params, changed)
        self._apply_parameters()
        if self._u_lag is None or self._x.shape[0] != self._model.nx:
            self._reset_state()               # another model: its own state size
        elif list(self._params['joint_names']) != self._follower.joint_names:
            self._new_follower('joint_names changed')
        if self._params['publish_clock'] != clock:
            self._sync_clock()
        if self._params['rate'] != rate:
            self._timer.cancel()
            self.destroy_timer(self._timer)
            self._timer = self.create_timer(1.0 / float(self._params['rate']), self._tick)

    # -- time base ----------------------------------------------------------------------------

    def _sync_clock(self):
        """Take the offset stamp - _sim_time: 0 with publish_clock, else from the ROS clock."""
        if self._params['publish_clock']:
            self._offset_ns = 0
        else:
            self._offset_ns = self.get_clock().now().nanoseconds - self._sim_ns

    def _check_clock(self):
        """Re-take the offset when the ROS clock jumped (e.g. another /clock source)."""
        if self._params['publish_clock']:
            return
        drift = self.get_clock().now().nanoseconds - self._sim_ns - self._offset_ns
        if abs(drift) > CLOCK_JUMP_S * NS:
            self.get_logger().warning(f'ROS clock jumped by {drift / NS:.3f} s against the '
                                      'simulated time: stamps follow it')
            self._offset_ns += drift

    def _stamp(self):
        """Stamp of the current simulated time."""
        return time_of_ns(self._sim_ns + self._offset_ns)

    # -- state and trajectory -----------------------------------------------------------------

    def _step(self, u):
        """Return the state after one RK4 step of 1 / integration_rate under control u."""
        if isinstance(self._model, MujocoEngine):
            return self._model.step(self._x, np.asarray(u, dtype=float))
        self._model.kernels.rollout(np.ascontiguousarray(self._x, dtype=float),
                                    np.ascontiguousarray(u, dtype=float).reshape(1, -1),
                                    self._dt, self._p, RK4, self._states)
        return self._states[1].copy()

    def _reset_state(self):
        x0 = np.asarray(self._params['initial_state'], dtype=float)
        self._x = x0.copy()
        self._u = np.zeros(self._n)
        self._u_lag = np.zeros(self._n)
        self._delay = deque(np.zeros(self._n) for _ in range(self._delay_steps))
        self._active = None                  # the Scheduled trajectory being executed
        self._pending = None                 # a Scheduled trajectory with a future stamp
        self._hold = x0[0::2].copy()
        self._max_error = np.zeros(self._n)
        self._new_follower('the plant was reset')

    def _new_follower(self, reason):
        """Abort the action goals (reason) and start a follower for the current joints."""
        if self._follower is not None:
            self._end_goals(reason)
        self._follower = fjt.TrajectoryFollower(self._params['joint_names'],
                                                interpolate_from_desired_state=True)
        self._following = False     # the follower (an action goal) drives the reference

    def _end_goals(self, reason, hold=None):
        """Abort the active and pending action goals; the follower holds `hold` if given."""
        self._follower.stop(fjt.INVALID_GOAL, reason, hold)
        self._deliver_outcomes()

    def _on_reset(self, _request, response):
        self._reset_state()
        response.success = True
        response.message = f'reset to initial_state {np.round(self._x, 6).tolist()}'
        self.get_logger().info(response.message)
        return response

    def _on_trajectory(self, msg):
        try:
            arrays = conversions.trajectory_arrays(msg, self._params['joint_names'])
        except conversions.ConversionError as exc:
            self.get_logger().error(f'ignoring trajectory: {exc}')
            return
        if len(arrays.times) == 0:
            if self._following or self._follower.active:
                self._end_goals('stopped by an empty trajectory on the trajectory topic')
            self._following = False
            self._active = self._pending = None
            self._hold = self._x[0::2].copy()
            self._max_error = np.zeros(self._n)
            self.get_logger().info('empty trajectory: stopping, holding the current position')
            return
        reference = Reference.of(arrays)
        now = self._sim_ns
        received = stamp_ns(msg.header.stamp)
        start = now if received == 0 else received - self._offset_ns
        end = start + int(round(reference.duration * NS))
        if end < now:
            self.get_logger().error(
                f'ignoring trajectory: stamped {received / NS:.6f} s, it ended '
                f'{(now - end) / NS:.4f} s ago (a trajectory entirely in the past)')
            return
        when = ('now' if received == 0 else f'in {(start - now) / NS:.4f} s' if start > now
                else f'trimmed: started {(now - start) / NS:.4f} s ago')
        if self._pending is not None:
            self.get_logger().info('a newer trajectory replaces the pending one')
        self._pending = Scheduled(reference, start, max(start, now))
        self.get_logger().info(f'executing a trajectory of {len(arrays.times)} points, '
                               f'{reference.duration:.4f} s, stamp '
                               f'{(start + self._offset_ns) / NS:.9f} ({when})')
        self._activate_due()

    def _activate_due(self):
        """Switch to the pending trajectory when the current step reached its activation."""
        pending = self._pending
        if pending is None or self._sim_ns < pending.activate_ns:
            return
        q, dq, _ = self._target(pending.activate_ns)
        pending.reference = pending.reference.starting_from(
            (pending.activate_ns - pending.start_ns) / NS, q, dq)
        if self._following or self._follower.active:
            self._end_goals(TOPIC_PREEMPTED)
            self._following = False
        self._active, self._pending = pending, None
        self._max_error = np.zeros(self._n)

    def _target(self, sim_ns):
        """(q_ref, dq_ref, u_ff) at simulated time sim_ns [ns]."""
        if self._following:
            sample = self._follower.reference(sim_ns)
            return sample.positions, sample.velocities, sample.effort
        if self._active is None:
            return self._hold, np.zeros(self._n), np.zeros(self._n)
        return self._active.reference.at((sim_ns - self._active.start_ns) / NS)

    def _command(self):
        """Saturated PD + feed-forward command at the current step."""
        x = self._x
        if self._following or self._follower.active:
            q_ref, dq_ref, u_ff = self._follow_step()
        else:
            q_ref, dq_ref, u_ff = self._target(self._sim_ns)
        u = (u_ff + self._kp * (q_ref - x[0::2]) + self._kd * (dq_ref - x[1::2]))
        return np.clip(u, -self._u_max, self._u_max)

    def _follow_step(self):
        """Return the follower's reference at this step (it checks tolerances, starts goals)."""
        before = None
        if self._following:
            sample = self._follower.reference(self._sim_ns)
            before = (sample.positions, sample.velocities, sample.accelerations, sample.effort)
        else:
            q, dq, u_ff = self._target(self._sim_ns)
            before = (q, dq, None, u_ff)
            # The goal starts now: the topic's trajectories (active or pending) are dropped.
            self._active = self._pending = None
            self._following = True
            self._max_error = np.zeros(self._n)
        sample = self._follower.update(self._sim_ns, self._x[0::2], self._x[1::2], before)
        return sample.positions, sample.velocities, sample.effort

    def _actuate(self, u_cmd):
        """Return the u applied over this step: u_cmd delayed, then through the lag."""
        if self._delay_steps:
            self._delay.append(u_cmd)
            u_cmd = self._delay.popleft()
        self._u_lag = u_cmd + (self._u_lag - u_cmd) * self._lag_decay
        return self._u_lag.copy()

    # -- simulation ---------------------------------------------------------------------------

    @survives_shutdown
    def _tick(self):
        behind = time.monotonic() - self._wall_start - self._sim_time
        if behind > MAX_CATCH_UP_S:
            self.get_logger().warning(f'simulation {behind:.3f} s behind real time: skipping',
                                      throttle_duration_sec=5.0)
            skipped = behind - MAX_CATCH_UP_S
            self._wall_start += skipped
            if not self._params['publish_clock']:
                self._offset_ns += int(round(skipped * NS))
            behind = MAX_CATCH_UP_S
        self._check_clock()
        for _ in range(int(behind / self._dt + 1e-9)):
            self._activate_due()
            self._u = self._actuate(self._command())
            self._x = self._step(self._u)
            self._sim_ns += self._dt_ns
            self._sim_time = self._sim_ns / NS
        if not np.all(np.isfinite(self._x)):
            self.get_logger().error('state diverged (non-finite); resetting to initial_state')
            self._reset_state()
        self._activate_due()
        goal = self._follower.goal
        if goal is not None and goal.is_cancel_requested:
            self._follower.cancel(goal, self._x[0::2])
        self._deliver_outcomes()
        if self._active is not None or self._following:
            q_ref = self._target(self._sim_ns)[0]
            self._max_error = np.maximum(self._max_error, np.abs(q_ref - self._x[0::2]))
        self._publish_state()

    def _publish_state(self):
        stamp = self._stamp()
        if self._params['publish_clock']:
            if self._clock_pub is None:
                self._clock_pub = self.create_publisher(Clock, '/clock', 10)
            self._clock_pub.publish(Clock(clock=stamp))
        names = list(self._params['joint_names'])
        msg = JointState()
        msg.header.stamp = stamp
        msg.name = names
        msg.position = [float(v) for v in self._x[0::2]]
        msg.velocity = [float(v) for v in self._x[1::2]]
        msg.effort = [float(v) for v in self._u]
        self._state_pub.publish(msg)
        q_ref, dq_ref, u_ff = self._target(self._sim_ns)
        reference = JointState()
        reference.header.stamp = stamp
        reference.name = names
        reference.position = [float(v) for v in q_ref]
        reference.velocity = [float(v) for v in dq_ref]
        reference.effort = [float(v) for v in u_ff]
        self._reference_pub.publish(reference)

    @survives_shutdown
    def _publish_tracking(self):
        q_ref, dq_ref, _ = self._target(self._sim_ns)
        error = q_ref - self._x[0::2]
        velocity_error = dq_ref - self._x[1::2]
        start = ''
        trajectory = self._follower.trajectory if self._following else None
        if trajectory is not None:
            elapsed = (self._sim_ns - trajectory.start_ns) / NS
            duration = trajectory.times_ns[-1] / NS
            phase = ('goal ' if self._follower.goal is not None else '') + (
                'tracking' if elapsed < duration else 'holding')
            start = trajectory.start_ns + self._offset_ns
            start = f'{start // NS}.{start % NS:09d}'
        elif self._active is None:
            phase, elapsed, duration = 'idle', 0.0, 0.0
        else:
            elapsed = (self._sim_ns - self._active.start_ns) / NS
            duration = self._active.reference.duration
            phase = 'tracking' if elapsed < duration else 'holding'
            start = self._active.start_ns + self._offset_ns
            start = f'{start // NS}.{start % NS:09d}'
        pending = self._pending
        worst = float(np.max(np.abs(error)))
        values = {'phase': phase, 'time_into_trajectory': elapsed,
                  'trajectory_duration': duration, 'trajectory_start': start,
                  'pending_in': ('' if pending is None
                                 else (pending.activate_ns - self._sim_ns) / NS)}
        joints = range(1, self._n + 1)
        values.update({f'position_error_q{j}': error[j - 1] for j in joints})
        values.update({f'velocity_error_dq{j}': velocity_error[j - 1] for j in joints})
        values.update({f'max_position_error_q{j}': self._max_error[j - 1] for j in joints})
        values.update({f'effort_u{j}': self._u[j - 1] for j in joints})
        values['sim_time'] = self._sim_time
        self._tracking_pub.publish(conversions.diagnostic_msg(
            self.get_fully_qualified_name(), DiagnosticStatus.OK,
            f'{phase}: |position error| {worst:.3g}', values))

    # -- FollowJointTrajectory ------------------------------------------------------------------

    async def _execute_goal(self, goal_handle):
        """Run one goal to its end: validate, follow (possibly preempted), return the result."""
        request = goal_handle.request
        names = list(self._params['joint_names'])
        try:
            trajectory = fjt.validate(request.trajectory, names, self._sim_ns + self._offset_ns)
        except fjt.GoalError as exc:
            self.get_logger().error(f'goal refused, error_code {exc.code}: {exc.text}')
            goal_handle.abort()
            return self._action_type.Result(error_code=exc.code, error_string=exc.text)
        if trajectory.start_ns is not None:
            trajectory.start_ns -= self._offset_ns          # stamp -> simulated time
        defaults = fjt.Tolerances.defaults(len(names))
        tolerances, warning = fjt.goal_tolerances(defaults, request, names)
        if warning:
            self.get_logger().warning(warning)
        future = Future()
        self._goal_futures[id(goal_handle)] = future   # goal handles are not hashable
        self._pending = None        # the newest trajectory wins: a pending topic one is dropped
        self._follower.follow(trajectory, tolerances, goal_handle)
        self._deliver_outcomes()
        self.get_logger().info(
            f'executing a goal of {len(trajectory.points)} points, '
            f'{trajectory.times_ns[-1] / NS:.4f} s, '
            + ('now' if trajectory.start_ns is None
               else f'start {(trajectory.start_ns + self._offset_ns) / NS:.9f}'))
        outcome = await future
        result = self._action_type.Result(error_code=outcome.code or 0,
                                          error_string=outcome.text)
        if outcome.code is fjt.CANCELED:
            goal_handle.canceled()
        elif outcome.code == fjt.SUCCESSFUL:
            goal_handle.succeed()
        else:
            goal_handle.abort()
        # rclpy refuses different severities from one call site: two calls.
        if outcome.code == fjt.SUCCESSFUL:
            self.get_logger().info(f'goal ended: error_code 0: {outcome.text}')
        else:
            self.get_logger().warning(f'goal ended: error_code {outcome.code}: {outcome.text}')
        return result

    def _deliver_outcomes(self):
        """Wake the execute callbacks of the goals that ended."""
        for outcome in self._follower.take_outcomes():
            future = self._goal_futures.pop(id(outcome.goal), None)
            if future is not None and not future.done():
                future.set_result(outcome)

    @survives_shutdown
    def _publish_feedback(self):
        goal, feedback = self._follower.goal, self._follower.feedback
        if goal is None or feedback is None or not self._following:
            return
        msg = self._action_type.Feedback()
        msg.header.stamp = time_of_ns(feedback.time_ns + self._offset_ns)
        msg.joint_names = list(self._follower.joint_names)
        desired = feedback.desired
        msg.desired = trajectory_point(desired.positions, desired.velocities,
                                       desired.accelerations, desired.effort)
        msg.actual = trajectory_point(feedback.actual_positions, feedback.actual_velocities)
        msg.error = trajectory_point(feedback.error_positions, feedback.error_velocities)
        goal.publish_feedback(msg)


def main(args=None):
    """Run plant_node until shutdown; exit code 2 for invalid parameters."""
    return run_node('plant_node', PlantNode, SingleThreadedExecutor, args=args,
                    errors=(parameters.ParameterError, InvalidParameterValueException,
                            InvalidParameterTypeException),
                    error_prefix='invalid parameters: ')


if __name__ == '__main__':
    sys.exit(main())
