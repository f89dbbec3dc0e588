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
solver_node's planning without rclpy: the Planner on a recording port, with real solves.

The cases of the node's process tests (a goal solved and published, refusals, a plan that
new obstacles make unsafe stopped and planned again, a canceled goal braking, a replan cycle
published ahead of its stamp or kept when late), each in well under a second, plus the ROS-free
pieces it is made of (ExecutionState, goal_requests, SolveProgress, KernelLoader).  Published
trajectories are checked against limits and goals recomputed here.
"""

import math
import threading
import time
from types import SimpleNamespace

import numpy as np
import numpy_model as nm
import pytest
from toc_ros import goal_requests as goals, progress as schema
from toc_ros import kernel_loader, planner as planner_module
from toc_ros.core import goal_starts as starts, Progress, replan_policy as policy, solve, Status
from toc_ros.core.executing_plan import braking_plan, ExecutingPlan, Seed
from toc_ros.core.model import RobotParams
from toc_ros.core.models import CylindricalRobot
from toc_ros.execution_state import ExecutionState
from toc_ros.goal_requests import BRAKING_REST, start_state
from toc_ros.nodes import parameters
from toc_ros.nodes.solver_settings import SolverNodeConfig
from toc_ros.planner import Planner
from toc_ros.replan_cycles import CYCLE_SOURCE
from toc_ros.solve_progress import SolveProgress

X0 = (math.pi / 12.0, 0.0, 1.0, 0.0)
NEAR_GOAL = np.array([-0.5, 0.0, 1.0, 0.0])
U_MAX = np.array([600.0, 500.0])
A = 1.1             # [m] the cylindrical robot's hand offset (eq. 37's a)
SOLVE_WAIT_S = 120.0


def config(**changes):
    """Return the node's default settings with changes (solver.N 100: quick solves)."""
    flat = {name: parameters.default(name) for name in parameters.SOLVER_NODE_NAMES}
    flat.update({'solver.N': 100, 'solver.timeout': 300.0})
    flat.update(changes)
    return SolverNodeConfig.from_flat(flat)


class Log:
    """A logger that records (severity, text)."""

    def __init__(self):
        self.lines = []

    def info(self, text, **_):
        self.lines.append(('info', text))

    def warning(self, text, **_):
        self.lines.append(('warning', text))

    def error(self, text, **_):
        self.lines.append(('error', text))


class Port:
    """The node side of a Planner: records what it would publish; a clock that tests set."""

    def __init__(self, settings, measured=None):
        self.config, self.measured, self.clock = settings, measured, 100.0
        self.measured_at = None      # node-clock time of measured (None: unknown)
        self.received_at = None      # node-clock time it arrived (None: nothing received)
        self.trajectories, self.paths, self.reports = [], [], []
        self.holds = []              # each trajectory's hold_effort
        self.markers, self.arm = 0, 0
        self.logger = Log()
        self.estimate = (None, '')

    def settings(self):
        return self.config

    def snapshot(self):
        return self.config, self.measured

    def measured_time(self):
        return self.measured_at

    def measured_received(self):
        return self.received_at

    def now(self):
        return self.clock

    def publish_trajectory(self, msg, hold_effort=None):
        self.trajectories.append(msg)
        self.holds.append(hold_effort)

    def publish_path(self, msg):
        self.paths.append(msg)

    def publish_markers(self):
        self.markers += 1

    def arm_moved(self):
        self.arm += 1

    def report(self, report):
        self.reports.append(report)

    def estimated_model(self, _config):
        return self.estimate

    def events(self):
        return [r.event for r in self.reports]


def planner(settings=None, measured=None):
    ready = threading.Event()
    ready.set()
    settings = settings or config()
    port = Port(settings, measured)
    return Planner(port, settings.planning_data(), ready), port


def finish(plan_maker, request=None):
    """Wait until request (if given) and every follow-up (a replan, a cycle) is done."""
    assert request is None or request.done.wait(SOLVE_WAIT_S)
    deadline = time.monotonic() + SOLVE_WAIT_S
    while plan_maker.worker.busy() and time.monotonic() < deadline:
        time.sleep(0.005)
    assert not plan_maker.worker.busy()


def points(msg):
    """Return (times [s], positions, velocities, efforts) of a JointTrajectory."""
    t = np.array([p.time_from_start.sec + 1e-9 * p.time_from_start.nanosec for p in msg.points])
    return (t, np.array([p.positions for p in msg.points]),
            np.array([p.velocities for p in msg.points]),
            np.array([p.effort for p in msg.points]))


def stamp(msg):
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


def hand(q1, q2):
    r = A + q2
    return np.array([r * math.cos(q1), r * math.sin(q1)])


@pytest.fixture(scope='module')
def solved():
    """Solve a goal from X0 to NEAR_GOAL (no measured state: from initial_state)."""
    p, port = planner()
    request = p.submit(lambda _c: NEAR_GOAL, 'goal_joints')
    finish(p, request)
    return p, port, request


# -- goals ---------------------------------------------------------------------------------

def test_a_goal_is_solved_published_at_the_start_lead_and_reported(solved):
    p, port, request = solved
    assert len(port.trajectories) == 1 and len(port.paths) == 1 and port.markers == 1
    msg = port.trajectories[0]
    assert stamp(msg) == pytest.approx(port.clock + port.config.node.start_lead, abs=1e-9)
    t, q, dq, u = points(msg)
    assert np.all(np.diff(t) > 0.0)
    assert np.all(np.abs(u) <= U_MAX * (1 + 1e-9))                  # the bounds, recomputed
    np.testing.assert_allclose(q[0], np.array(X0)[0::2], atol=1e-9)  # from initial_state
    np.testing.assert_allclose(q[-1], NEAR_GOAL[0::2], atol=1e-3)
    np.testing.assert_allclose(dq[-1], [0.0, 0.0], atol=1e-3)
    rows = np.array(port.config.problem.obstacles)
    clearance = min(np.hypot(*(hand(a, b) - rows[0, :2])) - rows[0, 2] for a, b in q)
    assert clearance > 0.0
    final = port.reports[-1]
    assert final.status is Status.SOLVED and final.goal_source == 'goal_joints'
    assert final.start_source == 'initial_state' and final.data_revision == 0
    assert final.obstacles_hash == schema.obstacles_hash(port.config.problem.obstacles,
                                                         port.config.problem.margin)
    plan, revision = p.plans.current()
    assert revision == 0 and plan.source == 'goal_joints' and plan.replannable
    np.testing.assert_array_equal(plan.goal, NEAR_GOAL)
    assert plan.start == stamp(msg) and request.path is port.paths[0]


PANDA_READY = [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785]


def panda_planner():
    """Return a Planner and Port for the Panda at rest in its ready pose (N 30, no cycles)."""
    pytest.importorskip('pinocchio')
    from arm_oracle import PANDA_JOINTS
    return planner(config(**{'robot.model': 'panda', 'joint_names': PANDA_JOINTS,
                             'initial_state': PANDA_READY, 'solver.N': 30,
                             'replan.rate': 0.0, 'obstacles.rows': []}))


def test_an_arm_goal_from_rest_ends_at_rest_and_is_held_until_it_starts():
    p, port = panda_planner()
    from arm_oracle import ArmOracle, find_panda_urdf
    import pinocchio as pin
    ready = PANDA_READY
    goal = np.array([0.6, -0.5, 0.2, -2.1, 0.1, 1.7, 0.7])
    finish(p, p.submit(lambda c: c.model.state(goal), 'goal_joints'))
    oracle = ArmOracle(find_panda_urdf().read_text())
    assert len(port.trajectories) == 1, port.logger.lines
    msg, hold = port.trajectories[0], port.holds[0]
    # The controller's goal holds the start with its gravity torque (recomputed here).
    np.testing.assert_allclose(hold, pin.computeGeneralizedGravity(
        oracle.model, oracle.model.createData(), np.array(ready)), rtol=0, atol=1e-9)
    _, q, dq, u = points(msg)
    assert np.all(dq[-1] == 0.0)                       # JTC refuses a moving last point
    np.testing.assert_allclose(u[-1], pin.computeGeneralizedGravity(
        oracle.model, oracle.model.createData(), q[-1]), rtol=0, atol=1e-9)


def test_an_arm_goal_while_the_arm_moves_continues_the_commanded_motion():
    """Started on the executing Euler plan, set for its own step: no jump of the reference."""
    p, port = panda_planner()
    from toc_ros.core.plan_reference import cubic_at
    first = np.array([0.8, -0.3, 0.0, -2.0, 0.0, 1.8, 0.785])
    finish(p, p.submit(lambda c: c.model.state(first), 'goal_joints'))
    plan, _ = p.plans.current()
    k = int(np.searchsorted(plan.times, 0.3 * plan.duration))
    port.clock = port.measured_at = plan.start + plan.times[k]
    port.measured = plan.states[k].copy()
    goal = np.array([-0.6, 0.2, 0.5, -1.6, 0.4, 1.5, 0.2])
    finish(p, p.submit(lambda c: c.model.state(goal), 'goal_joints'))
    assert len(port.trajectories) == 2 and port.reports[-1].start_source == goals.ON_PLAN
    old, new = port.trajectories
    times, q_old, dq_old, _ = points(old)
    _, q_new, dq_new, _ = points(new)
    at = stamp(new) - stamp(old)
    assert at >= plan.times[k] + port.config.node.goal_lead - 1e-9
    # The new plan's first point is where the commanded motion (the cubic through the old
    # points) is at its stamp, moving as fast: the old point there shifted by the new plan's
    # own half step would be millimetres off at these speeds.
    np.testing.assert_allclose(q_new[0], cubic_at(times, q_old, dq_old, at), atol=1e-5)
    assert np.max(np.abs(dq_new[0])) > 1.0
    node = int(np.argmin(np.abs(times - at)))
    np.testing.assert_allclose(dq_new[0], dq_old[node], atol=1e-9)
    assert 'from the start set for its step' in port.reports[-1].message
    p.worker.stop()


def test_a_goal_is_planned_with_the_online_estimate_once_one_is_in_use():
    p, port = planner(config(**{'replan.rate': 0.0}))
    finish(p, p.submit(lambda _c: NEAR_GOAL, 'goal_joints'))
    assert port.reports[-1].estimate == ''
    assert p.plans.current()[0].model is not None
    configured_t_f = port.reports[-1].t_f
    heavier = CylindricalRobot(RobotParams(hand_mass=60.0))     # the online estimate
    port.estimate = (heavier, 'hand_mass=60')
    # Once that plan is over, from the start again (a goal while it runs would start on it).
    port.clock += port.config.node.start_lead + configured_t_f + 1.0
    port.measured = np.array(X0)
    finish(p, p.submit(lambda _c: NEAR_GOAL, 'goal_joints'))
    final = port.reports[-1]
    assert final.status is Status.SOLVED and final.estimate == 'hand_mass=60'
    assert p.plans.current()[0].model is heavier
    # A heavier hand under the same torque bounds takes longer (the model was really used).
    assert final.t_f > configured_t_f * 1.01
    p.worker.stop()


def test_refused_goals_are_reported_with_the_reason_and_never_queued():
    p, port = planner()
    assert p.submit(lambda _c: np.array([0.3, 0.0, 5.0, 0.0]), 'goal_joints') is None
    assert 'outside extension_limits' in port.reports[-1].message
    assert port.reports[-1].status is Status.INVALID_INPUT
    inside = np.array([math.pi / 4, 0.0, math.sqrt(2.0) - A, 0.0])   # the hand on (1, 1)
    assert p.submit(lambda _c: inside, 'goal_pose') is None
    assert 'start state from initial_state' in port.reports[-1].message
    assert not p.worker.busy() and port.trajectories == []


def test_a_goal_is_refused_while_the_newest_joint_states_is_stale():
    p, port = planner(config(max_state_age=0.5), measured=np.array(X0, dtype=float))
    port.received_at = port.clock - 0.8
    assert p.submit(lambda _c: NEAR_GOAL, 'goal_joints') is None
    assert 'no recent joint_states' in port.reports[-1].message
    assert '0.8 s ago' in port.reports[-1].message
    assert port.reports[-1].status is Status.INVALID_INPUT
    # Fresh again (a new joint_states): planned and published.
    port.received_at = port.clock - 0.1
    request = p.submit(lambda _c: NEAR_GOAL, 'goal_joints')
    finish(p, request)
    assert len(port.trajectories) == 1
    p.worker.stop()


def test_a_queued_goal_whose_joint_states_went_stale_meanwhile_is_refused_when_its_turn_comes():
    ready = threading.Event()           # the kernels still loading: the goal waits
    settings = config(max_state_age=0.5)
    port = Port(settings, np.array(X0, dtype=float))
    port.received_at = port.clock
    p = Planner(port, settings.planning_data(), ready)
    request = p.submit(lambda _c: NEAR_GOAL, 'goal_joints')
    assert request is not None and port.reports[-1].event == schema.EVENT_QUEUED
    port.clock += 2.0                   # the plant stopped publishing meanwhile
    ready.set()
    finish(p, request)
    assert port.trajectories == []
    assert 'no recent joint_states' in port.reports[-1].message
    p.worker.stop()


def test_an_obstacle_on_the_rest_of_the_plan_stops_it_and_the_goal_is_planned_again():
    p, port = planner()
    finish(p, p.submit(lambda _c: NEAR_GOAL, 'goal_joints'))
    plan, _ = p.plans.current()
    port.clock = plan.start + 0.3 * plan.duration
    k = int(0.7 * (len(plan.times) - 1))
    x, y = hand(plan.states[k, 0], plan.states[k, 2])
    port.config = config(**{'obstacles.x': [1.0, float(x)], 'obstacles.y': [1.0, float(y)],
                            'obstacles.radius': [0.2, 0.03]})
    p.data_changed(port.config)
    # No measured state: the stop is an empty trajectory (the plant holds).
    assert port.trajectories[1].points == [] and p.plans.current()[1] == 1
    stopped = [r for r in port.reports if r.event == schema.EVENT_STOPPED]
    assert len(stopped) == 1 and 'cuts obstacle 1' in stopped[0].message
    assert 'planning the goal again' in stopped[0].message
    finish(p)
    replaced = port.reports[-1]
    assert replaced.event == schema.EVENT_REPLACED and replaced.status is Status.SOLVED
    assert replaced.goal_source == goals.REPLAN and replaced.data_revision == 1
    _, q, _, _ = points(port.trajectories[-1])
    gaps = [np.hypot(*(hand(a, b) - [x, y])) - 0.03 for a, b in q]
    assert min(gaps) > 0.0


def test_with_a_measured_state_the_stop_brakes_and_unchanged_data_change_nothing():
    p, port = planner(config(**{'replan.rate': 0.0}))
    finish(p, p.submit(lambda _c: NEAR_GOAL, 'goal_joints'))
    plan, _ = p.plans.current()
    port.clock = plan.start + 0.4 * plan.duration
    k = int(np.searchsorted(plan.times, 0.4 * plan.duration))
    port.measured = plan.states[k].copy()
    p.data_changed(config(**{'replan.rate': 0.0}))          # the same planning data
    assert len(port.trajectories) == 1 and p.plans.current()[1] == 0
    x, y = hand(plan.states[-5, 0], plan.states[-5, 2])
    port.config = config(**{'replan.rate': 0.0, 'obstacles.x': [1.0, float(x)],
                            'obstacles.y': [1.0, float(y)], 'obstacles.radius': [0.2, 0.02]})
    p.data_changed(port.config)
    braking, _ = p.plans.current()
    assert braking is not None and braking.braking and braking.source == 'brake'
    t, q, dq, u = points(port.trajectories[1])
    np.testing.assert_allclose(q[0], port.measured[0::2], atol=1e-12)
    np.testing.assert_allclose(dq[-1], [0.0, 0.0], atol=1e-2)
    assert np.all(np.abs(u) <= U_MAX * (1 + 1e-9))
    p.worker.stop()


def test_a_goal_while_a_plan_moves_the_robot_starts_on_it_and_late_ones_go_farther(
        monkeypatch):
    p, port = planner(config(**{'replan.rate': 0.0}))
    finish(p, p.submit(lambda _c: NEAR_GOAL, 'goal_joints'))
    plan, _ = p.plans.current()
    lead = port.config.node.goal_lead
    k = int(np.searchsorted(plan.times, 0.3 * plan.duration))
    port.clock = port.measured_at = plan.start + plan.times[k]    # measured on it, just now
    port.measured = plan.states[k].copy()
    other = np.array([-0.3, 0.0, 1.2, 0.0])
    finish(p, p.submit(lambda _c: other, 'goal_joints'))
    msg = port.trajectories[-1]
    # Stamped at the executing plan's node at or after now + goal_lead, starting on its state
    # there (the robot follows the plan until then), not where it was measured.
    node = int(np.searchsorted(plan.times, port.clock + lead - plan.start - 1e-12))
    assert stamp(msg) == pytest.approx(plan.start + plan.times[node], abs=1e-6)
    _, q, _, _ = points(msg)
    # The measured state predicted to that node under the plan's controls (the robot's motion
    # there; the goal's Euler plan nodes are within millimetres of it).
    start = starts.goal_start_on_plan(plan, 4, port.measured, port.measured_at, port.clock,
                                      lead, port.config.node.replan_stitch)[0]
    np.testing.assert_allclose(q[0], start[0::2], atol=1e-9)
    assert np.max(np.abs(start - plan.states[node])) < 0.01
    assert np.max(np.abs(start - port.measured)) > 0.05
    assert port.reports[-1].start_source == goals.ON_PLAN
    np.testing.assert_allclose(q[-1], other[0::2], atol=1e-3)

    # A solve that ends after its start's time is not published: solved again from twice as
    # far ahead, until the plan's rest (here every solve takes 0.12 s of the node clock, and
    # the robot is measured on its plan at the start of each).
    p2, port2 = planner(config(**{'replan.rate': 0.0, 'goal_lead': 0.05}))
    finish(p2, p2.submit(lambda _c: NEAR_GOAL, 'goal_joints'))
    plan2, _ = p2.plans.current()
    k = int(np.searchsorted(plan2.times, 0.3 * plan2.duration))
    port2.clock = port2.measured_at = plan2.start + plan2.times[k]
    port2.measured = plan2.states[k].copy()

    def slow_solve(*args, **kwargs):
        k = min(int(np.searchsorted(plan2.times, port2.clock - plan2.start)), N_NODES - 1)
        port2.measured, port2.measured_at = plan2.states[k].copy(), port2.clock
        result = solve(*args, **kwargs)
        port2.clock += 0.12
        return result
    N_NODES = len(plan2.times)
    monkeypatch.setattr(planner_module, 'solve', slow_solve)
    request = p2.submit(lambda _c: other, 'goal_joints')
    finish(p2, request)
    late = [text for _, text in port2.logger.lines if 'solved after its start' in text]
    assert late, port2.logger.lines
    final = port2.trajectories[-1]
    assert len(port2.trajectories) == 2 and port2.reports[-1].status is Status.SOLVED
    source = port2.reports[-1].start_source
    assert source in (goals.ON_PLAN, goals.ON_PLAN_REST)
    _, q2, _, _ = points(final)
    if source == goals.ON_PLAN_REST:
        np.testing.assert_allclose(q2[0], plan2.states[-1, 0::2], atol=1e-9)
        assert stamp(final) >= plan2.start + plan2.duration - 1e-9
    else:           # published before its stamp, on the plan (the prediction of the
        #             robot's motion there, within centimetres of the Euler plan's node)
        assert request.published_stamp < stamp(final)
        k = int(np.searchsorted(plan2.times, stamp(final) - plan2.start - 1e-9))
        np.testing.assert_allclose(q2[0], plan2.states[k, 0::2], atol=0.03)
    p.worker.stop()
    p2.worker.stop()


def moving_with_a_circle_ahead():
    """Return a plan 40 % executed (measured on it) and a circle on its rest short of the goal."""
    p, port = planner(config(**{'replan.rate': 0.0}))
    finish(p, p.submit(lambda _c: NEAR_GOAL, 'goal_joints'))
    plan, _ = p.plans.current()
    port.clock = plan.start + 0.4 * plan.duration
    port.measured = plan.states[int(np.searchsorted(plan.times, 0.4 * plan.duration))].copy()
    k = int(0.75 * (len(plan.times) - 1))
    x, y = hand(plan.states[k, 0], plan.states[k, 2])
    port.config = config(**{'replan.rate': 0.0, 'obstacles.x': [1.0, float(x)],
                            'obstacles.y': [1.0, float(y)], 'obstacles.radius': [0.2, 0.02]})
    return p, port, plan


def test_a_goal_planned_while_braking_starts_at_the_stops_rest_when_it_ends():
    p, port, plan = moving_with_a_circle_ahead()
    heavier = CylindricalRobot(RobotParams(hand_mass=60.0))     # the online estimate
    port.estimate = (heavier, 'hand_mass=60')
    p.data_changed(port.config)
    finish(p)
    # The stop, then the goal again from where the stop rests, applying from its end on (the
    # measured state is still the moving one from before the stop), for the estimated model.
    assert p.plans.current()[0].model is heavier
    assert len(port.trajectories) == 3, [(r.event, r.status, r.message) for r in port.reports]
    t_stop, q_stop, dq_stop, _ = points(port.trajectories[1])
    t_new, q_new, dq_new, _ = points(port.trajectories[2])
    np.testing.assert_allclose(q_new[0], q_stop[-1], atol=1e-12)
    np.testing.assert_allclose(dq_new[0], [0.0, 0.0], atol=1e-2)
    assert stamp(port.trajectories[2]) >= port.clock + t_stop[-1] - 1e-6
    replaced = [r for r in port.reports if r.event == schema.EVENT_REPLACED]
    assert replaced and replaced[-1].start_source == BRAKING_REST
    p.worker.stop()


def test_a_deferred_brake_is_published_at_its_deadline_unless_a_plan_replaced_it():
    p, port, plan = moving_with_a_circle_ahead()
    p.plans.defer_brake(plan, port.clock + 0.1)
    p.brake_if_overdue(port.config)
    assert len(port.trajectories) == 1                 # not due yet
    port.clock += 0.1
    p.brake_if_overdue(port.config)
    assert len(port.trajectories) == 2 and p.plans.current()[0].braking
    stopped = [r for r in port.reports if r.event == schema.EVENT_STOPPED]
    assert len(stopped) == 1 and 'no replan around it in time' in stopped[0].message
    p.brake_if_overdue(port.config)                     # once
    assert len(port.trajectories) == 2
    finish(p)
    # A plan that replaced the deferred one (a replan in time) is not braked.
    replaced, _ = p.plans.current()
    p.plans.defer_brake(plan, port.clock)               # not executing: ignored
    port.clock += 1.0
    p.brake_if_overdue(port.config)
    assert p.plans.current()[0] is replaced
    p.worker.stop()


def test_a_deferred_brake_comes_before_the_stop_that_brake_can_wait_checked():
    for lead in (0.0, 0.025, policy.MAX_LEAD_S):
        assert 5.0 + lead < policy.brake_deadline(5.0, lead) < 5.0 + policy.brake_wait(lead)


def test_a_measured_state_is_predicted_along_the_plan_to_now(solved):
    p, _, _ = solved
    plan, _ = p.plans.current()
    k, m = 20, 35
    measured = plan.states[k] + np.array([0.0, 0.01, 0.0, -0.01])    # off the plan a little
    t_k, t_m = plan.start + plan.times[k], plan.start + plan.times[m]
    # Independent: classic RK4 of eq. 37 in fine steps under the plan's controls.
    x = measured.copy()
    for i in range(k, m):
        steps = 20
        for _ in range(steps):
            x = nm.step(x, plan.controls[i], (plan.times[i + 1] - plan.times[i]) / steps, 'rk4')
    predicted = policy.state_now(plan, measured, t_k, t_m)
    # The prediction holds the control of each 1 ms step's midpoint: steps across a switch
    # of the plan's controls take one of them (some 1e-3 in velocity over 15 intervals).
    np.testing.assert_allclose(predicted, x, atol=5e-3)
    assert np.max(np.abs(predicted - measured)) > 0.1
    # As it is: time unknown, from before the plan, or not older than now.
    assert policy.state_now(plan, measured, None, t_m) is measured
    assert policy.state_now(plan, measured, plan.start - 0.1, t_m) is measured
    assert policy.state_now(plan, measured, t_m, t_m) is measured


def test_cancel_goal_brakes_the_executing_plan_once():
    p, port = planner(config(**{'replan.rate': 0.0}))
    assert p.cancel_goal('goal canceled') == (
        False, 'no active goal (nothing solving, queued or executing)')
    finish(p, p.submit(lambda _c: NEAR_GOAL, 'goal_joints'))
    plan, _ = p.plans.current()
    port.clock = plan.start + 0.5 * plan.duration
    port.measured = plan.states[len(plan.times) // 2].copy()
    ok, message = p.cancel_goal('goal canceled')
    assert ok and message.startswith('goal canceled: braking to rest')
    assert not plan.goal_active and p.plans.current()[0].braking
    assert port.reports[-1].event == schema.EVENT_GOAL_CANCELED
    assert port.reports[-1].status is Status.CANCELED
    assert len(port.trajectories) == 2
    # Nothing drives to the goal any more: a second cancel has nothing to do.
    assert p.cancel_goal('goal canceled')[0] is False and len(port.trajectories) == 2


# -- replan cycles ------------------------------------------------------------------------------

def cycle_setup():
    p, port = planner(config(**{'replan.rate': 20.0}))
    finish(p, p.submit(lambda _c: NEAR_GOAL, 'goal_joints'))
    plan, _ = p.plans.current()
    port.clock = plan.start + 0.2 * plan.duration
    k = int(np.searchsorted(plan.times, 0.2 * plan.duration))
    return p, port, plan, plan.states[k].copy()


def test_a_due_cycle_is_published_on_a_plan_node_ahead_of_now():
    p, port, plan, state = cycle_setup()
    received = time.monotonic() + 30.0      # a deadline that a loaded machine still meets
    assert p.maybe_replan(port.config, state, port.clock, received)
    assert p.plans.next_cycle == pytest.approx(received + 1.0 / 20.0)
    finish(p)
    report = port.reports[-1]
    assert report.event == schema.EVENT_REPLANNED and report.goal_source == CYCLE_SOURCE
    new, _ = p.plans.current()
    assert new is not plan and len(port.trajectories) == 2 and port.arm == 1
    start = stamp(port.trajectories[-1]) - plan.start
    assert start >= port.clock - plan.start + port.config.node.replan_lead - 1e-9
    assert np.min(np.abs(plan.times - start)) < 1e-9          # on a node of the old plan
    # Not due again before the next rate tick (state on the plan: no deviation).
    assert not p.maybe_replan(port.config, new.states[0], new.start, received + 0.01)


def test_a_late_cycle_keeps_the_plan_and_seeds_the_next():
    p, port, plan, state = cycle_setup()
    received = time.monotonic() - 10.0      # its deadline passed long ago
    assert p.maybe_replan(port.config, state, port.clock, received)
    finish(p)
    report = port.reports[-1]
    assert report.event == schema.EVENT_REPLAN_KEPT and 'kept the executing plan' in \
        report.message
    assert p.plans.current()[0] is plan and len(port.trajectories) == 1
    assert report.latency_s >= 10.0
    if report.status is Status.SOLVED:      # late: it seeds the next cycle of this plan
        assert 'late: ready' in report.message and p.plans.seed.plan is plan


def test_a_cycle_whose_deadline_passes_while_its_messages_are_built_is_not_published(
        monkeypatch):
    # Solved in time, but building its plan and messages runs past the deadline (a loaded
    # machine): the check at the last moment before publishing keeps the executing plan.
    import toc_ros.planner as planner_module
    built = planner_module.plan_from_result

    def slow_plan_from_result(*args, **kwargs):
        time.sleep(1.0)                     # past any lead (capped well below a second)
        return built(*args, **kwargs)

    p, port, plan, state = cycle_setup()
    monkeypatch.setattr(planner_module, 'plan_from_result', slow_plan_from_result)
    received = time.monotonic() + 0.5       # the deadline: received + lead
    assert p.maybe_replan(port.config, state, port.clock, received)
    finish(p)
    report = port.reports[-1]
    assert report.event == schema.EVENT_REPLAN_KEPT, report.message
    assert p.plans.current()[0] is plan and len(port.trajectories) == 1
    if report.status is Status.SOLVED:
        assert 'late: ready' in report.message and p.plans.seed.plan is plan


def segment_gap(q1, q2, centre, radius):
    """Clearance of the arm (base to hand, a segment) to a circle [m], recomputed here."""
    tip, centre = hand(q1, q2), np.asarray(centre, dtype=float)
    s = np.clip(np.dot(centre, tip) / np.dot(tip, tip), 0.0, 1.0)
    return float(np.hypot(*(centre - s * tip)) - radius)


def test_a_cycle_from_inside_the_margin_plans_out_with_half_its_true_clearance():
    p, port = planner(config(**{'replan.rate': 20.0, 'obstacles.margin': 0.1}))
    finish(p, p.submit(lambda _c: NEAR_GOAL, 'goal_joints'))
    plan, _ = p.plans.current()
    port.clock = plan.start + 0.2 * plan.duration
    k = int(np.searchsorted(plan.times, 0.2 * plan.duration))
    # The plant carried the hand 0.15 m further out than planned, 0.04 m from a small circle
    # beyond it that the plan itself clears by more than the margin.
    state = plan.states[k].copy()
    state[2] += 0.15
    radius = 0.05
    direction = np.array([math.cos(state[0]), math.sin(state[0])])
    centre = (A + state[2] + 0.04 + radius) * direction
    port.config = config(**{'replan.rate': 20.0, 'obstacles.margin': 0.1,
                            'obstacles.x': [1.0, float(centre[0])],
                            'obstacles.y': [1.0, float(centre[1])],
                            'obstacles.radius': [0.2, radius]})
    assert min(segment_gap(a, b, centre, radius) for a, b in plan.states[k:, 0::2]) > 0.1
    p.data_changed(port.config)
    assert len(port.trajectories) == 1              # the plan is clear: nothing to stop
    assert p.maybe_replan(port.config, state, port.clock, time.monotonic() + 30.0)
    finish(p)
    report = port.reports[-1]
    assert report.event == schema.EVENT_REPLANNED, report.message
    assert 'from inside the obstacle margin' in report.message
    _, q, _, _ = points(port.trajectories[-1])
    gaps = np.array([segment_gap(a, b, centre, radius) for a, b in q])
    assert 0.0 < gaps[0] < 0.1                      # it starts inside the margin
    assert np.min(gaps) >= 0.5 * gaps[0] - 1e-6     # and keeps half of that clearance
    assert np.max(np.abs(q[-1] - NEAR_GOAL[0::2])) < 1e-6


def test_no_cycle_without_replanning_or_for_a_state_of_another_size():
    p, port = planner(config(**{'replan.rate': 0.0}))
    finish(p, p.submit(lambda _c: NEAR_GOAL, 'goal_joints'))
    plan, _ = p.plans.current()
    assert not p.maybe_replan(port.config, plan.states[0], port.clock, 0.0)
    q, port2, plan2, state = cycle_setup()
    assert not q.maybe_replan(port2.config, state[:3], port2.clock, 0.0)
    assert start_state(port.config, None)[1] == 'initial_state'
    assert start_state(port.config, state)[1] == 'joint_states'


# -- the execution record -----------------------------------------------------------------------

def straight_plan(start=0.0, duration=1.0, nodes=11, result=None):
    times = np.linspace(0.0, duration, nodes)
    states = np.zeros((nodes, 4))
    states[:, 0] = np.linspace(0.2, 0.8, nodes)
    states[:, 2] = 1.0
    return ExecutingPlan(start=start, times=times, states=states,
                         controls=np.zeros((nodes - 1, 2)), goal=states[-1], source='test',
                         model=CylindricalRobot(), result=result, path_states=states)


def test_new_data_count_revisions_only_when_the_planning_data_change():
    record = ExecutionState({'obstacles.x': [1.0]})
    assert record.new_data({'obstacles.x': [1.0]}) is None
    assert record.new_data({'obstacles.x': [0.5]}) == 1
    assert record.new_data({'obstacles.x': [0.5], 'robot.model': 'x'}) == 2
    assert record.current() == (None, 2)


def test_a_stale_plan_is_named_a_finished_one_forgotten():
    record = ExecutionState({})
    plan = straight_plan(start=10.0)
    record.executing = plan
    assert record.stale_plan(0, 10.5, lambda _p, _t: None) is None
    assert record.stale_plan(0, 10.5, lambda _p, t: f'cuts at {t}') == (plan, 0.5, 'cuts at 0.5')
    assert record.stale_plan(1, 10.5, lambda _p, _t: 'x') is None     # newer data meanwhile
    assert record.executing is plan
    assert record.stale_plan(0, 11.0 + 0.51, lambda _p, _t: 'x') is None   # over (+ slack)
    assert record.executing is None


def test_a_seed_warm_starts_only_the_cycles_of_its_plan():
    record = ExecutionState({})
    plan, other = straight_plan(), straight_plan()
    record.executing = plan
    assert record.cycle_source(plan) == (0, plan)
    result = SimpleNamespace(time_grid=plan.times, states=plan.states)
    record.seed_next(other, result, SimpleNamespace(robot_model=plan.model))   # not executing
    assert record.seed is None
    record.seed_next(plan, result, SimpleNamespace(robot_model=plan.model))
    assert isinstance(record.seed, Seed) and record.cycle_source(plan) == (0, record.seed)
    record.executing = other
    assert record.cycle_source(plan) is None and record.cycle_source(other) == (0, other)


def test_the_lead_follows_the_median_of_recent_cycles_capped():
    record = ExecutionState({})
    for _ in range(policy.MIN_LATENCY_SAMPLES - 1):
        record.record_latency(0.04)
    assert record.cycle_lead(0.025) == 0.025          # too few samples yet
    record.record_latency(0.04)
    assert record.cycle_lead(0.025) == pytest.approx(policy.LEAD_PER_MEDIAN * 0.04)
    for _ in range(policy.LATENCY_WINDOW):
        record.record_latency(5.0)                    # a stalled machine: capped
    assert record.cycle_lead(0.025) == pytest.approx(policy.MAX_LEAD_S)
    record.clear_latencies()
    assert record.cycle_lead(0.025) == 0.025
    record.cycle_taken(3.0, 20.0)
    assert record.next_cycle == pytest.approx(3.05)


def test_the_drawn_path_is_in_joint_states():
    record = ExecutionState({})
    assert record.drawing() == (None, None, 0)
    record.executing = straight_plan()
    record.plan_info = ('hash', 0)
    path, info, revision = record.drawing()
    np.testing.assert_array_equal(path, record.executing.states)
    assert info == ('hash', 0) and revision == 0


# -- goal requests ------------------------------------------------------------------------------

def test_a_plan_requests_start_is_ignored_unless_it_is_the_measured_hand_position():
    model = CylindricalRobot()
    x = np.array(X0)
    here = hand(x[0], x[2])
    args = ('base_link', model, x)
    assert goals.ignored_start('', 0.0, 0.0, *args) is None                 # no start given
    assert goals.ignored_start('', *here, *args) is None
    assert goals.ignored_start('base_link', here[0] + 9e-4, here[1], *args) is None
    assert 'm from the measured hand position' in goals.ignored_start(
        'base_link', here[0] + 2e-3, here[1], *args)
    assert 'is not finite' in goals.ignored_start('', math.nan, 1.0, *args)
    assert "its frame 'map' is not 'base_link'" == goals.ignored_start('map', *here, *args)
    assert goals.ignored_start('base_link', *here, '/base_link', model, x) is None


def test_a_replan_from_inside_the_margin_uses_half_the_true_clearance():
    settings = config(**{'obstacles.margin': 0.1})
    rows = np.array(settings.problem.obstacles)
    # The hand 0.05 m outside the circle (inside the 0.1 m margin).
    r = math.hypot(1.0, 1.0) - 0.2 - 0.05
    start = np.array([math.pi / 4, 0.0, r - A, 0.0])
    assert np.hypot(*hand(start[0], start[2]) - rows[0, :2]) - rows[0, 2] == pytest.approx(0.05)
    flat = goals.recovery_params(settings, start)
    assert flat['obstacles.margin'] == pytest.approx(0.025, rel=1e-6)
    goal = np.array([0.0, 0.0, 0.5, 0.0])
    refusal = goals.goal_refusal(settings, start, 'joint_states', goal, 'goal')
    assert 'start state from joint_states' in refusal
    assert goals.goal_refusal(settings, start, 'joint_states', goal, goals.REPLAN) is None
    problem, guess, margin = goals.goal_problem(settings, start, goal, goals.REPLAN, None, 0.0)
    assert margin == pytest.approx(0.025, rel=1e-6) and problem.margin == margin
    assert guess is None
    assert goals.recovery_params(settings, np.array(X0)) is None        # clear of the margin


def test_a_start_on_the_plan_predicted_inside_the_margin_is_planned_with_the_recovery_margin():
    # The paper's plan around its circle, and a robot measured 30 ms behind it: the start
    # predicted along the plan from there lies inside the margin (the plan keeps it at its
    # nodes).  A goal then starts there with half the true clearance as its margin (it was
    # refused: 'start state puts the arm inside obstacle 0 (inflated by the margin)').
    from toc_ros.core.executing_plan import plan_from_result
    from toc_ros.core.obstacles import model_clearance
    settings = config()
    goal = np.array([5 * math.pi / 12, 0.0, 1.0, 0.0])
    base = settings.problem
    result = solve(base, settings.options)
    assert result.status is Status.SOLVED
    plan = plan_from_result(result, 0.0, goal, 'goal', base.robot_model)
    rows = np.array(base.obstacles)
    inside = []
    for k in range(1, len(plan.times) - 20):
        now = plan.times[k] + 0.03
        start = starts.goal_start_on_plan(plan, 4, plan.states[k], now, now, 0.15, -1.0)[0]
        gap = float(model_clearance(base.robot_model, start[None, :], rows).min())
        if 0.0 < gap < base.margin:
            inside.append((start, gap, now))
    assert inside
    start, gap, now = inside[len(inside) // 2]
    assert 'inflated by the margin' in goals.goal_refusal(settings, start, 'joint_states', goal,
                                                          'goal')
    assert goals.goal_refusal(settings, start, goals.ON_PLAN, goal, 'goal') is None
    problem, guess, margin = goals.goal_problem(settings, start, goal, 'goal', plan, now,
                                                goals.ON_PLAN)
    # Half the clearance of the start or of its first step (along its velocity), the smaller.
    assert 0.0 < margin <= 0.5 * gap + 1e-15 and problem.margin == margin
    replanned = solve(problem, settings.options, initial_guess=guess)
    assert replanned.status is Status.SOLVED, replanned.message
    clear = model_clearance(base.robot_model, replanned.states[1:], rows)
    assert clear.min() >= margin - 1e-6


def test_a_goal_from_a_plan_that_the_robot_lags_is_solved_again_with_less_margin():
    # The paper's robot 44 ms behind its plan past the circle (found by node tests in shuffled
    # order): the start predicted along the plan is 2 mm outside the margin, moving into it
    # faster than the efforts stop it.  The solve from it stalls (1473 iterations); a second
    # one with half the margin is published.
    goal = np.array([5 * math.pi / 12, 0.0, 1.0, 0.0])
    start = (goal[0] - 1.0472, 0.0, 1.0, 0.0)
    p, port = planner(config(**{'solver.N': 300, 'replan.rate': 0.0,
                                'initial_state': list(start)}))
    finish(p, p.submit(lambda _c: goal, 'goal_joints'))
    plan, _ = p.plans.current()
    assert len(plan.times) == 301
    port.clock = port.measured_at = plan.start + plan.times[99] + 0.044
    port.measured = plan.states[99].copy()
    finish(p, p.submit(lambda _c: goal, 'goal_joints'))
    report = port.reports[-1]
    assert report.start_source == goals.ON_PLAN
    assert report.status is Status.SOLVED and report.margin == pytest.approx(0.005)
    assert len(port.trajectories) == 2
    assert any('again with margin 0.005 m' in text for _, text in port.logger.lines)
    p.worker.stop()


def test_outcome_texts_of_goals_and_cycles():
    result = SimpleNamespace(status=Status.CANCELED, message='stopped', has_trajectory=False)
    assert goals.goal_outcome(result, 'preempted', 'x') == (Status.CANCELED,
                                                            'preempted (stopped)')
    result.status = Status.INVALID_INPUT
    assert goals.goal_outcome(result, None, 'initial_state')[1] == \
        'stopped (start state from initial_state)'
    assert goals.cycle_failure(result, None, None, 0.025, False, True) == \
        f'{Status.INVALID_INPUT.value}: stopped'
    assert goals.cycle_failure(result, 'preempted', None, 0.025, False, True) == \
        f'{Status.INVALID_INPUT.value}: preempted'
    solved = SimpleNamespace(status=Status.SOLVED, message='ok', has_trajectory=True)
    assert goals.cycle_failure(solved, None, None, 0.025, True, True) is None
    assert goals.cycle_failure(solved, None, 0.0123, 0.025, False, True) == (
        'late: ready 12.3 ms after its deadline (25 ms after its joint_states); it seeds the '
        'next cycle')
    assert goals.cycle_failure(solved, 'canceled', None, 0.025, False, False) == \
        'canceled: not published'
    assert 'violates the new data' in goals.cycle_failure(solved, None, None, 0.025, False,
                                                          True)


# -- progress and kernels -----------------------------------------------------------------------

def test_the_heartbeat_fills_gaps_longer_than_the_limit_only():
    now = [0.0]
    progress = SolveProgress(max_gap=0.15, clock=lambda: now[0])
    assert progress.due() is None                       # no solve
    first = Progress(0, 1.0, math.nan, math.nan, 0.0, 'start')
    assert progress.start(first) is first
    progress.sent()
    now[0] = 0.1
    assert progress.due() is None
    now[0] = 0.2
    assert progress.due().elapsed_s == pytest.approx(0.2)
    later = Progress(5, 0.9, 1.0, 0.0, 0.1, 'iterate')
    assert progress.update(later) is later
    assert progress.update(Progress(6, 0.9, 1.0, 0.0, 0.1, 'done')) is None
    now[0] = 0.3
    assert progress.due().iteration == 5
    progress.end()
    assert progress.due() is None and progress.update(later) is None


def test_kernels_load_in_the_background_and_again_only_for_other_kernels(monkeypatch):
    loaded, done = [], threading.Event()
    monkeypatch.setattr(kernel_loader, 'warm_up', lambda models: loaded.append(models))
    model = CylindricalRobot()
    loader = kernel_loader.KernelLoader(model, lambda s: done.set(), lambda e: None)
    assert loader.status()[0] is False and 'so far' in loader.status()[1]
    loader.start()
    assert done.wait(10.0) and loader.ready.is_set() and loaded == [None]
    assert loader.status()[1].startswith('ready: numba kernels loaded in')
    assert loader.switch(CylindricalRobot()) is False and loader.ready.is_set()
    other = SimpleNamespace(kernels=object())
    done.clear()
    assert loader.switch(other) is True
    assert done.wait(10.0) and loaded[-1] == [other] and loader.model is other


def test_a_failed_load_is_reported_and_the_node_still_gets_ready(monkeypatch):
    errors, done = [], threading.Event()

    def fail(_models):
        raise RuntimeError('no compiler')
    monkeypatch.setattr(kernel_loader, 'warm_up', fail)
    loader = kernel_loader.KernelLoader(CylindricalRobot(), lambda s: done.set(),
                                        errors.append)
    loader.start()
    assert done.wait(10.0) and loader.ready.is_set()
    assert [str(e) for e in errors] == ['no compiler']


def test_a_braking_stop_into_a_circle_is_left_from_its_state_ahead_not_its_rest():
    # A circle moved onto where a stop will rest: a goal planned from that rest would be
    # refused (inside a circle) while the robot brakes into it; it starts from the stop's
    # node at now + lead instead, from where a plan may still steer clear.
    from toc_ros.core.obstacles import model_clearance
    moving = straight_plan(start=10.0, duration=1.0)
    stop = braking_plan(moving, np.array([0.5, 1.0, 1.0, -0.5]), 10.5, 0.002)
    rest = stop.states[-1]
    hand = rest[2] * np.array([math.cos(rest[0]), math.sin(rest[0])])
    circle = [(hand[0], hand[1], 0.05)]
    assert model_clearance(stop.model, rest[None, :], circle).min() < 0.0
    lead = 0.02
    start, when = starts.braking_rest_start(stop, 10.5, 4, rows=circle, lead=lead)
    k = int(np.searchsorted(stop.times, stop.elapsed(10.5) + lead))
    assert 0 < k < len(stop.times) - 1
    np.testing.assert_array_equal(start, stop.states[k])
    assert when == pytest.approx(stop.start + stop.times[k])
    assert model_clearance(stop.model, start[None, :], circle).min() > 0.0
    # A circle elsewhere: the rest, as without circles.
    far = [(hand[0] + 1.0, hand[1] + 1.0, 0.05)]
    start, when = starts.braking_rest_start(stop, 10.5, 4, rows=far, lead=lead)
    np.testing.assert_array_equal(start, rest)
    assert when == pytest.approx(stop.start + stop.duration)


def test_the_rest_of_a_braking_stop_is_a_goals_start_only_while_the_stop_executes():
    moving = straight_plan(start=10.0, duration=1.0, result='a solve result')
    stop = braking_plan(moving, np.array([0.5, 1.0, 1.0, -0.5]), 10.5, 0.002)
    assert stop.braking and stop.times[-1] > 0.0
    rest = starts.braking_rest_start(stop, 10.5, 4)
    assert rest is not None
    np.testing.assert_array_equal(rest[0], stop.states[-1])
    assert rest[1] == pytest.approx(10.5 + stop.times[-1])
    assert starts.braking_rest_start(moving, 10.5, 4) is None          # not a stop
    ended = 10.5 + stop.times[-1] + 1e-6
    assert starts.braking_rest_start(stop, ended, 4) is None   # ended, no measured state
    # Ended, the robot still moving near its held end (overshot and pulled back): the rest,
    # from now; at rest there: its measured state is the start.
    moving_near = stop.states[-1] + np.array([0.01, 0.05, 0.0, 0.0])
    rest = starts.braking_rest_start(stop, ended, 4, moving_near, ended)
    assert rest is not None and rest[1] == ended
    np.testing.assert_array_equal(rest[0], stop.states[-1])
    resting = stop.states[-1] + np.array([0.01, 0.0, 0.0, 0.0])
    assert starts.braking_rest_start(stop, ended, 4, resting, ended) is None
    assert starts.braking_rest_start(stop, 10.5, 6) is None            # another model
    assert starts.braking_rest_start(None, 10.5, 4) is None
    # Measured on the stop: its rest; measured far off it (a reset plant): none.
    on_stop = stop.states[10]
    assert starts.braking_rest_start(stop, 10.5, 4, on_stop, 10.5 + stop.times[10]) is not None
    reset = np.array([0.2, 0.0, 1.0, 0.0])
    assert starts.braking_rest_start(stop, 10.5, 4, reset, 10.5 + stop.times[10]) is None
