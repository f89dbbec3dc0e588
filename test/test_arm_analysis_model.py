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
toc-analyze rebuilds a URDF arm from its recording alone (the arm_* fields of ~/progress).

The reports are solver_node's own: SolverNodeConfig.model_keys of an accepted parameter set
with robot.model urdf, the Panda's URDF given by parameter (panda_joint7's effort limit
changed), a sphere file of one sphere per link (radii unlike the shipped set's), joint-limit
overrides, a finger locked open and a tip link.  The sphere file is deleted before the
analysis; clearances and limit excesses are recomputed by the independent oracle (arm_oracle)
from the URDF text and the sphere rows kept by the test.
"""

import hashlib
import json
import re

from arm_oracle import ArmOracle, find_panda_urdf, PANDA_JOINTS, PANDA_SPHERES
import numpy as np
import pytest
from rclpy.serialization import serialize_message
from test_arm_analysis import motion, T0, write_run
from toc_ros import arm_config
from toc_ros import progress as schema
from toc_ros.analysis.cli import main
from toc_ros.core import Status
from toc_ros.nodes import parameters
from toc_ros.nodes.solver_settings import checked
from toc_ros.recording.bag_writer import BagWriter
import yaml

LINKS = [f'panda_link{i}' for i in range(8)] + ['panda_hand', 'panda_leftfinger',
                                                'panda_rightfinger']
FINGER = 0.03                   # panda_finger_joint1 locked open [m] (URDF limits 0 .. 0.04)
LIMITS = ['panda_joint1.upper=0.8', 'panda_joint2.velocity=1.0']
TIP = 'panda_link8'
EFFORT7 = 20.0                  # panda_joint7's effort limit in the recorded URDF (12 shipped)


def urdf_text():
    """Return the Panda's URDF with panda_joint7's effort limit set to EFFORT7."""
    text = find_panda_urdf().read_text()
    head, joint, tail = text.partition('<joint name="panda_joint7"')
    body, end, rest = tail.partition('</joint>')
    body, count = re.subn(r'effort="[^"]*"', f'effort="{EFFORT7}"', body)
    assert count == 1
    return head + joint + body + end + rest


def write_spheres(path):
    """Write a sphere file: one sphere per link, radii 0.04 + 0.005 k (shipped: others)."""
    doc = {link: [[0.0, 0.0, 0.02, 0.04 + 0.005 * k]] for k, link in enumerate(LINKS)}
    # The two fingers are held together by their locked joints: never checked.
    doc['ignore_pairs'] = [['panda_leftfinger', 'panda_rightfinger']]
    path.write_text(yaml.safe_dump(doc))
    return path


def node_config(**changes):
    """Return the SolverNodeConfig solver_node accepts for the Panda's joints and changes."""
    values = {name: parameters.default(name) for name in parameters.SOLVER_NODE_NAMES}
    values.update(arm_config.TOPIC_DEFAULTS)
    values.update({'joint_names': PANDA_JOINTS, 'solver.N': 20})
    values.update(changes)
    errors, config = checked(values)
    assert not errors, errors
    return config


def custom_config(spheres):
    """Return the config of the custom arm: robot.model urdf, its URDF by parameter."""
    return node_config(**{'robot.model': 'urdf', 'robot_description': urdf_text(),
                          'robot.collision_spheres': str(spheres),
                          'robot.joint_limits': LIMITS, 'robot.tip_link': TIP,
                          'robot.locked_joints': [f'panda_finger_joint1={FINGER}']})


def node_reports(config, ready=True):
    """Return the reports solver_node writes of config: ready (with texts), then results."""
    reports = [schema.ProgressReport(message='ready', event=schema.EVENT_READY, elapsed_s=1.0,
                                     **config.model_keys(texts=True))] if ready else []
    return reports + [schema.ProgressReport(status=Status.SOLVED, message='solved',
                                            **config.model_keys()),
                      schema.ProgressReport(status=Status.SOLVED, latency_s=0.01,
                                            event=schema.EVENT_REPLANNED, **config.model_keys())]


def finger_sets(oracle):
    """
    Return the obstacle sets: one sphere at sample 25 only, then a far one.

    The sphere is 2 cm into the left finger's, beyond it as seen from the hand's sphere, so
    that the finger is the nearest (its locked opening matters).
    """
    times, q, _, _ = motion(oracle)
    centres = {}
    for frame, offset, radius in oracle.spheres:
        link = oracle.model.frames[frame].name
        centres[link] = oracle.tip(q[25], link).act(offset), radius
    (finger, radius), (hand, _) = centres['panda_leftfinger'], centres['panda_hand']
    away = (finger - hand) / np.linalg.norm(finger - hand)
    centre = finger + away * (radius + 0.05 - 0.02)
    return [(times[25] - 0.005, [tuple(centre) + (0.05,)]),
            (times[25] + 0.005, [(2.0, 2.0, 2.0, 0.1)])]


def expected_clearance(oracle, times, q, sets):
    """Return (min clearance, its time on the analysis' base) over the samples."""
    values = np.array([oracle.clearance(qk, [r for s, r in sets if s <= t][-1], 0.0)
                       if sets[0][0] <= t else np.inf for t, qk in zip(times, q)])
    worst = int(np.argmin(values))
    # The analysis counts from the first message: the first report at 0.18 s (write_run).
    return values[worst], times[worst] - min(0.18, sets[0][0])


def analyse(bag, out, capsys, *extra):
    assert main([str(bag), '--out', str(out), *extra]) == 0, capsys.readouterr().err
    return json.loads((out / 'summary.json').read_text())


@pytest.fixture
def custom(tmp_path):
    """Return (config, oracle of the custom arm, its obstacle sets) with the file deleted."""
    spheres = write_spheres(tmp_path / 'my_spheres.yaml')
    config = custom_config(spheres)
    oracle = ArmOracle(urdf_text(), spheres, locked={'panda_finger_joint1': FINGER})
    spheres.unlink()        # the analysis must not need it
    return config, oracle, finger_sets(oracle)


def test_the_recorded_arm_is_rebuilt_without_its_files(custom, tmp_path, capsys):
    config, oracle, sets = custom
    bag = tmp_path / 'urdf_run'
    times, q, dq, effort = write_run(bag, oracle, node_reports(config), sets)
    summary = analyse(bag, tmp_path / 'report', capsys)
    assert not summary['warnings'], summary['warnings']
    model = summary['model']
    assert (model['name'], model['joints'], model['source']) == (
        'urdf', PANDA_JOINTS, 'solver progress')
    assert model['spheres'] == len(LINKS) and model['tip_link'] == TIP
    value, time = expected_clearance(oracle, times, q, sets)
    c = summary['min_clearance']
    assert value < 0.0 and abs(c['value'] - value) < 1e-9 and abs(c['time_s'] - time) < 1e-6
    # The clearance tells the recorded arm apart: the shipped spheres or a closed finger
    # (what an analysis without the recorded settings would assume) give another one.
    kept = write_spheres(tmp_path / 'kept.yaml')
    for other in (ArmOracle(urdf_text(), PANDA_SPHERES, locked={'panda_finger_joint1': FINGER}),
                  ArmOracle(urdf_text(), kept)):
        assert abs(expected_clearance(other, times, q, sets)[0] - value) > 1e-3
    # Limits: the overrides and the recorded URDF's effort limit, computed here.
    excess = summary['limit_excess']
    assert abs(excess['position'][0] - (np.max(q[:, 0]) - 0.8)) < 1e-9
    assert abs(excess['velocity'][1] - (np.max(np.abs(dq[:, 1])) - 1.0)) < 1e-9
    assert abs(excess['effort'][6] - (np.max(np.abs(effort[:, 6])) - EFFORT7)) < 1e-9
    assert excess['effort'][6] == pytest.approx(3.0)


def test_a_recording_without_the_ready_report_says_what_it_assumed(custom, tmp_path, capsys):
    """The texts ride on the ready report only: without it, files are matched by sha256."""
    _, _, sets = custom
    # The Panda by name (its URDF shipped) with custom spheres, whose file is deleted.
    spheres = write_spheres(tmp_path / 'panda_spheres.yaml')
    config = node_config(**{'robot.model': 'panda', 'robot.collision_spheres': str(spheres),
                            'robot.locked_joints': [f'panda_finger_joint1={FINGER}']})
    copy = tmp_path / 'elsewhere.yaml'
    copy.write_text(spheres.read_text())
    spheres.unlink()
    urdf = find_panda_urdf().read_text()
    bag = tmp_path / 'late_run'
    oracle = ArmOracle(urdf, copy, locked={'panda_finger_joint1': FINGER})
    times, q, _, _ = write_run(bag, oracle, node_reports(config, ready=False), sets)
    summary = analyse(bag, tmp_path / 'assumed', capsys)
    warning = [w for w in summary['warnings'] if 'collision spheres planned with' in w]
    assert len(warning) == 1 and str(spheres) in warning[0], summary['warnings']
    digest = hashlib.sha256(copy.read_text().encode()).hexdigest()[:12]
    assert digest in warning[0] and 'assumed the shipped panda set' in warning[0]
    assumed = ArmOracle(urdf, PANDA_SPHERES, locked={'panda_finger_joint1': FINGER})
    value, _ = expected_clearance(assumed, times, q, sets)
    assert abs(summary['min_clearance']['value'] - value) < 1e-9
    # --params naming a file with the same content: found by its sha256, nothing assumed.
    summary = analyse(bag, tmp_path / 'matched', capsys, '--params',
                      str(params_file(tmp_path, collision_spheres=str(copy))))
    assert not summary['warnings'], summary['warnings']
    value, _ = expected_clearance(oracle, times, q, sets)
    assert abs(summary['min_clearance']['value'] - value) < 1e-9


def test_missing_texts_that_nothing_replaces_are_refused_with_the_reason(custom, tmp_path,
                                                                         capsys):
    """robot.model urdf by parameter without its ready report: neither spheres nor URDF."""
    config, _, _ = custom
    bag = tmp_path / 'no_texts'
    writer = BagWriter(bag, flush_period=None).create()
    writer.add_topic('/solver_node/progress', 'diagnostic_msgs/msg/DiagnosticStatus', [])
    for k, report in enumerate(node_reports(config, ready=False)):
        writer.write('/solver_node/progress',
                     serialize_message(schema.progress_msg('solver_node', report)), T0 + k)
    writer.close()
    assert main([str(bag), '--out', str(tmp_path / 'r')]) == 2
    err = capsys.readouterr().err
    assert "the recorded arm 'urdf' cannot be rebuilt" in err
    assert 'give robot.collision_spheres in --params' in err and 'sha256' in err
    # Spheres given (any file: what is assumed is said), the URDF is still missing.
    params = params_file(tmp_path, collision_spheres=str(PANDA_SPHERES))
    assert main([str(bag), '--out', str(tmp_path / 'r'), '--params', str(params)]) == 2
    err = capsys.readouterr().err
    assert 'assumed robot.collision_spheres of --params' in err and 'no URDF' in err
    # Both from --params, found by their sha256 (the same sphere rows written again).
    spheres = write_spheres(tmp_path / 'same.yaml')
    out = tmp_path / 'found'
    params = params_file(tmp_path, urdf_text(), collision_spheres=str(spheres))
    assert main([str(bag), '--out', str(out), '--params', str(params)]) == 0
    summary = json.loads((out / 'summary.json').read_text())
    assert not summary['warnings'] and summary['model']['spheres'] == len(LINKS)
    # Another URDF (the shipped one: panda_joint7's effort limit 12) is assumed, and said.
    params = params_file(tmp_path, find_panda_urdf().read_text(),
                         collision_spheres=str(spheres))
    assert main([str(bag), '--out', str(out), '--params', str(params)]) == 0
    summary = json.loads((out / 'summary.json').read_text())
    urdf_sha = hashlib.sha256(urdf_text().strip().encode()).hexdigest()[:12]
    assert len(summary['warnings']) == 1, summary['warnings']
    assert f'URDF planned with (robot_description parameter, sha256 {urdf_sha})' in \
        summary['warnings'][0]
    assert 'assumed the URDF of robot_description of --params' in summary['warnings'][0]


def params_file(folder, description=None, **robot):
    """Write a ROS 2 parameter file: robot_description and robot.* values; return its path."""
    path = folder / 'params.yaml'
    values = {'robot': robot}
    if description is not None:
        values['robot_description'] = description
    path.write_text(yaml.safe_dump({'/**': {'ros__parameters': values}}))
    return path
