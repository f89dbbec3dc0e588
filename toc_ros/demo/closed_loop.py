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
One closed-loop execution against running solver_node and plant_node, and its numbers.

``run_execution`` sets the plant's mismatch and the solver's ``replan.rate``, resets the
plant, sends the obstacles and a joint goal, moves an obstacle during the execution when
told to, waits until the plant rests (or the time is up) and returns
``closed_loop.execution_metrics`` of what it received.  The demo's mismatch stage and
``benchmarks/bench_replanning.py`` both run it.
"""

from dataclasses import dataclass, field
import math
import time
from typing import Optional, Tuple

import numpy as np
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from toc_ros import conversions
from toc_ros.analysis.closed_loop import arrival_time, execution_metrics, PlanSpan
from toc_ros.progress import EVENT_REPLAN_KEPT, EVENT_REPLANNED, progress_from_msg

PROGRESS = 'solver_node/progress'
OBSTACLE_PERIOD_S = 0.1       # a moving obstacle is re-sent at 10 Hz
REST_SPEED = 1e-3             # [rad/s, m/s]: at rest


@dataclass(frozen=True)
class MovingObstacle:
    """Obstacle row `index` moves at `velocity` [m/s] from `start` to `stop` [s after t0]."""

    index: int
    velocity: Tuple[float, float]
    start: float
    stop: float

    def rows(self, base, t):
        """Return the obstacle rows at time t [s after t0]."""
        rows = [list(r) for r in base]
        span = min(max(t - self.start, 0.0), self.stop - self.start)
        rows[self.index][0] += self.velocity[0] * span
        rows[self.index][1] += self.velocity[1] * span
        return tuple(tuple(r) for r in rows)


# The paper's scenario in the loop (cylindrical robot): start and goal of section 4.
PAPER_GOAL_Q = (5.0 * math.pi / 12.0, 1.0)
PAPER_OBSTACLES = ((1.0, 1.0, 0.2),)
# A circle that moves into the paper plan's path while the arm approaches: from 1.8 m to
# 1.3 m from the base along the bearing 0.98 rad at 1 m/s from t = 0.2 s to 0.7 s; the first
# plan's arm sweeps through its final place from t = 1.24 s on.
_BEARING = (math.cos(0.98), math.sin(0.98))
MOVING_OBSTACLES = PAPER_OBSTACLES + ((1.8 * _BEARING[0], 1.8 * _BEARING[1], 0.1),)
MOVING = MovingObstacle(index=1, velocity=(-_BEARING[0], -_BEARING[1]), start=0.2, stop=0.7)
# The plant's model mismatch: payload +20 % (hand_mass 50 -> 60 kg), inertia x 1.2;
# TRUE_ROBOT is the same change as solver parameters (for the true plant's t_min).
MISMATCH = {'payload_mass_offset': 10.0, 'inertia_scale': 1.2}
TRUE_ROBOT = {'robot.hand_mass': 60.0, 'robot.inertia': 193.0 * 1.2}
# What replan.estimate identifies online in that scenario (the plant's changed parameters).
ESTIMATED = ('hand_mass', 'inertia')
NOMINAL_PLANT = {'payload_mass_offset': 0.0, 'inertia_scale': 1.0, 'actuator_lag': 0.0,
                 'control_delay': 0.0}
# A margin that covers the plant's tracking error around a moving circle [m]: with the
# heavier plant it tracks each plan within ~0.01 m while cycles are on time, but a loaded
# machine delays cycles by 2-4 periods, and the arm then drifts several centimetres off the
# plan (benchmarks/RESULTS.md, "The demo's closed loop on a loaded machine").
MOVING_MARGIN = 0.05


@dataclass
class Execution:
    """What run_execution saw: the numbers and the raw series for plots."""

    metrics: dict
    plans: list = field(default_factory=list)        # PlanSpan per published plan
    times: Optional[np.ndarray] = None               # joint_states stamps [s]
    positions: Optional[np.ndarray] = None
    schedule: list = field(default_factory=list)     # [(stamp, rows)] obstacles sent
    reports: list = field(default_factory=list)      # ProgressReport of the replan cycles


def _stamp(msg_stamp):
    return msg_stamp.sec + 1e-9 * msg_stamp.nanosec


def _now(client):
    return client.node.get_clock().now().nanoseconds * 1e-9


def run_execution(client, publishers, model, joint_names, goal_q, obstacles, *,
                  plant=None, replan_rate=20.0, moving=None, margin=None, estimate=(),
                  integrator=None, max_nodes=None, solver=None, timeout=20.0):
    """
    Run one goal in the loop and return an Execution.

    client: a harness.RosClient collecting 'joint_states', 'trajectory' and PROGRESS;
    publishers: (goal_joints, obstacles) publishers; plant: plant_node parameter values for
    this run (mismatch knobs); moving: a MovingObstacle or None; margin, integrator,
    max_nodes: the solver's obstacles.margin, solver.integrator and replan.max_nodes for this
    run, solver: further solver_node parameters for this run (all restored afterwards);
    estimate: its replan.estimate (set anew each run: every run estimates from scratch).
    """
    goal_pub, obstacles_pub = publishers

    def send(rows):
        obstacles_pub.publish(conversions.obstacles_msg(rows))
    temporary = {}
    if margin is not None:
        temporary['obstacles.margin'] = float(margin)
    if integrator is not None:
        temporary['solver.integrator'] = str(integrator)
    if max_nodes is not None:
        temporary['replan.max_nodes'] = int(max_nodes)
    temporary.update(solver or {})
    restore = client.get_parameters('solver_node', list(temporary)) if temporary else {}
    values = dict(temporary, **{'replan.rate': float(replan_rate), 'replan.estimate': Parameter(
        'replan.estimate', Parameter.Type.STRING_ARRAY, [str(n) for n in estimate])})
    _set(client, 'solver_node', values)
    try:
        return _execute(client, goal_pub, send, model, joint_names, goal_q, obstacles, plant,
                        moving, timeout)
    finally:
        if restore:
            _set(client, 'solver_node', restore)


def _execute(client, goal_pub, send, model, joint_names, goal_q, obstacles, plant, moving,
             timeout):
    if plant:
        _set(client, 'plant_node', plant)
    client.trigger('plant_node/reset')
    schedule = [(_now(client), tuple(tuple(r) for r in obstacles))]
    send(obstacles)
    _wait_obstacles(client, obstacles)
    time.sleep(0.3)      # the solver sees the reset state on joint_states
    since = time.monotonic()
    goal = JointState(name=list(joint_names), position=[float(q) for q in goal_q],
                      velocity=[0.0] * len(goal_q))
    goal_pub.publish(goal)
    first = client.wait_for(lambda: client.stamped('trajectory', since), 60.0,
                            'the first trajectory')[0][1]
    t0 = _stamp(first.header.stamp)
    duration = conversions.duration_seconds(first.points[-1].time_from_start)
    deadline = time.monotonic() + min(timeout, 3.0 * duration + 3.0)
    next_move = 0.0
    while time.monotonic() < deadline:
        now = _now(client)
        if moving is not None and now - t0 <= moving.stop + OBSTACLE_PERIOD_S \
                and time.monotonic() >= next_move:
            rows = moving.rows(obstacles, now - t0)
            schedule.append((now, rows))
            send(rows)
            next_move = time.monotonic() + OBSTACLE_PERIOD_S
        if now - t0 > duration and _at_rest(client, joint_names, goal_q, since):
            break
        time.sleep(0.01)
    plans = _plans(client, since)
    # The final error is taken 0.2 s after the last plan's end.
    wait_end = time.monotonic() + 5.0
    while _now(client) < plans[-1].end + 0.25 and time.monotonic() < wait_end:
        time.sleep(0.02)
    plans = _plans(client, since)
    states = [m for _, m in client.stamped('joint_states', since)]
    times = np.array([_stamp(m.header.stamp) for m in states])
    positions = np.array([conversions.joint_state_arrays(m, joint_names)[0] for m in states])
    reports = [progress_from_msg(m) for m in client.messages(PROGRESS, since)]
    cycles = [r for r in reports if r.event in (EVENT_REPLANNED, EVENT_REPLAN_KEPT)]
    latencies = [r.latency_s for r in cycles if r.event == EVENT_REPLANNED]
    kept = sum(r.event == EVENT_REPLAN_KEPT for r in cycles)
    metrics = execution_metrics(model, goal_q, plans, times, positions, schedule,
                                latencies, kept)
    return Execution(metrics, plans, times, positions, schedule, cycles)


def _plans(client, since):
    return [PlanSpan(_stamp(m.header.stamp), conversions.duration_seconds(
        m.points[-1].time_from_start)) for _, m in client.stamped('trajectory', since)
        if m.points]


def true_reference(params, changes, goal_q, obstacles=None, margin=None):
    """
    Return {'t_min', 'arrival_s'} of the best plan for the true plant (nan when unsolved).

    Fast mode on the solver parameters params with changes (the true plant's data); arrival_s
    is that plan's own arrival_time (ARRIVAL_TOL): what a perfect execution of it scores.
    obstacles / margin: the obstacle rows and margin to plan around instead of params' (for a
    moving circle: its final place).
    """
    result, model = _true_plan(params, changes, obstacles, margin)
    if not result.success:
        return {'t_min': math.nan, 'arrival_s': math.nan}
    positions = model.positions(np.asarray(result.states))
    return {'t_min': float(result.final_time),
            'arrival_s': arrival_time(np.asarray(result.time_grid), positions, goal_q)}


def _true_plan(params, changes, obstacles, margin):
    from toc_ros import config
    from toc_ros.core import solve
    values = dict(params, **changes)
    if obstacles is not None:
        for i, key in enumerate(('x', 'y', 'radius')):
            values[f'obstacles.{key}'] = [float(row[i]) for row in obstacles]
    if margin is not None:
        values['obstacles.margin'] = float(margin)
    problem = config.problem_from_parameters(values)
    return solve(problem, config.options_from_parameters(values)), problem.robot_model


def _set(client, node, values):
    results = client.set_parameters(node, values)
    refused = [r.reason for r in results if not r.successful]
    if refused:
        raise RuntimeError(f'{node} refused {values}: {refused}')


def _wait_obstacles(client, rows):
    expected = [[float(v) for v in row] for row in rows]

    def taken():
        values = client.get_parameters(
            'solver_node', ['obstacles.x', 'obstacles.y', 'obstacles.radius'], timeout=5.0)
        got = [list(r) for r in zip(values['obstacles.x'], values['obstacles.y'],
                                    values['obstacles.radius'])]
        return got == expected
    client.wait_for(taken, 30.0, 'solver_node to take the obstacles')


def _at_rest(client, joint_names, goal_q, since):
    msgs = client.messages('joint_states', since)
    if not msgs:
        return False
    q, dq = conversions.joint_state_arrays(msgs[-1], joint_names)
    return (float(np.max(np.abs(q - np.asarray(goal_q)))) < 1e-3
            and float(np.max(np.abs(dq))) < REST_SPEED)
