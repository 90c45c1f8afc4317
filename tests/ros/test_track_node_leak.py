"""Memory of the track node over lifecycle cycles that activate it (issue 26, item 8).

``gc.freeze()`` in ``on_activate`` moved every object alive then, the model
of that configuration included, out of the collector's reach for good: each
configure / activate / deactivate / cleanup cycle left its model's reference
cycles behind (~200 kB a cycle, 212 -> 243 MB over 150 cycles). The node
process is cycled through the ``change_state`` service, as ``ros2 lifecycle
set`` does it, and its resident memory read from ``/proc`` after a first
batch of cycles (the process's own caches filled) and after the next batch.
"""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("clm_msgs.msg", reason="clm_msgs not built: bash scripts/setup_ros.sh VENV")

from driver import track_node
from streams import encoded, frames

from clm_core.io.timebase import NS

#: Cycles before the first reading (caches of the process filled) and between the two readings.
WARM_CYCLES, CYCLES = 10, 60
#: Growth allowed over CYCLES cycles [kB]: 1/3 of what the frozen models alone added (~200 kB a cycle).
MAX_GROWTH_KB = CYCLES * 200 // 3


def rss_kb(pid: int) -> int:
    """Resident memory of process ``pid`` [kB]."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise AssertionError(f"no VmRSS for process {pid}")


def test_activate_cycles_keep_memory_bounded(ros_python, ros_domain_id) -> None:  # type: ignore[no-untyped-def]
    msgs = encoded(frames(40, 5 * NS))
    with track_node(ros_python, ros_domain_id, "autostart:=false", discover=False) as run:
        drv = run.drv

        def cycle(k: int) -> None:
            assert drv.transition("configure") and drv.transition("activate"), k
            assert drv.state() == "active"
            assert drv.transition("deactivate") and drv.transition("cleanup"), k

        assert drv.transition("configure") and drv.transition("activate")
        drv.wait_discovery()
        drv.send(msgs, expected_answers=len(msgs))  # the active node answers (a model with state)
        assert drv.transition("deactivate") and drv.transition("cleanup")
        for k in range(WARM_CYCLES):
            cycle(k)
        before = rss_kb(run.proc.pid)
        for k in range(CYCLES):
            cycle(k)
        after = rss_kb(run.proc.pid)
        print(f"track node resident memory over {CYCLES} activate cycles: {before} -> {after} kB "
              f"({(after - before) / CYCLES:+.1f} kB a cycle)")
        assert after - before < MAX_GROWTH_KB, (before, after)
