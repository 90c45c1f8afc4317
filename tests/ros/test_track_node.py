"""The track-soil node in its own process over real DDS (loopback, own domain).

- its responses equal what clm_core computes offline for the same input, bit for bit;
- message counts in = out; bad input is rejected, counted per cause in
  /diagnostics, logged once per cause, and the node keeps its state;
- invalid or unstable parameters are refused at configure time and on runtime updates.
"""

from __future__ import annotations

import math
import signal

import numpy as np
import pytest

pytest.importorskip("clm_msgs.msg", reason="clm_msgs not built: bash scripts/setup_ros.sh VENV")

from clm_ros.conversions import rclpy_wheel_loads
from driver import Driver, status_dict

from clm_core.io.timebase import NS
from clm_core.online import OnlineTrackModel, Rejected, WheelFrame
from clm_core.params import load_model

NODE = "import sys\nfrom clm_ros.track_node import main\nsys.exit(main(sys.argv))\n"

OFF = np.array([0.0, 3.0])


def _stream(n: int, v: float = 30.0, t0_ns: int = 5 * NS, x0: float = 30.0) -> list[tuple[int, np.ndarray, np.ndarray]]:
    return [(t0_ns + k * 10**6, x0 - OFF + v * k * 1e-3, np.array([85e3, 85e3])) for k in range(n)]


def _msgs(stream):  # type: ignore[no-untyped-def]
    return [rclpy_wheel_loads(t, [0, 1], p, f) for t, p, f in stream]


def _offline(stream, **kw):  # type: ignore[no-untyped-def]
    m = OnlineTrackModel(load_model("mevergnies", "mevergnies", "clm"), dt=1e-4, n_sleepers=61, **kw)
    out = []
    for t, p, f in stream:
        try:
            out.append(m.process(WheelFrame.of(t, np.arange(len(p)) if len(p) == 2 else [0, 1], p, f)))
        except Rejected:
            pass
    return out, m


@pytest.fixture
def node_and_driver(ros_python, ros_domain_id):  # type: ignore[no-untyped-def]
    proc = ros_python.spawn(NODE, ["--ros-args", "-p", "diagnostics_period:=0.2"], name="track_node")
    drv = Driver(ros_domain_id)
    try:
        drv.wait_discovery()
        yield proc, drv
    finally:
        drv.close()


def test_node_equals_offline_bit_for_bit(node_and_driver) -> None:  # type: ignore[no-untyped-def]
    proc, drv = node_and_driver
    stream = _stream(400)
    drv.send(_msgs(stream), expected_answers=400)
    assert len(drv.sleepers) == 400 and len(drv.wheels) == 400  # in = out
    offline, _ = _offline(stream)
    for got, ref in zip(drv.sleepers, offline):
        assert got.stamp_ns == ref.stamp_ns
        np.testing.assert_array_equal(np.asarray(got.soil_force), ref.soil_force)
        np.testing.assert_array_equal(np.asarray(got.rail_deflection), ref.rail_deflection)
        np.testing.assert_array_equal(np.asarray(got.sleeper_index), ref.sleeper_index)
    for got, ref in zip(drv.wheels, offline):
        np.testing.assert_array_equal(np.asarray(got.rail_deflection), ref.wheel_deflection)
        np.testing.assert_array_equal(np.asarray(got.rail_velocity), ref.wheel_velocity)
    # physics sanity: 85 kN per wheel, the soil under the track carries it
    assert 0.2 * 85e3 < max(drv.sleepers[-1].soil_force) < 85e3
    d = drv.latest_diagnostics()
    assert d["accepted"] == "400" and d["rejected"] == "0" and d["published"] == "400"


def test_sigusr1_prints_every_threads_stack_and_the_node_goes_on(node_and_driver) -> None:  # type: ignore[no-untyped-def]
    """``kill -USR1`` (clm_core.stacks, run_node): the stacks on stderr, the node serves on and exits 0 on SIGTERM."""
    proc, drv = node_and_driver
    stream = _stream(200)
    drv.send(_msgs(stream[:100]), expected_answers=100)
    proc.send_signal(signal.SIGUSR1)
    drv.send(_msgs(stream[100:]), expected_answers=100)  # served on after the dump
    assert len(drv.sleepers) == 200
    proc.terminate()
    _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert "most recent call first" in err and "node_main.py" in err, err  # the main thread's stack, in run_node
    assert err.count("Thread 0x") + err.count("Current thread 0x") >= 2, err  # every thread, not just one


def test_bad_input_rejected_counted_logged_once(node_and_driver) -> None:  # type: ignore[no-untyped-def]
    proc, drv = node_and_driver
    good = _stream(300)
    seq: list[tuple[int, list[int], list[float], list[float]]] = [(t, [0, 1], list(p), list(f)) for t, p, f in good]
    t_bad = good[100][0]
    bad = [
        (t_bad + 1000, [0, 1], [1.0, 2.0], [math.nan, 1.0]),  # NaN force -> non_finite
        (t_bad + 2000, [0, 1], [math.inf, 2.0], [1.0, 1.0]),  # infinite position -> non_finite
        (t_bad + 3000, [0, 1], list(good[100][1]), [-5e3, 1.0]),  # tensile
        (t_bad + 4000, [0, 1], list(good[100][1]), [-6e3, 1.0]),  # tensile again: logged once
        (t_bad + 5000, [0, 0], list(good[100][1]), [1.0, 1.0]),  # duplicate id
        (t_bad + 6000, [0, 7], list(good[100][1]), [1.0, 1.0]),  # unknown id
        (t_bad - 10**6, [0, 1], list(good[100][1]), [1.0, 1.0]),  # stamp going backwards
        (t_bad + 7000, [0, 1], [0.0, 500.0], [1.0, 1.0]),  # wheels outside the window
    ]
    full = seq[:101] + bad + seq[101:]
    msgs = [rclpy_wheel_loads(t, ids, p, f) for t, ids, p, f in full]
    drv.send(msgs, expected_answers=300)
    assert len(drv.sleepers) == 300  # every accepted input answered, nothing else
    # state intact: the good stream's answers equal the offline run of the same sequence
    m = OnlineTrackModel(load_model("mevergnies", "mevergnies", "clm"), dt=1e-4, n_sleepers=61)
    ref = []
    for t, ids, p, f in full:
        try:
            ref.append(m.process(WheelFrame.of(t, ids, p, f)))
        except Rejected:
            pass
    assert len(ref) == 300
    np.testing.assert_array_equal(np.asarray(drv.sleepers[-1].soil_force), ref[-1].soil_force)
    clean, _ = _offline(good)
    np.testing.assert_array_equal(np.asarray(drv.sleepers[-1].soil_force), clean[-1].soil_force)
    d = drv.latest_diagnostics()
    assert d["rejected.non_finite"] == "2" and d["rejected.tensile"] == "2"
    assert d["rejected.duplicate_id"] == "1" and d["rejected.unknown_id"] == "1"
    assert d["rejected.stamp_not_increasing"] == "1" and d["rejected.outside_window"] == "1"
    assert d["accepted"] == "300" and d["rejected"] == "8" and d["received"] == "308"
    # the period with the rejections said so (WARN)
    warned = [status_dict(m) for _, m in drv.diagnostics if status_dict(m)["_level"] == "1"]
    assert any("rejected" in w["_message"] for w in warned), [status_dict(m)["_message"] for _, m in drv.diagnostics]
    # a jump far ahead re-synchronises once confirmed by the frames after it (resync_confirm = 3; handled, answered)
    drv.send([rclpy_wheel_loads(good[-1][0] + 50 * NS + k * 10**6, [0, 1], [1000.0, 997.0], [85e3, 85e3])
              for k in range(3)], expected_answers=1)
    assert drv.latest_diagnostics()["resyncs"] == "2"
    proc.terminate()
    _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert err.count("rejected (tensile") == 1 and err.count("rejected (non_finite") == 1, err


@pytest.mark.parametrize(
    ("args", "reason"),
    [
        (["-p", "soil.dc:=-400000.0"], "not positive semi-definite"),
        (["-p", "soil:=clay"], "unknown soil preset 'clay'"),
        (["-p", "track.kb:=-5.0"], "track.kb = -5"),
    ],
)
def test_invalid_parameters_refused_at_configure(ros_python, args, reason) -> None:  # type: ignore[no-untyped-def]
    proc = ros_python.spawn(NODE, ["--ros-args", *args], name="track_node_bad")
    out, err = ros_python.wait(proc, 60)
    assert proc.returncode == 2
    assert "configure refused" in err and reason in err, err


def test_parameter_file_and_runtime_updates(ros_python, ros_domain_id, tmp_path) -> None:  # type: ignore[no-untyped-def]
    from clm_core.params import ModelParams, save_params_file

    p = load_model("mevergnies", "haren", "clm")
    p = ModelParams.from_dict({**p.to_dict(), "overrides": [{"sleepers": [55], "kb": 4.7e6}]})
    f = tmp_path / "p.yaml"
    save_params_file(p, f)
    proc = ros_python.spawn(NODE, ["--ros-args", "-p", f"params_file:={f}"], name="track_node_file")
    drv = Driver(ros_domain_id)
    try:
        drv.wait_discovery()
        stream = _stream(50)
        drv.send(_msgs(stream), expected_answers=50)
        m = OnlineTrackModel(p, dt=1e-4, n_sleepers=61)
        for t, pos, fz in stream:
            ref = m.process(WheelFrame.of(t, [0, 1], pos, fz))
        np.testing.assert_array_equal(np.asarray(drv.sleepers[-1].soil_force), ref.soil_force)
        # runtime update through the parameter service: unstable refused with its reason, valid accepted
        r = drv.set_double("soil.dc", -400e3)
        assert not r.successful and "not positive semi-definite" in r.reason
        r = drv.set_double("track.kb", 60e6)
        assert r.successful, r.reason
        # the counters survive the update (monotonic for the node's life)
        assert drv.latest_diagnostics()["accepted"] == "50"
        drv.send(_msgs(_stream(20, t0_ns=20 * NS)), expected_answers=20)
        d = drv.latest_diagnostics()
        assert d["accepted"] == "70" and d["published"] == "70" and d["resyncs"] == "2"
    finally:
        drv.close()
    proc.terminate()
    ros_python.wait(proc, 20)
