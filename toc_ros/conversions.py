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
from std_msgs.msg import ColorRGBA
from toc_ros.core import Problem, ProblemError
from toc_ros.core.model import dynamics
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


def duration_seconds(duration):
    """Seconds of a builtin_interfaces/Duration."""
    return duration.sec + duration.nanosec * 1e-9


def accelerations(states, controls, packed_params):
    """(N+1, 2) joint accelerations f(x_i, u_i) of eq. (37); the last node uses u_{N-1}."""
    out = np.empty((states.shape[0], 2))
    for i in range(states.shape[0]):
        f = dynamics(states[i], controls[min(i, controls.shape[0] - 1)], packed_params)
        out[i, 0], out[i, 1] = f[1], f[3]
    return out


def trajectory_msg(result, joint_names, robot, stamp):
    """
    Build the JointTrajectory of a solved result: all N+1 nodes at t_i = i tau.

    positions (q1, q2), velocities (dq1, dq2), accelerations from eq. (37), effort = u_i (the
    optimal controls, zero-order hold from t_i; the last point repeats u_{N-1}).
    """
    states = np.asarray(result.states, dtype=float)
    controls = np.asarray(result.controls, dtype=float)
    acc = accelerations(states, controls, robot.packed())
    msg = JointTrajectory()
    msg.header.stamp = stamp
    msg.joint_names = list(joint_names)
    points = []
    for i, t in enumerate(result.time_grid):
        u = controls[min(i, controls.shape[0] - 1)]
        points.append(JointTrajectoryPoint(
            positions=[float(states[i, 0]), float(states[i, 2])],
            velocities=[float(states[i, 1]), float(states[i, 3])],
            accelerations=[float(acc[i, 0]), float(acc[i, 1])],
            effort=[float(u[0]), float(u[1])],
            time_from_start=duration_msg(float(t))))
    msg.points = points
    return msg


def _yaw_quaternion(pose, yaw):
    pose.orientation.z = math.sin(0.5 * yaw)
    pose.orientation.w = math.cos(0.5 * yaw)


def hand_path_msg(states, a, frame_id, stamp):
    """nav_msgs/Path of the hand for states (rows q1, dq1, q2, dq2); yaw along the arm."""
    msg = Path()
    msg.header.frame_id = frame_id
    msg.header.stamp = stamp
    states = np.asarray(states, dtype=float).reshape(-1, 4)
    reach = a + states[:, 2]
    poses = []
    for q1, r in zip(states[:, 0], reach):
        pose = PoseStamped()
        pose.header = msg.header
        pose.pose.position.x = float(r * math.cos(q1))
        pose.pose.position.y = float(r * math.sin(q1))
        _yaw_quaternion(pose.pose, float(q1))
        poses.append(pose)
    msg.poses = poses
    return msg


def _marker(frame_id, stamp, ns, marker_id, marker_type, rgba):
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
    circles) has radius R' + margin (what the planner keeps the arm out of).  a [m]: hand
    offset of the robot.  path_states / arm_state: rows (q1, dq1, q2, dq2) or None.
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
        body = _marker(frame_id, stamp, 'obstacles', k, Marker.CYLINDER, (0.5, 0.5, 0.5, 0.8))
        body.pose.position.x, body.pose.position.y = float(cx), float(cy)
        body.pose.position.z = 0.5 * OBSTACLE_HEIGHT
        body.scale.x = body.scale.y = 2.0 * float(radius)
        body.scale.z = OBSTACLE_HEIGHT
        out.markers.append(body)
    if len(rows):
        rings = _marker(frame_id, stamp, 'inflated_obstacles', 0, Marker.LINE_LIST,
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
    if path_states is not None and len(path_states):
        states = np.asarray(path_states, dtype=float).reshape(-1, 4)
        line = _marker(frame_id, stamp, 'planned_path', 0, Marker.LINE_STRIP,
                       (0.0, 0.8, 0.0, 1.0))
        line.scale.x = 0.01
        reach = a + states[:, 2]
        line.points = [Point(x=float(r * math.cos(q)), y=float(r * math.sin(q)))
                       for q, r in zip(states[:, 0], reach)]
        out.markers.append(line)
    if arm_state is not None:
        q1, q2 = float(arm_state[0]), float(arm_state[2])
        arm = _marker(frame_id, stamp, 'arm', 0, Marker.LINE_STRIP, (0.1, 0.3, 1.0, 1.0))
        arm.scale.x = 0.03
        arm.points = [Point(), Point(x=(a + q2) * math.cos(q1), y=(a + q2) * math.sin(q1))]
        out.markers.append(arm)
    for ns, info, z, text in (('obstacles_info', obstacles_info, 0.3, 'obstacles'),
                              ('plan_info', plan_info, 0.45, 'plan for obstacles')):
        if info is None:
            continue
        label = _marker(frame_id, stamp, ns, 0, Marker.TEXT_VIEW_FACING, (1.0, 1.0, 1.0, 1.0))
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


def pose_to_joint_goal(msg, base_frame, a, extension_limits=(-math.inf, math.inf)):
    """
    Joint goal (q1, 0, q2, 0) of a PoseStamped hand target by inverse kinematics.

    q1 = atan2(y, x), q2 = sqrt(x^2 + y^2) - a, at rest.  The pose must be in base_frame;
    orientation and z are ignored (the planar model fixes the hand's orientation).
    """
    frame = _frame(msg.header.frame_id)
    if frame != _frame(base_frame):
        raise ConversionError(f"goal pose is in frame '{msg.header.frame_id}', expected "
                              f"'{base_frame}' (no TF lookup: send it in the base frame)")
    p = msg.pose.position
    x, y, _ = _finite((p.x, p.y, p.z), 'goal position')
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


def joint_state_to_state(msg, joint_names):
    """State (q1, dq1, q2, dq2) of a two-joint JointState (velocities default to zero)."""
    pos, vel = joint_state_arrays(msg, joint_names)
    return np.array([pos[0], vel[0], pos[1], vel[1]])


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
    try:    # the one obstacle check: Problem.validate (finite, radius > 0, off the base)
        Problem(obstacles=rows, margin=0.0).validate(states=False)
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
