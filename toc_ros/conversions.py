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
The one place where ROS messages and the core's numpy types are converted into each other.

Input conversions validate and raise ConversionError (a ValueError) with a message meant for
the user; output conversions trust the core's results.  SI units, radians, REP-103 frames:
the robot's plane is the x-y plane of the base frame, the hand at (a + q2)(cos q1, sin q1).
"""

from collections import namedtuple
import math

from builtin_interfaces.msg import Duration, Time
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, PoseStamped
from nav_msgs.msg import Path
import numpy as np
from std_msgs.msg import ColorRGBA, Float64MultiArray, MultiArrayDimension
from toc_ros.core import ProblemError
from toc_ros.core.model import dynamics, RobotParams
from toc_ros.core.models import CylindricalRobot, ModelError, RobotModel
from toc_ros.core.plan_reference import rest_at_end
from toc_ros.core.problem import check_obstacles
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
from visualization_msgs.msg import Marker, MarkerArray

# Goals closer than this to the base axis have no defined rotation q1 = atan2(y, x).
MIN_AXIS_DISTANCE = 1e-6
# Line segments of an inflated-obstacle circle marker.
CIRCLE_SEGMENTS = 32
# Height [m] of the obstacle cylinders drawn in RViz (the model is planar).
OBSTACLE_HEIGHT = 0.1

TrajectoryArrays = namedtuple(
    'TrajectoryArrays', 'times positions velocities accelerations efforts')
TrajectoryArrays.__doc__ = """Trajectory as arrays in a given joint order.

times (M,) [s] from the trajectory start; positions, velocities (M, J) (velocities zero when
the message has none); accelerations, efforts (M, J) or None when the message has none.
"""


class ConversionError(ValueError):
    """A message that cannot be used; the text says why (for the log and ~/progress)."""


# ---------------------------------------------------------------------------------------------
# Output: core -> messages


def _sec_nanosec(seconds):
    # Round the total, not the fraction: 15.9999999996 s is (16, 0), not (15, 0).
    total = int(round(seconds * 1e9))
    return total // 1_000_000_000, total % 1_000_000_000


def duration_msg(seconds):
    """builtin_interfaces/Duration of a non-negative time [s] (nanosecond resolution)."""
    sec, nanosec = _sec_nanosec(seconds)
    return Duration(sec=sec, nanosec=nanosec)


def time_msg(seconds):
    """builtin_interfaces/Time of a non-negative time [s] (nanosecond resolution)."""
    sec, nanosec = _sec_nanosec(seconds)
    return Time(sec=sec, nanosec=nanosec)


def nanoseconds(msg):
    """Integer nanoseconds of a builtin_interfaces/Time or Duration."""
    return msg.sec * 1_000_000_000 + msg.nanosec


def time_of_ns(total):
    """builtin_interfaces/Time of integer nanoseconds (>= 0)."""
    return Time(sec=total // 1_000_000_000, nanosec=total % 1_000_000_000)


def duration_of_ns(total):
    """builtin_interfaces/Duration of integer nanoseconds (>= 0)."""
    return Duration(sec=total // 1_000_000_000, nanosec=total % 1_000_000_000)


def duration_seconds(duration):
    """Seconds of a builtin_interfaces/Duration (the double nearest to the nanoseconds)."""
    return nanoseconds(duration) / 1e9


def as_model(robot):
    """
    Return the RobotModel of robot.

    A RobotModel as is; RobotParams or a hand offset a [m] as the cylindrical robot (the
    older call forms of the functions below).
    """
    if isinstance(robot, RobotModel):
        return robot
    if isinstance(robot, RobotParams):
        return CylindricalRobot(robot)
    return CylindricalRobot(RobotParams(a=float(robot)))


def accelerations(states, controls, packed_params, model=None):
    """(N+1, n) joint accelerations of f(x_i, u_i) (default eq. 37); the last uses u_{N-1}."""
    if model is None:
        out = np.empty((states.shape[0], 2))
        for i in range(states.shape[0]):
            f = dynamics(states[i], controls[min(i, controls.shape[0] - 1)], packed_params)
            out[i, 0], out[i, 1] = f[1], f[3]
        return out
    out = np.empty((states.shape[0], model.n_joints))
    f = np.empty(model.nx)
    for i in range(states.shape[0]):
        model.kernels.rhs(np.ascontiguousarray(states[i]),
                          np.ascontiguousarray(controls[min(i, controls.shape[0] - 1)]),
                          packed_params, f)
        out[i] = model.velocities(f)        # d(dq)/dt
    return out


def trajectory_msg(result, joint_names, robot, stamp):
    """
    Build the JointTrajectory of a solved result: all N+1 nodes at t_i = i tau.

    robot: the RobotModel (or RobotParams of the cylindrical robot).  Positions q, velocities
    dq (a plan that ends at rest ends exactly at rest: core/plan_reference.py), accelerations
    from the model's dynamics, effort = u_i (the optimal controls, zero-order hold from t_i;
    the last point repeats u_{N-1}; with actuator states (models/actuated.py) the commands,
    which the drives turn into the applied efforts).
    """
    model = as_model(robot)
    states = np.asarray(result.states, dtype=float)
    controls = np.asarray(result.controls, dtype=float)
    if isinstance(model, CylindricalRobot):
        acc = accelerations(states, controls, model.packed())
    else:
        acc = accelerations(states, controls, model.packed(), model)
    msg = JointTrajectory()
    msg.header.stamp = stamp
    msg.joint_names = list(joint_names)
    # Whole columns to Python lists at once: per-element numpy indexing and float() calls would
    # be most of the cost on long plans.  Times rounded as in _sec_nanosec.
    last = np.minimum(np.arange(states.shape[0]), controls.shape[0] - 1)
    total = np.round(np.asarray(result.time_grid, dtype=float) * 1e9).astype(np.int64)
    velocities = rest_at_end(model.velocities(states))[0]
    rows = zip(model.positions(states).tolist(), velocities.tolist(), np.asarray(acc).tolist(),
               controls[last].tolist(), (total // 1_000_000_000).tolist(),
               (total % 1_000_000_000).tolist())
    msg.points = [JointTrajectoryPoint(positions=q, velocities=dq, accelerations=ddq, effort=u,
                                       time_from_start=Duration(sec=sec, nanosec=nanosec))
                  for q, dq, ddq, u, sec, nanosec in rows]
    return msg


def hand_path_msg(states, a, frame_id, stamp):
    """
    nav_msgs/Path of the hand for states (rows x); yaw along the last link.

    a: the RobotModel (or the cylindrical robot's hand offset [m]).
    """
    model = as_model(a)
    msg = Path()
    msg.header.frame_id = frame_id
    msg.header.stamp = stamp
    states = np.asarray(states, dtype=float).reshape(-1, model.nx)
    seg = model.link_segments(model.positions(states))[:, -1, :]
    yaws = np.arctan2(seg[:, 3] - seg[:, 1], seg[:, 2] - seg[:, 0])
    poses = []
    for (x, y), yaw in zip(seg[:, 2:4].tolist(), yaws.tolist()):
        pose = PoseStamped(header=msg.header)
        pose.pose.position.x = x
        pose.pose.position.y = y
        pose.pose.orientation.z = math.sin(0.5 * yaw)
        pose.pose.orientation.w = math.cos(0.5 * yaw)
        poses.append(pose)
    msg.poses = poses
    return msg


def arm_points(model, q):
    """
    Points of the arm marker for joint positions q: (points, chain).

    chain True: the links form a chain (one LINE_STRIP through base, joints and hand);
    False: two points per link (a LINE_LIST).
    """
    seg = model.link_segments(np.asarray(q, dtype=float))
    chain = bool(np.allclose(seg[1:, 0:2], seg[:-1, 2:4])) if len(seg) > 1 else True
    if chain:
        points = [seg[0, 0:2]] + [row[2:4] for row in seg]
    else:
        points = [p for row in seg for p in (row[0:2], row[2:4])]
    return [Point(x=float(p[0]), y=float(p[1])) for p in points], chain


def new_marker(frame_id, stamp, ns, marker_id, marker_type, rgba):
    """Return an ADD Marker of type marker_type in frame_id, identity orientation, colour rgba."""
    marker = Marker()
    marker.header.frame_id = frame_id
    marker.header.stamp = stamp
    marker.ns = ns
    marker.id = marker_id
    marker.type = marker_type
    marker.action = Marker.ADD
    marker.pose.orientation.w = 1.0
    marker.color = ColorRGBA(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])
    return marker


def markers_msg(obstacles, margin, a, frame_id, stamp, path_states=None, arm_state=None,
                obstacles_info=None, plan_info=None):
    """
    Build the MarkerArray for RViz: DELETEALL, then obstacles, inflated circles, hand path, arm.

    obstacles: rows (x, y, radius R'); the 'inflated_obstacles' marker (one LINE_LIST of all
    circles) has radius R' + margin (what the planner keeps the arm out of).  a: the RobotModel
    (or the cylindrical robot's hand offset [m]).  path_states / arm_state: states x or None;
    the 'arm' marker draws every link, the 'planned_path' the hand.
    obstacles_info / plan_info: (obstacles hash, data revision) of the current obstacle set and
    of the set the path was planned for, drawn as text markers 'obstacles_info' / 'plan_info'.
    Cost: one cylinder per obstacle plus one line list, so a large set stays cheap.
    """
    out = MarkerArray()
    clear = Marker()
    clear.header.frame_id = frame_id
    clear.header.stamp = stamp
    clear.action = Marker.DELETEALL
    out.markers.append(clear)
    rows = np.asarray(obstacles, dtype=float).reshape(-1, 3)
    for k, (cx, cy, radius) in enumerate(rows):
        body = new_marker(frame_id, stamp, 'obstacles', k, Marker.CYLINDER, (0.5, 0.5, 0.5, 0.8))
        body.pose.position.x, body.pose.position.y = float(cx), float(cy)
        body.pose.position.z = 0.5 * OBSTACLE_HEIGHT
        body.scale.x = body.scale.y = 2.0 * float(radius)
        body.scale.z = OBSTACLE_HEIGHT
        out.markers.append(body)
    if len(rows):
        rings = new_marker(frame_id, stamp, 'inflated_obstacles', 0, Marker.LINE_LIST,
                           (1.0, 0.5, 0.0, 1.0))
        rings.scale.x = 0.01
        angles = np.linspace(0.0, 2.0 * math.pi, CIRCLE_SEGMENTS + 1)
        inflated = rows[:, 2:3] + float(margin)
        xs = rows[:, 0:1] + inflated * np.cos(angles)[None, :]
        ys = rows[:, 1:2] + inflated * np.sin(angles)[None, :]
        # Segment i of every circle: points i and i + 1.
        seg_x = np.stack([xs[:, :-1], xs[:, 1:]], axis=2).reshape(-1)
        seg_y = np.stack([ys[:, :-1], ys[:, 1:]], axis=2).reshape(-1)
        rings.points = [Point(x=x, y=y) for x, y in zip(seg_x.tolist(), seg_y.tolist())]
        out.markers.append(rings)
    model = as_model(a)
    if path_states is not None and len(path_states):
        states = np.asarray(path_states, dtype=float).reshape(-1, model.nx)
        line = new_marker(frame_id, stamp, 'planned_path', 0, Marker.LINE_STRIP,
                          (0.0, 0.8, 0.0, 1.0))
        line.scale.x = 0.01
        hand = model.hand_position(model.positions(states))
        line.points = [Point(x=x, y=y) for x, y in hand.tolist()]
        out.markers.append(line)
    if arm_state is not None:
        points, chain = arm_points(model, model.positions(np.asarray(arm_state, dtype=float)))
        arm = new_marker(frame_id, stamp, 'arm', 0, Marker.LINE_STRIP if chain
                         else Marker.LINE_LIST, (0.1, 0.3, 1.0, 1.0))
        arm.scale.x = 0.03
        arm.points = points
        out.markers.append(arm)
    for ns, info, z, text in (('obstacles_info', obstacles_info, 0.3, 'obstacles'),
                              ('plan_info', plan_info, 0.45, 'plan for obstacles')):
        if info is None:
            continue
        label = new_marker(frame_id, stamp, ns, 0, Marker.TEXT_VIEW_FACING, (1.0, 1.0, 1.0, 1.0))
        label.pose.position.z = z
        label.scale.z = 0.08
        label.text = f'{text} {info[0]}, data revision {info[1]}'
        out.markers.append(label)
    return out


def _fmt(value):
    if isinstance(value, str):
        return value
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return str(int(value))
    return f'{float(value):.9g}'


def diagnostic_msg(name, level, message, values):
    """Build a DiagnosticStatus with values (a dict, order kept) as string key/values."""
    return DiagnosticStatus(level=level, name=name, message=message,
                            values=[KeyValue(key=k, value=_fmt(v)) for k, v in values.items()])


def diagnostic_values(msg):
    """Key/values of a DiagnosticStatus as a dict of strings."""
    return {kv.key: kv.value for kv in msg.values}


# ---------------------------------------------------------------------------------------------
# Input: messages -> core


def _finite(values, what):
    arr = np.asarray(values, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise ConversionError(f'{what} contains NaN or inf: {arr.tolist()}')
    return arr


def _frame(frame_id):
    return frame_id[1:] if frame_id.startswith('/') else frame_id


def _goal_xy(msg, base_frame):
    """Return the finite (x, y) [m] of a goal pose, which must be in base_frame."""
    if _frame(msg.header.frame_id) != _frame(base_frame):
        raise ConversionError(f"goal pose is in frame '{msg.header.frame_id}', expected "
                              f"'{base_frame}' (no TF lookup: send it in the base frame)")
    p = msg.pose.position
    x, y, _ = _finite((p.x, p.y, p.z), 'goal position')
    return x, y


def pose_to_joint_goal(msg, base_frame, a, extension_limits=(-math.inf, math.inf),
                       branch=None, seed=None):
    """
    Joint goal state (at rest) of a PoseStamped hand target by inverse kinematics.

    a: a RobotModel (its inverse_kinematics with the IK branch and the seed, joint positions
    that a numeric IK starts from; ConversionError with the model's reason for an unreachable
    or ambiguous goal), or the cylindrical robot's hand offset a [m]: q1 = atan2(y, x),
    q2 = sqrt(x^2 + y^2) - a within extension_limits.  The pose must be in base_frame;
    orientation and z are ignored (planar models).
    """
    x, y = _goal_xy(msg, base_frame)
    if isinstance(a, RobotModel) and not isinstance(a, CylindricalRobot):
        try:
            q = a.inverse_kinematics(float(x), float(y), branch, seed=seed)
        except ModelError as exc:
            raise ConversionError(str(exc))
        return a.state(q)
    if isinstance(a, CylindricalRobot):
        a = float(a.params.a)
    distance = math.hypot(x, y)
    if distance < MIN_AXIS_DISTANCE:
        raise ConversionError(f'goal ({x:.6g}, {y:.6g}) is on the base axis: the rotation '
                              'q1 = atan2(y, x) is undefined')
    q2 = distance - a
    low, high = extension_limits
    if not low <= q2 <= high:
        raise ConversionError(
            f'goal ({x:.6g}, {y:.6g}) is out of reach: distance {distance:.6g} m from the base '
            f'axis needs extension q2 = {q2:.6g} m outside [{low:.6g}, {high:.6g}] m '
            f'(reach {a + low:.6g} to {a + high:.6g} m)')
    return np.array([math.atan2(y, x), 0.0, q2, 0.0])


def joint_state_arrays(msg, joint_names, require_velocity=False):
    """
    (positions, velocities) of joint_names, picked by name from a JointState.

    Velocities default to zero when the message has none (unless require_velocity).
    """
    names = list(msg.name)
    if len(set(names)) != len(names):
        raise ConversionError(f'joint state has duplicate joint names {names}')
    if len(msg.position) != len(names):
        raise ConversionError(f'joint state has {len(names)} names but {len(msg.position)} '
                              'positions')
    if len(msg.velocity) not in ((len(names),) if require_velocity else (0, len(names))):
        raise ConversionError(f'joint state has {len(names)} names but {len(msg.velocity)} '
                              'velocities' + (' (velocities are required)'
                                              if require_velocity else ''))
    missing = [n for n in joint_names if n not in names]
    if missing:
        raise ConversionError(f'joint state lacks joints {missing} (has {names})')
    index = [names.index(n) for n in joint_names]
    positions = _finite([msg.position[i] for i in index], 'joint positions')
    velocities = (_finite([msg.velocity[i] for i in index], 'joint velocities')
                  if len(msg.velocity) else np.zeros(len(index)))
    return positions, velocities


def joint_state_efforts(msg, joint_names):
    """Efforts of joint_names from a JointState (None when it has none; ConversionError)."""
    names = list(msg.name)
    if not len(msg.effort):
        return None
    if len(msg.effort) != len(names):
        raise ConversionError(f'joint state has {len(names)} names but {len(msg.effort)} '
                              'efforts')
    try:
        index = [names.index(n) for n in joint_names]
    except ValueError:
        raise ConversionError(f'joint state lacks joints of {list(joint_names)} (has {names})') \
            from None
    return _finite([msg.effort[i] for i in index], 'joint efforts')


def joint_state_to_state(msg, joint_names):
    """State (q1, dq1, q2, dq2, ...) of joint_names from a JointState (velocities default 0)."""
    pos, vel = joint_state_arrays(msg, joint_names)
    state = np.empty(2 * len(pos))
    state[0::2], state[1::2] = pos, vel
    return state


def obstacles_msg(rows):
    """Float64MultiArray with rows (x, y, radius) and a (rows, 3) layout."""
    msg = Float64MultiArray()
    msg.layout.dim = [MultiArrayDimension(label='rows', size=len(rows), stride=3 * len(rows)),
                      MultiArrayDimension(label='x_y_radius', size=3, stride=3)]
    msg.data = [float(v) for row in rows for v in row]
    return msg


def obstacle_rows_from_msg(msg):
    """
    Obstacle rows (x, y, radius) of a Float64MultiArray (validated, may be empty).

    The layout may be empty (data holds whole rows) or two dimensions (rows, 3); data_offset
    is honoured.
    """
    dims = list(msg.layout.dim)
    offset = int(msg.layout.data_offset)
    data = np.asarray(msg.data, dtype=float)[offset:]
    if dims:
        if len(dims) != 2 or dims[1].size != 3:
            raise ConversionError('obstacles layout must be 2-D (rows, 3) or empty, got '
                                  + str([(d.label, d.size) for d in dims]))
        rows = dims[0].size
        stride = dims[0].stride if dims[0].stride else 3 * rows
        if stride != 3 * rows or dims[1].stride not in (0, 3) or data.size < 3 * rows:
            raise ConversionError(f'obstacles layout does not match the data: {rows} rows of '
                                  f'3 need 3 * rows = {3 * rows} values (strides '
                                  f'{dims[0].stride}, {dims[1].stride}), got {data.size}')
        data = data[:3 * rows]
    elif data.size % 3:
        raise ConversionError(f'obstacles data must hold rows of (x, y, radius): {data.size} '
                              'values is not a multiple of 3')
    rows = tuple((float(x), float(y), float(r)) for x, y, r in data.reshape(-1, 3))
    try:    # the one obstacle check, Problem.validate's (finite, radius > 0, off the base)
        check_obstacles(rows)
    except ProblemError as exc:
        raise ConversionError(str(exc))
    return rows


def trajectory_arrays(msg, joint_names):
    """
    Convert a JointTrajectory to TrajectoryArrays in the order of joint_names (validated).

    Requires positions for every point; velocities, accelerations and effort either for every
    point or for none; times strictly increasing from >= 0.  An empty trajectory gives arrays
    with zero rows.
    """
    names = list(msg.joint_names)
    missing = [n for n in joint_names if n not in names]
    if missing:
        raise ConversionError(f'trajectory lacks joints {missing} (has {names})')
    if len(set(names)) != len(names):
        raise ConversionError(f'trajectory has duplicate joint names {names}')
    index = [names.index(n) for n in joint_names]
    points = msg.points
    times = np.array([duration_seconds(p.time_from_start) for p in points], dtype=float)
    if len(points) and (times[0] < 0.0 or np.any(np.diff(times) <= 0.0)):
        raise ConversionError('trajectory time_from_start must be >= 0 and strictly increasing')

    def field(attr, required):
        lengths = {len(getattr(p, attr)) for p in points}
        if not points or (lengths == {0} and not required):
            return None
        if lengths != {len(names)}:
            raise ConversionError(f'every trajectory point needs {len(names)} {attr} '
                                  f'(one per joint), got lengths {sorted(lengths)}')
        arr = np.array([list(getattr(p, attr)) for p in points], dtype=float)[:, index]
        return _finite(arr, f'trajectory {attr}')

    positions = field('positions', True)
    velocities = field('velocities', False)
    empty = np.zeros((len(points), len(joint_names)))
    return TrajectoryArrays(times, empty if positions is None else positions,
                            empty.copy() if velocities is None else velocities,
                            field('accelerations', False), field('effort', False))
