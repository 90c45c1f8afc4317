"""The command line shared by ``bags/*/regenerate.py`` (:mod:`clm_core.synthetic.shipped`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from clm_core.synthetic.shipped import regenerate


@dataclass(frozen=True)
class _Written:
    path: Path


def _recipe(payload: bytes) -> Any:
    """A bag writer that refuses an existing directory, as the real ones do."""

    def write(path: Path, *, storage: Any) -> _Written:
        path.mkdir()  # raises FileExistsError when the old bag was not removed
        (path / f"data.{storage}").write_bytes(payload)
        return _Written(path)

    return write


def test_regenerate_replaces_bags_keeps_readme_and_reports_sizes(tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    old = tmp_path / "a"
    old.mkdir()
    (old / "stale.mcap").write_bytes(b"old")
    (old / "README.md").write_text("hand-written\n", encoding="utf-8")
    bags = {"a": _recipe(b"x" * 2_000_000), "b": _recipe(b"y" * 10)}

    assert regenerate("doc", tmp_path / "unused", bags, ["--out", str(tmp_path), "--storage", "sqlite3"]) == 0

    assert sorted(p.name for p in old.iterdir()) == ["README.md", "data.sqlite3"]
    assert (old / "README.md").read_text(encoding="utf-8") == "hand-written\n"
    assert sorted(p.name for p in (tmp_path / "b").iterdir()) == ["data.sqlite3"]
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith(f"{old}: 2.00 MB (") and out[1].startswith(f"{tmp_path / 'b'}: 0.00 MB (")


def test_regenerate_refuses_an_unknown_storage(tmp_path: Path) -> None:
    with pytest.raises(SystemExit):
        regenerate("doc", tmp_path, {"a": _recipe(b"")}, ["--storage", "rosbag1"])
    assert not (tmp_path / "a").exists()
