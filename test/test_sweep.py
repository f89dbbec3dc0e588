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
toc-sweep: spec checks, a real LocalCluster, and a separately started Dask cluster.

The cluster of this module (`dask scheduler` + two `dask worker` processes on 127.0.0.1,
random ports) is shared by its tests and torn down at the end; the last test kills one of its
workers mid-sweep.  Rows are compared bit for bit with serial solves by toc-solve's own code
path (and with `toc-solve --json` for some cases).
"""

import json
import math
import os
from pathlib import Path
import shlex
import signal
import socket
import subprocess
import sys
import time

import pyarrow.parquet as pq
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
RESULT_KEYS = ('status', 'final_time', 'iterations', 'max_control_excess', 'terminal_error',
               'min_clearance', 'message')
# A small paper-like sweep for the LocalCluster test: 2 x 2 hand goals x 2 obstacle placements;
# the goal (1.5, 1.6) puts the arm inside the first placement's circle (an INVALID_INPUT row).
LOCAL_SPEC = {
    'base': {'mode': 'fast', 'integrator': 'euler', 'N': 60},
    'grid': {'goal.x': [0.5, 1.5], 'goal.y': [1.0, 1.6]},
    'zip': [{'obstacles.0.x': [1.0, 0.8], 'obstacles.0.y': [1.0, 0.5]}],
}
# For the external cluster: 14 cases, paper mode with a fixed iteration count, so that each
# takes ~0.3 s (long enough to interrupt the sweep) however fast the fast mode gets.
CLUSTER_SPEC = {
    'base': {'mode': 'paper', 'N': 1000, 'max-iterations': 8000},
    'grid': {'goal.q1': {'linspace': [0.6, 1.5, 7]}, 'goal.q2': [0.7, 1.1]},
}


def _env():
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(filter(None, [str(ROOT), env.get('PYTHONPATH')]))
    env.setdefault('AMENT_PREFIX_PATH', sys.prefix)
    return env


def _free_port():
    with socket.socket() as sock:
        sock.bind(('127.0.0.1', 0))
        return sock.getsockname()[1]


def _write_spec(folder, doc, name='spec.yaml'):
    path = Path(folder) / name
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return str(path)


def _sweep_cli(*args, timeout=180):
    return subprocess.run([sys.executable, '-m', 'toc_ros.sweep.cli', *args], cwd=ROOT,
                          env=_env(), capture_output=True, text=True, timeout=timeout)


def _start_sweep(*args):
    return subprocess.Popen([sys.executable, '-m', 'toc_ros.sweep.cli', *args], cwd=ROOT,
                            env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)


def _rows(out):
    files = sorted((Path(out) / 'results').glob('part-*.parquet'))
    return [row for f in files for row in pq.read_table(f).to_pylist()]


def _wait_for(predicate, timeout, what):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return
        time.sleep(0.05)
    raise AssertionError(f'timed out after {timeout} s waiting for {what}')


def _stop(proc):
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)


@pytest.fixture(scope='module')
def warm_cache():
    """Compile or load the numba kernels here first, so the workers find them cached."""
    from toc_ros.core import warm_up
    warm_up()


@pytest.fixture(scope='module')
def serial(warm_cache):
    """Solve serially by the code path of toc-solve (parse_args, build_problem, core solve)."""
    from toc_ros.core import solve
    from toc_ros.solve import build_problem, parse_args
    cache = {}

    def result(args_text):
        if args_text not in cache:
            argv = shlex.split(args_text)[1:]
            problem, options = build_problem(parse_args(argv))
            r = solve(problem, options)
            v = r.violations
            cache[args_text] = {
                'status': r.status.value, 'final_time': r.final_time,
                'iterations': r.iterations, 'max_control_excess': v.max_control_excess,
                'terminal_error': v.terminal_error, 'min_clearance': v.min_clearance,
                'message': r.message}
        return cache[args_text]
    return result


def _same_bits(a, b):
    if isinstance(a, float) and isinstance(b, float):
        return a == b or (math.isnan(a) and math.isnan(b))
    return a == b


def _assert_rows_equal_serial(rows, serial):
    for row in rows:
        expected = serial(row['args'])
        for key in RESULT_KEYS:
            assert _same_bits(row[key], expected[key]), (key, row, expected)


def _assert_each_case_once(rows, n_cases):
    ids = [r['case_id'] for r in rows]
    assert len(ids) == len(set(ids)) == n_cases, (len(ids), len(set(ids)), n_cases)


# -- spec checks (no cluster) -----------------------------------------------------------------

BAD_SPECS = [
    ({'grids': {'goal.x': [1.0]}}, 'unknown key(s) grids'),
    ({'grid': {'goal.z': [1.0]}}, 'goal.* takes one of'),
    ({'grid': {'speed': [1.0]}}, "unknown name 'speed'"),
    ({'grid': {'N': [60, 'many']}}, 'N mixes numbers and strings'),
    ({'grid': {'N': [60.5]}}, "argument --N: invalid int value: '60.5'"),
    ({'grid': {'mode': ['fast', 'slow']}}, "invalid choice: 'slow'"),
    ({'grid': {'goal.x': [1.0, 1.5]}}, 'goal.x and goal.y (hand position) must be varied'),
    ({'grid': {'goal.x': [1.0], 'goal.y': [1.0], 'goal.q1': [1.0]}}, 'exclude each other'),
    ({'zip': [{'goal.q1': [1.0, 1.2], 'goal.q2': [1.0]}]}, 'must have equal lengths'),
    ({'grid': {'goal.q1': {'linspace': [0, 1]}}}, 'linspace takes [start, stop, num]'),
    ({'grid': {'goal.q1': [1.0, float('nan')]}}, 'is not a finite number'),
    ({'grid': {'goal.q1': {'linspace': [0, 1, 20]}, 'goal.q2': {'linspace': [0, 1, 20]}},
      'limit': 100}, 'expands to 400 cases, more than its limit 100'),
    ({'grid': {'obstacles.1.x': [0.5]}}, 'a new obstacle 1 needs x, y and radius'),
    ({'grid': {'obstacles.0.rad': [0.5]}}, 'obstacles.K.* takes one of'),
    ({'base': {'json': 'out.json'}}, 'base.json: not a toc-solve option usable in a sweep'),
    ({'base': {'obstacle': [1.0, 1.0, 0.2]}}, 'base.obstacle must be a list of [x, y, radius]'),
    ({'random': {'n': 5, 'seed': 1, 'ranges': {'goal.q1': [1.0, 0.5]}}}, 'finite low < high'),
    ({'grid': {'goal.q1': [1.0]}, 'random': {'n': 2, 'ranges': {'goal.q1': [0.5, 1.0]}}},
     'goal.q1 varied more than once'),
    ({'grid': {'goal.q1': [1.0, 1.0]}}, 'case 1 (goal.q1=1.0) is the same case as case 0'),
    ({'grid': {'obstacles.0.x': [0.0, 0.1], 'obstacles.0.y': [0.0]}},
     'every case is an invalid problem'),
    ({'grid': {'timeout': [-1.0]}}, '--timeout must be >= 0 seconds'),
    ({'grid': {'goal.q1': [1.0]}, 'plot': {'x': 'goal.q1', 'y': 'goal.q3'}},
     "plot.y = 'goal.q3' is not a varied name"),
    ({'base': {'config': 'missing.yaml'}}, 'cannot read parameter file'),
]


@pytest.mark.parametrize('doc,message', BAD_SPECS)
def test_bad_specs_are_refused_before_any_solve(tmp_path, monkeypatch, capsys, doc, message):
    refused_before_any_solve(tmp_path, monkeypatch, capsys, doc, message)


def refused_before_any_solve(tmp_path, monkeypatch, capsys, doc, message):
    """Check that toc-sweep refuses the spec doc with message, starting no cluster."""
    from toc_ros.sweep import cli, runner

    def no_cluster(*_args, **_kwargs):
        raise AssertionError('a cluster was started for a bad spec')

    monkeypatch.setattr(runner, 'connect', no_cluster)
    out = tmp_path / 'out'
    code = cli.main([_write_spec(tmp_path, doc), '--out', str(out), '--quiet'])
    err = capsys.readouterr().err
    assert code == 2, err
    assert 'toc-sweep: bad spec:' in err and message in err, err
    assert 'Traceback' not in err
    assert not out.exists()


ISSUE_EXAMPLE = """\
base: {mode: fast, integrator: euler, N: 300}     # toc-solve long options, without "--"
grid:                                             # cross product of the listed values
  goal.x: [1.0, 1.5]                              # hand goal [m] (with goal.y), or goal.q1/q2
  goal.y: [1.0, 1.5]
  obstacles.0.x: [0.9, 1.1]                       # obstacles.K.{x,y,radius}; start.q1/q2/dq1/dq2
random: {n: 0, seed: 1, ranges: {}}               # optional: n samples, uniform in ranges
"""


def test_the_issue_example_spec_is_accepted(tmp_path, capsys):
    from toc_ros.sweep import cli
    from toc_ros.sweep.dataset import schema_for
    from toc_ros.sweep.spec import load_spec
    path = tmp_path / 'issue.yaml'
    path.write_text(ISSUE_EXAMPLE)
    assert cli.main([str(path), '--dry-run']) == 0
    assert '8 case(s), varied: goal.x, goal.y, obstacles.0.x' in capsys.readouterr().out
    columns = schema_for(load_spec(str(path))).names
    assert columns[:4] == ['case_id', 'goal.x', 'goal.y', 'obstacles.0.x']
    assert {'status', 'final_time', 'iterations', 'wall_time_s', 'max_control_excess',
            'terminal_error', 'min_clearance', 'worker'} <= set(columns)


def test_unreadable_and_non_yaml_specs(tmp_path, capsys):
    from toc_ros.sweep import cli
    assert cli.main([str(tmp_path / 'nope.yaml')]) == 2
    assert 'cannot read' in capsys.readouterr().err
    bad = tmp_path / 'bad.yaml'
    bad.write_text('grid: {goal.x: [1, 2\n')
    assert cli.main([str(bad)]) == 2
    assert 'is not valid YAML' in capsys.readouterr().err


def test_cases_become_toc_solve_arguments(tmp_path):
    from toc_ros.solve import build_problem, parse_args
    from toc_ros.sweep.cases import CaseBuilder, format_number
    from toc_ros.sweep.spec import parse_spec
    doc = {'base': {'N': 80, 'obstacle': [[1.0, 1.0, 0.2]]},
           'grid': {'goal.x': [1.0], 'goal.y': [-1.0e-5], 'robot.u_max.1': [450.0],
                    'obstacles.1.x': [-1.0], 'obstacles.1.y': [0.5], 'obstacles.1.radius': [0.1]}}
    builder = CaseBuilder(parse_spec(doc, path=str(tmp_path / 's.yaml')))
    (case_id, argv, values, problem, options), = builder.cases()
    args = parse_args(argv)
    assert args.N == 80
    assert args.obstacle == [[1.0, 1.0, 0.2], [-1.0, 0.5, 0.1]]
    assert args.x_goal == (math.atan2(-1e-5, 1.0), 0.0, math.hypot(1.0, 1e-5) - 1.1, 0.0)
    assert argv[argv.index('--robot.u_max') + 1:][:2] == ['600.0', '450.0']
    assert values == {'goal.x': 1.0, 'goal.y': -1e-5, 'robot.u_max.1': 450.0,
                      'obstacles.1.x': -1.0, 'obstacles.1.y': 0.5, 'obstacles.1.radius': 0.1}
    assert (problem.n_intervals, problem.model.params.u2_max, len(problem.obstacles)) == (
        80, 450.0, 2)
    assert (problem, options) == build_problem(args)      # as toc-solve builds it from the file
    for value in (-1e-05, 1.0 / 3.0, -123456.789e10, 5e-324, 2.0 ** 60):
        assert float(format_number(value)) == value
    # Same case, other spec and other config path with the same content: same hash.
    config = tmp_path / 'copy.yaml'
    config.write_text((ROOT / 'config' / 'toc_ros.yaml').read_text())
    doc2 = {'base': {'config': str(config), 'obstacle': [[1.0, 1.0, 0.2]], 'N': 80},
            'zip': [{'goal.x': [1.0], 'goal.y': [-1.0e-5]}],
            'grid': {'robot.u_max.1': [450.0], 'obstacles.1.x': [-1.0],
                     'obstacles.1.y': [0.5], 'obstacles.1.radius': [0.1]}}
    (other_id, *_), = CaseBuilder(parse_spec(doc2, path=str(tmp_path / 's.yaml'))).cases()
    assert other_id == case_id
    doc2['grid']['robot.u_max.1'] = [451.0]
    (third_id, *_), = CaseBuilder(parse_spec(doc2, path=str(tmp_path / 's.yaml'))).cases()
    assert third_id != case_id


def test_an_exception_in_the_solver_is_an_error_row(monkeypatch):
    import toc_ros.core
    from toc_ros.sweep.worker import solve_case

    def broken(problem, options):
        raise RuntimeError('kaput')

    monkeypatch.setattr(toc_ros.core, 'solve', broken)
    row = solve_case(('0123456789abcdef', ['--N', '60'], {'N': 60}, None, None))
    assert row['status'] == 'ERROR' and 'RuntimeError: kaput' in row['message']
    assert row['N'] == 60 and row['args'] == 'toc-solve --N 60' and math.isnan(row['final_time'])


def test_random_samples_are_seeded():
    from toc_ros.sweep.spec import parse_spec
    doc = {'random': {'n': 5, 'seed': 7, 'ranges': {'goal.q1': [0.5, 1.5], 'goal.q2': [0, 1]}}}
    first = list(parse_spec(doc).cases())
    assert first == list(parse_spec(doc).cases())
    assert len(first) == 5 and all(0.5 <= c['goal.q1'] < 1.5 for c in first)
    doc['random']['seed'] = 8
    assert first != list(parse_spec(doc).cases())


def test_an_output_directory_in_use_is_refused(tmp_path, capsys):
    from toc_ros.sweep import cli
    from toc_ros.sweep.dataset import Dataset, schema_for
    from toc_ros.sweep.spec import load_spec
    spec = _write_spec(tmp_path, LOCAL_SPEC)
    holder = Dataset(tmp_path / 'out', schema_for(load_spec(spec)))
    holder.prepare(False)          # this (live) process holds OUT/.lock
    try:
        assert cli.main([spec, '--out', str(tmp_path / 'out'), '--resume', '--quiet']) == 2
        assert 'is in use by another toc-sweep' in capsys.readouterr().err
    finally:
        holder.close()
    assert not (tmp_path / 'out' / '.lock').exists()


def test_summary_and_heat_map_of_random_samples(tmp_path):
    import pyarrow as pa
    from toc_ros.sweep.dataset import schema_for
    from toc_ros.sweep.report import write_report
    from toc_ros.sweep.spec import parse_spec
    doc = {'random': {'n': 40, 'seed': 3, 'ranges': {'goal.x': [0.5, 2.0],
                                                     'goal.y': [-1.0, 1.0]}},
           'grid': {'robot.hand_mass': [50.0, 80.0]}}
    sweep = parse_spec(doc, path=str(tmp_path / 'random.yaml'))
    rows = []
    for k, case in enumerate(sweep.cases()):
        status = ('SOLVED', 'SOLVED', 'STALLED', 'INVALID_INPUT')[k % 4]
        t = 1.0 + case['goal.x'] if status == 'SOLVED' else math.nan
        rows.append(dict(case, case_id=f'{k:016x}', status=status, final_time=t,
                         iterations=k, wall_time_s=0.01, max_control_excess=0.0,
                         terminal_error=0.0, min_clearance=0.1, worker='w', message='m',
                         args='toc-solve --obstacle 1 1 0.2'))
    table = pa.Table.from_pylist(rows, schema=schema_for(sweep))
    summary = write_report(table, sweep, str(tmp_path), n_cases=82)
    assert summary['rows'] == 80 and summary['missing'] == 2
    assert summary['by_status'] == {'INVALID_INPUT': 20, 'SOLVED': 40, 'STALLED': 20}
    solved = sorted(r['final_time'] for r in rows if r['status'] == 'SOLVED')
    assert summary['t_min_solved']['count'] == 40
    assert summary['t_min_solved']['max'] == solved[-1]
    assert summary['longest'][0]['final_time'] == solved[-1]
    assert summary['failures'][0]['status'] == 'STALLED'     # solver failures before invalid
    assert (tmp_path / 'heatmap.png').stat().st_size > 10000
    text = (tmp_path / 'summary.md').read_text()
    assert '| STALLED | 20 |' in text and '(2 missing)' in text


# -- a real LocalCluster (the default of toc-sweep) ------------------------------------------

@pytest.mark.slow
def test_local_cluster_rows_equal_serial_solves(tmp_path, warm_cache, serial):
    from toc_ros.sweep import cli
    out = tmp_path / 'local'
    spec = _write_spec(tmp_path, LOCAL_SPEC)
    assert cli.main([spec, '--workers', '2', '--out', str(out), '--quiet']) == 0
    rows = _rows(out)
    _assert_each_case_once(rows, 8)
    assert {r['status'] for r in rows} == {'SOLVED', 'INVALID_INPUT'}
    assert all(r['worker'].startswith('tcp://127.0.0.1:') for r in rows)
    _assert_rows_equal_serial(rows, serial)
    # Two cases against the toc-solve command itself (its --json file).
    for k, row in enumerate(r for r in rows if r['status'] == 'SOLVED'):
        if k == 2:
            break
        path = tmp_path / f'case{k}.json'
        argv = shlex.split(row['args'])[1:]
        proc = subprocess.run([sys.executable, '-m', 'toc_ros.solve', *argv, '--json',
                               str(path), '--quiet'], cwd=ROOT, env=_env(), timeout=120)
        assert proc.returncode == 0
        data = json.loads(path.read_text())
        assert data['final_time'] == row['final_time']
        assert data['iterations'] == row['iterations']
        assert data['violations'] == {k: row[k] for k in data['violations']}
    summary = json.loads((out / 'summary.json').read_text())
    assert summary['rows'] == 8 and summary['missing'] == 0
    assert summary['by_status'] == {'INVALID_INPUT': sum(r['status'] == 'INVALID_INPUT'
                                                         for r in rows),
                                    'SOLVED': sum(r['status'] == 'SOLVED' for r in rows)}
    assert summary['t_min_solved']['max'] == max(r['final_time'] for r in rows
                                                 if r['status'] == 'SOLVED')
    assert (out / 'heatmap.png').stat().st_size > 10000
    assert '| SOLVED |' in (out / 'summary.md').read_text()
    # Running again without --resume is refused; with --resume nothing is solved.
    assert cli.main([spec, '--out', str(out), '--quiet']) == 2
    files = sorted((out / 'results').glob('part-*'))
    assert cli.main([spec, '--out', str(out), '--resume', '--quiet']) == 0
    assert sorted((out / 'results').glob('part-*')) == files


# -- a separately started dask scheduler + dask worker processes -----------------------------

@pytest.fixture(scope='module')
def cluster(warm_cache):
    """`dask scheduler` and two `dask worker` processes on 127.0.0.1 (random ports)."""
    port = _free_port()
    address = f'tcp://127.0.0.1:{port}'
    dask = [sys.executable, '-m', 'dask']
    local = ['--no-dashboard', '--dashboard-address', '127.0.0.1:0']   # HTTP server too
    procs = [subprocess.Popen(dask + ['scheduler', '--host', '127.0.0.1', '--port', str(port),
                                      '--idle-timeout', '600'] + local,
                              env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    workers = {}
    try:
        from distributed import Client
        deadline = time.monotonic() + 60
        client = None
        while client is None:
            try:
                client = Client(address, timeout=5)
            except (OSError, TimeoutError):
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.2)
        for k in range(2):
            proc = subprocess.Popen(
                dask + ['worker', address, '--nthreads', '1', '--no-nanny', '--host',
                        '127.0.0.1', '--name', f'w{k}', '--death-timeout', '60'] + local,
                env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            procs.append(proc)
        client.wait_for_workers(2, timeout=60)
        for addr, info in client.scheduler_info(n_workers=-1)['workers'].items():
            workers[info['name']] = addr
        client.close()
        yield {'address': address, 'workers': workers,
               'procs': dict(zip(('w0', 'w1'), procs[1:]))}
    finally:
        for proc in reversed(procs):
            _stop(proc)


@pytest.mark.slow
def test_external_scheduler_interrupted_sweep_resumes_missing_cases_only(
        tmp_path, cluster, serial):
    out = tmp_path / 'ext'
    spec = _write_spec(tmp_path, CLUSTER_SPEC)
    n = 14
    sweep = _start_sweep(spec, '--scheduler', cluster['address'], '--out', str(out),
                         '--batch-size', '1')
    try:
        _wait_for(lambda: len(_rows(out)) >= 3 or sweep.poll() is not None, 120,
                  'three rows')
        sweep.send_signal(signal.SIGKILL)        # the client dies mid-sweep
        sweep.wait(10)
    finally:
        _stop(sweep)
    before = {f.name: f.read_bytes() for f in (out / 'results').glob('part-*.parquet')}
    first = _rows(out)
    assert 3 <= len(first) < n, len(first)
    proc = _sweep_cli(spec, '--scheduler', cluster['address'], '--out', str(out), '--resume')
    assert proc.returncode == 0, proc.stderr
    assert f'{n} case(s) in {spec}, {len(first)} already in' in proc.stdout
    assert f'solving {n - len(first)}' in proc.stdout
    rows = _rows(out)
    _assert_each_case_once(rows, n)
    for name, data in before.items():         # earlier files untouched
        assert (out / 'results' / name).read_bytes() == data
    new = [r for r in rows if r['case_id'] not in {f['case_id'] for f in first}]
    assert len(new) == n - len(first)
    assert {r['worker'] for r in rows} <= set(cluster['workers'].values())
    _assert_rows_equal_serial(rows, serial)
    run = json.loads((out / 'summary.json').read_text())['run']
    assert run['done'] == n - len(first)
    assert run['task_warm_up_s'] < 0.05          # the plugin warmed the workers, not the tasks
    # Two sweeps registered the warm-up plugin; each worker process warmed up once.
    from distributed import Client
    with Client(cluster['address'], timeout=10) as client:
        events = [event for _, event in client.get_events('toc_ros')]
    warmed = sorted(e['worker'] for e in events if e['now'])
    assert warmed == sorted(cluster['workers'].values()), events
    assert len(events) >= 2 * len(warmed)
    # The spec grows by one q2 value: --resume solves the 7 new cases only.
    grown = dict(CLUSTER_SPEC, grid=dict(CLUSTER_SPEC['grid'], **{'goal.q2': [0.7, 1.1, 0.9]}))
    spec = _write_spec(tmp_path, grown, 'grown.yaml')
    proc = _sweep_cli(spec, '--scheduler', cluster['address'], '--out', str(out), '--resume')
    assert proc.returncode == 0, proc.stderr
    assert f'21 case(s) in {spec}, 14 already in' in proc.stdout and 'solving 7' in proc.stdout
    _assert_each_case_once(_rows(out), 21)


@pytest.mark.slow
def test_external_scheduler_worker_killed_mid_sweep_loses_no_case(tmp_path, cluster, serial):
    """Last test of the module: it kills worker w0 of the shared cluster."""
    out = tmp_path / 'kill'
    spec = _write_spec(tmp_path, CLUSTER_SPEC)
    victim = cluster['workers']['w0']
    sweep = _start_sweep(spec, '--scheduler', cluster['address'], '--out', str(out),
                         '--batch-size', '1')
    try:
        _wait_for(lambda: any(r['worker'] == victim for r in _rows(out))
                  or sweep.poll() is not None, 120, 'a row from worker w0')
        from distributed import Client
        with Client(cluster['address'], timeout=10) as client:
            # Kill it while the scheduler has a task of this sweep on it.
            _wait_for(lambda: any(str(k).startswith('toc-sweep-') for k in
                                  client.processing(workers=[victim]).get(victim, ()))
                      or sweep.poll() is not None, 60, 'a task on worker w0')
            assert sweep.poll() is None, 'the sweep ended before the worker could be killed'
            cluster['procs']['w0'].send_signal(signal.SIGKILL)
        stdout, stderr = sweep.communicate(timeout=150)
    finally:
        _stop(sweep)
    assert sweep.returncode == 0, stderr
    rows = _rows(out)
    _assert_each_case_once(rows, 14)
    by_worker = {w: sum(r['worker'] == w for r in rows) for w in cluster['workers'].values()}
    assert 1 <= by_worker[victim] < 14 and by_worker[cluster['workers']['w1']] >= 1
    _assert_rows_equal_serial(rows, serial)
