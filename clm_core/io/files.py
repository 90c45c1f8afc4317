"""Writers of the generic file formats: strict JSON and NPZ (one writer each, used by every module that writes them).

- :func:`write_json` / :func:`dumps_json` / :func:`to_jsonable`: every
  ``summary.json``, ``index.json``, study file and the calibration node's
  ``metrics_json``: numpy values as plain numbers, non-finite numbers as
  ``null`` (strict JSON any reader accepts).
- :func:`write_npz`: every ``.npz`` archive, one array at a time (memory maps
  are streamed, not copied), no pickling.

The time-history layouts written with them are in :mod:`clm_core.outputs.history`.
"""

from __future__ import annotations

import json
import math
import zipfile
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.lib.format import write_array

__all__ = ["dumps_json", "to_jsonable", "write_json", "write_npz"]


# ----------------------------------------------------------------------------- JSON


def to_jsonable(obj: Any) -> Any:
    """``obj`` as plain JSON values (recursively).

    Mappings become dicts with string keys, sequences and numpy arrays lists,
    numpy scalars Python numbers, paths strings; non-finite floats become
    ``None`` (``null``) so that the text is strict JSON any reader accepts.

    Parameters
    ----------
    obj : object
        Summary data (dicts, lists, numbers, numpy values, strings, paths).

    Returns
    -------
    object
        The same data built of dict, list, str, int, float, bool and None.
    """
    if isinstance(obj, Mapping):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, (str, bool)) or obj is None:
        return obj
    if isinstance(obj, Path):
        return str(obj)
    if hasattr(obj, "tolist"):
        return to_jsonable(obj.tolist())
    if isinstance(obj, int):
        return obj
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    try:
        v = float(obj)
    except (TypeError, ValueError):
        return str(obj)
    return v if math.isfinite(v) else None


def dumps_json(data: Any, indent: int | None = 2) -> str:
    """Strict JSON text of ``data`` (:func:`to_jsonable`)."""
    return json.dumps(to_jsonable(data), indent=indent, allow_nan=False)


def write_json(path: str | Path, data: Any) -> Path:
    """Write ``data`` to ``path`` as indented strict JSON with a final newline; return the path."""
    p = Path(path)
    p.write_text(dumps_json(data) + "\n", encoding="utf-8")
    return p


# ----------------------------------------------------------------------------- NPZ


def write_npz(path: str | Path, arrays: Mapping[str, Any] | Iterable[tuple[str, Any]], compress: bool = False) -> Path:
    """Write arrays to an NPZ archive, one array at a time (memory maps are streamed, not copied).

    Parameters
    ----------
    path : path
        The ``.npz`` file (overwritten).
    arrays : mapping or iterable of (name, array)
        Arrays in file order; each is stored as ``name.npy`` without pickling.
    compress : bool
        Deflate the members (as :func:`numpy.savez_compressed`); default stored.

    Returns
    -------
    Path
        ``path``; :func:`numpy.load` reads it.
    """
    items = arrays.items() if isinstance(arrays, Mapping) else arrays
    mode = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    p = Path(path)
    with zipfile.ZipFile(p, "w", compression=mode, allowZip64=True) as zf:
        for name, arr in items:
            with zf.open(f"{name}.npy", "w", force_zip64=True) as fh:
                write_array(fh, np.asanyarray(arr), allow_pickle=False)
    return p
