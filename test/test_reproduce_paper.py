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
Smoke test of benchmarks/reproduce_paper.py in its --quick configuration (N = 200, M = 2000).

One run of every experiment (module fixture), written to a temporary directory; the report's
numbers and figures are checked against the runs, and the measurements the explanation relies
on are re-checked with the plain-numpy model of test/numpy_model.py.
"""

import copy
from dataclasses import replace
import importlib.util
import math
from pathlib import Path
import re

from benchmarks import reproduce_paper as rp
import numpy as np
import numpy_model as nm
import pytest

from toc_ros.core import CylindricalRobot

pytestmark = pytest.mark.slow

HAVE_CASADI = importlib.util.find_spec('casadi') is not None
PNG_MAGIC = b'\x89PNG\r\n\x1a\n'


@pytest.fixture(scope='module')
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp('reproduction')
    res = rp.run_all(rp.QUICK, use_reference=HAVE_CASADI)
    path = rp.write_report(res, out)
    return res, path, path.read_text(encoding='utf-8')


def _linked_figures(text):
    return re.findall(r'!\[[^\]]*\]\(([^)]+)\)', text)


def test_every_linked_figure_is_a_png_next_to_the_report(quick):
    _, path, text = quick
    links = _linked_figures(text)
    expected = {'fig5_paper_mode.png', 'fig6_fast_mode.png', 'fig7_hand_path.png',
                'paper_mode_convergence.png', 'u2max_sweep.png'}
    if HAVE_CASADI:
        expected.add('hand_only_obstacle.png')
    assert {Path(link).name for link in links} == expected
    for link in links:
        assert not Path(link).is_absolute() and link.startswith('figures/')
        data = (path.parent / link).read_bytes()
        assert data[:8] == PNG_MAGIC and len(data) > 10000, link


def test_table_reports_the_runs(quick):
    res, _, text = quick
    assert 'Quick configuration' in text and '| 1.71 |' in text
    rows = [ln for ln in text.splitlines() if ln.startswith('| ')]

    def row(prefix, disc):
        found = [ln for ln in rows if ln.startswith(prefix) and disc in ln]
        assert len(found) == 1, (prefix, disc)
        return found[0]

    paper = row('| paper mode', 'M = 2000')
    assert f'| {res["paper"].t_f:.4f} |' in paper
    assert f'| {res["paper"].violations.max_control_excess:.3g} |' in paper
    fast = row('| fast mode', 'Euler, N = 200')
    assert f'| {res["fast"].t_f:.4f} |' in fast and '| SOLVED |' in fast
    assert f'| {res["fast_rk4"].t_f:.4f} |' in row('| fast mode', 'RK4, N = 50')
    if HAVE_CASADI:
        ipopt = row('| reference: CasADi + IPOPT', 'Euler, N = 200')
        assert f'| {res["reference"].t_f:.4f} |' in ipopt
    else:
        assert 'IPOPT reference is omitted' in text


def test_fast_mode_results_are_feasible_and_agree_with_the_reference(quick):
    res, _, _ = quick
    for key in ('fast', 'fast_rk4'):
        run = res[key]
        assert run.ok, run.note
        measured = nm.assert_feasible(run.problem, _as_result(run))
        assert measured['min_clearance'] > -1e-6
    assert res['fast_variants']['eq37', False].t_f < res['fast'].t_f
    if HAVE_CASADI:
        ref = res['reference']
        assert ref.ok and ref.t_f == pytest.approx(res['fast'].t_f, rel=1e-3)


def test_paper_mode_breakdown_matches_the_recorded_cost(quick):
    """J1 + J2 + J3 recomputed from the returned controls equals the solver's J_T there."""
    res, _, _ = quick
    run, b = res['paper'], res['paper_breakdown']
    assert run.ok and b['accepted'] > 0
    states = nm.simulate(nm.X0, run.controls, run.t_f)
    np.testing.assert_allclose(b['terminal'], states[-1] - nm.XG, rtol=0, atol=1e-9)
    assert b['j1'] + b['j2'] + b['j3'] == pytest.approx(b['j_accepted'], rel=1e-8)
    assert b['j_accepted'] < rp.PaperOptions().j_eps
    assert b['budget_terminal'] == pytest.approx(math.sqrt(0.01 / 600.0))


def test_ray_penetration_agrees_with_polynomial_roots():
    """Eq. (39)-(41) residual against numpy_model's root finder on arms that cut the circle."""
    q1 = np.linspace(0.6, 0.95, 41)
    states = np.column_stack([q1, np.zeros_like(q1), np.full_like(q1, 0.4), np.zeros_like(q1)])
    expected = []
    for x in states:
        hit = nm.ray_first_hit(x[0], 1.0, 1.0, 0.21)
        expected.append(0.0 if hit is None else min(hit - 1.1 - x[2], 0.0))
    got = rp.ray_penetration(states, 1.1, nm.PAPER_CIRCLES)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
    assert np.min(got) < -0.1


@pytest.mark.skipif(not HAVE_CASADI, reason='needs casadi for the hand-only reference')
def test_hand_only_optimum_keeps_the_hand_out_but_cuts_with_the_arm(quick):
    res, _, text = quick
    hand = res['reference_variants']['eq37', 'hand']
    assert hand.ok and hand.t_f < res['reference'].t_f - 0.3
    states = nm.simulate(nm.X0, hand.controls, hand.t_f)
    hx = (1.1 + states[:, 2]) * np.cos(states[:, 0])
    hy = (1.1 + states[:, 2]) * np.sin(states[:, 0])
    assert np.min(np.hypot(hx - 1.0, hy - 1.0) - 0.21) > -1e-6
    arm = nm.sampled_clearance(states, nm.PAPER_CIRCLES)
    assert np.min(arm) < -0.1
    assert f'{hand.t_f:.4f}' in text


def test_limit_sweep_brackets_the_claim_and_scaling_law_holds(quick):
    res, _, text = quick
    sweep = res['sweep']
    assert sweep['bracketed']
    solved = {u2: run.t_f for u2, run in sweep['steps'] if run.ok}
    assert solved[sweep['lo']] > rp.PAPER_CLAIM >= solved[sweep['hi']]
    assert sweep['hi'] - sweep['lo'] <= rp.QUICK.sweep_tol
    times = [solved[u2] for u2 in sorted(solved)]
    assert all(a >= b for a, b in zip(times, times[1:]))       # more force, less time
    assert f'u2_max ≈ {sweep["hi"]:.0f} N' in text
    # t_min(s u_max) = t_min(u_max) / sqrt(s): an exact property of eq. (37).
    both = res['both_scaled']
    assert both.ok
    assert both.t_f == pytest.approx(res['fast'].t_f / math.sqrt(res['both_scale']), rel=1e-3)


def test_report_without_reference_says_so(quick, tmp_path):
    res, _, _ = quick
    stripped = copy.copy(res)
    stripped.update(have_reference=False, reference=None, reference_variants={},
                    reference_reason='casadi is not importable in this environment')
    stripped['sweep'] = {k: v for k, v in res['sweep'].items() if k != 'confirm_ipopt'}
    for key in ('reference_rk4', 'u1_alone_ipopt'):
        stripped.pop(key, None)
    text = rp.write_report(stripped, tmp_path).read_text(encoding='utf-8')
    assert 'IPOPT reference is omitted: casadi is not importable' in text
    assert 'reference: CasADi + IPOPT' not in text
    assert 'hand_only_obstacle.png' not in text
    header = [ln for ln in text.splitlines() if ln.startswith('| model (sign')]
    assert len(header) == 1 and header[0].endswith('| paper mode | fast mode |')


def _as_result(run):
    """Adapt a reproduce_paper.SolveRecord to the SolveResult fields assert_feasible reads."""
    return type('R', (), {'controls': run.controls, 'states': run.states, 'final_time': run.t_f,
                          'time_grid': run.time_grid, 'violations': run.violations})()


def test_report_numbers_come_from_the_data(quick):
    """The scenario's numbers in the text are read from the Problem, not written by hand."""
    res, _, text = quick
    assert rp._scenario_text(res['paper'].problem) in ' '.join(text.split())
    changed = replace(rp.BASE, margin=0.03,
                      model=CylindricalRobot(replace(rp.BASE.model.params, u2_max=450.0)))
    described = rp._scenario_text(changed)
    assert 'to R = 0.23 m' in described and '|u2| ≤ 450 N' in described
    steps = res['paper'].problem.n_intervals * rp.PaperOptions().d_tau
    assert f'N Δτ = {steps:.3g} s' in text
    assert f'inflated circle\nR = {0.2 + res["paper"].problem.margin:g} m' in text
