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
Starting points of the fast mode's runs, and solutions carried between grids.

Cold starts: the joints along a cubic in time (interpolation_start) or along a joint path of
homotopy.py (path_start), with the controls of that motion (controls_for).  Warm starts: a
previous result or a primal guess on the requested grid (warm_start_point).  Between grids:
the ladder of intermediate grids, and states, controls and multipliers resampled on it.
"""

import math

import numpy as np

from .result import SolveResult

# Refinement from the coarse grid to N intervals in steps of at most LADDER_RATIO (ladder()).
LADDER_RATIO = 4.0
# Fraction of t_f over which a start or goal velocity is blended in (path_start).
BLEND = 0.1
# Smoothing passes (weights 1/4, 1/2, 1/4, ends fixed) over the grid path.
SMOOTHING = 3


def interpolation_start(problem, n, t_f=None):
    """
    Return the cold starting point for n intervals over t_f (default the problem's t_f0).

    Each joint moves from x0 to x_goal along a cubic in time (positions and velocities match
    both ends), and the controls are that motion's inverse dynamics clipped to the bounds
    (least squares through df/du; exact for models affine in u).  The same point is handed to
    the reference solvers in benchmarks/ so that all start alike.
    """
    t_f = float(problem.t_f0 if t_f is None else t_f)
    return start_along(problem, interpolation_states(problem, n, t_f), t_f) + (t_f,)


def interpolation_states(problem, n, t_f=None):
    """Return the joint states (n + 1, 2 n) of interpolation_start (its controls cost more)."""
    model = problem.robot_model
    t_f = float(problem.t_f0 if t_f is None else t_f)
    x0 = np.asarray(problem.x0, dtype=float)
    xg = np.asarray(problem.x_goal, dtype=float)
    q0, qg = model.positions(x0), model.positions(xg)
    v0, vg = model.velocities(x0) * t_f, model.velocities(xg) * t_f
    n_q = model.n_joints
    s = np.linspace(0.0, 1.0, n + 1)[:, None]
    # Cubic Hermite basis on s in [0, 1] (positions, and velocities scaled by t_f).
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, \
        s**3 - s**2
    d00, d10, d01, d11 = 6 * s**2 - 6 * s, 3 * s**2 - 4 * s + 1, -6 * s**2 + 6 * s, \
        3 * s**2 - 2 * s
    q = h00 * q0 + h10 * v0 + h01 * qg + h11 * vg
    dq = (d00 * q0 + d10 * v0 + d01 * qg + d11 * vg) / t_f
    states = np.empty((n + 1, 2 * n_q))
    states[:, 0::2] = q
    states[:, 1::2] = dq
    return states


def fold_starts(problem, states, t_f, variants):
    """
    Return a start (states, controls, t_f) per variant (joints, factor): their folds scaled.

    A joint's fold is its deviation from the straight interpolation between the ends
    (interpolation_states over the same t_f, so the ends' positions and velocities match);
    factor -1 mirrors it (the joint swings the other way with the same timing), 2 doubles it
    (the joint whips twice as far).
    """
    n = states.shape[0] - 1
    straight = interpolation_states(problem, n, t_f)
    starts = []
    for joints, factor in variants:
        columns = [c for j in joints for c in (2 * j, 2 * j + 1)]
        folded = np.array(states[:, :straight.shape[1]], dtype=float)
        folded[:, columns] = straight[:, columns] + factor * (folded[:, columns] -
                                                              straight[:, columns])
        starts.append(start_along(problem, folded, t_f) + (t_f,))
    return starts


def bang_bang_time(distance, v0, v1, acceleration):
    """
    Return the least time [s] of a double integrator from velocity v0 to v1 over distance.

    Under |acceleration| <= acceleration (> 0): one switch between full acceleration and full
    deceleration (either order), the switching velocity from v_s^2 = s a d + (v0^2 + v1^2) / 2.
    """
    best = math.inf
    for sign in (1.0, -1.0):
        square = sign * acceleration * distance + 0.5 * (v0 * v0 + v1 * v1)
        if square < 0.0:
            continue
        switch = sign * math.sqrt(square)
        first, second = (switch - v0) / (sign * acceleration), \
            (switch - v1) / (sign * acceleration)
        if first >= -1e-12 and second >= -1e-12:
            best = min(best, max(first, 0.0) + max(second, 0.0))
    return best


def joint_accelerations(problem):
    """
    Return the acceleration [rad/s^2 or m/s^2] each joint gets from its own bound, (n,).

    u_max_j |df/du|_jj (the diagonal of the inverse mass matrix times the bound), the smaller
    at the start's and the goal's configuration, at rest; less the larger gravity (drift)
    acceleration there, but never below a quarter of it.
    """
    model = problem.robot_model.joint_model      # the joints driven directly by u
    u_max = np.asarray(model.u_max, dtype=float)
    f = np.zeros(model.nx)
    fx = np.zeros((model.nx, model.nx))
    fu = np.zeros((model.nx, model.nu))
    least = np.full(model.n_joints, math.inf)
    for state in (problem.x0, problem.x_goal):
        x = model.joint_states(np.asarray(state, dtype=float)).copy()
        x[1::2] = 0.0
        model.kernels.rhs_jac(x, np.zeros(model.nu), model.packed(), f, fx, fu)
        own = np.abs(np.diag(fu[1::2, :])) * u_max
        least = np.minimum(least, np.maximum(own - np.abs(f[1::2]), 0.25 * own))
    return least


def fitted_final_time(problem):
    """
    Return a final time [s] that fits the problem: the slowest joint's bang-bang time.

    Each joint alone from its start to its goal (positions and velocities) under the
    acceleration of joint_accelerations: a lower estimate of the minimum time, ignoring the
    coupling between the joints (and the obstacles).  None when it cannot be formed (a model
    whose controls do not drive its joints one to one).
    """
    model = problem.robot_model.joint_model
    if model.nu != model.n_joints:
        return None
    acc = joint_accelerations(problem)
    x0 = model.joint_states(np.asarray(problem.x0, dtype=float))
    xg = model.joint_states(np.asarray(problem.x_goal, dtype=float))
    times = [bang_bang_time(xg[2 * j] - x0[2 * j], x0[2 * j + 1], xg[2 * j + 1], acc[j])
             for j in range(model.n_joints) if acc[j] > 0.0 and math.isfinite(acc[j])]
    t_f = max(times, default=math.nan)
    return t_f if math.isfinite(t_f) and t_f > 0.0 else None


def start_along(problem, joint_states, t_f):
    """
    Return (states, controls) of a start that moves the joints along joint_states over t_f.

    joint_states (n + 1, 2 n) from the start's to the goal's joints; the controls by
    controls_for the joints.  A model with actuator states (models/actuated.py) gets those
    controls as its applied torques (actuator_states) and as commands.
    """
    model = problem.robot_model
    joint = model.joint_model
    controls = controls_for(joint, joint_states, t_f)
    if not has_actuators(model):
        return joint_states, controls
    return np.hstack([joint_states, actuator_states(problem, controls)]), controls


def actuator_states(problem, controls):
    """
    Actuator states (N + 1, n) that apply controls (N, n) (models/actuated.py).

    Each node's applied control is the command of the interval it starts (the lag as if
    instant); the first and last nodes keep the start's and the goal's.
    """
    model = problem.robot_model
    joints = model.joint_model.nx
    states = np.vstack([model.actuator_states(controls),
                        np.asarray(problem.x_goal, dtype=float)[None, joints:]])
    states[0] = np.asarray(problem.x0, dtype=float)[joints:]
    return states


def controls_for(model, states, t_f):
    """
    Return controls (n, nu) whose Euler steps follow states (n + 1, nx) over t_f, clipped.

    Least squares through df/du at u = 0 (exact for models affine in u).
    """
    n = states.shape[0] - 1
    tau = t_f / n
    k = model.kernels
    p = model.packed()
    f = np.zeros((n, model.nx))
    fx = np.zeros((model.nx, model.nx))
    fu = np.zeros((n, model.nx, model.nu))
    zero = np.zeros(model.nu)
    u_max = np.asarray(model.u_max, dtype=float)
    for i in range(n):
        k.rhs_jac(states[i], zero, p, f[i], fx, fu[i])
    # One stacked pseudo-inverse instead of n lstsq calls: no Python loop over the nodes.
    target = (states[1:] - states[:-1]) / tau - f
    u = np.matmul(np.linalg.pinv(fu), target[:, :, None])[:, :, 0]
    return np.clip(u, -u_max, u_max)


def ladder(coarse, n):
    """
    Intermediate grids between coarse and n intervals, a geometric sequence (ratio <= 4).

    A refinement that jumps by 10 needs ~45 iterations on the N grid (planar_2r, N = 1000),
    one via 316 intervals ~20 there plus ~20 on the cheaper grid.
    """
    if n <= coarse:
        return []
    steps = int(math.ceil(math.log(n / coarse) / math.log(LADDER_RATIO) - 1e-12))
    return [int(round(coarse * (n / coarse) ** (k / steps))) for k in range(1, steps)]


def resample(states, controls, n):
    """
    Carry a trajectory to n intervals.

    States are interpolated linearly in time, controls piecewise constant (the control of the
    old interval that contains the new interval's midpoint).
    """
    m = controls.shape[0]
    old = np.linspace(0.0, 1.0, m + 1)
    new = np.linspace(0.0, 1.0, n + 1)
    out_states = np.column_stack([np.interp(new, old, states[:, r])
                                  for r in range(states.shape[1])])
    mid = (np.arange(n) + 0.5) / n
    idx = np.minimum((mid * m).astype(np.int64), m - 1)
    return out_states, controls[idx].copy()


def resample_duals(duals, m, n):
    """Multipliers carried from m to n intervals (obstacle duals scale with tau)."""
    old = np.linspace(0.0, 1.0, m + 1)
    new = np.linspace(0.0, 1.0, n + 1)
    lam = np.column_stack([np.interp(new, old, duals['lam'][:, r])
                           for r in range(duals['lam'].shape[1])])
    nodes_old = old[1:]
    nodes_new = new[1:]
    z = np.column_stack([np.interp(nodes_new, nodes_old, duals['z'][:, j])
                         for j in range(duals['z'].shape[1])]) * (m / n) \
        if duals['z'].shape[1] else np.zeros((n, 0))
    out = {'lam': lam, 'nu': duals['nu'].copy(), 'z': z}
    if 'rho' in duals:
        out['rho'] = duals['rho']
    if 'zl' in duals:
        mid = (np.arange(n) + 0.5) / n
        idx = np.minimum((mid * m).astype(np.int64), m - 1)
        out['zl'] = duals['zl'][idx] * (m / n)
        out['zu'] = duals['zu'][idx] * (m / n)
    return out


def widen_duals(duals, kept, n_circles, n_links):
    """
    Multipliers of a run on the circles kept (indices) for all n_circles of the problem.

    The obstacle duals z of the circles it did not have are 0: InteriorPointRun.start makes
    them mu / slack, an inactive constraint's start.
    """
    z = duals['z']
    wide = np.zeros((z.shape[0], n_links * n_circles))
    for link in range(n_links):
        for r, k in enumerate(kept):
            wide[:, link * n_circles + k] = z[:, link * len(kept) + r]
    return dict(duals, z=wide)


def warm_start_point(problem, guess, n):
    """
    Return (states, controls, t_f, duals or None, drift) from an initial guess for n intervals.

    drift: how far [max norm] the problem's start lies from the guess's first state.
    """
    if isinstance(guess, SolveResult):
        controls = np.asarray(guess.controls, dtype=float)
        t_f = float(guess.final_time)
        states = np.asarray(guess.states, dtype=float)
        duals = guess.solver_state.get('duals') if guess.solver_state else None
    else:
        controls, t_f = guess
        controls = np.asarray(controls, dtype=float)
        t_f = float(t_f)
        states = None
        duals = None
    model = problem.robot_model
    if controls.ndim != 2 or controls.shape[1] != model.nu or controls.shape[0] < 1:
        raise ValueError(f'initial guess controls must be an M x {model.nu} array, got shape '
                         f'{controls.shape}')
    if not (np.all(np.isfinite(controls)) and math.isfinite(t_f) and t_f > 0.0):
        raise ValueError('initial guess must have finite controls and a positive final time')
    m = controls.shape[0]
    drift = 0.0
    if states is not None and states.shape == (m + 1, model.nx) \
            and np.all(np.isfinite(states)):
        # A trajectory (e.g. the remainder of the plan being executed): its states and
        # multipliers, starting from the problem's start (the robot may have drifted off it;
        # the first shooting defect absorbs that).
        drift = float(np.max(np.abs(states[0] - np.asarray(problem.x0, dtype=float))))
        states = states.copy()
        states[0] = problem.x0
    else:
        # Roll the controls out from the problem's start: consistent states (zero defects).
        states = np.empty((m + 1, model.nx))
        model.kernels.rollout(np.asarray(problem.x0, dtype=float),
                              np.ascontiguousarray(np.clip(controls, -model.u_max,
                                                           model.u_max)),
                              t_f / m, model.packed(), problem.integrator_id, states)
        duals = None
    if not np.all(np.isfinite(states)):
        raise ValueError('initial guess controls make the state diverge')
    if m != n:
        if duals is not None and duals['z'].shape[1] == model.n_links * len(problem.obstacles):
            duals = resample_duals(duals, m, n)
        else:
            duals = None
        states, controls = resample(states, controls, n)
    elif duals is not None and duals['z'].shape[1] != model.n_links * len(problem.obstacles):
        duals = None
    return states, controls, t_f, duals, drift


def has_actuators(model):
    """Return whether model has actuator states besides its joints (models/actuated.py)."""
    return model.joint_model is not model


def path_start(problem, path, n):
    """
    Return (states, controls, t_f) for n intervals along a joint path (M, n_joints), over t_f0.

    The smoothed path is parameterised by arc length and traversed with s(t) = 3 t^2 - 2 t^3
    (rest at both ends); cubic Hermite velocity terms as in interpolation_start, over the first
    and last BLEND of the time only, add the start and goal velocities.  Controls as in
    interpolation_start (start_along).
    """
    model = problem.robot_model
    t_f = float(problem.t_f0)
    x0 = np.asarray(problem.x0, dtype=float)
    xg = np.asarray(problem.x_goal, dtype=float)
    p = np.array(path, dtype=float)
    for _ in range(SMOOTHING):
        p[1:-1] = 0.25 * p[:-2] + 0.5 * p[1:-1] + 0.25 * p[2:]
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    arc /= max(arc[-1], 1e-12)
    keep = np.concatenate([[True], np.diff(arc) > 1e-12])
    p, arc = p[keep], arc[keep]
    s = np.linspace(0.0, 1.0, n + 1)
    sig = 3.0 * s**2 - 2.0 * s**3
    dsig = (6.0 * s - 6.0 * s**2) / t_f
    # Hermite velocity terms compressed into the first / last BLEND of the time (so that they
    # move the path by at most 0.15 BLEND t_f |v|): w h10(s / w), w h11(1 - (1 - s) / w).
    a = np.clip(s / BLEND, 0.0, 1.0)
    b = np.clip(1.0 - (1.0 - s) / BLEND, 0.0, 1.0)
    h10, h11 = a**3 - 2.0 * a**2 + a, b**3 - b**2
    d10, d11 = 3.0 * a**2 - 4.0 * a + 1.0, 3.0 * b**2 - 2.0 * b
    d10[s > BLEND] = 0.0
    d11[s < 1.0 - BLEND] = 0.0
    v0, vg = model.velocities(x0), model.velocities(xg)
    joints = range(p.shape[1])
    q = np.column_stack([np.interp(sig, arc, p[:, j]) for j in joints])
    slope = np.column_stack([np.interp(sig, arc, np.gradient(p[:, j], arc)) for j in joints])
    states = np.empty((n + 1, 2 * model.n_joints))
    states[:, 0::2] = q + BLEND * t_f * (h10[:, None] * v0 + h11[:, None] * vg)
    states[:, 1::2] = slope * dsig[:, None] + d10[:, None] * v0 + d11[:, None] * vg
    states[0], states[-1] = model.joint_states(x0), model.joint_states(xg)
    return start_along(problem, states, t_f) + (t_f,)
