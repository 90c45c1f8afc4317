"""Static checks of the shape of ``clm_core`` (AST only, nothing imported): private reach-ins and import layers.

Used by ``tests/test_code_shape.py`` and ``tests/test_import_contract.py``;
``python -m tests.codeshape`` prints the figures (the before/after of issue 22).

A *unit* is a subpackage of ``clm_core`` (``clm_core.online``) or a module at
its top (``clm_core.track``).
"""

from __future__ import annotations

import ast
import sys
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CORE = ROOT / "clm_core"

#: The layers of clm_core, bottom first: a unit may import units of its own layer or below, never above.
#: Inside a layer, any order (they are peers). ``io`` (timebase, codec, bags, files) sits on the bottom layer
#: alone; ``outputs`` (history files, figures, reports) above the physics whose results it writes.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("errors", "arrays", "checks", "lazy", "progress", "environ", "stacks"),
    ("io",),
    ("params", "settings"),
    ("newmark", "profile", "peaks", "spectra", "frequency", "excitation", "soil", "track"),
    ("solver",),
    ("online", "vehicle"),
    ("halfspace", "calibration"),
    ("freefield",),
    ("outputs",),
    ("synthetic",),
    ("studies",),
    ("commands", "cli"),
)


def unit_of(module: str) -> str:
    """``clm_core.online.model`` -> ``online``; ``clm_core.track`` -> ``track``; ``clm_core`` -> ``""``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def layer_of(unit: str) -> int:
    """Index of the layer of ``unit`` (KeyError for a unit the table does not place)."""
    for i, layer in enumerate(LAYERS):
        if unit in layer:
            return i
    raise KeyError(f"unit {unit!r} of clm_core is in no layer of tests/codeshape.LAYERS")


def modules() -> Iterator[tuple[str, Path]]:
    """(dotted name, path) of every module of clm_core."""
    for path in sorted(CORE.rglob("*.py")):
        rel = path.relative_to(ROOT).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts.pop()
        yield ".".join(parts), path


def _parse(path: Path) -> ast.Module:
    return ast.parse(path.read_text(encoding="utf-8"), str(path))


# ----------------------------------------------------------------------------- imports


@dataclass(frozen=True)
class Import:
    """One import of a clm_core module by another."""

    module: str
    line: int
    target: str
    in_function: bool
    type_only: bool

    def __str__(self) -> str:
        where = " (inside a function)" if self.in_function else ""
        kind = " (TYPE_CHECKING)" if self.type_only else ""
        return f"{self.module.replace('.', '/')}.py:{self.line} imports {self.target}{where}{kind}"


def _resolve(module: str, is_pkg: bool, node: ast.ImportFrom) -> str:
    if node.level == 0:
        return node.module or ""
    base = module.split(".")
    if not is_pkg:
        base = base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _visit(module: str, is_pkg: bool, node: ast.AST, in_function: bool, type_only: bool) -> Iterator[Import]:
    for child in ast.iter_child_nodes(node):
        fn = in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
        to = type_only or (isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test))
        if isinstance(child, ast.Import):
            for a in child.names:
                if a.name.startswith("clm_core."):
                    yield Import(module, child.lineno, a.name, fn, to)
        elif isinstance(child, ast.ImportFrom):
            base = _resolve(module, is_pkg, child)
            if base == "clm_core":  # from clm_core import settings (a module) or __version__ (a name)
                for a in child.names:
                    sub = CORE / a.name
                    if sub.is_dir() or sub.with_suffix(".py").is_file():
                        yield Import(module, child.lineno, f"clm_core.{a.name}", fn, to)
            elif base.startswith("clm_core."):
                yield Import(module, child.lineno, base, fn, to)
        elif isinstance(child, ast.Call) and _dynamic_import(child):
            # importlib.import_module("clm_core.x") / __import__("clm_core.x"): an import all the same
            arg = child.args[0]
            if isinstance(arg, ast.Constant) and isinstance(arg.value, str) and arg.value.startswith("clm_core."):
                yield Import(module, child.lineno, arg.value, fn, to)
        yield from _visit(module, is_pkg, child, fn, to)


def _dynamic_import(call: ast.Call) -> bool:
    f = call.func
    name = f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else ""
    return name in ("import_module", "__import__") and bool(call.args)


def imports() -> Iterator[Import]:
    """Every import of a clm_core module inside clm_core, lazy ones (inside functions), TYPE_CHECKING ones and
    ``importlib.import_module``/``__import__`` of a literal name included."""
    for module, path in modules():
        yield from _visit(module, path.name == "__init__.py", _parse(path), False, False)


def probe_imports(module: str, source: str) -> list[Import]:
    """The clm_core imports of ``source`` as if it were the module ``module`` (tests of the scan)."""
    return list(_visit(module, False, ast.parse(source), False, False))


def upward_imports(found: Iterable[Import] | None = None) -> list[Import]:
    """The imports of a unit of a higher layer by one of a lower layer: at import time, inside functions
    (lazy) and under ``TYPE_CHECKING`` (``type_only``) alike."""
    out = []
    for imp in imports() if found is None else found:
        src, dst = unit_of(imp.module), unit_of(imp.target)
        if not src or not dst or src == dst:
            continue
        if layer_of(dst) > layer_of(src):
            out.append(imp)
    return out


# ----------------------------------------------------------------------------- private reach-ins


@dataclass(frozen=True)
class ReachIn:
    """``obj._name`` in one unit where ``_name`` is private to another unit of clm_core."""

    module: str
    line: int
    expr: str
    owners: tuple[str, ...]

    def __str__(self) -> str:
        return f"{self.module.replace('.', '/')}.py:{self.line} {self.expr} (private to {', '.join(self.owners)})"


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def private_names() -> dict[str, set[str]]:
    """Per unit: the private names it defines (attributes set on self/cls or an object, methods, class and
    module-level names, ``__slots__`` entries, private modules)."""
    out: dict[str, set[str]] = {}
    for module, path in modules():
        unit = unit_of(module)
        names = out.setdefault(unit, set())
        if _private(path.stem):
            names.add(path.stem)
        for node in ast.walk(_parse(path)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and _private(node.name):
                names.add(node.name)
            elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store) and _private(node.attr):
                names.add(node.attr)
            elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store) and _private(node.id):
                names.add(node.id)
            elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and _private(node.target.id):
                names.add(node.target.id)
            elif (isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "__slots__"
                                                       for t in node.targets)):
                for c in ast.walk(node.value):
                    if isinstance(c, ast.Constant) and isinstance(c.value, str) and _private(c.value):
                        names.add(c.value)
    return out


def reach_ins(probes: dict[str, str] | None = None) -> list[ReachIn]:
    """Every ``obj._name`` (obj not ``self``/``cls``) whose private name only another unit of clm_core defines.

    ``probes``: extra modules ``{dotted name: source}`` scanned as if they were part of clm_core (tests).
    """
    defined = private_names()
    out = []
    sources = [(m, p, _parse(p)) for m, p in modules()]
    for name, text in (probes or {}).items():
        sources.append((name, CORE / "probe.py", ast.parse(text)))
    for module, path, tree in sources:
        unit = unit_of(module)
        for node in ast.walk(tree):
            if not (isinstance(node, ast.Attribute) and _private(node.attr)):
                continue
            if isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"):
                continue
            if node.attr in defined.get(unit, ()):
                continue
            owners = tuple(sorted(u for u, names in defined.items() if node.attr in names))
            if owners:
                out.append(ReachIn(module, node.lineno, ast.unparse(node), owners))
        # ``from clm_core.x import _name`` / ``import clm_core.x._mod``: a private name of another unit too
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for a in node.names:
                    if (a.name.startswith("clm_core.") and unit_of(a.name) != unit
                            and any(_private(p) for p in a.name.split("."))):
                        out.append(ReachIn(module, node.lineno, f"import {a.name}", (unit_of(a.name),)))
            elif isinstance(node, ast.ImportFrom):
                base = _resolve(module, path.name == "__init__.py", node)
                if base.startswith("clm_core.") and unit_of(base) != unit:
                    for a in node.names:
                        if _private(a.name) or any(_private(p) for p in base.split(".")):
                            out.append(ReachIn(module, node.lineno, f"from {base} import {a.name}",
                                               (unit_of(base),)))
    return out


def core_private_imports(root: Path | None = None, source: str | None = None) -> list[str]:
    """Imports of a private module or name of ``clm_core`` by the ROS package (``ros2_ws/src`` by default; or
    ``source``, one probe text): ``from clm_core.x._mod import n``, ``from clm_core.x import _n``,
    ``import clm_core.x._mod``. The ROS layer uses the core's public API only."""
    texts = ([("probe.py", source)] if source is not None
             else [(str(p.relative_to(ROOT)), p.read_text(encoding="utf-8"))
                   for p in sorted((root or ROOT / "ros2_ws" / "src").rglob("*.py"))])
    out = []
    for name, text in texts:
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("clm_core"):
                mod = node.module or ""
                for a in node.names:
                    if _private(a.name) or any(_private(p) for p in mod.split(".")):
                        out.append(f"{name}:{node.lineno} from {mod} import {a.name}")
            elif isinstance(node, ast.Import):
                for a in node.names:
                    if a.name.startswith("clm_core.") and any(_private(p) for p in a.name.split(".")):
                        out.append(f"{name}:{node.lineno} import {a.name}")
    return out


def long_modules(limit: int = 700) -> list[tuple[str, int]]:
    """Modules of clm_core longer than ``limit`` lines."""
    return [(m, n) for m, p in modules() if (n := len(p.read_text(encoding="utf-8").splitlines())) > limit]


if __name__ == "__main__":
    ups = upward_imports()
    print(f"upward imports: {len(ups)} ({sum(not i.type_only for i in ups)} at run time)")
    for i in ups:
        print("  ", i)
    ri = reach_ins()
    print(f"private reach-ins across units: {len(ri)}")
    for r in ri:
        print("  ", r)
    cp = core_private_imports()
    print(f"private imports of clm_core by the ROS package: {len(cp)}")
    for c in cp:
        print("  ", c)
    lm = long_modules()
    print(f"modules over 700 lines: {len(lm)}", *(f"{m} {n}" for m, n in lm))
    print("longest module: {} ({} lines)".format(*max(((m, len(p.read_text(encoding="utf-8").splitlines()))
                                                      for m, p in modules()), key=lambda x: x[1])))
    sys.exit(0)
