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
Tuning of the fast mode's strategy: grids, barrier parameters, attempts and bands.

Read by fast_solver.py, refinement.py and class_starts.py; the interior-point run's own
tolerances are ip_run.py's.
"""

from .ip_run import ELASTIC_WEIGHT

# Grids: a cold solve on N > 2 COARSE_INTERVALS starts on COARSE_INTERVALS intervals.
COARSE_INTERVALS = 100
# Barrier parameter of the first cold attempt (IPOPT's default 0.1 led into poorer local optima
# more often: planar_2r with circles, the demo scenario), and of a warm start on N intervals:
# MU_WARM / N, since the bound multipliers of the discrete problem scale with tau = t_f / N.
MU_COLD = 0.01
# Further cold starts of the N grid after a failure, with these barrier parameters.
MU_COLD_RETRIES = (0.01, 1.0)
MU_WARM = 1e-5
# ... and of a warm start whose first state the robot has drifted from (a replan cycle):
# MU_DRIFT / N, re-centred more than a refinement's.  Over 38 perturbed cycle starts of the
# paper scenario (150 intervals) 1e-4 needed no cold fallback where 1e-5 needed 2-9, and on
# the actuated model 26 instead of 35 iterations (median).
MU_DRIFT = 1e-4
# A warm start keeps the controls of the guess on their bounds (within WARM_PUSH).
WARM_PUSH = 1e-6
# A warm start whose first state lies within WARM_EXACT of the start uses MU_EXACT.
WARM_EXACT = 1e-6
MU_EXACT = 1e-10
# Iterations a warm start may take before fast mode solves from scratch instead.
WARM_BUDGET = 60
# Cold-start attempts (elastic weight, initial barrier parameter), all from the same cold
# start: the first always; the others when the problem has obstacles and the first did not
# converge on the coarse grid or needed the inertia correction on more than EXPLORE_NONCONVEX
# of its iterations there (other weights and barrier parameters lead around the obstacles
# other ways, into other local optima; see FastSolve._explore).
COLD_ATTEMPTS = ((ELASTIC_WEIGHT, MU_COLD), (0.3, 1.0), (1.0, 0.1), (10.0, 0.01), (0.1, 0.1),
                 (1.0, 1e-3), (100.0, 1.0), (0.03, 0.1))
EXPLORE_NONCONVEX = 20
# (Elastic weight, initial barrier parameter) of the attempt from each class start of
# homotopy.py (near collision-free starts, one per homotopy class of a two-joint configuration
# space), tried instead of the interpolation start when that crosses an obstacle.  The first
# cold attempt's pair: on the 12 planar_2r scenarios of bench_planar_2r.py it reached the best
# known optimum from some class start in every one (so did mu0 = 1.0, at more iterations).
CLASS_ATTEMPT = (ELASTIC_WEIGHT, MU_COLD)
# Fraction of a solve's timeout after which no further cold attempt starts.
EXPLORE_TIME = 0.25
# Converged coarse optima within REFINE_BAND of the shortest (scaled by COARSE_INTERVALS / their
# grid: the discretisation error ~ 1 / intervals) are refined (at most MAX_REFINE distinct
# ones); the shortest refined one is the result (_finish).
REFINE_BAND = 0.02
MAX_REFINE = 3
# A refinement on the N grid (a warm start from a coarser grid's optimum and multipliers) may
# take this share of the iteration limit.  One that needs more is leaving its basin: a fast
# whip's coarse optimum can be an artefact of the coarse grid (a three-link arm under gravity:
# 0.597 s on 100 intervals, no optimum near it on 300); the budget then goes to the next
# candidate (refinement._refine_others).  Of 291 refinements on 160 random free three-link
# moves the 289 that converged took at most 261 iterations; 2R and the paper's robot <= 21.
REFINE_SHARE = 0.15
# Grid of the cold attempts from the class starts (when the coarse grid is not the N grid):
# half the cost per iteration and fewer iterations than on COARSE_INTERVALS, the same optima
# after refinement on planar_2r (where a finer grid with a large initial mu can miss some).
EXPLORE_INTERVALS = 50
# A lazy solve's candidates (_lazy_classes) climb without the circles they stay this far [m]
# from (segment clearance, at every node of the coarse run): fewer constraints per node on the
# ladder and the N grid; a climb that comes closer is checked and redone as a relaxed one.
NARROW_MARGIN = 0.05
# Cold starts that fit the problem: besides the straight start over the problem's t_f0, the
# same joint path over each of these multiples of the fitted final time (the slowest joint's
# bang-bang time, start_points.fitted_final_time) that t_f0 exceeds more than FIT_BAND times
# (or falls short of): a start much slower than the robot lets the first iterations wander
# into optima that spin the distal joints (three-link arms).  The problem's own start stays
# the first, so that where it is fit (within FIT_BAND of the fitted time) nothing changes.
FIT_FACTORS = (1.0, 2.0)
FIT_BAND = 3.0
# ... and of a model with three or more joints: all of these, whatever t_f0 (starts of other
# timing reach other folds; a slow start, 3 x, lets the distal links settle into a fold that
# the faster ones pass by).
FIT_FACTORS_FOLDING = (1.0, 2.0, 0.8, 1.2, 3.0)
# Fold starts of a model with three or more joints (fast_solver._fold_attempts): how many per
# source, from how many distinct cold optima, and their (elastic weight, barrier parameter);
# also from the result on the N grid when the attempts ran on a coarser one.
# Four on three links: the mirror images of all distal joints' folds and of the wrist's, the
# wrist's doubled, the elbow's mirrored.  Optima of three links differ by which way the distal
# links fold and how far the wrist whips, in narrow basins: from such a start mu = 0.01 (the
# cold attempts') leaves the basin, 1e-6 to 1e-4 stay.  The coarse grid's basins are not the N
# grid's (a fast whip's discretisation error), hence the folds on the N grid too.  On 128
# random free planar_3r moves (N = 300), with FIT_FACTORS_FOLDING: 116 within 0.1 % of the best
# known optimum (81 with one mirror source), at 339 ms median (90 ms) (benchmarks/RESULTS.md,
# "Three-link folds").
FOLD_STARTS = 4
FOLD_SOURCES = 2
FOLD_ATTEMPT = (ELASTIC_WEIGHT, 1e-4)
# A cold solve of three or more joints is the best of whole cold searches (fast_solver's
# _cold_searches) that differ in the first barrier parameter of their fitted attempts (None:
# none, the start over t_f0 alone).  Within one search more attempts are not more optima: the
# coarse optima compete for the refinements, and another search's start pushes a good one out
# (each attempt added to one search moved cases both ways); best-of is never worse than its
# first search.  On 160 random free planar_3r moves (N = 300) against IPOPT's best: 153 within
# 0.1 % with the first search alone, 156 with the second, 158 with all three (159 with
# the 3 x fitted start).
FOLDING_SEARCHES = (MU_COLD, None, 1.0)
