"""The online input policy without middleware (clm_core.online)."""

import re

import numpy as np
import pytest

from clm_core.errors import ParameterError
from clm_core.online import OnlineTrackModel, Rejected, WheelFrame
from clm_core.params import load_model

OFF = np.array([0.0, 3.0])



@pytest.fixture(scope="module")
def params():  # type: ignore[no-untyped-def]
    return load_model("mevergnies", "mevergnies", "clm")


def _frames(n: int, t0: int = 0) -> list[WheelFrame]:
    return [WheelFrame.of(t0 + k * 10**6, [0, 1], 30.0 - OFF + 30.0 * k * 1e-3, [85e3, 85e3]) for k in range(n)]


def test_rejected_frames_leave_state_and_wheel_set_untouched(params) -> None:  # type: ignore[no-untyped-def]
    ref = OnlineTrackModel(params, n_sleepers=61)
    m = OnlineTrackModel(params, n_sleepers=61, accept_new_wheels=True)
    frames = _frames(40)
    for f in frames[:20]:
        ref.process(f)
        m.process(f)
    # a new wheel id in a frame that is refused (wheels span more than the window) is not registered
    with pytest.raises(Rejected, match="outside_window"):
        m.process(WheelFrame.of(19_500_000, [0, 1, 9], [30.6, 27.6, 300.0], [85e3, 85e3, 85e3]))
    with pytest.raises(Rejected, match="non_finite"):
        m.process(WheelFrame.of(19_500_000, [0, 1], [30.6, 27.6], [np.nan, 1.0]))
    with pytest.raises(Rejected, match="stamp_not_increasing"):
        m.process(WheelFrame.of(5_000_000, [0, 1], [30.6, 27.6], [1.0, 1.0]))
    assert 9 not in m._slot and len(m._slot) == 2
    for f in frames[20:]:
        a, b = ref.process(f), m.process(f)
    np.testing.assert_array_equal(a.soil_force, b.soil_force)
    assert m.stats.accepted == 40 and m.stats.rejected_total == 3
    assert dict(m.stats.rejected) == {"outside_window": 1, "non_finite": 1, "stamp_not_increasing": 1}


def test_unknown_id_refused_without_accept_new_wheels(params) -> None:  # type: ignore[no-untyped-def]
    m = OnlineTrackModel(params, n_sleepers=61)
    m.process(_frames(1)[0])
    with pytest.raises(Rejected, match="unknown_id"):
        m.process(WheelFrame.of(1_000_000, [0, 5], [30.03, 27.03], [85e3, 85e3]))
    # a wheel leaving and coming back under its id is accepted
    m.process(WheelFrame.of(2_000_000, [0], [30.06], [85e3]))
    r = m.process(WheelFrame.of(3_000_000, [0, 1], [30.09, 27.09], [85e3, 85e3]))
    assert r.wheel_deflection.shape == (2,) and np.all(r.wheel_deflection > 0)


@pytest.mark.parametrize(
    ("kwargs", "fragment"),
    [
        ({"dt": "x"}, "dt = 'x': must be a real number"),
        ({"dt": -1e-4}, "dt = -0.0001 s: must be > 0"),
        ({"max_gap": "x"}, "max_gap = 'x': must be a real number"),
        ({"max_gap": 0.0}, "max_gap = 0 s: must be > 0"),
        ({"wheel_ids": [1.5]}, "wheel_ids = [1.5]: must be integers"),
        ({"wheel_ids": "x"}, "wheel_ids = 'x': must be integers"),
    ],
)
def test_model_refuses_bad_settings(kwargs: dict[str, object], fragment: str) -> None:
    with pytest.raises(ParameterError, match=re.escape(fragment)):
        OnlineTrackModel(load_model(), **kwargs)  # type: ignore[arg-type]


def test_model_with_a_fixed_wheel_set_builds() -> None:
    """wheel_ids registered the wheels before their arrays existed (AttributeError '_pos')."""
    model = OnlineTrackModel(load_model(), wheel_ids=[3, 7, 3])
    assert model._slot == {3: 0, 7: 1}
