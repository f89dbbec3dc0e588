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

"""One solve from a command line: Ctrl-C cancels it, a progress line, JSON out, exit codes."""

import json
import math
import os
import signal
import threading

EXIT_WRITE_ERROR = 5
EXIT_INTERRUPTED = 130      # shell convention for SIGINT


def _strict(value):
    """Replace NaN/inf (not JSON) by None, e.g. in the states of a diverged paper-mode run."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _strict(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_strict(v) for v in value]
    return value


def write_json(path, result):
    """Write result.to_dict() to path as strict JSON (non-finite numbers become null)."""
    tmp = f'{path}.tmp'
    try:
        with open(tmp, 'w') as stream:
            json.dump(_strict(result.to_dict()), stream, allow_nan=False)
            stream.write('\n')
        os.replace(tmp, path)
    except BaseException:
        if os.path.isfile(tmp):
            os.remove(tmp)      # (no half-written file left beside a path that failed)
        raise


def solve_interruptible(problem, options, progress, guess=None):
    """Run solve() in this thread; the first Ctrl-C cancels it, returning the best so far."""
    from toc_ros.core import solve
    cancel = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        return solve(problem, options, progress=progress, cancel=cancel, initial_guess=guess)
    previous = signal.getsignal(signal.SIGINT)
    if previous is None:      # installed outside Python: restore the default instead
        previous = signal.default_int_handler

    def on_sigint(_signum, _frame):
        cancel.set()
        # A second Ctrl-C falls back to the previous behaviour (KeyboardInterrupt).
        signal.signal(signal.SIGINT, previous)

    signal.signal(signal.SIGINT, on_sigint)
    try:
        return solve(problem, options, progress=progress, cancel=cancel, initial_guess=guess)
    finally:
        signal.signal(signal.SIGINT, previous)


BAR_WIDTH = 24          # characters of paper mode's progress bar


class ProgressLine:
    """A carriage-return-updated status line on stderr (used only on a terminal)."""

    def __init__(self, stream, max_iterations, mode):
        self.stream = stream
        self.max_iterations = max_iterations
        self.mode = mode
        self.width = 0

    def __call__(self, progress):
        """Progress callback of toc_ros.core.solve."""
        if progress.phase == 'done':
            return
        if self.mode == 'paper':
            frac = min(1.0, progress.iteration / max(1, self.max_iterations))
            filled = int(round(frac * BAR_WIDTH))
            head = f'[{"#" * filled}{"-" * (BAR_WIDTH - filled)}] {100 * frac:3.0f}%'
        else:
            head = f'{progress.phase or "fast"}'
        line = (f'{head}  it {progress.iteration}  t_f {progress.t_f:.6f} s  '
                f'cost {progress.cost:.3g}  {progress.elapsed_s:.1f} s')
        self.stream.write('\r' + line.ljust(self.width))
        self.stream.flush()
        self.width = len(line)

    def clear(self):
        """Erase the line again."""
        if self.width:
            self.stream.write('\r' + ' ' * self.width + '\r')
            self.stream.flush()
            self.width = 0
