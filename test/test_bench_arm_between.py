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

"""benchmarks/arm_between_nodes.py: its clearances between the nodes, checked independently."""

import os
import sys
from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip('pinocchio')

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from arm_oracle import ArmOracle, find_panda_urdf  # noqa: E402, I100
from benchmarks import arm_between_nodes  # noqa: E402
from benchmarks.bench_arm_fast import SCENARIOS  # noqa: E402
from benchmarks.bench_arm_suite import MARGIN  # noqa: E402
from toc_ros.core import Problem, solve, Status  # noqa: E402
from toc_ros.core.arms import load_arm, load_spheres  # noqa: E402
from toc_ros.core.arms.arm_solve import ArmRobot  # noqa: E402

SPHERES = os.path.join(arm_between_nodes.HERE, 'data', 'arm_spheres_panda.yaml')


@pytest.fixture(scope='module')
def panda():
    arm = load_arm('panda')
    oracle = ArmOracle(find_panda_urdf().read_text(), spheres_path=SPHERES)
    return ArmRobot(arm, load_spheres(SPHERES, arm)), oracle


def test_clearances_of_a_plan_match_the_oracle_on_the_cubic_a_controller_follows(panda):
    robot, oracle = panda
    start, goal, sets = SCENARIOS['panda']
    obstacles = np.asarray(sets['1 sphere'], dtype=float).reshape(-1, 4)
    result = solve(Problem(x0=start, x_goal=goal, model=robot, obstacles=obstacles,
                           margin=MARGIN, n_intervals=12))
    assert result.status is Status.SOLVED
    samples = 3
    measured = arm_between_nodes.clearances(robot, result, obstacles, MARGIN, samples)
    # Independently: the published points are the nodes half a step along their velocity,
    # and between two points the motion is the one they stand for (plan_reference.py): from
    # the point on, its velocity going linearly from dq_k to dq_k+1 (which the controller's
    # cubic reproduces); clearances by the oracle's own kinematics.
    n = robot.arm.n
    q, dq, times = result.states[:, :n], result.states[:, n:], result.time_grid
    h = times[1] - times[0]
    points = q + 0.5 * h * dq
    fractions = np.arange(1, samples + 1) / (samples + 1)
    cubic = [points[k] + dq[k] * (s * h) + (dq[k + 1] - dq[k]) * (s * s * h / 2.0)
             for k in range(len(q) - 1) for s in fractions]
    chords = [q[k] + s * (q[k + 1] - q[k]) for k in range(len(q) - 1) for s in fractions]

    def worst(configurations):
        return min(oracle.clearance(c, obstacles, MARGIN) for c in configurations)
    expected = (worst(q), worst(points), worst(cubic), worst(chords))
    assert np.allclose(measured, expected, rtol=0.0, atol=1e-9), (measured, expected)
    # The solver keeps the nodes clear; what it does not constrain is reported as it is.
    assert measured[0] >= -1e-9


def test_an_obstacle_between_two_clear_nodes_is_found_between_them(panda):
    robot, oracle = panda
    q_a = np.array([-0.6, -0.3, 0.0, -2.0, 0.0, 1.8, 0.785])
    q_b = q_a.copy()
    q_b[0] = 0.6
    hand = oracle.tip(0.5 * (q_a + q_b)).translation
    # A sphere at the hand's middle position, small enough for both ends to clear it.
    obstacles = np.array([[*hand, 0.02]])
    assert oracle.clearance(q_a, obstacles, 0.0) > 0.0
    assert oracle.clearance(q_b, obstacles, 0.0) > 0.0
    h = 0.5
    velocity = (q_b - q_a) / h
    plan = SimpleNamespace(states=np.array([np.concatenate([q_a, velocity]),
                                            np.concatenate([q_b, velocity])]),
                           time_grid=np.array([0.0, h]))
    nodes, points, between, chords = arm_between_nodes.clearances(robot, plan, obstacles, 0.0,
                                                                  samples=5)
    assert nodes > 0.0
    # The chord between the nodes passes the obstacle; so does the published motion, whose
    # first point is the nodes' middle (half a step along the velocity).
    assert chords < 0.0 and points < 0.0
    assert chords == pytest.approx(oracle.clearance(0.5 * (q_a + q_b), obstacles, 0.0),
                                   abs=1e-9)
