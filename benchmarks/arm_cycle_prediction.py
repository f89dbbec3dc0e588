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
How well a replan cycle's start is predicted on a recorded Panda demo run (offline).

    python benchmarks/arm_cycle_prediction.py RUN_DIR HORIZON_S

For every joint_states sample while a plan is the one executed (before the next plan's
stamp), the state HORIZON_S later is predicted four ways and compared with the recorded one
(interpolated): 'open' (the cycles' predictor off the plan, core/replan.py: RK4 of
pinocchio.aba under the plan's torques from the measured state, the plan model with 1 kg in
the hand), 'shift' (the measured state moved by the plan's own change over the horizon: the
tracking error persists), 'mix' (their mean) and 'plan' (the plan's own state then: the
cycles' start on the plan, replan.stitch; the tracking controller removes the error).
"""

import sys

import numpy as np
from toc_ros.core.arms import load_arm
from toc_ros.core.arms.payload import with_payload
from toc_ros.core.replan import _predict_arm
from toc_ros.recording.bag_reader import Recording


def _stamp(msg):
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


def read(run):
    """Return (joint_states [(t, q, dq)], trajectories with points) of a recording."""
    samples, plans = [], []
    with Recording(run) as recording:
        for raw, msg, *_ in recording.decoded(['/joint_states', '/trajectory']):
            if raw.topic == '/joint_states':
                samples.append((_stamp(msg), np.array(msg.position), np.array(msg.velocity)))
            elif msg.points:
                plans.append(msg)
    return samples, plans


def errors(samples, plans, horizon):
    """Return {predictor: [(max position error, max velocity error)]} over the samples."""
    arm = with_payload(load_arm('panda'), 1.0, 'panda_hand')
    times = np.array([s[0] for s in samples])
    states = np.array([np.concatenate([s[1], s[2]]) for s in samples])
    out = {'open': [], 'shift': [], 'mix': [], 'plan': []}
    for index, plan in enumerate(plans):
        start = _stamp(plan)
        # Only while this plan is the one executed: the next one replaces it at its stamp.
        until = _stamp(plans[index + 1]) if index + 1 < len(plans) else np.inf
        grid = np.array([p.time_from_start.sec + 1e-9 * p.time_from_start.nanosec
                         for p in plan.points])
        path = np.array([list(p.positions) + list(p.velocities) for p in plan.points])
        torques = np.array([p.effort for p in plan.points])[:-1]
        during = ((times > start + 0.02) & (times < start + grid[-1] - horizon - 0.01)
                  & (times + horizon < until))
        for k in np.flatnonzero(during):
            later = times[k] + horizon
            j = np.searchsorted(times, later)
            if j >= len(times):
                continue
            w = (later - times[j - 1]) / (times[j] - times[j - 1])
            actual = (1.0 - w) * states[j - 1] + w * states[j]
            s0, s1 = times[k] - start, later - start
            open_loop = _predict_arm(arm, states[k], grid, torques, s0, s1)
            moved = np.array([np.interp(s1, grid, c) - np.interp(s0, grid, c) for c in path.T])
            shift = states[k] + moved
            on_plan = np.array([np.interp(s1, grid, c) for c in path.T])
            for name, guess in (('open', open_loop), ('shift', shift),
                                ('mix', 0.5 * (open_loop + shift)), ('plan', on_plan)):
                gap = np.abs(guess - actual)
                out[name].append((gap[:7].max(), gap[7:].max()))
    return out


def main(argv=None):
    """Print the prediction errors of a recorded run over a horizon."""
    argv = sys.argv[1:] if argv is None else argv
    run, horizon = argv[0], float(argv[1])
    for name, values in errors(*read(run), horizon).items():
        e = np.array(values)
        print(f'H = {1e3 * horizon:.0f} ms {name:6s} n = {len(e)}: q error median '
              f'{1e3 * np.median(e[:, 0]):.2f} mrad, p90 {1e3 * np.percentile(e[:, 0], 90):.2f}; '
              f'dq error median {np.median(e[:, 1]):.3f}, p90 '
              f'{np.percentile(e[:, 1], 90):.3f} rad/s')


if __name__ == '__main__':
    main()
