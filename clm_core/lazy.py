"""Names of a package imported on first use (a module-level ``__getattr__``, PEP 562).

A package that re-exports names from heavy submodules (numba kernels,
scipy) keeps its import light by resolving each name only when it is first
read::

    _LAZY = {"simulate": "coupled", "load_vehicle": "presets"}
    __getattr__ = lazy_getattr(__name__, _LAZY)

Static checkers see the names through ``if TYPE_CHECKING:`` imports.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any


def lazy_getattr(package: str, table: Mapping[str, str]) -> Callable[[str], Any]:
    """A module ``__getattr__`` that imports ``package.<table[name]>`` and returns its ``name``.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    table : mapping of str to str
        Public name -> submodule (relative to ``package``) that defines it.

    Returns
    -------
    callable
        ``__getattr__(name)``; raises :class:`AttributeError` for a name not in
        ``table``, as Python does for a missing module attribute.
    """

    def getattr_(name: str) -> Any:
        module = table.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(f"{package}.{module}"), name)

    return getattr_


__all__ = ["lazy_getattr"]
