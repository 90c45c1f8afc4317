"""Shared small free-field models (low band, short influence length: seconds to build)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from clm_core.freefield import FreeFieldModel
from clm_core.profile import load_profile


@pytest.fixture(scope="session", autouse=True)
def _filter_cache(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """The tests' filter cache is their own (never the user's ~/.cache/clm), empty at the start of the session."""
    mp = pytest.MonkeyPatch()
    mp.setenv("CLM_CACHE_DIR", str(tmp_path_factory.mktemp("clm-cache")))
    yield
    mp.undo()


@pytest.fixture(scope="session")
def small_model() -> FreeFieldModel:
    """Mevergnies soil, receivers at 8 and 16 m (x = 0 and 3 m), 12 m influence, 40 Hz band, 100 Hz model rate."""
    return FreeFieldModel(load_profile("mevergnies"), [[0.0, 8.0], [3.0, 16.0]], 0.6, 2e-3,
                          influence_length=12.0, band=40.0, model_rate=100.0)
