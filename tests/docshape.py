"""Docstrings against code: the numpydoc ``Parameters`` sections of clm_core name the real parameters.

Used by ``tests/test_docstrings.py``; ``python -m tests.docshape`` lists the mismatches.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import re
from collections.abc import Callable, Iterator
from typing import Any

import clm_core

_HEADER = re.compile(r"^(\s*)(Parameters|Other Parameters)\s*$")
_SECTION_END = re.compile(r"^\s*[A-Z][A-Za-z ]+\s*$")


def documented(doc: str | None) -> list[str] | None:
    """The names a numpydoc docstring's ``Parameters`` (and ``Other Parameters``) sections list (None: no section).

    An entry is a line at the section's indentation: ``name : type``, ``name``, ``a, b : type``, ``*args``.
    """
    if not doc:
        return None
    lines = inspect.cleandoc(doc).splitlines()
    names: list[str] | None = None
    i = 0
    while i < len(lines):
        m = _HEADER.match(lines[i])
        if not (m and i + 1 < len(lines) and set(lines[i + 1].strip()) == {"-"}):
            i += 1
            continue
        names = names if names is not None else []
        indent = len(m.group(1))
        i += 2
        while i < len(lines):
            line = lines[i]
            if i + 1 < len(lines) and set(lines[i + 1].strip()) == {"-"} and _SECTION_END.match(line):
                break  # the next section
            if line.strip() and len(line) - len(line.lstrip()) == indent:
                head = line.split(" : ", 1)[0].strip()
                for part in head.split(","):
                    name = part.strip().lstrip("*")
                    if name.isidentifier():
                        names.append(name)
            i += 1
    return names


def real(fn: Callable[..., Any]) -> list[str] | None:
    """The parameters of ``fn`` a caller passes (not self/cls), or None if there is no signature."""
    try:
        sig = inspect.signature(fn)
    except (TypeError, ValueError):
        return None
    return [p.name for p in sig.parameters.values() if p.name not in ("self", "cls")]


def public_callables() -> Iterator[tuple[str, Callable[..., Any], str | None]]:
    """(qualified name, callable, docstring whose Parameters describe it) of every public function, class and
    method defined in clm_core (a class: its docstring describes ``__init__``)."""
    names = ["clm_core", *sorted(m.name for m in pkgutil.walk_packages(clm_core.__path__, "clm_core."))]
    for modname in names:
        mod = importlib.import_module(modname)
        for name, obj in sorted(vars(mod).items()):
            if name.startswith("_") or getattr(obj, "__module__", None) != modname:
                continue
            if inspect.isclass(obj):
                yield f"{modname}.{name}", obj, obj.__doc__
                for mname, m in sorted(vars(obj).items()):
                    if mname.startswith("_"):
                        continue
                    f = m.__func__ if isinstance(m, (staticmethod, classmethod)) else m
                    if inspect.isfunction(f):
                        yield f"{modname}.{name}.{mname}", getattr(obj, mname), f.__doc__
            elif inspect.isfunction(obj):
                yield f"{modname}.{name}", obj, obj.__doc__


def mismatches() -> list[str]:
    """Every callable whose Parameters section lists a name it does not take, or leaves out one it takes."""
    out = []
    for qual, fn, doc in public_callables():
        docs = documented(doc)
        if docs is None:
            continue
        params = real(fn)
        if params is None:
            continue
        extra = [d for d in docs if d not in params]
        missing = [p for p in params if p not in docs]
        if extra or missing:
            out.append(f"{qual}: documented but not a parameter {extra}; a parameter not documented {missing}")
    return out


def counted() -> tuple[int, int]:
    """(callables with a Parameters section, those without) among the public callables."""
    with_section = without = 0
    for _, _, doc in public_callables():
        if documented(doc) is None:
            without += 1
        else:
            with_section += 1
    return with_section, without


if __name__ == "__main__":
    found = mismatches()
    print(f"{len(found)} mismatches; (with a Parameters section, without) = {counted()}")
    for line in found:
        print("  ", line)
