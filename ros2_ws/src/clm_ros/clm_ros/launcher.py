"""The end-to-end demo: vehicle simulator node + track–soil node over DDS, recorded and plotted.

``clm demo`` (the README's main command via ``scripts/demo.sh``):

1. takes the ROS domain ``domain_id`` (``--domain``, default 42 from
   :mod:`clm_core.settings`, held exclusively among the clm runs of this
   machine) with discovery on loopback, so that a user can watch the run
   live with their own tools in that domain;
2. runs one train through the run harness (:mod:`clm_ros.harness`: the demo
   is a one-train fleet): the track–soil node (``clm_ros.track_node``) and
   the vehicle simulator node (``clm_ros.vehicle_node``, one train of
   ``duration``) as separate processes; the vehicle waits for its own track
   node (active, subscribed, matched) and the recorder, then for the
   harness's start signal, so the bag and the figures start with the first
   message;
3. records ``/wheel_loads``, ``/sleeper_response``, ``/wheel_rail_response``,
   the window's markers ``/track_markers`` and ``/diagnostics`` to a rosbag2
   bag (mcap) in the output directory (:class:`clm_ros.bag_tools.BagRecorder`:
   raw subscriptions). The track node also publishes the fixed series of
   sleepers 100, 200 and 300 on ``/monitored_sleepers``, for live views only
   (``config/foxglove_demo.json`` is a Foxglove layout of the demo);
4. when the vehicle's latched status says its train is done and every
   wheel-load message is answered in the bag, stops both nodes (SIGINT; both
   must exit 0) and renders the plots (:func:`clm_core.outputs.plots.plot_demo`:
   sleeper soil forces over time, rail deflection and soil force along the
   track at the moment of the peak soil force, one panel per wheel of the
   wheel loads) to PNG, writes ``summary.json`` and ``index.html`` linking
   them (:func:`clm_core.outputs.report_index.write_index`).

``summary.json`` holds, measured from the first message with nothing
excluded: ``lag_median_s``, ``lag_p99_s``, ``lag_max_s`` (the time the
recorder's middleware received each ``sleeper_response``, its log time in
the bag, minus the stamp of its wheel-load message), ``feedback_used`` and ``feedback_total`` (answers the vehicle used
to close the loop, of the messages it published), the vehicle's own counts
(``vehicle_node``), each process's CPU time per message
(``cpu_us_per_message``), the exit codes, and the peaks; ``status`` (``ok``,
or the train's ``failed``/``timeout``) and ``reason``. An abnormal run still
writes its summary and keeps its bag, then exits with an error.

Users with a full ROS install get the same graph from
``ros2 launch clm_ros demo.launch.py``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from clm_core.errors import ClmError
from clm_core.io.files import write_json
from clm_core.outputs.report_index import write_index
from clm_core.peaks import masked_max, peak_window
from clm_core.progress import Progress
from clm_ros.errors import ClmRosError
from clm_ros.harness import TrainSpec, number, run_trains
from clm_ros.launch_common import DEMO_MONITORED_SLEEPERS, LIVE_VIEWS
from clm_ros.processes import hold_domain_id, ros_env
from clm_ros.run_settings import RunSettings

#: What the demo records: the data topics, the window's markers (10 Hz) and /diagnostics. Not the monitored
#: sleepers: one more 1-kHz topic for the recorder, and their series are in /sleeper_response (live views only).
TOPICS = {
    "/wheel_loads": "clm_msgs/msg/WheelLoads",
    "/sleeper_response": "clm_msgs/msg/SleeperResponse",
    "/wheel_rail_response": "clm_msgs/msg/WheelRailResponse",
    "/track_markers": LIVE_VIEWS["track_markers"],
    "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
}


def run_demo(
    out_dir: str | Path = "results/demo",
    run: RunSettings | None = None,
    *,
    hold_domain: bool = True,
    timeout: float = 300.0,
    overwrite: bool = False,
    ready_timeout: float | None = None,
) -> dict[str, Any]:
    """Run the demo; return the summary (also written to ``out_dir/summary.json``).

    ``run``: what the pair runs (default: the run settings of
    :mod:`clm_core.settings`). Its ``domain_id`` is held exclusively among
    the clm runs of this machine while the demo runs
    (:func:`clm_ros.processes.hold_domain_id`; a caller that holds it already
    passes ``hold_domain=False``). An existing bag in ``out_dir`` is refused
    unless ``overwrite``. A progress bar shows the recorded wheel-load
    messages on a terminal. The demo is a one-train run of the run harness
    (:func:`clm_ros.harness.run_trains`): ``ready_timeout`` bounds the wait
    for the nodes to be ready (default ``timeout``), ``timeout`` the train
    after its start [s].

    Raises
    ------
    ClmRosError
        The domain is in use, a node failed, exited early or did not exit
        cleanly, or the train was not ready or not done in time: the summary
        (``status``, ``reason``) is written and the bag kept first.
    """
    run = RunSettings() if run is None else run
    bag = Path(out_dir) / "demo_bag"
    if bag.exists() and not overwrite:
        raise ClmRosError(f"{bag}: exists; choose another output directory or pass overwrite (--overwrite)")
    if not hold_domain:
        return _run_demo(run.domain_id, Path(out_dir), run, timeout, ready_timeout)
    with hold_domain_id(run.domain_id) as dom:
        return _run_demo(dom, Path(out_dir), run, timeout, ready_timeout)


def _run_demo(dom: int, out: Path, run: RunSettings, timeout: float, ready_timeout: float | None) -> dict[str, Any]:
    spec = TrainSpec(
        "demo", "", {**run.track_parameters(), "monitored_sleepers": DEMO_MONITORED_SLEEPERS},
        # one train, then the vehicle idles until stopped here; it waits for its track node and this recorder
        run.vehicle_parameters(wait_for_subscribers=2), messages=run.messages)
    bar = Progress(run.messages, "clm demo", unit="msg")
    try:
        r = run_trains(out, [spec], domain_id=dom, env=ros_env(dom), topics=TOPICS, bag_name="demo_bag",
                       storage=run.storage, timeout=timeout, ready_timeout=ready_timeout,
                       log_name=lambda _s, kind: kind,
                       progress=bar.update_to)
    finally:
        bar.close()
    train = r.trains[0]
    summary: dict[str, Any] = {"status": "ok" if r.ok else train.state, "reason": r.reasons(),
                               "message_counts": r.message_counts}
    n = r.message_counts.get("/wheel_loads", 0) - train.n0
    cpu = {**train.cpu_us, "recorder": round(1e6 * r.recorder_cpu_s / n, 1) if n > 0 else None, "messages": n}
    summary["cpu_us_per_message"] = cpu if n > 0 else {}
    try:
        summary.update(analyse_bag(out / "demo_bag", out))
    except (ClmRosError, ClmError) as exc:  # an abnormal run: nothing (or no bag) to plot; the summary says why
        summary["reason"] = "; ".join(x for x in (summary["reason"], str(exc)) if x)
        summary["status"] = "failed" if summary["status"] == "ok" else summary["status"]
    v = train.final
    summary.update({
        "feedback_used": int(v.get("train.feedback_used", 0)),
        "feedback_total": int(v.get("train.feedback_total", 0)),
        "vehicle_node": {k.removeprefix("train."): number(x) for k, x in v.items() if k.startswith("train.")},
        "exit_codes": r.exit_codes,
        "supervisor_transport": r.supervisor_transport,
        "scheduling": {"vehicle_node": v.get("scheduling", "unknown"),
                       "track_node": summary.get("track_node_diagnostics", {}).get("scheduling", "unknown")},
        "loadavg": list(os.getloadavg()),
    })
    summary.update({**run.summary(), "bag": str(out / "demo_bag"), "ros_domain_id": dom})
    write_json(out / "summary.json", summary)
    write_index(out, title=f"clm demo: {run.vehicle} at {run.speed:g} m/s on {run.track} / {run.soil} ({run.model})")
    if summary["status"] != "ok":  # the run is recorded (and plotted where it could be); the exit is an error
        raise ClmRosError(f"{summary['reason']}; the summary and the bag are in {out}/")
    return summary


def analyse_bag(bag: str | Path, out: str | Path) -> dict[str, Any]:
    """Read a demo bag back, plot it, and return figures (lags, peaks).

    Of the track node's ``/diagnostics``: ``track_node_diagnostics`` is its last sample (sent after the train,
    so its per-period figures, ``lag_*`` and the like, are ``nan`` with ``answers_in_period`` 0) and
    ``track_node_last_busy_diagnostics`` the last sample of a period with answers (the node's own lag figures
    over that period, [s]); empty when the bag holds none.
    """
    from clm_ros.bag_tools import read_topics

    wheel_t: list[int] = []
    wheel_F: list[np.ndarray] = []
    wheel_x: list[np.ndarray] = []
    recv: dict[int, int] = {}
    s_t: list[int] = []
    s_idx: list[np.ndarray] = []
    s_x: list[np.ndarray] = []
    s_F: list[np.ndarray] = []
    s_w: list[np.ndarray] = []
    diag: dict[str, str] = {}
    got = read_topics(bag, ["/wheel_loads", "/sleeper_response", "/diagnostics"])
    for _, w in got.get("/wheel_loads", []):
        wheel_t.append(w.stamp_ns)
        wheel_F.append(w.forces)
        wheel_x.append(w.positions)
    for log_ns, r in got.get("/sleeper_response", []):
        recv[r.stamp_ns] = log_ns
        s_t.append(r.stamp_ns)
        s_idx.append(r.sleeper_index)
        s_x.append(r.position)
        s_F.append(r.soil_force)
        s_w.append(r.rail_deflection)
    busy: dict[str, str] = {}  # the last sample of a period with answers: its lag figures are numbers
    for _, d in got.get("/diagnostics", []):
        for status in d.status:
            if "track-soil" in status.name:
                diag = {kv.key: kv.value for kv in status.values}
                answers = diag.get("answers_in_period", "0")  # absent while the lags are unavailable
                if answers.isdigit() and int(answers) > 0:
                    busy = diag
    if not s_t:
        raise ClmRosError(f"bag {bag}: no sleeper responses recorded")
    t0 = wheel_t[0]
    # sleeper soil forces over time on a global grid of sleepers
    gmin = min(int(i.min()) for i in s_idx)
    gmax = max(int(i.max()) for i in s_idx)
    grid = np.full((len(s_t), gmax - gmin + 1), np.nan)
    for k, (idx, F) in enumerate(zip(s_idx, s_F)):
        grid[k, idx - gmin] = F
    # reported peaks: over the sleepers the train has passed and the instants after its start (clm_core.peaks)
    wgrid = np.full_like(grid, np.nan)
    xg = np.full(grid.shape[1], np.nan)
    for k, (idx, x, w) in enumerate(zip(s_idx, s_x, s_w)):
        wgrid[k, idx - gmin] = w
        xg[idx - gmin] = x
    spacing = round(float(np.nanmedian(np.diff(xg))), 9) if np.isfinite(np.diff(xg)).any() else 1.0
    window = peak_window(float(np.nanmax(wheel_x[0])), float(np.nanmin(wheel_x[-1])), spacing)
    passed = window.sleepers(xg)
    peak_force, peak_j, fb_force = masked_max(np.nanmax(grid, axis=0), passed)
    max_defl, _, fb_defl = masked_max(np.nanmax(wgrid, axis=0), passed)
    peak_k = int(np.nanargmax(grid[:, peak_j]))
    Fw = np.concatenate(wheel_F) if wheel_F else np.zeros(1)
    nw = max(len(f) for f in wheel_F) if wheel_F else 1
    Wm = np.full((len(wheel_F), nw), np.nan)
    for k, f in enumerate(wheel_F):
        Wm[k, : len(f)] = f
    from clm_core.io.timebase import lag_figures
    from clm_core.outputs.plots import DEMO_FIGURES, plot_demo
    from clm_core.peaks import sleeper_envelope, wheel_load_statistics

    plot_demo(
        out,
        t=(np.array(s_t) - t0) / 1e9,
        soil_force=grid,
        first_sleeper=gmin,
        t_profile=(s_t[peak_k] - t0) / 1e9,
        profile_x=np.asarray(s_x[peak_k], float),
        profile_deflection=np.asarray(s_w[peak_k], float),
        profile_force=np.asarray(s_F[peak_k], float),
        wheel_t=(np.array(wheel_t) - t0) / 1e9,
        wheel_load=Wm,
        static_wheel_load=Wm[0],  # the vehicle's first message: the train at rest on the track (static loads)
        admitted_sleepers=passed,
    )
    front = np.array([np.nanmax(x) if len(x) else np.nan for x in wheel_x])
    admitted = np.repeat(window.instants(front)[:, None], nw, axis=1)
    peak_wheel, _, fb_wheel = masked_max(Wm, admitted)
    t_adm = [t for t, ok in zip(wheel_t, admitted[:, 0]) if ok]
    exclusion = window.describe(np.arange(gmin, gmax + 1), passed,
                                instants_from_s=(t_adm[0] - t0) / 1e9 if t_adm else None,
                                sleepers_fallback=fb_force or fb_defl, instants_fallback=fb_wheel)
    exclusion["applies_to"] = ["peak_sleeper_soil_force_N", "peak_sleeper_global_index", "max_rail_deflection_m",
                               "peak_wheel_load_N"]
    exclusion["whole_run"] = {"peak_sleeper_soil_force_N": float(np.nanmax(grid)),
                              "max_rail_deflection_m": float(max(np.max(w) for w in s_w)),
                              "peak_wheel_load_N": float(Fw.max())}
    return {
        **lag_figures(s_t, received_ns=[recv[t] for t in s_t]).named(),
        "responses": len(s_t),
        "wheel_load_messages": len(wheel_t),
        "peak_sleeper_soil_force_N": peak_force,
        "peak_sleeper_global_index": int(gmin + peak_j),
        "max_rail_deflection_m": max_defl,
        "peak_wheel_load_N": peak_wheel,
        "peak_exclusion": exclusion,
        "rms_wheel_load_N": float(np.sqrt(np.mean(Fw**2))),
        **wheel_load_statistics(Wm, Wm[0], admitted),
        **sleeper_envelope(np.full(len(s_t), gmin), grid).describe(passed),
        "track_node_diagnostics": diag,  # its last sample: after the train, so its period's figures are nan
        "track_node_last_busy_diagnostics": busy,
        "plots": list(DEMO_FIGURES),
    }
