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
Check an arm trajectory with Pinocchio, independently of the CasADi model that produced it.

The URDF is loaded by Pinocchio's own parser (the joints not planned locked with
pinocchio.buildReducedModel), the controls are re-integrated with pinocchio.aba (explicit
Euler or RK4 with the same h = t_f / N, controls constant on each interval), and every limit
and clearance is measured at every node k = 0..N on the re-integrated states:

    check = check_trajectory(spec, t_f, controls, integrator='euler', states=states)
    check['terminal_error'], check['max_position_excess'], check['min_clearance'], ...

Also where the example-robot-data URDFs are (example_robot_urdf).
"""

import importlib.metadata
import math
import os
import sys

import numpy as np

ROBOTS_SUBDIR = os.path.join('share', 'example-robot-data', 'robots')
EXAMPLE_URDFS = {'panda': os.path.join('panda_description', 'urdf', 'panda.urdf'),
                 'ur5': os.path.join('ur_description', 'urdf', 'ur5_robot.urdf')}
PANDA_JOINTS = tuple(f'panda_joint{i}' for i in range(1, 8))
UR5_JOINTS = ('shoulder_pan_joint', 'shoulder_lift_joint', 'elbow_joint', 'wrist_1_joint',
              'wrist_2_joint', 'wrist_3_joint')


def _robot_dirs():
    try:
        dist = importlib.metadata.distribution('example-robot-data')
        yield str(dist.locate_file(os.path.join('cmeel.prefix', ROBOTS_SUBDIR)))
    except importlib.metadata.PackageNotFoundError:
        pass
    for entry in sys.path:
        yield os.path.join(entry, 'cmeel.prefix', ROBOTS_SUBDIR)
        # A cmeel site-packages directory itself: <prefix>/lib/pythonX.Y/site-packages.
        yield os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(entry))),
                           ROBOTS_SUBDIR)


def example_robot_urdf(name):
    """Path of 'panda' or 'ur5' in the example-robot-data wheel (FileNotFoundError if absent)."""
    rel = EXAMPLE_URDFS[name]
    for folder in _robot_dirs():
        path = os.path.join(folder, rel)
        if os.path.isfile(path):
            return path
    raise FileNotFoundError(f'example-robot-data URDF {rel} not found (pip install '
                            'example-robot-data)')


def pinocchio_model(urdf, joints, locked=None):
    """
    (model, q_index, v_index, continuous) of Pinocchio for the planned joints, others locked.

    Locked joints take their given value or 0, clamped into Pinocchio's limits for them.
    q_index, v_index: the Pinocchio configuration and velocity index of each planned joint, in
    the caller's order.  Revolute and prismatic joints have one coordinate; a continuous joint
    (continuous[i]) is Pinocchio's unbounded revolute joint, (cos, sin) at q_index, q_index + 1.
    """
    import pinocchio as pin
    text = str(urdf)
    if text.lstrip().startswith('<'):
        full = pin.buildModelFromXML(text)
    else:
        full = pin.buildModelFromUrdf(text)
    locked = dict(locked or {})
    q_ref = pin.neutral(full)
    lock_ids = []
    for jid in range(1, full.njoints):
        name = full.names[jid]
        if name in joints:
            continue
        lock_ids.append(jid)
        i, nq = full.joints[jid].idx_q, full.joints[jid].nq
        if nq == 1:
            value = float(locked.get(name, 0.0))
            if name not in locked:
                value = min(max(value, full.lowerPositionLimit[i]), full.upperPositionLimit[i])
            q_ref[i] = value
    # buildReducedModel finds a locked joint by name among all frames: a link of the same name
    # (so100's 'gripper') is renamed while it runs.
    clashing = [f for f in full.frames
                if f.type == pin.FrameType.BODY and f.name in {full.names[j] for j in lock_ids}]
    for frame in clashing:
        frame.name += ' (link)'
    model = pin.buildReducedModel(full, lock_ids, q_ref) if lock_ids else full
    for frame in model.frames:
        if frame.name.endswith(' (link)'):
            frame.name = frame.name[:-len(' (link)')]
    q_index, v_index, continuous = [], [], []
    for name in joints:
        jid = model.getJointId(name)
        if jid >= model.njoints or model.joints[jid].nv != 1 or model.joints[jid].nq not in (
                1, 2):
            raise ValueError(f'joint {name}: not a one-degree-of-freedom joint of the '
                             'Pinocchio model')
        q_index.append(model.joints[jid].idx_q)
        v_index.append(model.joints[jid].idx_v)
        continuous.append(model.joints[jid].nq == 2)
    return model, np.asarray(q_index), np.asarray(v_index), np.asarray(continuous, dtype=bool)


def check_trajectory(spec, t_f, controls, integrator='euler', states=None):
    """
    Re-integrate controls (N, n) over t_f with pinocchio.aba from spec.start; measure all.

    Returns a dict (every limit at every node k = 0..N of the re-integrated trajectory):
    terminal_error (inf-norm of x(N) - goal), defect (inf-norm of the re-integrated states
    minus `states`, when given), max_position_excess, max_velocity_excess, max_effort_excess
    (>= 0, 0 when within), min_clearance (min over nodes and (sphere, obstacle) pairs of
    |p_s - c_o| - (r_s + R_o + margin); inf without obstacles), states (re-integrated).
    """
    import pinocchio as pin
    from .arm_problem import load_spheres
    model, idx, vdx, continuous = pinocchio_model(spec.urdf, spec.joints, spec.locked)
    data = model.createData()
    n = len(spec.joints)
    controls = np.asarray(controls, dtype=float)
    n_int = controls.shape[0]
    h = float(t_f) / n_int

    def full_q(q):
        out = pin.neutral(model)
        out[idx] = np.where(continuous, np.cos(q), q)
        out[idx[continuous] + 1] = np.sin(q[continuous])
        return out

    def accel(x, u):
        tau, v = np.zeros(model.nv), np.zeros(model.nv)
        tau[vdx], v[vdx] = u, x[n:]
        qdd = pin.aba(model, data, full_q(x[:n]), v, tau)
        return np.concatenate([x[n:], qdd[vdx]])

    def _x(values):
        x = np.asarray(values, dtype=float).ravel()
        return np.concatenate([x, np.zeros(n)]) if x.size == n else x

    x0, xg = _x(spec.start), _x(spec.goal)
    xs = np.empty((n_int + 1, 2 * n))
    xs[0] = x0
    for k in range(n_int):
        x, u = xs[k], controls[k]
        if integrator == 'euler':
            xs[k + 1] = x + h * accel(x, u)
        elif integrator == 'rk4':
            k1 = accel(x, u)
            k2 = accel(x + 0.5 * h * k1, u)
            k3 = accel(x + 0.5 * h * k2, u)
            k4 = accel(x + h * k3, u)
            xs[k + 1] = x + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        else:
            raise ValueError(f'unknown integrator {integrator!r}')
    lower, upper, effort, velocity = _limits(model, idx, vdx, continuous, spec)
    q, qd = xs[:, :n], xs[:, n:]
    out = {
        'terminal_error': float(np.max(np.abs(xs[-1] - xg))),
        'defect': (float(np.max(np.abs(xs - np.asarray(states)))) if states is not None
                   else math.nan),
        'max_position_excess': float(max(np.max(q - upper), np.max(lower - q), 0.0)),
        'max_velocity_excess': float(max(np.max(np.abs(qd) - velocity), 0.0)),
        'max_effort_excess': float(max(np.max(np.abs(controls) - effort), 0.0)),
        'min_clearance': math.inf,
        'states': xs,
    }
    spheres = load_spheres(spec.robot_spheres)
    obstacles = np.asarray(spec.obstacles, dtype=float).reshape(-1, 4)
    if obstacles.shape[0] and spheres:
        frames = {link: model.getFrameId(link, pin.BODY) for link in spheres}
        worst = math.inf
        for k in range(n_int + 1):
            pin.framesForwardKinematics(model, data, full_q(q[k]))
            for link, rows in spheres.items():
                placement = data.oMf[frames[link]]
                for x, y, z, r in rows:
                    centre = placement.act(np.array([x, y, z], dtype=float))
                    dist = np.linalg.norm(centre[None, :] - obstacles[:, :3], axis=1)
                    worst = min(worst, float(np.min(dist - (r + obstacles[:, 3] + spec.margin))))
        out['min_clearance'] = worst
    return out


def _limits(model, idx, vdx, continuous, spec):
    # A continuous joint's angle is unbounded (Pinocchio's limits there bound cos and sin).
    lower = np.where(continuous, -np.inf, model.lowerPositionLimit[idx]).astype(float)
    upper = np.where(continuous, np.inf, model.upperPositionLimit[idx]).astype(float)
    effort = np.array(model.effortLimit[vdx], dtype=float)
    velocity = np.array(model.velocityLimit[vdx], dtype=float)
    for i, name in enumerate(spec.joints):
        for key, value in (spec.limits or {}).get(name, {}).items():
            {'lower': lower, 'upper': upper, 'effort': effort, 'velocity': velocity}[key][i] = \
                float(value)
    return lower, upper, effort, velocity
