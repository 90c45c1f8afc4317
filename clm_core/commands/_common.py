"""Arguments and helpers shared by the ``clm`` sub-commands.

- :func:`add_command`: a sub-command's parser from its declaration (name,
  the function that runs it, whose docstring is the command's help, the run
  settings it takes); the ROS layer's commands (``clm_ros.commands``) use it too;
- :func:`add_model_arguments` / :func:`model_from_args`: the track, soil and
  model options (from the settings schema) and the parameter set they describe;
- :func:`output_dir`: the one rule for outputs: an existing, non-empty output
  is refused unless ``--overwrite``; a run that fails removes the directory it
  created, so no empty or half-written output is left behind;
- :func:`quantity`: numbers on the final lines, with units and 4 significant
  digits (``40.99 kN``, ``1.443 mm``).

JSON files are written by :func:`clm_core.io.files.write_json` (the one JSON helper).
"""

from __future__ import annotations

import argparse
import inspect
import shutil
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from clm_core.commands._options import add_setting, add_settings
from clm_core.errors import InputError
from clm_core.params import ModelParams
from clm_core.settings import Setting


def add_command(
    sub: Any,
    name: str,
    run: Callable[[argparse.Namespace], int],
    *,
    settings: Iterable[str | Setting[Any]] = (),
) -> argparse.ArgumentParser:
    """Add one sub-command to ``sub`` and return its parser, ready for the command's own options.

    The command's text is the docstring of ``run``: its summary line is the
    line of ``clm --help`` (shown with a lower-case first letter and no full
    stop), the rest is the description of ``clm NAME --help`` (one paragraph:
    argparse reflows it).

    Parameters
    ----------
    sub : argparse sub-parsers action
        What ``add_subparsers`` returned (``register(sub)`` receives it).
    name : str
        The sub-command (``clm NAME``).
    run : callable
        Runs the parsed arguments and returns the exit code (``args.func``);
        documented for the user (see above).
    settings : iterable of str or Setting
        Settings (by name in :data:`clm_core.settings.SETTINGS`, or objects:
        the ROS commands' from ``clm_ros.parameters``) whose options come
        first, with the schema's defaults (:func:`add_settings`).

    Returns
    -------
    argparse.ArgumentParser
    """
    summary, _, description = (inspect.getdoc(run) or "").partition("\n\n")
    summary = " ".join(summary.split()).removesuffix(".")
    p: argparse.ArgumentParser = sub.add_parser(name, help=summary[:1].lower() + summary[1:],
                                                description=" ".join(description.split()))
    p.set_defaults(func=run)
    add_settings(p, settings)
    return p


def add_model_arguments(p: argparse.ArgumentParser) -> None:
    """--track, --soil, --model, --params, --set."""
    for name in ("track", "soil", "model", "params_file"):
        add_setting(p, name)
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="override a parameter, e.g. --set kb=50e6 (repeatable)",
    )


def add_window_arguments(p: argparse.ArgumentParser, automatic_sleepers: str = "") -> None:
    """--sleepers, --elements-per-bay (the streaming track window).

    ``automatic_sleepers``: when given, ``--sleepers`` defaults to None and
    this text says how the command chooses the window.
    """
    if automatic_sleepers:
        add_setting(p, "n_sleepers", default=None, note=automatic_sleepers)
    else:
        add_setting(p, "n_sleepers")
    add_setting(p, "elements_per_bay")


def model_from_args(args: argparse.Namespace) -> ModelParams:
    """Build the validated parameter set the arguments describe."""
    from clm_core.params import model_from_settings, parse_assignments

    return model_from_settings(args.track, args.soil, args.model, args.params_file, parse_assignments(args.set))


def check_output(path: str | Path, overwrite: bool, option: str = "--out") -> Path:
    """Refuse an existing, non-empty output unless ``overwrite`` (before any computation).

    Raises
    ------
    InputError
        ``path`` exists and is a file, or a non-empty directory without ``overwrite``.
    """
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise InputError(f"{option} {p}: exists and is not a directory")
    if p.is_dir() and any(p.iterdir()) and not overwrite:
        raise InputError(f"{option} {p}: exists and is not empty; choose another directory or pass --overwrite")
    return p


@contextmanager
def output_dir(path: str | Path, overwrite: bool, option: str = "--out") -> Iterator[Path]:
    """The output directory of a command, created for the duration of the run.

    Checks :func:`check_output`, creates the directory (and missing parents)
    and yields it. If the body raises, the directories created here are removed
    again with whatever was written into them: a failed run leaves no empty or
    partial output. An existing directory (``--overwrite``) is left in place.
    """
    p = check_output(path, overwrite, option)
    top: Path | None = None  # the highest directory created here
    q = p.absolute()
    while not q.exists():
        top = q
        q = q.parent
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{option} {p}: cannot create the directory ({exc.strerror})") from None
    try:
        yield p
    except BaseException:
        if top is not None:
            shutil.rmtree(top, ignore_errors=True)
        raise


def remove_bag(path: Path, option: str) -> None:
    """Remove an existing rosbag2 bag directory (``--overwrite``); refuse anything that is not a bag."""
    if not path.exists():
        return
    if path.is_dir() and ((path / "metadata.yaml").is_file() or not any(path.iterdir())):
        shutil.rmtree(path)
        return
    raise InputError(f"{option} {path}: exists and is not a rosbag2 bag (no metadata.yaml); not removed")


_PREFIXES = {"N": ((1e6, "MN"), (1e3, "kN"), (1.0, "N")), "m": ((1.0, "m"), (1e-3, "mm"), (1e-6, "um")),
             "s": ((1.0, "s"), (1e-3, "ms"), (1e-6, "us"))}


def quantity(value: float | None, unit: str = "", digits: int = 4) -> str:
    """``value`` with ``digits`` significant digits and its unit, scaled for N, m and s.

    >>> quantity(40986.936, "N"), quantity(0.0014428, "m"), quantity(0.006722, "s"), quantity(1.994)
    ('40.99 kN', '1.443 mm', '6.722 ms', '1.994')
    """
    if value is None:
        return "n/a"
    v = float(value)
    if v != v or v in (float("inf"), float("-inf")):
        return f"{v} {unit}".strip()
    for scale, name in _PREFIXES.get(unit, ()):
        if abs(v) >= scale or scale == _PREFIXES[unit][-1][0]:
            return f"{v / scale:.{digits}g} {name}"
    return f"{v:.{digits}g} {unit}".strip()
