"""The demo's receivers (clm_core.outputs.demo_receivers): a real bag in the demo's layout -> receivers, report."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from clm_core.errors import InputError
from clm_core.freefield import free_field, receivers_from_distances
from clm_core.io import messages as msgs
from clm_core.io.bags import BagWriter
from clm_core.outputs.demo_receivers import demo_receivers, main, read_demo_bag
from clm_core.params import load_track
from clm_core.profile import load_profile
from clm_core.synthetic.window import moving_window_forces

T0 = 1_700_000_000 * 1_000_000_000
DT, N_WIN = 2e-3, 31


def write_demo_bag(path: Path, n: int, drop: tuple[int, ...] = ()) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A bag with the demo's topics: wheel loads, sleeper responses (a moving window), wheel-rail responses."""
    t, first, F = moving_window_forces(n, DT, 60.0, N_WIN, 0.6, -15.0)
    with BagWriter(path) as w:
        cw = w.add_topic("/wheel_loads", msgs.WHEEL_LOADS)
        cs = w.add_topic("/sleeper_response", msgs.SLEEPER_RESPONSE)
        cr = w.add_topic("/wheel_rail_response", msgs.WHEEL_RAIL_RESPONSE)
        for i in range(n):
            s = T0 + int(round(t[i] * 1e9))
            x = -15.0 + 60.0 * t[i]
            w.write(cw, s, msgs.encode_wheel_loads(s, "track", [0], [x], [85e3]))
            if i in drop:
                continue
            idx = first[i] + np.arange(N_WIN)
            defl = F[i] * 1e-8
            w.write(cs, s, msgs.encode_sleeper_response(s, "track", idx, idx * 0.6, F[i], defl, defl, defl))
            w.write(cr, s, msgs.encode_wheel_rail_response(s, "track", [0], [x], [1e-3 + 1e-5 * np.sin(40 * t[i])],
                                                           [0.0]))
    return t, first, F


@pytest.fixture()
def demo_out(tmp_path: Path) -> Path:
    out = tmp_path / "demo"
    out.mkdir()
    (out / "summary.json").write_text(json.dumps({"status": "ok", "vehicle": "thalys", "speed_m_per_s": 60.0,
                                                  "track": "mevergnies", "soil": "mevergnies", "model": "clm"}))
    return out


def test_demo_receivers_equal_the_free_field_of_the_recorded_forces(demo_out: Path) -> None:
    t, first, F = write_demo_bag(demo_out / "demo_bag", 900)
    entry = demo_receivers(demo_out, (8.0, 16.0, 32.0), influence_length=12.0)
    # the same numbers from the forces themselves (window-relative), receivers at the recorded stretch's middle
    lo, hi = int(first.min()), int(first.max()) + N_WIN - 1
    _, track = load_track("mevergnies")
    rec = receivers_from_distances([8.0, 16.0, 32.0], x=0.5 * (lo + hi) * 0.6)
    ref = free_field(load_profile("mevergnies"), rec, t, first, F, 0.6, contact_length=track.contact_length,
                     contact_width=track.contact_width, influence_length=12.0)
    with np.load(demo_out / "receivers.npz") as z:
        v = z["velocity"]
        assert z["lv_db"].shape == (3, 20)
    assert v.shape == ref.velocity.shape
    assert np.max(np.abs(v - ref.velocity)) <= 1e-12 * np.max(np.abs(ref.velocity))
    got = [r["ppv_mm_per_s"] for r in entry["receivers"]]
    assert np.allclose(got, ref.measures.ppv_mm_s, rtol=1e-12) and got[0] > got[1] > got[2] > 0
    summary = json.loads((demo_out / "summary.json").read_text())
    assert summary["status"] == "ok" and len(summary["receivers"]["receivers"]) == 3
    assert summary["receivers"]["frames_interpolated"] == 0
    for name in ("receivers.png", "rail_deflection_spectra.png", "rail_deflection_third_octave.png"):
        assert (demo_out / name).stat().st_size > 10_000
    page = (demo_out / "index.html").read_text()
    assert "PPV [mm/s]" in page and "rail_deflection_spectra.png" in page and "receivers.png" in page
    assert f"{ref.measures.ppv_mm_s[0]:.4g}" in page
    # the second run reads the filters from the cache: same numbers
    again = demo_receivers(demo_out, (8.0, 16.0, 32.0), influence_length=12.0)
    assert again["filters_from_cache"] and not entry["filters_from_cache"]
    with np.load(demo_out / "receivers.npz") as z:
        assert np.array_equal(z["velocity"], v)


def test_a_missing_frame_is_interpolated_and_counted(tmp_path: Path) -> None:
    t, first, F = write_demo_bag(tmp_path / "bag", 200, drop=(100,))
    rec = read_demo_bag(tmp_path / "bag")
    assert rec.interpolated == 1 and rec.t.size == 200 and np.allclose(np.diff(rec.t), DT)
    cols = first[100] + np.arange(N_WIN) - rec.first_sleeper
    both = np.isfinite(rec.soil_force[99, cols]) & np.isfinite(rec.soil_force[101, cols])
    mid = 0.5 * (rec.soil_force[99, cols] + rec.soil_force[101, cols])
    assert np.allclose(rec.soil_force[100, cols][both], mid[both])


def test_no_bag_is_a_clear_error(demo_out: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main([str(demo_out)]) == 2
    assert "demo_bag" in capsys.readouterr().err
    with pytest.raises(InputError, match="sleeper response"):
        with BagWriter(demo_out / "demo_bag") as w:
            c = w.add_topic("/wheel_loads", msgs.WHEEL_LOADS)
            w.write(c, T0, msgs.encode_wheel_loads(T0, "track", [0], [0.0], [85e3]))
        read_demo_bag(demo_out / "demo_bag")
    assert main([str(demo_out), "--receivers", "8,abc"]) == 2
