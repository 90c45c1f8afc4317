"""docs/architecture.md against the tree: every path it names exists, every code name it gives is defined.

The page drifted from the code in 7 places before issue 22 (``io/history.py``
after the history files moved, names of removed helpers, ...). Checked here,
source text only (nothing imported):

- every path in it (a token with ``/`` or ending in ``.py``/``.md``/``.yaml``, in
  backticks or in the two diagrams) is a file or directory of the repository:
  ``clm_core/...``, ``tests/...``, ``docs/...`` from the root, ``clm_ros/...``
  in ``ros2_ws/src/clm_ros``, ``launch/...`` there too, a bare ``x.py`` or
  ``io/x.py`` under ``clm_core`` (the diagrams name modules relative to it);
- every code name in backticks (``OnlineTrackModel.from_settings``,
  ``lag_figures``) is defined (``def``, ``class`` or an assignment) in
  ``clm_core``, ``clm_ros`` or ``tests``, or is a ``clm_msgs`` message type.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "architecture.md"
SOURCES = [ROOT / "clm_core", ROOT / "ros2_ws" / "src" / "clm_ros", ROOT / "tests"]
#: Where a relative path of the page may be rooted (the diagrams name modules relative to clm_core).
BASES = [ROOT, ROOT / "clm_core", ROOT / "docs", ROOT / "ros2_ws" / "src", ROOT / "ros2_ws" / "src" / "clm_ros"]

_PATH = re.compile(r"(?<![\w./-])((?:[\w.*-]+/)+[\w.*-]*|[\w-]+\.(?:py|md|yaml))(?![\w/])")
#: First parts that make a token with ``/`` a path (else ``NPZ/CSV``, ``1/3-octave`` are words).
_ROOTS = ("clm_core", "clm_ros", "clm_msgs", "tests", "docs", "ros2_ws", "launch", "bags", "benchmarks", "scripts",
          "examples", "presets")
_EXTENSIONS = (".py", ".md", ".yaml", ".msg", ".srv", ".action", ".toml", ".sh")
_CODE = re.compile(r"`([^`]+)`")
#: Backticked words that are not names of this code (Python's, an entry-point group).
_NOT_CODE = {"NamedTuple", "TYPE_CHECKING", "importlib.import_module", "clm.commands"}
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*$")


def paths(text: str) -> set[str]:
    """The path-like tokens of ``text`` (``clm_core/io/bags.py``, ``solver/``, ``settings.py``; no URLs)."""
    units = {p.name for p in (ROOT / "clm_core").iterdir()} | {p.stem for p in (ROOT / "clm_core").glob("*.py")}
    out = set()
    for m in _PATH.finditer(text.replace("://", " ").replace("<br/>", " ")):
        p = m.group(1).rstrip(".")
        first = p.split("/")[0]
        if p.endswith(_EXTENSIONS) or first in _ROOTS or first in units:
            out.add(p)
    return out


def exists(path: str) -> bool:
    """``path`` (globs allowed) is a file or directory under one of :data:`BASES`; a bare name (``window.py``,
    the diagrams' modules of a package named before) anywhere under clm_core or clm_ros."""
    p = path.rstrip("/")
    if any(any(base.glob(p)) if "*" in p else (base / p).exists() for base in BASES):
        return True
    return "/" not in p and any(any(src.rglob(p)) for src in SOURCES)


def _defined_names() -> set[str]:
    names: set[str] = set()
    pat = re.compile(r"^[ \t]*(?:async[ \t]+)?(?:def|class)[ \t]+(\w+)|^[ \t]*(\w+)[ \t]*(?::[^=\n]*)?=", re.M)
    for src in SOURCES:
        for f in src.rglob("*.py"):
            for m in pat.finditer(f.read_text(encoding="utf-8")):
                names.add(m.group(1) or m.group(2))
    names |= {f.stem for f in (ROOT / "ros2_ws" / "src" / "clm_msgs").rglob("*.msg")}  # message types
    return names


def code_names(text: str) -> set[str]:
    """Dotted code names in backticks (not paths, options, commands, file names or literal values)."""
    out = set()
    for m in _CODE.finditer(re.sub(r"```.*?```", " ", text, flags=re.S)):
        tok = m.group(1).strip()
        files = tok.endswith((*_EXTENSIONS, ".json", ".npz", ".png", ".csv"))
        if _NAME.match(tok) and not files and tok not in _NOT_CODE:
            out.add(tok)
    return out


def test_every_path_in_the_architecture_page_exists() -> None:
    found = paths(DOC.read_text(encoding="utf-8"))
    assert len(found) > 40, sorted(found)
    missing = sorted(p for p in found if not exists(p))
    assert missing == [], f"docs/architecture.md names paths that do not exist: {missing}"


def test_every_code_name_in_the_architecture_page_is_defined() -> None:
    defined = _defined_names()
    names = code_names(DOC.read_text(encoding="utf-8"))
    assert len(names) > 20, sorted(names)
    # a dotted name counts by its last part; module names (clm_core, clm_ros, rclpy, ...) are paths, not checked here
    unknown = sorted(n for n in names if n.split(".")[-1] not in defined and "." not in n.split(".")[-1]
                     and not _is_module(n))
    assert unknown == [], f"docs/architecture.md names code that is not defined: {unknown}"


def _is_module(name: str) -> bool:
    parts = name.split(".")
    if parts[0] in ("clm_core", "clm_ros", "clm_msgs", "rclpy", "rosbags", "numba", "scipy", "numpy", "dask",
                    "matplotlib", "launch", "launch_ros"):
        return True
    return exists("/".join(parts) + ".py") or exists("/".join(parts))


def test_the_checks_see_a_stale_path_and_name() -> None:
    text = "history in `clm_core/io/history.py`, see `io/plots/` and `OnlineTrackModel.no_such_factory`"
    assert {"clm_core/io/history.py", "io/plots/"} <= paths(text)
    assert not exists("clm_core/io/history.py") and not exists("io/plots/") and exists("clm_core/outputs/plots/")
    assert "OnlineTrackModel.no_such_factory" in code_names(text)
    assert "no_such_factory" not in _defined_names() and "from_settings" in _defined_names()
