#!/usr/bin/env python3
"""Benchmark: ``clm view`` relaying the demo to a WebSocket client, and the demo's own lag meanwhile.

Each run, in a ROS domain of its own: ``clm view --rate RATE`` as its own
process, a Foxglove WebSocket client (``websockets``, in this process, on a
thread) subscribed to ``/sleeper_response`` (``--all``: to all six channels,
as the shipped layout plus the answers), then the demo as
:func:`clm_ros.launcher.run_demo` runs it (benchmarks/demo_lag.py's approach:
lag = the recorder's reception time of each answer minus its wheel-load
stamp, from ``summary.json``). Alternating with each such run, a baseline run
of the demo without the viewer (``--no-baseline`` skips them).

Relayed fraction: the thinned stream is the first answer of every ``1/RATE``
period of header stamps among the answers the demo's bag holds (all of
them); the fraction is how many of those periods the client received an
answer of. Printed both over the whole run and from the first answer the
client received on (what is left once the relay's reader has discovered the
track node: the demo waits for its own recorder, not for the viewer). Also
the relay's counts (taken, relayed, thinned, dropped). Then the worst run.

Targets (issue 25): >= 99 % of the thinned stream delivered at 100 Hz, the
demo's lag p99 < 10 ms with the viewer. Figures are printed, never asserted.

    .venv/bin/python benchmarks/view_relay.py [--runs 3] [--duration 3] [--rate 100] [--all] [--no-baseline]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
CLM_ROS_SRC = REPO / "ros2_ws" / "src" / "clm_ros"
if str(CLM_ROS_SRC) not in sys.path:
    sys.path.insert(0, str(CLM_ROS_SRC))

from clm_ros.launcher import run_demo  # noqa: E402
from clm_ros.processes import hold_domain_id, ros_env  # noqa: E402
from clm_ros.run_settings import RunSettings  # noqa: E402

TOPIC = "/sleeper_response"
#: What the client offers (the foxglove-sdk server speaks foxglove.sdk.v1; foxglove_bridge foxglove.websocket.v1).
SUBPROTOCOLS: list[Any] = ["foxglove.sdk.v1", "foxglove.websocket.v1"]


class Client(threading.Thread):
    """A Foxglove WebSocket client that subscribes and keeps the header stamp of every message of TOPIC."""

    def __init__(self, port: int, topics: list[str]) -> None:
        super().__init__(daemon=True)
        self.port, self.topics = port, topics
        self.stamps: list[int] = []
        self.other = 0
        self.subscribed = threading.Event()
        self.stop = threading.Event()
        self.last_message = time.monotonic()
        self.error: str | None = None

    def run(self) -> None:
        from websockets.sync.client import connect

        try:
            with connect(f"ws://127.0.0.1:{self.port}", subprotocols=SUBPROTOCOLS,
                         max_size=None) as ws:
                channels: dict[str, int] = {}
                while not set(self.topics) <= set(channels):
                    frame = ws.recv(timeout=30)
                    if isinstance(frame, str) and json.loads(frame).get("op") == "advertise":
                        channels.update({c["topic"]: c["id"] for c in json.loads(frame)["channels"]})
                subs = [{"id": i, "channelId": channels[t]} for i, t in enumerate(self.topics)]
                ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                mine = self.topics.index(TOPIC)
                self.subscribed.set()
                while not self.stop.is_set():
                    try:
                        frame = ws.recv(timeout=0.2)
                    except TimeoutError:
                        continue
                    if isinstance(frame, bytes) and frame[0] == 1:
                        self.last_message = time.monotonic()
                        sub_id = struct.unpack_from("<I", frame, 1)[0]
                        if sub_id == mine:
                            # payload at 13: CDR encapsulation (4 bytes), then header.stamp sec, nanosec
                            sec, nsec = struct.unpack_from("<iI", frame, 17)
                            self.stamps.append(sec * 1_000_000_000 + nsec)
                        else:
                            self.other += 1
        except Exception as exc:  # reported with the run's figures
            self.error = repr(exc)
            self.subscribed.set()


def bag_stamps(bag: Path) -> list[int]:
    """Header stamps [ns] of every /sleeper_response in the demo's bag."""
    from clm_core.io.bags import BagReader

    reader = BagReader(bag)
    out = []
    try:
        for bm in reader.messages():
            if bm.topic == TOPIC:
                sec, nsec = struct.unpack_from("<iI" if bm.data[1] == 1 else ">iI", bm.data, 4)
                out.append(sec * 1_000_000_000 + nsec)
    finally:
        reader.close()
    return out


def with_view(duration: float, out: Path, rate: float, topics: list[str]) -> dict[str, Any]:
    with hold_domain_id() as dom:
        stats = out.parent / f"{out.name}_view.json"
        view = subprocess.Popen(
            [sys.executable, "-m", "clm_core.cli", "view", "--domain", str(dom), "--port", "0", "--rate", str(rate),
             "--log-period", "0", "--stats", str(stats)],
            env=ros_env(dom), stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, text=True)
        try:
            assert view.stdout is not None
            first = view.stdout.readline()
            port = int(first.split("ws://127.0.0.1:")[1].split(" ")[0])
            client = Client(port, topics)
            client.start()
            client.subscribed.wait(60)
            s = run_demo(out, RunSettings(duration=duration, domain_id=dom), hold_domain=False, overwrite=True)
            while time.monotonic() - client.last_message < 1.0:  # what is still on its way
                time.sleep(0.1)
            client.stop.set()
            client.join(10)
        finally:
            view.send_signal(signal.SIGINT)
            view.communicate(timeout=30)
    relay_stats = json.loads(stats.read_text())
    counts = relay_stats["counts"][TOPIC]
    taken = sum(c["received"] for c in relay_stats["counts"].values())
    period = round(1e9 / rate)
    expected = sorted({t // period for t in bag_stamps(Path(s["bag"]))})
    got = {t // period for t in client.stamps}
    first_period = min(got) if got else None
    after = [p for p in expected if first_period is not None and p >= first_period]
    return {
        "lag_median_ms": 1e3 * s["lag_median_s"], "lag_p99_ms": 1e3 * s["lag_p99_s"],
        "lag_max_ms": 1e3 * s["lag_max_s"], "expected": len(expected), "delivered": len(got & set(expected)),
        "fraction_pct": 100.0 * len(got & set(expected)) / max(len(expected), 1),
        "fraction_after_first_pct": 100.0 * len(got & set(after)) / max(len(after), 1),
        "missed_before_first": len(expected) - len(after),
        "relay": counts, "relay_cpu_us_per_taken": 1e6 * relay_stats["cpu_s_watching"] / max(taken, 1),
        "other_channels_messages": client.other, "client_error": client.error,
        "loadavg_1min": os.getloadavg()[0],
    }


def baseline(duration: float, out: Path) -> dict[str, Any]:
    with hold_domain_id() as dom:
        s = run_demo(out, RunSettings(duration=duration, domain_id=dom), hold_domain=False, overwrite=True)
    return {"lag_median_ms": 1e3 * s["lag_median_s"], "lag_p99_ms": 1e3 * s["lag_p99_s"],
            "lag_max_ms": 1e3 * s["lag_max_s"], "loadavg_1min": os.getloadavg()[0]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--duration", type=float, default=3.0, help="simulated seconds per demo run (default 3)")
    ap.add_argument("--rate", type=float, default=100.0, help="clm view --rate [Hz] (default 100)")
    ap.add_argument("--all", action="store_true", help="the client watches all six channels, not only the answers")
    ap.add_argument("--no-baseline", action="store_true", help="no demo runs without the viewer")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    from clm_ros.view import DEFAULT_TOPICS

    topics = list(DEFAULT_TOPICS) if a.all else [TOPIC]
    views: list[dict[str, Any]] = []
    bases: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(a.runs):
            r = with_view(a.duration, Path(tmp) / f"view{i}", a.rate, topics)
            views.append(r)
            c = r["relay"]
            if not a.json:
                print(f"run {i + 1} with clm view: delivered {r['delivered']}/{r['expected']} periods "
                      f"({r['fraction_pct']:.2f} %; from the first on {r['fraction_after_first_pct']:.2f} %, "
                      f"{r['missed_before_first']} before it); relay: {c['received']} taken, {c['relayed']} relayed, "
                      f"{c['thinned']} thinned, {c['dropped']} dropped, CPU "
                      f"{r['relay_cpu_us_per_taken']:.0f} us per message taken; "
                      f"demo lag median {r['lag_median_ms']:.2f} ms p99 {r['lag_p99_ms']:.2f} ms max "
                      f"{r['lag_max_ms']:.2f} ms; load {r['loadavg_1min']:.2f}"
                      + (f"; client error {r['client_error']}" if r["client_error"] else ""), flush=True)
            if not a.no_baseline:
                b = baseline(a.duration, Path(tmp) / f"base{i}")
                bases.append(b)
                if not a.json:
                    print(f"run {i + 1} without: demo lag median {b['lag_median_ms']:.2f} ms p99 {b['lag_p99_ms']:.2f} "
                          f"ms max {b['lag_max_ms']:.2f} ms; load {b['loadavg_1min']:.2f}", flush=True)
    if a.json:
        print(json.dumps({"with_view": views, "baseline": bases, "rate": a.rate, "topics": topics}))
        return 0
    worst_f = min(views, key=lambda r: r["fraction_pct"])
    worst_l = max(views, key=lambda r: r["lag_p99_ms"])
    print(f"{a.runs} runs of {a.duration:g} s at {a.rate:g} Hz, client on {len(topics)} channel(s), "
          f"{os.cpu_count()} cores")
    print(f"worst relayed fraction: {worst_f['fraction_pct']:.2f} % (from the first relayed answer on: "
          f"{min(r['fraction_after_first_pct'] for r in views):.2f} %); dropped by the relay: "
          f"{max(r['relay']['dropped'] for r in views)} at most")
    print(f"demo lag p99 with clm view: worst {worst_l['lag_p99_ms']:.2f} ms, median over runs "
          f"{statistics.median(r['lag_p99_ms'] for r in views):.2f} ms"
          + (f"; without: worst {max(b['lag_p99_ms'] for b in bases):.2f} ms, median "
             f"{statistics.median(b['lag_p99_ms'] for b in bases):.2f} ms" if bases else ""))
    print("targets (issue 25): >= 99 % of the thinned stream delivered, demo lag p99 < 10 ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
