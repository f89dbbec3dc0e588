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
as the solver: model.kernels.rollout over one step) at a fixed step 1 / integration_rate, in
real time: a timer at ``rate`` runs as many steps as wall time has advanced, then publishes
``joint_states`` (position, velocity, effort = applied u).

Control, evaluated every step: u = sat(u_ff + kp (q_ref - q) + kd (dq_ref - dq)), saturated at
robot.u_max.  A trajectory runs from its receipt; q_ref, dq_ref are its cubic Hermite
interpolation and u_ff its effort held from each point to the next (the solver's
piecewise-constant controls).  A new trajectory preempts the old one, an empty one stops it;
after the last point the PD holds the final position with zero feed-forward.  The subscription
is volatile: a plan latched before the plant started is not executed (it would start from a
state the robot is not in).
``payload_mass_offset`` and ``inertia_scale`` make the plant differ from the solver's model:
cylindrical: hand_mass + offset, inertia * scale; planar_2r: m_p + offset, m1 and m2 * scale;
other models refuse values other than 0 and 1.  kp and kd have one gain per joint.

``~/tracking`` (DiagnosticStatus, 10 Hz) reports the tracking error; ``~/reset``
(std_srvs/Trigger) returns to ``initial_state`` and drops the trajectory.

Run: ``ros2 run toc_ros plant_node --ros-args --params-file config/toc_ros.yaml``
"""

import dataclasses
import sys
import time

from diagnostic_msgs.msg import DiagnosticStatus
import numpy as np
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
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
from trajectory_msgs.msg import JointTrajectory

PARAMETER_NAMES = parameters.PLANT_NODE_NAMES
TRACKING_PERIOD_S = 0.1
# Longer stalls of the timer (suspended process, overloaded machine) are skipped, not replayed.
MAX_CATCH_UP_S = 0.5


RK4 = integrator_id('rk4')
MISMATCH = {'cylindrical': 'robot.hand_mass + payload_mass_offset, robot.inertia * '
                           'inertia_scale',
            'planar_2r': 'm_p + payload_mass_offset, m1 and m2 * inertia_scale'}


def plant_model(params):
    """
    Return the plant's RobotModel: the solver's model with the mismatch knobs applied.

    Raises ProblemError for a bad model, or for mismatch knobs on a model without a mapping.
    """
    model = model_from_parameters(params)
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


class Reference:
    """Reference (q, dq, u_ff) of a trajectory over time since its start; holds the end."""

    def __init__(self, arrays):
        self.n = arrays.positions.shape[1]
        self.times = arrays.times
        self.positions = arrays.positions
        self.velocities = arrays.velocities
        self.efforts = arrays.efforts
        self.duration = float(self.times[-1])

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


class PlantNode(Node):
    """Simulated robot; see the module docstring."""

    def __init__(self, **kwargs):
        super().__init__('plant_node', **kwargs)
        parameters.declare(self, PARAMETER_NAMES)
        self._params = parameters.values(self, PARAMETER_NAMES)
        errors = parameter_errors(self._params)
        if errors:
            raise parameters.ParameterError('; '.join(errors))
        self._apply_parameters()
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._after_set_parameters)
        self._state_pub = self.create_publisher(JointState, 'joint_states', 10)
        self._clock_pub = None    # created when publish_clock is first true
        self._tracking_pub = self.create_publisher(DiagnosticStatus, '~/tracking', 10)
        self.create_subscription(JointTrajectory, 'trajectory', self._on_trajectory, 10)
        self.create_service(Trigger, '~/reset', self._on_reset)
        self._sim_time = 0.0
        self._wall_start = time.monotonic()
        self._reset_state()
        self._step(np.zeros(self._n))   # compile/load the model kernels before the timer
        self._timer = self.create_timer(1.0 / float(self._params['rate']), self._tick)
        self.create_timer(TRACKING_PERIOD_S, self._publish_tracking)
        self.get_logger().info(
            f'ready: state {np.round(self._x, 6).tolist()}, RK4 at '
            f"{self._params['integration_rate']} Hz, joint_states at {self._params['rate']} Hz")

    # -- parameters ---------------------------------------------------------------------------

    def _apply_parameters(self):
        params = self._params
        model = plant_model(params)
        self._model = model
        self._n = model.n_joints
        self._p = model.packed()
        self._u_max = np.asarray(model.u_max, dtype=float)
        self._states = np.empty((2, model.nx))
        self._kp = np.asarray(params['kp'], dtype=float)
        self._kd = np.asarray(params['kd'], dtype=float)
        self._dt = 1.0 / float(params['integration_rate'])

    def _on_set_parameters(self, changed):
        result = parameters.result(parameter_errors(parameters.candidate(self._params,
                                                                         changed)))
        if not result.successful:
            self.get_logger().warning(f'refused parameter change: {result.reason}')
        return result

    def _after_set_parameters(self, changed):
        rate = self._params['rate']
        self._params = parameters.candidate(self._params, changed)
        self._apply_parameters()
        if self._x.shape[0] != self._model.nx:     # another model: its own state size
            self._reset_state()
        if self._params['rate'] != rate:
            self._timer.cancel()
            self.destroy_timer(self._timer)
            self._timer = self.create_timer(1.0 / float(self._params['rate']), self._tick)

    # -- state and trajectory -----------------------------------------------------------------

    def _step(self, u):
        """Return the state after one RK4 step of 1 / integration_rate under control u."""
        self._model.kernels.rollout(np.ascontiguousarray(self._x, dtype=float),
                                    np.ascontiguousarray(u, dtype=float).reshape(1, -1),
                                    self._dt, self._p, RK4, self._states)
        return self._states[1].copy()

    def _reset_state(self):
        x0 = np.asarray(self._params['initial_state'], dtype=float)
        self._x = x0.copy()
        self._u = np.zeros(self._n)
        self._reference = None
        self._ref_start = 0.0
        self._hold = x0[0::2].copy()
        self._max_error = np.zeros(self._n)

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
        self._max_error = np.zeros(self._n)
        if len(arrays.times) == 0:
            self._reference = None
            self._hold = self._x[0::2].copy()
            self.get_logger().info('empty trajectory: stopping, holding the current position')
            return
        self._reference = Reference(arrays)
        self._ref_start = self._sim_time
        self.get_logger().info(f'executing a trajectory of {len(arrays.times)} points, '
                               f'{self._reference.duration:.4f} s')

    def _target(self, sim_time):
        """(q_ref, dq_ref, u_ff) at sim_time."""
        if self._reference is None:
            return self._hold, np.zeros(self._n), np.zeros(self._n)
        return self._reference.at(sim_time - self._ref_start)

    def _control(self, sim_time):
        q_ref, dq_ref, u_ff = self._target(sim_time)
        x = self._x
        u = (u_ff + self._kp * (q_ref - x[0::2]) + self._kd * (dq_ref - x[1::2]))
        return np.clip(u, -self._u_max, self._u_max)

    # -- simulation ---------------------------------------------------------------------------

    @survives_shutdown
    def _tick(self):
        behind = time.monotonic() - self._wall_start - self._sim_time
        if behind > MAX_CATCH_UP_S:
            self.get_logger().warning(f'simulation {behind:.3f} s behind real time: skipping',
                                      throttle_duration_sec=5.0)
            self._wall_start += behind - MAX_CATCH_UP_S
            behind = MAX_CATCH_UP_S
        for _ in range(int(behind / self._dt + 1e-9)):
            self._u = self._control(self._sim_time)
            self._x = self._step(self._u)
            self._sim_time += self._dt
        if not np.all(np.isfinite(self._x)):
            self.get_logger().error('state diverged (non-finite); resetting to initial_state')
            self._reset_state()
        if self._reference is not None:
            q_ref = self._target(self._sim_time)[0]
            self._max_error = np.maximum(self._max_error, np.abs(q_ref - self._x[0::2]))
        self._publish_state()

    def _publish_state(self):
        if self._params['publish_clock']:
            if self._clock_pub is None:
                self._clock_pub = self.create_publisher(Clock, '/clock', 10)
            stamp = conversions.time_msg(self._sim_time)
            self._clock_pub.publish(Clock(clock=stamp))
        else:
            stamp = self.get_clock().now().to_msg()
        msg = JointState()
        msg.header.stamp = stamp
        msg.name = list(self._params['joint_names'])
        msg.position = [float(v) for v in self._x[0::2]]
        msg.velocity = [float(v) for v in self._x[1::2]]
        msg.effort = [float(v) for v in self._u]
        self._state_pub.publish(msg)

    @survives_shutdown
    def _publish_tracking(self):
        q_ref, dq_ref, _ = self._target(self._sim_time)
        error = q_ref - self._x[0::2]
        velocity_error = dq_ref - self._x[1::2]
        if self._reference is None:
            phase, elapsed, duration = 'idle', 0.0, 0.0
        else:
            elapsed = self._sim_time - self._ref_start
            duration = self._reference.duration
            phase = 'tracking' if elapsed < duration else 'holding'
        worst = float(np.max(np.abs(error)))
        values = {'phase': phase, 'time_into_trajectory': elapsed,
                  'trajectory_duration': duration}
        joints = range(1, self._n + 1)
        values.update({f'position_error_q{j}': error[j - 1] for j in joints})
        values.update({f'velocity_error_dq{j}': velocity_error[j - 1] for j in joints})
        values.update({f'max_position_error_q{j}': self._max_error[j - 1] for j in joints})
        values.update({f'effort_u{j}': self._u[j - 1] for j in joints})
        values['sim_time'] = self._sim_time
        self._tracking_pub.publish(conversions.diagnostic_msg(
            self.get_fully_qualified_name(), DiagnosticStatus.OK,
            f'{phase}: |position error| {worst:.3g}', values))


def main(args=None):
    """Run plant_node until shutdown; exit code 2 for invalid parameters."""
    return run_node('plant_node', PlantNode, SingleThreadedExecutor, args=args,
                    errors=(parameters.ParameterError, InvalidParameterValueException,
                            InvalidParameterTypeException),
                    error_prefix='invalid parameters: ')


if __name__ == '__main__':
    sys.exit(main())
