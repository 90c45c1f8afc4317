"""What determines a case, resolved on the client: file contents, parameter values, the code revision.

A case's identity (the result store's key, :func:`identity_key`) is a SHA-256 of
everything that determines its result:

- its resolved settings (defaults filled in), with every file-valued setting
  (a soil or track YAML, a parameter file, a vehicle file, a profile CSV, a
  bag, a channel map) replaced by the SHA-256 of the file's *content*;
- the resolved model parameters (their values, :meth:`clm_core.params.ModelParams.to_dict`),
  so an edited soil file changes the key of exactly the cases that use it;
- the code revision (:func:`code_revision`): a hash of every file of the
  clm_core package actually installed (sources and presets), not the version
  string alone.

Files are read by the client, relative paths from *its* working directory
(:func:`ship`), and their contents travel with the task: a worker writes them
into a content-addressed folder of its own temporary directory
(:func:`materialise`) and never opens a path of the client's. A worker whose
installed clm_core differs from the client's refuses the case
(:func:`check_code`).
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import shutil
import tempfile
import uuid
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from clm_core.errors import ParameterError

#: Hex digits of a store key.
KEY_DIGITS = 16

#: Most bytes shipped with one input (a bag and its channel map included) [B].
MAX_SHIPPED_BYTES = 512 * 1024 * 1024


@dataclass(frozen=True)
class Shipped:
    """A file or directory read by the client, to be rebuilt on a worker (:func:`materialise`).

    Attributes
    ----------
    name : str
        Base name of the file or directory (kept on the worker: a run labels
        its model and vehicle by the file's stem).
    files : tuple of (str, bytes)
        ``(relative path, content)``; paths start with ``name`` (a file: just ``name``).
    sha256 : str
        Hash of the contents (and of the relative paths inside a directory; not of ``name``).
    source : str
        Absolute path on the client (for records and messages only; workers never open it).
    """

    name: str
    files: tuple[tuple[str, bytes], ...]
    sha256: str
    source: str

    @property
    def size(self) -> int:
        """Bytes of content."""
        return sum(len(b) for _, b in self.files)

    def identity(self) -> dict[str, str]:
        """What the case key holds for this input: its content hash (not its name, nor the client's path)."""
        return {"sha256": self.sha256}


def ship(path: str | Path, label: str, base: str | Path | None = None) -> Shipped:
    """Read a file or a directory (recursively) on the client.

    Parameters
    ----------
    path : path
        Relative paths are taken from ``base`` (default: this process's working directory).
    label : str
        What the path is, for the messages (``soil``, ``bag``, ...).
    base : path, optional
        The folder relative paths start from.

    Raises
    ------
    ParameterError
        The path does not exist or cannot be read, or holds more than :data:`MAX_SHIPPED_BYTES`.
    """
    p = Path(path)
    if not p.is_absolute():
        p = Path(base or Path.cwd()) / p
    p = p.resolve()
    if not p.exists():
        raise ParameterError(f"{label} = {str(path)!r}: no such file (relative paths are read from "
                             f"{base or Path.cwd()})")
    members = [p] if p.is_file() else sorted(c for c in p.rglob("*") if c.is_file())
    total = sum(m.stat().st_size for m in members)
    if total > MAX_SHIPPED_BYTES:
        raise ParameterError(f"{label} = {str(path)!r}: {total} bytes; at most {MAX_SHIPPED_BYTES} are shipped to "
                             "the workers")
    h = hashlib.sha256()
    files: list[tuple[str, bytes]] = []
    for m in members:
        rel = p.name if m == p else f"{p.name}/{m.relative_to(p).as_posix()}"
        try:
            data = m.read_bytes()
        except OSError as exc:
            raise ParameterError(f"{label} = {str(path)!r}: cannot read {m} ({exc.strerror})") from None
        files.append((rel, data))
        inner = "" if m == p else m.relative_to(p).as_posix()  # the top name is not content
        h.update(inner.encode() + b"\0" + hashlib.sha256(data).digest())
    return Shipped(p.name, tuple(files), h.hexdigest(), str(p))


def inputs_root() -> Path:
    """This process's folder of materialised inputs (in the temporary directory, one per user)."""
    return Path(tempfile.gettempdir()) / f"clm-study-inputs-{os.getuid()}"


def materialise(item: Shipped, root: str | Path | None = None) -> Path:
    """Rebuild a shipped file or directory on this machine; return its path (``root/<hash>/<name>``).

    Content-addressed: an input already rebuilt (same hash) is reused; a new
    one is written into a temporary folder and renamed, so concurrent workers
    on one host never see half a file.
    """
    base = Path(root) if root is not None else inputs_root()
    final = base / item.sha256[:32]
    if not (final / item.name).exists():
        tmp = base / f".{item.sha256[:32]}.{uuid.uuid4().hex[:8]}"
        for rel, data in item.files:
            dest = tmp / rel
            dest.parent.mkdir(parents=True, exist_ok=True)
            dest.write_bytes(data)
        try:
            os.rename(tmp, final)
        except OSError:  # another process of this host wrote the same content first
            shutil.rmtree(tmp, ignore_errors=True)
    return final / item.name


def code_files(package: str | Path | None = None) -> list[Path]:
    """Every file of the installed clm_core package (sources, presets), byte-code caches excluded, sorted."""
    root = Path(package) if package is not None else Path(__file__).resolve().parents[1]
    return sorted(p for p in root.rglob("*") if p.is_file() and "__pycache__" not in p.parts
                  and p.suffix not in (".pyc", ".pyo", ".nbi", ".nbc"))


@functools.lru_cache(maxsize=1)
def code_revision() -> str:
    """SHA-256 of the clm_core package this process runs: the relative path and content of every file.

    Computed once per process (the first call, at a worker's warm-up): it
    describes the code the process imported, not later edits on disk.
    """
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for p in code_files(root):
        h.update(p.relative_to(root).as_posix().encode() + b"\0" + hashlib.sha256(p.read_bytes()).digest())
    return h.hexdigest()


class CodeMismatch(Exception):
    """A worker runs another clm_core than the client (its cases would not be the client's cases)."""


def check_code(expected: str) -> None:
    """Raise :class:`CodeMismatch` unless this process runs the clm_core revision ``expected``."""
    mine = code_revision()
    if mine != expected:
        from clm_core import __version__

        raise CodeMismatch(f"this worker runs other clm_core code (revision {mine[:12]}, version {__version__}) "
                           f"than the client (revision {expected[:12]}): install the same clm_core on every worker")


def identity_key(identity: Mapping[str, Any]) -> str:
    """The store key of an identity mapping: :data:`KEY_DIGITS` hex digits of the SHA-256 of its sorted JSON."""
    text = json.dumps(dict(identity), sort_keys=True, default=repr)
    return hashlib.sha256(text.encode()).hexdigest()[:KEY_DIGITS]


# ----------------------------------------------------------------------------- study cases


#: Study settings that may name a file (read on the client, shipped to the workers).
FILE_SETTINGS: tuple[str, ...] = ("track", "soil", "params_file", "vehicle", "irregularity")


def names_a_file(name: str, value: Any) -> bool:
    """True if the setting ``name = value`` names a file, by the rule of the loader that reads it.

    ``track``, ``soil``, ``vehicle``: a ``.yaml``/``.yml`` name or an existing
    path (else a shipped preset); ``params_file``: any value; ``irregularity``:
    anything but a spectrum name or ``none`` (a profile CSV).
    """
    if name not in FILE_SETTINGS or value is None or str(value).strip() == "":
        return False
    text = str(value).strip()
    if name == "params_file":
        return True
    if name == "irregularity":
        from clm_core.vehicle.irregularity import SPECTRA

        return text.lower() != "none" and text.lower() not in SPECTRA
    return Path(text).suffix in (".yaml", ".yml") or Path(text).exists()


@dataclass(frozen=True)
class CaseInput:
    """A study case as shipped to a worker (:func:`clm_core.studies.runner.run_case`).

    Attributes
    ----------
    settings : dict
        The case's checked settings as given (file settings hold the client's text).
    files : dict
        ``{setting: Shipped}``: the content of every file the case reads.
    code : str
        The client's :func:`code_revision`; a worker with another refuses the case.
    key : str
        The case's identity (:func:`identity_key` of settings, file hashes, parameter values, code).
    """

    settings: dict[str, Any]
    files: dict[str, Shipped]
    code: str
    key: str


class CaseResolver:
    """Resolves study cases on the client: reads each file once, builds each base model once.

    Parameters
    ----------
    base : path, optional
        Folder that relative paths start from (default: the working directory).
    """

    def __init__(self, base: str | Path | None = None) -> None:
        self.base = Path(base) if base is not None else Path.cwd()
        self.code = code_revision()
        self._files: dict[tuple[str, str], Shipped] = {}
        self._models: dict[tuple[Any, ...], Any] = {}

    def file(self, name: str, value: Any, where: str = "") -> Shipped:
        """The shipped content of the file the setting ``name = value`` names."""
        ident = (name, str(value).strip())
        if ident not in self._files:
            try:
                self._files[ident] = ship(ident[1], name, self.base)
            except ParameterError as exc:
                rule = (" (not a spectrum, 'none', nor an existing CSV file)" if name == "irregularity" else "")
                raise ParameterError(f"{where}{exc}{rule}") from None
        return self._files[ident]

    def parameters(self, case_settings: Mapping[str, Any], files: Mapping[str, Shipped]) -> Any:
        """The resolved model parameters of a case (``ModelParams.to_dict()``, without its name), or the error
        that building them gives (the worker then fails the case with the same error)."""
        from clm_core.errors import ClmError
        from clm_core.studies.runner import model_settings

        model, overrides = model_settings({**case_settings, **{k: f.source for k, f in files.items()}})
        ident = (model["track"], model["soil"], model["model"], model["params_file"])
        if ident not in self._models:
            from clm_core.params import model_from_settings

            try:
                self._models[ident] = model_from_settings(*ident)
            except (ClmError, ValueError) as exc:
                self._models[ident] = f"{type(exc).__name__}: {exc}"
        base = self._models[ident]
        if isinstance(base, str):
            return base
        try:
            mp = base.override(**overrides) if overrides else base
        except (ClmError, ValueError) as exc:
            return f"{type(exc).__name__}: {exc}"
        values = mp.to_dict()
        values.pop("name", None)  # a label made of the file names, not a value of the model
        return values

    def resolve(self, case_settings: Mapping[str, Any], where: str = "") -> CaseInput:
        """The :class:`CaseInput` of a case with checked settings (:func:`clm_core.studies.spec.check_settings`).

        Raises
        ------
        ParameterError
            A file the case names does not exist or cannot be read (``where`` starts the message).
        """
        from clm_core.studies.spec import resolved

        s = dict(case_settings)
        full = resolved(s)
        files = {n: self.file(n, full[n], where) for n in FILE_SETTINGS if names_a_file(n, full.get(n))}
        ident = {**full, **{k: f.identity() for k, f in files.items()}}
        key = identity_key({"settings": ident, "parameters": self.parameters(s, files), "code": self.code})
        return CaseInput(s, files, self.code, key)
