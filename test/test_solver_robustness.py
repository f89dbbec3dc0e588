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
Fast mode on cases it used to fail: former STALLED random scenarios and planar_2r circles.

* Random scenarios 14 and 20 of benchmarks/random_scenarios.py (N = 300, two and three
  circles crossed by the cold start): STALLED before the elastic weight was raised only at
  solutions of the barrier problem.  Checked by the numpy re-integration of numpy_model and
  against the IPOPT transcription of benchmarks/reference_ipopt.py (when casadi is importable,
  else the recorded optimum).
* planar_2r of benchmarks/bench_planar_2r.py (Euler, N = 1000, circle A active): without
  gravity STALLED before; with gravity a poor local optimum (0.817 s) before the further cold
  attempts.  Checked by an Euler re-integration with the arm's closed-form dynamics written
  here in numpy, and the clearance of both links by numpy segment geometry; t_f against the
  best IPOPT t_f the benchmark measured on the same discretisation.
* The five planar_2r scenarios that took 1000-1500 iterations of further cold attempts (two
  ending in poorer local optima) before the class starts of homotopy.py; the class starts
  themselves checked by independent geometry (clearance of both links along the paths, and
  winding numbers around configurations inside the obstacles for distinct classes); the
  parallel attempts against the same attempts one after the other, bit for bit.
"""

from dataclasses import replace
import importlib.util
import math
from types import SimpleNamespace

import numpy as np
import numpy_model as nm
import pytest
from test_solver_fast import _solve_with_cancel

from toc_ros.core import fast_solver, fast_tuning, homotopy, ip_run, ipm, Problem, solve, \
    SolverOptions, start_points, Status, warm_up, workers
from toc_ros.core.models import load_model
from toc_ros.core.obstacles import segment_clearance
from toc_ros.core.prefetch import Prefetch

pytestmark = pytest.mark.slow

HAVE_CASADI = importlib.util.find_spec('casadi') is not None
GAP = 1e-3              # 0.1 %
TOL = 1e-6              # the SOLVED tolerances (terminal error, clearance)

# (x0, x_goal, circles, best IPOPT t_f of the benchmark run in benchmarks/RESULTS.md).
RANDOM = {
    14: ((2.96371552435794, 0.0, 1.111122200647496, 0.0),
         (5.04598342070355, 0.0, 0.9163852766285077, 0.0),
         ((-0.6803887848962021, -1.337373679824137, 0.09695843787011853),
          (-0.7256054590257625, -0.8240268995890693, 0.10919318546029319)), 2.41810),
    20: ((-0.7219685627535797, -0.3282229849181655, 1.1190599770583576, -0.19127626426140792),
         (0.9621554594031496, 0.06228331035746315, 0.6886332301755282, 0.0),
         ((0.7975872278731166, -0.22188219768891881, 0.26325933212145247),
          (1.3732255951946963, -0.4018614372489332, 0.18746968607847325),
          (1.4618824169988551, 0.3602668628273199, 0.28621549162037296)), 2.73409),
}

# planar_2r: q = (0, 0.3) -> (1.6, 0.3) at rest, circle A of bench_planar_2r.py; the best
# IPOPT t_f of that benchmark (same start, or from fast mode's solution), before this change.
CIRCLE_A = (1.50 * math.cos(0.35), 1.50 * math.sin(0.35), 0.12)
CIRCLE_B = (1.45 * math.cos(1.30), 1.45 * math.sin(1.30), 0.12)
PLANAR = {'g0': (0.0, 0.643441), 'g9.81': (9.81, 0.758213)}


@pytest.fixture(scope='module', autouse=True)
def _compiled():
    warm_up()
    warm_up([load_model('planar_2r'), load_model('planar_2r', g=9.81)])


def _reference_t_f(problem):
    from benchmarks import reference_ipopt as module
    res = module.solve_reference(problem.x0, problem.x_goal, problem.obstacles, problem.margin,
                                 N=problem.n_intervals, integrator=problem.integrator,
                                 model_variant=problem.model.params.model_variant,
                                 u_max=tuple(problem.model.u_max))
    assert res['success'], res['attempts']
    return res['t_f']


@pytest.mark.parametrize('index', sorted(RANDOM))
def test_former_stalled_random_scenario_is_solved_at_the_ipopt_optimum(index):
    x0, goal, circles, recorded = RANDOM[index]
    problem = Problem(x0=x0, x_goal=goal, obstacles=circles, n_intervals=300)
    result = solve(problem, SolverOptions(mode='fast'))
    assert result.status is Status.SOLVED, result.message
    measured = nm.assert_feasible(problem, result, tol=TOL)
    assert measured['min_clearance'] < 1e-3, 'expected an obstacle to be active'
    t_ref = _reference_t_f(problem) if HAVE_CASADI else recorded
    assert result.final_time <= (1.0 + GAP) * t_ref, (result.final_time, t_ref)


def _planar_rhs(x, u, prm):
    """dx/dt of the planar 2R arm: M(q) ddq + C(q, dq) dq + G(q) = u, rods and a payload."""
    l1, l2, m1, m2, mp, g = prm
    a = (m1 / 3.0 + m2 + mp) * l1 * l1
    b = (m2 / 3.0 + mp) * l2 * l2
    c = (0.5 * m2 + mp) * l1 * l2
    q1, dq1, q2, dq2 = x
    mass = np.array([[a + b + 2.0 * c * math.cos(q2), b + c * math.cos(q2)],
                     [b + c * math.cos(q2), b]])
    coriolis = c * math.sin(q2) * np.array([-(2.0 * dq1 * dq2 + dq2 * dq2), dq1 * dq1])
    gravity = g * np.array([(0.5 * m1 + m2 + mp) * l1 * math.cos(q1)
                            + (0.5 * m2 + mp) * l2 * math.cos(q1 + q2),
                            (0.5 * m2 + mp) * l2 * math.cos(q1 + q2)])
    ddq = np.linalg.solve(mass, np.asarray(u) - coriolis - gravity)
    return np.array([dq1, ddq[0], dq2, ddq[1]])


def _planar_problem(g):
    model = load_model('planar_2r', g=g)
    return Problem(model=model, x0=tuple(float(v) for v in model.state(np.array([0.0, 0.3]))),
                   x_goal=tuple(float(v) for v in model.state(np.array([1.6, 0.3]))),
                   obstacles=(CIRCLE_A,), n_intervals=1000)


def _assert_planar_feasible(problem, result):
    """Re-integrate (Euler, numpy) and check bounds, the goal and both links' clearance."""
    model = problem.robot_model
    controls = np.asarray(result.controls)
    n = problem.n_intervals
    assert controls.shape == (n, 2)
    assert np.all(np.abs(controls) <= np.asarray(model.u_max)[None, :])
    prm = model.params
    prm = (prm.l1, prm.l2, prm.m1, prm.m2, prm.m_p, prm.g)
    tau = result.final_time / n
    states = np.empty((n + 1, 4))
    states[0] = problem.x0
    for i in range(n):
        states[i + 1] = states[i] + tau * _planar_rhs(states[i], controls[i], prm)
    assert np.linalg.norm(states[-1] - np.asarray(problem.x_goal)) <= TOL
    np.testing.assert_allclose(result.states, states, rtol=0, atol=1e-9)
    # Both links, every node 1..N, outside every inflated circle.
    circles = np.array(problem.obstacles, dtype=float).reshape(-1, 3)
    circles[:, 2] += problem.margin
    segments = nm.chain_segments(states[1:, 0::2], prm[:2])
    assert np.min(nm.segment_clearance(segments, circles)) >= -TOL


@pytest.mark.parametrize('name', sorted(PLANAR))
def test_planar_2r_active_circle_is_solved_feasible_for_both_links(name):
    g, best_ipopt = PLANAR[name]
    problem = _planar_problem(g)
    result = solve(problem, SolverOptions(mode='fast'))
    assert result.status is Status.SOLVED, result.message
    _assert_planar_feasible(problem, result)
    assert result.final_time <= (1.0 + GAP) * best_ipopt, (result.final_time, best_ipopt)


def _bench_problem(circles, g, moving):
    model = load_model('planar_2r', g=g)
    x0 = model.state(np.array([0.0, 0.3]), np.array([0.8, -0.5]) if moving else None)
    return Problem(model=model, x0=tuple(float(v) for v in x0),
                   x_goal=tuple(float(v) for v in model.state(np.array([1.6, 0.3]))),
                   obstacles=circles, n_intervals=1000)


# The five scenarios of bench_planar_2r.py that the further cold attempts from the straight
# start solved in 1046-1486 iterations (328-1180 ms), two of them in poorer local optima
# (0.817221 s and 0.854373 s), before the class starts of homotopy.py: (circles, g, moving
# start, best known t_f (checked by IPOPT started from it, benchmarks/RESULTS.md)).
CLASS_CASES = {
    '2 circles, g = 0': ((CIRCLE_A, CIRCLE_B), 0.0, False, 0.639760),
    '2 circles, g = 0, moving start': ((CIRCLE_A, CIRCLE_B), 0.0, True, 0.612745),
    '1 circle, g = 9.81': ((CIRCLE_A,), 9.81, False, 0.758211),
    '2 circles, g = 9.81': ((CIRCLE_A, CIRCLE_B), 9.81, False, 0.758211),
    '2 circles, g = 9.81, moving start': ((CIRCLE_A, CIRCLE_B), 9.81, True, 0.704656),
}


@pytest.mark.parametrize('name', sorted(CLASS_CASES))
def test_class_starts_reach_the_best_known_optimum_in_few_iterations(name):
    circles, g, moving, best = CLASS_CASES[name]
    problem = _bench_problem(circles, g, moving)
    result = solve(problem, SolverOptions(mode='fast'))
    assert result.status is Status.SOLVED, result.message
    _assert_planar_feasible(problem, result)
    assert result.final_time <= (1.0 + GAP) * best, (result.final_time, best)
    assert result.iterations <= 600, result.iterations


@pytest.mark.parametrize('limit', [3, 40, 200])
def test_class_starts_keep_the_iteration_limit(limit):
    problem = _bench_problem((CIRCLE_A, CIRCLE_B), 0.0, False)
    result = solve(problem, SolverOptions(mode='fast', max_iterations=limit))
    assert result.iterations <= limit, (result.iterations, limit)
    assert result.status in (Status.SOLVED, Status.MAX_ITERATIONS, Status.STALLED), result.status


def _winding(loop, point):
    """Winding number of the closed polygon loop (M, 2) around point (2,)."""
    d = loop - point
    angle = np.arctan2(d[:, 1], d[:, 0])
    step = np.diff(np.concatenate([angle, angle[:1]]))
    return int(round(np.sum((step + np.pi) % (2.0 * np.pi) - np.pi) / (2.0 * np.pi)))


def test_class_starts_are_collision_free_and_pairwise_not_homotopic():
    problem = _bench_problem((CIRCLE_A, CIRCLE_B), 0.0, False)
    model = problem.robot_model
    l1, l2 = model.params.l1, model.params.l2
    paths = homotopy.class_paths(problem)
    assert len(paths) == 4
    radius = CIRCLE_A[2] + problem.margin
    for path in paths:
        assert np.allclose(path[0], [0.0, 0.3]) and np.allclose(path[-1], [1.6, 0.3])
        # Dense along the polyline: both links clear of both circles but for a fraction of
        # a grid cell (the grid's corners).
        s = np.linspace(0.0, 1.0, 20)[:, None]
        q = np.concatenate([(1.0 - s) * a + s * b for a, b in zip(path[:-1], path[1:])])
        circles = np.array([CIRCLE_A, CIRCLE_B])
        circles[:, 2] = radius
        gaps = nm.segment_clearance(nm.chain_segments(q, (l1, l2)), circles)
        assert np.min(gaps) >= -0.02
        states, _, _ = start_points.path_start(problem, path, 50)
        assert np.array_equal(states[0], problem.x0)
        assert np.array_equal(states[-1], problem.x_goal)
    # Configurations with the hand on a circle's centre (both elbow branches, and copies
    # shifted by 2 pi) lie inside the obstacles: a loop through two class paths that winds
    # around one of them cannot be contracted in the free space.
    inside = []
    for cx, cy, _ in (CIRCLE_A, CIRCLE_B):
        r = math.hypot(cx, cy)
        elbow_angle = math.acos((r * r - l1 * l1 - l2 * l2) / (2.0 * l1 * l2))
        for q2 in (elbow_angle, -elbow_angle):
            q1 = math.atan2(cy, cx) - math.atan2(l2 * math.sin(q2), l1 + l2 * math.cos(q2))
            inside += [(q1 + 2.0 * math.pi * i, q2 + 2.0 * math.pi * j)
                       for i in (-1, 0, 1) for j in (-1, 0, 1)]
    for i in range(len(paths)):
        for j in range(i + 1, len(paths)):
            loop = np.concatenate([paths[i], paths[j][::-1][1:-1]])
            assert any(_winding(loop, np.array(p)) != 0 for p in inside), (i, j)


@pytest.mark.parametrize('g', [0.0, 9.81])
def test_parallel_attempts_are_bit_identical_to_one_after_the_other(monkeypatch, g):
    # g = 9.81: two class starts end at the same coarse optimum (the first one's climb counts).
    problem = _bench_problem((CIRCLE_A, CIRCLE_B), g, False)
    prefetched = []
    run = Prefetch.run

    def counted(self):
        found, done = run(self)
        prefetched.append((len(done['climbs']), len(done['finals'])))
        return found, done

    monkeypatch.setattr(Prefetch, 'run', counted)
    results = []
    for count in (2, 1):
        monkeypatch.setattr(workers, 'WORKERS', count)
        results.append(solve(problem, SolverOptions(mode='fast')))
    # Two workers: the candidates' climbs and the best one's refinement to N ran in the
    # pipeline of the attempts; one worker: after them.
    assert len(prefetched) == 1 and prefetched[0][0] >= 1 and prefetched[0][1] == 1, prefetched
    first, second = results
    assert first.status is second.status is Status.SOLVED
    assert first.final_time == second.final_time and first.iterations == second.iterations
    assert np.array_equal(first.controls, second.controls)
    assert np.array_equal(first.history, second.history, equal_nan=True)


def test_further_cold_attempts_are_deterministic():
    problem = _planar_problem(9.81)
    first = solve(problem, SolverOptions(mode='fast'))
    second = solve(problem, SolverOptions(mode='fast'))
    assert first.status is second.status is Status.SOLVED
    assert first.final_time == second.final_time and first.iterations == second.iterations
    assert np.array_equal(first.controls, second.controls)
    assert np.array_equal(first.history, second.history, equal_nan=True)


def test_compiled_clearance_has_the_bits_of_the_numpy_oracle():
    rng = np.random.default_rng(3)
    seg = rng.normal(size=(500, 2, 4))
    seg[::7, 1, 2:] = seg[::7, 1, :2]                 # zero-length segments
    seg[1::7, 0, :] = [0.0, 0.0, 1.0, 0.0]            # projections at an end and beyond
    circles = np.array([[0.0, 1.0, 0.3], [1.5, 0.0, 0.2], [-0.5, 0.0, 0.1]])
    circles = np.concatenate([circles, np.column_stack([rng.normal(size=(3, 2)),
                                                        rng.uniform(0.05, 0.5, 3)])])
    for squared in (False, True):
        assert np.array_equal(segment_clearance(seg, circles, squared),
                              nm.segment_clearance(seg, circles, squared=squared))
    # Leading dimensions and a non-finite segment end are kept as the oracle keeps them.
    seg[5, 1, 2] = np.nan
    assert np.array_equal(segment_clearance(seg.reshape(50, 10, 2, 4), circles),
                          nm.segment_clearance(seg.reshape(50, 10, 2, 4), circles),
                          equal_nan=True)


def test_class_search_stops_with_the_goal_states_of_the_full_search(monkeypatch):
    problem = _bench_problem((CIRCLE_A, CIRCLE_B), 0.0, False)
    calls = []
    search = homotopy.class_search
    monkeypatch.setattr(homotopy, 'class_search', lambda *a: calls.append(a) or search(*a))
    assert len(homotopy.class_paths(problem)) == 4
    args = calls[0]
    early_dist, early_parent = search(*args)
    full_dist, full_parent = search(*args[:-2], 1 << 30, np.inf)
    free, goal = args[0], args[2]
    s_count = 1 << len(args[3])
    base = (goal[0] * free.shape[1] + goal[1]) * s_count
    kept = [state for state in range(base, base + s_count) if np.isfinite(early_dist[state])]
    assert len(kept) == 4
    for state in kept:
        assert early_dist[state] == full_dist[state]
        while state >= 0:           # the same path back to the start
            assert early_parent[state] == full_parent[state]
            state = early_parent[state]
    # It did stop early: states the full search reached are left out.
    assert np.count_nonzero(np.isfinite(early_dist)) < np.count_nonzero(np.isfinite(full_dist))


def _coarse(t_f):
    return SimpleNamespace(t_f=t_f, n=fast_solver.EXPLORE_INTERVALS)


def _candidates(found):
    solver = SimpleNamespace(done=0, limit=2000)
    return fast_solver.FastSolve._candidates(solver, found)


def test_candidates_are_the_distinct_optima_in_the_band_and_the_first_attempt_of_equal_ones():
    band = fast_tuning.REFINE_BAND * fast_tuning.COARSE_INTERVALS / fast_solver.EXPLORE_INTERVALS
    a, b, c = _coarse(0.70), _coarse(0.70 * (1.0 + 0.5 * band)), _coarse(0.70 * (1.0 + 2 * band))
    same = _coarse(0.70 * (1.0 - 1e-7))      # the same optimum as a, slightly shorter
    assert _candidates([c, b, a]) == [a, b]
    assert _candidates([a, same, b]) == [a, b]      # a's attempt came first
    assert _candidates([same, a, b]) == [same, b]
    many = [_coarse(0.70 * (1.0 + 0.01 * band * k)) for k in range(5)]
    assert _candidates(many[::-1]) == many[:fast_tuning.MAX_REFINE]


def test_prefetch_cancels_the_climbs_and_refinements_of_displaced_candidates():
    solver = SimpleNamespace(done=0, limit=2000, _poller=lambda logs: None)
    solver._candidates = lambda found: fast_solver.FastSolve._candidates(solver, found)
    prefetch = Prefetch(solver, [None] * 5, None, None)
    slow, fast, again, other = _coarse(0.80), _coarse(0.70), _coarse(0.70), _coarse(0.71)
    prefetch._finished(('attempt', 2), (again, ipm.CONVERGED))
    prefetch._finished(('attempt', 0), (slow, ipm.CONVERGED))
    prefetch.climbs = {0: [[], None, True], 2: [[], None, True]}
    prefetch._finished(('attempt', 3), (other, ipm.CONVERGED))
    # 0.80 is out of the band of 0.70 (attempt 2): its climb is cancelled, attempt 2's is not.
    assert prefetch.climbs[0][2] is False and prefetch.climbs[2][2] is True
    prefetch._finished(('attempt', 1), (fast, ipm.CONVERGED))
    # Attempt 1 ends at attempt 2's optimum and stands for it: attempt 2's climb is cancelled.
    assert prefetch.climbs[2][2] is False
    assert prefetch._candidates() == [fast, other]
    # The refinement to N goes to the shortest climbed candidate so far (not the shortest
    # coarse one), and is cancelled when a shorter climb or a later attempt puts it out.
    prefetch.climbs[1] = [[], None, True]
    prefetch.climbs[3] = [[], None, True]
    first = SimpleNamespace(t_f=0.65)
    prefetch._finished(('climb', 1), (first, ipm.CONVERGED))
    assert prefetch._best_climbed() is first         # attempt 3's climb still runs
    prefetch.finals[id(first)] = [[], None, True]
    best = SimpleNamespace(t_f=0.64)
    prefetch._finished(('climb', 3), (best, ipm.CONVERGED))
    assert prefetch._best_climbed() is best and prefetch.finals[id(first)][2] is False
    prefetch.finals[id(best)] = [[], None, True]
    prefetch._finished(('attempt', 4), (_coarse(0.60), ipm.CONVERGED))
    assert prefetch._best_climbed() is None and prefetch.finals[id(best)][2] is False


@pytest.mark.parametrize('delay', [0.02, 0.08])
def test_a_cancel_during_the_class_attempts_and_climbs_is_honoured(delay):
    # N = 20000: the attempts take ~10 ms, the climbs to 6034 intervals a few hundred ms.
    problem = replace(_bench_problem((CIRCLE_A, CIRCLE_B), 0.0, False), n_intervals=20000)
    result, seconds = _solve_with_cancel(problem, SolverOptions(mode='fast'), delay)
    assert result.status is Status.CANCELED, result.message
    assert seconds <= 0.1


def _attempt_runs(monkeypatch, one_worker=True):
    """
    Record every interior-point run started by the solves that follow.

    one_worker: with two workers a prefetched climb that a later result cancels may or may
    not have started (timing); the result is the same, the started runs are not.
    """
    if one_worker:
        monkeypatch.setattr(workers, 'WORKERS', 1)
    runs = []
    start = ip_run.InteriorPointRun.start

    def recorded(self, *args, **kwargs):
        runs.append(self)
        return start(self, *args, **kwargs)

    monkeypatch.setattr(ip_run.InteriorPointRun, 'start', recorded)
    return runs


def test_lazy_circles_solve_the_classes_of_the_circle_in_the_way_only(monkeypatch):
    # '2 circles, g = 9.81': the optimum without circles hits circle A only, and the optima of
    # A's two classes are clear of B: no class search with both circles, 3 attempts not 4.
    problem = _bench_problem((CIRCLE_A, CIRCLE_B), 9.81, False)
    runs = _attempt_runs(monkeypatch)
    searched = []
    classes = homotopy.classes
    monkeypatch.setattr(homotopy, 'classes', lambda problem, *a: searched.append(
        problem.obstacles) or classes(problem, *a))
    result = solve(problem, SolverOptions(mode='fast'))
    assert result.status is Status.SOLVED, result.message
    _assert_planar_feasible(problem, result)
    assert abs(result.final_time - CLASS_CASES['2 circles, g = 9.81'][3]) <= 1e-6
    coarse = [run.kept for run in runs if run.n == fast_solver.EXPLORE_INTERVALS]
    assert coarse == [(), (0,), (0,)], coarse
    # The class search ran on the relaxation with circle A only, never with both circles.
    assert searched == [(CIRCLE_A,)], searched
    # The climbs and the N grid without circles: the candidate stays 0.24 m clear of A (more
    # than NARROW_MARGIN), and the N grid's solution is clear of both.
    # (Runs started, with prefetches that a later attempt cancelled: a set.)
    assert {run.kept for run in runs if run.n > fast_solver.EXPLORE_INTERVALS} == {()}
    assert result.solver_state['duals']['z'].shape == (problem.n_intervals, 4)


def test_a_relaxed_climb_that_hits_a_dropped_circle_but_ranks_behind_a_clear_one_is_dropped(
        monkeypatch):
    # '2 circles, g = 0': A's two candidates climb without B; the 0.6363 s one touches B on
    # 368 intervals (0.6427 s there) but the clear one is shorter (0.6404 s): no climb again.
    problem = _bench_problem((CIRCLE_A, CIRCLE_B), 0.0, False)
    runs = _attempt_runs(monkeypatch)
    hits = []
    violated = fast_solver.FastSolve._violated
    monkeypatch.setattr(fast_solver.FastSolve, '_violated', lambda self, run: hits.append(
        (run.n, round(run.t_f, 4), bool(violated(self, run)))) or violated(self, run))
    result = solve(problem, SolverOptions(mode='fast'))
    assert result.status is Status.SOLVED, result.message
    _assert_planar_feasible(problem, result)
    assert abs(result.final_time - CLASS_CASES['2 circles, g = 0'][3]) <= 1e-6
    assert (368, 0.6427, True) in hits and (368, 0.6404, False) in hits, hits
    # The 0.6363 s candidate climbs with A, the 0.6477 s one (clear of A) without circles.
    assert {run.kept for run in runs if run.n > fast_solver.EXPLORE_INTERVALS} == {(0,), ()}


def _hit_on(monkeypatch, grid):
    """Make FastSolve._violated report circle B for the relaxed runs on grid intervals."""
    violated = fast_solver.FastSolve._violated
    monkeypatch.setattr(fast_solver.FastSolve, '_violated', lambda self, run: {1}
                        if run.n == grid and run.kept is not None and 1 not in run.kept
                        else violated(self, run))


@pytest.mark.parametrize('workers_count', [1, 2])
def test_a_relaxed_climb_that_hits_a_dropped_circle_is_done_again_with_all_circles(
        monkeypatch, workers_count):
    # '2 circles, g = 9.81' (A's optima are clear of B at every grid) with B reported hit on
    # the rank grid: the candidate climbs again from its coarse run with both circles.
    monkeypatch.setattr(workers, 'WORKERS', workers_count)
    problem = _bench_problem((CIRCLE_A, CIRCLE_B), 9.81, False)
    runs = _attempt_runs(monkeypatch, one_worker=False)
    _hit_on(monkeypatch, 368)
    result = solve(problem, SolverOptions(mode='fast'))
    assert result.status is Status.SOLVED, result.message
    _assert_planar_feasible(problem, result)
    assert abs(result.final_time - CLASS_CASES['2 circles, g = 9.81'][3]) <= 1e-6
    # Runs started (with cancelled prefetches): the relaxed climb, then both circles.
    climbs = [(run.n, run.kept) for run in runs if run.n > fast_solver.EXPLORE_INTERVALS]
    relaxed = [(n, kept) for n, kept in climbs
               if n < problem.n_intervals and kept is not None]
    assert (136, ()) in relaxed and (368, ()) in relaxed, climbs   # narrowed: no circle
    assert climbs[-3:] == [(136, None), (368, None), (problem.n_intervals, None)], climbs


def test_a_relaxed_solution_that_hits_a_dropped_circle_on_the_n_grid_is_refined_again(
        monkeypatch):
    # The same with B reported hit on the N grid: refined again from the climb, both circles.
    problem = _bench_problem((CIRCLE_A, CIRCLE_B), 9.81, False)
    runs = _attempt_runs(monkeypatch)
    _hit_on(monkeypatch, problem.n_intervals)
    result = solve(problem, SolverOptions(mode='fast'))
    assert result.status is Status.SOLVED, result.message
    _assert_planar_feasible(problem, result)
    assert abs(result.final_time - CLASS_CASES['2 circles, g = 9.81'][3]) <= 1e-6
    finals = [run.kept for run in runs if run.n == problem.n_intervals]
    assert finals[-1] is None and () in finals[:-1], finals


def test_a_relaxed_candidate_that_hits_a_dropped_circle_leads_to_the_bounded_classes(
        monkeypatch):
    # '2 circles, g = 0, moving start': A's best optimum passes through B; of the four classes
    # of both circles, the two inside A's other class (bounded by its optimum, 0.95 s, out of
    # the band of 0.61 s) are not solved.
    problem = _bench_problem((CIRCLE_A, CIRCLE_B), 0.0, True)
    runs = _attempt_runs(monkeypatch)
    result = solve(problem, SolverOptions(mode='fast'))
    assert result.status is Status.SOLVED, result.message
    _assert_planar_feasible(problem, result)
    assert abs(result.final_time - CLASS_CASES['2 circles, g = 0, moving start'][3]) <= 1e-6
    coarse = [run.kept for run in runs if run.n == fast_solver.EXPLORE_INTERVALS]
    assert coarse == [(), (0,), (0,), None, None], coarse
    assert len(homotopy.class_paths(problem)) == 4


def test_a_relaxed_candidate_that_hits_a_dropped_circle_starts_the_problem_warm(monkeypatch):
    # '2 circles, g = 0, moving start': the problem started from A's best optimum (0.6053 s,
    # through B) ends in the class of both circles next to it, at the class start's optimum
    # (0.6055 s): of the two classes inside A's best one only the other is attempted.  The
    # candidate stays 0.15 m clear of A: it climbs with B only.
    problem = _bench_problem((CIRCLE_A, CIRCLE_B), 0.0, True)
    runs = _attempt_runs(monkeypatch)
    attempted = []
    attempts = fast_solver.FastSolve._class_attempts
    monkeypatch.setattr(fast_solver.FastSolve, '_class_attempts', lambda self, paths, *a:
                        attempted.append(len(paths)) or attempts(self, paths, *a))
    result = solve(problem, SolverOptions(mode='fast'))
    assert result.status is Status.SOLVED, result.message
    _assert_planar_feasible(problem, result)
    assert abs(result.final_time - CLASS_CASES['2 circles, g = 0, moving start'][3]) <= 1e-6
    assert attempted == [2, 1], attempted             # A's two classes, then one of both
    warm = [run for run in runs if run.n == fast_solver.EXPLORE_INTERVALS][3]
    assert warm.kept is None and warm.path is not None
    assert abs(warm.t_f - 0.605497) <= 1e-6 and warm.iterations < 20
    assert {run.kept for run in runs if run.n > fast_solver.EXPLORE_INTERVALS} == {(1,)}
    assert result.solver_state['duals']['z'].shape == (problem.n_intervals, 4)


def test_duals_for_a_relaxation_select_its_circles_columns():
    # A run on circles (0, 2) of 3, 2 links, carried to the relaxation with circle 2 only.
    run = SimpleNamespace(kept=(0, 2), duals=lambda: {
        'z': np.array([[1.0, 2.0, 3.0, 4.0]]), 'lam': np.zeros((2, 4)), 'rho': 1.0})
    solver = SimpleNamespace(problem=SimpleNamespace(
        obstacles=(None,) * 3, robot_model=SimpleNamespace(n_links=2)))
    narrowed = fast_solver.FastSolve._duals(solver, run, (None, (2,)))
    assert np.array_equal(narrowed['z'], [[2.0, 4.0]])
    wide = fast_solver.FastSolve._duals(solver, run)
    assert np.array_equal(wide['z'], [[1.0, 0.0, 2.0, 3.0, 0.0, 4.0]])
    assert fast_solver.FastSolve._duals(solver, run, (None, (0, 2)))['z'].shape == (1, 4)


def test_bounded_classes_are_bit_identical_with_one_or_two_workers(monkeypatch):
    # Three prefetching pipelines (A's classes, then two parts of the classes of both).
    problem = _bench_problem((CIRCLE_A, CIRCLE_B), 0.0, True)
    results = []
    for count in (2, 1, 2):
        monkeypatch.setattr(workers, 'WORKERS', count)
        results.append(solve(problem, SolverOptions(mode='fast')))
    for other in results[1:]:
        assert other.status is results[0].status is Status.SOLVED
        assert other.final_time == results[0].final_time
        assert other.iterations == results[0].iterations
        assert np.array_equal(other.controls, results[0].controls)
        assert np.array_equal(other.history, results[0].history, equal_nan=True)


def test_widened_duals_put_each_kept_circle_in_its_column_and_zero_elsewhere():
    # Columns link * K + k (ipm_obstacles.py): 2 links, circles 1 and 3 of 4 kept.
    z = np.arange(12.0).reshape(3, 4) + 1.0            # (nodes, 2 links x 2 kept)
    duals = {'z': z, 'lam': np.ones((4, 4)), 'rho': 10.0}
    wide = start_points.widen_duals(duals, (1, 3), 4, 2)
    assert wide['z'].shape == (3, 8)
    assert np.array_equal(wide['z'][:, [1, 3, 5, 7]], z)
    assert not np.any(wide['z'][:, [0, 2, 4, 6]])
    assert wide['lam'] is duals['lam'] and wide['rho'] == 10.0


def test_same_class_tells_the_sides_of_a_hole_apart():
    feet = np.array([[0.0, 0.0]])
    below = np.array([[-1.0, 0.0], [-0.5, -1.0], [0.5, -1.0], [1.0, 0.0]])
    below_too = np.array([[-1.0, 0.0], [0.0, -2.0], [1.0, 0.0]])
    above = np.array([[-1.0, 0.0], [0.0, 1.0], [1.0, 0.0]])
    assert homotopy.same_class(below, below_too, feet)
    assert not homotopy.same_class(below, above, feet)
    assert homotopy.same_class(below, above, np.array([[0.0, 5.0]]))   # no hole between


def test_prefetch_climbs_no_candidate_while_one_hits_a_dropped_circle():
    solver = SimpleNamespace(done=0, limit=2000, _poller=lambda logs: None,
                             _bind=lambda task, *a, **k: task)
    solver._candidates = lambda found: fast_solver.FastSolve._candidates(solver, found)
    blocked = _coarse(0.71)
    prefetch = Prefetch(solver, ['attempt 0', 'attempt 1', 'attempt 2'], None, None,
                        lambda run: run is not blocked)
    prefetch.waiting = [2]
    prefetch._finished(('attempt', 0), (_coarse(0.70), ipm.CONVERGED))
    prefetch._finished(('attempt', 1), (blocked, ipm.CONVERGED))
    assert prefetch._next()[0] == ('attempt', 2)      # not the climb of attempt 0
    assert not prefetch.climbs


def test_an_actuated_model_starts_from_the_lazy_joint_solution_with_all_circles():
    # The joint solve of _cold_actuated takes the lazy path (circle A's classes); its duals
    # reach the actuated N grid widened to both circles.
    from toc_ros.core.models import with_actuator_lag
    joint = _bench_problem((CIRCLE_A, CIRCLE_B), 9.81, False)
    model = with_actuator_lag(joint.robot_model, 0.01)
    problem = joint.with_model(model)
    result = solve(problem, SolverOptions(mode='fast'))
    assert result.status is Status.SOLVED, result.message
    assert result.violations.feasible()
    assert abs(result.final_time - CLASS_CASES['2 circles, g = 9.81'][3]) <= 0.02 * 0.758211
    assert result.solver_state['duals']['z'].shape == (problem.n_intervals, 4)


def test_no_relaxation_is_solved_where_the_circles_make_no_hole(monkeypatch):
    # The cylindrical robot: its circles reach the joint grid's border (no classes), so two
    # circles take the attempts from the straight start as before, without a relaxed one.
    problem = Problem.paper(obstacles=((1.0, 1.0, 0.2), (0.5, -1.2, 0.3)))
    assert not homotopy.has_holes(problem) and homotopy.class_paths(problem) == []
    assert homotopy.has_holes(_bench_problem((CIRCLE_A, CIRCLE_B), 0.0, False))
    runs = _attempt_runs(monkeypatch)
    result = solve(problem, SolverOptions(mode='fast'))
    assert result.status is Status.SOLVED, result.message
    assert runs and all(run.kept is None for run in runs)


def test_fifty_circles_off_the_motion_keep_the_free_optimum():
    # Circles 2.6-3 m from the base never touch the paper robot's free motion; their 50,000
    # rows outweighed the objective at the first barrier parameter (STALLED at t_f 10.5 s after
    # 2000 iterations) until it was scaled to them (barrier_start.py).
    rng = np.random.default_rng(0)
    circles = []
    while len(circles) < 50:
        x, y = rng.uniform(-3.0, 3.0, 2)
        if 2.6 < math.hypot(x, y) < 3.0:
            circles.append((x, y, 0.05))
    free = solve(Problem.paper(obstacles=()))
    result = solve(Problem.paper(obstacles=tuple(circles)))
    assert result.status is Status.SOLVED, result.message
    assert result.final_time == pytest.approx(free.final_time, rel=1e-9)
    assert result.violations.min_clearance > 0.0
