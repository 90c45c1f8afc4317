"""``kill -USR1`` of a running ``clm`` command prints every thread's stack and the command goes on (clm_core.stacks)."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time

import pytest

from clm_core.stacks import STACKS_SIGNAL, dump_stacks_on_signal, exit_with_stacks_after

# a clm command that waits (the stacks are asked for while it runs), then exits 0 once its stdin closes
WAITER = """
import sys, threading
from clm_core.stacks import dump_stacks_on_signal
assert dump_stacks_on_signal()
worker = threading.Thread(target=lambda: threading.Event().wait(60), name="worker", daemon=True)
worker.start()
print("ready", flush=True)
sys.stdin.read()
print("done", flush=True)
"""


@pytest.mark.skipif(STACKS_SIGNAL is None, reason="no SIGUSR1 on this platform")
def test_stacks_of_every_thread_and_the_process_goes_on() -> None:
    proc = subprocess.Popen([sys.executable, "-c", WAITER], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None and proc.stdout.readline() == "ready\n"
        proc.send_signal(signal.SIGUSR1)
        time.sleep(0.5)  # the dump is written by the signal handler, at once; the process must still run after it
        assert proc.poll() is None
        out, err = proc.communicate("", timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0 and out == "done\n", err
    assert err.count("Thread 0x") + err.count("Current thread 0x") == 2, err  # the main thread and the worker
    assert "in <lambda>" in err and "most recent call first" in err, err


def test_not_registered_off_the_main_thread() -> None:
    got: list[bool] = []
    t = threading.Thread(target=lambda: got.append(dump_stacks_on_signal()))
    t.start()
    t.join()
    assert got == [False]


# arms the exit deadline (argv[1] s), optionally disarms it (argv[2] == "cancel"), then waits argv[3] s in a thread
DEADLINE = """
import sys, threading, time
from clm_core.stacks import cancel_exit_deadline, exit_with_stacks_after
assert exit_with_stacks_after(float(sys.argv[1]))
if sys.argv[2] == "cancel":
    cancel_exit_deadline()
def stuck_in_teardown():
    time.sleep(float(sys.argv[3]))
t = threading.Thread(target=stuck_in_teardown)
t.start()
t.join()
print("ended", flush=True)
"""


def test_exit_deadline_ends_a_stuck_process_with_its_stacks() -> None:
    proc = subprocess.run([sys.executable, "-c", DEADLINE, "1.0", "keep", "60"], capture_output=True, text=True,
                          timeout=120)
    # ended by the deadline while the thread still waited (it never printed "ended"), with its stack
    assert proc.returncode == 1 and proc.stdout == "", (proc.returncode, proc.stdout, proc.stderr)
    assert "Timeout (0:00:01)!" in proc.stderr and "in stuck_in_teardown" in proc.stderr, proc.stderr


def test_exit_deadline_cancelled_lets_the_process_end_itself() -> None:
    proc = subprocess.run([sys.executable, "-c", DEADLINE, "1.0", "cancel", "2.5"], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0 and proc.stdout == "ended\n" and "Timeout" not in proc.stderr, proc.stderr


@pytest.mark.parametrize("seconds", [0.0, -1.0, float("nan")])
def test_exit_deadline_must_be_positive(seconds: float) -> None:
    with pytest.raises(ValueError, match="must be > 0"):
        exit_with_stacks_after(seconds)


CRASH = """
import ctypes
from clm_core.stacks import dump_stacks_on_signal
assert dump_stacks_on_signal()
def crashing_in_c():
    ctypes.string_at(0)  # a read at address 0 in C: SIGSEGV
crashing_in_c()
"""


@pytest.mark.skipif(not hasattr(signal, "SIGSEGV"), reason="no SIGSEGV on this platform")
def test_a_crash_in_c_prints_the_stacks_and_keeps_its_exit_status() -> None:
    proc = subprocess.run([sys.executable, "-c", CRASH], capture_output=True, text=True, timeout=120)
    assert proc.returncode == -signal.SIGSEGV, (proc.returncode, proc.stderr)
    assert "Fatal Python error: Segmentation fault" in proc.stderr and "in crashing_in_c" in proc.stderr, proc.stderr
