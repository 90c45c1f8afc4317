"""The generic file writers (clm_core.io.files): strict JSON, NPZ streamed one array at a time."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from clm_core.io.files import dumps_json, to_jsonable, write_json, write_npz


def test_json_is_strict_and_plain(tmp_path: Path) -> None:
    data = {"a": np.float64(1.5), "b": np.arange(3), "nan": float("nan"), "inf": np.inf, 3: (np.int32(4), True),
            "nested": [{"x": np.array([1.0, np.nan])}], "path": tmp_path, "none": None, "flag": np.bool_(False)}
    plain = to_jsonable(data)
    assert plain == {"a": 1.5, "b": [0, 1, 2], "nan": None, "inf": None, "3": [4, True],
                     "nested": [{"x": [1.0, None]}], "path": str(tmp_path), "none": None, "flag": False}
    assert type(plain["b"][0]) is int and type(plain["flag"]) is bool
    p = write_json(tmp_path / "s.json", data)
    text = p.read_text()
    assert text.endswith("}\n") and "NaN" not in text and "Infinity" not in text
    # any strict reader accepts it
    assert json.loads(text, parse_constant=lambda c: pytest.fail(f"non-standard constant {c}")) == plain
    assert dumps_json([1, 2], indent=None) == "[1, 2]"


def test_npz_writer_streams_memory_maps_and_compresses(tmp_path: Path) -> None:
    from numpy.lib.format import open_memmap

    mm = open_memmap(tmp_path / "m.npy", mode="w+", dtype=np.float64, shape=(1000, 7))
    mm[:] = np.arange(7000.0).reshape(1000, 7)
    arrays = {"m": mm[:600], "s": np.array(0.25), "txt": np.array('{"k": 1}'), "i": np.arange(5, dtype=np.int64)}
    write_npz(tmp_path / "a.npz", arrays)
    write_npz(tmp_path / "b.npz", list(arrays.items()), compress=True)
    for name in ("a.npz", "b.npz"):
        with np.load(tmp_path / name) as z:
            assert z.files == ["m", "s", "txt", "i"]
            np.testing.assert_array_equal(z["m"], np.arange(4200.0).reshape(600, 7))
            assert float(z["s"]) == 0.25 and json.loads(str(z["txt"])) == {"k": 1} and z["i"].dtype == np.int64
    assert (tmp_path / "b.npz").stat().st_size < 0.5 * (tmp_path / "a.npz").stat().st_size
