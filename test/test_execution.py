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

"""The outcome rules of executing plans through FollowJointTrajectory (no ROS graph)."""

import pytest

from toc_ros import execution as ex
from toc_ros.plant import follow_joint_trajectory as fjt


def test_error_names_are_the_plant_servers_codes():
    codes = {fjt.SUCCESSFUL: 'SUCCESSFUL', fjt.INVALID_GOAL: 'INVALID_GOAL',
             fjt.INVALID_JOINTS: 'INVALID_JOINTS',
             fjt.OLD_HEADER_TIMESTAMP: 'OLD_HEADER_TIMESTAMP',
             fjt.PATH_TOLERANCE_VIOLATED: 'PATH_TOLERANCE_VIOLATED',
             fjt.GOAL_TOLERANCE_VIOLATED: 'GOAL_TOLERANCE_VIOLATED'}
    assert ex.ERROR_NAMES == codes
    assert ex.PREEMPTED_TEXT == fjt.PREEMPTED


@pytest.mark.parametrize('goal, newest, status, code, text, kind', [
    (3, 3, ex.GOAL_SUCCEEDED, 0, '', ex.SUCCEEDED),
    (3, 3, ex.GOAL_CANCELED, 0, '', ex.CANCELED),
    # The controller preempts an older goal of ours when the newer one arrives.
    (2, 3, ex.GOAL_ABORTED, -1, ex.PREEMPTED_TEXT, ex.PREEMPTED),
    # Any end of an older goal after a newer one was sent: the newer plan has taken over.
    (2, 3, ex.GOAL_ABORTED, -4, 'path tolerance', ex.PREEMPTED),
    (3, 3, ex.GOAL_ABORTED, -4, 'path tolerance', ex.ABORTED),
    (3, 3, ex.GOAL_ABORTED, -2, 'joints', ex.ABORTED),
    # A preemption by someone else's goal (another client) ends ours too.
    (3, 3, ex.GOAL_ABORTED, -1, ex.PREEMPTED_TEXT, ex.PREEMPTED),
    # SUCCEEDED with an error code is not a success.
    (3, 3, ex.GOAL_SUCCEEDED, -5, 'goal tolerance', ex.ABORTED),
])
def test_classify_result(goal, newest, status, code, text, kind):
    outcome = ex.classify_result(goal, newest, status, code, text)
    assert outcome.kind == kind
    assert outcome.goal_id == goal
    assert outcome.failed == (kind in (ex.ABORTED, ex.REJECTED, ex.UNAVAILABLE))


def test_goal_status_values_are_action_msgs():
    from action_msgs.msg import GoalStatus
    assert (ex.GOAL_SUCCEEDED, ex.GOAL_CANCELED, ex.GOAL_ABORTED) == (
        GoalStatus.STATUS_SUCCEEDED, GoalStatus.STATUS_CANCELED, GoalStatus.STATUS_ABORTED)


def test_describe_names_the_code():
    text = ex.Outcome(ex.ABORTED, 4, -4, 'joint 1 off by 0.2 rad').describe()
    assert 'goal 4 aborted' in text and 'PATH_TOLERANCE_VIOLATED' in text and '0.2 rad' in text
    assert ex.Outcome(ex.UNAVAILABLE, 1, text='no action server /x').failed


def test_missing_control_msgs_is_a_reason_not_a_crash():
    action, reason = ex.follow_joint_trajectory_action()
    assert (action is None) == (reason is not None)
    if action is None:
        assert 'control_msgs' in reason
