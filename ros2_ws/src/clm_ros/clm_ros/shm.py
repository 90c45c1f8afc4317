"""Stale Fast DDS shared-memory ports of the node's own domain, found and removed at start (issue 26.3).

Fast DDS's shared-memory transport (which rmw_fastrtps adds whenever discovery
is limited to the local host) keeps one port per locator in ``/dev/shm``:
``fastrtps_port<N>`` (the port's ring buffer and its mutex), ``fastrtps_port<N>_el``
and ``fastrtps_port<N>_sl`` (lock files), ``sem.fastrtps_port<N>_mutex`` (the
named mutex taken to open the port). ``N`` is an RTPS port of the domain:
``7400 + 250 * domain + offset``, ``0 <= offset < 250`` (the well-known port
mapping: discovery multicast ``7400 + 250 d``, then the participants' unicast
ports). A process killed with SIGKILL while it held a port's mutex leaves that
port locked: every later process of the domain that writes to it (discovery
writes to the multicast port first) blocks for ever at start, SIGINT ignored
(seen: every 4th new process, 2 of 2 ``clm demo`` runs).

A port no live process has mapped (``/proc/<pid>/maps``) is stale: nothing
reads or writes it, and Fast DDS creates it anew when it is next opened. At
start, before the node's participant exists, :func:`clean_stale_ports`
removes the files of every such port of the node's domain, and only of its
domain (other domains, other users' files and ports still mapped are left
alone). A port still mapped by a live process of the domain is never removed
(that would split it between the old and the new processes): a lock left
behind while other processes of the domain live on is cleared when the last of
them has gone.
"""

from __future__ import annotations

import os
import re
import time
from pathlib import Path

__all__ = ["DOMAIN_GAIN", "PORT_BASE", "SHM_DIR", "STALE_AGE", "clean_stale_ports", "domain_of_environment",
           "mapped_files", "port_files"]

#: Where POSIX shared memory lives on Linux.
SHM_DIR = Path("/dev/shm")
#: RTPS well-known port mapping: the ports of domain d are PORT_BASE + DOMAIN_GAIN * d + offset, offset < DOMAIN_GAIN.
PORT_BASE, DOMAIN_GAIN = 7400, 250
#: A port's files must all be at least this old [s] to be removed: a process that has just created a port maps it
#: within microseconds, never this late (the files of a port being created are never taken for stale ones).
STALE_AGE = 2.0
_PORT_FILE = re.compile(r"(?:sem\.)?fastrtps_port(\d+)(?:_el|_sl|_mutex)?")


def domain_of_environment() -> int:
    """The ROS domain of this process (``ROS_DOMAIN_ID``, 0 when unset or not a number)."""
    try:
        return int(os.environ.get("ROS_DOMAIN_ID", "0") or 0)
    except ValueError:
        return 0


def port_files(domain_id: int, shm_dir: Path = SHM_DIR) -> dict[int, list[Path]]:
    """The Fast DDS shared-memory files of ``domain_id``'s ports, by port."""
    lo = PORT_BASE + DOMAIN_GAIN * domain_id
    out: dict[int, list[Path]] = {}
    try:
        entries = list(shm_dir.iterdir())
    except OSError:
        return out
    for f in entries:
        m = _PORT_FILE.fullmatch(f.name)
        if m and lo <= int(m.group(1)) < lo + DOMAIN_GAIN:
            out.setdefault(int(m.group(1)), []).append(f)
    return out


def mapped_files(shm_dir: Path = SHM_DIR) -> set[str] | None:
    """Names of the files of ``shm_dir`` some live process has mapped (None: the process table cannot be read)."""
    prefix = f"{shm_dir}/"
    names: set[str] = set()
    try:
        pids = [p for p in os.listdir("/proc") if p.isdigit()]
    except OSError:
        return None
    for pid in pids:
        try:
            with open(f"/proc/{pid}/maps", encoding="utf-8", errors="replace") as maps:
                for line in maps:
                    i = line.find(prefix)
                    if i >= 0:
                        names.add(line[i + len(prefix):].split(" (deleted)")[0].strip())
        except OSError:  # the process ended, or is not ours to read: it cannot hold our files' mutexes either
            continue
    return names


def _older(files: list[Path], age: float) -> bool:
    """Whether every one of ``files`` was last changed at least ``age`` s ago."""
    now = time.time()
    try:
        return all(now - f.stat().st_ctime >= age for f in files)
    except OSError:  # gone meanwhile
        return False


def clean_stale_ports(domain_id: int | None = None, shm_dir: Path = SHM_DIR) -> list[str]:
    """Remove the files of the ports of ``domain_id`` (default: this process's) that no live process maps.

    Returns
    -------
    list of str
        The names of the files removed (empty: nothing stale, or ``/proc`` unreadable: nothing is removed then).
    """
    domain = domain_of_environment() if domain_id is None else domain_id
    ports = port_files(domain, shm_dir)
    if not ports:
        return []
    mapped = mapped_files(shm_dir)
    if mapped is None:
        return []
    removed: list[str] = []
    for files in ports.values():
        if any(f.name in mapped for f in files) or not _older(files, STALE_AGE):
            continue  # a live process uses this port, or is creating it
        for f in files:
            try:
                f.unlink()
                removed.append(f.name)
            except OSError:  # another user's file, or gone meanwhile
                continue
    return sorted(removed)
