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
Receding-horizon helpers (ROS-free): predict the state along a plan, and a braking stop.

A replan cycle starts the new plan a little in the future (the solve and transport latency),
so it must start from where the robot will be then: ``predict`` integrates the measured state
forward under the executing plan's piecewise-constant controls with the model's RK4 step.
``brake`` is the stop for an infeasible situation: every joint decelerates at its full
control bound until it rests, the fastest stop a bang-bang control allows per joint;
``stop_later_is_clear`` tells whether that stop may still wait.
"""

import math

import numpy as np

from toc_ros.core.horizon import integrator_id
from toc_ros.core.obstacles import model_clearance

RK4 = integrator_id('rk4')
# Largest RK4 step of a prediction [s]: well below the plans' tau (~2 ms at N = 1000).
PREDICT_STEP_S = 1e-3
# The braking control is bang-bang away from rest and linear below this joint speed, so that
# it comes to rest without chattering [rad/s or m/s].
BRAKE_SMOOTHING_SPEED = 0.02
BRAKE_REST_SPEED = 1e-4
BRAKE_MAX_S = 5.0


def control_at(times, controls, t):
    """Return the plan's piecewise-constant control at plan time t (zero outside the plan)."""
    return controls_at(times, controls, np.array([float(t)]))[0]


def controls_at(times, controls, t):
    """Return the controls at every time of the array t (rows; zero outside the plan)."""
    t = np.asarray(t, dtype=float)
    index = np.clip(np.searchsorted(times, t, side='right') - 1, 0, controls.shape[0] - 1)
    inside = (t >= times[0]) & (t < times[-1])
    return np.where(inside[:, None], np.asarray(controls, dtype=float)[index], 0.0)


def predict(model, x, times, controls, t0, t1):
    """
    Return the state at plan time t1 from state x at plan time t0 under the plan's controls.

    times (N + 1,) and controls (N, nu) are the executing plan's grid and controls; outside
    the plan the control is zero (the tracker holds the end).  t1 <= t0 returns x.
    """
    x = np.ascontiguousarray(x, dtype=float)
    if getattr(model, 'is_arm', False):
        return _predict_arm(model.arm, x, times, controls, t0, t1)
    span = float(t1) - float(t0)
    if not span > 0.0:
        return x.copy()
    steps = max(1, math.ceil(span / PREDICT_STEP_S))
    dt = span / steps
    mids = float(t0) + dt * (np.arange(steps) + 0.5)
    u = controls_at(times, controls, mids)
    states = np.empty((steps + 1, model.nx))
    model.kernels.rollout(x, np.ascontiguousarray(u), dt, model.packed(), RK4, states)
    return states[-1].copy()


def _predict_arm(arm, x, times, controls, t0, t1):
    """
    Return predict()'s state for a URDF arm (x = (q, dq); pinocchio.aba, RK4 steps).

    After the plan's end the tracker holds its end (an arm without torque would fall): the
    prediction stops there.
    """
    import pinocchio as pin
    span = min(float(t1), float(times[-1])) - float(t0)
    if not span > 0.0:
        return x.copy()
    steps = max(1, math.ceil(span / PREDICT_STEP_S))
    dt = span / steps
    u = controls_at(times, controls, float(t0) + dt * (np.arange(steps) + 0.5))
    model, n = arm.model, arm.n
    data = model.createData()

    def rate(state, control):
        return np.concatenate([state[n:], pin.aba(model, data, state[:n], state[n:], control)])

    for control in u:
        k1 = rate(x, control)
        k2 = rate(x + 0.5 * dt * k1, control)
        k3 = rate(x + 0.5 * dt * k2, control)
        k4 = rate(x + dt * k3, control)
        x = x + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return x


def brake(model, x, dt):
    """
    Return (times, states, controls) of the fastest per-joint stop from state x.

    Each joint's control is -u_max sign(velocity), linear below BRAKE_SMOOTHING_SPEED; the
    rollout ends once every joint speed is below BRAKE_REST_SPEED (at most BRAKE_MAX_S), and
    the last state is the rest state (zero velocity).  controls has one row per interval.
    """
    u_max = np.asarray(model.u_max, dtype=float)
    state = np.ascontiguousarray(x, dtype=float).copy()
    p = model.packed()
    pair = np.empty((2, model.nx))
    states, controls = [state.copy()], []
    for _ in range(int(BRAKE_MAX_S / dt)):
        speed = model.velocities(state)
        if np.max(np.abs(speed)) < BRAKE_REST_SPEED:
            break
        u = -u_max * np.clip(speed / BRAKE_SMOOTHING_SPEED, -1.0, 1.0)
        model.kernels.rollout(state, u.reshape(1, -1), dt, p, RK4, pair)
        state = pair[1].copy()
        states.append(state.copy())
        controls.append(u)
    if not controls:         # already at rest: hold for one step
        states.append(state.copy())
        controls.append(np.zeros(model.nu))
    states = np.array(states)
    states[-1, 1:2 * model.n_joints:2] = 0.0
    return dt * np.arange(len(states)), states, np.array(controls)


def stop_later_is_clear(model, x, times, controls, t0, wait, circles, dt):
    """
    Return whether the fastest stop started wait [s] from now keeps every link out of circles.

    x: the state at plan time t0 of the executing plan (times, controls), which the robot
    follows for wait before braking (``brake`` with step dt); circles: rows (x, y, radius)
    of the true obstacles.  The plan itself up to t0 + wait is not checked here.
    """
    start = predict(model, x, times, controls, t0, t0 + wait)
    stop = brake(model, start, dt)[1]
    rows = np.asarray(circles, dtype=float).reshape(-1, 3)
    return not len(rows) or bool(np.min(model_clearance(model, stop, rows)) >= 0.0)
