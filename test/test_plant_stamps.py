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
plant_node as a process: trajectories by header.stamp, splices, actuator lag and delay.

Everything is checked on the real message traffic: ``plant_node/reference`` (q_ref, dq_ref,
u_ff), ``joint_states`` (effort = applied u) and ``plant_node/tracking``, against a cubic
Hermite interpolation and a first-order lag written out independently of the package
(plant_oracle.py).
Times are integer nanoseconds of the stamps (the plant's step grid is 1 ms).
"""

import math
import time
from types import SimpleNamespace

from diagnostic_msgs.msg import DiagnosticStatus
from node_harness import handshake, JOINTS, NodeProcess, PAPER_X0, RosClient, values
import numpy as np
from plant_oracle import deviation, Expected, hold, lagged, rest_to_rest
import pytest
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger
from toc_ros import conversions
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

pytestmark = pytest.mark.slow

NS = 1_000_000_000
MS = 1_000_000
START_Q = np.array([PAPER_X0[0], PAPER_X0[2]])
REFERENCE = 'plant_node/reference'
TRACKING = 'plant_node/tracking'
EXACT = 1e-9          # the plant's and this file's interpolation agree to rounding
SPLICE_JUMP = 1e-6    # issue 12: no jump in the reference position larger than this


@pytest.fixture(scope='module')
def plant(tmp_path_factory):
    client = RosClient()
    log_dir = tmp_path_factory.mktemp('plant_stamps')
    node = NodeProcess('plant_node', client.namespace, log_dir)
    try:
        node.wait_for_log('ready:')
        client.collect(JointState, 'joint_states', 1000)
        client.collect(JointState, REFERENCE, 1000)
        client.collect(DiagnosticStatus, TRACKING, 100)
        ctx = SimpleNamespace(
            client=client, node=node,
            trajectory=client.node.create_publisher(JointTrajectory,
                                                    client.name('trajectory'), 10),
            reset=client.node.create_client(Trigger, client.name('plant_node/reset')))
        client.wait_for(lambda: ctx.trajectory.get_subscription_count() > 0,
                        what='subscriber of trajectory')
        handshake(client, ctx.trajectory, JointTrajectory(joint_names=['handshake']),
                  lambda: 'handshake' in node.log())
        client.wait_for(lambda: client.messages(REFERENCE), 10.0, 'plant_node/reference')
        yield ctx
        assert node.stop() == 0, node.log()
    finally:
        node.stop()
        client.close()


def message(expected, stamp_ns=0):
    """Build the JointTrajectory of an Expected reference with a header stamp [ns]."""
    msg = JointTrajectory(joint_names=JOINTS)
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, NS)
    for k, t in enumerate(expected.times):
        point = JointTrajectoryPoint(positions=list(expected.positions[k]),
                                     velocities=list(expected.velocities[k]),
                                     time_from_start=conversions.duration_msg(float(t)))
        if expected.efforts is not None:
            point.effort = list(expected.efforts[k])
        msg.points.append(point)
    return msg


def ns(stamp):
    return stamp.sec * NS + stamp.nanosec


def reset(ctx):
    assert ctx.client.call(ctx.reset, Trigger.Request()).success
    time.sleep(0.05)


def now_ns(ctx):
    """Stamp of a joint_states message published after this call (on the plant's grid)."""
    since = time.monotonic()
    return ns(ctx.client.wait_for(lambda: ctx.client.messages('joint_states', since), 5.0,
                                  'joint_states')[0].header.stamp)


def tracking(ctx, since):
    return values(ctx.client.wait_for(lambda: ctx.client.messages(TRACKING, since), 5.0,
                                      'tracking')[-1])


def start_of(report):
    """Integer nanoseconds of the tracking report's trajectory_start ('sec.nanosec')."""
    sec, nanosec = report['trajectory_start'].split('.')
    return int(sec) * NS + int(nanosec)


def wait_started(ctx, start, timeout=5.0):
    ctx.client.wait_for(lambda: tracking(ctx, time.monotonic() - 0.12)['trajectory_start']
                        and start_of(tracking(ctx, time.monotonic() - 0.12)) == start,
                        timeout, f'the trajectory stamped {start} to run')


def references(ctx, first, last):
    """(stamp ns, q, dq, u_ff) of the reference messages stamped in [first, last]."""
    out = []
    for msg in ctx.client.messages(REFERENCE):
        t = ns(msg.header.stamp)
        if first <= t <= last:
            out.append((t, np.array(msg.position), np.array(msg.velocity),
                        np.array(msg.effort)))
    return out


def wait_until_stamp(ctx, stamp):
    ctx.client.wait_for(lambda: [m for m in ctx.client.messages(REFERENCE)
                                 if ns(m.header.stamp) >= stamp], 10.0, f'stamp {stamp}')


def near(samples, stamp, before_ns=50 * MS):
    """Tell whether samples lie on both sides of stamp within before_ns."""
    return (any(stamp - before_ns <= t < stamp for t, *_ in samples)
            and any(stamp <= t < stamp + before_ns for t, *_ in samples))


# -- stamps ---------------------------------------------------------------------------------

def test_future_stamp_replaces_from_that_instant_and_newest_pending_wins(plant):
    reset(plant)
    t0 = now_ns(plant)
    a = rest_to_rest(START_Q, [0.8, 1.3], 3.0)
    a_start = t0 + 300 * MS
    plant.trajectory.publish(message(a, a_start))
    wait_started(plant, a_start)
    t1 = now_ns(plant)
    b1 = rest_to_rest(a(0.0)[0] + [0.3, 0.0], [0.0, 0.8], 1.0)      # never executed
    b2 = rest_to_rest(a(0.0)[0] + [-0.2, 0.1], [0.2, 0.7], 1.0)
    b1_start, b2_start = t1 + 700 * MS, t1 + 1000 * MS
    since = time.monotonic()
    plant.trajectory.publish(message(b1, b1_start))
    plant.client.wait_for(lambda: tracking(plant, since)['pending_in'], 5.0, 'pending')
    plant.trajectory.publish(message(b2, b2_start))
    plant.client.wait_for(lambda: 'replaces the pending one' in plant.node.log(), 5.0,
                          'the newest pending trajectory to replace the other')
    wait_until_stamp(plant, b2_start + 1200 * MS)
    samples = references(plant, t0, b2_start + 1200 * MS)
    pieces = [(0, hold(START_Q)), (a_start, a), (b2_start, b2)]
    assert deviation(samples, pieces) < EXACT
    # Before b2's stamp a is tracked (through b1's stamp); from it b2, which jumps (no
    # continuity asked of these).
    assert near(samples, a_start) and near(samples, b1_start) and near(samples, b2_start)
    report = tracking(plant, time.monotonic())
    assert start_of(report) == b2_start and report['pending_in'] == ''


def test_zero_stamp_starts_now(plant):
    reset(plant)
    before = now_ns(plant)
    c = rest_to_rest(START_Q, [0.5, 0.9], 1.0)
    since = time.monotonic()
    plant.trajectory.publish(message(c, 0))
    report = plant.client.wait_for(
        lambda: [values(m) for m in plant.client.messages(TRACKING, since)
                 if values(m)['trajectory_start']], 5.0, 'the trajectory to start')[0]
    start = start_of(report)
    after = now_ns(plant)
    assert before <= start <= after         # at receipt, between the two joint_states
    assert (start - before) % MS == 0       # on the step grid
    wait_until_stamp(plant, start + 1200 * MS)
    samples = references(plant, before, start + 1200 * MS)
    assert deviation(samples, [(0, hold(START_Q)), (start, c)]) < EXACT


def test_past_stamp_is_trimmed_and_one_entirely_past_refused(plant):
    reset(plant)
    time.sleep(0.6)                       # held since more than the 0.5 s trimmed below
    d = rest_to_rest(START_Q, [0.6, 1.2], 2.0)
    stamp = now_ns(plant) - 500 * MS
    since = time.monotonic()
    plant.trajectory.publish(message(d, stamp))
    wait_started(plant, stamp)
    report = tracking(plant, since)
    assert float(report['time_into_trajectory']) >= 0.5     # started partway
    assert 'trimmed: started' in plant.node.log()
    running = now_ns(plant)                                  # after the receipt
    wait_until_stamp(plant, stamp + 2200 * MS)
    samples = references(plant, running, stamp + 2200 * MS)
    assert deviation(samples, [(stamp, d)]) < EXACT       # the reference of d, from partway
    # The reference before the receipt held the start; d from its stamp would not.
    held = references(plant, stamp, stamp + 200 * MS)
    assert held and deviation(held, [(0, hold(START_Q))]) == 0.0
    refusals = plant.node.log().count('entirely in the past')
    e = rest_to_rest(START_Q, [0.0, 0.9], 2.0)
    plant.trajectory.publish(message(e, now_ns(plant) - 3 * NS))
    plant.client.wait_for(lambda: plant.node.log().count('entirely in the past') > refusals,
                          5.0, 'the refusal')
    assert start_of(tracking(plant, time.monotonic())) == stamp     # d goes on


def test_splice_is_continuous_and_a_late_first_point_is_led_in(plant):
    reset(plant)
    a = rest_to_rest(START_Q, [0.9, 1.4], 3.0)
    a_start = now_ns(plant) + 300 * MS
    plant.trajectory.publish(message(a, a_start))
    wait_started(plant, a_start)
    # b: a replan from a's reference at the splice (first point = a there), to another goal.
    splice = a_start + 700 * MS
    q0, dq0, _ = a((splice - a_start) / NS)
    goal = np.array([0.4, 1.1])
    b = Expected([0.0, 0.5, 1.0, 1.5], [q0, q0 + 0.5 * (goal - q0), goal - 0.02, goal],
                 [dq0, [0.2, 0.1], [0.05, 0.02], [0.0, 0.0]])
    plant.trajectory.publish(message(b, splice))
    # c: its first point 0.25 s after its stamp; the reference goes there from b's.
    c_stamp = splice + 600 * MS
    c = Expected([0.25, 1.0], [[0.3, 1.0], [0.2, 1.05]], [[0.0, 0.0], [0.0, 0.0]])
    wait_started(plant, splice)
    plant.trajectory.publish(message(c, c_stamp))
    wait_until_stamp(plant, c_stamp + 1200 * MS)
    samples = references(plant, a_start, c_stamp + 1200 * MS)
    qb, dqb, _ = b((c_stamp - splice) / NS)
    lead_in = Expected([0.0, 0.25, 1.0], [qb, [0.3, 1.0], [0.2, 1.05]],
                       [dqb, [0.0, 0.0], [0.0, 0.0]])
    pieces = [(a_start, a), (splice, b), (c_stamp, lead_in)]
    worst = deviation(samples, pieces)
    before = [s for s in samples if s[0] < splice][-1]
    after = [s for s in samples if s[0] >= splice][0]
    print(f'splice: |reference - expected| <= {worst:.3g}; samples {(after[0] - before[0]) / MS}'
          f' ms apart around it')
    assert worst < EXACT
    assert near(samples, splice) and near(samples, c_stamp)
    # The reference is continuous at both switches: the jump of the expected reference there
    # (which the plant follows to < EXACT at every sample) is below SPLICE_JUMP.
    assert np.max(np.abs(b(0.0)[0] - a((splice - a_start) / NS)[0])) <= SPLICE_JUMP
    assert np.max(np.abs(lead_in(0.0)[0] - b((c_stamp - splice) / NS)[0])) <= SPLICE_JUMP
    # And b is not a: the plant switched (b heads elsewhere).
    late = [s for s in samples if splice + 400 * MS <= s[0] < c_stamp]
    assert max(np.max(np.abs(q - a((t - a_start) / NS)[0])) for t, q, *_ in late) > 0.01


def test_stamps_in_simulated_time_with_publish_clock(plant):
    reset(plant)
    results = plant.client.set_parameters('plant_node', {'publish_clock': True})
    assert results[0].successful, results[0].reason
    try:
        time.sleep(0.1)                    # joint_states in flight still have the old stamps
        t0 = now_ns(plant)
        assert t0 < 10 ** 6 * NS           # simulated time since start-up, not the epoch
        a = rest_to_rest(START_Q, [0.5, 1.1], 1.0)
        plant.trajectory.publish(message(a, t0 + 300 * MS))
        wait_started(plant, t0 + 300 * MS)
        wait_until_stamp(plant, t0 + 1500 * MS)
        samples = references(plant, t0, t0 + 1500 * MS)
        assert deviation(samples, [(0, hold(START_Q)), (t0 + 300 * MS, a)]) < EXACT
    finally:
        plant.client.set_parameters('plant_node', {'publish_clock': False})


# -- actuator lag and control delay ----------------------------------------------------------

def effort_step(ctx, lag, delay, effort=(100.0, 50.0), duration=0.6):
    """Feed-forward only (kp = kd = 0): an effort step at a future stamp; joint_states after."""
    reset(ctx)
    results = ctx.client.set_parameters('plant_node', {
        'kp': [0.0, 0.0], 'kd': [0.0, 0.0], 'actuator_lag': lag, 'control_delay': delay})
    assert all(r.successful for r in results), results
    try:
        reset(ctx)
        step = now_ns(ctx) + 1000 * MS    # ahead of any transport delay on a loaded machine
        u = np.array(effort)
        trajectory = Expected([0.0, duration], [START_Q, START_Q], [[0.0, 0.0]] * 2, [u, u])
        ctx.trajectory.publish(message(trajectory, step))
        end = step + int(duration * NS) + int((delay + 5 * lag) * NS) + 200 * MS
        ctx.client.wait_for(lambda: [m for m in ctx.client.messages('joint_states')
                                     if ns(m.header.stamp) >= end], 10.0, 'joint_states')
        samples = [(ns(m.header.stamp), np.array(m.effort))
                   for m in ctx.client.messages('joint_states')
                   if step - 100 * MS <= ns(m.header.stamp) <= end]
    finally:
        ctx.client.set_parameters('plant_node', {
            'kp': [15000.0, 8000.0], 'kd': [5000.0, 2000.0], 'actuator_lag': 0.0,
            'control_delay': 0.0})
        reset(ctx)
    return step, u, samples


@pytest.mark.parametrize('lag, delay', [(0.05, 0.0), (0.0, 0.04), (0.02, 0.03)])
def test_actuator_lag_and_control_delay(plant, lag, delay):
    step, u, samples = effort_step(plant, lag, delay)
    on = step + round(delay * NS)          # the command step reaches the lag
    # joint_states stamped t: the u applied over the step that ends at t.
    errors = [float(np.max(np.abs(e - lagged((t - on) / NS, 0.6, u, lag)))) for t, e in samples]
    assert max(errors) < 1e-6 * float(np.max(u)), max(errors)
    assert any(on <= t < on + 30 * MS for t, _ in samples)       # the edge was seen
    if delay:
        assert all(np.all(e == 0.0) for t, e in samples if t <= on)   # nothing before


def test_reset_clears_the_delay_buffer(plant):
    reset(plant)
    results = plant.client.set_parameters('plant_node', {'control_delay': 0.5,
                                                         'actuator_lag': 0.1})
    assert all(r.successful for r in results), results
    try:
        u = np.array([100.0, 50.0])
        push = Expected([0.0, 2.0], [START_Q, START_Q], [[0.0, 0.0]] * 2, [u, u])
        plant.trajectory.publish(message(push, 0))
        time.sleep(0.3)               # 0.3 s of commands in the 0.5 s buffer
        reset(plant)
        since = now_ns(plant)
        wait_until_stamp(plant, since + 700 * MS)
        efforts = [np.array(m.effort) for m in plant.client.messages('joint_states')
                   if ns(m.header.stamp) >= since]
        assert efforts and all(np.max(np.abs(e)) < 1e-9 for e in efforts)
    finally:
        plant.client.set_parameters('plant_node', {'control_delay': 0.0, 'actuator_lag': 0.0})
        reset(plant)


def test_bad_lag_and_delay_are_refused(plant, tmp_path):
    for name, value in [('actuator_lag', -0.01), ('actuator_lag', math.nan),
                        ('actuator_lag', math.inf), ('control_delay', -0.001),
                        ('control_delay', 1.5)]:
        result = plant.client.set_parameters('plant_node', {name: value})[0]
        assert not result.successful, (name, value)
    assert plant.client.get_parameters('plant_node', ['actuator_lag', 'control_delay']) == {
        'actuator_lag': 0.0, 'control_delay': 0.0}
    node = NodeProcess('plant_node', plant.client.namespace + '_bad', tmp_path,
                       {'control_delay': 2.0})
    try:
        deadline = time.monotonic() + 60.0
        while node.alive() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert node.stop() == 2, node.log()
        assert 'control_delay' in node.log()
    finally:
        node.stop()
