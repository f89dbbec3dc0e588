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
The class starts of a cold solve: one attempt per homotopy class of the joint plane.

A mixin of fast_solver.FastSolve (it uses the strategy's _solve_on, _parallel, _candidates,
_climber, _rank_grid and _may_explore).  When the straight start crosses an obstacle of a
two-joint model, one start per class of homotopy.py is solved on EXPLORE_INTERVALS, side by
side (prefetch.Prefetch); with several circles lazily, first on relaxations without the
circles that are not in the way (_lazy_classes), whose results bound the problem's classes
(_bounded_classes).
"""

import dataclasses
import math

import numpy as np

from . import homotopy, ipm, workers
from .fast_tuning import CLASS_ATTEMPT, COARSE_INTERVALS, MAX_REFINE, MU_WARM, NARROW_MARGIN, \
    REFINE_BAND
from .obstacles import model_clearance
from .prefetch import Prefetch
from .start_points import interpolation_start, path_start, resample, resample_duals, \
    widen_duals


def relaxation(run):
    """Return (problem, kept) of a relaxation's run (_lazy_classes), None for the problem's."""
    return None if run.kept is None else (run.problem, run.kept)


class ClassStarts:
    """The class attempts and lazy circles of FastSolve (a mixin)."""

    def _crosses(self, states):
        """
        Return whether the interpolation start's states (coarse grid) cross an obstacle.

        Only then are the class starts of homotopy.py solved (a two-joint model): the side of
        each obstacle that start ends on is arbitrary, while a start already on one side of
        each keeps its iterates out of the obstacles (fewer, convex iterations).
        """
        model = self.problem.robot_model
        if not len(self.problem.obstacles) or model.n_joints != 2:
            return False
        return bool(np.min(model_clearance(model, states, self.problem.circles())) < 0.0)

    def _explore_classes(self, paths, explore, n, relaxed=None, budget=None, allowance=None,
                         warm=()):
        """
        Run the class attempts of paths (of relaxed, default the problem) on explore intervals.

        Returns (converged runs, prefetched, allowance) as _class_attempts, with the climbs'
        allowance; ([], None, None) when the iteration budget has no room for them.  budget
        and allowance: given when the classes are solved in parts (_bounded_classes).
        """
        if budget is None:
            budget, allowance = self._class_budget(len(paths))
        if budget < 1:
            return [], None, None
        found, prefetched = self._class_attempts(paths, explore, budget, n, allowance, relaxed,
                                                 warm)
        return found, prefetched, allowance

    def _class_budget(self, count):
        """Return (budget of each of count class attempts, the climbs' allowance)."""
        # Each limit // 8, all within the iteration limit.
        budget = min(self.limit // 8, (self.limit - self.done) // max(count, 1))
        # The candidates' climbs get a share fixed now, and limit // 4 is left for the N grid
        # (_refine), so that both can start before the last attempt ends (_class_attempts).
        return budget, max(1, (self.limit - self.done - count * budget
                               - self.limit // 4) // MAX_REFINE)

    def _bounded_classes(self, paths, feet, explore, n, bounds):
        """
        Run the class attempts of paths, skipping those a relaxation bounds out of the band.

        feet: of the problem's holes (homotopy.classes).  bounds (from _lazy_classes, or
        None): (feet of the relaxation's holes, its converged attempts).  An attempt that ended
        in its start's class (homotopy.same_class around the relaxation's holes) is, under the
        class starts' premise, the best of that class; the problem's classes inside it (more
        circles) end no shorter.  So the paths with the smallest such lower bounds (within the
        band; no bound: 0) are solved first, and the others only if their bound is within the
        band of the shortest found.  A relaxation's candidate that hits the circles it did not
        have starts the problem warm first (_warm_classes): a problem's class next to it,
        whose attempt is then not run.  Returns (found, prefetched, allowance) as
        _explore_classes; the same budget and allowance for both parts (the prefetched climbs
        must be _finish's).
        """
        if bounds is None:
            return self._explore_classes(paths, explore, n)
        relaxed_feet, relaxed_runs = bounds
        model = self.problem.robot_model
        solutions = [(model.positions(run.ws.x), run.t_f) for run in relaxed_runs
                     if homotopy.same_class(run.path, model.positions(run.ws.x), relaxed_feet)]
        low = [min([t for q, t in solutions if homotopy.same_class(path, q, relaxed_feet)],
                   default=0.0) for path in paths]
        band = 1.0 + REFINE_BAND * COARSE_INTERVALS / min(explore, COARSE_INTERVALS)
        order = [k for k in range(len(paths)) if low[k] <= band * min(low)]
        budget, allowance = self._class_budget(len(paths))
        if budget < 1:
            return [], None, None
        warm, covered = self._warm_classes(relaxed_runs, paths, feet, explore, budget)
        first = [k for k in order if k not in covered]
        found, prefetched, allowance = self._explore_classes(
            [paths[k] for k in first], explore, n, None, budget, allowance, warm)
        shortest = min([run.t_f for run in found], default=math.inf)
        rest = [k for k in range(len(paths)) if k not in order and k not in covered and
                low[k] <= band * shortest]
        if not rest or not self._may_explore():
            return found, prefetched, allowance
        more, later, _ = self._explore_classes([paths[k] for k in rest], explore, n, None,
                                               budget, allowance)
        merged = {key: {**(prefetched or {}).get(key, {}), **(later or {}).get(key, {})}
                  for key in ('climbs', 'finals')}
        return found + more, merged, allowance

    def _warm_classes(self, relaxed_runs, paths, feet, explore, budget):
        """
        Return (converged runs, indices of their classes in paths): the problem from hits.

        Each candidate of the relaxation (_candidates) that hits a circle it did not have
        starts the problem on explore intervals (its primal-dual point, the widened duals):
        its optimum grazes that circle, so the problem's optimum on the near side of it is
        close (planar_2r '2 circles, g = 0, moving start': 12 iterations instead of the class
        start's 41, the same optimum).  The class (homotopy.same_class around feet) a run ends
        in is covered by it.  Serial, before the class attempts: the same runs with one or two
        workers.
        """
        model = self.problem.robot_model
        found, covered = [], set()
        for source in self._candidates(relaxed_runs):
            if not self._violated(source) or not self._may_explore():
                continue
            duals = self._duals(source)
            run, code = self._solve_on(explore, source.ws.x, source.controls(), source.t_f,
                                       MU_WARM / explore, duals, budget=budget,
                                       elastic=duals['rho'])
            if code != ipm.CONVERGED:
                continue
            q = model.positions(run.ws.x)
            same = [k for k, path in enumerate(paths) if homotopy.same_class(path, q, feet)]
            run.path = paths[same[0]] if same else None
            covered.update(same[:1])
            found.append(run)
        return found, covered

    def _lazy_classes(self, explore, n):
        """
        Class attempts on the circles that matter only: (found, prefetched, allowance, bounds).

        Lazy constraints over the circles: a local optimum of a relaxation (some circles
        dropped) that is clear of the dropped ones is one of the problem.  And under the
        premise of the class starts (the attempt from each class start reaches its class's
        best optimum), the relaxation's best is no longer than the problem's best of the same
        classes, so when the relaxation's candidates (_candidates) are all clear of the dropped
        circles they are the problem's candidates: fewer classes solved (two-circle planar_2r:
        2 attempts instead of 4, where circle B is not in the way).  First without circles
        (one attempt from the interpolation start), then with the circles its candidates hit,
        and so on.  The candidates climb on the relaxation too (fewer constraints per node);
        _finish keeps its solutions only where they are clear of the dropped circles.
        found is [] (the caller solves the classes of all circles) when they hit every circle,
        an attempt does not converge, a relaxation has no class starts or the budget is spent;
        bounds: (feet of the last relaxation's holes, its converged attempts) for
        _bounded_classes, or None.
        """
        problem = self.problem
        kept = ()
        relaxed = (dataclasses.replace(problem, obstacles=()), kept)
        budget = max(1, min(self.limit // 8, self.limit - self.done))
        run, code = self._solve_on(explore, *interpolation_start(relaxed[0], explore),
                                   CLASS_ATTEMPT[1], budget=budget, elastic=CLASS_ATTEMPT[0],
                                   relaxed=relaxed)
        found = [run] if code == ipm.CONVERGED else []
        prefetched = allowance = bounds = None
        while found:
            hit = set()
            for run in self._candidates(found):
                hit.update(self._violated(run))
            if not hit:
                return found, prefetched, allowance, None
            kept = tuple(sorted(set(kept) | hit))
            if len(kept) == len(problem.obstacles) or not self._may_explore():
                break
            relaxed = (dataclasses.replace(
                problem, obstacles=tuple(problem.obstacles[k] for k in kept)), kept)
            paths, feet = homotopy.classes(relaxed[0])
            if not paths:
                return [], None, None, None
            found, prefetched, allowance = self._explore_classes(paths, explore, n, relaxed)
            bounds = (feet, found)
        return [], None, None, bounds

    def _violated(self, run):
        """Return the indices of the circles run did not have that its nodes hit (a set)."""
        if run.kept is None:
            return set()
        dropped = [k for k in range(len(self.problem.obstacles)) if k not in run.kept]
        hit = self._clearances(run, dropped) < 0.0
        return {dropped[r] for r in np.flatnonzero(hit)}

    def _clearances(self, run, indices):
        """Return the least clearance of run's nodes 1..N to each circle of indices (array)."""
        model = self.problem.robot_model
        clear = model_clearance(model, run.ws.x[1:], self.problem.circles()[list(indices)])
        return np.min(clear.reshape(-1, model.n_links, len(indices)), axis=(0, 1))

    def _duals(self, run, relaxed=None):
        """
        Return the multipliers of run for a run on relaxed (problem, kept), default the problem.

        A relaxed run's are widened (widen_duals), then the circles of kept selected.
        """
        duals = run.duals()
        if run.kept is not None:
            if relaxed is not None and tuple(relaxed[1]) == tuple(run.kept):
                return duals
            duals = widen_duals(duals, run.kept, len(self.problem.obstacles),
                                self.problem.robot_model.n_links)
        if relaxed is None:
            return duals
        n_circles, kept = len(self.problem.obstacles), relaxed[1]
        columns = [link * n_circles + k for link in range(self.problem.robot_model.n_links)
                   for k in kept]
        return dict(duals, z=duals['z'][:, columns])

    def _narrowed(self, run):
        """
        Return the (problem, kept) run's candidate climbs on (None: the problem).

        Its own relaxation (relaxation), without the circles it stays NARROW_MARGIN clear of
        at every node in a lazy solve (self.narrow): their constraints are inactive there and
        likely on the finer grids, where a climb that hits them is redone with all circles
        (_clear_climbs, _complete).
        """
        relaxed = relaxation(run)
        if not self.narrow:
            return relaxed
        obstacles = self.problem.obstacles
        have = range(len(obstacles)) if run.kept is None else run.kept
        if not len(have):
            return relaxed
        kept = tuple(k for k, c in zip(have, self._clearances(run, have)) if c < NARROW_MARGIN)
        if len(kept) == len(have):
            return relaxed
        return dataclasses.replace(self.problem, obstacles=tuple(obstacles[k] for k in kept)), \
            kept

    def _class_attempts(self, paths, explore, budget, n, allowance, relaxed=None, warm=()):
        """
        Solve the class starts on explore intervals; return (converged runs, prefetched).

        The attempts (CLASS_ATTEMPT, budget each) run two at a time.  With two workers and an
        Euler ladder, a converged attempt that is a candidate among those converged so far
        (_candidates) starts its climb at once, ahead of the attempts still waiting, and the
        best climbed one its refinement to N (Prefetch): the chain to the N grid then overlaps
        the other attempts instead of following them.  These are _finish's climb and _refine's
        solve, with the same allowance and budget, so their results are the ones _finish would
        get (a prefetch); one that later results put out is cancelled.  Only the attempts' runs
        are recorded here (in task order), the climbs and the refinement by _finish.
        relaxed: (problem, kept) of a relaxation (_lazy_classes) the attempts are solved on;
        its candidates climb on the problem, and only while all are clear of the other circles.
        """
        rho, mu = CLASS_ATTEMPT
        problem = self.problem

        def attempt(solve, path, point=None):
            # The start is built on the worker: its numpy overlaps the other's kernel.
            point = point or path_start(problem, path, explore)
            run, code = solve(explore, *point, mu, None, budget, rho, relaxed)
            run.path = path                 # its class (_bounded_classes)
            return run, code

        # The first one here, before a helper thread starts building its own (the GIL).
        first = path_start(problem, paths[0], explore) if paths else None
        # warm: converged runs already (_warm_classes), first in task order.
        tasks = [lambda solve, run=run: (run, ipm.CONVERGED) for run in warm] + \
            [lambda solve, path=path, point=point: attempt(solve, path, point)
             for path, point in zip(paths, [first] + [None] * (len(paths) - 1))]
        rank = self._rank_grid(explore, n, MAX_REFINE)
        if workers.WORKERS < 2 or problem.integrator != 'euler' or rank == n:
            return [run for run, code in self._parallel(tasks) if code == ipm.CONVERGED], {}

        def refine(solve, run):
            # _refine's solve on a worker (the budget is limit // 4 there too: see _cold).
            states, controls = resample(run.ws.x, run.controls(), n)
            duals = resample_duals(run.duals(), run.n, n)
            return solve(n, states, controls, run.t_f, MU_WARM / n, duals,
                         max(1, self.limit // 4), duals['rho'], relaxation(run))

        return Prefetch(self, tasks, self._climber(rank, allowance), refine,
                        lambda run: not self._violated(run)).run()
