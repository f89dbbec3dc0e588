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
Helpers for tests that run toc_ros nodes as processes and talk to them with rclpy.

Each test module gets a private rclpy context on a random ROS_DOMAIN_ID (localhost discovery)
and a random namespace, so concurrent test runs do not see each other.
"""

import contextlib
import math
from pathlib import Path
import time
from types import SimpleNamespace

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from nav_msgs.srv import GetPlan
from rcl_interfaces.srv import GetParameters
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger
from toc_ros import harness
from toc_ros.harness import LATCHED  # noqa: F401 - the tests import it from here
from toc_ros.progress import EVENT_REFUSED, progress_from_msg

CYCLE_SOURCE = 'replan_cycle'     # goal_source of solver_node's replan-cycle reports

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / 'config' / 'toc_ros.yaml'
PAPER_X0 = (math.pi / 12.0, 0.0, 1.0, 0.0)
PAPER_GOAL = (5.0 * math.pi / 12.0, 0.0, 1.0, 0.0)
# A goal away from the paper's obstacle: a real plan that solves quicker than the paper's.
NEAR_GOAL = (-0.5, 0.0, 1.0, 0.0)
# Parameters of the nodes under test: small N for speed, a generous wall-clock limit because
# test machines are shared, and joint_states valid for an hour: the tests publish a start a
# few times (a robot at rest, no plant) and send goals for a while after it
# (test_node_robustness checks the default limit's refusals).
TEST_PARAMS = {'solver.N': 100, 'solver.timeout': 300.0, 'max_state_age': 3600.0}
SOLVE_TIMEOUT = 300.0
A = 1.1
U_MAX = (600.0, 500.0)
JOINTS = ['rotation_joint', 'extension_joint']


# Longest wait for a node's 'ready:' log: after an edit of toc_ros/core the first solver_node
# compiles the numba kernels (30-90 s, longer on a loaded shared machine).
READY_TIMEOUT = 300.0


class NodeProcess(harness.NodeProcess):
    """A toc_ros node of the tests: the scenario file unless told otherwise."""

    def __init__(self, module, namespace, log_dir, params=None, params_file=CONFIG, **kwargs):
        super().__init__(module, namespace, log_dir, params, params_file, **kwargs)

    def wait_for_log(self, text, timeout=READY_TIMEOUT):
        """Wait until text appears in the output (default: long enough for a cold compile)."""
        super().wait_for_log(text, timeout)


RosClient = harness.RosClient


def pose(x, y, frame='base_link'):
    """Build the PoseStamped of a hand target."""
    msg = PoseStamped()
    msg.header.frame_id = frame
    msg.pose.position.x = float(x)
    msg.pose.position.y = float(y)
    msg.pose.orientation.w = 1.0
    return msg


def pose_of(state):
    """Build the PoseStamped of the hand for a joint state (q1, dq1, q2, dq2)."""
    return pose((A + state[2]) * math.cos(state[0]), (A + state[2]) * math.sin(state[0]))


def values(status):
    """Key/values of a DiagnosticStatus (~/tracking; ~/progress is read with report())."""
    return {kv.key: kv.value for kv in status.values}


def report(status):
    """Return the ProgressReport of a ~/progress message."""
    return progress_from_msg(status)


def is_final(status):
    """Tell whether a ~/progress message ends a request (anything but a running solve)."""
    return progress_from_msg(status).final


def level_name(status):
    """Name of a DiagnosticStatus level."""
    return {DiagnosticStatus.OK: 'OK', DiagnosticStatus.WARN: 'WARN',
            DiagnosticStatus.ERROR: 'ERROR', DiagnosticStatus.STALE: 'STALE'}[status.level]


def reports(ctx, since):
    """Return the ~/progress reports received since a time (ctx: a running_solver or client)."""
    client = getattr(ctx, 'client', ctx)
    return [report(m) for m in client.messages('solver_node/progress', since)]


def wait_final(ctx, since, timeout=SOLVE_TIMEOUT, source=None):
    """
    Wait for the first final (not refused) progress report since a time; return it.

    Reports of replan cycles (replan.rate) are not answers to a request and are skipped
    unless source asks for them.
    """
    def found():
        return [r for r in reports(ctx, since)
                if r.final and r.event != EVENT_REFUSED
                and (r.goal_source == source if source is not None
                     else r.goal_source != CYCLE_SOURCE)]
    return ctx.client.wait_for(found, timeout, 'a final progress report')[0]


def parameter_round_trips(ctx, count, pause):
    """Time count get_parameters calls to solver_node [s], pause seconds apart."""
    client = ctx.client
    get = client.node.create_client(GetParameters, client.name('solver_node/get_parameters'))
    rounds = []
    for _ in range(count):
        started = time.monotonic()
        client.call(get, GetParameters.Request(names=['solver.N']), timeout=10.0)
        rounds.append(time.monotonic() - started)
        time.sleep(pause)
    return rounds


def eq37(x, u, hand_mass=50.0, link_mass=97.0, inertia=193.0, a=A):
    """Right-hand side of the paper's eq. (37), written out independently of the package."""
    a1, a2, a3 = inertia + hand_mass * a * a, 2.0 * hand_mass * a, link_mass + hand_mass
    x1, x2, x3, x4 = x
    den = a1 + a2 * x3 + a3 * x3 * x3
    return [x2, (-2.0 * a3 * x2 * x3 * x4 - a2 * x2 * x4 + u[0]) / den, x4,
            x3 * x2 * x2 - a2 / (2.0 * a3) * x2 * x2 + u[1] / a3]


def handshake(client, publisher, msg, heard, timeout=30.0, period=1.0):
    """
    Publish msg until heard() is true: proves the subscriber side matched the publisher.

    get_subscription_count() > 0 only says that the publisher matched the subscription; the
    node's side may match later and miss a volatile message sent in between.  msg should be
    harmless (e.g. an input the node refuses) and heard() detect the node's reaction.
    """
    deadline = time.monotonic() + timeout
    while True:
        publisher.publish(msg)
        until = min(deadline, time.monotonic() + period)
        while time.monotonic() < until:
            if heard():
                return
            time.sleep(0.01)
        assert time.monotonic() < deadline, f'no reaction to {publisher.topic_name}'


def refused_inputs_handshake(ctx):
    """Make sure each input topic reaches the node: send refused inputs until they are heard."""
    bad_pose = pose_of(PAPER_GOAL)
    bad_pose.header.frame_id = 'handshake'
    for publisher, msg, text in [
            (ctx.goal_pose, bad_pose, "'handshake'"),
            (ctx.goal_joints, JointState(name=['handshake'], position=[0.0]), "'handshake'"),
            (ctx.obstacles, Float64MultiArray(data=[1.0]), 'multiple of 3')]:
        since = time.monotonic()
        handshake(ctx.client, publisher, msg, lambda: [
            m for m in ctx.client.messages('solver_node/progress', since) if text in m.message])
    time.sleep(0.5)    # joint_states has no reaction to wait for; give discovery a moment


def wait_for_plans_to_end(ctx):
    """
    Wait until no plan published so far executes (the node clock past their ends + 0.6 s).

    For tests that share one node in any order (pytest-randomly): a plan of another test to the
    same goal would warm-start a test's goal on its remaining grid, and a braking stop the
    test's state is close to would be its start (the node's rules, not what they test).
    ctx.client must collect 'trajectory'.
    """
    ends = [m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
            + (m.points[-1].time_from_start.sec + 1e-9 * m.points[-1].time_from_start.nanosec)
            for m in ctx.client.messages('trajectory') if m.points]
    wait = max(ends, default=0.0) + 0.6 - time.time()    # + the 0.5 s it counts as executing
    if wait > 0.0:
        time.sleep(min(wait, 10.0))


@contextlib.contextmanager
def running_solver(log_dir, collect=(), depth=10):
    """
    Run solver_node with TEST_PARAMS; yield its client, process, input publishers and clients.

    collect: (message type, relative topic, qos) the client records; depth: history of the
    goal publishers.  Every input topic is proven matched (refused_inputs_handshake) before the
    body runs, and the node must exit cleanly at the end.
    """
    client = RosClient()
    node = NodeProcess('solver_node', client.namespace, log_dir, TEST_PARAMS)
    try:
        node.wait_for_log('ready:')
        for msg_type, topic, qos in collect:
            client.collect(msg_type, topic, qos)
        create = client.node.create_publisher
        ctx = SimpleNamespace(
            client=client, node=node,
            goal_pose=create(PoseStamped, client.name('goal_pose'), depth),
            goal_joints=create(JointState, client.name('goal_joints'), depth),
            joint_states=create(JointState, client.name('joint_states'), 10),
            obstacles=create(Float64MultiArray, client.name('obstacles'), 10),
            plan=client.node.create_client(GetPlan, client.name('solver_node/plan')),
            cancel=client.node.create_client(Trigger, client.name('solver_node/cancel')))
        for publisher in (ctx.goal_pose, ctx.goal_joints, ctx.joint_states, ctx.obstacles):
            client.wait_for(lambda p=publisher: p.get_subscription_count() > 0,
                            what=f'subscriber of {publisher.topic_name}')
        refused_inputs_handshake(ctx)
        yield ctx
        assert node.stop() == 0, node.log()
    finally:
        node.stop()
        client.close()
