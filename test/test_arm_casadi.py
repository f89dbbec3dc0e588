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
Checks of the CasADi arm reference (toc_ros/bench): model against Pinocchio, solves re-checked.

The CasADi recursions (own URDF parser) against Pinocchio's parser and algorithms on the
example-robot-data Panda (fingers locked) and UR5: forward dynamics, inverse dynamics, mass
matrix and link frame placements to 1e-10 over random states within the limits.  Small IPOPT
solves whose controls this file re-integrates with pinocchio.aba itself and whose limits and
clearances it measures itself at every node.
"""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

ca = pytest.importorskip('casadi')
pin = pytest.importorskip('pinocchio')

from toc_ros.bench import arm_casadi as ac  # noqa: E402
from toc_ros.bench import arm_problem as ap  # noqa: E402
from toc_ros.bench import arm_reference as ar  # noqa: E402
from toc_ros.bench import urdf_tree as ut  # noqa: E402
from toc_ros.bench.arm_check import (  # noqa: E402
    check_trajectory, example_robot_urdf, PANDA_JOINTS, UR5_JOINTS)

DATA = Path(__file__).resolve().parent / 'data'
FINGERS = ('panda_finger_joint1', 'panda_finger_joint2')
ROBOTS = {'panda': PANDA_JOINTS, 'ur5': UR5_JOINTS}
TOL = 1e-10


def _urdf(name):
    try:
        return example_robot_urdf(name)
    except FileNotFoundError as exc:
        pytest.skip(str(exc))


def _pinocchio(path, joints, locked=None):
    """Pinocchio's own reduced model (independent of toc_ros.bench's parser)."""
    full = pin.buildModelFromUrdf(path)
    q_ref = pin.neutral(full)
    lock = []
    for jid in range(1, full.njoints):
        if full.names[jid] not in joints:
            lock.append(jid)
            q_ref[full.joints[jid].idx_q] = (locked or {}).get(full.names[jid], 0.0)
    model = pin.buildReducedModel(full, lock, q_ref) if lock else full
    assert [model.names[j] for j in range(1, model.njoints)] == list(joints)
    return model


@pytest.fixture(scope='module', params=sorted(ROBOTS))
def robot(request):
    name = request.param
    path = _urdf(name)
    model = ac.load_arm(path, ROBOTS[name])
    return name, path, model, _pinocchio(path, ROBOTS[name])


def _random_states(tree, rng, count):
    lower, upper, effort, velocity = tree.limits()
    for _ in range(count):
        yield (rng.uniform(lower, upper), rng.uniform(-velocity, velocity),
               rng.uniform(-effort, effort), rng.normal(scale=3.0, size=tree.nq))


def test_dynamics_match_pinocchio(robot):
    _, _, model, pmodel = robot
    data = pmodel.createData()
    rng = np.random.default_rng(11)
    worst = {'aba': 0.0, 'rnea': 0.0, 'crba': 0.0, 'crba_fd': 0.0}
    for q, qd, tau, qdd in _random_states(model.tree, rng, 40):
        ref_acc = pin.aba(pmodel, data, q, qd, tau)
        worst['aba'] = max(worst['aba'], np.max(np.abs(
            np.asarray(model.forward_dynamics(q, qd, tau)).ravel() - ref_acc)))
        worst['crba_fd'] = max(worst['crba_fd'], np.max(np.abs(
            np.asarray(model.crba_dynamics(q, qd, tau)).ravel() - ref_acc)))
        worst['rnea'] = max(worst['rnea'], np.max(np.abs(
            np.asarray(model.rnea(q, qd, qdd)).ravel() - pin.rnea(pmodel, data, q, qd, qdd))))
        mass = pin.crba(pmodel, data, q)
        mass = np.triu(mass) + np.triu(mass, 1).T          # Pinocchio fills the upper half
        worst['crba'] = max(worst['crba'],
                            np.max(np.abs(np.asarray(model.mass_matrix(q)) - mass)))
    assert worst['aba'] < TOL and worst['rnea'] < TOL and worst['crba'] < TOL, worst
    # M^-1 by casadi's symbolic QR: accelerations up to ~1e3 rad/s^2 lose about two digits.
    assert worst['crba_fd'] < 1e-9, worst


def test_link_frames_and_points_match_pinocchio(robot):
    _, _, model, pmodel = robot
    data = pmodel.createData()
    links = sorted(model.tree.links)
    rng = np.random.default_rng(12)
    local = rng.normal(scale=0.1, size=(len(links), 3))
    points = model.point_positions(list(zip(links, map(tuple, local))))
    lower, upper, _, _ = model.tree.limits()
    frames = {link: ca.Function('frame', [model.q], list(model.link_placement(link)))
              for link in links}
    for _ in range(20):
        q = rng.uniform(lower, upper)
        pin.framesForwardKinematics(pmodel, data, q)
        got = np.asarray(points(q))
        for j, link in enumerate(links):
            placement = data.oMf[pmodel.getFrameId(link, pin.BODY)]
            np.testing.assert_allclose(got[:, j], placement.act(local[j]), rtol=0, atol=TOL)
            rot, pos = frames[link](q)
            np.testing.assert_allclose(np.asarray(rot), placement.rotation, rtol=0, atol=TOL)
            np.testing.assert_allclose(np.asarray(pos).ravel(), placement.translation, rtol=0,
                                       atol=TOL)


def test_locked_fingers_at_other_values_match_pinocchio():
    path = _urdf('panda')
    locked = {FINGERS[0]: 0.03, FINGERS[1]: 0.01}
    model = ac.load_arm(path, PANDA_JOINTS, locked=locked)
    pmodel = _pinocchio(path, PANDA_JOINTS, locked)
    data = pmodel.createData()
    rng = np.random.default_rng(13)
    for q, qd, tau, _ in _random_states(model.tree, rng, 10):
        np.testing.assert_allclose(np.asarray(model.forward_dynamics(q, qd, tau)).ravel(),
                                   pin.aba(pmodel, data, q, qd, tau), rtol=0, atol=TOL)
    # The default lock is 0 clamped into the limits, like a value given explicitly.
    assert ut.parse_urdf(path, PANDA_JOINTS).locked == {FINGERS[0]: 0.0, FINGERS[1]: 0.0}


def test_joint_order_is_the_callers():
    path = _urdf('ur5')
    order = UR5_JOINTS[::-1]
    model = ac.load_arm(path, order)
    pmodel = _pinocchio(path, UR5_JOINTS)
    data = pmodel.createData()
    rng = np.random.default_rng(14)
    for q, qd, tau, _ in _random_states(ut.parse_urdf(path, UR5_JOINTS), rng, 5):
        got = np.asarray(model.forward_dynamics(q[::-1], qd[::-1], tau[::-1])).ravel()
        np.testing.assert_allclose(got[::-1], pin.aba(pmodel, data, q, qd, tau), rtol=0,
                                   atol=TOL)


def test_bad_input_is_refused_with_the_reason():
    path = _urdf('panda')
    with pytest.raises(ut.UrdfError, match='unknown planned joint'):
        ut.parse_urdf(path, PANDA_JOINTS[:6] + ('elbow',))
    with pytest.raises(ut.UrdfError, match="type 'fixed' cannot be planned"):
        ut.parse_urdf(path, ('panda_joint8',))
    with pytest.raises(ut.UrdfError, match='does not parse'):
        ut.parse_urdf('<robot><link name="a"></robot>', ('j',))
    with pytest.raises(ut.UrdfError, match='neither XML text nor an existing file'):
        ut.parse_urdf('/nonexistent/robot.urdf', ('j',))
    with pytest.raises(ut.UrdfError, match='both planned and locked'):
        ut.parse_urdf(path, PANDA_JOINTS, locked={'panda_joint1': 0.0})
    text = Path(path).read_text(encoding='utf-8').replace('effort="87.0"', 'effort="0"', 1)
    with pytest.raises(ut.UrdfError, match='panda_joint1 has no positive effort'):
        ut.parse_urdf(text, PANDA_JOINTS)
    # ... unless overridden (the joint_limits.yaml way).
    tree = ut.parse_urdf(text, PANDA_JOINTS, limits={'panda_joint1': {'effort': 50.0}})
    assert tree.limits()[2][0] == 50.0
    q0 = (0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.8)
    spec = ap.ArmSpec(urdf=path, joints=PANDA_JOINTS, start=q0, goal=q0,
                      robot_spheres=str(DATA / 'arm_spheres_panda.yaml'))
    with pytest.raises(ap.SpecError, match='negative radius'):
        ap.ArmProblem(replace(spec, robot_spheres={'panda_hand': [[0, 0, 0, -0.1]]}))
    with pytest.raises(ap.SpecError, match="unknown link 'no_link'"):
        ap.ArmProblem(replace(spec, robot_spheres={'no_link': [[0, 0, 0, 0.1]]}))
    with pytest.raises(ap.SpecError, match=r'start state: panda_joint4 = 0.5 outside'):
        ap.ArmProblem(replace(spec, start=q0[:3] + (0.5,) + q0[4:]))
    with pytest.raises(ap.SpecError, match=r'goal must be 7 joint positions or 14'):
        ap.ArmProblem(replace(spec, goal=q0[:6]))
    with pytest.raises(ap.SpecError, match=r'goal must be .* finite'):
        ap.ArmProblem(replace(spec, goal=q0[:6] + (np.nan,)))
    # An obstacle at the hand sphere's centre: the pair and the depth in the message.
    hand = np.asarray(ap.ArmProblem(spec).points(np.array(q0)))[:, 1]
    with pytest.raises(ap.SpecError, match=r'start state: sphere panda_hand\[0\] inside '
                                           r'obstacle 0 .* by 0.13 m'):
        ap.ArmProblem(replace(spec, obstacles=(tuple(hand) + (0.05,),)))
    with pytest.raises(ap.SpecError, match='integrator must be one of'):
        ar.ArmTranscription(ap.ArmProblem(spec), 10, 'midpoint')


# ----------------------------------------------------------------------------------------
# solves, re-checked here with Pinocchio
# ----------------------------------------------------------------------------------------

UR5_START = (-1.0, -1.6, 1.6, -1.5, -1.57, 0.0)
UR5_GOAL = (1.2, -1.2, 1.3, -1.6, -1.57, 0.5)


def _reintegrate(pmodel, x0, controls, t_f, integrator):
    """States (N+1, 2n) from pinocchio.aba, explicit Euler or RK4, constant controls."""
    data = pmodel.createData()
    n = pmodel.nv

    def f(x, u):
        return np.concatenate([x[n:], pin.aba(pmodel, data, x[:n], x[n:], u)])

    h = t_f / len(controls)
    xs = [np.asarray(x0, dtype=float)]
    for u in controls:
        x = xs[-1]
        if integrator == 'euler':
            xs.append(x + h * f(x, u))
        else:
            k1 = f(x, u)
            k2 = f(x + 0.5 * h * k1, u)
            k3 = f(x + 0.5 * h * k2, u)
            k4 = f(x + h * k3, u)
            xs.append(x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4))
    return np.array(xs)


def _assert_limits(pmodel, states, controls):
    n = pmodel.nv
    q, qd = states[:, :n], states[:, n:]
    assert np.all(q >= pmodel.lowerPositionLimit - 1e-9)
    assert np.all(q <= pmodel.upperPositionLimit + 1e-9)
    assert np.all(np.abs(qd) <= pmodel.velocityLimit + 1e-9)
    assert np.all(np.abs(controls) <= pmodel.effortLimit + 1e-9)


def _clearance(pmodel, states, spheres, obstacles, margin):
    data = pmodel.createData()
    n = pmodel.nv
    out = []
    for x in states:
        pin.framesForwardKinematics(pmodel, data, x[:n])
        for link, rows in spheres.items():
            placement = data.oMf[pmodel.getFrameId(link, pin.BODY)]
            for cx, cy, cz, r in rows:
                p = placement.act(np.array([cx, cy, cz], dtype=float))
                for ox, oy, oz, radius in obstacles:
                    out.append(np.linalg.norm(p - (ox, oy, oz)) - r - radius - margin)
    return np.array(out).reshape(len(states), -1)


def test_ipopt_free_ur5_is_a_minimum_time_solution_pinocchio_agrees_with():
    path = _urdf('ur5')
    spec = ap.ArmSpec(urdf=path, joints=UR5_JOINTS, start=UR5_START, goal=UR5_GOAL)
    out = ar.solve_arm_ipopt(spec, 20, 'euler', n_starts=2)
    assert out['success'], out['attempts']
    pmodel = _pinocchio(path, UR5_JOINTS)
    x0 = np.concatenate([UR5_START, np.zeros(6)])
    states = _reintegrate(pmodel, x0, out['controls'], out['t_f'], 'euler')
    np.testing.assert_allclose(states[-1], np.concatenate([UR5_GOAL, np.zeros(6)]), rtol=0,
                               atol=1e-7)
    np.testing.assert_allclose(states, out['states'], rtol=0, atol=1e-7)
    _assert_limits(pmodel, states, out['controls'])
    # Minimum time: some torque or velocity bound is active.
    bound = max(np.max(np.abs(out['controls']) / pmodel.effortLimit),
                np.max(np.abs(states[:, 6:]) / pmodel.velocityLimit))
    assert bound > 1.0 - 1e-6
    # Both starts reach the same optimum here; the arm's check module agrees with this file.
    assert out['t_spread'] < 1e-6 * out['t_f']
    check = check_trajectory(spec, out['t_f'], out['controls'], 'euler', out['states'])
    assert check['terminal_error'] < 1e-7 and check['defect'] < 1e-7


# Two IPOPT solves of the UR5 (several seconds): the obstacle-free one below stays quick.
@pytest.mark.slow
def test_ipopt_one_sphere_keeps_the_clearance():
    # The UR5 swings its arm up through a sphere; going around it costs a little time.
    path = _urdf('ur5')
    spheres = ap.load_spheres(str(DATA / 'arm_spheres_ur5.yaml'))
    start, goal = (0.0, -0.4, 0.4, -1.57, -1.57, 0.0), (0.0, -2.0, 0.9, -1.57, -1.57, 0.0)
    obstacles, margin = ((0.60, 0.0, 0.55, 0.2),), 0.02
    spec = ap.ArmSpec(urdf=path, joints=UR5_JOINTS, start=start, goal=goal,
                      obstacles=obstacles, robot_spheres=spheres, margin=margin)
    pmodel = _pinocchio(path, UR5_JOINTS)
    # The straight joint path goes through the obstacle; the start and goal are clear.
    s = np.linspace(0.0, 1.0, 41)[:, None]
    line = np.hstack([(1 - s) * np.asarray(start) + s * np.asarray(goal), np.zeros((41, 6))])
    through = _clearance(pmodel, line, spheres, obstacles, margin)
    assert np.min(through) < -0.05 and np.min(through[[0, -1]]) > 0.0
    out = ar.solve_arm_ipopt(spec, 20, 'euler', n_starts=2)
    assert out['success'], out['attempts']
    x0 = np.concatenate([start, np.zeros(6)])
    states = _reintegrate(pmodel, x0, out['controls'], out['t_f'], 'euler')
    np.testing.assert_allclose(states[-1], np.concatenate([goal, np.zeros(6)]), rtol=0,
                               atol=1e-7)
    _assert_limits(pmodel, states, out['controls'])
    clear = _clearance(pmodel, states, spheres, obstacles, margin)
    assert np.min(clear) > -1e-8
    assert np.min(clear) < 1e-6          # the obstacle is active: the solution touches it
    free = ar.solve_arm_ipopt(replace(spec, obstacles=()), 20, 'euler', n_starts=1)
    assert out['t_f'] > free['t_f'] * (1.0 + 1e-5)


def test_lifted_and_explicit_transcriptions_have_the_same_optimum():
    path = _urdf('ur5')
    problem = ap.ArmProblem(ap.ArmSpec(urdf=path, joints=UR5_JOINTS, start=UR5_START,
                                       goal=UR5_GOAL))
    t_f = {}
    for form in ar.FORMULATIONS:
        nlp = ar.ArmTranscription(problem, 10, 'euler', formulation=form)
        out = nlp.solve(problem.path_guess(problem.line_time(), 10))
        assert out['success'], (form, out['status'])
        t_f[form] = out['t_f']
        check = check_trajectory(problem.spec, out['t_f'], out['controls'], 'euler',
                                 out['states'])
        assert check['terminal_error'] < 1e-7 and check['defect'] < 1e-7, (form, check)
    assert abs(t_f['lifted'] - t_f['explicit']) < 1e-8 * t_f['lifted'], t_f


@pytest.mark.slow
def test_fatrop_and_ipopt_share_the_optimum_and_rk4_reintegrates():
    """
    FATROP and IPOPT (stagewise and global transcriptions) agree on the optimum.

    FATROP from the cold line start converges; IPOPT started at its result stays at that
    optimum: the two see the same problem.  N = 10 keeps it at ~20 s: cold FATROP at N = 20
    takes ~1,000 iterations (~3 min here), and warm-started from IPOPT's optimum it fails
    (primal-only warm starts do not suit it); the N = 20 agreement is measured in
    benchmarks/RESULTS.md ("Arms: reference minimum times").
    """
    path = _urdf('panda')
    spec = ap.ArmSpec(urdf=path, joints=PANDA_JOINTS,
                      start=(-1.2, 0.2, 0.0, -2.0, 0.0, 2.2, 0.8),
                      goal=(1.2, 0.1, 0.3, -1.8, 0.2, 2.0, 0.3),
                      robot_spheres=str(DATA / 'arm_spheres_panda.yaml'),
                      obstacles=((0.60, 0.0, 0.42, 0.08),), margin=0.02)
    fatrop = ar.solve_arm_fatrop(spec, 10, 'rk4')
    assert fatrop['success'], fatrop['status']
    ipopt = ar.solve_arm(spec, 10, 'rk4', 'ipopt',
                         guess=(fatrop['states'], fatrop['controls'], fatrop['t_f']))
    assert ipopt['success'] and ipopt['max_violation'] < 1e-6, ipopt['status']
    gap = abs(ipopt['t_f'] - fatrop['t_f'])
    assert gap <= 1e-4 * fatrop['t_f'], (ipopt['t_f'], fatrop['t_f'])
    pmodel = _pinocchio(path, PANDA_JOINTS)
    spheres = ap.load_spheres(spec.robot_spheres)
    for out in (ipopt, fatrop):
        x0 = np.concatenate([spec.start, np.zeros(7)])
        states = _reintegrate(pmodel, x0, out['controls'], out['t_f'], 'rk4')
        np.testing.assert_allclose(states[-1, :7], spec.goal, rtol=0, atol=1e-6)
        _assert_limits(pmodel, states, out['controls'])
        assert np.min(_clearance(pmodel, states, spheres, spec.obstacles, 0.02)) > -1e-8
