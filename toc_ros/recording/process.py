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

"""Start recorder_node as a separate process and stop it cleanly (used by toc-demo and tests)."""

import datetime
import json
import os
import signal
import subprocess
import sys
import time
from typing import Iterable, List, Optional

# The folder that holds the toc_ros package (the source tree when run uninstalled).
_PACKAGE_PARENT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def default_output_dir(root: str = 'runs', now: Optional[datetime.datetime] = None) -> str:
    """Return ``<root>/<UTC timestamp>``, e.g. ``runs/2026-11-25T17-00-00Z``."""
    now = now or datetime.datetime.now(datetime.timezone.utc)
    return os.path.join(root, now.astimezone(datetime.timezone.utc).strftime('%Y-%m-%dT%H-%M-%SZ'))


def recorder_command(output: Optional[str] = None, topics: Optional[Iterable[str]] = None,
                     exclude: Optional[str] = None, python: Optional[str] = None,
                     extra_ros_args: Iterable[str] = ()) -> List[str]:
    """
    Return the argv that runs recorder_node with these parameters.

    Values are passed JSON-quoted, which ROS parses as YAML strings, so values such as
    ``2026`` or ``true`` stay strings. Give absolute topic names (relative and ``~`` names
    resolve in the recorder's own namespace). No ``topics`` (or an empty list) records every
    topic.
    """
    argv = [python or sys.executable, '-m', 'toc_ros.nodes.recorder_node', '--ros-args']
    if output is not None:
        argv += ['-p', 'output:=' + json.dumps(os.fspath(output))]
    topics = list(topics or [])
    if topics:
        argv += ['-p', 'topics:=' + json.dumps([str(t) for t in topics])]
    if exclude:
        argv += ['-p', 'exclude:=' + json.dumps(exclude)]
    return argv + list(extra_ros_args)


class RecorderProcess:
    """
    recorder_node in a child process; ``stop()`` sends SIGINT and waits for a closed bag.

    The child inherits the environment (ROS_DOMAIN_ID etc.) plus ``env``; the directory
    holding this toc_ros package is put first on PYTHONPATH so it also runs uninstalled.
    """

    def __init__(self, output: str, topics: Optional[Iterable[str]] = None,
                 exclude: Optional[str] = None, env: Optional[dict] = None, **popen_kwargs):
        self.output = os.path.abspath(os.fspath(output))
        self.argv = recorder_command(self.output, topics, exclude)
        child_env = dict(os.environ)
        child_env.update(env or {})
        paths = [_PACKAGE_PARENT] + [p for p in child_env.get('PYTHONPATH', '').split(
            os.pathsep) if p and p != _PACKAGE_PARENT]
        child_env['PYTHONPATH'] = os.pathsep.join(paths)
        self._env = child_env
        self._popen_kwargs = popen_kwargs
        self.process: Optional[subprocess.Popen] = None

    @property
    def mcap_path(self) -> str:
        """Path of the MCAP file the recorder writes."""
        return os.path.join(self.output, os.path.basename(self.output) + '_0.mcap')

    def start(self) -> 'RecorderProcess':
        """Start the child process."""
        self.process = subprocess.Popen(self.argv, env=self._env, **self._popen_kwargs)
        return self

    def wait_ready(self, timeout: float = 10.0) -> bool:
        """Wait until the bag file exists (recorder started); False on timeout or exit."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if os.path.exists(self.mcap_path):
                return True
            if self.process is None or self.process.poll() is not None:
                return False
            time.sleep(0.02)
        return False

    def stop(self, timeout: float = 10.0, sig: int = signal.SIGINT) -> int:
        """Signal the recorder to stop, wait for it, escalate if it hangs; return exit code."""
        if self.process is None:
            raise RuntimeError('recorder process was not started')
        if self.process.poll() is None:
            self.process.send_signal(sig)
            try:
                return self.process.wait(timeout)
            except subprocess.TimeoutExpired:
                self.process.terminate()
                try:
                    return self.process.wait(timeout)
                except subprocess.TimeoutExpired:
                    self.process.kill()
        return self.process.wait()

    def __enter__(self) -> 'RecorderProcess':
        return self.start()

    def __exit__(self, *exc_info) -> None:
        if self.process is not None and self.process.poll() is None:
            self.stop()
