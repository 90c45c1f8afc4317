"""Simulator state (clm_core.solver.state): a refused call restores everything, window included."""

from __future__ import annotations

import numpy as np
import pytest

from clm_core.errors import InputError
from clm_core.params import ModelParams, load_model
from clm_core.solver import TrackSimulator

F0 = 100e3
V = 40.0


@pytest.fixture(scope="module")
def mev() -> ModelParams:
    return load_model("mevergnies", "mevergnies", "clm")


def _start(mev: ModelParams) -> TrackSimulator:
    sim = TrackSimulator(mev, 2e-4, 21)
    sim.initialize([0.0], [F0])
    sim.advance(0.01, ([V * 0.01], [F0]))
    return sim


def test_copy_is_independent(mev: ModelParams) -> None:
    sim = _start(mev)
    s = sim._s
    c = s.copy()
    for name in ("u", "v", "prev_dofs", "prev_vals", "pos", "F", "pk_force", "pk_rail"):
        a, b = getattr(s, name), getattr(c, name)
        assert a is not b and np.array_equal(a, b), name
    c.u[:] = 1.0
    assert not np.any(s.u == 1.0)
    assert c.placement == s.placement and c.op is s.op


def test_refusal_after_window_shifts_restores_window_state_and_peaks(mev: ModelParams) -> None:
    """A load function that fails after several shifts leaves the simulator exactly as before the call."""
    sim = _start(mev)
    before = (sim.t, sim.window, sim.placement, sim.operator, *sim.state_vectors(), *sim.peaks())

    def bad(t: float) -> tuple[list[float], list[float]]:
        return [V * t], [F0 if t < 0.2 else np.nan]

    with pytest.raises(InputError, match="force nan"):
        sim.advance(0.25, bad)
    after = (sim.t, sim.window, sim.placement, sim.operator, *sim.state_vectors(), *sim.peaks())
    assert after[:4] == before[:4]
    for a, b in zip(after[4:], before[4:]):
        assert np.array_equal(a, b)

    # and it continues exactly as a simulator that never saw the refused call
    ref = _start(mev)
    shifted = []
    for s in (sim, ref):
        w0 = s.window[0]
        s.advance(0.25, lambda t: ([V * t], [F0]))
        shifted.append(s.window[0] - w0)
    assert shifted[0] == shifted[1] >= 10  # 9.6 m travelled: the window moved
    np.testing.assert_array_equal(sim.state_vectors()[0], ref.state_vectors()[0])
    np.testing.assert_array_equal(sim.peaks()[1], ref.peaks()[1])


def test_time_of_step_counts_from_initialize(mev: ModelParams) -> None:
    sim = TrackSimulator(mev, 2e-4, 21)
    sim.initialize([0.0], [F0], t0=1.5)
    sim.advance(1.51, ([0.4], [F0]))
    assert sim.time_of_step(0) == 1.5
    assert sim.time_of_step(50) == pytest.approx(sim.t)


def test_checkpoint_and_rollback_put_back_time_window_state_and_peaks(mev: ModelParams) -> None:
    """The public checkpoint/rollback (the online model's undo): after moving on across window shifts, a rollback
    gives back the checkpoint's state exactly, twice from the same checkpoint, and the run continues as one that
    never moved on."""
    sim = _start(mev)
    cp = sim.checkpoint()
    steps0 = sim.steps

    def state(s: TrackSimulator) -> tuple[object, ...]:
        return (s.t, s.steps, s.window, s.placement, s.operator, *s.state_vectors(), *s.peaks())

    before = state(sim)
    for _ in range(2):
        w0 = sim.window[0]
        sim.advance(sim.t + 0.2, lambda t: ([V * t], [F0]))
        assert sim.window[0] > w0 and sim.steps > steps0  # moved on, window shifted
        sim.rollback(cp)
        after = state(sim)
        assert after[:5] == before[:5]
        for a, b in zip(after[5:], before[5:]):
            assert np.array_equal(a, b)
    ref = _start(mev)
    for s in (sim, ref):
        s.advance(s.t + 0.05, lambda t: ([V * t], [F0]))
    assert np.array_equal(sim.state_vectors()[0], ref.state_vectors()[0])
    with pytest.raises(TypeError, match="checkpoint"):
        sim.rollback("not a checkpoint")  # type: ignore[arg-type]
