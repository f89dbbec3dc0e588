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

"""Acceptance of the demo: when the plant is at rest at a goal, and the verdict of a run."""

from toc_ros.core import Status

# |q - q_goal| per joint once the plant is at rest [rad, m].  The plant's PD (the default
# gains of parameters.PlantSettings) rests within ~1e-5 of the goal about 0.8 s after the end.
POSITION_TOL = (1e-3, 1e-3)
# At rest: every joint_states sample over SETTLE_WINDOW_S within these bounds.
SETTLE_POSITION = 1e-3      # [rad, m]
SETTLE_VELOCITY = 1e-3      # [rad/s, m/s]
SETTLE_WINDOW_S = 0.3
# Longest wait for rest after the trajectory's end.
SETTLE_TIMEOUT_S = 5.0
# The trajectory must end at the goal (the solver's SOLVED tolerance is far below).
TRAJECTORY_END_TOL = 1e-6


class Settling:
    """Feed joint states (receipt time, positions, velocities); settled() once at rest."""

    def __init__(self, q_goal, not_before):
        self.q_goal = list(q_goal)
        self.not_before = not_before      # receipt time of the trajectory end
        self._window = []                 # receipt times of the resting samples

    def add(self, stamp, positions, velocities):
        """Take one sample; return True once the robot rested for SETTLE_WINDOW_S."""
        errors = [abs(p - g) for p, g in zip(positions, self.q_goal)]
        if (stamp < self.not_before or max(errors) > SETTLE_POSITION
                or max(abs(v) for v in velocities) > SETTLE_VELOCITY):
            self._window.clear()
            return False
        self._window.append(stamp)
        return self._window[-1] - self._window[0] >= SETTLE_WINDOW_S


def reached(errors):
    """Tell whether final errors (rad, m) are within POSITION_TOL."""
    return all(abs(e) <= tol for e, tol in zip(errors, POSITION_TOL))


def success(summary, stages):
    """Return the demo's verdict: every plan SOLVED and reached, every process exited 0."""
    plans = summary['plans']
    loop = summary.get('closed_loop')
    if loop is not None:
        # Each replanning run must arrive and keep the arm out of every true circle.
        for name in ('replanning', 'replanning + estimation'):
            run = loop['runs'].get(name)
            if not run or not run['arrival_s'] == run['arrival_s'] \
                    or not run['min_clearance'] >= 0.0:
                return False
    return (len(plans) == stages and all(
        p.get('status') == Status.SOLVED.value and p.get('reached') for p in plans)
        and summary.get('error') is None
        and all(code == 0 for code in summary.get('exit_codes', {None: 1}).values()))


def arm_success(summary, stages):
    """Return the arm demo's verdict: every goal reached and clear of the spheres, clean exit."""
    done = summary.get('arm_stages', [])
    return (len(done) == stages and all(
        s.get('status') == Status.SOLVED.value and s.get('reached')
        and 'min_clearance' in s and s['min_clearance'] >= 0.0 for s in done)
        and summary.get('error') is None
        and all(code == 0 for code in summary.get('exit_codes', {None: 1}).values()))
