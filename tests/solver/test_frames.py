"""The compiled per-frame path (TrackSimulator.advance_frames): the same physics as advance(), restored when refused."""

from __future__ import annotations

import numpy as np
import pytest

from clm_core.params import ModelParams, load_model
from clm_core.solver import FrameLoads, TrackSimulator
from clm_core.solver import _frame_kernel as fk

DT_NS = 100_000  # 1e-4 s
LIMITS = np.array([1e7, 1e6, 1.0, 250.0, 1e3])  # position, force, tensile, speed, span (fk.LIM_*)


@pytest.fixture(scope="module")
def mev() -> ModelParams:
    return load_model("mevergnies", "mevergnies", "clm")


def _loads(sim: TrackSimulator, t_ns: np.ndarray, P: np.ndarray, F: np.ndarray, P0: np.ndarray, F0: np.ndarray,
           t_prev: int = 0) -> FrameLoads:
    """Frames at ``t_ns`` (R,) [ns] of wheels P, F (R, W), from the previous frame P0, F0 at ``t_prev``."""
    R, W = P.shape
    ticks = np.concatenate([[t_prev], t_ns]).astype(np.int64)
    return FrameLoads(ticks, ticks[1:] // DT_NS, DT_NS, np.arange(R + 1, dtype=np.int64) * W,
                      np.tile(np.arange(W, dtype=np.int64), R), P.ravel().copy(), F.ravel().copy(), np.zeros(0),
                      np.zeros(R + 1, dtype=np.int64), LIMITS, P0.copy(), F0.copy())


def test_frames_are_the_steps_of_advance(mev: ModelParams) -> None:
    """Frames every 1 ms (on steps) through window shifts and an overridden stretch: the responses at the frames are
    those of advance() with the same interpolated loads, to rounding (the interpolation is computed from integer
    ticks in the kernel, from float times in advance())."""
    p = ModelParams.from_dict({**mev.to_dict(), "overrides": [{"sleepers": [66, 67], "kb": 4.7e6}]})
    pos0, F0 = np.array([30.0, 27.0]), np.array([85e3, 90e3])
    a, b = TrackSimulator(p, 1e-4, 41), TrackSimulator(p, 1e-4, 41)
    a.initialize(pos0, F0)
    b.initialize(pos0, F0)
    R = 60
    t = (np.arange(R) + 1) * 10 * DT_NS
    P = pos0 + 60.0 * (t / 1e9)[:, None]  # 60 m/s: several shifts, the soft sleepers enter the window
    F = F0 * (1 + 0.1 * np.sin(t / 1e7))[:, None]
    res = a.advance_frames(_loads(a, t, P, F, pos0, F0), 1e9, 1.0)
    assert res.done == R and res.failure == "" and a.n_factorisations > 1
    for r in range(R):
        b.advance(t[r] / 1e9, (P[r], F[r]))
        snap = b.snapshot()
        assert res.first_sleeper[r] == snap.sleeper_index[0]
        scale = np.abs(snap.soil_force).max()
        np.testing.assert_allclose(res.sleepers[0, r], snap.soil_force, rtol=0, atol=1e-9 * scale)
        np.testing.assert_allclose(res.sleepers[1, r], snap.rail_deflection, rtol=1e-9, atol=1e-15)
        np.testing.assert_allclose(res.wheels[0, 2 * r: 2 * r + 2], snap.wheel_deflection, rtol=1e-9)
    np.testing.assert_allclose(a.state_vectors()[0], b.state_vectors()[0], rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(a.peaks()[1], b.peaks()[1], rtol=1e-9)


def test_a_refused_frame_restores_the_state_exactly(mev: ModelParams) -> None:
    """From frame 40 the loads are 8 times larger: a response soon breaks the bound; the frames before it are
    done and the state is that after them bit for bit (restored from the copy of the first call, those frames
    run again through the window shifts)."""
    pos0, F0 = np.array([30.0, 27.0]), np.array([85e3, 85e3])
    R = 60
    t = (np.arange(R) + 1) * 10 * DT_NS
    P = pos0 + 83.0 * (t / 1e9)[:, None]
    F = np.tile(F0, (R, 1))
    F[40:] *= 8.0
    a, b = TrackSimulator(mev, 1e-4, 41), TrackSimulator(mev, 1e-4, 41)
    a.initialize(pos0, F0)
    b.initialize(pos0, F0)
    la = _loads(a, t, P, F, pos0, F0)
    res = a.advance_frames(la, 1e9, 3e-3)
    d = res.done
    assert 40 <= d < 45 and res.status == fk.STOP_RESPONSE and "not finite or beyond its bounds" in res.failure
    lb = _loads(b, t[:d], P[:d], F[:d], pos0, F0)
    ref = b.advance_frames(lb, 1e9, 3e-3)
    assert ref.done == d
    for x, y in zip(a.state_vectors() + a.peaks()[1:], b.state_vectors() + b.peaks()[1:]):
        assert x.tobytes() == y.tobytes()
    assert a.placement == b.placement and a._s.k == b._s.k and la.P_prev.tobytes() == lb.P_prev.tobytes()
    assert a._s.prev_vals.tobytes() == b._s.prev_vals.tobytes()
    assert res.sleepers[:, :d].tobytes() == ref.sleepers.tobytes()


def test_values_checked_before_a_frame_is_stepped(mev: ModelParams) -> None:
    sim = TrackSimulator(mev, 1e-4, 41)
    pos0, F0 = np.array([30.0]), np.array([85e3])
    sim.initialize(pos0, F0)
    t = np.array([1, 2, 3]) * 10 * DT_NS
    P = np.array([[30.03], [30.06], [30.09]])
    F = np.array([[85e3], [2e6], [85e3]])
    res = sim.advance_frames(_loads(sim, t, P, F, pos0, F0))
    assert (res.done, res.status, res.rule, res.wheel) == (1, fk.STOP_INVALID, fk.RULE_FORCE, 0) and sim._s.k == 10


def test_a_fixed_window_refuses_wheels_leaving_it_part_way(mev: ModelParams) -> None:
    sim = TrackSimulator(mev, 1e-4, 41, follow=False, start_position=30.0)
    pos0, F0 = np.array([30.0]), np.array([85e3])
    sim.initialize(pos0, F0)
    u0 = sim.state_vectors()[0]
    t = np.array([1, 2]) * 10 * DT_NS
    res = sim.advance_frames(_loads(sim, t, np.array([[30.03], [60.0]]), np.array([[85e3], [85e3]]), pos0, F0))
    assert res.done == 1 and res.status == fk.STOP_SHIFT and "outside the allowed part" in res.failure
    assert sim._s.k == 10 and not np.array_equal(sim.state_vectors()[0], u0)


def test_time_never_goes_back(mev: ModelParams) -> None:
    from clm_core.errors import InputError

    sim = TrackSimulator(mev, 1e-4, 41)
    sim.initialize([30.0], [85e3])
    sim.advance(1e-3, ([30.03], [85e3]))
    with pytest.raises(InputError, match="time going backwards"):
        sim.advance_frames(_loads(sim, np.array([5 * DT_NS]), np.array([[30.0]]), np.array([[85e3]]),
                                  np.array([30.0]), np.array([85e3])))
