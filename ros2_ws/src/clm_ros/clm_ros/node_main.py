"""The life of a node process: start, spin, and a clean exit on SIGINT or SIGTERM.

:func:`run_node` is the ``main`` of a node process:

- ``rclpy.init`` without rclpy's own signal handlers (they shut the context
  down under the feet of a thread that is publishing: an ``RCLError`` or an
  abort); SIGINT and SIGTERM only set a flag here;
- an ``EventsExecutor`` spun with ``spin_once`` (its ``spin()`` delivered no
  callback on the Jazzy wheels; measured in benchmarks/node_lag.py) until the
  flag is set or the node asks to exit;
- then, in this order: the node's :meth:`stop` (it stops its own threads;
  they never outlive it), the executor, the node, the context. Exit code 0.

A node used with it may define ``stop()`` (stop threads, called once, before
anything is destroyed) and an ``exit_code`` attribute (None while it runs; a
number ends the process with that code, e.g. after its last train).

The flag is polled every ``poll`` seconds (0.1 s): the exit after a signal
takes that plus the node's ``stop`` (tests/ros/test_vehicle_node.py measures
it against the 2-s requirement of issue 12).
"""

from __future__ import annotations

import signal
import sys
import threading
from collections.abc import Callable, Sequence
from types import FrameType
from typing import Any

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.signals import SignalHandlerOptions

from clm_core.errors import ClmError


def run_node(make: Callable[[], Any], args: Sequence[str] | None = None, name: str = "node",
             poll: float = 0.1) -> int:
    """Create the node with ``make()``, spin it until a signal or its ``exit_code``; return the exit code.

    Parameters
    ----------
    make : callable
        Builds the node (after ``rclpy.init``). A :class:`clm_core.errors.ClmError`
        raised here is printed as one line and gives exit code 2.
    args : sequence of str, optional
        Command line (``--ros-args ...``); default ``sys.argv``.
    name : str
        Program name in error messages.
    poll : float
        Longest wait between two looks at the signal flag [s].
    """
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    rclpy.init(args=list(args) if args is not None else None, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    executor = None
    code = 0
    try:
        try:
            node = make()
        except ClmError as exc:
            print(f"{name}: error: {exc}", file=sys.stderr)
            return 2
        executor = EventsExecutor()
        executor.add_node(node)
        while not stop.is_set() and rclpy.ok():
            executor.spin_once(timeout_sec=poll)
            exit_code = getattr(node, "exit_code", None)
            if exit_code is not None:
                code = int(exit_code)
                break
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None and hasattr(node, "stop"):
            node.stop()
        if executor is not None:
            executor.shutdown(timeout_sec=1.0)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        for s, handler in previous.items():
            signal.signal(s, handler)
    return code
