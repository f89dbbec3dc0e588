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

"""Bad problems and options give INVALID_INPUT with a message, before any iteration runs."""

from dataclasses import replace
import math
import re

import numpy as np
import pytest

from toc_ros.core import (CylindricalRobot, PaperOptions, Problem, RobotParams, solve,
                          SolverOptions, Status)
from toc_ros.core.obstacles import model_clearance
from toc_ros.core.problem import PAPER_GOAL, PAPER_OBSTACLES, PAPER_X0

NAN, INF = math.nan, math.inf
PAPER = Problem.paper()
ROBOT = RobotParams()


def _robot(**changes):
    return CylindricalRobot(replace(ROBOT, **changes))


# (case id, problem, pattern the message must contain)
BAD_PROBLEMS = [
    ('nan_start', replace(PAPER, x0=(NAN, 0.0, 1.0, 0.0)), 'x0'),
    ('inf_goal_velocity', replace(PAPER, x_goal=(1.3, INF, 1.0, 0.0)), 'x_goal'),
    ('nan_obstacle', replace(PAPER, obstacles=((1.0, NAN, 0.2),)), 'obstacle 0'),
    ('inf_radius', replace(PAPER, obstacles=((1.0, 1.0, INF),)), 'obstacle 0'),
    ('nan_margin', replace(PAPER, margin=NAN), 'margin'),
    ('negative_margin', replace(PAPER, margin=-0.01), 'margin'),
    ('nan_mass', replace(PAPER, model=_robot(hand_mass=NAN)), 'hand_mass'),
    ('zero_link_mass', replace(PAPER, model=_robot(link_mass=0.0)), 'link_mass'),
    ('negative_inertia', replace(PAPER, model=_robot(inertia=-193.0)), 'inertia'),
    ('zero_a', replace(PAPER, model=_robot(a=0.0)), r'robot\.a'),
    ('zero_u1_max', replace(PAPER, model=_robot(u1_max=0.0)), 'u1_max'),
    ('negative_u2_max', replace(PAPER, model=_robot(u2_max=-500.0)), 'u2_max'),
    ('inf_u2_max', replace(PAPER, model=_robot(u2_max=INF)), 'u2_max'),
    ('unknown_variant', replace(PAPER, model=_robot(model_variant='eq38')),
     'model_variant'),
    ('robot_data_instead_of_a_model', replace(PAPER, model=ROBOT), 'model must be'),
    ('zero_N', replace(PAPER, n_intervals=0), 'N must'),
    ('negative_N', replace(PAPER, n_intervals=-5), 'N must'),
    ('fractional_N', replace(PAPER, n_intervals=2.5), 'N must'),
    ('zero_t_f0', replace(PAPER, t_f0=0.0), 't_f0'),
    ('negative_t_f0', replace(PAPER, t_f0=-2.5), 't_f0'),
    ('nan_t_f0', replace(PAPER, t_f0=NAN), 't_f0'),
    ('negative_radius', replace(PAPER, obstacles=((1.0, 1.0, -0.2),)), 'radius'),
    ('unknown_integrator', replace(PAPER, integrator='rk45'), 'integrator'),
    ('start_vector_too_short', replace(PAPER, x0=(0.26, 0.0, 1.0)), 'x0'),
    ('goal_vector_too_long', replace(PAPER, x_goal=(1.3, 0.0, 1.0, 0.0, 0.0)), 'x_goal'),
    ('obstacle_row_of_two', replace(PAPER, obstacles=((1.0, 1.0),)), 'obstacles'),
    # At 45 degrees the arm runs through the centre of the paper's circle.
    ('start_inside_obstacle', replace(PAPER, x0=(math.pi / 4, 0.0, 1.0, 0.0)), 'start'),
    ('goal_inside_obstacle', replace(PAPER, x_goal=(math.pi / 4, 0.0, 1.0, 0.0)), 'goal'),
    # Clear of the bare circle (R' = 0.2 m) but 5 mm inside the inflated one (R = 0.21 m).
    ('start_inside_margin', replace(PAPER, x0=(math.pi / 4 - math.asin(0.205 / math.sqrt(2)),
                                               0.0, 1.0, 0.0)), 'start'),
    ('obstacle_contains_base', replace(PAPER, obstacles=((0.1, 0.0, 0.5),)), 'base'),
    # The base is 4 mm outside the circle, but inside it once inflated by the margin.
    ('inflated_obstacle_contains_base', replace(PAPER, obstacles=((0.5, 0.0, 0.496),)),
     'base'),
    # a + q2 <= 0: the hand would be behind the base, a goal no arm can reach.
    ('unreachable_goal', replace(PAPER, x_goal=(1.3, 0.0, -1.2, 0.0)), 'goal'),
]

BAD_OPTIONS = [
    ('unknown_mode', SolverOptions(mode='slow'), 'mode'),
    ('zero_max_iterations', SolverOptions(max_iterations=0), 'max_iterations'),
    ('negative_timeout', SolverOptions(timeout=-1.0), 'timeout'),
    ('nan_timeout', SolverOptions(timeout=NAN), 'timeout'),
    ('zero_eta', SolverOptions(mode='paper', paper=PaperOptions(eta=0.0)), 'eta'),
    ('nan_k_b', SolverOptions(mode='paper', paper=PaperOptions(k_b=NAN)), 'k_b'),
    ('unknown_obstacle_gradient',
     SolverOptions(mode='paper', paper=PaperOptions(obstacle_gradient='approx')),
     'obstacle_gradient'),
]


def _check_rejected(problem, options, pattern):
    calls = []
    result = solve(problem, options, progress=calls.append)
    assert result.status is Status.INVALID_INPUT
    assert result.status.exit_code() == 4
    assert re.search(pattern, result.message, re.IGNORECASE), result.message
    # Nothing ran: no iteration, no trajectory, no progress report.
    assert result.iterations == 0 and not result.has_trajectory and calls == []
    return result


@pytest.mark.parametrize('mode', ['fast', 'paper'])
@pytest.mark.parametrize('case, problem, pattern', BAD_PROBLEMS,
                         ids=[c[0] for c in BAD_PROBLEMS])
def test_bad_problem_is_rejected_before_iterating(case, problem, pattern, mode):
    _check_rejected(problem, SolverOptions(mode=mode), pattern)


@pytest.mark.parametrize('case, options, pattern', BAD_OPTIONS, ids=[c[0] for c in BAD_OPTIONS])
def test_bad_options_are_rejected_before_iterating(case, options, pattern):
    _check_rejected(PAPER, options, pattern)


def test_every_problem_is_named_in_one_message():
    problem = replace(PAPER, n_intervals=0, t_f0=-1.0, integrator='midpoint')
    message = _check_rejected(problem, SolverOptions(), 'N must').message
    assert 't_f0' in message and 'integrator' in message


def test_not_a_problem_is_rejected():
    _check_rejected({'x0': (0, 0, 1, 0)}, SolverOptions(), 'Problem')


def test_valid_problems_near_the_limits_are_accepted():
    """The checks are not over-eager: a start just clear of the inflated circle is fine."""
    angle = math.pi / 4 - math.asin(0.215 / math.sqrt(2))      # 5 mm clear of R = 0.21 m
    problem = replace(PAPER, x0=(angle, 0.0, 1.0, 0.0), n_intervals=20)
    result = solve(problem, SolverOptions(mode='paper', max_iterations=1))
    assert result.status is not Status.INVALID_INPUT, result.message
    assert result.iterations == 1


def test_a_problem_has_no_obstacle_unless_given():
    """Start and goal are all a problem needs; nothing is avoided that was not given."""
    problem = Problem(x0=PAPER_X0, x_goal=PAPER_GOAL, n_intervals=100)
    assert problem.obstacles == () and problem.circles().shape == (0, 3)
    assert problem.model == CylindricalRobot(RobotParams())
    result = solve(problem)
    assert result.status is Status.SOLVED, result.message
    assert result.violations.min_clearance == math.inf      # no circle was measured
    # The arm sweeps through the paper's circle: it was not planned around (a circle given
    # to nobody would have kept it outside).
    paper_circle = Problem.paper().circles()
    assert float(np.min(model_clearance(problem.model, result.states, paper_circle))) < 0.0


def test_the_paper_scenario_is_an_explicit_constructor():
    paper = Problem.paper()
    assert paper.obstacles == PAPER_OBSTACLES == ((1.0, 1.0, 0.2),)
    assert (paper.x0, paper.x_goal, paper.margin) == (PAPER_X0, PAPER_GOAL, 0.01)
    assert paper.model == CylindricalRobot(RobotParams())
    assert (paper.n_intervals, paper.integrator, paper.t_f0) == (1000, 'euler', 2.5)
    changed = Problem.paper(n_intervals=50, margin=0.02)
    assert (changed.n_intervals, changed.margin, changed.obstacles) == (50, 0.02,
                                                                        PAPER_OBSTACLES)


def test_start_and_goal_are_required():
    with pytest.raises(TypeError, match='x0'):
        Problem()
    with pytest.raises(TypeError, match='x_goal'):
        Problem(x0=PAPER_X0)


def test_the_robot_is_given_one_way_only():
    """The robot is the model; the former robot= keyword and attribute say so."""
    for make in (lambda: Problem(x0=PAPER_X0, x_goal=PAPER_GOAL, robot=ROBOT),
                 lambda: replace(PAPER, robot=ROBOT),
                 lambda: Problem.paper(robot=ROBOT)):
        with pytest.raises(TypeError, match=r'model=CylindricalRobot\(RobotParams'):
            make()
    with pytest.raises(AttributeError, match='Problem.model'):
        PAPER.robot
    heavy = replace(ROBOT, hand_mass=60.0)
    assert Problem.paper(model=CylindricalRobot(heavy)).model.params.hand_mass == 60.0
