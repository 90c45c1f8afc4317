"""Content-addressed on-disk cache of the receiver filters (:class:`~clm_core.freefield.model.FreeFieldModel`).

Building the filters (the layered half-space Green's functions at every FFT
frequency, integrated over every contact area for every receiver) is the
only slow step of the free-field computation; a run that repeats a soil,
track geometry and receiver set (the demo, a parameter study on the
vehicle, a re-run) reads them back instead.

Key
---
SHA-256 of a canonical JSON text holding everything the filters depend on:
the soil profile's values (per layer: thickness, E, rho, nu, beta, xi), the
receivers (x, y), the sleeper spacing, the input step, the contact area,
the influence length, the band limit, the model rate, the tail, the
design constants of :mod:`clm_core.freefield.model` (their values at run
time: a test that changes one gets its own entries), and the code
revision: the SHA-256 of the source of every module that computes them
(:data:`SOURCES`), so an edit of the method invalidates every entry.
Floats enter by ``repr`` (exact round trip), so equal inputs give equal
keys and any change of a value gives a new key.

Store
-----
One ``<key>.npz`` per model in :func:`cache_dir` (``CLM_CACHE_DIR`` /
``freefield``, else ``$XDG_CACHE_HOME/clm/freefield``, else
``~/.cache/clm/freefield``), written to a temporary file and renamed (a
concurrent reader never sees half a file; two writers of one key write the
same numbers). The entry keeps its key text; an entry that cannot be read or
whose key text differs is ignored and rewritten. ``CLM_FREEFIELD_CACHE=0``
turns the cache off.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import tempfile
import zipfile
from dataclasses import fields
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from clm_core.arrays import Array
from clm_core.profile import SoilProfile

__all__ = ["SOURCES", "cache_dir", "cache_enabled", "code_revision", "load", "model_key", "store"]

log = logging.getLogger(__name__)

#: Modules whose source determines the filters (relative to the clm_core package).
SOURCES = ("freefield/model.py", "halfspace/green.py", "halfspace/bessel.py", "halfspace/bem.py", "profile.py")
#: Arrays an entry holds (besides its key text).
ARRAYS = ("step_response", "freqs", "transfer", "leakage", "n_fir", "delay")


def cache_enabled() -> bool:
    """False when ``CLM_FREEFIELD_CACHE`` is ``0``, ``false``, ``no`` or ``off``."""
    return os.environ.get("CLM_FREEFIELD_CACHE", "1").strip().lower() not in ("0", "false", "no", "off")


def cache_dir() -> Path:
    """The directory of the entries (see the module docstring); not created here."""
    base = os.environ.get("CLM_CACHE_DIR")
    if base:
        return Path(base) / "freefield"
    xdg = os.environ.get("XDG_CACHE_HOME")
    root = Path(xdg) if xdg else Path.home() / ".cache"
    return root / "clm" / "freefield"


@lru_cache(maxsize=1)
def code_revision() -> str:
    """SHA-256 of the sources in :data:`SOURCES` (hex)."""
    pkg = Path(__file__).resolve().parent.parent
    h = hashlib.sha256()
    for rel in SOURCES:
        h.update(rel.encode())
        h.update((pkg / rel).read_bytes())
    return h.hexdigest()


def _profile_values(profile: SoilProfile) -> list[dict[str, str]]:
    return [{f.name: repr(getattr(lay, f.name)) for f in fields(lay)} for lay in profile.layers]


def model_key(profile: SoilProfile, receivers: Array, **values: float) -> tuple[str, str]:
    """(key, key text) of a model: the profile's layers, the receivers and the named scalar ``values``."""
    text = json.dumps({
        "code": code_revision(),
        "layers": _profile_values(profile),
        "receivers": [[repr(float(x)), repr(float(y))] for x, y in np.asarray(receivers, dtype=float)],
        **{k: repr(float(v)) for k, v in sorted(values.items())},
    }, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest(), text


def load(key: str, text: str) -> dict[str, Any] | None:
    """The arrays of entry ``key`` whose key text is ``text``, or None (absent, unreadable, other key text)."""
    if not cache_enabled():
        return None
    path = cache_dir() / f"{key}.npz"
    try:
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:
            if str(z["key"]) != text:
                log.warning("free-field cache %s: key text differs; ignored", path)
                return None
            return {name: z[name] for name in ARRAYS}
    except FileNotFoundError:
        return None
    except (OSError, KeyError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        log.warning("free-field cache %s: unreadable (%s); ignored", path, exc)
        return None


def store(key: str, text: str, arrays: dict[str, Any]) -> Path | None:
    """Write entry ``key`` atomically; None when the cache is off or its directory is not writable."""
    if not cache_enabled():
        return None
    d = cache_dir()
    try:
        d.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{key}.", suffix=".npz", dir=d)
        try:
            with os.fdopen(fd, "wb") as fh:
                members: dict[str, Any] = {name: np.asarray(arrays[name]) for name in ARRAYS}
                np.savez(fh, key=np.array(text), **members)
            os.replace(tmp, d / f"{key}.npz")
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
    except OSError as exc:
        log.warning("free-field cache %s: not written (%s)", d, exc)
        return None
    return d / f"{key}.npz"
