"""The on-disk cache of the receiver filters (clm_core.freefield.cache) and the shared-contour Green's functions."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from clm_core.freefield import FreeFieldModel
from clm_core.freefield import cache as fcache
from clm_core.halfspace.bessel import j0_matvec, j0_outer
from clm_core.halfspace.green import KernelEngine
from clm_core.profile import Layer, SoilProfile, load_profile

REC = [[0.0, 8.0], [3.0, 16.0]]
OPTS = {"influence_length": 6.0, "band": 40.0, "model_rate": 100.0}


@pytest.fixture()
def cache_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("CLM_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv("CLM_FREEFIELD_CACHE", raising=False)
    return tmp_path / "freefield"


def test_second_build_reads_the_same_numbers(cache_dir: Path) -> None:
    p = load_profile("mevergnies")
    a = FreeFieldModel(p, REC, 0.6, 2e-3, **OPTS)
    assert not a.cached
    assert (cache_dir / f"{a.cache_key}.npz").is_file()
    b = FreeFieldModel(p, REC, 0.6, 2e-3, **OPTS)
    assert b.cached and b.cache_key == a.cache_key
    assert np.array_equal(a.step_response, b.step_response)
    assert np.array_equal(a.transfer, b.transfer) and np.array_equal(a.freqs, b.freqs)
    assert (a.leakage, a.n_fir, a.delay) == (b.leakage, b.n_fir, b.delay)
    c = FreeFieldModel(p, REC, 0.6, 2e-3, cache=False, **OPTS)
    assert not c.cached and np.array_equal(a.step_response, c.step_response)


def test_every_input_changes_the_key() -> None:
    p = load_profile("mevergnies")
    base = {"spacing": 0.6, "dt": 2e-3, "band": 40.0}
    k0, _ = fcache.model_key(p, np.array(REC), **base)
    assert fcache.model_key(p, np.array(REC), **base)[0] == k0
    lay = p.layers[0]
    softer = SoilProfile(layers=(Layer(thickness=None, E=lay.E, rho=lay.rho, nu=lay.nu, beta=lay.beta * (1 + 1e-12),
                                       xi=lay.xi),), name=p.name)
    others = [
        fcache.model_key(softer, np.array(REC), **base)[0],
        fcache.model_key(p, np.array(REC) + np.array([[0.0, 1e-9], [0.0, 0.0]]), **base)[0],
        fcache.model_key(p, np.array(REC), **{**base, "dt": 1e-3})[0],
        fcache.model_key(p, np.array(REC), **{**base, "band": 41.0})[0],
        fcache.model_key(p, np.array(REC), **{**base, "tail": 0.25})[0],
    ]
    assert len({*others, k0}) == len(others) + 1
    # the code revision is part of the key text
    assert fcache.code_revision() in fcache.model_key(p, np.array(REC), **base)[1]


def test_a_damaged_entry_is_rebuilt(cache_dir: Path, caplog: pytest.LogCaptureFixture) -> None:
    p = load_profile("mevergnies")
    a = FreeFieldModel(p, REC, 0.6, 2e-3, **OPTS)
    path = cache_dir / f"{a.cache_key}.npz"
    path.write_bytes(path.read_bytes()[:200])
    with caplog.at_level("WARNING"):
        b = FreeFieldModel(p, REC, 0.6, 2e-3, **OPTS)
    assert not b.cached and "unreadable" in caplog.text
    assert np.array_equal(a.step_response, b.step_response)
    assert FreeFieldModel(p, REC, 0.6, 2e-3, **OPTS).cached  # rewritten whole


def test_cache_off(cache_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CLM_FREEFIELD_CACHE", "0")
    m = FreeFieldModel(load_profile("mevergnies"), REC, 0.6, 2e-3, **OPTS)
    assert not m.cached and not cache_dir.exists()


def test_j0_matvec_equals_the_table_product() -> None:
    r = np.arange(300) * 0.2
    t = np.linspace(0.0, 1.0, 97)
    k = 3.0 * 0.5 * (1 - np.cos(np.pi * t)) + 0.05j * np.sin(np.pi * t)
    f = np.exp(1j * np.arange(97)) / (1 + np.arange(97))
    ref = j0_outer(r, k) @ f
    assert np.max(np.abs(j0_matvec(r, k, f) - ref)) <= 1e-12 * np.max(np.abs(ref))


@pytest.mark.parametrize("profile", ["mevergnies", "haren"])
def test_shared_contour_equals_own_contour(profile: str) -> None:
    """A frequency on the top frequency's ellipse equals its own ellipse (a different path, the same integral)."""
    p = load_profile(profile)
    wide = KernelEngine(p, 40.0, 0.1, 100.0)  # f_max 100 Hz: 30 and 60 Hz on the 100-Hz ellipse
    for f in (30.0, 60.0):
        w = 2 * math.pi * f
        own = KernelEngine(p, 40.0, 0.1, f)(w).gs
        shared = wide(w).gs
        assert wide._contour(w)[3] is not None  # the shared path was used
        assert np.max(np.abs(shared - own)) <= 1e-6 * np.max(np.abs(own))
