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
Refinement of a cold solve's coarse optima on the N grid (fast_solver.FastSolve's mixin).

The distinct converged coarse runs within REFINE_BAND of the shortest (at most MAX_REFINE) are
the candidates; each climbs the ladder of intermediate grids (start_points.ladder) with its
primal-dual solution resampled, side by side on the solve's threads (run_execution.py), and
the shortest converged one is carried to N.  A relaxation's run (class_starts.py, lazy
circles) climbs on its relaxation and is re-solved with every circle when it hits one.
"""

import math

from . import ipm
from .class_starts import relaxation
from .fast_tuning import COARSE_INTERVALS, MAX_REFINE, MU_WARM, REFINE_BAND, REFINE_SHARE
from .start_points import ladder, resample, resample_duals


def _in_band(run, shortest):
    """Return whether a converged coarse run is within REFINE_BAND of the shortest t_f."""
    # The band scales with the discretisation error, ~ 1 / intervals.
    band = REFINE_BAND * COARSE_INTERVALS / min(run.n, COARSE_INTERVALS)
    return run.t_f <= (1.0 + band) * shortest


def same_optimum(run, other):
    """Return whether two converged runs end at the same t_f (within 1e-6, relative)."""
    return abs(run.t_f - other.t_f) <= 1e-6 * other.t_f


class Refinement:
    """The refinement steps of FastSolve (uses RunExecution's and ClassStarts' methods)."""

    def _finish(self, found, n, allowance=None, prefetched=None):
        """
        Refine the distinct coarse optima close to the best one; set self.best.

        The coarse grid's ranking of nearby optima is not the N grid's, so the distinct
        converged ones within REFINE_BAND of the shortest (at most MAX_REFINE) are carried up.
        Through the intermediate grids of ladder() when there are any (each step a few cheap
        iterations, fewer in all than one jump to N): every candidate to the last intermediate
        grid, then the shortest converged there to N (the next one if it fails).  Without
        intermediate grids each candidate goes to N and the shortest converged one is kept.
        The candidates climb the ladder side by side (_parallel), each within allowance
        iterations (default: an equal share of the iterations left); prefetched: climbs and a
        refinement to N already run (Prefetch.run), with the same allowance and budget.
        """
        candidates = self._candidates(found)
        if not candidates:
            return
        rank = self._rank_grid(min(run.n for run in candidates), n, len(candidates))
        if rank == n:
            for coarse in candidates:
                if self.done >= self.limit:
                    break
                run, code = self._complete(self._refine(coarse, n), coarse, n)
                if code == ipm.CONVERGED and (self.best is None or run.t_f < self.best.t_f):
                    self.best = run
            return
        # The candidates side by side (_parallel), each up its own ladder within its share.
        left = self.limit - self.done
        if left < 1:
            return
        candidates = candidates[:left]
        climb = self._climber(rank, allowance or left // len(candidates))
        climbs = (prefetched or {}).get('climbs', {})
        finals = (prefetched or {}).get('finals', {})
        climbed = self._parallel(
            [lambda solve, run=run: climb(solve, run) for run in candidates],
            {k: climbs[id(run)] for k, run in enumerate(candidates) if id(run) in climbs})
        ranked = self._clear_climbs(climbed, candidates, climb)
        for source in sorted(ranked, key=lambda r: r.t_f) + candidates:
            if self.done >= self.limit:
                break
            if id(source) in finals:           # its refinement to N, run already
                (run, code), runs = finals.pop(id(source))
                for done in runs:
                    self._record(done)
                    self.run = done
            else:
                run, code = self._refine(source, n)
            run, code = self._complete((run, code), source, n)
            if code == ipm.CONVERGED:
                self.best = run
                return

    def _refine_others(self, found, n):
        """
        After _finish refined no candidate on the N grid: the other coarse optima, shortest first.

        A coarse optimum of a fast whip can be an artefact of the coarse grid's discretisation
        error, whose refinement wanders without converging (a three-link arm under gravity: the
        coarse 0.597 s, 500 iterations on 300 intervals, IPOPT's best there 0.650 s); the next
        distinct ones (outside the band of the shortest) are then refined one by one, within
        the budget left, until one converges (sets self.best).
        """
        tried = self._candidates(found)
        for coarse in sorted(found, key=lambda run: run.t_f):      # stable: attempt order
            if self.best is not None or self.done >= self.limit:
                return
            if any(same_optimum(coarse, other) for other in tried):
                continue
            tried.append(coarse)
            run, code = self._complete(self._refine(coarse, n), coarse, n)
            if code == ipm.CONVERGED:
                self.best = run

    def _clear_climbs(self, climbed, candidates, climb):
        """
        Return the converged climbs of candidates whose solutions are the problem's.

        climbed: (run, code) per candidate.  A relaxation's climb (_lazy_classes) clear of the
        dropped circles is a local optimum of the problem; one that hits them bounds its
        candidate's climb with all circles from below (under the class starts' premise), so
        that climb is done (from the clear coarse candidate) only when the bound is shorter
        than the shortest clear climb.
        """
        hit = {k for k, (run, code) in enumerate(climbed)
               if code == ipm.CONVERGED and self._violated(run)}
        shortest = min([run.t_f for k, (run, code) in enumerate(climbed)
                        if code == ipm.CONVERGED and k not in hit], default=math.inf)
        redo = [k for k in sorted(hit) if climbed[k][0].t_f < shortest]
        again = self._parallel([lambda solve, run=candidates[k]: climb(solve, run, True)
                                for k in redo])
        climbed = list(climbed)
        for k, value in zip(redo, again):
            climbed[k] = value
        return [run for k, (run, code) in enumerate(climbed)
                if code == ipm.CONVERGED and (k not in hit or k in redo)]

    def _candidates(self, found):
        """
        Return the distinct runs of found (in attempt order) within the band of the shortest.

        Shortest first, at most MAX_REFINE.  Of runs that end at the same t_f (within 1e-6: the
        same optimum reached from two starts) the first attempt's stands for them: it usually
        converges first, so its climb may have started already (_class_attempts).
        """
        order = sorted(range(len(found)), key=lambda k: found[k].t_f)   # stable
        chosen = []
        for k in order:
            if self.done >= self.limit or len(chosen) >= MAX_REFINE:
                break
            if not _in_band(found[k], found[order[0]].t_f):
                continue
            same = [i for i, c in enumerate(chosen) if same_optimum(found[k], found[c])]
            if not same:
                chosen.append(k)
            elif k < chosen[same[0]]:
                chosen[same[0]] = k
        return [found[k] for k in chosen]

    def _rank_grid(self, coarse, n, count):
        """
        Return the grid count candidates from coarse intervals are ranked on.

        The last grid of the ladder from coarse to N (N if none): from the class attempts' 50
        intervals 136, 368 (the last step to N 2.7, 15-20 iterations there on planar_2r; via
        126 and 316 it was 17-25).  Never coarser than from COARSE_INTERVALS: nearby optima
        swap places on coarse grids (planar_2r: on 126 intervals, not on 316).  An RK4 coarse
        solution is already close to the N grid's (error O(tau^4), not O(tau)): there the
        intermediate grid saves no N-grid iterations (paper scenario: 17 there after 25 on
        316, 19 straight), so a single candidate goes straight to N.
        """
        if self.problem.integrator != 'euler' and count == 1:
            return n
        return max((ladder(coarse, n) or [n])[-1], (ladder(COARSE_INTERVALS, n) or [n])[-1])

    def _climber(self, rank, allowance):
        """
        Return climb(solve, run, full=False): run's solution up the ladder to rank.

        Within allowance iterations; a relaxation's run (_lazy_classes) climbs on its
        relaxation, or with full on the problem.
        """
        def climb(solve, run, full=False):
            used, code = 0, ipm.CONVERGED
            relaxed = None if full else self._narrowed(run)
            for m in ladder(run.n, rank) + [rank]:
                if used >= allowance:
                    return run, ipm.ITERATION_LIMIT
                states, controls = resample(run.ws.x, run.controls(), m)
                duals = resample_duals(self._duals(run, relaxed), run.n, m)
                run, code = solve(m, states, controls, run.t_f, MU_WARM / m, duals,
                                  min(self.limit // 4, allowance - used), duals['rho'],
                                  relaxed)
                used += run.iterations
                if code != ipm.CONVERGED:
                    break
            return run, code
        return climb

    def _refine(self, run, n, full=False):
        """
        Carry a converged run's primal-dual solution to n intervals and solve there.

        A relaxation's run (_lazy_classes) on its relaxation, or with full on the problem.
        """
        relaxed = None if full else relaxation(run)
        states, controls = resample(run.ws.x, run.controls(), n)
        duals = resample_duals(run.duals() if relaxed else self._duals(run), run.n, n)
        return self._solve_on(n, states, controls, run.t_f, MU_WARM / n, duals,
                              budget=max(1, int(REFINE_SHARE * self.limit)),
                              elastic=duals['rho'], relaxed=relaxed)

    def _complete(self, refined, source, n):
        """
        Return refined (run, code) on the N grid, solved on the problem if need be.

        A relaxation's run (_lazy_classes) clear of the circles it does not have at every
        node is a local optimum of the problem too (those constraints inactive, multipliers
        0); one that hits them is refined again from source (clear of them, _finish) with
        all circles.
        """
        run, code = refined
        if code != ipm.CONVERGED or not self._violated(run):
            return run, code
        return self._refine(source, n, full=True)
