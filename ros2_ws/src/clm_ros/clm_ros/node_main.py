"""The life of a node process: start, spin, and a clean exit on SIGINT or SIGTERM.

:func:`run_node` is the ``main`` of a node process:

- ``rclpy.init`` without rclpy's own signal handlers (they shut the context
  down under the feet of a thread that is publishing: an ``RCLError`` or an
  abort); SIGINT and SIGTERM only set a flag here; Fast DDS publishes
  synchronously unless ``RMW_FASTRTPS_PUBLICATION_MODE`` says otherwise
  (:data:`PUBLICATION_MODE`);
- the heap built at start-up frozen out of the garbage collector's reach
  (:func:`freeze_heap`: no 0.1-s collection pause in the middle of a run);
- an ``EventsExecutor`` spun with ``spin_once`` (its ``spin()`` delivered no
  callback on the Jazzy wheels; measured in benchmarks/node_lag.py) until the
  flag is set or the node asks to exit;
- then, in this order: the node's :meth:`stop` (it stops its own threads;
  they never outlive it), the executor, the node, the context (the DDS
  participant leaves the graph, announced to its peers). Exit code 0.

A node used with it may define ``service()`` (called between two turns of
the executor: it does what is due and returns how long the executor may wait
for callbacks until its next action [s], so that a node with a timetable,
such as the vehicle node, needs no thread of its own), ``stop()`` (called
once, before anything is destroyed) and an ``exit_code`` attribute (None
while it runs; a number ends the process with that code, e.g. after its
last train).

The flag is polled every ``poll`` seconds (0.1 s): the exit after a signal
takes that plus the node's ``stop``, a few ms. :func:`exit_process` then ends
the process without the interpreter's finalization, which takes 0.3-1.5 s
with numba, numpy and scipy loaded on a busy 2-core machine (measured), once
everything of ROS has been destroyed in order (tests/ros/test_vehicle_node.py
measures the exit against the 2-s requirement of issue 12).
"""

from __future__ import annotations

import gc
import os
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
from rclpy.utilities import get_default_context

from clm_core.errors import ClmError

#: Fast DDS publication mode of the node processes unless the environment sets one: a synchronous write
#: sends from the publishing thread; the asynchronous default hands every message to a thread of Fast DDS,
#: one more thread switch per message: 85-90 against 150-190 us of CPU per message for a 1-kHz raw publisher
#: with one reliable subscriber on the 2-core machine (load 4-5), measured for issue 10.
PUBLICATION_MODE = "SYNCHRONOUS"


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
    os.environ.setdefault("RMW_FASTRTPS_PUBLICATION_MODE", PUBLICATION_MODE)
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
        freeze_heap()
        executor = EventsExecutor()
        executor.add_node(node)
        service = getattr(node, "service", None)
        while not stop.is_set() and rclpy.ok():
            wait = poll if service is None else min(max(service(), 0.0), poll)
            executor.spin_once(timeout_sec=wait)
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
        get_default_context().destroy()  # the DDS participant goes now: its peers see it leave
        for s, handler in previous.items():
            signal.signal(s, handler)
    return code


def freeze_heap() -> None:
    """Move every object alive now out of the cyclic garbage collector's reach (``gc.freeze``).

    With numba, numpy, scipy and rclpy loaded a process holds ~150 000
    objects: a full collection of them takes ~0.1 s on the 2-core machine
    (measured), a stall the collector may start at any message. The objects
    built at start-up live as long as the process; what is allocated later is
    collected as usual. Call it when the start-up (and a configure) is done.
    """
    gc.collect()
    gc.freeze()


def exit_process(code: int) -> None:
    """End the process now with ``code``: flush stdout and stderr, skip the interpreter's finalization.

    For a node's console entry point, after :func:`run_node` returned (every
    ROS entity, the executor and the context are destroyed by then).
    """
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)
