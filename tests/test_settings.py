"""The run-settings schema (clm_core.settings): one default per setting, checks that name value and rule."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml

from clm_core import settings
from clm_core.errors import ParameterError
from clm_core.params import PARAMETER_DOCS
from clm_core.settings import MODEL_PARAMETERS, SETTINGS, Setting
from clm_core.vehicle.irregularity import SPECTRA

ROOT = Path(__file__).resolve().parents[1]
DEMO_YAML = ROOT / "ros2_ws" / "src" / "clm_ros" / "config" / "demo.yaml"


def test_every_setting_is_complete_and_its_default_valid() -> None:
    assert len(SETTINGS) >= 25
    for name, s in SETTINGS.items():
        assert s.name == name and name == name.lower() and " " not in name
        assert s.kind in (float, int, str, bool) and s.unit and s.description
        assert s.check(s.default) == s.default, name
        text = s.help()
        assert "default " in text and (s.unit in ("-", "") or f"[{s.unit}]" in text), name
        if s.default is None:
            assert s.none_means and s.from_ros(s.to_ros()) is None, name
        if s.minimum is not None and s.maximum is not None:
            assert s.minimum <= s.maximum, name
    # the profile names the description lists are the spectra the builder knows
    assert set(SPECTRA) == {f"fra{i}" for i in range(1, 7)} | {"german-low", "german-high"}
    assert "fra1..fra6, german-low, german-high" in settings.IRREGULARITY.description


def test_checks_name_the_setting_the_value_and_the_rule() -> None:
    cases = [
        (settings.SPEED, -5, "speed = -5: must be 0 to 150 m/s"),
        (settings.SPEED, math.nan, "speed = nan: must be finite"),
        (settings.SPEED, True, "speed = True: must be a real number"),
        (settings.N_SLEEPERS, 61.5, "n_sleepers = 61.5: must be an integer"),
        (settings.STORAGE, "zip", "storage = 'zip': must be one of mcap, sqlite3"),
        (settings.WAVELENGTH_BAND, "1", "wavelength_band = '1': expected two numbers LMIN,LMAX in m"),
        (settings.DT, None, "dt: a value is needed"),
    ]
    for s, value, message in cases:
        with pytest.raises(ParameterError) as err:
            s.check(value)
        assert str(err.value).startswith(message), str(err.value)
    assert settings.SPEED.check(60) == 60.0 and isinstance(settings.SPEED.check(60), float)  # integers are real
    assert settings.N_SLEEPERS.check(61.0) == 61
    assert settings.SPEED.parse("83.33") == 83.33
    with pytest.raises(ParameterError, match=r"^--speed = 'x': must be a real number"):
        settings.SPEED.parse("x")
    assert settings.ACCEPT_NEW_WHEELS.parse("false") is False
    assert settings.LEAD_SLEEPERS.from_ros(-1) is None and settings.LEAD_SLEEPERS.from_ros(20) == 20
    assert settings.wavelength_band("2,40") == (2.0, 40.0)


def test_model_parameters_follow_the_parameter_docs() -> None:
    assert set(MODEL_PARAMETERS) == {f"{sec}.{n}" for n, (sec, _, _) in PARAMETER_DOCS.items()}
    kb = MODEL_PARAMETERS["track.kb"]
    assert kb.unit == "N/m" and kb.default is None and math.isnan(kb.to_ros())
    assert kb.check(60000000) == 60e6  # an integer for a real-valued parameter (issue 12.8)
    assert settings.setting("track.kb") is kb
    with pytest.raises(KeyError, match="unknown setting 'speeed'"):
        settings.setting("speeed")


def test_a_setting_refuses_an_invalid_default() -> None:
    with pytest.raises(ParameterError, match="x = -1: must be 0 to 1"):
        Setting("x", float, -1.0, "m", "a length", minimum=0.0, maximum=1.0)
    with pytest.raises(ValueError, match="needs none_means"):
        Setting("y", float, None, "m", "automatic without saying how")


def test_one_default_everywhere() -> None:
    """The demo's run (demo.yaml) and the vehicle run use the schema's defaults (launcher: tests/ros; the nodes' own
    settings' defaults: tests/ros/test_node_settings.py)."""
    from clm_core.vehicle.run import VehicleRunSpec

    spec = VehicleRunSpec()
    assert (spec.vehicle, spec.speed, spec.irregularity, spec.seed, spec.duration) == (
        "thalys", 83.33, "german-low", 1, 3.0)
    params = yaml.safe_load(DEMO_YAML.read_text())
    flat: dict[str, object] = {}
    for section in params.values():
        flat.update(section["ros__parameters"])
    checked = 0
    for name, value in flat.items():
        if name in SETTINGS:
            assert value == pytest.approx(SETTINGS[name].default) if isinstance(value, float) else \
                value == SETTINGS[name].default, (name, value)
            checked += 1
    assert checked >= 15
