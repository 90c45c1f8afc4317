"""Compiled coupled stepping (engine='stream') against the per-step Python path (engine='stream-python').

Both run the same scheme (TrackSimulator two-phase step, VehicleNewmark,
Hertz contact by Newton, the same window shifts); the compiled kernel
computes the track's wheel compliance from cached columns of K_eff^-1 and
sums in another order, so the results agree to rounding (observed <= 1e-11
relative), asserted to 1e-9.
"""

from __future__ import annotations

from dataclasses import replace
from unittest import mock

import numpy as np
import pytest

from clm_core.errors import InputError
from clm_core.params import ModelParams, SleeperOverride
from clm_core.vehicle.coupled import CoupledResult, CoupledSimulation
from clm_core.vehicle.irregularity import DippedJoint, Irregularity, WheelFlat, random_profile
from clm_core.vehicle.multibody import Train

RTOL = 1e-9
FIELDS = ("wheel_position", "wheel_load", "compression", "wheel_displacement", "rail_deflection", "irregularity",
          "vehicle_energy", "t_out", "soil_force", "sleeper_rail_deflection", "peak_soil_force")
#: least scale of a field: the vibration energy of a vehicle at rest is rounding noise (~1e-16 J)
FLOOR = {"vehicle_energy": 1e-6}


def _both(**kw: object) -> tuple[CoupledResult, CoupledResult]:
    duration = kw.pop("duration")
    fast = CoupledSimulation(engine="stream", **kw).run(duration)  # type: ignore[arg-type]
    slow = CoupledSimulation(engine="stream-python", **kw).run(duration)  # type: ignore[arg-type]
    return fast, slow


def _assert_same(fast: CoupledResult, slow: CoupledResult, iteration_slack: int = 0) -> dict[str, float]:
    """Every history equal to RTOL relative to its largest magnitude; NaN pattern and integers identical.

    ``iteration_slack``: how far the Newton iteration counts may differ. At rest the contact residual
    sits at rounding level, on either side of the 1e-14 tolerance depending on the order of the sums,
    so one path may take one more (no-op) iteration than the other.
    """
    np.testing.assert_array_equal(fast.t, slow.t)
    np.testing.assert_array_equal(fast.sleeper_index, slow.sleeper_index)
    np.testing.assert_array_equal(fast.sleeper_x, slow.sleeper_x)
    its_fast = np.asarray(fast.newton_iterations, dtype=np.int64)
    diff = np.abs(its_fast - np.asarray(slow.newton_iterations, dtype=np.int64))
    assert int(diff.max(initial=0)) <= iteration_slack, diff.max(initial=0)
    np.testing.assert_array_equal(fast.static_wheel_load, slow.static_wheel_load)
    errs = {}
    for f in FIELDS:
        a, b = getattr(fast, f), getattr(slow, f)
        assert a.shape == b.shape, f
        np.testing.assert_array_equal(np.isfinite(a), np.isfinite(b), err_msg=f)
        ok = np.isfinite(b)
        scale = max(float(np.max(np.abs(b[ok]))) if ok.any() else 0.0, FLOOR.get(f, 0.0))
        err = float(np.max(np.abs(a[ok] - b[ok]))) / scale if scale > 0 else 0.0
        errs[f] = err
        assert err <= RTOL, (f, err)
    assert fast.contact_losses() == slow.contact_losses()
    assert fast.meta["engine"] == "stream" and slow.meta["engine"] == "stream-python"
    return errs


def test_fast_path_equals_per_step_path_with_window_shifts(params: ModelParams, power_car: Train) -> None:
    """300 km/h on a FRA 5 profile with a dipped joint: ~20 window shifts, snapshots every 5 steps."""
    V = 83.3
    irr = Irregularity(profile=random_profile("fra5", 0.0, 40.0, seed=1), lead_in=5.0,
                       defects=(DippedJoint(x=26.0, depth=0.01, half_length=3.0),))
    fast, slow = _both(train=power_car, params=params, speed=V, dt=1e-4, irregularity=irr, x_start=20.0,
                       duration=0.12)
    _assert_same(fast, slow)
    assert fast.sleeper_index.size > 61 + 10  # the window moved by more than 10 bays
    assert np.isfinite(fast.peak_soil_force).sum() > 61 + 10


def test_fast_path_equals_per_step_path_through_contact_loss(params: ModelParams, power_car: Train) -> None:
    """A 60 mm fresh wheel flat: the flat wheel leaves the rail and impacts, in both paths alike."""
    fl = WheelFlat(wheel=0, x=25.0, length=0.06, shape="fresh")
    fast, slow = _both(train=power_car, params=params, speed=30.0, dt=5e-5, x_start=24.0,
                       irregularity=Irregularity(flats=(fl,)), snapshot_every=7, duration=0.06)
    _assert_same(fast, slow)
    steps, events = fast.contact_losses()
    assert steps > 0 and events >= 1
    assert fast.wheel_load[:, 0].max() > 2 * fast.static_wheel_load[0]


def test_fast_path_equals_per_step_path_on_a_non_uniform_track(params: ModelParams, power_car: Train) -> None:
    """Overrides under the run (hanging sleeper, soft soil patch): a factorisation per window, columns per operator."""
    p = replace(params, overrides=(
        SleeperOverride((45,), {"kb": 4.7e6}),
        SleeperOverride(tuple(range(50, 58)), {"kf": 20e6}),
    ))
    fast, slow = _both(train=power_car, params=p, speed=60.0, dt=1e-4, x_start=26.0, duration=0.1,
                       irregularity=Irregularity(profile=random_profile("fra5", 0.0, 40.0, seed=3), lead_in=2.0))
    _assert_same(fast, slow)
    # the wheels crossed the overridden sleepers: the hanging sleeper carries less than its neighbours
    g = fast.sleeper_index
    pk = fast.peak_soil_force
    assert pk[g == 45][0] < 0.8 * min(pk[g == 44][0], pk[g == 46][0])


def test_fast_path_at_rest_and_custom_snapshots(params: ModelParams, power_car: Train) -> None:
    """V = 0 (no shift, chunks of the maximum length) and snapshot_every = 1."""
    fast, slow = _both(train=power_car, params=params, speed=0.0, dt=1e-4, x_start=20.0, snapshot_every=1,
                       duration=0.03)
    _assert_same(fast, slow, iteration_slack=1)
    np.testing.assert_allclose(fast.wheel_load, np.broadcast_to(fast.static_wheel_load, fast.wheel_load.shape),
                               rtol=1e-9)
    assert fast.t_out.size == fast.t.size


def test_newton_failure_is_reported_by_both_paths(params: ModelParams, power_car: Train) -> None:
    """A NaN irregularity at step 30: both paths stop with the same InputError."""
    orig = Irregularity.wheel_irregularity

    def bad(self, X, X0, radius):  # type: ignore[no-untyped-def]
        R = orig(self, X, X0, radius)
        R[30, 1] = np.nan
        return R

    with mock.patch.object(Irregularity, "wheel_irregularity", bad):
        for engine in ("stream", "stream-python"):
            sim = CoupledSimulation(power_car, params, speed=30.0, dt=1e-4, x_start=20.0, engine=engine)
            with pytest.raises(InputError, match="contact Newton iteration did not converge"):
                sim.run(0.01)


def test_track_two_phase_api_after_compiled_chunks(params: ModelParams, power_car: Train) -> None:
    """coupled_chunk / coupled_commit leave a TrackSimulator whose begin_step / finish_step continue exactly."""
    from clm_core.solver import TrackSimulator
    from clm_core.vehicle._coupled_kernel import coupled_steps
    from clm_core.vehicle.contact import static_compression
    from clm_core.vehicle.multibody import VehicleNewmark

    dt, V, n1, n2 = 1e-4, 60.0, 700, 60
    tr = power_car
    sim = CoupledSimulation(tr, params, speed=V, dt=dt, x_start=20.0)
    X = sim.wheel_positions(np.arange(n1 + n2 + 1) * dt)
    P0 = tr.static_wheel_loads()

    def start() -> tuple[TrackSimulator, VehicleNewmark, np.ndarray, np.ndarray]:
        ts = TrackSimulator(params, dt, 61, start_position=float(X[0].mean()))
        ts.initialize(X[0], P0)
        d0 = static_compression(P0, sim.hertz)
        u0 = tr.static_state(ts.snapshot().wheel_deflection + d0)
        veh = VehicleNewmark(tr, dt)
        veh.set_state(u0, None, P0)
        return ts, veh, u0, d0

    # reference: n1 + n2 two-phase steps from Python
    ts_a, veh_a, _, delta = start()
    for n in range(1, n1 + n2 + 1):
        wf, _, G = ts_a.begin_step(X[n])
        delta, P, _ = veh_a.step_with_contact(wf, G, np.zeros(4), sim.hertz, delta)
        ts_a.finish_step(P)

    # n1 compiled steps, then n2 two-phase steps
    ts_b, veh_b, u0, delta = start()
    R = np.zeros((n1 + 1, 4))
    out = {k: np.empty((n1 + 1, 4)) for k in ("load", "comp", "zw", "wr")}
    energy, iters = np.empty(n1 + 1), np.zeros(n1 + 1, dtype=np.int64)
    n, shifts = 1, 0
    while n <= n1:
        first0 = ts_b.window[0]
        m, targs = ts_b.coupled_chunk(X[n : n1 + 1])
        shifts += ts_b.window[0] != first0
        e = n + m
        done, _, status, _ = coupled_steps(
            *targs, veh_b._Kinv, veh_b._KinvB, veh_b.H, tr.M, tr.C, tr.K, tr.gravity_force, tr.wheel_dof,
            veh_b.u, veh_b.v, veh_b.a, u0, dt, R[n:e], sim.hertz, delta, 1e-14, 50,
            out["load"][n:e], out["comp"][n:e], out["zw"][n:e], out["wr"][n:e], energy[n:e], iters[n:e],
            n, 10**9, np.empty((1, 61)), np.empty((1, 61)), np.empty(1, dtype=np.int64), np.empty(61),
        )
        assert status == 0 and done == m
        ts_b.coupled_commit(done, out["load"][e - 1])
        n = e
    assert shifts >= 5  # 4.2 m = 7 bays
    assert ts_b.t == pytest.approx(n1 * dt, abs=1e-15)
    for n in range(n1 + 1, n1 + n2 + 1):
        wf, _, G = ts_b.begin_step(X[n])
        delta, P, _ = veh_b.step_with_contact(wf, G, np.zeros(4), sim.hertz, delta)
        ts_b.finish_step(P)

    ua, va = ts_a.state_vectors()
    ub, vb = ts_b.state_vectors()
    assert ts_a.window == ts_b.window
    np.testing.assert_allclose(ub, ua, rtol=0, atol=RTOL * np.abs(ua).max())
    np.testing.assert_allclose(vb, va, rtol=0, atol=RTOL * np.abs(va).max())
    np.testing.assert_allclose(veh_b.u, veh_a.u, rtol=0, atol=RTOL * np.abs(veh_a.u).max())
    _, pa, ra = ts_a.peaks()
    _, pb, rb = ts_b.peaks()
    np.testing.assert_allclose(pb, pa, rtol=RTOL)
    np.testing.assert_allclose(rb, ra, rtol=RTOL)
