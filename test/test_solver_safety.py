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
solver_node as a process under changing data and load (issue 10): no stale plan, bounded work.

Every published trajectory is re-checked here, from its points, against the obstacle set in
force when it was received (an independent segment-to-circle distance).
"""

import math
import threading
import time

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from nav_msgs.srv import GetPlan
from node_harness import (
    A, LATCHED, NEAR_GOAL, NodeProcess, PAPER_GOAL, parameter_round_trips, pose_of, report,
    reports, RosClient, running_solver, SOLVE_TIMEOUT, TEST_PARAMS, wait_final)
import numpy as np
import numpy_model as nm
import pytest
from rclpy.qos import QoSProfile
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger
from toc_ros import progress as schema
from toc_ros.core import Status
from trajectory_msgs.msg import JointTrajectory
from visualization_msgs.msg import MarkerArray

pytestmark = pytest.mark.slow

MARGIN = 0.01
PAPER_OBSTACLES = [(1.0, 1.0, 0.2)]
# The second circle: the paper's plan passes 0.1 m inside it.
NEW_OBSTACLES = [(1.0, 1.0, 0.2), (0.424, 0.424, 0.1)]
COLLECT = [(DiagnosticStatus, 'solver_node/progress', 1000),
           (JointTrajectory, 'trajectory', LATCHED),
           (MarkerArray, 'markers', LATCHED)]


@pytest.fixture(scope='module')
def solver(tmp_path_factory):
    with running_solver(tmp_path_factory.mktemp('safety'), COLLECT, depth=400) as ctx:
        yield ctx


@pytest.fixture
def paper_obstacles(solver):
    """Start from the paper's obstacle set, and restore it afterwards."""
    set_obstacles(solver, PAPER_OBSTACLES)
    yield
    solver.client.call(solver.cancel, Trigger.Request())
    set_obstacles(solver, PAPER_OBSTACLES)


def obstacle_parameters(ctx):
    values = ctx.client.get_parameters(
        'solver_node', ['obstacles.x', 'obstacles.y', 'obstacles.radius'])
    return [tuple(r) for r in zip(values['obstacles.x'], values['obstacles.y'],
                                  values['obstacles.radius'])]


def set_obstacles(ctx, rows):
    """Publish an obstacle set and wait until the node's parameters hold it."""
    ctx.obstacles.publish(Float64MultiArray(data=[float(v) for row in rows for v in row]))
    ctx.client.wait_for(lambda: obstacle_parameters(ctx) == [tuple(r) for r in rows], 10.0,
                        f'obstacles {rows}')
    return time.monotonic()


def clearance(positions, rows, margin=MARGIN, a=A):
    """Smallest distance [m] of the arm segments at the points to the inflated circles."""
    return float(np.min(nm.arm_clearance(positions, rows, a), initial=math.inf)) - margin


def positions(trajectory):
    return [list(p.positions) for p in trajectory.points]


def test_obstacle_change_during_a_solve_restarts_it(solver, paper_obstacles):
    client = solver.client
    assert all(r.successful for r in client.set_parameters('solver_node', {'solver.N': 300}))
    try:
        since = time.monotonic()
        solver.goal_pose.publish(pose_of(PAPER_GOAL))
        client.wait_for(lambda: [r for r in reports(solver, since) if r.solving], 60.0,
                        'the solve to start')
        changed = set_obstacles(solver, NEW_OBSTACLES)
        final = wait_final(solver, since)
    finally:
        client.set_parameters('solver_node', {'solver.N': 100})
    restarts = [r for r in reports(solver, since) if r.event == schema.EVENT_RESTARTED]
    assert restarts, [r.message for r in reports(solver, since)]
    # (A rare CI failure found a final report without an obstacle hash: say which one.)
    assert final.obstacles_hash == schema.obstacles_hash(NEW_OBSTACLES, MARGIN), \
        [(r.status, r.event, r.goal_source, r.message) for r in reports(solver, since)
         if r.final]
    assert final.data_revision == restarts[-1].data_revision
    published = client.stamped('trajectory', since)
    if final.status is not Status.SOLVED:
        # The solver may fail on the harder set (a local method): then nothing is published,
        # in particular not the plan of the old set.
        assert not published, final.message
        return
    assert published
    for received, trajectory in published:
        assert received >= changed - 0.05, 'a trajectory of the old set was published'
        assert clearance(positions(trajectory), NEW_OBSTACLES) >= -1e-6
    # The markers name the set the plan was planned for.
    latest = client.wait_for(lambda: [
        m for m in client.messages('markers', since)
        if any(k.ns == 'plan_info' and final.obstacles_hash in k.text for k in m.markers)],
        10.0, 'markers naming the plan')[-1]
    assert any(k.ns == 'obstacles_info' and final.obstacles_hash in k.text
               for k in latest.markers)


def test_obstacle_change_during_execution_stops_the_plan(solver, paper_obstacles):
    client = solver.client
    since = time.monotonic()
    solver.goal_pose.publish(pose_of(PAPER_GOAL))
    final = wait_final(solver, since)
    assert final.status is Status.SOLVED, final.message
    received, trajectory = client.wait_for(lambda: client.stamped('trajectory', since), 10.0,
                                           'the trajectory')[-1]
    # A circle on the hand's path at 70 % of the trajectory, which is still to come.
    point = trajectory.points[int(0.7 * (len(trajectory.points) - 1))]
    q1, q2 = point.positions
    circle = ((A + q2) * math.cos(q1), (A + q2) * math.sin(q1), 0.05)
    rows = PAPER_OBSTACLES + [circle]
    assert clearance(positions(trajectory), rows) < 0.0
    changed = set_obstacles(solver, rows)
    reach_s = point.time_from_start.sec + 1e-9 * point.time_from_start.nanosec
    assert changed - received < reach_s - 0.2, 'too slow to test: the circle is passed'
    stopped = client.wait_for(lambda: [
        t for t, m in client.stamped('trajectory', received) if not m.points],
        5.0, 'an empty trajectory (stop)')[0]
    assert stopped - changed < 1.0
    notices = client.wait_for(lambda: [r for r in reports(solver, since)
                                       if r.event == schema.EVENT_STOPPED], 5.0, 'the notice')
    assert notices[0].status is Status.CANCELED and 'cuts obstacle' in \
        notices[0].message
    # A replacement plan for the same goal follows; no published trajectory cuts the new set.
    # (Fast mode may finish it before set_obstacles has seen the new parameters: look for it
    # from the first trajectory's arrival on.)
    replan = wait_final(solver, received, source='replan')
    assert replan.event == schema.EVENT_REPLACED
    assert replan.obstacles_hash == schema.obstacles_hash(rows, MARGIN)
    after = [m for t, m in client.stamped('trajectory', received) if t > received]
    assert after and not after[0].points       # the stop first
    for later in after:
        if later.points:
            assert clearance(positions(later), rows) >= -1e-6
            assert later.points[-1].positions.tolist() == pytest.approx(
                [PAPER_GOAL[0], PAPER_GOAL[2]], abs=1e-6)


def test_obstacle_limit_refuses_large_sets(solver, paper_obstacles):
    client = solver.client
    limit = client.get_parameters('solver_node', ['obstacles.max_count'])['obstacles.max_count']
    assert limit == 64
    far = [(5.0 * math.cos(0.1 * k), 5.0 * math.sin(0.1 * k), 0.05) for k in range(5000)]
    for count in (limit + 1, 5000):
        since = time.monotonic()
        solver.obstacles.publish(Float64MultiArray(data=[v for row in far[:count] for v in row]))
        refusal = client.wait_for(lambda: [r for r in reports(solver, since)
                                           if r.event == schema.EVENT_REFUSED], 10.0,
                                  'the refusal')[0]
        assert f'{count} obstacles exceed obstacles.max_count = {limit}' in refusal.message
        started = time.monotonic()
        assert obstacle_parameters(solver) == PAPER_OBSTACLES
        assert time.monotonic() - started < 1.0
    results = client.set_parameters('solver_node', {
        'obstacles.x': [r[0] for r in far[:limit + 1]]})
    assert not results[0].successful      # also refused as parameters (lengths or count)
    set_obstacles(solver, far[:limit])    # the limit itself is accepted


def test_responsive_at_the_obstacle_limit(solver, paper_obstacles):
    """Progress >= 5 Hz, parameters and ~/cancel answer quickly while solving with 64 circles."""
    client = solver.client
    rows = PAPER_OBSTACLES + [(4.5 * math.cos(0.1 * k), 4.5 * math.sin(0.1 * k), 0.05)
                              for k in range(63)]
    set_obstacles(solver, rows)
    assert all(r.successful for r in client.set_parameters(
        'solver_node', {'solver.N': 1000, 'solver.mode': 'paper',
                        'solver.max_iterations': 10 ** 8}))
    try:
        since = time.monotonic()
        solver.goal_pose.publish(pose_of(PAPER_GOAL))
        client.wait_for(lambda: [r for r in reports(solver, since) if r.solving], 60.0,
                        'the solve to start')
        rounds = parameter_round_trips(solver, 10, 0.1)
        time.sleep(1.0)
        started = time.monotonic()
        answer = client.call(solver.cancel, Trigger.Request(), timeout=10.0)
        cancel_s = time.monotonic() - started
        final = wait_final(solver, since, 30.0)
    finally:
        client.set_parameters('solver_node', {'solver.N': 100, 'solver.mode': 'fast',
                                              'solver.max_iterations': 0})
    stamps = [t for t, m in client.stamped('solver_node/progress', since)
              if report(m).solving]
    gaps = np.diff(stamps)
    print(f'64 circles: parameter round trips max {max(rounds):.3f} s, cancel {cancel_s:.3f} s, '
          f'progress gaps max {gaps.max():.3f} s over {len(stamps)} messages')
    assert answer.success and final.status is Status.CANCELED
    # Promised: 100 ms; generous margins for a shared 2-core machine, where one round trip
    # in ten has taken 0.6 s under CI load (both processes wait for a core, not for the solve).
    assert np.median(rounds) < 0.15 and max(rounds) < 1.0 and cancel_s < 1.0
    assert len(stamps) >= 10 and gaps.max() < 0.5


def test_every_request_of_a_burst_is_answered(solver, paper_obstacles):
    client = solver.client
    # rmw_fastrtps delivers every response of a service to every client's response reader
    # (of this process and of others alike), so a burst larger than a client's history depth
    # (default 10) overwrites that client's own answer: every client of a burst needs a depth
    # of at least the burst's size.  The node's own queues are deep enough either way.
    deep = QoSProfile(depth=100)
    plans = [client.node.create_client(GetPlan, client.name('solver_node/plan'),
                                       qos_profile=deep) for _ in range(20)]
    cancels = [client.node.create_client(Trigger, client.name('solver_node/cancel'),
                                         qos_profile=deep) for _ in range(50)]
    for service in plans + cancels:
        assert service.wait_for_service(timeout_sec=30.0)
    # wait_for_service sees the request side matched; give the response side (the node's
    # writer to each new client) time to match too, else a fast answer can be lost in DDS.
    time.sleep(2.0)
    since = time.monotonic()
    done, futures = threading.Semaphore(0), []
    for k, service in enumerate(plans):
        goal = pose_of((NEAR_GOAL[0] + 0.001 * k, 0.0, NEAR_GOAL[2], 0.0))
        future = service.call_async(GetPlan.Request(goal=goal))
        future.add_done_callback(lambda _f: done.release())
        futures.append(future)
    for _ in range(20):
        assert done.acquire(timeout=SOLVE_TIMEOUT), (
            f'~/plan requests {[k for k, f in enumerate(futures) if not f.done()]} of 20 not '
            'answered')
    answers = [f.result() for f in futures]
    assert sum(len(a.plan.poses) > 0 for a in answers) >= 1
    superseded = [r for r in reports(solver, since) if r.status is Status.CANCELED]
    assert len(superseded) >= sum(len(a.plan.poses) == 0 for a in answers)

    futures = [service.call_async(Trigger.Request()) for service in cancels]
    for future in futures:
        future.add_done_callback(lambda _f: done.release())
    for _ in range(50):
        assert done.acquire(timeout=30.0), (
            f'{sum(not f.done() for f in futures)} of 50 ~/cancel requests not answered')
    for service in plans + cancels:
        client.node.destroy_client(service)


def test_only_the_newest_goal_is_solved_after_a_flood(solver, paper_obstacles):
    client = solver.client
    # N = 1000: a solve (tens of ms) outlasts the gap between two flooded goals even on a
    # loaded machine, so no goal but the newest can finish before the next one supersedes it.
    assert client.set_parameters('solver_node', {'solver.N': 1000})[0].successful
    try:
        since = time.monotonic()
        goals = [(NEAR_GOAL[0] + 0.0005 * k, 0.0, NEAR_GOAL[2], 0.0) for k in range(300)]
        for goal in goals:
            solver.goal_pose.publish(pose_of(goal))
        newest = goals[-1]
        final = client.wait_for(lambda: [
            r for r in reports(solver, since) if r.final and r.goal is not None
            and r.goal[0] == pytest.approx(newest[0], abs=1e-9)], SOLVE_TIMEOUT,
            'the result of the newest goal')[0]
    finally:
        client.set_parameters('solver_node', {'solver.N': TEST_PARAMS['solver.N']})
    assert final.status is Status.SOLVED, final.message
    time.sleep(0.5)
    solved = [r for r in reports(solver, since) if r.status is Status.SOLVED]
    assert [r.goal[0] for r in solved] == pytest.approx([newest[0]], abs=1e-9)
    published = [m for m in client.messages('trajectory', since) if m.points]
    assert len(published) == 1
    assert published[0].points[-1].positions[0] == pytest.approx(newest[0], abs=1e-6)


def test_goal_sent_while_the_kernels_compile_is_solved(tmp_path, monkeypatch):
    """A cold numba cache: the node listens at once, queues the goal, solves it once ready."""
    monkeypatch.setenv('NUMBA_CACHE_DIR', str(tmp_path / 'cold_cache'))
    client = RosClient()
    node = NodeProcess('solver_node', client.namespace, tmp_path, {'solver.N': 100})
    try:
        client.collect(DiagnosticStatus, 'solver_node/progress', 100)
        goal_pub = client.node.create_publisher(PoseStamped, client.name('goal_pose'), 10)
        ready = client.node.create_client(Trigger, client.name('solver_node/ready'))
        client.wait_for(lambda: goal_pub.get_subscription_count() > 0, 120.0,
                        'the goal subscription')
        # (~/ready is a query: asked again if the first answer is lost, harness.call)
        answer = client.call(ready, Trigger.Request(), timeout=30.0, attempts=3)
        assert not answer.success, 'the kernels were loaded already: nothing to test'
        assert 'numba kernels loaded' not in node.log()
        since = time.monotonic()
        # Published while the node is not ready; repeated only until the node says it queued
        # it (the first message may precede the publisher's matching on the node's side).
        deadline = time.monotonic() + 60.0
        while not [r for r in reports(client, since) if r.event == schema.EVENT_QUEUED]:
            assert time.monotonic() < deadline, node.log()
            goal_pub.publish(pose_of(NEAR_GOAL))
            time.sleep(1.0)
        assert not client.call(ready, Trigger.Request(), timeout=30.0, attempts=3).success
        # A goal repeated before its 'queued' report came back (the compile holds the GIL) is
        # superseded by the repeat: the newest one is solved.
        final = client.wait_for(
            lambda: [r for r in reports(client, since)
                     if r.final and r.event != schema.EVENT_SUPERSEDED], 400.0,
            "the queued goal's result")[0]
        assert final.status is Status.SOLVED, final.message
        assert 'queued' in node.log()
        assert client.call(ready, Trigger.Request(), timeout=30.0, attempts=3).success
        assert node.stop() == 0, node.log()
    finally:
        node.stop()
        client.close()
