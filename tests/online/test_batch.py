"""process_batch is process frame by frame, bit for bit, for any split of a stream (issue 10.1).

The track node takes every waiting message in one call, offline replay
reads a bag in chunks: both must give what the frames give one by one, so
that the node equals the replay however the messages were batched. Streams
with refusals of every kind, window shifts, wheels entering and leaving,
re-synchronisations and refused responses (restored part-way through a
batch) are split at random.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from clm_core.online import InputPolicy, OnlineTrackModel, Rejected, WheelFrame
from clm_core.params import ModelParams, load_model
from tests.online.tools import MS, WALL, answers, same, state, stream

PARAMS: ModelParams = load_model("mevergnies", "mevergnies", "clm")


def _hostile(f: WheelFrame, kind: str, k: int) -> WheelFrame:
    """Frame ``f`` spoilt in one way (``kind``)."""
    ids, P, F = f.ids, f.positions.copy(), f.forces.copy()
    if kind == "nan":
        F[0] = np.nan
    elif kind == "huge":
        F[-1] = 1.7e308
    elif kind == "heavy":  # refused by the response bound of the tight policy
        F *= 8.0
    elif kind == "far":
        P[0] = 1e19
    elif kind == "back":
        return WheelFrame(f.stamp_ns - 3 * MS, ids, P, F)
    elif kind == "jump":
        return WheelFrame(f.stamp_ns + 7 * 10**9 + k * MS, ids, P, F)
    elif kind == "new":  # a wheel entering ahead
        return WheelFrame.of(f.stamp_ns, [*ids.tolist(), 9], [*P.tolist(), P[0] + 2.0], [*F.tolist(), 5e4])
    elif kind == "leave":  # the rear wheel has left
        return WheelFrame(f.stamp_ns, ids[:1], P[:1], F[:1])
    elif kind == "dup":
        return WheelFrame(f.stamp_ns, np.zeros_like(ids), P, F)
    elif kind == "sizes":
        return WheelFrame(f.stamp_ns, ids, P[:1], F)
    elif kind == "foreign":  # other wheels (unknown ids unless new wheels are accepted)
        return WheelFrame(f.stamp_ns, ids + 7, P, F)
    return WheelFrame(f.stamp_ns, ids, P, F)


KINDS = ("nan", "huge", "heavy", "far", "back", "jump", "new", "leave", "dup", "sizes", "foreign")


@st.composite
def scenarios(draw: st.DrawFn) -> tuple[list[WheelFrame], list[int], dict[str, object]]:
    n = draw(st.integers(20, 90))
    period = draw(st.sampled_from([MS, MS // 2, 3 * MS // 7]))
    v = draw(st.sampled_from([0.0, 30.0, 83.33, -40.0]))
    frames = stream(n, t0=draw(st.sampled_from([0, WALL])), period=period, v=v)
    spoil = draw(st.dictionaries(st.integers(1, n - 1), st.sampled_from(KINDS), max_size=n // 3))
    frames = [_hostile(f, spoil[k], k) if k in spoil else f for k, f in enumerate(frames)]
    if draw(st.booleans()):  # a restart of the stream (confirmed after three frames)
        frames += stream(draw(st.integers(3, 12)), t0=frames[-1].stamp_ns - 40 * MS, x0=80.0)
    cuts = sorted(draw(st.lists(st.integers(1, len(frames) - 1), max_size=8, unique=True)))
    kw: dict[str, object] = {"accept_new_wheels": draw(st.booleans())}
    if draw(st.booleans()):
        kw["policy"] = InputPolicy(max_response_displacement=3e-3)
    return frames, cuts, kw


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(scenarios())
def test_batches_equal_frame_by_frame(sc: tuple[list[WheelFrame], list[int], dict[str, object]]) -> None:
    frames, cuts, kw = sc
    one = OnlineTrackModel(PARAMS, dt=1e-4, n_sleepers=41, **kw)  # type: ignore[arg-type]
    single = answers(one, frames)
    many = OnlineTrackModel(PARAMS, dt=1e-4, n_sleepers=41, **kw)  # type: ignore[arg-type]
    batched: list[object] = []
    for a, b in zip([0, *cuts], [*cuts, len(frames)]):
        batched += many.process_batch(frames[a:b])
    assert len(batched) == len(single)
    for k, (x, y) in enumerate(zip(batched, single)):
        assert same(x, y), (k, x, y)  # type: ignore[arg-type]
    assert state(many) == state(one) and many.stats == one.stats


def test_a_backlog_in_one_call_equals_the_stream() -> None:
    """A backlog larger than a run of the kernel (RUN_FRAMES) in one call."""
    frames = stream(700, t0=WALL, v=83.33)
    one = OnlineTrackModel(PARAMS)
    many = OnlineTrackModel(PARAMS)
    got = many.process_batch(frames)
    assert all(same(a, b) for a, b in zip(got, answers(one, frames)))
    assert many.stats.accepted == 700 and many.stats.steps == 6990 and not any(isinstance(r, Rejected) for r in got)


@pytest.mark.parametrize("chunk", [1, 7, 256])
def test_counters_carry_over_to_a_rebuilt_model(chunk: int) -> None:
    """A rebuilt model (parameter update) continues the counters: monotonic over a node's life."""
    frames = stream(40)
    m = OnlineTrackModel(PARAMS)
    for a in range(0, 20, chunk):
        m.process_batch(frames[a:min(a + chunk, 20)])
    m.process_batch([_hostile(frames[20], "nan", 20)])
    before = (m.stats.accepted, m.stats.rejected_total, m.stats.steps)
    rebuilt = OnlineTrackModel(load_model("mevergnies", "haren", "clm"), stats=m.stats)
    rebuilt.process_batch(frames[21:])
    assert rebuilt.stats is m.stats and rebuilt.stats.accepted == before[0] + 19
    assert rebuilt.stats.rejected_total == before[1] == 1 and rebuilt.stats.steps > before[2]
    assert rebuilt.stats.resyncs == 2  # the new model starts its state at its first frame
