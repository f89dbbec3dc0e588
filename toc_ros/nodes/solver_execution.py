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
solver_node's execute.* link: plans sent as FollowJointTrajectory goals, their outcomes reported.

The client and the goals' rules are execution.py; this module creates the client from the
node's settings (again whenever an execute.* parameter changes), refuses the parameter when
control_msgs is missing, and turns each goal's outcome into a ~/progress report.
"""

from toc_ros import execution
from toc_ros import progress as schema


def refused(flat, changed):
    """Return why a change of execute.follow_joint_trajectory is refused, or None."""
    if flat['execute.follow_joint_trajectory'] and any(
            p.name == 'execute.follow_joint_trajectory' for p in changed):
        reason = execution.follow_joint_trajectory_action()[1]
        if reason:
            return f'execute.follow_joint_trajectory: {reason}'
    return None


class ExecutionLink:
    """The FollowJointTrajectory client of execute.* (none while the action name is empty)."""

    def __init__(self, node):
        self._node = node               # its report(): one ~/progress message
        self._executor = None

    def configure(self, node_settings):
        """(Re)create the client for node_settings' execute.* values."""
        old, self._executor = self._executor, None
        if old is not None:
            old.destroy()
        name = node_settings.execute_action
        if not name:
            return
        logger = self._node.get_logger()
        action_type, reason = execution.follow_joint_trajectory_action()
        if action_type is None:
            logger.error(f'execute.follow_joint_trajectory {name!r} refused: {reason}; '
                         'plans go to the trajectory topic only')
            self._node.report(schema.refusal_report(f'execute.follow_joint_trajectory: {reason}'))
            return
        tolerances = execution.Tolerances(node_settings.execute_path_tolerance,
                                          node_settings.execute_goal_tolerance,
                                          node_settings.execute_goal_time)
        self._executor = execution.TrajectoryExecutor(
            self._node, name, tolerances, self._on_outcome, action_type,
            effort=node_settings.execute_effort)
        logger.info(f'executing plans through {name} (FollowJointTrajectory'
                    + (', with efforts)' if node_settings.execute_effort else ')'))
        self._executor.watch_server(lambda: logger.info(f'action server {name} found'))

    def send(self, trajectory, hold_effort=None):
        """Send a published trajectory as a goal (nothing without a client)."""
        executor = self._executor
        if executor is not None:
            executor.send(trajectory, hold_effort)

    def _on_outcome(self, outcome):
        """Report a goal's outcome; a failed execution of the newest plan is an error."""
        if outcome.kind == execution.ACCEPTED:
            return      # the plan's own report said it was published: no message per goal
        level = schema.DiagnosticStatus.ERROR if outcome.failed else schema.DiagnosticStatus.OK
        self._node.report(schema.ProgressReport(message=outcome.describe(), level=level,
                                                event=schema.EVENT_EXECUTION))
        if outcome.failed:
            # The controller holds the robot where it is; with replan cycles on, the next
            # cycle plans on from the measured state (its deviation starts one at once).
            self._node.get_logger().warning(outcome.describe())
