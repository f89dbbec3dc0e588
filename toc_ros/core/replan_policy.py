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
The replan and braking policy of a goal's execution (a planner node wires it to its inputs).

While a plan executes, replan cycles solve to the same goal from the measured state predicted
forward by a lead (the time the solve and the transport need).  This module decides:

- when a cycle is due (``cycle_reason``) and on which node of the executing plan the new
  plan starts (``cycle_start``: the replan grid);
- how long the lead is (``cycle_lead``: the configured lead, or more when recent cycles took
  longer) and how long a cycle may solve (``cycle_timeout``) on how many nodes (``cycle_nodes``);
- which plan warm-starts a cycle (``cycle_warm_source``: a late cycle's plan seeds the next);
- whether a plan that new data makes unsafe may run on while a cycle plans around the new
  data, or must brake at once (``brake_can_wait``), until when at most (``brake_deadline``),
  and whether to try again after a failed
  cycle (``retry_after_failed_cycle``);
- what abandoning a goal does to the executing plan (``cancel_goal_action``).

Where a goal starts (on the executing plan, at a braking stop's rest) and with which margin:
goal_starts.py.
"""

import dataclasses
import math
from typing import Any

import numpy as np

from toc_ros.core.executing_plan import nearest_node
from toc_ros.core.replan import predict, stop_later_is_clear

# A replan cycle needs at least this many nodes of the executing plan left (a cycle keeps its
# plan's grid, so near the end of a plan cut to the largest cycle size few are left).
MIN_CYCLE_GUESS_NODES = 5
MIN_CYCLE_TIMEOUT_S = 0.002
# A measured state's stamp further than this from the node clock is from another time base
# (a simulated clock that the planner does not use, say): its age is then taken as zero.
MAX_STATE_AGE_S = 1.0
# [rad/s, m/s] joint speeds up to which a goal's start is at rest (its plan starts the start
# lead after it is published).
REST_SPEED = 1e-3
# The lead grows with the measured cycle latency (the median of the last LATENCY_WINDOW cycles,
# x LEAD_PER_MEDIAN) up to MAX_LEAD_S.
LATENCY_WINDOW = 20
MAX_LEAD_S = 0.2
LEAD_PER_MEDIAN = 2.0
MIN_LATENCY_SAMPLES = 5
# [s] a cycle's solve may run this long past its deadline: not published, its plan warm-starts
# the next cycle (a new switching structure takes one slow solve, then the next is fast).  Not
# longer: the solves that need more (an overshoot in the final braking: hundreds of
# iterations) would take a core from the plant for a tenth of a second and delay the next
# cycles.
SEED_EXTRA_S = 0.05
# New data that puts a true (uninflated) obstacle on the executing plan brakes at once unless
# braking can wait for a replan: the plan stays out of the true obstacles until the replan's
# outcome is known (its lead + SEED_EXTRA_S + BRAKE_HORIZON_S from now), and the fastest stop
# started then still keeps every link out of them (brake_can_wait).  So the lead, which grows
# with the measured cycle latency on a loaded machine, moves the braking decision earlier.
BRAKE_HORIZON_S = 0.1
# Step of the braking trajectory that is published.
BRAKE_STEP_S = 0.002
# Step of the stop simulated to decide whether braking can wait: its path stays within 3e-4
# (rad, m) of the BRAKE_STEP_S one, at a sixth of the time.
BRAKE_CHECK_STEP_S = 0.01
# Reasons of a replan cycle.
RATE, DEVIATION, DATA_CHANGE = 'rate', 'deviation', 'data change'


@dataclasses.dataclass
class Cycle:
    """One replan cycle: the plan it replaces and the state it starts from."""

    plan: Any               # the ExecutingPlan when the cycle started
    start: np.ndarray       # state predicted at stamp_s
    stamp_s: float          # the new plan's header.stamp [s, node clock]
    received: float         # monotonic time when its measured state arrived
    state_stamp: float      # that state's stamp [s]
    deviation: float        # max |q - q_ref| of the measured state [rad or m]
    reason: str             # RATE, DEVIATION or DATA_CHANGE
    revision: int = -1      # the data revision when it started
    deadline: float = math.inf      # publish by then: received + lead [s, monotonic]
    integrator: str = ''    # discretisation of its plan ('': the problem's own)


def state_time(t, now):
    """Return a measured state's time t [s], or now when t is from another time base."""
    return now if abs(now - t) > MAX_STATE_AGE_S else t


def state_now(plan, measured, measured_time, now):
    """
    Return a measured state predicted along plan to now, or as it is.

    The robot follows plan until another trajectory reaches it, so a state measured at
    measured_time [s, node clock] has moved on along plan since: on a loaded machine the newest
    joint_states a node has processed can be a fifth of a second old, and a braking stop from
    where the robot was then would pull it back along its path.  As it is when its time is
    unknown or from another time base (state_time), or from before the plan started.
    """
    model = None if plan is None else plan.model
    if measured is None or measured_time is None or model is None \
            or getattr(model, 'is_arm', False) or np.shape(measured) != (model.nx,):
        return measured         # (URDF arms are not predicted: no rollout kernel here)
    t0, t1 = plan.elapsed(state_time(measured_time, now)), plan.elapsed(now)
    if t0 < 0.0 or not t1 > t0:
        return measured
    return predict(model, measured, plan.times, plan.controls, t0, t1)


def at_rest(model, x):
    """Tell whether every joint speed of state x is at most REST_SPEED."""
    return bool(np.max(np.abs(model.velocities(np.asarray(x)))) <= REST_SPEED)


def cycle_lead(lead, latencies):
    """
    Return a cycle's lead [s]: the configured lead, or more when recent cycles took longer.

    More: LEAD_PER_MEDIAN x the median of the recent cycle latencies (with at least
    MIN_LATENCY_SAMPLES).  The median, not a high percentile: the rare cycle whose warm start
    needs a new switching structure (a new estimate, the final braking) runs late and seeds the
    next one instead of stretching every cycle's lead, and with it the prediction.
    """
    recent = list(latencies)
    latency = (LEAD_PER_MEDIAN * float(np.median(recent))
               if len(recent) >= MIN_LATENCY_SAMPLES else 0.0)
    return max(float(lead), latency)


def latency_sample(latency):
    """Return a solved cycle's latency as the lead's window keeps it (capped: MAX_LEAD_S)."""
    return min(float(latency), MAX_LEAD_S / LEAD_PER_MEDIAN)


def cycle_reason(deviation, deviation_limit, received, next_cycle):
    """Return why a cycle is due from a measured state (DEVIATION, RATE) or None."""
    if deviation_limit > 0.0 and deviation > deviation_limit:
        return DEVIATION
    if received >= next_cycle:
        return RATE
    return None


def cycle_start(plan, now, lead, min_remaining):
    """
    Return (start_at, stamp) of a cycle's plan, or None when too little is left for one.

    The new plan starts on a node of the executing one (the first at or after now + lead,
    plan time start_at; stamp = its node-clock time): its warm start, that plan's remainder
    from the node, then starts where the predicted state is, not up to half an interval away
    (which costs iterations).  None when less than min_remaining [s] of the plan is left then.
    """
    start_at = now + lead - plan.start
    node = int(np.searchsorted(plan.times, start_at))
    if node < plan.times.shape[0]:
        start_at = float(plan.times[node])
    if plan.duration - start_at < float(min_remaining):
        return None
    return start_at, plan.start + start_at


# replan.stitch = -1 for URDF arms [rad]: the replan.deviation that starts a cycle at once.
ARM_STITCH = 0.02


def cycle_start_state(plan, state, measured_at, start_at, deviation, stitch):
    """
    Return the state a cycle's plan starts from at plan time start_at (a node of the plan).

    Within stitch [rad or m] of the plan (deviation, measured at plan time measured_at) the
    plan's own state there: the tracking controller (feed-forward + feedback) keeps the robot
    on its reference, and an open-loop prediction, which leaves that feedback out, drifts
    from where the robot will be (on a recorded Panda run, 60 ms ahead: 8-9 mrad median
    against 3.3-3.5 from the plan's state); the new plan also continues the commanded
    reference without a jump.  Farther off (or stitch 0) the measured state predicted forward
    under the plan's controls.  stitch < 0: by model (ARM_STITCH for URDF arms, else 0: on
    the paper's robot with a 20 % heavier plant, cycles from the prediction arrived 0.3-0.9 %
    after the plant's best plan, from the plan's state 1.2-1.3 %).  A prediction starts an
    arm's Euler plan half a step behind it (ExecutingPlan.start_for): its published motion
    then begins at the prediction.
    """
    if stitch < 0.0:
        stitch = ARM_STITCH if getattr(plan.model, 'is_arm', False) else 0.0
    if stitch > 0.0 and deviation <= stitch:
        node = int(np.searchsorted(plan.times, start_at))
        if node < plan.times.shape[0] and plan.times[node] == start_at:
            return np.array(plan.states[node], dtype=float)
    return plan.start_for(predict(plan.model, state, plan.times, plan.controls, measured_at,
                                  start_at))


def next_cycle(plan, state, t, now, received, lead, settings, next_due, revision,
               reason=None):
    """
    Return the replan Cycle due from a measured state, or None.

    state: measured at node-clock time t, received at monotonic time received; settings:
    replan_deviation, replan_min_remaining, replan_stitch and replan_integrator (the node's
    settings; the cycle plans with that integrator); next_due: monotonic time
    of the next regular cycle; reason: None (due by deviation or rate) or why it is due at
    once (DATA_CHANGE).  The cycle starts at the plan node at or after now + lead
    (cycle_start), from the plan's state there or the predicted one (cycle_start_state), and
    must be published by received + lead.
    """
    t = state_time(t, now)
    measured_at = t - plan.start
    if measured_at < 0.0:
        # The plan starts a lead after the state of the cycle that made it, and the state is
        # from before that: wait for it to apply, unless new data cannot wait; then start
        # from the plan's own start (that cycle's prediction).
        if reason is None:
            return None
        state, measured_at = plan.states[0], 0.0
    deviation = plan.deviation(state, measured_at)
    if reason is None:
        reason = cycle_reason(deviation, settings.replan_deviation, received, next_due)
        if reason is None:
            return None
    timing = cycle_start(plan, now, lead, settings.replan_min_remaining)
    if timing is None:
        return None
    start_at, stamp = timing
    start = cycle_start_state(plan, state, measured_at, start_at, deviation,
                              getattr(settings, 'replan_stitch', 0.0))
    # URDF arms are planned with explicit Euler only (their solver): the goal's integrator.
    integrator = '' if getattr(plan.model, 'is_arm', False) else getattr(
        settings, 'replan_integrator', '')
    return Cycle(plan, start, stamp, received, t, deviation, reason, revision, received + lead,
                 integrator)


def cycle_problem(source, cycle, problem, max_nodes, options, now):
    """
    Return (problem, options, warm start) of a cycle, or (None, None, why) when it cannot run.

    source: what warm-starts it (cycle_warm_source); problem: the cycle's problem from
    cycle.start to the goal (model and data current), planned with cycle.integrator when it
    names one; the warm start is source's remainder
    from its node nearest to cycle.start, on its own grid (cycle_nodes), and the solve may run
    until the deadline plus SEED_EXTRA_S (cycle_timeout).
    """
    guess = source.result.remainder(source.times[nearest_node(
        source.model, source.states, cycle.start)])
    if guess.controls.shape[0] < MIN_CYCLE_GUESS_NODES:
        return None, None, f'only {guess.controls.shape[0]} plan nodes left'
    problem = dataclasses.replace(
        problem, integrator=cycle.integrator or problem.integrator, n_intervals=cycle_nodes(
            guess.controls.shape[0], max_nodes, guess.final_time,
            getattr(problem.robot_model, 'max_step', math.inf)))
    options = dataclasses.replace(options, timeout=cycle_timeout(
        cycle.deadline, now, options.timeout))
    return problem, options, guess


def cycle_nodes(guess_nodes, max_nodes, final_time, max_step):
    """
    Return the intervals of a cycle's problem.

    The warm start's own grid (same tau: it is then nearly optimal), cut to max_nodes intervals
    (resampling to another grid each cycle would move the control switches off it and cost
    many more iterations), but with steps no longer than the model's max_step (actuator lags;
    2 % to spare: the plan's t_f may grow a little, and its remainders keep its grid).
    """
    return max(min(int(guess_nodes), int(max_nodes)), math.ceil(1.02 * final_time / max_step))


def cycle_timeout(deadline, now, timeout):
    """
    Return a cycle's solve timeout [s]: until its deadline + SEED_EXTRA_S, within timeout.

    A cycle's plan is published only by its deadline; a solve that runs late goes on for up to
    SEED_EXTRA_S and seeds the next cycle.  timeout None: no configured limit.
    """
    limit = math.inf if not timeout else timeout
    return max(min(deadline - now + SEED_EXTRA_S, limit), MIN_CYCLE_TIMEOUT_S)


def cycle_warm_source(plan, seed):
    """Return what warm-starts a cycle: a late cycle's seed for this plan, else the plan."""
    return plan if seed is None or seed.plan is not plan else seed


def brake_wait(lead):
    """Return how long braking would wait for a data-change cycle with this lead [s]."""
    return lead + SEED_EXTRA_S + BRAKE_HORIZON_S


def brake_deadline(now, lead):
    """
    Return when a plan whose braking waits for a replan must brake unless replaced [s].

    brake_can_wait checked a stop started brake_wait(lead) after now; the deadline comes half
    of BRAKE_HORIZON_S before that, so the stop is published in time even when the replan's
    outcome (its failure, say) never comes: a worker that a loaded machine starves.
    """
    return float(now) + lead + SEED_EXTRA_S + 0.5 * BRAKE_HORIZON_S


def brake_can_wait(plan, rows, measured, elapsed, lead, conflict):
    """
    Return whether a plan that violates new data may run on while a replan is tried.

    rows: the true (uninflated) circles; conflict: the time until the plan's rest enters one
    (executing_plan.true_conflict_time; None: never).  Yes when it never does, or when it stays
    out of them for the wait (brake_wait(lead)) and the fastest stop (replan.brake) from the
    state predicted at the wait's end (measured: the latest state, at plan time elapsed)
    keeps every link out of them: braking later than that could no longer stop clear.
    """
    if conflict is None:
        return True
    wait = brake_wait(lead)
    model = plan.model
    if conflict <= wait or model is None or np.shape(measured) != (model.nx,):
        return False
    try:
        return stop_later_is_clear(model, measured, plan.times, plan.controls, elapsed, wait,
                                   rows, BRAKE_CHECK_STEP_S)
    except (ValueError, FloatingPointError):
        return False


def retry_after_failed_cycle(reason, cycle_revision, revision, late):
    """
    Tell whether a failed cycle's plan, unsafe under the current data, gets another cycle.

    Yes unless it was a data-change cycle on the same data that failed in time (another would
    fail alike); a late one seeded the next, which starts where it ended.
    """
    return reason != DATA_CHANGE or cycle_revision != revision or late


# What abandoning a goal does to the executing plan (cancel_goal_action).
BRAKE, HOLD, NOTHING = 'brake', 'hold', 'nothing'


def cancel_goal_action(plan, now, measured):
    """
    Return how a goal cancel stops the robot: BRAKE, HOLD or NOTHING.

    BRAKE: a plan of the goal still executes and the measured state fits its model (the
    fastest stop from there); HOLD: it executes but no usable state is known (an empty
    trajectory: the robot holds); NOTHING: no plan moves the robot to the goal (none
    published, finished, or a braking stop already executing).
    """
    if plan is None or plan.braking or not plan.executing(now):
        return NOTHING
    model = plan.model
    if measured is None or model is None or np.shape(measured) != (model.nx,):
        return HOLD
    return BRAKE


def cycle_allowed(plan, replanning, ready):
    """Tell whether replan cycles may run for plan: replanning on, ready, its goal active."""
    return replanning and ready and plan is not None and plan.replannable
