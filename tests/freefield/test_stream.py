"""The streaming form gives the offline numbers (issue 23.2): same forces, same velocities to rounding."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from clm_core.errors import InputError
from clm_core.freefield import FreeFieldModel, ReceiverStream, receiver_velocity
from clm_core.synthetic.window import moving_window_forces


def _stream(model: FreeFieldModel, t: np.ndarray, first: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    s = ReceiverStream(model)
    ts, vs = [], []
    for i in range(t.size):
        out = s.push(float(t[i]), first[i] + np.arange(F.shape[1]), F[i])
        if out is not None:
            ts.append(out[0])
            vs.append(out[1])
    return np.array(ts), np.array(vs).T


def test_stream_equals_offline(small_model: FreeFieldModel) -> None:
    t, first, F = moving_window_forces(1500, small_model.dt)
    off = receiver_velocity(small_model, t, first, F)
    ts, v = _stream(small_model, t, first, F)
    np.testing.assert_array_equal(ts.size, off.t.size)
    np.testing.assert_allclose(ts, off.t, rtol=0, atol=1e-12)
    peak = np.max(np.abs(off.velocity))
    assert peak > 1e-5  # a real signal: the 85 kN load passes the receivers (m/s)
    assert np.max(np.abs(v - off.velocity)) <= 1e-9 * peak


def test_sosfilt_state_carry_is_bit_equal() -> None:
    """The band limit is run frame by frame with its state: bit-equal to the whole-record filter."""
    rng = np.random.default_rng(3)
    x = rng.normal(size=(7, 400))
    sos = signal.butter(8, 100.0, output="sos", fs=1000.0)
    whole = signal.sosfilt(sos, x, axis=-1)
    zi = np.zeros((sos.shape[0], 7, 2))
    parts = []
    for i in range(400):
        y, zi = signal.sosfilt(sos, x[:, i:i + 1], axis=-1, zi=zi)
        parts.append(y[:, 0])
    np.testing.assert_array_equal(np.array(parts).T, whole)


def test_stream_starts_from_held_forces(small_model: FreeFieldModel) -> None:
    """Constant forces (the static state of the first frame) give zero velocity: no start-up step."""
    n = 300
    t = np.arange(n) * small_model.dt
    F = np.tile(np.linspace(10e3, 80e3, 21), (n, 1))
    first = np.full(n, -10)
    off = receiver_velocity(small_model, t, first, F)
    assert np.max(np.abs(off.velocity)) == 0.0
    _, v = _stream(small_model, t, first, F)
    assert np.max(np.abs(v)) == 0.0


def test_stream_refuses_gaps_and_bad_frames(small_model: FreeFieldModel) -> None:
    s = ReceiverStream(small_model)
    s.push(0.0, [0, 1], [1.0, 2.0])
    with pytest.raises(InputError, match="expected"):
        s.push(3 * small_model.dt, [0, 1], [1.0, 2.0])
    with pytest.raises(InputError, match="non-finite"):
        s.push(small_model.dt, [0, 1], [np.nan, 2.0])
    with pytest.raises(InputError, match="2 sleeper indices for 3 forces"):
        s.push(small_model.dt, [0, 1], [1.0, 2.0, 3.0])
    assert s.frames == 1  # refused frames change nothing


def test_offline_refuses_wrong_step(small_model: FreeFieldModel) -> None:
    t = np.arange(10) * 2 * small_model.dt
    with pytest.raises(InputError, match="uniform dt"):
        receiver_velocity(small_model, t, np.zeros(10, int), np.zeros((10, 3)))


def test_a_record_shorter_than_the_delay_is_refused_clearly(small_model: FreeFieldModel) -> None:
    """The filters delay the output by D model steps: a shorter record has no velocity to give (named, with D)."""
    n = small_model.delay * small_model.decimation  # D model steps of input: D outputs, all before the first input
    t, first, F = moving_window_forces(n, small_model.dt)
    with pytest.raises(InputError, match=f"delay is {small_model.delay} model steps"):
        receiver_velocity(small_model, t, first, F)
    t, first, F = moving_window_forces(n + 2 * small_model.decimation, small_model.dt)
    assert receiver_velocity(small_model, t, first, F).velocity.shape[1] >= 2
