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
The URDF arm of a recording, rebuilt from what solver_node's progress reports say of it.

Its ready and result reports name the arm (toc_ros.arm_record): joints, locked values, limit
overrides, tip link, and the sources and sha256 of its URDF and sphere file, whose texts the
ready report carries.  Those win over --params and the defaults: they are what was planned
with.  A text the recording lacks (it starts after the ready report) is looked for by its
sha256 in the recorded robot_description topic, --params and the local files; when none has
it, the warning says what was assumed instead.  Recordings made before the reports carried
the arm are rebuilt as then (--params, the arm settings' defaults, the joints of the first
trajectory, the last recorded robot_description) with a warning that lists the assumptions.
"""

from toc_ros import arm_config
from toc_ros.arm_record import ArmRecord, file_text, sha256, SHIPPED, URDF_PARAMETER, URDF_TOPIC
from toc_ros.config import model_from_parameters
from toc_ros.core import ProblemError
from toc_ros.core.arms.spheres import SHIPPED_NAMES, shipped_spheres_path
from toc_ros.core.settings import parameter_table
import yaml


NO_URDF = 'no URDF (record the robot_description topic, or give robot_description in --params)'


def _short(digest):
    return digest[:12]


def recorded_arm(run, name, reports, warn=None):
    """
    Return (ArmPlanModel, its flat arm parameters) of the recorded arm robot.model `name`.

    reports: the recording's ProgressReports that name this model, in order ([] when only
    --params name it); the first record among them is analysed.  ProblemError with the
    reason when the arm cannot be rebuilt.
    """
    records = [r for r in map(ArmRecord.from_report, reports) if r is not None]
    if not records:
        params = arm_parameters(run, name, warn=warn)
        return _built(params), params
    record = records[0]
    if warn is not None and any(not record.same_arm(r) for r in records[1:]):
        warn(f'the {name} arm changed during the recording (settings or files of later '
             'progress reports differ): analysing with the first one')
    params = arm_parameters(run, name, record, warn, records)
    spheres = next((r.spheres for r in records
                    if r.spheres and sha256(r.spheres) == record.spheres_sha256), None)
    if spheres is None:
        params['robot.collision_spheres'] = _local_spheres(run, name, record, warn)
    model = _built(params, spheres)
    if record.urdf_source == name and model.arm.source['sha256'] != record.urdf_sha256 \
            and warn is not None:
        here = _short(model.arm.source['sha256'])
        warn(f'the {name} URDF here (example-robot-data, sha256 {here}) is not the one '
             f'planned with (sha256 {_short(record.urdf_sha256)}): kinematics and limits '
             'may differ')
    return model, params


def arm_parameters(run, name, record=None, warn=None, records=()):
    """
    Return the flat parameters that rebuild the recorded arm robot.model `name`.

    record: the ArmRecord of its progress reports (its settings win over --params; records:
    all of them, whose texts are searched for its URDF); None for recordings without one:
    --params (the arm settings' defaults where they have none), the planned joints of the
    first recorded trajectory and the last recorded robot_description.
    """
    params = {p.name: p.default for p in parameter_table(arm_config.ArmSettings)}
    params.update(run.params)
    params['robot.model'] = name
    if record is None:
        _legacy(run, name, params, warn)
        return params
    params.update({'joint_names': list(record.joints),
                   'robot.locked_joints': list(record.locked),
                   'robot.joint_limits': list(record.joint_limits),
                   'robot.tip_link': record.tip_link,
                   'robot.payload_mass': record.payload_mass})
    params[arm_config.TOPIC_DESCRIPTION] = ''
    if record.urdf_source in (URDF_PARAMETER, URDF_TOPIC):
        params['robot_description'] = _urdf(run, record, records or (record,), warn)
    return params


def _legacy(run, name, params, warn):
    """Fill the parameters of a recording without an ArmRecord; warn what is assumed."""
    assumed = []
    for _, msg in run.messages.get('trajectory', ()):
        if msg.joint_names:
            params['joint_names'] = list(msg.joint_names)
            break
    else:
        names = ', '.join(str(n) for n in params.get('joint_names', ()))
        assumed.append(f'the joint_names of --params ({names})')
    descriptions = run.messages.get('robot_description', ())
    if descriptions:
        params[arm_config.TOPIC_DESCRIPTION] = descriptions[-1][1].data
    if name == 'urdf' and not str(run.params.get('robot_description', '')).strip() \
            and descriptions:
        assumed.append('the last recorded robot_description')
    if not str(run.params.get('robot.collision_spheres', '')).strip() \
            and name in SHIPPED_NAMES:
        assumed.append(f'the shipped {name} collision spheres')
    if not run.params.get('robot.joint_limits'):
        assumed.append("the URDF's joint limits")
    if not run.params.get('robot.locked_joints'):
        assumed.append('the joints not planned locked at 0 (clamped into their limits)')
    if not str(run.params.get('robot.tip_link', '')).strip():
        assumed.append('the default tip link')
    if assumed and warn is not None:
        warn(f'the recording does not name the settings of the {name} arm planned with '
             '(no ~/progress report carries them: made before solver_node reported them, or '
             'without ~/progress; --params can give them): assumed ' + '; '.join(assumed))


def _urdf(run, record, records, warn):
    """Return the URDF text of robot.model urdf: the one planned with, else what is assumed."""
    texts = [('a ready report', r.urdf) for r in records if r.urdf]
    texts += [('the recorded robot_description topic', msg.data)
              for _, msg in reversed(run.messages.get('robot_description', ()))]
    given = str(run.params.get('robot_description', '')).strip()
    if given:
        texts.insert(0, ('robot_description of --params', given))
    for _, text in texts:
        # As the node hashes it: the parameter or topic value without surrounding blanks.
        if sha256(text.strip()) == record.urdf_sha256:
            return text.strip()
    if not texts:
        return ''           # _built says that there is no URDF
    where, text = texts[0]
    why = ("it starts after solver_node's ready report" if record.urdf_source == URDF_PARAMETER
           else 'that robot_description message was not recorded')
    if warn is not None:
        warn(f'the URDF planned with (robot_description {record.urdf_source}, sha256 '
             f'{_short(record.urdf_sha256)}) is not in the recording ({why}); assumed the '
             f'URDF of {where} (sha256 {_short(sha256(text.strip()))}): kinematics and '
             'limits may differ')
    return text.strip()


def _local_spheres(run, name, record, warn):
    """Return the path of a local sphere file for a record whose sphere text is missing."""
    candidates = []
    given = str(run.params.get('robot.collision_spheres', '')).strip()
    if given:
        candidates.append(('robot.collision_spheres of --params', given))
    if record.spheres_source != SHIPPED:
        candidates.append(('the recorded path', record.spheres_source))
    if name in SHIPPED_NAMES:
        candidates.append((f'the shipped {name} set', shipped_spheres_path(name)))
    readable = []
    for where, path in candidates:
        try:
            digest = sha256(file_text(path))
        except (OSError, UnicodeDecodeError):
            continue
        if digest == record.spheres_sha256:
            return path
        readable.append((where, path, digest))
    planned = (f'the collision spheres planned with ({record.spheres_source}, sha256 '
               f'{_short(record.spheres_sha256)}) are not in the recording (it starts after '
               "solver_node's ready report)")
    if not readable:
        raise ProblemError(f'the recorded arm {name!r} cannot be rebuilt: {planned} and no '
                           'local file has them: give robot.collision_spheres in --params')
    where, path, digest = readable[0]
    if warn is not None:
        warn(f'{planned}; assumed {where} {path} (sha256 {_short(digest)}): clearances may '
             'differ')
    return path


def _built(params, spheres=None):
    """
    Return the arm model of flat parameters (ProblemError with the reason).

    spheres: the recorded YAML text of the sphere set (None: robot.collision_spheres or the
    shipped set, read as solver_node reads them).
    """
    name = params['robot.model']
    why = f'the recorded arm {name!r} cannot be rebuilt'
    if spheres is None:
        try:
            model = model_from_parameters(params)
        except ProblemError as error:
            raise ProblemError(f'{why}: {error}') from None
        if getattr(model, 'pending', False):
            raise ProblemError(f'{why}: {NO_URDF}')
        return model
    description = arm_config.effective_description(params) if name == 'urdf' else ''
    if name == 'urdf' and not description:
        raise ProblemError(f'{why}: {NO_URDF}')
    try:
        mapping = yaml.safe_load(spheres)
    except yaml.YAMLError as exc:
        raise ProblemError(f'{why}: its recorded collision spheres are not YAML: {exc}') \
            from None
    if not isinstance(mapping, dict) or not mapping:
        raise ProblemError(f'{why}: its recorded collision spheres are no mapping of links')
    from toc_ros.arm_model import build_arm     # Pinocchio: only when an arm is analysed
    try:
        arm = arm_config.settings(params)
        return build_arm(name, description, tuple(params['joint_names']),
                         arm_config.locked_values(arm.locked_joints),
                         arm_config.limit_overrides(arm.joint_limits), mapping)
    except ProblemError as error:
        raise ProblemError(f'{why}: {error}') from None
