"""The run harness of ``clm demo`` and ``clm fleet`` (clm_ros.harness): abnormal ends and how many ran at once.

- an abnormal demo (its train not done within the run's timeout) still
  writes ``summary.json`` with the train's status and reason, keeps (and
  plots) the bag, and raises with that reason (no hang, no traceback);
- a train that is never ready ends ``failed`` after the bounded readiness
  wait, saying what its vehicle last said;
- the trains of a fleet start together: the summary says how many ran at
  once (and a schedule, ``stagger``, spreads the starts);
- the overlap count of the summary (``max_running_at_once``) from the trains'
  start and end times.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

pytest.importorskip("clm_msgs.msg", reason="clm_msgs not built: bash scripts/setup_ros.sh VENV")

from clm_ros.harness import Train, TrainSpec, _concurrency


def test_abnormal_demo_writes_summary_and_keeps_the_bag(tmp_path: Path, ros_domain_id: int) -> None:
    from clm_ros.errors import ClmRosError
    from clm_ros.launcher import run_demo
    from clm_ros.run_settings import RunSettings

    out = tmp_path / "demo"
    # a train of 2 s and a run timeout of 0.5 s after its start: the train ends "timeout", mid-way
    with pytest.raises(ClmRosError, match=r"demo: timeout: not done 0.5 s after its start \(vehicle: train 1: running"):
        run_demo(out, RunSettings(duration=2.0, domain_id=ros_domain_id), hold_domain=False, timeout=0.5,
                 ready_timeout=300)
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "timeout" and s["reason"].startswith("demo: timeout: not done 0.5 s after its start")
    assert s["exit_codes"] == {"vehicle_node": 0, "track_node": 0}  # stopped cleanly all the same
    # the bag is closed and kept with what was recorded until then, and plotted
    from clm_core.io.bags import BagReader

    with BagReader(out / "demo_bag") as reader:
        n = reader.topics["/wheel_loads"].message_count
    assert 0 < n < 2001 and s["message_counts"]["/wheel_loads"] == n
    assert (out / "sleeper_soil_forces.png").exists() and (out / "index.html").exists()


def test_train_never_ready_fails_after_the_bounded_wait(tmp_path: Path, ros_domain_id: int) -> None:
    from clm_ros.harness import run_trains
    from clm_ros.processes import ros_env
    from clm_ros.run_settings import RunSettings

    run = RunSettings(duration=0.2)
    # the vehicle waits for a track node that does not exist under that name: never ready
    spec = TrainSpec("lonely", "/lonely", run.track_parameters(),
                     {**run.vehicle_parameters(wait_for_subscribers=1), "track_node": "no_such_track_node"})
    r = run_trains(tmp_path, [spec], domain_id=ros_domain_id, env=ros_env(ros_domain_id), topics=None,
                   bag_name="bag", storage="mcap", timeout=60, ready_timeout=60)
    t = r.trains[0]
    assert t.state == "failed" and not r.ok
    assert t.reason.startswith("not ready after 60 s (vehicle: train 1: waiting for no_such_track_node")
    assert r.exit_codes == {"/lonely/vehicle_node": 0, "/lonely/track_node": 0}  # stopped cleanly
    assert r.concurrency["started_together"] == 0 and r.concurrency["max_running_at_once"] == 0


def test_fleet_trains_start_together_or_on_a_schedule(tmp_path: Path, ros_domain_id: int) -> None:
    from clm_ros.fleet import run_fleet
    from clm_ros.run_settings import RunSettings

    run = RunSettings(duration=0.5, domain_id=ros_domain_id)
    s = run_fleet(tmp_path / "together", run, trains=3, hold_domain=False, record=False, verify=False,
                  progress=False, pair_process=True)
    o = s["overall"]
    assert s["status"] == "ok" and o["started_together"] == 3 and o["max_running_at_once"] == 3
    assert o["start_spread_s"] < 0.25  # one start time for all (each vehicle polls its start every 10 ms)
    s = run_fleet(tmp_path / "staggered", run, trains=2, hold_domain=False, record=False, verify=False,
                  progress=False, pair_process=True, stagger=1.0)
    o = s["overall"]
    assert s["status"] == "ok" and s["stagger_s"] == 1.0 and o["max_running_at_once"] == 1
    assert 0.9 < o["start_spread_s"] < 1.5


def test_concurrency_is_the_largest_overlap() -> None:
    def train(start: float, end: float) -> Train:
        t = Train(TrainSpec("t", "/t", {}, {}))
        t.status = {"train.start_ns": str(int((10 + start) * 1e9)), "train.end_ns": str(int((10 + end) * 1e9))}
        return t

    c = _concurrency([train(0, 5), train(1, 4), train(3, 6), train(5.5, 7)])  # 3 at once from 3 to 4 s
    assert c["max_running_at_once"] == 3 and c["start_spread_s"] == pytest.approx(5.5)
    assert _concurrency([train(0, 1), train(1, 2)])["max_running_at_once"] == 1  # one ends as the next starts
    assert _concurrency([]) == {"max_running_at_once": 0, "start_spread_s": None}
