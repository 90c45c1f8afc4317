"""The ``clm`` command: thin argument parsing around the core.

Sub-commands live in :mod:`clm_core.commands` (one module each, discovered
here) and, for the ROS layer, in packages that register ``register(subparsers)``
functions under the entry-point group ``clm.commands`` (``clm_ros`` declares
replay, record, play and demo in its setup.py). The core never imports the ROS
layer: it only loads what the installed distributions declare.

Errors become one readable line on stderr and exit code 2: errors of the core
(:class:`clm_core.errors.ClmError`), missing files, and bad command-line input
(an option outside its range, a missing argument: :class:`ClmArgumentParser`).

Building the parser imports only light modules (the command modules import
their computing modules inside ``run``), so ``clm --help`` answers quickly.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
from collections.abc import Sequence
from typing import Any, NoReturn

from clm_core import __version__, commands
from clm_core.errors import ClmError
from clm_core.stacks import dump_stacks_on_signal

#: Entry-point group of sub-commands from other distributions (the ROS layer).
ENTRY_POINT_GROUP = "clm.commands"


class UsageError(ClmError):
    """Bad command-line input (raised by :class:`ClmArgumentParser` instead of exiting)."""

    def __init__(self, prog: str, message: str) -> None:
        super().__init__(message)
        self.prog = prog


class ClmArgumentParser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (raised, then printed by :func:`main`, exit code 2)."""

    def error(self, message: str) -> NoReturn:
        # "argument --speed: --speed = -5: must be ..." -> "--speed = -5: must be ..."
        head, sep, rest = message.partition(": ")
        if sep and head.startswith("argument ") and rest.startswith(head.split()[-1].split("/")[0] + " "):
            message = rest
        raise UsageError(self.prog, message)


def _plugin_registrars() -> list[tuple[str, Any]]:
    """``register`` functions of the ``clm.commands`` entry points (sorted by name; broken ones skipped)."""
    from importlib.metadata import entry_points

    out = []
    for ep in sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name):
        try:
            out.append((ep.name, ep.load()))
        except ImportError:  # a half-installed plugin must not break the core's commands
            continue
    return out


def build_parser() -> argparse.ArgumentParser:
    """Return the ``clm`` parser with every sub-command registered."""
    parser = ClmArgumentParser(
        prog="clm",
        description="Coupled lumped mass (CLM) railway track-soil dynamics.",
    )
    parser.add_argument("--version", action="version", version=f"clm {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{commands.__name__}.{info.name}")
        register = getattr(module, "register", None)
        if register is not None:
            register(sub)
    for _name, register in _plugin_registrars():
        register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``clm`` command; return the process exit code.

    ``kill -USR1 <pid>`` of a running ``clm`` process prints the Python stack of each of its threads to stderr,
    and the process goes on: how a run that hangs is diagnosed.
    """
    dump_stacks_on_signal()
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except UsageError as exc:
        print(f"{exc.prog}: error: {exc}", file=sys.stderr)
        return 2
    try:
        code: int = args.func(args)
    except (ClmError, FileNotFoundError) as exc:
        print(f"clm {args.command}: error: {exc}", file=sys.stderr)
        return 2
    return code


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
