"""Command-line options generated from the run-settings schema (:mod:`clm_core.settings`).

:func:`add_setting` turns a :class:`~clm_core.settings.Setting` into an
argparse option: its type, default, help (description, unit, range, default)
and range check come from the schema, so ``--speed -5`` is refused while the
arguments are parsed, with one line naming the option, the value and the rule
(exit code 2, see :class:`clm_core.cli.ClmArgumentParser`).
"""

from __future__ import annotations

import argparse
from collections.abc import Iterable
from typing import Any

from clm_core.errors import ParameterError
from clm_core.settings import Setting, setting

#: Marker for "the schema's default".
SCHEMA = object()


class _Parse:
    """argparse ``type=``: :meth:`Setting.parse` with the error as an ``ArgumentTypeError``."""

    def __init__(self, s: Setting[Any], label: str) -> None:
        self.s = s
        self.label = label
        self.__name__ = s.kind.__name__  # argparse names the type in some messages

    def __call__(self, text: str) -> Any:
        try:
            return self.s.parse(text, self.label)
        except ParameterError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None


def add_setting(
    parser: Any,
    name: str | Setting[Any],
    *,
    default: Any = SCHEMA,
    note: str = "",
    metavar: str | None = None,
    optional_value: bool = False,
) -> argparse.Action:
    """Add the option of one setting to ``parser`` (a parser or an argument group).

    Parameters
    ----------
    parser : argparse.ArgumentParser or argument group
        Where to add it.
    name : str or Setting
        The setting (by name in :data:`clm_core.settings.SETTINGS`).
    default : object, optional
        Parsed-argument default. By default the schema's; a command passes
        None when it resolves an automatic value itself (then ``note`` says how,
        e.g. "or the span of --loads-file"), never another value.
    note : str
        Appended to the help text.
    metavar : str, optional
        Shown instead of the type (choices are shown as ``{a,b}``).
    optional_value : bool
        The option may be given without a value, meaning the schema's default
        (``--vehicle`` alone: the default vehicle); absent, it is None.

    Returns
    -------
    argparse.Action
    """
    s = setting(name) if isinstance(name, str) else name
    if optional_value and default is not None:
        raise ValueError(f"add_setting({s.name}): an optional value means the option defaults to None")
    if default is not SCHEMA and default is not None:
        raise ValueError(f"add_setting({s.name}): a command may only defer the default (None), not change it")
    text = s.help() + (f" {note}" if note else "")
    text = text.replace("%", "%%")
    dflt = s.default if default is SCHEMA else None
    if s.kind is bool:
        return parser.add_argument(  # type: ignore[no-any-return]
            *s.option_strings, dest=s.name, default=dflt, action=argparse.BooleanOptionalAction, help=text
        )
    mv = metavar or ("{" + ",".join(s.choices) + "}" if s.choices else None)
    extra: dict[str, Any] = {"nargs": "?", "const": s.default} if optional_value else {}
    return parser.add_argument(  # type: ignore[no-any-return]
        *s.option_strings, dest=s.name, default=dflt, type=_Parse(s, s.option), metavar=mv, help=text, **extra
    )


def add_settings(parser: Any, names: Iterable[str | Setting[Any]]) -> None:
    """:func:`add_setting` for each setting (or name), with the schema's defaults."""
    for n in names:
        add_setting(parser, n)


def add_overwrite(parser: Any, what: str = "the output directory") -> None:
    """``--overwrite``: write over an existing output (the same rule in every command)."""
    parser.add_argument(
        "--overwrite", action="store_true",
        help=f"write into {what} even if it exists and is not empty (files and bags of the same name are "
        "replaced); without it an existing output is refused",
    )
