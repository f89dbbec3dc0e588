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
Feasibility polish of a converged arm trajectory: its defects down to rounding.

A run converges with its constraint violation <= 1e-9, but the SOLVED test integrates the
controls again from the start (open loop), and a long horizon amplifies the defects left at
the nodes: the Panda at N = 400 turned 7.5e-11 into a terminal error of 1.4e-6.  The polish
takes up to STEPS minimum-norm corrections (dx, du, dT) onto the linearised steps, the
Newton steps of the constraints alone (one Riccati solve each, identity weights; controls
within BOUND_ROOM of a bound are held by a large weight, so the bounds stay met), and keeps
the point when it lowers the largest defect.  The corrections are of the size of the
defects, so the objective (T) and the optimality conditions move by as little.
"""

import numpy as np

from . import riccati, riccati_euler

STEPS = 3
HELD = 1e12              # weight of a control held at its bound
BOUND_ROOM = 1e-6        # scaled controls within this of +-1 are held
# No further step once the largest defect is within DONE of the largest state entry (about 50
# ulps): below that a step, a derivative pass and a Riccati solve, only reshuffles rounding.
DONE = 1e-14


def polish(evaluator, states, controls, t_f):
    """
    Return (states, scaled controls, t_f, largest defect before, after) (module docstring).

    states (N + 1, 2n) with the start and goal at its ends, controls scaled by the efforts
    (in [-1, 1]); the input itself when no step lowers the largest defect.
    """
    x, v, t = np.array(states, dtype=float), np.array(controls, dtype=float), float(t_f)
    n_int, n = v.shape
    nx = 2 * n
    worst = before = float(np.max(np.abs(evaluator.defects(x, v, t))))
    held = np.abs(v) > 1.0 - BOUND_ROOM
    hxx = np.tile(np.eye(nx + 1), (n_int, 1, 1))
    huu = np.zeros((n_int, n, n))
    huu[:, np.arange(n), np.arange(n)] = np.where(held, HELD, 1.0)
    zeros = (np.zeros((n_int, n, nx + 1)), np.zeros((n_int, nx + 1)), np.zeros((n_int, n)))
    # The interior point's Riccati kernel for these steps (compiled by its warm-up solve).
    euler = evaluator.integrator == 'euler'
    work = (riccati_euler.work_arrays_euler(n_int, nx, n) if euler
            else riccati.work_arrays(n_int, nx, n))
    done = DONE * max(1.0, float(np.max(np.abs(x))))
    for _ in range(STEPS):
        if worst <= done:
            break
        terms = evaluator.stage_terms(x, v, t, np.zeros((n_int + 1, nx)), hessian='none')
        dx, dv = np.zeros((n_int + 1, nx)), np.zeros((n_int, n))
        lam, nu = np.zeros((n_int + 1, nx)), np.zeros(nx)
        if euler:
            code, d_t = riccati_euler.riccati_solve_euler(
                terms['a'], terms['b'], terms['c'], terms['defect'], hxx, zeros[0], huu,
                zeros[1], zeros[2], *work, dx, dv, lam)
        else:
            code, d_t = riccati.riccati_solve(
                terms['a'], terms['b'], terms['c'], terms['defect'], hxx, zeros[0], huu,
                zeros[1], zeros[2], 1.0, *work, dx, dv, lam, nu)
        if code != riccati.OK or not np.all(np.isfinite(dx)) or not np.isfinite(d_t):
            break
        trial_x, trial_v, trial_t = x + dx, np.clip(v + dv, -1.0, 1.0), t + d_t
        trial_x[0], trial_x[-1] = x[0], x[-1]
        trial = float(np.max(np.abs(evaluator.defects(trial_x, trial_v, trial_t))))
        if not trial < worst:
            break
        x, v, t, worst = trial_x, trial_v, trial_t, trial
    return x, v, t, before, worst
