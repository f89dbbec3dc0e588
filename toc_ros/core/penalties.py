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
Penalty terms of the paper's cost, eq. (6): J1 (eq. 7), J2 (eqs. 8-9), J3 (eq. 42).

Each function returns its value and writes (J2, J3) or adds (J1) its partial derivatives to
caller-owned gradient buffers (grad_x: N+1 x 4 over the states, grad_u: N x 2 over the
controls), which the BPTT recursion (bptt.py) then propagates back through the dynamics.
"""

from numba import njit

from .obstacles import obstacle_penalty


@njit(cache=True)
def terminal_penalty(x_final, x_goal, k_b, grad_x_final):
    """J1 = K_B sum_k (x_k(N) - x_k(t_f))^2, eq. (7); adds dJ1/dx(N) (G_x(N) of eq. 30)."""
    total = 0.0
    for k in range(x_final.shape[0]):
        err = x_final[k] - x_goal[k]
        total += k_b * err * err
        grad_x_final[k] += 2.0 * k_b * err
    return total


@njit(cache=True)
def control_bound_penalty(controls, u_max, k_v_hat, grad_u):
    """
    J2 of eq. (8) with g = (u_max - u, u_max + u) >= 0 and the Heaviside H- of eq. (9).

    Writes dJ2/du into every entry of grad_u (N x 2).
    """
    total = 0.0
    for i in range(controls.shape[0]):
        for k in range(controls.shape[1]):
            u = controls[i, k]
            if u > u_max[k]:          # g = u_max - u < 0, dg/du = -1
                g = u_max[k] - u
                total += k_v_hat * g * g
                grad_u[i, k] = -2.0 * k_v_hat * g
            elif u < -u_max[k]:       # g = u_max + u < 0, dg/du = +1
                g = u_max[k] + u
                total += k_v_hat * g * g
                grad_u[i, k] = 2.0 * k_v_hat * g
            else:
                grad_u[i, k] = 0.0
    return total


@njit(cache=True)
def paper_penalties(states, controls, x_goal, u_max, a, circles, k_b, k_v_hat, k_p_hat,
                    grad_mode, grad_x, grad_u):
    """J_T = J1 + J2 + J3 of eq. (33); returns (J1, J2, J3) and fills the gradient buffers."""
    n = controls.shape[0]
    # J3 and J2 overwrite their buffers entirely; J1 then adds to the last row.
    j3 = obstacle_penalty(states, a, circles, k_p_hat, grad_mode, grad_x)
    j2 = control_bound_penalty(controls, u_max, k_v_hat, grad_u)
    j1 = terminal_penalty(states[n], x_goal, k_b, grad_x[n])
    return j1, j2, j3
