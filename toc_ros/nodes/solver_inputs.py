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
solver_node's topic inputs: joint states, goals, obstacles and the URDF, translated.

A mixin of SolverNode (its lock, settings, planner and model): each callback converts one
message, refuses what does not convert with the reason (on ~/progress through the planner),
and hands the rest on: joint states to the planner's replan check and the online estimate,
goals to the planner's queue, obstacles and robot_description like a parameter change.
"""

import time

import numpy as np
from rclpy.parameter import Parameter
from toc_ros import arm_config, arm_goals, conversions, goal_requests as goals
from toc_ros.nodes.solver_settings import checked

ARM_REDRAW = 1e-3     # [rad, m, rad/s, m/s] state change that redraws the arm marker


def obstacle_count(msg):
    """Rows of an obstacles message, counted without reading the data (the limit check)."""
    dims = list(msg.layout.dim)
    if dims:
        return int(dims[0].size)
    return len(msg.data) // 3


class SolverInputs:
    """The topic callbacks of SolverNode (see the module docstring)."""

    def _on_joint_states(self, msg):
        with self._lock:
            config = self._config
        names = config.frames.joint_names
        try:
            state = conversions.joint_state_to_state(msg, names)
            # The applied efforts are the actuator states of a model with actuator lag.
            effort = (conversions.joint_state_efforts(msg, names)
                      if config.robot.actuator_lag > 0.0 else None)
        except conversions.ConversionError as exc:
            self.get_logger().warning(f'ignoring joint_states: {exc}', throttle_duration_sec=5.0)
            return
        received = time.monotonic()
        now = self.now()
        stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        state_time = stamp if stamp > 0.0 else now
        with self._lock:
            if self._config is not config:
                # Converted for the joints of settings that changed meanwhile (joint_names of
                # another size): the next message is read with the new ones.
                return
            self._measured = state
            self._measured_effort = effort
            self._measured_time = state_time
            self._measured_received = now
            # Redraw the arm when it moved visibly, not for every message of a resting robot.
            drawn = self._arm_drawn
            if drawn is None or np.shape(drawn) != np.shape(state) \
                    or np.max(np.abs(state - drawn)) > ARM_REDRAW:
                self._arm_dirty = True
        if config.node.replan_estimate:
            self._estimate_from(msg, config, state, state_time)
        self._planner.maybe_replan(config, self._model_state(state, effort), state_time,
                                   received)

    def _model_state(self, joints, effort=None):
        """
        Return the current model's state from a measured joint state and its efforts.

        A model with actuator states (robot.actuator_lag) takes the efforts as the applied ones
        (without them: the torques that hold the joints' velocities); others the joint state.
        self._model follows the robot parameters (KernelLoader.switch): no model is built here,
        on the joint_states path.
        """
        try:
            return self._model.full_state(joints, effort)
        except ValueError:          # e.g. efforts for another joint count: the joint state
            return np.array(joints, dtype=float)

    def _estimate_from(self, msg, config, state, state_time):
        """Feed the online estimator (replan.estimate) with one joint_states sample."""
        try:
            effort = conversions.joint_state_efforts(msg, config.frames.joint_names)
        except conversions.ConversionError as exc:
            effort, why = None, str(exc)
        else:
            why = 'joint_states carry no effort'
        if effort is None:
            self.get_logger().warning(f'replan.estimate: {why}; nothing estimated',
                                      throttle_duration_sec=5.0)
            return
        # The joints' model; the efforts are the applied ones, after any actuator lag.
        self._estimate.add(self._model.joint_model, config.node.replan_estimate,
                           config.node.replan_estimate_window, state_time, state, effort)

    def _pose_goal(self, msg, config):
        """Joint goal of a hand pose by the model's IK, seeded by the start (ConversionError)."""
        start = goals.goal_start(config, self.snapshot()[1], self._planner.plans.current()[0],
                                 self.now(), self.measured_time())[0]
        if config.is_arm:
            return arm_goals.pose_goal(msg, config, start)
        return conversions.pose_to_joint_goal(
            msg, config.frames.base_frame, config.model, tuple(config.node.extension_limits),
            config.node.ik_branch, seed=config.model.positions(start))

    def _on_goal_pose(self, msg):
        self._planner.submit(lambda config: self._pose_goal(msg, config), 'goal_pose')

    def _on_goal_joints(self, msg):
        self._planner.submit(lambda config: arm_goals.joint_goal(msg, config) if config.is_arm
                             else conversions.joint_state_to_state(
                                 msg, config.frames.joint_names), 'goal_joints')

    def _take_topic_value(self, source, translate):
        """Apply a topic's flat value (arm_inputs) like a parameter change, or refuse it."""
        with self._lock:
            config = self._config
        try:
            update = translate(config)
        except conversions.ConversionError as exc:
            self._planner.refuse(source, str(exc))
            return
        if update is None:
            return
        key, value = update
        errors, config = checked(dict(config.flat, **{key: value}))
        if errors:
            self._planner.refuse(source, '; '.join(errors))
            return
        with self._lock:
            self._config = config
            self._arm_dirty = True
        if self._kernels.switch(config.model):
            self.get_logger().info(f'{source}: loading the new robot model')
        if key == arm_config.SPHERES:
            what = f'{len(value)} obstacle sphere(s)'
        elif config.flat['robot.model'] == 'urdf':
            what = 'new URDF'
        else:       # kept: checked and used once robot.model is set to urdf
            what = f"new URDF kept (robot.model {config.flat['robot.model']!r} does not use it)"
        self.get_logger().info(f'{source}: {what}')
        self._planner.data_changed(config)

    def _on_obstacle_markers(self, msg):
        self._take_topic_value('obstacle_markers',
                               lambda config: self._arm_inputs.from_markers(msg, config))

    def _on_robot_description(self, msg):
        self._take_topic_value('robot_description',
                               lambda config: self._arm_inputs.from_description(msg, config))

    def _on_obstacles(self, msg):
        with self._lock:
            limit, arm = self._config.node.max_count, self._config.is_arm
        if arm:     # rows (x, y, z, r)
            self._take_topic_value('obstacles',
                                   lambda config: self._arm_inputs.from_array(msg, config))
            return
        count = obstacle_count(msg)
        if count > limit:    # refused before any per-obstacle work
            self._planner.refuse('obstacles',
                                 f'{count} obstacles exceed obstacles.max_count = {limit}')
            return
        try:
            rows = conversions.obstacle_rows_from_msg(msg)
        except conversions.ConversionError as exc:
            self._planner.refuse('obstacles', str(exc))
            return
        outcome = self.set_parameters_atomically([
            Parameter(f'obstacles.{key}', Parameter.Type.DOUBLE_ARRAY, [row[i] for row in rows])
            for i, key in enumerate(('x', 'y', 'radius'))])
        if not outcome.successful:
            self._planner.refuse('obstacles', outcome.reason)
        else:
            self.get_logger().info(f'obstacles replaced: {len(rows)} circle(s)')
