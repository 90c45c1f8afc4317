"""Window placement and shift rules (clm_core.solver.window): pure rules, no assembly."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clm_core.errors import InputError, ParameterError
from clm_core.solver.window import Placement, Window, shift_bays, shift_entries

D = 0.6  # sleeper spacing [m]
WIN = Window.create(31, D, lead_sleepers=10, margin_sleepers=4)


def test_defaults_and_start_placement() -> None:
    w = Window.create(61, D)
    assert (w.lead_sleepers, w.margin_sleepers) == (20, 10)
    assert Window.create(12, D).margin_sleepers == 2
    p = w.start(0.0)
    assert p == Placement(-30, "forward")  # centred: sleepers -30 .. 30
    assert w.start(6.1) == Placement(10 - 30, "forward")  # rounded to the nearest sleeper
    assert Window.create(61, D, follow=False).start(0.0).orientation == "free"


def test_allowed_zone_per_orientation() -> None:
    """Forward: margin behind, lead ahead; backward: the mirror image; free: margin at both ends."""
    N, m, ld = 31, 4, 10
    assert WIN.limits("forward") == (m, N - 1 - ld)
    assert WIN.limits("backward") == (ld, N - 1 - m)
    assert Window.create(31, D, 10, 4, follow=False).limits("free") == (m, N - 1 - m)
    lo, hi = WIN.allowed_range(Placement(100, "forward"))
    assert lo == pytest.approx(104 * D) and hi == pytest.approx(120 * D)


def test_span_includes_the_clamped_ghost_bay_on_its_side() -> None:
    assert WIN.span(Placement(5, "forward")) == (5, 32)
    assert WIN.span(Placement(5, "backward")) == (4, 32)
    assert WIN.span(Placement(5, "free")) == (5, 31)


def test_wheels_inside_keep_the_placement() -> None:
    p = Placement(0, "forward")
    lo, hi = WIN.allowed_range(p)
    assert WIN.required(p, hi, lo, "t", 0.0) is p
    assert WIN.place(p, np.array([lo, np.nan, hi]), "t", 0.0) is p
    assert WIN.place(p, np.array([np.nan]), "t", 0.0) is p  # no wheel on the track: nothing to place


@settings(max_examples=200, deadline=None)
@given(first=st.integers(-1000, 1000), beyond=st.floats(1e-6, 40.0), spread=st.floats(0.0, 15.0))
def test_forward_shift_is_the_fewest_bays_that_restore_the_lead(first: int, beyond: float, spread: float) -> None:
    p = Placement(first, "forward")
    _, hi = WIN.allowed_range(p)
    front = hi + beyond * D
    rear = front - spread * D
    q = WIN.required(p, front, rear, "t", 0.0)
    assert q.orientation == "forward" and q.first > p.first
    lo_q, hi_q = WIN.allowed_range(q)
    assert lo_q - 1e-9 <= rear and front <= hi_q + 1e-9
    # one bay less would leave the foremost wheel beyond the front limit
    assert front > WIN.allowed_range(Placement(q.first - 1, "forward"))[1] + 1e-9


@settings(max_examples=200, deadline=None)
@given(first=st.integers(-1000, 1000), behind=st.floats(1e-6, 40.0), spread=st.floats(0.0, 15.0))
def test_backward_shift_is_the_mirror_image(first: int, behind: float, spread: float) -> None:
    p = Placement(first, "forward")
    lo, _ = WIN.allowed_range(p)
    rear = lo - behind * D
    front = rear + spread * D
    q = WIN.required(p, front, rear, "t", 0.0)
    assert q.orientation == "backward" and q.first < p.first
    lo_q, hi_q = WIN.allowed_range(q)
    assert lo_q - 1e-9 <= rear and front <= hi_q + 1e-9
    assert lo_q == pytest.approx((q.first + WIN.lead_sleepers) * D)  # the lead is kept behind now
    assert rear < WIN.allowed_range(Placement(q.first + 1, "backward"))[0] - 1e-9


def test_wheels_spanning_more_than_the_zone_are_refused() -> None:
    p = Placement(0, "forward")
    a, b = WIN.limits("forward")
    _, hi = WIN.allowed_range(p)
    with pytest.raises(InputError, match=f"holds at most {b - a} bays"):
        WIN.required(p, hi + 5 * D, hi + 5 * D - (b - a + 1) * D, "advance", 0.25)
    # exactly the zone's length fits
    q = WIN.required(p, hi + 5 * D, hi + 5 * D - (b - a) * D, "advance", 0.25)
    assert q.first == 5


def test_fixed_window_refuses_instead_of_shifting() -> None:
    w = Window.create(31, D, 10, 4, follow=False)
    p = w.start(0.0)
    lo, hi = w.allowed_range(p)
    with pytest.raises(InputError, match=r"outside the allowed part .* follow=False"):
        w.place(p, np.array([hi + 0.01]), "step", 0.1)
    with pytest.raises(InputError, match="outside the allowed part"):
        w.place(p, np.array([lo - 0.01]), "step", 0.1)


def test_outside_flags_rows_beyond_either_limit() -> None:
    p = Placement(0, "forward")
    lo, hi = WIN.allowed_range(p)
    front = np.array([hi, hi + 0.01, -np.inf, lo + 1.0])
    rear = np.array([lo, lo, np.inf, lo - 0.01])
    assert WIN.outside(p, front, rear).tolist() == [False, True, False, True]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [({"margin_sleepers": 0}, "margin_sleepers"), ({"lead_sleepers": 2, "margin_sleepers": 3}, "lead_sleepers"),
     ({"lead_sleepers": 21, "margin_sleepers": 10}, "n_sleepers"), ({"elements_per_bay": 1}, "elements_per_bay")],
)
def test_bad_rules_are_refused(kwargs: dict[str, int], match: str) -> None:
    with pytest.raises(ParameterError, match=match):
        Window.create(31, D, **kwargs)  # type: ignore[arg-type]
    if "elements_per_bay" in kwargs:
        Window.create(31, D, follow=False, elements_per_bay=1)  # a fixed window needs no rail-only end nodes


def test_shift_moves_whole_bays_and_adds_bays_at_rest() -> None:
    a = np.arange(1.0, 13.0)  # 4 bays of 3 DOFs
    b = a.copy()
    shift_bays(b, 1, 3)
    assert b.tolist() == [4, 5, 6, 7, 8, 9, 10, 11, 12, 0, 0, 0]
    b = a.copy()
    shift_bays(b, -2, 3)
    assert b.tolist() == [0, 0, 0, 0, 0, 0, 1, 2, 3, 4, 5, 6]
    b = a.copy()
    shift_bays(b, 5, 3)
    assert not b.any()
    b = a.copy()
    shift_bays(b, 0, 3)
    assert np.array_equal(b, a)


def test_shift_renumbers_load_entries_and_drops_those_that_left() -> None:
    dofs = np.array([0, 2, 7, 11], dtype=np.int64)
    vals = np.array([1.0, 2.0, 3.0, 4.0])
    d, v = shift_entries(dofs, vals, 1, 3, 12)
    assert d.tolist() == [4, 8] and v.tolist() == [3.0, 4.0]
    d, v = shift_entries(dofs, vals, -1, 3, 12)
    assert d.tolist() == [3, 5, 10] and v.tolist() == [1.0, 2.0, 3.0]
    assert math.isclose(float(v.sum()), 6.0)
