"""Fixtures of the vehicle tests: the paper's Mevergnies track on its CLM soil, and one Thalys power car."""

from __future__ import annotations

import pytest

from clm_core.params import ModelParams, load_model
from clm_core.vehicle.multibody import Train
from clm_core.vehicle.presets import load_vehicle


@pytest.fixture(scope="module")
def params() -> ModelParams:
    """The Mevergnies track on the Mevergnies soil, CLM model (paper Sec. 5)."""
    return load_model("mevergnies", "mevergnies", "clm")


@pytest.fixture(scope="module")
def power_car() -> Train:
    """One Thalys power car (the vehicle of the paper's site measurements)."""
    return load_vehicle("thalys").train(1)
