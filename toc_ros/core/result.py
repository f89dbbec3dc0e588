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

"""Result types of the solvers: a status enum (like toppra/ruckig return codes) and dataclasses."""

from dataclasses import dataclass, field
import enum
import math
from typing import Optional

import numpy as np

# Feasibility tolerances of a SOLVED result: controls within bounds exactly,
# terminal state error (Euclidean norm) and clearance deficit at most 1e-6.
TERMINAL_TOL = 1e-6
CLEARANCE_TOL = 1e-6


HISTORY_COLUMNS = ('iteration', 't_f', 'cost', 'infeasibility')


class Status(enum.Enum):
    """Outcome of a solve; exit codes of toc-solve follow exit_code()."""

    SOLVED = 'SOLVED'                          # feasible within the tolerances above
    SOLVED_INACCURATE = 'SOLVED_INACCURATE'    # converged by its own rule, residual violations
    MAX_ITERATIONS = 'MAX_ITERATIONS'
    STALLED = 'STALLED'
    CANCELED = 'CANCELED'
    TIMEOUT = 'TIMEOUT'
    INVALID_INPUT = 'INVALID_INPUT'

    def exit_code(self):
        """Process exit code: 0 solved, 1 inaccurate, 2 no convergence, 3 stopped, 4 bad input."""
        return {Status.SOLVED: 0, Status.SOLVED_INACCURATE: 1, Status.MAX_ITERATIONS: 2,
                Status.STALLED: 2, Status.CANCELED: 3, Status.TIMEOUT: 3,
                Status.INVALID_INPUT: 4}[self]


@dataclass
class Violations:
    """Constraint violations measured on a returned trajectory."""

    max_control_excess: float = math.inf   # max(|u| - u_max, 0) over nodes and joints
    terminal_error: float = math.inf       # |x(N) - x_goal| (Euclidean)
    min_clearance: float = math.inf        # min distance arm-to-inflated-circle [m] (<0: hit)

    def feasible(self):
        """Return True when within the SOLVED tolerances."""
        return (self.max_control_excess <= 0.0 and self.terminal_error <= TERMINAL_TOL
                and self.min_clearance >= -CLEARANCE_TOL)

    def as_dict(self):
        """Plain-float dict (JSON)."""
        return {'max_control_excess': float(self.max_control_excess),
                'terminal_error': float(self.terminal_error),
                'min_clearance': float(self.min_clearance)}


@dataclass
class Progress:
    """What a solver reports while it runs (progress callback argument)."""

    iteration: int
    t_f: float
    cost: float
    best_feasible_t_f: float      # nan until a candidate meets the mode's acceptance rule
    elapsed_s: float
    phase: str = ''
    violations: Optional[Violations] = None
    infeasibility: float = math.nan   # constraint violation of the iterate (fast: l1 norm)


@dataclass
class SolveResult:
    """Outcome of one solve; arrays in SI units and radians."""

    status: Status
    message: str
    mode: str = ''
    integrator: str = ''
    n_intervals: int = 0
    final_time: float = math.nan
    time_grid: np.ndarray = field(default_factory=lambda: np.zeros(0))
    states: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    controls: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    iterations: int = 0
    wall_time_s: float = 0.0
    # One row per iteration, HISTORY_COLUMNS: iteration, t_f [s], cost (the objective the mode
    # minimises: J_T in paper mode, t_f in fast mode), infeasibility (fast mode: l1 norm of
    # the constraint violation of the iterate; paper mode: nan, its penalties are the cost).
    history: np.ndarray = field(default_factory=lambda: np.zeros((0, len(HISTORY_COLUMNS))))
    violations: Violations = field(default_factory=Violations)
    cost: float = math.nan            # objective at the returned point (paper J_T, fast t_f)
    # Solver internals for a warm start (fast mode: the multipliers); not part of --json.
    solver_state: Optional[dict] = None

    @property
    def success(self):
        """Return True for Status.SOLVED."""
        return self.status is Status.SOLVED

    @property
    def has_trajectory(self):
        """Return True when states/controls hold a trajectory (best so far if stopped)."""
        return self.controls.shape[0] > 0

    def remainder(self, elapsed):
        """
        Return the part of this trajectory from the node at time elapsed [s] on.

        The warm start for replanning from the state the robot reached: states, controls and
        the remaining time from node k = round(elapsed / tau) (at most N - 1), with fast mode's
        multipliers sliced alike.  solve(problem_from_the_new_state, initial_guess=...) then
        starts from it.
        """
        n = self.controls.shape[0]
        if n == 0:
            raise ValueError('the result has no trajectory')
        tau = self.final_time / n
        if not (math.isfinite(float(elapsed)) and math.isfinite(tau) and tau > 0.0):
            raise ValueError(f'remainder needs a finite elapsed time [s] of a trajectory with '
                             f'a positive final time, got {elapsed!r} of {self.final_time!r}')
        k = int(min(max(round(float(elapsed) / tau), 0), n - 1))
        state = None
        if self.solver_state and 'duals' in self.solver_state:
            duals = self.solver_state['duals']
            state = {'duals': {'lam': duals['lam'][k:].copy(), 'nu': duals['nu'].copy(),
                               'z': duals['z'][k:].copy()}}
            for name in ('zl', 'zu'):
                if name in duals:
                    state['duals'][name] = duals[name][k:].copy()
            if 'rho' in duals:
                state['duals']['rho'] = duals['rho']
        if self.solver_state and 'arm_duals' in self.solver_state:
            # A URDF arm's multipliers: arrays by node or interval, scalars kept.
            state = {'arm_duals': {name: value[k:].copy() if np.ndim(value) else value
                                   for name, value in self.solver_state['arm_duals'].items()}}
        return SolveResult(
            status=self.status, message=f'remainder from node {k} of a {self.status.value} '
            'trajectory', mode=self.mode, integrator=self.integrator, n_intervals=n - k,
            final_time=self.final_time - k * tau,
            time_grid=self.time_grid[k:] - self.time_grid[k] if self.time_grid.size else
            self.time_grid, states=self.states[k:].copy(), controls=self.controls[k:].copy(),
            violations=self.violations, cost=self.cost, solver_state=state)

    def to_dict(self):
        """JSON-ready dict (the toc-solve --json contract)."""
        return {
            'status': self.status.value,
            'message': self.message,
            'mode': self.mode,
            'final_time': _num(self.final_time),
            'integrator': self.integrator,
            'N': int(self.n_intervals),
            'iterations': int(self.iterations),
            'wall_time_s': float(self.wall_time_s),
            'time_grid': self.time_grid.tolist(),
            'states': self.states.tolist(),
            'controls': self.controls.tolist(),
            'cost': _num(self.cost),
            'violations': {k: _num(v) for k, v in self.violations.as_dict().items()},
            'history_columns': list(HISTORY_COLUMNS),
            'history': [[_num(v) for v in row] for row in self.history.tolist()],
        }


def guess_from_dict(data):
    """
    Return (controls, t_f) of a to_dict() result (a toc-solve --json file).

    The pair is meant for solve(initial_guess=).

    Raises ValueError with a reason when the data holds no usable trajectory.
    """
    if not isinstance(data, dict):
        raise ValueError('expected a JSON object as written by toc-solve --json')
    controls = data.get('controls')
    t_f = data.get('final_time')
    if not controls or t_f is None:
        raise ValueError('the result has no trajectory (controls and final_time)')
    try:
        controls = np.array(controls, dtype=float)
        t_f = float(t_f)
    except (TypeError, ValueError):
        raise ValueError('controls must be rows of numbers and final_time a number')
    if controls.ndim != 2:
        raise ValueError(f'controls must be an M x nu array, got shape {controls.shape}')
    return controls, t_f


def _num(value):
    """JSON has no inf/nan: map them to None."""
    value = float(value)
    return value if math.isfinite(value) else None
