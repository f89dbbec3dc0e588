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

"""What the nodes share: the main() skeleton, shutdown-safe callbacks, 'topics' parsing."""

import faulthandler
import functools
import os
import re
import signal
import sys
import threading
from typing import List

import rclpy
from rclpy.exceptions import InvalidHandle
from rclpy.executors import ExternalShutdownException
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.parameter import Parameter

# What rclpy raises when a publisher, timer... is used after its context was shut down
# (e.g. RCLError "publisher's context is invalid" when SIGINT lands during a callback).
SHUTDOWN_RACE_ERRORS = (rclpy_implementation.RCLError, InvalidHandle)


def is_shutdown_race(node, error: BaseException) -> bool:
    """Tell whether error comes from using node's entities after its context was shut down."""
    return (isinstance(error, SHUTDOWN_RACE_ERRORS) and node is not None
            and not node.context.ok())


def survives_shutdown(callback):
    """
    Decorate a Node method used as a callback: what it does after shutdown is dropped.

    rclpy's SIGINT handler shuts the context down from another thread, so a timer callback
    that is running at that moment fails in its next publish. That is the end of the node,
    not an error: the call returns None. The same errors while the context is valid propagate.
    """
    @functools.wraps(callback)
    def wrapper(self, *args, **kwargs):
        try:
            return callback(self, *args, **kwargs)
        except SHUTDOWN_RACE_ERRORS as error:
            if not is_shutdown_race(self, error):
                raise
            return None
    return wrapper


def topic_list(parameter: Parameter) -> List[str]:
    """Topic names from a string array, a comma/space separated string or an empty value."""
    value = parameter.value
    if parameter.type_ == Parameter.Type.STRING_ARRAY:
        names = list(value)
    elif parameter.type_ == Parameter.Type.STRING:
        names = re.split(r'[,\s]+', value)
    elif parameter.type_ == Parameter.Type.NOT_SET or not value:
        names = []  # "topics:=[]" arrives unset or as an empty array of another type
    else:
        raise ValueError(f'topics must be a list of topic names, got {value!r}')
    if any(not isinstance(n, str) for n in names):
        raise ValueError(f'topics must be strings, got {value!r}')
    return [n.strip() for n in names if n and n.strip()]


# Set by the first SIGINT a node process receives (see _note_interrupt).
INTERRUPTED = threading.Event()
# Set once rclpy.init has installed its signal handler (which shuts the context down).
_RCLPY_HANDLES = threading.Event()


def _note_interrupt(signum, frame):
    """
    Python's SIGINT handler: note the request; raise KeyboardInterrupt only before rclpy.init.

    Once rclpy's handler runs first (it chains to this one) it has shut the context down and
    the executor returns by itself.  A KeyboardInterrupt raised then lands on whatever Python
    line runs, also inside a `with lock:` of rclpy's or of the node's; the clean-up then waited
    on that lock forever (a node SIGKILLed at the end of toc-demo under load).
    """
    INTERRUPTED.set()
    if not _RCLPY_HANDLES.is_set():
        signal.default_int_handler(signum, frame)


# A node process whose clean-up still runs this long after its context was shut down (a
# SIGINT) or after run_node began it prints every thread's stack and exits: toc-demo's
# plant_node hung there under load, ignored SIGTERM (rclpy's handler takes it) and was
# SIGKILLed; once inside rclpy's destroy_node with its context still up (the watch had only
# waited for the context's end).
SHUTDOWN_GRACE_S = 5.0


def _exit_when_clean_up_hangs(name, finished, cleaning, grace=SHUTDOWN_GRACE_S):
    """
    Watch (daemon thread) for run_node's clean-up lasting > grace; then exit the process.

    The clean-up counts from the context's shutdown or from cleaning being set, whichever
    comes first; the process exits with cleaning.code (run_node's exit code; 0 when the
    shutdown was asked for: what hangs is the teardown).
    """
    while rclpy.ok() and not cleaning.is_set() and not finished.is_set():
        finished.wait(0.2)
    if finished.wait(grace):
        return
    sys.stderr.write(f'{name}: the clean-up after shutdown still runs after {grace:g} s; '
                     "its threads' stacks follow, then the process exits\n")
    sys.stderr.flush()
    faulthandler.dump_traceback(all_threads=True)
    os._exit(getattr(cleaning, 'code', 0))


def run_node(name, make_node, make_executor, args=None, spin=None, errors=(), error_code=2,
             error_prefix=''):
    """
    Run a node the demo_nodes_py way and return the process exit code.

    spin(node, executor) replaces executor.spin() and returns the exit code; an exception in
    errors is printed as '<name>: error: <error_prefix><error>' and gives error_code.
    """
    # Installed before rclpy.init, whose SIGINT handler chains to Python's.  A shutdown can
    # still surface as an error inside C++ code run by the executor (a callback racing the
    # context's end); after a SIGINT any such error is the end that was asked for.
    own_process = threading.current_thread() is threading.main_thread()
    if own_process:   # signal.signal's rule; and a node thread in a test must not exit
        signal.signal(signal.SIGINT, _note_interrupt)
        # SIGUSR1 prints every thread's stack (the harness asks before it kills a hung node).
        faulthandler.register(signal.SIGUSR1, all_threads=True)
    rclpy.init(args=args)
    _RCLPY_HANDLES.set()
    finished, cleaning = threading.Event(), threading.Event()
    if own_process:
        threading.Thread(target=_exit_when_clean_up_hangs, args=(name, finished, cleaning),
                         daemon=True).start()
    node = None
    exit_code = 0
    try:
        node = make_node()
        executor = make_executor()
        executor.add_node(node)
        if spin is None:
            executor.spin()
        else:
            exit_code = spin(node, executor)
    except errors as error:
        print(f'{name}: error: {error_prefix}{error}', file=sys.stderr)
        exit_code = error_code
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except SHUTDOWN_RACE_ERRORS as error:
        if not is_shutdown_race(node, error):  # a callback racing shutdown is no failure
            raise
    except Exception:
        if not INTERRUPTED.is_set():
            raise
    finally:
        # A second Ctrl-C while shutting down must not abort the cleanup.  signal.signal()
        # runs pending Python handlers after installing the new one: a Ctrl-C that rclpy's
        # handler already turned into a shutdown can surface here once as KeyboardInterrupt.
        # (an exception on its way out: the process ends in error, also when the watch ends it)
        cleaning.code = exit_code if sys.exc_info()[0] is None else 1
        cleaning.set()
        try:
            try:
                signal.signal(signal.SIGINT, signal.SIG_IGN)
            except KeyboardInterrupt:
                signal.signal(signal.SIGINT, signal.SIG_IGN)
            if node is not None:
                node.destroy_node()
            rclpy.try_shutdown()
        finally:
            finished.set()      # (an error here keeps its own exit code)
    return exit_code
