"""``clm fleet`` over real DDS on loopback: N vehicle + track node pairs, each in its namespace, in one domain.

- two pairs started as a second host would start them (``first_index`` 3: /train_3, /train_4): distinct
  namespaces, every pair's wheel-load messages answered once and in order (in = out, in the bag and by the
  vehicle's own counts), its answers equal bit for bit to the offline replay of its recorded wheel loads, every
  node exits 0 on SIGINT, and the overall figures are the worst of the per-train ones;
- the same with each pair's two nodes in one process (``pair_process``);
- a node killed with SIGKILL in the middle of its train ends only its own train (``failed``, with the reason):
  the other train finishes, correct; the bag and a summary with every train's status survive; exit 1;
- bad arguments give a clear error before anything starts;
- the launch file (``ros2 launch clm_ros fleet.launch.py``) makes the same pairs (run against stand-ins of
  launch/launch_ros, as tests/ros/test_packaging.py does).

No figure of speed is asserted (a shared 2-core machine): benchmarks/fleet_capacity.py gives them.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

pytest.importorskip("clm_msgs.msg", reason="clm_msgs not built: bash scripts/setup_ros.sh VENV")

from tests.clitools import CLM, run_clm, wait_or_stacks

DURATION = 0.3
N_MSG = round(DURATION * 1000) + 1


def test_fleet_two_pairs_correct_and_summarised(tmp_path: Path, ros_domain_id: int) -> None:
    from clm_ros.fleet import PAIR_TOPICS, run_fleet
    from clm_ros.run_settings import RunSettings

    from clm_core import settings
    from clm_core.io.bags import BagReader

    out = tmp_path / "fleet"
    s = run_fleet(out, RunSettings(duration=DURATION, domain_id=ros_domain_id), trains=2, first_index=3,
                  hold_domain=False, timeout=240, progress=False, record_sleepers=True)
    assert s["recorded_topics"] == ["wheel_loads", "wheel_rail_response", "sleeper_response"]
    assert json.loads((out / "summary.json").read_text()) == json.loads(json.dumps(s))
    seed = settings.SEED.default
    assert set(s["trains"]) == {"train_3", "train_4"} and s["seeds"] == [seed + 3, seed + 4]
    assert s["ros_domain_id"] == ros_domain_id
    # one bag, every pair's topics in its own namespace
    with BagReader(out / "fleet_bag") as reader:
        counts = {t: info.message_count for t, info in reader.topics.items()}
    for ns in ("/train_3", "/train_4"):
        for t in PAIR_TOPICS:
            assert counts[f"{ns}/{t}"] == N_MSG, (ns, t)
    assert s["message_counts"] == counts
    for name, t in s["trains"].items():
        assert t["namespace"] == f"/{name}"
        # in = out, once each, in order (stamps), by the recorder and by the vehicle
        assert t["messages_in"] == t["messages_out"] == t["wheel_rail_responses"] == t["sleeper_responses"] == N_MSG
        assert t["in_equals_out"]
        v = t["vehicle_node"]
        assert v["published"] == v["answered"] == t["feedback_total"] == N_MSG
        assert t["feedback_used"] == v["feedback_used"] <= N_MSG
        assert v["feedback_used"] + v["too_late"] + v["after_last_step"] == N_MSG
        # equal to offline replay of the recorded wheel loads, bit for bit (as the demo bag and bag round trip)
        assert t["offline_equal"] and t["offline_max_abs_diff"] == 0.0
        assert t["offline_accepted"] == N_MSG and t["offline_compared"] == 2 * N_MSG
        assert 0 < t["lag_median_s"] <= t["lag_p99_s"] <= t["lag_max_s"] < 60
        assert t["lag_median_s"] == t["vehicle_lag_median_s"]  # the data path's lag, as the vehicle measured it
        assert 0 < t["recorder_lag_median_s"] <= t["recorder_lag_p99_s"] <= t["recorder_lag_max_s"] < 60
        assert 0 < t["vehicle_lag_median_s"] <= t["vehicle_lag_p99_s"] <= t["vehicle_lag_max_s"] < 60
        assert t["exit_codes"] == {"vehicle_node": 0, "track_node": 0} and t["correct"]
        assert set(t["cpu_us_per_message"]) == {"track_node", "vehicle_node"}
    assert s["exit_codes"] == {f"/train_{i}/{k}": 0 for i in (3, 4) for k in ("vehicle_node", "track_node")}
    o = s["overall"]
    trains = s["trains"].values()
    assert o["trains"] == 2 and o["all_correct"] and o["all_in_equals_out"] and o["all_offline_equal"]
    assert o["messages_in"] == o["messages_out"] == 2 * N_MSG
    for key in ("lag_median_s", "lag_p99_s", "lag_max_s"):
        assert o[f"worst_{key}"] == max(t[key] for t in trains)
    assert o["lowest_feedback_fraction"] == min(t["feedback_used"] / t["feedback_total"] for t in trains)
    assert {p.name for p in out.glob("*.log")} == {f"train_{i}_{k}.log" for i in (3, 4)
                                                   for k in ("vehicle_node", "track_node")}


def test_fleet_pair_process_same_answers(tmp_path: Path, ros_domain_id: int) -> None:
    """``pair_process``: the pair's two nodes in one process (clm_ros.fleet_pair); the same topics and checks."""
    from clm_ros.fleet import run_fleet
    from clm_ros.run_settings import RunSettings

    from clm_core.io.bags import BagReader

    s = run_fleet(tmp_path / "f", RunSettings(duration=DURATION, domain_id=ros_domain_id), trains=1,
                  hold_domain=False, timeout=240, progress=False, pair_process=True)
    t = s["trains"]["train_0"]
    assert s["pair_process"] and s["exit_codes"] == {"/train_0/pair": 0} and t["exit_codes"] == {"pair": 0}
    assert t["messages_in"] == t["messages_out"] == t["feedback_total"] == N_MSG and t["in_equals_out"]
    # by default the bag holds the wheel loads and the answers that close the loop (not the sleeper responses),
    # recorded in the pair's own process to a bag of its own (no transport, no supervisor's recorder to send to)
    assert s["recorded_topics"] == ["wheel_loads", "wheel_rail_response"] and "sleeper_responses" not in t
    assert s["recorded_in"] == "pair processes" and s["train_bags"] == {"train_0": str(tmp_path / "f" / "train_0_bag")}
    with BagReader(tmp_path / "f" / "train_0_bag") as reader:
        assert {k: i.message_count for k, i in reader.topics.items()} == {
            "/train_0/wheel_loads": N_MSG, "/train_0/wheel_rail_response": N_MSG}
    assert t["offline_equal"] and t["offline_compared"] == N_MSG and t["correct"]
    assert set(t["cpu_us_per_message"]) == {"pair"}


def _children(pid: int) -> dict[int, str]:
    """{pid: command line} of the children of process ``pid``."""
    out = {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
            if ppid == pid:
                out[int(d.name)] = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except (OSError, IndexError, ValueError):
            continue
    return out


def test_fleet_node_killed_keeps_the_others_bag_and_summary(tmp_path: Path, ros_domain_id: int,
                                                             ros_env: dict[str, str]) -> None:
    """Issue 26.6: kill -9 of one train's track node in the middle of its train."""
    from clm_core.io.bags import BagReader

    out = tmp_path / "fleet"
    duration = 4.0
    n_msg = round(duration * 1000) + 1
    # the test holds the domain (fixture); the fleet joins it (--join-domain)
    proc = subprocess.Popen([*CLM, "fleet", "--trains", "2", "--duration", str(duration), "--domain",
                             str(ros_domain_id), "--join-domain", "--out", str(out)], env=ros_env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        log = out / "train_1_vehicle_node.log"
        deadline = time.monotonic() + 240
        while not (log.exists() and "train 1 starts" in log.read_text()):
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.1)
        time.sleep(0.5)  # in the middle of its train
        victims = [p for p, cmd in _children(proc.pid).items() if "clm_ros.track_node" in cmd and "/train_1" in cmd]
        assert len(victims) == 1, _children(proc.pid)
        os.kill(victims[0], signal.SIGKILL)
        stdout, stderr = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 1, (stdout, stderr)
    assert "train_1: failed: track node exited with code -9 during its train" in stderr, stderr
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "failed" and s["supervisor_transport"] == "UDP on loopback"
    dead, alive = s["trains"]["train_1"], s["trains"]["train_0"]
    assert dead["status"] == "failed" and "exited with code -9" in dead["reason"] and not dead["correct"]
    assert dead["exit_codes"]["track_node"] == -signal.SIGKILL
    assert alive["status"] == "ok" and alive["reason"] == "" and alive["correct"]
    assert alive["messages_in"] == alive["messages_out"] == n_msg and alive["offline_equal"]
    assert s["overall"]["status"] == {"train_0": "ok", "train_1": "failed"}
    # the bag survives, with the healthy train complete and what the dead one recorded until it died
    with BagReader(out / "fleet_bag") as reader:
        counts = {t: info.message_count for t, info in reader.topics.items()}
    assert counts["/train_0/wheel_loads"] == counts["/train_0/wheel_rail_response"] == n_msg
    assert 0 < counts["/train_1/wheel_rail_response"] < n_msg


def test_fleet_recorder_far_behind_loses_nothing(tmp_path: Path, ros_domain_id: int, ros_env: dict[str, str]) -> None:
    """Issue 21: a recorder starved for longer than the nodes' default writer history (5000 messages, 5 s at 1 kHz)
    still records every message of the train: the fleet's writers keep the whole train for it (a 5-train fleet
    lost the first of 5001 wheel loads and its answers, and its offline replay differed). The supervisor (recorder
    and all) is stopped with SIGSTOP for 6.5 s from the start of a 6-s train.

    Its participant is on UDP bound to loopback (``supervisor_transport``): on Fast DDS shared memory the nodes
    re-made the stopped supervisor's port under the same name, it received nothing after SIGCONT and the run
    waited for the end of train until its timeout (2 of 36 runs on 2026-12-04). The run's own timeout (120 s)
    is within the test's wait, so a stalled run ends with its summary and reason, not a kill."""
    from clm_core.io.bags import BagReader

    out = tmp_path / "fleet"
    duration = 6.0
    n_msg = round(duration * 1000) + 1
    # two processes per pair: the supervisor records (with --pair-process each pair records in its own process)
    proc = subprocess.Popen([*CLM, "fleet", "--trains", "1", "--duration", str(duration), "--timeout", "120",
                             "--domain", str(ros_domain_id), "--join-domain", "--out", str(out)], env=ros_env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        log = out / "train_0_vehicle_node.log"
        deadline = time.monotonic() + 240
        while not (log.exists() and "train 1 starts" in log.read_text()):
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.05)
        proc.send_signal(signal.SIGSTOP)
        try:
            time.sleep(6.5)
        finally:
            proc.send_signal(signal.SIGCONT)
        stdout, stderr = wait_or_stacks(proc, 300, "clm fleet after SIGCONT")  # past its own timeout: hung
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, (stdout, stderr)
    s = json.loads((out / "summary.json").read_text())
    assert s["supervisor_transport"] == "UDP on loopback"
    t = s["trains"]["train_0"]
    assert t["messages_in"] == t["messages_out"] == t["wheel_rail_responses"] == n_msg and t["offline_equal"]
    # the recorder was seconds behind (its lag says so), the data path was not stopped
    assert t["recorder_lag_max_s"] > 1.0 and t["lag_median_s"] == t["vehicle_lag_median_s"]
    with BagReader(out / "fleet_bag") as reader:
        counts = {k: info.message_count for k, info in reader.topics.items()}
    assert all(counts[f"/train_0/{k}"] == n_msg for k in ("wheel_loads", "wheel_rail_response"))


@pytest.mark.parametrize(("args", "message"), [
    (["--trains", "0"], "--trains = 0: must be 1 to 100"),
    (["--duration", "-1"], "--duration = -1: must be 0.001 to 3600 s"),
    (["--first-index", "-2"], "--first-index = -2: must be 0 to 10000"),
    (["--discovery-range", "MOON"], "--discovery-range: invalid choice: 'MOON'"),
])
def test_fleet_bad_arguments(tmp_path: Path, args: list[str], message: str) -> None:
    proc = run_clm(["fleet", "--out", str(tmp_path / "f"), *args], timeout=120)
    assert proc.returncode == 2 and message in proc.stderr, proc.stderr
    assert not (tmp_path / "f").exists()


def test_fleet_bad_arguments_in_python(tmp_path: Path) -> None:
    from clm_ros.errors import ClmRosError
    from clm_ros.fleet import run_fleet
    from clm_ros.run_settings import RunSettings

    from clm_core.errors import ParameterError

    for kw, message in (({"trains": 0}, "trains = 0: must be 1 to 100"),
                        ({"first_index": -1}, "first_index = -1: must be 0 to 10000"),
                        ({"record": False}, "verify needs the recorded wheel loads"),
                        ({"discovery_range": "LAN"}, "discovery_range = 'LAN': one of LOCALHOST, SUBNET")):
        with pytest.raises(ClmRosError, match=message):
            run_fleet(tmp_path / "f", **kw)  # type: ignore[arg-type]
    with pytest.raises(ParameterError, match="duration = -0.5: must be 0.001 to 3600 s"):
        run_fleet(tmp_path / "f", RunSettings(duration=-0.5))
    assert not (tmp_path / "f").exists()


def test_fleet_is_a_clm_command() -> None:
    proc = run_clm(["fleet", "--help"], timeout=60)
    assert proc.returncode == 0
    text = " ".join(proc.stdout.split())
    assert "--trains" in text and "--first-index" in text and "namespace /train_i" in text


def test_fleet_launch_file(monkeypatch: pytest.MonkeyPatch) -> None:
    from test_packaging import COMMON, LAUNCH, _arguments, _launch, _params, _run

    entities = _launch(LAUNCH / "fleet.launch.py", monkeypatch)
    own = {"trains", "first_index", "vehicle", "speed", "duration", "seed", "runs"}
    assert COMMON | own <= set(_arguments(entities))
    actions = _run(entities)
    nodes = [a for a in actions if a.kind == "Node"]
    assert [(n.kwargs["executable"], n.kwargs["namespace"]) for n in nodes] == [
        ("track_node", "/train_0"), ("track_node", "/train_1"), ("vehicle_node", "/train_0"),
        ("vehicle_node", "/train_1")]
    assert _params(nodes[2])[1] == {"use_sim_time": False, "trains": 1, "exit_when_done": True,
                                    "wait_for_subscribers": 1, "publish_clock": False}
    assert len([a for a in actions if a.kind == "RegisterEventHandler"]) == 2
    # a second host's pairs, under a prefix, with seeds
    actions = _run(entities, trains="3", first_index="2", namespace="line1", seed="10", duration="2.0")
    vehicles = [a for a in actions if a.kind == "Node" and a.kwargs["executable"] == "vehicle_node"]
    assert [v.kwargs["namespace"] for v in vehicles] == ["/line1/train_2", "/line1/train_3", "/line1/train_4"]
    assert [_params(v)[1]["seed"] for v in vehicles] == [12, 13, 14]
    assert all(_params(v)[1]["duration"] == 2.0 for v in vehicles)
