"""Sub-commands of the ``clm`` command line.

Each module here defines ``register(subparsers)``, which adds its parser and
sets ``func`` to a callable ``run(args) -> int`` whose docstring is the
command's help (:func:`add_command`).
:mod:`clm_core.cli` discovers the modules; a new command needs no edit elsewhere.

The names below are the API of a command, here and in a plugin (the ROS
commands of ``clm_ros.commands`` register through the entry-point group
``clm.commands``): a plugin imports them from this package, never from its
private modules ``_common`` and ``_options``.
"""

from clm_core.commands._common import (
    add_command,
    add_model_arguments,
    add_window_arguments,
    check_output,
    model_from_args,
    output_dir,
    quantity,
    remove_bag,
)
from clm_core.commands._options import add_overwrite, add_setting, add_settings

__all__ = [
    "add_command",
    "add_model_arguments",
    "add_overwrite",
    "add_setting",
    "add_settings",
    "add_window_arguments",
    "check_output",
    "model_from_args",
    "output_dir",
    "quantity",
    "remove_bag",
]
