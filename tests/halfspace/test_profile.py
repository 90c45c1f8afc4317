"""Soil profiles: presets, files, validation, complex moduli."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from clm_core.errors import ParameterError, PresetError
from clm_core.profile import Layer, SoilProfile, list_soil_presets, load_profile


@pytest.mark.parametrize("name", ["mevergnies", "soft", "medium", "stiff", "haren"])
def test_presets_load(name: str) -> None:
    prof = load_profile(name)
    assert prof.halfspace.thickness is None
    assert prof.name == name


def test_mevergnies_values() -> None:
    prof = load_profile("mevergnies")
    assert prof.is_homogeneous
    assert prof.top.cs == pytest.approx(177.0, rel=0.01)
    assert prof.top.cp == pytest.approx(330.0, rel=0.01)


def test_haren_inconsistent_table_speed_is_noted() -> None:
    """Table 4 gives c_s = 170 m/s for layer 2, E = 84 MPa, nu = 0.13 give 140.8 m/s."""
    prof = load_profile("haren")
    assert prof.n_layers == 5
    assert len(prof.notes) == 1 and "layers[1].cs" in prof.notes[0]
    assert prof.layers[1].cs == pytest.approx(140.8, abs=0.1)


def test_list_presets() -> None:
    assert {"mevergnies", "haren"} <= set(list_soil_presets())


def test_file_roundtrip(tmp_path: Path) -> None:
    prof = load_profile("haren")
    import yaml

    p = tmp_path / "p.yaml"
    p.write_text(yaml.safe_dump({"name": "x", "profile": prof.to_dict()}), encoding="utf-8")
    back = load_profile(p)
    assert back.layers == prof.layers


def test_unknown_preset() -> None:
    with pytest.raises(PresetError, match="unknown"):
        load_profile("atlantis")


def test_missing_file() -> None:
    with pytest.raises(PresetError, match="cannot read"):
        load_profile("/nonexistent/soil.yaml")


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"nu": 0.5}, "nu = 0.5"),
        ({"E": -1.0}, "E = -1"),
        ({"rho": 0.0}, "rho = 0"),
        ({"beta": -1e-4}, "beta"),
        ({"thickness": 0.0}, "thickness"),
    ],
)
def test_layer_rules(kwargs: dict[str, float], match: str) -> None:
    base = {"thickness": None, "E": 1e8, "rho": 1800.0, "nu": 0.3}
    base.update(kwargs)
    with pytest.raises(ParameterError, match=match):
        Layer(**base)  # type: ignore[arg-type]


def test_profile_needs_halfspace_last() -> None:
    with pytest.raises(ParameterError, match="half-space"):
        SoilProfile((Layer(1.0, 1e8, 1800.0, 0.3),))
    with pytest.raises(ParameterError, match="only the last"):
        SoilProfile((Layer(None, 1e8, 1800.0, 0.3), Layer(None, 1e8, 1800.0, 0.3)))


def test_complex_moduli() -> None:
    lay = Layer(None, 129e6, 1600.0, 0.3, beta=0.0004, xi=0.01)
    w = 2 * math.pi * 50.0
    lam, mu = lay.lame(w)
    assert mu == pytest.approx(lay.G * complex(1.0, w * 0.0004 + 0.02))
    assert (lam + 2 * mu) == pytest.approx(lay.M * complex(1.0, w * 0.0004 + 0.02))
