"""``kill -USR1`` of a running ``clm`` command prints every thread's stack and the command goes on (clm_core.stacks)."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time

import pytest

from clm_core.stacks import STACKS_SIGNAL, dump_stacks_on_signal

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
