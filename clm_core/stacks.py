"""Every thread's Python stack on request: ``kill -USR1 <pid>`` of a running ``clm`` or clm node process.

How a process that hangs is diagnosed without stopping it: the ``clm`` command
(:func:`clm_core.cli.main`) and every clm ROS node process
(``clm_ros.node_main.run_node``) call :func:`dump_stacks_on_signal` at start.
The stacks go to stderr (its log file under ``clm demo`` and ``clm fleet``),
and the process goes on as before.

:func:`exit_with_stacks_after` bounds how long a process may take to end: a
clm node arms it when it is asked to stop, so that a shut-down that hangs (in
DDS, in the interpreter's finalization) ends with every thread's stack on
stderr and exit code 1 instead of never.
"""

from __future__ import annotations

import contextlib
import faulthandler
import signal
import threading

__all__ = ["STACKS_SIGNAL", "cancel_exit_deadline", "dump_stacks_on_signal", "exit_with_stacks_after"]

#: The signal that asks for the stacks (absent on Windows: nothing is registered there).
STACKS_SIGNAL: int | None = getattr(signal, "SIGUSR1", None)


def dump_stacks_on_signal() -> bool:
    """Make :data:`STACKS_SIGNAL` print the stack of every thread to stderr (``faulthandler``), and a fatal error
    (SIGSEGV, SIGFPE, SIGABRT, SIGBUS, SIGILL: a crash in a C extension, e.g. in DDS at shut-down) print them too
    before the process dies of it as before (same exit status); return whether it is registered.

    Not registered (False) off the main thread (signal handlers belong to it), on a platform without the signal,
    or when stderr has no file descriptor (called in-process under an output capture).
    """
    if STACKS_SIGNAL is None or threading.current_thread() is not threading.main_thread():
        return False
    with contextlib.suppress(OSError, ValueError, AttributeError):  # stderr without a file descriptor
        faulthandler.register(STACKS_SIGNAL, all_threads=True)
        faulthandler.enable(all_threads=True)
        return True
    return False


def exit_with_stacks_after(seconds: float) -> bool:
    """Arm the process's exit deadline: if it still runs ``seconds`` s from now, ``Timeout (h:mm:ss)!`` and the
    stack of every thread go to stderr and it ends at once with exit code 1 (``faulthandler.dump_traceback_later``
    with ``exit``, a C thread: it needs neither the GIL nor a responsive main thread). Arming again moves the
    deadline; :func:`cancel_exit_deadline` disarms it. Returns whether it is armed (False where stderr has no file
    descriptor).

    Parameters
    ----------
    seconds : float
        Time left to the process [s], > 0.
    """
    if not seconds > 0:
        raise ValueError(f"exit deadline {seconds!r} s: must be > 0")
    with contextlib.suppress(OSError, ValueError, AttributeError):  # stderr without a file descriptor
        faulthandler.dump_traceback_later(seconds, exit=True)
        return True
    return False


def cancel_exit_deadline() -> None:
    """Disarm :func:`exit_with_stacks_after` (nothing happens when none is armed)."""
    faulthandler.cancel_dump_traceback_later()
