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

"""Timer callbacks racing shutdown (SIGINT after a SIGSTOP pause) end the node cleanly."""

from pathlib import Path
import random
import signal
import subprocess
import sys
import time

from node_harness import NodeProcess
import pytest
import rclpy
from rclpy.context import Context
from rclpy.exceptions import InvalidHandle
from rclpy.signals import SignalHandlerOptions
from toc_ros.nodes.plant_node import PlantNode

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def plant_in_process():
    context = Context()
    rclpy.init(context=context, domain_id=random.randint(101, 200),
               signal_handler_options=SignalHandlerOptions.NO)
    node = PlantNode(context=context)
    yield node, context
    node.destroy_node()
    rclpy.try_shutdown(context=context)


def test_callbacks_after_the_context_shut_down_return_quietly(plant_in_process):
    node, context = plant_in_process
    node._tick()
    node._publish_tracking()
    rclpy.shutdown(context=context)
    # Without the guard both raise RCLError "publisher's context is invalid".
    assert node._tick() is None
    assert node._publish_tracking() is None


def test_the_same_errors_with_a_live_context_still_propagate(plant_in_process):
    node, _context = plant_in_process
    node._state_pub.destroy()
    with pytest.raises(InvalidHandle):
        node._tick()


@pytest.mark.parametrize('pause_s, delay_s', [(5.0, None), (2.0, 0.0), (2.0, 0.05)])
def test_plant_sigint_after_a_sigstop_pause_exits_0(tmp_path, monkeypatch, pause_s, delay_s):
    """SIGINT while stopped (delay None) or right after SIGCONT, during the catch-up."""
    monkeypatch.setenv('ROS_DOMAIN_ID', str(random.randint(1, 100)))
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    plant = NodeProcess('plant_node', '/race', tmp_path,
                        params={'integration_rate': 5000.0, 'rate': 500.0})
    try:
        plant.wait_for_log('ready:')
        time.sleep(0.5)
        plant.process.send_signal(signal.SIGSTOP)
        time.sleep(pause_s)
        if delay_s is None:
            plant.process.send_signal(signal.SIGINT)
            plant.process.send_signal(signal.SIGCONT)
        else:
            plant.process.send_signal(signal.SIGCONT)
            time.sleep(delay_s)
            plant.process.send_signal(signal.SIGINT)
        exit_code = plant.process.wait(timeout=20)
    finally:
        if plant.process.poll() is None:
            plant.process.kill()
            plant.process.wait()
    log = plant.log()
    assert exit_code == 0, log
    assert 'Traceback' not in log and 'RCLError' not in log, log


RUN_NODE_SCRIPT = """
import os
import signal
import sys
import time
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from std_msgs.msg import String
from toc_ros.nodes.common import run_node


class Racer(Node):
    def __init__(self):
        super().__init__('racer')
        self.pub = self.create_publisher(String, 'race', 10)
        self.create_timer(0.05, self.tick)

    def tick(self):
        if sys.argv[1] == 'shutdown':
            rclpy.shutdown(context=self.context)  # as rclpy's SIGINT handler does
        elif sys.argv[1] in ('interrupt', 'error'):
            # What rclpy's take_message does when the KeyboardInterrupt of a SIGINT lands
            # while it converts a message: pybind11 reports a RuntimeError.
            try:
                if sys.argv[1] == 'interrupt':
                    os.kill(os.getpid(), signal.SIGINT)
                time.sleep(0.5)
            except KeyboardInterrupt:
                pass
            raise RuntimeError('Unable to convert call argument 0 to Python object')
        else:
            self.pub.destroy()                    # a real bug: the context is still valid
        self.pub.publish(String(data='late'))


sys.exit(run_node('racer', Racer, SingleThreadedExecutor))
"""


@pytest.mark.parametrize('case, expected', [('shutdown', 0), ('bug', 1), ('interrupt', 0),
                                            ('error', 1)])
def test_run_node_ends_cleanly_on_a_publish_racing_shutdown_only(tmp_path, monkeypatch,
                                                                 case, expected):
    monkeypatch.setenv('ROS_DOMAIN_ID', str(random.randint(1, 100)))
    monkeypatch.setenv('ROS_LOG_DIR', str(tmp_path))
    result = subprocess.run([sys.executable, '-c', RUN_NODE_SCRIPT, case], capture_output=True,
                            text=True, timeout=60, cwd=str(REPO))
    assert result.returncode == expected, result.stderr
    assert ('Traceback' in result.stderr) == (expected != 0), result.stderr


HANGING_CLEAN_UP_SCRIPT = """
import sys
import time
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from toc_ros.nodes.common import run_node


class Stuck(Node):
    def __init__(self):
        super().__init__('stuck')
        self.create_timer(0.05, lambda: None)
        print('ready', flush=True)

    def destroy_node(self):
        time.sleep(60)                  # a clean-up that never ends


sys.exit(run_node('stuck', Stuck, SingleThreadedExecutor))
"""


def test_a_node_whose_clean_up_hangs_after_sigint_prints_its_stacks_and_exits(
        tmp_path, monkeypatch):
    monkeypatch.setenv('ROS_DOMAIN_ID', str(random.randint(1, 100)))
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    monkeypatch.setenv('ROS_LOG_DIR', str(tmp_path))
    process = subprocess.Popen([sys.executable, '-c', HANGING_CLEAN_UP_SCRIPT], cwd=str(REPO),
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert process.stdout.readline().strip() == 'ready'
        started = time.monotonic()
        process.send_signal(signal.SIGINT)
        _, stderr = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == 0, stderr
    assert time.monotonic() - started < 15
    assert 'the clean-up after shutdown still runs after 5 s' in stderr
    assert 'in destroy_node' in stderr          # the stuck thread's stack


HANGING_CLEAN_UP_CONTEXT_UP_SCRIPT = HANGING_CLEAN_UP_SCRIPT.replace(
    "sys.exit(run_node('stuck', Stuck, SingleThreadedExecutor))",
    "sys.exit(run_node('stuck', Stuck, SingleThreadedExecutor, spin=lambda node, ex: 3))")


def test_a_clean_up_that_hangs_with_the_context_still_up_also_ends_the_process(
        tmp_path, monkeypatch):
    # The spin returns (its exit code 3) without a shutdown, and destroy_node hangs: toc-demo's
    # plant_node hung so inside rclpy's destroy_node, and the watch waited for the context.
    monkeypatch.setenv('ROS_DOMAIN_ID', str(random.randint(1, 100)))
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    monkeypatch.setenv('ROS_LOG_DIR', str(tmp_path))
    started = time.monotonic()
    result = subprocess.run([sys.executable, '-c', HANGING_CLEAN_UP_CONTEXT_UP_SCRIPT],
                            cwd=str(REPO), capture_output=True, text=True, timeout=45)
    assert result.returncode == 3, result.stderr          # the code run_node had
    assert time.monotonic() - started < 30
    assert 'the clean-up after shutdown still runs after 5 s' in result.stderr
    assert 'in destroy_node' in result.stderr
