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
The plan a robot executes, as a typed object, and what new data means for it.

An ``ExecutingPlan`` is the last trajectory published: its start on the node clock, its grid,
states and controls, the goal it drives to and the model it was planned with.  A braking stop
is one too (``result`` None: no solver result to warm-start from, so no replan cycles).  The
functions here tell what the rest of a plan violates under the current obstacles and bounds
(``violation``), when it would enter a true obstacle (``true_conflict_time``), from which
node a warm start fits a measured state (``nearest_node``, ``goal_warm_start``), and build the
braking stop that replaces a plan (``braking_plan``).
"""

import dataclasses
from typing import Any, Optional, Tuple

import numpy as np

from toc_ros.core.obstacles import model_clearance
from toc_ros.core.plan_reference import cubic_at, reference_positions
from toc_ros.core.replan import brake

# Fewest remaining plan nodes for which a goal's solve warm-starts from the executing plan.
MIN_WARM_NODES = 20
# A published trajectory is "executing" until its duration plus this has passed.
EXECUTION_SLACK_S = 0.5


@dataclasses.dataclass
class ExecutingPlan:
    """A published trajectory while it executes (a plan or a braking stop)."""

    start: float                 # its header.stamp [s, node clock]: plan time 0
    times: np.ndarray            # (N + 1,) plan time of each node [s]
    states: np.ndarray           # (N + 1, nx)
    controls: np.ndarray         # (N, nu), piecewise constant
    goal: np.ndarray             # the goal state it drives to (a stop: the abandoned goal)
    source: str                  # where its goal came from
    model: Any                   # the RobotModel it was planned with
    result: Any = None           # the SolveResult (None: a braking stop)
    path_states: Optional[np.ndarray] = None    # the path drawn for it
    goal_active: bool = True     # False once its goal was canceled: nothing drives to it
    joint_names: Tuple[str, ...] = ()   # the names it was published with (its stop's names)

    @property
    def duration(self):
        """Return the plan's length [s]."""
        return float(self.times[-1])

    @property
    def time_grid(self):
        """Return the node times (the name a SolveResult gives them)."""
        return self.times

    @property
    def braking(self):
        """Tell whether this is a braking stop (no solver result behind it)."""
        return self.result is None

    @property
    def replannable(self):
        """Tell whether replan cycles may replace it (a solved plan of an active goal)."""
        return self.result is not None and self.goal_active

    def elapsed(self, now):
        """Return the plan time [s] at node-clock time now."""
        return float(now) - self.start

    def executing(self, now, slack=EXECUTION_SLACK_S):
        """Tell whether it still executes at now (its duration plus slack not yet over)."""
        return self.elapsed(now) <= self.duration + slack

    @property
    def integrator(self):
        """Return the integrator of its nodes ('' for a stop: its nodes are on the motion)."""
        return '' if self.result is None else getattr(self.result, 'integrator', '')

    def published_positions(self):
        """Return the positions of its published points (plan_reference: arms' Euler plans)."""
        q = self.model.positions(self.states)
        if not getattr(self.model, 'is_arm', False):
            return q
        return reference_positions(q, self.model.velocities(self.states), self.times,
                                   self.integrator)

    def start_for(self, x, step=None):
        """
        Return the start of a new plan whose published motion begins at x.

        An arm's Euler plan publishes its nodes half a step ahead (plan_reference): a replan
        from a measured state x starts its nodes half a step behind it, so that the commanded
        motion does not jump ahead by h dq / 2; step: the new plan's h [s] (default this
        plan's, which a replan cycle keeps).  Other plans: x.
        """
        x = np.array(x, dtype=float)
        own = self._shifted_step()
        if own is None:
            return x
        n = self.model.n_joints
        q = x[:n] - 0.5 * (own if step is None else float(step)) * x[n:2 * n]
        arm = self.model.arm         # never past a position limit the measured state is within
        bounded = ~np.asarray(arm.continuous, dtype=bool)
        x[:n] = np.where(bounded, np.clip(q, np.minimum(arm.lower, x[:n]),
                                          np.maximum(arm.upper, x[:n])), q)
        return x

    def published_start(self, start):
        """Return (published positions, velocities) of a start this plan's start_for gave."""
        published = np.array(start, dtype=float)
        step = self._shifted_step()
        if step is not None:
            n = self.model.n_joints
            published[:n] += 0.5 * step * published[n:2 * n]
        return published

    def _shifted_step(self):
        """Return the step h of an arm's Euler plan (published h dq / 2 ahead), else None."""
        if not getattr(self.model, 'is_arm', False) or self.integrator != 'euler' \
                or self.times.shape[0] < 2:
            return None
        return float(self.times[1] - self.times[0])

    def reference_positions(self, t):
        """
        Return the joint positions the plan holds at plan time t.

        An arm's: the cubic through its published points, the motion its controller follows.
        Other robots' (their points are the nodes, and they have no velocity limits to keep):
        linear between the nodes.
        """
        if getattr(self.model, 'is_arm', False):
            return cubic_at(self.times, self.published_positions(),
                            self.model.velocities(self.states), t)
        q_plan = self.model.positions(self.states)
        return np.array([np.interp(t, self.times, q_plan[:, j])
                         for j in range(q_plan.shape[1])])

    def deviation(self, state, t):
        """Return max |q - q_ref| [rad or m] of a measured state at plan time t."""
        return float(np.max(np.abs(self.model.positions(state) - self.reference_positions(t))))

    def same_goal(self, model, goal):
        """Tell whether it drives model to goal (the same model, the same joint goal)."""
        return self.model == model and np.allclose(
            model.joint_states(self.goal), model.joint_states(goal), rtol=0.0, atol=1e-9)


@dataclasses.dataclass
class Seed:
    """A late replan cycle's plan: the next cycle for the same executing plan starts there."""

    plan: ExecutingPlan          # the executing plan it was solved for
    result: Any
    times: np.ndarray
    states: np.ndarray
    model: Any


def plan_from_result(result, start, goal, source, model, joint_names=()):
    """Return the ExecutingPlan of a solver result published for joint_names."""
    return ExecutingPlan(
        start=float(start), times=np.asarray(result.time_grid, dtype=float),
        states=np.asarray(result.states, dtype=float),
        controls=np.asarray(result.controls, dtype=float), goal=np.array(goal, dtype=float),
        source=source, model=model, result=result, path_states=result.states,
        joint_names=tuple(joint_names))


def braking_plan(plan, measured, now, dt):
    """
    Return the fastest stop from a measured state that replaces plan, or None.

    None when there is no usable state (None or not of the plan's model): then only an empty
    trajectory (the robot holds) can stop it.  The stop keeps the plan's goal (which a replan
    may drive to again) and drawn path.
    """
    model = plan.model
    if measured is None or model is None or np.shape(measured) != (model.nx,):
        return None
    times, states, controls = brake(model, np.asarray(measured, dtype=float), dt)
    return ExecutingPlan(start=float(now), times=times, states=states, controls=controls,
                         goal=plan.goal, source='brake', model=model, result=None,
                         path_states=plan.path_states, goal_active=plan.goal_active,
                         joint_names=plan.joint_names)


def nearest_node(model, states, x):
    """
    Return the index of the plan node nearest to state x in the joints' states.

    The plant lags or leads the plan's clock (mismatch, tracking error), so a warm start from
    the node nearest in state, scaled by each coordinate's spread along the plan, fits better
    than the node at the elapsed time.
    """
    states, x = model.joint_states(states), model.joint_states(np.asarray(x))
    scale = np.maximum(np.ptp(states, axis=0), 1e-6)
    return int(np.argmin(np.sum(((states - x) / scale) ** 2, axis=1)))


def remaining_nodes(times, elapsed):
    """
    Return the mask of the nodes ahead at plan time elapsed, the segment in execution too.

    At rest at the goal (elapsed past the end) the mask holds the last node.
    """
    rest = np.asarray(times) >= elapsed
    if rest.any():
        rest[max(int(np.argmax(rest)) - 1, 0)] = True
    else:
        rest[-1] = True
    return rest


def violation(plan, model, circles, elapsed, tolerance):
    """
    Return what the rest of plan violates for model among circles (inflated), or None.

    model: the robot model of the current data (another state size: planned for another
    model); circles: rows (x, y, radius + margin); tolerance: clearance [m] below zero that
    still counts as clear.  The rest starts with the segment in execution at plan time elapsed.
    """
    if model.nx != plan.states.shape[1]:
        return f'was planned for another robot model (now {model.name!r})'
    rest = remaining_nodes(plan.times, elapsed)
    circles = np.asarray(circles, dtype=float).reshape(-1, 3)
    if len(circles):
        gaps = model_clearance(model, plan.states[rest], circles)
        worst = float(np.min(gaps))
        if worst < -tolerance:
            k = int(np.argmin(np.min(gaps, axis=0))) % len(circles)
            return f'cuts obstacle {k} by {-worst:.3g} m'
    controls = plan.controls[rest[:len(plan.controls)]]
    if len(controls):
        excess = float(np.max(np.abs(controls) - np.asarray(model.u_max)[None, :]))
        if excess > 0.0:
            return f'exceeds u_max by {excess:.3g}'
    return None


def true_conflict_time(plan, rows, elapsed):
    """Return the time [s] until the plan's rest enters a true obstacle (None: never)."""
    model = plan.model
    rows = np.asarray(rows, dtype=float).reshape(-1, 3)
    if model is None or not len(rows) or model.nx != plan.states.shape[1]:
        return None
    rest = plan.times >= elapsed
    if not rest.any():
        return None
    gaps = model_clearance(model, plan.states[rest], rows)
    inside = np.min(gaps, axis=1) < 0.0
    if not inside.any():
        return None
    return float(plan.times[rest][int(np.argmax(inside))] - elapsed)


def goal_warm_start(plan, problem, now, fast_mode, min_nodes=MIN_WARM_NODES):
    """
    Return (problem, initial guess) of a goal's solve while plan executes.

    When the robot moves along a published plan to the same goal (a replan after an obstacle
    or data change, or a repeated goal), fast mode starts from the remainder of that plan
    (states, controls, multipliers from the plan node nearest to problem.x0, the measured
    state), on the plan's remaining nodes (same tau: the remainder is then nearly optimal
    already).  Otherwise, or with fewer than min_nodes left, (problem, None): a cold solve.
    """
    model = problem.robot_model
    if not fast_mode or plan is None or plan.result is None \
            or not plan.same_goal(model, problem.x_goal):
        return problem, None
    k = nearest_node(model, plan.states, problem.x0)
    remainder = plan.result.remainder(plan.times[k])
    nodes = remainder.controls.shape[0]
    if plan.elapsed(now) >= plan.duration or nodes < min_nodes \
            or remainder.controls.shape[1] != model.nu:
        return problem, None
    return dataclasses.replace(problem, n_intervals=nodes), remainder
