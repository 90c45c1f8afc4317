"""``clm simulate --receivers`` end to end (issue 23.1): files, figure, summary numbers; bad input refused."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from tests.clitools import input_error, run_clm


def test_simulate_with_receivers(tmp_path: Path) -> None:
    out = tmp_path / "run"
    rec_file = tmp_path / "rec.csv"
    rec_file.write_text("x_m,y_m\n3.0,12.0\n", encoding="utf-8")
    proc = run_clm(["simulate", "--duration", "0.6", "--speed", "40", "--start", "-5", "--out", str(out),
                    "--no-csv", "--receivers", "8,16", "--receivers-file", str(rec_file),
                    "--receiver-influence", "12"])
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    entry = summary["receivers"]
    assert entry["soil"] == "mevergnies"
    assert "5.6 Hz" in entry["kb_filter"] and "0.125 s" in entry["kb_filter"]
    recs = entry["receivers"]
    assert [r["y_m"] for r in recs] == [8.0, 16.0, 12.0] and recs[2]["x_m"] == 3.0
    ppv = [r["ppv_mm_per_s"] for r in recs]
    assert all(p > 0 for p in ppv) and ppv[0] > ppv[1]  # decays with the distance
    assert all(0 < r["kb_fmax_mm_per_s"] < r["ppv_mm_per_s"] for r in recs)
    assert set(recs[0]["lv_db_re_5e-8_m_per_s"]) >= {"1", "10", "80"}
    with np.load(out / "receivers.npz") as z:
        assert z["velocity"].shape[0] == 3 and z["velocity"].shape[1] == z["t"].size
        np.testing.assert_allclose(np.max(np.abs(z["velocity"]), axis=1) * 1e3, ppv, rtol=1e-9)
    assert (out / "receivers.png").stat().st_size > 10_000
    assert (out / "receivers.csv").read_text().startswith("t_s,v0_m_per_s,v1_m_per_s,v2_m_per_s")
    assert "PPV" in proc.stdout


def test_simulate_receivers_bad_input(tmp_path: Path) -> None:
    msg = input_error(run_clm(["simulate", "--duration", "0.05", "--out", str(tmp_path / "a"), "--no-csv",
                               "--receivers", "8,abc"]))
    assert "receivers" in msg and "abc" in msg
    bad = tmp_path / "bad.csv"
    bad.write_text("1.0,2.0\n3.0\n", encoding="utf-8")
    msg = input_error(run_clm(["simulate", "--duration", "0.05", "--out", str(tmp_path / "b"), "--no-csv",
                               "--receivers-file", str(bad)]))
    assert "line 2" in msg
    msg = input_error(run_clm(["simulate", "--duration", "0.05", "--out", str(tmp_path / "c"), "--no-csv",
                               "--receivers", "8", "--receiver-soil", "E=1e8,rho=1800"]))
    assert "nu" in msg
