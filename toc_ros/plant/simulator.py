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
The simulated robot of plant_node without ROS: state, drives, trajectories, action goals.

A ``PlantSimulator`` advances the plant by whole integration steps of simulated time (integer
nanoseconds).  Every step it takes the reference of what it follows (a topic trajectory, a
FollowJointTrajectory goal through ``follow_joint_trajectory.TrajectoryFollower``, or a hold),
commands u = sat(u_ff + kp (q_ref - q) + kd (dq_ref - dq)) (u_ff: the trajectory's effort, or
with a position command interface the torque that holds q_ref against gravity), passes it
through the drives (a delay of whole steps, then a first-order lag discretised exactly) and
integrates the applied u (``model.Stepper``).  Topic trajectories are scheduled by their start:
one in the future is pending until its first step, the newest wins, one that ended before now
is refused.  plant_node translates messages into these calls and publishes what it reads back.
"""

from collections import deque
import math

import numpy as np

from toc_ros.plant import follow_joint_trajectory as fjt
from toc_ros.plant.model import Stepper
from toc_ros.plant.reference import NS, Scheduled

TOPIC_PREEMPTED = 'preempted by a trajectory on the trajectory topic'
STOPPED = 'stopped by an empty trajectory on the trajectory topic'
# Longer stalls of the real-time loop (suspended process, overloaded machine) are skipped, not
# replayed.
MAX_CATCH_UP_S = 0.5


def catch_up(behind, dt, max_catch_up=MAX_CATCH_UP_S):
    """
    Return (steps, skipped [s]) of a real-time loop that is behind [s] real time.

    steps of dt make up the lag; a lag beyond max_catch_up is skipped (not simulated) down to
    max_catch_up.  The 1e-9 keeps a lag of exactly k steps from flooring to k - 1; a clock
    ahead of real time (behind < 0) takes no step.
    """
    skipped = 0.0
    if behind > max_catch_up:
        skipped = behind - max_catch_up
        behind = max_catch_up
    return max(int(behind / dt + 1e-9), 0), skipped


def stamp_text(total_ns):
    """Return integer nanoseconds as 'sec.nanosec' (nine digits, exact)."""
    return f'{total_ns // NS}.{total_ns % NS:09d}'


class PlantSimulator:
    """The plant's state, drives and references, advanced by integration steps."""

    def __init__(self, joint_names):
        self.joint_names = list(joint_names)
        self.sim_ns = 0                 # simulated time [ns]: whole steps
        self.follower = None
        self.following = False          # the follower (an action goal) drives the reference
        self.active = None              # the Scheduled topic trajectory being executed
        self.pending = None             # a Scheduled topic trajectory with a future start
        self._ended = []                # outcomes of the goals of replaced followers
        self.x = None
        self.u = None                   # the u applied over the last step
        self.u_lag = None               # the lag's output (None: no state yet)
        self._delay = deque()
        self.feed_forward = True        # False: a position command interface (command())

    # -- set-up -------------------------------------------------------------------------------

    def configure(self, model, kp, kd, integration_rate, actuator_lag, control_delay,
                  command_interface='effort'):
        """
        Take a model, gains and drive settings; return True when the state must be reset.

        command_interface 'position': the drives track the commanded position without the
        trajectory's efforts (command()); goals with efforts are the follower's to refuse.

        The step is 1 / integration_rate rounded to whole nanoseconds.  A longer delay repeats
        the oldest buffered command, a shorter one drops the oldest commands.  A model of
        another size needs reset() (its own state).
        """
        self.model = model
        self.n = model.n_joints
        self.feed_forward = command_interface == 'effort'
        self.u_max = np.asarray(model.u_max, dtype=float)
        self.kp = np.asarray(kp, dtype=float)
        self.kd = np.asarray(kd, dtype=float)
        self.dt_ns = max(1, int(round(NS / float(integration_rate))))
        self.dt = self.dt_ns / NS
        self._step = Stepper(model, self.dt)
        lag = float(actuator_lag)
        self.lag_decay = math.exp(-self.dt / lag) if lag > 0.0 else 0.0
        self.delay_steps = int(round(float(control_delay) / self.dt))
        if self.u_lag is not None and self.u_lag.shape[0] != self.n:
            self.u_lag = None              # another model: reset() follows
        if self.u_lag is not None:
            self._resize_delay()
        return self.u_lag is None or self.x.shape[0] != model.nx

    def _resize_delay(self):
        """Give the delay buffer delay_steps commands: repeat the oldest, or drop the oldest."""
        delay = self._delay
        while len(delay) > self.delay_steps:
            delay.popleft()
        oldest = delay[0] if delay else self.u_lag
        while len(delay) < self.delay_steps:
            delay.appendleft(oldest.copy())

    def reset(self, initial_state, joint_names, reason='the plant was reset'):
        """Return to initial_state: drives cleared, trajectories dropped, goals aborted."""
        x0 = np.asarray(initial_state, dtype=float)
        self.x = x0.copy()
        self.u = np.zeros(self.n)
        self.u_lag = np.zeros(self.n)
        self._delay = deque(np.zeros(self.n) for _ in range(self.delay_steps))
        self.active = self.pending = None
        self.hold = x0[0::2].copy()
        self.max_error = np.zeros(self.n)
        self.new_follower(joint_names, reason)

    def new_follower(self, joint_names, reason):
        """Abort the action goals (reason) and start a follower for joint_names."""
        if self.follower is not None:
            self.end_goals(reason)
            self._ended += self.follower.take_outcomes()
        self.joint_names = list(joint_names)
        self.follower = fjt.TrajectoryFollower(self.joint_names,
                                               interpolate_from_desired_state=True)
        self.following = False

    def end_goals(self, reason, hold=None):
        """Abort the active and pending action goals; the follower holds `hold` if given."""
        self.follower.stop(fjt.INVALID_GOAL, reason, hold)

    def take_outcomes(self):
        """Return the action goals that ended since the last call, oldest first."""
        ended, self._ended = self._ended, []
        return ended + self.follower.take_outcomes()

    def warm_up(self):
        """Take one step without keeping it: compiles or loads the model's kernels."""
        self._step(self.x, np.zeros(self.n))

    @property
    def sim_time(self):
        """Return the simulated time [s]."""
        return self.sim_ns / NS

    @property
    def positions(self):
        """Return the joint positions of the state [q1, dq1, q2, dq2, ...]."""
        return self.x[0::2]

    @property
    def velocities(self):
        """Return the joint velocities of the state."""
        return self.x[1::2]

    # -- trajectories -------------------------------------------------------------------------

    def stop(self):
        """Stop at once (an empty trajectory): hold the current position, drop the rest."""
        if self.following or self.follower.active:
            self.end_goals(STOPPED)
        self.following = False
        self.active = self.pending = None
        self.hold = self.x[0::2].copy()
        self.max_error = np.zeros(self.n)

    def ended_ago_ns(self, reference, start_ns):
        """Return how long [ns] before now reference, started at start_ns, ended (None: not)."""
        end = start_ns + int(round(reference.duration * NS))
        return self.sim_ns - end if end < self.sim_ns else None

    def schedule(self, reference, start_ns):
        """
        Run reference from start_ns [ns] on; return True when it replaced a pending one.

        It becomes active at the first step at or after max(start_ns, now) (a past start is
        trimmed: it runs from the point that corresponds to now).
        """
        replaced = self.pending is not None
        self.pending = Scheduled(reference, start_ns, max(start_ns, self.sim_ns))
        self.activate_due()
        return replaced

    def activate_due(self):
        """Switch to the pending trajectory when the current step reached its activation."""
        pending = self.pending
        if pending is None or self.sim_ns < pending.activate_ns:
            return
        q, dq, _ = self.target(pending.activate_ns)
        pending.reference = pending.reference.starting_from(
            (pending.activate_ns - pending.start_ns) / NS, q, dq)
        if self.following or self.follower.active:
            self.end_goals(TOPIC_PREEMPTED)
            self.following = False
        self.active, self.pending = pending, None
        self.max_error = np.zeros(self.n)

    def follow(self, trajectory, tolerances, goal):
        """Follow an action goal from the next step on (the newest wins: drop a pending one)."""
        self.pending = None
        self.follower.follow(trajectory, tolerances, goal)

    def target(self, sim_ns):
        """(q_ref, dq_ref, u_ff) at simulated time sim_ns [ns]."""
        if self.following:
            sample = self.follower.reference(sim_ns)
            return sample.positions, sample.velocities, sample.effort
        if self.active is None:
            return self.hold, np.zeros(self.n), np.zeros(self.n)
        return self.active.reference.at((sim_ns - self.active.start_ns) / NS)

    # -- stepping -----------------------------------------------------------------------------

    def command(self):
        """Saturated PD + feed-forward command at the current step."""
        x = self.x
        if self.following or self.follower.active:
            q_ref, dq_ref, u_ff = self._follow_step()
        else:
            q_ref, dq_ref, u_ff = self.target(self.sim_ns)
        holding = getattr(self.model, 'holding_torque', None)
        if not self.feed_forward:
            # A position-controlled drive: its own loop on the commanded position with gravity
            # compensation (where the model has gravity), no torque from the trajectory.
            u_ff = holding(q_ref) if holding is not None else np.zeros(self.n)
        elif holding is not None and self.holding():
            # An arm under gravity rests on its holding torque, as its own gravity
            # compensation does; PD alone would sag by g / kp (centimetres at the shoulder).
            u_ff = holding(q_ref)
        u = (u_ff + self.kp * (q_ref - x[0::2]) + self.kd * (dq_ref - x[1::2]))
        return np.clip(u, -self.u_max, self.u_max)

    def holding(self):
        """Tell whether the reference holds a position now (no trajectory moves it)."""
        if self.following:
            return self.follower.holds(self.sim_ns)
        if self.active is None:
            return True
        reference = self.active.reference
        t = (self.sim_ns - self.active.start_ns) / NS
        return t >= reference.duration or t < reference.times[0]

    def _follow_step(self):
        """Return the follower's reference at this step (it checks tolerances, starts goals)."""
        holding = getattr(self.model, 'holding_torque', None)
        held = holding is not None and self.holding()
        if self.following:
            sample = self.follower.reference(self.sim_ns)
            before = (sample.positions, sample.velocities, sample.accelerations, sample.effort)
        else:
            q, dq, u_ff = self.target(self.sim_ns)
            before = (q, dq, None, u_ff)
            # The goal starts now: the topic's trajectories (active or pending) are dropped.
            self.active = self.pending = None
            self.following = True
            self.max_error = np.zeros(self.n)
        if held:
            # The effort this controller commands while it holds (command()): a goal that
            # interpolates from the desired state starts from it.
            before = (*before[:3], holding(before[0]))
        sample = self.follower.update(self.sim_ns, self.x[0::2], self.x[1::2], before)
        return sample.positions, sample.velocities, sample.effort

    def actuate(self, u_cmd):
        """Return the u applied over this step: u_cmd delayed, then through the lag."""
        if self.delay_steps:
            self._delay.append(u_cmd)
            u_cmd = self._delay.popleft()
        self.u_lag = u_cmd + (self.u_lag - u_cmd) * self.lag_decay
        return self.u_lag.copy()

    def run(self, steps):
        """Advance by steps integration steps."""
        for _ in range(steps):
            self.activate_due()
            self.u = self.actuate(self.command())
            self.x = self._step(self.x, self.u)
            self.sim_ns += self.dt_ns

    def finite(self):
        """Tell whether no state value is NaN or infinite: else the simulation diverged."""
        return bool(np.all(np.isfinite(self.x)))

    def track_error(self):
        """Update the largest |q_ref - q| since the trajectory (or goal) started."""
        if self.active is not None or self.following:
            q_ref = self.target(self.sim_ns)[0]
            self.max_error = np.maximum(self.max_error, np.abs(q_ref - self.x[0::2]))

    # -- reports ------------------------------------------------------------------------------

    def tracking(self, offset_ns):
        """
        Return (phase, max |position error|, values) of the tracking report.

        offset_ns: stamp - simulated time; the trajectory's start is given as a stamp.
        """
        q_ref, dq_ref, _ = self.target(self.sim_ns)
        error = q_ref - self.x[0::2]
        velocity_error = dq_ref - self.x[1::2]
        start = ''
        trajectory = self.follower.trajectory if self.following else None
        if trajectory is not None:
            elapsed = (self.sim_ns - trajectory.start_ns) / NS
            duration = trajectory.times_ns[-1] / NS
            phase = ('goal ' if self.follower.goal is not None else '') + (
                'tracking' if elapsed < duration else 'holding')
            start = stamp_text(trajectory.start_ns + offset_ns)
        elif self.active is None:
            phase, elapsed, duration = 'idle', 0.0, 0.0
        else:
            elapsed = (self.sim_ns - self.active.start_ns) / NS
            duration = self.active.reference.duration
            phase = 'tracking' if elapsed < duration else 'holding'
            start = stamp_text(self.active.start_ns + offset_ns)
        pending = self.pending
        values = {'phase': phase, 'time_into_trajectory': elapsed,
                  'trajectory_duration': duration, 'trajectory_start': start,
                  'pending_in': ('' if pending is None
                                 else (pending.activate_ns - self.sim_ns) / NS)}
        joints = range(1, self.n + 1)
        values.update({f'position_error_q{j}': error[j - 1] for j in joints})
        values.update({f'velocity_error_dq{j}': velocity_error[j - 1] for j in joints})
        values.update({f'max_position_error_q{j}': self.max_error[j - 1] for j in joints})
        values.update({f'effort_u{j}': self.u[j - 1] for j in joints})
        values['sim_time'] = self.sim_time
        return phase, float(np.max(np.abs(error))), values
