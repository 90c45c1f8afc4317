"""The life of a node process: start, spin, and a clean exit on SIGINT or SIGTERM (every clm node's ``main``).

:func:`run_node` is the ``main`` of the track, vehicle and calibration nodes (and of a fleet's pair: a
vehicle and a track node on one executor, :mod:`clm_ros.fleet_pair`):

- rclpy's default handling of SIGINT raises ``KeyboardInterrupt`` wherever
  the main thread happens to be (possibly in a callback that is publishing)
  and shuts the context down under the feet of a thread that is publishing
  (an ``RCLError`` or an abort); SIGTERM ends the process at once. Here
  ``rclpy.init`` runs without rclpy's signal handlers and :class:`StopSignals`
  takes SIGINT and SIGTERM: while the node is built (its model built and
  warmed up) a signal interrupts the start-up at once
  (``KeyboardInterrupt``, nothing is half-done then); once the executor
  exists (rclpy's EventsExecutor installs handlers of its own when it is
  created; ours replace them) a signal only sets a flag;
- before the participant exists, the stale Fast DDS shared-memory ports of
  the node's domain (left locked by a process killed with SIGKILL; no live
  process maps them) are removed, said in one line (:mod:`clm_ros.shm`);
- Fast DDS publishes synchronously unless ``RMW_FASTRTPS_PUBLICATION_MODE``
  says otherwise (:data:`PUBLICATION_MODE`), with the profile
  :data:`FASTDDS_PROFILE` unless the environment names one;
- ``kill -USR1 <pid>`` prints every thread's Python stack to stderr and the
  process goes on (:func:`clm_core.stacks.dump_stacks_on_signal`): how a node
  that hangs is diagnosed;
- the heap built at start-up frozen out of the garbage collector's reach
  (:func:`freeze_heap`: no 0.1-s collection pause in the middle of a run);
- once the node and its executor exist, every thread of the process under
  ``SCHED_FIFO`` at the node's ``realtime_priority`` when permitted
  (:mod:`clm_ros.realtime`; the start-up ran at normal priority), said once
  in the log and kept in the node's ``scheduling`` for its /diagnostics;
  back to normal scheduling as soon as the spinning ends (a stop), so that
  nothing of the shut-down can busy-wait under ``SCHED_FIFO``
  (:func:`clm_ros.realtime.release_fifo`);
- an executor (``EventsExecutor`` unless the node needs another: its
  ``spin()`` delivered no callback on the Jazzy wheels, measured in
  benchmarks/node_lag.py) spun with ``spin_once`` until the flag is set or
  the node asks to exit; an exception escaping a callback (a service called
  with an invalid request, say) is logged (one bounded line) and spinning
  goes on;
- after a signal, the node's ``drain`` (if any): it may go on spinning for a
  grace period to finish or abort what runs; a second signal cuts it short;
- then, in this order: the node's ``stop`` (it stops its own threads; they
  never outlive it), the executor, the node, the context (the DDS
  participant leaves the graph, announced to its peers);
- from the first stop signal, and from the start of that shut-down whatever
  ended the spinning, the process has :data:`EXIT_DEADLINE_S` s to end: past
  it, every thread's stack goes to stderr (``Timeout (0:00:20)!`` first) and
  the process ends with exit code 1 (:func:`clm_core.stacks.exit_with_stacks_after`).
  A shut-down takes 0.2-1.5 s (measured); one that hangs (in DDS, in the
  interpreter's finalization) must not keep a stopped node alive for ever.

A node used with it may define (all optional; with several nodes, each one's):

``exit_code``
    None while it runs; a number ends the process with that code (e.g. 2
    when the model cannot be configured at start, 0 after the last train).
``serve_due() -> float``
    Called between two turns of the executor: does what is due and returns
    how long the executor may wait for callbacks until its next action [s]
    (a node with a timetable, such as the vehicle node, needs no thread).
``drain(spin_until) -> None``
    Called once after a stop signal, before ``stop``; ``spin_until(done,
    timeout)`` spins until ``done()``, ``timeout`` s or a second signal.
``stop() -> None``
    Called once, before anything is destroyed.
``realtime_priority``
    The ``SCHED_FIFO`` priority the node asks for (0 or absent: none; with
    several nodes, the highest); :func:`run_node` sets the node's
    ``scheduling`` to the :class:`clm_ros.realtime.Scheduling` outcome.
``abandoned() -> bool``
    True when a thread that cannot be interrupted still runs (the
    calibration node's fit): the process then ends at once once ROS is
    shut down (:func:`exit_process`).

The flag is polled every ``poll`` seconds (0.1 s): the exit after a signal
takes that plus the node's ``drain`` and ``stop``, a few ms. :func:`exit_process`
ends the process without the interpreter's finalization, which takes 0.3-1.5 s
with numba, numpy and scipy loaded on a busy 2-core machine (measured), once
everything of ROS has been destroyed in order (tests/ros/test_vehicle_node.py
measures the exit against the 2-s requirement of issue 12).
"""

from __future__ import annotations

import gc
import os
import select
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable, Sequence
from pathlib import Path
from types import FrameType
from typing import Any

import rclpy
from rclpy.exceptions import InvalidParameterValueException
from rclpy.executors import Executor, ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import get_default_context

from clm_core.errors import ClmError
from clm_core.stacks import dump_stacks_on_signal, exit_with_stacks_after
from clm_ros.node_log import bounded
from clm_ros.realtime import apply_fifo, release_fifo
from clm_ros.shm import clean_stale_ports, domain_of_environment

__all__ = ["EXIT_DEADLINE_S", "FASTDDS_PROFILE", "PUBLICATION_MODE", "START_ERRORS", "StopSignals", "exit_process",
           "freeze_heap", "run_node"]

#: Fast DDS publication mode of the node processes unless the environment sets one: a synchronous write
#: sends from the publishing thread; the asynchronous default hands every message to a thread of Fast DDS,
#: one more thread switch per message: 85-90 against 150-190 us of CPU per message for a 1-kHz raw publisher
#: with one reliable subscriber on the 2-core machine (load 4-5), measured for issue 10; track node at 1 kHz
#: (benchmarks/node_lag.py, same sitting): 307-337 against 388-477 us of CPU per message, lag p99 5.7-5.9
#: against 12.7-26.8 ms.
PUBLICATION_MODE = "SYNCHRONOUS"

#: Fast DDS XML profile of the node processes unless the environment names one (``FASTRTPS_DEFAULT_PROFILES_FILE``
#: or ``FASTDDS_DEFAULT_PROFILES_FILE``): reliable writers coalesce their per-sample NACK-suppression timer
#: (5 ms instead of 0), ~51 -> ~30 us of CPU per publish to a reliable reader (see the file).
FASTDDS_PROFILE = Path(__file__).with_name("fastdds_profile.xml")

#: Longest time from a stop signal (or the start of the shut-down) to the process's end [s]; past it the stacks go
#: to stderr and the process ends with exit code 1. A clean shut-down takes 0.2-1.5 s on the busy 2-core machine.
EXIT_DEADLINE_S = 20.0

#: Errors of a node's construction that mean an invalid setting: printed as one line, exit code 2.
START_ERRORS: tuple[type[Exception], ...] = (ClmError, ValueError, InvalidParameterValueException)


class StopSignals:
    """SIGINT and SIGTERM as a stop request (an event), installed with :meth:`install`.

    Attributes
    ----------
    event : threading.Event
        Set at the first signal.
    signum : int or None
        The first signal received.
    count : int
        Signals received so far (a second one cuts a node's ``drain`` short).

    Parameters
    ----------
    deadline : float, optional
        Seconds the process has to end from the first signal
        (:func:`clm_core.stacks.exit_with_stacks_after`); None: no deadline.
    """

    def __init__(self, deadline: float | None = None) -> None:
        self.deadline = deadline
        self.event = threading.Event()
        self.signum: int | None = None
        self.count = 0
        self._interrupt = True
        self._previous: dict[int, Any] = {}

    def install(self, interrupt: bool) -> None:
        """(Re-)install the handlers; ``interrupt``: raise ``KeyboardInterrupt`` at once (start-up) or only
        set the event (spinning)."""
        self._interrupt = interrupt
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous = signal.signal(sig, self._handler)
            self._previous.setdefault(sig, previous)

    def restore(self) -> None:
        """Put back the handlers found at the first :meth:`install`."""
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous.clear()

    def _handler(self, signum: int, frame: FrameType | None) -> None:
        if self.signum is None:
            self.signum = signum
            if self.deadline is not None:
                exit_with_stacks_after(self.deadline)
        self.count += 1
        self.event.set()
        if self._interrupt:
            raise KeyboardInterrupt

    def requested(self) -> bool:
        """Whether a stop was requested."""
        return self.event.is_set()

    @property
    def name(self) -> str:
        """The first signal's name (``SIGTERM``), ``""`` before any."""
        return signal.Signals(self.signum).name if self.signum is not None else ""


def run_node(make: Callable[[StopSignals], Any], args: Sequence[str] | None = None, name: str = "node",
             poll: float = 0.1, executor_type: Callable[[], Executor] = EventsExecutor,
             exit_now: bool = False) -> int:
    """Create the node(s) with ``make(stop)``, spin until a signal or an ``exit_code``; return the exit code.

    Parameters
    ----------
    make : callable
        Builds the node, or a tuple of nodes served by one executor (after
        ``rclpy.init``), given the :class:`StopSignals` (long callbacks may
        check :meth:`StopSignals.requested`). An error of
        :data:`START_ERRORS` raised here is printed as one line and gives
        exit code 2.
    args : sequence of str, optional
        Command line (``--ros-args ...``); default ``sys.argv``.
    name : str
        Program name in error messages.
    poll : float
        Longest wait between two looks at the signal flag [s].
    executor_type : callable
        Makes the executor (default ``EventsExecutor``: ~30 % less CPU per
        message than the ``SingleThreadedExecutor``).
    exit_now : bool
        End the process with :func:`exit_process` once ROS is shut down (for
        a console entry point; also done whenever a node's ``abandoned()``
        is true).
    """
    dump_stacks_on_signal()
    os.environ.setdefault("RMW_FASTRTPS_PUBLICATION_MODE", PUBLICATION_MODE)
    if not ({"FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE"} & os.environ.keys()) and \
            FASTDDS_PROFILE.is_file():
        os.environ["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(FASTDDS_PROFILE)
    nodes: tuple[Any, ...] = ()
    executor: Executor | None = None
    code = 0
    stop = StopSignals(deadline=EXIT_DEADLINE_S)
    stop.install(interrupt=True)  # during start-up a signal interrupts at once (everything below is in the try)
    try:
        stale = clean_stale_ports()  # before the participant opens the domain's ports (issue 26.3)
        if stale:
            print(f"{name}: removed {len(stale)} stale Fast DDS shared-memory file(s) of domain "
                  f"{domain_of_environment()} (no live process mapped them): {bounded(', '.join(stale), 200)}",
                  file=sys.stderr)
        rclpy.init(args=list(args) if args is not None else None, signal_handler_options=SignalHandlerOptions.NO)
        try:
            made = make(stop)
        except START_ERRORS as exc:
            print(f"{name}: error: {bounded(' '.join(str(exc).split()))}", file=sys.stderr)
            return 2
        nodes = tuple(made) if isinstance(made, (tuple, list)) else (made,)
        freeze_heap()
        executor = executor_type()
        for node in nodes:
            executor.add_node(node)
        _schedule(nodes)
        stop.install(interrupt=False)
        code = _spin(nodes, executor, stop, poll)
        _leave_realtime(nodes)  # the shut-down never runs under SCHED_FIFO (clm_ros.realtime.release_fifo)
        if stop.requested():
            for node in _having(nodes, "drain"):
                node.drain(lambda done, timeout: _spin_until(executor, lambda: done() or stop.count > 1, timeout))
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        stop.install(interrupt=False)
        exit_with_stacks_after(EXIT_DEADLINE_S)  # whatever ended the spinning: the shut-down cannot hang for ever
        _leave_realtime(nodes)  # (again: an exception ended the spinning)
        for node in _having(nodes, "stop"):
            node.stop()
        if executor is not None:
            executor.shutdown(timeout_sec=1.0)
        for node in reversed(nodes):
            node.destroy_node()
        rclpy.try_shutdown()
        get_default_context().destroy()  # the DDS participant goes now: its peers see it leave
        stop.restore()
    if exit_now or any(node.abandoned() for node in _having(nodes, "abandoned")):
        exit_process(code)
    return code


def _having(nodes: tuple[Any, ...], hook: str) -> list[Any]:
    """The nodes that define ``hook``."""
    return [node for node in nodes if hasattr(node, hook)]


def _schedule(nodes: tuple[Any, ...]) -> None:
    """Every thread under ``SCHED_FIFO`` at the nodes' highest ``realtime_priority`` when permitted; said once."""
    asked = [int(node.realtime_priority) for node in _having(nodes, "realtime_priority")]
    if not asked:
        return
    outcome = apply_fifo(max(asked))
    for node in nodes:
        node.scheduling = outcome
    logger = nodes[0].get_logger()
    if outcome.requested and not outcome.priority:
        logger.warning(f"scheduling: {outcome.text}; answers may wait for other processes on a busy machine")
    else:
        logger.info(f"scheduling: {outcome.text}")


def _leave_realtime(nodes: tuple[Any, ...]) -> None:
    """Back to normal scheduling for the shut-down, said once when there was real-time scheduling."""
    n = release_fifo()
    if n and nodes:
        nodes[0].get_logger().info(f"scheduling: back to normal for the shut-down ({n} threads)")


def _exit_code(nodes: tuple[Any, ...]) -> int | None:
    """The first ``exit_code`` a node has set, None while every node should run."""
    for node in nodes:
        code = getattr(node, "exit_code", None)
        if code is not None:
            return int(code)
    return None


#: Seconds between two checks of the context and the nodes' exit codes while spinning.
CHECK_PERIOD = 0.02


#: Longest wait of the wait-set loop on the nodes' own fds before the executor is served [s] (services, timers).
WAIT_SLICE = 0.002


def _spin(nodes: tuple[Any, ...], executor: Executor, stop: StopSignals, poll: float) -> int:
    """Spin until a signal, the end of the context or a node's ``exit_code``; return the exit code.

    A node with a ``wait_fd()`` (the track node with ``answer_loop`` = ``waitset``) that returns an fd >= 0 is
    served by a wait-set loop: this thread waits on the fds itself (``select``, at most :data:`WAIT_SLICE`) and
    calls the node's ``serve_fd()`` when one is readable (its data path runs here, with no hand-over to the
    executor), and serves the executor (``spin_once(0)``: services, timers) when the wait ran out or
    :data:`WAIT_SLICE` has passed since it last did. Otherwise the executor alone, as ever."""
    serve = [node.serve_due for node in _having(nodes, "serve_due")]
    waiters = _having(nodes, "wait_fd")  # none unless a node waits on its own fd: the executor alone, as ever
    spin_once, clock = executor.spin_once, time.monotonic
    check = 0.0  # the context and the exit codes are checked every CHECK_PERIOD (a message each ms otherwise)
    served = 0.0  # when the wait-set loop last served the executor
    while not stop.requested():
        now = clock()
        if now >= check:
            check = now + CHECK_PERIOD
            if not rclpy.ok():
                break
            code = _exit_code(nodes)
            if code is not None:
                return code
        wait = min([poll, *(max(s(), 0.0) for s in serve)]) if serve else poll
        fds = {fd: node for node in waiters if (fd := node.wait_fd()) >= 0} if waiters else {}
        try:
            if not fds:
                spin_once(timeout_sec=wait)
                continue
            readable = select.select(list(fds), [], [], min(wait, WAIT_SLICE))[0]
            for fd in readable:
                fds[fd].serve_fd()
            if not readable or clock() - served >= WAIT_SLICE:
                served = clock()
                spin_once(timeout_sec=0)
        except Exception as exc:  # a callback's failure must not end the node
            if stop.requested() or not rclpy.ok():
                break
            tb = traceback.format_exception_only(type(exc), exc)[-1].strip()
            nodes[0].get_logger().error(bounded(f"a callback raised and was skipped: {tb}"))
    return _exit_code(nodes) or 0


def _spin_until(executor: Executor, done: Callable[[], bool], timeout: float) -> None:
    """Spin ``executor`` until ``done()`` or ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while not done() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)


def guard_change_state(node: Any, log: Any, state: Callable[[], str]) -> None:
    """Make a lifecycle ``node`` answer ``change_state`` with success = false for a transition its current state
    does not have (rclpy raises there, and the caller would wait for an answer forever); logged on ``log``
    (a :class:`clm_ros.node_log.NodeLog`) with ``state()``."""
    srv = getattr(node, "_service_change_state", None)
    if srv is None:
        return
    inner = srv.callback

    def guarded(request: Any, response: Any) -> Any:
        try:
            return inner(request, response)
        except Exception as exc:  # RCLError: no such transition from this state
            log.warning(f"transition {request.transition.id} {request.transition.label!r} refused in state "
                        f"{state()}: {exc}")
            response.success = False
            return response

    srv.callback = guarded


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

    Called by :func:`run_node` once every ROS entity, the executor and the
    context are destroyed.
    """
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)
