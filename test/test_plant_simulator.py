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
The ROS-free plant simulator (toc_ros/plant/simulator.py), in simulated time.

The cases of the plant's process tests, plus edge cases that real time cannot provoke exactly.

References are checked against the independent Hermite polynomial and first-order lag of
plant_oracle.py; the integration step against an RK4 of the model's dynamics written here.
"""

from types import SimpleNamespace

import numpy as np
from plant_oracle import deviation, Expected, hold, lagged, rest_to_rest
import pytest
from toc_ros.core.model import dynamics
from toc_ros.core.models import CylindricalRobot
from toc_ros.plant import follow_joint_trajectory as fjt
from toc_ros.plant.model import Stepper
from toc_ros.plant.reference import NS, Reference
from toc_ros.plant.simulator import (catch_up, MAX_CATCH_UP_S, PlantSimulator, stamp_text,
                                     STOPPED, TOPIC_PREEMPTED)

MS = 1_000_000
JOINTS = ['rotation_joint', 'extension_joint']
X0 = np.array([np.pi / 12.0, 0.0, 1.0, 0.0])
START_Q = X0[0::2]
EXACT = 1e-9
SPLICE_JUMP = 1e-6
KP, KD = (15000.0, 8000.0), (5000.0, 2000.0)


def simulator(kp=KP, kd=KD, lag=0.0, delay=0.0, rate=1000.0):
    sim = PlantSimulator(JOINTS)
    sim.configure(CylindricalRobot(), kp, kd, rate, lag, delay)
    sim.reset(X0, JOINTS)
    return sim


def reference(expected):
    return Reference(expected.times, expected.positions, expected.velocities, expected.efforts)


def advance(sim, until_ns, samples=None):
    """Step to until_ns as the node's timer does; collect (t, q_ref, dq_ref, u_ff)."""
    while sim.sim_ns < until_ns:
        sim.run(1)
        sim.activate_due()
        sim.track_error()
        if samples is not None:
            samples.append((sim.sim_ns, *(np.array(v) for v in sim.target(sim.sim_ns))))
    return samples


def test_step_is_rk4_of_the_model_dynamics():
    model = CylindricalRobot()
    p, dt = model.packed(), 1e-3
    x, u = np.array([0.3, 0.2, 1.1, -0.1]), np.array([120.0, -40.0])
    k1 = dynamics(x, u, p)
    k2 = dynamics(x + 0.5 * dt * k1, u, p)
    k3 = dynamics(x + 0.5 * dt * k2, u, p)
    k4 = dynamics(x + dt * k3, u, p)
    expected = x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    np.testing.assert_allclose(Stepper(model, dt)(x, u), expected, rtol=0, atol=1e-12)


def test_step_is_whole_nanoseconds_and_the_state_starts_at_rest():
    sim = simulator(rate=3000.0)
    assert sim.dt_ns == 333_333 and sim.dt == 333_333 / NS
    np.testing.assert_array_equal(sim.x, X0)
    np.testing.assert_array_equal(sim.u, [0.0, 0.0])
    assert sim.tracking(0)[0] == 'idle'


def test_future_stamp_replaces_from_that_instant_and_newest_pending_wins():
    sim = simulator()
    t0 = sim.sim_ns
    a = rest_to_rest(START_Q, [0.8, 1.3], 3.0)
    a_start = t0 + 300 * MS
    assert not sim.schedule(reference(a), a_start)
    assert sim.tracking(0)[2]['pending_in'] == pytest.approx(0.3)
    samples = advance(sim, a_start + 100 * MS, [])
    b1 = rest_to_rest(a(0.0)[0] + [0.3, 0.0], [0.0, 0.8], 1.0)      # never executed
    b2 = rest_to_rest(a(0.0)[0] + [-0.2, 0.1], [0.2, 0.7], 1.0)
    b1_start, b2_start = sim.sim_ns + 700 * MS, sim.sim_ns + 1000 * MS
    assert not sim.schedule(reference(b1), b1_start)
    assert sim.schedule(reference(b2), b2_start)       # replaces the pending b1
    advance(sim, b2_start + 1200 * MS, samples)
    pieces = [(0, hold(START_Q)), (a_start, a), (b2_start, b2)]
    assert deviation(samples, pieces) < EXACT
    phase, _, values = sim.tracking(0)
    assert values['trajectory_start'] == stamp_text(b2_start) and values['pending_in'] == ''
    assert phase == 'holding' and values['time_into_trajectory'] == pytest.approx(1.2)


def test_zero_stamp_starts_now_on_the_step_grid():
    sim = simulator()
    advance(sim, 123 * MS)
    c = rest_to_rest(START_Q, [0.5, 0.9], 1.0)
    start = sim.sim_ns
    sim.schedule(reference(c), start)
    assert sim.active is not None and sim.pending is None       # at once
    samples = advance(sim, start + 1200 * MS, [])
    assert deviation(samples, [(start, c)]) < EXACT
    assert sim.tracking(7)[2]['trajectory_start'] == stamp_text(start + 7)


def test_past_stamp_is_trimmed_and_one_entirely_past_refused():
    sim = simulator()
    advance(sim, 600 * MS)
    d = rest_to_rest(START_Q, [0.6, 1.2], 2.0)
    stamp = sim.sim_ns - 500 * MS
    assert sim.ended_ago_ns(reference(d), stamp) is None
    sim.schedule(reference(d), stamp)
    assert sim.tracking(0)[2]['time_into_trajectory'] == pytest.approx(0.5)   # partway
    samples = advance(sim, stamp + 2200 * MS, [])
    assert deviation(samples, [(stamp, d)]) < EXACT
    e = rest_to_rest(START_Q, [0.0, 0.9], 2.0)
    assert sim.ended_ago_ns(reference(e), sim.sim_ns - 3 * NS) == 1 * NS
    # Ending exactly now is not in the past (the last point still applies).
    assert sim.ended_ago_ns(reference(e), sim.sim_ns - 2 * NS) is None


def test_splice_is_continuous_and_a_late_first_point_is_led_in():
    sim = simulator()
    a = rest_to_rest(START_Q, [0.9, 1.4], 3.0)
    a_start = 300 * MS
    sim.schedule(reference(a), a_start)
    samples = advance(sim, a_start + 100 * MS, [])
    splice = a_start + 700 * MS
    q0, dq0, _ = a((splice - a_start) / NS)
    goal = np.array([0.4, 1.1])
    b = Expected([0.0, 0.5, 1.0, 1.5], [q0, q0 + 0.5 * (goal - q0), goal - 0.02, goal],
                 [dq0, [0.2, 0.1], [0.05, 0.02], [0.0, 0.0]])
    sim.schedule(reference(b), splice)
    advance(sim, splice + 100 * MS, samples)
    c_stamp = splice + 600 * MS
    c = Expected([0.25, 1.0], [[0.3, 1.0], [0.2, 1.05]], [[0.0, 0.0], [0.0, 0.0]])
    sim.schedule(reference(c), c_stamp)
    advance(sim, c_stamp + 1200 * MS, samples)
    qb, dqb, _ = b((c_stamp - splice) / NS)
    lead_in = Expected([0.0, 0.25, 1.0], [qb, [0.3, 1.0], [0.2, 1.05]],
                       [dqb, [0.0, 0.0], [0.0, 0.0]])
    pieces = [(0, hold(START_Q)), (a_start, a), (splice, b), (c_stamp, lead_in)]
    assert deviation(samples, pieces) < EXACT
    assert np.max(np.abs(b(0.0)[0] - a((splice - a_start) / NS)[0])) <= SPLICE_JUMP
    assert np.max(np.abs(lead_in(0.0)[0] - b((c_stamp - splice) / NS)[0])) <= SPLICE_JUMP
    late = [s for s in samples if splice + 400 * MS <= s[0] < c_stamp]
    assert max(np.max(np.abs(q - a((t - a_start) / NS)[0])) for t, q, *_ in late) > 0.01


def test_tracking_follows_the_plan_and_settles_on_the_goal():
    sim = simulator()
    goal = np.array([0.7, 1.2])
    sim.schedule(reference(rest_to_rest(START_Q, goal, 1.5)), 0)
    advance(sim, 3 * NS)
    _, worst, values = sim.tracking(0)
    assert values['phase'] == 'holding' and worst < 1e-3
    np.testing.assert_allclose(sim.positions, goal, atol=1e-3)
    assert 0.0 < values['max_position_error_q1'] < 0.05      # it lagged, then caught up
    assert values['sim_time'] == 3.0


def effort_samples(lag, delay, effort=(100.0, 50.0), duration=0.6):
    """Feed-forward only (kp = kd = 0): an effort step at 1 s; (t, applied u) every step."""
    sim = simulator(kp=(0.0, 0.0), kd=(0.0, 0.0), lag=lag, delay=delay)
    step = 1 * NS
    u = np.array(effort)
    sim.schedule(reference(Expected([0.0, duration], [START_Q, START_Q], [[0.0, 0.0]] * 2,
                                    [u, u])), step)
    end = step + int(duration * NS) + int((delay + 5 * lag) * NS) + 200 * MS
    out = []
    while sim.sim_ns < end:
        sim.run(1)
        sim.activate_due()
        if sim.sim_ns >= step - 100 * MS:
            out.append((sim.sim_ns, sim.u.copy()))
    return step, u, out


@pytest.mark.parametrize('lag, delay', [(0.05, 0.0), (0.0, 0.04), (0.02, 0.03), (0.0, 0.0)])
def test_actuator_lag_and_control_delay(lag, delay):
    step, u, samples = effort_samples(lag, delay)
    on = step + round(delay * NS)
    errors = [float(np.max(np.abs(e - lagged((t - on) / NS, 0.6, u, lag)))) for t, e in samples]
    assert max(errors) < 1e-6 * float(np.max(u)), max(errors)
    assert any(on <= t < on + 30 * MS for t, _ in samples)
    assert all(np.all(e == 0.0) for t, e in samples if t <= on)     # nothing before


def test_reset_clears_the_delay_buffer():
    sim = simulator(lag=0.1, delay=0.5)
    u = np.array([100.0, 50.0])
    sim.schedule(reference(Expected([0.0, 2.0], [START_Q, START_Q], [[0.0, 0.0]] * 2,
                                    [u, u])), 0)
    advance(sim, 300 * MS)               # 0.3 s of commands in the 0.5 s buffer
    sim.reset(X0, JOINTS)
    efforts = []
    while sim.sim_ns < 1000 * MS:
        sim.run(1)
        efforts.append(sim.u.copy())
    assert all(np.max(np.abs(e)) < 1e-9 for e in efforts)
    np.testing.assert_array_equal(sim.x, X0)     # held: no command reached the plant


def test_a_longer_delay_repeats_the_oldest_command_and_a_shorter_drops_the_oldest():
    sim = simulator(delay=0.003)
    commands = [np.full(2, float(k)) for k in (1, 2, 3)]
    for u in commands:
        sim.actuate(u)                   # buffer: 1, 2, 3 (the zeros went out)
    assert sim.configure(sim.model, KP, KD, 1000.0, 0.0, 0.005) is False
    out = [sim.actuate(np.full(2, 9.0))[0] for _ in range(6)]
    assert out == [1.0, 1.0, 1.0, 2.0, 3.0, 9.0]
    sim.configure(sim.model, KP, KD, 1000.0, 0.0, 0.002)    # buffer 9, 9, 9, 9, 9 -> 9, 9
    sim.actuate(np.full(2, 4.0))
    assert [sim.actuate(np.full(2, 5.0))[0] for _ in range(3)] == [9.0, 4.0, 5.0]


def test_lag_is_the_exact_discretisation():
    sim = simulator(lag=0.01)
    outputs = [sim.actuate(np.array([1.0, -2.0])) for _ in range(5)]
    for k, out in enumerate(outputs, start=1):
        np.testing.assert_allclose(out, np.array([1.0, -2.0]) * (1 - np.exp(-k * 1e-3 / 0.01)),
                                   rtol=1e-13, atol=0.0)


def test_commands_saturate_at_u_max():
    sim = simulator()
    sim.schedule(reference(Expected([0.0, 0.01], [START_Q, START_Q + 1.0], [[0.0, 0.0]] * 2)),
                 0)
    sim.run(5)
    np.testing.assert_array_equal(np.abs(sim.command()), sim.u_max)


@pytest.mark.parametrize('behind, steps, skipped', [
    (0.003, 3, 0.0), (0.0029999999999, 3, 0.0), (0.00299, 2, 0.0), (-0.01, 0, 0.0),
    (0.0, 0, 0.0), (MAX_CATCH_UP_S, 500, 0.0), (2.0, 500, 1.5)])
def test_catch_up_makes_up_whole_steps_and_skips_long_stalls(behind, steps, skipped):
    got = catch_up(behind, 1e-3)
    assert got[0] == steps and got[1] == pytest.approx(skipped, abs=1e-12)


def test_a_diverged_state_is_not_finite():
    sim = simulator()
    assert sim.finite()
    sim.x = np.array([np.nan, 0.0, 1.0, 0.0])
    assert not sim.finite()


def test_empty_trajectory_holds_the_current_position_and_drops_the_pending():
    sim = simulator()
    sim.schedule(reference(rest_to_rest(START_Q, [0.8, 1.3], 1.0)), 0)
    advance(sim, 400 * MS)
    sim.schedule(reference(rest_to_rest(START_Q, [0.1, 1.3], 1.0)), 900 * MS)
    sim.stop()
    assert sim.active is None and sim.pending is None
    here = sim.positions.copy()
    q_ref, dq_ref, u_ff = sim.target(sim.sim_ns + 5 * NS)
    np.testing.assert_array_equal(q_ref, here)
    assert not np.any(dq_ref) and not np.any(u_ff)
    assert sim.tracking(0)[0] == 'idle'


# -- FollowJointTrajectory goals against topic trajectories -----------------------------------

def goal_trajectory(q0, q1, duration=1.0):
    points = [fjt.Point(np.asarray(q, dtype=float), np.zeros(2)) for q in (q0, q1)]
    return fjt.Trajectory([0, int(duration * NS)], points)


def follow(sim, trajectory):
    goal = SimpleNamespace(name='goal')
    sim.follow(trajectory, fjt.Tolerances.defaults(2), goal)
    return goal


def test_a_goal_drops_the_topic_trajectories_and_starts_from_their_reference():
    sim = simulator()
    a = rest_to_rest(START_Q, [0.8, 1.3], 2.0)
    sim.schedule(reference(a), 0)
    sim.schedule(reference(a), 5 * NS)                 # pending
    advance(sim, 500 * MS)
    before = a(0.5)[0]
    goal = follow(sim, goal_trajectory(before, [0.3, 1.0]))
    assert sim.pending is None
    advance(sim, 501 * MS)
    assert sim.following and sim.active is None
    # The goal starts from the reference being followed (no jump).
    assert np.max(np.abs(sim.target(sim.sim_ns)[0] - before)) < 1e-3
    assert sim.tracking(0)[0] == 'goal tracking'
    advance(sim, 3 * NS)
    outcomes = sim.take_outcomes()
    assert [(o.goal, o.code) for o in outcomes] == [(goal, fjt.SUCCESSFUL)]


def test_a_topic_trajectory_aborts_the_goal_when_it_starts():
    sim = simulator()
    goal = follow(sim, goal_trajectory(START_Q, [0.3, 1.0], 2.0))
    advance(sim, 200 * MS)
    sim.schedule(reference(rest_to_rest(START_Q, [0.5, 1.0], 1.0)), 600 * MS)
    advance(sim, 599 * MS)
    assert sim.following and not sim.take_outcomes()    # not yet: it is pending
    advance(sim, 600 * MS)
    assert not sim.following and sim.active is not None
    outcomes = sim.take_outcomes()
    assert [(o.goal, o.code, o.text) for o in outcomes] == [
        (goal, fjt.INVALID_GOAL, TOPIC_PREEMPTED)]


def test_an_empty_trajectory_and_a_reset_abort_the_goal():
    sim = simulator()
    goal = follow(sim, goal_trajectory(START_Q, [0.3, 1.0], 2.0))
    advance(sim, 100 * MS)
    sim.stop()
    assert [(o.goal, o.text) for o in sim.take_outcomes()] == [(goal, STOPPED)]
    goal = follow(sim, goal_trajectory(START_Q, [0.3, 1.0], 2.0))
    advance(sim, 200 * MS)
    sim.reset(X0, JOINTS)
    assert [(o.goal, o.text) for o in sim.take_outcomes()] == [
        (goal, 'the plant was reset')]
    assert not sim.following and sim.follower.goal is None
