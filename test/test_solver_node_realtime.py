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
solver_node with the millisecond fast mode, as a real process.

* The node answers get_parameters while fast mode solves 100 circles at N = 8000 (the kernels
  release the GIL, so the executor keeps running).
* Goal -> trajectory: the time from publishing a goal to receiving its trajectory exceeds the
  solve's own wall time (reported on ~/progress) by little (target 20 ms; measured numbers in
  benchmarks/RESULTS.md; the assertion leaves room for a loaded shared machine, the measured
  numbers are printed).
"""

import math
import time

from node_harness import (
    JOINTS, LATCHED, NEAR_GOAL, PAPER_GOAL, PAPER_X0, parameter_round_trips, pose_of, reports,
    running_solver, wait_final, wait_for_plans_to_end)
import numpy as np
import pytest
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger
from toc_ros.core import Status
from toc_ros.goal_requests import ON_PLAN
from trajectory_msgs.msg import JointTrajectory

from diagnostic_msgs.msg import DiagnosticStatus  # noqa: I100 (message packages)

pytestmark = pytest.mark.slow

COLLECT = [(DiagnosticStatus, 'solver_node/progress', 1000),
           (JointTrajectory, 'trajectory', LATCHED)]


@pytest.fixture(scope='module')
def solver(tmp_path_factory):
    with running_solver(tmp_path_factory.mktemp('realtime'), COLLECT, depth=50) as ctx:
        yield ctx


@pytest.fixture(autouse=True)
def at_rest_at_the_start(solver):
    """
    Start each test with no plan executing and the robot measured at rest at PAPER_X0.

    The tests run in any order (pytest-randomly): after the replanning test the robot was
    measured moving along a plan to PAPER_GOAL, and a goal to it then started on that plan's
    remainder (a solve of a few iterations, not the long one a test needs).
    """
    from sensor_msgs.msg import JointState
    wait_for_plans_to_end(solver)
    for _ in range(3):
        solver.joint_states.publish(JointState(
            name=list(JOINTS), position=[PAPER_X0[0], PAPER_X0[2]], velocity=[0.0, 0.0]))
        time.sleep(0.1)


def test_parameters_answer_while_solving_100_circles_at_n_8000(solver):
    client = solver.client
    far = [(4.5 * math.cos(0.06 * k), 4.5 * math.sin(0.06 * k), 0.05) for k in range(99)]
    rows = [(1.0, 1.0, 0.2)] + far
    assert all(r.successful for r in client.set_parameters(
        'solver_node', {'obstacles.max_count': 128, 'solver.N': 8000, 'solver.mode': 'fast'}))
    try:
        solver.obstacles.publish(Float64MultiArray(data=[v for row in rows for v in row]))
        client.wait_for(lambda: len(client.get_parameters(
            'solver_node', ['obstacles.x'])['obstacles.x']) == 100, 10.0, '100 obstacles')
        since = time.monotonic()
        solver.goal_pose.publish(pose_of(PAPER_GOAL))
        client.wait_for(lambda: [r for r in reports(solver, since) if r.solving], 60.0,
                        'the solve to start')
        rounds = parameter_round_trips(solver, 10, 0.05)
        still_solving = not [r for r in reports(solver, since) if r.final]
        client.call(solver.cancel, Trigger.Request(), timeout=10.0)
        final = wait_final(solver, since, 120.0)
    finally:
        client.call(solver.cancel, Trigger.Request(), timeout=10.0)
        client.set_parameters('solver_node', {'solver.N': 100, 'obstacles.max_count': 64})
        solver.obstacles.publish(Float64MultiArray(data=[1.0, 1.0, 0.2]))
    print(f'100 circles, N = 8000: get_parameters round trips median '
          f'{1e3 * np.median(rounds):.1f} ms, max {1e3 * max(rounds):.1f} ms '
          f'(solving throughout: {still_solving}, final {final.status.value})')
    assert still_solving, 'the solve ended before the measurement: make the problem longer'
    # Promised < 100 ms; slack for a loaded 2-core machine on the worst round trip.
    assert np.median(rounds) < 0.1 and max(rounds) < 0.3, rounds


def test_goal_to_trajectory_adds_little_to_the_solve_time(solver):
    client = solver.client
    # replan.rate 0: the repeated goal, not a replan cycle, is what replans here.
    assert all(r.successful for r in client.set_parameters(
        'solver_node', {'solver.N': 300, 'solver.mode': 'fast', 'replan.rate': 0.0}))
    overheads = []
    try:
        for goal in (PAPER_GOAL, NEAR_GOAL) * 3:
            before = client.count('trajectory')
            since = time.monotonic()
            solver.goal_pose.publish(pose_of(goal))
            client.wait_for(lambda b=before: client.count('trajectory') > b, 60.0,
                            'the trajectory')
            received = client.stamped('trajectory', since)[-1][0]
            final = wait_final(solver, since, 120.0)
            assert final.status is Status.SOLVED, final.message
            overheads.append(received - since - final.elapsed_s)
            time.sleep(0.2)
    finally:
        client.set_parameters('solver_node', {'solver.N': 100})
    print('goal -> trajectory minus solve time [ms]: '
          + ', '.join(f'{1e3 * o:.1f}' for o in overheads)
          + f' (median {1e3 * np.median(overheads):.1f})')
    # Target 20 ms (median); a loaded shared machine gets generous slack.
    assert np.median(overheads) < 0.1, overheads


def test_replanning_the_same_goal_while_moving_starts_from_the_plan_remainder(solver):
    """Same goal again while the plan executes: the remainder of the plan seeds the solve."""
    from sensor_msgs.msg import JointState
    client = solver.client
    # replan.rate 0: the repeated goal, not a replan cycle, is what replans here.
    assert all(r.successful for r in client.set_parameters(
        'solver_node', {'solver.N': 300, 'solver.mode': 'fast', 'replan.rate': 0.0}))
    try:
        before = client.count('trajectory')
        since = time.monotonic()
        solver.joint_states.publish(JointState(
            name=['rotation_joint', 'extension_joint'], position=[PAPER_GOAL[0] - 1.0472, 1.0],
            velocity=[0.0, 0.0]))
        time.sleep(0.2)
        solver.goal_pose.publish(pose_of(PAPER_GOAL))
        client.wait_for(lambda: client.count('trajectory') > before, 60.0, 'the first plan')
        first = wait_final(solver, since, 120.0)
        assert first.status is Status.SOLVED, first.message
        plan = client.messages('trajectory', since)[-1]
        # The robot follows the plan: report the planned state at 30 % of it, then re-send the
        # goal (a replan from the moving robot).
        k = int(0.3 * (len(plan.points) - 1))
        point = plan.points[k]
        t_k = point.time_from_start.sec + 1e-9 * point.time_from_start.nanosec
        received = client.stamped('trajectory', since)[-1][0]
        # The plan applies start_lead (0.03 s) after it is published: t_k from then on.
        time.sleep(max(0.0, received + 0.03 + t_k - time.monotonic()))
        solver.joint_states.publish(JointState(
            name=['rotation_joint', 'extension_joint'], position=list(point.positions),
            velocity=list(point.velocities)))
        time.sleep(0.05)
        again = time.monotonic()
        solver.goal_pose.publish(pose_of(PAPER_GOAL))
        second = wait_final(solver, again, 120.0)
    finally:
        client.set_parameters('solver_node', {'solver.N': 100, 'replan.rate': 20.0})
    print(f'replan: {second.iteration} iterations on N = {second.n_intervals} in '
          f'{1e3 * second.elapsed_s:.1f} ms (first plan: {first.iteration} iterations, '
          f'{1e3 * first.elapsed_s:.1f} ms)')
    assert second.status is Status.SOLVED, second.message
    # While the robot moves, on the plan ahead (goal_lead), where the remainder starts.
    assert second.start_source == ON_PLAN
    # The plan's remaining nodes (same tau) and far fewer iterations than the cold plan.
    assert second.n_intervals < 300
    assert second.iteration < 0.6 * first.iteration
