"""Parameter objects: validation, presets, YAML round trip, overrides."""

import math
from pathlib import Path

import pytest

from clm_core.errors import ParameterError, PresetError, StabilityError
from clm_core.params import (
    ModelParams,
    RailParams,
    SoilParams,
    TrackParams,
    list_presets,
    load_model,
    load_params_file,
    load_soil,
    load_track,
    save_params_file,
)
from clm_core.profile import load_profile
from clm_core.track import assemble


def test_presets_listed() -> None:
    assert list_presets("tracks") == ["mevergnies", "soil-study"]
    assert list_presets("soils") == ["haren", "medium", "mevergnies", "soft", "stiff"]


def test_table_values() -> None:
    rail, track = load_track("mevergnies")
    assert rail.I == pytest.approx(3055e-8) and rail.A == pytest.approx(76.9e-4)
    assert (track.kp, track.dp, track.kb, track.db, track.ms, track.spacing) == (120e6, 4e3, 47e6, 72e3, 150.0, 0.6)
    _, ss = load_track("soil-study")
    assert (ss.kp, ss.dp, ss.kb, ss.db, ss.spacing) == (90e6, 30e3, 120e6, 40e3, 0.72)
    s = load_soil("mevergnies")
    assert (s.mf, s.df, s.kf, s.dc, s.kc) == (380.0, 680e3, 72e6, -155e3, 160e6)
    assert load_soil("stiff").kc == 724e6 and load_soil("haren").mf == 5003.0
    prof = load_profile("haren")
    assert len(prof.layers) == 6 and prof.layers[-1].thickness is None
    # c_s of Table 1 (177 m/s) follows from E, rho, nu
    assert load_profile("mevergnies").layers[0].cs == pytest.approx(177.0, rel=0.01)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"kb": math.nan}, "track.kb = nan"),
        ({"kp": -1.0}, "track.kp = -1: must be > 0"),
        ({"ms": 0.0}, "track.ms = 0: must be > 0"),
        ({"E": math.inf}, "rail.E = inf"),
        ({"db": -5.0}, "track.db = -5: must be >= 0"),
        ({"mf": 0.0}, "soil.mf = 0: must be > 0"),
        ({"kf": -2.0}, "soil.kf = -2"),
        ({"dc": -300e3}, "not positive semi-definite"),
        ({"nonsense": 1.0}, "unknown parameter 'nonsense'"),
    ],
)
def test_invalid_values_refused(kwargs: dict[str, float], match: str) -> None:
    base = load_model("mevergnies", "mevergnies", "clm")
    with pytest.raises(ParameterError, match=match):
        base.override(**kwargs)


def test_model_parameter_mismatch_refused() -> None:
    with pytest.raises(ParameterError, match="not a parameter of the 'winkler' model"):
        SoilParams(model="winkler", kf=1e6, df=1e3, mf=10.0)
    with pytest.raises(ParameterError, match="soil.model = 'elastic'"):
        SoilParams(model="elastic", kf=1e6)  # type: ignore[arg-type]
    with pytest.raises(ParameterError, match="contact_width"):
        TrackParams(spacing=0.2)


def test_assembled_damping_must_be_psd() -> None:
    # A per-sleeper patch of strongly negative coupling damping passes the
    # object checks of the overrides but not the assembled damping matrix.
    p = load_model("mevergnies", "mevergnies", "clm")
    bad = ModelParams.from_dict({**p.to_dict(), "overrides": [{"from": 10, "to": 14, "dc": -600e3}]})
    with pytest.raises(StabilityError, match="not positive semi-definite"):
        assemble(bad, 25)
    assemble(p, 25)  # the preset itself is fine


def test_unknown_presets_and_files() -> None:
    with pytest.raises(PresetError, match="unknown soil preset 'clay'"):
        load_soil("clay")
    with pytest.raises(PresetError, match="unknown track preset"):
        load_track("tgv")
    with pytest.raises(PresetError, match="not found"):
        load_params_file("/nonexistent/params.yaml")


def test_yaml_round_trip_with_overrides(tmp_path) -> None:  # type: ignore[no-untyped-def]
    p = load_model("mevergnies", "haren", "clm", {"kb": 50e6})
    p = ModelParams.from_dict(
        {**p.to_dict(), "overrides": [{"sleepers": [3], "kb": 5e6}, {"from": 7, "to": 9, "kf": 20e6}]}
    )
    f = tmp_path / "p.yaml"
    save_params_file(p, f)
    q = load_params_file(f)
    assert q == p
    assert q.track.kb == 50e6 and q.overrides[1].sleepers == (7, 8, 9)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("rail: {E: 1e9}\nsoil: {model: clm, mf: 1, kf: 1e6, df: 1e3, kc: 1e6, dc: 0}\ntrakc: {}\n", "unknown section"),
        ("overrides: [{kb: 1e6}]\n", "needs 'sleepers"),
        ("overrides: [{sleepers: [1], kz: 1e6}]\n", "unknown per-sleeper parameter 'kz'"),
    ],
)
def test_bad_parameter_file(tmp_path: Path, text: str, message: str) -> None:
    f = tmp_path / "bad.yaml"
    f.write_text(text)
    with pytest.raises(ParameterError, match=message):
        load_params_file(f)


def test_override_aliases_and_models() -> None:
    p = load_model("mevergnies", "mevergnies", "clm").override(d=0.65, Er=200e9)
    assert p.track.spacing == 0.65 and p.rail.E == 200e9
    w = p.with_model("winkler")
    assert (w.soil.mf, w.soil.kc, w.soil.dc) == (0.0, 0.0, 0.0) and w.soil.kf == 72e6
    assert RailParams().EI == pytest.approx(210e9 * 3055e-8)
