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

"""The ~/progress schema: one writer, one reader, and nobody else spells its keys."""

import dataclasses
import math
from pathlib import Path
import re

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
import numpy as np
import pytest
from toc_ros import progress as schema
from toc_ros.core import Progress, SolveResult, Status, Violations

REPO = Path(__file__).resolve().parents[1]


def _result(status):
    n = 10
    return SolveResult(status=status, message='ok', mode='fast', integrator='euler',
                       n_intervals=n, final_time=1.5, time_grid=np.linspace(0, 1.5, n + 1),
                       states=np.zeros((n + 1, 4)), controls=np.zeros((n, 2)), iterations=7,
                       wall_time_s=0.25, violations=Violations(0.0, 1e-9, 0.05))


def test_running_report_round_trip():
    report = schema.running_report(Progress(12, 2.1, 0.5, math.nan, 0.3, 'fast'))
    msg = schema.progress_msg('solver', report)
    assert msg.level == DiagnosticStatus.OK and msg.name == 'solver'
    raw = {kv.key: kv.value for kv in msg.values}
    assert raw['status'] == schema.SOLVING and raw['iteration'] == '12'
    assert raw['best_feasible_t_f'] == 'nan' and 'min_clearance' not in raw
    back = schema.progress_from_msg(msg)
    assert back.solving and not back.final and back.status is None
    assert (back.iteration, back.t_f, back.elapsed_s, back.phase) == (12, 2.1, 0.3, 'fast')
    assert math.isnan(back.best_feasible_t_f) and back.min_clearance is None


@pytest.mark.parametrize('status', list(Status))
def test_result_levels_and_round_trip(status):
    expected = {Status.SOLVED: DiagnosticStatus.OK, Status.SOLVED_INACCURATE:
                DiagnosticStatus.WARN, Status.CANCELED: DiagnosticStatus.WARN,
                Status.TIMEOUT: DiagnosticStatus.WARN, Status.STALLED: DiagnosticStatus.ERROR,
                Status.MAX_ITERATIONS: DiagnosticStatus.ERROR,
                Status.INVALID_INPUT: DiagnosticStatus.ERROR}
    assert set(expected) == set(Status)
    report = schema.result_report(_result(status), 'why', goal_source='test',
                                  goal=(1.0, 0.0, 0.5, 0.0), data_revision=3,
                                  obstacles_hash=schema.obstacles_hash([(1, 1, 0.2)], 0.01))
    msg = schema.progress_msg('solver', report)
    assert (msg.level, msg.message) == (expected[status], 'why')
    back = schema.progress_from_msg(msg)
    assert back.final and back.status is status
    assert back.goal_source == 'test' and back.min_clearance == 0.05
    assert back.goal == (1.0, 0.0, 0.5, 0.0) and back.data_revision == 3
    assert back.n_intervals == 10 and back.iteration == 7 and back.t_f == 1.5
    assert back.obstacles_hash == report.obstacles_hash and len(back.obstacles_hash) == 12


def test_refusals_and_notices():
    refusal = schema.progress_msg('solver', schema.refusal_report('bad goal'))
    back = schema.progress_from_msg(refusal)
    assert refusal.level == DiagnosticStatus.ERROR and back.status is Status.INVALID_INPUT
    assert back.event == schema.EVENT_REFUSED and back.message == 'bad goal'
    ready = schema.progress_msg('solver', schema.ProgressReport(
        message='ready', elapsed_s=3.0, event=schema.EVENT_READY))
    back = schema.progress_from_msg(ready)
    assert back.status_name == schema.IDLE and not back.solving and not back.final
    assert back.event == schema.EVENT_READY and back.elapsed_s == 3.0
    restarted = schema.progress_from_msg(schema.progress_msg('solver', schema.ProgressReport(
        message='again', event=schema.EVENT_RESTARTED)))
    assert restarted.solving


def test_arm_fields_round_trip_and_are_absent_from_older_messages():
    """Names and entries as 'a, b', texts (newlines, commas) as they are; () not written."""
    from toc_ros.arm_record import ArmRecord
    spheres = 'panda_link1: [[0.0, 0.0, -0.1, 0.08]]\nignore_pairs: []\n'
    report = schema.ProgressReport(
        status=Status.SOLVED, robot_model='urdf', arm_joints=('j1', 'j2'),
        arm_locked=('finger=0.02',), arm_tip_link='tool', arm_urdf_source='parameter',
        arm_urdf_sha256='ab' * 32, arm_urdf='<robot name="a, b">\n</robot>',
        arm_spheres_source='/x/spheres.yaml', arm_spheres_sha256='cd' * 32,
        arm_spheres=spheres)
    msg = schema.progress_msg('solver', report)
    raw = {kv.key: kv.value for kv in msg.values}
    assert raw['arm_joints'] == 'j1, j2' and 'arm_joint_limits' not in raw
    back = schema.progress_from_msg(msg)
    assert back == dataclasses.replace(report, level=msg.level, name='solver')
    record = ArmRecord.from_report(back)
    assert record.joints == ('j1', 'j2') and record.joint_limits == ()
    assert record.spheres == spheres and 'arm_spheres' not in record.fields()
    assert record.fields(texts=True)['arm_urdf'] == report.arm_urdf
    old = schema.progress_from_msg(schema.progress_msg('solver', schema.ProgressReport(
        status=Status.SOLVED, robot_model='panda')))
    assert old.arm_joints == () and old.arm_urdf_source == ''
    assert ArmRecord.from_report(old) is None


def test_reading_is_tolerant():
    """Messages from a recording: int levels, bad numbers, unknown keys and statuses."""
    msg = DiagnosticStatus(level=b'\x01', name='n', message='m', values=[
        KeyValue(key='status', value='NEW_STATUS'), KeyValue(key='iteration', value='x'),
        KeyValue(key='t_f', value='fast'), KeyValue(key='other', value='1')])
    back = schema.progress_from_msg(msg)
    assert back.status is Status.INVALID_INPUT and 'NEW_STATUS' in back.message
    assert back.iteration is None and math.isnan(back.t_f)

    class Decoded:        # what a bag reader gives: plain attributes, an int level
        level, name, message = 2, 'n', 'm'
        values = [KeyValue(key='status', value='SOLVED')]
    back = schema.progress_from_msg(Decoded)
    assert back.status is Status.SOLVED and back.level == DiagnosticStatus.ERROR


def test_obstacles_hash_depends_on_rows_and_margin():
    base = schema.obstacles_hash([(1.0, 1.0, 0.2)], 0.01)
    assert base == schema.obstacles_hash(((1.0, 1.0, 0.2),), 0.01)
    assert base != schema.obstacles_hash([(1.0, 1.0, 0.2)], 0.02)
    assert base != schema.obstacles_hash([(1.0, 1.0, 0.2), (0.4, 0.4, 0.1)], 0.01)
    assert schema.obstacles_hash([], 0.01) != base
    assert schema.obstacles_hash([(-0.0, 1.0, 0.2)], 0.01) == schema.obstacles_hash(
        [(0.0, 1.0, 0.2)], 0.01)


def test_no_other_module_spells_a_progress_key_or_status():
    """
    Only the schema (and the core's Status) spell status names; nobody reads keys by hand.

    Status names in quotes anywhere, and progress keys looked up with .get('key') (summary
    files may reuse a key's name for their own fields, which is not parsing ~/progress).
    """
    names = [s.value for s in Status] + [schema.SOLVING, schema.IDLE]
    quoted = '|'.join(map(re.escape, names))
    # Keys that summary files also have for their own fields are not checked.
    generic = {'status', 'mode', 'integrator', 'N', 'goal', 'iteration', 't_f', 'cost'}
    looked_up = '|'.join(re.escape(k) for k in schema.KEYS if k not in generic)
    pattern = re.compile(rf"""['"]({quoted})['"]|\.get\(['"]({looked_up})['"]""")
    allowed = {REPO / 'toc_ros' / 'progress.py', REPO / 'toc_ros' / 'core' / 'result.py'}
    offenders = []
    for path in sorted((REPO / 'toc_ros').rglob('*.py')):
        if path in allowed or 'sweep' in path.parts or 'core' in path.parts:
            continue
        for number, line in enumerate(path.read_text().splitlines(), 1):
            if pattern.search(line):
                offenders.append(f'{path.relative_to(REPO)}:{number}: {line.strip()}')
    assert not offenders, '\n'.join(offenders)
