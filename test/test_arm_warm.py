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
Warm starts of the URDF-arm solver.

A plan's remainder (with its multipliers) from the state the robot reached, a (controls, t_f)
pair, a guess on another grid, and guesses that are bad.

A warm solve must end where a cold solve of the same problem ends (the same optimum), and
every result is re-checked independently (toc_ros/bench/arm_check.py: Pinocchio's own URDF
parser, the controls re-integrated from the problem's start, every limit and clearance at
every node).
"""

import dataclasses

import numpy as np
import pytest

pin = pytest.importorskip('pinocchio')

from test_arm_solve import (_independent_check, _problem, DATA, MARGIN,  # noqa: E402, I100
                            SCENARIOS)
from toc_ros.core import solve, SolveResult, Status  # noqa: E402, I100
from toc_ros.core.arms import load_arm  # noqa: E402


@pytest.fixture(scope='module')
def panda_plan():
    """Return a cold Panda plan around one sphere (N = 60) and its problem."""
    problem = _problem('panda', 60)
    result = solve(problem)
    assert result.status is Status.SOLVED, result.message
    return problem, result


def _check(problem, result):
    """Re-measure result from problem's start with the independent checker."""
    _independent_check('panda', result, tuple(problem.obstacles), tuple(problem.x0),
                       tuple(problem.x_goal))


def _from(problem, state, n_int):
    return dataclasses.replace(problem, x0=tuple(state), n_intervals=n_int)


@pytest.mark.parametrize('drift', [0.0, 1e-3])
def test_remainder_with_multipliers_reaches_the_cold_optimum_in_few_iterations(panda_plan,
                                                                               drift):
    problem, plan = panda_plan
    rest = plan.remainder(0.3 * plan.final_time)
    n = 7
    state = rest.states[0].copy()
    state[:n] += drift                    # where the robot is, off the plan by drift
    state[n:] *= 1.0 - drift
    replan = _from(problem, state, rest.controls.shape[0])
    cold = solve(replan)
    warm = solve(replan, initial_guess=rest)
    assert cold.status is Status.SOLVED and warm.status is Status.SOLVED, warm.message
    assert 'warm start with multipliers' in warm.message
    # The remainder is nearly optimal: fewer Newton steps than from the cold start (on the
    # plan none; 1e-3 off it 2 against 11-12: WARM_NEAR).
    assert warm.iterations <= 2 * cold.iterations // 3, (warm.iterations, cold.iterations)
    if drift == 0.0:
        # On the plan itself it is the solution (its multipliers scaled to the remainder's
        # T row): taken as it is, the same t_f as the cold solve within its tolerance.
        assert warm.iterations == 0, warm.message
        assert warm.final_time == rest.final_time
        assert warm.final_time == pytest.approx(cold.final_time, rel=1e-8)
    else:
        # Two converged runs from different starts: the same t_f to within what the
        # convergence tolerance (1e-8) leaves of it.
        assert warm.final_time == pytest.approx(cold.final_time, rel=1e-9)
    _check(replan, warm)


def test_a_replan_1e3_off_the_plan_past_a_sphere_at_100_intervals_takes_few_iterations():
    # The warm-replan row (the Panda past a sphere, N = 100, from 30 %).  A plan whose
    # joints that do not set the time are off the barrier path's centre (a bend of the free
    # optimum run warm from its multipliers, tried and reverted) made this replan's first
    # Newton step move them by up to 0.26 rad toward it: 36 iterations instead of 2.
    problem = _problem('panda', 100)
    plan = solve(problem)
    assert plan.status is Status.SOLVED, plan.message
    rest = plan.remainder(0.3 * plan.final_time)
    state = rest.states[0].copy()
    state[:7] += 1e-3
    state[7:] *= 1.0 - 1e-3
    replan = _from(problem, state, rest.controls.shape[0])
    warm = solve(replan, initial_guess=rest)
    assert warm.status is Status.SOLVED, warm.message
    assert warm.iterations <= 3, warm.message
    assert warm.final_time == pytest.approx(solve(replan).final_time, rel=1e-9)
    _check(replan, warm)


def _drifted_replan(panda_plan, drift):
    problem, plan = panda_plan
    rest = plan.remainder(0.3 * plan.final_time)
    state = rest.states[0].copy()
    state[:7] += drift
    state[7:] *= 1.0 - drift
    return _from(problem, state, rest.controls.shape[0]), rest


def test_a_start_near_the_plan_begins_at_the_last_barrier_parameter(panda_plan, monkeypatch):
    # 1e-3 off the plan is within WARM_NEAR: the run starts at mu = 1e-9, where it
    # converges in fewer Newton steps than from mu = 1e-7 (the same optimum).
    from toc_ros.core.arms import arm_solve
    replan, rest = _drifted_replan(panda_plan, 1e-3)
    near = solve(replan, initial_guess=rest)
    monkeypatch.setattr(arm_solve, 'WARM_NEAR', 0.0)
    drifted = solve(replan, initial_guess=rest)
    assert near.status is Status.SOLVED and drifted.status is Status.SOLVED
    assert near.message.startswith('warm start with multipliers at mu = 1e-09: converged'), \
        near.message
    assert 'mu = 1e-07' not in near.message
    assert drifted.message.startswith('warm start with multipliers: converged')
    assert near.iterations < drifted.iterations, (near.iterations, drifted.iterations)
    assert near.final_time == pytest.approx(drifted.final_time, rel=1e-9)
    _check(replan, near)


def test_a_near_start_that_fails_at_the_last_barrier_parameter_tries_the_drift_one(
        panda_plan, monkeypatch):
    # One iteration at mu = 1e-9 is too few to converge (it takes two): the second try
    # starts from the same guess at mu = 1e-7, not from the cold start.
    from toc_ros.core.arms import arm_solve
    monkeypatch.setattr(arm_solve, 'WARM_NEAR_BUDGET', 1)
    replan, rest = _drifted_replan(panda_plan, 1e-3)
    result = solve(replan, initial_guess=rest)
    assert result.status is Status.SOLVED, result.message
    first, second = result.message.split('; ')[:2]
    assert first.startswith('warm start with multipliers at mu = 1e-09: max_iterations after '
                            '1 iteration'), result.message
    assert second.startswith('warm start with multipliers at mu = 1e-07: converged'), \
        result.message
    assert 'without the obstacles' not in result.message     # (no cold search ran)
    _check(replan, result)


def test_remainder_slices_the_arm_multipliers_with_the_plan(panda_plan):
    _, plan = panda_plan
    full = plan.solver_state['arm_duals']
    rest = plan.remainder(0.3 * plan.final_time)
    k = plan.controls.shape[0] - rest.controls.shape[0]
    duals = rest.solver_state['arm_duals']
    assert duals['lam'].shape == (rest.controls.shape[0] + 1, 14)
    assert duals['zlv'].shape == rest.controls.shape
    np.testing.assert_array_equal(duals['z'], full['z'][k:])
    assert duals['zlt'] == full['zlt'] and duals['prox'] == full['prox']


def test_a_controls_pair_and_another_grid_are_warm_starts_without_multipliers(panda_plan):
    problem, plan = panda_plan
    cold = solve(_problem('panda', 80))
    for guess in ((plan.controls, plan.final_time), plan):      # 60 intervals for 80
        warm = solve(_problem('panda', 80), initial_guess=guess)
        assert warm.status is Status.SOLVED, warm.message
        assert warm.message.startswith('warm start:')
        assert warm.final_time == pytest.approx(cold.final_time, rel=1e-6)
    same = solve(problem, initial_guess=(plan.controls, plan.final_time))
    assert same.status is Status.SOLVED and same.final_time == pytest.approx(
        plan.final_time, rel=1e-6)
    _check(problem, same)


def test_a_poor_guess_falls_back_to_the_cold_start(panda_plan):
    problem, plan = panda_plan
    # No torques at all: the arm sags under gravity, far from the goal; the warm run fails.
    result = solve(problem, initial_guess=(np.zeros_like(plan.controls), 0.5))
    assert result.status is Status.SOLVED, result.message
    assert result.message.startswith('warm start: line_search_failed')
    assert result.final_time == pytest.approx(plan.final_time, rel=1e-6)
    _check(problem, result)
    # Torques that make the rollout diverge give no start point at all: the cold start.
    result = solve(problem, initial_guess=(np.full_like(plan.controls, 50.0), 1.0))
    assert result.status is Status.SOLVED, result.message
    assert result.message.startswith(
        'initial guess not used: its controls make the state diverge; ')
    assert result.final_time == plan.final_time


def test_a_changed_obstacle_set_keeps_the_other_multipliers(panda_plan):
    problem, plan = panda_plan
    rest = plan.remainder(0.3 * plan.final_time)
    more = SCENARIOS['panda'][2] + ((0.0, 0.6, 1.2, 0.05),)
    replan = dataclasses.replace(_from(problem, rest.states[0], rest.controls.shape[0]),
                                 obstacles=more)
    warm = solve(replan, initial_guess=rest)
    cold = solve(replan)
    assert warm.status is Status.SOLVED, warm.message
    assert warm.final_time == pytest.approx(cold.final_time, rel=1e-6)


@pytest.mark.parametrize('guess, reason', [
    ('controls', 'SolveResult or a pair'),
    ((np.zeros((10, 3)), 1.0), 'M x 7'),
    ((np.full((10, 7), np.nan), 1.0), 'finite controls'),
    ((np.zeros((10, 7)), -1.0), 'positive final time'),
    ((np.zeros((10, 7)), 'x'), 'must be numbers'),
    (SolveResult(status=Status.STALLED, message='no trajectory'), 'M x 7'),
])
def test_bad_guesses_are_invalid_input_with_the_reason(guess, reason):
    result = solve(_problem('panda', 20), initial_guess=guess)
    assert result.status is Status.INVALID_INPUT
    assert reason in result.message


def test_cli_warm_starts_from_a_result_file(tmp_path, capsys):
    import json
    from toc_ros.solve import main
    start, goal, obs = SCENARIOS['panda']
    common = ['--model', 'panda', '--collision-spheres', str(DATA / 'arm_spheres_panda.yaml'),
              '--start', *map(str, start), '--goal', *map(str, goal),
              '--sphere', *map(str, obs[0]), '--margin', str(MARGIN), '--quiet']
    first, second = tmp_path / 'a.json', tmp_path / 'b.json'
    assert main(common + ['--N', '40', '--json', str(first)]) == 0
    assert main(common + ['--N', '50', '--initial-guess', str(first), '--json',
                          str(second)]) == 0
    data = json.loads(second.read_text())
    assert data['status'] == 'SOLVED' and data['message'].startswith('warm start:')
    assert data['final_time'] == pytest.approx(
        solve(_problem('panda', 50)).final_time, rel=1e-6)
    (tmp_path / 'bad.json').write_text('{"controls": []}')
    assert main(common + ['--N', '50', '--initial-guess', str(tmp_path / 'bad.json')]) == 4
    assert 'has no trajectory' in capsys.readouterr().err


def test_a_start_a_little_past_a_velocity_limit_is_planned_back_within_it(panda_plan):
    # A measured state the tracking carried 5 % past joint 1's limit: the plan starts there
    # and keeps every limit from node 1 on; 20 % past it is refused with the reason.
    problem, plan = panda_plan
    arm = load_arm('panda')
    rest = plan.remainder(0.3 * plan.final_time)
    fast = rest.states[0].copy()
    joint = int(np.argmax(np.abs(fast[7:]) / arm.velocity))
    for factor, solved in ((1.05, True), (1.2, False)):
        fast[7 + joint] = np.sign(fast[7 + joint]) * factor * arm.velocity[joint]
        replan = _from(problem, fast, rest.controls.shape[0])
        result = solve(replan, initial_guess=rest)
        if solved:
            assert result.status is Status.SOLVED, result.message
            assert np.all(np.abs(result.states[1:, 7:]) <= arm.velocity + 1e-9)
            assert result.violations.max_velocity_excess == 0.0
            _check_from_node_1(replan, result, arm)
        else:
            assert result.status is Status.INVALID_INPUT
            assert 'exceeds its limit' in result.message and '+10 % allowed' in result.message


def _check_from_node_1(problem, result, arm):
    """Re-check independently, leaving out the start's own velocity excess."""
    from toc_ros.bench.arm_check import check_trajectory, example_robot_urdf
    from toc_ros.bench.arm_problem import ArmSpec
    spec = ArmSpec(urdf=example_robot_urdf('panda'), joints=arm.joint_names,
                   start=tuple(problem.x0), goal=tuple(problem.x_goal),
                   obstacles=tuple(problem.obstacles),
                   robot_spheres=str(DATA / 'arm_spheres_panda.yaml'), margin=MARGIN)
    check = check_trajectory(spec, result.final_time, result.controls, 'euler', result.states)
    assert check['terminal_error'] < 1e-6 and check['defect'] < 1e-9
    assert np.all(np.abs(check['states'][1:, 7:]) <= arm.velocity + 1e-9)
    assert check['max_effort_excess'] == 0.0 and check['min_clearance'] >= -1e-6
