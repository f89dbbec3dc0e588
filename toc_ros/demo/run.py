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

"""The demo's run: start the nodes, send each stage's obstacles and goal, watch the plant."""

import dataclasses
import math
import os
import time

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger
from toc_ros import config, conversions, harness
from toc_ros.analysis.closed_loop import latency_stats
from toc_ros.core import Status
from toc_ros.demo import checks, closed_loop
from toc_ros.demo.summary import recording_facts
from toc_ros.progress import (EVENT_READY, EVENT_REPLAN_KEPT, EVENT_REPLANNED,
                              progress_from_msg)
from toc_ros.recording.process import recorder_command
from trajectory_msgs.msg import JointTrajectory


@dataclasses.dataclass(frozen=True)
class Stage:
    """One goal of the demo: joint target (q1, q2 [rad or m]) and the obstacle set sent before."""

    label: str
    q_goal: tuple
    obstacles: tuple


STAGES = (
    # Section 4 of the paper: to q = (5 pi/12, 1 m) around one circle.
    Stage('paper goal', (5.0 * math.pi / 12.0, 1.0), ((1.0, 1.0, 0.2),)),
    # Back past a moved circle and a new one, starting wherever the plant came to rest.
    Stage('replan', (math.pi / 12.0, 0.8), ((0.9, 1.2, 0.2), (1.5, 0.6, 0.15))),
)
# The planar two-link arm (config/toc_ros_planar_2r.yaml): circles beyond the reach of link 1,
# near the free optimum's path but clear of the straight joint interpolation, so that fast
# mode, a local method, starts on a side of each.
PLANAR_2R_STAGES = (
    Stage('planar_2r goal', (0.9, 0.9), ((0.23, 1.09, 0.12),)),
    Stage('replan', (-0.4, 1.3), ((0.34, 1.26, 0.11), (1.6, -0.2, 0.1))),
)
# toc-demo --model NAME: (parameter file in the package's config/, stages, with the closed-loop
# stage: the paper's goal under model mismatch and a moving circle, open loop and replanning).
SCENARIOS = {'cylindrical': ('toc_ros.yaml', STAGES, True),
             'planar_2r': ('toc_ros_planar_2r.yaml', PLANAR_2R_STAGES, False)}
# (name, replan.rate [Hz], replan.estimate); every run plans with RK4 (CLOSED_LOOP_INTEGRATOR:
# the plan is then what the plant does under its piecewise-constant controls).
CLOSED_LOOP_RUNS = (('open loop', 0.0, ()), ('replanning', 20.0, ()),
                    ('replanning + estimation', 20.0, closed_loop.ESTIMATED))
CLOSED_LOOP_INTEGRATOR = 'rk4'
# replan.max_nodes: bounds an RK4 cycle's cost at 20 Hz; 75 rather than the node's default 100
# cuts it by a quarter, so that fewer cycles miss their deadline when the machine is loaded (their
# 27 ms steps cost the replanned arrival nothing measurable: replanning corrects them).
CLOSED_LOOP_MAX_NODES = 75

PROGRESS_PRINT_PERIOD_S = 0.5
REQUIRED_TOPICS = (
    '/goal_pose', '/goal_joints', '/obstacles', '/trajectory', '/planned_path', '/markers',
    '/solver_node/progress', '/joint_states', '/plant_node/tracking', '/plant_node/reference')
# Topics that must be recorded before the first goal (/goal_joints has no publisher here).
WATCHED_TOPICS = tuple(t for t in REQUIRED_TOPICS if t != '/goal_joints')
RECORDER_NODE = 'recorder_node'
PROGRESS = 'solver_node/progress'


class DemoError(RuntimeError):
    """The demo cannot go on (a node died, a wait timed out); the message says why."""


class Printer:
    """Stage lines with the time since the start (nothing when quiet)."""

    def __init__(self, quiet):
        self.quiet = quiet
        self.start = time.monotonic()

    def stage(self, text):
        """Print a stage line."""
        if not self.quiet:
            print(f'[{time.monotonic() - self.start:6.1f} s] {text}', flush=True)

    def detail(self, text):
        """Print an indented detail line."""
        if not self.quiet:
            print(f'           {text}', flush=True)


def kernel_cache_found():
    """Tell whether numba's cache holds compiled toc_ros kernels (else the solver compiles)."""
    import numba
    import toc_ros.core  # noqa: F401 - points numba's cache at the core's directory
    cache_dir = numba.config.CACHE_DIR
    return bool(cache_dir) and os.path.isdir(cache_dir) and any(
        name.endswith('.nbi') for _, _, files in os.walk(cache_dir) for name in files)


def goal_pose_msg(q_goal, a, frame_id):
    """Build the hand's PoseStamped at joint positions q (a: RobotModel or hand offset [m])."""
    model = conversions.as_model(a)
    state = model.state(q_goal)[None, :]
    pose = conversions.hand_path_msg(state, model, frame_id, PoseStamped().header.stamp).poses[0]
    pose.header.frame_id = frame_id
    return pose


class Demo:
    """One run of the demo: start, wait_ready, run_stage per Stage, stop; fills summary."""

    def __init__(self, args, printer):
        self.args = args
        self.out = printer
        self.deadline = time.monotonic() + args.timeout
        model_name = getattr(args, 'model', 'cylindrical') or 'cylindrical'
        file_name, self.stages, self.closed_loop = SCENARIOS[model_name]
        self.params_file = config.default_config_path(file_name)
        params = config.load_parameters(self.params_file, 'solver_node')
        self.model = config.model_from_parameters(params)
        self.a = float(params['robot.a'])
        self.base_frame = str(params['base_frame'])
        self.joint_names = list(params['joint_names'])
        self.solver_timeout = float(params['solver.timeout'])
        self.children = {}
        self.client = None
        self.goal_pub = self.obstacles_pub = self.goal_joints_pub = None
        self.ready_reported = False
        self.summary = {'plans': [], 'position_tolerance': list(checks.POSITION_TOL),
                        'joint_names': self.joint_names, 'robot_a': self.a,
                        'model': self.model.name, 'params_file': self.params_file,
                        'joint_units': ['rad' if kind == 'revolute' else 'm'
                                        for kind in self.model.joint_kinds],
                        'base_frame': self.base_frame, 'ros_domain_id':
                        os.environ.get('ROS_DOMAIN_ID'), 'recording': None}

    # waiting ------------------------------------------------------------------------------------

    def _check_children(self):
        for child in self.children.values():
            if not child.alive():
                raise DemoError(f'{child.name} exited with code {child.process.returncode}:\n'
                                f'{child.tail()}')

    def _wait(self, predicate, what, timeout=None, tick=None, optional=False):
        """
        Poll predicate until truthy and return its value.

        DemoError when a node exits or the time is up; after an optional wait's own timeout
        (not the demo's --timeout) the result is None instead.
        """
        own_end = math.inf if timeout is None else time.monotonic() + timeout
        while True:
            value = predicate()
            if value:
                return value
            self._check_children()
            self._report_ready()
            now = time.monotonic()
            if now > self.deadline:
                raise DemoError(f'timed out waiting for {what} (--timeout)')
            if now > own_end:
                if optional:
                    return None
                raise DemoError(f'timed out waiting for {what}')
            if tick is not None:
                tick()
            time.sleep(0.02)

    def _report_ready(self):
        """Print (once) the solver's ready notice: the kernel load time, from ~/progress."""
        if self.ready_reported or self.client is None:
            return
        for msg in self.client.messages(PROGRESS):
            report = progress_from_msg(msg)
            if report.event == EVENT_READY:
                self.ready_reported = True
                self.summary['kernel_load_s'] = report.elapsed_s
                self.out.stage(f'solver_node: numba kernels loaded in {report.elapsed_s:.1f} s')
                return

    # start --------------------------------------------------------------------------------------

    def start(self, log_dir):
        """Start the nodes (each in its own session) and the demo's own client node."""
        self.client = client = harness.RosClient('toc_demo', namespace='', private_domain=False)
        client.collect(DiagnosticStatus, PROGRESS, 100)
        client.collect(JointState, 'joint_states', 10, keep=1000)
        client.collect(DiagnosticStatus, 'plant_node/tracking', 10, keep=50)
        client.collect(JointTrajectory, 'trajectory', harness.LATCHED_HISTORY)
        self.goal_pub = client.node.create_publisher(PoseStamped, '/goal_pose', harness.LATCHED)
        self.obstacles_pub = client.node.create_publisher(Float64MultiArray, '/obstacles',
                                                          harness.LATCHED)
        self.goal_joints_pub = client.node.create_publisher(JointState, '/goal_joints', 10)
        if self.args.record:
            argv = recorder_command(self.args.output, extra_ros_args=[
                '-r', f'__node:={RECORDER_NODE}'])
            self.children['recorder'] = harness.NodeProcess(
                argv=argv, name=RECORDER_NODE, log_dir=log_dir, new_session=True)
        for name in ('solver_node', 'plant_node'):
            self.children[name] = harness.NodeProcess(
                name, log_dir=log_dir, params_file=self.params_file, new_session=True)

    def wait_ready(self):
        """Wait until the nodes are connected and the plant publishes joint_states."""
        out, client = self.out, self.client
        if kernel_cache_found():
            out.stage('solver_node: loading the numba kernels from the cache (goals sent '
                      'meanwhile are queued) ...')
        else:
            out.stage('solver_node: first run, compiling the numba kernels (about a minute; '
                      'cached for later runs; goals sent meanwhile are queued) ...')
        ready = client.node.create_client(Trigger, '/solver_node/ready')

        def solver_ready():
            try:
                return client.call(ready, Trigger.Request(), timeout=5.0).success
            except harness.HarnessError:
                return False
        self._wait(solver_ready, 'solver_node to load its kernels')
        self._report_ready()
        out.stage('solver_node ready')
        self._wait(lambda: client.count('joint_states'), 'joint_states from plant_node',
                   timeout=60.0)
        out.stage('plant_node publishes joint_states')
        subscribers = 2 if self.args.record else 1
        self._wait(lambda: (self.goal_pub.get_subscription_count() >= subscribers
                            and self.obstacles_pub.get_subscription_count() >= subscribers
                            and 'solver_node' in client.subscribers('joint_states')
                            and 'plant_node' in client.subscribers('trajectory')),
                   'the nodes to connect', timeout=60.0)
        if self.args.record:
            self._wait(lambda: all(RECORDER_NODE in client.subscribers(t.lstrip('/'))
                                   for t in WATCHED_TOPICS),
                       f'recorder_node to subscribe to {", ".join(WATCHED_TOPICS)}',
                       timeout=30.0)
            out.stage(f'recorder_node records to {self.args.output}')

    def _solver_obstacles(self):
        try:
            values = self.client.get_parameters(
                'solver_node', ['obstacles.x', 'obstacles.y', 'obstacles.radius'], timeout=5.0)
        except harness.HarnessError:
            return None
        return tuple(zip(values['obstacles.x'], values['obstacles.y'],
                         values['obstacles.radius']))

    # one goal -----------------------------------------------------------------------------------

    def run_stage(self, number, stage):
        """Send the stage's obstacles and goal, wait for the plan and its execution."""
        out, client = self.out, self.client
        q_goal = stage.q_goal
        plan = {'label': stage.label, 'goal_q': list(q_goal), 'obstacles':
                [list(r) for r in stage.obstacles]}
        self.summary['plans'].append(plan)
        out.stage(f'plan {number} ({stage.label}): {len(stage.obstacles)} obstacle(s) '
                  f'{list(stage.obstacles)}')
        self.obstacles_pub.publish(conversions.obstacles_msg(stage.obstacles))
        expected = tuple(tuple(float(v) for v in row) for row in stage.obstacles)
        self._wait(lambda: self._solver_obstacles() == expected,
                   'solver_node to take the obstacles', timeout=30.0)

        goal = goal_pose_msg(q_goal, self.model, self.base_frame)
        plan['goal_pose'] = [goal.pose.position.x, goal.pose.position.y]
        progress_seen = client.count(PROGRESS)
        trajectories_seen = client.count('trajectory')
        sent = time.monotonic()
        self.goal_pub.publish(goal)
        out.stage(f'plan {number}: goal_pose ({goal.pose.position.x:.4f}, '
                  f'{goal.pose.position.y:.4f}) m in {self.base_frame}, i.e. q = '
                  f'({", ".join(f"{q:.4f}" for q in q_goal)}) ({self.model.name})')

        printed = [0.0]

        def final():
            reports = [progress_from_msg(m) for m in client.messages(PROGRESS)[progress_seen:]]
            for report in reports:
                if report.final:
                    return report
            running = [r for r in reports if r.solving]
            if running and time.monotonic() - printed[0] >= PROGRESS_PRINT_PERIOD_S:
                printed[0] = time.monotonic()
                latest = running[-1]
                best = latest.best_feasible_t_f
                out.detail(f'solving: {latest.elapsed_s:.1f} s, iteration {latest.iteration}, '
                           f't_f {latest.t_f:.4f} s, best feasible t_f '
                           + ('none yet' if best is None or math.isnan(best)
                              else f'{best:.4f} s'))
            return None

        # The first goal may wait for the kernels: only the demo's --timeout bounds it.
        report = self._wait(final, f'the result of plan {number}',
                            timeout=None if number == 1 else self.solver_timeout + 30.0)
        plan.update(status=report.status.value, message=report.message, t_min=report.t_f,
                    solve_wall_time_s=report.elapsed_s, iterations=report.iteration,
                    start_source=report.start_source, obstacles_hash=report.obstacles_hash,
                    data_revision=report.data_revision,
                    goal_to_result_s=time.monotonic() - sent)
        out.stage(f"plan {number}: {plan['status']}: t_min {plan['t_min']:.4f} s, solved in "
                  f"{plan['solve_wall_time_s']:.2f} s ({plan['iterations']} iterations), "
                  f'start from {plan["start_source"]}')
        if report.status is not Status.SOLVED:
            raise DemoError(f'plan {number} ended {plan["status"]}: {report.message}')

        # The goal's own plan: replan cycles (replan.rate) publish more to the same goal.
        received, trajectory = self._wait(
            lambda: client.stamped('trajectory')[trajectories_seen:],
            f'the trajectory of plan {number}', timeout=10.0)[0]
        start, end = trajectory.points[0], trajectory.points[-1]
        duration = conversions.duration_seconds(end.time_from_start)
        plan['trajectory'] = {'points': len(trajectory.points), 'duration_s': duration,
                              'start_q': list(start.positions), 'end_q': list(end.positions)}
        end_error = max(abs(e - g) for e, g in zip(end.positions, q_goal))
        if end_error > checks.TRAJECTORY_END_TOL:
            raise DemoError(f'plan {number}: the trajectory ends {end_error:.3g} from the goal')
        out.stage(f'plan {number}: plant_node executes {len(trajectory.points)} points, '
                  f'{duration:.4f} s')
        self._execute(plan, received, duration)

    def _joint_state(self, msg):
        positions, velocities = conversions.joint_state_arrays(msg, self.joint_names)
        return positions.tolist(), velocities.tolist()

    def _execute(self, plan, received, duration):
        """Wait until the plant rests at the goal (or gave up), record the final error."""
        client, q_goal = self.client, plan['goal_q']
        settling = checks.Settling(q_goal, received + duration)
        last = [received]

        def settled():
            for stamp, msg in client.stamped('joint_states', last[0]):
                if stamp <= last[0]:
                    continue
                last[0] = stamp
                try:
                    positions, velocities = self._joint_state(msg)
                except conversions.ConversionError:
                    continue
                if settling.add(stamp, positions, velocities):
                    return True
            return False

        at_rest = bool(self._wait(settled, 'plant_node to settle at the goal',
                                  timeout=duration + checks.SETTLE_TIMEOUT_S, optional=True))
        stamp, msg = client.stamped('joint_states')[-1]
        positions, velocities = self._joint_state(msg)
        tracking = client.messages('plant_node/tracking')
        tracking = conversions.diagnostic_values(tracking[-1]) if tracking else {}
        errors = [p - g for p, g in zip(positions, q_goal)]
        plan.update(
            final_q=positions, final_dq=velocities, final_error=errors,
            final_distance=math.hypot(*errors), at_rest=at_rest,
            settle_time_s=stamp - received - duration,
            max_tracking_error=[_num(tracking.get('max_position_error_q1')),
                                _num(tracking.get('max_position_error_q2'))],
            reached=at_rest and checks.reached(errors))
        self.out.stage(
            f"plan {len(self.summary['plans'])}: plant "
            f"{'at rest' if at_rest else 'NOT at rest'} "
            f'{plan["settle_time_s"]:.2f} s after the trajectory end, error '
            f'({errors[0]:.2e}, {errors[1]:.2e}), max tracking error during execution '
            f'({plan["max_tracking_error"][0]:.2e}, {plan["max_tracking_error"][1]:.2e}) '
            '[rad or m]')

    # the closed-loop stage ----------------------------------------------------------------------

    def run_closed_loop(self):
        """
        Run the paper's goal with a mismatched plant and a moving circle (CLOSED_LOOP_RUNS).

        The plant gets payload +20 % and inertia x 1.2, a circle moves into the path during
        the execution; each run starts from the plant's initial_state (~/reset).  The numbers
        (closed_loop.execution_metrics) go to summary['closed_loop'].
        """
        out, client = self.out, self.client
        out.stage('closed loop: plant with payload +20 % and inertia x 1.2, a circle moving '
                  'into the path; open loop, replanning, replanning with online estimation')
        params = config.load_parameters(self.params_file, 'solver_node')
        # The true plant around the circle's final place: what the best plan could achieve.
        final = closed_loop.MOVING.rows(closed_loop.MOVING_OBSTACLES, math.inf)
        params['solver.integrator'] = CLOSED_LOOP_INTEGRATOR
        reference = closed_loop.true_reference(params, closed_loop.TRUE_ROBOT,
                                               closed_loop.PAPER_GOAL_Q, final,
                                               closed_loop.MOVING_MARGIN)
        rate = client.get_parameters('solver_node', ['replan.rate'], timeout=5.0)
        runs = {}
        self.summary['closed_loop'] = {'true_t_min': reference['t_min'],
                                       'true_arrival_s': reference['arrival_s'], 'runs': runs,
                                       'integrator': CLOSED_LOOP_INTEGRATOR,
                                       'mismatch': closed_loop.MISMATCH,
                                       'margin': closed_loop.MOVING_MARGIN}
        try:
            for name, replan_rate, estimate in CLOSED_LOOP_RUNS:
                execution = closed_loop.run_execution(
                    client, (self.goal_joints_pub, self.obstacles_pub), self.model,
                    self.joint_names, closed_loop.PAPER_GOAL_Q, closed_loop.MOVING_OBSTACLES,
                    plant=dict(closed_loop.NOMINAL_PLANT, **closed_loop.MISMATCH),
                    replan_rate=replan_rate, moving=closed_loop.MOVING,
                    margin=closed_loop.MOVING_MARGIN, estimate=estimate,
                    integrator=CLOSED_LOOP_INTEGRATOR, max_nodes=CLOSED_LOOP_MAX_NODES)
                estimates = [r.estimate for r in execution.reports if r.estimate]
                m = runs[name] = dict(execution.metrics, replan_rate=replan_rate,
                                      last_estimate=estimates[-1] if estimates else '')
                latency = ('' if not m['latencies'] else
                           f", replan latency median {1e3 * m['latency_median_s']:.1f} ms, "
                           f"p99 {1e3 * m['latency_p99_s']:.1f} ms")
                out.stage(f"closed loop, {name}: {m['plans']} plan(s), arrival "
                          f"{m['arrival_s']:.3f} s (the true plant's best plan "
                          f"{reference['arrival_s']:.3f} s, t_min {reference['t_min']:.3f} s), "
                          f"final error {m['final_error']:.2e}, min clearance "
                          f"{m['min_clearance']:.4f} m{latency}"
                          + (f", estimate {m['last_estimate']}" if m['last_estimate'] else ''))
        finally:
            self.client.set_parameters('plant_node', closed_loop.NOMINAL_PLANT)
            self.client.set_parameters('solver_node', rate)

    def summarize_replanning(self):
        """Put the replan cycles of the whole run (every stage) in summary['replanning']."""
        reports = [progress_from_msg(m) for m in self.client.messages(PROGRESS)]
        latencies = [r.latency_s for r in reports if r.event == EVENT_REPLANNED]
        kept = sum(r.event == EVENT_REPLAN_KEPT for r in reports)
        stats = self.summary['replanning'] = dict(latency_stats(latencies), kept=kept)
        if latencies:
            self.out.stage(f"replan cycles of the whole demo: {stats['latencies']} published, "
                           f"{kept} kept; latency median {1e3 * stats['latency_median_s']:.1f} "
                           f"ms, p99 {1e3 * stats['latency_p99_s']:.1f} ms, max "
                           f"{1e3 * stats['latency_max_s']:.1f} ms")

    # stop ---------------------------------------------------------------------------------------

    def stop(self):
        """Stop the nodes (recorder last, so it gets their final messages); log exit codes."""
        nodes = [c for n, c in self.children.items() if n != 'recorder']
        for child in nodes:
            child.interrupt()
        for child in nodes + [self.children.get('recorder')]:
            if child is not None:
                child.stop()
        self.summary['exit_codes'] = {c.name: c.exit_code for c in self.children.values()}
        self.summary['stopped_by'] = {c.name: c.stopped_by for c in self.children.values()}
        recorder = self.children.get('recorder')
        if recorder is not None:
            self.summary['recording'] = recording_facts(self.args.output,
                                                        recorder.exit_code == 0)

    def close(self):
        """Stop every child that still runs and the client."""
        for child in self.children.values():
            child.stop()
        if self.client is not None:
            self.client.close()
            self.client = None


def _num(text):
    try:
        return float(text)
    except (TypeError, ValueError):
        return math.nan
