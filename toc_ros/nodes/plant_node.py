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
changes, when the timer skips a stall (see simulator.MAX_CATCH_UP_S) and when the ROS clock
jumps by more than CLOCK_JUMP_S; a received stamp maps back to simulated time as
stamp - offset.  So joint_states stamps are the exact time of the published state, and a
trajectory stamped with a joint_states stamp + d starts exactly d after that state, on the
integration step grid.

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
position and velocity, as above; with ``command_interface`` position (a position-controlled
arm) u_ff is the torque that holds the sampled position against gravity, for goals and topic
trajectories alike, and goals with efforts are refused (INVALID_GOAL, JTC's text).  Either path
replaces the other, the newest wins: a valid goal aborts the active goal (INVALID_GOAL,
"Current goal preempted by new incoming action.", as JTC) and drops a topic trajectory (active
or pending); a topic trajectory aborts the active goal (INVALID_GOAL, "preempted by a
trajectory on the trajectory topic") when it starts, so that the client learns that its goal no
longer runs.  Invalid goals are accepted and at once aborted with their code (JTC rejects them,
but a rejection carries no error code in ROS 2).  control_msgs is imported lazily: without it
the node runs without the action and says why.

The simulation itself (stepping, drives, scheduling, tracking) is ROS-free:
toc_ros.plant.simulator, with the dynamics of toc_ros.plant.model; this node translates.

Run: ``ros2 run toc_ros plant_node --ros-args --params-file config/toc_ros.yaml``
"""

import math
import sys
import time

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
from toc_ros.core import ProblemError
from toc_ros.execution import follow_joint_trajectory_action
from toc_ros.nodes import parameters
from toc_ros.nodes.common import run_node, survives_shutdown
from toc_ros.plant import follow_joint_trajectory as fjt
from toc_ros.plant.model import MISMATCH, plant_model
from toc_ros.plant.reference import NS, Reference
from toc_ros.plant.simulator import catch_up, PlantSimulator
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

PARAMETER_NAMES = parameters.PLANT_NODE_NAMES
TRACKING_PERIOD_S = 0.1
FEEDBACK_PERIOD_S = 0.05
ACTION_NAME = '~/follow_joint_trajectory'
# Without publish_clock: a ROS clock this far from _sim_time + offset re-takes the offset.
CLOCK_JUMP_S = 1.0
MAX_CONTROL_DELAY_S = parameters.MAX_CONTROL_DELAY_S
MAX_ACTUATOR_LAG_S = parameters.MAX_ACTUATOR_LAG_S


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
    # The default gains are two (the planar models'): an arm needs its own, one per joint.
    hint = (f' (one per joint of {model.name}; for an arm see config/panda.yaml and '
            "docs/own_arm.md's kp, kd)")
    for name in ('kp', 'kd'):
        errors += parameters.vector_errors(name, params[name], n, minimum=0.0, size_hint=hint)
    errors += actuator_errors(params)
    errors += [e + f' (plant: {MISMATCH.get(model.name, "")})' for e in model.check()]
    if not float(params['integration_rate']) >= float(params['rate']):
        errors.append(f"integration_rate ({params['integration_rate']} Hz) must be >= rate "
                      f"({params['rate']} Hz)")
    return errors


class PlantNode(Node):
    """Simulated robot; see the module docstring."""

    def __init__(self, **kwargs):
        super().__init__('plant_node', **kwargs)
        parameters.declare(self, PARAMETER_NAMES)
        self._params = parameters.values(self, PARAMETER_NAMES)
        errors = parameter_errors(self._params)
        if errors:
            raise parameters.ParameterError('; '.join(errors))
        self._sim = PlantSimulator(self._params['joint_names'])
        self._apply_parameters()
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._after_set_parameters)
        self._state_pub = self.create_publisher(JointState, 'joint_states', 10)
        self._reference_pub = self.create_publisher(JointState, '~/reference', 10)
        self._clock_pub = None    # created when publish_clock is first true
        self._tracking_pub = self.create_publisher(DiagnosticStatus, '~/tracking', 10)
        self.create_subscription(JointTrajectory, 'trajectory', self._on_trajectory, 10)
        self.create_service(Trigger, '~/reset', self._on_reset)
        self._goal_futures = {}
        self._wall_start = time.monotonic()
        self._sync_clock()
        self._reset_state()
        self._sim.warm_up()     # compile/load the model kernels before the timer
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
            f'ready: state {np.round(self._sim.x, 6).tolist()}, RK4 at '
            f"{self._params['integration_rate']} Hz, joint_states at {self._params['rate']} Hz")

    # -- parameters ---------------------------------------------------------------------------

    def _apply_parameters(self):
        """Configure the simulator; return True when its state must be reset."""
        params = self._params
        return self._sim.configure(plant_model(params), params['kp'], params['kd'],
                                   params['integration_rate'], params['actuator_lag'],
                                   params['control_delay'], params['command_interface'])

    def _on_set_parameters(self, changed):
        result = parameters.result(parameter_errors(parameters.candidate(self._params,
                                                                         changed)))
        if not result.successful:
            self.get_logger().warning(f'refused parameter change: {result.reason}')
        return result

    def _after_set_parameters(self, changed):
        rate, clock = self._params['rate'], self._params['publish_clock']
        self._params = parameters.candidate(self._params, changed)
        if self._apply_parameters():
            self._reset_state()               # another model: its own state size
        elif list(self._params['joint_names']) != self._sim.follower.joint_names:
            self._sim.new_follower(self._params['joint_names'], 'joint_names changed')
            self._deliver_outcomes()
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
            self._offset_ns = self.get_clock().now().nanoseconds - self._sim.sim_ns

    def _check_clock(self):
        """Re-take the offset when the ROS clock jumped (e.g. another /clock source)."""
        if self._params['publish_clock']:
            return
        drift = self.get_clock().now().nanoseconds - self._sim.sim_ns - self._offset_ns
        if abs(drift) > CLOCK_JUMP_S * NS:
            self.get_logger().warning(f'ROS clock jumped by {drift / NS:.3f} s against the '
                                      'simulated time: stamps follow it')
            self._offset_ns += drift

    def _stamp(self):
        """Stamp of the current simulated time."""
        return conversions.time_of_ns(self._sim.sim_ns + self._offset_ns)

    # -- state and trajectory -----------------------------------------------------------------

    def _reset_state(self):
        self._sim.reset(self._params['initial_state'], self._params['joint_names'])
        self._deliver_outcomes()

    def _on_reset(self, _request, response):
        self._reset_state()
        response.success = True
        response.message = f'reset to initial_state {np.round(self._sim.x, 6).tolist()}'
        self.get_logger().info(response.message)
        return response

    def _on_trajectory(self, msg):
        try:
            arrays = conversions.trajectory_arrays(msg, self._params['joint_names'])
        except conversions.ConversionError as exc:
            self.get_logger().error(f'ignoring trajectory: {exc}')
            return
        sim = self._sim
        if len(arrays.times) == 0:
            sim.stop()
            self._deliver_outcomes()
            self.get_logger().info('empty trajectory: stopping, holding the current position')
            return
        reference = Reference.of(arrays)
        now = sim.sim_ns
        received = conversions.nanoseconds(msg.header.stamp)
        start = now if received == 0 else received - self._offset_ns
        ago = sim.ended_ago_ns(reference, start)
        if ago is not None:
            self.get_logger().error(
                f'ignoring trajectory: stamped {received / NS:.6f} s, it ended '
                f'{ago / NS:.4f} s ago (a trajectory entirely in the past)')
            return
        when = ('now' if received == 0 else f'in {(start - now) / NS:.4f} s' if start > now
                else f'trimmed: started {(now - start) / NS:.4f} s ago')
        if sim.pending is not None:
            self.get_logger().info('a newer trajectory replaces the pending one')
        self.get_logger().info(f'executing a trajectory of {len(arrays.times)} points, '
                               f'{reference.duration:.4f} s, stamp '
                               f'{(start + self._offset_ns) / NS:.9f} ({when})')
        sim.schedule(reference, start)
        self._deliver_outcomes()

    # -- simulation ---------------------------------------------------------------------------

    @survives_shutdown
    def _tick(self):
        sim = self._sim
        behind = time.monotonic() - self._wall_start - sim.sim_time
        steps, skipped = catch_up(behind, sim.dt)
        if skipped:
            self.get_logger().warning(f'simulation {behind:.3f} s behind real time: skipping',
                                      throttle_duration_sec=5.0)
            self._wall_start += skipped
            if not self._params['publish_clock']:
                self._offset_ns += int(round(skipped * NS))
        self._check_clock()
        sim.run(steps)
        self._deliver_outcomes()
        if not sim.finite():
            self.get_logger().error('state diverged (non-finite); resetting to initial_state')
            self._reset_state()
        sim.activate_due()
        goal = sim.follower.goal
        if goal is not None and goal.is_cancel_requested:
            sim.follower.cancel(goal, sim.positions)
        self._deliver_outcomes()
        sim.track_error()
        self._publish_state()

    def _publish_state(self):
        stamp = self._stamp()
        if self._params['publish_clock']:
            if self._clock_pub is None:
                self._clock_pub = self.create_publisher(Clock, '/clock', 10)
            self._clock_pub.publish(Clock(clock=stamp))
        names = list(self._params['joint_names'])
        x = self._sim.x
        msg = JointState()
        msg.header.stamp = stamp
        msg.name = names
        msg.position = [float(v) for v in x[0::2]]
        msg.velocity = [float(v) for v in x[1::2]]
        msg.effort = [float(v) for v in self._sim.u]
        self._state_pub.publish(msg)
        q_ref, dq_ref, u_ff = self._sim.target(self._sim.sim_ns)
        reference = JointState()
        reference.header.stamp = stamp
        reference.name = names
        reference.position = [float(v) for v in q_ref]
        reference.velocity = [float(v) for v in dq_ref]
        reference.effort = [float(v) for v in u_ff]
        self._reference_pub.publish(reference)

    @survives_shutdown
    def _publish_tracking(self):
        phase, worst, values = self._sim.tracking(self._offset_ns)
        self._tracking_pub.publish(conversions.diagnostic_msg(
            self.get_fully_qualified_name(), DiagnosticStatus.OK,
            f'{phase}: |position error| {worst:.3g}', values))

    # -- FollowJointTrajectory ------------------------------------------------------------------

    async def _execute_goal(self, goal_handle):
        """Run one goal to its end: validate, follow (possibly preempted), return the result."""
        request = goal_handle.request
        names = list(self._params['joint_names'])
        try:
            trajectory = fjt.validate(
                request.trajectory, names, self._sim.sim_ns + self._offset_ns,
                effort_interface=self._params['command_interface'] == 'effort')
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
        self._sim.follow(trajectory, tolerances, goal_handle)
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
        for outcome in self._sim.take_outcomes():
            future = self._goal_futures.pop(id(outcome.goal), None)
            if future is not None and not future.done():
                future.set_result(outcome)

    @survives_shutdown
    def _publish_feedback(self):
        sim = self._sim
        goal, feedback = sim.follower.goal, sim.follower.feedback
        if goal is None or feedback is None or not sim.following:
            return
        msg = self._action_type.Feedback()
        msg.header.stamp = conversions.time_of_ns(feedback.time_ns + self._offset_ns)
        msg.joint_names = list(sim.follower.joint_names)
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
