"""The vehicle node's plain-Python parts without a middleware (clm_ros.vehicle_schedule, clm_ros.vehicle_counts).

- :class:`TrainSchedule`: trains per activation, headway and pause, numbering over activations;
- :class:`AnswerWatch`: silence counted only while messages are outstanding, from the oldest one sent since the
  last answer; a vehicle that stood still (nothing sent, or everything answered) blames no one; an answer ends it;
- :func:`build_plan` / :class:`TrainRun`: the timetable of a run, its messages decoded back to the vehicle's loads,
  answers fed back in closed loop and counted (stale, after the end, unmatched, malformed);
- :class:`Counts`: lag figures through clm_core.io.timebase.lag_figures, sums, the report line.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from clm_core.io.messages import decode_wheel_loads, encode_wheel_rail_response
from clm_core.io.timebase import NS, lag_figures

pytest.importorskip("clm_ros.vehicle_schedule", reason="clm_ros not installed")

from clm_ros.parameters import lookup
from clm_ros.vehicle_counts import Counts, diagnostics_values
from clm_ros.vehicle_schedule import AnswerWatch, TrainRun, TrainSchedule, build_plan

MS = 1_000_000


def run_settings(**over: object) -> dict[str, object]:
    names = ("vehicle", "cars", "speed", "duration", "rate", "dt", "start", "irregularity", "seed",
             "wavelength_band", "track", "soil", "model", "params_file", "max_feedback_delay")
    values = {n: lookup(n).default for n in names}
    values.update(duration=0.05, irregularity="none")
    values.update(over)
    return values


# ------------------------------------------------------------------ TrainSchedule

def test_schedule_counts_trains_per_activation() -> None:
    s = TrainSchedule(trains=2, headway_ns=0, pause_ns=0)
    s.activate(0)
    assert s.first_of_activation() and not s.complete()
    assert s.begin(0) == 1 and not s.first_of_activation()
    s.finish(5)
    assert s.begin(5) == 2
    s.finish(9)
    assert s.complete() and s.trains_done == 2
    s.activate(20)  # a new activation: two more, numbered on
    assert not s.complete() and s.first_of_activation() and s.begin(20) == 3


def test_schedule_headway_and_pause() -> None:
    s = TrainSchedule(trains=0, headway_ns=100, pause_ns=30)
    s.activate(0)
    s.begin(0)
    s.finish(50)  # a short train: the headway decides
    assert s.next_start == 100
    s.begin(100)
    s.finish(190)  # a long one: the pause after its end decides
    assert s.next_start == 220
    assert not s.complete()  # trains = 0: no end


def test_schedule_refuses_negative_values() -> None:
    with pytest.raises(ValueError, match="must be >= 0"):
        TrainSchedule(trains=-1, headway_ns=0, pause_ns=0)


# ------------------------------------------------------------------ AnswerWatch

def test_silence_needs_an_outstanding_message() -> None:
    w = AnswerWatch(timeout_ns=100 * MS)
    assert not w.silence_began(10 * NS)  # nothing sent: no silence, however long
    w.sent(1, 0, 0, 0)
    assert w.answer(1, 1 * MS) == (0, 0)
    assert not w.silence_began(10 * NS)  # everything answered, then the vehicle stood still: no silence


def test_silence_counted_from_the_send_not_the_due_time() -> None:
    """A vehicle stopped for 5 s catches up: its messages are sent long after they were due; the watch counts from
    the send (a stopped vehicle must not blame the track node)."""
    w = AnswerWatch(timeout_ns=500 * MS)
    w.sent(1, 0, 0, 0)
    w.answer(1, 1 * MS)
    t = 5 * NS  # the process resumes
    for k in range(2, 10):
        w.sent(k, k, k * MS, t)  # due 5 s ago, sent now
    assert not w.silence_began(t + 100 * MS)
    assert w.silence_began(t + 600 * MS)  # and still, a track node that does not answer them is reported
    assert w.silent and not w.silence_began(t + 700 * MS)  # once


def test_silence_counted_from_the_vehicle_s_resume() -> None:
    """The vehicle stopped with messages outstanding (their answers wait, untaken, in its own middleware); on resuming
    it sends its late messages: silence counts from the resume, not from the messages sent before the stop."""
    w = AnswerWatch(timeout_ns=500 * MS)
    for k in range(5):
        w.sent(k, k, k * MS, k * MS)  # sent on time, then the process stops at 5 ms
    t = 3 * NS  # resumed
    w.sent(5, 5, 5 * MS, t)  # late by ~3 s: the vehicle stood still
    assert not w.silence_began(t + 1 * MS)  # before: 3 s of 'silence' blamed on the track node at once
    w.sent(6, 6, 6 * MS, t + 2 * MS)
    assert not w.silence_began(t + 400 * MS)
    assert w.silence_began(t + 600 * MS)  # no answer for the timeout after the resume: reported


def test_silence_ends_with_an_answer_and_counts_again_from_there() -> None:
    w = AnswerWatch(timeout_ns=100 * MS)
    w.sent(1, 0, 0, 0)
    w.sent(2, 1, 1 * MS, 1 * MS)
    assert w.silence_began(200 * MS)
    assert w.answer(2, 210 * MS) == (1, 1 * MS) and not w.silent
    # message 1 stays unanswered (lost): silence counts from the last answer, not from it
    assert not w.silence_began(250 * MS)
    assert w.silence_began(320 * MS)


def test_lost_message_does_not_make_a_talking_track_node_silent() -> None:
    w = AnswerWatch(timeout_ns=100 * MS)
    w.sent(0, 0, 0, 0)  # never answered
    for k in range(1, 1000):
        w.sent(k, k, k * MS, k * MS)
        w.answer(k, k * MS + 300_000)
        assert not w.silence_began(k * MS + 400_000)


def test_old_messages_forgotten() -> None:
    w = AnswerWatch(timeout_ns=NS, forget_ns=10 * NS)
    w.sent(1, 0, 0, 0)
    w.silence_began(11 * NS)
    assert not w.outstanding and w.answer(1, 11 * NS) is None


# ------------------------------------------------------------------ plan and train

def test_plan_timetable() -> None:
    plan = build_plan(run_settings(rate=1000.0, dt=1e-4, duration=0.05))
    assert (plan.substeps, plan.period_ns, plan.n_messages) == (10, MS, 51)
    assert plan.n_wheels == plan.wheel_ids().size and plan.wheel_ids()[-1] == plan.n_wheels - 1


def test_plan_refuses_a_rate_not_dividing_the_step() -> None:
    with pytest.raises(Exception, match="must be a whole number"):
        build_plan(run_settings(rate=3000.0, dt=1e-4))


def test_plan_parameter_set_from_the_model_factory_rule() -> None:
    """The track and soil come from clm_core.online.model.model_params: an unknown preset is refused naming it."""
    with pytest.raises(Exception, match="no_such_track"):
        build_plan(run_settings(track="no_such_track"))


def _answer(stamp: int, n: int, w: float) -> bytes:
    return encode_wheel_rail_response(stamp, "track", np.arange(n, dtype=np.uint32), np.zeros(n), np.full(n, w),
                                      np.zeros(n))


def test_train_messages_and_closed_loop_feedback() -> None:
    plan = build_plan(run_settings(rate=1000.0, dt=1e-4, duration=0.05, max_feedback_delay=0.005))
    watch = AnswerWatch(timeout_ns=NS)
    run = TrainRun(plan, base_ns=7 * NS, start_ns=100, frame_id="track", closed_loop=True, watch=watch)
    n = plan.n_wheels
    sent = []
    for k in range(10):
        stamp, due, raw = run.message(k)
        d = decode_wheel_loads(raw)
        assert (stamp, due) == (7 * NS + k * MS, 100 + k * MS) and d.stamp_ns == stamp
        np.testing.assert_array_equal(d.positions, run.vehicle.x)
        watch.sent(stamp, run.vehicle.k, due, due)
        sent.append((stamp, due))
    assert run.vehicle.k == 9 * plan.substeps
    # a fresh answer is used, one older than max_feedback_delay is not (too late), an unknown stamp is unmatched
    assert run.answer(_answer(sent[8][0], n, 1e-4), sent[8][1] + 300_000) == ""
    assert run.answer(_answer(sent[1][0], n, 1e-4), sent[9][1]) == ""
    assert run.answer(_answer(123, n, 1e-4), sent[9][1]) == ""
    assert run.answer(b"garbage", sent[9][1]) == ""
    c = run.counts
    assert (c.answered, c.used, c.stale, c.unmatched, c.malformed) == (2, 1, 1, 1, 1)
    assert list(c.lags_ns) == [300_000, sent[9][1] - sent[1][1]]
    run.end()
    assert run.answer(_answer(sent[2][0], n, 1e-4), sent[9][1]) == "" and c.after_end == 1
    assert c.model_messages == 10 and c.model_cpu_s > 0


def test_open_loop_answers_counted_not_used() -> None:
    plan = build_plan(run_settings())
    watch = AnswerWatch(timeout_ns=NS)
    run = TrainRun(plan, 0, 0, "track", False, watch)
    stamp, due, _ = run.message(0)
    watch.sent(stamp, 0, due, due)
    run.answer(_answer(stamp, plan.n_wheels, 1e-4), due + 1)
    assert (run.counts.answered, run.counts.used) == (1, 0)


# ------------------------------------------------------------------ counts

def test_counts_lags_through_the_one_helper_and_sums() -> None:
    a, b = Counts(published=3, answered=2), Counts(published=1, late=1)
    a.lags_ns.extend([1 * MS, 3 * MS])
    assert a.lags() == lag_figures([1 * MS, 3 * MS])
    s = a + b
    assert (s.published, s.answered, s.late) == (4, 2, 1)
    assert math.isnan(Counts().lags().median_s)
    text = a.report(1, 1000.0, stopped=True)
    assert text.startswith("train 1 (stopped): published 3 wheel-load messages") and "median 2.00 ms" in text
    assert "no answer" in Counts().report(2, 1000.0, False)
    v = diagnostics_values(a, s, [2 * MS], 0, final=True)
    assert v["train.lag_median_s"] == "0.002000" and v["recent_lag_median_s"] == "0.002000"
    assert v["published"] == 4 and "train.lag_p99_s" in v
    assert "train.lag_median_s" not in diagnostics_values(a, s, [], 0, final=False)


def test_module_examples_run() -> None:
    """The examples in the docstrings of clm_ros.vehicle_schedule and clm_ros.vehicle_counts run as doctests."""
    import doctest

    import clm_ros.vehicle_counts as counts
    import clm_ros.vehicle_schedule as schedule

    for mod, least in ((schedule, 10), (counts, 5)):
        failed, attempted = doctest.testmod(mod, optionflags=doctest.ELLIPSIS)
        assert attempted >= least and failed == 0, mod.__name__
