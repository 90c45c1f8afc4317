"""The command line of the scripts that regenerate the shipped sample bags (``bags/*/regenerate.py``).

Each script names its bags and how each is written; this module parses
``--storage`` and ``--out``, replaces the old bag directories (a
hand-written ``README.md`` inside one survives) and prints what it wrote.
"""

from __future__ import annotations

import argparse
import shutil
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol


class WrittenBag(Protocol):
    """What a bag writer returns: at least the bag directory."""

    @property
    def path(self) -> Path:
        """The bag directory."""
        ...


class BagRecipe(Protocol):
    """Writes one bag: ``recipe(directory, storage='mcap' or 'sqlite3')`` -> the written bag."""

    def __call__(self, path: Path, *, storage: Any) -> WrittenBag:
        """Write the bag at ``path`` with the storage plugin ``storage``."""
        ...


def regenerate(doc: str, here: Path, bags: Mapping[str, BagRecipe], argv: Sequence[str] | None = None) -> int:
    """Regenerate shipped bags: parse the command line, write each bag anew, print its size.

    Parameters
    ----------
    doc : str
        The script's docstring (its ``--help`` text).
    here : Path
        Default output directory (the script's own).
    bags : mapping name -> recipe
        Bag directory name -> function writing it (directory, ``storage=``).
    argv : sequence of str, optional
        Arguments (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit status 0.
    """
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--storage", default="mcap", choices=("mcap", "sqlite3"))
    ap.add_argument("--out", default=str(here), help="directory of the bags (default: this one)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name, write in bags.items():
        path = out / name
        readme = path / "README.md"
        keep = readme.read_text(encoding="utf-8") if readme.is_file() else None
        if path.exists():
            shutil.rmtree(path)
        t = time.perf_counter()
        bag = write(path, storage=args.storage)
        if keep is not None:  # the hand-written README of a shipped bag survives regeneration
            readme.write_text(keep, encoding="utf-8")
        size = sum(f.stat().st_size for f in bag.path.iterdir())
        print(f"{bag.path}: {size / 1e6:.2f} MB ({time.perf_counter() - t:.1f} s)")
    return 0
