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
toc-demo --robot panda: a pick-and-place-like sequence on the Panda around two spheres.

solver_node and plant_node of config/panda.yaml (the plans assume a 1 kg payload in the hand,
the MuJoCo plant carries 20 % more; replan cycles at 20 Hz), three goals (joint, pose, joint),
run twice as the planar demo's closed loop (RUNS): replanning with the 1 kg model, then
replanning with the payload estimated online from joint_states, each from the ready pose (the
plant's ~/reset).  During the first motion of each run one sphere drops onto the route of the
second, which plans around it.  Every
joint_states sample of each motion is checked against the obstacle spheres in force when it
was received (the core's sphere clearance, no margin); the summary has arrival, final error,
clearance and cycle latencies.
"""

import dataclasses
import math
import os
import time

from geometry_msgs.msg import PoseStamped
import numpy as np
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from toc_ros import config, conversions
from toc_ros.analysis.closed_loop import arrival_time, ARRIVAL_TOL, latency_stats
from toc_ros.core import Status
from toc_ros.demo import checks
from toc_ros.demo.run import Demo, DemoError, PROGRESS
from toc_ros.progress import EVENT_REPLAN_KEPT, EVENT_REPLANNED, progress_from_msg
import yaml

PARAMS_FILE = 'panda.yaml'
# (name, replan.estimate) of each run of the three goals.
RUNS = (('replanning', ()), ('replanning + estimation', ('payload_mass',)))
PLANNED_PAYLOAD_KG = 1.0    # robot.payload_mass: at the hand's origin in the plan model
PAYLOAD_KG = 1.2            # plant_node's payload_mass_offset (+20 %), estimated online
MARGIN = 0.03               # [m] obstacles.margin of the plans
READY = (0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785)
# The hand's route: ready pose -> pick on the +y side -> place on the -y side (an arc in front
# of the base, over x ~ 0.6 m) -> home in front.  Sphere 1 stands below the arc; sphere 2
# drops, during the pick motion, from above onto the arc: the place motion plans around it.
STATIC = (0.62, 0.10, 0.25, 0.07)
DROP = tuple((delay, (0.62, -0.10, z, 0.06)) for delay, z in
             ((0.0, 1.0), (0.05, 0.9), (0.10, 0.8), (0.15, 0.7), (0.20, 0.62)))


@dataclasses.dataclass(frozen=True)
class ArmStage:
    """One goal: joint positions, or a tip pose (x, y, z, qx, qy, qz, qw) in the base frame."""

    label: str
    joints: tuple = ()
    pose: tuple = ()
    moving: tuple = ()      # ((delay after the first plan [s], (x, y, z, r)), ...): sphere 2


STAGES = (
    ArmStage('pick', joints=(0.9, -0.3, 0.0, -2.0, 0.0, 1.8, 0.785), moving=DROP[1:]),
    # The hand pointing down (quaternion x = 1: its z axis along -z of the base).
    ArmStage('place', pose=(0.45, -0.45, 0.40, 1.0, 0.0, 0.0, 0.0)),
    ArmStage('home', joints=(0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.785)),
)


class PandaDemo(Demo):
    """The Panda's run: start, wait_ready, run (every stage), stop; fills summary."""

    def __init__(self, args, printer):
        self.args = args
        self.out = printer
        self.deadline = time.monotonic() + args.timeout
        self.stages = STAGES
        self.stage_count = len(STAGES) * len(RUNS)
        self.closed_loop = False
        self.params_file = None
        params = config.load_parameters(config.default_config_path(PARAMS_FILE), 'solver_node')
        self.joint_names = list(params['joint_names'])
        self.base_frame = str(params['base_frame'])
        self.solver_timeout = float(params.get('solver.timeout', 60.0))
        self.children = {}
        self.client = None
        self.goal_pub = self.obstacles_pub = self.goal_joints_pub = None
        self.ready_reported = False
        self.sent = []          # (monotonic time, obstacle rows) as published
        self.summary = {'robot': 'panda', 'plans': [], 'arm_stages': [],
                        'joint_names': self.joint_names, 'base_frame': self.base_frame,
                        'payload_kg': PAYLOAD_KG, 'planned_payload_kg': PLANNED_PAYLOAD_KG,
                        'margin': MARGIN,
                        'position_tolerance': [checks.SETTLE_POSITION] * len(self.joint_names),
                        'ros_domain_id': os.environ.get('ROS_DOMAIN_ID'), 'recording': None}

    def _write_params(self, log_dir):
        """Return a parameter file: config/panda.yaml with the URDF, the payload and margin."""
        from toc_ros.core.arms.model import named_arm_path
        with open(config.default_config_path(PARAMS_FILE)) as stream:
            doc = yaml.safe_load(stream)
        with open(named_arm_path('panda')) as stream:
            urdf = stream.read()
        solver = doc['solver_node']['ros__parameters']
        plant = doc['plant_node']['ros__parameters']
        solver['robot_description'] = plant['robot_description'] = urdf
        solver.setdefault('obstacles', {})['margin'] = MARGIN
        plant['payload_mass_offset'] = PAYLOAD_KG
        plant.setdefault('robot', {})['tip_link'] = 'panda_hand'
        solver.setdefault('robot', {}).update(tip_link='panda_hand',
                                              payload_mass=PLANNED_PAYLOAD_KG)
        path = os.path.join(log_dir, 'panda_demo.yaml')
        with open(path, 'w') as stream:
            yaml.safe_dump({f'/**/{name}': values for name, values in doc.items()}, stream)
        self.summary['params_file'] = path
        return path

    def start(self, log_dir):
        """Start the nodes with the Panda's parameters (Demo.start) and keep every sample."""
        self.params_file = self._write_params(log_dir)
        super().start(log_dir)
        self.client.collect(JointState, 'joint_states', 10, keep=200000)

    # one stage ----------------------------------------------------------------------------------

    def _publish_obstacles(self, rows):
        self.obstacles_pub.publish(Float64MultiArray(data=[float(v) for r in rows for v in r]))
        self.sent.append((time.monotonic(), tuple(tuple(r) for r in rows)))

    def _goal(self, stage):
        """Publish the stage's goal: goal_joints, or goal_pose of the tip in the base frame."""
        if stage.joints:
            self.goal_joints_pub.publish(JointState(name=self.joint_names,
                                                    position=list(stage.joints)))
            return
        msg = PoseStamped()
        msg.header.frame_id = self.base_frame
        p, o = msg.pose.position, msg.pose.orientation
        p.x, p.y, p.z = stage.pose[:3]
        o.x, o.y, o.z, o.w = stage.pose[3:]
        self.goal_pub.publish(msg)

    def run_arm_stage(self, number, stage, run):
        """Send the goal (moving sphere 2 meanwhile), wait for arrival, measure the motion."""
        out, client = self.out, self.client
        result = {'label': stage.label, 'goal': 'joints' if stage.joints else 'pose',
                  'target': list(stage.joints or stage.pose), 'run': run}
        self.summary['arm_stages'].append(result)
        progress_seen = client.count(PROGRESS)
        trajectories_seen = client.count('trajectory')
        sent = time.monotonic()
        self._goal(stage)
        out.stage(f'goal {number} ({stage.label}): {result["goal"]} '
                  f'{[round(v, 4) for v in result["target"]]}')

        def final():
            for msg in client.messages(PROGRESS)[progress_seen:]:
                report = progress_from_msg(msg)
                if report.final and report.goal_source in ('goal_joints', 'goal_pose'):
                    return report
            return None
        report = self._wait(final, f'the result of goal {number}',
                            timeout=None if number == 1 else self.solver_timeout + 30.0)
        result.update(status=report.status.value, message=report.message, t_min=report.t_f)
        if report.status is not Status.SOLVED:
            raise DemoError(f'goal {number} ended {report.status.value}: {report.message}')
        first_received, first = self._wait(
            lambda: client.stamped('trajectory')[trajectories_seen:],
            f'the trajectory of goal {number}', timeout=10.0)[0]
        goal_q = list(first.points[-1].positions)
        result['goal_q'] = goal_q
        out.stage(f'goal {number}: SOLVED, t_min {report.t_f:.4f} s '
                  f'({len(first.points)} points)')
        obstacles_at_start = self.sent[-1][1]
        schedule = [(first_received + delay, rows) for delay, rows in stage.moving]

        def move_sphere():
            while schedule and time.monotonic() >= schedule[0][0]:
                _, row = schedule.pop(0)
                self._publish_obstacles([STATIC, row])
        duration = conversions.duration_seconds(first.points[-1].time_from_start)
        settling = checks.Settling(goal_q, first_received)
        last = [first_received]

        def settled():
            for stamp, msg in client.stamped('joint_states', last[0]):
                if stamp <= last[0]:
                    continue
                last[0] = stamp
                q, dq = conversions.joint_state_arrays(msg, self.joint_names)
                if settling.add(stamp, q.tolist(), dq.tolist()):
                    return True
            return False
        at_rest = bool(self._wait(settled, f'the arm at goal {number}',
                                  timeout=duration + 10.0, tick=move_sphere, optional=True))
        move_sphere()
        samples = client.stamped('joint_states', sent)
        reports = [progress_from_msg(m) for m in client.messages(PROGRESS)[progress_seen:]]
        result.update(self._measure(samples, goal_q, first, first_received, reports),
                      at_rest=at_rest)
        result['reached'] = at_rest and result['final_error'] <= checks.SETTLE_POSITION
        plant = self._plant_reference(first, goal_q, obstacles_at_start)
        result.update(t_min_plant=plant['t_min'], plant_arrival_s=plant['arrival_s'])
        out.stage(f"goal {number}: {'at rest' if at_rest else 'NOT at rest'}, arrival "
                  f"{result['arrival_s']:.3f} s (the plant's best plan "
                  f"{result['plant_arrival_s']:.3f} s, t_min {report.t_f:.3f} s planned, "
                  f"{result['t_min_plant']:.3f} s of the plant), within "
                  f"{checks.SETTLE_POSITION:g} rad at {result['settled_s']:.3f} s, final error "
                  f"{result['final_error']:.2e} rad, min clearance "
                  f"{result['min_clearance']:.4f} m, {result['cycles']} cycle(s) replanned "
                  f"({result['kept']} kept), estimate {result['payload_estimate'] or 'none'}")

    def _plant_reference(self, first, goal_q, obstacles):
        """
        Return {'t_min', 'arrival_s'} of the plant's own best plan of the goal (nan unsolved).

        The same start (the first plan's first point), goal, obstacles, margin and grid, with
        the payload the plant carries: what the issue's 'true plant's minimum time' means;
        arrival_s is the arrival_time of that plan's published motion, what a perfect execution
        of it scores.
        """
        from toc_ros.core import Problem, solve
        from toc_ros.core.arms import default_spheres, load_arm
        from toc_ros.core.arms.arm_solve import ArmRobot
        from toc_ros.core.arms.payload import with_payload
        from toc_ros.core.plan_reference import reference_positions
        arm = with_payload(load_arm('panda'), PAYLOAD_KG, 'panda_hand')
        point = first.points[0]
        result = solve(Problem(model=ArmRobot(arm, default_spheres(arm)),
                               x0=tuple(point.positions) + tuple(point.velocities),
                               x_goal=tuple(goal_q), obstacles=tuple(obstacles), margin=MARGIN,
                               n_intervals=len(first.points) - 1))
        if result.status is not Status.SOLVED:
            return {'t_min': math.nan, 'arrival_s': math.nan}
        # Its published motion (as executed plans are), not its Euler nodes half a step behind.
        states = np.asarray(result.states)
        positions = reference_positions(states[:, :arm.n], states[:, arm.n:], result.time_grid,
                                        result.integrator)
        return {'t_min': result.final_time,
                'arrival_s': arrival_time(np.asarray(result.time_grid), positions, goal_q)}

    def _measure(self, samples, goal_q, first, first_received, reports):
        """Arrival, final error, clearance over the samples, cycles and their latencies."""
        from toc_ros.core.arms import (default_spheres, load_arm, obstacle_clearance,
                                       sphere_kinematics_batch)
        q = np.array([conversions.joint_state_arrays(m, self.joint_names)[0]
                      for _, m in samples])
        times = np.array([t for t, _ in samples])
        errors = np.max(np.abs(q - np.asarray(goal_q)), axis=1)
        # From the first plan's start (its header.stamp, on the node clock like joint_states'
        # stamps): arrival as everywhere in toc_ros (analysis.closed_loop.ARRIVAL_TOL), and
        # when the arm stays within the demo's at-rest tolerance (the PD's last millimetres).
        stamp0 = first.header.stamp.sec + 1e-9 * first.header.stamp.nanosec
        stamps = np.array([m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
                           for _, m in samples])
        # (nan: not there by the last sample; an arm at the goal already arrived at 0.)
        arrival, settled = (
            float(np.clip(arrival_time(stamps, q, goal_q, tol=tol) - stamp0, 0.0, None))
            for tol in (ARRIVAL_TOL, checks.SETTLE_POSITION))
        arm = load_arm('panda')
        spheres = default_spheres(arm)
        centres, _ = sphere_kinematics_batch(spheres, q)
        worst = math.inf
        for k, t in enumerate(times):
            rows = [r for s, r in self.sent if s <= t]
            if rows and rows[-1]:
                gaps = obstacle_clearance(centres[k], spheres.radii, np.array(rows[-1]), 0.0)
                worst = min(worst, float(np.min(gaps)))
        latencies = [r.latency_s for r in reports if r.event == EVENT_REPLANNED]
        # The online estimate the last cycle of the motion had (replan.estimate).
        estimate = next((r.estimate for r in reversed(reports) if r.estimate), '')
        return dict(latency_stats(latencies), arrival_s=arrival, settled_s=settled,
                    payload_estimate=estimate,
                    final_error=float(errors[-1]), min_clearance=worst,
                    cycles=len(latencies),
                    kept=sum(r.event == EVENT_REPLAN_KEPT for r in reports),
                    samples=len(samples))

    def run(self):
        """Run every stage per RUNS from the ready pose, the static sphere and sphere 2 aside."""
        for name, estimate in RUNS:
            self.out.stage(f'{name}: replan.estimate {list(estimate)}')
            self._publish_obstacles([STATIC, DROP[0][1]])
            time.sleep(0.3)          # sphere 2 lifted before the arm comes back below it
            self._set('solver_node', {'replan.estimate': Parameter(
                'replan.estimate', Parameter.Type.STRING_ARRAY, list(estimate))})
            # The last goal abandoned (no cycle drives the reset arm back to it), then the arm
            # back to the ready pose.
            self.client.trigger('solver_node/cancel_goal')
            if not self.client.trigger('plant_node/reset').success:
                raise DemoError('plant_node refused ~/reset')
            time.sleep(0.3)          # the solver sees the ready pose on joint_states
            for number, stage in enumerate(self.stages, 1):
                self.run_arm_stage(number, stage, name)

    def _set(self, node, values):
        refused = [r.reason for r in self.client.set_parameters(node, values)
                   if not r.successful]
        if refused:
            raise DemoError(f'{node} refused {sorted(values)}: {refused}')
