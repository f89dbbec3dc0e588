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
Checks of the IPOPT / FATROP reference transcriptions (benchmarks/reference_solvers.py).

Small N only (a few seconds in all): both solvers agree with each other and with fast mode on
the paper scenario and on planar_2r with a circle, every solution is feasible when re-integrated,
the NLP's clearance constraint equals toc_ros' own clearance measure, and pack/unpack are
inverse in both layouts.
"""

from dataclasses import replace
import math

from benchmarks import reference_solvers as rs
import numpy as np
import pytest

from toc_ros.core import Problem, solve, SolverOptions
from toc_ros.core.models import load_model
from toc_ros.core.obstacles import model_clearance

pytestmark = pytest.mark.slow

ca = pytest.importorskip('casadi')

PAPER = Problem.paper(n_intervals=40)
PLANAR = Problem(model=load_model('planar_2r'), x0=(0.0, 0.0, 0.3, 0.0),
                 x_goal=(1.6, 0.0, 0.3, 0.0), obstacles=((0.11, 1.2, 0.15),), n_intervals=40)
PLANAR_FREE = replace(PLANAR, obstacles=(), model=load_model('planar_2r', g=9.81))


def _solvers():
    return [s for s in rs.SOLVERS if rs.have_solver(s)]


@pytest.mark.parametrize('problem', [PAPER, PLANAR_FREE], ids=['paper', 'planar_2r-gravity'])
def test_ipopt_fatrop_and_fast_mode_agree_and_are_feasible(problem):
    fast = solve(problem, SolverOptions(mode='fast'))
    assert fast.success, fast.message
    for name in _solvers():
        out = rs.Reference(problem, name).solve()
        assert out['success'], (name, out['status'])
        assert out['feasible'], (name, out['violations'])
        assert out['setup_time_s'] > 0.0 and out['solve_time_s'] > 0.0
        assert out['iterations'] > 0
        assert abs(out['t_f'] - fast.final_time) < 1e-5 * fast.final_time, name
        # The returned states are the re-integrated ones (zero defects in the NLP).
        states, _ = rs.measure_violations(problem, out['controls'], out['t_f'])
        assert np.max(np.abs(states - out['states'])) < 1e-6


def test_fast_mode_solution_is_a_solution_of_the_reference_nlp():
    # planar_2r with an active circle has several local optima; started at fast mode's
    # solution, both references must stay there (same discrete problem, same optimum).
    fast = solve(PLANAR, SolverOptions(mode='fast'))
    assert fast.success, fast.message
    for name in _solvers():
        out = rs.Reference(PLANAR, name).solve((fast.states, fast.controls, fast.final_time),
                                               warm=True)
        assert out['success'], (name, out['status'])
        v = out['violations']
        # FATROP relaxes the control bounds slightly (~1e-8 relative) with the warm options.
        assert v['max_control_excess'] < 1e-5 and v['terminal_error'] < 1e-6, (name, v)
        assert v['min_clearance'] > -1e-6, (name, v)
        assert abs(out['t_f'] - fast.final_time) < 1e-5 * fast.final_time, name


def test_warm_start_from_the_solution_converges_at_once():
    ref = rs.Reference(PAPER, 'ipopt')
    cold = ref.solve()
    warm = ref.solve((cold['states'], cold['controls'], cold['t_f']), warm=True)
    assert warm['success'] and warm['feasible']
    assert abs(warm['t_f'] - cold['t_f']) < 1e-7
    assert warm['iterations'] < cold['iterations']


@pytest.mark.parametrize('layout', ['global', 'stagewise'])
def test_pack_unpack_round_trip(layout):
    ref = rs.Reference(PLANAR, 'ipopt', layout=layout)
    rng = np.random.default_rng(3)
    states = rng.normal(size=(41, 4))
    controls = rng.uniform(-1.0, 1.0, size=(40, 2)) * ref.u_max
    w = ref.pack(states, controls, 1.7)
    s2, c2, t2 = ref.unpack(w)
    # x(0) and x(N) are fixed by bounds in the global layout: pack clips them.
    np.testing.assert_allclose(s2[1:-1], states[1:-1])
    np.testing.assert_allclose(c2, controls)
    assert t2 == pytest.approx(1.7)


@pytest.mark.parametrize('problem', [PAPER, PLANAR], ids=['paper', 'planar_2r'])
def test_nlp_clearance_matches_the_core_measure(problem):
    model = problem.robot_model
    name, params = rs.model_spec(problem)
    _, segments, _ = rs.casadi_model(name, params)
    circles = problem.circles()
    clear = rs._segment_constraint(segments, circles, model.n_joints)
    rng = np.random.default_rng(5)
    for _ in range(50):
        x = model.state(rng.uniform(-1.5, 1.5, model.n_joints))
        gaps = model_clearance(model, x[None, :], circles)[0]       # distance - R
        c = np.asarray(clear(x[0::2])).ravel()                       # (d^2 - R^2) / (2 R)
        radius = np.tile(circles[:, 2], model.n_links)
        d = gaps + radius
        np.testing.assert_allclose(c, (d * d - radius * radius) / (2.0 * radius), atol=1e-10)


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match='solver'):
        rs.Reference(PAPER, 'snopt')
    with pytest.raises(ValueError, match='stagewise'):
        rs.Reference(PAPER, 'fatrop', layout='global')
    ref = rs.Reference(PAPER, 'ipopt')
    with pytest.raises(ValueError, match='guess needs'):
        ref.solve((np.zeros((3, 4)), np.zeros((2, 2)), 1.0))
    assert math.isnan(rs.gap_percent(math.nan, 1.0))
