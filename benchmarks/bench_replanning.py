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
Online replanning in the closed loop (issue 12): open loop against replanning, real nodes.

solver_node and plant_node run as processes on a private ROS domain (the shipped parameter
file, solver.N = --N, solver.integrator = --integrator); each scenario is executed once with
replan.rate = 0 (plan once, the plant's PD tracks it) and once with replan.rate = --rate, from
the paper's start to its goal around its circle:

* mismatch: the plant's payload +20 % (hand_mass 50 -> 60 kg) and inertia x 1.2; run a third
  time with replan.estimate = hand_mass, inertia (the cycles plan with the online estimate);
* lag: a 10 ms first-order actuator lag on the plant (plant_node actuator_lag); run a third
  time with the planner told the lag (robot.actuator_lag: plans with actuator states);
* moving: a second circle moves into the path during the execution (the plant matches the
  model); the arm must keep clear of it and still arrive.

Reported per run (toc_ros.analysis.closed_loop.execution_metrics, from the joint_states,
trajectory and ~/progress messages received): the final position error 0.2 s after the end of
the last plan, the arrival time (every joint within 1e-2 of the goal from then on) against
the arrival time of the true plant's best plan by the same rule (fast mode on the plant's own
parameters; for the lag the model with the lag's actuator states), the last plan's end
(where the planner has the arm at
rest at the goal) against that plan's t_min, the executed clearance to every true circle (no
margin) over all joint_states, and the replan cycle latency (joint_states received ->
trajectory published, measured in solver_node) median / p99 / max over the whole execution.

    PYTHONPATH=. python benchmarks/bench_replanning.py [--N 1000] [--integrator rk4]
        [--rate 20] [--scenarios mismatch lag moving] [--markdown FILE] [--json FILE]

--configs compares closed-loop settings on the mismatch scenario with estimation instead:
each CONFIG is GOAL_INTEGRATOR/CYCLE_INTEGRATOR/MAX_NODES (solver.integrator,
replan.integrator, replan.max_nodes; 'default' for the node's default), run --repeat times
round-robin after one unrecorded run each (the configurations see the same machine load),
against the true plant's best RK4
plan; reported per run and per configuration (the median and range of the runs, and the
latency percentiles of all their published cycles pooled):

    PYTHONPATH=. python benchmarks/bench_replanning.py --repeat 3
        --configs euler/euler/300 default/default/default
"""

import argparse
import json
import math
import os
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Float64MultiArray  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402
from benchmarks.bench_solvers import write_outputs  # noqa: E402, I100
from toc_ros import config, harness  # noqa: E402
from toc_ros.demo.closed_loop import (  # noqa: E402
    ESTIMATED, MISMATCH, MOVING, MOVING_MARGIN, MOVING_OBSTACLES, NOMINAL_PLANT, PAPER_GOAL_Q,
    PAPER_OBSTACLES, run_execution, true_reference, TRUE_ROBOT)
from toc_ros.nodes.parameters import SolverNodeSettings  # noqa: E402
from trajectory_msgs.msg import JointTrajectory  # noqa: E402
from diagnostic_msgs.msg import DiagnosticStatus  # noqa: E402, I100

# The plant's actuator lag in the lag scenario [s]; the planner is told it in a third run.
LAG = 0.01
SCENARIOS = {
    'mismatch': {'plant': MISMATCH, 'true': TRUE_ROBOT, 'estimate': ESTIMATED},
    'lag': {'plant': {'actuator_lag': LAG}, 'true': {'robot.actuator_lag': LAG},
            'actuators': {'robot.actuator_lag': LAG}},
    'moving': {'plant': {}, 'true': {}, 'moving': MOVING, 'obstacles': MOVING_OBSTACLES,
               'margin': MOVING_MARGIN},
}


def _table(rows):
    lines = ['| scenario | loop | planned t_min [s] | true t_min [s] | arrival [s] | '
             "arrival / true plan's | last plan end / true t_min | final error (end + 0.2 s) "
             '| min clearance [m] | plans | kept | latency median / p99 / max [ms] |',
             '|' + '---|' * 12]
    for r in rows:
        m, true = r['metrics'], r['true']
        lat = ('-' if not m['latencies'] else
               f"{1e3 * m['latency_median_s']:.1f} / {1e3 * m['latency_p99_s']:.1f} / "
               f"{1e3 * m['latency_max_s']:.1f}")
        lines.append(
            f"| {r['scenario']} | {r['loop']} | {m['planned_t_min']:.4f} | "
            f"{true['t_min']:.4f} | {m['arrival_s']:.4f} | "
            f"{m['arrival_s'] / true['arrival_s']:.4f} | "
            f"{m['last_plan_end_s'] / true['t_min']:.4f} | "
            f"{m['final_error']:.2e} | {m['min_clearance']:.4f} | {m['plans']} | "
            f"{m['replans_kept']} | {lat} |")
    return '\n'.join(lines)


def _config(text):
    """Return (label, solver.integrator, replan.integrator, replan.max_nodes) of a CONFIG."""
    parts = text.split('/')
    if len(parts) != 3 or any(p not in ('euler', 'rk4', 'default') for p in parts[:2]) \
            or not (parts[2] == 'default' or parts[2].isdigit()):
        raise argparse.ArgumentTypeError(
            f'{text!r}: expected GOAL/CYCLE/MAX_NODES, e.g. euler/rk4/150 or '
            'default/default/default')
    goal, cycle, nodes = (None if p == 'default' else p for p in parts)
    return text, goal, cycle, None if nodes is None else int(nodes)


def _percentiles(values):
    values = np.asarray(values, dtype=float)
    if not values.size:
        return math.nan, math.nan, math.nan
    return (float(np.percentile(values, 50)), float(np.percentile(values, 99)),
            float(values.max()))


def _compare_table(rows, configs):
    """Per-run rows and a per-configuration summary (medians, ranges, pooled latencies)."""
    lines = ['| configuration (goal / cycle integrator / max_nodes) | run | arrival [s] | '
             "arrival / true plan's | final error | plans | kept | "
             'latency median / p99 / max [ms] |', '|---|---:|---:|---:|---:|---:|---:|---|']
    for r in rows:
        m = r['metrics']
        lat = _percentiles(r['latencies_s'])
        lines.append(
            f"| {r['config']} | {r['run']} | {m['arrival_s']:.4f} | "
            f"{m['arrival_s'] / r['true']['arrival_s']:.4f} | {m['final_error']:.2e} | "
            f"{m['plans']} | {m['replans_kept']} | "
            f'{1e3 * lat[0]:.1f} / {1e3 * lat[1]:.1f} / {1e3 * lat[2]:.1f} |')
    lines += ['', '| configuration | runs | arrival / true: median (min - max) | '
              'runs without a published cycle | per-run latency median [ms]: median (min - max) '
              '| per-run p99 [ms]: min - max | pooled cycles | pooled median / p99 / max [ms] |',
              '|---|---:|---|---:|---|---|---:|---|']
    for label, *_ in configs:
        mine = [r for r in rows if r['config'] == label]
        ratios = [r['metrics']['arrival_s'] / r['true']['arrival_s'] for r in mine]
        # Latencies of the runs that published cycles (a run without one has none).
        published = [r for r in mine if r['latencies_s']]
        medians = [1e3 * _percentiles(r['latencies_s'])[0] for r in published] or [math.nan]
        p99s = [1e3 * _percentiles(r['latencies_s'])[1] for r in published] or [math.nan]
        pooled = [t for r in mine for t in r['latencies_s']]
        p = _percentiles(pooled)
        lines.append(
            f'| {label} | {len(mine)} | {np.median(ratios):.4f} ({min(ratios):.4f} - '
            f'{max(ratios):.4f}) | {len(mine) - len(published)} | '
            f'{np.median(medians):.1f} ({min(medians):.1f} - '
            f'{max(medians):.1f}) | {min(p99s):.1f} - {max(p99s):.1f} | {len(pooled)} | '
            f'{1e3 * p[0]:.1f} / {1e3 * p[1]:.1f} / {1e3 * p[2]:.1f} |')
    return '\n'.join(lines)


def compare(client, publishers, params, model, joint_names, args):
    """Run every --configs configuration --repeat times round-robin; return rows."""
    spec = SCENARIOS['mismatch']
    reference = true_reference(dict(params, **{'solver.N': args.N, 'solver.integrator': 'rk4'}),
                               spec['true'], PAPER_GOAL_Q, PAPER_OBSTACLES)
    rows = []
    # Run 0 of each configuration is not recorded: a configuration's first cycles compile its
    # kernels in solver_node (numba), which takes seconds.
    for run in range(-1, args.repeat):
        for label, goal, cycle, nodes in args.configs:
            execution = run_execution(
                client, publishers, model, joint_names, PAPER_GOAL_Q, PAPER_OBSTACLES,
                plant=dict(NOMINAL_PLANT, **spec['plant']), replan_rate=args.rate,
                estimate=spec['estimate'], integrator=goal, max_nodes=nodes,
                solver=None if cycle is None else {'replan.integrator': cycle})
            if run < 0:
                continue
            row = {'config': label, 'run': run + 1, 'true': reference,
                   'metrics': execution.metrics,
                   'latencies_s': [r.latency_s for r in execution.reports
                                   if r.event == 'replanned']}
            rows.append(row)
            print(json.dumps(row), flush=True)
            time.sleep(0.5)
    return rows


def main(argv=None):
    """Run the scenarios and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[1])
    parser.add_argument('--N', type=int, default=1000)
    parser.add_argument('--integrator', default='rk4', choices=('euler', 'rk4'),
                        help='solver.integrator (rk4: the plan is what the plant does under '
                        'its piecewise-constant controls)')
    parser.add_argument('--rate', type=float, default=20.0)
    parser.add_argument('--max-nodes', type=int, default=SolverNodeSettings().replan_max_nodes,
                        help="solver_node's replan.max_nodes (default: the node's)")
    parser.add_argument('--scenarios', nargs='+', default=list(SCENARIOS),
                        choices=list(SCENARIOS))
    parser.add_argument('--configs', nargs='+', type=_config, metavar='CONFIG',
                        help='compare GOAL/CYCLE/MAX_NODES configurations (above)')
    parser.add_argument('--repeat', type=int, default=3, help='runs per --configs entry')
    parser.add_argument('--markdown')
    parser.add_argument('--json')
    args = parser.parse_args(argv)
    params_file = config.default_config_path()
    params = config.load_parameters(params_file, 'solver_node')
    model = config.model_from_parameters(params)
    joint_names = list(params['joint_names'])
    log_dir = tempfile.mkdtemp(prefix='bench_replanning_')
    client = harness.RosClient('bench_replanning')
    nodes = [harness.NodeProcess('solver_node', client.namespace, log_dir,
                                 {'solver.N': args.N, 'solver.timeout': 30.0}, params_file),
             harness.NodeProcess('plant_node', client.namespace, log_dir, None, params_file)]
    rows = []
    try:
        client.collect(DiagnosticStatus, 'solver_node/progress', 100, keep=20000)
        client.collect(JointState, 'joint_states', 100, keep=20000)
        client.collect(JointTrajectory, 'trajectory', harness.LATCHED_HISTORY, keep=2000)
        goal_pub = client.node.create_publisher(JointState, client.name('goal_joints'), 10)
        obstacles_pub = client.node.create_publisher(
            Float64MultiArray, client.name('obstacles'), 10)
        ready = client.node.create_client(Trigger, client.name('solver_node/ready'))
        client.wait_for(lambda: client.call(ready, Trigger.Request(), 300.0).success, 600.0,
                        'solver_node ready')
        client.wait_for(lambda: goal_pub.get_subscription_count() > 0
                        and obstacles_pub.get_subscription_count() > 0
                        and client.count('joint_states') > 10, 60.0, 'the nodes')
        if args.configs:
            rows = compare(client, (goal_pub, obstacles_pub), params, model, joint_names, args)
        for name in ([] if args.configs else args.scenarios):
            spec = SCENARIOS[name]
            obstacles = spec.get('obstacles', PAPER_OBSTACLES)
            if spec.get('moving') is not None:      # the circle's final place
                obstacles = spec['moving'].rows(obstacles, math.inf)
            reference = true_reference(dict(params, **{'solver.N': args.N,
                                                       'solver.integrator': args.integrator}),
                                       spec['true'], PAPER_GOAL_Q, obstacles, spec.get('margin'))
            loops = [('open loop', 0.0, (), None), ('replanning', args.rate, (), None)]
            if spec.get('estimate'):
                loops.append(('replanning + estimation', args.rate, spec['estimate'], None))
            if spec.get('actuators'):
                loops += [('open loop + actuator model', 0.0, (), spec['actuators']),
                          ('replanning + actuator model', args.rate, (), spec['actuators'])]
            for loop, rate, estimate, solver in loops:
                plant = dict(NOMINAL_PLANT, **spec['plant'])
                execution = run_execution(
                    client, (goal_pub, obstacles_pub), model, joint_names, PAPER_GOAL_Q,
                    spec.get('obstacles', PAPER_OBSTACLES), plant=plant, replan_rate=rate,
                    moving=spec.get('moving'), margin=spec.get('margin'), estimate=estimate,
                    integrator=args.integrator, max_nodes=args.max_nodes, solver=solver)
                cycles = [r for r in execution.reports if r.event == 'replanned']
                row = {'scenario': name, 'loop': loop, 'true': reference,
                       'metrics': execution.metrics,
                       # per published cycle: solve time and stamp lead over its state [s]
                       'cycle_solve_s': [r.elapsed_s for r in cycles],
                       'cycle_lead_s': [r.plan_stamp - r.state_stamp for r in cycles],
                       'kept': [r.message for r in execution.reports
                                if r.event == 'replan_kept'],
                       'estimates': [r.estimate for r in cycles if r.estimate]}
                rows.append(row)
                print(json.dumps(row), flush=True)
                time.sleep(0.5)
    finally:
        for node in nodes:
            node.stop()
        client.close()
    load = os.getloadavg()
    if args.configs:
        text = (f'bench_replanning --configs: mismatch with replan.estimate [hand_mass, '
                f'inertia], first plan N = {args.N}, replan.rate = {args.rate} Hz, '
                f'{args.repeat} runs each, true plan RK4, load {load[0]:.2f}\n\n'
                + _compare_table(rows, args.configs))
        write_outputs(text + '\n', {'N': args.N, 'rate': args.rate, 'rows': rows},
                      args.markdown, args.json)
        return 0
    text = (f'bench_replanning: N = {args.N}, solver.integrator = {args.integrator}, '
            f'replan.rate = {args.rate} Hz, replan.max_nodes = {args.max_nodes}, '
            f'load {load[0]:.2f}\n\n' + _table(rows))
    data = {'N': args.N, 'integrator': args.integrator, 'rate': args.rate, 'rows': rows}
    write_outputs(text + '\n', data, args.markdown, args.json)
    return 0


if __name__ == '__main__':
    sys.exit(main())
