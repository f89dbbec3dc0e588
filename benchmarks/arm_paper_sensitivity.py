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
Why paper mode is not offered for URDF arms: the BPTT gradient of J_T through an arm.

The paper's heuristic (section 3) descends J_T = J1 + J2 + J3 with a constant learning rate
along the BPTT gradient of a single-shooting rollout.  Written here for an arm (the Panda or the
UR5 of bench_arm_fast.py, free), with the paper's constants (PaperOptions) and the controls
scaled by the efforts:

    J1 = K_B |x(N) - x_goal|^2,  J2 = K_V-hat sum H-(g) g^2 (g = 1 - |u| / u_max),
    J3 = K_p-hat sum H-(g) g^2 over the joint position and velocity limits at nodes 1..N,

from the torques that make the Euler rollout follow the straight joint path's velocities over
t_f0 (its terminal error ~1e-4).  Printed per arm, t_f0 and N: J_T there, and the gradient's
norm at a point 1e-3 (relative to the efforts) off those torques, with the central difference
of J_T along a random direction against the gradient's projection (the gradient is right where
J_T is finite).  The arms under gravity are unstable in open loop: the gradient grows like
e^(lambda t_f) and a constant learning rate that moves the controls at all leaves the region
where J_T is finite (fast mode has the defects as constraints, multiple shooting, and does not
integrate the open loop).

    PYTHONPATH=. .venv/bin/python benchmarks/arm_paper_sensitivity.py [--N 100] [--t-f0 1.3 2.5]
"""

import argparse
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from benchmarks.bench_arm_fast import SCENARIOS  # noqa: E402, I100
from toc_ros.core.arms import load_arm  # noqa: E402
from toc_ros.core.arms.arm_eval import ArmEvaluator  # noqa: E402
from toc_ros.core.arms.arm_start import cubic_path  # noqa: E402
from toc_ros.core.arms.arm_warm import rollout  # noqa: E402
from toc_ros.core.problem import PaperOptions  # noqa: E402
import pinocchio as pin  # noqa: E402, I100


def tracking_torques(arm, x0, x_goal, n_int, t_f):
    """Torques (N, n) whose Euler rollout follows the cubic path's velocities over t_f."""
    n, h = arm.n, t_f / n_int
    path = cubic_path(x0, x_goal, t_f, n_int)
    data = arm.model.createData()
    x, torques = x0.copy(), np.empty((n_int, n))
    for k in range(n_int):
        acc = (path[k + 1, n:] - x[n:]) / h
        torques[k] = np.clip(pin.rnea(arm.model, data, x[:n], x[n:], acc), -arm.effort,
                             arm.effort)
        x = x + h * np.concatenate([x[n:], pin.aba(arm.model, data, x[:n], x[n:], torques[k])])
    return torques


def cost_gradient(arm, evaluator, x0, x_goal, v, t_f, t_f0, po):
    """(J_T, dJ_T/dv) at scaled controls v (module docstring), by the adjoint of bptt.py."""
    n, n_int = arm.n, v.shape[0]
    tau0 = t_f0 / n_int
    states = rollout(arm, x0, v * arm.effort[None, :], t_f, 'euler')
    terms = evaluator.stage_terms(states, v, t_f, np.zeros_like(states), hessian='none')
    grad_x = np.zeros_like(states)
    err = states[-1] - x_goal
    total = po.k_b * float(err @ err)
    grad_x[-1] += 2.0 * po.k_b * err
    excess = np.maximum(np.abs(v) - 1.0, 0.0)
    total += tau0 * po.k_v * float(np.sum(excess * excess))
    grad_v = 2.0 * tau0 * po.k_v * excess * np.sign(v)
    q, dq = states[1:, :n], states[1:, n:]
    for g, sign, part in ((arm.upper - q, -1.0, slice(0, n)), (q - arm.lower, 1.0, slice(0, n)),
                          (arm.velocity - dq, -1.0, slice(n, 2 * n)),
                          (dq + arm.velocity, 1.0, slice(n, 2 * n))):
        short = np.minimum(np.where(np.isfinite(g), g, 0.0), 0.0)
        total += tau0 * po.k_p * float(np.sum(short * short))
        grad_x[1:, part] += 2.0 * tau0 * po.k_p * sign * short
    lam = grad_x[-1]
    for k in range(n_int - 1, -1, -1):
        grad_v[k] += terms['b'][k].T @ lam
        lam = grad_x[k] + terms['a'][k].T @ lam
    return total, grad_v


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--arms', nargs='+', default=['panda', 'ur5'])
    parser.add_argument('--N', type=int, default=100)
    parser.add_argument('--t-f0', type=float, nargs='+', default=[1.3, 1.6, 2.5])
    args = parser.parse_args(argv)
    po = PaperOptions()
    rng = np.random.default_rng(0)
    print('| arm | N | t_f0 [s] | J_T at the tracking torques | |grad| 1e-3 off them | '
          'central difference / projection |')
    print('|---|---|---|---|---|---|')
    for name in args.arms:
        start, goal, _ = SCENARIOS[name]
        arm = load_arm(name)
        x0 = np.concatenate([start, np.zeros(arm.n)])
        x_goal = np.concatenate([goal, np.zeros(arm.n)])
        evaluator = ArmEvaluator(arm, None, np.zeros((0, 4)), 0.0, args.N)
        for t_f0 in args.t_f0:
            v0 = tracking_torques(arm, x0, x_goal, args.N, t_f0) / arm.effort[None, :]
            j0, _ = cost_gradient(arm, evaluator, x0, x_goal, v0, t_f0, t_f0, po)
            v = v0 + 1e-3 * rng.standard_normal(v0.shape)
            with np.errstate(all='ignore'):
                _, grad = cost_gradient(arm, evaluator, x0, x_goal, v, t_f0, t_f0, po)
                d, eps = rng.standard_normal(v.shape), 1e-7
                diff = (cost_gradient(arm, evaluator, x0, x_goal, v + eps * d, t_f0, t_f0, po)[0]
                        - cost_gradient(arm, evaluator, x0, x_goal, v - eps * d, t_f0, t_f0,
                                        po)[0]) / (2 * eps)
                print(f'| {name} | {args.N} | {t_f0:g} | {j0:.3g} | '
                      f'{np.linalg.norm(grad):.3g} | {diff:.6g} / {np.sum(grad * d):.6g} |',
                      flush=True)


if __name__ == '__main__':
    main()
