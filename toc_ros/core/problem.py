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

"""Problem definition, solver options and input validation (before any iteration runs)."""

import dataclasses
from dataclasses import dataclass, field
import functools
import math
from typing import Optional, Tuple

import numpy as np

from .horizon import integrator_id
from .models.base import RobotModel
from .models.cylindrical import CylindricalRobot
from .obstacles import GRAD_EXACT, GRAD_SHORTCUT, model_clearance
from .result import Violations
from .settings import setting

PAPER_X0 = (math.pi / 12.0, 0.0, 1.0, 0.0)
PAPER_GOAL = (5.0 * math.pi / 12.0, 0.0, 1.0, 0.0)
PAPER_OBSTACLES = ((1.0, 1.0, 0.2),)     # section 4: R' = 0.2 m at (1 m, 1 m)
PAPER_MARGIN = 0.01                      # dR [m] of section 4.2
MAX_INTERVALS = 200000
MODES = ('fast', 'paper')
# Iteration budgets: paper mode runs the paper's M = 30000 gradient iterations; fast mode counts
# interior-point (Newton-type) iterations over all its grids.
DEFAULT_ITERATIONS = {'paper': 30000, 'fast': 2000}


class ProblemError(ValueError):
    """Invalid problem or options; the message says what and why."""


@dataclass(frozen=True)
class Problem:
    """
    Move the robot from x0 to x_goal (rest or not) in minimum time around circles.

    Only the start x0 and the goal x_goal must be given.  The defaults: the paper's
    cylindrical robot as the model, no obstacles, margin dR = 0.01 m, N = 1000 Euler intervals,
    t_f0 = 2.5 s.  Problem.paper() is the scenario of the paper's section 4 (its start, goal and
    circle).  obstacles: rows (cx, cy, R') [m] in the base frame; margin dR [m] inflates each to
    R = R' + dR (section 4.2).  N intervals of tau = t_f / N, t_f0 the initial final time.
    """

    # The flat parameters' defaults (ros_default), i.e. the scenario file's, are the paper's.
    x0: Tuple[float, ...] = setting(
        description='[q1 rad, dq1 rad/s, q2 m, dq2 m/s]: start state', ros_name='initial_state',
        ros_default=PAPER_X0)
    x_goal: Tuple[float, ...] = setting(
        description='[q1 rad, dq1 rad/s, q2 m, dq2 m/s]: goal', ros_name='goal_state',
        ros_default=PAPER_GOAL)
    # The robot: any RobotModel (models/), e.g. CylindricalRobot(RobotParams(u1_max=700.0)).
    model: RobotModel = field(default_factory=CylindricalRobot)
    obstacles: Tuple[Tuple[float, float, float], ...] = setting(
        (), "obstacle circles (x, y, radius R' > 0): obstacles.x/.y/.radius have equal lengths",
        unit='m', columns=('x', 'y', 'radius'), ros_default=PAPER_OBSTACLES)
    margin: float = setting(PAPER_MARGIN, "dR: clearance margin, the arm stays outside R' + dR",
                            unit='m', low=0.0, high=100.0, ros_name='obstacles.margin')
    n_intervals: int = setting(1000, 'number of time intervals of the trajectory', low=2,
                               high=MAX_INTERVALS, ros_name='solver.N')
    integrator: str = setting('euler', "discretisation of eq. (37): 'euler' (the paper's) or "
                              "'rk4'", choices=('euler', 'rk4'), ros_name='solver.integrator')
    t_f0: float = setting(2.5, 'initial guess of the final time (> 0)', unit='s', low=0.0,
                          high=1e4, ros_name='solver.t_f0')

    @classmethod
    def paper(cls, **changes):
        """
        Return the paper's scenario (section 4), with changes (field=value) if given.

        The cylindrical robot of eq. (37) with the paper's data moves at rest from
        q = (pi/12 rad, 1 m) to (5 pi/12 rad, 1 m) around the circle R' = 0.2 m at (1 m, 1 m),
        margin 0.01 m; N = 1000 Euler intervals.
        """
        return cls(**{'x0': PAPER_X0, 'x_goal': PAPER_GOAL, 'model': CylindricalRobot(),
                      'obstacles': PAPER_OBSTACLES, 'margin': PAPER_MARGIN, 'n_intervals': 1000,
                      'integrator': 'euler', 't_f0': 2.5, **changes})

    @property
    def robot_model(self):
        """Return the RobotModel solved for: the model."""
        return self.model

    @property
    def robot(self):
        """Refuse the former second way to give the robot: it is the model now."""
        raise AttributeError('Problem.robot is gone: the robot is Problem.model (a RobotModel; '
                             'its data: Problem.model.params)')

    def with_model(self, model):
        """
        Return this problem for another RobotModel.

        Joint states x0, x_goal (2 n entries) become the model's states (models with actuator
        states: the torques that hold the joints' velocities, see actuated.py).
        """
        robot = getattr(model, 'robot', None)
        if robot is not None:       # a URDF arm's plan model: the Problem holds its ArmRobot
            return dataclasses.replace(self, model=robot)
        states = {name: _model_state(model, getattr(self, name)) for name in ('x0', 'x_goal')}
        return dataclasses.replace(self, model=model, **states)

    @property
    def integrator_id(self):
        """Kernel id of the integrator (ValueError when unknown)."""
        return integrator_id(self.integrator)

    def circles(self):
        """Obstacles as a (K, 3) array with inflated radii R = R' + dR."""
        c = np.array(self.obstacles, dtype=float).reshape(-1, 3)
        c[:, 2] += self.margin
        return c

    def kernel_arrays(self):
        """Return the kernels' inputs: packed model data, x0, x_goal, u_max, inflated circles."""
        return (self.model.packed(), np.asarray(self.x0, float), np.asarray(self.x_goal, float),
                self.model.u_max, np.ascontiguousarray(self.circles()))

    def validate(self, states=True):
        """
        Raise ProblemError with every problem found (nothing is solved before this passes).

        states=False skips the checks of x0 and x_goal against the arm length and the
        obstacles (for a caller that checks those per request, e.g. against a measured start).
        """
        if not isinstance(self.model, RobotModel):
            raise ProblemError('model must be a toc_ros.core.models.RobotModel, e.g. '
                               'CylindricalRobot(RobotParams(...)), got '
                               f'{type(self.model).__name__}')
        model = self.robot_model
        errors = list(model.check())
        x0 = _vector('x0', self.x0, model.nx, errors)
        xg = _vector('x_goal', self.x_goal, model.nx, errors)
        if not isinstance(self.n_intervals, (int, np.integer)) or isinstance(
                self.n_intervals, bool) or not 2 <= self.n_intervals <= MAX_INTERVALS:
            errors.append(f'N must be an integer in [2, {MAX_INTERVALS}], '
                          f'got {self.n_intervals!r}')
        try:
            integrator_id(self.integrator)
        except ValueError as exc:
            errors.append(str(exc))
        if not finite_number(self.t_f0) or self.t_f0 <= 0.0:
            errors.append(f't_f0 must be a finite positive time [s], got {self.t_f0!r}')
        if not finite_number(self.margin) or self.margin < 0.0:
            errors.append(f'margin must be finite and >= 0 [m], got {self.margin!r}')
        circles = _obstacle_rows(self.obstacles, self.margin, errors)
        if not errors and states:
            for name, x in (('start', x0), ('goal', xg)):
                errors += model.check_state(x, name)
            if not errors and len(circles):
                n_circles = len(circles)
                for name, x in (('start', x0), ('goal', xg)):
                    gaps = model_clearance(model, x[None, :], self.circles())[0]
                    for j in np.flatnonzero(gaps < 0.0):
                        link, k = divmod(int(j), n_circles)
                        where = f' (link {link})' if model.n_links > 1 else ''
                        errors.append(f'{name} state puts the arm{where} inside obstacle {k} '
                                      f'(inflated by the margin): clearance {gaps[j]:.6g} m')
        if errors:
            raise ProblemError('; '.join(errors))


def _refuse_robot_keyword(init):
    """Wrap Problem.__init__: the robot keyword of earlier versions gets a clear TypeError."""
    @functools.wraps(init)
    def __init__(self, *args, **kwargs):
        if 'robot' in kwargs:
            raise TypeError('Problem(robot=...) is gone: give the robot as a model, '
                            'Problem(model=CylindricalRobot(RobotParams(...)), ...) '
                            '(toc_ros.core.models.CylindricalRobot)')
        init(self, *args, **kwargs)
    return __init__


Problem.__init__ = _refuse_robot_keyword(Problem.__init__)


@dataclass(frozen=True)
class PaperOptions:
    """Constants of the section-3 heuristic (defaults: the paper's section 4 values)."""

    k_b: float = setting(600.0, 'K_B of eq. (7), paper mode (> 0)', low=0.0, high=1e12,
                         ros_name='K_B')
    # J2 uses K_V-hat = tau0 K_V (section 4, constant tau0).
    k_v: float = setting(0.01, 'K_V, paper mode (> 0)', low=0.0, high=1e12, ros_name='K_V')
    k_p: float = setting(1000.0, 'K_p of eq. (42), obstacle penalty, paper mode (> 0)',
                         low=0.0, high=1e12, ros_name='K_p')
    eta: float = setting(1000.0, 'learning rate eta of eq. (32), paper mode (> 0)', low=0.0,
                         high=1e12)
    # Arms descend in joint accelerations, where eta = 1000 diverges: their rate is relative.
    arm_step: float = setting(1.0, 'URDF arms, paper mode: learning rate as a fraction of 1/L, '
                              'L the terminal penalty curvature in the joint accelerations at '
                              'tau0 (stable below 2)', low=0.0, high=2.0)
    d_tau: float = setting(1e-5, 'decrement of tau = t_f / N of eq. (34), paper mode (> 0)',
                           unit='s', low=0.0, high=1.0)
    j_eps: float = setting(0.01, 'J_eps of eq. (34), paper mode (> 0)', low=0.0, high=1e12,
                           ros_name='J_eps')
    obstacle_gradient: str = setting('shortcut', "'shortcut' (eq. 46) or 'exact' (eqs. 44-45)",
                                     choices=('shortcut', 'exact'))

    def grad_mode(self):
        """Kernel id of the obstacle-gradient variant."""
        return GRAD_SHORTCUT if self.obstacle_gradient == 'shortcut' else GRAD_EXACT


@dataclass(frozen=True)
class SolverOptions:
    """How to solve: mode, iteration and time limits, progress period."""

    mode: str = setting('fast', "'fast' (feasible minimum time) or 'paper' (the section-3 "
                        'heuristic)', choices=MODES)
    # None: the mode's default (DEFAULT_ITERATIONS)
    max_iterations: Optional[int] = setting(
        None, 'iteration limit of one solve (fast, 3+ joints: of each of its cold searches); 0 = '
        "the mode's default (paper: M = 30000 gradient steps, fast: 2000 interior-point "
        'iterations)', low=0, high=1_000_000_000, none_value=0)
    # [s] wall clock; None = no limit (the scenario file's default is 60 s)
    timeout: Optional[float] = setting(None, 'wall-clock limit of one solve; 0 = none',
                                       unit='s', low=0.0, high=86400.0, none_value=0.0,
                                       ros_default=60.0)
    progress_period: float = 0.1         # [s] between progress callbacks
    paper: PaperOptions = field(default_factory=PaperOptions)

    def iteration_limit(self):
        """Return max_iterations, or the mode's default: the paper's M, or the fast budget."""
        if self.max_iterations is not None:
            return int(self.max_iterations)
        return DEFAULT_ITERATIONS[self.mode]

    def validate(self):
        """Raise ProblemError for bad option values."""
        errors = []
        if self.mode not in MODES:
            errors.append(f'mode must be one of {MODES}, got {self.mode!r}')
        if self.max_iterations is not None and (not isinstance(
                self.max_iterations, (int, np.integer)) or isinstance(
                self.max_iterations, bool) or self.max_iterations < 1):
            errors.append(f'max_iterations must be an integer >= 1, got {self.max_iterations!r}')
        if self.timeout is not None and (not finite_number(self.timeout) or self.timeout <= 0):
            errors.append(f'timeout must be a positive number of seconds, got {self.timeout!r}')
        if not finite_number(self.progress_period) or self.progress_period <= 0:
            errors.append(f'progress_period must be > 0, got {self.progress_period!r}')
        po = self.paper
        for name in ('k_b', 'k_v', 'k_p', 'eta', 'arm_step', 'd_tau', 'j_eps'):
            value = getattr(po, name)
            if not finite_number(value) or value <= 0.0:
                errors.append(f'paper.{name} must be a finite positive number, got {value!r}')
        if finite_number(po.arm_step) and po.arm_step >= 2.0:
            errors.append(f'paper.arm_step must be below 2 (1/L is half the stable limit), got '
                          f'{po.arm_step!r}')
        if po.obstacle_gradient not in ('shortcut', 'exact'):
            errors.append("paper.obstacle_gradient must be 'shortcut' or 'exact', "
                          f'got {po.obstacle_gradient!r}')
        if errors:
            raise ProblemError('; '.join(errors))


def measure_violations(problem, controls, final_time):
    """Re-integrate controls over final_time and measure bounds, terminal error, clearance."""
    model = problem.robot_model
    controls = np.ascontiguousarray(controls, dtype=float)
    n = controls.shape[0]
    states = np.empty((n + 1, model.nx))
    model.kernels.rollout(np.asarray(problem.x0, float), controls, final_time / n,
                          model.packed(), problem.integrator_id, states)
    excess = np.max(np.abs(controls) - np.asarray(model.u_max)[None, :])
    circles = problem.circles()
    clearance = (float(np.min(model_clearance(model, states, circles)))
                 if len(circles) else math.inf)
    return states, Violations(
        max_control_excess=max(float(excess), 0.0),
        terminal_error=float(np.linalg.norm(states[-1] - np.asarray(problem.x_goal, float))),
        min_clearance=clearance)


def check_obstacles(obstacles, margin=0.0):
    """Raise ProblemError unless obstacles are rows (x, y, R' > 0), finite, off the base."""
    errors = []
    _obstacle_rows(obstacles, margin, errors)
    if errors:
        raise ProblemError('; '.join(errors))


# Obstacle circles are refused beyond this [m] (centre coordinates and radius): the planar
# models span a few metres, and constraint values (d^2 - R^2) / (2 R) of circles some hundred
# metres away lose the digits the convergence test needs (at 300 m the paper robot stalled).
CIRCLE_EXTENT = 100.0


def _obstacle_rows(obstacles, margin, errors):
    """Return obstacles as a (K, 3) array (None if not rows of numbers); problems to errors."""
    try:
        circles = np.array(obstacles, dtype=float).reshape(-1, 3)
    except (TypeError, ValueError):
        errors.append('obstacles must be rows (x, y, radius) of numbers')
        return None
    for k, (cx, cy, radius) in enumerate(circles):
        if not all(map(math.isfinite, (cx, cy, radius))):
            errors.append(f'obstacle {k} has a non-finite value ({cx}, {cy}, {radius})')
        elif radius <= 0.0:
            errors.append(f'obstacle {k} radius must be > 0, got {radius}')
        elif max(abs(cx), abs(cy), radius) > CIRCLE_EXTENT:
            errors.append(f'obstacle {k} ({cx}, {cy}, {radius}) reaches beyond '
                          f'{CIRCLE_EXTENT:g} m from the base: not a workspace obstacle of '
                          "these robots, and its constraint's values would lose their digits")
        elif finite_number(margin) and math.hypot(cx, cy) <= radius + margin:
            errors.append(f'obstacle {k} at ({cx}, {cy}) with inflated radius '
                          f'{radius + margin} contains the robot base')
    return circles


def _model_state(model, x):
    """Return x as the model's state when it is a joint state of a larger one, else x."""
    try:
        arr = np.array(x, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        return x            # validate() reports it
    if model.nx == arr.shape[0] or arr.shape[0] != 2 * model.n_joints \
            or not np.all(np.isfinite(arr)):
        return x
    try:
        return tuple(float(v) for v in model.full_state(arr))
    except (ArithmeticError, ValueError) as exc:        # ModelError is a ValueError
        raise ProblemError(f'no actuator state for the joint state {arr.tolist()}: {exc}')


def finite_number(value):
    """Return True for a real number (not bool) that is finite."""
    return (isinstance(value, (int, float, np.floating, np.integer))
            and not isinstance(value, bool) and math.isfinite(value))


def _vector(name, value, size, errors):
    try:
        arr = np.array(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        errors.append(f'{name} must be {size} numbers')
        return np.full(size, np.nan)
    if arr.shape != (size,):
        errors.append(f'{name} must have {size} entries [q1, dq1, q2, dq2, ...], got '
                      f'{arr.shape[0]}')
        return np.full(size, np.nan)
    if not np.all(np.isfinite(arr)):
        errors.append(f'{name} contains NaN or inf: {arr.tolist()}')
    return arr
