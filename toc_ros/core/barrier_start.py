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
The first barrier parameter of a start without multipliers when obstacle rows crowd it.

Every obstacle row adds mu (-log slack) terms to a barrier problem whose objective is the
final time alone.  With many obstacles off the motion (a wall of spheres behind an arm, fifty
circles around the paper's robot) those terms outweigh the objective at the first mu by orders
of magnitude: the barrier problem's optimum is a much slower motion, and the run spends
hundreds of iterations coming back from it, or stalls (benchmarks/RESULTS.md, "Many obstacle
spheres" and "Many circles").  Where the rows' terms exceed CROWDED times the bounds' terms,
the first mu is scaled by 2 B / (B + R); below that nothing changes (every benchmarked
scenario has fewer rows, and keeps its bits).
"""

CROWDED = 8.0


def crowding_share(bound_terms, row_terms):
    """Return the factor on the first barrier parameter: 1, or 2 B / (B + R) when crowded."""
    bound_terms, row_terms = float(bound_terms), float(row_terms)
    if row_terms <= CROWDED * bound_terms:
        return 1.0
    return 2.0 * bound_terms / (bound_terms + row_terms)
