"""The ``clm`` command: thin argument parsing around the core.

Sub-commands live in :mod:`clm_core.commands` (one module each, discovered
here), and in ``clm_ros.commands`` when the ROS layer is installed (bag
replay, record, play, the demo launcher). Errors from the core (:class:`clm_core.errors.ClmError`) become one
readable line on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
from collections.abc import Sequence

from clm_core import __version__, commands
from clm_core.errors import ClmError


def build_parser() -> argparse.ArgumentParser:
    """Return the ``clm`` parser with every sub-command registered."""
    parser = argparse.ArgumentParser(
        prog="clm",
        description="Coupled lumped mass (CLM) railway track-soil dynamics.",
    )
    parser.add_argument("--version", action="version", version=f"clm {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    packages = [commands]
    try:  # commands of the ROS layer (bags, replay), when clm_ros is installed
        packages.append(importlib.import_module("clm_ros.commands"))
    except ImportError:
        pass
    for package in packages:
        for info in sorted(pkgutil.iter_modules(package.__path__), key=lambda m: m.name):
            module = importlib.import_module(f"{package.__name__}.{info.name}")
            register = getattr(module, "register", None)
            if register is not None:
                register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``clm`` command; return the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        code: int = args.func(args)
    except ClmError as exc:
        print(f"clm {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except FileNotFoundError as exc:
        print(f"clm {args.command}: error: {exc}", file=sys.stderr)
        return 2
    return code


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
