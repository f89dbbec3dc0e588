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
Plain-numpy re-implementation of the robot, integrators and geometry for the tests.

Written from the paper (eq. 37, section 4) without importing toc_ros, so that the tests check
the core against something that does not share its code.  Slow (Python loops): use small N
or a single re-integration per solve.
"""

import math

import numpy as np

PAPER = {'hand_mass': 50.0, 'link_mass': 97.0, 'inertia': 193.0, 'a': 1.1}
U_MAX = np.array([600.0, 500.0])
X0 = np.array([math.pi / 12.0, 0.0, 1.0, 0.0])
XG = np.array([5.0 * math.pi / 12.0, 0.0, 1.0, 0.0])
PAPER_CIRCLES = np.array([[1.0, 1.0, 0.21]])      # R' = 0.2 m inflated by dR = 0.01 m
# Euler N = 1000 optimum of the paper scenario from the independent IPOPT transcription.
T_STAR_PAPER = 2.067276


def f(x, u, variant='eq37', robot=None):
    """Eq. (37): dx/dt for x = [q1, dq1, q2, dq2], u = [u1, u2]."""
    r = dict(PAPER, **(robot or {}))
    big_m, a = r['hand_mass'], r['a']
    c1 = r['inertia'] + big_m * a * a
    c2 = 2.0 * big_m * a
    c3 = r['link_mass'] + big_m
    _, dq1, q2, dq2 = x
    sign = -1.0 if variant == 'eq37' else 1.0
    den = c1 + c2 * q2 + c3 * q2 * q2
    return np.array([
        dq1,
        (-2.0 * c3 * dq1 * q2 * dq2 - c2 * dq1 * dq2) / den + u[0] / den,
        dq2,
        q2 * dq1 * dq1 + sign * c2 / (2.0 * c3) * dq1 * dq1 + u[1] / c3,
    ])


def step(x, u, tau, integrator='euler', variant='eq37', robot=None):
    """One explicit Euler or classic RK4 step with u held constant."""
    x = np.asarray(x, dtype=float)
    if integrator == 'euler':
        return x + tau * f(x, u, variant, robot)
    k1 = f(x, u, variant, robot)
    k2 = f(x + tau / 2.0 * k1, u, variant, robot)
    k3 = f(x + tau / 2.0 * k2, u, variant, robot)
    k4 = f(x + tau * k3, u, variant, robot)
    return x + tau / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def simulate(x0, controls, t_f, integrator='euler', variant='eq37', robot=None):
    """Re-integrate piecewise-constant controls (N x 2) over t_f: states (N+1 x 4)."""
    controls = np.asarray(controls, dtype=float)
    tau = t_f / controls.shape[0]
    xs = [np.asarray(x0, dtype=float)]
    for u in controls:
        xs.append(step(xs[-1], u, tau, integrator, variant, robot))
    return np.array(xs)


def rk4(x, u, dt, steps, variant='eq37', robot=None):
    """Integrate eq. (37) with u held over `steps` classic RK4 steps of dt each."""
    x = np.asarray(x, dtype=float)
    for _ in range(steps):
        x = step(x, u, dt, 'rk4', variant, robot)
    return x


def follow_then_brake(times, controls, x, t, wait, u_max, rest_speed, smoothing_speed,
                      dt=0.002, substeps=10):
    """
    Follow a plan from state x at time t for wait [s], then stop: the path of the stop.

    The plan holds controls[i] on [times[i], times[i + 1]) (integrated in RK4 steps of at most
    1 ms).  The stop applies u = -u_max * clip(dq / smoothing_speed, -1, 1) to each joint
    (full bound against the velocity, linear near rest), held for dt in `substeps` RK4 steps,
    until every joint is slower than rest_speed.  Rows: the state where braking starts, then
    one per dt.
    """
    x, end = np.asarray(x, dtype=float), t + wait
    while t < end - 1e-12:
        i = min(int(np.searchsorted(times, t, side='right')) - 1, len(controls) - 1)
        h = min(end, times[i + 1]) - t
        steps = max(1, math.ceil(h / 1e-3))
        x, t = rk4(x, controls[i], h / steps, steps), t + h
    path = [x]
    while np.max(np.abs(x[1::2])) >= rest_speed:
        u = -np.asarray(u_max) * np.clip(x[1::2] / smoothing_speed, -1.0, 1.0)
        x = rk4(x, u, dt / substeps, substeps)
        path.append(x)
    return np.array(path)


def segment_clearance(segments, circles, squared=False):
    """
    Clearance of segments (..., L, 4) rows (ax, ay, bx, by) to circles (K, 3): (..., L K).

    The tests' one clearance oracle (numpy, independent of the package's compiled one).
    Column link * K + k; squared=False: d - R [m], squared=True: (d^2 - R^2) / (2 R).  The
    closest point of a segment to a centre c is a + t (b - a), t = clip((c - a).(b - a) /
    |b - a|^2, 0, 1).
    """
    seg = np.asarray(segments, dtype=float)
    circles = np.reshape(np.asarray(circles, dtype=float), (-1, 3))
    a, b = seg[..., None, 0:2], seg[..., None, 2:4]          # (..., L, 1, 2)
    c = circles[:, 0:2]                                       # (K, 2)
    v = b - a
    length_sq = np.sum(v * v, axis=-1)
    t = np.sum((c - a) * v, axis=-1) / np.where(length_sq > 0.0, length_sq, 1.0)
    t = np.clip(np.where(length_sq > 0.0, t, 0.0), 0.0, 1.0)
    closest = a + t[..., None] * v
    d_sq = np.sum((closest - c) ** 2, axis=-1)                # (..., L, K)
    radius = circles[:, 2]
    out = (d_sq - radius ** 2) / (2.0 * radius) if squared else np.sqrt(d_sq) - radius
    return out.reshape(out.shape[:-2] + (-1,))


def chain_segments(q, lengths):
    """Link segments (M, L, 4) of a planar serial chain with revolute joints q (M, L)."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    angles = np.cumsum(q, axis=1)
    lengths = np.asarray(lengths, dtype=float)[None, :, None]
    steps = np.stack([np.cos(angles), np.sin(angles)], axis=2) * lengths
    ends = np.cumsum(steps, axis=1)
    starts = np.concatenate([np.zeros_like(ends[:, :1]), ends[:, :-1]], axis=1)
    return np.concatenate([starts, ends], axis=2)


def arm_segments(states, a=PAPER['a']):
    """Return the paper arm's segment [0, (a + q2) e(q1)] at states (M, 4): (M, 1, 4)."""
    states = np.atleast_2d(np.asarray(states, dtype=float))
    reach = a + states[:, 2]
    return np.stack([np.zeros_like(reach), np.zeros_like(reach), reach * np.cos(states[:, 0]),
                     reach * np.sin(states[:, 0])], axis=1)[:, None, :]


def clearance(states, circles, a=PAPER['a']):
    """Distance from the paper arm [0, (a + q2) e(q1)] to each circle's edge: (N+1, K)."""
    return segment_clearance(arm_segments(states, a), circles)


def arm_clearance(q, circles, a=PAPER['a']):
    """clearance() of joint positions q (M, 2) = (q1, q2) rows: (M, K)."""
    q = np.reshape(np.asarray(q, dtype=float), (-1, 2))
    states = np.zeros((q.shape[0], 4))
    states[:, 0], states[:, 2] = q[:, 0], q[:, 1]
    return clearance(states, circles, a)


def sampled_clearance(states, circles, a=PAPER['a'], samples=4001):
    """Like clearance() but by brute force over points along the arm (an upper bound)."""
    states = np.atleast_2d(states)
    circles = np.reshape(np.asarray(circles, dtype=float), (-1, 3))
    s = np.linspace(0.0, 1.0, samples)[None, :] * (a + states[:, 2])[:, None]
    px = s * np.cos(states[:, 0])[:, None]
    py = s * np.sin(states[:, 0])[:, None]
    return np.stack([np.min(np.hypot(px - cx, py - cy), axis=1) - radius
                     for cx, cy, radius in circles], axis=1)


def violations(x0, x_goal, controls, t_f, circles, u_max=U_MAX, integrator='euler',
               variant='eq37', robot=None):
    """Re-integrate and measure: dict of states, control excess, terminal error, clearance."""
    states = simulate(x0, controls, t_f, integrator, variant, robot)
    a = dict(PAPER, **(robot or {}))['a']
    gaps = clearance(states, circles, a)
    excess = np.max(np.abs(np.asarray(controls)) - np.asarray(u_max)[None, :])
    return {'states': states,
            'max_control_excess': max(0.0, float(excess)),
            'terminal_error': float(np.linalg.norm(states[-1] - np.asarray(x_goal))),
            'min_clearance': float(np.min(gaps)) if gaps.size else math.inf}


def ray_first_hit(q1, cx, cy, radius):
    """
    Distance along the ray s e(q1), s >= 0, to its first intersection with a circle.

    Solves |s e - c|^2 = R^2 with numpy's polynomial roots; None when the ray misses.
    """
    e = np.array([math.cos(q1), math.sin(q1)])
    roots = np.roots([1.0, -2.0 * (e @ (cx, cy)), cx * cx + cy * cy - radius * radius])
    real = roots[np.abs(roots.imag) < 1e-12].real
    ahead = real[real > 0.0]
    return float(np.min(ahead)) if ahead.size else None


def assert_feasible(problem, result, tol=1e-6):
    """
    Check a SolveResult of toc_ros against an independent re-integration (SOLVED tolerances).

    problem is a toc_ros Problem (only its plain fields are read).  Returns the measured dict.
    """
    data = problem.model.params
    robot = {'hand_mass': data.hand_mass, 'link_mass': data.link_mass,
             'inertia': data.inertia, 'a': data.a}
    u_max = np.array([data.u1_max, data.u2_max])
    circles = np.reshape(np.array(problem.obstacles, dtype=float), (-1, 3))
    circles[:, 2] += problem.margin
    n = problem.n_intervals
    controls = np.asarray(result.controls)
    assert controls.shape == (n, 2) and np.asarray(result.states).shape == (n + 1, 4)
    measured = violations(problem.x0, problem.x_goal, controls, result.final_time, circles,
                          u_max, problem.integrator, data.model_variant, robot)
    # Bounds hold exactly, not within a tolerance.
    assert np.all(np.abs(controls) <= u_max[None, :]), measured['max_control_excess']
    assert measured['terminal_error'] <= tol, measured['terminal_error']
    assert measured['min_clearance'] >= -tol, measured['min_clearance']
    # The returned states are the trajectory of the returned controls.
    np.testing.assert_allclose(result.states, measured['states'], rtol=0, atol=1e-9)
    np.testing.assert_allclose(result.time_grid, np.linspace(0.0, result.final_time, n + 1),
                               rtol=0, atol=1e-12)
    v = result.violations
    assert v.max_control_excess == measured['max_control_excess'] == 0.0
    assert abs(v.terminal_error - measured['terminal_error']) < 1e-9
    assert (v.min_clearance == measured['min_clearance'] == math.inf
            or abs(v.min_clearance - measured['min_clearance']) < 1e-9)
    if circles.shape[0]:
        # The closed form agrees with brute force (which can only over-estimate).
        closed = clearance(measured['states'], circles, robot['a'])
        sampled = sampled_clearance(measured['states'], circles, robot['a'])
        assert np.all(sampled >= closed - 1e-12) and np.max(sampled - closed) < 1e-3
    return measured


def planar_2r_f(x, u, l1=1.0, l2=0.8, m1=12.0, m2=8.0, mp=2.0, g=0.0):
    """planar_2r of issue 13 from its Lagrangian, written out here (not the package's)."""
    q1, dq1, q2, dq2 = x
    a = (m1 / 3.0 + m2 + mp) * l1 ** 2
    b = (m2 / 3.0 + mp) * l2 ** 2
    c = (m2 / 2.0 + mp) * l1 * l2
    mass = np.array([[a + b + 2.0 * c * np.cos(q2), b + c * np.cos(q2)],
                     [b + c * np.cos(q2), b]])
    coriolis = c * np.sin(q2) * np.array([-(2.0 * dq1 * dq2 + dq2 ** 2), dq1 ** 2])
    gravity = np.array([g * (m1 / 2.0 + m2 + mp) * l1 * np.cos(q1)
                        + g * (m2 / 2.0 + mp) * l2 * np.cos(q1 + q2),
                        g * (m2 / 2.0 + mp) * l2 * np.cos(q1 + q2)])
    ddq = np.linalg.solve(mass, np.asarray(u) - coriolis - gravity)
    return np.array([dq1, ddq[0], dq2, ddq[1]])
