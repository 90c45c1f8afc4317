"""How a node process lives and ends: SIGINT/SIGTERM as a stop request, an executor loop that survives.

rclpy's default handling of SIGINT raises ``KeyboardInterrupt`` wherever the
main thread happens to be, possibly in the middle of a callback that is
updating state or publishing, and shuts the context down under a running
publisher; SIGTERM ends the process at once. A node that must exit cleanly
(exit 0, within 2 s, also under load) instead:

1. starts rclpy without its signal handlers
   (``rclpy.init(signal_handler_options=SignalHandlerOptions.NO)``);
2. installs :class:`StopSignals` once the executor exists (rclpy's
   EventsExecutor installs its own SIGINT/SIGTERM handlers when it is
   created; ours replace them): a signal only sets an event;
3. spins with :func:`spin_until_stopped`: short ``spin_once`` calls until the
   event is set; long callbacks check :meth:`StopSignals.requested` between
   chunks of work; an exception escaping a callback (a service called with
   an invalid request, say) is logged and the loop goes on;
4. destroys the node and shuts rclpy down.

Before spinning starts (the node builds and warms up its model), a signal
interrupts the start-up at once (``KeyboardInterrupt``), which leaves
nothing half-done behind.
"""

from __future__ import annotations

import os
import signal
import threading
import traceback
from collections.abc import Callable
from typing import Any

from clm_ros.diagnostics import bounded

__all__ = ["PUBLICATION_MODE", "StopSignals", "publish_synchronously", "spin_until_stopped"]

#: Fast DDS publication mode of a node process unless its environment sets one. Synchronous: the publishing
#: thread sends; the asynchronous default hands every message to a Fast DDS thread (one more thread switch
#: per message). Track node at 1 kHz (benchmarks/node_lag.py, same sitting): 307-337 against 388-477 us of
#: CPU per message, lag p99 5.7-5.9 against 12.7-26.8 ms.
PUBLICATION_MODE = "SYNCHRONOUS"


def publish_synchronously() -> None:
    """Default ``RMW_FASTRTPS_PUBLICATION_MODE`` to :data:`PUBLICATION_MODE` (before ``rclpy.init``)."""
    os.environ.setdefault("RMW_FASTRTPS_PUBLICATION_MODE", PUBLICATION_MODE)


class StopSignals:
    """SIGINT and SIGTERM as a stop request (an event), installed with :meth:`install`."""

    def __init__(self) -> None:
        self.event = threading.Event()
        self.signum: int | None = None
        self._interrupt = True

    def install(self, interrupt: bool) -> None:
        """(Re-)install the handlers; ``interrupt``: raise ``KeyboardInterrupt`` at once (start-up) or only
        set the event (spinning)."""
        self._interrupt = interrupt
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self._handler)

    def _handler(self, signum: int, frame: Any) -> None:
        self.signum = signum
        self.event.set()
        if self._interrupt:
            raise KeyboardInterrupt

    def requested(self) -> bool:
        """Whether a stop was requested."""
        return self.event.is_set()


def spin_until_stopped(executor: Any, stop: StopSignals, ok: Callable[[], bool], log: Callable[[str], None],
                       period: float = 0.05) -> None:
    """Spin ``executor`` one event at a time until ``stop`` is requested or ``ok()`` is false.

    An exception escaping a callback is logged (bounded) and spinning goes on.
    """
    while not stop.requested() and ok():
        try:
            executor.spin_once(timeout_sec=period)
        except Exception as exc:  # a callback's failure must not end the node
            if stop.requested() or not ok():
                break
            tb = traceback.format_exception_only(type(exc), exc)[-1].strip()
            log(bounded(f"a callback raised and was skipped: {tb}"))
