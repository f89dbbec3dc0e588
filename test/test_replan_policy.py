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
The replan, brake and stale-plan policy of solver_node, exercised directly (no ROS, no solve).

The executing plan here is an independent RK4 rollout of the paper's eq. (37) under bang-bang
controls; clearances, conflicts and stops are recomputed with the tests' own numpy model.
"""

import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import numpy_model as nm
import pytest
from toc_ros.core import goal_starts as starts, Problem, replan_policy as policy, SolverOptions
from toc_ros.core.executing_plan import (braking_plan, ExecutingPlan, goal_warm_start,
                                         nearest_node, remaining_nodes, Seed,
                                         true_conflict_time, violation)
from toc_ros.core.model import RobotParams
from toc_ros.core.models import CylindricalRobot
from toc_ros.core.online_estimate import EstimateHold
from toc_ros.core.replan import BRAKE_REST_SPEED, BRAKE_SMOOTHING_SPEED

MODEL = CylindricalRobot()
U_MAX = np.array([600.0, 500.0])
X0 = np.array([math.pi / 12.0, 0.0, 1.0, 0.0])
N, T = 100, 1.2


def make_plan(start=0.0, u1=600.0, result=None, goal=None):
    """Return a rotation: u1 full ahead for half the time, full back after (an RK4 rollout)."""
    controls = np.zeros((N, 2))
    controls[:N // 2, 0], controls[N // 2:, 0] = u1, -u1
    states = nm.simulate(X0, controls, T, integrator='rk4')
    times = np.linspace(0.0, T, N + 1)
    return ExecutingPlan(start=start, times=times, states=states, controls=controls,
                         goal=states[-1].copy() if goal is None else np.asarray(goal),
                         source='goal_joints', model=MODEL, result=result,
                         path_states=states)


def hand(x):
    r = nm.PAPER['a'] + x[2]
    return np.array([r * math.cos(x[0]), r * math.sin(x[0])])


@pytest.fixture(scope='module')
def plan():
    return make_plan()


# -- stale-plan detection -------------------------------------------------------------------

def test_a_plan_clear_of_the_obstacles_is_not_stale(plan):
    assert violation(plan, MODEL, [], 0.0, 1e-9) is None
    assert violation(plan, MODEL, [(-2.0, -2.0, 0.3)], 0.0, 1e-9) is None


def test_an_obstacle_on_the_rest_of_the_plan_makes_it_stale(plan):
    """A new circle on node 70: the cut depth is the independent clearance's minimum."""
    circle = (*hand(plan.states[70]), 0.1)
    far = (-2.0, -2.0, 0.3)
    for elapsed in (0.0, plan.times[40], plan.times[70] - 1e-6):
        text = violation(plan, MODEL, [far, circle], elapsed, 1e-9)
        rest = plan.times >= elapsed
        rest[max(int(np.argmax(rest)) - 1, 0)] = True
        depth = -np.min(nm.clearance(plan.states[rest], [circle]))
        assert depth > 0.05
        assert text == f'cuts obstacle 1 by {depth:.3g} m', text


def test_an_obstacle_on_the_part_already_passed_is_not_a_violation(plan):
    circle = (*hand(plan.states[20]), 0.02)
    assert violation(plan, MODEL, [circle], 0.0, 1e-9) is not None
    # The first node from which the rest stays clear (independent clearance): once the
    # segment starting there executes, the circle is behind the arm.
    gaps = np.min(nm.clearance(plan.states, [circle]), axis=1)
    j = 1 + max(k for k in range(N + 1) if gaps[k] < 0.0)
    assert 20 < j < N
    assert violation(plan, MODEL, [circle], plan.times[j] + 1e-6, 1e-9) is None
    assert violation(plan, MODEL, [circle], plan.times[j - 1] + 1e-6, 1e-9) is not None


def test_the_segment_in_execution_and_the_rest_at_the_goal_are_checked(plan):
    mask = remaining_nodes(plan.times, plan.times[30] + 1e-3)
    assert np.flatnonzero(mask)[0] == 30 and mask[30:].all() and not mask[:30].any()
    mask = remaining_nodes(plan.times, T + 5.0)
    assert np.flatnonzero(mask).tolist() == [N]
    circle = (*hand(plan.states[-1]), 0.05)      # on the goal: stale even once arrived
    assert violation(plan, MODEL, [circle], T + 5.0, 1e-9).startswith('cuts obstacle 0')


def test_a_tolerance_below_zero_clearance_still_counts_as_clear(plan):
    x = hand(plan.states[60])
    radius = 0.05
    depth = -np.min(nm.clearance(plan.states, [(*x, radius)]))
    assert violation(plan, MODEL, [(*x, radius)], 0.0, depth + 1e-6) is None
    assert violation(plan, MODEL, [(*x, radius)], 0.0, depth - 1e-6) is not None


def test_lower_control_bounds_and_another_model_make_a_plan_stale(plan):
    weak = CylindricalRobot(RobotParams(u1_max=450.0))
    assert violation(plan, weak, [], 0.0, 1e-9) == 'exceeds u_max by 150'
    # The excess is only ahead: both halves exceed, so the last interval still does.
    assert violation(plan, weak, [], plan.times[-2] + 1e-6, 1e-9) == 'exceeds u_max by 150'
    lagged = SimpleNamespace(nx=6, name='lagged')
    assert violation(plan, lagged, [], 0.0, 1e-9) == \
        "was planned for another robot model (now 'lagged')"


def test_time_to_conflict_is_the_first_node_inside_a_true_obstacle(plan):
    circle = (*hand(plan.states[80]), 0.06)
    inside = np.min(nm.clearance(plan.states, [circle]), axis=1) < 0.0
    first = int(np.argmax(inside))
    assert 50 < first <= 80
    for elapsed in (0.0, 0.31):
        expected = plan.times[plan.times >= elapsed][np.argmax(inside[plan.times >= elapsed])]
        assert true_conflict_time(plan, [circle], elapsed) == pytest.approx(
            expected - elapsed, abs=1e-12)
    assert true_conflict_time(plan, [circle], T + 1.0) is None
    assert true_conflict_time(plan, [(-2.0, -2.0, 0.2)], 0.0) is None
    assert true_conflict_time(plan, [], 0.0) is None


# -- brake or wait: against an independent simulation ---------------------------------------

def follow_then_brake(plan, k, wait):
    """Independently: plan controls from node k for wait [s], then the bang-bang stop."""
    return nm.follow_then_brake(plan.times, plan.controls, plan.states[k], plan.times[k], wait,
                                U_MAX, BRAKE_REST_SPEED, BRAKE_SMOOTHING_SPEED, substeps=2)


def test_braking_waits_for_a_replan_only_while_a_later_stop_still_ends_clear(plan):
    """
    A new obstacle where the plan ends: a short lead may wait, a long one (slow cycles) not.

    Expected outcomes come from the independent stop after brake_wait(lead); the circle sits
    where the stop after the long lead's wait ends.
    """
    k = 25                                     # t = 0.3 s, accelerating
    short, long_ = 0.025, policy.MAX_LEAD_S
    stop_long = follow_then_brake(plan, k, policy.brake_wait(long_))
    circle = (*hand(stop_long[-1]), 0.05)
    conflict = true_conflict_time(plan, [circle], plan.times[k])
    assert conflict is not None and conflict > policy.brake_wait(long_)
    outcomes = {}
    for lead in (short, 0.1, long_):
        stop = follow_then_brake(plan, k, policy.brake_wait(lead))
        expected = bool(np.min(nm.clearance(stop, [circle])) >= 0.0)
        got = policy.brake_can_wait(plan, [circle], plan.states[k], plan.times[k], lead,
                                    conflict)
        assert got == expected, (lead, got)
        outcomes[lead] = got
    assert outcomes[short] and not outcomes[long_]     # the test discriminates


def test_braking_cannot_wait_when_the_conflict_comes_first_or_no_state_fits(plan):
    k = 25
    far = [(-2.0, -2.0, 0.1)]
    args = (plan, far, plan.states[k], plan.times[k], 0.025)
    assert policy.brake_can_wait(*args, None)            # never enters one: no hurry
    wait = policy.brake_wait(0.025)
    assert not policy.brake_can_wait(*args, wait)         # in conflict within the wait
    assert not policy.brake_can_wait(*args, 0.5 * wait)
    assert policy.brake_can_wait(*args, wait + 0.2)       # the stop then is clear of `far`
    assert not policy.brake_can_wait(plan, far, np.zeros(6), plan.times[k], 0.025, 1.0)


# -- recovery margin ------------------------------------------------------------------------

def test_recovery_margin_is_half_the_true_clearance_inside_the_margin():
    x = np.array([0.3, 0.0, 1.0, 0.0])
    e = np.array([math.cos(0.3), math.sin(0.3)])
    normal = np.array([-e[1], e[0]])
    centre = 1.5 * e + 0.25 * normal              # 0.25 m beside the arm at s = 1.5 m
    rows = [(*centre, 0.2)]
    gap = float(np.min(nm.clearance(x, rows)))
    assert gap == pytest.approx(0.05, abs=1e-9)
    assert starts.recovery_margin(MODEL, x, rows, 0.1) == pytest.approx(0.5 * gap, abs=1e-9)
    assert starts.recovery_margin(MODEL, x, rows, 0.05 - 1e-6) is None     # outside it
    assert starts.recovery_margin(MODEL, x, [(*centre, 0.3)], 0.1) is None  # inside a circle
    assert starts.recovery_margin(MODEL, x, [], 0.1) is None
    assert starts.recovery_margin(MODEL, x[:3], rows, 0.1) is None
    # Several circles: the nearest decides.
    rows2 = rows + [(*(1.5 * e - 0.23 * normal), 0.2)]
    assert starts.recovery_margin(MODEL, x, rows2, 0.1) == pytest.approx(0.015, abs=1e-9)


# -- cycle lead, grid, budget ---------------------------------------------------------------

def test_cycle_lead_follows_the_median_of_slow_cycles():
    assert policy.cycle_lead(0.025, []) == 0.025
    assert policy.cycle_lead(0.025, [0.1] * (policy.MIN_LATENCY_SAMPLES - 1)) == 0.025
    slow = [0.02, 0.03, 0.04, 0.03, 0.05]
    assert policy.cycle_lead(0.025, slow) == pytest.approx(policy.LEAD_PER_MEDIAN * 0.03)
    assert policy.cycle_lead(0.1, slow) == 0.1                 # the setting is the floor
    # One late outlier does not stretch the lead; the cap holds for any latency.
    assert policy.cycle_lead(0.025, slow + [5.0]) == pytest.approx(
        policy.LEAD_PER_MEDIAN * float(np.median(slow + [5.0])))
    capped = [policy.latency_sample(v) for v in (0.5, 1.0, 3.0, 0.4, 9.0)]
    assert policy.cycle_lead(0.025, capped) == pytest.approx(policy.MAX_LEAD_S)
    assert policy.latency_sample(0.01) == 0.01


def test_cycle_starts_on_the_first_plan_node_after_the_lead(plan):
    shifted = make_plan(start=100.0)
    for now, lead in ((100.0, 0.025), (100.31, 0.05), (100.5, 0.0)):
        start_at, stamp = policy.cycle_start(shifted, now, lead, 0.15)
        node = shifted.times[shifted.times >= now + lead - 100.0 - 1e-12][0]
        assert start_at == node and stamp == pytest.approx(100.0 + node)
    assert policy.cycle_start(shifted, 100.0 + T - 0.1, 0.025, 0.15) is None
    assert policy.cycle_start(shifted, 100.0 + T - 0.2, 0.025, 0.15) is not None
    # Past the plan's end: the plan time itself (no node left), nothing remains.
    assert policy.cycle_start(shifted, 100.0 + T + 1.0, 0.025, 0.0) is None


def test_a_goal_while_a_plan_moves_the_robot_starts_on_it_ahead(plan):
    """starts.goal_start_on_plan: the plan's node at now + lead, its time, or its rest."""
    moving = make_plan(start=10.0, result=SimpleNamespace())      # a solved plan, no stop
    now, lead = 10.3, 0.15
    measured = moving.states[25]                 # on the plan at 0.3 s, measured just now
    start, stamp, rest = starts.goal_start_on_plan(moving, 4, measured, 10.3, now, lead, 0.0)
    node = int(np.searchsorted(moving.times, 0.45))
    assert not rest and stamp == pytest.approx(10.0 + moving.times[node], abs=1e-12)
    assert moving.times[node] >= 0.45 - 1e-12 and moving.times[node - 1] < 0.45
    # stitch 0: the measured state predicted to the node under the plan's controls (an
    # independent RK4 of the same controls from the same state: the plan's own state).
    np.testing.assert_allclose(start, moving.states[node], rtol=0, atol=1e-9)
    # Far behind the robot is what the old start was: the measured state itself.
    assert np.max(np.abs(start - measured)) > 0.05
    # A plan that ends before now + lead: its rest, from its end.
    start, stamp, rest = starts.goal_start_on_plan(moving, 4, moving.states[90], 11.08, 11.1,
                                                   lead, 0.0)
    assert rest and stamp == pytest.approx(10.0 + T) and np.array_equal(start, moving.states[-1])
    # A robot at rest (the plan not started yet, or not followed) or no measured state: the
    # measured state is the start, as for any goal.
    assert starts.goal_start_on_plan(moving, 4, X0, 9.9, 9.95, lead, 0.0) is None
    assert starts.goal_start_on_plan(moving, 4, None, None, now, lead, 0.0) is None
    # Within the stitch (replan.stitch -1: GOAL_STITCH for every model) of the plan: the
    # plan's own state at the node, the commanded reference there.
    start, stamp, rest = starts.goal_start_on_plan(moving, 4, measured + [0.01, 0, 0, 0],
                                                   10.3, now, lead, -1.0)
    assert np.array_equal(start, moving.states[node]) and stamp == 10.0 + moving.times[node]
    # Over, a braking stop, another model, no plan: not this rule.
    assert starts.goal_start_on_plan(moving, 4, X0, 11.3, 11.3, lead, 0.0) is None
    stop = dataclasses.replace(moving, result=None, source='brake')
    assert starts.goal_start_on_plan(stop, 4, measured, 10.3, now, lead, 0.0) is None
    assert starts.goal_start_on_plan(moving, 6, measured, 10.3, now, lead, 0.0) is None
    assert starts.goal_start_on_plan(None, 4, measured, 10.3, now, lead, 0.0) is None


def test_cycle_nodes_budget_and_reason():
    assert policy.cycle_nodes(800, 300, 1.0, math.inf) == 300
    assert policy.cycle_nodes(120, 300, 1.0, math.inf) == 120
    assert policy.cycle_nodes(120, 300, 1.0, 0.002) == math.ceil(1.02 * 1.0 / 0.002)
    assert policy.cycle_timeout(10.0, 9.99, None) == pytest.approx(0.01 + policy.SEED_EXTRA_S)
    assert policy.cycle_timeout(10.0, 9.99, 0.02) == pytest.approx(0.02)
    assert policy.cycle_timeout(10.0, 11.0, None) == policy.MIN_CYCLE_TIMEOUT_S
    assert policy.cycle_reason(0.03, 0.02, 1.0, 5.0) == policy.DEVIATION
    assert policy.cycle_reason(0.03, 0.0, 1.0, 5.0) is None          # deviation off
    assert policy.cycle_reason(0.01, 0.02, 5.0, 5.0) == policy.RATE
    assert policy.cycle_reason(0.01, 0.02, 4.9, 5.0) is None
    assert policy.state_time(3.0, 3.5) == 3.0
    assert policy.state_time(3.0, 3.0 + policy.MAX_STATE_AGE_S + 0.1) == pytest.approx(4.1)


def test_failed_data_change_cycles_are_retried_only_on_new_data_or_when_late():
    retry = policy.retry_after_failed_cycle
    assert retry(policy.RATE, 3, 3, False)
    assert retry(policy.DEVIATION, 3, 3, False)
    assert not retry(policy.DATA_CHANGE, 3, 3, False)
    assert retry(policy.DATA_CHANGE, 2, 3, False)
    assert retry(policy.DATA_CHANGE, 3, 3, True)


# -- warm starts ----------------------------------------------------------------------------

def test_the_warm_start_node_is_the_nearest_in_scaled_state(plan):
    rng = np.random.default_rng(5)
    spread = np.ptp(plan.states, axis=0)
    spread[spread < 1e-6] = 1e-6
    for k in (0, 17, 50, 99, 100):
        x = plan.states[k] + 1e-4 * spread * rng.normal(size=4)
        assert nearest_node(MODEL, plan.states, x) == k
    # A plant lagging the plan's clock: the state decides, not the time.
    x = plan.states[40]
    expected = int(np.argmin(np.sum(((plan.states - x) / spread) ** 2, axis=1)))
    assert nearest_node(MODEL, plan.states, x) == expected == 40


class FakeResult:
    """A plan's result whose remainder records the time it is cut at."""

    def __init__(self, nodes, nu=2):
        self.nodes, self.nu, self.cuts = nodes, nu, []

    def remainder(self, t):
        self.cuts.append(t)
        k = int(round(t / (T / self.nodes)))
        return SimpleNamespace(controls=np.zeros((self.nodes - k, self.nu)))


def test_a_goals_warm_start_is_the_rest_of_a_plan_to_the_same_goal():
    result = FakeResult(N)
    executing = make_plan(start=10.0, result=result)
    problem = Problem(x0=tuple(executing.states[30] + 1e-5), x_goal=tuple(executing.goal),
                      obstacles=())
    warm, guess = goal_warm_start(executing, problem, 10.3, True)
    assert result.cuts == [executing.times[30]]
    assert guess.controls.shape == (N - 30, 2) and warm.n_intervals == N - 30
    # Cold: another goal, paper mode, no plan, the plan over, too few nodes left.
    other = Problem(x0=problem.x0, x_goal=(0.9, 0.0, 1.2, 0.0), obstacles=())
    assert goal_warm_start(executing, other, 10.3, True) == (other, None)
    assert goal_warm_start(executing, problem, 10.3, False) == (problem, None)
    assert goal_warm_start(None, problem, 10.3, True) == (problem, None)
    assert goal_warm_start(executing, problem, 10.0 + T + 0.01, True) == (problem, None)
    late = Problem(x0=tuple(executing.states[90]), x_goal=tuple(executing.goal), obstacles=())
    assert goal_warm_start(executing, late, 10.3, True) == (late, None)   # 10 < 20 nodes
    braking = make_plan(start=10.0)
    assert goal_warm_start(braking, problem, 10.3, True) == (problem, None)


def test_a_late_cycles_seed_warm_starts_only_the_next_cycle_of_its_plan(plan):
    other = make_plan()
    seed = Seed(plan, None, plan.times, plan.states, MODEL)
    assert policy.cycle_warm_source(plan, seed) is seed
    assert policy.cycle_warm_source(other, seed) is other
    assert policy.cycle_warm_source(plan, None) is plan


# -- estimate hysteresis --------------------------------------------------------------------

def test_the_planned_estimate_changes_only_when_it_moved_enough():
    built = []

    def build(values):
        built.append(dict(values))
        return ('model', values['m'])
    hold = EstimateHold()
    assert hold.update({'m': 50.0}, build) == ('model', 50.0)
    assert hold.update({'m': 50.4}, build) == ('model', 50.0)      # 0.8 %: kept
    assert hold.update({'m': 50.6}, build) == ('model', 50.6)      # 1.2 %: follows
    assert hold.update({'m': 50.6, 'J': 1.0}, build) == ('model', 50.6)   # new names
    assert len(built) == 3
    # No model for a moved estimate: none this time, the held one stays for the next.
    assert hold.update({'m': 80.0}, lambda v: None) is None
    assert hold.update({'m': 50.61, 'J': 1.0}, build) == ('model', 50.6) and len(built) == 3
    assert hold.update(None, build) is None and hold.values is None     # no estimate


# -- goal lifecycle -------------------------------------------------------------------------

def test_cancel_goal_brakes_an_executing_plan_and_stops_its_cycles():
    executing = make_plan(start=0.0, result=FakeResult(N))
    moving = executing.states[40]
    assert policy.cycle_allowed(executing, True, True)
    assert policy.cancel_goal_action(executing, 0.5, moving) == policy.BRAKE
    assert policy.cancel_goal_action(executing, 0.5, None) == policy.HOLD
    assert policy.cancel_goal_action(executing, 0.5, np.zeros(6)) == policy.HOLD
    assert policy.cancel_goal_action(None, 0.5, moving) == policy.NOTHING
    assert policy.cancel_goal_action(executing, T + 1.0, moving) == policy.NOTHING   # over
    executing.goal_active = False
    assert not policy.cycle_allowed(executing, True, True)
    stop = braking_plan(executing, moving, 0.5, policy.BRAKE_STEP_S)
    assert stop.braking and not stop.goal_active and not stop.replannable
    assert np.array_equal(stop.states[0], moving) and not np.any(stop.states[-1, 1::2])
    assert stop.start == 0.5 and np.array_equal(stop.goal, executing.goal)
    assert policy.cancel_goal_action(stop, 0.6, moving) == policy.NOTHING    # already braking
    assert braking_plan(executing, None, 0.5, policy.BRAKE_STEP_S) is None


def test_a_plant_reset_during_a_goal_is_a_deviation_that_replans_to_the_goal():
    """The reset state is far off the plan: a cycle at once, the goal stays active."""
    executing = make_plan(start=0.0, result=FakeResult(N))
    reset = X0.copy()
    deviation = executing.deviation(reset, 0.6)
    q_ref = np.interp(0.6, executing.times, executing.states[:, 0])
    assert deviation == pytest.approx(abs(q_ref - X0[0]), abs=1e-12)
    assert policy.cycle_reason(deviation, 0.02, 0.0, 1.0) == policy.DEVIATION
    assert policy.cycle_allowed(executing, True, True)
    assert not policy.cycle_allowed(executing, False, True)       # replanning off
    assert not policy.cycle_allowed(executing, True, False)       # not ready


def test_a_due_cycle_starts_from_the_state_predicted_to_its_plan_node():
    """The start is an independent RK4 of eq. (37) from the measured state to the stamp."""
    executing = make_plan(start=50.0, result=FakeResult(N))
    settings = SimpleNamespace(replan_deviation=0.02, replan_min_remaining=0.15)
    k = 30
    measured = executing.states[k] + np.array([0.004, 0.01, -0.003, 0.0])   # off the plan
    t = 50.0 + executing.times[k]
    now, lead = t + 0.004, 0.025
    cycle = policy.next_cycle(executing, measured, t, now, 7.0, lead, settings, 6.0, 3)
    assert cycle.reason == policy.RATE and cycle.revision == 3
    assert cycle.deadline == 7.0 + lead and cycle.state_stamp == t
    node = executing.times[executing.times >= now + lead - 50.0 - 1e-12][0]
    assert cycle.stamp_s == pytest.approx(50.0 + node)
    x, s = measured.copy(), executing.times[k]
    while s < node - 1e-12:                   # the plan's controls, interval by interval
        i = int(np.searchsorted(executing.times, s, side='right')) - 1
        h = min(node, executing.times[i + 1]) - s
        x, s = nm.rk4(x, executing.controls[i], h / 20, 20), s + h
    assert np.max(np.abs(cycle.start - x)) < 1e-7
    assert cycle.deviation == pytest.approx(0.004, abs=1e-9)
    # Not due before the next tick unless it deviates; a state from before the plan's start
    # waits unless new data cannot wait; too little left: none.
    assert policy.next_cycle(executing, measured, t, now, 5.0, lead, settings, 6.0, 3) is None
    off = executing.states[k] + np.array([0.05, 0.0, 0.0, 0.0])
    assert policy.next_cycle(executing, off, t, now, 5.0, lead, settings, 6.0,
                             3).reason == policy.DEVIATION
    early = policy.next_cycle(executing, measured, 49.9, 50.0, 5.0, lead, settings, 6.0, 3)
    assert early is None
    forced = policy.next_cycle(executing, measured, 49.9, 50.0, 5.0, lead, settings, 6.0, 3,
                               reason=policy.DATA_CHANGE)
    assert forced.reason == policy.DATA_CHANGE and forced.deviation == 0.0
    end = 50.0 + T - 0.1
    assert policy.next_cycle(executing, executing.states[-5], end, end, 9.0, lead, settings,
                             6.0, 3) is None


def test_a_cycle_on_track_starts_on_the_plans_own_state_and_off_track_predicted():
    """replan.stitch: within it the plan's node state (no jump), beyond it the prediction."""
    executing = make_plan(start=50.0, result=FakeResult(N))
    k, lead = 30, 0.025
    t = 50.0 + executing.times[k]
    node = int(np.flatnonzero(executing.times >= t + 0.004 + lead - 50.0 - 1e-12)[0])
    measured = executing.states[k] + np.array([0.004, 0.01, -0.003, 0.0])
    far = executing.states[k] + np.array([0.03, 0.01, -0.003, 0.0])
    starts = {}
    for stitch in (0.0, 0.005, 0.02):
        settings = SimpleNamespace(replan_deviation=0.05, replan_min_remaining=0.15,
                                   replan_stitch=stitch)
        for name, state in (('near', measured), ('far', far)):
            cycle = policy.next_cycle(executing, state, t, t + 0.004, 7.0, lead, settings,
                                      6.0, 3)
            assert cycle.stamp_s == pytest.approx(50.0 + executing.times[node])
            starts[stitch, name] = cycle.start
    # On track (0.004 rad off, within 0.005 and 0.02): exactly the plan's state at the node.
    for stitch in (0.005, 0.02):
        assert np.array_equal(starts[stitch, 'near'], executing.states[node])
    # Off track (0.03 rad), or stitching off: the measured state predicted to the node.
    predicted = starts[0.0, 'near']
    assert np.max(np.abs(predicted - executing.states[node])) > 1e-3
    for stitch in (0.0, 0.005, 0.02):
        assert np.array_equal(starts[stitch, 'far'], starts[0.0, 'far'])
    assert np.max(np.abs(starts[0.0, 'far'][0] - executing.states[node][0])) > 0.02
    # -1 (the default) by model: predicted for a planar model, on the plan for a URDF arm
    # within ARM_STITCH (the arm's prediction is not needed there).
    np.testing.assert_allclose(policy.cycle_start_state(
        executing, measured, executing.times[k], executing.times[node], 0.004, -1.0),
        predicted, rtol=0.0, atol=1e-12)
    arm_plan = SimpleNamespace(model=SimpleNamespace(is_arm=True), times=executing.times,
                               states=executing.states)
    assert np.array_equal(policy.cycle_start_state(
        arm_plan, measured, executing.times[k], executing.times[node],
        policy.ARM_STITCH, -1.0), executing.states[node])


def test_a_cycle_problem_keeps_the_warm_starts_grid_within_its_budget():
    result = FakeResult(N)
    executing = make_plan(start=0.0, result=result)
    cycle = policy.Cycle(executing, executing.states[40], 0.5, 1.0, 0.45, 0.0, policy.RATE,
                         deadline=1.025)
    problem = Problem(x0=tuple(executing.states[40]), x_goal=tuple(executing.goal),
                      obstacles=())
    options = SolverOptions(timeout=None)
    guess = SimpleNamespace(controls=np.zeros((60, 2)), final_time=0.72)
    source = SimpleNamespace(result=SimpleNamespace(remainder=lambda t: guess),
                             times=executing.times, states=executing.states, model=MODEL)
    planned, budget, got = policy.cycle_problem(source, cycle, problem, 300, options, 1.0)
    assert got is guess and planned.n_intervals == 60
    assert budget.timeout == pytest.approx(0.025 + policy.SEED_EXTRA_S)
    planned, _, _ = policy.cycle_problem(source, cycle, problem, 40, options, 1.0)
    assert planned.n_intervals == 40
    guess = SimpleNamespace(controls=np.zeros((4, 2)), final_time=0.05)
    assert policy.cycle_problem(source, cycle, problem, 300, options, 1.0) == (
        None, None, 'only 4 plan nodes left')


def test_a_cycle_plans_with_the_replan_integrator_and_goals_keep_theirs():
    """replan.integrator reaches the cycle's problem; without one it keeps the problem's."""
    executing = make_plan(start=50.0, result=FakeResult(N))
    k = 30
    t = 50.0 + executing.times[k]
    rk4_settings = SimpleNamespace(replan_deviation=0.02, replan_min_remaining=0.15,
                                   replan_integrator='rk4')
    cycle = policy.next_cycle(executing, executing.states[k], t, t + 0.004, 7.0, 0.025,
                              rk4_settings, 6.0, 3)
    assert cycle.integrator == 'rk4'
    problem = Problem(x0=tuple(cycle.start), x_goal=tuple(executing.goal), obstacles=())
    assert problem.integrator == 'euler'
    guess = SimpleNamespace(controls=np.zeros((60, 2)), final_time=0.72)
    source = SimpleNamespace(result=SimpleNamespace(remainder=lambda t: guess),
                             times=executing.times, states=executing.states, model=MODEL)
    options = SolverOptions(timeout=None)
    planned, _, _ = policy.cycle_problem(source, cycle, problem, 300, options, 1.0)
    assert planned.integrator == 'rk4' and planned.n_intervals == 60
    # Every other field is the given problem's.
    assert dataclasses.replace(planned, integrator='euler', n_intervals=N) == \
        dataclasses.replace(problem, n_intervals=N)
    euler = dataclasses.replace(cycle, integrator='euler')
    assert policy.cycle_problem(source, euler, problem, 300, options, 1.0)[0].integrator == \
        'euler'
    unnamed = dataclasses.replace(cycle, integrator='')
    rk4_problem = dataclasses.replace(problem, integrator='rk4')
    assert policy.cycle_problem(source, unnamed, rk4_problem, 300, options, 1.0)[0] \
        .integrator == 'rk4'


def test_a_measured_state_is_stale_when_older_than_the_limit_or_from_a_clock_gone_back():
    assert starts.stale_state(None, 100.0, 1.0) is None          # none: initial_state
    assert starts.stale_state(99.5, 100.0, 1.0) is None
    assert starts.stale_state(99.0, 100.0, 1.0) is None          # exactly the limit
    old = starts.stale_state(98.75, 100.0, 1.0)
    assert old is not None and '1.25 s ago' in old and 'max_state_age = 1 s' in old
    back = starts.stale_state(130.0, 100.0, 1.0)                  # a simulation reset
    assert back is not None and 'went back' in back
    assert starts.stale_state(100.0, 100.0, 0.01) is None


def test_the_recovery_margin_counts_the_first_step_of_a_start_moving_into_the_margin():
    rows = [(1.0, 1.0, 0.2)]
    r = math.hypot(1.0, 1.0) - 0.2 - 0.012          # the hand 12 mm off the circle
    toward = np.array([math.pi / 4, 0.0, r - 1.1, 0.5])   # extending toward it at 0.5 m/s
    assert starts.recovery_margin(MODEL, toward, rows, 0.01) is None      # outside the margin
    # One 10 ms step ahead the hand is 7 mm off: half of that is the margin.
    assert starts.recovery_margin(MODEL, toward, rows, 0.01, step=0.01) == \
        pytest.approx(0.5 * 0.007, rel=1e-6)
    away = toward * np.array([1.0, 1.0, 1.0, -1.0])
    assert starts.recovery_margin(MODEL, away, rows, 0.01, step=0.01) is None


def test_a_failed_goal_from_the_plan_is_retried_with_half_the_margin_or_the_clearance():
    rows = [(1.0, 1.0, 0.2)]
    r = math.hypot(1.0, 1.0) - 0.2
    at = lambda gap: np.array([math.pi / 4, 0.0, r - gap - 1.1, 0.0])    # noqa: E731
    assert starts.retry_margin(MODEL, at(0.012), rows, 0.01) == pytest.approx(0.005)
    assert starts.retry_margin(MODEL, at(0.004), rows, 0.01) == pytest.approx(0.002)
    assert starts.retry_margin(MODEL, at(-0.001), rows, 0.01) is None     # inside the circle
    assert starts.retry_margin(MODEL, at(0.012), rows, 0.0) is None
    assert starts.retry_margin(MODEL, at(0.012), [], 0.01) is None
