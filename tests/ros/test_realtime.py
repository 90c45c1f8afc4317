"""Real-time scheduling of the node processes (clm_ros.realtime, clm_ros.node_main.run_node).

Every thread of a node process goes under SCHED_FIFO at the node's
``realtime_priority`` once the node is built, or none does: refused (no
root, CAP_SYS_NICE or ``ulimit -r``), the process keeps normal scheduling,
says so once and still answers. Checked from ``/proc/<pid>/task/*/stat``
(policy and rt_priority), which the kernel keeps, not the code under test.
Permission is taken away for real: ``RLIMIT_RTPRIO`` 0 and, for root, a
re-exec under ``setpriv`` without CAP_SYS_NICE.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest

pytest.importorskip("clm_msgs.msg", reason="clm_msgs not built: bash scripts/setup_ros.sh VENV")

from clm_ros.parameters import REALTIME_PRIORITY
from clm_ros.realtime import MAX_PRIORITY, NORMAL_THREADS, apply_fifo, thread_scheduling
from driver import NODE_SCRIPT, track_node
from streams import encoded, frames

from clm_core.errors import ParameterError
from clm_core.io.timebase import NS

SCHED_OTHER, SCHED_FIFO = 0, 1
CAP_SYS_NICE = 23

#: Prepended to a child's code: take the permission to use real-time scheduling away, for real.
DROP_PERMISSION = """\
import os, resource, shutil, sys
resource.setrlimit(resource.RLIMIT_RTPRIO, (0, 0))
if os.geteuid() == 0 and not os.environ.get("CLM_TEST_NO_SYS_NICE"):
    os.environ["CLM_TEST_NO_SYS_NICE"] = "1"
    setpriv = shutil.which("setpriv")
    os.execv(setpriv, [setpriv, "--bounding-set=-sys_nice", "--inh-caps=-sys_nice", sys.executable, *sys.argv])
"""

#: A child that asks for SCHED_FIFO 5, starts a thread afterwards and prints what /proc says of every thread.
APPLY = """\
import json, threading
from clm_ros.realtime import apply_fifo, thread_scheduling
threads = [threading.Thread(target=threading.Event().wait, args=(2.0,), daemon=True) for _ in range(3)]
for t in threads[:2]:
    t.start()
outcome = apply_fifo(5)
threads[2].start()  # started after: inherits the policy of the thread that starts it
print(json.dumps({"priority": outcome.priority, "reason": outcome.reason, "threads": outcome.threads,
                  "text": outcome.text, "sched": thread_scheduling()}))
"""


def may_use_fifo(pid: int | str = "self") -> bool:
    """Whether a process has CAP_SYS_NICE or an RLIMIT_RTPRIO (what the kernel checks)."""
    status = Path(f"/proc/{pid}/status").read_text()
    cap_eff = int(next(line.split()[1] for line in status.splitlines() if line.startswith("CapEff:")), 16)
    limits = Path(f"/proc/{pid}/limits").read_text()
    rtprio = next(line.split()[3] for line in limits.splitlines() if line.startswith("Max realtime priority"))
    return bool(cap_eff >> CAP_SYS_NICE & 1) or rtprio == "unlimited" or int(rtprio) > 0


def needs_setpriv() -> None:
    if os.geteuid() == 0 and shutil.which("setpriv") is None:
        pytest.skip("running as root without setpriv: CAP_SYS_NICE cannot be taken away")


def test_every_thread_fifo_or_none_and_later_threads_inherit(ros_python) -> None:  # type: ignore[no-untyped-def]
    got = json.loads(ros_python.run(APPLY, name="apply").stdout)
    sched = set(map(tuple, got["sched"].values()))
    assert len(got["sched"]) >= 4  # the main thread and the three others
    if may_use_fifo():
        assert got["priority"] == 5 and got["reason"] == "" and got["threads"] >= 3, got
        assert sched == {(SCHED_FIFO, 5)}, got
        assert got["text"].startswith("SCHED_FIFO 5 (")
    else:  # this machine gives no real-time scheduling: the refusal, whole
        assert got["priority"] == 0 and "not permitted" in got["reason"], got
        assert sched == {(SCHED_OTHER, 0)}, got


#: A child with a DDS participant and a reliable writer asking for SCHED_FIFO 5; prints each thread's name and policy.
APPLY_DDS = """\
import json, os, rclpy
from std_msgs.msg import Int64
from clm_ros.realtime import apply_fifo, thread_scheduling
rclpy.init()
node = rclpy.create_node("fifo_probe")
node.create_publisher(Int64, "fifo_probe", 10)
outcome = apply_fifo(5)
names = {}
for tid in thread_scheduling():
    try:
        names[tid] = open(f"/proc/self/task/{tid}/comm").read().strip()
    except OSError:
        pass
sched = {names[t]: s for t, s in thread_scheduling().items() if t in names}
print(json.dumps({"priority": outcome.priority, "sched": sched}))
"""


def test_fast_dds_async_writer_thread_stays_normal(ros_python) -> None:  # type: ignore[no-untyped-def]
    """The participant's dds.asyn thread keeps SCHED_OTHER (its try_lock loop under SCHED_FIFO held both cores of the
    machine in 2 of 5 fleet runs, issue 21); every other thread, Fast DDS's reception and event threads included, is
    SCHED_FIFO."""
    if not may_use_fifo():
        pytest.skip("this machine gives no real-time scheduling (nothing to keep normal)")
    got = json.loads(ros_python.run(APPLY_DDS, name="apply_dds").stdout)
    sched = {name: tuple(s) for name, s in got["sched"].items()}
    assert got["priority"] == 5, got
    asyn = {n for n in sched if n.startswith("dds.asyn")}
    assert asyn, f"no Fast DDS async writer thread among {sorted(sched)}"
    assert {sched[n] for n in asyn} == {(SCHED_OTHER, 0)}, sched
    others = {n: s for n, s in sched.items() if n not in asyn}
    assert any(n.startswith(("dds.ev", "dds.udp", "dds.shm")) for n in others), sorted(sched)
    assert set(others.values()) == {(SCHED_FIFO, 5)}, sched


def test_refused_leaves_every_thread_normal_and_says_why(ros_python) -> None:  # type: ignore[no-untyped-def]
    needs_setpriv()
    got = json.loads(ros_python.run(DROP_PERMISSION + APPLY, name="apply_refused").stdout)
    assert got["priority"] == 0 and got["threads"] == 0, got
    assert "not permitted" in got["reason"] and "ulimit -r" in got["reason"], got
    assert got["text"].startswith("normal (SCHED_FIFO 5 refused: not permitted"), got
    assert set(map(tuple, got["sched"].values())) == {(SCHED_OTHER, 0)}, got  # never half real-time


def test_priority_out_of_range_is_a_clear_error() -> None:
    assert apply_fifo(0).text == "normal (realtime_priority = 0)"  # changes nothing
    assert set(thread_scheduling().values()) == {(SCHED_OTHER, 0)}  # (this test process: untouched)
    for bad in (-1, MAX_PRIORITY + 1):
        with pytest.raises(ValueError, match=rf"realtime_priority = {bad}: must be 0 \(off\) to {MAX_PRIORITY}"):
            apply_fifo(bad)
        with pytest.raises(ParameterError, match="realtime_priority"):
            REALTIME_PRIORITY.check(bad)


def _answers_and_scheduling(run, n: int = 50) -> dict[str, str]:  # type: ignore[no-untyped-def]
    """Send ``n`` frames, check every one is answered; the node's latest /diagnostics."""
    run.drv.send(encoded(frames(n, 5 * NS)), expected_answers=n)
    assert len(run.drv.sleepers) == n
    return run.drv.latest_diagnostics()


def test_track_node_runs_under_fifo_at_its_priority(ros_python, ros_domain_id) -> None:  # type: ignore[no-untyped-def]
    if not may_use_fifo():
        pytest.skip("no CAP_SYS_NICE nor RLIMIT_RTPRIO here: the refusal is tested below")
    with track_node(ros_python, ros_domain_id, "realtime_priority:=7") as run:
        d = _answers_and_scheduling(run)
        assert d["scheduling"].startswith("SCHED_FIFO 7 ("), d
        sched = thread_scheduling(run.proc.pid)
        names = {tid: Path(f"/proc/{run.proc.pid}/task/{tid}/comm").read_text().strip() for tid in sched}
        normal = {tid for tid, name in names.items() if name.startswith(NORMAL_THREADS)}
        assert normal and {sched[tid] for tid in normal} == {(SCHED_OTHER, 0)}, (names, sched)
        # every other thread, those of DDS and rclpy too
        assert {s for tid, s in sched.items() if tid not in normal} == {(SCHED_FIFO, 7)}, (names, sched)
    assert "scheduling: SCHED_FIFO 7" in run.err


def test_track_node_priority_0_keeps_normal_scheduling(ros_python, ros_domain_id) -> None:  # type: ignore[no-untyped-def]
    with track_node(ros_python, ros_domain_id, "realtime_priority:=0") as run:
        d = _answers_and_scheduling(run)
        assert d["scheduling"] == "normal (realtime_priority = 0)", d
        assert set(thread_scheduling(run.proc.pid).values()) == {(SCHED_OTHER, 0)}


def test_track_node_refused_runs_on_and_says_so(ros_python, ros_domain_id) -> None:  # type: ignore[no-untyped-def]
    needs_setpriv()
    with track_node(ros_python, ros_domain_id, script=DROP_PERMISSION + NODE_SCRIPT) as run:
        assert not may_use_fifo(run.proc.pid)
        d = _answers_and_scheduling(run)  # the default priority, refused: the node answers all the same
        default = REALTIME_PRIORITY.default
        assert d["scheduling"].startswith(f"normal (SCHED_FIFO {default} refused: not permitted"), d
        assert set(thread_scheduling(run.proc.pid).values()) == {(SCHED_OTHER, 0)}
    assert run.err.count("scheduling: normal (SCHED_FIFO") == 1  # said once, as a warning
    assert "[WARN]" in next(line for line in run.err.splitlines() if "scheduling: normal" in line)
