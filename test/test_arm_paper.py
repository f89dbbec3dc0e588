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

"""Paper mode for URDF arms (core/arms/arm_paper.py): gradient, model identity, the heuristic."""

import json
import math
import os

import numpy as np
import pytest

pin = pytest.importorskip('pinocchio')

from toc_ros.bench.arm_check import check_trajectory, example_robot_urdf  # noqa: E402
from toc_ros.bench.arm_problem import ArmSpec  # noqa: E402
from toc_ros.core import PaperOptions, Problem, solve, SolverOptions, Status  # noqa: E402
from toc_ros.core.arms import load_arm, load_spheres  # noqa: E402
from toc_ros.core.arms.arm_eval import ArmEvaluator  # noqa: E402
from toc_ros.core.arms.arm_paper import ArmPaperRun, terminal_curvature  # noqa: E402
from toc_ros.core.arms.arm_solve import ArmRobot  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(os.path.dirname(HERE), 'benchmarks', 'data')
UR5_START = (0.0, -0.4, 0.4, -1.57, -1.57, 0.0)
UR5_GOAL = (0.0, -2.0, 0.9, -1.57, -1.57, 0.0)
UR5_SPHERE = ((0.60, 0.0, 0.55, 0.2),)
MARGIN = 0.02


def _robot(name='ur5'):
    arm = load_arm(name)
    return ArmRobot(arm, load_spheres(os.path.join(DATA, f'arm_spheres_{name}.yaml'), arm,
                                      self_collision=False))


def _run(robot, n_int, t_f0, obstacles=UR5_SPHERE, start=UR5_START, goal=UR5_GOAL):
    n = robot.arm.n
    x0 = np.concatenate([start, np.zeros(n)])
    xg = np.concatenate([goal, np.zeros(n)])
    evaluator = ArmEvaluator(robot.arm, robot.spheres, obstacles, MARGIN, n_int)
    return ArmPaperRun(robot, evaluator, x0, xg, n_int, t_f0, PaperOptions())


def test_the_gradient_matches_central_differences_with_every_penalty_active():
    robot = _robot()
    run = _run(robot, n_int=12, t_f0=0.6)
    rng = np.random.default_rng(3)
    # Large accelerations through the sphere: torques, velocities, positions and clearance
    # rows all past their bounds somewhere.
    a = rng.normal(0.0, 25.0, (12, robot.arm.n))
    a[:, 1] -= 60.0
    tau = run.tau0
    j1, j2, j3, grad = run.cost_gradient(a, tau)
    q, v = run.rollout(a, tau)
    assert j1 > 0 and j2 > 0 and j3 > 0
    assert np.any(np.abs(v[1:]) > robot.arm.velocity)                     # velocity rows
    assert np.any((q > robot.arm.upper) | (q < robot.arm.lower))          # position rows
    assert np.min(run.evaluator.clearances(q[1:])) < 0                    # sphere rows

    def total(acc):
        return sum(run.cost_gradient(acc, tau)[:3])

    step = 1e-6
    for _ in range(6):
        d = rng.normal(size=a.shape)
        fd = (total(a + step * d) - total(a - step * d)) / (2 * step)
        assert fd == pytest.approx(float(np.sum(grad * d)), rel=2e-5, abs=1e-6)
    for k, i in ((0, 1), (5, 0), (11, 4)):
        e = np.zeros_like(a)
        e[k, i] = 1.0
        fd = (total(a + step * e) - total(a - step * e)) / (2 * step)
        assert fd == pytest.approx(grad[k, i], rel=2e-5, abs=1e-6)


def test_the_torques_reproduce_the_acceleration_plan_under_the_arms_own_euler_steps():
    # The identity the mode rests on: ABA(q, v, RNEA(q, v, a)) = a, so the returned torques,
    # re-integrated by the independent check (its own Pinocchio model from the URDF), give
    # back the double integrator's states.
    robot = _robot('panda')
    start = (-1.2, 0.2, 0.0, -2.0, 0.0, 2.2, 0.8)
    run = _run(robot, n_int=20, t_f0=1.5, obstacles=(), start=start,
               goal=(1.2, 0.1, 0.3, -1.8, 0.2, 2.0, 0.3))
    a = np.random.default_rng(5).normal(0.0, 2.0, (20, 7))
    q, v = run.rollout(a, run.tau0)
    torques = run.torques(q, v, a)
    spec = ArmSpec(urdf=example_robot_urdf('panda'), joints=robot.arm.joint_names,
                   start=start, goal=start, obstacles=(), robot_spheres=None, margin=0.0)
    check = check_trajectory(spec, 1.5, torques, 'euler', np.hstack([q, v]))
    assert check['defect'] < 1e-9


def test_the_learning_rate_is_the_inverse_curvature_of_the_terminal_penalty():
    # L against the Hessian of J1 formed by finite differences of its gradient.
    robot = _robot()
    run = _run(robot, n_int=8, t_f0=2.0, obstacles=())
    a0 = np.zeros((8, robot.arm.n))
    size = a0.size
    hessian = np.zeros((size, size))
    step = 1e-4
    for j in range(size):
        e = np.zeros(size)
        e[j] = step
        hessian[:, j] = (run.cost_gradient(a0 + e.reshape(a0.shape), run.tau0)[3]
                         - run.cost_gradient(a0 - e.reshape(a0.shape), run.tau0)[3]
                         ).ravel() / (2 * step)
    # Away from every bound the Hessian is J1's alone (the start is at rest, within limits).
    assert np.max(np.linalg.eigvalsh(0.5 * (hessian + hessian.T))) == pytest.approx(
        terminal_curvature(8, run.tau0, 600.0), rel=1e-6)
    assert run.eta == pytest.approx(1.0 / terminal_curvature(8, run.tau0, 600.0))


def test_a_paper_solve_meets_what_its_acceptance_promises_by_an_independent_check():
    # J_T < J_eps bounds each penalised violation: |x(N) - x_f| <= sqrt(J_eps / K_B), a torque
    # excess <= sqrt(J_eps / (tau0 K_V)), a velocity excess or depth <= sqrt(J_eps /
    # (tau0 K_p)); all are re-measured here on the torques integrated again by arm_check.
    robot = _robot()
    n_int, t_f0 = 30, 2.5
    problem = Problem(x0=UR5_START, x_goal=UR5_GOAL, model=robot, obstacles=UR5_SPHERE,
                      margin=MARGIN, n_intervals=n_int, t_f0=t_f0)
    result = solve(problem, SolverOptions(mode='paper', max_iterations=4000))
    assert result.status in (Status.SOLVED, Status.SOLVED_INACCURATE), result.message
    assert result.mode == 'paper' and result.iterations == 4000
    accepted = result.solver_state['accepted']
    assert accepted > 0
    # Every accepted iteration shortened tau by d_tau (t_f by N d_tau).
    assert result.final_time == pytest.approx(t_f0 - (accepted - 1) * n_int * 1e-5, abs=1e-9)
    fast = solve(problem)
    assert fast.status is Status.SOLVED
    assert result.final_time > 0.99 * fast.final_time
    spec = ArmSpec(urdf=example_robot_urdf('ur5'), joints=robot.arm.joint_names,
                   start=UR5_START, goal=UR5_GOAL, obstacles=UR5_SPHERE,
                   robot_spheres=os.path.join(DATA, 'arm_spheres_ur5.yaml'), margin=MARGIN)
    check = check_trajectory(spec, result.final_time, result.controls, 'euler',
                             result.states)
    tau0 = t_f0 / n_int
    assert check['defect'] < 1e-9
    assert check['terminal_error'] <= math.sqrt(0.01 / 600.0)
    assert check['max_effort_excess'] <= math.sqrt(0.01 / (tau0 * 0.01))
    assert check['max_velocity_excess'] <= math.sqrt(0.01 / (tau0 * 1000.0))
    # A row (d^2 - R^2) / (2 R) is within 2x of the depth d - R for any depth.
    assert check['min_clearance'] >= -2.0 * math.sqrt(0.01 / (tau0 * 1000.0))
    assert result.violations.terminal_error == pytest.approx(
        np.linalg.norm(result.states[-1] - np.r_[UR5_GOAL, np.zeros(6)]))


def test_paper_mode_is_deterministic_and_stops_on_a_timeout():
    robot = _robot()
    problem = Problem(x0=UR5_START, x_goal=UR5_GOAL, model=robot, obstacles=UR5_SPHERE,
                      margin=MARGIN, n_intervals=10)
    options = SolverOptions(mode='paper', max_iterations=300)
    first, second = solve(problem, options), solve(problem, options)
    assert first.final_time == second.final_time
    assert np.array_equal(first.controls, second.controls)
    stopped = solve(problem, SolverOptions(mode='paper', max_iterations=10 ** 9, timeout=0.3))
    assert stopped.status is Status.TIMEOUT
    assert 0 < stopped.iterations < 10 ** 9 and stopped.controls.shape == (10, 6)
    assert stopped.history.shape == (stopped.iterations, 4)


@pytest.mark.parametrize('options, guess, t_f0, text', [
    (SolverOptions(mode='paper', paper=PaperOptions(arm_step=2.0)), None, 2.5, 'below 2'),
    (SolverOptions(mode='paper'), (np.zeros((10, 6)), 1.0), 2.5, 'fast mode only'),
    # Integrated open loop over 1e9 s the plan's torques left the numbers (NaN states).
    (SolverOptions(mode='paper'), None, 1e9, 'range of final times'),
    (SolverOptions(mode='paper'), None, 1e-9, 'range of final times'),
])
def test_bad_paper_settings_for_arms_are_refused_with_the_reason(options, guess, t_f0, text):
    problem = Problem(x0=UR5_START, x_goal=UR5_GOAL, model=_robot(), n_intervals=10,
                      t_f0=t_f0)
    result = solve(problem, options, initial_guess=guess)
    assert result.status is Status.INVALID_INPUT and text in result.message


def test_toc_solve_runs_paper_mode_for_an_arm(tmp_path):
    from toc_ros.solve import main
    out = tmp_path / 'paper.json'
    code = main(['--model', 'ur5', '--mode', 'paper', '--N', '20', '--max-iterations', '500',
                 '--t-f0', '3.0',
                 '--start', *map(str, UR5_START), '--goal', *map(str, UR5_GOAL),
                 '--json', str(out), '--quiet'])
    data = json.loads(out.read_text())
    assert data['status'] in ('SOLVED', 'SOLVED_INACCURATE', 'MAX_ITERATIONS')
    assert (code == 0) == (data['status'] == 'SOLVED')      # exit 0 only when SOLVED
    assert np.array(data['controls']).shape == (20, 6)
    assert data['final_time'] < 3.0         # started from --t-f0 3.0 and shortened it
