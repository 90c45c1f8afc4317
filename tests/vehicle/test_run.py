"""Bad input to the vehicle run spec (clm_core.vehicle.run)."""

from __future__ import annotations

import re

import pytest

from clm_core.errors import ParameterError
from clm_core.vehicle.run import VehicleRunSpec


@pytest.mark.parametrize(
    ("kwargs", "fragment"),
    [
        ({"train": 5}, "train = 5: must be a sequence of strings"),
        ({"train": "ICE"}, "train = 'ICE': must be a sequence of strings"),
        ({"defects": "joint"}, "defects = 'joint': must be a sequence of strings"),
    ],
)
def test_spec_refuses_sequences_that_are_not_lists(kwargs: dict[str, object], fragment: str) -> None:
    with pytest.raises(ParameterError, match=re.escape(fragment)):
        VehicleRunSpec(**kwargs)  # type: ignore[arg-type]


def test_spec_keeps_lists_and_tuples_of_names() -> None:
    assert VehicleRunSpec(train=["a", "b"]).train == ("a", "b")  # type: ignore[arg-type]
    assert VehicleRunSpec(defects=()).defects == ()
