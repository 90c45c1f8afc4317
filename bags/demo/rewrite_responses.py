"""Recompute the responses of the demo bag with the current track model, keeping everything else.

The wheel loads, the diagnostics, every log time and every topic's QoS stay
as recorded; each ``/sleeper_response`` and ``/wheel_rail_response`` is
replaced by what the track node computes today for the wheel loads it
answers (``OnlineTrackModel.process``, 61 sleepers, dt = 1e-4 s, frame
``track``), so that "offline replay gives the recorded responses" holds
again after a change of the model's arithmetic. Used once so far: the
integer-nanosecond time base (issue 12.8) made every 1-ms frame 10 steps
where float seconds had given 9 or 11 steps for 96 of the 1000 frames.

    .venv/bin/python bags/demo/rewrite_responses.py        # rewrites bags/demo/demo_bag in place
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

from clm_core.io import messages as msgs
from clm_core.io.bags import BagReader, BagWriter
from clm_core.online import OnlineTrackModel, Rejected, frame_from_cdr
from clm_core.params import load_model

BAG = Path(__file__).resolve().parent / "demo_bag"


def main() -> int:
    model = OnlineTrackModel(load_model("mevergnies", "mevergnies", "clm"), dt=1e-4, n_sleepers=61)
    tmp = BAG.parent / ".rewrite"
    new = tmp / BAG.name  # the storage file is named after its directory
    answers: dict[int, tuple[bytes, bytes]] = {}
    with BagReader(BAG) as r:
        for m in r.messages(["/wheel_loads"]):
            res = model.process_batch([frame_from_cdr(m.data)])[0]
            if isinstance(res, Rejected):
                raise SystemExit(f"wheel loads at {m.log_ns} refused: {res}")
            answers[res.stamp_ns] = (
                msgs.encode_sleeper_response(res.stamp_ns, "track", *msgs.sleeper_fields(res).values()),
                msgs.encode_wheel_rail_response(res.stamp_ns, "track", *msgs.wheel_fields(res).values()),
            )
        with BagWriter(new, r.storage) as w:
            conns = {name: w.add_topic(name, info.msgtype, qos=list(info.qos)) for name, info in r.topics.items()}
            for m in r.messages():
                data = m.data
                if m.topic == "/sleeper_response":
                    data = answers[msgs.decode_sleeper_response(m.data).stamp_ns][0]
                elif m.topic == "/wheel_rail_response":
                    data = answers[msgs.decode_wheel_rail_response(m.data).stamp_ns][1]
                w.write(conns[m.topic], m.log_ns, data)
    shutil.rmtree(BAG)
    new.rename(BAG)
    tmp.rmdir()
    print(f"{BAG}: {len(answers)} sleeper and wheel-rail responses recomputed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
