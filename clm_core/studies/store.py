"""The result store of a study directory and the results table.

``DIR/cases/<key>.json`` holds one finished case (its row, settings and the
``clm simulate`` command of the same run alone), written atomically: to a
temporary file in the same directory, flushed to disk, then renamed over the
final name, so a study killed at any instant leaves each case either stored
whole or not at all. A study started again on the same directory reads the
store and runs only the cases it lacks (:func:`clm_core.studies.study.run_study`).

``DIR/results.parquet`` and ``DIR/results.csv`` hold the table, one row per
case in case order (:func:`write_table`).
"""

from __future__ import annotations

import csv
import json
import math
import os
import uuid
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from clm_core.errors import InputError
from clm_core.io.files import dumps_json


class ResultStore:
    """Finished cases of one study directory, one JSON file per case key.

    Parameters
    ----------
    root : path
        The study directory; the store is ``root/cases``.
    """

    def __init__(self, root: str | Path) -> None:
        self.dir = Path(root) / "cases"

    def path(self, key: str) -> Path:
        """File of the case ``key``."""
        return self.dir / f"{key}.json"

    def load(self) -> dict[str, dict[str, Any]]:
        """Every stored record by key (left-over temporary files of a killed run are removed)."""
        out: dict[str, dict[str, Any]] = {}
        if not self.dir.is_dir():
            return out
        for p in self.dir.iterdir():
            if p.name.startswith("."):  # a temporary file of a write that was interrupted
                p.unlink(missing_ok=True)
                continue
            if p.suffix != ".json":
                continue
            try:
                rec = json.loads(p.read_text())
            except (OSError, ValueError):
                continue  # unreadable: the case is run again
            if isinstance(rec, dict) and rec.get("key") == p.stem and isinstance(rec.get("row"), dict):
                out[p.stem] = rec
        return out

    def put(self, record: Mapping[str, Any]) -> Path:
        """Store one case atomically (``record['key']`` names it); return its file."""
        self.dir.mkdir(parents=True, exist_ok=True)
        final = self.path(str(record["key"]))
        tmp = self.dir / f".{final.stem}.{uuid.uuid4().hex[:8]}.tmp"
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(dumps_json(record) + "\n")
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, final)
        return final

    def clear(self) -> None:
        """Remove every stored case."""
        if self.dir.is_dir():
            for p in self.dir.iterdir():
                p.unlink()


def _cell(v: Any) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return ""
    if isinstance(v, float):
        return repr(v)
    return str(v)


def columns_of(rows: Sequence[Mapping[str, Any]], first: Sequence[str] = (), last: Sequence[str] = ()) -> list[str]:
    """Column names: ``first``, then every other key in order of appearance, then ``last``."""
    seen = dict.fromkeys(first)
    for r in rows:
        seen.update(dict.fromkeys(k for k in r if k not in last))
    seen.update(dict.fromkeys(last))
    return list(seen)


def write_table(rows: Sequence[Mapping[str, Any]], columns: Sequence[str], out: str | Path,
                stem: str = "results") -> list[Path]:
    """Write the rows as ``out/<stem>.parquet`` (pyarrow) and ``out/<stem>.csv``; return both paths.

    Missing values (a failed case's metrics) are nulls in Parquet and empty
    cells in the CSV; floats are written in full (``repr``), so the CSV reads
    back to the same numbers.
    """
    d = Path(out)
    paths = [d / f"{stem}.parquet", d / f"{stem}.csv"]
    _write_parquet(rows, columns, paths[0])
    tmp = paths[1].with_name(f".{paths[1].name}.tmp")
    with open(tmp, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        for r in rows:
            w.writerow([_cell(r.get(c)) for c in columns])
    os.replace(tmp, paths[1])
    return paths


def _write_parquet(rows: Sequence[Mapping[str, Any]], columns: Sequence[str], path: Path) -> None:
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError as exc:  # pragma: no cover - a declared dependency
        raise InputError(f"writing {path.name} needs pyarrow ({exc}); pip install pyarrow") from None
    arrays = {}
    for c in columns:
        vals = [_plain(r.get(c)) for r in rows]
        try:
            arrays[c] = pa.array(vals)
        except (pa.ArrowInvalid, pa.ArrowTypeError):  # mixed kinds in one column: text
            arrays[c] = pa.array([None if v is None else str(v) for v in vals], type=pa.string())
    tmp = path.with_name(f".{path.name}.tmp")
    pq.write_table(pa.table(arrays), tmp)
    os.replace(tmp, path)


def _plain(v: Any) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, (list, tuple)):
        return " ; ".join(str(x) for x in v)
    return v


def read_table(path: str | Path) -> list[dict[str, Any]]:
    """Rows of a results Parquet file (as written by :func:`write_table`)."""
    import pyarrow.parquet as pq

    return list(pq.read_table(path).to_pylist())
