"""CLM calibration from a soil profile and the ``clm soil-calibrate`` command."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from clm_core.cli import main
from clm_core.halfspace.bem import RowGeometry
from clm_core.halfspace.calibrate import SoilCalibration, calibrate_profile
from clm_core.profile import load_profile
from clm_core.soil.fit import ClmSumFit


def test_calibration_small_row_is_consistent() -> None:
    """Five areas, coarse mesh: sums, fit and single-area static stiffness are coherent."""
    prof = load_profile("mevergnies")
    geo = RowGeometry(n_areas=5, nx=4, ny=8, grading=1.0)
    f = np.arange(0.0, 61.0, 5.0)
    cal = calibrate_profile(prof, freqs=f, fmin=0.0, fmax=60.0, geometry=geo)
    X = cal.row.centre_column
    assert cal.total_sum[0] == pytest.approx(1.0 / X[0].sum())
    # the static sum is softer than a single area (neighbours move too) and positive
    assert 0 < cal.total_sum[0].real < cal.single_static
    # the alternating sum is stiffer (neighbours move the other way)
    assert cal.alternating_sum[0].real > cal.single_static
    assert cal.fit.df > 0 and cal.fit.df + 4 * cal.fit.dc > 0
    assert cal.single_static / cal.eq6_static == pytest.approx(1.0, abs=0.08)  # coarse mesh
    s = cal.summary()
    assert s["fit"]["band"] == [0.0, 60.0] and s["fit"]["norm"] == "ls"
    assert set(s["sums_at"]) == {"0", "10", "50"}
    json.dumps(s)


def test_cli_writes_files(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "cal"
    code = main(
        [
            "soil-calibrate",
            "--profile",
            "medium",
            "--out",
            str(out),
            "--areas",
            "5",
            "--fmax",
            "40",
            "--sweep-max",
            "40",
            "--df",
            "5",
            "--norm",
            "relative",
        ]
    )
    assert code == 0
    soil = yaml.safe_load((out / "soil.yaml").read_text())
    assert set(soil["clm"]) == {"mf", "df", "kf", "dc", "kc"}
    assert soil["profile"]["layers"][-1]["thickness"] is None
    # the written file is itself a loadable profile (same format as the presets)
    assert load_profile(out / "soil.yaml").layers == load_profile("medium").layers
    summary = json.loads((out / "summary.json").read_text())
    assert summary["fit"]["norm"] == "relative"
    assert summary["preset_clm"]["kf"] == 69e6
    assert summary["single_area"]["static_eq6"] > 0
    for name in ("sums.png", "receptances.png", "sweep.npz"):
        assert (out / name).stat().st_size > 0
    assert "medium" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (["--areas", "4"], "--areas = 4"),
        (["--fmin", "50", "--fmax", "40"], "fmin"),
        (["--profile", "atlantis"], "unknown"),
    ],
)
def test_cli_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], match: str) -> None:
    base = {"--profile": "medium", "--out": str(tmp_path / "x")}
    args = ["soil-calibrate"]
    for k, v in base.items():
        if k not in argv:
            args += [k, v]
    code = main(args + argv)
    assert code == 2
    err = capsys.readouterr().err
    assert match in err and err.count("\n") == 1


@pytest.fixture(scope="module")
def mevergnies_row() -> SoilCalibration:
    """41 areas on the Mevergnies half-space, 0-100 Hz, fitted in 0-80 Hz (ls): about 30 s."""
    return calibrate_profile(load_profile("mevergnies"), freqs=np.arange(0.0, 101.0, 1.0), fmin=0.0, fmax=80.0)


@pytest.mark.slow
def test_mevergnies_full_row_against_table1(mevergnies_row: SoilCalibration) -> None:
    """41 areas, 0-100 Hz: k_f, d_f, d_c near Table 1, k_c lower, m_f ~ 0 (see docs/halfspace.md)."""
    fit = mevergnies_row.fit
    assert fit.df == pytest.approx(680e3, rel=0.15)
    assert fit.dc == pytest.approx(-155e3, rel=0.15)
    assert fit.kf == pytest.approx(72e6, rel=0.3)
    assert fit.kc < 0.6 * 160e6
    assert fit.mf < 100.0


@pytest.mark.slow
def test_mevergnies_joint_fit_gives_positive_mass(mevergnies_row: SoilCalibration) -> None:
    """Issue 14, item 5: the total sum alone wants m_f < 0 (clipped to 0); both sums jointly give m_f > 0."""
    cal = mevergnies_row
    fit, other = cal.fit, cal.other_route
    assert fit.route == "joint" and fit.mf > 0 and fit.constrained == ()
    assert isinstance(other, ClmSumFit) and other.route == "total-first"
    assert other.mf == 0.0 and "mf=0" in other.constrained and other.mf_unconstrained < -100.0
    # the joint fit is the better fit of the two sums together (ls norm: sum of squared errors in the band)
    f = cal.freqs[(cal.freqs >= 0.0) & (cal.freqs <= 80.0)]
    i = np.searchsorted(cal.freqs, f)

    def cost(r: ClmSumFit) -> float:
        return float(
            np.sum(np.abs(r.total_sum(f) - cal.total_sum[i]) ** 2)
            + np.sum(np.abs(r.alternating_sum(f) - cal.alternating_sum[i]) ** 2)
        )

    assert cost(fit) < cost(other)
    # the quality of both fits is reported, for both routes
    q = cal.summary()["fit_quality"]
    assert q["route"] == "joint" and q["norm"] == "ls" and q["band_hz"] == [0.0, 80.0]
    for key in ("total", "alternating"):
        assert 0.0 < q[key]["residual"] < 0.15 and q[key]["max_rel_error"] > q[key]["residual"]
        assert q["other_route"][key]["residual"] == pytest.approx(other.quality()[key]["residual"])
    assert q["other_route"]["mf"] == 0.0 and q["other_route"]["mf_unconstrained"] < -100.0


@pytest.mark.parametrize("route", ["joint", "total-first"])
def test_cli_route_and_both_fit_qualities(tmp_path: Path, capsys: pytest.CaptureFixture[str], route: str) -> None:
    """``--route`` picks the fit (joint by default); summary, soil.yaml and stdout give the quality of both sums."""
    out = tmp_path / "cal"
    argv = ["soil-calibrate", "--profile", "medium", "--out", str(out), "--areas", "5", "--fmax", "40",
            "--sweep-max", "40", "--df", "5", "--no-plots"]
    assert main(argv + ([] if route == "joint" else ["--route", route])) == 0
    summary = json.loads((out / "summary.json").read_text())
    q = summary["fit_quality"]
    assert summary["fit"]["route"] == q["route"] == summary["command"]["route"] == route
    other = "total-first" if route == "joint" else "joint"
    assert q["other_route"]["route"] == other
    for key in ("total", "alternating"):
        assert q[key]["residual"] == pytest.approx(summary["fit"][f"residual_{key}"])
        assert q[key]["max_rel_error"] == pytest.approx(summary["fit"][f"max_rel_error_{key}"])
        assert q["other_route"][key]["residual"] > 0
    source = yaml.safe_load((out / "soil.yaml").read_text())["source"]
    assert f"route '{route}'" in source and "residual total sum" in source and "alternating sum" in source
    text = capsys.readouterr().out
    assert "total sum (Eq. 16) residual" in text and "alternating sum (Eq. 18) residual" in text
    assert f"{other} route:" in text
