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
How far MuJoCo (the plant) and Pinocchio (the planner's model) agree on toc_ros' arm plans.

Each case is planned in fast mode (Euler, N intervals, Pinocchio's dynamics), then its torques
(held constant over each interval) are played from the plan's start on

* Pinocchio's ABA, RK4 at the plant's step (1 kHz): the plan's own dynamics in continuous
  time; its distance to the plan is the Euler discretisation error of the plan;
* plant_node's simulator on MuJoCo (``toc_ros.plant``, engine mujoco: the same URDF, RK4 at
  1 kHz, no damping or friction, the unplanned joints locked), feed-forward only (kp = kd = 0):
  its distance to the Pinocchio run is the engines' disagreement, to the plan the open-loop
  drift the PD has to absorb;
* the same simulator with the PD of config/panda.yaml (UR5: KP, KD below): the final error
  0.5 s after the plan's end, and the largest tracking error on the way;
* the discrete stability of that PD at 1 kHz: max over random configurations of
  dt * max |eig(M(q)^-1 Kd)| (the D term acting once per step diverges above 2).

Errors are max over joints and plan nodes of |q - q_plan| [rad].  Run:
``python benchmarks/bench_mujoco_drift.py [--N 100]``; RESULTS.md, "MuJoCo against the plans".
"""

import argparse
import time

import numpy as np

CASES = {
    # name: (arm, start q, goal q, obstacle spheres (x, y, z, r))
    'panda, one sphere': ('panda', (0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785),
                          (1.2, -0.3, 0.2, -1.9, 0.1, 1.8, 0.3), ((0.45, 0.25, 0.45, 0.08),)),
    'panda, free': ('panda', (-1.2, 0.2, 0.0, -2.0, 0.0, 2.2, 0.8),
                    (1.2, 0.1, 0.3, -1.8, 0.2, 2.0, 0.3), ()),
    'ur5, one sphere': ('ur5', (0.0, -0.4, 0.4, -1.57, -1.57, 0.0),
                        (0.0, -2.0, 0.9, -1.57, -1.57, 0.0), ((0.8, 0.3, 0.9, 0.05),)),
}
# Panda: config/panda.yaml's gains; UR5: the same kp, kd 50/20/15/5 (its larger inertia keeps
# that D term stable at 1 kHz: dt * max eig(M^-1 Kd) < 2).
KP = {'panda': [600.0, 600.0, 600.0, 600.0, 250.0, 150.0, 50.0],
      'ur5': [600.0, 600.0, 600.0, 250.0, 150.0, 50.0]}
KD = {'panda': [20.0, 20.0, 20.0, 20.0, 8.0, 6.0, 2.0],
      'ur5': [50.0, 50.0, 50.0, 20.0, 15.0, 5.0]}
RATE = 1000.0           # [Hz] the plant's integration rate (plant_node's default)
SETTLE_S = 0.5          # [s] after the plan's end: the final error


def plan(arm_name, start, goal, obstacles, n_intervals):
    """Return the arm model and the result of a fast-mode solve (Euler, margin 0.02 m)."""
    from toc_ros.core import Problem, solve
    from toc_ros.core.arms import load_arm
    from toc_ros.core.arms.arm_solve import ArmRobot
    arm = load_arm(arm_name)
    problem = Problem(model=ArmRobot.shipped(arm), x0=start, x_goal=goal,
                      obstacles=list(obstacles), margin=0.02, n_intervals=n_intervals)
    result = solve(problem)
    if not result.has_trajectory:
        raise RuntimeError(f'{arm_name}: {result.status.value} {result.message}')
    return arm, result


def pinocchio_rollout(arm, x0, times, controls, rate=RATE, plant_grid=False):
    """
    Positions at the plan's nodes of ABA + RK4 at about 1 / rate under the held controls.

    plant_grid False: each interval in whole substeps (the torque switches at the nodes);
    True: steps of exactly 1 / rate from 0 with the control of the interval each step starts
    in, as the plant steps (a switch waits for the next step), positions at the first step at
    or after each node.
    """
    import pinocchio as pin
    model, data, n = arm.model, arm.model.createData(), len(arm.joint_names)

    def f(x, u):
        return np.concatenate([x[n:], pin.aba(model, data, x[:n], x[n:], u)])

    def rk4(x, u, h):
        k1 = f(x, u)
        k2 = f(x + 0.5 * h * k1, u)
        k3 = f(x + 0.5 * h * k2, u)
        k4 = f(x + h * k3, u)
        return x + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    x, out = np.array(x0, dtype=float), [np.array(x0[:n], dtype=float)]
    if plant_grid:
        step_ns = int(round(1e9 / rate))
        now = 0
        for t in times[1:]:
            while now < int(round(t * 1e9)):
                k = min(int(np.searchsorted(times, now / 1e9, side='right')) - 1,
                        len(controls) - 1)
                x = rk4(x, controls[k], step_ns / 1e9)
                now += step_ns
            out.append(x[:n].copy())
        return np.array(out)
    for k, u in enumerate(controls):
        steps = max(1, int(round((times[k + 1] - times[k]) * rate)))
        for _ in range(steps):
            x = rk4(x, u, (times[k + 1] - times[k]) / steps)
        out.append(x[:n].copy())
    return np.array(out)


def mujoco_run(arm, result, kp, kd, settle=SETTLE_S, rate=RATE):
    """
    Return (positions at the plan's nodes, final positions) of plant_node's MuJoCo simulator.

    The plan as plant_node receives it (points at the nodes, effort = the held control), from
    the plan's start state; the final positions settle seconds after the plan's end.
    """
    from toc_ros.plant.model import MujocoEngine
    from toc_ros.plant.reference import Reference
    from toc_ros.plant.simulator import PlantSimulator
    n = len(arm.joint_names)
    engine = MujocoEngine({'robot_description': arm.urdf, 'joint_names': list(arm.joint_names),
                           'payload_mass_offset': 0.0, 'inertia_scale': 1.0,
                           'integration_rate': rate})
    sim = PlantSimulator(list(arm.joint_names))
    sim.configure(engine, kp, kd, rate, 0.0, 0.0)
    states, times = result.states, result.time_grid
    sim.reset(np.ravel(np.column_stack([states[0, :n], states[0, n:]])), arm.joint_names)
    efforts = np.vstack([result.controls, result.controls[-1:]])
    sim.schedule(Reference(times, states[:, :n], states[:, n:], efforts), 0)
    out = [sim.positions.copy()]
    for t in times[1:]:         # the first step at or after each node
        sim.run(-(-int(round(t * 1e9)) // sim.dt_ns) - sim.sim_ns // sim.dt_ns)
        out.append(sim.positions.copy())
    sim.run(int(round(settle * rate)))
    return np.array(out), sim.positions.copy()


def d_term_stability(arm, kd, dt=1.0 / RATE, samples=2000, seed=0):
    """Max over random configurations (uniform within the limits) of dt * max|eig(M^-1 Kd)|."""
    import pinocchio as pin
    data, rng, worst = arm.model.createData(), np.random.default_rng(seed), 0.0
    low = np.where(np.isfinite(arm.lower), arm.lower, -np.pi)
    high = np.where(np.isfinite(arm.upper), arm.upper, np.pi)
    for _ in range(samples):
        mass = pin.crba(arm.model, data, rng.uniform(low, high))
        mass = np.triu(mass) + np.triu(mass, 1).T
        rate = np.max(np.abs(np.linalg.eigvals(np.linalg.solve(mass, np.diag(kd)))))
        worst = max(worst, float(dt * rate))
    return worst


def measure(name, n_intervals):
    """Plan one case and return its row of errors [rad] and times [s]."""
    arm_name, start, goal, obstacles = CASES[name]
    started = time.perf_counter()
    arm, result = plan(arm_name, start, goal, obstacles, n_intervals)
    solve_s = time.perf_counter() - started
    n = len(arm.joint_names)
    q_plan = result.states[:, :n]
    q_pin = pinocchio_rollout(arm, result.states[0], result.time_grid, result.controls)
    q_grid = pinocchio_rollout(arm, result.states[0], result.time_grid, result.controls,
                               plant_grid=True)
    q_open, _ = mujoco_run(arm, result, np.zeros(n), np.zeros(n))
    q_pd, q_final = mujoco_run(arm, result, KP[arm_name], KD[arm_name])

    def worst(a, b):
        return float(np.max(np.abs(a - b)))
    return {'case': name, 't_f': float(result.final_time), 'status': result.status.value,
            'solve_s': solve_s, 'plan_vs_pinocchio': worst(q_plan, q_pin),
            'grid_vs_pinocchio': worst(q_grid, q_pin),
            'mujoco_vs_pinocchio': worst(q_open, q_grid),
            'open_loop_drift': worst(q_open, q_plan),
            'open_loop_end': worst(q_open[-1], q_plan[-1]),
            'pd_tracking': worst(q_pd, q_plan), 'pd_final': worst(q_final, np.asarray(goal)),
            'd_term': d_term_stability(arm, KD[arm_name])}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--N', type=int, default=100, help='Euler intervals of each plan')
    parser.add_argument('--cases', nargs='*', default=list(CASES), choices=list(CASES))
    args = parser.parse_args(argv)
    print('| case | status | t_f [s] | plan (Euler) vs Pinocchio RK4 | switches on the 1 kHz '
          'grid vs at the nodes | MuJoCo vs Pinocchio, same grid | open-loop drift, max / at the '
          'end | PD tracking, max | PD final, '
          f'{SETTLE_S} s after | D term at 1 kHz, max |')
    print('|---|---|---:|---:|---:|---:|---:|---:|---:|---:|')
    for name in args.cases:
        r = measure(name, args.N)
        print(f"| {r['case']} | {r['status']} | {r['t_f']:.4f} | {r['plan_vs_pinocchio']:.2e} | "
              f"{r['grid_vs_pinocchio']:.2e} | {r['mujoco_vs_pinocchio']:.2e} | "
              f"{r['open_loop_drift']:.2e} / "
              f"{r['open_loop_end']:.2e} | {r['pd_tracking']:.2e} | {r['pd_final']:.2e} | "
              f"{r['d_term']:.2f} |",
              flush=True)


if __name__ == '__main__':
    main()
