"""Shared small free-field models (low band, short influence length: seconds to build)."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
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


def moving_window_forces(n: int, dt: float, speed: float = 60.0, n_window: int = 31,
                         spacing: float = 0.6, x0: float = -15.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A moving window of sleepers carrying a 85 kN moving load (hat-shared) plus a 30 Hz ripple [s], [-], [N]."""
    t = np.arange(n) * dt
    xw = x0 + speed * t
    first = np.floor(xw / spacing).astype(np.int64) - n_window // 2
    F = np.zeros((n, n_window))
    for i in range(n):
        xs = (first[i] + np.arange(n_window)) * spacing
        F[i] = 85e3 * np.maximum(0.0, 1.0 - np.abs(xs - xw[i]) / spacing) + 300.0 * np.sin(2 * np.pi * 30 * t[i])
    return t, first, F
