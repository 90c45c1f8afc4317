"""Running the ``clm`` command as a user does: in a subprocess, or in a pseudo-terminal.

A pseudo-terminal makes stderr a TTY, so the command shows its progress bars
(tqdm) exactly as in an interactive shell: the replay crash on a bar without a
total (issue 13) only happened there.
"""

from __future__ import annotations

import fcntl
import os
import pty
import select
import struct
import subprocess
import sys
import termios
import time
from collections.abc import Iterable, Mapping, Sequence

import pytest

from clm_core.stacks import STACKS_SIGNAL

CLM = [sys.executable, "-m", "clm_core.cli"]


def run_clm(args: Sequence[str], env: Mapping[str, str] | None = None, timeout: float = 600.0,
            cwd: str | None = None) -> subprocess.CompletedProcess[str]:
    """``clm ARGS`` in a subprocess with pipes (no terminal)."""
    return subprocess.run([*CLM, *args], capture_output=True, text=True, env=None if env is None else dict(env),
                          timeout=timeout, cwd=cwd)


def ask_for_stacks(procs: Iterable[subprocess.Popen[str]], settle: float = 2.0) -> None:
    """Ask every process of ``procs`` still running for every thread's stack (``kill -USR1``,
    :mod:`clm_core.stacks`: a clm command or node prints them to stderr and goes on; a process without the handler
    just ends), then give them ``settle`` s to print. The caller kills them after."""
    running = [p for p in procs if p.poll() is None]
    if running and STACKS_SIGNAL is not None:
        for p in running:
            p.send_signal(STACKS_SIGNAL)
        time.sleep(settle)


def wait_or_stacks(proc: subprocess.Popen[str], timeout: float, what: str = "") -> tuple[str, str]:
    """Wait ``timeout`` s for ``proc`` to exit and return its (stdout, stderr); past that, fail the test with every
    thread's stack of the process (``kill -USR1``, :mod:`clm_core.stacks`: a clm command or node prints them to
    stderr), then killed, and its output. ``what`` names the wait in the failure."""
    try:
        return proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        ask_for_stacks([proc])
        proc.kill()
        out, err = proc.communicate()
        pytest.fail(f"{what or proc.args!r}: still running after {timeout} s; its threads then (SIGUSR1)\n"
                    f"--- stdout\n{(out or '')[-20000:]}\n--- stderr\n{(err or '')[-20000:]}")


def input_error(proc: subprocess.CompletedProcess[str]) -> str:
    """The message of a ``clm`` run refused as an input error: exit code 2 and one line on stderr (asserted)."""
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1, f"exit {proc.returncode}:\n{proc.stderr}"
    return lines[0]


def run_in_pty(argv: Sequence[str], env: Mapping[str, str] | None = None, timeout: float = 600.0,
               cwd: str | None = None) -> tuple[int, str]:
    """Run ``argv`` with stdin, stdout and stderr on a pseudo-terminal (80 x 24); return (exit code, output)."""
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 80, 0, 0))
    proc = subprocess.Popen(list(argv), stdin=slave, stdout=slave, stderr=slave, close_fds=True,
                            env=None if env is None else dict(env), cwd=cwd)
    os.close(slave)
    chunks: list[bytes] = []
    deadline = time.monotonic() + timeout
    try:
        while True:
            if time.monotonic() > deadline:
                proc.kill()
                raise TimeoutError(f"{argv!r} still running after {timeout} s:\n" + b"".join(chunks).decode())
            ready, _, _ = select.select([master], [], [], 0.2)
            if ready:
                try:
                    data = os.read(master, 65536)
                except OSError:  # EIO: every writer closed the terminal
                    break
                if not data:
                    break
                chunks.append(data)
            elif proc.poll() is not None:
                break
        proc.wait(timeout=30)
    finally:
        os.close(master)
    return proc.returncode, b"".join(chunks).decode(errors="replace")
