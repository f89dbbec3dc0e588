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
The summary entries of a run report: per plan, per execution and per closed-loop execution.

Violations are recomputed from the recorded trajectories (not taken from the solver's reports,
which are listed beside them), tracking errors from the joint_states against the plan's
reference at the same times.
"""

from typing import List

import numpy as np

from toc_ros.conversions import as_model
from toc_ros.core.obstacles import model_clearance

from .recorded_loops import ClosedLoop
from .recorded_plans import Execution, Plan
from .recorded_run import as_float, hand_xy, json_number, Solve


def closed_loop_numbers(loop: ClosedLoop, plans: List[Plan]) -> dict:
    """Summary entry of a closed-loop execution (times from its t0 unless said otherwise)."""
    m = loop.metrics
    mine = [plans[i] for i in loop.plans]
    late = [p.time - p.start for p in mine if p.stamp is not None and p.time > p.start]

    def latency(prefix, count):
        return {'median_s': json_number(m[f'{prefix}_median_s']),
                'p99_s': json_number(m[f'{prefix}_p99_s']),
                'max_s': json_number(m[f'{prefix}_max_s']), 'count': count}
    return {
        'index': loop.index,
        'plans': loop.plans,
        'plan_count': len(loop.plans),
        'executed_plans': sum(p.executed for p in mine),
        'goal': loop.goal.tolist(),
        'goal_source': loop.goal_source or None,
        'start_s': loop.t0,
        'samples': int(loop.times.size),
        'events': loop.events,
        'planned_t_min': json_number(m['planned_t_min']),
        'arrival_s': json_number(m['arrival_s']),
        'last_plan_end_s': json_number(m['last_plan_end_s']),
        'final_error': json_number(m['final_error']),
        'min_clearance': json_number(m['min_clearance']),
        # plans the recorder received after their stamp (the plant trims their start)
        'late_receipts': {'count': len(late), 'max_s': max(late) if late else None},
        'planned_arrivals': [{'plan': p.index, 'received_s': p.time - loop.t0,
                              'arrival_s': p.start + p.duration - loop.t0,
                              'executed': p.executed} for p in mine],
        'latency_node': latency('latency', m['latencies']),
        'latency_recorded': {**latency('recorded_latency', m['recorded_latencies']),
                             'unmatched': loop.unmatched},
    }


def plan_numbers(plan: Plan, u_max: np.ndarray, a, start_state=None) -> dict:
    """Summary entry of a plan (a: RobotModel or hand offset): report and violations."""
    solve = plan.solve or Solve(status='unknown')
    report = solve.report
    excess = None
    if plan.efforts is not None:
        excess = max(float(np.max(np.abs(plan.efforts) - u_max[None, :])), 0.0)
    circles = plan.obstacles.copy()
    circles[:, 2] += plan.margin
    clearance = (float(np.min(model_clearance(as_model(a), plan.states, circles)))
                 if len(circles) else None)
    terminal = (float(np.linalg.norm(plan.states[-1] - plan.goal))
                if plan.goal is not None else None)
    start_error = (float(np.linalg.norm(plan.states[0] - start_state))
                   if start_state is not None else None)
    return {
        'index': plan.index,
        'received_s': plan.time,
        'stamp_s': plan.stamp,
        'start_s': plan.start,
        'executed': plan.executed,
        'closed_loop': plan.execution,
        'event': report.event or None,
        'status': solve.status,
        'message': solve.message,
        't_min': float(plan.times[-1]),
        'solve_wall_time_s': json_number(as_float(report.elapsed_s)),
        'iterations': report.iteration,
        'points': int(plan.times.size),
        'joint_names': plan.joint_names,
        'goal': None if plan.goal is None else plan.goal.tolist(),
        'goal_source': plan.goal_source or None,
        'obstacles': plan.obstacles.tolist(),
        'obstacles_source': plan.obstacles_source,
        'margin': plan.margin,
        'margin_source': plan.margin_source,
        'violations': {'max_control_excess': json_number(excess),
                       'terminal_error': json_number(terminal),
                       'min_clearance': json_number(clearance),
                       'start_error': json_number(start_error)},
        'reported_violations': {
            'max_control_excess': json_number(as_float(report.max_control_excess)),
            'terminal_error': json_number(as_float(report.terminal_error)),
            'min_clearance': json_number(as_float(report.min_clearance))},
    }


def tracking_errors(execution: Execution, a) -> dict:
    """Per-sample errors: q1, q2 [rad or m] and hand position [m] (measured - planned)."""
    meas, ref = execution.states, execution.reference
    model = as_model(a)
    hand_m = np.column_stack(hand_xy(model, meas))
    hand_r = np.column_stack(hand_xy(model, ref))
    return {'q1': meas[:, 0] - ref[:, 0], 'q2': meas[:, 2] - ref[:, 2],
            'hand': np.hypot(*(hand_m - hand_r).T)}


def execution_numbers(execution: Execution, plan: Plan, a, u_max: np.ndarray) -> dict:
    """Summary entry of an execution: final error, RMS tracking error, max effort."""
    errors = tracking_errors(execution, a)
    final = execution.states[-1]
    target = plan.states[-1]
    model = as_model(a)
    hand_final = np.hypot(*(np.array(hand_xy(model, final)) - np.array(hand_xy(model, target))))
    max_effort = (None if execution.efforts is None
                  else np.nanmax(np.abs(execution.efforts), axis=0))
    return {
        'plan': execution.plan,
        'start_s': float(execution.times[0]),
        'end_s': float(execution.times[-1]),
        'samples': int(execution.times.size),
        'interrupted': bool(execution.interrupted),
        'final_error': float(np.linalg.norm(final - target)),
        'final_state': final.tolist(),
        'final_hand_error': float(hand_final),
        'rms_error': {k: float(np.sqrt(np.mean(v ** 2))) for k, v in errors.items()},
        'max_hand_error': float(np.max(errors['hand'])),
        'max_effort': None if max_effort is None else max_effort.tolist(),
        'effort_within_bounds': (None if max_effort is None
                                 else bool(np.all(max_effort <= u_max * (1 + 1e-9)))),
    }
