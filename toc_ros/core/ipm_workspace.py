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
The interior-point method's data: one Workspace (a namedtuple of arrays) per solve.

Scalars live in fscal / iscal under the F_* / I_* names below, one history row per iteration
under the H_* names.  Every kernel of ipm.py, ipm_evaluation.py, riccati.py and
ipm_linesearch.py reads and writes this layout only, so a solve is one object that a thread
can own and another can stop (iscal[I_STOP]).
"""

from collections import namedtuple

import numpy as np

# fscal entries.
F_T = 0              # final time [s]
F_MU = 1             # barrier parameter
F_T_LOW = 2          # bounds on T [s]
F_T_HIGH = 3
F_ZT_LOW = 4         # duals of the T bounds
F_ZT_HIGH = 5
F_TOL = 6            # overall optimality tolerance (scaled, IPOPT's)
F_CONSTR_TOL = 7     # constraint violation tolerance (unscaled)
F_MU_MIN = 8
F_THETA = 9          # constraint violation at the current point (l1)
F_PHI = 10           # barrier objective at the current point
F_ERR = 11           # optimality error E_0 at the current point
F_DELTA = 12         # last inertia-correction shift
F_RHO = 13           # terminal augmentation weight (does not change the step)
F_THETA_MAX = 14
F_THETA_MIN = 15
F_ALPHA = 16         # last primal step length
F_DUAL_INF = 17
F_PRIMAL_INF = 18
F_COMPL = 19
F_DT = 20            # last step in T
F_ALPHA_DUAL = 21
F_T_REF = 22          # the objective is T^2 / (2 T_ref): same minimiser as T, with curvature
F_ELASTIC = 23       # l1 weight rho of the elastic variables of the obstacle constraints
F_ELASTIC_MAX = 24   # largest elastic variable at the current point
F_ERR_MU = 25        # optimality error of the barrier problem (E_mu)
N_FSCAL = 26

# iscal entries.
I_N = 0              # intervals
I_METHOD = 1         # integrator id (horizon.EULER / RK4)
I_ITER = 2           # iterations done
I_MAX_ITER = 3
I_N_FILTER = 4
I_LS_FAILS = 5       # consecutive line-search failures
I_STATUS = 6
I_REG_TRIES = 7      # factorizations of the last iteration
I_BACKTRACKS = 8     # line-search trials of the last iteration
I_STOP = 9           # set to 1 by another thread to stop the iterations (cancel, timeout)
I_ACCEPTABLE = 10    # consecutive iterations at an acceptable point (ACCEPT_TOL)
N_ISCAL = 11

# History columns (one row per iteration).
H_T, H_THETA, H_ERR, H_MU, H_ALPHA, H_DELTA = 0, 1, 2, 3, 4, 5
N_HIST = 6

# Size of the filter of the line search (ipm_linesearch.add_to_filter replaces the worst
# entry once it is full).
MAX_FILTER = 200


Workspace = namedtuple('Workspace', [
    # state and control sizes as tuples of that length: their lengths are part of the numba
    # type, so every kernel is compiled for its model's (nx, nu) with constant loop bounds,
    # which numba unrolls and keeps in registers (same arithmetic as sizes read from shapes);
    # size_q: the joints, whose positions are the states 0, 2, ..., 2 (nq - 1)
    'size_x', 'size_u', 'size_q',
    # problem data
    'p', 'x0', 'x_goal', 'u_max', 'circles',
    # primal: states, scaled controls; duals: dynamics, terminal, obstacles, control bounds
    'x', 'v', 'lam', 'nu', 's', 'e', 'z', 'zl', 'zu',
    # derivatives at the current point
    'jac_x', 'jac_v', 'jac_t', 'defect', 'cons', 'cons_q',
    # stage blocks of the Newton system: Q (xi, xi), S (v, xi), R (v, v), q, r
    'qq', 'ss', 'rr', 'qv', 'rv',
    # Riccati sweep; term_m, term_c: the terminal system dx(N) = term_c + term_m nu
    'pp', 'pc', 'gain', 'ff', 'chol', 'term_m', 'term_c',
    # step
    'dx', 'dv', 'lam_new', 'nu_new', 'ds', 'de', 'dz', 'dzl', 'dzu',
    # trial point of the line search
    'xt', 'vt', 'st', 'et', 'ct',
    # filter, history, scalars
    'filt', 'hist', 'fscal', 'iscal',
])


def make_workspace(n, nx, nu, n_links, circles, p, x0, x_goal, u_max, max_iter, nq=None):
    """
    Allocate a Workspace for N = n intervals (scalars still to be set by the caller).

    nq: number of joints (default nx / 2; a model with actuator states has more states).
    """
    nq = nx // 2 if nq is None else int(nq)
    circles = np.ascontiguousarray(np.reshape(circles, (-1, 3)), dtype=float)
    nb = n_links * circles.shape[0]
    nxi = nx + 1
    ncol = nx + 1
    z = np.zeros
    return Workspace(
        size_x=(0,) * nx, size_u=(0,) * nu, size_q=(0,) * nq,
        p=np.ascontiguousarray(p, dtype=float), x0=np.array(x0, dtype=float),
        x_goal=np.array(x_goal, dtype=float), u_max=np.array(u_max, dtype=float),
        circles=circles,
        x=z((n + 1, nx)), v=z((n, nu)), lam=z((n + 1, nx)), nu=z(nx), s=z((n + 1, nb)),
        e=z((n + 1, nb)),
        z=z((n + 1, nb)), zl=z((n, nu)), zu=z((n, nu)),
        jac_x=z((n, nx, nx)), jac_v=z((n, nx, nu)), jac_t=z((n, nx)), defect=z((n, nx)),
        cons=z((n + 1, nb)), cons_q=z((n + 1, nb, nq)),
        qq=z((n + 1, nxi, nxi)), ss=z((n, nu, nxi)), rr=z((n, nu, nu)), qv=z((n + 1, nxi)),
        rv=z((n, nu)),
        pp=z((n + 1, nxi, nxi)), pc=z((n + 1, nxi, ncol)), gain=z((n, nu, nxi)),
        ff=z((n, nu, ncol)), chol=z((n, nu, nu)), term_m=z((nx, nx)), term_c=z(nx),
        dx=z((n + 1, nx)), dv=z((n, nu)), lam_new=z((n + 1, nx)), nu_new=z(nx),
        ds=z((n + 1, nb)), de=z((n + 1, nb)), dz=z((n + 1, nb)), dzl=z((n, nu)),
        dzu=z((n, nu)),
        xt=z((n + 1, nx)), vt=z((n, nu)), st=z((n + 1, nb)), et=z((n + 1, nb)),
        ct=z((n + 1, nb)),
        filt=z((MAX_FILTER, 2)), hist=np.full((max_iter, N_HIST), np.nan),
        fscal=z(N_FSCAL), iscal=np.zeros(N_ISCAL, dtype=np.int64))
