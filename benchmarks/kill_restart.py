"""Benchmark: is a track node restarted after a kill -9 heard by a live vehicle? (prints, never asserts).

One vehicle node (1 kHz wheel loads, a 3600-s train, answer timeout 0.5 s)
and one track node in a domain held for this run, on loopback. Then, ``N``
times: SIGKILL the track node 0.2-1.2 s after it answers, wait for the
vehicle's "no answer from the track node", start a new track node and wait up
to ``--wait`` s for the vehicle's "the track node answers again". Prints one
line per restart and, at the first restart not heard, every thread's stack of
both processes (SIGUSR1), the Fast DDS shared-memory files each maps
(``/proc/PID/maps``; a ``(deleted)`` port is a port unlinked under a live
listener) and the domain's files in /dev/shm; then stops.

Found 2026-12-05 (stress run at 0265cfd, ``test_track_node_killed_and_back``):
the 83rd and the 116th restart of two series were never heard.

Usage::

    python benchmarks/kill_restart.py [--restarts 400] [--wait 30]
"""

from __future__ import annotations

import argparse
import random
import subprocess
import sys
import threading
import time
from pathlib import Path

from clm_ros import processes
from clm_ros.shm import port_files

from clm_core.stacks import STACKS_SIGNAL

PYTHON = sys.executable


class Logs:
    """The stderr lines of the started nodes, tagged, collected by one thread per process."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    def follow(self, proc: subprocess.Popen[str], tag: str) -> None:
        def read() -> None:
            assert proc.stderr is not None
            for line in iter(proc.stderr.readline, ""):
                self.lines.append(f"{tag}: {line.rstrip()}")

        threading.Thread(target=read, daemon=True).start()

    def wait_for(self, text: str, since: int, timeout: float) -> bool:
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout:
            if any(text in line for line in self.lines[since:]):
                return True
            time.sleep(0.02)
        return False


def shm_maps(pid: int) -> list[str]:
    """The Fast DDS shared-memory files process ``pid`` maps (``(deleted)`` marks an unlinked one)."""
    try:
        rows = Path(f"/proc/{pid}/maps").read_text().splitlines()
    except OSError as exc:
        return [f"unreadable: {exc}"]
    return sorted({" ".join(r.split()[5:]) for r in rows if "/dev/shm/fastrtps" in r})


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--restarts", type=int, default=400)
    ap.add_argument("--wait", type=float, default=30.0, help="seconds to wait for the answers of a new track node")
    args = ap.parse_args()
    logs = Logs()
    with processes.hold_domain_id() as domain:
        env = processes.ros_env(domain)

        def start(module: str, tag: str, params: dict[str, float] | None = None) -> subprocess.Popen[str]:
            p = subprocess.Popen([PYTHON, "-m", module, *processes.ros_args(params or {})], env=env, text=True,
                                 stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
            logs.follow(p, tag)
            return p

        vehicle = start("clm_ros.vehicle_node", "vehicle",
                        {"duration": 3600.0, "diagnostics_period": 0.2, "answer_timeout": 0.5})
        track = start("clm_ros.track_node", "track0")
        heard = 0
        try:
            if not logs.wait_for("train 1 starts", 0, 60):
                print("the vehicle's train did not start within 60 s:\n" + "\n".join(logs.lines))
                return 1
            time.sleep(1.0)
            for i in range(1, args.restarts + 1):
                time.sleep(random.uniform(0.2, 1.2))
                mark = len(logs.lines)
                track.kill()
                track.wait()
                silence = logs.wait_for("no answer from the track node", mark, 10)
                mark = len(logs.lines)
                track = start("clm_ros.track_node", f"track{i}")
                if logs.wait_for("answers again", mark, args.wait):
                    heard += 1
                    print(f"restart {i}: heard" + ("" if silence else " (no silence reported)"), flush=True)
                    continue
                print(f"restart {i}: NOT HEARD within {args.wait:g} s (domain {domain})")
                for name, p in (("track node", track), ("vehicle", vehicle)):
                    print(f"{name} {p.pid} maps: " + "; ".join(shm_maps(p.pid)))
                    if STACKS_SIGNAL is not None:
                        p.send_signal(STACKS_SIGNAL)
                time.sleep(3.0)
                files = sorted(f.name for group in port_files(domain).values() for f in group)
                print("domain files in /dev/shm: " + ", ".join(files))
                print("\n".join(logs.lines[mark:]))
                break
        finally:
            for p in (track, vehicle):
                if p.poll() is None:
                    p.kill()
        print(f"restarts heard: {heard}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
