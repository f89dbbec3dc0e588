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
toc-sweep over a URDF arm: spec checks, arm cases as toc-solve arguments, a Panda sweep on Dask.

The rows of the LocalCluster sweep are judged by test/arm_oracle.py (Pinocchio straight from
the URDF, nothing of toc_ros): a SOLVED row's final joint positions put panda_hand on the
case's tip target, within the limits and clear of the case's sphere; one case solved again by
the `toc-solve` command of its args column gives the same bits, and the oracle's clearance
over that trajectory is the row's min_clearance.  An unreachable target is an INVALID_INPUT
row with IK's reason.
"""

import json
import math
from pathlib import Path
import shlex
import subprocess
import sys

from arm_oracle import ArmOracle, find_panda_urdf
import numpy as np
import pyarrow.parquet as pq
import pytest
from test_sweep import refused_before_any_solve
import yaml

ROOT = Path(__file__).resolve().parents[1]
READY = [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785]      # the Panda's ready pose
BASE = {'model': 'panda', 'start': READY, 'goal-pose': [0.5, 0.1, 0.3],
        'sphere': [[0.5, -0.1, 0.42, 0.08]], 'margin': 0.02, 'N': 20}
# 2 targets x 2 sphere placements: x = 0.45 is solved for both, x = 1.3 is out of the
# Panda's reach (IK: unreachable within the joint limits).
LOCAL_SPEC = {'base': BASE, 'grid': {'goal_pose.x': [0.45, 1.3],
                                     'spheres.0.y': [-0.1, -0.25]}}
TIP_TOL_M = 1e-4


def _env():
    import os
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(filter(None, [str(ROOT), env.get('PYTHONPATH')]))
    env.setdefault('AMENT_PREFIX_PATH', sys.prefix)
    return env


def _write_spec(folder, doc):
    path = Path(folder) / 'arm.yaml'
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return str(path)


def _spec(base=None, drop=(), **axes):
    doc = {'base': {k: v for k, v in dict(BASE, **(base or {})).items() if k not in drop}}
    doc.update(axes)
    return doc


@pytest.fixture(scope='module')
def oracle():
    return ArmOracle(find_panda_urdf().read_text())


@pytest.fixture(scope='module')
def warm_cache():
    """Compile or load the numba kernels here first (planar and arm), so workers find them."""
    from toc_ros.arm_cli import build_arm_problem, build_parser
    from toc_ros.core import warm_up, warm_up_for
    warm_up()
    argv = ['--model', 'panda', '--start', *map(str, READY), '--goal-pose', '0.45', '0.1',
            '0.3', '--sphere', '0.5', '-0.1', '0.42', '0.08', '--N', '20']
    problem, options, _ = build_arm_problem(build_parser().parse_args(argv))
    warm_up_for(problem, options)


# -- spec checks (no cluster) -----------------------------------------------------------------

BAD_ARM_SPECS = [
    (_spec(grid={'goal_pose.w': [1.0]}), 'goal_pose.* takes one of x, y, z'),
    (_spec(grid={'spheres.1.x': [0.4]}),
     'spheres.1.x: base.sphere has 1 sphere(s), so there is no sphere 1'),
    (_spec(grid={'spheres.0.r': [0.1]}), 'spheres.K.* takes one of x, y, z, radius'),
    (_spec(grid={'obstacles.0.x': [0.4]}), 'an arm sweep varies start.qK/dqK'),
    (_spec(grid={'goal.x': [0.4]}), 'an arm sweep varies start.qK/dqK'),
    (_spec(base={'goal': READY}, drop=('goal-pose',), grid={'goal.q8': [0.1]}),
     'goal.q8: the arm has 7 joints'),
    (_spec(grid={'goal.q1': [0.1]}), 'goal.qK vary a joint goal: give base.goal'),
    (_spec(base={'goal': READY}, drop=('goal-pose',), grid={'goal_pose.x': [0.4]}),
     'base.goal is a joint goal'),
    (_spec(drop=('goal-pose',), grid={'goal_pose.x': [0.4]}), 'must all be varied'),
    (_spec(drop=('goal-pose',)), 'no goal: give base.goal'),
    (_spec(grid={'model': ['panda', 'ur5']}), 'model cannot be varied: one arm per spec'),
    (_spec(grid={'joints': ['panda_joint1']}), 'joints cannot be varied: one arm per spec'),
    (_spec(grid={'sphere': [0.1]}), 'sphere cannot be varied as a whole'),
    (_spec(grid={'speed': [0.1]}), "unknown name 'speed' for an arm sweep"),
    (_spec(grid={'integrator': ['euler', 'midpoint']}), "invalid choice: 'midpoint'"),
    (_spec(grid={'timeout': [-1.0]}), 'timeout must be a positive number'),
    (_spec(grid={'goal_pose.x': [0.4, 0.4]}), 'is the same case as case 0'),
    (_spec(base={'tip': 'no_such_link'}), "base.tip: unknown link 'no_such_link'"),
    (_spec(base={'joints': 'panda_joint1,nope'}), 'unknown joint'),
    (_spec(base={'sphere': [[0.5, 0.1, 0.3]]}), 'base.sphere must be a list of [x, y, z'),
    (_spec(base={'start': READY[:6]}), 'base.start takes the 7 joint positions'),
    (_spec(drop=('start',)), 'base.start is required'),
    (_spec(base={'goal-pose': [0.5, 0.1]}), 'base.goal-pose takes [X, Y, Z]'),
    (_spec(base={'json': 'r.json'}), 'base.json: not an option of toc-solve for arms'),
]


@pytest.mark.parametrize('doc,message', BAD_ARM_SPECS)
def test_bad_arm_specs_are_refused_before_any_solve(tmp_path, monkeypatch, capsys, doc,
                                                    message):
    refused_before_any_solve(tmp_path, monkeypatch, capsys, doc, message)


def test_arm_cases_become_toc_solve_arguments(tmp_path, oracle):
    from toc_ros.arm_cli import build_arm_problem, build_parser
    from toc_ros.sweep.arm_cases import case_builder
    from toc_ros.sweep.spec import parse_spec
    doc = _spec(grid={'goal_pose.x': [0.45], 'spheres.0.radius': [0.05], 'start.dq2': [0.1],
                      'N': [30]})
    builder = case_builder(parse_spec(doc, path=str(tmp_path / 's.yaml')))
    assert builder.is_arm
    (case_id, argv, values, problem, options), = builder.cases()
    assert (problem, options) == (None, None)      # built on the workers
    args = build_parser().parse_args(argv)
    assert args.model == 'panda' and args.N == 30 and args.margin == 0.02
    assert args.goal_pose == [0.45, 0.1, 0.3] and args.goal is None
    assert args.sphere == [[0.5, -0.1, 0.42, 0.05]]
    assert args.start == READY + [0.0, 0.1] + [0.0] * 5       # velocities appended
    problem, _, _ = build_arm_problem(args)
    tip = oracle.tip(problem.x_goal[:7]).translation
    assert np.linalg.norm(tip - [0.45, 0.1, 0.3]) < TIP_TOL_M
    # A joint goal: goal.qK set element K of base.goal.
    doc = _spec(base={'goal': READY}, drop=('goal-pose',), grid={'goal.q1': [0.3, 0.4]})
    rows = case_builder(parse_spec(doc, path=str(tmp_path / 's.yaml'))).cases()
    goals = [build_parser().parse_args(r[1]).goal for r in rows]
    assert goals == [[0.3] + READY[1:], [0.4] + READY[1:]]
    assert len({r[0] for r in rows}) == 2


def test_an_unreachable_target_is_an_invalid_input_row(tmp_path):
    from toc_ros.sweep.arm_cases import case_builder
    from toc_ros.sweep.spec import parse_spec
    from toc_ros.sweep.worker import solve_case
    doc = _spec(grid={'goal_pose.x': [1.3]})
    case, = case_builder(parse_spec(doc, path=str(tmp_path / 's.yaml'))).cases()
    row = solve_case(case)
    assert row['status'] == 'INVALID_INPUT'
    assert 'goal pose panda_hand at [1.3, 0.1, 0.3] is unreachable within the joint limits' in (
        row['message'])
    assert row['goal_pose.x'] == 1.3 and math.isnan(row['final_time'])
    assert row['goal_q'] is None and row['final_q'] is None


def test_toc_solve_goal_pose_refusals(tmp_path, capsys):
    from toc_ros.solve import main
    start = ['--model', 'panda', '--start', *map(str, READY), '--N', '20']
    out = tmp_path / 'r.json'
    assert main(start + ['--goal-pose', '1.3', '0', '0.3', '--json', str(out)]) == 4
    data = json.loads(out.read_text())
    assert data['status'] == 'INVALID_INPUT'
    assert 'panda_hand at [1.3, 0.0, 0.3] is unreachable within the joint limits' in (
        data['message'])
    assert main(start + ['--goal-pose', '0.4', '0', '0.3', '--tip', 'no_such_link']) == 4
    assert "unknown link 'no_such_link'" in capsys.readouterr().err
    assert main(start + ['--goal-pose', '0.4', '0', '0.3', '0', '1']) == 4
    assert '--goal-pose takes X Y Z [QX QY QZ QW], got 5 values' in capsys.readouterr().err
    with pytest.raises(SystemExit) as stop:
        main(start + ['--goal', *map(str, READY), '--goal-pose', '0.4', '0', '0.3'])
    assert stop.value.code == 2
    assert 'not allowed with argument' in capsys.readouterr().err


# -- a real LocalCluster ----------------------------------------------------------------------

def _check_solved_row(row, oracle):
    """Check that the row's values are its arguments and its final state reaches the target."""
    from toc_ros.arm_cli import build_parser
    args = build_parser().parse_args(shlex.split(row['args'])[1:])
    target = [row['goal_pose.x'], BASE['goal-pose'][1], BASE['goal-pose'][2]]
    assert args.goal_pose == target and args.start == READY and args.N == BASE['N']
    assert args.sphere == [[0.5, row['spheres.0.y'], 0.42, 0.08]]
    final = np.array(row['final_q'])
    tip = oracle.tip(final).translation
    assert np.linalg.norm(tip - target) < TIP_TOL_M, (tip, target)
    assert np.max(np.abs(final - row['goal_q'])) < 1e-6
    assert np.all(final >= oracle.lower - 1e-9) and np.all(final <= oracle.upper + 1e-9)
    assert oracle.clearance(final, args.sphere, args.margin) >= row['min_clearance'] - 1e-9
    assert row['min_clearance'] >= -1e-6 and row['terminal_error'] < 1e-6
    return args


@pytest.mark.slow
def test_local_cluster_arm_sweep_rows_check_independently(tmp_path, warm_cache, oracle):
    from toc_ros.sweep import cli
    out = tmp_path / 'arm'
    spec = _write_spec(tmp_path, LOCAL_SPEC)
    assert cli.main([spec, '--workers', '2', '--out', str(out), '--quiet']) == 0
    rows = pq.read_table(out / 'results').to_pylist()
    assert sorted((r['goal_pose.x'], r['spheres.0.y']) for r in rows) == [
        (0.45, -0.25), (0.45, -0.1), (1.3, -0.25), (1.3, -0.1)]
    assert len({r['case_id'] for r in rows}) == 4
    assert all(r['worker'].startswith('tcp://127.0.0.1:') for r in rows)
    solved = [r for r in rows if r['status'] == 'SOLVED']
    unreachable = [r for r in rows if r['goal_pose.x'] == 1.3]
    assert [r['goal_pose.x'] for r in solved] == [0.45, 0.45], [
        (r['status'], r['message']) for r in rows]
    for row in unreachable:
        assert row['status'] == 'INVALID_INPUT'
        assert 'is unreachable within the joint limits' in row['message']
        assert math.isnan(row['final_time']) and row['final_q'] is None
    for row in solved:
        assert row['final_time'] > 0 and row['iterations'] > 0 and row['wall_time_s'] > 0
        _check_solved_row(row, oracle)
    # One case by the toc-solve command itself: the same bits, and the oracle's clearance
    # over its trajectory is the row's.
    row = solved[0]
    path = tmp_path / 'case.json'
    proc = subprocess.run([sys.executable, '-m', 'toc_ros.solve',
                           *shlex.split(row['args'])[1:], '--json', str(path), '--quiet'],
                          cwd=ROOT, env=_env(), timeout=120)
    assert proc.returncode == 0
    data = json.loads(path.read_text())
    assert (data['final_time'], data['iterations']) == (row['final_time'], row['iterations'])
    assert data['violations']['min_clearance'] == row['min_clearance']
    states = np.array(data['states'])
    assert np.array_equal(states[-1, :7], row['final_q'])
    obstacles = [[0.5, row['spheres.0.y'], 0.42, 0.08]]
    worst = min(oracle.clearance(q, obstacles, BASE['margin']) for q in states[:, :7])
    assert worst == pytest.approx(row['min_clearance'], abs=1e-9)
    summary = json.loads((out / 'summary.json').read_text())
    assert summary['by_status'] == {'INVALID_INPUT': 2, 'SOLVED': 2}
    assert summary['t_min_solved']['max'] == max(r['final_time'] for r in solved)
    assert (out / 'heatmap.png').stat().st_size > 10000
