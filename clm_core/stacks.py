"""Every thread's Python stack on request: ``kill -USR1 <pid>`` of a running ``clm`` or clm node process.

How a process that hangs is diagnosed without stopping it: the ``clm`` command
(:func:`clm_core.cli.main`) and every clm ROS node process
(``clm_ros.node_main.run_node``) call :func:`dump_stacks_on_signal` at start.
The stacks go to stderr (its log file under ``clm demo`` and ``clm fleet``),
and the process goes on as before.
"""

from __future__ import annotations

import contextlib
import faulthandler
import signal
import threading

__all__ = ["STACKS_SIGNAL", "dump_stacks_on_signal"]

#: The signal that asks for the stacks (absent on Windows: nothing is registered there).
STACKS_SIGNAL: int | None = getattr(signal, "SIGUSR1", None)


def dump_stacks_on_signal() -> bool:
    """Make :data:`STACKS_SIGNAL` print the stack of every thread to stderr (``faulthandler``); return whether it
    is registered.

    Not registered (False) off the main thread (signal handlers belong to it), on a platform without the signal,
    or when stderr has no file descriptor (called in-process under an output capture).
    """
    if STACKS_SIGNAL is None or threading.current_thread() is not threading.main_thread():
        return False
    with contextlib.suppress(OSError, ValueError, AttributeError):  # stderr without a file descriptor
        faulthandler.register(STACKS_SIGNAL, all_threads=True)
        return True
    return False
