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

"""solver_node under bad input and load: clear refusals, no crash, bounded memory."""

import math
import time

from diagnostic_msgs.msg import DiagnosticStatus
from nav_msgs.srv import GetPlan
from node_harness import (
    is_final, JOINTS, level_name, NEAR_GOAL, PAPER_GOAL, PAPER_X0, pose,
    pose_of, report, running_solver, SOLVE_TIMEOUT, TEST_PARAMS, wait_for_plans_to_end)
import psutil
import pytest
from rcl_interfaces.srv import GetParameters
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension
from toc_ros.core import Status
from trajectory_msgs.msg import JointTrajectory

pytestmark = pytest.mark.slow

N = TEST_PARAMS['solver.N']


@pytest.fixture(scope='module')
def solver(tmp_path_factory):
    collect = [(DiagnosticStatus, 'solver_node/progress', 1000),
               (JointTrajectory, 'trajectory', 10)]
    with running_solver(tmp_path_factory.mktemp('robust'), collect, depth=100) as ctx:
        yield ctx


def finals(ctx, since):
    return [m for m in ctx.client.messages('solver_node/progress', since) if is_final(m)]


def joints(names, positions, velocities=()):
    return JointState(name=list(names), position=[float(p) for p in positions],
                      velocity=[float(v) for v in velocities])


def state_msg(x):
    return joints(JOINTS, [x[0], x[2]], [x[1], x[3]])


def set_start(ctx, x):
    """Publish a measured state (a few times: the node keeps the latest)."""
    for _ in range(3):
        ctx.joint_states.publish(state_msg(x))
        time.sleep(0.1)


def rows(data, dims=()):
    msg = Float64MultiArray(data=[float(v) for v in data])
    msg.layout.dim = [MultiArrayDimension(label=label, size=size, stride=stride)
                      for label, size, stride in dims]
    return msg


def framed(frame):
    msg = pose_of(PAPER_GOAL)
    msg.header.frame_id = frame
    return msg


# (what, topic attribute, message, text expected in the ERROR progress message)
TOPIC_CASES = [
    ('goal_pose NaN', 'goal_pose', pose(math.nan, 1.0), 'NaN'),
    ('goal_pose inf', 'goal_pose', pose(1.0, math.inf), 'NaN or inf'),
    ('goal_pose wrong frame', 'goal_pose', framed('map'), "frame 'map'"),
    ('goal_pose without frame', 'goal_pose', framed(''), "frame ''"),
    ('goal_pose on the axis', 'goal_pose', pose(0.0, 0.0), 'base axis'),
    ('goal_pose too far', 'goal_pose', pose(10.0, 0.0), 'out of reach'),
    ('goal_pose too near', 'goal_pose', pose(0.05, 0.0), 'out of reach'),
    ('goal_pose in obstacle', 'goal_pose', pose(1.0, 1.0), 'goal state puts the arm inside'),
    ('goal_joints missing joint', 'goal_joints', joints(['rotation_joint'], [1.0]),
     'lacks joints'),
    ('goal_joints NaN', 'goal_joints', joints(JOINTS, [math.nan, 1.0]), 'NaN'),
    ('goal_joints too few positions', 'goal_joints', joints(JOINTS, [1.0]),
     '2 names but 1 positions'),
    ('goal_joints too few velocities', 'goal_joints', joints(JOINTS, [1.0, 1.0], [0.0]),
     'velocities'),
    ('goal_joints duplicate names', 'goal_joints',
     joints(JOINTS + ['rotation_joint'], [1.0, 1.0, 1.0]), 'duplicate'),
    ('goal_joints infinite velocity', 'goal_joints',
     joints(JOINTS, [1.0, 1.0], [math.inf, 0.0]), 'NaN or inf'),
    ('goal_joints beyond the extension limit', 'goal_joints', joints(JOINTS, [1.0, 5.0]),
     'extension_limits'),
    ('goal_joints arm through obstacle', 'goal_joints',
     joints(JOINTS, [math.pi / 4, 1.0]), 'goal state puts the arm inside obstacle 0'),
    ('obstacle with negative radius', 'obstacles', rows([1.0, 1.0, -0.2]),
     'radius must be > 0'),
    ('obstacles not in rows of 3', 'obstacles', rows([1.0, 1.0, 0.2, 3.0]), 'multiple of 3'),
    ('obstacle NaN', 'obstacles', rows([1.0, math.nan, 0.2]), 'non-finite'),
    ('obstacle over the base', 'obstacles', rows([0.1, 0.0, 0.3]), 'contains the robot base'),
    ('obstacles with a bad layout', 'obstacles',
     rows([1.0, 1.0, 0.2], [('rows', 1, 2), ('xy', 2, 1)]), 'layout'),
]

# (parameter values, text expected in the refusal reason)
PARAMETER_CASES = [
    ({'solver.N': 1}, 'out of range'),
    ({'robot.hand_mass': -5.0}, 'out of range'),
    ({'robot.a': math.nan}, 'out of range'),
    ({'robot.u_max': [600.0]}, 'robot.u_max must have 2 entries'),
    ({'obstacles.x': [1.0, 2.0]}, 'must have equal lengths'),
    ({'solver.mode': 'bogus'}, 'mode must be one of'),
    ({'solver.integrator': 'midpoint'}, 'integrator must be one of'),
    ({'joint_names': ['a', 'a']}, 'distinct'),
    ({'initial_state': [0.0, 0.0, 1.0]}, 'initial_state must have 4 entries'),
    ({'goal_state': [0.0, 0.0, math.inf, 0.0]}, 'goal_state must be finite'),
    ({'robot.hand_mass': 'heavy'}, 'Wrong parameter type'),
    ({'solver.t_f0': 0.0}, 't_f0 must be a finite positive time'),
    ({'extension_limits': [2.0, 1.0]}, 'q2_min < q2_max'),
    ({'solver.paper.K_B': 0.0}, 'paper.k_b must be a finite positive number'),
    ({'robot.model_variant': 'eq38'}, 'robot.model_variant must be one of'),
    ({'base_frame': ''}, 'base_frame must not be empty'),
    ({'obstacles.radius': [-0.2]}, 'radius must be > 0'),
]


def test_bad_inputs_get_clear_refusals_and_the_node_keeps_serving(solver):
    client = solver.client
    refused = []
    for what, topic, msg, expected in TOPIC_CASES:
        since = time.monotonic()
        getattr(solver, topic).publish(msg)
        reply = client.wait_for(lambda: finals(solver, since), 10.0, what)[0]
        assert level_name(reply) == 'ERROR' and expected in reply.message, (what, reply.message)
        refused.append(what)
    # A measured start state inside an obstacle: the plan is refused with that reason.
    set_start(solver, (math.pi / 4, 0.0, 1.0, 0.0))
    since = time.monotonic()
    solver.goal_joints.publish(state_msg(PAPER_GOAL))
    reply = client.wait_for(lambda: finals(solver, since), 10.0, 'start in obstacle')[0]
    assert 'start state puts the arm inside obstacle 0' in reply.message, reply.message
    assert 'joint_states' in reply.message
    refused.append('start state in obstacle')
    set_start(solver, PAPER_X0)
    # ~/plan refusals answer with an empty path at once.
    for what, goal, expected in [('plan in frame odom', framed('odom'), "frame 'odom'"),
                                 ('plan NaN', pose(math.nan, math.nan), 'NaN')]:
        since = time.monotonic()
        response = client.call(solver.plan, GetPlan.Request(goal=goal), 10.0)
        assert len(response.plan.poses) == 0
        reply = client.wait_for(lambda: finals(solver, since), 10.0, what)[0]
        assert level_name(reply) == 'ERROR' and expected in reply.message, (what, reply.message)
        refused.append(what)
    for change, expected in PARAMETER_CASES:
        results = client.set_parameters('solver_node', change)
        assert not results[0].successful and expected in results[0].reason, (change, results)
        refused.append(f'parameter {change}')
    assert len(refused) >= 20
    # Nothing of the above changed the node's set-up, and it still plans.
    get = client.node.create_client(GetParameters, client.name('solver_node/get_parameters'))
    current = client.call(get, GetParameters.Request(names=['solver.N', 'obstacles.radius']))
    assert current.values[0].integer_value == N
    assert list(current.values[1].double_array_value) == [0.2]
    response = client.call(solver.plan, GetPlan.Request(goal=pose_of(NEAR_GOAL)), SOLVE_TIMEOUT)
    assert len(response.plan.poses) == N + 1
    assert solver.node.process.poll() is None
    print(f'{len(refused)} bad inputs refused')


def test_goals_after_the_joint_states_stopped_are_refused_until_they_come_again(solver):
    client = solver.client
    assert all(r.successful for r in client.set_parameters('solver_node',
                                                           {'max_state_age': 0.5}))
    try:
        set_start(solver, PAPER_X0)
        time.sleep(1.0)             # the state publisher stopped half a second ago at least
        since = time.monotonic()
        solver.goal_joints.publish(state_msg(NEAR_GOAL))
        reply = client.wait_for(lambda: finals(solver, since), 10.0, 'a stale start')[0]
        assert level_name(reply) == 'ERROR' and 'no recent joint_states' in reply.message, \
            reply.message
        since = time.monotonic()
        response = client.call(solver.plan, GetPlan.Request(goal=pose_of(NEAR_GOAL)), 10.0)
        assert len(response.plan.poses) == 0
        assert 'no recent joint_states' in client.wait_for(
            lambda: finals(solver, since), 10.0, 'a stale start (~/plan)')[0].message
        # The state comes again: the same request is planned from it.
        set_start(solver, PAPER_X0)
        since = time.monotonic()
        response = client.call(solver.plan, GetPlan.Request(goal=pose_of(NEAR_GOAL)),
                               SOLVE_TIMEOUT)
        solved = client.wait_for(lambda: finals(solver, since), 10.0, 'the plan')[0]
        assert report(solved).status is Status.SOLVED, solved.message
        # (N + 1 poses, or fewer: the rest of another test's plan to it that still executes)
        assert len(response.plan.poses) > 1, solved.message
    finally:
        assert all(r.successful for r in client.set_parameters('solver_node',
                                                               {'max_state_age': 3600.0}))
        wait_for_plans_to_end(solver)       # (the next test plans to NEAR_GOAL from rest)


def test_200_goals_back_to_back(solver, record_property):
    """Plans (mostly instant ones to the current state), bursts that preempt; RSS bounded."""
    client = solver.client
    # Goals only: no replan cycles from the states this test reports (they would shorten
    # the executing plan, and a repeated goal warm-starts from its rest).
    assert all(r.successful for r in client.set_parameters('solver_node', {'replan.rate': 0.0}))
    set_start(solver, PAPER_X0)
    process = psutil.Process(solver.node.process.pid)

    def run(count, first=0):
        real = 0
        k = first
        for round_ in range(10 ** 6):
            if k >= first + count:
                break
            kind = round_ % 4
            if round_ % 16 == 8:    # a real plan now and then
                response = client.call(solver.plan, GetPlan.Request(goal=pose_of(NEAR_GOAL)),
                                       SOLVE_TIMEOUT)
                assert len(response.plan.poses) == N + 1
                real += 1
                k += 1
            elif kind == 0:
                response = client.call(solver.plan, GetPlan.Request(goal=pose_of(PAPER_X0)),
                                       30.0)
                assert len(response.plan.poses) == N + 1
                k += 1
            else:                   # a burst of topic goals: each preempts the one before
                burst = min(5, first + count - k)
                since = time.monotonic()
                for _ in range(burst):
                    if kind == 1:
                        solver.goal_joints.publish(state_msg(PAPER_X0))
                    else:
                        solver.goal_pose.publish(pose_of(PAPER_X0))
                # Every accepted goal ends with exactly one final report (solved or dropped).
                client.wait_for(lambda: len(finals(solver, since)) >= burst, 30.0,
                                f'{burst} final reports')
                k += burst
        return real

    response = client.call(solver.plan, GetPlan.Request(goal=pose_of(NEAR_GOAL)), SOLVE_TIMEOUT)
    assert len(response.plan.poses) == N + 1    # warm: a real plan before measuring
    run(20)
    time.sleep(0.5)
    before = process.memory_info().rss
    started = time.monotonic()
    real = run(200, first=20)
    elapsed = time.monotonic() - started
    time.sleep(0.5)
    after = process.memory_info().rss
    growth = (after - before) / before
    record_property('rss_before_mb', round(before / 2 ** 20, 1))
    record_property('rss_after_mb', round(after / 2 ** 20, 1))
    record_property('rss_growth', round(growth, 4))
    print(f'200 goals ({real} real plans) in {elapsed:.1f} s: RSS {before / 2 ** 20:.1f} -> '
          f'{after / 2 ** 20:.1f} MiB ({100 * growth:+.2f} %)')
    assert solver.node.process.poll() is None
    assert growth < 0.10
    statuses = [report(m).status for m in finals(solver, started)]
    assert Status.SOLVED in statuses and set(statuses) <= {Status.SOLVED, Status.CANCELED}
