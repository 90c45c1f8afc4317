"""The online input policy against hostile input (issue 12.1-12.3, 12.8): each defect with its regression test.

- integer-nanosecond time: whole steps whatever the magnitude of the stamps;
- absurd positions and forces are refused (no OverflowError, no NaN state);
- a response that is not finite or beyond its bound is never returned, the state is restored exactly;
- no single stamp outlier takes the stream over; a real restart is followed once confirmed;
- refusal messages are bounded.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from clm_core import settings
from clm_core.errors import InputError, ParameterError
from clm_core.io.errors import MessageError
from clm_core.io.timebase import NS
from clm_core.online import InputPolicy, OnlineTrackModel, Reason, Rejected, WheelFrame
from clm_core.params import load_model
from clm_core.solver import TrackSimulator
from tests.online.tools import MS, WALL, answers, same, state, stream


@pytest.fixture(scope="module")
def params():  # type: ignore[no-untyped-def]
    return load_model("mevergnies", "mevergnies", "clm")


def _model(params, **kw):  # type: ignore[no-untyped-def]
    return OnlineTrackModel(params, dt=1e-4, n_sleepers=61, **kw)


# ------------------------------------------------------------------------------------------ time (12.8)


def test_wall_clock_stamps_advance_whole_steps(params) -> None:  # type: ignore[no-untyped-def]
    """1-ms frames at wall-clock stamps are 10 steps each (float seconds gave 9 or 11), and the answers do not
    depend on the magnitude of the stamps."""
    m = _model(params)
    wall = stream(300, t0=WALL)
    steps = []
    for f in wall:
        before = m.stats.steps
        m.process(f)
        steps.append(m.stats.steps - before)
    assert steps == [0] + [10] * 299 and m.stats.simulated_ns == 299 * MS
    assert m.time_ns == wall[-1].stamp_ns
    near = answers(_model(params), stream(300, t0=0))
    for a, b in zip(answers(_model(params), wall), near):
        assert a.stamp_ns - WALL == b.stamp_ns  # type: ignore[union-attr]
        assert same(a, dataclasses.replace(b, stamp_ns=a.stamp_ns))  # type: ignore[type-var]


def test_seconds_are_not_a_stamp() -> None:
    with pytest.raises(TypeError):
        WheelFrame.of(0.001, [0], [1.0], [1.0])  # type: ignore[arg-type]


def test_dt_must_be_whole_nanoseconds(params) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ParameterError, match="whole number of nanoseconds"):
        OnlineTrackModel(params, dt=1.0000005e-4)


# ------------------------------------------------------------------------------------------ bounds (12.1, 12.2)


@pytest.mark.parametrize(
    ("positions", "forces", "reason"),
    [
        ([1e19, 1e19 - 3.0], [85e3, 85e3], Reason.IMPLAUSIBLE_POSITION),  # raised OverflowError in the shift
        ([-1e300, 27.0], [85e3, 85e3], Reason.IMPLAUSIBLE_POSITION),
        ([30.0, 27.0], [1.7e308, 85e3], Reason.IMPLAUSIBLE_FORCE),  # poisoned every later answer with NaN
        ([30.0, 27.0], [1e12, 85e3], Reason.IMPLAUSIBLE_FORCE),  # deflections of kilometres
        ([30.0, 27.0], [np.inf, 85e3], Reason.NON_FINITE),
        ([30.0, np.nan], [85e3, 85e3], Reason.NON_FINITE),
        ([30.0, 27.0], [-1e3, 85e3], Reason.TENSILE),
    ],
)
def test_absurd_values_refused_and_the_stream_flows_on(params, positions, forces, reason) -> None:  # type: ignore[no-untyped-def]
    clean = stream(60)
    bad = WheelFrame.of(clean[29].stamp_ns + MS // 2, [0, 1], positions, forces)
    m = _model(params)
    got = answers(m, clean[:30])
    before = state(m)
    with pytest.raises(Rejected) as exc:
        m.process(bad)
    assert exc.value.reason is reason and state(m) == before
    got += answers(m, clean[30:])
    ref = answers(_model(params), clean)
    assert all(same(a, b) for a, b in zip(got, ref))
    assert all(np.all(np.isfinite(r.soil_force)) for r in got)  # type: ignore[union-attr]
    assert dict(m.stats.rejected) == {reason.value: 1} and m.stats.accepted == 60


def test_one_rule_enum_for_the_kernel_and_the_policy() -> None:
    """Each value rule, broken alone, comes out of the compiled check as its :class:`FrameRule` code and out of
    the policy as that rule's refusal (``REASONS``); every rule but NONE has one, and no two share one."""
    from clm_core.online.policy import REASONS, RULES, check_frame
    from clm_core.solver import FrameRule
    from clm_core.solver import check_frame as kernel_check_frame

    assert set(REASONS) == set(FrameRule) - {FrameRule.NONE} and len(set(REASONS.values())) == len(REASONS)
    assert RULES == tuple(REASONS.get(r) for r in sorted(FrameRule))
    lim = InputPolicy(max_wheel_force=1e6, max_wheel_position=1e4, max_wheel_speed=200.0).limits(20.0)
    ok = (np.array([0.0, 3.0]), np.array([8e4, 8e4]), np.array([50.0, 50.0]))
    broken = {
        FrameRule.NON_FINITE: (np.array([0.0, np.nan]), ok[1], ok[2]),
        FrameRule.TENSILE: (ok[0], np.array([8e4, -1e3]), ok[2]),
        FrameRule.FORCE: (ok[0], np.array([8e4, 2e6]), ok[2]),
        FrameRule.POSITION: (np.array([0.0, 2e4]), ok[1], ok[2]),
        FrameRule.SPEED: (ok[0], ok[1], np.array([50.0, 300.0])),
        FrameRule.SPAN: (np.array([0.0, 30.0]), ok[1], ok[2]),
    }
    assert kernel_check_frame(*ok, lim)[0] == FrameRule.NONE and check_frame(*ok, lim)[0] is None
    for rule, frame in broken.items():
        assert FrameRule(kernel_check_frame(*frame, lim)[0]) is rule
        assert check_frame(*frame, lim)[0] is REASONS[rule]


def test_speeds_bounded_nan_unknown(params) -> None:  # type: ignore[no-untyped-def]
    m = _model(params)
    f = stream(2)
    m.process(WheelFrame.of(f[0].stamp_ns, [0, 1], f[0].positions, f[0].forces, [np.nan, 30.0]))
    with pytest.raises(Rejected, match="implausible_speed"):
        m.process(WheelFrame.of(f[1].stamp_ns, [0, 1], f[1].positions, f[1].forces, [30.0, 1e5]))
    with pytest.raises(Rejected, match="non_finite"):
        m.process(WheelFrame.of(f[1].stamp_ns, [0, 1], f[1].positions, f[1].forces, [-np.inf, 30.0]))


def test_the_simulator_refuses_positions_beyond_the_line() -> None:
    """The window shift itself refuses what would overflow the sleeper indices (was an OverflowError)."""
    sim = TrackSimulator(load_model("mevergnies", "mevergnies", "clm"), 1e-4, 21)
    sim.initialize([0.0], [1e5])
    with pytest.raises(InputError, match="beyond the line's range"):
        sim.advance(1e-3, ([1e19], [1e5]))
    assert sim.t == 0.0


def test_bounds_are_settings_with_one_default(params) -> None:  # type: ignore[no-untyped-def]
    pol = InputPolicy()
    for name in settings.ONLINE_POLICY:
        assert getattr(pol, name) == settings.setting(name).default
    assert InputPolicy.from_settings({"max_wheel_force": 5e5, "dt": 1e-4}).max_wheel_force == 5e5
    with pytest.raises(ParameterError, match="max_wheel_force = 0"):
        InputPolicy(max_wheel_force=0.0)
    with pytest.raises(ParameterError, match="resync_confirm = 1"):
        InputPolicy(resync_confirm=1)
    m = _model(params, policy=InputPolicy(max_wheel_force=9e4))
    f = stream(1)[0]
    with pytest.raises(Rejected, match="implausible_force"):
        m.process(WheelFrame.of(f.stamp_ns, [0, 1], f.positions, [9.5e4, 8e4]))


def test_too_many_wheels(params) -> None:  # type: ignore[no-untyped-def]
    m = _model(params, accept_new_wheels=True, policy=InputPolicy(max_wheels=3))
    f = stream(3)
    m.process(f[0])
    with pytest.raises(Rejected, match="too_many_wheels"):
        m.process(WheelFrame.of(f[1].stamp_ns, [0, 1, 2, 3], [30.0, 29.0, 28.0, 27.0], [1e4] * 4))
    with pytest.raises(Rejected, match="too_many_wheels"):  # two new ids: the set would hold 4
        m.process(WheelFrame.of(f[1].stamp_ns, [0, 7, 8], [30.0, 29.0, 28.0], [1e4] * 3))
    m.process(WheelFrame.of(f[1].stamp_ns, [0, 7], [30.03, 29.0], [1e4] * 2))
    assert m._slot_ids == [0, 1, 7]


# ------------------------------------------------------------------------------------------ the response (12.2)


def test_response_beyond_its_bound_refused_state_restored(params) -> None:  # type: ignore[no-untyped-def]
    """A frame whose response breaks the bound is refused and the state put back exactly, also part-way through a
    batch and after window shifts (the restore then runs the frames before it again)."""
    pol = InputPolicy(max_response_displacement=2e-3)  # 85 kN on 2 wheels deflects the rail up to 1.2 mm
    frames = stream(120, v=80.0, force=85e3)  # shifts every ~7 frames
    heavy = {40, 41, 77}  # (three in a row would re-synchronise: below)
    frames = [WheelFrame.of(f.stamp_ns, f.ids, f.positions, f.forces * (6.0 if k in heavy else 1.0))
              for k, f in enumerate(frames)]
    m = _model(params, policy=pol)
    single: list = []
    for k, f in enumerate(frames):
        before = state(m)
        try:
            single.append(m.process(f))
        except Rejected as exc:
            assert exc.reason is Reason.IMPLAUSIBLE_RESPONSE and k in heavy
            assert state(m) == before
            single.append(exc)
    refused = {k for k, r in enumerate(single) if isinstance(r, Rejected)}
    assert refused <= heavy and {40, 77} <= refused  # (a heavy frame right after an accepted one may still pass)
    ref = answers(_model(params, policy=pol), [f for k, f in enumerate(frames) if k not in refused])
    assert all(same(a, b) for a, b in zip([r for r in single if not isinstance(r, Rejected)], ref))
    mb = _model(params, policy=pol)
    batch = mb.process_batch(frames)
    assert all(same(a, b) for a, b in zip(batch, single)) and state(mb) == state(m)


def test_a_state_gone_bad_does_not_blind(params) -> None:  # type: ignore[no-untyped-def]
    """A frame accepted near the response bound (its response still rising) makes the next ones exceed it: after
    resync_confirm refused responses in a row, the last of them restarts the state, and the stream flows on."""
    pol = InputPolicy(max_response_displacement=3e-3)
    frames = stream(30)
    frames[10] = WheelFrame.of(frames[10].stamp_ns, [0, 1], frames[10].positions, [6.8e5, 7.1e5])
    m = _model(params, policy=pol)
    got = answers(m, frames)
    kinds = [r.reason if isinstance(r, Rejected) else "resync" if r.resynced else None for r in got]
    assert kinds[10] is None and kinds[11:14] == [Reason.IMPLAUSIBLE_RESPONSE] * 2 + ["resync"], kinds
    assert "frame 2 of the 3 that confirm a new stream" in str(got[12])
    assert all(k is None for k in kinds[14:]) and m.stats.resyncs == 2
    assert all(same(a, b) for a, b in zip(got[13:], answers(_model(params, policy=pol), frames[13:])))


def test_non_finite_response_never_returned_state_restored(params) -> None:  # type: ignore[no-untyped-def]
    """The kernel's own check: a state that went non-finite (here: put there by hand) gives no answer."""
    m = _model(params)
    frames = stream(10)
    answers(m, frames[:5])
    m.sim._s.u[7] = np.inf
    before = state(m)
    with pytest.raises(Rejected, match="implausible_response: the response is not finite"):
        m.process(frames[5])
    assert state(m) == before and m.sim._s.u[7] == np.inf


def test_wheels_entering_while_others_jump_hold_their_values(params) -> None:  # type: ignore[no-untyped-def]
    """A wheel entering where another lands after a 30 m jump: interpolated, they would span more than the window
    holds part-way, and every later frame (interpolated from this one) would be refused. The frame's values hold
    over its interval instead, and the stream flows on."""
    m = _model(params, accept_new_wheels=True)
    m.process(WheelFrame.of(0, [0], [30.0], [85e3]))
    m.process(WheelFrame.of(MS, [0], [30.03], [85e3]))
    r = m.process(WheelFrame.of(2 * MS, [0, 1], [60.0, 60.5], [85e3, 85e3]))
    assert np.array_equal(m.sim._s.pos[:2], [60.0, 60.5]) and r.wheel_deflection.shape == (2,)
    after = answers(m, [WheelFrame.of(2 * MS + k * MS, [0, 1], [60.0 + 0.03 * k, 60.5 + 0.03 * k], [85e3, 85e3])
                        for k in range(1, 20)])
    assert not any(isinstance(x, Rejected) for x in after) and m.stats.rejected_total == 0


# ------------------------------------------------------------------------------------------ stamps (12.3)

def _with(frames: list[WheelFrame], k: int, outlier: WheelFrame | list[WheelFrame]) -> list[WheelFrame]:
    extra = outlier if isinstance(outlier, list) else [outlier]
    return frames[:k] + extra + frames[k:]


def _at(f: WheelFrame, stamp: int) -> WheelFrame:
    return WheelFrame(stamp, f.ids, f.positions, f.forces)


@pytest.mark.parametrize(
    ("shift", "reason"),
    [
        (3 * 10**17, Reason.STAMP_JUMP),  # 9.5 years ahead
        (5 * 10**9, Reason.STAMP_JUMP),  # 5 s ahead (max_gap 1 s)
        (-(10**15), Reason.STAMP_NOT_INCREASING),  # far in the past
        (-MS - MS // 2, Reason.STAMP_NOT_INCREASING),  # a little late
        (-MS, Reason.STAMP_NOT_INCREASING),  # the last stamp again
        (10**19 * 5, Reason.MALFORMED),  # beyond builtin_interfaces/Time
    ],
)
def test_a_single_stamp_outlier_does_not_take_the_stream(params, shift, reason) -> None:  # type: ignore[no-untyped-def]
    clean = stream(80, t0=WALL)
    outlier = _at(clean[39], clean[39].stamp_ns + MS + shift)  # at the next stamp, shifted
    m = _model(params)
    got = answers(m, _with(clean, 40, outlier))
    assert isinstance(got[40], Rejected) and got[40].reason is reason
    ref = answers(_model(params), clean)
    assert all(same(a, b) for a, b in zip(got[:40] + got[41:], ref))
    assert m.stats.accepted == 80 and m.stats.resyncs == 1 and dict(m.stats.rejected) == {reason.value: 1}


def test_two_outliers_on_one_timeline_still_refused(params) -> None:  # type: ignore[no-untyped-def]
    clean = stream(60, t0=WALL)
    far = [_at(clean[0], clean[29].stamp_ns + 100 * 10**9 + k * MS) for k in range(2)]  # confirm needs 3
    m = _model(params)
    got = answers(m, _with(clean, 30, far))
    assert [r.reason for r in got[30:32]] == [Reason.STAMP_JUMP] * 2  # type: ignore[union-attr]
    assert all(same(a, b) for a, b in zip(got[:30] + got[32:], answers(_model(params), clean)))


def test_header_nanosec_overflow_is_malformed(params) -> None:  # type: ignore[no-untyped-def]
    """A header with nanosec >= 1e9 is refused at the edge, in the message and in its CDR bytes (the node's path),
    before the model sees it: the model's state is untouched. (The node counts it as ``rejected.malformed``: over
    DDS in tests/ros/test_track_node_robust.py.)"""
    from clm_core.io.messages import typestore, wheel_loads_msg
    from clm_core.online import frame_from_cdr, frame_from_msg

    ts = typestore()
    msg = wheel_loads_msg(ts, WALL, [0, 1], [30.0, 27.0], [85e3, 85e3])
    m = _model(params)
    m.process(frame_from_cdr(ts.serialize_cdr(msg, "clm_msgs/msg/WheelLoads")))
    before = state(m)
    msg.header.stamp.nanosec = 1_500_000_000
    with pytest.raises(MessageError, match="nanosec"):
        frame_from_msg(msg)
    with pytest.raises(MessageError, match="nanosec"):
        frame_from_cdr(ts.serialize_cdr(msg, "clm_msgs/msg/WheelLoads"))
    assert state(m) == before and m.stats.accepted == 1 and m.stats.rejected_total == 0


@pytest.mark.parametrize("jump", [-(WALL // 2), 50 * 10**9])  # a restart from an earlier time; a clock jump ahead
def test_a_restart_of_the_stream_is_followed_once_confirmed(params, jump) -> None:  # type: ignore[no-untyped-def]
    old = stream(50, t0=WALL)
    new = stream(40, t0=old[-1].stamp_ns + jump, x0=500.0)
    m = _model(params)
    got = answers(m, old + new)
    why = Reason.STAMP_JUMP if jump > 0 else Reason.STAMP_NOT_INCREASING
    assert [getattr(r, "reason", None) for r in got[50:53]] == [why, why, None] and got[52].resynced  # type: ignore[union-attr]
    assert m.stats.resyncs == 2 and m.stats.accepted == 88
    # from the confirming frame on, the state is that of a fresh model started there
    ref = answers(_model(params), new[2:])
    assert all(same(a, b) for a, b in zip(got[52:], ref))


def test_the_first_frame_as_an_outlier_is_left_behind(params) -> None:  # type: ignore[no-untyped-def]
    clean = stream(40, t0=WALL)
    m = _model(params)
    got = answers(m, [_at(clean[0], WALL + 10 ** 17), *clean])
    assert got[0].resynced and [getattr(r, "reason", None) for r in got[1:4]] == [  # type: ignore[union-attr]
        Reason.STAMP_NOT_INCREASING, Reason.STAMP_NOT_INCREASING, None]
    assert got[3].resynced and all(same(a, b) for a, b in zip(got[3:], answers(_model(params), clean[2:])))  # type: ignore[union-attr]


def test_a_first_frame_of_foreign_wheels_is_left_behind(params) -> None:  # type: ignore[no-untyped-def]
    """The wheel set comes from the first frame; a stream of other wheels takes over only once confirmed."""
    clean = stream(30, t0=WALL)
    m = _model(params)
    got = answers(m, [WheelFrame.of(WALL - MS, [7, 8], [30.0, 27.0], [80000.0, 80000.0]), *clean])
    assert [getattr(r, "reason", None) for r in got[1:4]] == [Reason.UNKNOWN_ID, Reason.UNKNOWN_ID, None]
    assert "frame 2 of the 3 that confirm a new stream" in str(got[2]) and got[3].resynced  # type: ignore[union-attr]
    assert m._slot_ids == [0, 1] and all(same(a, b) for a, b in zip(got[3:], answers(_model(params), clean[2:])))
    # the foreign wheels now are the strangers: one frame of them changes nothing
    before = state(m)
    with pytest.raises(Rejected, match="unknown_id"):
        m.process(WheelFrame.of(clean[-1].stamp_ns + MS, [7, 8], [31.0, 28.0], [8e4, 8e4]))
    assert state(m) == before


def test_second_publisher_on_the_same_clock_is_not_told_apart_by_stamps(params) -> None:  # type: ignore[no-untyped-def]
    """A second publisher on the SAME clock (another vehicle, 100 m further, stamps interleaved): every stamp
    continues the timeline, so the stamp rules cannot tell the two apart and the model alone would take them as one
    stream (issue 26.2). The edge separates sources by publisher (the track node, by the writer's GID: over DDS in
    tests/ros/test_track_node_sources.py); with the second source's frames refused there, the answers are bit for
    bit those of the first stream alone."""
    first = stream(60, t0=WALL)
    second = stream(60, t0=WALL + MS // 2, x0=130.0)
    mixed = [f for pair in zip(first, second) for f in pair]
    merged = answers(_model(params), mixed)
    assert not any(isinstance(r, Rejected) for r in merged)  # the stamps alone let the second source in
    alone = answers(_model(params), first)
    assert not all(same(a, b) for a, b in zip(merged[0::2], alone))  # ... and it corrupts the first one's answers
    separated = answers(_model(params), [f for k, f in enumerate(mixed) if k % 2 == 0])
    assert all(same(a, b) for a, b in zip(separated, alone))


def test_interleaved_timelines_never_confirm(params) -> None:  # type: ignore[no-untyped-def]
    """A second publisher on another clock, interleaved with the stream: refused every time, the stream flows."""
    clean = stream(60, t0=WALL)
    other = stream(60, t0=10**12)
    mixed = [f for pair in zip(clean, other) for f in pair]
    m = _model(params)
    got = answers(m, mixed)
    assert all(isinstance(r, Rejected) for r in got[1::2]) and not any(isinstance(r, Rejected) for r in got[0::2])
    assert m.stats.accepted == 60 and m.stats.resyncs == 1 and m.stats.rejected_total == 60
    assert all(same(a, b) for a, b in zip(got[0::2], answers(_model(params), clean)))


def test_resync_confirm_is_respected(params) -> None:  # type: ignore[no-untyped-def]
    old = stream(20, t0=WALL)
    new = stream(10, t0=0)
    m = _model(params, policy=InputPolicy(resync_confirm=5))
    got = answers(m, old + new)
    assert [isinstance(r, Rejected) for r in got[20:26]] == [True] * 4 + [False, False] and got[24].resynced  # type: ignore[union-attr]


# ------------------------------------------------------------------------------------------ messages (12.8)


def test_refusal_messages_are_bounded(params) -> None:  # type: ignore[no-untyped-def]
    m = _model(params, policy=InputPolicy(max_wheels=2000))
    m.process(stream(1)[0])
    ids = np.arange(10, 1006)
    with pytest.raises(Rejected) as exc:
        m.process(WheelFrame.of(MS, ids, np.full(ids.size, 30.0), np.full(ids.size, 1e3)))
    text = str(exc.value)
    assert exc.value.reason is Reason.UNKNOWN_ID and len(text) < 300 and "(988 more)" in text, text
    r = m.reject(Reason.MALFORMED, "x" * 5000)
    assert len(str(r)) <= 320 and "chars cut" in str(r)


def test_malformed_frames(params) -> None:  # type: ignore[no-untyped-def]
    m = _model(params)
    f = stream(1)[0]
    bad = [
        WheelFrame(1.5, f.ids, f.positions, f.forces),  # type: ignore[arg-type]
        WheelFrame(0, f.ids, f.positions.reshape(2, 1), f.forces),
        WheelFrame(0, np.array(["a", "b"]), f.positions, f.forces),  # type: ignore[arg-type]
        WheelFrame(0, f.ids, f.positions, f.forces[:1]),
    ]
    got = m.process_batch(bad)
    assert [r.reason for r in got] == [Reason.MALFORMED] * 3 + [Reason.SIZE_MISMATCH]  # type: ignore[union-attr]
    assert m.stats.accepted == 0 and m.stats.rejected_total == 4 and not math.isnan(m.dt)


def test_catch_up_work_per_message_is_bounded(params) -> None:  # type: ignore[no-untyped-def]
    """A frame within max_gap but more than MAX_CATCH_UP_NS ahead re-synchronises instead of integrating the gap
    step by step (issue 26.10: 1 s ahead was 10 000 steps, ~195 ms of CPU); a shorter gap is integrated."""
    from clm_core.online.policy import MAX_CATCH_UP_NS

    clean = stream(30, t0=WALL)
    m = _model(params)
    answers(m, clean)
    last = clean[-1]
    near = _at(last, last.stamp_ns + MAX_CATCH_UP_NS // 2)
    steps = m.stats.steps
    r = m.process(near)
    assert not r.resynced and m.stats.steps - steps == MAX_CATCH_UP_NS // 2 // m.dt_ns
    far = _at(last, near.stamp_ns + NS)  # 1 s ahead: within max_gap (1 s)
    steps, resyncs = m.stats.steps, m.stats.resyncs
    r = m.process(far)
    assert r.resynced and m.stats.resyncs == resyncs + 1 and m.stats.steps - steps <= MAX_CATCH_UP_NS // m.dt_ns
    # the state restarted there: the answers from it on are those of a fresh model started at that frame
    after = [_at(far, far.stamp_ns + k * MS) for k in range(1, 20)]
    got = answers(m, after)
    ref = answers(_model(params), [far, *after])[1:]
    assert all(same(a, b) for a, b in zip(got, ref))
    # beyond max_gap it is still a jump (refused until confirmed)
    with pytest.raises(Rejected, match="stamp_jump"):
        m.process(_at(far, after[-1].stamp_ns + NS + MS))
